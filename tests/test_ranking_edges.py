"""The equal-time answer at its boundaries (issue 36, class 4): each rule of
harness/protocol/ranking.py's and equal_time.py's docstrings (and docs/method.md, "The
equal-time answer") tested just below, at and just above its edge, on hand-built cells whose
answers follow from the rule alone.

- An equal-time cell of budget T at its curve's end is read at T where its time lies within
  ±TOLERANCE (10%) of T, inclusive; a cell of another budget or an spp level gets no tolerance.
- A standing that reads an equal-time cell of T more than 10% off T is "off budget".
- A budget equal to a cell's time is bracketed (read at that cell); a hair outside a curve's
  span is "not reached" or "not measured".
- Headline budgets are round (1, 2, 5 × 10^k ms), at most three, each ranking at least half of
  the estimators (and two), at least 2× apart (exactly 2× included), most estimators first.
- Calibration: an spp whose predicted time equals the budget is chosen; refinement stops within
  half the tolerance, inclusive; the spp run is the largest measured within tolerance and budget.
- An error budget (``iblbench check``) passes a value equal to its limit (``<=``, ``>=``).

Times are stored with 7 significant digits (``stats.renders_text``), so "just above 11 ms" is
11.00001."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pandas as pd
import pytest

from iblbench.harness.protocol import ranking
from iblbench.harness.protocol.equal_time import (TOLERANCE, best_measured, choose_spp,
                                                  corrected_spp)
from iblbench.harness.protocol.ranking import curve, headline_budgets, rank
from iblbench.harness.protocol.stats import renders_text

T = 10.0   # the budget of the tolerance tests: ±10% is exactly ±1 ms


def cell(spp: int, time_ms: float, error: float, budget: float = math.nan, estimator: str = "a"):
    """Rows of one cell of ``estimator``: two seeds × three renders, every render ``time_ms``,
    the replicates ``error`` × (1, 1.1, 1.2) so that their mean is 1.1 × ``error``."""
    errors = [error, 1.1 * error, 1.2 * error]
    return [{"scene": "s", "estimator": estimator, "spp": spp, "frame": 0, "seed": seed,
             "time_budget_ms": budget, "mean_delta_e76": errors[0],
             "mean_delta_e76_renders": renders_text(errors), "time_ms": time_ms,
             "time_ms_renders": renders_text([time_ms] * 3)} for seed in (0, 1)]


def standing(cells: list, budget: float = T) -> ranking.Standing:
    rows = pd.DataFrame(sum(cells, []))
    (only,) = [*(r := rank({"a": curve(rows)}, "s", budget)).ranked, *r.unranked]
    return only


def ranking_at(cells: list, budget: float = T) -> ranking.Ranking:
    return rank({"a": curve(pd.DataFrame(sum(cells, [])))}, "s", budget)


# ---- the tolerance at each end of a curve ---------------------------------------------------------

@pytest.mark.parametrize("time_ms, status", [(10.5, "ranked"), (11.0, "ranked"),
                                             (11.00001, "not reached")])
def test_an_equal_time_cell_at_the_fast_end_is_read_within_its_tolerance(time_ms, status):
    """The fastest cell was measured for T = 10 ms and took up to 11 ms: read there (its own
    error, 1.1 × 2), not "not reached"; a hair beyond +10% it is not reached."""
    got = standing([cell(8, time_ms, 2.0, budget=T), cell(64, 40.0, 0.5)])
    assert got.status == status
    if status == "ranked":
        assert got.error.mean == pytest.approx(2.2) and not got.missed


@pytest.mark.parametrize("time_ms, status", [(9.5, "ranked"), (9.0, "ranked"),
                                             (8.999999, "not measured")])
def test_an_equal_time_cell_at_the_slow_end_is_read_within_its_tolerance(time_ms, status):
    got = standing([cell(1, 2.5, 8.0), cell(32, time_ms, 1.0, budget=T)])
    assert got.status == status
    if status == "ranked":
        assert got.error.mean == pytest.approx(1.1) and not got.missed


@pytest.mark.parametrize("budget", [math.nan, 20.0])
def test_only_a_cell_of_that_budget_gets_the_tolerance(budget):
    """An spp level, or an equal-time cell calibrated for 20 ms, 5% past T: not reached at T."""
    assert standing([cell(8, 10.5, 2.0, budget=budget), cell(64, 40.0, 0.5)]).status == "not reached"
    assert standing([cell(1, 2.5, 8.0), cell(32, 9.5, 1.0, budget=budget)]).status == "not measured"


@pytest.mark.parametrize("time_ms, off", [(11.0, False), (11.00001, True), (9.0, False),
                                          (8.999999, True)])
def test_a_standing_is_off_budget_only_beyond_the_tolerance(time_ms, off):
    """A curve that brackets T between an spp level and an equal-time cell of T: the standing
    reads that cell, and is off budget (named in the verdict) only where the cell missed T by
    more than 10%."""
    result = ranking_at([cell(1, 5.0, 4.0), cell(16, time_ms, 1.0, budget=T), cell(256, 40.0, 0.25)])
    (got,) = result.ranked
    assert got.missed is off and (result.missed == ["a"]) is off
    assert ("off budget: a" in result.verdict()) is off


def test_a_cell_of_another_budget_off_its_own_is_a_point_like_any_other():
    result = ranking_at([cell(1, 5.0, 4.0), cell(16, 11.5, 1.0, budget=20.0), cell(256, 40.0, 0.25)])
    assert result.ranked[0].missed is False and "off budget" not in result.verdict()


# ---- budgets equal to a cell's time --------------------------------------------------------------

SPP_CURVE = [cell(4, 1.0, 8.0), cell(16, 4.0, 2.0), cell(64, 16.0, 1.0)]


@pytest.mark.parametrize("budget, error", [(1.0, 8.8), (4.0, 2.2), (16.0, 1.1), (2.0, 4.4),
                                           (8.0, 2.2 * math.sqrt(0.5))])
def test_a_budget_equal_to_a_cells_time_reads_that_cell(budget, error):
    """At a cell's own time (either end or inside) the error is that cell's; between two it is
    their log–log mean (2 ms: √(8.8 · 2.2) = 4.4)."""
    got = standing(SPP_CURVE, budget)
    assert got.status == "ranked" and got.error.mean == pytest.approx(error)


@pytest.mark.parametrize("budget, status", [(0.9999999, "not reached"), (16.00001, "not measured")])
def test_a_hair_outside_the_curve_is_not_ranked(budget, status):
    assert standing(SPP_CURVE, budget).status == status


def test_a_curve_that_already_rises_keeps_its_times_bit_for_bit():
    """The isotonic fit moves only points out of order; summed naively, 0.2 and 0.5 ms became
    0.2 and 0.49999999999999994, and a budget of 0.5 ms, the slowest cell's own time, was
    "not measured"."""
    rng = np.random.default_rng(5)
    for times in [np.array([0.2, 0.5]), np.array([0.1, 0.1, 0.1]), *np.sort(rng.uniform(0, 10, (200, 5)))]:
        np.testing.assert_array_equal(ranking.rising(times), times)
    np.testing.assert_array_equal(ranking.rising([1.0, 3.0, 2.0, 4.0]), [1.0, 2.5, 2.5, 4.0])
    fits = ranking.rising(rng.uniform(0, 10, (200, 6)))
    assert (np.diff(fits, axis=-1) >= 0).all()
    got = standing([cell(4, 0.2, 2.0), cell(16, 0.5, 1.0)], 0.5)
    assert got.status == "ranked" and got.error.mean == pytest.approx(1.1)


# ---- headline budgets --------------------------------------------------------------------------

def spans(**by_estimator):
    """Curves of two cells that take the given (fastest, slowest) ms (the headline budgets read
    their times alone)."""
    replicates = pd.Series([1.0, 1.0])
    return {name: [ranking.Point(spp, float(t), replicates, np.full(ranking.BOOTSTRAP, float(t)))
                   for spp, t in zip((16, 64), span)] for name, span in by_estimator.items()}


def test_budgets_exactly_twice_apart_and_reaching_exactly_half_are_both_headlines():
    """Round budgets 1, 2 and 5 lie in [1, 9]; 1 and 2 reach a and b (2 of 4: half; 1 ms is their
    fastest cell's time, so it counts), 5 reaches only c: the headlines are 1 and 2, 2× apart."""
    assert headline_budgets(spans(a=(1, 3), b=(1, 3), c=(4, 6), d=(7, 9))) == [1.0, 2.0]


def test_a_budget_reaching_less_than_half_is_no_headline():
    """A fifth estimator (10–11 ms) makes half 2.5: no budget reaches that many."""
    assert headline_budgets(spans(a=(1, 3), b=(1, 3), c=(4, 6), d=(7, 9), e=(10, 11))) == []


def test_round_budgets_2_and_2_5_times_apart_are_all_kept():
    assert headline_budgets(spans(a=(1, 5), b=(1, 5), c=(1, 5))) == [1.0, 2.0, 5.0]


def test_the_spacing_rule_at_its_edge(monkeypatch):
    """Budgets 2 and 5 ms (2.5× apart) are both chosen where the spacing is 2.5, and not where it
    is a hair more."""
    curves = spans(a=(2, 5), b=(2, 5))
    monkeypatch.setattr(ranking, "BUDGET_SPACING", 2.5)
    assert headline_budgets(curves) == [2.0, 5.0]
    monkeypatch.setattr(ranking, "BUDGET_SPACING", math.nextafter(2.5, math.inf))
    assert len(headline_budgets(curves)) == 1


def test_headline_budgets_keep_their_rules_on_random_curves():
    """On 300 random sets of spans: at most three round budgets in the covered range, each
    reaching at least max(2, half) of the estimators, pairwise at least 2× apart; the first has
    the most reach of any round budget; every qualifying budget left out is within 2× of a
    chosen one, or three are chosen; none chosen only where none qualifies."""
    rng = np.random.default_rng(36)
    round_budgets = [m * 10.0 ** k for k in range(-2, 6) for m in (1.0, 2.0, 5.0)]
    for _ in range(300):
        count = int(rng.integers(1, 7))
        lows = rng.choice(round_budgets[3:13] + list(10 ** rng.uniform(-1, 2, 10)), count)
        highs = lows * rng.choice([1.0, 2.0, 2.5, 4.0, 10.0, 100.0], count)
        chosen = headline_budgets(spans(**{f"e{i}": (float(lo), float(hi))
                                           for i, (lo, hi) in enumerate(zip(lows, highs))}))
        low, high = float(min(lows)), float(max(highs))
        reach = {b: sum(lo <= b <= hi for lo, hi in zip(lows, highs))
                 for b in round_budgets if low <= b <= high}
        qualifying = [b for b, r in reach.items() if r >= max(2, count / 2)]
        assert len(chosen) <= 3 and chosen == sorted(chosen)
        assert all(b in qualifying for b in chosen), (chosen, reach)
        assert all(max(x / y, y / x) >= 2 for x, y in itertools.combinations(chosen, 2)), chosen
        assert bool(chosen) == bool(qualifying)
        if chosen:
            assert max(reach[b] for b in chosen) == max(reach.values())
            assert len(chosen) == 3 or all(any(max(b / c, c / b) < 2 for c in chosen)
                                           for b in qualifying if b not in chosen), (chosen, reach)


# ---- calibration's edges (equal_time.py) --------------------------------------------------------

def test_an_spp_whose_predicted_time_equals_the_budget_is_chosen():
    """a + b·spp ≤ budget, equality included: 1 + 0.5·20 = 11; and 0.1 + 0.1·2 = 0.3, which
    float arithmetic puts a hair under 2 spp."""
    assert choose_spp(1.0, 0.5, 11.0) == 20
    assert choose_spp(1.0, 0.5, 10.999999) == 19
    assert choose_spp(0.1, 0.1, 0.3) == 2
    assert choose_spp(1.0, 0.5, 11.0, limit=20) == 20 and choose_spp(1.0, 0.5, 11.0, limit=19) == 19
    assert choose_spp(1.0, 0.5, 1.2) == 1   # even 1 spp over the budget: 1


@pytest.mark.parametrize("measured, done", [(21.0, True), (19.0, True), (21.00001, False),
                                            (18.99999, False)])
def test_refinement_stops_within_half_the_tolerance_inclusive(measured, done):
    """Budget 20 ms: half the tolerance is ±1 ms.  Outside it the next step is the largest spp
    that the median slope (intercept 0) predicts within the budget: 100·20/measured."""
    step = corrected_spp(0.0, {100: measured}, 100, 20.0)
    assert step is None if done else step == math.floor(100 * 20.0 / measured)


@pytest.mark.parametrize("medians, expected", [
    ({100: 9.0, 120: 10.0, 140: 11.0}, 120),          # within tolerance and budget: the largest (10 = budget)
    ({100: 9.0, 120: 10.00001, 140: 11.0}, 100),      # 120 a hair over the budget
    ({50: 8.0, 100: 11.0}, 100),                      # only 100 within tolerance (+10% exactly)
    ({50: 8.0, 100: 11.00001}, 50),                   # none within: the largest within the budget
    ({50: 10.5, 100: 11.00001}, 50),                  # within tolerance but over: the nearest
    ({50: 11.00001, 100: 12.0}, 50),                  # none within, none under: the cheapest
])
def test_the_spp_run_is_the_best_measured_at_the_tolerances_edge(medians, expected):
    assert best_measured(medians, T) == expected


# ---- the error budgets' limits (budgets.py: "<=" and ">=", equality passing) -----------------------

@pytest.mark.parametrize("limits, results", [
    ("max_mean_delta_e76 = 2.0\nmin_mean_delta_e76 = 2.0", ["PASS", "PASS"]),
    ("max_mean_delta_e76 = 1.9999999", ["FAIL"]),
    ("min_mean_delta_e76 = 2.0000001", ["FAIL"]),
    ("nonfinite = 3", ["PASS"]),
    ("nonfinite = 2", ["FAIL"]),
    ('max_time_ratio = { baseline = "fast", metric = "time_ms_shade", max = 2.0 }', ["PASS"]),
    ('max_time_ratio = { baseline = "fast", metric = "time_ms_shade", max = 1.9999999 }', ["FAIL"]),
])
def test_an_error_budget_passes_a_value_equal_to_its_limit_and_fails_one_a_hair_beyond(
        tmp_path, limits, results):
    """The cell's ΔE76 is (1.5 + 2.5) / 2 = 2.0 over its seeds, its non-finite pixels 1 + 2 = 3,
    its shade time 2.0 ms against the baseline's 1.0 ms."""
    from test_budgets import configuration, row

    from iblbench.harness.protocol.budgets import evaluate, load_budgets

    table = pd.DataFrame([row("s", "slow", 16, seed=0, mean_delta_e76=1.5, nonfinite=1, time_ms_shade=2.0),
                          row("s", "slow", 16, seed=1, mean_delta_e76=2.5, nonfinite=2, time_ms_shade=2.0),
                          row("s", "fast", 16, seed=0), row("s", "fast", 16, seed=1)])
    budgets = tmp_path / "budgets.toml"
    budgets.write_text(configuration(2) + f'[[rule]]\nscene = "s"\nestimator = "slow"\nspp = 16\n{limits}\n')
    assert list(evaluate(load_budgets(budgets), table).result) == results
