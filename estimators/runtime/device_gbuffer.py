"""The G-buffer's covered pixels, compacted and resident on the device for every frame."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from iblbench.estimators.runtime.chunks import run_in_chunks
from iblbench.estimators.runtime.device import Compute, KeptBuffers, sample_blocks
from iblbench.scenes.gbuffer import GBuffer

# Work items per group of a pixel kernel.  PoCL's own choice (local size None) depends on the
# factors of the pixel count: at 128² it gave 3 groups of 3124 (sphere scenes; on 2 cores one
# thread runs two of them), 5 of 1867 (blob), 1 of 1304 (park-turn at 48²: one core), and
# groups of 1 at a prime count.  Groups of 64 spread any count over the cores: at load ~1, 200
# renders each, interleaved, the median shade time fell to 0.70-0.89x at 9216 pixels (balanced
# 256 spp, uniform 16, envmap{mis="brdf"} 64) and to 0.55-0.56x (envmap) at 1280 against 1304;
# images bit-identical.  It does not make renders more repeatable: groups of 5 within 15%
# IQR/median were as often or less often so (45-72% against 55-90%).  And the runner's
# 64-pixel warm-up now compiles the local size the timed renders use.
PIXEL_GROUP = 64
# Work items per group of a kernel whose loop steps in LOCKSTEP (lanes.cl: bis's and smc's
# resampling searches, the `lockstep` limit probe): 4 AVX-512 vectors, 2 warps.
LOCKSTEP_GROUP = 64


def _float4(xyz: np.ndarray, w: np.ndarray | float = 0.0) -> np.ndarray:
    out = np.empty(xyz.shape[:-1] + (4,), np.float32)
    out[..., :3] = xyz
    out[..., 3] = w
    return out


class DeviceGBuffer:
    """Covered pixels only, as float4 buffers: ``normal``, ``view``, ``kd`` and ``ks`` (w = shininess),
    and ``visibility``, each pixel's visibility mask (uint32 words, common.cl's ``visible``; one
    unread word when the G-buffer has none).  ``defines``: the kernel defines every kernel that
    reads the G-buffer is built with (``VISIBILITY``, ``VIS_RES``), empty without visibility.

    Uploaded once per scene (geometry and camera are static).  ``count`` is the number of covered
    pixels; the buffers hold ``launch_size`` ≥ ``count`` of them (a multiple of ``PIXEL_GROUP``,
    padded with copies of the last pixel, so the padding shades a real surface and stays finite).
    A pixel kernel runs over ``launch_size`` work items (:meth:`run`, in chunks); per-pixel outputs are
    ``launch_size`` long, and the first ``count`` are the image's.  ``scatter`` puts per-pixel
    kernel outputs back into the image.
    """

    def __init__(self, compute: Compute, gbuffer: GBuffer):
        self.gbuffer = gbuffer
        self.shape = gbuffer.shape
        self.pixel_index = np.flatnonzero(gbuffer.mask)
        self.count = len(self.pixel_index)
        self.launch_size = -(-self.count // PIXEL_GROUP) * PIXEL_GROUP
        self.is_diffuse = gbuffer.is_diffuse
        m = gbuffer.mask
        self.normal = compute.to_device(self._padded(_float4(gbuffer.normal[m])))
        self.view = compute.to_device(self._padded(_float4(gbuffer.view[m])))
        self.kd = compute.to_device(self._padded(_float4(gbuffer.kd[m])))
        self.ks = compute.to_device(self._padded(_float4(gbuffer.ks[m], gbuffer.shininess[m])))
        self.has_visibility = gbuffer.visibility is not None
        self.visibility_res = gbuffer.visibility_res if self.has_visibility else 0
        self.visibility = compute.to_device(self._padded(gbuffer.visibility[m]) if self.has_visibility
                                            else np.zeros(1, np.uint32))
        self.defines = {"VISIBILITY": 1, "VIS_RES": self.visibility_res} if self.has_visibility else {}
        self._scratch = KeptBuffers()   # run_sampled's partial sums, kept across frames

    def _padded(self, pixels: np.ndarray) -> np.ndarray:
        """``pixels`` followed by copies of the last one up to ``launch_size``."""
        padding = np.repeat(pixels[-1:], self.launch_size - self.count, axis=0)
        return np.concatenate([pixels, padding])

    def run(self, compute: Compute, kernel: cl.Kernel, *args) -> list[cl.Event]:
        """Run a pixel kernel over ``launch_size`` work items in groups of ``PIXEL_GROUP``, in
        launches of about ``chunks.CHUNK_MS`` device time each (:func:`run_in_chunks`: a pixel
        kernel's work grows with spp).  A launch's global ids start at its first pixel, so a work
        item's pixel is ``get_global_id(0)``, but ``get_global_size(0)`` is that launch's size: a
        kernel whose outputs are planes takes ``launch_size`` as an argument.  Returns the
        launches' events (``event_ms`` sums them).  The launch sizes start from the rate of the
        last run of the same kernel, device and signed scalar arguments (spp among them; the
        unsigned ones are the Philox keys, seed and frame, which set no item's work)."""
        return self._run_items(compute, kernel, self.launch_size, *args)

    def _run_items(self, compute: Compute, kernel: cl.Kernel, items: int, *args) -> list[cl.Event]:
        """:meth:`run` over ``items`` work items (a multiple of ``PIXEL_GROUP``)."""
        scalars = tuple(a.item() if isinstance(a, np.generic) else a for a in args
                        if isinstance(a, (int, float, np.generic)) and not isinstance(a, np.unsignedinteger))
        kind = (id(compute), kernel.function_name, items, scalars)
        return run_in_chunks(items, PIXEL_GROUP, lambda first, count: compute.run(
            kernel, count, *args, group=PIXEL_GROUP, offset=first), kind=kind)

    def run_sampled(self, compute: Compute, kernel_of, name: str, chunks: int, *args) -> list[cl.Event]:
        """Run the kernel ``name`` (``kernel_of(name)``: of the estimator's program) that sums its
        pixels' draws in lane chunks (light_pool.cl's launch shapes: ``LAUNCH_PARAMS``, its last
        three arguments before them the radiance, counts and evaluations planes), in
        ``compute.launch_shape``.  ``chunks``: the most chunks of POOL_LANES draws a pixel has, its
        strategies' together.  The pixel shape is :meth:`run`; the sample-block shape runs
        ``launch_size`` × blocks work items (:func:`device.sample_blocks`) into a scratch of partial
        sums, then ``sum_sample_blocks`` over the pixels.  Returns every launch's event."""
        if compute.launch_shape == "pixel":
            return self.run(compute, kernel_of(name), *args)
        per_block, blocks = sample_blocks(compute.info.device.max_compute_units, self.count, chunks)
        partial = self._scratch.get(compute, "partial", 4 * 4 * self.launch_size * blocks)   # R, G, B, effective
        radiance, counts = args[-3], args[-2]
        events = self._run_items(compute, kernel_of(name), self.launch_size * blocks,
                                 *args, np.int32(per_block), np.int32(blocks), partial)
        events.append(compute.run(kernel_of("sum_sample_blocks"), self.launch_size, partial,
                                  np.int32(self.launch_size), np.int32(blocks), radiance, counts,
                                  group=PIXEL_GROUP))
        return events

    def scatter(self, values: np.ndarray) -> np.ndarray:
        """Per-covered-pixel ``[N, ...]`` → image ``[H, W, ...]`` with zeros elsewhere."""
        out = np.zeros((self.shape[0] * self.shape[1],) + values.shape[1:], values.dtype)
        out[self.pixel_index] = values
        return out.reshape(self.shape + values.shape[1:])
