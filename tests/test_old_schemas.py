"""Folders written by older schemas (issue 35): ``report``, ``check``, ``compare`` and ``budgets``
read every schema whose missing columns have a sound value, and otherwise say in one line which
schema the folder holds and how to upgrade it; ``run`` into such a folder says first what it
renders again and keeps the old table.

Each older folder is a small real run whose table is rewritten with the columns that schema had,
listed here from docs/results.md ("Earlier schema versions") and the history of
harness/protocol/results.py, not from today's ``COLUMNS``."""
from __future__ import annotations

import json
import shutil

import pandas as pd
import pytest

from iblbench import cli
from iblbench.harness.protocol.runner import RunConfig, run

KEY = ["scene", "estimator", "spp", "frame", "seed"]
CONFIGURATION = ["width", "height", "env_res", "estimator_params", "estimator_version",
                 "schema_version"]
ERRORS = ["mean_delta_e76", "mean_delta_e2000", "rel_mse", "flip"]
SAMPLES = ["used_samples", "effective_samples", "effective_ratio", "evaluations"]
ONE_RENDER_TIMES = ["time_ms_build", "time_ms_sample", "time_ms_shade", "time_ms_frame"]
TIMES = ["time_ms", "time_ms_min", "time_ms_iqr", "time_ms_build", "time_ms_sample",
         "time_ms_shade", "time_ms_host", "time_repeats"]
RENDERS = ["mean_delta_e76_renders", "mean_delta_e2000_renders", "rel_mse_renders"]
SCHEMA_COLUMNS = {
    1: KEY + ["estimator_version"] + ERRORS + SAMPLES + ["nonfinite"] + ONE_RENDER_TIMES
       + ["device", "protocol"],
    3: KEY + ["time_budget_ms"] + CONFIGURATION + ERRORS + ["flicker"] + SAMPLES + ["nonfinite"]
       + ONE_RENDER_TIMES + ["device", "protocol"],
    4: KEY + ["time_budget_ms"] + CONFIGURATION + ["metrics"] + ERRORS + ["flicker"] + SAMPLES
       + ["nonfinite"] + TIMES + ["device", "protocol"],
    5: KEY + ["time_budget_ms"] + CONFIGURATION + ["metrics"] + ERRORS + ["flicker"] + SAMPLES
       + ["shadow_rays", "nonfinite"] + TIMES + ["device", "protocol"],
    6: KEY + ["time_budget_ms"] + CONFIGURATION + ["metrics"] + ERRORS + ["flicker"] + SAMPLES
       + ["shadow_rays", "nonfinite"] + RENDERS + TIMES + ["time_ms_renders", "device", "protocol"],
}
RUN_FLAGS = ["--scene", "sphere-sun", "--estimator", "uniform", "--spp", "2", "--seeds", "1",
             "--res", "8x8", "--env-res", "8", "--repeats", "1", "--no-progress"]


@pytest.fixture(scope="module")
def current(tmp_path_factory):
    """A run of today's schema: one cell, 8×8 pixels (a few seconds)."""
    out = tmp_path_factory.mktemp("schema-now")
    run(RunConfig(out=out, scenes=("sphere-sun",), estimators=("uniform",), spp=(2,), seeds=1,
                  resolution=(8, 8), env_res=8, repeats=1, progress=False))
    return out


def older(current, tmp_path, schema: int, seeds: int = 1):
    """A copy of ``current`` whose table has the columns of ``schema`` (its one row repeated
    over ``seeds`` seeds); schemas before 4 timed one render on the host (``time_ms_frame``)."""
    folder = tmp_path / f"schema{schema}"
    shutil.copytree(current, folder)
    table = pd.read_parquet(current / "results.parquet")
    table = pd.concat([table.assign(seed=seed) for seed in range(seeds)], ignore_index=True)
    table = table.assign(time_ms_frame=table.time_ms_host, schema_version=schema)
    table = table[SCHEMA_COLUMNS[schema]]
    table.to_parquet(folder / "results.parquet", index=False)
    table.to_csv(folder / "results.csv", index=False)
    return folder, table


def iblbench(capsys, *argv) -> tuple[int, str, str]:
    status = cli.main([*map(str, argv)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_report_says_which_schema_and_how_to_upgrade_where_times_are_missing(current, tmp_path,
                                                                           capsys):
    for schema in (1, 3):   # one render's host time: nothing to read as today's time_ms
        folder, _ = older(current, tmp_path, schema)
        status, _, err = iblbench(capsys, "report", folder)
        assert status == 2 and err.count("\n") == 1, err
        assert f"{folder / 'results.parquet'}: holds results of schema {schema}" in err, err
        assert f"--out {folder}" in err and f"results.schema{schema}.parquet" in err, err
    folder, _ = older(current, tmp_path, 4)   # no shadow_rays, per-render columns or host
    status, out, err = iblbench(capsys, "report", folder)
    assert status == 0 and (folder / "report" / "index.html").is_file(), err
    # the table: today's times without time_budget_ms (KeyError: 'time_budget_ms')
    folder = tmp_path / "no-budget-column"
    shutil.copytree(current, folder)
    table = pd.read_parquet(current / "results.parquet").drop(columns=["time_budget_ms"])
    table.to_parquet(folder / "results.parquet", index=False)
    status, out, err = iblbench(capsys, "report", folder)
    assert status == 0 and (folder / "report" / "index.html").is_file(), err


def test_check_reads_a_schema_5_folder(current, tmp_path, capsys):
    folder, table = older(current, tmp_path, 5)   # no per-render columns, no host
    budgets = tmp_path / "budgets.toml"
    budgets.write_text('[configuration]\nwidth = 8\nheight = 8\nenv_res = 8\nseeds = 1\n'
                       'protocol = "lab-reinhard-v1"\n\n[[rule]]\nscene = "sphere-sun"\n'
                       'estimator = "uniform"\nspp = 2\n'
                       f'max_mean_delta_e76 = {2 * table.mean_delta_e76[0]}\n', encoding="utf-8")
    status, out, err = iblbench(capsys, "check", folder, "--budgets", budgets)
    assert status == 0, err
    assert out.strip().splitlines()[-1].startswith("check: PASS"), out


def test_compare_reads_a_schema_1_folder(current, tmp_path, capsys):
    folder, _ = older(current, tmp_path, 1)   # no time_budget_ms: every cell is equal-spp
    status, out, err = iblbench(capsys, "compare", folder, current, "--json")
    assert status == 0, err
    summary = json.loads(out)
    assert len(summary["cells"]) == 1 and summary["only_in_a"]["cells"] == 0, out
    assert "protocol: schema_version 1 (A) vs 7 (B)" in summary["differences"], out


def test_budgets_reads_a_schema_4_folder(current, tmp_path, capsys):
    folder, _ = older(current, tmp_path, 4, seeds=8)   # budgets want 8 seeds
    output = tmp_path / "budgets.toml"
    status, out, err = iblbench(capsys, "budgets", folder, "--margin", "0.1", "--output", output)
    assert status == 0, err
    assert "wrote 1 rule" in out and 'estimator = "uniform"' in output.read_text(), out


def test_run_into_a_schema_6_folder_says_what_it_renders_again_and_keeps_the_old_table(
        current, tmp_path, capsys):
    folder, table = older(current, tmp_path, 6)
    status, _, err = iblbench(capsys, "run", *RUN_FLAGS, "--out", folder)
    assert status == 0, err
    backup = folder / "results.schema6.parquet"
    notice = [line for line in err.splitlines() if "schema 6" in line]
    assert notice == [f"iblbench: {folder / 'results.parquet'} holds 1 rows of schema 6 (this "
                      "iblbench writes schema 7): this run renders 1 of them again and replaces "
                      "their rows, 0 not in its sweep stay as they are; the old table is kept as "
                      f"{backup}"], err
    pd.testing.assert_frame_equal(pd.read_parquet(backup), table)
    assert pd.read_parquet(folder / "results.parquet").schema_version.tolist() == [7]
