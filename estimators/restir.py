"""``restir``: reservoir-based spatiotemporal importance resampling of the environment map
(Bitterli et al. 2020, "Spatiotemporal reservoir resampling for real-time ray tracing with
dynamic direct lighting"), with the generalised RIS weights of Lin et al. 2022 ("Generalized
resampled importance sampling", GRIS) that keep reuse unbiased when the integrand changes
between frames, and RTXDI's environment presampling.  Kernels ``restir.cl``.

The target of a pixel at frame t is p̂_t = L_Y·ρ_Y·cos⁺·V (luminance of the map's radiance
times luminance of the Phong BRDF times the cosine, times the pixel's visibility where the
scene has masks: sir.cl's γ with V).  Each of the pixel's ``spp`` *chains* is one reservoir
carried from frame to frame and shaded once; the chains are independent given the frame's
presamples (their own random streams, and spatial reuse within a chain; they share the
presamples, and two chains pick the same tile with probability 1/``tiles``), so the frame's
estimate, their mean, has about 1/spp of one chain's variance.  Per frame and chain:

1. **Presampling** (RTXDI's environment presampling): ``tiles`` tiles of ``tile_size`` light
   directions per frame, drawn by descent through the frame's luminance pyramid (the frame
   cache's ``weight_pyramid``, the one ``hierarchical`` builds and samples: descent.cl's exact
   fixed-point descent), each stored with its density p_L.  Only the pyramid, the
   presamples and the pixels' target scales (step 3) are rebuilt per frame.
2. **Initial RIS** (Talbot 2005; Bitterli Alg. 3): M = ``candidates`` candidates,
   M_B = round(``brdf_share``·M) from the Phong mixture and M_L = M − M_B read uniformly from one
   tile (the chain's, drawn each frame), each of weight m_s·p̂/p_s with p_s its own strategy's
   exact density and m_s the balance heuristic over the two strategies,
   m_s = p̃_s/(M_L p̃_L + M_B p_B), whose light density p̃_L is the texel's share of the pyramid's
   total times the point's Jacobian (the descent's density but for its fixed-point rounding: one
   load, where the exact density re-descends the pyramid, which made pass 1 4× slower; the m_s
   are a partition of unity whatever p̃_L is); one is kept with probability ∝ its weight;
   W = Σ w / p̂(kept), confidence c = M.  A candidate read from a tile has marginal density p_L
   (every presample is a draw of p_L), which is all RIS needs for E[f(Y)·W] = ∫f, although
   candidates of one tile may repeat a presample (RTXDI's argument).
3. **Temporal reuse** (``temporal``): the chain's reservoir of frame t−1's step 3 (ω', W', c'), c'
   capped at ``history_cap``·M (RTXDI's M-cap; default 1, see "Choices"), is combined with the
   initial one.  The geometry is static, so the previous pixel is the pixel itself, and a
   direction to the map needs no shift (identity, Jacobian 1).
   - unbiased: GRIS's resampling weights w_i = m_i(ω_i)·p̂_t(ω_i)·W_i, W = Σ w / p̂_t(kept),
     with the generalised balance heuristic with confidence weights:
     m_i(ω) = c_i s_i p̂_i(ω) / Σ_j c_j s_j p̂_j(ω), p̂_1 = p̂_t and p̂_2 = p̂_{t−1} (the pixel's
     target under *last* frame's map, kept on the device).  The m_i sum to 1
     wherever p̂_t > 0 and m_2 = 0 wherever p̂_{t−1} = 0, so light that appears is found by the
     fresh candidates with full weight and light that vanishes gives the old sample weight 0.
     Two deterministic choices (any positive constants that do not depend on the samples keep
     Σ m_i = 1, hence unbiasedness):
     - s_i = 1/Z̃_i, Z̃ a stand-in for the normaliser ∫p̂ of the pixel under that frame's map
       (``restir_target_scales``: over the pyramid's level of at most 2 × 2 cells a face, Σ the
       cell's Y·Ω times ρ_Y·cos⁺ at its centre, without V), so that m_i weighs the inputs' sample
       densities p̂_i/∫p̂_i, not targets whose scales differ 100× across a switch.  8 × 8 cells
       (every texel of the test's 8² map) gave no better z on sphere-switch (frames 17-23, 1000
       seeds: pixel |z| ≤ 4.1 at 8², ≤ 3.9 at 4², ≤ 4.4 at 2²; the Šidák bound is 4.9) at 16× the
       cost, which at one chain was most of a frame's.  With s_i = 1 the history kept 20/21 of
       the responsibility for the sky after a light went off while it
       sampled the sky 0.6% of the time: sphere-switch's frame 20 was 8× too dark at some pixels
       over 400 seeds (heavy tails; unbiased in expectation);
     - the history's c' is scaled by min(Z̃_t/Z̃_{t−1}, Z̃_{t−1}/Z̃_t): a map that lost or gained
       most of the pixel's light leaves the history few samples where the light now is.  Scaled
       only where the map lost light, frames 20-23 of sphere-switch (light off) had pixel |z| of
       8 at 1000 seeds without it and ≤ 3.0 with it; and where the light came on (frames 10-16)
       a pixel that sees it at grazing (n·ω = 0.04, whose coarse cell's centre is well above the
       horizon, so Z̃ overrates its light) kept 7% too little of it (|z| 6-7, light candidates
       only, at cap 20), since the history (c' = 160 against M = 8) held 6% of the
       responsibility for the light it never sampled; scaled both ways, ≤ 3.7.  With
       ``sphere-switch``'s 30 frames at 2000 seeds, the largest pixel |z| is 0.70 of the Šidák
       bound (tests/test_restir.py).
     Cost: p̂_t at ω' and p̂_{t−1} at ω (2 evaluations; p̂_{t−1}(ω') is stored).
   Both modes reuse the history so: the temporal inputs share the pixel's V, and GRIS's weights
   are what makes a map that changes safe.
4. **Spatial reuse** (``neighbours`` k): k pixels uniform in a disc of ``radius`` pixels about the
   pixel (clamped to the image), kept if covered, not the pixel, and passing RTXDI's tests
   (normals within acos 0.5, depths within 10%; depth is the distance to the eye, found by least
   squares as the point nearest every pixel's view ray), each with its chain's reservoir of step
   3; combined as step 3 with p̂_j the target of neighbour j at frame t (its own normal, BRDF and
   visibility) and s_j its Z̃: (k+1)·k evaluations.  The result is shaded; the chain's history
   for frame t+1 is its step-3 reservoir (see "Choices").
   - biased (``unbiased = False``): Bitterli Alg. 6's 1/Z combination with Z counted without
     visibility: w_i = p̂_t(ω_i)·W_i·c_i, W = Σ w / (p̂_t(kept)·Z), Z = Σ c_j over the inputs
     whose target *without V* is positive at the kept sample (the cheap test: Bitterli §4.3
     notes that the exact Z needs a shadow ray per neighbour; here k² of the (k+1)·k
     evaluations skip V).  Unbiased wherever the neighbours' visibility agrees (no masks, or no
     shadow boundary among them); dark beside shadows, where a shadowed neighbour that cannot
     produce the sample is counted (tests/test_restir.py).
5. **Shading**: f(ω)·W with f = L·ρ·cos⁺·V (RGB; V = 1 wherever p̂_t > 0): one sample a chain.

Speed.  Pass 1 runs a chain's M candidates POOL_LANES at a time in explicit lanes; pass 2 runs
POOL_LANES chains of a pixel at a time, a chain a lane (its neighbours, the (k+1)·k targets, the
combination and the shading), and a chain left alone (one after whole blocks) in scalars, where
a block of lanes would cost more; at spp 1 it is built without the lanes.  Each lane does the one-chain arithmetic and the
chains are summed in order, so the images are those of one chain at a time, bit for bit.  PoCL
runs neither kernel's work items as SIMD lanes (``POCL_VECTORIZER_REMARKS=1``: no work-item loop
of either vectorised), so the explicit lanes are what makes them SIMD.

Budget.  ``spp`` = chains, each shading one sample (``used`` = spp; ``effective``: the chains
whose kept sample has a positive cosine).  ``evaluations`` (per pixel, mean) counts every
evaluation of p̂, its support test or f: spp·(M + 2 (temporal) + (k+1)k (spatial) + 1);
``shadow_rays`` those with V (the biased mode's neighbour targets have none).  Extras:
``neighbours`` (mean neighbours reused a chain), ``confidence`` (mean c of the shaded reservoirs
in units of M: the history a chain carries and its neighbours' confidence; the history alone
where ``neighbours`` is 0).  One chain does not converge with M: even with
M → ∞ its kept sample is distributed ∝ p̂ and f/p̂ (the map's colour over its luminance) keeps a
variance, which is why the budget counts chains.

State.  The chains' reservoirs, last frame's map and last frame's target scales live on the
device between frames (nothing is read back within a frame).  A new G-buffer, face size, seed
or spp starts without history (its first frame is initial RIS and spatial reuse only);
:meth:`reset` forgets it.

Unbiasedness.  ``unbiased = True`` (the default) is unbiased on every frame, static or not,
switch frames included (tests/test_restir.py z-tests each frame of ``sphere-switch``; the
conformance suite's ``check_unbiased_over_frames`` a switching map): its c, s and neighbour
choices do not depend on the samples' values.  ``unbiased = False`` is biased beside shadows
(Tags per instance, so the suite skips its z-tests and asks that its error falls).

The biased mode's 1/Z applied to temporal reuse too (tried first) failed the stress battery's
dimming-sun recovery (last frame's error ×5.3 the first's: Z counted the history's whole
confidence while the history rarely sampled where the light had gone); with GRIS's temporal
weights in both modes it recovers.

Sources.  Neither paper is in the papers of ARCHITECTURE.md §Papers: the algorithms follow Bitterli's Alg. 3
(streaming RIS), 4 (combining reservoirs) and 6 (1/Z) and GRIS's resampling weights and
confidence-weighted balance heuristic as published, without equation numbers checked here.

Choices, measured (relMSE of the last frame over 6 seeds at 4 chains, 48², 32² faces; with no
reuse 0.036 on blob-minutes and static sphere-studio, 0.046 on sphere-studio-moving):
- ``history_cap`` 1, not RTXDI's 20.  Temporal reuse alone (no neighbours), caps 1 / 2 / 20:
  static sphere-studio (frame 8) 0.0125 / 0.0079 / 0.0051: a long history is what reuse is for
  on a still map; but blob-minutes (a sun moving 0.2 of a texel a frame, frame 10) 0.022 /
  0.024 / 0.113 and sphere-studio-moving (frame 8) 0.032 / 0.062 / 0.387: on a moving map the
  history's samples lag the light by about cap frames while its MIS weight claims the density
  of last frame's target, so where the light has just arrived the history takes responsibility
  for light it never sampled, and the rare sample that is there carries a weight that the next
  frames reuse; at cap 20 the error grows every frame.  Unbiased all the same: it is the
  variance that grows.
- ``radius`` 2 pixels, not RTXDI's 30 at 1080p: at 48² a disc of 16 reaches a third of the image,
  and the neighbours' targets differ so much that spatial reuse added variance (static
  sphere-studio, spatial reuse alone: 0.044 at radius 16, 0.034 at 4, 0.025 at 2).
- The spatially reused reservoir is shaded but not kept (Bitterli and RTXDI keep it): kept, its
  neighbours' shared samples came back every frame as if independent (static sphere-studio,
  radius 2, cap 20: 0.015 at frame 8 kept, 0.0083 not).
Measured with a session script over ``restir.render`` (the note of issue 24 gives the commands).

Deviations.  From RTXDI: a cube map's luminance pyramid instead of its octahedral
importance map (the presamples' density is exact per texel); no material similarity test (one
material per scene); no boiling filter; 32 × 256 presamples a frame (RTXDI: 128 × 1024 at
1080p).  From Bitterli: BRDF candidates beside the light ones; the unbiased weights are GRIS's
scaled balance heuristic (O(k²) target evaluations), not Alg. 6 with visibility.  A W that
overflows float is set to 0 (never seen).  Flicker: temporal reuse correlates frames, so an
error persists across frames (RTXDI #9 reports it on thin glossy surfaces); the runner's
``flicker`` column measures it.
"""
from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pyopencl as cl

from iblbench.estimators.base import (Estimate, Estimator, KernelCost, Limit, Mutant, Setting, SweepPart,
                                      Tags, WorkCounts, read_estimate, specular_lobe_defines)
from iblbench.estimators.runtime import philox
from iblbench.estimators.runtime.device import KeptBuffers, event_ms

MAX_SPP = 1024          # reservoir chains a pixel: 32 bytes of each of two frames' reservoirs
MAX_CANDIDATES = 4096
MAX_NEIGHBOURS = 8   # restir.cl's bound of k
MIN_TILE = 16        # presamples are drawn in whole blocks of POOL_LANES (at most 16) lanes
STREAM_RESTIR_REUSE = 51   # restir.cl's stream of the reuse steps' numbers
TIE_MARGIN = 1e-4          # float32's rounding of a neighbour's offset (≤ 4 pixels) is far below it


@dataclasses.dataclass(frozen=True)
class ReSTIRParams:
    """(``spp``: the reservoir chains of a pixel.)  ``candidates``: M, the initial candidates of a
    chain's reservoir per frame; ``brdf_share``: the share of them drawn from the BRDF (the rest
    from the map's presamples); ``temporal``: reuse last frame's reservoir; ``history_cap``: its
    confidence capped at this many times M (RTXDI's M-cap; default 1, not RTXDI's 20: see
    "Choices"); ``neighbours``: pixels reused spatially, at most 8 (0: none); ``radius``: their
    disc's radius in pixels; ``unbiased``: GRIS weights in spatial reuse (True) or Bitterli's 1/Z
    counted without visibility (biased beside shadows); ``tiles`` and ``tile_size``: presample
    tiles per frame and presamples per tile (powers of two)."""

    candidates: int = 8
    brdf_share: float = 0.25
    temporal: bool = True
    history_cap: float = 1.0
    neighbours: int = 2
    radius: float = 2.0
    unbiased: bool = True
    tiles: int = 32
    tile_size: int = 256


def _power_of_two(n: int) -> bool:
    return n >= 1 and n & (n - 1) == 0


def eye_depths(gbuffer) -> np.ndarray:
    """Each covered pixel's distance to the eye (``gbuffer``: a DeviceGBuffer or a host GBuffer), the point nearest (least squares) every pixel's
    view ray x + t·v; all 0 for a synthetic G-buffer whose rays do not meet (positions all 0)."""
    g = getattr(gbuffer, "gbuffer", gbuffer)   # a DeviceGBuffer's host G-buffer, or a host one
    x = g.position[g.mask].astype(np.float64)
    v = g.view[g.mask].astype(np.float64)
    projector = np.eye(3) - v[:, :, None] * v[:, None, :]     # I − v vᵀ: off-ray components
    eye = np.linalg.lstsq(projector.sum(0), np.einsum("nij,nj->i", projector, x), rcond=None)[0]
    return np.linalg.norm(x - eye, axis=1).astype(np.float32)


def neighbours_found(gbuffer, chains: int, neighbours: int, radius: float, seed: int,
                     frame: int) -> np.ndarray:
    """How many neighbours each covered pixel's spatial pass (step 4) finds, per chain, int
    ``[pixels, chains]``, on the host G-buffer ``gbuffer``: the rule of step 4 (a pixel uniform
    in the disc, clamped to the image; kept if covered, not the pixel, its normal within acos 0.5
    and its depth within 10%) drawn from the kernel's Philox numbers (``runtime.philox``), its
    geometry in NumPy.  For ``work_counts``: what a render found, recomputed without it.
    ValueError where an offset lies within ``TIE_MARGIN`` of a half pixel, where the device's
    float32 rounding may decide otherwise."""
    height, width = gbuffer.mask.shape
    index = np.flatnonzero(gbuffer.mask)
    at = np.full(height * width, -1)
    at[index] = np.arange(len(index))
    normal = gbuffer.normal[gbuffer.mask].astype(np.float32)
    depth = eye_depths(gbuffer)
    pixel, chain = np.meshgrid(np.arange(len(index)), np.arange(chains), indexing="ij")
    found = np.zeros(pixel.shape, int)
    for j in range(neighbours):
        words = philox.rng_block(seed, frame, STREAM_RESTIR_REUSE, pixel, 1 + j, chain)
        distance = np.float32(radius) * np.sqrt(philox.rng_unit(words[0]).astype(np.float64))
        turn = 2 * np.pi * philox.rng_unit(words[1]).astype(np.float64)
        offsets = distance * np.cos(turn), distance * np.sin(turn)
        if min(np.abs(np.abs(v) % 1.0 - 0.5).min() for v in offsets) < TIE_MARGIN:
            raise ValueError("a neighbour's offset lies within rounding of a tie of rint: the neighbours "
                             "a device finds are not known; choose another seed")
        x = np.clip(index[pixel] % width + np.rint(offsets[0]).astype(int), 0, width - 1)
        y = np.clip(index[pixel] // width + np.rint(offsets[1]).astype(int), 0, height - 1)
        q = at[y * width + x]
        kept = (q >= 0) & (q != pixel)
        q = np.where(kept, q, pixel)
        kept &= np.einsum("...i,...i->...", normal[pixel], normal[q]) >= np.float32(0.5)
        kept &= ~(np.abs(depth[q] - depth[pixel]) > np.float32(0.1) * depth[pixel])
        found += kept
    return found


class ReSTIR(Estimator):
    __doc__ = __doc__
    name = "restir"
    sweep = SweepPart(("restir",), spp=(1, 4, 16, 64), order=11)
    portability_variants = ("restir{unbiased=false}",)
    cost = KernelCost(137, 206, 352, 54, 188, derivation="""\
        the mean of a default chain's 17 evaluations (``Estimate.evaluations``): 8 candidates in
        one block of lanes, 204 each (every lane draws a BRDF direction 107 beside its
        presample's; n·ω 5, lobe power 41, the texel of ω 20, Y(L) 5, ρ_Y 3, p̂ 2, the light and
        BRDF densities 12, the weight 6, the reservoir update 3), 8 reuse targets, 76 (p̂
        alone: n·ω 5, lobe power 41, texel 20, Y(L) 5, ρ_Y 3, products 2), and the shading, 82 (n·ω
        5, lobe power 41, texel 20, phong_value 7, f·W 6, sum 3); F_s is the rest of a chain (a
        shaded sample): the lanes' merge 50, the temporal combination 27, two neighbours found
        80 (disc point, sincos_turn, normal and depth tests), the spatial combination 49; B_s:
        its reservoirs, 32 B each, written once and read four times (history, own, two
        neighbours), and two neighbours' shading, 192 B; per pixel the shading loaded in the two
        shading kernels 48 and the power 6 (the target scales run in the sample stage, outside
        shade_ms); bytes: the G-buffer read twice, 128, the scale (4) and stats (16) written and
        read back, radiance (16) and counts (8) out, 60 (presamples, maps and pyramid
        cache-resident)""",
        lane_loops=((0, 8 / 17), (1, 9 / 17)), limits=(   # approximate: restir.cl's two shading passes
            # restir_initial_temporal: a chain's 8 candidates in one block of lanes (half of it
            # masked at 16 lanes), one chain a sample
            Limit("philox", per_eval=2, why="a candidate's block and its BRDF draw's"),
            Limit("phong_power", per_eval=2, why="a candidate's ξ^{1/(m+1)} and lobe power"),
            Limit("gather", per_eval=8,
                  why="a candidate's presample (x, y, z, pdf), its texel's R, G, B and pyramid"),
            Limit("divide", per_eval=10,
                  why="√ξ, log2 ξ, the direction 3, lanes_texel_of 3, the densities 2"),
            # restir_spatial_shade: chains in lanes, a chain a lane: 8 reuse targets, the shading
            Limit("phong_power", per_eval=1, group=1, why="a target's or the shading's lobe power"),
            Limit("gather", per_eval=75 / 9, group=1,
                  why="a reuse target's texel and its neighbour's reservoir 9, the shading's "
                      "texel 3"),
            Limit("divide", per_eval=3, group=1, why="lanes_texel_of's s/ma, t/ma and √q"),
            Limit("philox", per_sample=2, why="the two neighbours' disc points")))
    Params = ReSTIRParams
    settings = (Setting("candidates", 2), Setting("brdf_share", 0.0), Setting("temporal", False),
                Setting("history_cap", 20.0, {"neighbours": 0}, says="history_cap"),
                Setting("neighbours", 0), Setting("radius", 8.0), Setting("unbiased", False),
                Setting("tiles", 1), Setting("tile_size", 16))
    tags = Tags(unbiased=True, temporal=True, has_pdf=False)
    requires = ("weight_pyramid",)
    kernel_files = ("restir.cl", "sir.cl", "hierarchical.cl", "descent.cl", "envmap.cl", "lanes.cl")
    mutants = (   # for iblbench selftest (harness/verify/mutants.py)
        Mutant("restir-gris-weight-without-previous-target", "restir.cl",
               "restir_target(&s, prev_env, res, current.w, visibility, p)",
               "restir_target(&s, env, res, current.w, visibility, p)",
               stress=("temporal-dropout",)),
        Mutant("restir-m-cap-off-by-one", "restir.cl",
               "min(inputs[1].confidence, history_cap * current.confidence)",
               "min(inputs[1].confidence, (history_cap + 1.0f) * current.confidence)"),
    )
    max_spp = MAX_SPP

    def __init__(self, params=None, **overrides):
        super().__init__(params, **overrides)
        p = self.params
        if not 1 <= p.candidates <= MAX_CANDIDATES or not 0.0 <= p.brdf_share <= 1.0 or not p.history_cap >= 0.0 \
                or not 0 <= p.neighbours <= MAX_NEIGHBOURS or not p.radius >= 1.0 \
                or not _power_of_two(p.tiles) or not _power_of_two(p.tile_size) or p.tile_size < MIN_TILE:
            raise ValueError(f"invalid restir parameters {p}")
        self.tags = dataclasses.replace(type(self).tags, unbiased=bool(p.unbiased))
        self._buffers = KeptBuffers()
        self._maps_of = (None, None)   # (a G-buffer, held: no later one takes its id; its pixel maps)
        self.reset()

    def reset(self) -> None:
        self._key = None
        self._parity = 0

    def defines(self, gbuffer=None) -> dict:
        return specular_lobe_defines(gbuffer)

    def candidate_split(self) -> tuple[int, int]:
        """(light, BRDF) candidates of a reservoir."""
        brdf = int(round(self.params.candidates * self.params.brdf_share))
        return self.params.candidates - brdf, brdf

    def work_counts(self, gbuffer, frames) -> list[WorkCounts]:
        """"Budget" above, per chain: M candidates, 2 targets of temporal reuse after the first
        frame, (r+1)·r targets of spatial reuse with the r neighbours it found
        (:func:`neighbours_found`) and the shading; shadow rays the same but the shading's and,
        in the biased mode, the r·r neighbour targets without V.  Extra ``neighbours``: the
        mean r."""
        p, counts = self.params, []
        for t, frame in enumerate(frames):
            found = neighbours_found(gbuffer, frame.spp, p.neighbours, p.radius, frame.seed, frame.cache.frame)
            temporal = 2 if p.temporal and t > 0 else 0
            spatial = found * (found + 1)
            counts.append(WorkCounts(
                evaluations=(p.candidates + temporal + spatial + 1).sum(1),
                shadow_rays=(p.candidates + temporal + (spatial if p.unbiased else found)).sum(1),
                extras={"neighbours": found.mean()}))
        return counts

    def _pixel_maps(self, compute, gbuffer) -> tuple:
        """(each launched pixel's image index, each image position's pixel or −1, depths), on the
        device, made once per G-buffer."""
        if self._maps_of[0] is not gbuffer:
            index = np.concatenate([gbuffer.pixel_index, np.repeat(gbuffer.pixel_index[-1:],
                                                                   gbuffer.launch_size - gbuffer.count)])
            at = np.full(gbuffer.shape[0] * gbuffer.shape[1], -1, np.int32)
            at[gbuffer.pixel_index] = np.arange(gbuffer.count, dtype=np.int32)
            depth = eye_depths(gbuffer)
            depth = np.concatenate([depth, np.repeat(depth[-1:], gbuffer.launch_size - gbuffer.count)])
            self._maps_of = (gbuffer, tuple(compute.to_device(a) for a in
                                            (index.astype(np.int32), at, depth.astype(np.float32))))
        return self._maps_of[1]

    def render(self, gbuffer, cache, spp, seed) -> Estimate:
        if not 1 <= spp <= MAX_SPP:
            raise ValueError(f"spp must be in [1, {MAX_SPP}], got {spp}")
        compute, p, res = cache.compute, self.params, cache.res
        light_count, brdf_count = self.candidate_split()
        key = (gbuffer, res, int(seed), int(spp))   # the G-buffer itself (compared by identity), held
        temporal = p.temporal and key == self._key
        self._key = key
        n, chains = gbuffer.launch_size, int(spp)
        buffer = functools.partial(self._buffers.get, compute)
        # One chain a pixel: pass 2 built without its lanes (restir.cl, CHAIN_LANES; defines() may
        # set it, as tests/test_restir.py does to run every chain in scalars).  Nor in the GPU's
        # launch shape: a GPU runs each work item's lanes one after another, and their private
        # arrays would spill; the scalar chains give the same images bit for bit.
        chain_lanes = chains > 1 and compute.launch_shape == "pixel"
        kernel = functools.partial(compute.kernel, self.kernel_package(), "restir.cl",
                                   defines={"CHAIN_LANES": int(chain_lanes), **self.defines(gbuffer), "BRDF_SAMPLES": 1})
        pyramid, tables = cache.weight_pyramid(False), cache.descent_tables(False)
        presample_count = p.tiles * p.tile_size
        presamples = buffer("presamples", 4 * 4 * presample_count)
        lanes = compute.pool_lanes
        # Histories alternate: this frame's reservoirs (and map, and target scales) go where last
        # frame's are not.
        parity, self._parity = self._parity, 1 - self._parity
        scales, previous_scales = buffer(f"scales{parity}", n * 4), buffer(f"scales{1 - parity}", n * 4)
        surface = (gbuffer.normal, gbuffer.view, gbuffer.kd, gbuffer.ks, gbuffer.visibility)
        sample_events = [compute.run(kernel("restir_presample"), -(-presample_count // lanes), tables.bounds,
                                     tables.probability, np.int32(res), np.uint32(seed), np.uint32(cache.frame), presamples),
                         gbuffer.run(compute, kernel("restir_target_scales"), *surface[:4], pyramid.buffer,
                                     np.int32(res), scales)]
        reservoirs = lambda name: (buffer(f"{name}_sample", chains * n * 16), buffer(f"{name}_info", chains * n * 16))
        history, new_history = reservoirs(f"history{1 - parity}"), reservoirs(f"history{parity}")
        previous_env = buffer(f"env{1 - parity}", cache.env_buffer.size)
        this_env = buffer(f"env{parity}", cache.env_buffer.size)
        stats, radiance, counts = buffer("stats", n * 16), buffer("radiance", n * 16), buffer("counts", n * 8)
        pixel_index, pixel_at, depth = self._pixel_maps(compute, gbuffer)
        events = [
            gbuffer.run(compute, kernel("restir_initial_temporal"), *surface, np.int32(n), cache.env_buffer, previous_env,
                        pyramid.buffer, presamples, scales, previous_scales, np.int32(res),
                        np.int32(presample_count), np.int32(p.tiles),
                        np.int32(p.tile_size), np.int32(light_count), np.int32(brdf_count), np.int32(chains),
                        np.int32(temporal), np.float32(p.history_cap),
                        np.uint32(seed), np.uint32(cache.frame), *history, *new_history, stats),
            gbuffer.run(compute, kernel("restir_spatial_shade"), *surface, np.int32(n), cache.env_buffer, np.int32(res),
                        pixel_index, pixel_at, depth, np.int32(gbuffer.shape[1]), np.int32(gbuffer.shape[0]),
                        np.int32(p.neighbours), np.float32(p.radius), np.int32(chains), np.int32(p.unbiased),
                        np.uint32(seed), np.uint32(cache.frame), *new_history, scales, radiance, counts,
                        stats)]
        if p.temporal:   # this frame's map, p̂_{t−1}'s for the next frame: a device copy
            events.append(cl.enqueue_copy(compute.queue, this_env, cache.env_buffer,
                                          byte_count=cache.env_buffer.size))
            events[-1].wait()
        st = compute.to_host(stats, (n, 4), np.float32)[:gbuffer.count]
        estimate = read_estimate(compute, gbuffer, radiance, counts, float(st[:, 0].mean()),
                                 {"sample": sum(map(event_ms, sample_events)) + tables.build_ms,
                                  "shade": sum(map(event_ms, events))},
                                 shadow_rays=float(st[:, 3].mean()))
        estimate.extras = {"neighbours": float(st[:, 1].mean()),
                           "confidence": float(st[:, 2].mean()) / self.params.candidates}
        return estimate

    def kept_state(self, compute, gbuffer, spp: int) -> dict[str, np.ndarray]:
        """Host copies of what the last ``render(gbuffer, …, spp, …)`` keeps for the next frame,
        for tests of the weights (read back only here, never by a render): ``sample``
        [spp, covered pixels, 4], each chain's reservoir's (ω, W); ``info`` likewise, (c, p̂, 0, 0);
        ``scales`` [covered pixels], each pixel's 1/Z̃ under the frame's map."""
        if self._key is None or self._key[0] is not gbuffer or self._key[3] != int(spp):
            raise ValueError("kept_state reads the last render's G-buffer and spp, not others")
        n, parity = gbuffer.launch_size, 1 - self._parity
        read = lambda name, count: compute.to_host(self._buffers.get(compute, name, count * 4), (count,), np.float32)
        chains = lambda name: read(name, int(spp) * n * 4).reshape(int(spp), n, 4)[:, :gbuffer.count]
        return {"sample": chains(f"history{parity}_sample"), "info": chains(f"history{parity}_info"),
                "scales": read(f"scales{parity}", n)[:gbuffer.count]}
