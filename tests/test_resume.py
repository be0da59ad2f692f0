"""The results store: resuming, --force, the journal, kill -9 safety, temporal units, equal time."""
from __future__ import annotations

import dataclasses
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from iblbench.estimators.registry import _registry, register
from iblbench.estimators.uniform import Uniform
from iblbench.cli import main
from iblbench.harness.protocol.results import (DETERMINISTIC_COLUMNS, JOURNAL, Journal,
                                               read_journal, read_results, row_key, write_results)
from iblbench.harness.protocol.runner import RunConfig, run
from iblbench.foundation.errors import InputError

TINY = """\
protocol = "lab-reinhard-v1"
scenes = ["sphere-sun"]
estimators = ["uniform", "balanced"]
spp = [4, 8]
seeds = 2
resolution = "16x16"
env_res = 8
"""
KEY = ["scene", "estimator", "spp", "frame", "seed", "time_budget_ms"]


def sorted_table(out: Path) -> pd.DataFrame:
    table = pd.read_parquet(out / "results.parquet")
    return table.sort_values(KEY).reset_index(drop=True)


def cli_run(capsys, config: Path, out: Path, *flags: str) -> tuple[pd.DataFrame, str]:
    code = main(["run", "--config", str(config), "--out", str(out), "--no-progress", *flags])
    err = capsys.readouterr().err
    assert code == 0, err
    return sorted_table(out), err


@pytest.fixture
def tiny_config(tmp_path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


# ---- resuming -----------------------------------------------------------------------------------


def test_rerun_resumes_and_keeps_the_table(tmp_path, tiny_config, capsys):
    out = tmp_path / "out"
    first, err = cli_run(capsys, tiny_config, out)
    assert "resumed" not in err and len(first) == 8
    second, err = cli_run(capsys, tiny_config, out)
    assert "resumed: 8 cells already done, 0 to run" in err
    pd.testing.assert_frame_equal(first, second)          # timings too: nothing was re-rendered
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["resumed_cells"] == 8 and manifest["cells_to_run"] == 0
    assert manifest["status"] == "complete"
    assert not (out / JOURNAL).exists()


def test_force_recomputes(tmp_path, tiny_config, capsys):
    out = tmp_path / "out"
    first, _ = cli_run(capsys, tiny_config, out)
    forced, err = cli_run(capsys, tiny_config, out, "--force")
    assert "resumed" not in err and len(forced) == len(first)
    assert not np.array_equal(first.time_ms_host, forced.time_ms_host)
    pd.testing.assert_frame_equal(first[DETERMINISTIC_COLUMNS], forced[DETERMINISTIC_COLUMNS])


def test_a_changed_configuration_is_recomputed_not_duplicated(tmp_path, tiny_config, capsys):
    out = tmp_path / "out"
    cli_run(capsys, tiny_config, out)
    # Another --res is refused without --force (tests/test_robustness.py); with it, it replaces.
    table, err = cli_run(capsys, tiny_config, out, "--res", "20x12", "--spp", "4", "--force")
    assert "resumed" not in err
    assert len(table) == 4 and not table.duplicated(KEY).any()
    assert sorted(set(zip(table.spp, table.width))) == [(4, 20)]
    table, err = cli_run(capsys, tiny_config, out, "--res", "20x12", "--spp", "4")
    assert "resumed: 4 cells already done, 0 to run" in err


def images(out: Path) -> set[str]:
    return {str(path.relative_to(out / "images")) for path in (out / "images").rglob("*.exr")}


def test_force_with_one_estimator_keeps_the_others_cells_or_says_it_removed_them(
        tmp_path, tiny_config, capsys):
    """Issue 23: ``--force --estimator uniform`` reruns uniform's cells only; balanced's stay,
    rows and images.  With another --res it replaces the scene's cells: balanced's rows went
    silently and their EXRs stayed on disk; now both go, and the run says so."""
    out = tmp_path / "out"
    first, _ = cli_run(capsys, tiny_config, out)
    balanced = first[first.estimator == "balanced"].reset_index(drop=True)
    before = images(out)
    assert len(before) == 9   # 8 cells and the reference
    table, err = cli_run(capsys, tiny_config, out, "--estimator", "uniform", "--force")
    assert "removed" not in err
    pd.testing.assert_frame_equal(table[table.estimator == "balanced"].reset_index(drop=True),
                                  balanced)   # not rerun: its timings are the first run's
    assert images(out) == before
    table, err = cli_run(capsys, tiny_config, out, "--estimator", "uniform", "--force",
                         "--res", "20x12", "--spp", "4")
    assert set(zip(table.estimator, table.spp, table.width)) == {("uniform", 4, 20)}
    assert images(out) == {"sphere-sun/f0/reference.exr", "sphere-sun/f0/uniform_spp4_s0.exr",
                           "sphere-sun/f0/uniform_spp4_s1.exr"}
    assert ("--force: removed the 8 cells of another image configuration, rows, images and "
            "saved inputs (sphere-sun was run with --res 16x16 (now 20x12))") in err


def test_a_journal_left_by_a_killed_run_is_folded_in(tmp_path, tiny_config, capsys):
    out = tmp_path / "out"
    complete, _ = cli_run(capsys, tiny_config, out)
    rows = complete.to_dict("records")
    write_results(out, rows[:5])                       # the table as of the last fold
    journal = Journal(out)
    for row in rows[5:7]:
        journal.append(row)
    journal.close()
    with open(out / JOURNAL, "ab") as handle:
        handle.write(b'{"scene": "sphere-sun", "estim')   # the line in flight at kill -9
    assert len(read_journal(out)) == 2 and len(read_results(out)) == 7
    table, err = cli_run(capsys, tiny_config, out)
    assert "resumed: 7 cells already done, 1 to run" in err
    assert not (out / JOURNAL).exists()
    pd.testing.assert_frame_equal(table[DETERMINISTIC_COLUMNS], complete[DETERMINISTIC_COLUMNS])


def _cell(seed: int, delta_e: float) -> dict:
    """A row of one cell of a hand-made store (the key, a metric)."""
    return {"scene": "sphere-sun", "estimator": "uniform", "spp": 4, "frame": 0, "seed": seed,
            "time_budget_ms": None, "mean_delta_e76": delta_e}


def _readers_agree(out: Path) -> dict:
    """The cell key → ΔE76 that the run's resume (read_results), the report and the check read;
    asserted equal, one row per cell each."""
    from iblbench.harness.protocol.budgets import load_results
    from iblbench.reports.tables import load_run

    resume = {row_key(row): row["mean_delta_e76"] for row in read_results(out)}
    assert len(resume) == len(read_results(out))
    for table in (load_run(out)[0], load_results(out)):
        rows = table.to_dict("records")
        assert {row_key(row): row["mean_delta_e76"] for row in rows} == resume and len(rows) == len(resume)
    return resume


def test_journal_rows_replace_the_tables_rows_of_the_same_cell(tmp_path):
    """read_results, and the report's and the check's readers, take a cell's row from the
    journal where both hold it: the journal is newer (the table is the last fold)."""
    write_results(tmp_path, [_cell(0, 1.0), _cell(1, 2.0)])
    journal = Journal(tmp_path)
    for row in (_cell(1, 20.0), _cell(2, 30.0)):    # cell 1 rerun, cell 2 new
        journal.append(row)
    journal.close()
    assert {key[4]: value for key, value in _readers_agree(tmp_path).items()} == {
        0: 1.0, 1: 20.0, 2: 30.0}


def test_a_forced_rerun_killed_before_its_fold_reads_its_new_rows(tmp_path, tiny_config, capsys,
                                                                  monkeypatch):
    """``run(force=True)`` on a folder of finished cells, killed (no fold, no Ctrl-C handler)
    after journalling 3 of its 8 cells: the table still holds the old rows of all 8 and the
    journal the new rows of 3.  Resume, report and check read the new rows of those 3 and the
    old of the other 5; a plain rerun then finds all 8 done and folds exactly those rows.  The
    old rows are marked by a ΔE76 100 above what the renders give."""
    from iblbench.harness.protocol import runner as runner_module

    out = tmp_path / "out"
    fresh, _ = cli_run(capsys, tiny_config, out)
    fresh_delta_e = {row_key(row): row["mean_delta_e76"] for row in fresh.to_dict("records")}
    write_results(out, [{**row, "mean_delta_e76": row["mean_delta_e76"] + 100}
                        for row in fresh.to_dict("records")])

    class Killed(BaseException):
        """Stands for kill -9: the runner neither catches nor folds it."""

    append = Journal.append

    def append_then_die(journal, row):
        append(journal, row)
        if len(read_journal(out)) == 3:
            raise Killed

    monkeypatch.setattr(Journal, "append", append_then_die)
    monkeypatch.setattr(runner_module, "FOLD_SECONDS", float("inf"))
    config = RunConfig(out=out, scenes=("sphere-sun",), estimators=("uniform", "balanced"),
                       spp=(4, 8), seeds=2, resolution=(16, 16), env_res=8, progress=False)
    with pytest.raises(Killed):
        run(dataclasses.replace(config, force=True))
    monkeypatch.undo()
    rerun = {row_key(row) for row in read_journal(out)}
    assert len(rerun) == 3 and len(pd.read_parquet(out / "results.parquet")) == 8
    read = _readers_agree(out)
    assert read == {key: value + 100 * (key not in rerun) for key, value in fresh_delta_e.items()}

    resumed = run(config)
    assert "resumed: 8 cells already done, 0 to run" in capsys.readouterr().err
    assert not (out / JOURNAL).exists()
    assert {row_key(row): row["mean_delta_e76"] for row in resumed.to_dict("records")} == read
    assert _readers_agree(out) == read


def test_a_damaged_journal_line_before_the_last_is_an_input_error(tmp_path):
    (tmp_path / JOURNAL).write_bytes(b'{"scene": \n{"scene": "a"}\n')
    with pytest.raises(InputError, match="line 1 is damaged"):
        read_journal(tmp_path)


# ---- kill -9 ------------------------------------------------------------------------------------


def test_kill_9_mid_run_then_resume_equals_an_uninterrupted_run(tmp_path):
    """SIGKILL a real ``iblbench run`` twice, each time once a few cells are in, then finish.
    A frame's cells come in together (they render in rounds), so each kill lands in a later
    scene than the last: three scenes."""
    config = tmp_path / "sweep.toml"
    config.write_text(TINY.replace('["sphere-sun"]', '["sphere-sun", "sphere-backlit", "blob-sun"]')
                      .replace('["uniform", "balanced"]', '["uniform", "balanced_mis"]')
                      .replace("[4, 8]", "[16]").replace("seeds = 2", "seeds = 3"))
    total = 3 * 2 * 1 * 3   # cells take ~0.2-0.4 s each here, most of it HDR-FLIP
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    env.pop("IBLBENCH_DEVICE", None)

    def start(out: Path) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "iblbench.cli", "run", "--config",
                                 str(config), "--out", str(out), "--no-progress"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    clean = tmp_path / "clean"
    finished = start(clean)
    assert finished.wait(timeout=120) == 0, finished.stderr.read()
    expected = sorted_table(clean)
    assert len(expected) == total

    out = tmp_path / "killed"
    done, rng = 0, random.Random(4)
    for _ in range(2):
        process = start(out)
        deadline = time.monotonic() + 120
        while len(read_results(out)) < done + 2:       # a few cells past where we were
            assert process.poll() is None, process.stderr.read()
            assert time.monotonic() < deadline
            time.sleep(0.005)
        time.sleep(rng.uniform(0.0, 0.15))              # somewhere inside the next cell
        assert process.poll() is None, "the run finished before it could be killed"
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=30)
        assert process.returncode == -signal.SIGKILL
        rows = read_results(out)                        # the table and journal stay readable
        assert done + 2 <= len(rows) <= total   # on a loaded machine, maybe after the last cell
        assert len({row_key(row) for row in rows}) == len(rows)
        assert json.loads((out / "manifest.json").read_text())["status"] == "running"
        done = len(rows)

    process = start(out)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 0, stderr
    resumed = int(stderr.split("resumed: ")[1].split(" cells")[0])
    assert resumed >= done and f"{total - resumed} to run" in stderr
    table = sorted_table(out)
    assert not table.duplicated(KEY).any() and len(table) == total
    pd.testing.assert_frame_equal(table[DETERMINISTIC_COLUMNS], expected[DETERMINISTIC_COLUMNS])
    assert json.loads((out / "manifest.json").read_text())["status"] == "complete"
    assert not (out / JOURNAL).exists() and not list(out.rglob(".*.exr"))


# ---- temporal estimators: the frame sequence is the unit ----------------------------------------


class TemporalUniform(Uniform):
    """``uniform`` declared temporal, logging which instance renders what (test only)."""

    name = "uniform_temporal_test"
    tags = dataclasses.replace(Uniform.tags, temporal=True)
    log: list = []

    def reset(self) -> None:
        self.log.append((id(self), "reset"))

    def render(self, gbuffer, cache, spp, seed):
        self.log.append((id(self), cache.frame, seed))
        return super().render(gbuffer, cache, spp, seed)


@pytest.fixture
def temporal():
    register(TemporalUniform)
    TemporalUniform.log.clear()
    yield TemporalUniform
    _registry.pop(TemporalUniform.name)


def test_a_temporal_estimator_resumes_whole_sequences(tmp_path, temporal):
    (tmp_path / "day").mkdir()
    for index in range(3):
        np.save(tmp_path / "day" / f"f{index}.npy",
                np.full((6, 4, 4, 3), 0.5 + index, np.float32))
    trimesh.creation.icosphere(1).export(tmp_path / "ball.obj")
    scene = tmp_path / "seq.toml"
    scene.write_text('[mesh]\npath = "ball.obj"\n[environment]\npath = "day/*.npy"\n'
                     '[camera]\neye = [0, 0, 3]\ntarget = [0, 0, 0]\n')
    out = tmp_path / "out"
    config = RunConfig(out=out, scenes=(str(scene),), estimators=(temporal.name, "uniform"),
                       spp=(4,), seeds=2, resolution=(16, 16), progress=False)
    first = run(config)
    assert len(first) == 2 * 3 * 2
    # Drop frame 1 of seed 0 for both estimators, as if those cells had been lost.
    rows = [row for row in first.to_dict("records") if (row["frame"], row["seed"]) != (1, 0)]
    write_results(out, rows)
    temporal.log.clear()
    second = run(config).set_index(["estimator", "frame", "seed"]).sort_index()
    renders = [entry for entry in temporal.log if entry[1] != "reset" and entry[2] < 2]
    # The whole seed-0 sequence again, in frame order, on one fresh instance reset first (the
    # other renders are the warm-up's and the timing twins', on seeds no cell uses).
    assert [(frame, seed) for _, frame, seed in renders] == [(0, 0), (1, 0), (2, 0)]
    instance = renders[0][0]
    assert {entry[0] for entry in renders} == {instance}
    assert temporal.log.index((instance, "reset")) < temporal.log.index(renders[0])
    before = first.set_index(["estimator", "frame", "seed"]).sort_index()
    changed = before.time_ms_host != second.time_ms_host
    assert sorted(changed[changed].index) == sorted([
        (temporal.name, 0, 0), (temporal.name, 1, 0), (temporal.name, 2, 0), ("uniform", 1, 0)])


# ---- equal time ---------------------------------------------------------------------------------


def test_equal_time_gives_the_slower_estimator_fewer_samples(tmp_path, capsys):
    out = tmp_path / "out"
    config = RunConfig(out=out, scenes=("sphere-sun",), estimators=("uniform", "balanced_mis"),
                       spp=(), time_budget_ms=(2.0,), seeds=1, resolution=(32, 32), env_res=16,
                       progress=False)
    table = run(config).set_index("estimator")
    assert (table.time_budget_ms == 2.0).all()
    assert table.spp["balanced_mis"] < table.spp["uniform"], table.spp
    manifest = json.loads((out / "manifest.json").read_text())
    budget = manifest["time_budget"]
    assert budget["budgets_ms"] == [2.0] and "build + sample + shade" in budget["measure"]
    fits = {entry["estimator"]: entry for entry in budget["calibrations"]}
    assert set(fits) == {"uniform", "balanced_mis"}
    for label, fit in fits.items():
        assert fit["chosen_spp"] == table.spp[label] and fit["budget_ms"] == 2.0
        assert fit["b_ms_per_spp"] > 0 and fit["a_ms"] >= 0
        assert fit["measured_ms"] <= 2.2 or fit["chosen_spp"] == 1
        assert {1, 4, 16, 64} <= {run["spp"] for run in fit["runs"]}
        # three renders per spp, more while they spread too wide (up to 3 × 3; harness/protocol/timing.py)
        assert all(3 <= len(run["device_ms"]) <= 9 for run in fit["runs"])
    assert fits["balanced_mis"]["b_ms_per_spp"] > fits["uniform"]["b_ms_per_spp"]
    # Resuming keeps the chosen spp and the recorded calibration.
    again = run(config).set_index("estimator")
    assert "resumed: 2 cells already done, 0 to run" in capsys.readouterr().err
    assert dict(again.spp) == dict(table.spp)
    resumed = json.loads((out / "manifest.json").read_text())["time_budget"]["calibrations"]
    assert {entry["estimator"] for entry in resumed if entry["resumed"]} == set(fits)


def test_cli_summary_reports_error_at_equal_time(tmp_path, tiny_config, capsys):
    out = tmp_path / "out"
    code = main(["run", "--config", str(tiny_config), "--spp", "4", "--seeds", "1",
                 "--time-budget-ms", "50", "--out", str(out), "--no-progress"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "error at equal time" in captured.out and "mean_delta_e76" in captured.out
    table = sorted_table(out)
    assert table.time_budget_ms.isna().sum() == 2 and (table.time_budget_ms == 50).sum() == 2


# ---- a damaged manifest (issue 23) ---------------------------------------------------------------

@pytest.mark.parametrize("text, why", [("[1, 2]", "not a JSON object"),
                                       ('{"created": "2026-', "not valid JSON")])
def test_a_damaged_manifest_stops_run_compare_and_check_and_is_kept(tmp_path, tiny_config, capsys,
                                                                    text, why):
    """Issue 23: a manifest that is JSON but not an object crashed `run` and `compare` with a
    traceback; a truncated one was replaced by `run` (the run history lost) and `check` passed."""
    out = tmp_path / "out"
    cli_run(capsys, tiny_config, out)
    manifest = out / "manifest.json"
    manifest.write_text(text)
    for argv in (["run", "--config", str(tiny_config), "--out", str(out), "--no-progress"],
                 ["compare", str(out), str(out)], ["check", str(out)]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(manifest) in err and why in err, (argv, err)
    assert manifest.read_text() == text


def test_a_damaged_estimate_image_is_rendered_again_on_resume(tmp_path, tiny_config, capsys):
    """Issue 23: resume counted a cell whose EXR was corrupt as done (and `report` then failed
    on the image)."""
    from iblbench.scenes.imageio import read_exr

    out = tmp_path / "out"
    table, _ = cli_run(capsys, tiny_config, out)
    image = out / "images" / "sphere-sun" / "f0" / "balanced_spp8_s1.exr"
    whole = read_exr(image)
    image.write_bytes(image.read_bytes()[: image.stat().st_size // 2])   # cut in half
    again, err = cli_run(capsys, tiny_config, out)
    assert f"resumed: {len(table) - 1} cells already done, 1 to run" in err, err
    assert np.array_equal(read_exr(image), whole)   # the same seed renders the same image
    pd.testing.assert_frame_equal(again[DETERMINISTIC_COLUMNS], table[DETERMINISTIC_COLUMNS])


def test_the_report_shows_no_image_where_an_estimate_is_damaged(tmp_path, tiny_config, capsys):
    """Issue 23: a corrupt estimate EXR failed the whole report; it shows "no image" there."""
    from iblbench.reports.report import write_report

    out = tmp_path / "out"
    cli_run(capsys, tiny_config, out)
    image = out / "images" / "sphere-sun" / "f0" / "balanced_spp8_s0.exr"
    image.write_bytes(image.read_bytes()[: image.stat().st_size // 2])
    html = write_report(out)["path"].read_text()
    assert "no image" in html and "balanced_spp8_s0.png" not in html
    assert "uniform_spp8_s0.png" in html
