"""``havran``: Havran et al. 2005, "Importance Sampling for Video Environment Maps".

Each frame is decomposed into K = spp directional lights, shaded per pixel in ``havran.cl``.

**Point set.**  A fixed 2-D set: the Halton (2, 3) sequence, Lloyd-relaxed once (per process,
memoised) on the unit *torus*.  Relaxation is hierarchical, which makes it progressive: level l
holds the first 2^l Halton points; the first 2^(l-1) are the already relaxed points of level
l-1 and stay fixed, and only the new 2^(l-1) points take ``LLOYD_ITERATIONS`` Lloyd steps, each
moving a point to the centroid of its toroidal Voronoi cell, estimated on a regular grid of
about ``LLOYD_SAMPLES_PER_POINT`` samples per point.  So the first K points are the same for
every larger K (adding lights never moves existing ones), and every power-of-two prefix is
relaxed.  Beyond ``RELAX_MAX`` points the raw Halton points follow (still progressive).
Toroidal rather than clamped so that the relaxed set stays blue noise under the per-seed
Cranley–Patterson rotation below (a rotation mod 1 is an isometry of the torus, not of the
square).

**Seed.**  The render seed picks one Cranley–Patterson shift of the whole set, fixed for the
sequence (the runner keeps the seed per sequence): the same initial points every frame, as the
paper asks, and each point uniform on [0, 1)² over seeds, so on a static map the estimate is
unbiased over seeds (the FIR filter of identical frames is the identity).  On a changing map the
filter mixes past frames: biased by design.

**Mapping (bicontinuous).**  A face-wise cube-map CDF inversion jumps where the face changes, so
the map's pdf is built on one 2-D parameterisation of the sphere: Lambert's cylindrical
equal-area map, (x, y) ∈ [0, 1]² → φ = 2πx, cos θ = 1 − 2y, with +Y (the map's up) as the pole:
ω = (sin θ cos φ, cos θ, sin θ sin φ), dω = 4π dx dy.  On an ``NZ × NPHI`` grid (NZ = 2R,
NPHI = 4R for faces of R texels, capped) each cell (all have equal solid angle) gets a mass
from ``SUPERSAMPLE``² nearest-texel luminance lookups: (1 − γ)·their mean + γ·a conservative
bound, the max of the lookups (and of the texels whose centres fall in the cell) over the 3×3
cells around it (γ = ``CONSERVATIVE`` = 0.1).  The mean alone makes p ∝ Y only up to the grid
mismatch: a sun texel that overlaps a cell but none of its lookups gets the cell's tiny
density, so L/p explodes (measured: L/p up to 5000× its mean on sphere-sun at R = 64, and ΔE
*rising* from K = 64 to 256); the bound keeps L/p ≲ 1/γ of the ideal (measured ≤ 20×).  A
uniform density of weight ``DEFENSIVE`` = 0.01 is mixed in, so the pdf is positive everywhere
and an all-black map gives uniform lights.  Inversion:

- y from the rows' marginal CDF, linear within a row (piecewise-constant marginal density);
- x from the *blend* of the conditional CDFs of the two rows whose centres bracket y, linearly
  in y (clamped at the first and last half-row), inverted linearly within a column.

Every CDF is strictly increasing and continuous, the blended CDF is continuous in y (at a row
centre the blend is exactly that row's CDF, from either side), so (u1, u2) → (x, y) is a
homeomorphism of the square, and (x, y) → ω is continuous: nearby points give nearby
directions everywhere, including across cube faces (the test pins it).  The density of this
map is exact and is what the weights use:

    p(ω) = m_i·NZ · ((1 − t)·c_{i0,j} + t·c_{i1,j})·NPHI / (4π)

with m_i the row probability, c the column probabilities per row, t the blend.

**Lights.**  Light k: ω_k from point k, weight (L(ω_k)/p(ω_k))/K with L the cube-map texel of
ω_k (nearest lookup, ARCHITECTURE.md §Conventions).  **FIR filter**: per light, a causal low-pass filter over the
sequence's last ``len(fir_taps)`` frames: direction normalize(Σ a_j ω_k(t−j)), weight
Σ a_j W_k(t−j).  The taps are per frame of the sequence, not per render: a frame t−j the run
did not render (``--frames`` with a step, the first frames of a sequence) has no lights and no
tap, and the taps of the frames present are renormalised.  So a run with a step ≥ the filter's
length renders every frame unfiltered; measure flicker on consecutive frames.  (Filtering over
rendered frames instead mixed lights 6 frames apart at step 6 and lagged the day's falling
power: ΔE 54 at blob-day's night frame 66.)  ``reset()`` clears the history (so does a change
of seed or K, or a frame index that does not increase; rendering the same frame again replaces
its entry).

**Bias bound.**  On a static map (taps renormalised, so the filter of identical frames is the
identity) each point u_k + Δ is uniform on the square under the seed's shift Δ, so ω_k has the
map's exact density p and E_Δ[W_k ρ cos⁺] = I/K: averaged over seeds the estimate is I, up to
the float32 sum of K terms in the shading kernel (relative ≤ (K + 8)·2^-24).  But a sequence
keeps its seed, so the error of one shift repeats on every frame: it is the bias that one
sequence shows.  With f = L ρ cos⁺ (for a pixel, or summed over the image) and the variance of
one light V = ∫ f²/p dω − I², that bias has E_Δ[(Î_K − I)²] ≤ V/K: exactly V/K for
independent lights, and the relaxed set (each point still uniform under Δ) is assumed to do no
worse — the test measures it (3.4× below the bound on a 1e3 sun at K = 4096).  So the sequence
bias is at most z·√(V/K) for all but a fraction 2Φ(−z) of seeds: it shrinks as K^-1/2, and V
is finite because the defensive and conservative shares bound f/p (above).  On a changing map
the filter adds a lag bias that K does not shrink (the filtered mean follows I with the taps'
delay).  ``tests/test_havran_bias.py`` holds the mean over 16 seeds at K = 4096 to
z_Šidák·√(V/(16K)) + (K + 8)·2^-24, with V by quadrature of the map's density; a pdf that took
the cell's own row instead of the blend biased it by 1.6-2.3% and failed.

**Shading.**  L ≈ Σ_k W_k ρ(ω_k) cos⁺(n, ω_k) over the lights with n·ω_k > 0 (per-normal
culling).  used = K, effective = the lights above the horizon, evaluations = the lights shaded.
**On the device.**  The map, the K lights and the filter run as ``havran.cl`` kernels on
device buffers: nothing of a frame goes back to the host (the relaxed, rotated points are
uploaded once per sequence, the filter's history is a device ring of the last
``len(fir_taps)`` frames' lights, slot frame mod ``len(fir_taps)``).  Their arithmetic is that
of the NumPy twins, :class:`EqualAreaMap` (its ``sample`` and ``radiance``) and
:func:`fir_filter`, in acc_t (:func:`acc_type`) without multiply-add
contraction; the tests hold the device lights to those twins.  Only libm's cos and sin (a few ulps) and the texel lookup of a
direction within rounding of a texel edge can differ, so the lights are those of the NumPy
path to ~1e-15 and the estimator is statistically unchanged.

The ``sample`` timing is the device time of the kernels that build the frame's map CDFs
(once per frame, but counted in every render, as a light pool's build is), place the K lights
and filter them; the ``shade`` timing is the kernel's device time.
"""
from __future__ import annotations

import dataclasses
import functools
import time
import weakref

import numpy as np

from iblbench.estimators.base import (Estimator, KernelCost, Limit, Mutant, Setting, SweepPart, Tags,
                                      WorkCounts, read_estimate, visibility_defines)
from iblbench.estimators.runtime.device import event_ms
from iblbench.scenes import cubemap

LLOYD_ITERATIONS = 4
LLOYD_SAMPLES_PER_POINT = 64
RELAX_MAX = 4096          # points beyond this are raw Halton (relaxing them costs seconds)
MAX_K = 1 << 20
GRID_MAX_NZ = 512         # equal-area grid rows at most (columns = 2 × rows)
SUPERSAMPLE = 3           # lookups per cell and axis
CONSERVATIVE = 0.1        # share of the cell mass from the 3×3-dilated max (bounds L/p)
DEFENSIVE = 0.01          # uniform share of the map's pdf
SEED_SALT = 0x2005


# ---- the point set -------------------------------------------------------------------------------

def radical_inverse(index: np.ndarray, base: int) -> np.ndarray:
    index = np.asarray(index, np.int64).copy()
    result = np.zeros(index.shape, np.float64)
    scale = 1.0 / base
    while np.any(index > 0):
        result += (index % base) * scale
        index //= base
        scale /= base
    return result


def halton(n: int) -> np.ndarray:
    """The first ``n`` points of the Halton (2, 3) sequence, ``[n, 2]``."""
    i = np.arange(n)
    return np.stack([radical_inverse(i, 2), radical_inverse(i, 3)], axis=-1)


def lloyd_step(points: np.ndarray, movable: np.ndarray, samples_per_point: int = LLOYD_SAMPLES_PER_POINT
               ) -> np.ndarray:
    """One toroidal Lloyd step: each movable point goes to the centroid of its Voronoi cell on the
    unit torus, estimated on a regular grid of about ``samples_per_point`` samples per point."""
    from scipy.spatial import cKDTree   # here, not at import: `iblbench list` stays fast

    n = len(points)
    side = int(min(2048, max(32, np.ceil(np.sqrt(samples_per_point * n)))))
    g = (np.arange(side) + 0.5) / side
    grid = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    _, nearest = cKDTree(points % 1.0, boxsize=1.0).query(grid)
    offset = grid - points[nearest]
    offset -= np.round(offset)                   # shortest way round the torus
    count = np.bincount(nearest, minlength=n)
    shift = np.stack([np.bincount(nearest, offset[:, a], minlength=n) for a in (0, 1)], -1)
    shift /= np.maximum(count, 1)[:, None]
    out = points.copy()
    out[movable] = (points[movable] + shift[movable]) % 1.0
    return out


_relaxed = [halton(1)]   # _relaxed[l]: the relaxed 2^l-point level


def relaxed_points(k: int, iterations: int = LLOYD_ITERATIONS) -> np.ndarray:
    """The first ``k`` points of the hierarchically Lloyd-relaxed Halton set, ``[k, 2]``.

    Prefix-stable: ``relaxed_points(k) == relaxed_points(k2)[:k]`` for every k ≤ k2."""
    if not 1 <= k <= MAX_K:
        raise ValueError(f"K must be in [1, {MAX_K}], got {k}")
    levels = _relaxed if iterations == LLOYD_ITERATIONS else [halton(1)]
    top = min(k, RELAX_MAX)
    while len(levels[-1]) < top:
        old = levels[-1]
        n = 2 * len(old)
        points = np.concatenate([old, halton(n)[len(old):]])
        movable = np.arange(n) >= len(old)
        for _ in range(iterations):
            points = lloyd_step(points, movable)
        levels.append(points)
    level = next(p for p in levels if len(p) >= top)
    if k <= len(level):
        return level[:k].copy()
    return np.concatenate([level, halton(k)[len(level):]])


def seed_shift(seed: int) -> np.ndarray:
    """The Cranley–Patterson rotation of the point set for a render seed (fixed per sequence)."""
    return np.random.default_rng([SEED_SALT, int(seed)]).random(2)


# ---- the bicontinuous map of the frame's pdf -------------------------------------------------------

def equal_area_to_direction(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(x, y) ∈ [0, 1]² → unit direction; +Y is the pole, dω = 4π dx dy."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    cos_t = 1.0 - 2.0 * y
    sin_t = np.sqrt(np.clip(1.0 - cos_t * cos_t, 0.0, None))
    phi = 2.0 * np.pi * x
    return np.stack([sin_t * np.cos(phi), cos_t, sin_t * np.sin(phi)], -1)


def direction_to_equal_area(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`equal_area_to_direction` for unit directions ``[..., 3]``."""
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    x = (np.arctan2(d[..., 2], d[..., 0]) / (2.0 * np.pi)) % 1.0
    y = np.clip((1.0 - d[..., 1]) / 2.0, 0.0, 1.0)
    return x, y


def grid_shape(res: int) -> tuple[int, int]:
    """(NZ, NPHI) of the equal-area grid for faces of ``res`` texels."""
    nz = int(min(2 * res, GRID_MAX_NZ))
    return nz, 2 * nz


@functools.lru_cache(maxsize=8)
def lookup_texels(res: int) -> np.ndarray:
    """The texel (face·R² + row·R + col) of every supersample lookup, ``[NZ·S, NPHI·S]``: cell
    (i, j) looks up rows i·S … i·S + S − 1 and columns j·S … j·S + S − 1.  Geometry only, so
    computed once per face size."""
    nz, nphi = grid_shape(res)
    x = (np.arange(nphi * SUPERSAMPLE) + 0.5) / (nphi * SUPERSAMPLE)
    y = (np.arange(nz * SUPERSAMPLE) + 0.5) / (nz * SUPERSAMPLE)
    face, row, col = cubemap.direction_to_texel(equal_area_to_direction(x[None, :], y[:, None]).reshape(-1, 3), res)
    return ((face * res + row) * res + col).reshape(nz * SUPERSAMPLE, nphi * SUPERSAMPLE)


@functools.lru_cache(maxsize=8)
def centre_cells(res: int) -> np.ndarray:
    """The cell (i·NPHI + j) that holds each texel's centre, ``[6·R·R]`` (small texels near the
    poles can fall between a cell's lookups)."""
    nz, nphi = grid_shape(res)
    cx, cy = direction_to_equal_area(cubemap.texel_directions(res).reshape(-1, 3))
    return (np.minimum((cy * nz).astype(np.int64), nz - 1) * nphi
            + np.minimum((cx * nphi).astype(np.int64), nphi - 1))


class EqualAreaMap:
    """The frame's luminance pdf on the equal-area grid and its continuous inversion.

    ``EqualAreaMap(env)`` builds it with NumPy: the twin (the tests' oracle) of the device map
    that :meth:`on_device` builds with the kernels of ``havran.cl``, and of ``place_lights``,
    the device twin of :meth:`sample`."""

    def __init__(self, env: np.ndarray):
        start = time.perf_counter()
        res = env.shape[1]
        self.nz, self.nphi = grid_shape(res)
        self.env = env
        s = SUPERSAMPLE
        texel_lum = np.maximum(cubemap.luminance(env.astype(np.float64)), 0.0).reshape(-1)
        lookups = texel_lum[lookup_texels(res)].reshape(self.nz, s, self.nphi, s)
        mean, value = lookups.mean(axis=(1, 3)), lookups.max(axis=(1, 3))
        # Every texel also counts in the cell that holds its centre (small texels near the poles).
        np.maximum.at(value.reshape(-1), centre_cells(res), texel_lum)
        # Conservative: a 3×3 max filter (φ wraps), so a texel that overlaps a cell but none of
        # its lookups still bounds that cell's density from below, and L/p stays bounded.
        padded = np.pad(value, ((1, 1), (0, 0)), mode="edge")
        padded = np.concatenate([padded[:, -1:], padded, padded[:, :1]], axis=1)
        bound = np.max([padded[1 + a:1 + a + self.nz, 1 + b:1 + b + self.nphi]
                        for a in (-1, 0, 1) for b in (-1, 0, 1)], axis=0)
        mass = (1.0 - CONSERVATIVE) * mean + CONSERVATIVE * bound
        total = mass.sum()
        uniform = np.full_like(mass, 1.0 / mass.size)
        if total > 0 and np.isfinite(total):
            prob = (1.0 - DEFENSIVE) * mass / total + DEFENSIVE * uniform
        else:
            prob = uniform
        self.row_prob = prob.sum(axis=1)                              # m_i
        self.row_cdf = np.cumsum(self.row_prob)
        self.row_cdf /= self.row_cdf[-1]
        self.col_prob = prob / self.row_prob[:, None]                 # c_{i,j}
        self.col_cdf = np.cumsum(self.col_prob, axis=1)
        self.col_cdf /= self.col_cdf[:, -1:]
        self.build_ms = (time.perf_counter() - start) * 1e3

    @staticmethod
    def on_device(cache) -> "DeviceEqualAreaMap":
        """The map of a FrameCache's frame, built by havran.cl from the uploaded map."""
        return DeviceEqualAreaMap(cache)

    @classmethod
    def of_device_map(cls, device: "DeviceEqualAreaMap", env: np.ndarray) -> "EqualAreaMap":
        """The NumPy inversion (:meth:`sample`) over a device map's own arrays (host copies):
        the twin of ``place_lights`` for tests and the stress battery's χ²."""
        twin = cls.__new__(cls)
        twin.nz, twin.nphi, twin.env, twin.build_ms = device.nz, device.nphi, env, device.build_ms
        for name in DeviceEqualAreaMap.ARRAYS:
            setattr(twin, name, getattr(device, name))
        return twin

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points ``[n, 2]`` in [0, 1)² → (directions ``[n, 3]``, pdf in solid angle ``[n]``)."""
        u = np.asarray(u, np.float64)
        u1, u2 = u[:, 0], u[:, 1]
        i = np.minimum(np.searchsorted(self.row_cdf, u1, side="right"), self.nz - 1)
        lo = np.where(i > 0, self.row_cdf[np.maximum(i - 1, 0)], 0.0)
        y = (i + np.clip((u1 - lo) / self.row_prob[i], 0.0, 1.0)) / self.nz
        centre = y * self.nz - 0.5
        i0 = np.floor(centre).astype(np.int64)
        t = centre - i0
        r0, r1 = np.clip(i0, 0, self.nz - 1), np.clip(i0 + 1, 0, self.nz - 1)
        # The blend of rows r0 and r1's CDFs is non-decreasing (and stays so in rounding), so the
        # count of its entries ≤ u2 is a binary search over columns, O(log nphi) a point.
        blend = lambda col: (1.0 - t) * self.col_cdf[r0, col] + t * self.col_cdf[r1, col]
        below, above = np.zeros(len(u), np.int64), np.full(len(u), self.nphi)
        while np.any(below < above):
            active = below < above
            mid = np.minimum((below + above) // 2, self.nphi - 1)    # clamped for finished points
            left = active & (blend(mid) <= u2)
            below, above = np.where(left, mid + 1, below), np.where(active & ~left, mid, above)
        j = np.minimum(below, self.nphi - 1)
        lo = np.where(j > 0, blend(np.maximum(j - 1, 0)), 0.0)
        width = (1.0 - t) * self.col_prob[r0, j] + t * self.col_prob[r1, j]
        x = (j + np.clip((u2 - lo) / width, 0.0, 1.0)) / self.nphi
        pdf = self.row_prob[i] * self.nz * width * self.nphi / (4.0 * np.pi)
        return equal_area_to_direction(x, y), pdf

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        face, row, col = cubemap.direction_to_texel(dirs, self.env.shape[1])
        return self.env[face, row, col].astype(np.float64)


def acc_type(compute) -> np.dtype:
    """havran.cl's acc_t on ``compute``: double where its kernels are built with doubles
    (``Compute.doubles``: the device has them and this is not the float path), else float.  The
    buffers the kernels accumulate into are sized by it and read back as it."""
    return np.dtype(np.float64 if compute.doubles else np.float32)


class DeviceEqualAreaMap:
    """The frame's map on the device: the arrays of :class:`EqualAreaMap` (row_prob, row_cdf,
    col_prob, col_cdf) as acc_t buffers (``buffers``), equal to the NumPy build up to float
    rounding (luminance in float32 on the device); ``build_ms`` is the kernels' device time.
    The arrays' attributes are host copies made on first access (tests and inspection)."""

    ARRAYS = ("row_prob", "row_cdf", "col_prob", "col_cdf")

    def __init__(self, cache):
        compute, res = cache.compute, cache.res
        self.compute = compute
        self.nz, self.nphi = grid_shape(res)
        lookup, offsets, texels = _device_tables(compute, res)
        cells = self.nz * self.nphi
        self.acc = acc_type(compute)
        width = self.acc.itemsize
        mean, value, mass = compute.empty(4 * cells), compute.empty(4 * cells), compute.empty(width * cells)
        row_mass, row_prob, row_cdf = (compute.empty(width * self.nz) for _ in range(3))
        col_prob, col_cdf, factors = compute.empty(width * cells), compute.empty(width * cells), compute.empty(2 * width)

        def run(name, size, *args):
            return compute.run(compute.kernel(Havran.kernel_package(), "havran.cl", name), size, *args)

        nz, nphi = np.int32(self.nz), np.int32(self.nphi)
        events = [
            run("cell_lookups", cells, cache.env_buffer, lookup, nphi, np.int32(SUPERSAMPLE), offsets,
                texels, mean, value),
            run("cell_mass", cells, mean, value, nz, nphi, np.float32(CONSERVATIVE), mass),
            run("row_mass", self.nz, mass, nphi, row_mass),
            run("grid_factors", 1, row_mass, nz, nphi, np.float32(DEFENSIVE), factors),
            run("row_cdfs", self.nz, mass, factors, nphi, row_prob, col_prob, col_cdf),
            run("marginal_cdf", 1, row_prob, nz, row_cdf),
        ]
        self.buffers = dict(zip(self.ARRAYS, (row_prob, row_cdf, col_prob, col_cdf)))
        self.build_ms = sum(event_ms(e) for e in events)

    def __getattr__(self, name):
        if name not in DeviceEqualAreaMap.ARRAYS:
            raise AttributeError(name)
        shape = (self.nz,) if name.startswith("row") else (self.nz, self.nphi)
        array = self.compute.to_host(self.buffers[name], shape, self.acc).astype(np.float64)
        setattr(self, name, array)
        return array


_maps: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_tables: dict = {}


def _device_tables(compute, res: int) -> tuple:
    """The lookup texels and, as CSR (offsets per cell, texels), the texel centres per cell, on
    the device: uploaded once per (context, face size)."""
    key = (compute, res)
    if key not in _tables:
        cells = centre_cells(res)
        order = np.argsort(cells, kind="stable")
        offsets = np.searchsorted(cells[order], np.arange(np.prod(grid_shape(res)) + 1))
        _tables[key] = (compute.to_device(lookup_texels(res).astype(np.int32)),
                        compute.to_device(offsets.astype(np.int32)),
                        compute.to_device(order.astype(np.int32)))
    return _tables[key]


def frame_map(cache) -> DeviceEqualAreaMap:
    """The map of a FrameCache's frame, built on the device once per cache."""
    if cache not in _maps:
        _maps[cache] = EqualAreaMap.on_device(cache)
    return _maps[cache]


# ---- the FIR filter ------------------------------------------------------------------------------

def fir_filter(directions: list[np.ndarray], weights: list[np.ndarray], taps,
               lags=None) -> tuple[np.ndarray, np.ndarray]:
    """Causal FIR over a light trajectory, newest first: ``directions[j]``/``weights[j]`` is
    frame t − ``lags[j]`` (default: t − j).  Entry j gets tap ``taps[lags[j]]``; entries beyond
    the filter's length are ignored and the taps of the entries present are renormalised.
    Directions are filtered as vectors and renormalised (falling back to the newest one where
    the sum vanishes)."""
    lags = range(len(directions)) if lags is None else lags
    used = [j for j, lag in enumerate(lags) if lag < len(taps)]
    if len(used) == 1:           # no history (or no filter): the identity, bit for bit
        return directions[used[0]], weights[used[0]]
    a = np.asarray([taps[lags[j]] for j in used], np.float64)
    a = a / a.sum()
    d = sum(a_j * directions[j] for a_j, j in zip(a, used))
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    d = np.where(norm > 1e-9, d / np.maximum(norm, 1e-300), directions[used[0]])
    w = sum(a_j * weights[j] for a_j, j in zip(a, used))
    return d, w


# ---- the estimator -------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class HavranParams:
    """Parameters of ``havran``.

    ``fir_taps`` (default (0.5, 0.3, 0.2)): the causal low-pass filter's taps, newest frame
    first; its length is the filter's length (``(1.0,)`` turns filtering off).  Taps must be
    non-negative with a positive sum; they are renormalised over the history that exists.
    """

    fir_taps: tuple[float, ...] = (0.5, 0.3, 0.2)


class Havran(Estimator):
    """Halton + Lloyd-relaxed inverse-transform directional lights (Havran et al. 2005), with
    FIR-filtered trajectories and power and per-normal culling; K = spp lights."""

    name = "havran"
    sweep = SweepPart(("havran",), order=4)
    cost = KernelCost(57, 5, 0, 17, 92, derivation="""\
        a light above the horizon: lobe power 41, phong_value 7, ×W, ×cos 6, sum 3; per light
        n·ω 5, culled or not; per pixel the reflection 12 and hoisted factors 5; bytes: 64 in,
        radiance float4, counts float2 and evaluations out""",
        scalar=True, limits=(   # render_havran's loop over the K lights, a pixel a work item
            Limit("phong_power", per_sample=1, why="phong_brdf's lobe power, a light"),))
    Params = HavranParams
    settings = (Setting("fir_taps", (1.0,), says="fir_taps"), Setting("fir_taps", (0.2, 0.8), says="fir_taps"))
    tags = Tags(unbiased=False, temporal=True, has_pdf=False)
    unbiased_on_static_maps = True   # "Bias bound" above: the stress battery z-tests static maps
    requires = ()
    max_spp = MAX_K
    kernel_files = ("havran.cl",)
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        Mutant("havran-lobe-axis-normal", "havran.cl",
               "float3 r = reflect_view(n, view[p].xyz);",
               "float3 r = n;", stress=("shininess",)),
        # The renderer places and filters its lights on the device (havran.cl); EqualAreaMap.sample
        # and fir_filter are the tests' NumPy twins, so the mutants change the kernels' side.
        # (A mutant of this file spells its text in two pieces: the file holds it whole once.)
        Mutant("havran-fir-not-renormalised", "havran.py",
               "compute.to_device((a / a.sum())" ".astype(acc))",
               "compute.to_device(a.astype(acc))", stress=("static-sequence",)),
        Mutant("havran-pdf-blend-row0-only", "havran.cl",
               "acc_t width = (1 - t) * col_prob[(cdf0 - col_cdf) + j] + t * col_prob[(cdf1 - col_cdf) + j];",
               "acc_t width = col_prob[(cdf0 - col_cdf) + j];",
               stress=("hot-texel", "black-faces")),
        Mutant("havran-pdf-of-own-row-not-blend", "havran.cl",
               "acc_t pdf = row_prob[i] * nz * width * nphi",
               "acc_t pdf = row_prob[i] * nz * col_prob[i * nphi + j] * nphi",
               stress=("hot-texel", "black-faces")),
        Mutant("havran-weight-without-k", "havran.cl",
               "acc_t scale = pdf * count;",
               "acc_t scale = pdf * max(count - 1, 1);", stress=("constant",)),
        Mutant("havran-culling-keeps-backfacing", "havran.cl",
               "        if (c <= 0.0f)\n            continue;",
               "        if (c < -0.5f)\n            continue;", stress=("constant",)),
        # acc_t by the device alone: at fp64=False on a device with doubles the kernels write
        # floats into buffers read as doubles (check_float_path, off by about 500×).
        Mutant("havran-acc-type-by-device", "havran.py",
               "np.float64 if compute." "doubles else np.float32",
               "np.float64 if compute.info.has_fp64 else np.float32"),
    )

    def __init__(self, params=None, **overrides):
        super().__init__(params, **overrides)
        taps = np.asarray(self.params.fir_taps, np.float64)
        if taps.ndim != 1 or len(taps) < 1 or np.any(taps < 0) or not taps.sum() > 0:
            raise ValueError(f"fir_taps must be non-negative with a positive sum, got {self.params.fir_taps}")
        self.reset()

    def reset(self) -> None:
        self._key = None          # (seed, K) of the history
        self._history: list[int] = []   # the frames whose lights the ring holds, newest first
        self._ring = None         # (compute, K, directions, weights): acc_t [len(taps), K, 4] each
        self._points = None       # (compute, K, seed, the points' buffer)

    def _kernel(self, compute, name):
        return compute.kernel(self.kernel_package(), self.kernel_files[0], name)

    def _points_buffer(self, compute, k: int, seed: int):
        """The rotated relaxed points on the device, uploaded once per (context, K, seed)."""
        if self._points is None or self._points[:3] != (compute, k, seed):
            points = (relaxed_points(k) + seed_shift(seed)) % 1.0
            self._points = (compute, k, seed, compute.to_device(points.astype(acc_type(compute))))
        return self._points[3]

    def _place(self, cache, k: int, seed: int, directions, weights, slot: int) -> float:
        """This frame's unfiltered lights into slot ``slot`` of ``directions`` and ``weights``
        (acc_t [slots, K, 4]); returns the device ms of the map and the placement."""
        compute, envmap = cache.compute, frame_map(cache)
        maps = [envmap.buffers[name] for name in DeviceEqualAreaMap.ARRAYS]
        event = compute.run(self._kernel(compute, "place_lights"), k, cache.env_buffer,
                            np.int32(cache.res), *maps, np.int32(envmap.nz), np.int32(envmap.nphi),
                            self._points_buffer(compute, k, seed), np.int32(k), np.int32(slot),
                            directions, weights)
        return envmap.build_ms + event_ms(event)

    def _acc_buffers(self, compute, k: int, slots: int = 1):
        width = acc_type(compute).itemsize
        return compute.empty(slots * k * 4 * width), compute.empty(slots * k * 4 * width)

    def _to_host(self, compute, buffer, k: int) -> np.ndarray:
        return compute.to_host(buffer, (k, 4), acc_type(compute))[:, :3].astype(np.float64)

    def raw_lights(self, cache, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """This frame's unfiltered lights, host copies (tests): directions ``[k, 3]`` and weights
        L/(p·K) ``[k, 3]``; the history is untouched."""
        directions, weights = self._acc_buffers(cache.compute, k)
        self._place(cache, k, seed, directions, weights, 0)
        return self._to_host(cache.compute, directions, k), self._to_host(cache.compute, weights, k)

    def _filtered(self, cache, k: int, seed: int) -> tuple:
        """The filtered lights of this frame on the device, updating the history: (float4
        directions, float4 weights, acc_t directions, acc_t weights, device ms)."""
        compute, taps = cache.compute, self.params.fir_taps
        frame = int(cache.frame)
        if self._key != (int(seed), k) or (self._history and frame < self._history[0]):
            self.reset()
        if not (self._history and frame == self._history[0]):
            self._history.insert(0, frame)
        self._key = (int(seed), k)
        self._history = [f for f in self._history if frame - f < len(taps)]
        if self._ring is None or self._ring[:2] != (compute, k):
            self._ring = (compute, k) + self._acc_buffers(compute, k, len(taps))
        rings = self._ring[2:]
        ms = self._place(cache, k, seed, *rings, frame % len(taps))
        a = np.asarray([taps[frame - f] for f in self._history], np.float64)
        acc = acc_type(compute)
        slots = compute.to_device(np.asarray([f % len(taps) for f in self._history], np.int32))
        outputs = self._acc_buffers(compute, k) + (compute.empty(k * 16), compute.empty(k * 16))
        event = compute.run(self._kernel(compute, "filter_lights"), k, *rings, np.int32(k), slots,
                            compute.to_device((a / a.sum()).astype(acc)), np.int32(len(a)), *outputs)
        return outputs[2:] + outputs[:2] + (ms + event_ms(event),)

    def lights(self, cache, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """The filtered lights of this frame, host copies (tests), updating the history."""
        _, _, directions, weights, _ = self._filtered(cache, k, seed)
        return self._to_host(cache.compute, directions, k), self._to_host(cache.compute, weights, k)

    def work_counts(self, gbuffer, frames) -> list[WorkCounts]:
        """"Shading" above: the K lights above each pixel's horizon (n·ω > 0) shaded, each with
        its V; the lights those a fresh instance places and filters on the same frames."""
        twin, normals = type(self)(self.params), gbuffer.normal[gbuffer.mask].astype(np.float32)
        counts = []
        for frame in frames:
            directions, _ = twin.lights(frame.cache, frame.spp, frame.seed)
            above = (normals @ directions.astype(np.float32).T > 0).sum(1)
            counts.append(WorkCounts(above, above))
        return counts

    def render(self, gbuffer, cache, spp, seed):
        if not 1 <= spp <= MAX_K:
            raise ValueError(f"spp (K lights) must be in [1, {MAX_K}], got {spp}")
        compute = cache.compute
        # Like a light pool's build_ms, the frame's map build counts in every render's "sample"
        # stage, though it is built once per frame and reused.
        light_dir, light_weight, _, _, sample_ms = self._filtered(cache, int(spp), seed)
        defines = visibility_defines(gbuffer)
        cells = compute.empty(4 * int(spp) if defines else 4)
        if defines:   # the lights' visibility cells, found once for every pixel
            event = compute.run(compute.kernel(self.kernel_package(), self.kernel_files[0], "light_cells",
                                               defines), int(spp), light_dir, cells)
            sample_ms += event_ms(event)
        kernel = compute.kernel(self.kernel_package(), self.kernel_files[0], "render_havran", defines)
        radiance = compute.empty(gbuffer.launch_size * 16)
        counts = compute.empty(gbuffer.launch_size * 8)
        evaluations = compute.empty(gbuffer.launch_size * 4)
        event = gbuffer.run(compute, kernel, gbuffer.normal, gbuffer.view, gbuffer.kd,
                            gbuffer.ks, gbuffer.visibility, cells, light_dir, light_weight, np.int32(spp),
                            radiance, counts, evaluations)
        mean_evaluations = compute.to_host(evaluations, (gbuffer.count,), np.int32).mean() \
            if gbuffer.count else 0.0
        return read_estimate(compute, gbuffer, radiance, counts, mean_evaluations,
                             {"sample": sample_ms, "shade": event_ms(event)})
