"""Per-frame device products, built lazily: only what the chosen estimators ``require``.

Products:
- ``env``: the frame's radiance as a float4 device buffer ``[6·R·R]`` (always uploaded);
- ``cdf``: per-face marginal (rows) and conditional (columns | row) luminance CDFs and the face
  luminance integrals I_f (Lu 2013 Eq. 3), built on the device.  The CDFs are 2^63 fixed point
  (uint64 words, ``CDF_ONE`` below), searched with 63-bit variates: every texel of positive
  luminance keeps a positive, relatively exact probability next to a sun (issue 6, stress case
  sun-1e9; the reasons are in ``kernels/common.cl``);
- ``pool``: Lu 2013's shared light-sample pool (Algorithm 1, line 10): per lit face, samples
  drawn from that face's CDFs, each storing direction, pdf_L(ω|f) and radiance.  Its size
  depends on the estimator's budget and its random rotation on the render seed, so
  ``require("pool")`` builds only its input (``cdf``) and :meth:`FrameCache.light_pool` draws a
  pool per (size, seed) on first use; its device time is ``timings_ms["pool"]``.

Each build is timed by OpenCL profiling events (``timings_ms``); ``built`` lists what was built,
so the runner can record which stages were skipped.  :func:`build_fixed_point_cdfs` is the same
fixed-point CDF build for any runs of weights on the device (another sampler's map).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

import dataclasses
import weakref

from iblbench.harness.device import Compute, event_ms
from iblbench.scenes import cubemap

PRODUCTS = ("env", "cdf", "pool")
CDF_ONE = 2 ** 63   # the fixed-point CDFs' total (kernels/common.cl)
POOLS_KEPT = 4   # pools of recent (size, seed) kept resident
SPARE_BUFFERS_KEPT = 2   # buffers of one size kept for the next frame's cache


def build_fixed_point_cdfs(compute: Compute, weights: cl.Buffer, runs: int,
                           n: int) -> tuple[cl.Buffer, cl.Buffer, float]:
    """Fixed-point CDFs of ``runs`` runs of ``n`` float32 weights ≥ 0 (a device buffer
    ``[runs, n]``, run-major), built on the device by ``weight_cdfs`` of framecache.cl: one
    work item per run, eight bins per vector step.

    Returns (cdfs, totals, device ms): ``cdfs`` uint64 ``[runs, n]``, each run's inclusive
    prefix sums of integer widths ending at exactly ``CDF_ONE`` = 2^63, where every positive
    weight has a width ≥ 1 (searched with ``cdf_search``/``cdf_bin`` of kernels/common.cl);
    ``totals`` float32 ``[runs]``, each run's Σ w.  A two-level sampler (rows, then columns)
    builds its conditional CDFs from the map and its marginal from the conditional's totals."""
    cdfs, totals = compute.empty(runs * n * 8), compute.empty(runs * 4)
    event = compute.run(compute.kernel("iblbench.harness", "framecache.cl", "weight_cdfs"), runs,
                        weights, np.int32(n), cdfs, totals)
    return cdfs, totals, event_ms(event)


_solid_angles: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_spare_buffers: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _texel_solid_angles(compute: Compute, res: int) -> cl.Buffer:
    """Ω per texel of a face, float32 ``[R, R]`` on the device: geometry, uploaded once per
    (context, face size), not per frame."""
    per_res = _solid_angles.setdefault(compute, {})
    if res not in per_res:
        per_res[res] = compute.to_device(cubemap.texel_solid_angles(res).astype(np.float32))
    return per_res[res]


def _spare_buffer(compute: Compute, nbytes: int) -> cl.Buffer:
    """A buffer of ``nbytes`` that a dead cache left (else a new one).  Device buffers stay
    resident across frames: a fresh one pays its first-touch page faults inside the kernel that
    first writes it (on PoCL, 45 ms of a 1024² CDF build that takes 25 ms without them)."""
    spare = _spare_buffers.get(compute, {}).get(nbytes)
    return spare.pop() if spare else compute.empty(nbytes)


def _keep_spares(compute_ref: weakref.ref, buffers: list) -> None:
    """A cache's finaliser: its buffers become spares for the next cache of the context."""
    compute = compute_ref()
    if compute is not None:
        per_size = _spare_buffers.setdefault(compute, {})
        for buffer in buffers:
            spare = per_size.setdefault(buffer.size, [])
            if len(spare) < SPARE_BUFFERS_KEPT:
                spare.append(buffer)


@dataclasses.dataclass(frozen=True)
class LightPool:
    """``per_face`` entries per face, face-major: ``dir_pdf`` float4 (ω, pdf_L(ω|f)) and
    ``radiance`` float4; ``build_ms`` is the device time that drew it."""

    dir_pdf: cl.Buffer
    radiance: cl.Buffer
    per_face: int
    seed: int
    build_ms: float


class FrameCache:
    def __init__(self, compute: Compute, env: np.ndarray, frame: int = 0):
        env = np.asarray(env, dtype=np.float32)
        if env.ndim != 4 or env.shape[0] != 6 or env.shape[1] != env.shape[2] or env.shape[3] != 3:
            raise ValueError(f"environment must be [6, R, R, 3], got {env.shape}")
        self.compute = compute
        self.env = env
        self.frame = frame
        self.res = env.shape[1]
        self.timings_ms: dict[str, float] = {}
        self._owned: list[cl.Buffer] = []   # the map's and the CDFs' buffers: spares once dead
        weakref.finalize(self, _keep_spares, weakref.ref(compute), self._owned)
        self._env_buffer = self._upload_env()
        self._cdf: tuple | None = None
        self._face_integrals: np.ndarray | None = None
        self._pools: dict[tuple[int, int], LightPool] = {}

    def retarget(self, frame: int) -> None:
        """Serve frame ``frame``, whose environment is this cache's own (the same array): the
        CDFs and the uploaded map stay; the light pools, whose random rotation depends on the
        frame, are dropped so that they are drawn for the new frame."""
        self.frame = frame
        self._pools.clear()

    @property
    def built(self) -> list[str]:
        return (["env"] + (["cdf"] if self._cdf is not None else [])
                + (["pool"] if self._pools else []))

    def require(self, products) -> None:
        """Build every named product that is not built yet."""
        for name in products:
            if name not in PRODUCTS:
                raise KeyError(f"unknown frame-cache product '{name}'; valid: {', '.join(PRODUCTS)}")
            if name in ("cdf", "pool"):
                self._build_cdf()

    @property
    def env_buffer(self) -> cl.Buffer:
        return self._env_buffer

    @property
    def marginal(self) -> cl.Buffer:
        return self._build_cdf()[0]

    @property
    def conditional(self) -> cl.Buffer:
        return self._build_cdf()[1]

    @property
    def face_integral_buffer(self) -> cl.Buffer:
        return self._build_cdf()[2]

    @property
    def face_integrals(self) -> np.ndarray:
        """I_f = Σ Y·Ω per face, float32 ``[6]`` (host copy, made on first use)."""
        if self._face_integrals is None:
            self._face_integrals = self.compute.to_host(self.face_integral_buffer, (6,), np.float32)
        return self._face_integrals

    def _buffer(self, nbytes: int) -> cl.Buffer:
        """A device buffer this cache owns (a spare of a dead cache where there is one)."""
        buffer = _spare_buffer(self.compute, nbytes)
        self._owned.append(buffer)
        return buffer

    def _upload_env(self) -> cl.Buffer:
        padded = np.zeros(self.env.shape[:3] + (4,), np.float32)
        padded[..., :3] = self.env
        buffer = self._buffer(padded.nbytes)
        event = cl.enqueue_copy(self.compute.queue, buffer, padded)
        event.wait()
        self.timings_ms["upload"] = event_ms(event)
        return buffer

    def _build_cdf(self) -> tuple:
        if self._cdf is None:
            c, res = self.compute, self.res
            conditional = self._buffer(6 * res * res * 8)      # fixed-point CDF words (common.cl)
            row_weight = self._buffer(6 * res * 4)
            rows = c.run(c.kernel("iblbench.harness", "framecache.cl", "row_cdfs"), 6 * res,
                         self._env_buffer, _texel_solid_angles(c, res), np.int32(res), conditional,
                         row_weight)
            marginal, integral, faces_ms = build_fixed_point_cdfs(c, row_weight, 6, res)
            self.timings_ms["cdf"] = event_ms(rows) + faces_ms
            self._cdf = (marginal, conditional, integral)
        return self._cdf

    def light_pool(self, per_face: int, seed: int) -> LightPool:
        """The pool of ``per_face`` samples per face for render seed ``seed`` (drawn on first use).

        The seed and frame pick the random rotation of the pool's fixed 2-D sequence, so each
        render seed sees an independent, unbiased pool.
        """
        key = (int(per_face), int(seed))
        if key not in self._pools:
            marginal, conditional, integral = self._build_cdf()
            c, count = self.compute, 6 * key[0]
            dir_pdf, radiance = c.empty(count * 16), c.empty(count * 16)
            event = c.run(c.kernel("iblbench.harness", "framecache.cl", "build_light_pool"), count,
                          self._env_buffer, marginal, conditional, integral, np.int32(self.res),
                          np.int32(key[0]), np.uint32(seed), np.uint32(self.frame), dir_pdf, radiance)
            self.timings_ms["pool"] = event_ms(event)
            if len(self._pools) >= POOLS_KEPT:
                del self._pools[next(iter(self._pools))]
            self._pools[key] = LightPool(dir_pdf, radiance, key[0], key[1], self.timings_ms["pool"])
        return self._pools[key]

    def host_cdfs(self) -> tuple[np.ndarray, np.ndarray]:
        """(marginal ``[6, R]``, conditional ``[6, R, R]``) copied back, for tests and checks:
        uint64 fixed-point CDFs, inclusive, ending at exactly ``CDF_ONE`` = 2^63 (a bin's
        probability is its width / 2^63; kernels/common.cl)."""
        marginal, conditional = self._build_cdf()[:2]
        res = self.res
        return (self.compute.to_host(marginal, (6, res), np.uint64),
                self.compute.to_host(conditional, (6, res, res), np.uint64))
