"""The equal-time answer: which estimator wins at a time budget per frame, and how sure that is
(issue 23).  The report opens with it, ``iblbench run`` prints it and ``run --json`` carries it.

**Error at a budget.**  Each estimator's cells of a scene (its spp levels and equal-time cells)
are points of its error–time curve: the cell's time (the median of its timed renders,
:func:`~iblbench.harness.protocol.stats.column_interval`) and its replicates of the metric (one
value per (seed, render), :func:`~iblbench.harness.protocol.stats.cell_values`).  The error at a
budget T is read along the curve between the two points whose times bracket T, interpolated in
log–log (log error linear in log time), *replicate by replicate*: replicate (s, r) at T is
exp((1 − w)·log e_lo(s, r) + w·log e_hi(s, r)), w = log(T / t_lo) / log(t_hi / t_lo).  The
interval at T is then the cells' own interval (Student-t, skewness-corrected:
:func:`~iblbench.harness.protocol.stats.skew_corrected_ci`) over those interpolated replicates,
so it carries the two points' own spread and whatever they share.  The times are taken as the
cells' medians: their own uncertainty (the time intervals in the tables) is not carried into
the error's.

**Who is not ranked.**  An estimator whose fastest cell takes longer than T is "not reached"
(it cannot render a frame in T at the spp measured); one whose slowest cell is faster than T is
"not measured" (its error at T would need more spp than the sweep ran; no extrapolation).  A
budget within the equal-time tolerance (±10%) beyond a curve's end reads that end's cell, as an
equal-time cell of that budget is (it landed within ±10% of it).

**Ranks.**  The ranked estimators are sorted by their mean error at T.  Each adjacent pair is
*resolved* when the ratio of the two errors' means excludes 1 at 95%
(:func:`~iblbench.harness.protocol.stats.compare_values`): paired when the two have the same
replicates (the same seeds and renders, which in one run they do), Welch otherwise.

**Headline budgets** (:func:`headline_budgets`): a sweep's own time budgets where it has them,
else up to three round budgets (1, 2 or 5 × 10^k ms) inside the time range the scene's cells
covered, each ranking as many estimators as possible and at least half of them, at least 2×
apart.

**Per device.**  Times of different devices are never compared: where a table holds rows of
several devices (:func:`~iblbench.harness.protocol.stats.by_device`), each device's cells are
ranked on their own, at that device's headline budgets, and each :class:`Ranking` names its
``device`` (None where the table has one device, whose rankings read as before).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from iblbench.harness.protocol.equal_time import TOLERANCE
from iblbench.harness.protocol.stats import (TIME_COLUMN, MeanCI, RatioCI, by_device,
                                             cell_values, column_interval, compare_values,
                                             skew_corrected_ci)

METRIC = "mean_delta_e76"
FLICKER = "flicker"   # a sequence's figure from its second frame on (harness/protocol/metrics.py)
METRIC_NAMES = {"mean_delta_e76": "ΔE76", "mean_delta_e2000": "ΔE2000", "rel_mse": "relMSE",
                FLICKER: "flicker"}
BUDGETS = 3                 # headline budgets per scene at most
BUDGET_SPACING = 2.0        # headline budgets at least this factor apart
BUDGET_REACH = 0.5          # a headline budget ranks at least this share of the estimators
_ROUND = (1.0, 2.0, 5.0)    # round budgets: these × 10^k ms


@dataclasses.dataclass(frozen=True)
class Point:
    """One cell of an estimator's error–time curve."""
    spp: int
    time_ms: float
    replicates: pd.Series   # the metric per (seed, render)


@dataclasses.dataclass(frozen=True)
class Standing:
    """One estimator at one budget: ``status`` "ranked" (with ``error`` and the interpolated
    ``replicates``), "not reached" or "not measured" (module docstring); ``span_ms``: its
    curve's fastest and slowest cell; ``spp``: the two spp it was read between (ranked)."""
    estimator: str
    status: str
    span_ms: tuple[float, float]
    error: MeanCI | None = None
    replicates: pd.Series | None = None
    spp: tuple[int, int] | None = None


@dataclasses.dataclass(frozen=True)
class Ranking:
    """Every estimator of one scene at one budget: ``ranked`` best first, each adjacent pair's
    :class:`RatioCI` (worse / better) in ``versus_next``, and the rest; ``device``: the device
    whose cells these are, where the table holds several (module docstring), else None."""
    scene: str
    budget_ms: float
    metric: str
    ranked: list[Standing]
    versus_next: list[RatioCI]
    unranked: list[Standing]
    device: str | None = None

    @property
    def resolved(self) -> tuple[int, int]:
        """(adjacent pairs resolved, adjacent pairs)."""
        return sum(r.significant for r in self.versus_next), len(self.versus_next)

    def pair(self, a: str, b: str) -> RatioCI | None:
        """``b``'s error over ``a``'s at this budget (any two ranked estimators, adjacent or
        not), or None where either is not ranked: the A/A control's check."""
        standings = {s.estimator: s for s in self.ranked}
        if a not in standings or b not in standings:
            return None
        return compare_values(standings[a].replicates, standings[b].replicates)

    @property
    def winner(self) -> str:
        """The best estimator, or "tie: a, b, …" for those not resolved from it in a chain."""
        if not self.ranked:
            return "–"
        tied = [self.ranked[0].estimator]
        for standing, ratio in zip(self.ranked[1:], self.versus_next):
            if ratio.significant:
                break
            tied.append(standing.estimator)
        return tied[0] if len(tied) == 1 else "tie: " + ", ".join(tied)

    def verdict(self) -> str:
        """One line, e.g. ``at 5 ms/frame: balanced_mis (ΔE76 0.9 [0.8, 1.0]) ahead of envmap
        (1.7 [1.6, 1.8]); smc not reached``."""
        name = METRIC_NAMES.get(self.metric, self.metric)
        on = f" ({self.device})" if self.device is not None else ""
        head = f"at {self.budget_ms:g} ms/frame on {self.scene}{on}: "
        if not self.ranked:
            text = head + "no estimator measured"
        elif len(self.ranked) == 1:
            text = head + f"only {self.ranked[0].estimator} ({name} {_figure(self.ranked[0])})"
        else:
            first, second, ratio = self.ranked[0], self.ranked[1], self.versus_next[0]
            pair = (f"{first.estimator} ({name} {_figure(first)}) ahead of {second.estimator} "
                    f"({_figure(second)})" if ratio.significant else
                    f"{first.estimator} ({name} {_figure(first)}) and {second.estimator} "
                    f"({_figure(second)}) not resolved (p = {ratio.p:.2g})")
            text = head + pair
            if len(self.ranked) > 2:
                last = self.ranked[-1]
                text += f"; last {last.estimator} ({_figure(last)}, {last.error.mean / first.error.mean:.2g}×)"
        for status in ("not reached", "not measured"):
            names = [s.estimator for s in self.unranked if s.status == status]
            if names:
                text += f"; {', '.join(names)} {status}"
        return text

    def to_dict(self) -> dict:
        def standing(s: Standing, ratio: RatioCI | None = None) -> dict:
            entry = {"estimator": s.estimator, "status": s.status,
                     "span_ms": [float(t) for t in s.span_ms]}
            if s.error is not None:
                entry.update(error=s.error.to_dict(), spp_between=list(s.spp))
            if ratio is not None:
                entry["versus_next"] = ratio.to_dict()
            return entry

        ratios = list(self.versus_next) + [None]
        device = {"device": self.device} if self.device is not None else {}
        return {"scene": self.scene, **device, "budget_ms": self.budget_ms, "metric": self.metric,
                "winner": self.winner, "verdict": self.verdict(),
                "resolved_pairs": list(self.resolved),
                "ranked": [standing(s, r) for s, r in zip(self.ranked, ratios)],
                "unranked": [standing(s) for s in self.unranked]}


def _figure(standing: Standing) -> str:
    ci = standing.error
    if not ci.resolved:
        return f"{ci.mean:.2g}"
    return f"{ci.mean:.2g} [{ci.low:.2g}, {ci.high:.2g}]"


def curve(rows: pd.DataFrame, metric: str = METRIC, frame: int | None = None) -> list[Point]:
    """An estimator's error–time curve on one scene: one :class:`Point` per cell (spp level or
    time budget) of ``rows``, sorted by time.  A point's time is always its cell's (every frame);
    its replicates are ``metric``'s over the cell's frames, or of ``frame`` alone.  Flicker is
    defined from the run's second frame of the sequence on, so its first frame is left out."""
    points = []
    for _, cell in rows.groupby(["spp", "time_budget_ms"], sort=False, dropna=False):
        time_ms = column_interval(cell, TIME_COLUMN)[0].mean
        scored = cell if frame is None else cell[cell.frame == frame]
        if metric == FLICKER:
            scored = scored[scored.frame != cell.frame.min()]
        if not len(scored):
            continue
        values, _ = cell_values(scored, metric)
        if math.isfinite(time_ms) and values.notna().all():
            points.append(Point(int(cell.spp.iloc[0]), float(time_ms), values))
    return sorted(points, key=lambda p: (p.time_ms, p.spp))


def standing_at(estimator: str, points: list[Point], budget_ms: float) -> Standing:
    """Where ``estimator``'s curve stands at ``budget_ms`` (module docstring)."""
    span = (points[0].time_ms, points[-1].time_ms)
    if budget_ms * (1 + TOLERANCE) < span[0]:
        return Standing(estimator, "not reached", span)
    if budget_ms > span[1] * (1 + TOLERANCE):
        return Standing(estimator, "not measured", span)
    budget_ms = min(max(budget_ms, span[0]), span[1])   # within the tolerance of an end
    upper = next(i for i, p in enumerate(points) if p.time_ms >= budget_ms)
    lo, hi = points[max(upper - 1, 0)], points[upper]
    if hi.time_ms == budget_ms:   # on a cell (or on an end, within the tolerance)
        return Standing(estimator, "ranked", span, skew_corrected_ci(hi.replicates.to_numpy()),
                        hi.replicates, (hi.spp, hi.spp))
    shared = lo.replicates.index.intersection(hi.replicates.index)
    if len(shared) < 2:   # the two cells share no replicates: nothing to read between
        return Standing(estimator, "not measured", span)
    w = math.log(budget_ms / lo.time_ms) / math.log(hi.time_ms / lo.time_ms)
    tiny = np.finfo(np.float64).tiny   # a replicate of error 0 stays finite in the log
    log_lo = np.log(np.maximum(lo.replicates[shared].to_numpy(), tiny))
    log_hi = np.log(np.maximum(hi.replicates[shared].to_numpy(), tiny))
    values = pd.Series(np.exp((1 - w) * log_lo + w * log_hi), index=shared)
    return Standing(estimator, "ranked", span, skew_corrected_ci(values.to_numpy()), values,
                    (lo.spp, hi.spp))


def rank(curves: dict[str, list[Point]], scene: str, budget_ms: float,
         metric: str = METRIC, device: str | None = None) -> Ranking:
    """Every estimator's standing at ``budget_ms`` (``curves``: estimator → :func:`curve`, of
    ``device``'s cells where the table holds several devices)."""
    standings = [standing_at(label, points, budget_ms) for label, points in curves.items() if points]
    ranked = sorted((s for s in standings if s.status == "ranked"), key=lambda s: s.error.mean)
    unranked = [s for s in standings if s.status != "ranked"]
    # worse / better, paired where the two have the same replicates, else Welch
    versus = [compare_values(a.replicates, b.replicates) for a, b in zip(ranked, ranked[1:])]
    return Ranking(scene, budget_ms, metric, ranked, versus, unranked, device)


def round_budgets(low: float, high: float) -> list[float]:
    """The round budgets (1, 2, 5 × 10^k ms) in [low, high]."""
    if not (0 < low <= high and math.isfinite(high)):
        return []
    exponents = range(math.floor(math.log10(low)) - 1, math.ceil(math.log10(high)) + 1)
    return [m * 10.0 ** k for k in exponents for m in _ROUND if low <= m * 10.0 ** k <= high]


def headline_budgets(curves: dict[str, list[Point]], sweep_budgets=()) -> list[float]:
    """The budgets a scene's ranking is shown at (module docstring)."""
    spans = [(points[0].time_ms, points[-1].time_ms) for points in curves.values() if points]
    if sweep_budgets:
        return sorted(float(b) for b in sweep_budgets)[:BUDGETS]
    if not spans:
        return []
    candidates = round_budgets(min(s[0] for s in spans), max(s[1] for s in spans))
    reach = {b: sum(lo <= b <= hi for lo, hi in spans) for b in candidates}
    chosen: list[float] = []
    # Most estimators ranked first; among equals the middle of the range (log scale) first.
    middle = math.log(min(s[0] for s in spans) * max(s[1] for s in spans)) / 2
    for budget in sorted(candidates, key=lambda b: (-reach[b], abs(math.log(b) - middle))):
        if reach[budget] >= max(2, BUDGET_REACH * len(spans)) and all(max(budget / c, c / budget) >= BUDGET_SPACING for c in chosen):
            chosen.append(budget)
        if len(chosen) == BUDGETS:
            break
    return sorted(chosen)


def scene_rankings(table: pd.DataFrame, metric: str = METRIC, budgets=None) -> dict[str, list[Ranking]]:
    """Per scene of ``table`` (a results table), its rankings at its headline budgets
    (``budgets``: the same budgets for every scene instead), each device's in turn where the
    table holds several (module docstring); none for a table without times or the metric."""
    if TIME_COLUMN not in table or metric not in table:
        return {}
    out = {scene: [] for scene in dict.fromkeys(table.scene)}
    for device, on_device in by_device(table):
        for scene, rows in on_device.groupby("scene", sort=False):
            curves = {label: curve(cells, metric)
                      for label, cells in rows.groupby("estimator", sort=False)}
            sweep = sorted(rows.time_budget_ms.dropna().unique())
            chosen = budgets if budgets is not None else headline_budgets(curves, sweep)
            out[scene] += [rank(curves, scene, budget, metric, device) for budget in chosen]
    return out


def resolved_share(rankings: dict[str, list[Ranking]]) -> tuple[int, int]:
    """(adjacent pairs resolved, adjacent pairs) over every scene and budget."""
    pairs = [r.resolved for scene in rankings.values() for r in scene]
    return sum(p[0] for p in pairs), sum(p[1] for p in pairs)


def rankings_text(rankings: dict[str, list[Ranking]]) -> str:
    """What ``iblbench run`` prints at the end: each verdict, and how many pairs resolved."""
    lines = ["equal-time answer (error read along each estimator's error-time curve; "
             "'ahead' = resolved at 95%, paired over shared seeds and renders):"]
    lines += ["  " + ranking.verdict() for scene in rankings.values() for ranking in scene]
    resolved, pairs = resolved_share(rankings)
    if pairs:
        lines.append(f"  adjacent ranks resolved: {resolved} of {pairs} ({resolved / pairs:.0%})")
    return "\n".join(lines)
