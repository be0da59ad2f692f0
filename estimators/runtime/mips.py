"""Mip chains of a cube map on the device: the frame cache's ``weight_pyramid`` and
``radiance_mips`` products (estimators/runtime/framecache.py), both built by ``reduce_2x2`` of mips.cl.

Layout (one definition, read by every sampler of a chain): level 0 is the finest, of the map's
face size R; level l has size n_l = ⌈R / 2^l⌉ (:func:`level_sizes`), down to 1×1.  Every level
lies in one float32 buffer, level after level from the finest, level l's texels ``[6, n_l, n_l,
channels]`` (face-major, rows downward: ARCHITECTURE.md §Conventions) from float offset ``offsets[l]``
(:func:`level_offsets`).  A parent texel covers the 2×2 children (2·row + a, 2·col + b) that
exist: an odd size leaves the last row and column of parents with fewer children.

- Sampling-weight pyramid (``channels`` 1, sums): level 0 holds each texel's sampling weight,
  Y·Ω or MIS-compensated (framecache.cl's ``sampling_weights``); a parent holds the sum of its
  children, so the coarsest level holds each face's total weight (I_f = Σ Y·Ω uncompensated).
  ``hierarchical`` descends it (estimators/hierarchical.cl).
- Radiance mip chain (``channels`` 4, means): level 0 is a copy of the map's float4 texels; a
  parent holds the box average of its children (RGB; w stays 0), per face: no filtering across
  cube edges.  Where a face size is not a power of two, a parent of fewer children averages
  those it has, so coarser levels weigh the texels unequally.  A solid-angle weighting of the average would be a different filter; the box is
  what a GPU's mip generation computes.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pyopencl as cl

from iblbench.estimators.runtime.device import Compute, event_ms


def level_sizes(res: int) -> tuple[int, ...]:
    """Face sizes of the levels of a chain over faces of ``res``: R, ⌈R/2⌉, …, 1."""
    sizes = [int(res)]
    while sizes[-1] > 1:
        sizes.append((sizes[-1] + 1) // 2)
    return tuple(sizes)


def level_offsets(res: int, channels: int) -> tuple[int, ...]:
    """Float offset of each level of a chain over faces of ``res`` (finest first), and, last, the
    float count of the whole chain."""
    offsets = [0]
    for n in level_sizes(res):
        offsets.append(offsets[-1] + 6 * n * n * channels)
    if offsets[-1] > 2 ** 31 - 1:   # the kernels index the chain with int offsets
        raise ValueError(f"a mip chain of {res}² faces with {channels} channels holds {offsets[-1]} "
                         f"floats, past the 2^31 − 1 an int offset reaches (faces up to 8192² hold fewer)")
    return tuple(offsets)


@dataclasses.dataclass(frozen=True)
class MipChain:
    """A chain in the layout of the module docstring: ``buffer`` float32, level l's texels from
    float offset ``offsets[l]``, of face size ``sizes[l]``; ``build_ms`` the device time that
    built it (the compensated weight pyramid's without that of the plain one it reads)."""

    buffer: cl.Buffer
    sizes: tuple[int, ...]
    offsets: tuple[int, ...]
    channels: int
    build_ms: float

    def host_levels(self, compute: Compute) -> list[np.ndarray]:
        """Every level copied back, float32 ``[6, n_l, n_l, channels]`` (tests and checks)."""
        flat = compute.to_host(self.buffer, (level_offsets(self.sizes[0], self.channels)[-1],), np.float32)
        return [flat[at:at + 6 * n * n * self.channels].reshape(6, n, n, self.channels)
                for at, n in zip(self.offsets, self.sizes)]


    def face_totals(self, compute: Compute) -> np.ndarray:
        """The 1×1 level alone, float32 ``[6, channels]``: six texels read back, not the chain."""
        out = np.empty((6, self.channels), np.float32)
        cl.enqueue_copy(compute.queue, out, self.buffer, src_offset=4 * self.offsets[-1]).wait()
        return out


def reduce_levels(compute: Compute, buffer: cl.Buffer, res: int, channels: int, average: bool) -> float:
    """Fill levels 1… of the chain in ``buffer`` from its level 0 (already there), parent level
    by parent level; returns their device ms."""
    sizes, offsets = level_sizes(res), level_offsets(res, channels)
    kernel = compute.kernel("iblbench.estimators.runtime", "mips.cl", "reduce_2x2",
                            {"CHANNELS": channels, "AVERAGE": int(average)})
    total_ms = 0.0
    for level in range(1, len(sizes)):
        event = compute.run(kernel, 6 * sizes[level] ** 2, buffer, np.int32(offsets[level - 1]),
                            np.int32(sizes[level - 1]), np.int32(offsets[level]), np.int32(sizes[level]))
        total_ms += event_ms(event)
    return total_ms


def chain(buffer: cl.Buffer, res: int, channels: int, build_ms: float) -> MipChain:
    """The :class:`MipChain` of ``buffer`` in this module's layout."""
    return MipChain(buffer, level_sizes(res), level_offsets(res, channels)[:-1], channels, build_ms)
