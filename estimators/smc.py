"""``smc``: sequential Monte Carlo sampling of Ghosh et al. 2006, as Kronander et al. §6 use it.

Per pixel, N weighted particles {ω_i, W_i} (W normalised) approximate the target
γ_t = L_Y,t·ρ_Y·cos⁺ (Eq. 3) and persist across frames in device buffers, with Z_{t−1} and
γ_{t−1}(ω_i) (kernel ``smc.cl``).  Per frame t:

1. **Init / re-init by BIS** (§6.1, ``sir.cl``): on the first frame after :meth:`reset` (or a
   new G-buffer, N or face size) and wherever re-initialisation is triggered, N particles are
   resampled by BIS from M = ``init_candidates``·N candidates, W_i = 1/N, Z = Ẑ.  Deviations:
   the candidates come from ½ map + ½ BRDF sampling (``init_env_pick``), not the BRDF alone,
   with the strategy stratified (exactly ½M of each, weights γ/q with the mixture q: Veach's
   multi-sample MIS; a random pick per candidate adds a binomial variance of √(½/(½M)) = 7.9%
   relative at M = 160 on a light only the map finds, which was the whole error after a switch);
   and the frame's estimate is the candidates' (1/M) Σ f/q, the expectation of Eq. 4's
   resampled estimate given the candidates (Rao-Blackwellised), not the N resampled samples'.
   With ``init_env_pick = 0`` the candidates are exactly ``bis``'s (same random streams).
2. **Reweight** (Eq. 5) through S = ``intermediates`` + 1 tempered steps
   π_k = γ_{t−1}^{1−α_k} γ_t^{α_k}, α_k = k/S (Ghosh's intermediate distributions; S = 1 is
   plain Eq. 5): step k multiplies W_i by π_k/π_{k−1} = (γ_t/γ_{t−1})(ω_i)^{1/S} at the particle's
   current position, updates **Z ← Z·Σ_i W_i^{old}·incr_i** (Eq. 8, one factor per step; the
   product over steps is Z_t), and renormalises.
3. **Resample** when ESS = 1/Σ W_i² < 2N/3 (§6.1), by systematic resampling.
4. **Adapt** (Eq. 6): one Metropolis–Hastings move per particle targeting π_k, by one of three
   π_k-reversible MH kernels: a *local* move, ω' uniform in the cone of half-angle
   δ = ``local_degrees`` about ω (symmetric: q(ω→ω') = q(ω'→ω)), accepted with
   a = min(1, π_k(ω')/π_k(ω)); or an *independent* move from the map (face f with probability
   μ_f = I_f/Σ I, then a texel by frame t's CDFs and a point uniform in it: density
   μ_{f(ω)}·pdf_L(ω|f(ω)) of ARCHITECTURE.md §Conventions, drawn by two alias tables built from those CDFs each
   frame (``sir.cl``; an exact, O(1) draw of the same distribution, not the CDFs' inversion); the
   BRDF on an all-black map) or from the BRDF (p_B, the Phong mixture), accepted with
   a = min(1, π_k(ω')·q(ω) / (π_k(ω)·q(ω'))).  (Kronander's Eq. 6 prints q(ω→ω') in both
   numerator and denominator; the reverse density belongs in the numerator, as here.)
   Deviation: move j = (step − 1)·N + i takes its kernel from a fixed schedule (Beatty
   sequences: a ν share of local moves, the independent ones alternating map and BRDF) instead
   of a random pick with probability ν.  A fixed cycle of π-invariant kernels leaves π
   invariant as the random mixture does, and it fixes the number of map and BRDF proposals per
   frame, which step 6 needs.
5. **Re-init test**: if Z_t/Z_{t−1} > ``reinit_threshold`` or < 1/``reinit_threshold`` (Z
   jumped), or a reweighting sum is 0/non-finite (every particle lost its target, e.g. the
   light went out), or a weighted particle has γ_{t−1} = 0 (guard), or Z_{t−1} = 0 (the pixel
   saw black last frame), the pixel is re-initialised by BIS on frame t (step 1).
   Deviation: Kronander §6.3 re-initialises on a large increase of Z_t/Z_{t−1}; here a fall
   past 1/``reinit_threshold`` counts too (a light that dims leaves the particles on it), and
   two map-level tests are added, on the device; either re-initialises every pixel:
   - *power*: the map's total luminance power Σ_f I_f jumps by more than the same threshold
     between frames.  A small light switching on changes Z by less than ×4 (or not at all) at
     pixels none of whose particles sees it, and Eq. 5 alone never notices it there.
   - *shape*: the map's light distribution P (texel probabilities ∝ Y·Ω, ARCHITECTURE.md §Conventions) changed so
     much that 1 + χ²(P_t ‖ P_{t−1}) = Σ_x P_t(x)²/P_{t−1}(x) > 1/``reinit_map_ess`` (+∞ where a
     black texel lit up).  Why: §6.3 assumes γ_t ≈ γ_{t−1}.  Light that moves to where γ_{t−1}
     was dim reaches Eq. 8 only through rare, huge weights, so Z_t mostly misses it, while
     neither the power nor Z_t/Z_{t−1} need leave ×4, and Z_t, a product over frames, keeps
     that error.  On ``park-turn`` (the photograph's sun moves half a 32² texel a frame at
     constant power) the median pixel's Z_t fell to 0.82 of the exact one on frame 1 and to 0.77
     by frame 4: ΔE76 0.44 on frame 0, 9.8-11.3 on frames 1-5 at 64 spp (2 seeds), with 0-25 of
     1304 pixels re-initialised a frame.  Threshold: particles drawn from P_{t−1} and weighted to P_t keep
     Kong's effective sample size N/(1 + χ²); the default 2/3 is §6.1's resampling threshold,
     below which Kronander calls the weights degenerate (resampling then repairs the weights,
     but not Z_t: §6.3).  χ² measured between consecutive frames: rotating-sun (a soft sun, 1°
     a frame) ≤ 0.008, where the sampler carries its particles; ``park-turn`` 0.8-59;
     moving-lights 1.3e3-1.5e3; day (64² faces) ≤ 0.012 at night, 0.27 and 0.52 at sunrise and
     sunset, 25-6.4e3 while the sun is up (a 0.5° disc moving 4° a frame).  Where it fires a frame costs an init, M + N evaluations (21N with the
     defaults) against 9N, yet a third of a continuing frame's device time on PoCL
     (``park-turn`` at 64 spp: smc_advance's serial MH moves are slower than the vectorised
     BIS).  The test is on the map, not on a pixel's γ: a pixel that cannot see the change is
     re-initialised too.  ``reinit_map_ess = 0`` turns it off (Kronander's rule alone).
     Consequence: on ``park-turn``, ``torus-moving`` and the daytime frames of ``day`` the test
     fires on every changed frame, so there smc re-initialises every pixel every frame and its
     figures are those of its BIS init (½ map + ½ BRDF candidates, step 1), not of particles
     carried by SMC; it carries them where the map changes smoothly (rotating-sun).
6. **Estimate** (Eq. 7) on a frame whose map changed: L̂ = Z_t Σ_i W_i f(ω_i)/γ_t(ω_i).
   Deviation, on a **static frame** (the map equals the previous frame's): Eq. 5 and 8 have
   nothing to do (every increment is 1), and Kronander's sampler would keep Z_t, hence its
   error, frozen at the init's for as long as the map stays.  Here the frame's n_map + n_brdf
   independent MH proposals ω (step 4) are also importance samples of the mixture, and give
   fresh unbiased estimates Σ γ_t(ω)/(n_map p_map(ω) + n_brdf p_B(ω)) of Z_t and
   Σ f(ω)/(n_map p_map(ω) + n_brdf p_B(ω)) of the integral (balance heuristic); Z_t and L̂ are
   the sample-count-weighted means of the previous frame's values (n samples behind them: M
   after an init, N after a changed frame's Eq. 7) and the fresh ones.  Each is then a mean of unbiased estimates, and the error
   keeps falling while the map stays (tests/test_smc.py).  On sphere-switch this is what
   brings smc's ΔE to within 1.5× of balanced_mis's at equal evaluations after a switch.

Budget.  N = ``spp`` particles (``N`` > 0 fixes it; Kronander's N = 8 is spp 8); ``used`` = N
particles, ``effective`` = those with γ_t > 0.  ``evaluations`` per pixel (mean over pixels)
counts every evaluation of a target or integrand at a direction: on a changed frame N (γ_t at
the particles) + per step N MH proposals (2 at α < 1, where γ_{t−1} is evaluated at the
proposal too, 1 at α = 1) + N (f in Eq. 7); on a static frame the S·N MH proposals only (γ_t
at the particles is γ_{t−1}, stored; a proposal's γ and f share one evaluation); and M + N for
each BIS (re-)init (its candidates and resampled samples).  With the defaults a changed frame
costs N(1 + 2·3 + 1 + 1) = 9N and a static one 4N.  ``shadow_rays`` counts V at new directions
only: the MH proposals (S·N a carried frame) and an init's M candidates (γ_t at a particle, γ_{t−1} at a
proposal and f at a resampled or carried particle reuse a direction whose V is known).

Extras (per-frame columns): ``ess``: mean over pixels that carried state of the smallest ESS
before resampling over the frame's steps (NaN on an init frame); ``reinits``: pixels
re-initialised this frame (the first frame's init is not counted); ``resample_steps``: mean
resamplings per pixel.

Kernels (``smc.cl``).  ``smc_advance`` runs steps 2-6 for every pixel that carries state and
flags those that need a BIS re-init; ``smc_list_reinit`` lists them on the device (no round trip
to the host within a frame); ``smc_init`` runs step 1 for the listed pixels (all of them on a
first frame) in padded groups, launched over every pixel, its groups past the list returning at
once: each work item runs its candidates in explicit vectors of 16 lanes, and its other loops
are vectorised by PoCL across pixels (``sir.cl``, ``lanes.cl``).  Both run their pixels in launches of about
``chunks.CHUNK_MS`` device time (``estimators/runtime/chunks.py``: no launch outlasts a display
driver's watchdog at N = 4096), which changes no pixel's value.  Before them,
``map_alias_pairs`` and ``map_alias_columns`` build the map proposal's alias tables and the map's
texels with their density (``sir.cl``) from the frame cache's CDFs and face integrals, and the
map's power Σ_f max(I_f, 0) beside last frame's; on a changed frame that carries state,
``map_change`` adds 1 + χ² of the texels' densities against last frame's.  ``smc_advance``
tests both (step 5): nothing of the frame is read back before the outputs.  The texels
alternate between two buffers, so last frame's are γ_{t−1}'s map (no copy).  The frame's
``sample`` time is the tables' build and ``map_change``, its ``shade`` time the other kernels'
device time.  Device buffers (particles, BIS scratch, tables, outputs) are kept across frames
and :meth:`reset`, so a frame allocates and first-touches none.

Not unbiased (``Tags.unbiased = False``).  An init frame is unbiased, and so is a static
stretch after it; a continuing frame on a changing map
is a consistent SMC sampler (error → 0 as N → ∞) but not unbiased at finite N: Eq. 5's weights
need supp γ_t ⊆ supp γ_{t−1} at the particles' reach (light appearing where the last map was
black is missed by Z_t until a re-init), and the re-init decision and the γ_{t−1} = 0 guard
choose between two estimators by the value of the estimate itself, which biases the mixture.
The conformance suite therefore skips the z-test and runs the temporal checks.

Defaults: ν = 0.5 (Ghosh's mixture; local moves refine narrow lobes, independent moves escape
them), δ = 3°, 3 intermediate distributions (Kronander), re-init threshold 4 (a ×4 or ÷4 jump of
Z in one frame is far beyond the frame-to-frame change of a smooth sequence but well inside a
light switching), ``reinit_map_ess`` = 2/3 (step 5), ``init_candidates`` = 20 (Kronander's
BIS M/N = 400/20).
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from iblbench.estimators.base import (Estimator, ExtraColumn, KernelCost, Limit, Mutant, Setting,
                                      SweepPart, Tags, WorkCounts, read_estimate, specular_lobe_defines)
from iblbench.estimators.bis import MAX_SPP, run_bis_chunks, run_lockstep
from iblbench.estimators.runtime.chunks import run_in_chunks
from iblbench.estimators.runtime.device import KeptBuffers, event_ms
from iblbench.scenes import cubemap, visibility

MAP_CHANGE_GROUP = 64   # work items of map_change's one group (smc.cl), at most
# smc_advance's work items per group: one local size for every launch (PoCL builds a kernel per
# local size), its launches (chunks.run_in_chunks) padded to whole groups.  16, not 64: a group is
# the least a launch takes, and at N = 4096 one of 64 pixels took a second on one CPU core.
ADVANCE_GROUP = 16


@dataclasses.dataclass(frozen=True)
class SMCParams:
    """``N``: particles per pixel (0: N = spp); ``nu``: probability of a local MH move;
    ``local_degrees``: half-angle of the local move's cone; ``intermediates``: tempered
    distributions between frames (one MH move each, plus one at γ_t); ``reinit_threshold``:
    re-initialise by BIS when Z_t/Z_{t−1} leaves [1/threshold, threshold];
    ``reinit_map_ess``: re-initialise every pixel when the map's change would leave particles drawn
    from last frame's map an effective sample size under this share of N (0: never);
    ``init_candidates``: BIS candidates per particle at (re-)init; ``init_env_pick``: the share
    of (re-)init candidates drawn from the map instead of the BRDF (0: Burke's BRDF-only
    candidates, as Kronander; default 0.5, as the MH independent moves: an init that misses a
    small bright light passes that error on to the following frames)."""

    N: int = 0
    nu: float = 0.5
    local_degrees: float = 3.0
    intermediates: int = 3
    reinit_threshold: float = 4.0
    reinit_map_ess: float = 2.0 / 3.0
    init_candidates: int = 20
    init_env_pick: float = 0.5


class SMC(Estimator):
    __doc__ = __doc__
    name = "smc"
    sweep = SweepPart(("smc",), spp=(1, 4, 16), order=6)
    extra_columns = {
        "ess": ExtraColumn("smc's ESS", "smc: smallest ESS before resampling\n(particles, mean over "
                                        "carried pixels)"),
        "reinits": ExtraColumn("smc's re-inits", "smc: pixels re-initialised per frame", log=False)}
    perf_budget = (20, 3)   # as bis's (estimators/bis.py)
    cost = KernelCost(176, 45, 24, 58, 140, derivation="""\
        the first frame's smc_init (BIS with M = 20 N, the first half of the candidates from the
        map); F_e is a candidate, 176: a 16-lane block takes one strategy, the BRDF's draw 107
        (uniforms 3, both cosines 36, direction 68) or a map draw 28, half each 67.5, stratum 2,
        the texel of ω and its area_per_solid_angle 20, lobe power 41, n·ω 5, q 9 (mixture pdf 5
        × (1 − env_pick), + env_pick × the texel's .w × area 3), γ's other 10, γ/q 1, f/γ 12, as
        it leaves its lane the total and bound 2 and the w·f/γ sums 6 (175.5); F_s is a
        resampled one's excess, 45: regenerated in blocks that mix both strategies, so both
        draws 135, stratum 2, texel 10, lobe power 41, n·ω 5, γ 10, f/γ 12 (215: q is dead
        there), its position 2 and sums 3, the effective count 1: 221 = 176 + 45; per sample the
        particle (ω, W) and gammas written, 24 B; per pixel shading 24, hoisted factors 20
        (bis's + 1 − env_pick), the stratified pick 3, the resampling 3, the candidate ratio
        Σw·f/γ / Σw 3, 1/N 1, the estimate 3, stats 1; bytes: 64 in, its list entry 4, state,
        carried estimate, radiance, counts and stats out (72)""",
        lane_loops=((1, 1.0),), limits=(   # smc_init: BIS, half its candidates from the map
            Limit("philox", per_eval=1.5, why="a candidate's block, and a map draw's words"),
            Limit("phong_power", per_eval=1.5,
                  why="the lobe power; a BRDF draw's ξ^{1/(m+1)} (half)"),
            Limit("dependent_load", per_eval=1.5,
                  why="a map draw (half): the pair's alias entry, its column's, the texel"),
            Limit("gather", per_eval=3.5, why="the texel's R, G, B and its pdf's .w"),
            Limit("divide", per_eval=14,
                  why="a BRDF draw 5 or a map draw's alias positions 2, its face 1, x and y 2, "
                      "lanes_face_direction 2; lanes_texel_of 3, f/γ 3, γ/q 1, the strategy 1"),
            Limit("serial_add", per_eval=1, why="the weights' total, as bis's"),
            Limit("lockstep", per_sample=10, why="the resampling's search, as bis's")))
    Params = SMCParams
    # The re-init rules' settings: tests/test_smc.py holds each rule alone to its pixels.
    settings = (Setting("N", 4), Setting("nu", 1.0), Setting("local_degrees", 30.0),
                Setting("intermediates", 1), Setting("reinit_threshold", 1.01),
                Setting("reinit_map_ess", 0.0), Setting("init_candidates", 5),
                Setting("init_env_pick", 0.0))
    tags = Tags(unbiased=False, temporal=True, has_pdf=False)
    requires = ("cdf",)
    kernel_files = ("smc.cl", "sir.cl", "lanes.cl")
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        Mutant("smc-weight-update-without-previous-target", "smc.cl",
               "exp(log(g.y / g.x) / (float)steps)",
               "exp(log(g.y) / (float)steps)", stress=("temporal-dropout",)),
        Mutant("smc-mh-acceptance-inverted-proposal", "smc.cl",
               "ratio = (pi_new * q_old) / (pi_old * q_new);",
               "ratio = (pi_new * q_new) / (pi_old * q_old);", stress=("temporal-dropout",)),
        Mutant("smc-reinit-threshold-one-sided", "smc.cl",
               "if (!(ratio <= threshold && ratio >= 1.0f / threshold)) reinit = 1;",
               "if (!(ratio <= threshold)) reinit = 1;",
               stress=("temporal-dropout", "dimming-sun")),
        Mutant("smc-estimate-without-normaliser", "smc.cl",
               "estimate = z * ratio;",
               "estimate = ratio;", stress=("smooth-rotation",)),
        Mutant("smc-init-proposal-pdf-without-map-share", "sir.cl",
               "pdf += q->env_pick * GATHER(lanes_t, (__global const float *)q->texels + 3, 4 * texel) * area;",
               "pdf += GATHER(lanes_t, (__global const float *)q->texels + 3, 4 * texel) * area;",
               stress=("constant",)),
    )
    twin = "iblbench.harness.verify.twins.ghosh2006"   # its NumPy twin (conformance.check_matches_twin)
    max_spp = MAX_SPP   # N particles (bis's bound: its init is bis)

    def __init__(self, params=None, **overrides):
        super().__init__(params, **overrides)
        p = self.params
        if p.N < 0 or not 0.0 <= p.nu <= 1.0 or not 0.0 < p.local_degrees <= 180.0 \
                or p.intermediates < 0 or not p.reinit_threshold > 1.0 or p.init_candidates < 1 \
                or not 0.0 <= p.reinit_map_ess <= 1.0 \
                or not 0.0 <= p.init_env_pick <= 1.0:
            raise ValueError(f"invalid smc parameters {p}")
        self._spare = KeptBuffers()
        self.reset()

    def reset(self) -> None:
        self._key = None
        self._buffers = None
        self._prev_host_env = None
        self._texel_parity = 0

    def defines(self, gbuffer=None) -> dict:
        return specular_lobe_defines(gbuffer)

    def particles(self, spp: int) -> int:
        return self.params.N or int(spp)

    def work_counts(self, gbuffer, frames) -> list[WorkCounts]:
        """"Budget" above, per pixel, on a sequence whose every changed map is a scaled copy of
        the one before (ValueError otherwise: which pixels' own rule of step 5 fires is then not
        known without the particles), lit wherever a pixel looks but at pixels whose every
        visibility cell is closed, which see black: there every particle keeps a positive weight
        and Z_t/Z_{t−1} is the scale.  A BIS init costs M + N evaluations and M shadow rays (the
        candidates' V); a static frame S·N MH proposals, each one evaluation and one ray; a
        changed one N + (2(S−1) + 1)·N + N evaluations and S·N rays.  Re-initialised (an init,
        counted in the ``reinits`` extra after the first frame): every pixel on the first frame
        and where a map-level rule of step 5 fires (the power's jump past ``reinit_threshold``,
        or 1 + χ² past 1/``reinit_map_ess``, computed here from the maps); a black pixel on
        every frame (Z_{t−1} = 0).  No resampling anywhere (the weights stay equal):
        ``resample_steps`` 0."""
        p = self.params
        black = np.zeros(int(gbuffer.mask.sum()), bool) if gbuffer.visibility is None else \
            ~visibility.unpack_bits(gbuffer.visibility[gbuffer.mask], gbuffer.visibility_res).any(-1)
        counts, previous = [], None
        for frame in frames:
            N = self.particles(frame.spp)
            M, steps = p.init_candidates * N, p.intermediates + 1
            env = np.asarray(frame.cache.env, np.float64)
            if previous is None or np.array_equal(env, previous):
                reinit, carried = previous is None, (steps * N, steps * N)
            else:
                reinit, carried = self._map_rule_fires(previous, env), (N + (2 * steps - 1) * N + N, steps * N)
            reinit = reinit | black
            work = [np.where(reinit, init, carry) for init, carry in zip((M + N, M), carried)]
            reinits = 0 if previous is None else int(reinit.sum())
            counts.append(WorkCounts(*work, extras={"reinits": reinits, "resample_steps": 0.0}))
            previous = env
        return counts

    def _map_rule_fires(self, previous: np.ndarray, env: np.ndarray) -> bool:
        """Whether step 5's map-level rules re-initialise every pixel between two maps, of which
        the second must be a scaled copy of the first or fire one."""
        p = self.params
        omega = cubemap.texel_solid_angles(env.shape[1])
        before, after = (cubemap.luminance(m) * omega for m in (previous, env))
        ratio = after.sum() / before.sum()
        lit_up = np.where(after > 0, np.inf, 0.0)   # a black texel that lit up: +∞ (step 5)
        chi2_plus_1 = np.sum(np.divide((after / after.sum()) ** 2, before / before.sum(),
                                       out=lit_up, where=before > 0))
        if not 1.0 / p.reinit_threshold <= ratio <= p.reinit_threshold \
                or p.reinit_map_ess * chi2_plus_1 > 1.0:
            return True
        if not np.allclose(env, ratio * previous, rtol=1e-6, atol=0.0):
            raise ValueError("smc's counts are known on scaled maps and map-level re-inits only")
        return False

    def _map_tables(self, cache, defines, buffer, changed: bool):
        """The map proposal's alias tables (sir.cl), the map's power and, where the map
        ``changed`` since last frame, its change, built on the device.  The texels alternate
        between two buffers: last frame's are γ_{t−1}'s map."""
        compute, res = cache.compute, cache.res
        alias = buffer("alias", (6 * res + 6 * res * res) * 8)
        parity, self._texel_parity = self._texel_parity, 1 - self._texel_parity
        texels = buffer(f"texels{parity}", 6 * res * res * 16)
        prev_texels = buffer(f"texels{1 - parity}", 6 * res * res * 16)
        pair_probability, map_power = buffer("pair_probability", 6 * res * 4), buffer("map_power", 12)
        table_events = [
            compute.run(compute.kernel(self.kernel_package(), "smc.cl", "map_alias_pairs", defines), 1,
                        cache.marginal, cache.face_integral_buffer, alias, pair_probability, map_power),
            compute.run(compute.kernel(self.kernel_package(), "smc.cl", "map_alias_columns", defines),
                        6 * res, cache.env_buffer, cache.conditional, pair_probability, alias, texels)]
        if changed:
            change = compute.kernel(self.kernel_package(), "smc.cl", "map_change", defines)
            group = compute.fitting_group(change, MAP_CHANGE_GROUP)   # one group, the whole launch
            table_events.append(compute.run(change, group, texels, prev_texels, map_power, group=group))
        return texels, prev_texels, alias, map_power, table_events

    def render(self, gbuffer, cache, spp, seed):
        if not 1 <= spp <= MAX_SPP:
            raise ValueError(f"spp must be in [1, {MAX_SPP}], got {spp}")
        compute, p = cache.compute, self.params
        N = self.particles(spp)
        M = p.init_candidates * N
        key = (id(gbuffer), gbuffer.count, N, cache.res, int(seed))
        have_state = key == self._key
        static_frame = have_state and (cache.env is self._prev_host_env
                                       or np.array_equal(cache.env, self._prev_host_env))
        self._prev_host_env = cache.env
        count = gbuffer.count
        buffer = functools.partial(self._spare.get, compute)
        if not have_state:
            self._buffers = [buffer("particles", count * N * 16), buffer("gammas", count * N * 8),
                             buffer("scratch_p", count * N * 16), buffer("scratch_g", count * N * 8),
                             buffer("state", count * 16), buffer("carried_estimate", count * 16)]
            self._key = key
        particles, gammas, scratch_p, scratch_g, state, carried_estimate = self._buffers
        radiance = buffer("radiance", count * 16)
        counts = buffer("counts", count * 8)
        stats = buffer("stats", count * 16)
        rays = buffer("rays", count * 4)
        defines = {**self.defines(gbuffer), "ENV_RES": cache.res, "MAP_CHANGE_GROUP": MAP_CHANGE_GROUP}
        texels, prev_texels, alias, map_power, table_events = self._map_tables(
            cache, defines, buffer, changed=have_state and not static_frame)
        events = []
        if have_state:
            flags = buffer("flags", count * 4)
            advance = compute.kernel(self.kernel_package(), "smc.cl", "smc_advance", defines)

            def advance_pixels(first: int, pixels: int):
                return compute.run(
                    advance, -(-pixels // ADVANCE_GROUP) * ADVANCE_GROUP, gbuffer.normal, gbuffer.view,
                    gbuffer.kd, gbuffer.ks, gbuffer.visibility, cache.env_buffer, prev_texels, alias, texels,
                    map_power, np.int32(count), np.int32(N), np.int32(p.intermediates + 1), np.float32(p.nu),
                    np.float32(math.cos(math.radians(p.local_degrees))), np.float32(p.reinit_threshold),
                    np.float32(p.reinit_map_ess), np.int32(static_frame), np.uint32(seed),
                    np.uint32(cache.frame), particles, gammas, scratch_p, scratch_g, state,
                    carried_estimate, radiance, counts, stats, flags, rays, group=ADVANCE_GROUP, offset=first)

            events += run_in_chunks(count, ADVANCE_GROUP, advance_pixels, kind=(
                id(compute), "smc_advance", count, N, p.intermediates, bool(static_frame)))
            listed, listed_total = buffer("listed", count * 4), buffer("listed_total", 4)
            events.append(compute.run(
                compute.kernel(self.kernel_package(), "smc.cl", "smc_list_reinit", defines), 1,
                flags, np.int32(count), listed, listed_total))
        else:
            listed = compute.to_device(np.arange(count, dtype=np.int32))
            listed_total = compute.to_device(np.array([count], np.int32))
        # Launches over every pixel: smc_init's groups past the device's list return at once.
        init = compute.kernel(self.kernel_package(), "smc.cl", "smc_init", defines)
        events += run_bis_chunks(compute, init, count, M, N, lambda offset, pixels, *scratch: run_lockstep(
            compute, init, pixels, gbuffer.normal, gbuffer.view, gbuffer.kd, gbuffer.ks, gbuffer.visibility,
            texels, alias, map_power, np.int32(count), np.int32(N), np.int32(M),
            np.float32(p.init_env_pick), np.int32(have_state), np.uint32(seed), np.uint32(cache.frame),
            listed, listed_total, np.int32(offset), *scratch, particles, gammas, state, carried_estimate,
            radiance, counts, stats, rays), buffer)
        st = compute.to_host(stats, (gbuffer.count, 4), np.float32)
        carried = st[:, 0] >= 0
        estimate = read_estimate(compute, gbuffer, radiance, counts, float(st[:, 2].mean()),
                                 {"sample": sum(map(event_ms, table_events)),
                                  "shade": sum(map(event_ms, events))},
                                 shadow_rays=float(compute.to_host(rays, (count,), np.float32).mean())
                                 if gbuffer.has_visibility else 0.0)   # no read back without V
        estimate.extras = {
            "ess": float(st[carried, 0].mean()) if carried.any() else float("nan"),
            "reinits": float(st[:, 1].sum()),
            "resample_steps": float(st[:, 3].mean()),
        }
        return estimate
