"""Sweeps on a Dask cluster (issue 25): the same table as in process, bit for bit where it
should be; a worker killed mid-sweep; real ``dask scheduler`` / ``dask worker`` processes."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
import pytest

import iblbench
from iblbench.harness.protocol.distributed import chains
from iblbench.harness.protocol.results import (DETERMINISTIC_COLUMNS, KEY_COLUMNS, read_results,
                                               row_key, write_results)
from iblbench.harness.protocol.run_plan import RunConfig, plan_run, sequence_key
from iblbench.scenes.imageio import read_exr

pytestmark = pytest.mark.slow

# A switching map around its switch (the light comes on at frame 10; frames 8-9 and 10-11 are the
# same arrays, so a worker reuses a frame's cache), two temporal estimators whose state runs
# through the frames and a frame-by-frame one whose flicker links them; and a static scene.
SEQUENCE = """\
protocol = "lab-reinhard-v1"
scenes = ["sphere-switch", "sphere-sun"]
estimators = ["smc", "restir", "balanced_mis"]
spp = [4]
seeds = 3
frames = "8:12"
resolution = "20x20"
env_res = 16
metrics = ["de76", "relmse"]
"""


def sorted_rows(out: Path) -> pd.DataFrame:
    table = pd.read_parquet(out / "results.parquet")
    return table.sort_values(KEY_COLUMNS).reset_index(drop=True)


def assert_same_cells(out: Path, expected: Path) -> None:
    """Same keys, no duplicates, equal non-timing columns, bit-identical images."""
    table, reference = sorted_rows(out), sorted_rows(expected)
    assert not table.duplicated(KEY_COLUMNS).any()
    assert table[KEY_COLUMNS].equals(reference[KEY_COLUMNS])
    differing = [c for c in DETERMINISTIC_COLUMNS if not table[c].equals(reference[c])]
    assert not differing, differing
    images = sorted(p.relative_to(expected) for p in (expected / "images").rglob("*.exr"))
    assert images and images == sorted(p.relative_to(out) for p in (out / "images").rglob("*.exr"))
    for path in images:
        assert np.array_equal(read_exr(out / path), read_exr(expected / path)), path


def environment() -> dict:
    """The subprocesses' environment, read when they start: the session's private cache."""
    return dict(os.environ, PYTHONWARNINGS="ignore")


def run_cli(config: Path, out: Path, *flags: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "iblbench.cli", "run", "--config", str(config),
                             "--out", str(out), "--no-progress", *flags], env=environment(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def sequence_sweep(tmp_path_factory) -> tuple[Path, Path]:
    """(the sweep's config, its in-process run)."""
    folder = tmp_path_factory.mktemp("sequence")
    config = folder / "sequence.toml"
    config.write_text(SEQUENCE)
    process = run_cli(config, folder / "in-process")
    _, err = process.communicate(timeout=300)
    assert process.returncode == 0, err
    return config, folder / "in-process"


def test_units_are_cells_and_whole_sequences_in_the_in_process_order(tmp_path):
    config = RunConfig(out=tmp_path, scenes=("sphere-switch",), estimators=("smc", "uniform"),
                       spp=(4,), seeds=2, frames=slice(8, 11))
    plan = plan_run(config)
    todo = {("sphere-switch", label, 4, frame, seed, None)
            for label in ("smc", "uniform") for frame in (8, 9, 10) for seed in (0, 1)}
    found = chains(todo, plan)
    assert len(found) == 4 and sorted(k for units in found for unit in units for k in unit) \
        == sorted(todo)
    for units in found:
        keys = [k for unit in units for k in unit]
        assert len({sequence_key(k) for k in keys}) == 1
        assert [k[3] for k in keys] == [8, 9, 10]                    # frames in order
        # smc's state crosses frames: one unit; uniform's: one cell a unit
        assert [len(unit) for unit in units] == ([3] if keys[0][1] == "smc" else [1, 1, 1])
    assert [units[0][0][1:5:3] for units in found] == [("smc", 0), ("smc", 1), ("uniform", 0),
                                                       ("uniform", 1)]


def test_quick_on_two_workers_gives_the_in_process_table_and_report(tmp_path):
    """Acceptance: ``quick`` with ``--workers 2`` equals the in-process run in every non-timing
    column (the seeds are the cell's, so scheduling changes nothing), rows in the same order,
    each naming its host and device; given the same times, its report is the in-process one
    (every figure byte for byte, the page up to its manifest section)."""
    here_dir, there_dir = tmp_path / "run-in-process", tmp_path / "run-on-workers"
    here = iblbench.run(config="quick", out=here_dir, progress=False)
    there = iblbench.run(config="quick", out=there_dir, progress=False, workers=2)
    assert len(here) == len(there) == 192
    assert_same_cells(there_dir, here_dir)
    assert set(there.host) == {os.uname().nodename} and there.device.str.len().min() > 0
    manifest = json.loads((there_dir / "manifest.json").read_text())
    assert manifest["status"] == "complete" and len(manifest["workers"]) == 2
    assert len(manifest["timing"]["floor"]["groups_within"]) == 2   # one floor per worker

    table = pd.read_parquet(here_dir / "results.parquet")
    theirs = pd.read_parquet(there_dir / "results.parquet")
    assert theirs[KEY_COLUMNS].equals(table[KEY_COLUMNS])          # the in-process row order
    times = [column for column in table if column.startswith("time_")]
    theirs[times] = table[times]
    write_results(there_dir, theirs.to_dict("records"))
    # Likewise the machine's state, which the page's busy-machine sentence reads.
    mine = json.loads((here_dir / "manifest.json").read_text())
    manifest["timing"].update({k: mine["timing"].get(k) for k in ("load", "floor")})
    (there_dir / "manifest.json").write_text(json.dumps(manifest))
    pages = {}
    for name, folder in (("here", here_dir), ("there", there_dir)):
        pages[name] = iblbench.report(folder).read_text().replace(folder.name, "RUN")
    assert pages["there"].split("<h2>Manifest</h2>")[0] == pages["here"].split(
        "<h2>Manifest</h2>")[0]
    figures = sorted(p.relative_to(here_dir) for p in
                     (here_dir / "report").rglob("*.png"))
    assert len(figures) > 10
    for figure in figures:
        assert (there_dir / figure).read_bytes() == (here_dir / figure).read_bytes()


def test_temporal_sequences_through_workers_are_bit_identical(sequence_sweep, tmp_path):
    """smc's and restir's whole sequences on one worker each, balanced_mis's frames as chained
    cells: images, errors and flicker equal the in-process run's bit for bit."""
    config, expected = sequence_sweep
    process = run_cli(config, tmp_path / "workers", "--workers", "2")
    _, err = process.communicate(timeout=300)
    assert process.returncode == 0, err
    assert_same_cells(tmp_path / "workers", expected)
    flicker = sorted_rows(tmp_path / "workers").query("frame > 8").flicker
    assert flicker.notna().all() and (flicker > 0).all()


def _spawned_workers(client: psutil.Process) -> list[psutil.Process]:
    return [p for p in client.children(recursive=True)
            if "spawn_main" in " ".join(p.cmdline())]


def test_a_worker_killed_mid_sweep_is_survived(sequence_sweep, tmp_path):
    """SIGKILL one worker process once cells are coming in: Dask reruns its unit elsewhere (a
    temporal one from its first frame), and the table ends complete, without duplicates, equal
    to the in-process run."""
    config, expected = sequence_sweep
    out = tmp_path / "killed"
    process = run_cli(config, out, "--workers", "2")
    deadline = time.monotonic() + 240
    while len(read_results(out)) < 4:
        assert process.poll() is None, process.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    workers = _spawned_workers(psutil.Process(process.pid))
    assert len(workers) == 2
    workers[0].send_signal(signal.SIGKILL)
    _, err = process.communicate(timeout=300)
    assert process.returncode == 0, err   # one death is within allowed-failures: rerun, not lost
    rows = read_results(out)
    assert len({row_key(row) for row in rows}) == len(rows)
    assert_same_cells(out, expected)


def test_equal_time_budgets_on_workers(tmp_path):
    """A budget's first chain calibrates it; every other cell of that budget, on either worker,
    takes the spp it chose; each budget is calibrated once."""
    config = tmp_path / "budget.toml"
    config.write_text(SEQUENCE.replace("spp = [4]", "spp = []\ntime_budget_ms = [1.0, 3.0]")
                      .replace('["sphere-switch", "sphere-sun"]', '["sphere-sun"]')
                      .replace('["smc", "restir", "balanced_mis"]', '["uniform", "restir"]'))
    process = run_cli(config, tmp_path / "out", "--workers", "2")
    _, err = process.communicate(timeout=300)
    assert process.returncode == 0, err
    table = sorted_rows(tmp_path / "out")
    assert len(table) == 2 * 2 * 3
    assert (table.groupby(["estimator", "time_budget_ms"]).spp.nunique() == 1).all()
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    calibrated = sorted((c["estimator"], c["budget_ms"], c["chosen_spp"])
                        for c in manifest["time_budget"]["calibrations"])
    chosen = table.groupby(["estimator", "time_budget_ms"]).spp.first()
    assert calibrated == sorted((label, budget, spp) for (label, budget), spp in chosen.items())
    assert {entry["device"] for entry in manifest["time_budget"]["achieved"]} == set(table.device)


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_a_scheduler_and_two_workers_started_by_hand(sequence_sweep, tmp_path):
    """The README's walk-through with real processes: ``dask scheduler``, two ``dask worker
    ADDRESS``, then ``iblbench run --scheduler ADDRESS``; the run names the dashboard."""
    config, expected = sequence_sweep
    dask = Path(sys.executable).parent / "dask"
    address = f"tcp://127.0.0.1:{_free_port()}"
    started = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port",
                                 address.rsplit(":", 1)[1], "--dashboard-address", ":0"],
                                env=environment(), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)]
    try:
        started += [subprocess.Popen([dask, "worker", address, "--nthreads", "1"],
                                     env=environment(), cwd=tmp_path, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL) for _ in range(2)]
        process = run_cli(config, tmp_path / "cluster", "--scheduler", address)
        _, err = process.communicate(timeout=300)
        assert process.returncode == 0, err
        assert "Dask workers on" in err and "dashboard http://" in err
    finally:
        for child in started:
            child.terminate()
        for child in started:
            child.wait(timeout=30)
    assert_same_cells(tmp_path / "cluster", expected)
    workers = json.loads((tmp_path / "cluster" / "manifest.json").read_text())["workers"]
    assert len(workers) == 2


def test_a_scheduler_that_does_not_answer_is_one_line_and_writes_nothing(tmp_path):
    process = run_cli(Path("quick"), tmp_path / "out", "--scheduler",
                      f"tcp://127.0.0.1:{_free_port()}")
    _, err = process.communicate(timeout=120)
    assert process.returncode == 2 and "no Dask scheduler answers there" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "out").exists()
