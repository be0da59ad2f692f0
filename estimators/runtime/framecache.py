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
  pool per (size, seed) on first use; its device time is ``timings_ms["pool"]``;
- ``light_cdfs``: the light samplers' CDFs beyond ``cdf`` (estimators/envmap.py, and
  ``balanced_mis`` with MIS compensation), drawn on first use like the pool, since what they
  hold depends on the estimator's parameters: :meth:`FrameCache.map_alias`, alias tables of
  one distribution over all 6·R² texels of the map (the global distribution of pbrt-v4's
  ImageInfiniteLight, a row and then a column, each drawn in O(1)), and
  :meth:`FrameCache.light_cdfs` with ``compensated``, every CDF rebuilt from MIS-compensated
  weights.  ``require("light_cdfs")`` builds their input (``cdf``); their device times are
  ``timings_ms["map_alias"]``, ``["compensated_cdf"]`` and ``["compensated_map_alias"]``, and
  each render that reads them counts them in its ``sample`` stage, as the pool's;
- ``weight_pyramid``: each face's pyramid of sampling-weight sums (estimators/runtime/mips.py) over the
  texels' Y·Ω, :meth:`FrameCache.weight_pyramid` (``timings_ms["weight_pyramid"]``), and with
  ``compensated`` over the MIS-compensated weights of :meth:`FrameCache.light_cdfs`, drawn on
  first use (``["compensated_weight_pyramid"]``, counted in the reading render's ``sample``
  stage).  Its coarsest level is each face's total, so it needs no ``cdf`` product.
  :meth:`FrameCache.descent_tables` (of either pyramid), drawn on first use and
  counted in the reading render's ``sample`` stage (``timings_ms["descent_tables"]``,
  ``["compensated_descent_tables"]``), holds each descent choice's widths and each texel's
  probability, for the descents whose weights are the sums alone (estimators/descent.cl);
- ``radiance_mips``: the map's radiance mip chain, 2×2 box averages down to 1×1 per face
  (estimators/runtime/mips.py), :meth:`FrameCache.radiance_mips` (``timings_ms["radiance_mips"]``).

Each build is timed by OpenCL profiling events (``timings_ms``); ``built`` lists what was built,
so the runner can record which stages were skipped.  :func:`build_fixed_point_cdfs` is the same
fixed-point CDF build for any runs of weights on the device (another sampler's map).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

import dataclasses
import weakref

from iblbench.estimators.runtime import mips
from iblbench.estimators.runtime.device import Compute, event_ms
from iblbench.scenes import cubemap

PRODUCTS = ("env", "cdf", "pool", "light_cdfs", "weight_pyramid", "radiance_mips")
CDF_ONE = 2 ** 63   # the fixed-point CDFs' total (kernels/common.cl)
POOLS_KEPT = 4   # pools of recent (size, seed) kept resident
SPARE_BUFFERS_KEPT = 2   # buffers of one size kept for the next frame's cache
ROWS_PER_GROUP = 64   # at most, per work group of the row CDFs' build (_row_groups)


def build_fixed_point_cdfs(compute: Compute, weights: cl.Buffer, runs: int,
                           n: int) -> tuple[cl.Buffer, cl.Buffer, float]:
    """Fixed-point CDFs of ``runs`` runs of ``n`` float32 weights ≥ 0 (a device buffer
    ``[runs, n]``, run-major), built on the device by ``weight_cdfs`` of framecache.cl: one
    work item per run, in vector steps of sixteen weights and eight CDF words.

    Returns (cdfs, totals, device ms): ``cdfs`` uint64 ``[runs, n]``, each run's inclusive
    prefix sums of integer widths ending at exactly ``CDF_ONE`` = 2^63, where every positive
    weight has a width ≥ 1 (searched with ``cdf_search``/``cdf_bin`` of kernels/common.cl);
    ``totals`` float32 ``[runs]``, each run's Σ w.  A two-level sampler (rows, then columns)
    builds its conditional CDFs from the map and its marginal from the conditional's totals."""
    cdfs, totals = compute.empty(runs * n * 8), compute.empty(runs * 4)
    event = compute.run(compute.kernel("iblbench.estimators.runtime", "framecache.cl", "weight_cdfs"), runs,
                        weights, np.int32(n), cdfs, totals)
    return cdfs, totals, event_ms(event)


def _row_groups(rows: int) -> int:
    """Work items per group of a build of ``rows`` row CDFs: the largest divisor of ``rows`` up
    to ROWS_PER_GROUP.  PoCL's own choice at 6·1024 rows is two groups of 3072, one per core,
    so a core that the machine takes away for a while leaves its half undone while the other
    idles; 96 groups of 64 go to whichever core is free (at load 8 on 2 cores the median of 41
    alternated 1024² builds fell by 11%; idle, groups of 8 or 64 measured within noise of
    PoCL's choice at the last stop)."""
    return max(d for d in range(1, min(rows, ROWS_PER_GROUP) + 1) if rows % d == 0)


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


@dataclasses.dataclass(frozen=True)
class LightCdfs:
    """The fixed-point CDFs of a light sampler (layout of the ``cdf`` product): ``marginal``
    ``[6, R]`` (rows | face), ``conditional`` ``[6·R, R]`` (columns | row), ``face_integral``
    float ``[6]`` (each face's total weight: I_f for Y·Ω weights); ``build_ms`` is the device time
    that built them beyond the ``cdf`` product (0 for the ``cdf`` product itself)."""

    marginal: cl.Buffer
    conditional: cl.Buffer
    face_integral: cl.Buffer
    build_ms: float


def alias_bins(n: int) -> int:
    """Bins of an alias table over ``n`` bins: n padded to a power of two (kernels/common.cl's
    ``alias_bits``)."""
    return 1 << (n - 1).bit_length()


@dataclasses.dataclass(frozen=True)
class DescentTables:
    """A weight pyramid's descent tables (estimators/descent.cl's header has the layout):
    ``bounds`` uint32, four words a record, each choice's children's prefix widths out of 2^31,
    records indexed as a 4-ary heap from the faces'; ``probability`` float ``[6·R·R]``, each
    texel's probability P; ``node_probability`` float, each node's above the texels, in heap
    order (depth k's 6·4^k from 2·(4^k − 1)); ``build_ms`` the device time of the three."""

    bounds: cl.Buffer
    probability: cl.Buffer
    node_probability: cl.Buffer
    build_ms: float


@dataclasses.dataclass(frozen=True)
class MapAlias:
    """The map's two-level alias tables (framecache.cl's ``alias_tables``): ``words`` uint64,
    the rows' table (``alias_bins(6R)`` bins, each threshold·bins + alias), then each row's
    table over its columns (``alias_bins(R)`` bins each); ``probability`` float ``[6·R·R]``,
    each texel's P(row)·P(col | row); ``build_ms`` the device time of the weights, the rows' CDF
    and the tables (with the compensated CDFs' where compensated)."""

    words: cl.Buffer
    probability: cl.Buffer
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
        self._pools: dict[tuple[int, int, bool], LightPool] = {}
        self._compensated: tuple[LightCdfs, cl.Buffer] | None = None
        self._map_aliases: dict[bool, MapAlias] = {}
        self._weight_pyramids: dict[bool, mips.MipChain] = {}
        self._descent_tables: dict[bool, DescentTables] = {}
        self._radiance_mips: mips.MipChain | None = None

    def retarget(self, frame: int) -> None:
        """Serve frame ``frame``, whose environment is this cache's own (the same array): the
        CDFs and the uploaded map stay; the light pools, whose random rotation depends on the
        frame, are dropped so that they are drawn for the new frame."""
        self.frame = frame
        self._pools.clear()

    @property
    def built(self) -> list[str]:
        return (["env"] + (["cdf"] if self._cdf is not None else [])
                + (["pool"] if self._pools else [])
                + (["light_cdfs"] if self._compensated or self._map_aliases else [])
                + (["weight_pyramid"] if self._weight_pyramids else [])
                + (["radiance_mips"] if self._radiance_mips is not None else []))

    def require(self, products) -> None:
        """Build every named product that is not built yet."""
        for name in products:
            if name not in PRODUCTS:
                raise KeyError(f"unknown frame-cache product '{name}'; valid: {', '.join(PRODUCTS)}")
            if name in ("cdf", "pool", "light_cdfs"):
                self._build_cdf()
            elif name == "weight_pyramid":
                self.weight_pyramid(False)
            elif name == "radiance_mips":
                self.radiance_mips()

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
            rows = c.run(c.kernel("iblbench.estimators.runtime", "framecache.cl", "row_cdfs"), 6 * res,
                         self._env_buffer, _texel_solid_angles(c, res), np.int32(res), conditional,
                         row_weight, group=_row_groups(6 * res))
            marginal, integral, faces_ms = build_fixed_point_cdfs(c, row_weight, 6, res)
            self.timings_ms["cdf"] = event_ms(rows) + faces_ms
            self._cdf = (marginal, conditional, integral)
        return self._cdf

    def _sampling_weights(self, compensate: bool, texels: cl.Buffer | None = None,
                          face_integral: cl.Buffer | None = None) -> tuple[cl.Buffer, cl.Buffer, float]:
        """framecache.cl's ``sampling_weights``: (texel weights ``[6·R·R]``, written into
        ``texels`` where given, else into a new buffer with ``compensate`` and not at all
        without; row totals ``[6·R]``; device ms).  Compensation's Ȳ is from ``face_integral``
        (float ``[6]``; the ``cdf`` product's I_f where None)."""
        c, res = self.compute, self.res
        store = texels is not None or compensate
        if texels is None:
            texels = self._buffer(6 * res * res * 4) if compensate else c.empty(4)
        if face_integral is None:
            face_integral = self.face_integral_buffer if compensate else c.empty(4)
        rows = self._buffer(6 * res * 4)
        event = c.run(c.kernel("iblbench.estimators.runtime", "framecache.cl", "sampling_weights"), 6 * res,
                      self._env_buffer, _texel_solid_angles(c, res), face_integral,
                      np.int32(res), np.int32(compensate), np.int32(store), texels, rows)
        return texels, rows, event_ms(event)

    def light_cdfs(self, compensated: bool = False) -> LightCdfs:
        """The ``cdf`` product's CDFs, or with ``compensated`` the same CDFs of the MIS-compensated
        weights (built on first use).

        MIS compensation (Karlík et al. 2019) weights a texel by max(Y − Ȳ, min(Ȳ/1000, Y))·Ω,
        Ȳ = Σ_f I_f / 4π the map's mean luminance over the sphere: pbrt-v4's
        ``ImageInfiniteLight`` compensated distribution (src/pbrt/lights.cpp), chosen over
        Mitsuba 3's max(Y − Ȳ, 0) (emitters/envmap.cpp) because it keeps every lit texel's
        probability positive (at least a thousandth of its share in the uncompensated
        distribution of a mean texel): a compensated light sampler still reaches every texel
        of positive radiance, so its estimate stays unbiased even where BRDF sampling cannot
        reach (a specular lobe's zero tail), its χ² covers the whole support, and neither an
        all-black map (all weights 0: the CDF builder's uniform runs, Mitsuba 3 #1271's 0/0)
        nor a constant one (every Y − Ȳ = 0: weights Ȳ/1000·Ω, the uncompensated distribution)
        needs a case of its own.  Ȳ is the mean over solid angle (pbrt-v4's equal-area map
        averages over pixels of equal solid angle; Mitsuba 3 averages a lat-long map's pixels).
        """
        if not compensated:
            return LightCdfs(*self._build_cdf(), 0.0)
        if self._compensated is None:
            c, res = self.compute, self.res
            texels, rows, weights_ms = self._sampling_weights(True)
            conditional, row_totals, rows_ms = build_fixed_point_cdfs(c, texels, 6 * res, res)
            marginal, integral, faces_ms = build_fixed_point_cdfs(c, row_totals, 6, res)
            self.timings_ms["compensated_cdf"] = weights_ms + rows_ms + faces_ms
            self._compensated = (LightCdfs(marginal, conditional, integral,
                                           self.timings_ms["compensated_cdf"]), rows)
        return self._compensated[0]

    def map_alias(self, compensated: bool = False) -> MapAlias:
        """The alias tables of one distribution over all 6·R² texels of the map, by their weight
        (Y·Ω, or compensated as in :meth:`light_cdfs`), built on first use: a fixed-point CDF
        over the map's 6·R rows, face-major, by their total weights, and with the conditional
        CDFs of :meth:`light_cdfs` (``compensated``) one alias table over the rows and one over
        each row's columns (framecache.cl's ``alias_tables``, Walker 1977, Vose 1991, a work
        item per table), which draw a row and a column with exactly the CDFs' probabilities;
        ``probability`` holds their product per texel (``texel_probabilities``)."""
        if compensated not in self._map_aliases:
            c, res = self.compute, self.res
            if compensated:
                cdfs = self.light_cdfs(True)
                rows, weights_ms = self._compensated[1], cdfs.build_ms
            else:
                cdfs = self.light_cdfs(False)
                _, rows, weights_ms = self._sampling_weights(False)
            marginal, _, scan_ms = build_fixed_point_cdfs(c, rows, 1, 6 * res)
            row_bins, col_bins = alias_bins(6 * res), alias_bins(res)
            words = self._buffer((row_bins + 6 * res * col_bins) * 8)
            worklist = self._buffer(max(row_bins, 6 * res * col_bins) * 4)
            probability = self._buffer(6 * res * res * 4)
            kernel = lambda name: c.kernel("iblbench.estimators.runtime", "framecache.cl", name)
            events = (c.run(kernel("alias_tables"), 1, marginal, np.int32(6 * res), np.int32(0), words, worklist),
                      c.run(kernel("alias_tables"), 6 * res, cdfs.conditional, np.int32(res), np.int32(row_bins),
                            words, worklist),
                      c.run(kernel("texel_probabilities"), 6 * res * res, marginal, cdfs.conditional,
                            np.int32(res), probability))
            own_ms = scan_ms + sum(map(event_ms, events))
            self.timings_ms["compensated_map_alias" if compensated else "map_alias"] = own_ms + (
                0.0 if compensated else weights_ms)
            self._map_aliases[compensated] = MapAlias(words, probability, weights_ms + own_ms)
        return self._map_aliases[compensated]

    def light_pool(self, per_face: int, seed: int, compensated: bool = False) -> LightPool:
        """The pool of ``per_face`` samples per face for render seed ``seed`` (drawn on first use)
        from the CDFs of :meth:`light_cdfs` (``compensated``).

        The seed and frame pick the random rotation of the pool's fixed 2-D sequence, so each
        render seed sees an independent, unbiased pool.
        """
        key = (int(per_face), int(seed), bool(compensated))
        if key not in self._pools:
            cdfs = self.light_cdfs(compensated)
            marginal, conditional, integral = cdfs.marginal, cdfs.conditional, cdfs.face_integral
            c, count = self.compute, 6 * key[0]
            dir_pdf, radiance = c.empty(count * 16), c.empty(count * 16)
            event = c.run(c.kernel("iblbench.estimators.runtime", "framecache.cl", "build_light_pool"), count,
                          self._env_buffer, marginal, conditional, integral, np.int32(self.res),
                          np.int32(key[0]), np.uint32(seed), np.uint32(self.frame), dir_pdf, radiance)
            self.timings_ms["pool"] = event_ms(event)
            if len(self._pools) >= POOLS_KEPT:
                del self._pools[next(iter(self._pools))]
            self._pools[key] = LightPool(dir_pdf, radiance, key[0], key[1], self.timings_ms["pool"])
        return self._pools[key]

    # ---- mip products (estimators/runtime/mips.py) ------------------------------------------------------

    def weight_pyramid(self, compensated: bool = False) -> mips.MipChain:
        """Each face's pyramid of sampling-weight sums (estimators/runtime/mips.py's layout, level 0 the
        texels' weights): Y·Ω, or with ``compensated`` the MIS-compensated weights of
        :meth:`light_cdfs`, whose mean Ȳ comes from the plain pyramid's face totals (its
        coarsest level), so neither needs the ``cdf`` product.  Built on first use; a
        compensated pyramid's ``build_ms`` is its own (the plain one it reads has its own)."""
        if compensated not in self._weight_pyramids:
            c, res = self.compute, self.res
            offsets = mips.level_offsets(res, 1)
            buffer = self._buffer(offsets[-1] * 4)
            face_totals, copy_ms = None, 0.0
            if compensated:
                plain = self.weight_pyramid(False)
                face_totals = c.empty(6 * 4)
                copy = cl.enqueue_copy(c.queue, face_totals, plain.buffer, byte_count=6 * 4,
                                       src_offset=plain.offsets[-1] * 4)
                copy.wait()
                copy_ms = event_ms(copy)
            _, _, weights_ms = self._sampling_weights(compensated, buffer, face_totals)
            build_ms = copy_ms + weights_ms + mips.reduce_levels(c, buffer, res, 1, average=False)
            self.timings_ms["compensated_weight_pyramid" if compensated else "weight_pyramid"] = build_ms
            self._weight_pyramids[compensated] = mips.chain(buffer, res, 1, build_ms)
        return self._weight_pyramids[compensated]

    def descent_tables(self, compensated: bool = False) -> DescentTables:
        """The descent tables of :meth:`weight_pyramid` (``compensated``), built on first use
        from it (``timings_ms["descent_tables"]``, ``["compensated_descent_tables"]``: the
        tables' own device time, without the pyramid's): every choice's widths, computed once
        per frame where a descent whose weights are the sums alone would compute them per
        sample, and each texel's probability."""
        if compensated not in self._descent_tables:
            c, res = self.compute, self.res
            pyramid = self.weight_pyramid(compensated)
            depths = len(pyramid.sizes) - 1   # choices below the faces
            lanes = c.pool_lanes
            bounds = self._buffer(8 * 4 ** depths * 4)
            node_probability = self._buffer(max(2 * 4 ** depths - 2, 1) * 4)   # the depths' parents
            probability = self._buffer(6 * res * res * 4)
            kernel = c.kernel("iblbench.estimators.runtime", "framecache.cl", "descent_bounds")
            events = [c.run(kernel, max(1, -(-6 * 4 ** depth // lanes)), pyramid.buffer, np.int32(res),
                            np.int32(depth), bounds, node_probability, probability)
                      for depth in range(-1, depths)]
            build_ms = sum(map(event_ms, events))
            self.timings_ms["compensated_descent_tables" if compensated else "descent_tables"] = build_ms
            self._descent_tables[compensated] = DescentTables(bounds, probability, node_probability, build_ms)
        return self._descent_tables[compensated]

    def radiance_mips(self) -> mips.MipChain:
        """The map's radiance mip chain (estimators/runtime/mips.py's layout, float4 texels, level 0 a copy
        of the map, box averages down to 1×1 per face), built on first use."""
        if self._radiance_mips is None:
            c, res = self.compute, self.res
            offsets = mips.level_offsets(res, 4)
            buffer = self._buffer(offsets[-1] * 4)
            copy = cl.enqueue_copy(c.queue, buffer, self._env_buffer, byte_count=offsets[1] * 4)
            copy.wait()
            build_ms = event_ms(copy) + mips.reduce_levels(c, buffer, res, 4, average=True)
            self.timings_ms["radiance_mips"] = build_ms
            self._radiance_mips = mips.chain(buffer, res, 4, build_ms)
        return self._radiance_mips

    def host_cdfs(self) -> tuple[np.ndarray, np.ndarray]:
        """(marginal ``[6, R]``, conditional ``[6, R, R]``) copied back, for tests and checks:
        uint64 fixed-point CDFs, inclusive, ending at exactly ``CDF_ONE`` = 2^63 (a bin's
        probability is its width / 2^63; kernels/common.cl)."""
        marginal, conditional = self._build_cdf()[:2]
        res = self.res
        return (self.compute.to_host(marginal, (6, res), np.uint64),
                self.compute.to_host(conditional, (6, res, res), np.uint64))
