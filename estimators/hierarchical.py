"""``hierarchical``: light sampling by descent through a mip pyramid of each face's sampling
weights (Falcor's EnvMapSampler, Mitsuba 3's Hierarchical2D), with optional MIS with Phong BRDF
samples and MIS compensation, as ``envmap``."""
from __future__ import annotations

import numpy as np

from iblbench.estimators.base import KernelCost, Limit, Mutant, SweepPart
from iblbench.estimators.envmap import Envmap


class Hierarchical(Envmap):
    """Light sampling by sample-by-descent through each face's pyramid of Y·Ω sums (Falcor
    ``EnvMapSampler``, Source/Falcor/Rendering/Lights/EnvMapSampler.slang and its setup pass;
    Mitsuba 3 ``Hierarchical2D``, include/mitsuba/core/distr_2d.h), optionally with Phong BRDF
    samples under MIS (``envmap``'s budget, heuristics and compensation: its parameters and
    kernels, with this light sampler).

    Distribution.  The frame cache's ``weight_pyramid`` (estimators/runtime/mips.py): level 0 holds each
    texel's weight Y·Ω (Y its luminance, Ω its exact solid angle, so p(ω) ∝ Y(ω) as ``envmap``'s),
    each coarser level the sums of 2×2 children, the 1×1 level each face's total I_f.  A sample
    picks a face with probability ∝ I_f, then at every level one of the four children of the
    texel picked so far in proportion to their sums, down to a texel, and a point uniform in the
    texel's face square; its density is P(texel)·(1+x²+y²)^{3/2}/a_texel (ARCHITECTURE.md §Conventions), P(texel)
    the product of the choices' probabilities (to float rounding: the product of the choices'
    q/2^31 is formed in float, ~1e-6 relative).  Since every choice depends on the sums alone,
    the frame cache computes each choice's widths once per frame (``FrameCache.descent_tables``,
    the layout in descent.cl's header): a sample compares its level's word with three bounds a
    level, records indexed as a 4-ary heap (child c of record r is 4r + c), and the density
    (MIS weights, χ² hook) reads the texel's P from the same tables, the product formed in the
    sampler's order, so it is the density sampled, bit for bit.  Per frame the sampler needs
    only the pyramid and its tables: one pass of weights and log2 R reductions, the tables'
    widths and probabilities, no prefix scan (it does not require the ``cdf`` product).

    Speed (issue 37).  The widths were computed per sample from the sums (four gathers, a
    division and the clamps a level, as Mitsuba 3 rescales its sample per level); from the
    tables the render is the same image, bit for bit, at about 1.6× the speed (sphere-sun, 256²,
    env 64, 64 spp, 16 lanes): the level's three bounds are three gathers with no division,
    and its index one shift and add, where the sums' index took two integer multiplications.

    Exactness beside a 1e6:1 sun (descent.cl's header).  Each choice is made in 31-bit fixed
    point: child k gets an integer width q_k = max(1, ⌊2^31·w_k/Σw⌋) for w_k > 0 (0 for w_k = 0),
    the remainder to the largest child, and a fresh Philox word per level (its top 31 bits)
    picks the bin that holds it.  A child's probability is exactly q_k/2^31, and a child of
    positive weight has at least 2^-31 ≈ 4.7e-10 per choice, so every lit texel is reachable;
    floating-point thresholds on one reused uniform (Falcor's and Mitsuba's rescaled sample)
    resolve 2^-24 at best.

    Budget, MIS and compensation: ``envmap``'s (its docstring; the kernels are envmap.cl's with
    this light sampler compiled in).  ``mis_compensation`` builds the pyramid from pbrt-v4's
    max(Y − Ȳ, min(Ȳ/1000, Y))·Ω, with Ȳ from the plain pyramid's face totals
    (``FrameCache.weight_pyramid``), only with MIS.

    Deviations.  From Falcor: the pyramid is built per cube face over the map's own texels (no
    resampling into an octahedral importance map of fixed size, so its texels and the map's
    coincide and the density is exact per texel rather than the importance map's value at a
    point); the six faces are chosen first by their totals; each choice among the four children
    is one 4-way choice with a fresh random word (Falcor picks a column and then a row
    with one 2-D sample rescaled at every level; Mitsuba 3 a row then a column, likewise).  From
    Mitsuba 3: piecewise-constant texels (ARCHITECTURE.md §Conventions's nearest lookup) instead of its bilinear
    patches.  The point in the texel is the centre of a cell of a 2^16 × 2^16 grid over it (one
    32-bit word for both coordinates; ``envmap`` has 63-bit variates): the cosine and the BRDF
    are integrated over the texel by that grid's midpoint rule instead of exactly, an error of
    order 2^-32 of the texel's variation.  A face size that is not a power of two has levels of
    ⌈n/2⌉, whose last parents have fewer children (the missing ones weigh 0, as Mitsuba's zero
    padding).  The density is a float product of up to ⌈log2 R⌉ + 1 factors: a texel whose
    probability is below float's smallest normal (≈ 1e-38 of the map's total weight) would get
    density 0 and weight 0.
    """

    name = "hierarchical"
    sweep = SweepPart(("hierarchical",), order=9)
    cost = KernelCost(97, 0, 0, 76, 88, derivation="""\
        the default, light samples only: a light sample by descent through the descent tables
        (six levels below the faces at the default env 64): per level three bounds compared
        with the level's word (integer work, not counted), the texel's probability read; the
        point in the texel 12 (a grid cell's centre, 6 per coordinate), its pdf 8, the face
        direction normalised 12, lobe power 41, n·ω 5, D 1, add_samples 18; per pixel envmap's
        76 (the choices' widths are the tables', built once per frame)""",
        lane_loops=((1, 1.0),), limits=(   # descent.cl's descent_sample in render_map's light loop
            Limit("philox", per_eval=2, why="descent_word: 8 words (face, 6 levels, point)"),
            Limit("dependent_load", per_eval=7,
                  why="a level's first bound at the record picked above, 6 levels, then the "
                      "texel's probability and radiance"),
            Limit("gather", per_eval=15, why="the other two bounds of each level 12, the "
                                             "texel's probability 1 and other two channels 2"),
            Limit("phong_power", per_eval=1, why="the lobe power"),
            Limit("divide", per_eval=6,
                  why="x and y / res 2, √area 1, lanes_face_direction 2, add_samples 1")))
    requires = ("weight_pyramid",)
    kernel_files = ("hierarchical.cl", "descent.cl", "envmap.cl", "lanes.cl")
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        Mutant("hierarchical-light-jacobian-inverted", "descent.cl",
               "*pdf = probability * area * sqrt(area) * (float)(res * res) / 4.0f;",
               "*pdf = probability / (area * sqrt(area)) * (float)(res * res) / 4.0f;",
               stress=("sun-1e6",)),
        Mutant("hierarchical-density-quad-transposed", "runtime/framecache.cl",
               "probability[at[i] + (c >> 1) * res + (c & 1)]",
               "probability[at[i] + (c & 1) * res + (c >> 1)]",
               estimators=('hierarchical{mis="brdf"}',), stress=("face-pattern",)),
    )

    def _light_buffers(self, cache) -> tuple[tuple, float]:
        """((the descent tables' bounds, its texel probabilities), the device ms of this
        render's ``sample`` stage: the tables' build, and the compensated pyramid's, drawn on
        first use; the plain pyramid is the ``build`` stage's required product)."""
        tables = cache.descent_tables(self.compensated)
        pyramid_ms = cache.weight_pyramid(True).build_ms if self.compensated else 0.0
        return (tables.bounds, tables.probability), tables.build_ms + pyramid_ms

    def _map_is_black(self, cache) -> bool:
        """Whether every face total (the pyramid's 1×1 level) is 0."""
        return not np.any(cache.weight_pyramid(False).face_totals(cache.compute) > 0)
