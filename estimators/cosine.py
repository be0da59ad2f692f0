"""``cosine``: cosine-weighted hemisphere sampling, the textbook baseline that ignores both the map
and the glossy lobe."""
from __future__ import annotations

import numpy as np

from iblbench.estimators.base import (Estimator, KernelCost, Limit, Mutant, Tags, WorkCounts, read_estimate,
                                      visibility_defines)
from iblbench.estimators.runtime.device import event_ms


class Cosine(Estimator):
    """Cosine-weighted hemisphere sampling about the normal (Malley's method; Pharr, Jakob and
    Humphreys, *Physically Based Rendering*, 4th ed., §A.5.3): cos θ = √ξ₁, φ = 2π·ξ₂, density
    p(ω) = cos⁺(n,ω)/π, which importance-samples the diffuse lobe's ρ_d·cos exactly.  The
    estimate is (1/N) Σ_i π·ρ(ω_i) L(ω_i) V(ω_i): unbiased, as p > 0 over the whole upper
    hemisphere where ρ·cos⁺ lives, but blind to the map and to the specular lobe, so a sun or a
    sharp lobe leaves it noisy.  It reads no CDF: its only per-frame product is the uploaded map.

    Deviations: none; one pixel per work item, its samples in a scalar loop."""

    name = "cosine"
    tags = Tags(unbiased=True)
    kernel_files = ("cosine.cl",)
    perf_budget = (16, 3)   # a scalar loop, slow a sample: perf keeps `make bench` near its time
    cost = KernelCost(129, 0, 0, 41, 88, derivation="""\
        a sample: √ξ 1, its direction about n 55 (sincos_turn 24, the rest 31; the basis is the
        pixel's), n·ω 5, the texel of ω 10, lobe power 41 (r·ω 5, phong_power 35, max 1),
        phong_value 7, V·π·ρ·L and the sum 10: 129; per pixel the shading 24 (reflection 12,
        Y(kd), Y(ks) 10, lobe choice 2), the basis about n 13 and the mean 4: 41; bytes: 64 in,
        radiance 16 and counts 8 out""",
        scalar=True, limits=(   # render_cosine's loop over its samples, a pixel a work item
            Limit("philox", per_eval=1, why="rng_uniform4's block"),
            Limit("phong_power", per_eval=1, why="phong_brdf's lobe power"),
            Limit("divide", per_eval=7,
                  why="√ξ, direction_about_axis 4, dir_to_face_st's two quotients"),
            Limit("gather", per_eval=1, why="the texel")))
    mutants = (
        Mutant("cosine-density-without-pi", "cosine.cl",
               "sum += open * IBL_PI * phong_brdf", "sum += open * phong_brdf",
               stress=("constant",)),
    )

    def work_counts(self, gbuffer, frames) -> list[WorkCounts]:
        """N samples, each one evaluation and one V."""
        return [WorkCounts(frame.spp, frame.spp) for frame in frames]

    def render(self, gbuffer, cache, spp, seed):
        if spp < 1:
            raise ValueError(f"spp must be at least 1, got {spp}")
        compute = cache.compute
        kernel = compute.kernel(self.kernel_package(), "cosine.cl", "render_cosine",
                                visibility_defines(gbuffer))
        radiance = compute.empty(gbuffer.launch_size * 16)
        counts = compute.empty(gbuffer.launch_size * 8)
        event = gbuffer.run(compute, kernel, gbuffer.normal, gbuffer.view, gbuffer.kd, gbuffer.ks,
                            gbuffer.visibility, cache.env_buffer, np.int32(cache.res),
                            np.int32(spp), np.uint32(seed), np.uint32(cache.frame), radiance,
                            counts)
        return read_estimate(compute, gbuffer, radiance, counts, spp, {"shade": event_ms(event)})
