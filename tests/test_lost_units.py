"""Units lost with killed Dask workers (issue 36, class 3): whatever the point a worker dies at
and however many deaths a unit is allowed, a run ends with every cell in its table, or
"incomplete" (manifest) with an InputError (exit 2) that counts the cells it lacks; never
"complete" with a cell missing.

The runner and :class:`~iblbench.harness.protocol.distributed.Cluster` run as they do on a
cluster; below them, :class:`FakeDask` stands for Dask's client and scheduler, in this process
and in a chosen order, and :func:`stand_in` for the workers'
:func:`~iblbench.harness.protocol.distributed.render_unit` (a row per cell, nothing rendered).
Target units die at the point each attempt's script says:

- ``before``: a worker dies as the unit starts, nothing done;
- ``mid``: it dies with the unit's work done, before the unit returns;
- ``after``: it dies once the unit has returned, before the client gathers the result;
- ``retry``: ``mid``, then ``before`` on the rerun.

:class:`FakeDask` answers as Dask's scheduler does (``distributed.scheduler.allowed-failures``,
https://distributed.dask.org/en/stable/killed.html): a death while a unit is processing
(before, mid) counts against the allowance and reruns it on another worker, the death past the
allowance ends its future with ``KilledWorker``; a result lost with the worker that held it
(after) is recomputed without counting.  A target unit is so lost exactly when its script has
more running deaths than the allowance.  The targets: the unit that calibrates an equal-time
budget (the other chains of that budget wait for it), a temporal estimator's whole sequence,
and the second unit of a frame-by-frame chain.
"""
from __future__ import annotations

import contextlib
import itertools
import types

import pytest
from distributed.scheduler import KilledWorker

from iblbench.cli import main
from iblbench.foundation.errors import InputError
from iblbench.harness.protocol import distributed
from iblbench.harness.protocol.distributed import Cluster, UnitResult
from iblbench.harness.protocol.results import read_manifest, read_results, row_key
from iblbench.harness.protocol.run_plan import RunConfig, plan_run, sequences
from iblbench.harness.protocol.runner import Runner
from iblbench.harness.protocol.timing import TimingFloor

SCRIPTS = {"before": ("before",), "mid": ("mid",), "after": ("after",),
           "retry": ("mid", "before")}
RUNNING_DEATHS = ("before", "mid")     # the deaths Dask counts against the allowance
CALIBRATED_SPP = 8                     # the spp the stand-in "calibrates" a budget at
SCENE = "sphere-switch"
TARGETS = frozenset({
    (SCENE, "uniform", None, 8, 0, 1.0),   # calibrates the 1 ms budget; its other chains wait
    (SCENE, "smc", 4, 8, 0, None),         # a temporal sequence: one unit, frames 8 and 9
    (SCENE, "uniform", 4, 9, 1, None),     # a frame-by-frame chain's second unit
})
WORKER = {"address": "tcp://worker:1", "record": {"name": "Fake device", "host": "h"},
          "device": "Fake device",
          "floor": TimingFloor(launches=40, median_ms=0.1, groups_within=1.0, p90_over_p10=1.1)}
SWEEP = dict(scenes=(SCENE,), estimators=("uniform", "smc"), spp=(4,), time_budget_ms=(1.0,),
             seeds=2, frames=slice(8, 10), resolution=(16, 16), env_res=8, progress=False)


def stand_in(run_id, config, keys, chosen, maps, drop: bool = False) -> UnitResult:
    """render_unit's stand-in: a row per cell (an uncalibrated budget takes CALIBRATED_SPP);
    ``drop``: the unit's last row left out."""
    budget = None if keys[0][5] is None else (keys[0][0], keys[0][1], keys[0][5])
    spp = chosen.get(budget, CALIBRATED_SPP) if budget else keys[0][2]
    rows = [{"scene": key[0], "estimator": key[1], "spp": spp, "frame": key[3], "seed": key[4],
             "time_budget_ms": key[5] or float("nan"), "time_ms": 1.0,
             "time_ms_renders": "1 1 1", "device": WORKER["device"]} for key in keys]
    return UnitResult(rows=rows[:-1] if drop else rows, maps={},
                      chosen={budget: spp} if budget else {},
                      records={"stages": [], "skipped": [], "calibrations": [],
                               "device_ms": 0.0, "spread": {"cells": 0, "wide_cells": 0},
                               "warnings": []},
                      seconds={key: 0.01 for key in keys}, worker=WORKER)


class FakeFuture:
    def __init__(self, key: str, run):
        self.key, self.run = key, run    # run(): the unit's outcome, a result or an exception

    def result(self):
        outcome = self.run()
        if isinstance(outcome, BaseException):
            raise outcome
        return outcome

    def cancel(self) -> None:
        pass


class FakeDask:
    """Dask's client (``run``, ``scheduler_info``, ``submit``) and ``as_completed`` as
    Cluster.render uses them; units finish in submission order, or the latest first
    (``newest_first``), and die as ``script`` says (module docstring)."""

    def __init__(self, script: tuple, allowance: int, newest_first: bool = False, task=stand_in):
        self.script, self.allowance, self.newest_first, self.task = (script, allowance,
                                                                     newest_first, task)
        self.queue: list[FakeFuture] = []

    def run(self, function) -> dict:
        return {WORKER["address"]: WORKER}

    def scheduler_info(self) -> dict:
        return {"workers": {WORKER["address"]: {}}}

    def submit(self, task, *args, key, **options) -> FakeFuture:
        assert task is self.task
        return FakeFuture(key, lambda: self.outcome(key, args))

    def outcome(self, key: str, args):
        """What the client gets for a unit: its result, or KilledWorker once its deaths while
        processing pass the allowance."""
        keys, deaths = args[2], 0
        for attempt in itertools.count():
            point = (self.script[attempt] if keys[0] in TARGETS and attempt < len(self.script)
                     else None)
            if point == "mid":
                self.task(*args)            # its work done; the worker dies before returning
            if point in RUNNING_DEATHS:
                deaths += 1
                if deaths > self.allowance:
                    return KilledWorker(key, types.SimpleNamespace(address="tcp://dead:1"),
                                        self.allowance)
                continue
            result = self.task(*args)
            if point != "after":            # after: lost from the dead worker's memory, rerun
                return result

    def as_completed(self):
        return self

    def add(self, future: FakeFuture) -> None:
        self.queue.append(future)

    def __iter__(self):
        while self.queue:
            yield self.queue.pop(-1 if self.newest_first else 0)


class Recording(Cluster):
    """The cluster, keeping the keys its render said were lost."""

    def render(self, *args):
        self.lost = super().render(*args)
        return self.lost


def _on_fake_dask(monkeypatch, fake: FakeDask) -> Recording:
    """The runner's cluster: a Cluster over ``fake``."""
    engine = Recording(fake, task=fake.task)
    monkeypatch.setattr("distributed.as_completed", fake.as_completed)
    monkeypatch.setattr(distributed, "cluster", lambda _: contextlib.nullcontext(engine))
    return engine


def _outcome(config: RunConfig) -> tuple[set, set, str, str | None]:
    """(the sweep's cells, the cells in its table, its manifest's status, the run's error)."""
    try:
        Runner(config).run()
        error = None
    except InputError as raised:
        error = str(raised)
    rows = read_results(config.out)
    present = {row_key(row) for row in rows}
    assert len(present) == len(rows)                      # no cell twice
    cells = {key for _, _, keys in sequences(plan_run(config), config) for key in keys}
    return cells, present, read_manifest(config.out)["status"], error


def _assert_complete_or_incomplete(cells: set, present: set, status: str, error, out) -> set:
    """Every cell present and "complete", or "incomplete" with an error that counts the cells
    missing; returns them."""
    missing = cells - present
    assert present <= cells
    if missing:
        assert status == "incomplete" and error is not None, (status, error)
        assert error.startswith(f"{out}: {len(missing)} cells were lost"), error
    else:
        assert status == "complete" and error is None, (status, error)
    return missing


@pytest.mark.parametrize("newest_first", [False, True], ids=["in-order", "newest-first"])
@pytest.mark.parametrize("allowance", [0, 1, 3])
@pytest.mark.parametrize("point", list(SCRIPTS))
def test_a_run_that_lost_cells_never_ends_complete(tmp_path, monkeypatch, point, allowance,
                                                   newest_first):
    engine = _on_fake_dask(monkeypatch, FakeDask(SCRIPTS[point], allowance, newest_first))
    config = RunConfig(out=tmp_path / "out", workers=2, **SWEEP)
    cells, present, status, error = _outcome(config)
    missing = _assert_complete_or_incomplete(cells, present, status, error, config.out)
    # The cluster's own count is exact: the cells it lost are the cells missing, each once.
    assert sorted(map(repr, engine.lost)) == sorted(map(repr, missing))
    deaths = sum(step in RUNNING_DEATHS for step in SCRIPTS[point])
    expected = set()
    if deaths > allowance:   # a lost unit takes the rest of its chain with it
        expected = TARGETS | {(SCENE, "uniform", None, 9, 0, 1.0), (SCENE, "smc", 4, 9, 0, None)}
    assert missing == expected, (deaths, allowance)


def test_a_unit_that_returns_without_a_cell_s_row_leaves_the_run_incomplete(tmp_path,
                                                                            monkeypatch):
    """The runner counts the cells its journal lacks, not only those the cluster says it lost:
    a unit that came back short (no worker died) still leaves the run incomplete, exit 2."""
    def short(run_id, config, keys, chosen, maps):
        return stand_in(run_id, config, keys, chosen, maps, drop=keys[0] in TARGETS)

    engine = _on_fake_dask(monkeypatch, FakeDask((), allowance=3, task=short))
    out = tmp_path / "out"
    status = main(["run", "--out", str(out), "--workers", "2", "--scene", SCENE,
                   "--estimator", "uniform", "--estimator", "smc", "--spp", "4",
                   "--time-budget-ms", "1", "--seeds", "2", "--frames", "8:10", "--res", "16x16",
                   "--env-res", "8", "--no-progress"])
    assert status == 2 and engine.lost == []
    assert read_manifest(out)["status"] == "incomplete"
    present = {row_key(row) for row in read_results(out)}
    # each target unit's last cell: the calibrating one's, smc's frame 9, the chain's frame 9
    assert {(SCENE, "uniform", None, 8, 0, 1.0), (SCENE, "smc", 4, 9, 0, None),
            (SCENE, "uniform", 4, 9, 1, None)}.isdisjoint(present)
    assert len(present) == 16 - 3
