"""A sequence's error and flicker per frame at equal time (harness/protocol/sequence_answer.py,
the report's "Error and flicker at equal time"), on synthetic results whose curves are exact
power laws, so the figures at a budget are known in closed form."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from iblbench.harness.protocol.sequence_answer import frame_standings, sequence_summary
from iblbench.reports import plots

ERROR_SCALE = {0: 1.0, 1: 3.0, 2: 2.0}      # c_f: frame f's ΔE76 is c_f · (1 + 0.1·i) · t^-½
FLICKER_SCALE = {1: 0.5, 2: 0.8}            # k_f: flicker is k_f · (1 + 0.2·seed) · t^-½
RENDERS, SEEDS = 3, 2


def cell(estimator: str, spp: int, time_ms: float) -> list[dict]:
    """One cell: frames 0-2, two seeds of three renders; replicate i = 3·seed + render."""
    rows = []
    for frame, scale in ERROR_SCALE.items():
        for seed in range(SEEDS):
            renders = [scale * (1 + 0.1 * (RENDERS * seed + r)) * time_ms ** -0.5
                       for r in range(RENDERS)]
            flicker = (FLICKER_SCALE[frame] * (1 + 0.2 * seed) * time_ms ** -0.5
                       if frame in FLICKER_SCALE else math.nan)
            rows.append({"scene": "s", "estimator": estimator, "spp": spp, "frame": frame,
                         "seed": seed, "time_budget_ms": math.nan, "time_ms": time_ms,
                         "time_ms_renders": " ".join([f"{time_ms:g}"] * RENDERS),
                         "mean_delta_e76": renders[0],
                         "mean_delta_e76_renders": " ".join(f"{v:.12g}" for v in renders),
                         "flicker": flicker})
    return rows


@pytest.fixture
def results() -> pd.DataFrame:
    # "a" spans 1-4 ms, so a 2 ms budget is read between its cells; "b" starts at 10 ms.
    return pd.DataFrame(cell("a", 4, 1.0) + cell("a", 16, 4.0)
                        + cell("b", 1, 10.0) + cell("b", 4, 20.0))


BUDGET = 2.0
MEAN_FACTOR = 1.25    # the mean of 1 + 0.1·i over i = 0..5


def test_per_frame_error_and_flicker_at_a_budget_follow_the_curves(results):
    """Log–log interpolation of an exact power law is exact: frame f's ΔE76 at the budget is
    c_f · 1.25 · B^-½ and its flicker k_f · 1.1 · B^-½, each inside its own interval."""
    table = frame_standings(results, BUDGET)
    a = table[(table.estimator == "a") & table.frame.notna()].set_index(["metric", "frame"])
    for frame, scale in ERROR_SCALE.items():
        row = a.loc[("mean_delta_e76", frame)]
        assert row["mean"] == pytest.approx(scale * MEAN_FACTOR * BUDGET ** -0.5, rel=1e-9)
        assert row.low < row["mean"] < row.high
    assert ("flicker", 0) not in a.index          # undefined on the run's first frame
    for frame, scale in FLICKER_SCALE.items():
        row = a.loc[("flicker", frame)]
        assert row["mean"] == pytest.approx(scale * 1.1 * BUDGET ** -0.5, rel=1e-9)
        assert row.low < row["mean"] < row.high
    b = table[table.estimator == "b"]
    assert (b.status == "not reached").all() and b["mean"].isna().all()


def test_the_summary_gives_the_means_over_the_frames_and_the_worst_frame(results):
    summary = sequence_summary(frame_standings(results, BUDGET)).set_index("estimator")
    a = summary.loc["a"]
    assert a.delta_e76 == pytest.approx(np.mean(list(ERROR_SCALE.values())) * MEAN_FACTOR
                                        * BUDGET ** -0.5, rel=1e-9)
    assert a.flicker == pytest.approx(np.mean(list(FLICKER_SCALE.values())) * 1.1
                                      * BUDGET ** -0.5, rel=1e-9)
    assert a.delta_e76_low < a.delta_e76 < a.delta_e76_high
    assert a.flicker_low < a.flicker < a.flicker_high
    assert a.worst_frame == 1 and a.worst_delta_e76 == pytest.approx(
        3.0 * MEAN_FACTOR * BUDGET ** -0.5, rel=1e-9)
    assert summary.loc["b"].status == "not reached" and math.isnan(summary.loc["b"].delta_e76)
    assert list(summary.index) == ["a", "b"]       # ranked first


def test_the_plot_draws_each_ranked_estimator_per_frame_with_intervals(results, monkeypatch):
    from matplotlib.container import ErrorbarContainer

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig))
    plots.plot_frames_at_budget(None, frame_standings(results, BUDGET), "s", BUDGET, ["a", "b"])
    error_axes, flicker_axes = figures[0].axes[:2]
    for ax, frames in ((error_axes, [0, 1, 2]), (flicker_axes, [1, 2])):
        bars = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
        assert [c.get_label() for c in bars] == ["a"]            # b is not reached
        assert list(bars[0].lines[0].get_xdata()) == frames
