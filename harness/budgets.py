"""CI error budgets: ``iblbench check DIR --budgets budgets.toml``.

A budgets file is TOML with one ``[[rule]]`` table per rule. A rule picks cells of the results
table (``DIR/results.parquet``, DESIGN §6) by scene glob, estimator glob and spp, and sets limits
on them::

    [[rule]]
    name = "sun-mis-64"          # optional; shown in the output (default: "scene estimator spp=N")
    scene = "sphere-*"           # fnmatch glob on the scene name (required)
    estimator = "balanced*"      # fnmatch glob on the estimator name (required)
    spp = 64                     # an spp or a list of them, e.g. [16, 64] (required)
    max_mean_delta_e76 = 3.0     # mean ΔE76 (CIE 1976) <= 3.0
    max_rel_mse = 0.05           # relMSE <= 0.05
    min_effective_ratio = 0.6    # effective samples / used samples >= 0.6
    nonfinite = 0                # NaN/Inf pixels, summed over the cell's frames and seeds, <= 0
    max_time_ratio = { baseline = "uniform", metric = "time_ms", max = 3.0 }

Limits. ``max_<metric>`` and ``min_<metric>`` work for every quality metric of the table
(mean_delta_e76, mean_delta_e2000, rel_mse, flip, used_samples, effective_samples,
effective_ratio, evaluations); ``nonfinite = N`` bounds the total count of non-finite pixels
(use 0); ``max_time_ratio`` bounds ``median(metric of the cell) / median(metric of the baseline
cell)``, where the baseline cell is the named estimator on the same scene and spp *in the same
results table* (``metric`` is one of the time columns: time_ms, the cell's device time per
frame of :mod:`iblbench.harness.timing`, the default; time_ms_min, time_ms_iqr,
time_ms_build, time_ms_sample, time_ms_shade, time_ms_host). Absolute times cannot be budgeted:
they are too noisy across machines.
Any other key is an error (exit 2), so a typo never silently disables a limit.

What is compared. Only equal-spp rows count: rows with a ``time_budget_ms`` (equal-time cells,
whose spp is whatever fitted the budget on that device) are left out. Rows are grouped into cells by (scene, estimator, spp). A cell's value for a
``max_``/``min_`` limit is the **mean over its rows** (its frames × seeds); a NaN in any row makes
the value NaN, and NaN always fails. ``nonfinite`` is the sum over the rows. The time ratio is a
ratio of the two cells' times (:func:`iblbench.harness.timing.median_time`: the **median over
the rows**, frames × seeds), the same time the report and ``iblbench run`` print; both times are
shown beside the ratio.

Fail closed. The cells a rule expects are (every scene in the table matching its scene glob) ×
(every estimator in the table matching its estimator glob) × (each of its spp). A rule whose globs
match nothing, an expected cell absent from the table, and a time ratio whose baseline cell is
absent all FAIL; nothing is skipped.

Output: one line per rule × cell × limit (rule, scene, estimator, spp, metric, value, budget,
result), then a one-line verdict that names the failing rules. Exit status: 0 when every check
passes, 1 when any fails, 2 on bad input (no results table, unreadable table, missing or invalid
budgets file).
"""
from __future__ import annotations

import dataclasses
import fnmatch
import math
import pathlib

import pandas as pd

from iblbench.harness.results import METRIC_COLUMNS, load_table
from iblbench.harness.timing import COLUMNS as TIME_COLUMNS, TIME, median_time
from iblbench.scenes.errors import InputError
from iblbench.scenes.tomlfile import read_toml

CELL = ["scene", "estimator", "spp"]
TIME_METRICS = tuple(column for column in TIME_COLUMNS if column.startswith("time_ms"))
QUALITY_METRICS = tuple(column for column in METRIC_COLUMNS
                        if column not in TIME_COLUMNS and column != "nonfinite")
LIMIT_KEYS = tuple([f"max_{m}" for m in QUALITY_METRICS] + [f"min_{m}" for m in QUALITY_METRICS]
                   + ["nonfinite", "max_time_ratio"])
RULE_KEYS = ("name", "scene", "estimator", "spp") + LIMIT_KEYS
TIME_RATIO_KEYS = ("baseline", "metric", "max")
OUTPUT_COLUMNS = ["rule", "scene", "estimator", "spp", "metric", "value", "budget", "result"]


@dataclasses.dataclass(frozen=True)
class TimeRatio:
    baseline: str
    metric: str
    max: float


@dataclasses.dataclass(frozen=True)
class Rule:
    name: str
    scene: str
    estimator: str
    spp: tuple[int, ...]
    bounds: tuple[tuple[str, str, float], ...]   # (metric, "max" | "min", limit)
    nonfinite: int | None = None
    time_ratio: TimeRatio | None = None


# --- reading the budgets file --------------------------------------------------------------------


def _number(path, where: str, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(path, f"{where}: '{key}' must be a finite number, got {value!r}")
    return float(value)


def _parse_rule(path, index: int, table) -> Rule:
    where = f"rule {index}"
    if not isinstance(table, dict):
        raise InputError(path, f"{where}: expected a [[rule]] table")
    unknown = sorted(set(table) - set(RULE_KEYS))
    if unknown:
        raise InputError(path, f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; "
                               f"known limits: {', '.join(LIMIT_KEYS)}")
    for key in ("scene", "estimator"):
        if not isinstance(table.get(key), str) or not table[key]:
            raise InputError(path, f"{where}: '{key}' (a glob) is required and must be a string")
    spp = table.get("spp")
    spp_list = spp if isinstance(spp, list) else [spp]
    if (spp is None or not spp_list
            or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in spp_list)):
        raise InputError(path, f"{where}: 'spp' must be a positive integer or a list of them, "
                               f"got {spp!r}")
    name = table.get("name", f"{table['scene']} {table['estimator']} spp={spp}")
    if not isinstance(name, str) or not name:
        raise InputError(path, f"{where}: 'name' must be a non-empty string")
    where = f"rule {index} ({name})"

    bounds = []
    for key in LIMIT_KEYS:
        if key in table and key[:4] in ("max_", "min_") and key != "max_time_ratio":
            bounds.append((key[4:], key[:3], _number(path, where, key, table[key])))
    nonfinite = table.get("nonfinite")
    if nonfinite is not None and (isinstance(nonfinite, bool) or not isinstance(nonfinite, int)
                                  or nonfinite < 0):
        raise InputError(path, f"{where}: 'nonfinite' must be a non-negative integer (use 0), "
                               f"got {nonfinite!r}")
    time_ratio = None
    if "max_time_ratio" in table:
        spec = table["max_time_ratio"]
        if not isinstance(spec, dict):
            raise InputError(path, f"{where}: 'max_time_ratio' must be an inline table "
                                   "{ baseline = \"...\", metric = \"time_ms\", max = N }")
        unknown = sorted(set(spec) - set(TIME_RATIO_KEYS))
        if unknown:
            raise InputError(path, f"{where}: max_time_ratio: unknown key(s) "
                                   f"{', '.join(map(repr, unknown))}; known: "
                                   f"{', '.join(TIME_RATIO_KEYS)}")
        if not isinstance(spec.get("baseline"), str) or not spec["baseline"]:
            raise InputError(path, f"{where}: max_time_ratio needs 'baseline', an estimator name")
        metric = spec.get("metric", TIME)
        if metric not in TIME_METRICS:
            raise InputError(path, f"{where}: max_time_ratio: 'metric' must be one of "
                                   f"{', '.join(TIME_METRICS)}, got {metric!r}")
        if "max" not in spec:
            raise InputError(path, f"{where}: max_time_ratio needs 'max'")
        limit = _number(path, where, "max_time_ratio.max", spec["max"])
        if limit <= 0:
            raise InputError(path, f"{where}: max_time_ratio.max must be positive")
        time_ratio = TimeRatio(spec["baseline"], metric, limit)
    if not bounds and nonfinite is None and time_ratio is None:
        raise InputError(path, f"{where}: the rule sets no limit; known limits: "
                               f"{', '.join(LIMIT_KEYS)}")
    return Rule(name, table["scene"], table["estimator"], tuple(spp_list), tuple(bounds),
                nonfinite, time_ratio)


def load_budgets(path: str | pathlib.Path) -> list[Rule]:
    """The rules of a budgets file; :class:`InputError` naming the file if it is missing or bad."""
    path = pathlib.Path(path)
    document = read_toml(path, "budgets file")
    unknown = sorted(set(document) - {"rule"})
    if unknown:
        raise InputError(path, f"unknown top-level key(s) {', '.join(map(repr, unknown))}; "
                               "a budgets file holds only [[rule]] tables")
    rules = document.get("rule")
    if not isinstance(rules, list) or not rules:
        raise InputError(path, "no [[rule]] tables")
    return [_parse_rule(path, index, table) for index, table in enumerate(rules, start=1)]


# --- reading the results -------------------------------------------------------------------------


def load_results(out_dir: str | pathlib.Path) -> pd.DataFrame:
    """``DIR/results.parquet``; :class:`InputError` if it is missing, unreadable or incomplete."""
    return load_table(out_dir, CELL + list(METRIC_COLUMNS))


# --- evaluating ----------------------------------------------------------------------------------


def _fmt(value: float) -> str:
    return "nan" if value is None or not math.isfinite(value) else f"{value:.4g}"


def evaluate(rules: list[Rule], table: pd.DataFrame) -> pd.DataFrame:
    """One row per rule × expected cell × limit: value, budget and PASS/FAIL (see module doc)."""
    if "time_budget_ms" in table.columns:   # equal-time cells are not budgeted (module doc)
        table = table[table["time_budget_ms"].isna()]
    groups = {key: rows for key, rows in table.groupby(CELL, sort=True)} if len(table) else {}
    scenes = sorted(table["scene"].astype(str).unique()) if len(table) else []
    estimators = sorted(table["estimator"].astype(str).unique()) if len(table) else []
    out: list[dict] = []

    def emit(rule, scene, estimator, spp, metric, value, budget, ok):
        out.append({"rule": rule.name, "scene": scene, "estimator": estimator, "spp": spp,
                    "metric": metric, "value": value, "budget": budget,
                    "result": "PASS" if ok else "FAIL"})

    for rule in rules:
        rule_scenes = [s for s in scenes if fnmatch.fnmatchcase(s, rule.scene)]
        rule_estimators = [e for e in estimators if fnmatch.fnmatchcase(e, rule.estimator)]
        if not rule_scenes or not rule_estimators:
            for spp in rule.spp:
                emit(rule, rule.scene if not rule_scenes else ",".join(rule_scenes),
                     rule.estimator if not rule_estimators else ",".join(rule_estimators), spp,
                     "cell", "missing", "present", False)
            continue
        for scene in rule_scenes:
            for estimator in rule_estimators:
                for spp in rule.spp:
                    rows = groups.get((scene, estimator, spp))
                    if rows is None:
                        emit(rule, scene, estimator, spp, "cell", "missing", "present", False)
                        continue
                    for metric, kind, limit in rule.bounds:
                        value = float(rows[metric].astype(float).mean(skipna=False))
                        ok = math.isfinite(value) and (value <= limit if kind == "max"
                                                       else value >= limit)
                        emit(rule, scene, estimator, spp, metric, _fmt(value),
                             f"{'<=' if kind == 'max' else '>='} {limit:.4g}", ok)
                    if rule.nonfinite is not None:
                        count = rows["nonfinite"].astype(float).sum(skipna=False)
                        ok = math.isfinite(count) and count <= rule.nonfinite
                        emit(rule, scene, estimator, spp, "nonfinite (sum)",
                             _fmt(count), f"<= {rule.nonfinite}", ok)
                    if rule.time_ratio is not None:
                        ratio = rule.time_ratio
                        budget = f"<= {ratio.max:.4g}"
                        base = groups.get((scene, ratio.baseline, spp))
                        if base is None:
                            emit(rule, scene, estimator, spp, f"{ratio.metric} / {ratio.baseline}",
                                 "baseline missing", budget, False)
                            continue
                        mine = median_time(rows[ratio.metric])
                        theirs = median_time(base[ratio.metric])
                        metric = (f"{ratio.metric} / {ratio.baseline} "
                                  f"({_fmt(mine)} / {_fmt(theirs)} ms)")
                        value = mine / theirs if theirs > 0 else math.nan
                        emit(rule, scene, estimator, spp, metric, _fmt(value), budget,
                             math.isfinite(value) and value <= ratio.max)
    return pd.DataFrame(out, columns=OUTPUT_COLUMNS)


def verdict(checks: pd.DataFrame) -> str:
    failed = checks[checks["result"] != "PASS"]
    rules = checks["rule"].nunique()
    if failed.empty:
        return f"check: PASS, all {len(checks)} checks of {rules} rules within budget"
    names = list(dict.fromkeys(failed["rule"]))
    return (f"check: FAIL, {len(failed)} of {len(checks)} checks failed, in rule(s): "
            + "; ".join(names))


def check(out_dir: str | pathlib.Path, budgets: str | pathlib.Path) -> tuple[pd.DataFrame, str, int]:
    """Evaluate ``budgets`` on ``out_dir``'s results: (checks table, verdict line, exit status)."""
    rules = load_budgets(budgets)
    table = load_results(out_dir)
    checks = evaluate(rules, table)
    return checks, verdict(checks), 0 if (checks["result"] == "PASS").all() else 1
