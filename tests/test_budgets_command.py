"""``iblbench budgets DIR --margin M --se-multiple K`` (issue 11): a budgets file derived from a
multi-seed run, checked against an independent computation of its bounds, refused below 8 seeds,
and passed by ``check`` on the run it was made from.
"""
from __future__ import annotations

import datetime
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from iblbench import cli
from iblbench.harness.protocol.results import write_manifest, write_results
from test_budgets import row

ROOT = Path(__file__).resolve().parents[1]
DELTA_E = {"uniform": 4.0, "balanced": 3.0}


def seeded_run(tmp_path: Path, seeds: int, **change) -> Path:
    """sphere-sun × uniform, balanced × spp 16; seed s has ΔE76 = base + 0.1·s² and relMSE
    0.01·(1 + s), so every cell has a known spread."""
    rows = [row("sphere-sun", estimator, 16, seed=seed, mean_delta_e76=base + 0.1 * seed ** 2,
                rel_mse=0.01 * (1 + seed)) | change
            for estimator, base in DELTA_E.items() for seed in range(seeds)]
    out = tmp_path / "run"
    out.mkdir()
    write_results(out, rows)
    return out


def make(run: Path, output: Path, capsys, *flags) -> tuple[int, str]:
    status = cli.main(["budgets", str(run), "--output", str(output), *map(str, flags)])
    return status, capsys.readouterr().err


def test_bounds_are_the_mean_plus_minus_k_standard_errors_and_the_margin(tmp_path, capsys):
    run = seeded_run(tmp_path, 8)
    output = tmp_path / "budgets.toml"
    status, err = make(run, output, capsys, "--margin", 0.1, "--se-multiple", 2)
    assert status == 0, err
    document = tomllib.loads(output.read_text(encoding="utf-8"))
    assert document["configuration"] == {"width": 48, "height": 48, "env_res": 32, "seeds": 8,
                                         "protocol": "lab-reinhard-v1"}
    rules = {rule["estimator"]: rule for rule in document["rule"]}
    assert set(rules) == set(DELTA_E)
    seeds = np.arange(8)
    for estimator, base in DELTA_E.items():
        rule = rules[estimator]
        for metric, values in (("mean_delta_e76", base + 0.1 * seeds ** 2),
                               ("rel_mse", 0.01 * (1 + seeds))):
            mean, se = values.mean(), values.std(ddof=1) / math.sqrt(values.size)
            low, high = mean - 2 * se - 0.1 * mean, mean + 2 * se + 0.1 * mean
            # Rounded outward to 4 significant digits: never inside the exact bound.
            assert low - 1e-3 * abs(low) <= rule[f"min_{metric}"] <= low, (estimator, metric)
            assert high <= rule[f"max_{metric}"] <= high + 1e-3 * high, (estimator, metric)
        # Constant over seeds: the margin alone; used samples [spp − 1%, spp]; no NaN pixels.
        assert rule["min_effective_ratio"] == pytest.approx(0.8 * 0.9, rel=1e-3)
        assert rule["max_effective_ratio"] == pytest.approx(0.8 * 1.1, rel=1e-3)
        assert (rule["min_used_samples"], rule["max_used_samples"]) == (15.84, 16)
        assert rule["nonfinite"] == 0
    assert rules["balanced"]["max_time_ratio"]["max"] == pytest.approx(5.0)   # 5 × 1 ms / 1 ms
    assert "max_time_ratio" not in rules["uniform"]
    assert "measured" in output.read_text(encoding="utf-8")

    assert cli.main(["check", str(run), "--budgets", str(output)]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("check: PASS")


def test_header_says_when_how_and_why_the_budgets_were_made(tmp_path, capsys):
    """The header holds the date and both commands that remake the file (the sweep from the
    run's manifest), so it is remade, not edited."""
    run = seeded_run(tmp_path, 8)
    write_manifest(run, {"sweep": {"source": "shipped:quick", "overridden_by_flags": []}})
    output = tmp_path / "b.toml"
    status, err = make(run, output, capsys, "--margin", 0.05, "--why", "the pool stream changed")
    assert status == 0, err
    header = output.read_text(encoding="utf-8").split("[configuration]")[0]
    today = datetime.datetime.now(datetime.timezone.utc).date().isoformat()
    assert f"made on {today}" in header
    assert f"#   iblbench run --config quick --out {run}\n" in header
    assert f"#   iblbench budgets {run} --margin 0.05 --se-multiple 3 --output {output}\n" in header
    assert "# Why they were made: the pool stream changed\n" in header
    write_manifest(run, {"sweep": {"source": "/x/my.toml", "overridden_by_flags": ["--seeds"]}})
    make(run, output, capsys, "--margin", 0.05)
    header = output.read_text(encoding="utf-8").split("[configuration]")[0]
    assert (f"iblbench run --config /x/my.toml --out {run} with --seeds (values in its "
            "manifest.json)") in header and "Why they were made: not stated" in header


@pytest.mark.parametrize("seeds, change, needle", [
    (7, {}, "at least 8"),
    (8, {"nonfinite": 2}, "non-finite"),
])
def test_too_few_seeds_or_a_broken_run_is_refused_and_the_old_file_kept(tmp_path, capsys, seeds,
                                                                         change, needle):
    run = seeded_run(tmp_path, seeds, **change)
    output = tmp_path / "budgets.toml"
    output.write_text("old", encoding="utf-8")
    status, err = make(run, output, capsys, "--margin", 0.1)
    assert status == 2 and needle in err and err.count("\n") == 1, err
    assert output.read_text(encoding="utf-8") == "old"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".budgets")] == []


def test_budgets_from_a_real_run_pass_check_on_it(tmp_path):
    """A small real sweep of 8 seeds (about 6 s on 2 cores) → budgets → check passes."""
    env = dict(os.environ, PYTHONWARNINGS="ignore")

    def iblbench(*args):
        return subprocess.run([sys.executable, "-m", "iblbench.cli", *map(str, args)],
                              capture_output=True, text=True, env=env, timeout=300, cwd=ROOT)

    run = tmp_path / "run"
    result = iblbench("run", "--scene", "sphere-sun", "--estimator", "uniform", "--estimator",
                      "balanced", "--spp", "4", "--seeds", "8", "--res", "16x16", "--env-res", "8",
                      "--no-progress", "--out", run)
    assert result.returncode == 0, result.stdout + result.stderr
    output = tmp_path / "budgets.toml"
    result = iblbench("budgets", run, "--margin", "0.05", "--output", output)
    assert result.returncode == 0 and "wrote 2 rules" in result.stdout, result.stderr
    result = iblbench("check", run, "--budgets", output)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip().splitlines()[-1].startswith("check: PASS")


def test_run_command_names_the_python_api_for_an_api_run(tmp_path):
    """A run made by iblbench.run has no command line: the header must not claim one."""
    from iblbench.harness.protocol.budgets import run_command

    api_run = {"sweep": {"source": "shipped:default", "via": "iblbench.run (Python API)",
                         "overridden_by_arguments": ["scenes", "spp"]}}
    assert run_command(tmp_path, api_run).startswith("(Python: iblbench.run(scenes, spp)")
    cli_run = {"sweep": {"source": "shipped:quick", "overridden_by_flags": ["--seeds"]}}
    expected = f"iblbench run --config quick --out {tmp_path} with --seeds"
    assert run_command(tmp_path, cli_run).startswith(expected)


def test_without_output_an_existing_budgets_file_is_kept(tmp_path, capsys, monkeypatch):
    """Issue 23: without --output, `budgets` overwrote ./budgets.toml silently (from the
    repository root, the committed file).  It writes there only where none exists."""
    run = seeded_run(tmp_path, 8)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["budgets", str(run), "--margin", "0.1"]) == 0
    written = (tmp_path / "budgets.toml").read_text(encoding="utf-8")
    (tmp_path / "budgets.toml").write_text("committed", encoding="utf-8")
    capsys.readouterr()
    assert cli.main(["budgets", str(run), "--margin", "0.1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "budgets.toml" in err and "--output" in err, err
    assert (tmp_path / "budgets.toml").read_text(encoding="utf-8") == "committed"
    assert "[configuration]" in written


def test_the_check_table_fits_a_terminal(tmp_path, capsys):
    """Issue 23: the `check` table was about 220 characters wide (the rule's name, then its
    scene, estimator and spp again).  Where every rule is named as `budgets` names them, those
    three columns are left out: every line fits 130 columns, and each still names its rule."""
    run = seeded_run(tmp_path, 8)
    output = tmp_path / "b.toml"
    assert make(run, output, capsys, "--margin", 0.1)[0] == 0
    assert cli.main(["check", str(run), "--budgets", str(output)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(map(len, lines)) <= 130, max(lines, key=len)
    cells = [line for line in lines if "sphere-sun" in line]
    assert cells and all(line.count("sphere-sun") == 1 for line in cells), cells[0]   # said once
    assert any(line.split()[:3] == ["sphere-sun", "uniform", "spp=16"] for line in lines), lines
