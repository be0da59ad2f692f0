"""The one aggregation (harness/protocol/stats.py): hand-computed cases with table t quantiles, and
coverage simulated with stated tolerances."""
import math

import numpy as np
import pytest

from iblbench.harness.protocol.stats import (cell_intervals, interval_text, median_ci, mean_ci,
                                             ratio_ci, renders_text, separated,
                                             skew_corrected_ci, t_quantile)

# Two-sided 95% critical values of Student's t from printed tables (e.g. NIST/SEMATECH
# e-Handbook 1.4.2.5.2, upper 0.025 point).
T_TABLE = {1: 12.706, 2: 4.303, 4: 2.776, 9: 2.262, 29: 2.045, 120: 1.980}


@pytest.mark.parametrize("df, expected", sorted(T_TABLE.items()))
def test_t_quantile_matches_tables(df, expected):
    assert t_quantile(df) == pytest.approx(expected, abs=6e-4)


def test_mean_interval_by_hand():
    # [1, 2, 3, 4, 5]: mean 3, s = √2.5, half-width t(4) · s/√5 = 2.776 · 0.70711 = 1.9632.
    ci = mean_ci([1, 2, 3, 4, 5])
    assert (ci.mean, ci.n) == (3.0, 5)
    assert ci.sd == pytest.approx(math.sqrt(2.5))
    assert (ci.low, ci.high) == pytest.approx((3 - 1.9632, 3 + 1.9632), abs=2e-3)


def test_one_seed_has_no_interval():
    ci = mean_ci([2.5])
    assert ci.mean == 2.5 and not ci.resolved and math.isnan(ci.low)
    assert "no interval" in ci.text()
    ratio = ratio_ci([2.0], [3.0, 3.2])
    assert ratio.ratio == pytest.approx(3.1 / 2.0)
    assert not ratio.resolved and not ratio.significant and "n=1" in ratio.reason


def test_ratio_interval_by_hand():
    # A = [1, 2, 3]: mean 2, s² = 1; B = [2, 4, 6]: mean 4, s² = 4.  Relative variances of the
    # means 1/(3·4) = 4/(3·16) = 1/12, se = √(1/6), Welch df = (1/6)² / (2 · (1/144)/2) = 4,
    # interval 2 · exp(± 2.776 · 0.40825) = [0.6439, 6.212].
    ratio = ratio_ci([1, 2, 3], [2, 4, 6])
    assert ratio.ratio == pytest.approx(2.0)
    assert ratio.df == pytest.approx(4.0)
    assert (ratio.low, ratio.high) == pytest.approx((0.6439, 6.212), rel=2e-3)
    assert not ratio.significant


def test_constant_samples_give_a_point_interval():
    same = ratio_ci([3.0, 3.0, 3.0], [3.0, 3.0, 3.0])
    assert (same.low, same.ratio, same.high) == (1.0, 1.0, 1.0) and not same.significant
    shifted = ratio_ci([1.0, 1.0], [0.9, 0.9])
    assert shifted.high == pytest.approx(0.9) and shifted.significant


def test_undefined_ratios_say_why():
    assert "positive" in ratio_ci([0.0, 0.0], [1.0, 2.0]).reason
    assert "NaN" in ratio_ci([1.0, math.nan], [1.0, 2.0]).reason
    assert not ratio_ci([0.0, 0.0], [1.0, 2.0]).significant


def test_separated():
    assert separated(mean_ci([1.0, 1.1, 0.9]), mean_ci([5.0, 5.1, 4.9]))
    assert not separated(mean_ci([1.0, 2.0, 3.0]), mean_ci([2.5, 3.5, 4.5]))
    assert not separated(mean_ci([1.0]), mean_ci([5.0, 5.1]))


def _binomial_band(p: float, trials: int, sigmas: float = 4.0) -> float:
    return sigmas * math.sqrt(p * (1 - p) / trials)


def test_mean_interval_coverage():
    """Exact for normal data: coverage 0.95 within 4 binomial σ of 4000 trials (± 0.014)."""
    rng = np.random.default_rng(11)
    trials, true_mean = 4000, 5.0
    covered = 0
    for n in (2, 4, 8, 16):
        for _ in range(trials // 4):
            ci = mean_ci(rng.normal(true_mean, 1.5, n))
            covered += ci.low <= true_mean <= ci.high
    assert abs(covered / trials - 0.95) < _binomial_band(0.95, trials)


@pytest.mark.parametrize("n_a, n_b, cv_a, cv_b", [(4, 4, 0.15, 0.15), (6, 8, 0.05, 0.25),
                                                  (8, 8, 0.3, 0.3)])
def test_ratio_interval_coverage(n_a, n_b, cv_a, cv_b):
    """Normal seeds with coefficients of variation up to 0.3 per seed (a benchmark's ΔE spread
    over seeds is 5-40%): the log-scale delta interval covers the true ratio 95% ± 0.03 of
    3000 trials (binomial 4σ is 0.016; the rest allows the approximation's own error), and its
    false-positive rate under equal means is therefore within 5% ± 0.03."""
    rng = np.random.default_rng(n_a * 100 + n_b)
    trials, mean_a = 3000, 2.0
    for true_ratio in (1.0, 1.3):
        mean_b = mean_a * true_ratio
        covered = 0
        for _ in range(trials):
            ci = ratio_ci(rng.normal(mean_a, cv_a * mean_a, n_a),
                          rng.normal(mean_b, cv_b * mean_b, n_b))
            covered += ci.low <= true_ratio <= ci.high
        assert abs(covered / trials - 0.95) < 0.03, (true_ratio, covered / trials)


def test_ratio_detects_a_real_difference():
    """A 20% increase at 8 seeds with a 5% spread per seed is flagged (power ≫ 0.99: the
    expected z is 0.2 / (0.05·√(2/8)) ≈ 8); ratio_ci's verdict is checked on 200 draws."""
    rng = np.random.default_rng(3)
    flagged = sum(ratio_ci(rng.normal(1.0, 0.05, 8), rng.normal(1.2, 0.06, 8)).low > 1
                  for _ in range(200))
    assert flagged == 200


# ---- issue 23: medians of timed renders, paired ratios, replicates ----------------------------

def test_median_interval_of_few_values_is_their_range_at_its_own_level():
    """Below 6 values no pair of order statistics reaches 95%: the range, at γ = 1 − 2/2ⁿ."""
    for n, level in ((2, 0.5), (3, 0.75), (4, 0.875), (5, 0.9375)):
        ci = median_ci(np.arange(n, 0, -1.0))
        assert (ci.low, ci.high, ci.level) == (1.0, float(n), pytest.approx(level))
    assert not median_ci([3.0]).resolved


@pytest.mark.parametrize("n", [6, 10, 25])
@pytest.mark.parametrize("draw", ["exponential", "lognormal"])
def test_median_interval_coverage(n, draw):
    """Hettmansperger-Sheather's interval covers the true median in 93-97% of 4000 samples of
    skewed times (exponential: median ln 2; lognormal σ = 0.5: median 1); the binomial standard
    error of the coverage is 0.35%."""
    rng = np.random.default_rng(n)
    sample, median = ((lambda: rng.exponential(size=n), math.log(2)) if draw == "exponential"
                      else (lambda: rng.lognormal(0.0, 0.5, size=n), 1.0))
    intervals = [median_ci(sample()) for _ in range(4000)]
    covered = [ci.low <= median <= ci.high for ci in intervals]
    assert 0.93 <= np.mean(covered) <= 0.97


def test_paired_ratio_cancels_what_the_replicates_share_and_covers():
    """Replicates sharing a common factor (the same pool: ±20%) with a true ratio 1.03: the
    paired interval covers 1.03 in 93-97% of 2000 trials and resolves the 3% far more often
    than Welch's on the same values (over 70% of trials against under 30%), whose interval is
    wide with the shared factor in it."""
    rng = np.random.default_rng(23)
    covered, paired_hits, welch_hits = [], 0, 0
    for _ in range(2000):
        shared = rng.lognormal(0.0, 0.2, size=10)
        a = 5.0 * shared * rng.lognormal(0.0, 0.02, size=10)
        b = 5.15 * shared * rng.lognormal(0.0, 0.02, size=10)
        paired, welch = ratio_ci(a, b, paired=True), ratio_ci(a, b)
        covered.append(paired.low <= 1.03 <= paired.high)
        paired_hits += paired.significant
        welch_hits += welch.significant
        assert paired.paired and not welch.paired
        assert (paired.p < 0.05) == paired.significant and (welch.p < 0.05) == welch.significant
    assert 0.93 <= np.mean(covered) <= 0.97
    assert paired_hits > 0.7 * 2000 and welch_hits < 0.3 * 2000


def test_cell_intervals_use_every_scored_render_and_the_median_of_timed_renders():
    """Two seeds × 3 renders: the error is the t interval over the 6 replicates (by hand:
    mean 2, sd √0.8, t(0.975, 5) = 2.5706); the time is the median of all 7 timed renders."""
    import pandas as pd

    rows = pd.DataFrame([
        {"scene": "s", "estimator": "e", "spp": 4, "seed": 0, "frame": 0, "rel_mse": 1.0,
         "rel_mse_renders": renders_text([1.0, 2.0, 3.0]), "time_ms": 2.0,
         "time_ms_renders": renders_text([2.0, 1.0, 5.0, 9.0])},
        {"scene": "s", "estimator": "e", "spp": 4, "seed": 1, "frame": 0, "rel_mse": 2.0,
         "rel_mse_renders": renders_text([2.0, 1.0, 3.0]), "time_ms": 3.0,
         "time_ms_renders": renders_text([3.0, 4.0, 6.0])}])
    cell = cell_intervals(rows, ["scene", "estimator", "spp"], ["rel_mse", "time_ms"]).iloc[0]
    assert cell.rel_mse == pytest.approx(2.0) and cell.rel_mse_n == 6
    assert cell.rel_mse_half == pytest.approx(2.5706 * math.sqrt(0.8) / math.sqrt(6), rel=1e-4)
    assert cell.time_ms == 4.0 and cell.time_ms_n == 7
    assert cell.time_ms_low <= 4.0 <= cell.time_ms_high
    assert "median" in cell.time_ms_method and "scored renders" in cell.rel_mse_method


def test_a_host_wall_time_has_a_positive_interval_on_a_log_scale():
    """Issue 35: two seeds' host wall times gave ``600 ± 1300`` (a t interval with one degree of
    freedom reaching below zero).  On logs (by hand: geometric mean √(300·900), log sd ln 3/√2,
    t(0.975, 1) = 12.7062) the interval stays positive and is shown as [low, high]."""
    import pandas as pd

    rows = pd.DataFrame([{"scene": "s", "estimator": "e", "spp": 4, "seed": seed, "frame": 0,
                          "time_ms_host": ms} for seed, ms in enumerate([300.0, 900.0])])
    cell = cell_intervals(rows, ["scene", "estimator", "spp"], ["time_ms_host"]).iloc[0]
    centre, half = math.log(math.sqrt(300 * 900)), 12.7062 * (math.log(3) / math.sqrt(2)) / math.sqrt(2)
    assert cell.time_ms_host == pytest.approx(math.sqrt(300 * 900))
    assert cell.time_ms_host_low == pytest.approx(math.exp(centre - half), rel=1e-4)
    assert cell.time_ms_host_high == pytest.approx(math.exp(centre + half), rel=1e-4)
    text = interval_text(cell.time_ms_host, cell.time_ms_host_half, 2, low=cell.time_ms_host_low,
                         high=cell.time_ms_host_high)
    assert text == "520 [0.48, 560000]", text


@pytest.mark.parametrize("low, high, text", [
    (50.0, 7000.0, "600 [50, 7000]"),      # positive but wider than its figure: no "±"
    (-700.0, 1900.0, "600 ± 1300"),        # an interval that holds zero keeps "±"
    (math.nan, math.nan, "600 ± 1300"),    # no bounds given: as before
])
def test_an_interval_wider_than_its_positive_figure_is_shown_as_a_range(low, high, text):
    assert interval_text(600.0, 1300.0, 2, low=low, high=high) == text
    assert interval_text(600.0, 130.0, 2, low=470.0, high=730.0) == "600 ± 130"


def test_skew_corrected_interval_is_the_t_interval_without_skew_and_moves_up_with_it():
    symmetric = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    plain, hall = mean_ci(symmetric), skew_corrected_ci(symmetric)
    assert (hall.low, hall.high) == pytest.approx((plain.low, plain.high))
    skewed = np.array([1.0, 1.1, 0.9, 1.0, 1.05, 0.95, 1.0, 1.02, 0.98, 4.0])
    plain, hall = mean_ci(skewed), skew_corrected_ci(skewed)
    assert hall.mean == plain.mean and hall.high > plain.high and hall.low > plain.low


def test_skew_corrected_interval_covers_a_right_skewed_mean():
    """10 lognormal (σ = 0.5, skewness 1.75, as skewed as a relMSE over renders) values, 4000
    samples: Hall's interval holds the mean e^⅛ in 92.5-97% of them (the binomial standard
    error is 0.4%), the plain t interval in under 92% (it misses on the high side)."""
    rng = np.random.default_rng(1992)
    samples = rng.lognormal(0.0, 0.5, size=(4000, 10))
    mean = math.exp(0.125)
    hall = np.mean([(lambda c: c.low <= mean <= c.high)(skew_corrected_ci(x)) for x in samples])
    plain = np.mean([(lambda c: c.low <= mean <= c.high)(mean_ci(x)) for x in samples])
    assert 0.925 <= hall <= 0.97 and plain < 0.92, (hall, plain)
