"""Machine-readable outputs (issue 11, "Comparing runs and revisions"): ``--json`` on ``run``,
``check`` and ``stress`` parses with ``json.loads`` and says what the tables say; ``check
--junit`` parses with ``xml.etree`` and counts a crafted failing budget's failures.

``check`` and the run summary run in-process on hand-made results tables (no render); the
stress command runs its quick size on two small cases; ``run --json`` itself is in
tests/test_cli.py (a real run in a subprocess).
"""
from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from iblbench import cli
from iblbench.harness.protocol.machine_readable import run_summary
from iblbench.harness.protocol.results import COLUMNS, json_text, write_results
from test_budgets import row
from test_check_defects import CONFIGURATION, configured, rule


# ---- the one JSON writer --------------------------------------------------------------------------

def test_json_text_is_strict_json():
    text = json_text({"nan": float("nan"), "inf": np.float32("inf"), "n": np.int64(3),
                      "values": (np.float64(0.5), float("-inf"))})
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"nan": None, "inf": None, "n": 3, "values": [0.5, None]}


# ---- run -------------------------------------------------------------------------------------------

def _interval(values):
    """Mean and 95% Student-t half-width, written out here (not harness.stats)."""
    values = np.asarray(values, float)
    half = stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / math.sqrt(len(values))
    return values.mean(), half


def test_run_summary_aggregates_frames_then_seeds_with_intervals():
    """Two frames × three seeds: per seed the mean over frames, then the mean over seeds; an
    equal-time cell is its own entry; a metric left out (NaN everywhere) is absent."""
    rows, errors = [], {}
    for seed in range(3):
        for frame in range(2):
            errors[seed, frame] = 2.0 + seed * seed + 0.5 * frame
            rows.append(row("twilight", "uniform", 16, seed=seed, frame=frame,
                            mean_delta_e76=errors[seed, frame], time_ms=4.0 + seed, flip=np.nan,
                            nonfinite=seed, time_budget_ms=np.nan))
    for seed in range(2):
        rows.append(row("twilight", "uniform", 40, seed=seed, time_budget_ms=20.0,
                        mean_delta_e76=1.0 + seed, flip=np.nan))
    table = pd.DataFrame(rows, columns=COLUMNS)
    summary = json.loads(json_text(run_summary(table, Path("runs/x"), {"status": "complete"})))
    assert summary["command"] == "run" and summary["status"] == "complete"
    assert summary["out"] == "runs/x" and summary["rows"] == 8
    by_budget = {cell["time_budget_ms"]: cell for cell in summary["cells"]}
    assert set(by_budget) == {None, 20.0}
    cell = by_budget[None]
    assert (cell["scene"], cell["estimator"], cell["spp"]) == ("twilight", "uniform", 16)
    assert (cell["frames"], cell["seeds"], cell["nonfinite"]) == (2, 3, 0 + 0 + 1 + 1 + 2 + 2)
    mean, half = _interval([(errors[s, 0] + errors[s, 1]) / 2 for s in range(3)])
    figure = cell["metrics"]["mean_delta_e76"]
    assert figure["mean"] == pytest.approx(mean) and figure["half_width"] == pytest.approx(half)
    assert figure["low"] == pytest.approx(mean - half) and figure["high"] == pytest.approx(mean + half)
    assert cell["metrics"]["time_ms"]["mean"] == pytest.approx(5.0)
    assert "flip" not in cell["metrics"]
    budget = by_budget[20.0]
    assert budget["spp"] == 40 and budget["seeds"] == 2
    assert budget["metrics"]["mean_delta_e76"]["mean"] == pytest.approx(1.5)


def test_run_summary_with_one_seed_has_no_interval():
    table = pd.DataFrame([row("sphere-sun", "uniform", 16, time_budget_ms=np.nan)], columns=COLUMNS)
    cell = json.loads(json_text(run_summary(table, "o", {})))["cells"][0]
    assert cell["metrics"]["mean_delta_e76"] == {"mean": 1.0, "low": None, "high": None,
                                                 "half_width": None, "n": 1,
                                                 "method": "mean over seeds, 95% Student-t interval"}


# ---- check: --json and --junit ----------------------------------------------------------------------

@pytest.fixture
def run_dir(tmp_path) -> Path:
    """sphere-sun × uniform (ΔE76 3 and 5 over seeds 0, 1) and balanced (1, 1) at spp 16."""
    rows = [row("sphere-sun", estimator, 16, seed=seed, mean_delta_e76=value, **configured())
            for estimator, values in (("uniform", (3.0, 5.0)), ("balanced", (1.0, 1.0)))
            for seed, value in enumerate(values)]
    out = tmp_path / "run"
    out.mkdir()
    write_results(out, rows)
    return out


def _check(run_dir: Path, budgets_text: str, capsys, *flags: str):
    budgets = run_dir.parent / "budgets.toml"
    budgets.write_text(budgets_text, encoding="utf-8")
    status = cli.main(["check", str(run_dir), "--budgets", str(budgets), *flags])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


# uniform's mean ΔE76 is 4 (fails <= 3.5); balanced's is 1 (passes); both fail <= 0.5 (one
# rule, two failed checks); flicker on a static scene is n/a; the nonfinite rule passes.
FAILING = (CONFIGURATION
           + rule("sphere-sun", "*", "max_mean_delta_e76 = 3.5", name="de-tight")
           + rule("sphere-sun", "*", "max_mean_delta_e76 = 0.5", name="de-impossible")
           + rule("sphere-sun", "*", "nonfinite = 0", name="finite")
           + rule("sphere-sun", "*", "max_flicker = 1.0", name="steady"))


def test_check_json_on_a_failing_budget(run_dir, capsys):
    status, out, err = _check(run_dir, FAILING, capsys, "--json")
    assert status == 1
    summary = json.loads(out)                        # stdout is the JSON document alone
    assert "check: FAIL" in err and "de-tight" in err   # the table and verdict on stderr
    assert summary["command"] == "check" and summary["exit"] == 1 and summary["passed"] is False
    assert summary["failed"] == 3 and summary["checks"] == 8
    rules = {r["name"]: r for r in summary["rules"]}
    assert [r["name"] for r in summary["rules"]] == ["de-tight", "de-impossible", "finite", "steady"]
    assert {name: r["result"] for name, r in rules.items()} == {
        "de-tight": "FAIL", "de-impossible": "FAIL", "finite": "PASS", "steady": "n/a"}
    values = {c["estimator"]: c for c in rules["de-tight"]["checks"]}
    assert values["uniform"]["value"] == pytest.approx(4.0) and values["uniform"]["result"] == "FAIL"
    assert values["balanced"]["value"] == pytest.approx(1.0) and values["balanced"]["result"] == "PASS"
    assert values["uniform"]["bound"] == "<= 3.5" and values["uniform"]["spp"] == 16
    assert values["uniform"]["ci95"].startswith("± ")
    assert all(isinstance(c["value"], str) for c in rules["steady"]["checks"])   # n/a: no number


def test_check_json_on_a_passing_budget_and_a_missing_cell(run_dir, capsys):
    status, out, _ = _check(run_dir, CONFIGURATION + rule("sphere-sun", "balanced",
                                                          "max_mean_delta_e76 = 3.5"),
                            capsys, "--json")
    summary = json.loads(out)
    assert status == 0 == summary["exit"] and summary["passed"] and summary["failed"] == 0
    missing = (CONFIGURATION + rule("sphere-sun", "balanced", "max_rel_mse = 1.0")
               .replace("spp = 16", "spp = [16, 64]"))
    status, out, _ = _check(run_dir, missing, capsys, "--json")
    checks = json.loads(out)["rules"][0]["checks"]
    assert status == 1
    assert {(c["spp"], c["value"], c["result"]) for c in checks if c["metric"] == "cell"} == {
        (64, "missing", "FAIL")}


def test_check_json_on_bad_input_leaves_stdout_empty(run_dir, tmp_path, capsys):
    junit = tmp_path / "check.xml"
    status, out, err = _check(run_dir, CONFIGURATION.replace("width = 48", "width = 64")
                              + rule("sphere-sun", "*", "nonfinite = 0"), capsys, "--json",
                              "--junit", str(junit))
    assert (status, out) == (2, "") and "another configuration" in err and err.count("\n") == 1
    assert not junit.exists()


def test_check_junit_counts_failures_per_rule(run_dir, tmp_path, capsys):
    junit = tmp_path / "reports" / "check.xml"
    junit.parent.mkdir()
    status, out, _ = _check(run_dir, FAILING, capsys, "--junit", str(junit))
    assert status == 1 and "check: FAIL" in out          # without --json the table is on stdout
    root = ET.parse(junit).getroot()
    suite = root.find("testsuite")
    cases = {case.get("name"): case for case in suite.iter("testcase")}
    assert list(cases) == ["de-tight", "de-impossible", "finite", "steady"]
    for element in (root, suite):
        assert (element.get("tests"), element.get("failures"), element.get("skipped")) == ("4", "2", "1")
    assert len(root.findall(".//failure")) == 2
    assert cases["de-impossible"].find("failure").get("message").startswith("2 of 2 checks failed")
    assert cases["de-impossible"].find("failure").text.count("\n") == 1   # one line per check
    failure = cases["de-tight"].find("failure")
    assert failure.get("message").startswith("1 of 2 checks failed: sphere-sun uniform spp=16")
    assert "uniform" in failure.text and "balanced" not in failure.text
    assert cases["finite"].find("failure") is None and cases["finite"].find("skipped") is None
    assert cases["steady"].find("skipped") is not None
    assert "balanced" in cases["de-tight"].find("system-out").text


def test_check_junit_that_cannot_be_written_is_bad_input(run_dir, tmp_path, capsys):
    (tmp_path / "a-file").write_text("")
    status, _, err = _check(run_dir, FAILING, capsys, "--junit", str(tmp_path / "a-file" / "x.xml"))
    assert status == 2 and err.count("\n") == 1 and "--junit: cannot write it" in err, err


# ---- stress --json ----------------------------------------------------------------------------------

def test_stress_json_has_the_case_by_estimator_matrix(tmp_path, capsys):
    """static-sequence runs temporal estimators only, so (static-sequence, uniform) is n/a."""
    status = cli.main(["stress", "--quick", "--no-progress", "--case", "black-map",
                       "--case", "static-sequence", "--estimator", "uniform",
                       "--estimator", "havran", "--out", str(tmp_path), "--json"])
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert "stress: passed" in captured.err
    table = pd.read_csv(tmp_path / "stress.csv")
    assert status == 0 == summary["exit"] and summary["passed"]
    assert summary["cases"] == ["black-map", "static-sequence"]
    assert summary["estimators"] == ["uniform", "havran"]
    expected = {case: {label: "n/a" for label in summary["estimators"]} for case in summary["cases"]}
    for entry in table.itertuples():
        expected[entry.case][entry.estimator] = entry.status
    assert summary["matrix"] == expected
    assert summary["matrix"]["static-sequence"]["uniform"] == "n/a"
    assert summary["matrix"]["black-map"] == {"uniform": "pass", "havran": "pass"}
    assert len(summary["cells"]) == len(table)
    assert set(summary["cells"][0]) == set(table.columns)
    assert str(tmp_path / "stress.csv") in summary["files"]
