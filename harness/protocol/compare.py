"""``iblbench compare A B``: two result folders, cell by cell, with intervals.

**Cells.**  A cell is (scene, estimator, spp or time budget, frame), as in the results table
(:func:`iblbench.harness.protocol.results.row_key` without the seed).  In each cell and for each metric
of ``METRICS`` (every registered metric's column, :mod:`iblbench.harness.protocol.metric`, then
``effective_ratio`` and ``time_ms``) present in both folders (FLIP only where both runs computed
it), compare takes
each side's figure with its interval as the report does
(:func:`iblbench.harness.protocol.stats.column_interval`) and the ratio B/A of the means with its
95% interval (:func:`iblbench.harness.protocol.stats.compare_values`: delta method on
log(ratio)).  The values compared are the cells' replicates (each scored render of each seed; a
time: each timed render) where the rows carry them, else one value per seed.  When the two
sides have the same replicates (the same seeds and repeats: a rerun of one sweep) the test is
**paired** over them, so what a seed's renders share cancels; otherwise, and for a rerun with other seeds,
the sides are independent samples (Welch–Satterthwaite).  Each metric's entry gives the p-value
of the test used and, beside it, ``p_unpaired``: Welch's on the same values.
A change is **significant** when the interval excludes 1; it is marked ``worse`` or ``better``
by the metric's direction (its descriptor's; ``effective_ratio``: higher is better).  A cell with one
value on either side has no interval and is never significant ("n=1").

**Pairing estimators.**  Labels carry parameter overrides (``balanced{uniform_faces=true}``).
Equal labels are paired first.  Then a label left over on each side with the same base name
(the part before ``{``) is paired with it, when it is the only one of that base name left on
each side, so a run made with ``balanced{uniform_faces=true}`` in place of ``balanced`` is
compared with ``balanced``; such a pairing is printed as a difference.  Anything still
unpaired is listed as only in A or only in B and not compared.

**Thresholds.**  ``--fail-if 'METRIC>P%'`` (an increase of more than P%) or
``'METRIC<-P%'`` (a decrease of more than P%), repeatable.  A cell fails a threshold only
when its change is significant **and** its ratio is beyond the threshold (ratio > 1 + P/100,
or < 1 − P/100): a change within seed noise never fails, however large its point estimate.
Exit 1 when any cell fails (the cells are named), 0 otherwise; 2 on bad input (a missing
folder or table, no common cell, a bad threshold, a threshold on a metric no common cell has).

**Differences.**  compare says when the folders differ in code (the manifest's git revision,
each paired estimator's ``estimator_version``), device (the rows' ``device``), protocol
(``protocol``, ``schema_version``, ``metrics``, the manifest's timing ``measure`` and each
paired estimator's ``repeats``: a row's ``time_repeats`` varies with the timing spread, so it is no protocol) or
configuration (``width``,
``height``, ``env_res``).  It compares them anyway: the user decides what a difference means;
times are only meaningful on one device.  A cell whose rows on either side several devices ran
has its times left uncompared (times are never pooled over devices: :mod:`iblbench.harness.protocol.stats`).

Not done: correction for the many cells × metrics tested (at 95% one comparison in 20 of
unchanged code is significant by chance; a threshold keeps those small chance changes from
failing).
"""
from __future__ import annotations

import dataclasses
import difflib
import math
import pathlib
import re
import sys

import pandas as pd

from iblbench.harness.protocol.metric import columns, higher_is_better
from iblbench.harness.protocol.results import KEY_COLUMNS, json_text, load_table, read_manifest, row_key
from iblbench.harness.protocol.stats import (LEVEL, RATIO_METHOD, MeanCI, RatioCI, cell_values,
                                             column_interval, compare_values, devices,
                                             is_time_column, ratio_ci)
from iblbench.foundation.errors import InputError

METRICS = (*columns(), "effective_ratio", "time_ms")
HIGHER_IS_BETTER = frozenset({"effective_ratio", *higher_is_better()})
REQUIRED_COLUMNS = KEY_COLUMNS + ["estimator_version", "device", "protocol"]
# (what differs, row column): values compared between the two folders.
DIFFERENCE_COLUMNS = (("device", "device"), ("protocol", "protocol"),
                      ("protocol", "schema_version"), ("protocol", "metrics"),
                      ("configuration", "width"),
                      ("configuration", "height"), ("configuration", "env_res"))
_THRESHOLD = re.compile(r"^\s*(\w+)\s*([<>])\s*([+-]?\d+(?:\.\d*)?)\s*%\s*$")


@dataclasses.dataclass(frozen=True)
class Threshold:
    """``metric > change`` or ``metric < change``, change a fraction (0.05 for 5%)."""
    metric: str
    sign: str
    change: float
    text: str

    def exceeded(self, ratio: RatioCI) -> bool:
        """Significant and beyond the threshold."""
        if not ratio.significant:
            return False
        if self.sign == ">":
            return ratio.ratio > 1 + self.change
        return ratio.ratio < 1 + self.change


def parse_threshold(text: str) -> Threshold:
    """``'mean_delta_e76>5%'`` → a :class:`Threshold` (InputError naming the problem)."""
    match = _THRESHOLD.match(text)
    if not match:
        raise InputError(None, f"--fail-if {text!r}: write METRIC>P% (an increase of more than "
                               "P%) or METRIC<-P% (a decrease), e.g. 'mean_delta_e76>5%'")
    metric, sign, percent = match.group(1), match.group(2), float(match.group(3))
    if metric not in METRICS:
        near = difflib.get_close_matches(metric, METRICS, n=1)
        hint = f"did you mean '{near[0]}'? " if near else ""
        raise InputError(None, f"--fail-if {text!r}: unknown metric '{metric}'; {hint}"
                               f"metrics: {', '.join(METRICS)}")
    if (sign == ">" and percent < 0) or (sign == "<" and percent > 0):
        raise InputError(None, f"--fail-if {text!r}: use '>' with an increase (P ≥ 0) and '<' "
                               "with a decrease (-P ≤ 0)")
    return Threshold(metric, sign, percent / 100, text.strip())


def base_name(label: str) -> str:
    """The estimator name of a label without its parameter overrides."""
    return label.split("{", 1)[0]


def pair_estimators(labels_a, labels_b) -> tuple[list[tuple[str, str]], list[str], list[str]]:
    """(pairs (label in A, label in B), labels only in A, labels only in B): equal labels,
    then one leftover label per side with the same base name (module docstring)."""
    left_a, left_b = set(labels_a), set(labels_b)
    pairs = [(label, label) for label in sorted(left_a & left_b)]
    left_a -= left_b
    left_b -= set(labels_a)
    for base in sorted({base_name(l) for l in left_a} & {base_name(l) for l in left_b}):
        in_a = [l for l in left_a if base_name(l) == base]
        in_b = [l for l in left_b if base_name(l) == base]
        if len(in_a) == 1 and len(in_b) == 1:
            pairs.append((in_a[0], in_b[0]))
            left_a.remove(in_a[0])
            left_b.remove(in_b[0])
    return pairs, sorted(left_a), sorted(left_b)


def _cells(table: pd.DataFrame) -> dict[tuple, pd.DataFrame]:
    """(scene, estimator, spp | None, time budget | None, frame) → the cell's rows (its seeds)."""
    keys = [(scene, label, spp, budget, frame)
            for scene, label, spp, frame, _, budget in map(row_key, table.to_dict("records"))]
    return {key: rows for key, rows in table.groupby(pd.Series(keys, index=table.index),
                                                      sort=False)}


def cell_name(scene: str, label_a: str, label_b: str, spp, budget, frame) -> str:
    estimator = label_a if label_a == label_b else f"{label_a} → {label_b}"
    size = f"{budget:g} ms" if budget is not None else f"spp={spp}"
    return f"{scene} {estimator} {size} frame {frame}"


def _values(table: pd.DataFrame, column: str) -> str:
    if column not in table.columns:
        return "-"
    return ", ".join(sorted({str(v) for v in table[column].dropna()})) or "-"


def _differences(table_a, table_b, manifest_a, manifest_b, pairs) -> list[str]:
    found = []
    git_a, git_b = manifest_a.get("git_revision"), manifest_b.get("git_revision")
    if git_a != git_b:
        found.append(f"code: git revision {git_a or 'unknown'} (A) vs {git_b or 'unknown'} (B)")
    for label_a, label_b in pairs:
        versions_a = _values(table_a[table_a.estimator == label_a], "estimator_version")
        versions_b = _values(table_b[table_b.estimator == label_b], "estimator_version")
        if label_a != label_b:
            found.append(f"estimator: {label_a} (A) paired with {label_b} (B) by base name")
        if versions_a != versions_b:
            found.append(f"code: {label_b} estimator_version {versions_a} (A) vs {versions_b} (B)")
    timing_a, timing_b = manifest_a.get("timing", {}), manifest_b.get("timing", {})
    if timing_a.get("measure") != timing_b.get("measure"):
        found.append(f"protocol: timing measure {timing_a.get('measure')} (A) vs "
                     f"{timing_b.get('measure')} (B)")
    for label_a, label_b in pairs:   # repeats are per estimator label: only the paired ones
        repeats_a = timing_a.get("repeats", {}).get(label_a)
        repeats_b = timing_b.get("repeats", {}).get(label_b)
        if repeats_a != repeats_b:
            found.append(f"protocol: {label_b} timing repeats {repeats_a} (A) vs {repeats_b} (B)")
    for what, column in DIFFERENCE_COLUMNS:
        value_a, value_b = _values(table_a, column), _values(table_b, column)
        if value_a != value_b:
            found.append(f"{what}: {column} {value_a} (A) vs {value_b} (B)")
    return found


def _direction(metric: str, ratio: RatioCI) -> str | None:
    if not ratio.significant:
        return None
    increased = ratio.ratio > 1
    return "better" if increased == (metric in HIGHER_IS_BETTER) else "worse"


def _comparable(values_a: pd.Series, values_b: pd.Series) -> bool:
    return bool(values_a.notna().any() and values_b.notna().any())


def compare(dir_a, dir_b, thresholds=()) -> dict:
    """The comparison of two run folders as a JSON-ready dict (``iblbench compare --json``);
    ``failures`` lists every (cell, threshold) exceeded.  InputError on bad input."""
    dir_a, dir_b = pathlib.Path(dir_a), pathlib.Path(dir_b)
    table_a, table_b = (load_table(d, REQUIRED_COLUMNS) for d in (dir_a, dir_b))
    pairs, only_a, only_b = pair_estimators(table_a.estimator.unique(), table_b.estimator.unique())
    cells_a, cells_b = _cells(table_a), _cells(table_b)
    partner = dict(pairs)
    cells, failures, compared = [], [], set()
    matched_b = set()
    for key, rows_a in cells_a.items():
        scene, label_a, spp, budget, frame = key
        key_b = (scene, partner.get(label_a), spp, budget, frame)
        if key_b not in cells_b:
            continue
        matched_b.add(key_b)
        rows_b = cells_b[key_b]
        name = cell_name(scene, label_a, key_b[1], spp, budget, frame)
        metrics = {}
        for metric in METRICS:
            if metric not in rows_a.columns or metric not in rows_b.columns \
                    or not _comparable(rows_a[metric], rows_b[metric]) \
                    or (is_time_column(metric) and max(len(devices(r)) for r in (rows_a, rows_b)) > 1):
                continue
            compared.add(metric)
            values_a, values_b = (cell_values(rows, metric)[0] for rows in (rows_a, rows_b))
            ratio = compare_values(values_a, values_b)
            unpaired = ratio_ci(values_a.to_numpy(), values_b.to_numpy())
            metrics[metric] = {"a": column_interval(rows_a, metric)[0].to_dict(),
                               "b": column_interval(rows_b, metric)[0].to_dict(),
                               **ratio.to_dict(), "p_unpaired": unpaired.to_dict()["p"],
                               "change": _direction(metric, ratio)}
            failures += [{"cell": name, "metric": metric, "threshold": t.text,
                          "ratio": ratio.ratio, "low": ratio.low, "high": ratio.high}
                         for t in thresholds if t.metric == metric and t.exceeded(ratio)]
        cells.append({"name": name, "scene": scene, "estimator_a": label_a,
                      "estimator_b": key_b[1], "spp": spp, "time_budget_ms": budget,
                      "frame": frame, "metrics": metrics})
    if not cells:
        raise InputError(None, f"{dir_a} and {dir_b} have no cell in common (estimators "
                               f"{', '.join(table_a.estimator.unique())} vs "
                               f"{', '.join(table_b.estimator.unique())})")
    missing = sorted({t.metric for t in thresholds} - compared)
    if missing:
        raise InputError(None, f"--fail-if on {', '.join(missing)}: no common cell has it in "
                               "both runs")
    manifest_a, manifest_b = read_manifest(dir_a), read_manifest(dir_b)
    return {
        "a": str(dir_a), "b": str(dir_b), "level": LEVEL, "method": RATIO_METHOD,
        "differences": _differences(table_a, table_b, manifest_a, manifest_b, pairs),
        "pairs": [{"a": a, "b": b} for a, b in pairs],
        "only_in_a": {"estimators": only_a,
                      "cells": sum(k[1] in partner for k in cells_a) - len(cells)},
        "only_in_b": {"estimators": only_b,
                      "cells": sum(k[1] in partner.values() for k in cells_b) - len(matched_b)},
        "thresholds": [t.text for t in thresholds],
        "cells": cells,
        "failures": failures,   # significant, so every figure is finite
    }


def _ci_text(summary: dict) -> str:
    return MeanCI(*(math.nan if summary[k] is None else summary[k]
                    for k in ("mean", "low", "high")), summary["n"], math.nan).text()


def _ratio_text(entry: dict) -> str:
    return RatioCI(*(math.nan if entry[k] is None else entry[k]
                     for k in ("ratio", "low", "high", "df")), entry["reason"] or "").text()


def _p_text(entry: dict) -> str:
    """``2e-05 paired (Welch 0.031)``, or ``0.031 Welch``; empty without a p-value."""
    if entry["p"] is None:
        return ""
    if not entry["paired"]:
        return f"{entry['p']:.2g} Welch"
    welch = "–" if entry["p_unpaired"] is None else f"{entry['p_unpaired']:.2g}"
    return f"{entry['p']:.2g} paired (Welch {welch})"


def format_text(summary: dict) -> str:
    """The terminal form of :func:`compare`'s summary."""
    lines = [f"A: {summary['a']}", f"B: {summary['b']}"]
    lines += [f"differs in {d}" for d in summary["differences"]] or [
        "same code, device, protocol and configuration"]
    for side in ("a", "b"):
        only = summary[f"only_in_{side}"]
        if only["estimators"] or only["cells"]:
            lines.append(f"only in {side.upper()} (not compared): "
                         f"{', '.join(only['estimators']) or '-'}; {only['cells']} cell(s) of "
                         "paired estimators")
    rows = []
    for cell in summary["cells"]:
        for metric, entry in cell["metrics"].items():
            rows.append({"cell": cell["name"], "metric": metric,
                         "n A/B": f"{entry['a']['n']}/{entry['b']['n']}",
                         "A": _ci_text(entry["a"]), "B": _ci_text(entry["b"]),
                         "B/A [95%]": _ratio_text(entry), "p": _p_text(entry),
                         "change": entry["change"] or ""})
    with pd.option_context("display.width", 250, "display.max_colwidth", 80):
        lines.append(pd.DataFrame(rows).to_string(index=False))
    changes = [row for row in rows if row["change"]]
    worse = sum(row["change"] == "worse" for row in changes)
    lines.append(f"{len(changes)} significant change(s) ({worse} worse, {len(changes) - worse} "
                 f"better) in {len(summary['cells'])} cell(s); {summary['method']}")
    if summary["failures"]:
        lines.append(f"FAIL: {len(summary['failures'])} significant change(s) beyond a threshold:")
        lines += [f"  {f['cell']}: {f['metric']} ratio {f['ratio']:.3f} "
                  f"[{f['low']:.3f}, {f['high']:.3f}] ({f['threshold']})"
                  for f in summary["failures"]]
    elif summary["thresholds"]:
        lines.append(f"PASS: no significant change beyond {', '.join(summary['thresholds'])}")
    return "\n".join(lines)


def run_command(dir_a, dir_b, fail_if=(), as_json: bool = False) -> int:
    """``iblbench compare``: print the comparison (with ``as_json``, the JSON on stdout and the
    table on stderr); 1 if any threshold fails, else 0."""
    summary = compare(dir_a, dir_b, [parse_threshold(text) for text in fail_if])
    status = 1 if summary["failures"] else 0
    print(format_text(summary), file=sys.stderr if as_json else sys.stdout)
    if as_json:
        print(json_text({"command": "compare", "exit": status, **summary}))
    return status
