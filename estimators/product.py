"""``product``: per-pixel hierarchical product importance sampling of map × BRDF × cos by descent
through the weight pyramid (after Clarberg et al. 2005 and Clarberg & Akenine-Möller 2008), with
Phong BRDF samples under MIS."""
from __future__ import annotations

import dataclasses
import weakref

import numpy as np

from iblbench.estimators.base import KernelCost, Limit, Mutant, Setting, SweepPart
from iblbench.estimators.envmap import HEURISTICS, MIS_MODES
from iblbench.estimators.hierarchical import Hierarchical
from iblbench.estimators.runtime import mips
from iblbench.scenes import cubemap

CHILD_WEIGHTS = ("bound", "centre", "capped")
MAX_PRODUCT_LEVELS = 4   # the pixel's table (product.cl's light_state_t): about 4 KiB at 4, private


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

    ``product_levels`` (default 1): the choices weighed by the product, from the top: the faces'
    (1: theirs alone), then the children's of the coarsest levels, made once a pixel; the finer
    ones are ``hierarchical``'s, by the light weights alone (1 measured least error and time:
    the class docstring's table).  Where the pyramid has fewer levels
    (⌈log2 R⌉ + 1), every choice is the product's.  At most 4: the pixel's table of choices
    holds 2·4^(T−1) records of 16 bytes and 2·(4^T − 1) probabilities (56 bytes at 1, 1 KiB at 3,
    4 KiB at 4, in each work item's private memory).
    """

    mis: str = "brdf"
    heuristic: str = "power"
    child_weight: str = "capped"
    product_levels: int = 1

    def __post_init__(self):
        if self.mis not in MIS_MODES:
            raise ValueError(f"mis must be one of {', '.join(MIS_MODES)}, got {self.mis!r}")
        if self.heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, got {self.heuristic!r}")
        if self.child_weight not in CHILD_WEIGHTS:
            raise ValueError(f"child_weight must be one of {', '.join(CHILD_WEIGHTS)}, "
                             f"got {self.child_weight!r}")
        if not 1 <= self.product_levels <= MAX_PRODUCT_LEVELS:
            raise ValueError(f"product_levels must be in [1, {MAX_PRODUCT_LEVELS}], got {self.product_levels}")


class Product(Hierarchical):
    """Per-pixel product importance sampling of L·ρ·cos⁺ by descent through the weight pyramid
    (in the spirit of Clarberg, Jarosz, Akenine-Möller & Jensen 2005, "Wavelet importance
    sampling", and Clarberg & Akenine-Möller 2008, "Practical product importance sampling for
    direct illumination"; neither paper is in the papers of ARCHITECTURE.md §Papers, so no
    equation is cited: the method follows issue 24's description, and these notes say where it
    departs from what those papers are known for), with Phong BRDF samples under MIS
    (``envmap``'s budget, heuristics and χ² hooks: envmap.cl's kernels with this light sampler,
    product.cl).

    Target.  L(ω)·F(ω), F = cos⁺(n, ω)·(Y(kd)/π + Y(ks)·(m+2)/(2π)·cos⁺(r, ω)^m), the
    integrand's BRDF·cos in luminance, without V (scenes with visibility keep V in the
    integrand through ``visible()``, as every estimator; the descent does not see it).

    Descent (product.cl, with ``hierarchical``'s choices, descent.cl).  The frame cache's
    ``weight_pyramid`` (Y·Ω sums) and its ``descent_tables``, the only per-frame products.  The
    first T = ``product_levels`` choices are the product's: a face with probability ∝ I_f·F_f,
    then, for T ≥ 2, at each of the T − 1 coarsest levels one of the four children of the node
    picked so far ∝ W_k·F_k (W_k the child's pyramid sum, F_k the child-weight rule's factor for
    this pixel).  They depend on the pixel alone, so each work item makes their widths once, in
    a table of 2·4^(T−1) records in the frame tables' layout (``light_state_of``), and a sample
    reads them as ``hierarchical`` reads the frame's.  Below the
    node so picked (depth T − 1) the choices are ``hierarchical``'s, from the frame's tables,
    down to a texel, and a point uniform in the texel's face square.  Each choice is
    ``hierarchical``'s exact 31-bit fixed-point choice (probability exactly q_k/2^31, every child
    of positive weight ≥ 2^-31).  The texel's probability P = (the table's choices' q/2^31) ×
    P_frame(texel)/P_frame(node), the frame's texel and node probabilities (the product of the
    frame's choices down to them, in float); the table keeps each last-depth node's
    P_table/P_frame, so a sample's P and a direction's (``pdf``, MIS weights) are one read of
    it times the frame's P(texel): the density sampled, to float rounding, so the estimator is
    unbiased (a node whose frame probability underflows gets density 0).  The density is
    P·(1+x²+y²)^{3/2}/a_texel.  Where the pyramid has at most T levels every choice is the
    product's.

    Child-weight rules (F normalised by its maximum, so 0 ≤ F ≤ 1 and a weight never exceeds
    W_k).  A child's cone of directions (``node_cone_table``, geometry of the face size, built
    once on the host in float64): its centre direction, and a half angle θ ≤ √(hx² + hy²)/√(1 +
    d²) (hx, hy its half extents on the face plane, d its least distance from the face centre:
    the gnomonic map shrinks lengths by at least √(1 + |p|²)), with Taylor bounds of cos θ and
    sin θ ≤ θ; faces use their exact cone, θ = acos(1/√3).  ``"bound"``: an upper bound of F
    over the child: cos⁺(n, ·) and cos⁺(r, ·) bounded over the cone separately by cos(max(0, α −
    θ)) (α the centre's angle to n or r), plus a margin 2^-12 above float rounding, so F_k > 0
    wherever F is positive somewhere in the child and no child with light and a positive
    integrand is ever cut (tests/test_product.py checks the bound on 16² points per child).
    ``"centre"``: F at the child's centre direction, floored at 1/16 of the bound (a child whose
    centre is below the horizon or off a lobe while part of it is not stays reachable; 1/64 and
    1/4 measured worse, issue 24).  ``"capped"`` (default): the bound with the lobe's term
    cos_r^m replaced by min(its bound, (2π/(m + 1))/Ω_least): the lobe's integral over the
    sphere, 2π/(m + 1), spread over a lower bound Ω_least of the child's solid angle (its face
    area 4·hx·hy times the Jacobian at its farthest corner; faces 2π/3) bounds the lobe's mean
    over the child, so the factor bounds the child's mean of F (tests/test_product.py checks it
    against the mean on a 512² grid a face).

    Depth (issue 37; 64², env 64, 4 seeds, ΔE76 | relMSE at 64 spp, time per frame in ms of the
    same run on a shared 2-core AVX-512 Xeon; ``iblbench run --scene sphere-sun --scene blob-sun
    --scene sphere-studio --estimator 'hierarchical{mis="brdf"}' --estimator product
    --estimator 'product{product_levels=2}' … --spp 16,64 --seeds 4 --res 64x64 --env-res
    64``).  ± one standard error is 0.01–0.03 in ΔE and 1–3% in relMSE:

    ===============  ===================  ===================  ===================  ===================
    estimator        sphere-sun           blob-sun             sphere-studio        time ms (sun)
    ===============  ===================  ===================  ===================  ===================
    hier.{brdf}      1.719 | 0.00943      1.741 | 0.00975      1.911 | 0.0222       1.55
    T = 1 (default)  1.614 | 0.00783      1.676 | 0.00853      1.403 | 0.0141       1.70
    T = 2            1.698 | 0.00914      1.775 | 0.01004      1.590 | 0.0210       1.93
    T = 3            1.750 | 0.00970      1.810 | 0.01036      1.658 | 0.0233       2.30
    T = 4            1.752 | 0.00967      1.809 | 0.01030      1.674 | 0.0232       3.22
    ===============  ===================  ===================  ===================  ===================

    At 16 spp the order is the same (relMSE T = 1: 0.031 | 0.034 | 0.056 against
    ``hierarchical{mis="brdf"}``'s 0.038 | 0.039 | 0.088).  T = 3 and 4 reproduce the full-depth
    descent that this replaced (issue 24's figures at 16 spp, ΔE76 | relMSE 3.56 | 0.039 on
    sphere-sun and 3.68 | 0.041 on blob-sun, the same to the digits shown; on sphere-studio
    3.21 | 0.087 against T = 3's 3.23 | 0.093), so the product's finer levels add time without error's worth: the coarse
    factors credit a child with the lobe's bound (or, capped, its mean bound) and send samples
    towards the lobe's neighbourhood at the diffuse term's expense, while the faces' factor
    mostly removes the faces below the horizon.  Issue 24's rule comparison (full depth, 16 spp,
    relMSE sphere-sun | blob-sun | sphere-studio): capped 0.039 | 0.041 | 0.087, bound 0.248 |
    0.288 | 0.215, centre 0.200 | 0.218 | 0.197; ``mis = "none"`` raised it 3-4×,
    ``heuristic = "balance"`` lowered it 6-10%.

    Cost (issue 37; sphere-sun, 256², env 64, 64 spp, ``iblbench perf`` on an idle 2-core
    AVX-512 Xeon, 6 rounds alternated with the code before).  The full-depth descent made 24
    child factors a sample (about 100 vector operations each) and took 5.91× [5.70–6.00]
    ``hierarchical{mis="brdf"}``'s time a sample.  A pixel's factors are now made once, in
    vectors of the nodes (the faces in one, the children of POOL_LANES parents four at a
    time), from the tabled cones (two dot products, two cone bounds and the lobe's bound a
    child, no geometry); a node of the last depth keeps P_pixel/P_frame, so a sample's and a
    density's P is one table read times the frame's P(texel), and the choices below it are
    the frame's: 1.08× [0.87–1.29] ``hierarchical{mis="brdf"}``'s time a sample at the default
    T = 1 (22.7 → 123 Msamples/s), 1.62× [1.27–1.82] at T = 3 (docs/measurements.md).

    Deviations.  Clarberg et al. multiply wavelet (Haar) representations of the map and the
    BRDF and sample the product's quadtree; Clarberg & Akenine-Möller 2008 evaluate the BRDF on
    a coarse quadtree per pixel.  Here no BRDF representation is built: a factor per node (a
    bound of the mean, a bound or a centre value) multiplies the map's own pyramid sums, over
    the T coarsest choices only (the default, the faces).  Lobe and diffuse share one factor
    in luminance; kd and ks colours enter only through the estimate.  The lobe's term of
    ``"bound"`` and ``"capped"`` (and of ``"centre"``'s floor) is not the power of the cone's
    cosine bound c but (1 + m(1 − c)/32)^-32, an upper bound of it (c^m ≤ e^{-m(1-c)} ≤ that),
    cheaper than the power: equal to it within (1 + y²/64)-ish where the lobe is large (y =
    m(1 − c) small), looser in its tail (at m = 150, c = 0.95: 1.2e-3 against 4.5e-4), where
    it weighs little beside the diffuse term (relMSE 0.988-1.003× of the power's, issue 37).
    Otherwise as ``hierarchical`` (point on a 2^16 grid in the texel, float density).
    """

    name = "product"
    sweep = SweepPart(("product",), order=12)   # the default levels: about hierarchical's time a sample
    portability_variants = ('product{child_weight="centre",product_levels=4}',
                            'product{mis="none",child_weight="bound"}')
    cost = KernelCost(130, 0, 0, 190, 88, derivation="""\
        at the default product_levels = 1: a light sample is hierarchical's descent by the
        frame's tables (97) after a face picked from the pixel's table, times its node's ratio
        1: about 100; a BRDF sample under MIS (mis="brdf") its draw 66 more and its density by
        the same lookups 5: about 170; half of each, about 130 an evaluation; per pixel the
        faces' factors in one vector (the axes' cosines 10, two cone_cos_bound 20, lobe_bound 8,
        the cap 3, the factor 4), the faces' widths 34, their probabilities and ratios 12, the
        weigher 15 and envmap's 76: about 190 (each further level adds about 220 a POOL_LANES
        parents: four children's factors 45 each from the tabled cones, their widths 30, their
        probabilities 8); bytes as envmap's""",
        lane_loops=((1, 0.5), (1, 0.5)), limits=(   # render_map: light, then BRDF samples (mis="brdf")
            Limit("philox", per_eval=2, group=0, why="descent_word's two blocks"),
            Limit("philox", per_eval=1, group=1, why="draw_numbers' block"),
            Limit("phong_power", per_eval=1, group=0, why="the lobe power"),
            Limit("phong_power", per_eval=2, group=1, why="the draw's ξ^{1/(m+1)} and the lobe power"),
            Limit("divide", per_eval=8, group=0,
                  why="hierarchical's six, the mixture pdf's /π and the power heuristic's "
                      "other/own (mis=\"brdf\")"),
            Limit("divide", per_eval=9, group=1,
                  why="the BRDF draw and its pdf (brdf's 8), the power heuristic's other/own"),
            Limit("divide", per_pixel=15,
                  why="the faces' two cone bounds' √ and lobe_bound's reciprocal 3, their widths' "
                      "1, the weigher's 3, the last depth's ratios 6, the bases about n and r 2"),
            Limit("dependent_load", per_eval=7, group=0, why="hierarchical's chain"),
            Limit("gather", per_eval=16, group=0,
                  why="hierarchical's other loads 15, the node's ratio 1 (the pixel's table)"),
            Limit("gather", per_eval=5, group=1,
                  why="the density: the node's ratio and the texel's probability 2 (known from "
                      "ω: independent), the texel's R, G, B 3")))
    Params = ProductParams
    settings = (Setting("mis", "none"), Setting("heuristic", "balance"),
                Setting("child_weight", "centre"), Setting("child_weight", "bound"), Setting("product_levels", 2))
    kernel_files = ("product.cl", "descent.cl", "envmap.cl", "lanes.cl")
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        # The density reads the table's choices for a given direction: an off-by-one loop bound
        # there leaves out the first level's choice below the faces (the sampler still makes it).
        Mutant("product-pdf-missing-a-level", "product.cl",
               "for (int k = 1; k < choices; ++k) {\n        int l = levels - 1 - k;",
               "for (int k = 2; k < choices; ++k) {\n        int l = levels - 1 - k;",
               estimators=("product{product_levels=3}",), stress=("face-pattern",)),
        # weigh_children stages the four children: a child weighed with a sibling's lobe bound
        # still samples its own density (unbiased, χ² clean); the NumPy descent sees it.
        Mutant("product-children-lobe-bounds-swapped", "product.cl",
               "w[k] *= cone_factor(g, &cone[k], lobe[k]);",
               "w[k] *= cone_factor(g, &cone[k], lobe[3 - k]);",
               tests=("test_product.py::test_texel_probabilities_match_a_numpy_descent[face-pattern-capped-3]",)),
    )

    @property
    def compensated(self) -> bool:
        return False

    def _light_buffers(self, cache) -> tuple[tuple, float]:
        """((the weight pyramid, the node cones, the descent tables' bounds, node and texel
        probabilities), the device ms of the tables' build: the ``sample`` stage's, as
        ``hierarchical``'s; the pyramid is the ``build`` stage's required product, the cones
        geometry uploaded once per face size)."""
        tables = cache.descent_tables(False)
        cones = node_cones(cache.compute, cache.res, self.params.product_levels)
        return ((cache.weight_pyramid(False).buffer, cones, tables.bounds, tables.node_probability,
                 tables.probability), tables.build_ms)

    def defines(self, gbuffer=None) -> dict:
        """envmap.cl's options and product.cl's: the child-weight rule and the product's levels."""
        return {**super().defines(gbuffer), "CHILD_WEIGHT": CHILD_WEIGHTS.index(self.params.child_weight),
                "PRODUCT_LEVELS": self.params.product_levels}


_node_cones: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def node_cones(compute, res: int, product_levels: int):
    """:func:`node_cone_table` on the device, uploaded once per (context, face size, levels)."""
    per_context = _node_cones.setdefault(compute, {})
    if (res, product_levels) not in per_context:
        per_context[res, product_levels] = compute.to_device(node_cone_table(res, product_levels))
    return per_context[res, product_levels]


def _morton_half(m: np.ndarray) -> np.ndarray:
    """The bits of m at even positions, packed (descent_choice.cl's morton_half)."""
    out = np.zeros_like(m)
    for bit in range(16):
        out |= ((m >> (2 * bit)) & 1) << bit
    return out


def node_cone_table(res: int, product_levels: int) -> np.ndarray:
    """The cones of the children that product.cl's table weighs below the faces, float32, per
    depth k = 0 … min(T, L) − 2 of their parents (6·4^k, node Q: face Q >> 2k, Morton index
    Q's low 2k bits) a block of seven components × four children, each a plane of the parents
    padded to a multiple of 16 (the last parent repeated): the child's unit centre direction
    (x, y, z), cos θ's bounds cos_lo = 1 − t²/2 ≤ cos θ ≤ cos_lo + t⁴/24, sin θ ≤ min(t, 1), and
    1/Ω_least, for the half angle θ ≤ t = √(hx² + hy²)/√(1 + d²) (hx, hy its half extents on the
    face plane, d its least distance from the face's centre: the gnomonic map shrinks lengths by
    at least √(1 + |p|²)) and the solid angle Ω ≥ Ω_least = 4·hx·hy·(1 + (|x| + hx)² +
    (|y| + hy)²)^{-3/2}, the Jacobian at its farthest corner.  A child past an odd size's edge
    (weight 0) gets its parent's last texels' cone and 1/Ω_least = 0.  Geometry of the face
    size alone, computed in float64."""
    levels = len(mips.level_sizes(res))
    blocks = []
    for k in range(min(product_levels, levels) - 1):
        span = 2 ** (levels - 2 - k)   # the children's texels a side
        parents = 6 << (2 * k)
        node = np.arange(parents)
        morton = node & ((1 << (2 * k)) - 1)
        face, parent_row, parent_col = node >> (2 * k), _morton_half(morton >> 1), _morton_half(morton)
        planes = np.empty((7, 4, parents))
        for c in range(4):
            y0, x0 = (2 * parent_row + (c >> 1)) * span, (2 * parent_col + (c & 1)) * span
            exists = (y0 < res) & (x0 < res)
            y0, x0 = np.minimum(y0, res - 1), np.minimum(x0, res - 1)
            y1, x1 = np.minimum(y0 + span, res), np.minimum(x0 + span, res)
            x, y = (x0 + x1) / res - 1, (y0 + y1) / res - 1
            hx, hy = (x1 - x0) / res, (y1 - y0) / res
            dx, dy = np.maximum(np.abs(x) - hx, 0), np.maximum(np.abs(y) - hy, 0)
            t = np.sqrt(hx ** 2 + hy ** 2) / np.sqrt(1 + dx ** 2 + dy ** 2)
            least_omega = 4 * hx * hy / (1 + (np.abs(x) + hx) ** 2 + (np.abs(y) + hy) ** 2) ** 1.5
            planes[:3, c] = cubemap.face_st_to_direction(face, (x + 1) / 2, (y + 1) / 2).T
            planes[3, c] = 1 - t ** 2 / 2
            planes[4, c] = 1 - t ** 2 / 2 + t ** 4 / 24
            planes[5, c] = np.minimum(t, 1)
            planes[6, c] = np.where(exists, 1 / least_omega, 0)
        padded = -(-parents // 16) * 16
        blocks.append(np.pad(planes, ((0, 0), (0, 0), (0, padded - parents)), mode="edge").ravel())
    return np.concatenate(blocks).astype(np.float32) if blocks else np.zeros(1, np.float32)
