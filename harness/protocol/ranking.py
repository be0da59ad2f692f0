"""The equal-time answer: which estimator wins at a time budget per frame, and how sure that is
(issue 23).  The report opens with it, ``iblbench run`` prints it and ``run --json`` carries it.

**Error at a budget.**  Each estimator's cells of a scene (its spp levels and equal-time cells)
are points of its error–time curve: the cell's time (the median of its timed renders,
:func:`~iblbench.harness.protocol.stats.column_interval`) and its replicates of the metric (one
value per (seed, render), :func:`~iblbench.harness.protocol.stats.cell_values`).  More samples
never take less time, so the curve's times are first made to rise with spp: the least-squares
non-decreasing fit (isotonic regression, :func:`rising`), which pools a higher-spp cell measured
faster than a lower-spp one with it instead of reading between two cells out of order.  The
error at a budget T is read along that curve between the two points whose times bracket T,
interpolated in log–log (log error linear in log time), *replicate by replicate*: replicate
(s, r) at T is exp((1 − w)·log e_lo(s, r) + w·log e_hi(s, r)), w = log(T / t_lo) / log(t_hi /
t_lo); the error is their mean.

**Uncertainty: times and replicates together** (issue 32).  The budget's place on a curve
depends on measured times, which move 2× between two renders of the same work on a busy
machine; so the interval carries their uncertainty as well as the replicates'.  A bootstrap of
``BOOTSTRAP`` draws: each draw resamples every cell's timed renders (its time: their median;
:func:`_time_draws`, seeded by the cell), fits each curve's rising times again and reads the
error at T as above, with each replicate key (seed, render) weighed by a Poisson(1) count seeded
by the key (:func:`_key_weights`), so estimators with the same replicates are resampled
together (paired), and a pair's draws do not depend on what else the table holds; a table
always reads the same.  An estimator's interval, and the ratio of two estimators' errors, are
the 95% percentile intervals of those draws after their log deviations from the estimate are
widened by t(n − 1)/z · √(n/(n − 1)) for n replicates, so that without time noise they match
the Student-t interval rather than the bootstrap's narrower one (:func:`_widened`); a ratio's
p-value is twice the share of its widened draws on the far side of 1, so p < 0.05 exactly when
its interval excludes 1.  Two estimators whose replicates are identical (an unchanged copy
under another name) are then apart only where their times are apart beyond their renders'
spread.  Measured on the recorded timing noise of this machine
(:mod:`iblbench.harness.verify.timing_noise`, tests/test_timing_noise.py): the copy is called
apart in 2–3% of verdicts (30 of 30 when the times are taken as exact), and an estimator with
half the error at equal time is resolved in every one.

**Who is not ranked.**  An estimator is placed at T only where its measured cells bracket T: one
whose fastest cell (on the rising fit) takes longer than T is "not reached" (it cannot render a
frame in T at the spp measured); one whose slowest cell is faster than T is "not measured" (its
error at T would need more spp than the sweep ran; no extrapolation).  The one exception is an
equal-time cell of budget T at its curve's end that landed within the equal-time tolerance
(±10%) of T: it was measured for T, and is read there.

**Off budget.**  A standing read from an equal-time cell whose time missed its budget by more
than ``TOLERANCE`` is marked (``Standing.missed``), and the verdict names it ("off budget: …").

**Ranks.**  The ranked estimators are sorted by their mean error at T.  Each adjacent pair is
*resolved* when the bootstrap interval of the ratio of their errors excludes 1 (:func:`versus`).
A standing is marked off budget only where it reads an equal-time cell of T itself that missed
T; a cell calibrated for another budget is a point of the curve like any other.

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
import zlib

import numpy as np
import pandas as pd

from iblbench.harness.protocol.equal_time import TOLERANCE
from iblbench.harness.protocol.metric import higher_is_better, labels
from iblbench.harness.protocol.stats import (TIME_COLUMN, MeanCI, RatioCI, by_device,
                                             cell_values, column_interval, render_times,
                                             t_quantile)
from iblbench.harness.protocol.timing import robust_ms

METRIC = "mean_delta_e76"
FLICKER = "flicker"   # a sequence's figure from its second frame on (harness/protocol/metrics.py)
METRIC_NAMES = {**labels(), FLICKER: "flicker"}
BUDGETS = 3                 # headline budgets per scene at most
BUDGET_SPACING = 2.0        # headline budgets at least this factor apart
BUDGET_REACH = 0.5          # a headline budget ranks at least this share of the estimators
_ROUND = (1.0, 2.0, 5.0)    # round budgets: these × 10^k ms
BOOTSTRAP = 1000            # draws of the joint bootstrap of times and replicates
BOOTSTRAP_SEED = 20230     # fixed: a table's answer does not change from one reading to the next


@dataclasses.dataclass(frozen=True)
class Point:
    """One cell of an estimator's error–time curve: its robust time, its replicates of the
    metric, the bootstrap's draws of its time (:func:`_time_draws`, made once per cell, whatever
    budgets the curve is read at) and the budget it was calibrated for (None for an spp
    level)."""
    spp: int
    time_ms: float
    replicates: pd.Series   # the metric per (seed, render)
    time_draws: np.ndarray
    budget_ms: float | None = None

    @property
    def missed(self) -> bool:
        """An equal-time cell whose time lies more than TOLERANCE from its budget."""
        return (self.budget_ms is not None
                and abs(self.time_ms - self.budget_ms) > TOLERANCE * self.budget_ms)


@dataclasses.dataclass(frozen=True)
class Standing:
    """One estimator at one budget: ``status`` "ranked" (with ``error``, the interpolated
    ``replicates`` and the bootstrap ``draws`` of its error), "not reached" or "not measured"
    (module docstring); ``span_ms``: its curve's fastest and slowest cell; ``spp``: the two spp
    it was read between (ranked); ``missed``: it rests on an equal-time cell that missed its
    budget by more than TOLERANCE."""
    estimator: str
    status: str
    span_ms: tuple[float, float]
    error: MeanCI | None = None
    replicates: pd.Series | None = None
    spp: tuple[int, int] | None = None
    draws: np.ndarray | None = None
    missed: bool = False


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

    @property
    def missed(self) -> list[str]:
        """The ranked estimators read from an equal-time cell off its budget (module docstring)."""
        return [s.estimator for s in self.ranked if s.missed]

    def pair(self, a: str, b: str) -> RatioCI | None:
        """``b``'s error over ``a``'s at this budget (any two ranked estimators, adjacent or
        not), or None where either is not ranked: the A/A control's check."""
        standings = {s.estimator: s for s in self.ranked}
        if a not in standings or b not in standings:
            return None
        return versus(standings[a], standings[b])

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
        if self.missed:
            text += (f"; off budget: {', '.join(self.missed)} (equal-time cells more than "
                     f"{TOLERANCE:.0%} from {self.budget_ms:g} ms)")
        return text

    def to_dict(self) -> dict:
        def standing(s: Standing, ratio: RatioCI | None = None) -> dict:
            entry = {"estimator": s.estimator, "status": s.status,
                     "span_ms": [float(t) for t in s.span_ms]}
            if s.error is not None:
                entry.update(error=s.error.to_dict(), spp_between=list(s.spp),
                             off_budget=s.missed)
            if ratio is not None:
                entry["versus_next"] = ratio.to_dict()
            return entry

        ratios = list(self.versus_next) + [None]
        device = {"device": self.device} if self.device is not None else {}
        return {"scene": self.scene, **device, "budget_ms": self.budget_ms, "metric": self.metric,
                "winner": self.winner, "verdict": self.verdict(),
                "resolved_pairs": list(self.resolved), "off_budget": self.missed,
                "ranked": [standing(s, r) for s, r in zip(self.ranked, ratios)],
                "unranked": [standing(s) for s in self.unranked]}


def _figure(standing: Standing) -> str:
    ci = standing.error
    if not ci.resolved:
        return f"{ci.mean:.2g}"
    return f"{ci.mean:.2g} [{ci.low:.2g}, {ci.high:.2g}]"


def curve(rows: pd.DataFrame, metric: str = METRIC, frame: int | None = None,
          times: dict | None = None) -> list[Point]:
    """An estimator's error–time curve on one scene: one :class:`Point` per cell (spp level or
    time budget) of ``rows``, sorted by spp.  A point's time is always its cell's (every frame);
    its replicates are ``metric``'s over the cell's frames, or of ``frame`` alone.  Flicker is
    defined from the run's second frame of the sequence on, so its first frame is left out.
    ``times``: the cells' times and their draws kept by cell between calls on the same rows
    (a sequence's curves, one per frame and metric, share them)."""
    times = {} if times is None else times
    if metric in higher_is_better():   # the curve is read in log-log space as an error falling with time
        raise ValueError(f"the equal-time ranking reads errors (lower is better); "
                         f"{metric} is higher-is-better")
    points = []
    for _, cell in rows.groupby(["spp", "time_budget_ms"], sort=False, dropna=False):
        scored = cell if frame is None else cell[cell.frame == frame]
        if metric == FLICKER:
            scored = scored[scored.frame != cell.frame.min()]
        if not len(scored):
            continue
        values, _ = cell_values(scored, metric)
        spp, budget = int(cell.spp.iloc[0]), cell.time_budget_ms.iloc[0]
        budget = None if pd.isna(budget) else float(budget)
        name = f"{cell.estimator.iloc[0]}|{spp}|{budget}"
        if name not in times:
            time_ms = column_interval(cell, TIME_COLUMN)[0].mean
            times[name] = (time_ms, _time_draws(name, render_times(cell), float(time_ms))
                           if math.isfinite(time_ms) else None)
        time_ms, draws = times[name]
        if math.isfinite(time_ms) and values.notna().all():
            points.append(Point(spp, float(time_ms), values, draws, budget))
    return sorted(points, key=lambda p: (p.spp, p.time_ms))


def rising(times: np.ndarray) -> np.ndarray:
    """The least-squares non-decreasing fit of ``times`` along the last axis (a curve's times in
    spp order: more samples never take less time), by the min–max formula of isotonic
    regression, fit_i = max over j ≤ i of min over k ≥ i of mean(times[j..k]) (Barlow et al.
    1972), vectorised over the leading axes (the bootstrap's draws).  The means are taken of the
    times less times[i], so that a curve that already rises keeps its times bit for bit (summed
    as they were, a curve of 0.2 and 0.5 ms rose to 0.49999999999999994, and a budget of 0.5 ms
    was "not measured" on it); a running maximum keeps a pooled block, whose points' means then
    differ in their last bits, from falling."""
    times = np.asarray(times, np.float64)
    size = times.shape[-1]
    fit = np.empty_like(times)
    for i in range(size):
        deviations = times - times[..., i:i + 1]
        sums = np.concatenate([np.zeros(times.shape[:-1] + (1,)), np.cumsum(deviations, -1)], -1)
        means = [[(sums[..., k + 1] - sums[..., j]) / (k - j + 1) for k in range(i, size)]
                 for j in range(i + 1)]
        fit[..., i] = times[..., i] + np.max([np.min(row, axis=0) for row in means], axis=0)
    return np.maximum.accumulate(fit, axis=-1)


def _key_weights(keys) -> np.ndarray:
    """The bootstrap's weight of each replicate key in each draw, [BOOTSTRAP, len(keys)]:
    Poisson(1) counts seeded by the key alone (Hanley & MacGibbon 2006), so two estimators
    with a key in common weigh it alike in every draw (paired), whatever else the table holds."""
    return np.stack([np.random.default_rng([BOOTSTRAP_SEED, *map(int, key)]).poisson(
        1.0, BOOTSTRAP) for key in keys], axis=1)


def _time_draws(cell: str, times: np.ndarray, time_ms: float) -> np.ndarray:
    """BOOTSTRAP draws of a cell's robust time: its timed render ``times`` resampled, seeded by
    the ``cell`` ("estimator|spp|budget"); its ``time_ms`` itself, without renders to resample.
    Resampling them by replicate key instead, so that one round's renders go together in every
    cell, resolved no more pairs of the default sweep (177 of 213, against 180)."""
    if times.size < 2:
        return np.full(BOOTSTRAP, time_ms)
    picks = np.random.default_rng([BOOTSTRAP_SEED, zlib.crc32(cell.encode())]).integers(
        0, times.size, size=(BOOTSTRAP, times.size))
    return robust_ms(times[picks], axis=1)


def standing_at(estimator: str, points: list[Point], budget_ms: float) -> Standing:
    """Where ``estimator``'s curve stands at ``budget_ms`` (module docstring), with the bootstrap
    draws of its error there."""
    times = rising([p.time_ms for p in points])
    span = (float(times[0]), float(times[-1]))
    at_end = [p for p, t in zip(points, times) if p.budget_ms == budget_ms
              and abs(t - budget_ms) <= TOLERANCE * budget_ms and t in span]
    if budget_ms < span[0] and not at_end:
        return Standing(estimator, "not reached", span)
    if budget_ms > span[1] and not at_end:
        return Standing(estimator, "not measured", span)
    keys = points[0].replicates.index
    for point in points[1:]:
        keys = keys.intersection(point.replicates.index)
    if len(keys) < 2:   # the cells share no replicates: nothing to read between
        return Standing(estimator, "not measured", span)
    tiny = np.finfo(np.float64).tiny   # a replicate of error 0 stays finite in the log
    logs = np.log(np.maximum([p.replicates[keys].to_numpy() for p in points], tiny))
    clamped = min(max(budget_ms, span[0]), span[1])   # an equal-time cell at its curve's end
    (lo,), (hi,), (w,), (values,) = _read(logs, times[None, :], clamped)
    drawn = _read(logs, rising(np.stack([p.time_draws for p in points], 1)), clamped)[3]
    weights = _key_weights(keys)
    total = weights.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        error = np.where(total > 0, (weights * drawn).sum(axis=1) / total, np.nan)
    used = sorted({int(lo), int(hi)} if 0 < w < 1 else {int(hi if w else lo)})
    spp = tuple(points[i].spp for i in used)
    return Standing(estimator, "ranked", span,
                    _bootstrap_ci(float(values.mean()), error, len(keys)),
                    pd.Series(values, index=keys), spp if len(spp) == 2 else spp * 2, error,
                    any(points[i].missed and points[i].budget_ms == budget_ms for i in used))


def _between(times: np.ndarray, budget_ms: float):
    """Per row of ``times`` (rising along the last axis): the indices of the two points whose
    times bracket ``budget_ms`` and the log–log weight of the upper one, 0 or 1 on a point
    (clamped at the ends)."""
    size = times.shape[-1]
    upper = np.clip((times < budget_ms).sum(axis=-1), 1, max(size - 1, 1)) if size > 1 \
        else np.zeros(times.shape[0], int)
    lower = np.maximum(upper - 1, 0)
    t_lo = np.take_along_axis(times, lower[:, None], 1)[:, 0]
    t_hi = np.take_along_axis(times, upper[:, None], 1)[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(t_hi > t_lo, np.log(budget_ms / t_lo) / np.log(t_hi / t_lo), 1.0)
    return lower, upper, np.clip(w, 0.0, 1.0)


def _read(logs: np.ndarray, times: np.ndarray, budget_ms: float):
    """Per row of ``times`` (:func:`_between`): the bracketing indices, the weight and the
    replicates read at ``budget_ms`` log–log from ``logs`` (the points' log replicates)."""
    lower, upper, w = _between(times, budget_ms)
    return lower, upper, w, np.exp((1 - w[:, None]) * logs[lower] + w[:, None] * logs[upper])


def _widened(estimate: float, draws: np.ndarray, n: int) -> np.ndarray:
    """The finite positive ``draws`` of a figure, their log deviations from ``estimate`` scaled
    by t(n − 1)/z · √(n/(n − 1)), so that for a normal mean the percentile interval they give is
    the Student-t interval rather than the bootstrap's narrower one; empty for n < 2."""
    draws = draws[np.isfinite(draws) & (draws > 0)]
    if n < 2 or not draws.size:
        return np.empty(0)
    scale = t_quantile(n - 1) / t_quantile(math.inf) * math.sqrt(n / (n - 1))
    return estimate * np.exp(scale * (np.log(draws) - math.log(estimate)))


def _bootstrap_ci(estimate: float, draws: np.ndarray, n: int) -> MeanCI:
    """``estimate`` with the 95% percentile interval of its widened bootstrap ``draws``."""
    widened = _widened(estimate, draws, n)
    if not widened.size:
        return MeanCI(estimate, math.nan, math.nan, n, math.nan)
    low, high = np.percentile(widened, [2.5, 97.5])
    return MeanCI(estimate, float(low), float(high), n, math.nan)


def versus(a: Standing, b: Standing) -> RatioCI:
    """``b``'s error over ``a``'s from their draws (paired on the replicate keys they share,
    their times resampled each on its own): the 95% percentile interval of the widened ratio
    draws, and its p-value from the same draws, twice the share on the far side of 1 (so p <
    0.05 exactly when the interval excludes 1)."""
    ratio = b.error.mean / a.error.mean
    n = min(len(a.replicates), len(b.replicates))
    paired = a.replicates.index.sort_values().equals(b.replicates.index.sort_values())
    widened = _widened(ratio, b.draws / a.draws, n)
    if not widened.size:
        return RatioCI(ratio, math.nan, math.nan, math.nan, "n=1: no interval", paired=paired)
    low, high = np.percentile(widened, [2.5, 97.5])
    p = min(1.0, 2 * min(np.mean(widened <= 1), np.mean(widened >= 1)))
    return RatioCI(ratio, float(low), float(high), math.nan, p=float(p), paired=paired)


def rank(curves: dict[str, list[Point]], scene: str, budget_ms: float,
         metric: str = METRIC, device: str | None = None) -> Ranking:
    """Every estimator's standing at ``budget_ms`` (``curves``: estimator → :func:`curve`, of
    ``device``'s cells where the table holds several devices)."""
    standings = [standing_at(label, points, budget_ms)
                 for label, points in curves.items() if points]
    ranked = sorted((s for s in standings if s.status == "ranked"), key=lambda s: s.error.mean)
    unranked = [s for s in standings if s.status != "ranked"]
    return Ranking(scene, budget_ms, metric, ranked,
                   [versus(a, b) for a, b in zip(ranked, ranked[1:])], unranked, device)


def round_budgets(low: float, high: float) -> list[float]:
    """The round budgets (1, 2, 5 × 10^k ms) in [low, high]."""
    if not (0 < low <= high and math.isfinite(high)):
        return []
    exponents = range(math.floor(math.log10(low)) - 1, math.ceil(math.log10(high)) + 1)
    return [m * 10.0 ** k for k in exponents for m in _ROUND if low <= m * 10.0 ** k <= high]


def headline_budgets(curves: dict[str, list[Point]], sweep_budgets=()) -> list[float]:
    """The budgets a scene's ranking is shown at (module docstring)."""
    spans = [tuple(rising([p.time_ms for p in points])[[0, -1]]) for points in curves.values()
             if points]
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
             "'ahead' = resolved at 95%, times and errors resampled together):"]
    lines += ["  " + ranking.verdict() for scene in rankings.values() for ranking in scene]
    resolved, pairs = resolved_share(rankings)
    if pairs:
        lines.append(f"  adjacent ranks resolved: {resolved} of {pairs} ({resolved / pairs:.0%})")
    return "\n".join(lines)
