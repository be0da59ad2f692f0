"""The equal-time answer (issue 23): error read along each estimator's error-time curve at a
budget, ranks resolved by paired tests, the headline budgets, the verdict."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from iblbench.harness.protocol.ranking import (curve, headline_budgets, rank, round_budgets,
                                                scene_rankings)
from iblbench.harness.protocol.stats import renders_text


def cell(estimator, spp, times, errors, seeds=(0, 1), scene="s"):
    """Rows of one cell: per seed, the renders' errors (``errors[seed]``) and times."""
    return [{"scene": scene, "estimator": estimator, "spp": spp, "frame": 0, "seed": seed,
             "time_budget_ms": math.nan, "mean_delta_e76": errors[i][0],
             "mean_delta_e76_renders": renders_text(errors[i]), "time_ms": float(np.median(times)),
             "time_ms_renders": renders_text(times)} for i, seed in enumerate(seeds)]


def test_error_at_a_budget_is_interpolated_in_log_log_replicate_by_replicate():
    """Times 1 and 4 ms, each replicate's error 4 then 1: at 2 ms (halfway in log time) each
    replicate is √(4·1) = 2 — not the 2.5 of a linear reading — and identical replicates give
    a point interval."""
    rows = pd.DataFrame(cell("a", 16, [1.0] * 3, [[4.0] * 3] * 2)
                        + cell("a", 64, [4.0] * 3, [[1.0] * 3] * 2))
    ranking = rank({"a": curve(rows)}, "s", 2.0)
    (standing,) = ranking.ranked
    assert standing.error.mean == pytest.approx(2.0) and standing.spp == (16, 64)
    assert len(standing.replicates) == 6


def test_budgets_outside_a_curve_are_not_reached_or_not_measured():
    rows = pd.DataFrame(cell("slow", 1, [10.0] * 3, [[1.0, 1.1, 1.2]] * 2)
                        + cell("slow", 4, [40.0] * 3, [[0.5, 0.6, 0.7]] * 2)
                        + cell("fast", 16, [0.5] * 3, [[3.0, 3.1, 3.2]] * 2)
                        + cell("fast", 64, [2.0] * 3, [[2.0, 2.1, 2.2]] * 2))
    curves = {label: curve(r) for label, r in rows.groupby("estimator")}
    ranking = rank(curves, "s", 5.0)
    assert not ranking.ranked
    assert {s.estimator: s.status for s in ranking.unranked} == {"slow": "not reached",
                                                                "fast": "not measured"}
    assert "slow not reached" in ranking.verdict() and "fast not measured" in ranking.verdict()


def _pair(rng, shift, shared_sd=0.3, own_sd=0.01, n=5):
    """Two estimators over 2 seeds × n renders whose errors share a per-replicate factor (the
    same light pool), B ``shift`` times A."""
    shared = rng.lognormal(0, shared_sd, size=(2, n))
    a = 2.0 * shared * rng.lognormal(0, own_sd, size=(2, n))
    b = 2.0 * shift * shared * rng.lognormal(0, own_sd, size=(2, n))
    rows = []
    for label, errors in (("a", a), ("b", b)):
        rows += cell(label, 16, [1.0] * n, errors) + cell(label, 64, [4.0] * n, errors / 2)
    return pd.DataFrame(rows)


def test_adjacent_ranks_are_resolved_by_a_paired_test():
    """B 5% worse than A, with a shared ±30% factor: paired over the shared (seed, render)
    replicates the 5% is resolved in nearly every trial; the same values with their pairing
    broken (B's seeds renamed) are resolved far less often (the shared factor is noise then)."""
    rng = np.random.default_rng(7)
    paired = unpaired = 0
    for _ in range(200):
        rows = _pair(rng, 1.05)
        ranking = scene_rankings(rows, budgets=[2.0])["s"][0]
        assert [s.estimator for s in ranking.ranked] == ["a", "b"] or not ranking.versus_next[0].significant
        paired += ranking.versus_next[0].significant and ranking.versus_next[0].paired
        broken = rows.assign(seed=np.where(rows.estimator == "b", rows.seed + 10, rows.seed))
        ratio = scene_rankings(broken, budgets=[2.0])["s"][0].versus_next[0]
        unpaired += ratio.significant and not ratio.paired
    assert paired >= 190 and unpaired <= 60


def test_a_tie_is_not_resolved_at_the_stated_rate():
    """A and B with the same error distribution: 'resolved' (a false call) in about 5% of 400
    trials, at most 9%."""
    rng = np.random.default_rng(11)
    calls = sum(scene_rankings(_pair(rng, 1.0, own_sd=0.05), budgets=[2.0])["s"][0].resolved[0]
                for _ in range(400))
    assert calls <= 0.09 * 400


def test_the_verdict_names_the_winner_its_interval_and_who_is_far_behind():
    rows = pd.DataFrame(cell("good", 16, [1.0] * 3, [[1.0, 1.1, 0.9]] * 2)
                        + cell("good", 64, [4.0] * 3, [[0.5, 0.55, 0.45]] * 2)
                        + cell("bad", 16, [1.0] * 3, [[3.0, 3.3, 2.7]] * 2)
                        + cell("bad", 64, [4.0] * 3, [[1.5, 1.65, 1.35]] * 2)
                        + cell("slow", 1, [30.0] * 3, [[0.1] * 3] * 2))
    (ranking,) = scene_rankings(rows, budgets=[4.0])["s"]
    assert ranking.winner == "good" and ranking.resolved == (1, 1)
    text = ranking.verdict()
    assert text.startswith("at 4 ms/frame on s: good (ΔE76 0.5 [") and "ahead of bad (1.5 [" in text
    assert "slow not reached" in text


def test_headline_budgets_are_round_spaced_and_rank_most_estimators():
    assert round_budgets(1.5, 25) == [2.0, 5.0, 10.0, 20.0]
    rows = pd.DataFrame(sum((cell(label, spp, [t] * 3, [[1.0] * 3] * 2)
                             for label, span in (("a", (1.5, 30)), ("b", (2.5, 40)),
                                                 ("c", (3.0, 25)), ("d", (200, 400)))
                             for spp, t in zip((16, 64), span)), []))
    curves = {label: curve(r) for label, r in rows.groupby("estimator")}
    budgets = headline_budgets(curves)
    assert 2 <= len(budgets) <= 3 and all(3.0 <= b <= 25 for b in budgets)   # a, b, c rank
    assert all(b2 / b1 >= 2 for b1, b2 in zip(budgets, budgets[1:]))
    assert headline_budgets(curves, sweep_budgets=[8.0, 2.0]) == [2.0, 8.0]


def test_a_higher_is_better_metric_is_refused_not_ranked_upside_down():
    """PSNR rises with time: read as an error, the ranking would put the worst first."""
    rows = pd.DataFrame(cell("a", 16, [1.0] * 3, [[4.0] * 3] * 2)).assign(psnr=30.0)
    with pytest.raises(ValueError, match="higher-is-better"):
        curve(rows, "psnr")
