"""``envmap``: the production environment-map light sampler (pbrt-v4, Cycles, Mitsuba 3), with
optional MIS with Phong BRDF samples and MIS compensation."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from iblbench.estimators.base import (Estimator, KernelCost, Limit, Mutant, Setting, SweepPart, Tags,
                                      WorkCounts, read_estimate, specular_lobe_defines)
from iblbench.estimators.light_pool import HOOK_SPP, MAX_SPP, TICKS_PER_SAMPLE, hook_surface, lane_chunks
from iblbench.estimators.runtime.device import event_ms

MIS_MODES = ("none", "brdf")
HEURISTICS = ("balance", "power")


class MapSampler(Estimator):
    """What ``envmap`` and ``brdf`` share: ``envmap.cl``'s kernels, one pixel per work item (or one
    block of a pixel's draws: ``DeviceGBuffer.run_sampled``), light samples from one 2-D
    distribution over the whole map and/or Phong BRDF samples combined by MIS, configured by
    :meth:`defines`."""

    tags = Tags(unbiased=True, has_pdf=True)
    max_spp = MAX_SPP
    light_samples = True

    @property
    def brdf_samples(self) -> bool:
        return True

    @property
    def compensated(self) -> bool:
        return False

    def strategy_samples(self, spp: int) -> tuple[float, float]:
        """(light, BRDF) samples of a budget of ``spp``: envmap.cl's ``strategy_split``, the
        light half rounded down to a tick."""
        light = spp * TICKS_PER_SAMPLE // (2 if self.brdf_samples else 1) if self.light_samples else 0
        return light / TICKS_PER_SAMPLE, spp - light / TICKS_PER_SAMPLE

    def work_counts(self, gbuffer, frames) -> list[WorkCounts]:
        """Each strategy's N samples of :meth:`strategy_samples` in ⌈N⌉ draws (the last weighted by
        β), a draw one evaluation of the integrand and its V."""
        draws = [sum(math.ceil(n) for n in self.strategy_samples(frame.spp)) for frame in frames]
        return [WorkCounts(count, count) for count in draws]

    def defines(self, gbuffer=None) -> dict:
        """Compile-time options of envmap.cl (for this G-buffer, when one is given)."""
        return {**specular_lobe_defines(gbuffer), "BRDF_SAMPLES": int(self.brdf_samples),
                "MIS_POWER": int(getattr(self.params, "heuristic", "balance") == "power")}

    def _kernel(self, compute, name: str, gbuffer=None):
        return compute.kernel(self.kernel_package(), self.kernel_files[0], name, self.defines(gbuffer))

    def _light_buffers(self, cache) -> tuple[tuple, float]:
        """(the kernels' light-sampler buffers, ``LIGHT_PARAMS`` of envmap.cl: the map's alias
        table and its texel probabilities; device ms that built them for this render)."""
        if not self.light_samples:
            unread = cache.compute.empty(8)
            return (unread, unread), 0.0
        table = cache.map_alias(self.compensated)
        return (table.words, table.probability), table.build_ms

    def _map_is_black(self, cache) -> bool:
        """Whether every texel weighs 0 (from the ``cdf`` product's face integrals)."""
        cache.require(("cdf",))
        return not np.any(cache.face_integrals > 0)

    def render(self, gbuffer, cache, spp, seed):
        if not 1 <= spp <= MAX_SPP:
            raise ValueError(f"spp must be in [1, {MAX_SPP}], got {spp}")
        compute = cache.compute
        light_buffers, build_ms = self._light_buffers(cache)
        radiance = compute.empty(gbuffer.launch_size * 12)   # planes R, G, B (envmap.cl)
        counts = compute.empty(gbuffer.launch_size * 8)      # planes used, effective
        evaluations = compute.empty(gbuffer.launch_size * 4)
        draws = [math.ceil(samples) for samples in self.strategy_samples(spp)]
        event = gbuffer.run_sampled(
            compute, lambda name: self._kernel(compute, name, gbuffer), "render_map",
            lane_chunks(draws, compute.pool_lanes), gbuffer.normal,
            gbuffer.view, gbuffer.kd, gbuffer.ks, gbuffer.visibility, np.int32(gbuffer.launch_size),
            cache.env_buffer, *light_buffers,
            np.int32(cache.res), np.int32(spp), np.uint32(seed), np.uint32(cache.frame),
            radiance, counts, evaluations)
        mean_evaluations = compute.to_host(evaluations, (gbuffer.count,), np.int32).mean()
        return read_estimate(compute, gbuffer, radiance, counts, mean_evaluations,
                             {"sample": build_ms, "shade": event_ms(event)}, planar=True)

    # ---- χ² hooks ----------------------------------------------------------------------------

    def sample_directions(self, cache, normal, view, n, seed):
        """``n`` directions ``[n, 3]`` distributed as all the samples the estimator draws for one
        pixel at ``HOOK_SPP`` pooled ((t_L p_L + t_B p_B)/(t_L + t_B)), and that density.  The
        material is the conformance suite's glossy one (kd 0.5, ks 0.3, m 20).  None on an
        all-black map, as the pool estimators' hooks: every sample there weighs 0."""
        compute = cache.compute
        if self._map_is_black(cache):
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        lanes = compute.pool_lanes   # directions per work item (POOL_LANES, light_pool.cl)
        groups = -(-n // lanes)
        light_buffers, _ = self._light_buffers(cache)
        out = compute.empty(4 * groups * lanes * 4)
        compute.run(self._kernel(compute, "map_directions"), groups, hook_surface(cache, normal, view),
                    *light_buffers, np.int32(cache.res), np.int32(HOOK_SPP), np.uint32(seed), out)
        planes = compute.to_host(out, (4, groups * lanes), np.float32)[:, :n]
        return np.ascontiguousarray(planes[:3].T), planes[3].copy()

    def pdf(self, cache, normal, view, dirs):
        """Density of :meth:`sample_directions` at ``dirs`` ``[n, 3]``."""
        compute, n = cache.compute, len(dirs)
        lanes = compute.pool_lanes
        groups = -(-n // lanes)
        planes = np.zeros((3, groups * lanes), np.float32)
        planes[:, :n] = np.asarray(dirs, np.float32).T
        planes[2, n:] = 1.0   # padding: any unit direction
        light_buffers, _ = self._light_buffers(cache)
        out = compute.empty(groups * lanes * 4)
        compute.run(self._kernel(compute, "map_direction_pdf"), groups, hook_surface(cache, normal, view),
                    *light_buffers, np.int32(cache.res), np.int32(HOOK_SPP),
                    compute.to_device(planes), out)
        return compute.to_host(out, (groups * lanes,), np.float32)[:n]


@dataclasses.dataclass(frozen=True)
class EnvmapParams:
    """``mis`` (default ``"none"``): ``"none"``, light samples only; ``"brdf"``, half the budget
    to Phong BRDF samples, combined with the light samples by MIS.

    ``heuristic`` (default ``"power"``, the production renderers' choice): the MIS weights,
    ``"balance"`` or ``"power"`` (exponent 2); unused without MIS.

    ``mis_compensation`` (default False): the light distribution is built from compensated
    weights (pbrt-v4's form: ``FrameCache.light_cdfs``; ``weight_pyramid`` for
    ``hierarchical``).  Only with MIS, as pbrt-v4 does (its
    ``SampleLi`` uses the compensated distribution only when the caller allows an incomplete
    pdf, i.e. combines it with BSDF samples): without BRDF samples it would still be unbiased
    here (every lit texel keeps a positive pdf) but it takes samples from the dim sky that no
    other strategy covers, which Mitsuba 3 PR #484 measured to be worse; it is refused.
    """

    mis: str = "none"
    heuristic: str = "power"
    mis_compensation: bool = False

    def __post_init__(self):
        if self.mis not in MIS_MODES:
            raise ValueError(f"mis must be one of {', '.join(MIS_MODES)}, got {self.mis!r}")
        if self.heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, got {self.heuristic!r}")
        if self.mis_compensation and self.mis == "none":
            raise ValueError("mis_compensation needs MIS with BRDF samples (mis = \"brdf\"): "
                             "compensation without MIS only moves light samples to where "
                             "nothing else samples (Karlík et al. 2019; Mitsuba 3 PR #484)")


class Envmap(MapSampler):
    """Light sampling from one 2-D distribution over the whole cube map (pbrt-v4
    ``ImageInfiniteLight``, src/pbrt/lights.cpp; Cycles' background light; Mitsuba 3
    ``envmap``, src/emitters/envmap.cpp), optionally with Phong BRDF samples under MIS.

    Distribution.  Weights Y·Ω per texel (Y the texel's luminance, Ω its exact solid angle), so
    that p(ω) ∝ Y(ω) in solid angle; one marginal CDF over the map's 6·R rows (faces and rows
    together, face-major) and one conditional CDF over each row's columns (the ``cdf``
    product's, or the compensated ones), both the fixed-point CDFs of issue 6, so every texel of
    positive weight keeps a positive, relatively exact probability next to a 1e6:1 sun.  Each
    is drawn in O(1) from Walker's alias table (A. J. Walker, "An efficient method for generating
    discrete random variables with general distributions", ACM TOMS 3(3), 1977), built per frame
    in integers by Vose's worklists (M. D. Vose, "A linear algorithm for generating random
    numbers with a given distribution", IEEE TSE 17(9), 1991), a table over the rows and one over
    each row's columns (``FrameCache.map_alias``, framecache.cl's ``alias_tables``), which draw
    a bin with exactly its CDF width / 2^63.  A sample picks a row, a column, and a point uniform
    in the texel's face square; its density is P(row)·P(col | row)·(1+x²+y²)^{3/2}/a_texel
    (ARCHITECTURE.md §Conventions), P(row)·P(col | row) read from the tables' float product per
    texel, the same in the sampler and in the density lookup.  No per-normal balancing: the
    distribution is the same for every pixel.

    Change (issue 37): the two CDFs were searched by bisection, ⌈log2 6R⌉ + ⌈log2 R⌉ dependent
    loads, and the point in the texel came from the variates' positions in their bins.  The
    alias tables draw the same row and column probabilities with two loads (a second Philox
    block places the point), and the density lookup reads one float instead of four CDF words:
    the density is the same function as before, bit for bit, but the sample streams changed.

    Budget and MIS.  Without MIS all N_s samples are light samples (Eq. 4 of Lu 2013 with one
    strategy).  With ``mis = "brdf"`` N_s/2 are light and N_s/2 BRDF samples, each strategy's
    last sample weighted by β = frac(N) (Lu 2013 Eq. 5) so that odd and single-sample budgets
    stay unbiased; Veach's balance heuristic weights N_k p_k / Σ_j N_j p_j or power heuristic
    (N_k p_k)² / Σ_j (N_j p_j)² over the two strategies (envmap.cl, ``mis_denominator``).
    Both sum to 1 wherever the integrand is non-zero, since the BRDF density is positive
    wherever the BRDF is.

    MIS compensation (``mis_compensation``, Karlík et al. 2019, "MIS compensation: optimizing
    sampling techniques in multiple importance sampling", SIGGRAPH Asia 2019): the light
    distribution is built from max(Y − Ȳ, min(Ȳ/1000, Y))·Ω, pbrt-v4's form, not Mitsuba 3's
    max(Y − Ȳ, 0) (``FrameCache.light_cdfs`` says why: every lit texel keeps a positive pdf, so
    the estimate is unbiased even where the BRDF density is zero, and a black or constant map
    needs no special case).  Mitsuba 3 and pbrt-v4 use it only under MIS; so does this.

    Deviations from pbrt-v4: a cube map with nearest lookup and Y·Ω weights (ARCHITECTURE.md §Conventions) where
    pbrt-v4 samples an equal-area octahedral image by its bilinearly filtered channel average
    (by bisection of its 2-D CDF; alias tables here);
    a budget split N_s/2 + N_s/2 where a path tracer takes one light and one BSDF sample per
    vertex (the same at N_s = 2); no visibility (none in this benchmark).
    """

    name = "envmap"
    sweep = SweepPart(("envmap", 'envmap{mis="brdf"}', 'envmap{mis="brdf",mis_compensation=true}'),
                      order=8)
    portability_variants = ('envmap{mis="brdf"}', 'envmap{mis="brdf",mis_compensation=true}')
    cost = KernelCost(96, 0, 0, 76, 88, derivation="""\
        the default, light samples only: a light sample of the map's alias tables, 96: the row
        and the column, each a bin, its threshold test and alias (integer work, not counted),
        the face by a float quotient 1, the point in the texel 10, its pdf 8, the face
        direction normalised 12, lobe power 41, n·ω 5, D 1, add_samples 18; per pixel shading
        24, hoisted factors 5, sums out 47""",
        lane_loops=((1, 1.0),), limits=(   # render_map's light loop (the default: no BRDF samples)
            Limit("philox", per_eval=2, why="lanes_sample_light's blocks xi and at"),
            Limit("dependent_load", per_eval=3,
                  why="the row's alias word, then its column's (at the row drawn), then the "
                      "texel's probability and radiance (at the column drawn)"),
            Limit("gather", per_eval=3, why="the rest of that texel's four loads"),
            Limit("phong_power", per_eval=1, why="the lobe power"),
            Limit("divide", per_eval=7,
                  why="lanes_quotient 1, x and y / res 2, √q 1, lanes_face_direction's √ and "
                      "1/ 2, add_samples' β / D 1")))
    Params = EnvmapParams
    settings = (Setting("mis", "brdf", says="mis_brdf"),
                Setting("heuristic", "balance", {"mis": "brdf"}, says="mis_heuristic"),
                Setting("mis_compensation", True, {"mis": "brdf"}, says="mis_compensation"))
    requires = ("cdf", "light_cdfs")
    kernel_files = ("envmap.cl", "lanes.cl")
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        # A mutant of this file spells its text in two pieces, so the file holds it whole once.
        Mutant("envmap-heuristic-swapped", "envmap.py",
               '"MIS_POWER": int(getattr(self.params, "heuristic", ' '"balance") == "power")',
               '"MIS_POWER": int(getattr(self.params, "heuristic", "balance") == "balance")'),
        Mutant("envmap-light-jacobian-inverted", "envmap.cl",
               "*pdf = p_texel * q * sqrt(q) * (float)(res * res) / 4.0f;",
               "*pdf = p_texel / (q * sqrt(q)) * (float)(res * res) / 4.0f;",
               stress=("sun-1e6",)),
        # The threshold test's variate one bit short: a bin is kept with probability 2t/S
        # (capped at 1) instead of t/S, so the alias tables no longer draw their CDFs' widths.
        Mutant("envmap-alias-threshold-bit-short", "envmap.cl",
               "lane_words_t below = low & (lane_words_t)((CDF_ONE >> bits) - 1);",
               "lane_words_t below = low & (lane_words_t)((CDF_ONE >> (bits + 1)) - 1);",
               stress=("sun-1e6",)),
    )

    @property
    def brdf_samples(self) -> bool:
        return self.params.mis == "brdf"

    @property
    def compensated(self) -> bool:
        return self.params.mis_compensation
