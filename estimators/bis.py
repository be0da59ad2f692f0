"""``bis``: Burke et al. 2005 bidirectional importance sampling, as Kronander et al. §5 use it.

Sampling-importance-resampling per pixel (kernels ``sir.cl`` + ``bis.cl``):

1. M candidates ω_i from the Phong BRDF mixture p_B (ARCHITECTURE.md §Conventions, ``sample_phong``);
2. weights w_i = γ(ω_i)/p_B(ω_i) with the target γ = L_Y·ρ_Y·cos⁺ (Kronander Eq. 3: luminance
   of the radiance times luminance of the BRDF times the cosine);
3. N samples resampled from the candidates by **systematic** resampling (one uniform u, the
   positions (k+u)/N on the normalised cumulative weights);
4. L̂ = Ẑ/N · Σ_k f(ω_k)/γ(ω_k), Ẑ = (1/M) Σ_i w_i, f = L·ρ·cos⁺ in RGB (Eq. 4 with Ẑ taken
   over the candidates, which makes it unbiased; see ``sir.cl``).

Budget.  ``spp`` is the number N of resampled samples (the samples whose full integrand,
visibility included in a ray tracer, is evaluated: ``used``); the candidates are
M = round(spp · M_param / N_param), so the default params (M = 400, N = 20, Kronander's) give
M = 20·spp and spp = 20 is exactly Kronander's set-up.  ``evaluations`` = M + N per pixel: M
evaluations of γ at the candidates and N of f at the resampled samples, which is also what
the kernel computes: it stores the M weights' cumulative bounds and the N candidates chosen
(scratch of 8M + 4N bytes per pixel, in launches of at most ``SCRATCH_BYTES`` and about
``chunks.CHUNK_MS`` device time) and regenerates
only the N resampled candidates for f.
``used`` = ``effective`` = N (every resampled sample has γ > 0, so a positive cosine), 0 where
every candidate weight is 0 (black map above the horizon).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pyopencl as cl

from iblbench.estimators.base import (Estimator, KernelCost, Limit, Mutant, Setting, SweepPart, Tags,
                                      WorkCounts, read_estimate, specular_lobe_defines)
from iblbench.estimators.runtime.chunks import run_in_chunks
from iblbench.estimators.runtime.device import event_ms
from iblbench.estimators.runtime.device_gbuffer import LOCKSTEP_GROUP


@dataclasses.dataclass(frozen=True)
class BISParams:
    """``M`` candidates per ``N`` resampled samples (Kronander: M = 400, N = 20).  A render at
    ``spp`` resamples N = spp samples from M = round(spp·M/N) candidates."""

    M: int = 400
    N: int = 20


def candidates_for(spp: int, M: int, N: int) -> int:
    """Candidates of a render at ``spp`` resampled samples, for the ratio M:N (≥ spp)."""
    return max(int(spp), int(round(spp * M / N)))


def effective_sample_size(weights) -> float:
    """ESS = (Σ w)² / Σ w² = 1/Σ W² with W the normalised weights (Kronander §6.1)."""
    w = np.asarray(weights, np.float64)
    total = w.sum()
    return float(total * total / np.sum(w * w)) if total > 0 else 0.0


def systematic_resample(weights, u: float, n: int | None = None) -> np.ndarray:
    """NumPy twin of ``systematic_indices`` (sir.cl): index of each position (k + u)/n,
    k < n, in the cumulative normalised weights."""
    w = np.asarray(weights, np.float64)
    n = len(w) if n is None else n
    cumulative = np.cumsum(w) / w.sum()
    positions = (np.arange(n) + u) / n
    return np.minimum(np.searchsorted(cumulative, positions, side="right"), len(w) - 1)


# The most spp (resampled samples N) of bis and smc: N = 4096 weighs M = 20N = 81,920 candidates
# a pixel, seconds a frame at 128² on a CPU; 40,000 spp ran past 25 s a cell (issue 23).
MAX_SPP = 4096
SCRATCH_BYTES = 64 << 20   # BIS scratch per launch (N chosen, M bounds, 3 sums a pixel); more pixels,
#                             more launches


def lockstep_group(compute, kernel) -> int:
    """Work items per group of a LOCKSTEP kernel on this device."""
    return min(LOCKSTEP_GROUP, compute.group_limit(kernel))


def run_lockstep(compute, kernel, count: int, *args) -> cl.Event:
    """Launch a kernel that reaches LOCKSTEP (lanes.cl) over ``count`` work items in whole groups:
    the global size is padded up to a multiple of the group size (the kernel takes ``count`` and
    stores nothing past it).  Returns the profiled event."""
    group = lockstep_group(compute, kernel)
    kernel.set_args(*args)
    padded = max(-(-int(count) // group), 1) * group
    event = cl.enqueue_nd_range_kernel(compute.queue, kernel, (padded,), (group,))
    event.wait()
    return event


def run_bis_chunks(compute, kernel, count: int, M: int, N: int, launch, empty=None) -> list[cl.Event]:
    """Run ``count`` pixels in launches of about ``chunks.CHUNK_MS`` device time whose BIS
    scratch also fits SCRATCH_BYTES (:func:`~iblbench.estimators.runtime.chunks.run_in_chunks`):
    ``launch(offset, pixels, chosen, bounds, sums)`` runs one and returns its event, with scratch
    buffers (sir.cl, SIR_SCRATCH_ARGS) sized for the largest launch, from ``empty(name, nbytes)``
    if given (a caller's reused buffers), else newly allocated.  Its first launch starts from the
    rate of the last run of the same kernel, device, pixels, M and N.  Returns the events."""
    group = lockstep_group(compute, kernel)
    per_launch = max(group, SCRATCH_BYTES // (4 * N + 8 * M + 3 * 8) // group * group)
    size = min(per_launch, max(-(-int(count) // group), 1) * group)
    empty = empty or (lambda name, nbytes: compute.empty(nbytes))
    scratch = (empty("chosen", 4 * N * size), empty("bounds", 8 * M * size),
               empty("sums", 3 * 8 * size))
    return run_in_chunks(int(count), group, lambda offset, pixels: launch(offset, pixels, *scratch),
                         most=per_launch, kind=(id(compute), kernel.function_name, int(count), M, N))


class BIS(Estimator):
    __doc__ = __doc__
    name = "bis"
    sweep = SweepPart(("bis",), spp=(1, 4, 16), order=5)
    # perf: at Kronander's N = 20 (M = 400) with 3 repeats, unless --spp / --repeats say
    # otherwise: M + N = 21 candidates a resampled sample make spp 64 take seconds a frame at
    # 256² on a 2-core CPU (spp 16: about 0.8 s for bis, 1.9 s for smc).
    perf_budget = (20, 3)
    cost = KernelCost(183, 3, 0, 50, 88, derivation="""\
        F_e is a candidate, 183: uniforms 3, stratum 2, sample_phong_direction 104 (both polar
        cosines, ξ^{1/(m+1)} 35 and √ξ, the direction 68), lobe power 41, q 10 (n·ω 5, mixture
        pdf 5), γ = L_Y ρ_Y cos 20 (texel lookup 10, Y(L) 5, ρ_Y 3, products 2), γ/q 1, and as
        it leaves its lane the total (fp64) and the bound 2 (its f/γ is dead: no candidate
        ratio); F_s is a resampled one's excess: regenerated in 16-lane vectors, 181 (the
        candidate's 181 before its lane's sums, less q 10, γ/q 1 and ×cos 1, which nothing reads
        there, + f/γ 12), its systematic position 2 and f/γ sums 3: 186 = 183 + 3; per pixel
        shading 24, hoisted factors 19 (11 before the candidates, the 8 that f/γ needs again
        before the regeneration), the resampling uniform, Σw/N and Ẑ 3, output 4""",
        lane_loops=((1, 1.0),), limits=(   # sir.cl: sir_candidate_lanes for the M + N evaluations
            Limit("philox", per_eval=1, why="the candidate's block"),
            Limit("phong_power", per_eval=2, why="ξ^{1/(m+1)} and the lobe power"),
            Limit("divide", per_eval=13,
                  why="the strategy's (i + ½)/M 1, √ξ 1, direction_about_axis 4 (its basis' "
                      "1/(s + z), sin θ, √ and 1/ of the norm), the mixture pdf 1, "
                      "cube_face_st 2, f/γ's three quotients 3, γ/q 1"),
            Limit("gather", per_eval=3, why="the texel's R, G, B"),
            Limit("serial_add", per_eval=1,
                  why="bis_pixel: each candidate's weight leaves its lane into the total"),
            Limit("lockstep", per_sample=10,
                  why="a resampled position's binary search, ⌈log2 M⌉ = 9 steps at the "
                      "default M = 400, and its store, each ended by LOCKSTEP")))
    Params = BISParams
    settings = (Setting("M", 100), Setting("N", 5))
    tags = Tags(unbiased=True, temporal=False, has_pdf=False)
    requires = ("env",)
    kernel_files = ("bis.cl", "sir.cl", "lanes.cl")
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        Mutant("bis-resampling-fixed-variate", "sir.cl",
               "float u = lane_uniform4(seed, frame, STREAM_SIR_RESAMPLE, pixel, 0u, 0u).x;",
               "float u = 0.5f;", estimators=('bis{M=2,N=1}',), stress=("one-sample",)),
        Mutant("bis-target-without-cosine", "sir.cl",
               "lanes_t gamma = select((lanes_t)0.0f, radiance_y * rho_y * cosine, counted);",
               "lanes_t gamma = select((lanes_t)0.0f, radiance_y * rho_y, counted);",
               stress=("constant",)),
        Mutant("bis-normaliser-over-n-not-m", "sir.cl",
               "return positive ? (float)(total / (acc_t)M) : 0.0f;",
               "return positive ? (float)(total / (acc_t)N) : 0.0f;", stress=("constant",)),
    )
    max_spp = MAX_SPP

    def __init__(self, params=None, **overrides):
        super().__init__(params, **overrides)
        if self.params.M < 1 or self.params.N < 1:
            raise ValueError(f"bis needs M ≥ 1 and N ≥ 1, got {self.params}")

    def defines(self, gbuffer=None) -> dict:
        return specular_lobe_defines(gbuffer)

    def budget(self, spp: int) -> tuple[int, int]:
        """(M, N) of a render at ``spp``."""
        return candidates_for(spp, self.params.M, self.params.N), int(spp)

    def work_counts(self, gbuffer, frames) -> list[WorkCounts]:
        """"Budget" above: M = round(spp·M/N) candidates' γ and the N = spp resampled samples' f,
        only those N with V (the target leaves it out)."""
        counts = []
        for frame in frames:
            candidates = max(frame.spp, round(frame.spp * self.params.M / self.params.N))
            counts.append(WorkCounts(candidates + frame.spp, frame.spp))
        return counts

    def render(self, gbuffer, cache, spp, seed):
        if not 1 <= spp <= MAX_SPP:
            raise ValueError(f"spp must be in [1, {MAX_SPP}], got {spp}")
        compute = cache.compute
        M, N = self.budget(spp)
        kernel = compute.kernel(self.kernel_package(), "bis.cl", "render_bis", self.defines(gbuffer))
        radiance = compute.empty(gbuffer.count * 16)
        counts = compute.empty(gbuffer.count * 8)

        def launch(offset: int, pixels: int, *scratch) -> cl.Event:
            return run_lockstep(compute, kernel, pixels, gbuffer.normal, gbuffer.view, gbuffer.kd,
                                gbuffer.ks, gbuffer.visibility, cache.env_buffer, np.int32(cache.res), np.int32(M),
                                np.int32(N), np.uint32(seed), np.uint32(cache.frame), np.int32(offset),
                                np.int32(pixels), *scratch, radiance, counts)

        shade_ms = event_ms(run_bis_chunks(compute, kernel, gbuffer.count, M, N, launch))
        return read_estimate(compute, gbuffer, radiance, counts, M + N, {"shade": shade_ms}, shadow_rays=N)
