"""``check_estimator``: the conformance suite every estimator passes (ARCHITECTURE.md §Estimator contract).

In the spirit of scikit-learn's ``check_estimator``: one generator yields the checks that apply
to an estimator's tags; ``check_estimator`` runs them and ``parametrize_with_checks`` turns them
into pytest cases.  Known failures are declared with a reason and reported as expected failures.
Besides the tags, an estimator's declared ``settings`` drive two checks of the class (run on its
default instance): each parameter renders differently off its default, and does what its
docstring says (``SETTING_PROPERTIES``), checks the z-tests cannot make where every setting is
unbiased.

Statistical checks use fixed seeds (results are deterministic per device) and stated
tolerances: z-tests at a family-wise α = 1e-3 with Šidák correction, and a χ² goodness-of-fit of
``sample_directions`` against the integral of ``pdf`` over equal-area sphere bins (low-count
cells pooled, α = 1e-2), which writes a plot when it fails, as Mitsuba's ``chi2.py`` does.
"""
from __future__ import annotations

import dataclasses
import os
import pathlib
import tempfile
from typing import Callable, Iterator

import numpy as np
from scipy import stats

from iblbench.estimators.runtime.device import get_compute
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import GBuffer
from iblbench.harness.verify.convergence import MIN_ERROR_FALL_8_TO_128
from iblbench.estimators.base import CountFrame, Estimator
from iblbench.harness.verify.fixtures import (FACE_BLOB_WIDTH, FACE_BLOBS, SUN_FACE,  # noqa: F401
                                              constant_map, count_frames, count_gbuffer,
                                              face_pattern_map, fibonacci_directions,
                                              glossy_gbuffer, grazing_gbuffer, same_pixels,
                                              settings_frames, smooth_map, stress_maps, sun_map,
                                              white_lambertian)

ALPHA_Z = 1e-3
ALPHA_CHI2 = 1e-2


# ---- checks ---------------------------------------------------------------------------------------

@dataclasses.dataclass
class Harness:
    """Device state shared by the checks of one run."""

    compute: object

    def inputs(self, gbuffer: GBuffer, env: np.ndarray):
        return DeviceGBuffer(self.compute, gbuffer), FrameCache(self.compute, env)

    def render(self, estimator, gbuffer, cache, spp, seed):
        estimator.reset()
        cache.require(type(estimator).requires)
        return estimator.render(gbuffer, cache, spp, seed)

    def reference(self, gbuffer, cache) -> np.ndarray:
        return Reference(self.compute, use_cache=False).image(gbuffer, cache)


def check_constructible(estimator, h: Harness) -> None:
    cls = type(estimator)
    assert cls.name, "estimator has no name"
    assert dataclasses.is_dataclass(cls.Params), "Params must be a dataclass"
    fresh = cls()
    assert fresh.params == cls.Params(), "default construction must store the default params"


def check_output_shape(estimator, h: Harness) -> None:
    gbuffer, cache = h.inputs(glossy_gbuffer(), smooth_map())
    est = h.render(estimator, gbuffer, cache, 8, 0)
    shape = gbuffer.shape
    assert est.radiance.shape == shape + (3,) and est.radiance.dtype == np.float32, \
        f"radiance must be float32 {shape + (3,)}, got {est.radiance.dtype} {est.radiance.shape}"
    for name in ("used", "effective"):
        array = getattr(est, name)
        assert array.shape == shape, f"{name} must be {shape}, got {array.shape}"


def check_deterministic(estimator, h: Harness) -> None:
    gbuffer, cache = h.inputs(glossy_gbuffer(), smooth_map())
    first = h.render(estimator, gbuffer, cache, 8, 3).radiance
    again = h.render(estimator, gbuffer, cache, 8, 3).radiance
    other = h.render(estimator, gbuffer, cache, 8, 4).radiance
    assert np.array_equal(first, again), "the same seed must give the same image"
    assert not np.array_equal(first, other), "different seeds must give different images"


def check_stress_finite(estimator, h: Harness) -> None:
    failures = []
    for gb_name, gb in (("glossy", glossy_gbuffer()), ("grazing-m1e4", grazing_gbuffer())):
        for map_name, env in stress_maps().items():
            gbuffer, cache = h.inputs(gb, env)
            est = h.render(estimator, gbuffer, cache, 8, 1)
            bad = int(np.count_nonzero(~np.isfinite(est.radiance)))
            negative = int(np.count_nonzero(est.radiance < 0))
            if bad or negative or est.nonfinite:
                failures.append(f"{map_name}/{gb_name}: {bad} non-finite, {negative} negative")
    assert not failures, "; ".join(failures)


def check_sample_counts(estimator, h: Harness) -> None:
    spp = 10
    for env in (smooth_map(), stress_maps()["black-faces"]):
        gbuffer, cache = h.inputs(glossy_gbuffer(), env)
        est = h.render(estimator, gbuffer, cache, spp, 2)
        slack = 1e-4 * spp
        assert np.all(est.effective <= est.used + slack), "effective must not exceed used"
        assert np.all(est.used <= spp + slack), f"used must not exceed the budget {spp}"
        assert np.all(est.effective >= 0), "effective must be non-negative"


# An odd budget (a split in halves leaves fractional samples); a seed at which restir's neighbour
# offsets keep 2e-3 from a rounding tie on count_gbuffer (restir.neighbours_found; seed 1: 9e-6).
COUNT_SPP, COUNT_SEED = 3, 100


def count_configurations(estimator) -> list:
    """The configurations whose counts ``check_work_counts`` holds: the estimator, and on its
    default instance every declared setting's (each parameter that may take another path)."""
    cls = type(estimator)
    if estimator.params != cls.Params():
        return [estimator]
    return [estimator] + [setting_pair(cls, setting)[0] for setting in cls.settings]


def configuration_label(instance) -> str:
    """``name{param=value,...}`` of the parameters off their defaults."""
    default = type(instance).Params()
    changed = [f"{f.name}={getattr(instance.params, f.name)!r}" for f in dataclasses.fields(instance.params)
               if getattr(instance.params, f.name) != getattr(default, f.name)]
    return type(instance).name + (f"{{{','.join(changed)}}}" if changed else "")


def count_differences(label: str, estimate, expected, pixels: int, masked: bool) -> list[str]:
    """Where one render's counts differ from its ``WorkCounts`` (means over ``pixels``; shadow
    rays 0 without masks), to 1e-6 relative."""
    def mean(value) -> float:
        return float(np.mean(np.broadcast_to(np.asarray(value, np.float64), (pixels,))))

    wanted = {"evaluations": mean(expected.evaluations),
              "shadow_rays": mean(expected.shadow_rays) if masked else 0.0,
              **{name: mean(value) for name, value in expected.extras.items()}}
    got = {"evaluations": estimate.evaluations, "shadow_rays": estimate.shadow_rays, **estimate.extras}
    return [f"{label}: {name} {got.get(name)} where the docstring counts {value:.6g}"
            for name, value in wanted.items()
            if not (name in got and np.isclose(got[name], value, rtol=1e-6, atol=1e-9))]


def check_work_counts(estimator, h: Harness) -> None:
    """Every path's counts of work are the docstring's (``Estimator.work_counts``, computed in
    Python from the inputs, never from a render): ``evaluations``, ``shadow_rays`` and the extras
    that count work, on every frame of ``count_frames`` (first, static, a small change, a
    re-initialising jump), on ``count_gbuffer`` with and without visibility masks, for the
    estimator and, on its default instance, each declared setting (biased modes, spatial and
    temporal reuse off, other budgets).  A count that no other check recomputes (a re-initialised
    pixel counted twice, a pass whose shadow rays go uncounted) fails here."""
    failures = []
    caches = [FrameCache(h.compute, env, t) for t, env in enumerate(count_frames())]
    for cache in caches:
        cache.require(type(estimator).requires)
    frames = [CountFrame(cache, COUNT_SPP, COUNT_SEED) for cache in caches]
    for masked in (False, True):
        gb = count_gbuffer(masked)
        gbuffer = DeviceGBuffer(h.compute, gb)
        for instance in count_configurations(estimator):
            expected = instance.work_counts(gb, frames)
            instance.reset()
            for t, (frame, counts) in enumerate(zip(frames, expected, strict=True)):
                estimate = instance.render(gbuffer, frame.cache, frame.spp, frame.seed)
                label = f"{configuration_label(instance)} frame {t}{' masked' if masked else ''}"
                failures += count_differences(label, estimate, counts, gbuffer.count, masked)
    assert not failures, f"{len(failures)} counts off: " + "; ".join(failures[:4])


def check_float_path(estimator, h: Harness) -> None:
    """A device without cl_khr_fp64 runs the float path (``Compute(fp64=False)``: single-precision
    sums where the kernels accumulate in double), and ``iblbench doctor`` holds such a device to
    it; on the portability set's inputs it gives the double path's arrays within
    ``portability.FLOAT_RTOL``, every frame of a temporal estimator included.  (havran once sized
    its accumulators by the device, not by the path built, and was off by about 500×.)"""
    from iblbench.harness.verify import portability

    arrays = {path: portability.render_estimator(compute, type(estimator)(estimator.params))
              for path, compute in (("double", h.compute), ("float", portability.float_path(h.compute)))}
    off = portability.differences(arrays["float"], arrays["double"], exact_integers=False)
    assert not off, "the float path is off the double path: " + ", ".join(
        f"{name} by {value:.2g} (relative)" for name, value in sorted(off.items()))


EFFECTIVE_SEEDS = 40          # renders whose effective shares are averaged per pixel
EFFECTIVE_SPP = 64
EFFECTIVE_GRID = 128          # pdf points per cube face side for the mass above the horizon
EFFECTIVE_FLOOR = 5e-3        # that mass's quadrature error (cells the horizon cuts)


def upper_hemisphere_mass(pdf: Callable, normal: np.ndarray, grid: int = EFFECTIVE_GRID) -> float:
    """∫_{n·ω > 0} pdf(ω) dω by the midpoint rule on ``grid``² cells per face with exact cell
    solid angles (good to about 1/grid: the cells the horizon cuts)."""
    dirs = cubemap.texel_directions(grid).reshape(-1, 3)
    omega = np.broadcast_to(cubemap.texel_solid_angles(grid), (6, grid, grid)).reshape(-1)
    above = dirs @ np.asarray(normal, np.float64) > 0
    return float(np.sum(pdf(dirs[above].astype(np.float32)) * omega[above]))


def check_effective_share(estimator, h: Harness) -> None:
    """Estimators with a pdf (``tags.has_pdf``): each pixel's effective share (effective / used:
    the β-weighted samples with a positive cosine) equals, in the mean over seeds, the mass its
    pdf puts above the horizon, ∫_{n·ω>0} pdf dω: the analytic value the share must not exceed
    in expectation nor fall short of (a count that took every sample as effective gave 1.0).
    z-tests per pixel at family-wise α = 1e-3 (Šidák), the standard error over seeds plus
    ``EFFECTIVE_FLOOR``; the map lights every face, with light below every horizon."""
    gb = glossy_gbuffer(2)
    gbuffer, cache = h.inputs(gb, face_pattern_map())
    cache.require(type(estimator).requires)
    expected = np.array([upper_hemisphere_mass(lambda d: estimator.pdf(cache, n, v, d), n)
                         for n, v in zip(gb.normal.reshape(-1, 3), gb.view.reshape(-1, 3))])
    shares = []
    for seed in range(EFFECTIVE_SEEDS):
        est = h.render(estimator, gbuffer, cache, EFFECTIVE_SPP, seed)
        shares.append((est.effective / np.maximum(est.used, 1e-30)).reshape(-1))
    shares = np.array(shares)
    mean = shares.mean(0)
    z = (mean - expected) / (shares.std(0, ddof=1) / np.sqrt(EFFECTIVE_SEEDS) + EFFECTIVE_FLOOR)
    worst = int(np.argmax(np.abs(z)))
    assert np.abs(z).max() < sidak_z(z.size), \
        (f"effective share {mean[worst]:.4f} at pixel {worst}, but the pdf puts "
         f"{expected[worst]:.4f} of its samples above the horizon (z = {z[worst]:.1f})")


def check_white_furnace(estimator, h: Harness) -> None:
    """A constant map on a white Lambertian integrates to the map's value: the mean over 1000
    seeds is within 3 standard errors of it (a relative error of about 0.1%)."""
    value, seeds = 0.7, 1000
    gbuffer, cache = h.inputs(white_lambertian(), constant_map(value))
    means = np.array([h.render(estimator, gbuffer, cache, 12, s).radiance.mean() for s in range(seeds)])
    se = means.std(ddof=1) / np.sqrt(seeds)
    assert abs(means.mean() - value) <= 3 * se + 1e-6, \
        f"white furnace: mean {means.mean():.6f} vs {value} (3 SE = {3 * se:.2e})"


# ---- statistics shared with ``stress`` -------------------------------------------------------------

# The z-tests' standard-error floor, relative to the reference: the reference's own accuracy
# budget.  A zero-variance exact estimate then scores z = 0, and one off by a constant fails;
# a bias below about 3·REFERENCE_RTOL (3e-4 relative, the reference's measured quadrature
# error) passes whatever the number of seeds.
REFERENCE_RTOL = 1e-4


def sidak_z(tests: int, alpha: float = ALPHA_Z) -> float:
    """|z| above which any of ``tests`` two-sided z-tests rejects, at family-wise ``alpha``."""
    return float(stats.norm.isf(sidak_alpha(alpha, tests) / 2))


def sidak_alpha(alpha: float, tests: int) -> float:
    """The per-test level that gives family-wise level ``alpha`` over ``tests`` independent tests."""
    return float(-np.expm1(np.log1p(-alpha) / max(tests, 1)))


def sidak_p(p_min: float, tests: int) -> float:
    """Family-wise p-value of the smallest of ``tests`` p-values: 1 − (1 − p_min)^tests."""
    return float(-np.expm1(tests * np.log1p(-min(p_min, 1.0)))) if p_min < 1 else 1.0


def two_sided_p(z) -> np.ndarray:
    return 2.0 * stats.norm.sf(np.abs(z))


@dataclasses.dataclass
class BiasTest:
    """z-scores of the mean over seeds against the reference.

    ``pixel_z`` ``[k, 3]`` per tested pixel and channel; ``pooled_z`` ``[3]`` per channel of the
    tested pixels' summed error relative to their summed reference (it sees a bias of ~1% that
    hides in per-pixel noise).  The standard error is the sample one over seeds plus the floor
    ``REFERENCE_RTOL``·|reference| (and a tiny absolute floor, so an exact 0 scores 0)."""

    pixel_z: np.ndarray
    pooled_z: np.ndarray
    mean: np.ndarray          # [k, 3] mean over seeds
    reference: np.ndarray     # [k, 3]

    @property
    def tests(self) -> int:
        return self.pixel_z.size + self.pooled_z.size

    @property
    def max_abs_z(self) -> float:
        return float(max(np.abs(self.pixel_z).max(initial=0.0), np.abs(self.pooled_z).max(initial=0.0)))

    @property
    def p_min(self) -> float:
        return float(two_sided_p(self.max_abs_z))


def _z(difference: np.ndarray, spread: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """difference / (spread + floor); 0 where the difference is exactly 0, ∞ where it is not a
    number (a non-finite estimate must fail, not slip through a comparison with NaN)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(difference == 0, 0.0, difference / (spread + floor))
    return np.where(np.isnan(z), np.inf, z)


def bias_test(samples: np.ndarray, reference: np.ndarray) -> BiasTest:
    """The z-tests of :class:`BiasTest` for ``samples`` ``[seeds, k, 3]`` of k pixels against
    their ``reference`` ``[k, 3]``."""
    samples = np.asarray(samples, np.float64)
    reference = np.asarray(reference, np.float64)
    seeds = len(samples)
    tiny = np.finfo(np.float64).tiny
    floor = REFERENCE_RTOL * np.abs(reference) + tiny
    mean = samples.mean(0)
    pixel_z = _z(mean - reference, samples.std(0, ddof=1) / np.sqrt(seeds), floor)
    total = reference.sum(0)
    pooled = (samples - reference).sum(1) / np.where(total > 0, total, 1.0)      # [seeds, 3]
    pooled_z = _z(pooled.mean(0), pooled.std(0, ddof=1) / np.sqrt(seeds),
                  REFERENCE_RTOL + tiny)
    return BiasTest(pixel_z, pooled_z, mean, reference)


def check_unbiased(estimator, h: Harness) -> None:
    """z-tests of the mean over seeds against the exact reference, on a glossy and a purely
    specular case on ``face_pattern_map`` and a black-faces case.  Two families, each at α = 1e-3 with Šidák correction: the image mean
    per channel (it sees a bias of about 1%) and every pixel and channel."""
    seeds, spp = 1000, 8
    cases = {"glossy": (glossy_gbuffer(), face_pattern_map()),
             "specular-only": (glossy_gbuffer(ks=0.8, kd=0.0), face_pattern_map()),
             "black-faces": (glossy_gbuffer(), stress_maps(8)["black-faces"])}
    failures = []
    for case, (gb, env) in cases.items():
        gbuffer, cache = h.inputs(gb, env)
        reference = h.reference(gbuffer, cache).reshape(-1, 3)
        samples = np.stack([h.render(estimator, gbuffer, cache, spp, s).radiance.reshape(-1, 3)
                            for s in range(seeds)])
        test = bias_test(samples, reference)
        if np.abs(test.pooled_z).max() >= sidak_z(3):
            bias = (test.mean - test.reference).sum(0) / test.reference.sum(0)
            failures.append(f"{case}: image mean off by {np.round(100 * bias, 3)}% "
                            f"(z = {np.round(test.pooled_z, 2)})")
        z = test.pixel_z
        if np.abs(z).max() >= sidak_z(z.size):
            pixel, channel = np.unravel_index(np.argmax(np.abs(z)), z.shape)
            worst = np.unravel_index(pixel, gb.shape)
            failures.append(f"{case}: |z| = {np.abs(z).max():.2f} at pixel {worst} (mean "
                            f"{test.mean[pixel, channel]:.5g}, reference "
                            f"{test.reference[pixel, channel]:.5g})")
    assert not failures, "biased: " + "; ".join(failures)




def _rms_errors(estimator, h: Harness, gbuffer, cache, targets, spps) -> np.ndarray:
    """RMS error ``[targets, spps]`` of the same 6 seeds' renders against each of ``targets``,
    per spp of ``spps``."""
    errors = np.zeros((len(targets), len(spps)))
    for column, spp in enumerate(spps):
        images = np.array([h.render(estimator, gbuffer, cache, spp, s).radiance for s in range(6)])
        errors[:, column] = [np.sqrt(np.mean(np.square(images - target))) for target in targets]
    return errors


def _error_ratio_8_to_128(estimator, h: Harness) -> float:
    """RMS error over 6 seeds at 8 spp divided by that at 128 spp (16× the samples), on
    ``face_pattern_map`` (a face error leaves a bias floor there)."""
    gbuffer, cache = h.inputs(glossy_gbuffer(), face_pattern_map())
    low, high = _rms_errors(estimator, h, gbuffer, cache, [h.reference(gbuffer, cache)], (8, 128))[0]
    return float(low / high)


def check_convergence(estimator, h: Harness) -> None:
    """RMS error falls about as 1/√spp: 16× the samples gives 2.5-6.5× less error (ideal 4)."""
    ratio = _error_ratio_8_to_128(estimator, h)
    assert MIN_ERROR_FALL_8_TO_128 <= ratio <= 6.5, f"error ratio 8→128 spp is {ratio:.2f}, expected ≈ 4"


def check_error_falls(estimator, h: Harness) -> None:
    """For estimators that are not unbiased (``tags.unbiased = False``, e.g. ``havran``'s
    filtered, quasi-random lights): the 1/√spp law need not hold (a stratified or quasi-random
    estimator converges faster, a biased one may level off at its bias), so the check asks only
    that the RMS error falls: 16× the samples gives at least 2.5× less error (as the unbiased
    check's lower bound), on a static map where the error must go to zero with the budget."""
    ratio = _error_ratio_8_to_128(estimator, h)
    assert ratio >= MIN_ERROR_FALL_8_TO_128, f"error ratio 8→128 spp is {ratio:.2f}, expected the error to fall ≥ 2.5×"


LIMIT_SPP = (8, 128, 2048)   # each 16× the last


def check_consistent_limit(estimator, h: Harness) -> None:
    """For biased estimators that state their limit (``tags.has_limit``, e.g. ``fis``): as spp
    grows they converge to the exact integral of the map their ``limit_map(cache)`` hook
    returns (a filtered map), not to the map's.  On ``face_pattern_map`` (glossy pixels), the
    RMS error over 6 seeds against that limit's exact reference must fall at least 2.5× for
    each 16× the samples, 8 → 128 → 2048 spp (the unbiased checks' least fall; an error that
    levels off anywhere fails, as does a stated limit the estimator does not reach).  The error
    against the exact reference then falls from low spp and flattens at the stated bias
    B = RMS(limit − exact) (it stays within the limit error of B, by the triangle inequality);
    the message gives B and both errors at the highest spp."""
    gbuffer, cache = h.inputs(glossy_gbuffer(), face_pattern_map())
    cache.require(type(estimator).requires)
    exact = h.reference(gbuffer, cache)
    limit = h.reference(gbuffer, FrameCache(h.compute, estimator.limit_map(cache)))
    to_limit, to_exact = _rms_errors(estimator, h, gbuffer, cache, [limit, exact], LIMIT_SPP)
    falls = to_limit[:-1] / np.maximum(to_limit[1:], 1e-30)
    bias = float(np.sqrt(np.mean(np.square(limit - exact))))
    assert min(falls) >= MIN_ERROR_FALL_8_TO_128, (
        f"RMS error against the stated limit {', '.join(f'{e:.3g}' for e in to_limit)} at "
        f"{LIMIT_SPP} spp: falls ×{', ×'.join(f'{f:.2f}' for f in falls)}, expected ≥ "
        f"{MIN_ERROR_FALL_8_TO_128} per 16× (stated bias {bias:.3g}, error against the exact "
        f"reference {to_exact[-1]:.3g} at {LIMIT_SPP[-1]} spp)")


CHI2_MAX_BINS = 16        # χ² bins per cube face side at most
CHI2_MIN_POINTS = 64      # pdf evaluations per face side at least (resolves a Phong lobe)
CHI2_STRAY_SHARE = 1e-4   # samples allowed in bins of zero probability (texel-border rounding)


def _chi2_grid(res: int) -> tuple[int, int]:
    """(bins per face side B, pdf evaluation points per bin side) for a map of face size ``res``.

    Bins are blocks of whole texels and the points a midpoint grid aligned with the texels (for
    res ≤ 64), so the integral of a pdf that is smooth inside each texel and jumps between texels
    (a light pdf) is accurate even where one texel holds all of it."""
    bins = max(d for d in range(1, min(res, CHI2_MAX_BINS) + 1) if res % d == 0)
    points = res * max(4, -(-CHI2_MIN_POINTS // res)) if res <= 64 else 4 * CHI2_MIN_POINTS
    return bins, max(1, round(points / bins))


def _bin_probabilities(pdf: Callable, bins: int, points: int) -> np.ndarray:
    """∫_bin pdf dω ``[6·B·B]`` by the midpoint rule on ``points``² cells per bin, each weighted by
    its exact solid angle."""
    fine = bins * points
    dirs = cubemap.texel_directions(fine).reshape(-1, 3).astype(np.float32)
    omega = np.broadcast_to(cubemap.texel_solid_angles(fine), (6, fine, fine))
    values = pdf(dirs).reshape(6, fine, fine) * omega
    return values.reshape(6, bins, points, bins, points).sum(axis=(2, 4)).reshape(-1)


@dataclasses.dataclass
class Chi2Result:
    """A χ² goodness-of-fit of ``sample_directions`` against the integral of its ``pdf`` hook
    over bins of the cube map (``_chi2_grid``; cells expecting < 5 samples pooled into one).

    ``problems`` lists what makes the sampler wrong whatever the χ² says (the pdf returned with
    the samples disagrees with the hook, the hook does not integrate to 1, more than
    ``CHI2_STRAY_SHARE`` of the samples fall where the hook is 0); ``p_value`` is then 0."""

    p_value: float
    observed: np.ndarray      # [6·B·B] sample counts
    expected: np.ndarray      # [6·B·B] n · ∫_bin pdf
    bins: int
    problems: list[str]

    def plot(self, path: pathlib.Path, title: str) -> None:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(3, 1, figsize=(12, 7))
        observed, expected = self.observed, self.expected
        diff = (observed - expected) / np.sqrt(np.maximum(expected, 1))
        for ax, data, name in zip(axes, (observed, expected, diff), ("observed", "expected", "(o-e)/√e")):
            strip = data.reshape(6, self.bins, self.bins).transpose(1, 0, 2).reshape(self.bins, -1)
            im = ax.imshow(strip, aspect="equal")
            ax.set_title(f"{name}: faces {', '.join(cubemap.FACE_NAMES)}")
            ax.set_axis_off()
            fig.colorbar(im, ax=ax)
        fig.suptitle(title)
        fig.savefig(path)
        plt.close(fig)


def chi2_sampling(estimator, cache, normal, view, seed: int, n: int = 200_000) -> Chi2Result | None:
    """:class:`Chi2Result` of ``n`` directions the estimator samples for one (normal, view) on
    ``cache``'s map; None when it samples nothing there (an all-black map)."""
    dirs, sample_pdf = estimator.sample_directions(cache, normal, view, n, seed)
    if len(dirs) == 0:
        return None
    problems = []
    hook_pdf = estimator.pdf(cache, normal, view, dirs)
    # A sample within float rounding of a texel border may be looked up in its neighbour;
    # a wrong Jacobian or texel probability makes (nearly) every sample disagree.
    agree = np.isclose(sample_pdf, hook_pdf, rtol=1e-4, atol=0)
    if agree.mean() <= 0.999:
        problems.append(f"the pdf returned with the samples differs from the pdf hook for "
                        f"{100 * (1 - agree.mean()):.2f}% of samples")
    bins, points = _chi2_grid(cache.res)
    expected = n * _bin_probabilities(lambda d: estimator.pdf(cache, normal, view, d), bins, points)
    if abs(expected.sum() / n - 1) >= 0.01:
        problems.append(f"pdf integrates to {expected.sum() / n:.4f}, not 1")
    face, row, col = cubemap.direction_to_texel(dirs, bins)
    observed = np.bincount((face * bins + row) * bins + col, minlength=expected.size)
    stray = expected == 0
    if observed[stray].sum() > CHI2_STRAY_SHARE * n:
        problems.append(f"{observed[stray].sum()} samples fall where the pdf is zero")
    # Cells expecting < 5 samples are pooled with the next smallest until the pool expects ≥ 5.
    order = np.flatnonzero(~stray)[np.argsort(expected[~stray], kind="stable")]
    pooled = max(np.count_nonzero(expected[order] < 5),
                 int(np.searchsorted(np.cumsum(expected[order]), 5.0)) + 1)
    obs = np.append(observed[order[pooled:]], observed[order[:pooled]].sum())
    exp = np.append(expected[order[pooled:]], expected[order[:pooled]].sum())
    statistic = float(np.sum((obs - exp) ** 2 / exp))
    p_value = 0.0 if problems else (float(stats.chi2.sf(statistic, len(exp) - 1)) if len(exp) > 1 else 1.0)
    return Chi2Result(p_value, observed, expected, bins, problems)


def check_chi2_sampling(estimator, h: Harness) -> None:
    """χ² goodness-of-fit of ``sample_directions`` against the integrated ``pdf`` hook, on the
    map whose every face is asymmetric (``face_pattern_map``)."""
    gb = glossy_gbuffer(2)
    _, cache = h.inputs(gb, face_pattern_map())
    cache.require(type(estimator).requires)
    cases = [(gb.normal[i, j], gb.view[i, j]) for i, j in ((0, 0), (1, 1))]
    limit = sidak_alpha(ALPHA_CHI2, len(cases))
    for case, (normal, view) in enumerate(cases):
        result = chi2_sampling(estimator, cache, normal, view, seed=7 + case)
        assert not result.problems, "; ".join(result.problems)
        if result.p_value < limit:
            folder = pathlib.Path(os.environ.get("IBLBENCH_CHI2_PLOTS", tempfile.gettempdir()))
            folder.mkdir(parents=True, exist_ok=True)
            plot = folder / f"chi2_{type(estimator).name}_{case}.png"
            result.plot(plot, f"{type(estimator).name}: p = {result.p_value:.2e}")
            raise AssertionError(f"χ² rejects the sampler: p = {result.p_value:.2e} < {limit:.2e}; "
                                 f"plot: {plot}")


def check_temporal_consistency(estimator, h: Harness) -> None:
    """Temporal estimators (``Tags.temporal``): frame consistency over a static sequence.

    The other checks render one frame after ``reset()``, which for a temporal estimator is
    only its initialisation; this one runs 4 frames of a static map in order (frame index
    0..3) and asks that (a) every frame is finite and non-negative; (b) ``reset()`` forgets the
    state: the sequence replayed after it is bit-identical; (c) carried state does not drift on
    a static map: the RMS error of the last frame, over 4 seeds, is at most twice the first's.
    The z-test does not apply to temporal estimators tagged biased (their later frames depend
    on the estimates of earlier ones), so this is where their later frames are checked."""
    gb = glossy_gbuffer()
    gbuffer = DeviceGBuffer(h.compute, gb)
    env = smooth_map()
    caches = [FrameCache(h.compute, env, frame) for frame in range(4)]
    for cache in caches:
        cache.require(type(estimator).requires)
    reference = h.reference(gbuffer, caches[0])

    def sequence(seed):
        estimator.reset()
        return [estimator.render(gbuffer, cache, 8, seed).radiance for cache in caches]

    first = sequence(5)
    for t, image in enumerate(first):
        assert np.all(np.isfinite(image)) and np.all(image >= 0), f"frame {t}: non-finite or negative"
    again = sequence(5)
    assert all(np.array_equal(a, b) for a, b in zip(first, again)), \
        "reset() must clear the state: a replayed sequence differs"
    errors = np.array([[np.sqrt(np.mean((image - reference) ** 2)) for image in sequence(s)]
                       for s in range(4)])
    start, end = errors[:, 0].mean(), errors[:, -1].mean()
    assert end <= 2.0 * start + 1e-6, f"error drifts on a static map: RMS {start:.4g} → {end:.4g}"


def switch_frames(res: int = 8) -> list[np.ndarray]:
    """A light switching: ``smooth_map``, then a one-texel sun 1e3× its brightest texel on
    (``sun_map``), the same again, and off (the sky alone), each a frame of its own."""
    sky = smooth_map(res)
    sun = sun_map(res, 1e3)
    sun[sun != sun.max()] = sky[sun != sun.max()]
    return [sky, sun, sun.copy(), sky.copy()]


SEQUENCE_SEEDS = 1000


def sequence_renders(estimator, gbuffer, caches, seeds: int, spp: int) -> np.ndarray:
    """The covered pixels of every frame of ``caches`` for each of ``seeds`` seeds, each seed's
    sequence rendered in order after ``reset()``: ``[seeds, frames, pixels, 3]``."""
    samples = np.zeros((seeds, len(caches), gbuffer.count, 3))
    for seed in range(seeds):
        estimator.reset()
        for t, cache in enumerate(caches):
            samples[seed, t] = estimator.render(gbuffer, cache, spp, seed).radiance[gbuffer.gbuffer.mask]
    return samples


def check_unbiased_over_frames(estimator, h: Harness) -> None:
    """Temporal estimators tagged unbiased: the mean over seeds of every frame of a switching
    sequence (``switch_frames``: on, static, off), each sequence rendered in order after
    ``reset()``, is the frame's exact reference, by ``check_unbiased``'s two z-test families over
    every frame at once (Šidák).  The one-frame z-test sees only an estimator's first frame,
    before it carries anything; this one sees reuse across a map that changes and one that
    does not."""
    gbuffer = DeviceGBuffer(h.compute, glossy_gbuffer())
    caches = [FrameCache(h.compute, env, frame) for frame, env in enumerate(switch_frames())]
    for cache in caches:
        cache.require(type(estimator).requires)
    samples = sequence_renders(estimator, gbuffer, caches, SEQUENCE_SEEDS, 4)
    failures = []
    for t, cache in enumerate(caches):
        test = bias_test(samples[:, t], h.reference(gbuffer, cache)[gbuffer.gbuffer.mask])
        if np.abs(test.pooled_z).max() >= sidak_z(3 * len(caches)):
            failures.append(f"frame {t}: image mean z = {np.round(test.pooled_z, 2)}")
        if np.abs(test.pixel_z).max() >= sidak_z(test.pixel_z.size * len(caches)):
            failures.append(f"frame {t}: pixel |z| = {np.abs(test.pixel_z).max():.2f}")
    assert not failures, "biased over frames: " + "; ".join(failures)


TWIN_FRAMES = 10    # rotating-sun: the init, holds (1, 7, 8) and turning frames (2-6, 9)
# Runs of each of the 5 shading points: the MH misprint scores |z| 7.8 (6.1 at 128), the weight
# update without γ_{t−1} 115; the check costs 1.2-4 s (smc's kernels built).
TWIN_CHAINS = 256
TWIN_SPP = 8


def check_matches_twin(estimator, h: Harness) -> None:
    """Estimators that declare an independent NumPy twin (``twin``, harness/verify/twins): per frame
    of ``rotating-sun`` (a smoothly turning map that never re-initialises), shading point and
    channel, the estimator's and the twin's estimates over ``TWIN_CHAINS`` independent chains
    agree in distribution (harness/verify/twins/crosscheck.py): the means by Welch z, the variances by
    the kurtosis-scaled log ratio, one family at α = 1e-3 (Šidák).  It sees a reweighting or an
    MH acceptance off the paper, which leaves every single frame plausible."""
    from iblbench.harness.verify.twins import crosscheck

    args = (TWIN_FRAMES, TWIN_CHAINS, TWIN_SPP)
    estimates = crosscheck.estimator_runs(h.compute, estimator, *args, seed=1)[0]
    twin = crosscheck.twin_runs(estimator, *args, seed=7)[0]
    tests = {"mean": crosscheck.mean_z(estimates, twin),
             "variance": crosscheck.log_variance_z(estimates, twin)}
    bound = sidak_z(sum(z.size for z in tests.values()))
    failures = []
    for name, z in tests.items():
        worst = np.unravel_index(np.argmax(np.abs(z)), z.shape)
        if not np.abs(z[worst]) < bound:        # NaN fails too
            failures.append(f"{name} |z| = {abs(z[worst]):.1f} at (frame, point, channel) {worst}: "
                            f"mean {estimates.mean(2)[worst]:.4g} vs twin {twin.mean(2)[worst]:.4g}, "
                            f"variance ratio {estimates.var(2)[worst] / twin.var(2)[worst]:.2f}")
    assert not failures, f"off its twin {type(estimator).twin} (|z| bound {bound:.2f}): " + "; ".join(failures)


# ---- settings: each parameter does something, and what its docstring says -----------------------

def setting_pair(cls, setting) -> tuple:
    """(an estimator of ``setting``, one of its base: the same context, the parameter at its
    default)."""
    default = getattr(cls.Params(), setting.parameter)
    return (cls(**{**setting.context, setting.parameter: setting.value}),
            cls(**{**setting.context, setting.parameter: default}))


def check_settings_differ(estimator, h: Harness) -> None:
    """Every parameter of ``Params`` has a declared ``Setting`` off its default (``settings``),
    and each setting renders, at one seed, another image than its base (the same context, the
    parameter at its default): a parameter that is silently ignored renders its default's
    image, which every other check passes when both are unbiased.  16 glossy pixels on
    ``face_pattern_map`` at 8 spp; a temporal estimator renders ``settings_frames`` (a static
    frame, a small and a large change), where state is carried and re-initialised."""
    cls = type(estimator)
    undeclared = sorted({f.name for f in dataclasses.fields(cls.Params)}
                        - {setting.parameter for setting in cls.settings})
    assert not undeclared, (f"parameters with no Setting off their default in {cls.__name__}.settings: "
                            f"{', '.join(undeclared)}")
    frames = settings_frames() if cls.tags.temporal else [face_pattern_map()]
    gbuffer = DeviceGBuffer(h.compute, glossy_gbuffer(4))
    caches = [FrameCache(h.compute, env, frame) for frame, env in enumerate(frames)]
    for cache in caches:
        cache.require(cls.requires)

    def images(instance):
        instance.reset()
        return np.stack([instance.render(gbuffer, cache, 8, 3).radiance for cache in caches])

    same = []
    for setting in cls.settings:
        assert setting.value != getattr(cls.Params(), setting.parameter), \
            f"{setting.parameter} = {setting.value!r} is the default"
        with_setting, base = map(images, setting_pair(cls, setting))
        if np.array_equal(with_setting, base):
            same.append(f"{setting.parameter} = {setting.value!r}"
                        + (f" (with {setting.context})" if setting.context else ""))
    assert not same, f"renders exactly as with the default: {'; '.join(same)}"


def check_setting_properties(estimator, h: Harness) -> None:
    """Each setting that ``says`` what it does is held to that (``SETTING_PROPERTIES``), and so
    is its base."""
    cls = type(estimator)
    failures = []
    for setting in cls.settings:
        if not setting.says:
            continue
        check = SETTING_PROPERTIES.get(setting.says)
        if check is None:
            failures.append(f"{setting.parameter}: no property check '{setting.says}' (known: "
                            f"{', '.join(SETTING_PROPERTIES)})")
            continue
        try:
            check(cls, setting, h)
        except AssertionError as error:
            failures.append(f"{setting.parameter} = {setting.value!r} ({setting.says}): {error}")
    assert not failures, "; ".join(failures)


def says_shared_sequence(cls, setting, h: Harness) -> None:
    """``shared_sequence`` (Lu 2013 Sec. 2.2): every pixel reads the same pool samples and BRDF
    numbers, so 35 pixels of one normal, view and material render one value, bit for bit; off,
    each reads its own window and they take several."""
    gb = glossy_gbuffer(2)
    gbuffer, cache = h.inputs(same_pixels(gb.normal[1, 1], gb.view[1, 1]), face_pattern_map())
    for instance in setting_pair(cls, setting):
        image = h.render(instance, gbuffer, cache, 8, 3).radiance.reshape(-1, 3)
        values = len(np.unique(image, axis=0))
        shared = instance.params.shared_sequence
        assert (values == 1) == shared, (f"shared_sequence = {shared}, yet pixels of identical "
                                         f"inputs take {values} value(s)")


def phong_pdf(normal, view, dirs, kd: float = 0.5, ks: float = 0.3, shininess: float = 20.0):
    """ARCHITECTURE.md §Conventions's Phong sampling density of a grey material (the hooks' by default):
    (1 − p_s)·cos⁺(n,ω)/π + p_s·(m+1)/(2π)·cos⁺(r,ω)^m, p_s = ks/(kd + ks)."""
    n = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    v = np.asarray(view, np.float64) / np.linalg.norm(view)
    r = 2 * (n @ v) * n - v
    share = ks / (kd + ks)
    return ((1 - share) * np.maximum(dirs @ n, 0) / np.pi
            + share * (shininess + 1) / (2 * np.pi) * np.maximum(dirs @ r, 0) ** shininess)


def says_mis_brdf(cls, setting, h: Harness) -> None:
    """``mis = "brdf"``: half the samples from the Phong BRDF, so the pdf hook is ½ the
    light-only (base) pdf + ½ ``phong_pdf``, within 1e-4, at 2048 directions for two surfaces."""
    gb = glossy_gbuffer(2)
    _, cache = h.inputs(gb, face_pattern_map())
    cache.require(cls.requires)
    mixed, light = setting_pair(cls, setting)
    dirs = fibonacci_directions(2048).astype(np.float32)
    for n, v in ((gb.normal[0, 0], gb.view[0, 0]), (gb.normal[1, 1], gb.view[1, 1])):
        expected = 0.5 * light.pdf(cache, n, v, dirs) + 0.5 * phong_pdf(n, v, dirs)
        np.testing.assert_allclose(mixed.pdf(cache, n, v, dirs), expected, rtol=1e-4, atol=1e-7)


def mis_variances(normal, res: int, grid: int = 64) -> dict[str, float]:
    """Per heuristic, the variance of the estimate of one light and one BRDF sample under MIS
    (``envmap``'s budget at 2 spp) for a white Lambertian (ρ = 1/π, BRDF samples cos⁺/π) under
    a unit constant map of face size ``res``, by the midpoint rule on ``grid``² cells per face
    (texel-aligned).  The light density of Y·Ω texel weights with a point uniform in the
    texel's face square is (Ω_t/4π)·(1 + x² + y²)^{3/2}/(2/res)² (ARCHITECTURE.md §Conventions).  Each strategy k
    contributes Var_k[w_k f/p_k] = ∫ w_k² f²/p_k dω − (∫ w_k f dω)², the weights w_k =
    p_k^β/Σ_j p_j^β (β = 1 balance, 2 power; one sample each)."""
    dirs = cubemap.texel_directions(grid).reshape(-1, 3)
    omega = np.broadcast_to(cubemap.texel_solid_angles(grid), (6, grid, grid)).reshape(-1)
    _, s, t = cubemap.direction_to_face_st(dirs)
    _, row, col = cubemap.direction_to_texel(dirs, res)
    x, y = 2 * s - 1, 2 * t - 1   # the face square's coordinates
    p_light = (cubemap.texel_solid_angles(res)[row, col] / (4 * np.pi)
               * (1 + x * x + y * y) ** 1.5 / (2.0 / res) ** 2)
    cosine = np.maximum(dirs @ (np.asarray(normal, np.float64) / np.linalg.norm(normal)), 0)
    f = p_brdf = cosine / np.pi
    variances = {}
    for heuristic, beta in (("balance", 1), ("power", 2)):
        total = p_light ** beta + p_brdf ** beta
        variance = 0.0
        for p in (p_light, p_brdf):
            w = p ** beta / total
            second = np.divide(w * w * f * f, p, out=np.zeros_like(p), where=p > 0)
            variance += np.sum(second * omega) - np.sum(w * f * omega) ** 2
        variances[heuristic] = float(variance)
    return variances


HEURISTIC_SEEDS = 40


def says_mis_heuristic(cls, setting, h: Harness) -> None:
    """``heuristic``: the MIS weights are the named heuristic's, which changes the variance, not
    the mean: 256 pixels × ``HEURISTIC_SEEDS`` seeds of a white Lambertian under a constant map
    at 2 spp have the variance ``mis_variances`` gives for the setting's heuristic (and the
    base's for its own), to 4 standard errors of the sample variance plus 1% (quadrature); the
    two heuristics' variances lie 1.9× apart, many standard errors."""
    res, normal = 8, np.array([0.3, 0.5, 0.81])
    gbuffer, cache = h.inputs(same_pixels(normal, normal, 16, 16, 1.0, 0.0, 1.0), constant_map(1.0, res))
    expected = mis_variances(normal, res)
    for instance in setting_pair(cls, setting):
        values = np.concatenate([h.render(instance, gbuffer, cache, 2, seed).radiance[..., 1].ravel()
                                 for seed in range(HEURISTIC_SEEDS)]).astype(np.float64)
        centred = values - values.mean()
        variance = centred.var(ddof=1)
        se = np.sqrt((np.mean(centred ** 4) - variance ** 2) / len(values))
        named, other = instance.params.heuristic, {"balance": "power", "power": "balance"}
        assert abs(expected[other[named]] - expected[named]) > 10 * se, "the fixture cannot tell them apart"
        assert abs(variance - expected[named]) <= 4 * se + 0.01 * expected[named], (
            f"heuristic {named!r}: variance {variance:.4f} ± {se:.4f}, expected {expected[named]:.4f} "
            f"({other[named]} would give {expected[other[named]]:.4f})")


def says_mis_compensation(cls, setting, h: Harness) -> None:
    """``mis_compensation`` (``FrameCache.light_cdfs``): the light samples follow
    max(Y − Ȳ, min(Ȳ/1000, Y))·Ω, Ȳ = Σ Y·Ω/4π, not Y·Ω.  Below the horizon of a surface seen
    head-on the Phong density is 0 and the pdf hook is the light samples' alone; there, at each
    texel's centre, hook(compensated)/hook(base) is w_c/Y times a constant per face (the faces'
    shares of the budget may change), within 1e-4, on ``face_pattern_map``, where that ratio
    itself spans orders of magnitude within a face (Y − Ȳ on a blob, Ȳ/1000 around it)."""
    env = face_pattern_map()
    res = env.shape[1]
    _, cache = h.inputs(glossy_gbuffer(2), env)
    cache.require(cls.requires)
    normal = np.array([0.3, 0.5, 0.81])
    dirs = cubemap.texel_directions(res).reshape(-1, 3)
    below = dirs @ normal < 0
    compensated, plain = (instance.pdf(cache, normal, normal, dirs.astype(np.float32)).astype(np.float64)
                          for instance in setting_pair(cls, setting))
    y = cubemap.luminance(env.astype(np.float64)).reshape(-1)
    mean = np.sum(y * np.tile(cubemap.texel_solid_angles(res).reshape(-1), 6)) / (4 * np.pi)
    weight = np.maximum(y - mean, np.minimum(mean / 1000, y))
    faces = np.repeat(np.arange(6), res * res)
    spans = []
    for face in range(6):
        where = below & (faces == face) & (plain > 0)
        if where.sum() < 2:
            continue
        ratio = compensated[where] / plain[where]
        scaled = ratio * y[where] / weight[where]
        assert scaled.max() <= scaled.min() * (1 + 1e-4), (
            f"face {face}: compensated/plain light pdf over w_c/Y spans "
            f"{scaled.min():.6g}..{scaled.max():.6g}")
        spans.append(ratio.max() / ratio.min())
    assert max(spans, default=0) > 10, "the fixture does not tell the weights apart"


def says_fir_taps(cls, setting, h: Harness) -> None:
    """``fir_taps``: each frame's light weights are the taps' mean of the last frames' raw
    weights, newest first, renormalised over the frames there are (``(1.0,)``: the raw ones):
    on a constant map whose value changes every frame (so the lights keep their directions),
    weights_t = Σ_j a_j raw_{t−j} / Σ_j a_j, within 1e-12."""
    k, seed = 16, 3
    for instance in setting_pair(cls, setting):
        taps, raw = instance.params.fir_taps, []
        for frame, value in enumerate((0.7, 1.4, 0.35, 2.8)):
            cache = FrameCache(h.compute, constant_map(value), frame)
            raw.insert(0, instance.raw_lights(cache, k, seed)[1])
            _, weights = instance.lights(cache, k, seed)
            used = taps[:len(raw)]
            expected = sum(tap * past for tap, past in zip(used, raw)) / sum(used)
            np.testing.assert_allclose(weights, expected, rtol=1e-12, err_msg=f"taps {taps}, frame {frame}")


def says_history_cap(cls, setting, h: Harness) -> None:
    """``history_cap`` (RTXDI's M-cap): a reservoir's history counts at most history_cap × M
    candidates, so on a static map without spatial reuse (the setting's context) every
    reservoir's confidence settles at exactly (history_cap + 1)·M, the ``confidence`` extra in
    units of M, after history_cap + 1 frames."""
    gbuffer, cache = h.inputs(glossy_gbuffer(4), smooth_map())
    cache.require(cls.requires)
    for instance in setting_pair(cls, setting):
        cap = instance.params.history_cap
        instance.reset()
        for _ in range(int(cap) + 3):
            confidence = instance.render(gbuffer, cache, 2, 1).extras["confidence"]
        assert confidence == cap + 1, (f"history_cap = {cap}: the confidence settles at {confidence} M, "
                                       f"not {cap + 1} M")


# What a Setting ``says``: the check of the property its parameter's docstring states.
SETTING_PROPERTIES = {"shared_sequence": says_shared_sequence, "mis_brdf": says_mis_brdf,
                      "mis_heuristic": says_mis_heuristic, "mis_compensation": says_mis_compensation,
                      "fir_taps": says_fir_taps, "history_cap": says_history_cap}


def skipped_checks(estimator) -> dict[str, str]:
    """Checks that do not apply to this estimator and why (reported, not run)."""
    skipped = {}
    if not getattr(type(estimator), "twin", ""):
        skipped["check_matches_twin"] = ("no independent NumPy twin declared (class attribute twin, "
                                         "harness/verify/twins)")
    if type(estimator).work_counts is Estimator.work_counts:
        skipped["check_work_counts"] = "no count formula declared (Estimator.work_counts)"
    return skipped


def check_timing(estimator, h: Harness) -> None:
    gbuffer, cache = h.inputs(glossy_gbuffer(), smooth_map())
    timings = h.render(estimator, gbuffer, cache, 8, 0).timings_ms
    assert set(timings) & {"sample", "shade"}, "render must time its 'sample' and/or 'shade' stages"
    assert all(np.isfinite(v) and v >= 0 for v in timings.values()), f"bad timings {timings}"


def yield_checks(estimator) -> Iterator[Callable]:
    """The checks that apply to this estimator's tags, in a fixed order."""
    tags = estimator.tags   # an instance's: a parameter may choose a biased mode (restir)
    yield check_constructible
    yield check_output_shape
    if tags.deterministic:
        yield check_deterministic
    # Cheap checks that see most bugs first, the ones that build and render every variant
    # (settings, float path, counts) last: the mutation suite's conformance layer stops at the
    # first failure, and check_estimator runs them all either way.
    yield check_stress_finite
    yield check_sample_counts
    yield check_white_furnace
    if tags.unbiased:
        yield check_unbiased
        yield check_convergence
    elif tags.has_limit:        # biased toward a stated limit: it must reach that limit
        yield check_consistent_limit
    else:                       # no z-test, and no 1/√spp law: only that the error falls
        yield check_error_falls
    if tags.has_pdf:
        yield check_chi2_sampling
        yield check_effective_share
    if tags.temporal:
        yield check_temporal_consistency
        if tags.unbiased:
            yield check_unbiased_over_frames
    if "check_matches_twin" not in skipped_checks(estimator):
        yield check_matches_twin
    # Of the class, so on its default instance only (a variant would repeat them).
    if dataclasses.fields(type(estimator).Params) and estimator.params == type(estimator).Params():
        yield check_settings_differ
        if any(setting.says for setting in type(estimator).settings):
            yield check_setting_properties
    yield check_float_path
    if "check_work_counts" not in skipped_checks(estimator):
        yield check_work_counts
    yield check_timing


def check_estimator(estimator, expected_failed_checks: dict[str, str] | None = None,
                    compute=None) -> dict[str, str]:
    """Run every applicable check; returns ``{check: "passed" | "xfail: reason" | "skipped: reason"}``
    (``skipped_checks``).

    ``expected_failed_checks`` maps check names to the reason they are known to fail; those
    are run and reported, not raised.  Any other failure raises ``AssertionError`` naming all
    failed checks.
    """
    expected = expected_failed_checks or {}
    h = Harness(compute or get_compute())
    outcome = {name: f"skipped: {why}" for name, why in skipped_checks(estimator).items()}
    failures = []
    for check in yield_checks(estimator):
        try:
            check(estimator, h)
            outcome[check.__name__] = "passed"
        except AssertionError as error:
            if check.__name__ in expected:
                outcome[check.__name__] = f"xfail: {expected[check.__name__]}"
            else:
                failures.append(f"{check.__name__}: {error}")
    if failures:
        raise AssertionError(f"{type(estimator).name} fails conformance:\n  " + "\n  ".join(failures))
    return outcome


def parametrize_with_checks(estimators, expected_failed_checks: Callable | None = None):
    """A ``pytest.mark.parametrize`` over (estimator, check) pairs, driven by ``yield_checks``.

    ``expected_failed_checks(estimator)`` may return ``{check_name: reason}``; those cases are
    marked ``xfail`` with the reason.
    """
    import pytest

    params = []
    for estimator in estimators:
        known = expected_failed_checks(estimator) if expected_failed_checks else {}
        for check in yield_checks(estimator):
            marks = [pytest.mark.xfail(reason=known[check.__name__], strict=False)] \
                if check.__name__ in known else []
            params.append(pytest.param(estimator, _bound(check), marks=marks,
                                       id=f"{type(estimator).name}-{check.__name__}"))
        for name, why in skipped_checks(estimator).items():
            params.append(pytest.param(estimator, None, marks=pytest.mark.skip(reason=why),
                                       id=f"{type(estimator).name}-{name}"))
    return pytest.mark.parametrize("estimator, check", params)


def _bound(check: Callable) -> Callable:
    """A check that makes its own Harness, for use as a pytest parameter."""
    def run(estimator):
        check(estimator, Harness(get_compute()))
    run.__name__ = check.__name__
    return run
