"""CI error budgets (``iblbench check``): the repo's budgets.toml on a real quick sweep (passed by
the code, failed by the ``uniform_faces`` switch in place of ``balanced``), and the rules'
semantics on synthetic results tables.

The quick sweep runs once per module (a real ``iblbench`` subprocess, 20-35 s with Debian's
PoCL on 2 cores), its balanced cells once more with the switch; the other tests call
``cli.main`` in-process on small hand-made tables.  budgets.toml is made by ``make budgets``.
"""
from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from iblbench import cli
from iblbench.harness.protocol.budgets import (LIMIT_KEYS, configuration_differences, evaluate,
                                             load_budgets, read_budgets)
from iblbench.harness.protocol.results import COLUMNS, write_results
from iblbench.harness.protocol.sweep import load_sweep

ROOT = Path(__file__).resolve().parents[1]
BUDGETS = ROOT / "budgets.toml"
QUICK = load_sweep("quick")
UNIFORM_FACES = "balanced{uniform_faces=true}"   # μ_f = 1/6: the same renders as uniform
DELTA_E = ("mean_delta_e76", "mean_delta_e2000")


def iblbench(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, "-m", "iblbench.cli", *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=timeout, cwd=ROOT)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory) -> Path:
    """The ``quick`` sweep, run once."""
    out = tmp_path_factory.mktemp("quick")
    result = iblbench("run", "--config", "quick", "--no-progress", "--out", out)
    assert result.returncode == 0, result.stdout + result.stderr
    return out


def check_output(result: subprocess.CompletedProcess) -> str:
    return f"exit {result.returncode}\nstdout:\n{result.stdout}\nstderr:\n{result.stderr}"


# --- the repo's budgets on the real quick sweep --------------------------------------------------


def test_quick_sweep_is_within_the_repo_budgets(quick_run):
    result = iblbench("check", quick_run, "--budgets", "budgets.toml")
    assert result.returncode == 0, check_output(result)
    lines = result.stdout.strip().splitlines()
    assert lines[-1].startswith("check: PASS"), check_output(result)
    assert "FAIL" not in result.stdout
    # Every rule of the file is in the table, and every quick cell is covered.
    for rule in load_budgets(BUDGETS):
        assert any(line.startswith(rule.name + " ") or f" {rule.name} " in line
                   for line in lines), rule.name
    for scene in QUICK.scenes:
        for estimator in QUICK.estimators:
            for spp in QUICK.spp:
                assert re.search(rf"{scene}\s+{estimator}\s+(spp=)?{spp}\s", result.stdout), (
                    scene, estimator, spp)


def test_uniform_faces_switch_in_place_of_balanced_fails_the_delta_e_budgets(tmp_path):
    """Issue 11: the ΔE rules tell Lu's per-normal face balancing from μ_f = 1/6.  The quick
    sweep's balanced cells are rendered with ``uniform_faces=true``, labelled ``balanced`` as a
    build that lost the balancing would label them, and judged by budgets.toml's balanced rules:
    some ΔE76 bound fails, and every ΔE failure says the error is too high, not too low."""
    out = tmp_path / "mutant"
    result = iblbench("run", "--config", "quick", "--estimator", UNIFORM_FACES, "--repeats", 1,
                      "--no-progress", "--out", out)
    assert result.returncode == 0, result.stdout + result.stderr
    table = pd.read_parquet(out / "results.parquet").assign(estimator="balanced")
    configuration, rules = read_budgets(BUDGETS)
    assert configuration_differences(configuration, table) == []
    checks = evaluate([rule for rule in rules if rule.estimator == "balanced"], table,
                      configuration.seeds)
    delta_e = checks[checks.metric.isin(DELTA_E)]
    assert len(delta_e) == 2 * 2 * len(QUICK.scenes) * len(QUICK.spp)   # every cell judged
    failed = delta_e[delta_e.result == "FAIL"]
    assert (failed.metric == "mean_delta_e76").any(), delta_e.to_string()
    assert failed.budget.str.startswith("<=").all(), failed.to_string()


def test_tightening_one_budget_fails_and_names_the_rule(quick_run, tmp_path):
    table = pd.read_parquet(quick_run / "results.parquet")
    cell = table[(table.scene == "sphere-sun") & (table.estimator == "balanced_mis")
                 & (table.spp == 64)]
    measured = cell["mean_delta_e76"].mean()
    text = BUDGETS.read_text(encoding="utf-8")
    name = "sphere-sun balanced_mis spp=64"
    block = re.search(rf'name = "{name}".*?(?=\[\[rule\]\]|\Z)', text, re.S)
    assert block, f"budgets.toml lost its {name} rule"
    tightened_block, count = re.subn(r"max_mean_delta_e76 = [0-9.eE+-]+",
                                     f"max_mean_delta_e76 = {measured * 0.9:.6g}", block.group(0))
    assert count == 1
    tightened = tmp_path / "tight.toml"
    tightened.write_text(text[:block.start()] + tightened_block + text[block.end():],
                         encoding="utf-8")

    result = iblbench("check", quick_run, "--budgets", tightened)
    assert result.returncode == 1, check_output(result)
    failing = [line for line in result.stdout.splitlines() if line.rstrip().endswith("FAIL")]
    assert len(failing) == 1, check_output(result)
    assert failing[0].split()[:4] == [*name.split(), "mean_delta_e76"], failing[0]
    verdict = result.stdout.strip().splitlines()[-1]
    assert verdict.startswith("check: FAIL") and name in verdict, verdict


TWO_SIDED = ("mean_delta_e76", "rel_mse", "effective_ratio", "used_samples", "evaluations")


def test_every_quality_rule_bounds_both_sides():
    """Issue 13: a count that took every sample as effective (ratio 1.0) passed a lower bound."""
    for rule in load_budgets(BUDGETS):
        if rule.nonfinite is not None and not rule.bounds:
            continue
        kinds = {(metric, kind) for metric, kind, _ in rule.bounds}
        for metric in TWO_SIDED:
            assert {(metric, "min"), (metric, "max")} <= kinds, (rule.name, metric)


@pytest.mark.parametrize("bug, column, value", [
    ("every sample counted effective", "effective_ratio", 1.0),
    ("no sample counted effective", "effective_ratio", 0.0),
    ("a strategy's samples dropped", "used_samples", 0.5),
    ("the estimate scored against itself", "mean_delta_e76", 0.0)])
def test_a_count_or_score_bug_fails_the_repo_budgets(quick_run, tmp_path, bug, column, value):
    """The quick sweep's table with one column broken as the bug would break it, in every row
    (``used_samples`` scaled by ``value``), fails every quality rule on that column."""
    table = pd.read_parquet(quick_run / "results.parquet")
    table[column] = table[column] * value if column == "used_samples" else value
    broken = tmp_path / "broken"
    broken.mkdir()
    write_results(broken, table.to_dict("records"))
    result = iblbench("check", broken, "--budgets", "budgets.toml")
    assert result.returncode == 1, check_output(result)
    rules = load_budgets(BUDGETS)
    checks = evaluate(rules, table)
    failing = checks[(checks.result == "FAIL") & (checks.metric == column)]
    assert set(failing.rule) == {rule.name for rule in rules if rule.bounds}, bug


# --- semantics on synthetic tables ---------------------------------------------------------------


def row(scene, estimator, spp, seed=0, frame=0, **metrics) -> dict:
    values = {"mean_delta_e76": 1.0, "mean_delta_e2000": 1.0, "rel_mse": 0.01, "flip": 0.1,
              "used_samples": spp, "effective_samples": spp * 0.8, "effective_ratio": 0.8,
              "evaluations": spp, "nonfinite": 0, "time_ms": 3.0, "time_ms_min": 3.0,
              "time_ms_iqr": 0.0, "time_ms_build": 1.0, "time_ms_sample": 1.0,
              "time_ms_shade": 1.0, "time_ms_host": 2.0, "time_repeats": 5, "metrics": "de76",
              "width": 48, "height": 48, "env_res": 32}
    values.update(metrics)
    return {column: None for column in COLUMNS} | values | {
        "scene": scene, "estimator": estimator, "spp": spp, "seed": seed, "frame": frame,
        "estimator_version": "x", "device": "test", "protocol": "lab-reinhard-v1"}


@pytest.fixture
def results_dir(tmp_path) -> Path:
    """sphere-sun and sphere-backlit × uniform, balanced, balanced_mis × spp 16 and 64, 2 seeds,
    plus a scene 'cornell' with only uniform at spp 16."""
    rows = []
    for scene in ("sphere-sun", "sphere-backlit"):
        for estimator in ("uniform", "balanced", "balanced_mis"):
            for spp in (16, 64):
                for seed in (0, 1):
                    rows.append(row(scene, estimator, spp, seed=seed,
                                    mean_delta_e76={"uniform": 4.0, "balanced": 3.0,
                                                    "balanced_mis": 1.0}[estimator] + seed))
    rows.append(row("cornell", "uniform", 16))
    out = tmp_path / "run"
    out.mkdir()
    write_results(out, rows)
    return out


def configuration(seeds: int) -> str:
    """The [configuration] of the synthetic tables: row()'s sizes and protocol."""
    return (f"[configuration]\nwidth = 48\nheight = 48\nenv_res = 32\nseeds = {seeds}\n"
            "protocol = 'lab-reinhard-v1'\n")


def run_check(results_dir: Path, budgets_text: str, capsys,
              seeds: int = 2) -> tuple[int, pd.DataFrame, str, str]:
    budgets = results_dir.parent / "budgets.toml"
    budgets.write_text(configuration(seeds) + budgets_text, encoding="utf-8")
    status = cli.main(["check", str(results_dir), "--budgets", str(budgets)])
    captured = capsys.readouterr()
    checks = evaluate(load_budgets(budgets), pd.read_parquet(results_dir / "results.parquet")) \
        if status != 2 else None
    return status, checks, captured.out, captured.err


def test_globs_select_cells_and_values_are_means_over_seeds(results_dir, capsys):
    status, checks, out, _ = run_check(results_dir, """
[[rule]]
name = "bal"
scene = "sphere-*"
estimator = "balanced*"
spp = [16, 64]
max_mean_delta_e76 = 3.6
""", capsys)
    assert set(zip(checks.scene, checks.estimator)) == {
        (s, e) for s in ("sphere-sun", "sphere-backlit") for e in ("balanced", "balanced_mis")}
    assert sorted(checks.spp.unique()) == [16, 64] and len(checks) == 8
    # Means over the two seeds: balanced (3 + 4) / 2 = 3.5, balanced_mis (1 + 2) / 2 = 1.5.
    assert set(checks[checks.estimator == "balanced"].value) == {"3.5"}
    assert set(checks[checks.estimator == "balanced_mis"].value) == {"1.5"}
    assert status == 0 and out.strip().splitlines()[-1].startswith("check: PASS")

    status, checks, out, _ = run_check(results_dir, """
[[rule]]
name = "bal-tight"
scene = "sphere-sun"
estimator = "balanced"
spp = 64
max_mean_delta_e76 = 3.4
""", capsys)
    assert status == 1 and list(checks.result) == ["FAIL"]
    assert "bal-tight" in out.strip().splitlines()[-1]


@pytest.mark.parametrize("scene, estimator, spp", [
    ("nope-*", "*", "16"),              # scene glob matches nothing
    ("sphere-sun", "nope", "16"),       # estimator matches nothing
    ("sphere-sun", "uniform", "128"),   # no cell at that spp
    ("*", "balanced", "16"),            # 'cornell' is in the table but has no balanced cell
])
def test_missing_cells_fail_closed(results_dir, capsys, scene, estimator, spp):
    status, checks, out, _ = run_check(results_dir, f"""
[[rule]]
name = "r"
scene = "{scene}"
estimator = "{estimator}"
spp = {spp}
max_rel_mse = 1.0
""", capsys)
    assert status == 1, out
    missing = checks[checks.value == "missing"]
    assert len(missing) >= 1 and set(missing.result) == {"FAIL"}
    assert "missing" in out and out.strip().splitlines()[-1].startswith("check: FAIL")


def test_empty_table_fails_every_rule(tmp_path, capsys):
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    write_results(out_dir, [])
    status, checks, _, _ = run_check(out_dir, """
[[rule]]
scene = "*"
estimator = "*"
spp = 16
nonfinite = 0
""", capsys)
    assert status == 1 and list(checks.result) == ["FAIL"]


def test_time_ratio_is_a_ratio_of_seed_means_within_the_run(tmp_path, capsys):
    rows = []
    for seed, (mine, base) in enumerate([(1.0, 1.0), (2.0, 1.0), (10.0, 1.0)]):
        rows += [row("s", "fast", 16, seed=seed, time_ms_shade=base, time_ms=100.0),
                 row("s", "slow", 16, seed=seed, time_ms_shade=mine, time_ms=100.0)]
    rows.append(row("other", "slow", 16, time_ms_shade=1.0))   # no 'fast' baseline here
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    write_results(out_dir, rows)
    rule = """
[[rule]]
name = "ratio"
scene = "s"
estimator = "slow"
spp = 16
max_time_ratio = {{ baseline = "fast", metric = "time_ms_shade", max = {limit} }}
"""
    status, checks, _, _ = run_check(out_dir, rule.format(limit=4.5), capsys, seeds=3)
    assert status == 0 and list(checks.value) == ["4.333"]   # mean 13/3 / mean 1, not median 2
    status, checks, _, _ = run_check(out_dir, rule.format(limit=4.0), capsys, seeds=3)
    assert status == 1 and list(checks.result) == ["FAIL"]
    assert "(4.333 / 1 ms)" in checks.metric.iloc[0]   # both cells' times beside the ratio
    # The metric defaults to time_ms, the cell's device time per frame: 100 / 100.
    status, checks, _, _ = run_check(
        out_dir, rule.format(limit=1.01).replace('metric = "time_ms_shade", ', ""), capsys,
        seeds=3)
    assert status == 0 and list(checks.value) == ["1"]


def test_missing_baseline_fails_closed(tmp_path, capsys):
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    write_results(out_dir, [row("s", "slow", 16), row("s", "fast", 64)])
    status, checks, out, _ = run_check(out_dir, """
[[rule]]
scene = "s"
estimator = "slow"
spp = 16
max_time_ratio = { baseline = "fast", max = 100 }
""", capsys, seeds=1)
    assert status == 1 and list(checks.value) == ["baseline missing"]
    assert list(checks.result) == ["FAIL"]


def test_nonfinite_and_nan_metrics_fail(tmp_path, capsys):
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    write_results(out_dir, [row("s", "a", 16, seed=0), row("s", "a", 16, seed=1, nonfinite=3),
                            row("s", "b", 16, seed=0),
                            row("s", "b", 16, seed=1, mean_delta_e76=math.nan)])
    status, checks, out, _ = run_check(out_dir, """
[[rule]]
name = "finite"
scene = "s"
estimator = "*"
spp = 16
nonfinite = 0
max_mean_delta_e76 = 100
""", capsys)
    assert status == 1
    result = {(e, m): (v, r) for e, m, v, r in
              zip(checks.estimator, checks.metric, checks.value, checks.result)}
    assert result[("a", "nonfinite (sum)")] == ("3", "FAIL")
    assert result[("a", "mean_delta_e76")] == ("1", "PASS")
    assert result[("b", "nonfinite (sum)")] == ("0", "PASS")
    assert result[("b", "mean_delta_e76")] == ("nan", "FAIL")   # NaN never passes


def test_equal_time_rows_are_left_out(tmp_path):
    rows = [row("s", "a", 16, mean_delta_e76=1.0) | {"time_budget_ms": math.nan},
            row("s", "a", 16, mean_delta_e76=9.0) | {"time_budget_ms": 5.0},
            row("s", "b", 16, mean_delta_e76=9.0) | {"time_budget_ms": 5.0}]
    budgets = tmp_path / "b.toml"
    budgets.write_text(configuration(1) + "[[rule]]\nscene = 's'\nestimator = '*'\nspp = 16\n"
                       "max_mean_delta_e76 = 2\n", encoding="utf-8")
    checks = evaluate(load_budgets(budgets), pd.DataFrame(rows))
    # 'a' is judged on its equal-spp row only; 'b' has only an equal-time row, so it is
    # not in the equal-spp sweep and the glob does not expect it.
    assert list(zip(checks.estimator, checks.value, checks.result)) == [("a", "1", "PASS")]


@pytest.mark.parametrize("text, needle", [
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\nmax_delta_e = 3\n", "max_delta_e"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\nmax_time_ms = 3\n",
     "max_time_ms"),                                           # absolute times are not budgeted
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\nmax_time_repeats = 3\n",
     "max_time_repeats"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\n", "no limit"),
    ("[[rule]]\nscene = 'a'\nspp = 16\nmax_rel_mse = 1\n", "estimator"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 0\nmax_rel_mse = 1\n", "spp"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\nmax_rel_mse = '1'\n", "max_rel_mse"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\nnonfinite = true\n", "nonfinite"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\n"
     "max_time_ratio = { baseline = 'u', max = 2, metric = 'rel_mse' }\n", "metric"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\n"
     "max_time_ratio = { baseline = 'u', maximum = 2 }\n", "maximum"),
    ("[[rule]]\nscene = 'a'\nestimator = 'b'\nspp = 16\nmax_time_ratio = { max = 2 }\n",
     "baseline"),
    ("[[rules]]\nscene = 'a'\n", "rules"),
    ("", "no [[rule]]"),
    ("[[rule]\nscene = 'a'\n", "TOML syntax error"),
])
def test_bad_budgets_exit_2_naming_the_file(results_dir, capsys, text, needle):
    status, _, out, err = run_check(results_dir, text, capsys)
    assert status == 2, out + err
    assert err.startswith("iblbench: error: ") and err.count("\n") == 1, err
    assert "budgets.toml" in err and needle in err, err
    assert out == ""


def test_bad_results_dir_exits_2(tmp_path, capsys):
    budgets = str(BUDGETS)
    assert cli.main(["check", str(tmp_path / "nope"), "--budgets", budgets]) == 2
    assert "nope: no such run directory" in capsys.readouterr().err
    assert cli.main(["check", str(tmp_path), "--budgets", budgets]) == 2
    assert "results.parquet: no results table" in capsys.readouterr().err
    (tmp_path / "results.parquet").write_bytes(b"not parquet")
    assert cli.main(["check", str(tmp_path), "--budgets", budgets]) == 2
    err = capsys.readouterr().err
    assert "results.parquet: cannot read" in err and err.count("\n") == 1
    assert cli.main(["check", str(tmp_path), "--budgets", str(tmp_path / "none.toml")]) == 2
    assert "none.toml: budgets file not found" in capsys.readouterr().err


def test_repo_budgets_cover_every_limit_kind():
    rules = load_budgets(BUDGETS)
    kinds = {f"{kind}_{metric}" for rule in rules for metric, kind, _ in rule.bounds}
    assert {"max_mean_delta_e76", "max_rel_mse", "min_effective_ratio"} <= kinds
    assert any(rule.nonfinite == 0 for rule in rules)
    assert any(rule.time_ratio and rule.time_ratio.baseline == "uniform" for rule in rules)
    assert set(kinds) <= set(LIMIT_KEYS)
