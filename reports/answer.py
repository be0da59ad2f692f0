"""The report's equal-time answer (issue 23): the scene × budget matrix the page opens with,
each scene's ranking tables at its headline budgets, and the small-multiple error–time plot with
the top three highlighted (:func:`iblbench.harness.protocol.ranking.scene_rankings` decides; this
module only shows); and the page's first sentence where a busy machine moved the times
(:func:`busy_sentence`, issue 32)."""
from __future__ import annotations

import math

import markupsafe
import pandas as pd

from iblbench.harness.protocol.ranking import METRIC_NAMES, Ranking, resolved_share
from iblbench.harness.protocol.sequence_answer import (frame_curves, frame_standings,
                                                       sequence_summary)
from iblbench.reports import plots

PLOTS = {"highlight": "answer_top3.png", "all": "answer_all.png"}
# Other programs' CPU (``timing.load.others_cores``) above this share of the cores: a quarter
# of the machine taken from the run's device threads moved its times (two busy processes on 2
# cores took 1.0-1.3 of them; idle runs here 0.0-0.02).  Not the 1-minute load average, which
# lags a run of seconds by a minute, nor the timing floor, which is poor now and then on an
# idle VM.
BUSY_SHARE = 0.25


def busy_sentence(manifest: dict | None) -> str | None:
    """The page's first sentence where other programs used more than BUSY_SHARE of the cores
    while the run rendered (``timing.load``); None otherwise, and for an older manifest."""
    load = ((manifest or {}).get("timing") or {}).get("load") or {}
    others, cores = load.get("others_cores"), load.get("cores")
    if not (isinstance(others, (int, float)) and cores and others > BUSY_SHARE * cores):
        return None
    return (f"This machine was busy during the run (other programs used {others:.1f} of its "
            f"{cores} cores), so times are less certain than on an idle machine; the intervals "
            "include that.")


def _interval(ci) -> str:
    if ci is None:
        return "–"
    if not ci.resolved:
        return f"{ci.mean:.3g} (no interval)"
    return f"{ci.mean:.3g} [{ci.low:.3g}, {ci.high:.3g}]"


def _versus(ratio) -> str:
    """The test against the next rank: ``1.73 [1.60, 1.87], p 2e-07 (paired)``."""
    if ratio is None:
        return ""
    p = f", p {ratio.p:.2g}" if math.isfinite(ratio.p) else ""
    return f"{ratio.text()}{p} ({'paired' if ratio.paired else 'unpaired'})"


def ranking_table(ranking: Ranking, table_html) -> markupsafe.Markup:
    """One budget's ranking: the ranked estimators best first, each with its error at the budget
    and its 95% interval, its ratio to the best, the two spp it was read between, and the test
    against the next rank (ratio next ÷ this, its interval, p, paired or not; resolved or not);
    then the estimators the budget does not rank, and why."""
    name = METRIC_NAMES.get(ranking.metric, ranking.metric)
    best = ranking.ranked[0].error.mean if ranking.ranked else math.nan
    rows = []
    for i, standing in enumerate(ranking.ranked):
        ratio = ranking.versus_next[i] if i < len(ranking.versus_next) else None
        rows.append({
            "rank": str(i + 1), "estimator": standing.estimator,
            f"{name} at {ranking.budget_ms:g} ms [95%]": _interval(standing.error),
            "× best": f"{standing.error.mean / best:.2f}",
            "read between spp": "–".join(str(s) for s in dict.fromkeys(standing.spp)),
            "next ÷ this [95%], p": _versus(ratio),
            "resolved": ("yes" if ratio.significant else "NO") if ratio is not None else ""})
    for standing in ranking.unranked:
        fastest, slowest = standing.span_ms
        rows.append({"rank": "–", "estimator": standing.estimator,
                     f"{name} at {ranking.budget_ms:g} ms [95%]": standing.status,
                     "× best": "", "read between spp": f"its cells: {fastest:.3g}–{slowest:.3g} ms",
                     "next ÷ this [95%], p": "", "resolved": ""})
    return table_html(pd.DataFrame(rows), "summary ranking")


def matrix_table(rankings: dict[str, list[Ranking]], table_html) -> markupsafe.Markup:
    """Scene × budget: the winner at each headline budget, or the tie (those not resolved from
    it), with the budget in ms; budgets in order, lowest first.  Rankings of several devices
    get a row per scene and device, the device named in a column of its own."""
    groups: dict[tuple, list[Ranking]] = {}
    for scene, scene_rankings in rankings.items():
        if not scene_rankings:
            groups[(scene, None)] = []   # a row of –
        for ranking in scene_rankings:
            groups.setdefault((scene, ranking.device), []).append(ranking)
    width = max((len(r) for r in groups.values()), default=0)
    labels = ["lowest budget", "middle budget", "highest budget"] if width == 3 else \
        [f"budget {i + 1}" for i in range(width)]
    named = ["device"] if any(device is not None for _, device in groups) else []
    rows = []
    for (scene, device), group in groups.items():
        row = {"scene": scene, **({"device": device} if named else {})}
        for label, ranking in zip(labels, group):
            row[label] = f"{ranking.budget_ms:g} ms: {ranking.winner}"
        rows.append(row)
    return table_html(pd.DataFrame(rows, columns=["scene", *named, *labels]).fillna("–"),
                      "summary matrix")


def answer_context(draw, cells, rankings: dict[str, list[Ranking]], table_html) -> dict:
    """The page's opening: the matrix, the verdicts, the share of adjacent ranks resolved and
    the two versions of the small-multiple plot (drawn by ``draw(name, plot, *arguments)``,
    the report's :meth:`~iblbench.reports.figures.Figures.draw`)."""
    if not any(rankings.values()):
        return {}
    for highlight, name in ((True, PLOTS["highlight"]), (False, PLOTS["all"])):
        draw(name, plots.plot_answer, cells, rankings, highlight)
    resolved, pairs = resolved_share(rankings)
    return {"matrix": matrix_table(rankings, table_html), "plots": PLOTS,
            "resolved": resolved, "pairs": pairs,
            "verdicts": [r.verdict() for scene in rankings.values() for r in scene]}


def _figure(mean: float, low: float, high: float) -> str:
    if not math.isfinite(mean):
        return "–"
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"{mean:.3g} (no interval)"
    return f"{mean:.3g} [{low:.3g}, {high:.3g}]"


def sequence_table(summary: pd.DataFrame, budget_ms: float, table_html) -> markupsafe.Markup:
    """One budget's :func:`~iblbench.harness.protocol.sequence_answer.sequence_summary`: per
    estimator its ΔE76 and flicker over the frames with their 95% intervals and its worst frame,
    or why the budget does not rank it."""
    rows = []
    for r in summary.itertuples(index=False):
        ranked = r.status == "ranked"
        rows.append({
            "estimator": r.estimator,
            f"ΔE76 at {budget_ms:g} ms [95%]": (_figure(r.delta_e76, r.delta_e76_low,
                                                        r.delta_e76_high) if ranked else r.status),
            "flicker [95%]": _figure(r.flicker, r.flicker_low, r.flicker_high) if ranked else "",
            "worst frame (ΔE76)": (f"{int(r.worst_frame)} ({r.worst_delta_e76:.3g})"
                                   if ranked and math.isfinite(r.worst_delta_e76) else "")})
    return table_html(pd.DataFrame(rows), "summary ranking")


def sequence_context(draw, rows: pd.DataFrame, scene: str, slug: str,
                     rankings: list[Ranking], table_html) -> dict | None:
    """A sequence's error and flicker at equal time: a table per headline budget, and the
    per-frame plot at the middle one (drawn by ``draw``); None for a single frame or a scene
    without budgets."""
    if rows.frame.nunique() < 2 or not rankings:
        return None
    tables = []
    middle = rankings[len(rankings) // 2].budget_ms
    plot = f"frames_at_budget_{slug}.png"
    curves = frame_curves(rows)   # every budget reads the same curves
    for ranking in rankings:
        standings = frame_standings(rows, ranking.budget_ms, curves)
        tables.append({"budget_ms": ranking.budget_ms,
                       "table": sequence_table(sequence_summary(standings), ranking.budget_ms,
                                               table_html)})
        if ranking.budget_ms == middle:
            draw(plot, plots.plot_frames_at_budget, standings, scene, middle,
                 list(dict.fromkeys(rows.estimator)))
    return {"tables": tables, "plot": plot, "budget_ms": middle}
