"""``brdf``: Phong BRDF sampling only, the classic baseline for glossy surfaces under smooth maps."""
from __future__ import annotations

from iblbench.estimators.base import KernelCost, Limit, SweepPart
from iblbench.estimators.envmap import MapSampler


class Brdf(MapSampler):
    """Importance sampling of the energy-conserving Phong BRDF alone (ARCHITECTURE.md §Conventions; Lafortune and
    Willems 1994; pbrt-v4's BSDF sampling in a path tracer without light sampling).

    The lobe is chosen by luminance weight, p_s = Y(ks)/(Y(kd) + Y(ks)); the diffuse lobe is
    sampled cosine-weighted (cos θ = √ξ about n), the specular lobe ∝ cos^m about the mirror
    direction r (cos θ = ξ^{1/(m+1)}).  The density is the mixture
    p_B(ω) = (1 − p_s)·cos⁺(n,ω)/π + p_s·(m+1)/(2π)·cos⁺(r,ω)^m, which counts the specular
    lobe's mass below the surface: those samples are drawn, evaluate to zero, and count as used
    but not effective.  The estimate is Σ_i β_i L(ω_i) ρ(ω_i) cos⁺(n,ω_i) / (N_s p_B(ω_i)), the
    last of ⌈N_s⌉ draws weighted by β (Lu 2013 Eq. 5, here always 1: N_s is an integer).  It is
    unbiased because p_B > 0 wherever ρ·cos⁺ > 0 (the diffuse lobe where kd > 0, the specular
    lobe wherever its own term is positive).  It never reads the map's CDFs: its only per-frame
    product is the uploaded map.

    Deviations: none from ARCHITECTURE.md §Conventions; it shares ``envmap``'s kernel (``envmap.cl`` without light
    samples), so its BRDF draws are ``envmap``'s with MIS.
    """

    name = "brdf"
    sweep = SweepPart(("brdf",), order=7)
    cost = KernelCost(174, 0, 0, 103, 88, derivation="""\
        a BRDF sample drawn per pixel (estimators/envmap.cl without light samples), 174:
        uniforms 3, sincos_turn 24, √ξ 1, log2 ξ 16 and the exp2 half 19 of ξ^{1/(m+1)}, the
        direction 31 in the per-pixel bases, lobe power 41, n·ω 5, mixture pdf 5, texel lookup
        10, D 1, add_samples 18; per pixel shading 24, the bases about n and r 26, hoisted
        factors 6, the 16-lane sums out 47; bytes as uniform's""",
        lane_loops=((1, 1.0),), limits=(   # envmap.cl's BRDF loop, LIGHT_SAMPLES = 0
            Limit("philox", per_eval=1, why="draw_numbers' block"),
            Limit("phong_power", per_eval=2,
                  why="the draw's ξ^{1/(m+1)} (log2 ξ and the exp2 half: one power, its log2's "
                      "quotient included) and the lobe power"),
            Limit("divide", per_eval=8,
                  why="√ξ, the direction's sin θ and 1/|ω| 3, the mixture pdf's /π, "
                      "lanes_texel_of's s/ma and t/ma (its √q is dead), add_samples' β / D"),
            Limit("gather", per_eval=3, why="the texel's R, G, B"),
            Limit("divide", per_pixel=2, why="the bases about n and r")))
    kernel_files = ("brdf.cl", "envmap.cl", "lanes.cl")
    light_samples = False
