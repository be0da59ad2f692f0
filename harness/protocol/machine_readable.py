"""Machine-readable outputs: the ``--json`` summaries of ``run``, ``check`` and ``stress``, and
``check --junit`` (JUnit XML for CI systems).

**Where they go.**  With ``--json`` a command prints exactly one JSON document on stdout; its
human-readable output (tables, verdict) goes to stderr instead, as do warnings and progress.
``compare --json`` does the same.  A command that stops on an error (exit 2 bad input, 3
disk full, 130 interrupted) prints nothing on stdout: the one-line error is on stderr.  Every document is written by
:func:`iblbench.harness.protocol.results.json_text` (strict JSON: NaN and infinities are ``null``) and
carries ``"command"`` and ``"exit"`` (the command's exit status).  ``iblbench check --junit
FILE`` writes the XML to FILE (atomically) besides whatever goes to stdout.

**run** (one entry per cell of this run's sweep, resumed cells included; other runs' cells in
the same ``--out`` are left out)::

    {"command": "run", "exit": 0, "status": "complete",     # the manifest's status
     "out": "runs/a", "results": "runs/a/results.parquet", "rows": 12,
     "resumed_cells": 0, "cells_run": 12,                   # rows: (…, frame, seed) rows
     "aggregation": "mean over the cell's scored renders (…), 95% Student-t interval",
     "cells": [{"scene": "sphere-sun", "estimator": "uniform", "spp": 16,
                "time_budget_ms": null,                     # a number for an equal-time cell
                "frames": 1, "seeds": 2, "nonfinite": 0,    # nonfinite: summed over the rows
                "metrics": {"mean_delta_e76": {"mean": 3.1, "low": 2.7, "high": 3.5,
                                               "half_width": 0.4, "n": 10,
                                               "method": "mean over the cell's …"}, ...}}],
     "equal_time_answer": {"resolved_pairs": [157, 184],    # adjacent ranks resolved, of all
                           "rankings": [{"scene": "sphere-sun", "budget_ms": 5.0,
                                         "metric": "mean_delta_e76", "winner": "balanced_mis",
                                         "verdict": "at 5 ms/frame on sphere-sun: …",
                                         "resolved_pairs": [9, 11],
                                         "ranked": [{"estimator": "balanced_mis",
                                                     "status": "ranked", "span_ms": [2.1, 30],
                                                     "error": {"mean": 0.72, …},
                                                     "spp_between": [64, 256],
                                                     "versus_next": {"ratio": 1.8, "p": 1e-6,
                                                                     "paired": true, …}}, …],
                                         "unranked": [{"estimator": "smc",
                                                       "status": "not reached", …}]}, …],
                           "control": [{"original": "envmap",   # the A/A control (--control)
                                        "control": "envmap@control", "called_apart": 1,
                                        "verdicts": 3, "level": 0.05,
                                        "text": "A/A control: envmap@control was …"}]}}

A cell's figure is the one aggregation of :mod:`iblbench.harness.protocol.stats`: an error is the
mean over the cell's replicates (each scored render of each seed) with its 95% Student-t
interval, the time the median of its timed renders with an order-statistic interval; ``n`` says
how many values and ``method`` which; ``low``/``high`` are null without an interval.
``metrics`` holds each of ``RUN_METRICS`` the run computed (a metric left out, NaN in every row,
is absent); ``time_ms`` is the cell's time (:mod:`iblbench.harness.protocol.timing`).
``equal_time_answer`` is :mod:`iblbench.harness.protocol.ranking`'s, per scene and headline budget;
its ``control`` counts, per control of the run (none without ``--control``), the verdicts that
called it apart from its original (:mod:`iblbench.harness.protocol.control`).
Rows of several devices: each cell and ranking is per device and carries a ``device`` key (times
are per device); a one-device run's document has no such key.

**check**::

    {"command": "check", "exit": 1, "passed": false, "dir": "runs/q",
     "budgets": "budgets.toml", "verdict": "check: FAIL, ...", "checks": 40, "failed": 2,
     "rules": [{"name": "sun-mis-64", "result": "FAIL",       # PASS, FAIL or n/a
                "checks": [{"scene": "sphere-sun", "estimator": "balanced_mis", "spp": 64,
                            "metric": "mean_delta_e76", "value": 1.7, "ci95": "± 0.3",
                            "bound": "<= 1.5", "result": "FAIL"}, ...]}]}

``value`` is a number, ``null`` for NaN (which fails), or a word where there is no number
("missing", "baseline missing", "n/a: static scene (no flicker)"); ``bound`` is the budget as
``check`` prints it.  A rule's result is FAIL when any of its checks fails, n/a when all are
n/a, else PASS.

**check --junit**: one ``<testcase>`` per rule (``classname`` "iblbench.check", ``name`` the
rule's name) in one ``<testsuite>``; a failing rule has a ``<failure>`` whose ``message`` counts
its failed checks and whose text lists them; a rule whose checks are all n/a is
``<skipped>``; every rule's checks are in its ``<system-out>``.

**stress** (the matrix of case × estimator outcomes)::

    {"command": "stress", "exit": 0, "passed": true, "verdict": "stress: passed: ...",
     "out": "runs/stress", "files": [...], "device": "...", "seconds": 75.2,
     "scale": {"normals": 6, ...}, "cases": ["constant", ...], "estimators": ["uniform", ...],
     "matrix": {"constant": {"uniform": "pass", "havran": "pass"}, ...},
     "cells": [{"case": "constant", "estimator": "uniform", "status": "pass",
                "failures": "", "nonfinite": 0, ...}]}              # every stress.csv column

``matrix[case][estimator]`` is pass, FAIL, xfail, XPASS, or n/a where the case does not apply
to the estimator (no row).
"""
from __future__ import annotations

import math
import pathlib
import xml.etree.ElementTree as ET

import pandas as pd

from iblbench.harness.protocol.results import METRIC_COLUMNS
from iblbench.harness.protocol.stats import MEAN_METHOD, RENDERS, cell_intervals, time_keys

RUN_METRICS = tuple(c for c in METRIC_COLUMNS
                    if c not in ("nonfinite", "time_repeats") and not c.endswith(RENDERS))
RULE_COLUMNS = ["scene", "estimator", "spp", "metric", "value", "ci95", "bound", "result"]


# ---- run ----------------------------------------------------------------------------------------

def run_summary(rows: pd.DataFrame, out, manifest: dict, rankings=None) -> dict:
    """The ``run --json`` document of a sweep's rows (module docstring); ``rankings``: the
    equal-time answer (:func:`iblbench.harness.protocol.ranking.scene_rankings`), computed here
    when not given."""
    from iblbench.harness.protocol.control import control_calls
    from iblbench.harness.protocol.ranking import resolved_share, scene_rankings

    if rankings is None:
        rankings = scene_rankings(rows) if len(rows) else {}
    cells = []
    for keys, selected in ((["scene", "estimator", "spp"], rows[rows.time_budget_ms.isna()]),
                           (["scene", "estimator", "time_budget_ms"],
                            rows[rows.time_budget_ms.notna()])):
        if not len(selected):
            continue
        columns = [c for c in RUN_METRICS if c in selected and selected[c].notna().any()]
        keys = time_keys(rows, keys)   # several devices: a cell per device (times per device)
        intervals = cell_intervals(selected, keys, columns)
        for key, group in selected.groupby(keys, sort=True):
            interval = intervals.loc[key]
            budget = group.time_budget_ms.iloc[0]
            cells.append({
                "scene": key[0], "estimator": key[1], "spp": int(group.spp.iloc[0]),
                "time_budget_ms": None if pd.isna(budget) else float(budget),
                **({"device": key[3]} if len(keys) > 3 else {}),
                "frames": int(group.frame.nunique()), "seeds": int(interval.seeds),
                "nonfinite": int(group.nonfinite.sum()),
                "metrics": {c: {"mean": interval[c], "low": interval[f"{c}_low"],
                                "high": interval[f"{c}_high"], "half_width": interval[f"{c}_half"],
                                "n": int(interval[f"{c}_n"]), "method": interval[f"{c}_method"]}
                            for c in columns}})
    out = pathlib.Path(out)
    return {"command": "run", "exit": 0, "status": manifest.get("status"), "out": str(out),
            "results": str(out / "results.parquet"), "rows": len(rows),
            "resumed_cells": manifest.get("resumed_cells"),
            "cells_run": manifest.get("cells_to_run"), "aggregation": MEAN_METHOD, "cells": cells,
            "equal_time_answer": {
                "resolved_pairs": list(resolved_share(rankings)),
                "rankings": [ranking.to_dict() for scene in rankings.values() for ranking in scene],
                "control": [calls.to_dict() for calls in control_calls(
                    rankings, rows.get("estimator", ()))]}}


# ---- check --------------------------------------------------------------------------------------

def _value(text: str):
    """A check's value: a number (None for NaN) or the word ``check`` printed."""
    try:
        number = float(text)
    except ValueError:
        return text
    return number if math.isfinite(number) else None


def rule_outcomes(checks: pd.DataFrame) -> list[dict]:
    """The rows of :func:`iblbench.harness.protocol.budgets.evaluate` grouped by rule, in file order."""
    rules = []
    for name, group in checks.groupby("rule", sort=False):
        results = set(group.result)
        result = "FAIL" if "FAIL" in results else "n/a" if results == {"n/a"} else "PASS"
        entries = (group.rename(columns={"budget": "bound"})[RULE_COLUMNS]
                   .assign(value=group.value.map(_value), spp=group.spp.astype(int)))
        rules.append({"name": name, "result": result, "checks": entries.to_dict("records")})
    return rules


def check_summary(checks: pd.DataFrame, verdict: str, status: int, out_dir, budgets) -> dict:
    """The ``check --json`` document (module docstring)."""
    return {"command": "check", "exit": status, "passed": status == 0, "dir": str(out_dir),
            "budgets": str(budgets), "verdict": verdict, "checks": len(checks),
            "failed": int((checks.result == "FAIL").sum()), "rules": rule_outcomes(checks)}


def _check_line(check: dict) -> str:
    return (f"{check['scene']} {check['estimator']} spp={check['spp']} {check['metric']}: "
            f"{check['value']} {check['ci95']} (budget {check['bound']}) {check['result']}")


def junit_xml(checks: pd.DataFrame, budgets) -> str:
    """``check --junit``: one testcase per rule (module docstring)."""
    rules = rule_outcomes(checks)
    counts = {"tests": str(len(rules)),
              "failures": str(sum(r["result"] == "FAIL" for r in rules)), "errors": "0",
              "skipped": str(sum(r["result"] == "n/a" for r in rules))}
    suites = ET.Element("testsuites", name="iblbench check", **counts)
    suite = ET.SubElement(suites, "testsuite", name=f"iblbench check {budgets}", **counts)
    for rule in rules:
        case = ET.SubElement(suite, "testcase", classname="iblbench.check", name=rule["name"])
        failed = [c for c in rule["checks"] if c["result"] == "FAIL"]
        if failed:
            failure = ET.SubElement(case, "failure", type="budget",
                                    message=f"{len(failed)} of {len(rule['checks'])} checks "
                                            f"failed: {_check_line(failed[0])}"
                                            + (" …" if len(failed) > 1 else ""))
            failure.text = "\n".join(map(_check_line, failed))
        elif rule["result"] == "n/a":
            ET.SubElement(case, "skipped", message="every check of the rule is n/a")
        ET.SubElement(case, "system-out").text = "\n".join(map(_check_line, rule["checks"]))
    ET.indent(suites)
    return ET.tostring(suites, encoding="unicode", xml_declaration=True) + "\n"


# ---- stress -------------------------------------------------------------------------------------

def stress_summary(table: pd.DataFrame, cases, estimators, *, status: int, verdict: str,
                   out, files, device: str, seconds: float, scale: dict) -> dict:
    """The ``stress --json`` document (module docstring)."""
    outcome = {(row.case, row.estimator): row.status for row in table.itertuples()}
    return {"command": "stress", "exit": status, "passed": status == 0, "verdict": verdict,
            "out": str(out), "files": [str(f) for f in files], "device": device,
            "seconds": seconds, "scale": scale, "cases": list(cases),
            "estimators": list(estimators),
            "matrix": {case: {label: outcome.get((case, label), "n/a") for label in estimators}
                       for case in cases},
            "cells": table.to_dict("records")}
