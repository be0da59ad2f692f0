"""Protocol lab-reinhard-v1 against hand-computed values."""
import numpy as np
import pytest

from iblbench.estimators.base import Estimate
from iblbench.harness.protocol import metric, metrics


def cie_lightness(y):
    """L* of relative luminance y (white = 1), the CIE 1976 formula."""
    eps, kappa = 216 / 24389, 24389 / 27
    return np.where(y > eps, 116 * np.cbrt(y) - 16, kappa * y)


def grey_image(values, shape=(4, 4)):
    image = np.empty(shape + (3,), np.float32)
    image[...] = np.asarray(values, np.float32).reshape(-1, 1)[: shape[0] * shape[1]].reshape(shape + (1,))
    return image


def test_exposure_is_0_18_over_log_average():
    reference = grey_image(np.repeat([0.5, 2.0], 8))
    mask = np.ones((4, 4), bool)
    assert metrics.exposure(reference, mask) == pytest.approx(0.18 / np.sqrt(0.5 * 2.0), rel=1e-5)
    mask[:2] = False   # only covered pixels count: all 2.0 there
    assert metrics.exposure(reference, mask) == pytest.approx(0.18 / 2.0, rel=1e-5)


def test_reinhard_on_luminance_keeps_chromaticity():
    rgb = np.array([[2.0, 1.0, 0.5]])
    k = 0.3
    out = metrics.tonemap(rgb, k)
    y = 0.2126 * 2.0 + 0.7152 * 1.0 + 0.0722 * 0.5
    assert metrics.luminance(out)[0] == pytest.approx(k * y / (1 + k * y))
    assert out[0] / out[0, 1] == pytest.approx(rgb[0] / rgb[0, 1])


def test_delta_e76_of_greys_is_the_lightness_difference():
    reference = grey_image(np.full(16, 1.0))
    estimate = grey_image(np.full(16, 1.5))
    mask = np.ones((4, 4), bool)
    de76, de2000 = metrics.delta_e_images(estimate, reference, mask)
    k = 0.18   # log-average of the reference is 1
    y_ref, y_est = k * 1.0 / (1 + k * 1.0), k * 1.5 / (1 + k * 1.5)
    # sRGB grey is D65 white, so a* = b* = 0 and ΔE76 = |ΔL*|; ΔE2000 differs from ΔE76 for greys.
    assert de76 == pytest.approx(abs(cie_lightness(y_est) - cie_lightness(y_ref)), rel=1e-4)
    assert np.all(de2000 > 0) and not np.allclose(de2000, de76)
    assert np.all(metrics.delta_e_images(reference, reference, mask)[0] == 0)


def test_rel_mse_closed_form():
    reference = grey_image(np.full(16, 0.1))
    estimate = grey_image(np.full(16, 0.3))
    mask = np.ones((4, 4), bool)
    assert metrics.rel_mse(estimate, reference, mask) == pytest.approx(0.2 ** 2 / (0.01 + 0.01))


def test_score_counts_nonfinite_and_scores_them_as_black():
    reference = grey_image(np.full(16, 1.0))
    radiance = reference.copy()
    radiance[0, 0] = np.nan
    mask = np.ones((4, 4), bool)
    estimate = Estimate(radiance, np.full((4, 4), 8.0, np.float32), np.full((4, 4), 4.0, np.float32),
                        8.0, 3, {"shade": 1.0})
    row, de76 = metrics.score(estimate, reference, mask)
    black = reference.copy()
    black[0, 0] = 0
    assert row["nonfinite"] == 3 and np.isfinite(row["mean_delta_e76"])
    assert row["mean_delta_e76"] == pytest.approx(metrics.delta_e_images(black, reference, mask)[0].mean())
    assert de76[0, 0] > 0 and np.all(de76.ravel()[1:] == 0)
    assert row["effective_ratio"] == pytest.approx(0.5)


def test_hdr_flip_is_zero_for_identical_images_and_grows_with_error():
    pytest.importorskip("flip_evaluator")
    rng = np.random.default_rng(0)
    reference = rng.random((32, 32, 3)).astype(np.float32) * 4
    mask = np.zeros((32, 32), bool)
    mask[4:28, 4:28] = True
    assert metrics.hdr_flip(reference, reference, mask) == 0
    small = metrics.hdr_flip(reference * 1.05, reference, mask)
    large = metrics.hdr_flip(reference * 1.5, reference, mask)
    assert 0 < small < large


def test_hdr_flip_ignores_scale_and_is_nan_on_a_black_reference():
    # FLIP exits the whole process on the degenerate exposure range of a black or very dim
    # reference (found by tests/test_fuzz.py with a black environment).
    pytest.importorskip("flip_evaluator")
    reference = np.random.default_rng(1).random((16, 16, 3)).astype(np.float32) * 4
    mask = np.ones((16, 16), bool)
    bright = metrics.hdr_flip(reference * 1.2, reference, mask)
    assert metrics.hdr_flip(reference * 1.2e-30, reference * 1e-30, mask) == pytest.approx(bright, rel=1e-4)
    assert np.isnan(metrics.hdr_flip(reference, np.zeros_like(reference), mask))


# Sharma, Wu & Dalal (2005), "The CIEDE2000 color-difference formula", Table 1 (pairs 1, 2, 7, 17).
SHARMA_PAIRS = [
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, 3.1571, -77.2803), (50.0, 0.0, -82.7485), 2.8615),
    ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
]


@pytest.mark.parametrize("lab_a, lab_b, expected", SHARMA_PAIRS)
def test_delta_e2000_matches_sharma_test_data(lab_a, lab_b, expected):
    de76, de2000 = metrics.lab_differences(np.array(lab_a), np.array(lab_b))
    assert de2000 == pytest.approx(expected, abs=1e-4)
    assert de76 == pytest.approx(np.linalg.norm(np.subtract(lab_a, lab_b)))



def colour_science():
    """colour-science, an independent implementation of the protocol's colour formulas."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # colour warns about optional packages at import
        import colour
    return colour


def random_lab_pairs(n, seed):
    """L*a*b* pairs: random colours, close ones, greys, one zero chroma, and hues 180° ± 0.5° apart
    (where the mean hue switches branch)."""
    rng = np.random.default_rng(seed)
    lab = np.stack([rng.uniform(0, 100, n), rng.normal(0, 40, n), rng.normal(0, 40, n)], -1)
    close = lab + rng.normal(0, 3, (n, 3)) * rng.random((n, 1)) ** 2
    grey = lab * [1, 0, 0]
    angle = np.radians(180 + rng.uniform(-0.5, 0.5, n))
    cos, sin = np.cos(angle), np.sin(angle)
    opposite = np.stack([lab[:, 0] + 1, 0.9 * (lab[:, 1] * cos - lab[:, 2] * sin),
                         0.9 * (lab[:, 1] * sin + lab[:, 2] * cos)], -1)
    first = np.concatenate([lab, lab, lab, grey, lab, grey])
    second = np.concatenate([rng.permutation(lab), close, opposite, lab, grey, grey[::-1]])
    return first, second


def test_delta_e_agrees_with_colour_science():
    colour = colour_science()
    first, second = random_lab_pairs(100_000, 7)
    de76, de2000 = metrics.lab_differences(first, second)
    for mine, method in ((de76, "CIE 1976"), (de2000, "CIE 2000")):
        theirs = colour.delta_E(first, second, method=method)
        assert np.abs(mine - theirs).max() < 1e-5, method
        assert np.abs(mine - theirs).max() <= 1e-9 * theirs.max() + 1e-5
    # ΔE2000 is symmetric, as its formula is.
    assert np.allclose(metrics.lab_differences(second, first)[1], de2000, atol=1e-9)


def test_lab_agrees_with_colour_science():
    colour = colour_science()
    rgb = np.random.default_rng(8).random((10_000, 3)) ** 3   # dark colours: the linear segment too
    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    xyz = colour.RGB_to_XYZ(rgb, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
    assert np.abs(metrics.to_lab(rgb) - colour.XYZ_to_Lab(xyz, d65)).max() < 1e-10
    # sRGB white is D65 white, within the rounding of the printed matrix
    assert np.abs(metrics.to_lab(np.ones(3)) - [100, 0, 0]).max() < 1e-2


class CountingFlip:
    """A stand-in for flip_evaluator that counts its evaluations (and scores the mean absolute
    difference, so the scores still mean something)."""

    def __init__(self):
        self.calls = []

    def evaluate(self, reference, test, mode, applyMagma=False, computeMeanError=True,
                 parameters=None):
        self.calls.append("range" if parameters is None else "image")
        error = np.abs(np.asarray(test) - np.asarray(reference)).mean(axis=-1, keepdims=True)
        return error, None, {"startExposure": -1.0, "stopExposure": 1.0, "numExposures": 3}


def test_a_scorer_evaluates_flip_once_per_estimate_and_its_range_once(monkeypatch):
    fake = CountingFlip()
    monkeypatch.setattr(metrics, "_flip", lambda: fake)
    reference = grey_image(np.linspace(0.5, 2.0, 16))
    mask = np.ones((4, 4), bool)
    scorer = metrics.Scorer(reference, mask)
    for scale in (1.0, 1.1, 1.5):
        estimate = Estimate(reference * scale, np.ones((4, 4), np.float32),
                            np.ones((4, 4), np.float32), 1.0, 0, {})
        row, _ = scorer.score(estimate)
        assert np.isfinite(row["flip"])
    assert fake.calls == ["range", "image", "image", "image"]
    # Left out, FLIP is never evaluated and scores NaN; so is ΔE2000.
    fake.calls.clear()
    row, _ = metrics.score(estimate, reference, mask, metric.parse_metrics("relmse"))
    assert fake.calls == [] and np.isnan(row["flip"]) and np.isnan(row["mean_delta_e2000"])
    assert np.isfinite(row["mean_delta_e76"]) and np.isfinite(row["rel_mse"])


def test_parse_metrics_keeps_de76_and_names_the_valid_ones():
    assert metric.parse_metrics("flip, DE2000") == ("de76", "de2000", "flip")
    with pytest.raises(ValueError, match="unknown metric 'de99'; valid: de76,de2000,relmse,flip"):
        metric.parse_metrics("de76,de99")


def test_the_default_metrics_and_their_columns_are_the_four_of_the_protocol():
    assert metric.default_names() == ("de76", "de2000", "relmse", "flip")
    assert metric.columns()[:4] == ["mean_delta_e76", "mean_delta_e2000", "rel_mse", "flip"]
    assert metric.replicated_columns()[:3] == ("mean_delta_e76", "mean_delta_e2000", "rel_mse")


def test_every_registered_metric_reaches_the_table_the_flags_compare_and_budgets():
    """What reads the registry: a metric registered is a column (and a replicate column where
    it has replicates), a --metrics name, a compare metric and a budgets limit."""
    from iblbench.harness.protocol.results import COLUMNS
    from iblbench.harness.protocol.budgets import DERIVED_METRICS, LIMIT_KEYS
    from iblbench.harness.protocol.compare import HIGHER_IS_BETTER, METRICS

    for descriptor in metric.registered():
        assert descriptor.column in COLUMNS and descriptor.column in METRICS
        assert (descriptor.column + "_renders" in COLUMNS) == descriptor.replicated
        assert metric.parse_metrics(descriptor.name) == tuple(
            m.name for m in metric.registered() if m.always or m is descriptor)
        assert (descriptor.column in HIGHER_IS_BETTER) != descriptor.lower_is_better
        for kind in ("max", "min"):
            assert (f"{kind}_{descriptor.column}" in LIMIT_KEYS) == (kind in descriptor.budget_limits)
        assert (descriptor.column in DERIVED_METRICS) == descriptor.derive_budget
