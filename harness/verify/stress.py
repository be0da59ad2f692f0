"""``iblbench stress``: a battery of adversarial inputs, each named after the failure it guards
against (issue 6), run over every estimator (or the chosen ones).

One row per (case, estimator), over the case's variants (placements, sizes, frames):

- ``nonfinite``, ``negative``: non-finite and negative output values (must be 0);
- ``min``, ``max``: the smallest and largest finite output value;
- ``rel_rmse``: RMS error of one render against the exact reference over the mean reference
  (absolute where the reference is 0), mean over seeds and frames, worst variant;
- ``dark_nonzero``: output values that are not exactly 0 where the reference is exactly 0.  An
  unbiased estimator with non-negative output must be exactly 0 there (a positive value would
  give a positive mean), and every estimator must be on a map that has been black on every
  frame so far (a temporal filter may carry light out of earlier frames);
- ``reference_error``: where a variant's exact value is known (white furnace, black map), the
  reference's largest relative deviation from it (must be ≤ ``EXACT_RTOL``);
- ``reference_impossible``: reference values that are negative or not finite (radiance cannot
  be; must be 0);
- ``gbuffer_invalid``: covered pixels whose normal or view is not a finite unit vector or whose
  n·view < ``MIN_COS_VIEW`` (the G-buffer contract of ``scenes.gbuffer``);
- ``bias_pixels``, ``bias_z``, ``bias_p`` (unbiased estimators): how many (pixel, frame) pairs
  the z-test used in at least one colour channel, the largest |z| and its Šidák-corrected p-value over the row's tests;
- ``chi2_tests``, ``chi2_p`` (estimators with a pdf): χ² tests of the sampler on the case's
  maps and their Šidák-corrected smallest p-value;
- ``recovery`` (temporal estimators): RMS error of the last frame over that of the first, which
  shows the same map: the state carried over a drop-out or a jump must wash out (each relative
  to its frame's reference: on ``smooth-rotation`` a turned map, within that case's own limit);
- ``counts_z`` (light-pool estimators): the sample counts against their analytic values on
  frame 0: ``used`` must be the β-weighted ticks of the drawn strategies exactly, and
  ``effective`` (samples with n·ω > 0) must have the mean Σ_f N_f·q_f(n) + N_B·q_B, with q_f the
  probability that a light sample of face f lies above the pixel's horizon (texel probability
  Y·Ω/I_f times the share of the texel's square above it, ``horizon_shares``) and q_B ≤ 1 for
  the BRDF samples (so with BRDF samples only its upper side is tested): a t-test over
  ``COUNT_SEEDS`` renders of the image sum;
- ``cache_error``: the frame cache's light-sampling products on frame 0 against their
  definition (ARCHITECTURE.md §Conventions), computed in NumPy from the map: the face integrals I_f = Σ Y·Ω and
  each texel's probability given its face, Y·Ω/I_f, from the fixed-point CDFs (largest relative
  deviation; a texel of zero luminance must have probability exactly 0);
- ``chi2_p`` also holds, for ``havran``, the χ² of its map's sampler on each variant's frame 0:
  the pdf ``EqualAreaMap.sample`` returns must be the map's density (written here from its
  definition, ``havran_map_density``) and its samples must fall in the grid cells as the
  closed-form cell probabilities say (``havran_cell_probabilities``);
- ``scoring_error``: the metrics of protocol lab-reinhard-v1 (``harness/metrics``) on the
  variant's reference: the reference scores ΔE76 = relMSE = 0 against itself, and twice the
  reference scores what an independent NumPy implementation of the protocol gives (the
  exposure is the reference's: an exposure taken from the estimate would score 0);
- ``status``: ``pass``, ``FAIL``, ``xfail`` (a known failure, ``KNOWN_FAILURES``) or ``XPASS``
  (a known failure that passed: remove its mark); ``failures`` says what failed; ``notes``
  links the fixes the case found.

An estimator that is biased in general but unbiased over seeds on a static map (``havran``:
its filter of identical frames is the identity) says so with the class attribute
``unbiased_on_static_maps = True``; the z-test then applies to its frames on variants whose
frames are all the same map (the ``static-sequence`` case).

Statistical design.  Seeds are fixed (renders are deterministic per device), and each row's
tests are one family: z-tests at family-wise α = ``ALPHA_Z`` = 1e-3 and χ² at ``ALPHA_CHI2`` =
1e-2 over the whole battery, Šidák-corrected across the cases (``ALPHA_Z_CASE``), then across the
row's pixels, channels, frames and variants.  The z-test (``conformance.bias_test``) compares the
mean over ``Scale.seeds`` renders with the reference per pixel and channel, plus the tested
pixels' pooled image mean per channel; its standard error has a floor of
``REFERENCE_RTOL``·|reference| (the reference's accuracy budget), so an exact zero-variance
estimate passes and a wrong constant fails.

Which pixels a z-test may use.  A z-test of a mean over seeds is valid only where the
estimator's samples reach what the pixel integrates.  An estimator that is unbiased in
expectation fails it where part of the integral hides in a region the samples hit a few times
over all seeds (a light sampler on the dim sky beside a 1e9 sun: that sky is missing from almost
every render, so the mean is off by its share however unbiased the estimator), and it passes
vacuously where nothing is reached.  So each (pixel, channel, frame) is tested only where the
estimator reaches its integrand, by this model (``tested_pixels``): each colour channel of the
pixel's integral splits exactly into texel shares (``Reference.texel_integrals``; per channel,
since the samplers follow luminance and a channel may hide where the luminance is small: the
red sliver of one-sample's colour-split map); a texel's expected hits over all seeds are
seeds × (light draws of its face × Y·Ω/I_f × the share of the texel's square above the pixel's
horizon + BRDF draws × the texel's BRDF probability: a light hit on the part of a texel below the
horizon adds nothing, and a texel the horizon cuts to a sliver is reached as rarely as the
sliver's share says), with
the draws per render of the estimator's own budget split (``sample_budget``: the pool
estimators' per-normal face split, ``havran``'s K lights split by the faces' luminance, and
for any other estimator the smaller of one light draw per lit face and spp/2 BRDF draws).
``bis``'s image carries the colour of its N resampled draws only, which follow its target γ
(Kronander §5) where its M BRDF candidates reach it: its hits are the fewer of M candidate
draws and N draws × the texel's share of γ.  A texel is rare in a channel when one hit there
carries more than 1/``REACH_HITS`` of the pixel's value in it; a pixel's channel is tested
when its rare texels hold at most ``RARE_SHARE`` of its integral (and its reference is not 0:
those values are checked for exactness instead).  Each case says which pixels this leaves.  The light CDFs' own precision (float32 bins used to collapse to 0 next to a
bright sun) is audited analytically in ``harness/cdf_precision``, not by sampling.
"""
from __future__ import annotations

import dataclasses
import pathlib
import time

import numpy as np
import pandas as pd
from scipy import stats
from tqdm import tqdm

from iblbench.estimators.bis import BIS
from iblbench.estimators.envmap import MapSampler
from iblbench.estimators.havran import DEFENSIVE as HAVRAN_DEFENSIVE, Havran
from iblbench.estimators.light_pool import TICKS_PER_SAMPLE, PoolEstimator
from iblbench.harness.verify import conformance
from iblbench.harness.verify.stress_cases import (CASE_NAMES, CASES, KNOWN_FAILURES, LARGE,  # noqa: F401
                                                  NO_Z_PIXELS, SMALL, Scale, StressCase, Variant)
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import MIN_COS_VIEW, GBuffer

ALPHA_Z, ALPHA_CHI2 = conformance.ALPHA_Z, conformance.ALPHA_CHI2
REACH_HITS = 100       # a texel is rare when one hit there carries > 1/REACH_HITS of the pixel
RARE_SHARE = 1e-3      # a pixel is z-tested when rare texels hold at most this share of it
EXACT_RTOL = 1e-5      # the reference against a known exact value
COUNT_SEEDS = 24       # renders of the sample-count test
COUNT_MAX_RES = 64     # the count test runs on maps up to this face size
SCORING_RTOL = 1e-3    # the protocol's metrics against the independent implementation
CACHE_RTOL = 1e-4      # the frame cache's products against their definition (float32 inputs)
MAX_REACH_BLOCKS = 128  # reach is modelled on at most this many texel blocks per face side


ALPHA_Z_CASE = conformance.sidak_alpha(ALPHA_Z, len(CASES))
ALPHA_CHI2_CASE = conformance.sidak_alpha(ALPHA_CHI2, len(CASES))

# ---- one variant, prepared once for every estimator ------------------------------------------

def gbuffer_invalid(gbuffer: GBuffer) -> int:
    """Covered pixels that break the G-buffer contract: non-finite or non-unit normal or view,
    or n·view < MIN_COS_VIEW."""
    normal, view = gbuffer.normal[gbuffer.mask], gbuffer.view[gbuffer.mask]
    unit = lambda v: np.all(np.isfinite(v), axis=1) & (np.abs(np.linalg.norm(v, axis=1) - 1) < 1e-5)
    facing = np.einsum("ij,ij->i", normal, view) >= MIN_COS_VIEW * (1 - 1e-3)
    return int(np.count_nonzero(~(unit(normal) & unit(view) & facing)))


def _blocks(values: np.ndarray) -> np.ndarray:
    """Sum ``[6, R, R]`` texel values into at most MAX_REACH_BLOCKS² blocks per face."""
    res = values.shape[1]
    size = max(1, res // MAX_REACH_BLOCKS)
    return values.reshape(6, res // size, size, res // size, size).sum(axis=(2, 4))


@dataclasses.dataclass
class Prepared:
    """A variant on the device: its G-buffer, one FrameCache per frame and the references."""

    variant: Variant
    gbuffer: DeviceGBuffer
    caches: list[FrameCache]
    references: np.ndarray          # [frames, H, W, 3] float64
    reference: Reference
    _shares: tuple | None = None

    @classmethod
    def of(cls, variant: Variant, compute) -> "Prepared":
        reference = Reference(compute)
        gbuffer = DeviceGBuffer(compute, variant.gbuffer)
        caches = [FrameCache(compute, env, frame) for frame, env in enumerate(variant.frames)]
        references = np.stack([reference.image(gbuffer, cache) for cache in caches]).astype(np.float64)
        return cls(variant, gbuffer, caches, references, reference)

    def covered(self, images: np.ndarray) -> np.ndarray:
        """``[..., H, W, 3]`` → ``[..., covered, 3]``."""
        return images[..., self.variant.gbuffer.mask, :]

    def shares(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per frame, covered pixel and colour channel, each texel block's share of the pixel's
        integral of that channel ``[frames, n, 3, 6, B, B]``; per frame and pixel its share of
        bis's target γ = L_Y·ρ_Y·cos⁺ (Kronander Eq. 3) ``[frames, n, 6, B, B]``; per pixel a
        lower bound of the probability that one BRDF sample lands in it ``[n, 6, B, B]``; per
        frame and pixel the probability that a light sample of its face lands in it where the
        pixel's integrand may be positive, Y·Ω/I_f times the share of the texel's square above
        the pixel's horizon (``horizon_shares``; without a diffuse term, at most the share on the
        lobe's side of the plane cos_r = 0 too) ``[frames, n, 6, B, B]`` (float64 from the
        float32 map)."""
        if self._shares is None:
            g = self.variant.gbuffer
            kd, ks = g.kd[g.mask].astype(np.float64), g.ks[g.mask].astype(np.float64)
            kd_y, ks_y = cubemap.luminance(kd), cubemap.luminance(ks)
            m = g.shininess[g.mask].astype(np.float64)
            p_spec = np.divide(ks_y, kd_y + ks_y, out=np.zeros_like(ks_y), where=kd_y + ks_y > 0)
            res = self.caches[0].res
            frames = [env.astype(np.float64) for env in self.variant.frames]
            normals, views = g.normal[g.mask].astype(np.float64), g.view[g.mask].astype(np.float64)
            mirrors = 2 * np.einsum("ij,ij->i", normals, views)[:, None] * normals - views
            omega = cubemap.texel_solid_angles(res)
            texel_light = [_face_shares(cubemap.luminance(env) * omega) for env in frames]   # Y·Ω/I_f
            channel_shares, target_shares, brdf, light = [], [], [], []
            for i, table in enumerate(self.reference.texel_integrals(self.gbuffer, res)):
                cosine, lobe = table[..., 0].astype(np.float64), table[..., 1].astype(np.float64)
                diffuse, specular = cosine / np.pi, (m[i] + 2) / (2 * np.pi) * lobe
                channels = np.stack([[_blocks(env[..., c] * (kd[i, c] * diffuse + ks[i, c] * specular))
                                      for c in range(3)] for env in frames])
                target = np.stack([_blocks(cubemap.luminance(env) * (kd_y[i] * diffuse + ks_y[i] * specular))
                                   for env in frames])
                channel_shares.append(_normalised(channels))
                target_shares.append(_normalised(target))
                # ∫ cos_r^m ≥ ∫ cos_r^m cos_n over a texel: a lower bound of the lobe's share.
                brdf.append(_blocks((1 - p_spec[i]) / np.pi * cosine
                                    + p_spec[i] * (m[i] + 1) / (2 * np.pi) * lobe))
                support = horizon_shares(res, normals[i, None])[0]
                if kd_y[i] == 0:        # the lobe's half-space too: its share bounds the overlap's
                    support = np.minimum(support, horizon_shares(res, mirrors[i, None])[0])
                light.append(np.stack([_blocks(texel * support) for texel in texel_light]))
            self._shares = (np.stack(channel_shares, axis=1), np.stack(target_shares, axis=1),
                            np.stack(brdf), np.stack(light, axis=1))
        return self._shares


def _face_shares(values: np.ndarray) -> np.ndarray:
    """``[6, R, R]`` over each face's sum (0 on a face whose sum is 0)."""
    total = values.sum(axis=(1, 2), keepdims=True)
    return np.divide(values, total, out=np.zeros_like(values), where=total > 0)


def _normalised(blocks: np.ndarray) -> np.ndarray:
    """``[..., 6, B, B]`` over its sum across the last three axes (0 where that is 0)."""
    total = blocks.sum(axis=(-3, -2, -1), keepdims=True)
    return np.divide(blocks, total, out=np.zeros_like(blocks), where=total > 0)


# ---- the reach model ------------------------------------------------------------------------

def _uniform_sum_cdf(s: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """P(X + Y ≤ s) for independent X, Y uniform on [0, a] and [0, b] (a, b ≥ 0): the piecewise
    quadratic (ρ(s) − ρ(s − a) − ρ(s − b) + ρ(s − a − b))/(2ab), ρ(t) = max(t, 0)², with s
    clipped to [0, a + b] first (no cancellation of squares far from it) and each side at least
    1e-7 of a + b (a side of 0 is the limit; both 0: a step at 0)."""
    width = a + b
    a, b = np.maximum(a, 1e-7 * width), np.maximum(b, 1e-7 * width)
    t = np.clip(s, 0.0, a + b)
    ramp = lambda x: np.maximum(x, 0.0) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        cdf = (ramp(t) - ramp(t - a) - ramp(t - b) + ramp(t - a - b)) / (2 * a * b)
    return np.where(width > 0, np.clip(cdf, 0.0, 1.0), s >= 0)


def horizon_shares(res: int, axes: np.ndarray) -> np.ndarray:
    """Per axis a of ``axes [n, 3]``, the share of each texel's face square whose directions have
    a·ω > 0, ``[n, 6, R, R]``, exact: on face f, a·ω ∝ a·(xU + yV + W) is linear in the face
    point (x, y), so over a texel it is its least value there plus two independent uniform ramps
    (x and y are uniform on the texel's square, as every light sampler draws them), of heights
    |a·U|·2/R and |a·V|·2/R."""
    basis = cubemap.face_basis(np.arange(6))                              # [6, 3 (U, V, W), 3]
    slope_x, slope_y, centre = np.moveaxis(np.einsum("nk,fjk->nfj", np.asarray(axes, np.float64), basis), -1, 0)
    side = 2.0 / res
    edges = np.linspace(-1.0, 1.0, res + 1)[:-1]
    least_x = np.minimum(slope_x[..., None] * edges, slope_x[..., None] * (edges + side))   # [n, 6, R] by column
    least_y = np.minimum(slope_y[..., None] * edges, slope_y[..., None] * (edges + side))   # by row
    least = centre[..., None, None] + least_y[..., :, None] + least_x[..., None, :]
    rise = lambda slope: (np.abs(slope) * side)[..., None, None]
    return 1.0 - _uniform_sum_cdf(-least, rise(slope_x), rise(slope_y))


@dataclasses.dataclass(frozen=True)
class SampleBudget:
    """An estimator's draws per render, per normal: from each face's light CDF ``light [n, 6]``
    and from the Phong BRDF ``brdf [n]``; ``additive``: whether both count (True) or only the
    smaller (an estimator whose split is unknown: its reach is the weaker of the two).  A
    resampling estimator's image carries only its ``resampled [n]`` draws, which follow the
    target γ where the draws above (its candidates) reach it: a texel's hits are then the
    fewer of its candidate hits and its resampled draws from γ."""

    light: np.ndarray
    brdf: np.ndarray
    additive: bool = True
    resampled: np.ndarray | None = None


def sample_budget(estimator, cache: FrameCache, normals: np.ndarray, spp: int) -> SampleBudget:
    """The draws per render of ``estimator`` at ``spp`` (``SampleBudget``)."""
    n = len(normals)
    if isinstance(estimator, PoolEstimator):
        draws = np.ceil(estimator.strategy_ticks(cache, normals, spp) / TICKS_PER_SAMPLE)
        return SampleBudget(draws[:, :6], draws[:, 6])
    if isinstance(estimator, BIS):
        # M BRDF candidates, of which only the N resampled carry their colour into the image
        # (L̂ = Ẑ/N·Σ f/γ; the others enter through Ẑ, in luminance alone); the resampled
        # approximate the target γ (Kronander §5).
        candidates, resampled = estimator.budget(spp)
        return SampleBudget(np.zeros((n, 6)), np.full(n, float(candidates)),
                            resampled=np.full(n, float(resampled)))
    cache.require(("cdf",))        # the face integrals (an estimator that needs no CDFs)
    if isinstance(estimator, Havran):   # K = spp lights from the map's pdf, (1 − δ) ∝ luminance
        integrals = cache.face_integrals.astype(np.float64)   # 1e-300 underflows in float32
        share = integrals / max(float(integrals.sum()), 1e-300)
        return SampleBudget(np.tile((1.0 - HAVRAN_DEFENSIVE) * spp * share, (n, 1)), np.zeros(n))
    if isinstance(estimator, MapSampler) and not estimator.compensated:
        # One distribution over the whole map: face f holds the share I_f / Σ I of its draws.
        light, brdf = estimator.strategy_samples(spp)
        integrals = cache.face_integrals.astype(np.float64)
        share = integrals / max(float(integrals.sum()), 1e-300)
        return SampleBudget(np.tile(np.ceil(light) * share, (n, 1)), np.full(n, np.ceil(brdf)))
    lit = (cache.face_integrals > 0).astype(np.float64)
    return SampleBudget(np.tile(lit, (n, 1)), np.full(n, spp / 2), additive=False)


def tested_pixels(estimator, prepared: Prepared, frame: int, spp: int, seeds: int) -> np.ndarray:
    """Covered pixels and colour channels (bool ``[n, 3]``) whose z-test is valid for this
    estimator on this frame: a non-zero reference, and at most RARE_SHARE of the channel's
    integral on texels rare in that channel (module docstring)."""
    channel_shares, target_shares, brdf, light = prepared.shares()
    normals = prepared.variant.gbuffer.normal[prepared.variant.gbuffer.mask]
    budget = sample_budget(estimator, prepared.caches[frame], normals, spp)
    light_hits = budget.light[:, :, None, None] * light[frame]
    brdf_hits = budget.brdf[:, None, None, None] * brdf
    hits = light_hits + brdf_hits if budget.additive else np.minimum(light_hits, brdf_hits)
    if budget.resampled is not None:
        hits = np.minimum(hits, budget.resampled[:, None, None, None] * target_shares[frame])
    hits = seeds * hits
    share = channel_shares[frame]                                   # [n, 3, 6, B, B]
    rare = share * REACH_HITS > hits[:, None]
    lit = share.sum(axis=(2, 3, 4)) > 0
    return lit & (np.where(rare, share, 0.0).sum(axis=(2, 3, 4)) <= RARE_SHARE)


# ---- one row ----------------------------------------------------------------------------------

def render_all(estimator, prepared: Prepared, spp: int, seeds: int) -> np.ndarray:
    """``[seeds, frames, H, W, 3]`` float32: each seed's frame sequence from ``reset()``."""
    for cache in prepared.caches:
        cache.require(type(estimator).requires)
    images = []
    for seed in range(seeds):
        estimator.reset()
        images.append([estimator.render(prepared.gbuffer, cache, spp, seed).radiance
                       for cache in prepared.caches])
    return np.asarray(images)


def _relative_rmse(images: np.ndarray, references: np.ndarray) -> np.ndarray:
    """Per ``[..., frames]``: RMS error over covered values / mean reference (absolute RMS where
    the reference is 0).  Inputs ``[..., frames, covered, 3]``."""
    with np.errstate(over="ignore", invalid="ignore"):
        rms = np.sqrt(np.mean((images - references) ** 2, axis=(-2, -1)))
    scale = references.mean(axis=(-2, -1))
    return np.where(scale > 0, rms / np.where(scale > 0, scale, 1.0), rms)


@dataclasses.dataclass
class _Row:
    """What one (case, estimator) row accumulates over its variants."""

    nonfinite: int = 0
    negative: int = 0
    low: float = np.inf
    high: float = -np.inf
    rel_rmse: float = 0.0
    dark_nonzero: int = 0
    reference_error: float = np.nan
    reference_impossible: int = 0
    gbuffer_invalid: int = 0
    bias_pixels: int = 0
    bias_tests: int = 0
    bias_z: float = np.nan
    bias_where: str = ""
    chi2: list = dataclasses.field(default_factory=list)      # (p, where, problems)
    recovery: float = np.nan
    counts_z: float = np.nan
    counts_where: str = ""
    scoring_error: float = np.nan
    cache_error: float = np.nan


def _scan(row: _Row, prepared: Prepared, images: np.ndarray, tags) -> None:
    """Non-finite and negative values, range, error, exactness where the reference is 0."""
    values = prepared.covered(images).astype(np.float64)      # [seeds, frames, n, 3]
    references = prepared.covered(prepared.references)        # [frames, n, 3]
    row.reference_impossible = int(np.count_nonzero(~(references >= 0)))   # negative or NaN
    finite = np.isfinite(values)
    row.nonfinite += int(np.count_nonzero(~finite))
    row.negative += int(np.count_nonzero(values < 0))
    if finite.any():
        row.low = min(row.low, float(values[finite].min()))
        row.high = max(row.high, float(values[finite].max()))
    errors = _relative_rmse(values, references)               # [seeds, frames]
    row.rel_rmse = max(row.rel_rmse, float(np.nanmean(errors))) if np.isfinite(errors).all() \
        else np.inf
    black_so_far = np.cumprod([not np.any(env) for env in prepared.variant.frames]).astype(bool)
    for frame in range(len(prepared.caches)):
        if tags.unbiased or black_so_far[frame]:
            dark = references[frame] == 0
            row.dark_nonzero += int(np.count_nonzero(values[:, frame][:, dark] != 0))
    if tags.temporal and len(prepared.caches) > 1:
        row.recovery = max(np.nan_to_num(row.recovery, nan=0.0),
                           float(errors[:, -1].mean() / max(errors[:, 0].mean(), 1e-300)))


def _bias(row: _Row, estimator, prepared: Prepared, images: np.ndarray, spp: int) -> None:
    """z-tests of each colour channel over its tested pixels (``tested_pixels``)."""
    values = prepared.covered(images)
    references = prepared.covered(prepared.references)
    for frame in range(len(prepared.caches)):
        tested = tested_pixels(estimator, prepared, frame, spp, len(images))
        row.bias_pixels += int(tested.any(axis=1).sum())
        for channel in np.flatnonzero(tested.any(axis=0)):
            pixels = np.flatnonzero(tested[:, channel])
            test = conformance.bias_test(values[:, frame][:, pixels, channel, None],
                                         references[frame][pixels, channel, None])
            row.bias_tests += test.tests
            if test.max_abs_z <= np.nan_to_num(row.bias_z, nan=-1.0):
                continue
            worst = int(np.argmax(np.abs(test.pixel_z[:, 0])))
            where = (f"channel {channel}'s pooled image mean, z = {test.pooled_z[0]:.2f}"
                     if np.abs(test.pooled_z[0]) >= np.abs(test.pixel_z[worst, 0]) else
                     f"pixel {pixels[worst]} channel {channel}: mean {test.mean[worst, 0]:.5g} "
                     f"vs reference {test.reference[worst, 0]:.5g}")
            row.bias_z = test.max_abs_z
            row.bias_where = f"{prepared.variant.name}, frame {frame}, {where}"


def _chi2(row: _Row, estimator, prepared: Prepared, scale: Scale) -> None:
    """χ² of the sampler on frame 0's map at the brightest and the median pixel."""
    luminance = cubemap.luminance(prepared.covered(prepared.references[0]))
    order = np.argsort(luminance)
    normals = prepared.variant.gbuffer.normal[prepared.variant.gbuffer.mask]
    views = prepared.variant.gbuffer.view[prepared.variant.gbuffer.mask]
    cache = prepared.caches[0]
    cache.require(type(estimator).requires)
    for k, pixel in enumerate(dict.fromkeys((order[-1], order[len(order) // 2]))):
        result = conformance.chi2_sampling(estimator, cache, normals[pixel], views[pixel],
                                           seed=7 + k, n=scale.chi2_samples)
        if result is not None:
            row.chi2.append((result.p_value, f"{prepared.variant.name} pixel {pixel}", result.problems))


def _check_reference(row: _Row, prepared: Prepared) -> None:
    exact = prepared.variant.exact
    if exact is None:
        return
    deviation = np.abs(prepared.covered(prepared.references) - exact).max()
    error = deviation / exact if exact else deviation
    row.reference_error = max(np.nan_to_num(row.reference_error, nan=0.0), float(error))


def _counts(row: _Row, estimator, prepared: Prepared, spp: int) -> None:
    """``used`` and ``effective`` of frame 0 against their analytic values (``counts_z``)."""
    cache = prepared.caches[0]
    if cache.res > COUNT_MAX_RES:
        return
    cache.require(type(estimator).requires)
    mask = prepared.variant.gbuffer.mask
    normals = prepared.variant.gbuffer.normal[mask]
    ticks = estimator.strategy_ticks(cache, normals, spp).astype(np.float64) / TICKS_PER_SAMPLE
    weight = cubemap.luminance(prepared.variant.frames[0].astype(np.float64)) * cubemap.texel_solid_angles(cache.res)
    texel = _face_shares(weight)
    above = (horizon_shares(cache.res, normals) * texel).sum(axis=(2, 3))      # q_f [n, 6]
    expected_used = ticks.sum(1)
    light = (ticks[:, :6] * above).sum(1)
    brdf = ticks[:, 6]
    used, effective = [], []
    estimator.reset()
    for seed in range(COUNT_SEEDS):
        estimate = estimator.render(prepared.gbuffer, cache, spp, seed)
        used.append(estimate.used[mask])
        effective.append(estimate.effective[mask])
    used, effective = np.asarray(used, np.float64), np.asarray(effective, np.float64)
    wrong_used = np.abs(used - expected_used).max()
    if wrong_used > 1e-4 * spp:
        row.counts_z, row.counts_where = np.inf, f"{prepared.variant.name}: used off by {wrong_used:.4g}"
        return
    # The image sum per render: E = Σ (light + q_B·brdf) with q_B in [0, 1].
    excess = (effective - light - brdf).sum(1)          # ≤ 0 in expectation
    shortfall = (effective - light).sum(1)              # ≥ 0 in expectation (= 0 without BRDF)
    floor = 1e-6 * expected_used.sum() + 1e-12
    z = max(_t_as_z(excess, floor), -_t_as_z(shortfall, floor))
    if z > np.nan_to_num(row.counts_z, nan=-np.inf):
        row.counts_z = z
        row.counts_where = (f"{prepared.variant.name}: effective {effective.sum(1).mean():.5g} per image "
                            f"vs analytic {light.sum():.5g}" + (f" + up to {brdf.sum():.5g} BRDF samples"
                                                                if brdf.any() else ""))


def _t_as_z(values: np.ndarray, floor: float) -> float:
    """The t statistic of the mean of ``values`` over seeds against 0, as the z of the same
    two-sided tail (signed)."""
    t = values.mean() / (values.std(ddof=1) / np.sqrt(len(values)) + floor)
    return float(np.sign(t) * stats.norm.isf(stats.t.sf(abs(t), len(values) - 1)))


def protocol_delta_e76(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """ΔE76 of protocol lab-reinhard-v1 (ARCHITECTURE.md §Conventions) per pixel ``[n, 3]`` → ``[n]``, written from its
    definition: exposure 0.18 over the reference's log-average luminance (ε = 1e-6), Reinhard on
    luminance, linear sRGB → XYZ (IEC 61966-2-1 matrix) → L*a*b* with the D65 white."""
    weights = np.array([0.2126, 0.7152, 0.0722])
    k = 0.18 / np.exp(np.mean(np.log(1e-6 + np.maximum(reference @ weights, 0.0))))
    to_xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    white = np.array([0.3127 / 0.3290, 1.0, (1 - 0.3127 - 0.3290) / 0.3290])

    def lab(rgb):
        display = rgb * (k / (1 + k * (rgb @ weights)))[:, None]
        t = display @ to_xyz.T / white
        f = np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)
        return np.stack([116 * f[:, 1] - 16, 500 * (f[:, 0] - f[:, 1]), 200 * (f[:, 1] - f[:, 2])], -1)

    return np.linalg.norm(lab(estimate) - lab(reference), axis=-1)


def _check_scoring(row: _Row, prepared: Prepared) -> None:
    """``scoring_error``: the metrics on the reference of frame 0 (module docstring)."""
    from iblbench.harness.protocol import metrics

    mask = prepared.variant.gbuffer.mask
    reference = prepared.references[0]
    covered = reference[mask]
    if not (np.all(np.isfinite(covered)) and (covered @ np.array([0.2126, 0.7152, 0.0722])).max(initial=0) > 0
            and np.abs(covered).max() < 1e15):
        return
    doubled = 2.0 * reference
    self_de = metrics.delta_e_images(reference, reference, mask)[0][mask]
    de = metrics.delta_e_images(doubled, reference, mask)[0][mask]
    expected_de = protocol_delta_e76(doubled[mask], covered)
    rel_mse = metrics.rel_mse(doubled, reference, mask)
    expected_rel_mse = np.mean(covered ** 2 / (covered ** 2 + 0.01))
    error = max(np.abs(self_de).max(), metrics.rel_mse(reference, reference, mask),
                np.abs(de - expected_de).max() / max(expected_de.max(), 1e-12),
                abs(rel_mse - expected_rel_mse) / max(expected_rel_mse, 1e-300))
    row.scoring_error = max(np.nan_to_num(row.scoring_error, nan=0.0), float(error))


def havran_map_density(envmap, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """p(ω) of ``havran``'s map at equal-area point (x, y): the row's marginal density times the
    column density of the conditional CDFs blended linearly in y between the rows whose centres
    bracket y (estimators/havran.py, "Mapping")."""
    nz, nphi = envmap.nz, envmap.nphi
    row = np.minimum((y * nz).astype(np.int64), nz - 1)
    col = np.minimum((x * nphi).astype(np.int64), nphi - 1)
    below = np.floor(y * nz - 0.5).astype(np.int64)
    t = y * nz - 0.5 - below
    lower, upper = np.clip(below, 0, nz - 1), np.clip(below + 1, 0, nz - 1)
    column = (1 - t) * envmap.col_prob[lower, col] + t * envmap.col_prob[upper, col]
    return envmap.row_prob[row] * nz * column * nphi / (4 * np.pi)


def havran_cell_probabilities(envmap) -> np.ndarray:
    """P(grid cell i, j) ``[NZ, NPHI]`` of ``havran``'s map in closed form: row i has density
    m_i·NZ in y; over its lower half the blend weight of row i runs 0.5 → 1 against row i − 1
    (mean 0.75), over its upper half 1 → 0.5 toward row i + 1, rows clamped at the poles."""
    c = envmap.col_prob
    previous, following = np.vstack([c[:1], c[:-1]]), np.vstack([c[1:], c[-1:]])
    return envmap.row_prob[:, None] * (0.125 * previous + 0.75 * c + 0.125 * following)


def havran_map_chi2(envmap, n: int, seed: int) -> tuple[float, list[str]]:
    """(p-value, problems) of ``n`` samples of ``havran``'s map: the returned pdf against
    :func:`havran_map_density` (rtol 1e-6), then a χ² of the grid cells against
    :func:`havran_cell_probabilities` (cells expecting < 5 pooled)."""
    from iblbench.estimators.havran import direction_to_equal_area

    dirs, pdf = envmap.sample(np.random.default_rng(seed).random((n, 2)))
    x, y = direction_to_equal_area(dirs)
    agree = np.isclose(pdf, havran_map_density(envmap, x, y), rtol=1e-6, atol=0)
    problems = [] if agree.all() else [f"the pdf of havran's map differs from its density for "
                                       f"{100 * (1 - agree.mean()):.2f}% of samples"]
    cells = (np.minimum((y * envmap.nz).astype(np.int64), envmap.nz - 1) * envmap.nphi
             + np.minimum((x * envmap.nphi).astype(np.int64), envmap.nphi - 1))
    observed = np.bincount(cells, minlength=envmap.nz * envmap.nphi)
    expected = n * havran_cell_probabilities(envmap).reshape(-1)
    order = np.argsort(expected)
    pooled = int(np.searchsorted(np.cumsum(expected[order]), 5.0)) + 1
    obs = np.append(observed[order[pooled:]], observed[order[:pooled]].sum())
    exp = np.append(expected[order[pooled:]], expected[order[:pooled]].sum())
    p_value = float(stats.chi2.sf(np.sum((obs - exp) ** 2 / exp), len(exp) - 1))
    return (0.0 if problems else p_value), problems


def havran_placement_problems(envmap, cache, k: int = 256, seed: int = 7) -> list[str]:
    """The lights the renderer places on the device (``place_lights``) against the inversion
    that :func:`havran_map_chi2` tests (``EqualAreaMap.sample`` on the device map's arrays):
    directions to 1e-9 and weights L/(p·K) to 1e-9 relative (libm's cos and sin differ by
    ulps), so a kernel whose pdf or weight departs from its map is caught."""
    from iblbench.estimators.havran import Havran, relaxed_points, seed_shift

    want_dirs, pdf = envmap.sample((relaxed_points(k) + seed_shift(seed)) % 1.0)
    want_weights = envmap.radiance(want_dirs) / (pdf[:, None] * k)
    dirs, weights = Havran().raw_lights(cache, k, seed)
    problems = []
    if not np.allclose(dirs, want_dirs, rtol=0, atol=1e-9):
        problems.append("havran's device lights are not at its map's inversion")
    if not np.allclose(weights, want_weights, rtol=1e-9, atol=0):
        problems.append("havran's device light weights are not L/(p·K) of its map")
    return problems


def _havran_map(row: _Row, prepared: Prepared, scale: Scale) -> None:
    from iblbench.estimators.havran import EqualAreaMap, frame_map

    cache = prepared.caches[0]
    envmap = EqualAreaMap.of_device_map(frame_map(cache), prepared.variant.frames[0])
    p_value, problems = havran_map_chi2(envmap, scale.chi2_samples, seed=7)
    problems = problems + havran_placement_problems(envmap, cache)
    row.chi2.append((p_value, f"{prepared.variant.name} havran map", problems))


def _check_frame_cache(row: _Row, prepared: Prepared) -> None:
    """``cache_error``: frame 0's face integrals and texel probabilities (module docstring)."""
    cache = prepared.caches[0]
    cache.require(("cdf",))
    weight = (cubemap.luminance(prepared.variant.frames[0].astype(np.float64))
              * cubemap.texel_solid_angles(cache.res))                       # [6, R, R]
    integrals = weight.sum(axis=(1, 2))
    if not np.all(np.isfinite(integrals)):
        return
    marginal, conditional = cache.host_cdfs()
    widths = lambda cdf: np.diff(cdf.astype(np.float64), axis=-1, prepend=0.0) * 2.0 ** -63
    probability = widths(marginal)[:, :, None] * widths(conditional)             # P(texel | face)
    lit = integrals > 0
    expected = weight[lit] / integrals[lit, None, None]
    error = np.abs(probability[lit] - expected) / np.maximum(expected, 1e-12)
    error = np.where(expected > 0, error, np.where(probability[lit] != 0, np.inf, 0.0))
    face_error = np.abs(cache.face_integrals - integrals) / np.maximum(integrals, 1e-300)
    worst = max(float(error.max(initial=0.0)), float(face_error[lit].max(initial=0.0)),
                np.inf if np.any(cache.face_integrals[~lit]) else 0.0)
    row.cache_error = max(np.nan_to_num(row.cache_error, nan=0.0), worst)


def evaluate(case: StressCase, estimator, label: str, variants: list[Prepared], scale: Scale) -> dict:
    """The row of ``estimator`` (shown as ``label``) on ``case``'s prepared variants."""
    start = time.perf_counter()
    estimator = case.configured(estimator)
    tags = estimator.tags
    spp = case.spp or scale.spp
    row = _Row()
    for prepared in variants:
        z_tested = tags.unbiased or (getattr(type(estimator), "unbiased_on_static_maps", False)
                                     and prepared.variant.is_static)
        seeds = scale.seeds if z_tested else scale.scan_seeds
        images = render_all(estimator, prepared, spp, seeds)
        _scan(row, prepared, images, tags)
        _check_reference(row, prepared)
        _check_scoring(row, prepared)
        _check_frame_cache(row, prepared)
        row.gbuffer_invalid += gbuffer_invalid(prepared.variant.gbuffer)
        if isinstance(estimator, PoolEstimator):
            _counts(row, estimator, prepared, spp)
        if z_tested:
            _bias(row, estimator, prepared, images, spp)
        if tags.has_pdf:
            _chi2(row, estimator, prepared, scale)
        if isinstance(estimator, Havran):
            _havran_map(row, prepared, scale)
    return _finish(case, label, row, tags, [p.variant.name for p in variants],
                   time.perf_counter() - start)


def _finish(case: StressCase, label: str, row: _Row, tags, variants: list[str], seconds: float) -> dict:
    failures = []
    if row.nonfinite:
        failures.append(f"{row.nonfinite} non-finite values")
    if row.negative:
        failures.append(f"{row.negative} negative values")
    if row.dark_nonzero:
        failures.append(f"{row.dark_nonzero} values ≠ 0 where the reference is 0")
    if row.reference_error > EXACT_RTOL:
        failures.append(f"reference off the exact value by {row.reference_error:.3g}")
    if row.reference_impossible:
        failures.append(f"{row.reference_impossible} negative or non-finite reference values")
    if row.gbuffer_invalid:
        failures.append(f"{row.gbuffer_invalid} invalid G-buffer pixels")
    bias_p = np.nan
    if row.bias_tests:
        bias_p = conformance.sidak_p(float(conformance.two_sided_p(row.bias_z)), row.bias_tests)
        if bias_p < ALPHA_Z_CASE:
            failures.append(f"biased: |z| = {row.bias_z:.2f}, p = {bias_p:.2g} < {ALPHA_Z_CASE:.2g} "
                            f"({row.bias_where})")
    chi2_p = np.nan
    if row.chi2:
        p_min, where, problems = min(row.chi2, key=lambda item: item[0])
        chi2_p = conformance.sidak_p(p_min, len(row.chi2))
        if problems:
            failures.append(f"sampler: {'; '.join(problems)} ({where})")
        elif chi2_p < ALPHA_CHI2_CASE:
            failures.append(f"χ² rejects the sampler: p = {chi2_p:.2g} < {ALPHA_CHI2_CASE:.2g} ({where})")
    if row.counts_z > conformance.sidak_z(1, ALPHA_Z_CASE):
        failures.append(f"sample counts off their analytic values: {row.counts_where}")
    if row.cache_error > CACHE_RTOL:
        failures.append(f"the frame cache's CDFs or face integrals are off their definition by "
                        f"{row.cache_error:.3g} (relative)")
    if row.scoring_error > SCORING_RTOL:
        failures.append(f"the metrics are off the protocol by {row.scoring_error:.3g} (relative)")
    if row.recovery > case.recovery_limit:
        failures.append(f"no recovery: last-frame error ×{row.recovery:.3g} the first frame's")
    known = KNOWN_FAILURES.get((case.name, label))
    status = ("xfail" if failures else "XPASS") if known else ("FAIL" if failures else "pass")
    notes = "; ".join(note for note in (f"known failure: {known}" if known else "", case.notes) if note)
    return {
        "case": case.name, "estimator": label, "variants": ", ".join(variants), "status": status,
        "nonfinite": row.nonfinite, "negative": row.negative,
        "min": row.low if np.isfinite(row.low) else np.nan,
        "max": row.high if np.isfinite(row.high) else np.nan,
        "rel_rmse": row.rel_rmse, "dark_nonzero": row.dark_nonzero,
        "reference_error": row.reference_error,
        "reference_impossible": row.reference_impossible, "gbuffer_invalid": row.gbuffer_invalid,
        "bias_pixels": row.bias_pixels if row.bias_tests else np.nan, "bias_z": row.bias_z,
        "bias_p": bias_p, "chi2_tests": len(row.chi2) if tags.has_pdf else np.nan,
        "chi2_p": chi2_p, "recovery": row.recovery, "counts_z": row.counts_z,
        "scoring_error": row.scoring_error, "cache_error": row.cache_error, "seconds": seconds,
        "failures": "; ".join(failures), "notes": notes,
    }


# ---- the battery --------------------------------------------------------------------------------

def run_stress(estimators: dict, cases=CASE_NAMES, scale: Scale = LARGE, compute=None,
               progress: bool | None = None) -> pd.DataFrame:
    """Rows of every (case, estimator) that applies; ``estimators`` maps labels to instances.
    Each case's inputs and references are prepared once and shared by its estimators."""
    from iblbench.estimators.runtime.device import get_compute

    compute = compute or get_compute()
    cells = [(CASES[name], label) for name in cases for label, e in estimators.items()
             if CASES[name].applies(e)]
    rows = []
    with tqdm(total=len(cells), unit="cell", disable=None if progress is None else not progress,
              desc="iblbench stress") as bar:
        for name in cases:
            case = CASES[name]
            labels = [label for c, label in cells if c is case]
            if not labels:
                continue
            bar.set_postfix_str(name)
            variants = [Prepared.of(variant, compute) for variant in case.build(scale)]
            for label in labels:
                rows.append(evaluate(case, estimators[label], label, variants, scale))
                bar.update()
    return pd.DataFrame(rows)


def failed(table: pd.DataFrame) -> bool:
    return bool((table.status == "FAIL").any())


def verdict(table: pd.DataFrame) -> str:
    counts = table.status.value_counts()
    summary = ", ".join(f"{counts[s]} {s}" for s in ("pass", "FAIL", "xfail", "XPASS") if s in counts)
    return (f"stress: {'FAILED' if failed(table) else 'passed'}: {summary} of {len(table)} "
            f"(case, estimator) cells")


def _docstring_section(start: str, end: str | None = None) -> list[dict]:
    """A range of this module's docstring as blocks for the HTML page: ``{"text": paragraph}``
    or ``{"bullets": [list item, ...]}``, without reST quoting."""
    text = __doc__[__doc__.index(start):__doc__.index(end) if end else None].replace("``", "")
    blocks = []
    for paragraph in text.split("\n\n"):
        lines = paragraph.strip().splitlines()
        if lines and lines[0].startswith("- "):
            items = []
            for line in lines:
                if line.startswith("- "):
                    items.append(line[2:].strip())
                else:
                    items[-1] += " " + line.strip()
            blocks.append({"bullets": items})
        elif lines:
            blocks.append({"text": " ".join(line.strip() for line in lines)})
    return blocks


def write_tables(out: pathlib.Path, table: pd.DataFrame) -> list[pathlib.Path]:
    """``stress.parquet`` and ``stress.csv`` in ``out`` (an existing folder, see
    ``results.prepare_out``), each written atomically; ``stress.html`` is the API's
    (``iblbench.reports.report.stress_html`` on :func:`html_context`)."""
    from iblbench.harness.protocol.results import write_table

    paths = [out / "stress.parquet", out / "stress.csv"]
    write_table(table, *paths)
    return paths


def html_context(table: pd.DataFrame, scale: Scale, device: str, seconds: float) -> tuple[list, dict]:
    """The cases and the context that ``stress.html`` shows."""
    variants = dict(zip(table.case, table.variants))
    cases = [{"name": c.name, "guards": c.guards, "z_pixels": c.z_pixels, "notes": c.notes,
              "variants": variants[c.name]} for c in CASES.values() if c.name in variants]
    context = {"title": "iblbench stress", "verdict": verdict(table), "failed": failed(table),
               "device": device, "scale": ", ".join(f"{k} {v}" for k, v in dataclasses.asdict(scale).items()),
               "seconds": f"{seconds:.0f}", "alpha_z": ALPHA_Z, "alpha_chi2": ALPHA_CHI2,
               "alpha_z_case": f"{ALPHA_Z_CASE:.3g}", "alpha_chi2_case": f"{ALPHA_CHI2_CASE:.3g}",
               "columns": _docstring_section("One row per", "Statistical design."),
               "design": _docstring_section("Statistical design.")}
    return cases, context
