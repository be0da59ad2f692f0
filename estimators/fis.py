"""``fis``: filtered importance sampling (Colbert and Křivánek, "GPU-Based Importance Sampling",
GPU Gems 3 ch. 20), biased by design: BRDF samples that read a mip level of the map."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pyopencl.cltypes as cltypes

from iblbench.estimators.base import KernelCost, Limit, Setting, SweepPart, Tags, read_estimate
from iblbench.estimators.brdf import Brdf
from iblbench.estimators.light_pool import MAX_SPP, hook_surface, lane_chunks
from iblbench.estimators.runtime.device import event_ms

MAX_LEVELS = 16   # mip levels render_fis takes (its int16 of level offsets): faces up to 2^15, past
                 # the 8192² that mips.level_offsets allows


@dataclasses.dataclass(frozen=True)
class FisParams:
    """``lod_bias`` (default 1.0, the chapter's): mip levels added to Eq. 13's level after its
    clamp at 0, so every sample reads level ``lod_bias`` or coarser; 0 makes the estimator
    consistent (its limit is then the exact integral of the map)."""

    lod_bias: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.lod_bias) and self.lod_bias >= 0):
            raise ValueError(f"lod_bias must be a finite number ≥ 0, got {self.lod_bias!r}")


class Fis(Brdf):
    """Filtered importance sampling (Colbert and Křivánek 2007, GPU Gems 3 ch. 20, Sec. 20.2-20.4):
    N = spp Phong BRDF samples per pixel from a Hammersley set, each reading the radiance mip
    chain at a level chosen from its pdf, weighted by ρ·cos⁺/(N·p) (Eq. 2).

    Point set (Sec. 20.3, Eq. 10): the N points x_i = (i/N, Φ2(i)), Φ2 the base-2 radical
    inverse, a whole set per pixel (never a prefix), Cranley–Patterson rotated: both coordinates
    shifted modulo 1 by a Philox pair keyed by (seed, frame, pixel), in 32-bit fixed point so
    each rotated point alone is exactly uniform.  The chapter shares one fixed set between all
    pixels (shader constants) and lets the filter hide its aliasing; here the rotation makes
    the seeds independent (ARCHITECTURE.md §Estimator contract: a seed is a sample of the error) and makes the mean over
    seeds exactly the filtered integral I_N = ∫ L_lod(ω) ρ cos⁺ dω of the lod function at N, so
    the bias is a deterministic function of N (tests/test_fis.py checks it by quadrature).
    Per pixel, not per frame: a shared rotation keeps the chapter's duplicated highlights
    (Fig. 20-5a) as an error correlated across pixels; per pixel it is noise.

    Directions (Sec. 20.2.3): ARCHITECTURE.md §Conventions's Phong mixture.  ξ1 = i/N ⊕ shift picks the lobe by
    where it falls (specular below p_s = Y(ks)/(Y(kd) + Y(ks))) and, rescaled within that
    lobe's share, is the polar variate: cos θ = ξ^{1/(m+1)} about r (Eq. 7) or √ξ about n;
    ξ2 = Φ2(i) ⊕ shift is the azimuth 2πξ2 (Eq. 8); Eq. 9 and the basis of Duff et al. 2017
    (common.cl) take it to world space.  p is the mixture density.

    Mip level (Sec. 20.4, Eq. 11-13, with the cube map's distortion of Sec. 20.4.1):
      Ω_s = 1/(N·p(ω))                                                              (Eq. 11)
      Ω_p = d(u)/(w·h), w·h = R² (one face), d(u) = 4/(1+u²+v²)^{3/2}               (Eq. 12)
      lod = max(½·log2(Ω_s/Ω_p), 0) + lod_bias, lod_bias = 1                         (Eq. 13)
    where (u, v) ∈ [−1, 1]² is ω's point on its face plane: d(u)/R² is the level-0 texel's
    solid angle at ω to first order ((2/R)² times ARCHITECTURE.md §Conventions's dω/dA), not the exact texel Ω
    of ARCHITECTURE.md §Conventions (they differ by O(1/R²)); the chapter's d(u) (Eq. 14) is its dual-paraboloid
    map's.  The +1: the chapter adds 1 "to the calculated mipmap level defined by Equation 13",
    whose max(…, 0) clamp comes first; read so, every sample reads level 1 or coarser, and the
    bias does not vanish as N grows (others put the +1 inside the clamp, e.g. Filament's
    ``CubemapIBL::roughnessFilter``, libs/ibl: + log4(K) with K = 4, which then vanishes where
    Ω_s ≪ Ω_p).  The level is clamped to the coarsest (1×1 per face); log2 is common.cl's
    polynomial (phong_power's first half).

    Lookup: linear between the two levels around lod (⌊lod⌋ and ⌊lod⌋ + 1) and the nearest
    texel within each (OpenGL's GL_NEAREST_MIPMAP_LINEAR; the chapter's tex2Dlod takes its
    filter from a sampler state it does not give; a GPU's mipmapped sampler is usually
    trilinear).  Nearest within a level keeps ARCHITECTURE.md §Conventions's piecewise-constant map: at lod 0 a
    sample reads exactly what the reference integrates, and every level is constant over blocks
    of 2^l × 2^l level-0 texels.

    Mips and cube edges: ``FrameCache.radiance_mips`` (estimators/runtime/mips.py), per face 2×2 box means
    ("each pixel of level l is the average of the four corresponding pixels of level l − 1",
    Sec. 20.4), not weighted by solid angle, as a GPU's mip generation; an odd face size
    averages the children a parent has.  No filtering across cube edges: a texel at a face edge
    averages its own face only, so coarse levels show the seams Sec. 20.4.1 describes for cube
    maps.  The chapter's remedy, a scaled dual-paraboloid map (b = 1.2, Table 20-2), is not
    followed: ARCHITECTURE.md §Conventions fixes the cube map.

    Bias and limit (``tags.unbiased = False``, ``tags.has_limit``): the mean over seeds at N is
    I_N, which differs from the exact integral.  As N grows, ½·log2(Ω_s/Ω_p) → −∞ wherever
    p > 0, so lod → lod_bias and FIS converges to the exact integral of the map that
    :meth:`limit_map` returns: level 1 of the chain read at level-0 resolution by default (the
    map with each 2×2 block averaged); with ``lod_bias = 0`` the map itself.  The conformance
    check ``check_consistent_limit`` holds it to that limit; the report states the bias left
    at the highest spp against the exact reference.

    Counts: used = N, effective = the samples with n·ω > 0 and p > 0, evaluations = N.

    Deviations from the chapter: the rotated per-pixel set above (not one deterministic set);
    the full Phong mixture sampled and shaded by Eq. 2, where the chapter samples the specular
    lobe only and shades the diffuse one with spherical harmonics (Sec. 20.5); a cube map with
    per-face mips instead of the scaled dual-paraboloid map; nearest texels within a level.
    """

    name = "fis"
    sweep = SweepPart(("fis",), order=10)
    cost = KernelCost(223, 0, 0, 123, 88, derivation="""\
        a filtered BRDF sample, 223: its Hammersley point 2 and lobe rescale 5, brdf's draw
        after the uniforms 91 (sincos_turn 24, √ξ 1, ξ^{1/(m+1)} 35, direction 31), lobe power
        41, n·ω 5, mixture pdf 5, the texel of ω and its area_per_solid_angle 20, the lod of Eq.
        13 26 (log2 16, the clamps, bias, floor and share 10), the blend of two levels 9, D 1,
        add_samples 18; per pixel brdf's 103 and the lod shift ½·log2(R²/4N) 20 (its library
        log2 counted as the polynomial's 16); bytes as brdf's (the mip chain, 4/3 of the map,
        taken as cache-resident like the map)""",
        lane_loops=((1, 1.0),), limits=(   # render_fis's loop
            Limit("phong_power", per_eval=2.5,
                  why="the draw's ξ^{1/(m+1)} (log2 ξ and the exp2 half: one power, its log2's "
                      "quotient included) 1, the lobe power 1, the lod's log2 (the power's first "
                      "half) 0.5"),
            Limit("divide", per_eval=12,
                  why="ξ_cos's two quotients 2, √ξ 1, the direction 3, the mixture pdf 1, "
                      "lanes_texel_of 3, Jacobian / pdf 1, add_samples 1"),
            Limit("gather", per_eval=6, why="R, G, B at the two mip levels")))
    Params = FisParams
    settings = (Setting("lod_bias", 0.0),)   # tests/test_fis.py: the filtered integral at 0-2.25
    tags = Tags(unbiased=False, has_pdf=True, has_limit=True)
    requires = ("radiance_mips",)
    kernel_files = ("fis.cl", "envmap.cl", "lanes.cl")

    def render(self, gbuffer, cache, spp, seed):
        if not 1 <= spp <= MAX_SPP:
            raise ValueError(f"spp must be in [1, {MAX_SPP}], got {spp}")
        compute = cache.compute
        mips = cache.radiance_mips()
        radiance = compute.empty(gbuffer.launch_size * 12)   # planes R, G, B (as envmap.cl)
        counts = compute.empty(gbuffer.launch_size * 8)      # planes used, effective
        evaluations = compute.empty(gbuffer.launch_size * 4)
        level_offsets = cltypes.make_int16(*(np.array(mips.offsets + (0,) * MAX_LEVELS)[:MAX_LEVELS]
                                             // mips.channels))
        event = gbuffer.run_sampled(
            compute, lambda name: self._kernel(compute, name, gbuffer), "render_fis",
            lane_chunks([spp], compute.pool_lanes), gbuffer.normal,
            gbuffer.view, gbuffer.kd, gbuffer.ks, gbuffer.visibility, np.int32(gbuffer.launch_size),
            mips.buffer, level_offsets,
            np.int32(len(mips.sizes)), np.int32(cache.res), np.int32(spp),
            np.float32(self.params.lod_bias), np.uint32(seed), np.uint32(cache.frame), radiance,
            counts, evaluations)
        # The chain is a required product: the runner times its build as the build stage.
        return read_estimate(compute, gbuffer, radiance, counts, float(spp),
                             {"sample": 0.0, "shade": event_ms(event)}, planar=True)

    def sample_directions(self, cache, normal, view, n, seed):
        """The ``n`` directions ``[n, 3]`` that a render at spp = ``n`` draws for pixel 0 of
        frame 0 (one rotated Hammersley set), and their mixture density; the material is the
        conformance suite's glossy one.  A low-discrepancy set is spread more evenly than the
        independent draws a χ² test assumes, so the test is conservative here: it still sees
        a wrong mapping or pdf, not a too-even spread.  None on an all-black map, as the other
        samplers' hooks: every sample there weighs 0."""
        compute = cache.compute
        if not np.any(cache.env):
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        lanes = compute.pool_lanes   # points per work item (POOL_LANES, light_pool.cl)
        groups = -(-n // lanes)
        out = compute.empty(4 * groups * lanes * 4)
        compute.run(self._kernel(compute, "fis_directions"), groups, hook_surface(cache, normal, view),
                    np.int32(n), np.uint32(seed), out)
        planes = compute.to_host(out, (4, groups * lanes), np.float32)[:, :n]
        return np.ascontiguousarray(planes[:3].T), planes[3].copy()

    def limit_map(self, cache) -> np.ndarray:
        """The map ``[6, R, R, 3]`` whose exact integral this estimator converges to as spp
        grows: the chain's level lod_bias (clamped to the coarsest) read at every level-0
        texel as the kernel reads it (nearest texel, linear between two levels)."""
        levels = cache.radiance_mips().host_levels(cache.compute)
        top = len(levels) - 1
        lod = min(self.params.lod_bias, top)
        fine = int(math.floor(lod))
        coarse, share = min(fine + 1, top), lod - fine
        rows = np.arange(cache.res)

        def at_level0(level):
            return levels[level][:, rows[:, None] >> level, rows[None, :] >> level, :3]

        return ((1.0 - share) * at_level0(fine) + share * at_level0(coarse)).astype(np.float32)
