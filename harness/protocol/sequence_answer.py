"""A sequence's equal-time answer frame by frame (issue 24): each estimator's error (ΔE76) and
flicker at a scene's headline budget, per frame and over the frames, with 95% intervals.

Both are read as :mod:`.ranking` reads the error, along each estimator's error–time curve at the
budget, log–log between the two cells whose times bracket it (:func:`ranking.standing_at`):

- **per frame**, a cell's point has the cell's time (the median of its timed renders over every
  frame: one time per cell, as everywhere) and the frame's own replicates, one per (seed,
  render) for ΔE76 (:func:`ranking.curve` with ``frame``);
- **flicker** (the mean |change of the per-pixel ΔE76 map| from the previous frame of the run,
  :func:`iblbench.harness.protocol.metrics.flicker`) is scored on render 0 only, so its
  replicates are the seeds (its interval is the ranking's bootstrap over them and the cells'
  times; with one seed a budget is "not measured", as the ranking reads a budget only from
  replicates every cell of the curve shares, at least two), and it is undefined on the run's
  first frame;
- **over the frames**: ΔE76 as the ranking has it (each replicate the mean over the frames) and
  flicker as each seed's mean over the frames from the second on; and the worst frame, the one
  whose ΔE76 at the budget is highest among the frames read there.

An estimator the budget does not reach or that was not measured there (:mod:`.ranking`) gets no
figures, only its status.
"""
from __future__ import annotations

import math

import pandas as pd

from iblbench.harness.protocol.ranking import FLICKER, METRIC, curve, standing_at

COLUMNS = ("estimator", "frame", "metric", "status", "mean", "low", "high")


def _row(estimator: str, frame, metric: str, points, budget_ms: float) -> dict:
    """One figure of :func:`frame_standings`' table."""
    standing = standing_at(estimator, points, budget_ms) if points else None
    if standing is None or standing.status != "ranked":
        return {"estimator": estimator, "frame": frame, "metric": metric,
                "status": standing.status if standing else "not measured",
                "mean": math.nan, "low": math.nan, "high": math.nan}
    ci = standing.error
    return {"estimator": estimator, "frame": frame, "metric": metric, "status": "ranked",
            "mean": ci.mean, "low": ci.low, "high": ci.high}


def frame_curves(rows: pd.DataFrame) -> list[tuple]:
    """One scene's ``rows`` (a results table's) as curves: (estimator, frame (``None``: over the
    frames), metric (ΔE76, flicker), its :func:`ranking.curve`), which every budget reads."""
    out = []
    frames = sorted(int(f) for f in rows.frame.unique())
    for estimator, cells in rows.groupby("estimator", sort=False):
        times = {}   # the cells' times: the same in every frame's curve
        for metric in (METRIC, FLICKER):
            if metric not in cells:
                continue
            shown = frames[1:] if metric == FLICKER else frames
            out += [(estimator, frame, metric, curve(cells, metric, frame, times))
                    for frame in [None, *shown]]
    return out


def frame_standings(rows: pd.DataFrame, budget_ms: float, curves: list | None = None) -> pd.DataFrame:
    """One scene's ``rows`` (a results table's) read at ``budget_ms``: a row per estimator,
    frame (``None``: over the frames) and metric (ΔE76, flicker) with ``status`` ("ranked", or
    why not) and the figure's ``mean``, ``low`` and ``high`` (module docstring); ``curves``:
    :func:`frame_curves` of ``rows``, made once for several budgets."""
    curves = frame_curves(rows) if curves is None else curves
    return pd.DataFrame([_row(estimator, frame, metric, points, budget_ms)
                         for estimator, frame, metric, points in curves], columns=list(COLUMNS))


def sequence_summary(standings: pd.DataFrame) -> pd.DataFrame:
    """Per estimator (best ΔE76 first): its ΔE76 and flicker over the frames at the budget with
    their intervals, and its worst frame by ΔE76 (:func:`frame_standings`' table)."""
    whole = standings[standings.frame.isna()].set_index(["estimator", "metric"])
    per_frame = standings[standings.frame.notna() & (standings.metric == METRIC)]
    out = []
    for estimator in dict.fromkeys(standings.estimator):
        error = whole.loc[(estimator, METRIC)]
        flicker = (whole.loc[(estimator, FLICKER)] if (estimator, FLICKER) in whole.index
                   else None)
        frames = per_frame[(per_frame.estimator == estimator) & per_frame["mean"].notna()]
        worst = frames.loc[frames["mean"].idxmax()] if len(frames) else None
        out.append({"estimator": estimator, "status": error.status,
                    "delta_e76": error["mean"], "delta_e76_low": error.low,
                    "delta_e76_high": error.high,
                    "flicker": math.nan if flicker is None else flicker["mean"],
                    "flicker_low": math.nan if flicker is None else flicker.low,
                    "flicker_high": math.nan if flicker is None else flicker.high,
                    "worst_frame": None if worst is None else int(worst.frame),
                    "worst_delta_e76": math.nan if worst is None else worst["mean"]})
    table = pd.DataFrame(out)
    return table.sort_values("delta_e76", na_position="last", kind="stable").reset_index(drop=True)
