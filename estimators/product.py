"""``product``: per-pixel hierarchical product importance sampling of map × BRDF × cos by descent
through the weight pyramid (after Clarberg et al. 2005 and Clarberg & Akenine-Möller 2008), with
Phong BRDF samples under MIS."""
from __future__ import annotations

import dataclasses

from iblbench.estimators.base import KernelCost, Limit, Mutant, Setting, SweepPart
from iblbench.estimators.envmap import HEURISTICS, MIS_MODES
from iblbench.estimators.hierarchical import Hierarchical

CHILD_WEIGHTS = ("bound", "centre", "capped")


@dataclasses.dataclass(frozen=True)
class ProductParams:
    """``mis`` (default ``"brdf"``): half the budget to Phong BRDF samples, combined with the
    product samples by MIS, so that a lobe sharper than the levels the product resolves is still
    covered; ``"none"``: product samples only.

    ``heuristic`` (default ``"power"``): the MIS weights, ``"balance"`` or ``"power"``, as
    ``envmap``'s; unused without MIS.

    ``child_weight`` (default ``"capped"``): a child's BRDF·cos factor, ``"capped"`` (an upper
    bound of its mean over the child: ``"bound"`` with the lobe's term at most the lobe's
    integral over the child's solid angle), ``"bound"`` (an upper bound over the child's
    directions) or ``"centre"`` (its value at the child's centre direction, floored at 1/16 of
    the bound).

    ``light_levels`` (default 0): the choices among the children of the ``light_levels`` finest
    pyramid levels (1: the texels; 0: none) are made by the light weights alone, as
    ``hierarchical``'s; the coarser ones (and the faces, unless ``light_levels`` passes the
    pyramid's top) by the product.  At or beyond the pyramid's levels (⌈log2 R⌉ + 1) every choice
    is ``hierarchical``'s.
    """

    mis: str = "brdf"
    heuristic: str = "power"
    child_weight: str = "capped"
    light_levels: int = 0

    def __post_init__(self):
        if self.mis not in MIS_MODES:
            raise ValueError(f"mis must be one of {', '.join(MIS_MODES)}, got {self.mis!r}")
        if self.heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, got {self.heuristic!r}")
        if self.child_weight not in CHILD_WEIGHTS:
            raise ValueError(f"child_weight must be one of {', '.join(CHILD_WEIGHTS)}, "
                             f"got {self.child_weight!r}")
        if not 0 <= self.light_levels <= 32:
            raise ValueError(f"light_levels must be in [0, 32], got {self.light_levels}")


class Product(Hierarchical):
    """Per-pixel product importance sampling of L·ρ·cos⁺ by descent through the weight pyramid
    (in the spirit of Clarberg, Jarosz, Akenine-Möller & Jensen 2005, "Wavelet importance
    sampling", and Clarberg & Akenine-Möller 2008, "Practical product importance sampling for
    direct illumination"; neither paper is in the papers of ARCHITECTURE.md §Papers, so no equation is cited: the
    method follows issue 24's description, and these notes say where it departs from what those
    papers are known for), with Phong BRDF samples under MIS (``envmap``'s budget, heuristics
    and χ² hooks: envmap.cl's kernels with this light sampler, product.cl).

    Target.  L(ω)·F(ω), F = cos⁺(n, ω)·(Y(kd)/π + Y(ks)·(m+2)/(2π)·cos⁺(r, ω)^m), the
    integrand's BRDF·cos in luminance, without V (scenes with visibility keep V in the
    integrand through ``visible()``, as every estimator; the descent does not see it).

    Descent (weighed_descent.cl, with ``hierarchical``'s choices, descent.cl).  The frame cache's ``weight_pyramid``
    (Y·Ω sums, the only per-frame product).  A sample picks a face with probability ∝
    I_f·F_f, then at every level one of the four children of the node picked so far ∝
    W_k·F_k (W_k the child's pyramid sum, F_k the child-weight rule's factor for this pixel),
    down to a texel, and a point uniform in the texel's face square.  Each choice is
    ``hierarchical``'s exact 31-bit fixed-point choice, so its probability is exactly q_k/2^31
    and every child of positive weight keeps ≥ 2^-31.  The density is P(texel)·(1+x²+y²)^{3/2}
    /a_texel, P the product of the choices' probabilities, recomputed for any direction by the
    same descent with the same factors (``pdf``, MIS weights): exact to float rounding, so the
    estimator is unbiased.  Depth: by default every choice (faces, every level down to the
    texels) weighs by the product; ``light_levels = L`` makes the choices among the children
    of the L finest levels by W_k alone.

    Child-weight rules (F normalised by its maximum, so 0 ≤ F ≤ 1 and a weight never exceeds
    W_k).  ``"bound"``: an upper bound of F over the child.  The child's directions
    lie in a cone about its centre direction of half angle θ ≤ √(hx² + hy²)/√(1 + d²) (hx, hy
    its half extents on the face plane, d its least distance from the face centre: the
    gnomonic map shrinks lengths by at least √(1 + |p|²)); faces use their exact cone,
    θ = acos(1/√3).  cos⁺(n, ·) and cos⁺(r, ·) are bounded over the cone separately by
    cos(max(0, α − θ)) (α the centre's angle to n or r), with Taylor bounds of cos θ and
    sin θ ≤ θ instead of trigonometry, plus a margin 2^-12 above float rounding.  F_k > 0
    wherever F is positive somewhere in the child, so no child with light and a positive
    integrand is ever cut (tests/test_product.py checks the bound on 16² points per child).
    ``"centre"``: F at the child's centre direction, floored at 1/16 of the bound, so a child
    whose centre is below the horizon (or off a lobe) while part of it is not stays reachable;
    the floor 1/16 was measured against 1/64 (without MIS its heavy tail failed the 8→128 spp
    convergence check, ratio 2.3) and 1/4 (more error).  ``"capped"`` (default): the bound with
    the lobe's term cos_r^m replaced by min(its bound, (2π/(m + 1))/Ω_least): the lobe's
    integral over the whole sphere, 2π/(m + 1), is at least its integral over the child, so
    spread over the child's solid angle it bounds the lobe's *mean* there, and the factor,
    bound(cos_n)·(d + s·min(·)), is an upper bound of the child's mean of F (the issue's "BRDF's
    integral over the child", without a table: one division per child).  Ω_least is a lower
    bound of the child's solid angle: its face area 4·hx·hy times the gnomonic Jacobian
    (1 + x² + y²)^{-3/2} at its farthest corner (faces: 2π/3 exactly).  It is positive wherever
    the bound is, so it cuts no child the bound keeps; it tightens only children much larger
    than the lobe (with m = 150 at env 64: the faces and the two or three coarsest levels),
    which the bound credited with the lobe's peak (tests/test_product.py checks it against
    the mean on a 512² grid a face, with a purely specular m = 150 where the cap is tight).

    Measured (issue 24; 64×64, env_res 64, 4 seeds, PoCL on 2 shared cores; ΔE76 | relMSE |
    device ms per frame, median of 5 repeats; ``iblbench run --config cw.toml --repeats 5``,
    the config: these scenes and estimators, ``spp = [16, 64]``, ``seeds = 4``,
    ``resolution = "64x64"``, ``env_res = 64``, ``metrics = ["de76", "relmse"]``):

    ===============  ===============  ==================  ==================  ===================  ===================
    scene, 16 spp    balanced_mis     hierarchical{brdf}  product (capped)    product{bound}       product{centre}
    ===============  ===============  ==================  ==================  ===================  ===================
    sphere-sun       2.10|0.013|0.6   3.50|0.038|0.9      3.56|0.039|2.4      7.94|0.248|3.3       6.61|0.200|5.0
    blob-sun         2.18|0.015|0.6   3.55|0.039|1.6      3.68|0.041|4.6      8.66|0.288|4.4       7.16|0.218|5.3
    sphere-studio    2.31|0.038|0.6   3.99|0.089|1.6      3.21|0.087|4.6      4.95|0.215|4.5       3.51|0.197|5.0
    ===============  ===============  ==================  ==================  ===================  ===================

    At 64 spp the same (relMSE, sphere-sun | blob-sun | sphere-studio): balanced_mis 0.0030 |
    0.0036 | 0.011, hierarchical{brdf} 0.0094 | 0.0097 | 0.022, capped 0.0097 | 0.0102 |
    0.023, bound 0.059 | 0.071 | 0.057, centre 0.048 | 0.052 | 0.052.  So ``"capped"`` cuts
    the bound's relMSE 2.5-7× and ties ``hierarchical{mis="brdf"}`` at equal spp (within 6%;
    ΔE76 14-20% lower on sphere-studio), at the bound's cost (time within the runs' noise), still
    2.5-3× hierarchical's time; ``balanced_mis`` keeps 2-3× less relMSE at equal spp.  Why the
    bound and the centre lost: for a lobe of solid angle ~2π/(m+1) ≈ 0.04 sr, both misjudge a
    coarse child's share of ∫ W·F (the bound credits the whole child with the lobe's peak, the
    centre value misses a lobe off-centre), so the coarse choices send most samples to the
    lobe's neighbourhood and starve the diffuse term, which holds most of the integral.  With
    ``"capped"`` (16 spp): ``light_levels = 3`` changes relMSE by +0.5% to +6%;
    ``heuristic = "balance"`` lowers it 6-10% (0.036 | 0.037 | 0.082); ``mis = "none"`` raises
    it 3-4× (0.16 | 0.17 | 0.25).  On the conformance fixture (m = 20, 16² pixels, 16 spp, 20
    seeds) the bound beat ``hierarchical`` with MIS: relative RMS error 0.135 vs 0.214 on a 1e3
    sun and 0.142 vs 0.153 on face_pattern_map (not re-measured with ``"capped"``).

    Cost (issue 37; sphere-sun, env 64, 64 spp, PoCL 3.1 on a 2-core AVX-512 Xeon shared with
    other jobs, one PoCL thread, process CPU time per render, so that the load cancels; ratios
    measured in one run).  About 3.4× ``hierarchical{mis="brdf"}``'s time a sample at 256²
    (88 against 26 ns).  A sample makes one product descent (a light sample's draw, or a BRDF
    sample's density for MIS): 24 child factors (four a level, six levels below the faces; the
    faces' are the same for the whole pixel and the compiler hoists them out of the sample loop),
    each about 130 vector operations.  At 128², before the children were staged (below), with
    ``hierarchical{mis="brdf"}`` = 1: the whole 3.6; without the lobe's power 2.9; the children's
    geometry and centre cosines alone (no cone bound, power or cap) 2.3; no product level at all
    (``light_levels`` past the top) 1.07.  So the time is the factors' arithmetic, spread
    over the geometry (three reciprocal square roots and a square root a child), the two cone
    bounds and the power, and the kernel is bound by the count of vector operations, not by the
    divider or memory: square roots and divisions by Newton steps from a bit-level guess, and
    the geometry read from a table (three gathers a child), each saved under 10% or nothing.
    weigh_children runs the four children stage by stage (cones, the halves of the powers,
    factors: same bits): 3.82× to 3.43× at 256² (product's own time 10% less).  Measured and
    not taken: the top two levels' widths once per pixel instead of once per 16 samples,
    bit-identical, 7% less (it needs a per-pixel light-sampler state in envmap.cl's render
    loop); ``light_levels = 3`` 2.4× (issue 24: +0.5% to +6% relMSE).  Within 1.5× of
    ``hierarchical`` would need a factor about six times cheaper than this bound, or fewer of
    them (issue 37).  Since then (same machine and settings, shading time of alternated renders
    in one process): the lobe's bound cos_r^m of the bound cosine c replaced by
    (1 + m(1 − c)/32)^-32 (Deviations): the power made the kernel 1.10× slower [0.92–1.28, 10
    pairs], so product takes about 0.9× its time.  Measured and not taken: the children's cone
    half angle and least solid angle from their parent (looser bounds, one square root and two
    reciprocal ones a level instead of four), 0.79× product's time [0.73–0.87] on top of that
    (0.97× with the exact power); at test_product's fixed χ² seeds one pixel read p = 9e-4 (16
    other seeds per pixel: p uniform, 0.09–0.99), which needs a decision before the streams move
    again.  ``hierarchical{mis="brdf"}`` itself became about 2× faster (its choices read from the
    frame cache's descent tables, its density one lookup instead of a re-descent), so product
    now takes about 5.9× its time a sample (idle ``iblbench perf``, 7 rounds alternated with
    the code before: 4.02× [3.80–4.11] before, 5.93× [5.71–6.19] after): the weighed descent's 24 child factors a sample, each still about
    100 vector operations, against ``hierarchical``'s three gathers a level.  Within 1.5× needs
    product levels that are not recomputed a sample, or far fewer of them: a per-pixel table of
    the coarse levels' widths pays little at 64 spp (a pixel's light draws are two batches of
    16, as are its BRDF draws' densities: the 6 face records' 24 children cost 4 batch-wide
    factor evaluations to save 8 of a strategy's 48, the next level's 96 cost 8 to save 8), and
    ``light_levels = 9`` (no product level, the sums' widths computed a sample) is 1.9×
    ``hierarchical{mis="brdf"}`` and ``light_levels = 6`` (the faces alone) 1.8×.

    Deviations.  Clarberg et al. multiply wavelet (Haar) representations of the map and the
    BRDF and sample the product's quadtree; Clarberg & Akenine-Möller 2008 evaluate the BRDF on
    a coarse quadtree per pixel.  Here no BRDF representation is built: a factor per node
    (a bound of the mean, a bound or a centre value) multiplies the map's own pyramid sums, so
    the coarse levels see the BRDF's integral over the node only through ``"capped"``'s bound
    of it (the bound's and the centre's losses above).  Lobe and diffuse
    share one factor in luminance; kd and ks colours enter only through the estimate.  The
    lobe's term of ``"bound"`` and ``"capped"`` (and of ``"centre"``'s floor) is not the power
    of the cone's cosine bound c but (1 + m(1 − c)/32)^-32, an upper bound of it (c^m ≤
    e^{-m(1-c)} ≤ that), because the power was about a quarter of the kernel's time: equal to it
    within (1 + y²/64)-ish where the lobe is large (y = m(1 − c) small), looser in its tail
    (at m = 150, c = 0.95: 1.2e-3 against 4.5e-4), where it weighs little beside the diffuse
    term; every factor stays positive wherever F is, so the estimator stays unbiased.  Its
    error is the power's (about 10% of product's time): relMSE 0.988-1.003× of it on sphere-sun, blob-sun and sphere-studio
    at 16 and 64 spp (64², env 64, 4 seeds, ``iblbench run --scene … --estimator product --spp
    16,64 --seeds 4 --res 64x64 --env-res 64``, issue 37).
    Otherwise as ``hierarchical`` (point on a 2^16 grid in the texel, float density of up to
    ⌈log2 R⌉ + 1 factors).
    """

    name = "product"
    sweep = SweepPart(("product",), spp=(4, 16, 64, 256), order=12)
    portability_variants = ('product{child_weight="centre",light_levels=1}',
                            'product{mis="none",child_weight="bound"}')
    cost = KernelCost(1500, 0, 0, 142, 88, derivation="""\
        hierarchical's descent with each choice's children weighed by the pixel's BRDF·cos bound
        over the child's cone (product.cl's weigher: per child its centre and extents 12, the
        two cosines 10, the cone's bounds 12, two cone_cos_bound 20, the factor 10, about 64),
        four children a level over six levels and the six faces: about 1,150 a light sample
        (hierarchical's 182 + 6 × 4 × 36 + 6 × 20 beyond), and the default "capped" rule's least
        solid angle and cap, 15 a child (the farthest corner 6, its Jacobian 5, the area 2, the
        division and min 2), 360 more: about 1,500; as much for a BRDF sample's density under
        MIS (its draw 107 less the light draw's 41); per pixel the weigher's frame 30 and the
        lobe's integral 2, envmap's 76, the faces' widths 34; bytes as envmap's""",
        lane_loops=((1, 0.5), (1, 0.5)), limits=(   # render_map: light, then BRDF samples (mis="brdf")
            Limit("philox", per_eval=2, group=0, why="descent_word's two blocks"),
            Limit("philox", per_eval=1, group=1, why="draw_numbers' block"),
            *(Limit("phong_power", per_eval=1, group=group,
                    why="the sample's lobe power (light and BRDF samples alike: a BRDF sample's "
                        "density descends again); the children's and faces' lobe bounds are "
                        "lobe_bound's reciprocal and five squarings") for group in (0, 1)),
            *(Limit("divide", per_eval=304, group=group,
                    why="a child: child_cone's three rsqrt (√ and 1/) and √ 7, cone_r_bound's "
                        "√ 1, cone_factor's √ and its cap's quotient 2, lobe_bound's reciprocal "
                        "1: 44 a level, 264; the faces' 24; the widths' 7; about 9 more for the "
                        "sample (as envmap's or brdf's)") for group in (0, 1)),
            Limit("dependent_load", per_eval=7, group=0, why="hierarchical's chain"),
            Limit("gather", per_eval=20, group=0, why="hierarchical's other loads"),
            Limit("gather", per_eval=27, group=1,
                  why="descent_density: four children a level at the texel's ancestors 24 "
                      "(known from ω: independent), the texel's R, G, B 3")))
    Params = ProductParams
    settings = (Setting("mis", "none"), Setting("heuristic", "balance"),
                Setting("child_weight", "centre"), Setting("child_weight", "bound"), Setting("light_levels", 2))
    kernel_files = ("product.cl", "weighed_descent.cl", "descent.cl", "envmap.cl", "lanes.cl")
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        # The density recomputes the descent for a given direction: an off-by-one loop bound there
        # leaves out the texel level's choice (the sampler still makes it).
        Mutant("product-pdf-missing-a-level", "weighed_descent.cl",
               "for (int l = levels - 2; l >= 0; --l) {\n        int n = level_size(res, l);\n"
               "        offset -= 6 * n * n;\n        lane_uints_t q[4];\n        lane_ints_t child_row",
               "for (int l = levels - 2; l > 0; --l) {\n        int n = level_size(res, l);\n"
               "        offset -= 6 * n * n;\n        lane_uints_t q[4];\n        lane_ints_t child_row",
               stress=("face-pattern",)),
        # weigh_children stages the four children: a child weighed with a sibling's lobe bound
        # still samples its own density (unbiased, χ² clean); the NumPy descent sees it.
        Mutant("product-children-lobe-bounds-swapped", "product.cl",
               "w[k] *= cone_factor(g, &cone[k], lobe[k]);",
               "w[k] *= cone_factor(g, &cone[k], lobe[3 - k]);",
               tests=("test_product.py::test_texel_probabilities_match_a_numpy_descent[face-pattern-capped-0]",)),
    )

    @property
    def compensated(self) -> bool:
        return False

    def _light_buffers(self, cache) -> tuple[tuple, float]:
        """((the weight pyramid,), 0: its build is the ``build`` stage's required product)."""
        return (cache.weight_pyramid(False).buffer,), 0.0

    def defines(self, gbuffer=None) -> dict:
        """envmap.cl's options and product.cl's: the child-weight rule and the light-only levels."""
        return {**super().defines(gbuffer), "CHILD_WEIGHT": CHILD_WEIGHTS.index(self.params.child_weight),
                "LIGHT_LEVELS": self.params.light_levels}
