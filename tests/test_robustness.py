"""Defects hostile testing found (issue 11, 1-6): concurrent runs, a reused --out, spp bounds, a
full disk, Ctrl-C, a damaged journal."""
from __future__ import annotations

import errno
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import OpenEXR
import pandas as pd
import pytest

from iblbench.harness.protocol import runner as runner_module
from iblbench.cli import EXIT_DISK_FULL, main
from iblbench.harness.protocol.results import (JOURNAL, Journal, read_journal, read_results,
                                               write_results)
from iblbench.harness.protocol.runner import LOCK, RunConfig, Runner, _locked, run
from iblbench.foundation.errors import InputError

SMALL = dict(scenes=("sphere-sun",), estimators=("uniform",), seeds=1, resolution=(16, 16),
             env_res=8, repeats=1, metrics=("de76",), progress=False)
FLAGS = ["--scene", "sphere-sun", "--estimator", "uniform", "--seeds", "1", "--res", "16x16",
         "--env-res", "8", "--repeats", "1", "--metrics", "de76", "--no-progress"]


def cli(capsys, out: Path, *flags: str) -> tuple[int, str]:
    code = main(["run", "--out", str(out), *FLAGS, *flags])
    return code, capsys.readouterr().err


def subprocess_env() -> dict:
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    env.pop("IBLBENCH_DEVICE", None)
    return env


# ---- 1. concurrent runs ----------------------------------------------------------------------


def test_a_run_made_before_another_finished_keeps_that_runs_cells(tmp_path):
    """Run A is set up, run B finishes into the same folder, then A runs: B's cells stay."""
    out = tmp_path / "out"
    first = Runner(RunConfig(out=out, spp=(4,), **SMALL))
    run(RunConfig(out=out, spp=(8,), **SMALL))
    first.run()
    table = pd.read_parquet(out / "results.parquet")
    assert sorted(table.spp) == [4, 8]


def test_the_lock_file_outlives_a_run_so_no_two_runs_hold_it(tmp_path):
    """A run that opened the lock file before another released it, then locks it, must still
    exclude a third (it did not when the release unlinked the file: the third made a new one)."""
    out = tmp_path / "out"
    out.mkdir()
    with open(out / LOCK, "a") as early:
        run(RunConfig(out=out, spp=(4,), **SMALL))
        fcntl.flock(early, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(InputError, match="another iblbench run is writing"):
            with _locked(out):
                pass


# ---- 2. a reused --out -----------------------------------------------------------------------


def test_another_resolution_in_a_used_out_is_refused_and_force_replaces(tmp_path, capsys):
    out = tmp_path / "out"
    assert cli(capsys, out, "--spp", "4,8")[0] == 0
    before = pd.read_parquet(out / "results.parquet")
    code, err = cli(capsys, out, "--spp", "4", "--res", "20x12", "--env-res", "6")
    assert code == 2 and err.count("\n") == 1, err
    assert "--res 16x16 (now 20x12)" in err and "--env-res 8 (now 6)" in err and "--force" in err
    pd.testing.assert_frame_equal(pd.read_parquet(out / "results.parquet"), before)
    code, err = cli(capsys, out, "--spp", "4", "--res", "20x12", "--force")
    assert code == 0, err
    table = pd.read_parquet(out / "results.parquet")
    assert list(zip(table.spp, table.width, table.height)) == [(4, 20, 12)]


def test_a_ctrl_c_after_force_removed_the_other_cells_leaves_no_row_without_its_image(
        tmp_path, capsys, monkeypatch):
    """``force`` removed the other configuration's images before the run's first fold dropped
    their rows: a Ctrl-C in between (planning, tracing) left rows whose images were gone."""
    out = tmp_path / "out"
    assert cli(capsys, out, "--spp", "4,8")[0] == 0

    def interrupted(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(Runner, "_new_manifest", interrupted)   # after the removal, before the fold
    code, err = cli(capsys, out, "--spp", "4", "--res", "20x12", "--force")
    assert code == 130, err
    assert not any(path.exists() for path in (out / "images").rglob("*.exr")), \
        "the removal had not run: the test no longer reaches the window"
    assert read_results(out) == []


def test_the_manifest_lists_every_sweep_that_shares_the_table(tmp_path, capsys):
    out = tmp_path / "out"
    assert cli(capsys, out, "--spp", "4")[0] == 0
    assert cli(capsys, out, "--spp", "8")[0] == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert [entry["config"]["spp"] for entry in manifest["runs"]] == [[4], [8]]
    assert len(pd.read_parquet(out / "results.parquet")) == 2


# ---- 3. spp bounds ---------------------------------------------------------------------------


def test_spp_above_an_estimators_bound_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "out"
    code, err = cli(capsys, out, "--spp", "4,40000")
    assert code == 2 and err.count("\n") == 1, err
    assert "--spp 40000" in err and "uniform" in err and "32767" in err
    assert not out.exists()


# ---- 4. a full disk --------------------------------------------------------------------------


def _no_space(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "somewhere.png")


def _pyarrow_no_space(*args, **kwargs):   # pyarrow's IO errors carry the message, no errno
    raise OSError("error writing to file: No space left on device")


@pytest.mark.parametrize("target, replacement", [
    ((OpenEXR, "File"), _no_space),                        # write_exr makes it an InputError
    ((pd.DataFrame, "to_parquet"), _pyarrow_no_space),
    ((runner_module, "write_manifest"), _no_space),
])
def test_a_full_disk_is_one_line_and_its_own_exit_code(tmp_path, capsys, monkeypatch, target,
                                                       replacement):
    monkeypatch.setattr(*target, replacement)
    code, err = cli(capsys, tmp_path / "out", "--spp", "4")
    assert code == EXIT_DISK_FULL != 2
    assert err.count("\n") == 1 and "no space left on device" in err, err


def test_a_full_disk_leaves_the_manifest_failed_not_running(tmp_path, capsys, monkeypatch):
    """Issue 35: a run that filled the disk left its manifest saying "running"."""
    monkeypatch.setattr(OpenEXR, "File", _no_space)
    code, _ = cli(capsys, tmp_path / "out", "--spp", "4")
    assert code == EXIT_DISK_FULL
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["status"] == "failed", manifest["status"]
    assert os.strerror(errno.ENOSPC) in manifest["failure"], manifest["failure"]


def test_a_journal_line_a_full_disk_cut_short_is_taken_back(tmp_path, monkeypatch):
    """A full disk can take part of a write without an error; the next line, glued to that part
    once space was freed, was a damaged line mid-journal, which stops every reader."""
    journal, real_write = Journal(tmp_path), os.write
    rows = [dict(scene="sphere-sun", estimator="uniform", spp=spp, frame=0, seed=0)
            for spp in (1, 2, 3)]
    journal.append(rows[0])
    monkeypatch.setattr(os, "write", lambda fd, data: real_write(fd, data[:len(data) // 2]))
    with pytest.raises(OSError) as raised:
        journal.append(rows[1])
    assert raised.value.errno == errno.ENOSPC
    monkeypatch.setattr(os, "write", real_write)
    journal.append(rows[2])
    journal.close()
    lines = (tmp_path / JOURNAL).read_text().splitlines()
    assert [json.loads(line)["spp"] for line in lines] == [1, 3]


def test_a_full_disk_under_a_ctrl_c_save_leaves_the_manifest_failed(tmp_path, capsys, monkeypatch):
    """The save a Ctrl-C makes folds the table; a full disk there left the manifest "running"."""
    def interrupted(journal, row):
        raise KeyboardInterrupt

    folds = []

    def full_after_the_first_fold(*args):   # the first is the fold at the run's start
        folds.append(args)
        if len(folds) > 1:
            _pyarrow_no_space()
        return write_results(*args)

    monkeypatch.setattr(Journal, "append", interrupted)
    monkeypatch.setattr(runner_module, "write_results", full_after_the_first_fold)
    code, err = cli(capsys, tmp_path / "out", "--spp", "4")
    assert code == EXIT_DISK_FULL and err.count("\n") == 1, err
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["status"] == "failed", manifest["status"]


def test_a_full_disk_under_report_names_the_run_and_promises_no_resume(tmp_path, capsys, monkeypatch):
    """Issue 23: `report` on a full disk named no path and said "a run resumes"."""
    import iblbench.reports.report as report_module
    from iblbench.cli import main

    monkeypatch.setattr(report_module, "write_report", _pyarrow_no_space)
    code = main(["report", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == EXIT_DISK_FULL and err.count("\n") == 1, err
    assert str(tmp_path / "run") in err and "resume" not in err, err


# ---- 5. Ctrl-C -------------------------------------------------------------------------------


# `iblbench run` whose run stops after its second journalled cell until a signal comes.  A frame's
# cells are journalled in one burst after its renders, so a Ctrl-C sent on seeing two rows could
# land after the last (it did on CI: 32 of 32 saved); here it always lands with 30 cells to run.
RUN_THAT_WAITS_AFTER_TWO_CELLS = """
import sys, time
from iblbench.cli import main
from iblbench.harness.protocol.runner import Runner

journal_cell = Runner._journal_cell

def journal_then_wait(self, row):
    journal_cell(self, row)
    if len(self.journalled) == 2:
        time.sleep(120)

Runner._journal_cell = journal_then_wait
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_saves_the_finished_cells_and_releases_the_folder(tmp_path):
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-c", RUN_THAT_WAITS_AFTER_TWO_CELLS, "run", "--out", str(out), *FLAGS,
         "--spp", "1,2,3,4,5,6,7,8", "--seeds", "4"],
        env=subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while len(read_results(out)) < 2:   # the table too: a fold may have taken the journal
            assert process.poll() is None, process.stderr.read()
            assert time.monotonic() < deadline
            time.sleep(0.005)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 130, stderr
    table = pd.read_parquet(out / "results.parquet")
    assert len(table) == 2, stderr
    assert "2 cells saved; rerun to resume" in stderr and "Traceback" not in stderr
    assert not (out / JOURNAL).exists()
    assert json.loads((out / "manifest.json").read_text())["status"] == "interrupted"
    with open(out / LOCK, "a") as handle:          # released: this would fail while held
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)


def test_ctrl_c_before_the_first_cell_marks_the_manifest_interrupted(tmp_path, monkeypatch, capsys):
    """Issue 23: a Ctrl-C in the timing floor (or a warm-up) before the first cell left the
    manifest "running"."""
    def interrupted(compute):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner_module, "measure_timing_floor", interrupted)
    code, err = cli(capsys, tmp_path / "out", "--spp", "4")
    assert code == 130 and "0 cells saved" in err, err
    assert json.loads((tmp_path / "out" / "manifest.json").read_text())["status"] == "interrupted"


def test_a_ctrl_c_just_after_a_cell_is_journalled_keeps_that_cell(tmp_path, monkeypatch, capsys):
    """The fold rewrites the table from the runner's rows and then drops the journal; a Ctrl-C
    after the journal's write of a cell but before the runner recorded it lost that cell."""
    append, appended = Journal.append, []

    def append_then_interrupt_at_the_second(journal, row):
        append(journal, row)
        appended.append(row)
        if len(appended) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(Journal, "append", append_then_interrupt_at_the_second)
    code, err = cli(capsys, tmp_path / "out", "--spp", "1,2,3,4")
    assert code == 130 and "2 cells saved" in err, err
    assert sorted(pd.read_parquet(tmp_path / "out" / "results.parquet").spp) == sorted(
        row["spp"] for row in appended)


def test_a_ctrl_c_right_after_the_journal_is_closed_does_not_close_it_again(tmp_path, monkeypatch):
    """A Ctrl-C just after close(2) in a fold left the closed descriptor to the Ctrl-C's own
    fold, which fsynced it again (EBADF: a traceback, the manifest left "running")."""
    journal, real_close = Journal(tmp_path), os.close
    journal.append(dict(scene="sphere-sun", estimator="uniform", spp=1, frame=0, seed=0))

    def close_then_interrupt(fd):
        real_close(fd)
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "close", close_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        journal.close()
    monkeypatch.setattr(os, "close", real_close)
    journal.close()
    assert len((tmp_path / JOURNAL).read_text().splitlines()) == 1


# Stands in for the linker PoCL runs per kernel: its Nth run sends SIGINT to its process group
# (the run's, started in a session of its own), as a Ctrl-C in the terminal does mid-link.
FAKE_LD = """#!/bin/sh
n=$(($(cat "$LINKS" 2>/dev/null || echo 0) + 1)); echo $n > "$LINKS"
[ "$n" = "$SIGINT_AT_LINK" ] && kill -INT 0
exec "$REAL_LD" "$@"
"""


@pytest.mark.parametrize("link, stderr_read", [(1, True), (3, False)],
                         ids=["timing-floor", "warm-up-stderr-closed"])
def test_ctrl_c_while_pocl_links_a_kernel_ends_interrupted_not_aborted(tmp_path, link, stderr_read):
    """Issue 23: a Ctrl-C while PoCL compiled and linked the first kernels killed its linker
    too; PoCL then aborted the run (exit 134; LLVM's "IO failure on output stream" where the
    reader of stderr had died too) and left the manifest "running".  Link 1 is the timing
    floor's kernel (before the first cell), link 3 a warm-up's, with stderr's reader gone."""
    real_ld = shutil.which("ld")
    if real_ld is None:
        pytest.skip("no ld on PATH")
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "ld").write_text(FAKE_LD)
    (fake / "ld").chmod(0o755)
    out, links = tmp_path / "out", tmp_path / "links"
    cache = dict(IBLBENCH_CACHE=str(tmp_path / "cache"))
    # With two CPU drivers (Debian's PoCL and the pip one), choosing between them measures each
    # device's speed first, a kernel link each, before the run starts (a Ctrl-C there leaves no
    # folder at all): measured here, so that link 1 is the timing floor's on every machine.
    subprocess.run([sys.executable, "-m", "iblbench.cli", "list", "devices"], check=True,
                   env=dict(subprocess_env(), **cache), capture_output=True, timeout=300)
    env = dict(subprocess_env(), PATH=f"{fake}{os.pathsep}{os.environ['PATH']}", REAL_LD=real_ld,
               LINKS=str(links), SIGINT_AT_LINK=str(link), PYOPENCL_NO_CACHE="1",
               POCL_CACHE_DIR=str(tmp_path / "pocl"), **cache)
    process = subprocess.Popen(
        [sys.executable, "-m", "iblbench.cli", "run", "--out", str(out), *FLAGS, "--spp", "4"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        start_new_session=True)
    if stderr_read:
        stderr = process.communicate(timeout=120)[1]
    else:
        process.stderr.close()
        stderr = "(closed)"
        process.wait(timeout=120)
    if not links.exists():
        pytest.skip("this OpenCL driver runs no ld from PATH")
    assert int(links.read_text()) >= link, "the run ended before that link"
    assert process.returncode == 130, stderr
    assert json.loads((out / "manifest.json").read_text())["status"] == "interrupted"
    assert "Final linking" not in stderr and "IO failure" not in stderr, stderr


REFERENCE_SCRIPT = """
import sys
from iblbench.estimators.runtime.device import get_compute
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.scenes.gbuffer import trace_gbuffer
from iblbench.scenes.registry import load_scene

compute = get_compute()
scene = load_scene("sphere-sun", env_res=64)
cache = FrameCache(compute, scene.environment.frame(0), 0)
reference = Reference(compute, use_cache=False)
for size in (8, 320):   # the first compiles; the second takes seconds (160² took 0.86 s idle)
    gbuffer = trace_gbuffer(scene.mesh, scene.material, scene.camera, size, size)
    print("computing", flush=True)
    reference.image(DeviceGBuffer(compute, gbuffer), cache)
print("finished", flush=True)
"""


def test_ctrl_c_stops_a_long_reference_within_seconds(tmp_path):
    process = subprocess.Popen([sys.executable, "-c", REFERENCE_SCRIPT], env=subprocess_env(),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for _ in range(2):
        assert process.stdout.readline() == "computing\n", process.stderr.read()
    time.sleep(1.0)
    process.send_signal(signal.SIGINT)
    sent = time.monotonic()
    stdout, stderr = process.communicate(timeout=60)
    waited = time.monotonic() - sent
    assert "finished" not in stdout, "the reference ended before the signal; make it larger"
    assert "KeyboardInterrupt" in stderr
    assert waited < 2.0, f"{waited:.1f} s from SIGINT to exit"


# ---- 6. a damaged journal --------------------------------------------------------------------


def test_journal_lines_of_valid_json_but_wrong_content_are_skipped_and_counted(tmp_path, capsys):
    out = tmp_path / "out"
    assert cli(capsys, out, "--spp", "4,8")[0] == 0
    good = read_results(out)[0]
    lines = [json.dumps(row) for row in (
        {"scene": "sphere-sun"},                                  # keys missing
        dict(good, spp="4"),                                      # a key of the wrong type
        dict(good, mean_delta_e76="small"),                       # a metric of the wrong type
        [1, 2, 3],                                                # not an object
    )]
    (out / JOURNAL).write_text("\n".join(lines + [json.dumps(good)]) + "\n")
    assert len(read_journal(out)) == 1
    assert "skipped 4 damaged lines" in capsys.readouterr().err
    code, err = cli(capsys, out, "--spp", "4,8")
    assert code == 0 and "skipped 4 damaged lines" in err, err
    assert "resumed: 2 cells already done, 0 to run" in err
    assert len(pd.read_parquet(out / "results.parquet")) == 2


def test_a_resume_redraws_cells_whose_images_were_deleted(tmp_path, capsys):
    out = tmp_path / "out"
    assert cli(capsys, out, "--spp", "4,8")[0] == 0
    shutil.rmtree(out / "images")
    code, err = cli(capsys, out, "--spp", "4,8")
    assert code == 0 and "resumed" not in err, err
    stems = sorted(p.name for p in (out / "images" / "sphere-sun" / "f0").iterdir())
    assert stems == sorted(["reference.exr"] + [f"uniform_spp{n}_s0.exr" for n in (4, 8)])
