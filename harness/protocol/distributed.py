"""A sweep's cells on a Dask cluster (``iblbench run --workers N`` or ``--scheduler ADDRESS``).

Dask distributed schedules; iblbench only says what a unit of work is and keeps its one writer.

- **Units.** A frame-by-frame estimator's unit is one cell (scene, estimator, spp, frame, seed,
  budget).  A temporal estimator's is the whole frame sequence of one (scene, estimator, spp,
  budget, seed): its state never leaves one worker (ARCHITECTURE.md §Results and units of work).  The cells of one sequence key
  form a *chain*, submitted one unit after the other, so that the client can hand a frame's ΔE76
  map to the next frame's cell (flicker is then the in-process value, bit for bit).  Chains run
  side by side; an equal-time budget's chains wait for its first one, which calibrates the spp
  they all take (the runner's "Equal time").
- **Workers** are long-lived processes, started with spawn, never fork: an OpenCL context does
  not survive a fork, and pyopencl objects do not pickle.  :class:`OpenCLWorker`, a Dask
  ``WorkerPlugin``, makes each worker's context at its start on the device ``--device`` names
  (or the worker's ``IBLBENCH_DEVICE``, or the default choice), measures its timing floor, and
  keeps one :class:`~iblbench.harness.protocol.executor.Executor` per run, which renders one
  unit at a time (a worker given several threads runs its units one after the other).  Workers
  that own a GPU declare the resource ``GPU=1`` (``dask worker --resources GPU=1``); where any
  worker declares it, every unit is submitted with ``resources={"GPU": 1}``.  A LocalCluster's
  workers share this machine's one device and declare nothing.  The plugin points the workers
  at the client's on-disk cache (G-buffers, visibility, references, programs, each written by
  atomic rename under a content hash, so concurrent writers are safe), which must be on a
  filesystem they share, as the run's folder must be: workers write the cells' images there.
- **One writer.** Workers return rows; only the client journals them and folds the table
  (:mod:`.results`).  A killed worker's unit is rerun by Dask on another worker; a unit that
  kills ``distributed.scheduler.allowed-failures`` workers is lost with the rest of its chain
  (their flicker needs it), and the run ends "incomplete" (a rerun resumes them).  A killed
  client loses the units in flight; with ``--scheduler``, units already running may still
  write their images into the run's folder, which the next run replaces.
- **Seeds and time.** A cell's seeds come from its key, so no result depends on scheduling.
  Time columns are the worker's device's, and each row names its ``host`` and ``device``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import itertools
import logging
import os
import pathlib
import sys
import threading
import uuid

from distributed import WorkerPlugin

from iblbench.estimators.runtime.device import cache_dir, get_compute
from iblbench.harness.protocol.executor import CellClock, Executor, device_record
from iblbench.harness.protocol.run_plan import (RunConfig, RunPlan, cell_order, plan_run,
                                                sequence_key)
from iblbench.harness.protocol.scheduler_address import check_scheduler
from iblbench.harness.protocol.timing import host_threads_capped, measure_timing_floor
from iblbench.foundation.errors import InputError, argument
from iblbench.scenes.registry import scene_entry

PLUGIN = "iblbench-opencl"
WORKER_WAIT_S = 120   # how long a run waits for the first worker to join its scheduler


class OpenCLWorker(WorkerPlugin):
    """The Dask worker plugin that gives each worker its OpenCL context (module docstring)."""

    name = PLUGIN

    def __init__(self, device: str | None, cache: str, launch_shape: str | None = None):
        self.device, self.cache, self.launch_shape = device, cache, launch_shape
        self.executors: dict[str, Executor] = {}

    def setup(self, worker) -> None:
        os.environ["IBLBENCH_CACHE"] = self.cache
        self.compute = get_compute(self.device, self.launch_shape)
        self.lock = threading.Lock()   # one unit at a time on the executor and its queue
        self.floor = measure_timing_floor(self.compute)
        self.worker = {"address": worker.address, "record": device_record(self.compute),
                       "device": self.compute.device_name, "floor": self.floor}

    def teardown(self, worker) -> None:
        self.executors.clear()

    def executor(self, run_id: str, config: RunConfig) -> Executor:
        """This worker's executor of run ``run_id`` (the previous run's is dropped)."""
        if run_id not in self.executors:
            self.executors = {run_id: Executor(config, plan_run(config), self.compute)}
        return self.executors[run_id]


@dataclasses.dataclass
class UnitResult:
    rows: list[dict]
    maps: dict            # the ΔE76 map of the unit's last frame, by sequence key
    chosen: dict          # (scene, label, budget) → spp, for the budgets the unit calibrated
    records: dict         # Executor.drain()
    seconds: dict         # cell key → the worker's host seconds for it
    worker: dict          # address, record (device_record), device (the rows' name), floor


def render_unit(run_id: str, config: RunConfig, keys: list, chosen: dict,
                maps: dict) -> UnitResult:
    """A worker's task: render the cells ``keys`` (one unit) with the spp ``chosen`` for their
    budgets and the ΔE76 ``maps`` of the frames before them."""
    from distributed import get_worker

    plugin = get_worker().plugins[PLUGIN]
    rows = []
    with plugin.lock, host_threads_capped():
        executor = plugin.executor(run_id, config)
        executor.chosen.update(chosen)
        executor.progress = CellClock()
        maps = executor.render(keys, rows.append, maps)
        budgets = {(key[0], key[1], key[5]) for key in keys if key[5] is not None}
        return UnitResult(rows=rows, maps=maps,
                          chosen={b: executor.chosen[b] for b in budgets if b in executor.chosen},
                          records=executor.drain(), seconds=executor.progress.seconds,
                          worker=plugin.worker)


def _worker_record(dask_worker) -> dict:
    return dask_worker.plugins[PLUGIN].worker


def chains(todo, plan: RunPlan) -> list[list[list[tuple]]]:
    """The units of ``todo`` by chain (module docstring), in the in-process order: scene by
    scene, frame by frame, cells in :func:`cell_order`."""
    temporal = {spec.label for spec in plan.specs if spec.cls.tags.temporal}
    by_chain = {}
    for key in todo:
        by_chain.setdefault(sequence_key(key), []).append(key)
    scenes = {p.scene.name: (i, p.frames) for i, p in enumerate(plan.plans)}
    out = []
    for keys in by_chain.values():
        index, frames = scenes[keys[0][0]]
        keys.sort(key=lambda k: frames.index(k[3]))
        out.append(([keys] if keys[0][1] in temporal else [[k] for k in keys],
                    (index, frames.index(keys[0][3]), cell_order(keys[0]))))
    return [units for units, _ in sorted(out, key=lambda item: item[1])]


class Cluster:
    """A Dask client with the plugin registered on its workers, and their records; ``task``
    is what a worker runs for a unit (:func:`render_unit`; a test's stand-in takes its arguments
    and returns its UnitResult)."""

    def __init__(self, client, task=render_unit):
        self.client, self.task = client, task
        self.workers = client.run(_worker_record)   # address → UnitResult.worker

    @property
    def devices(self) -> set[str]:
        return {w["device"] for w in self.workers.values()}

    def render(self, config: RunConfig, plan: RunPlan, todo, chosen: dict, on_result) -> list:
        """Run every unit of ``todo``; ``on_result(UnitResult)`` for each, in the order they
        finish; returns the keys of the cells lost with workers that died."""
        from distributed import as_completed
        from distributed.scheduler import KilledWorker

        config = dataclasses.replace(
            config, out=pathlib.Path(config.out).resolve(), progress=False,
            scenes=tuple(scene_entry(s) for s in config.scenes))
        run_id, numbers = uuid.uuid4().hex[:8], itertools.count()
        gpu = any(w.get("resources", {}).get("GPU")
                  for w in self.client.scheduler_info()["workers"].values())
        pending, finished = {}, as_completed()
        waiting = {}   # (scene, label, budget) → chains waiting for its calibration
        lost = []

        def submit(units, index, maps):
            keys = units[index]
            budgets = {(k[0], k[1], k[5]) for k in keys if k[5] is not None}
            scene, label, spp, frame, seed, _ = keys[0]
            future = self.client.submit(
                self.task, run_id, config, keys, {b: chosen[b] for b in budgets if b in chosen},
                maps, pure=False, resources={"GPU": 1} if gpu else None,
                key=f"iblbench-{scene}-{label}-{spp}-f{frame}-s{seed}-{run_id}-{next(numbers)}")
            pending[future] = (units, index)
            finished.add(future)

        for units in chains(todo, plan):
            key = units[0][0]
            budget = (key[0], key[1], key[5])
            if key[5] is None or budget in chosen:
                submit(units, 0, {})
            elif budget in waiting:
                waiting[budget].append(units)
            else:   # the first chain of an uncalibrated budget calibrates it
                waiting[budget] = []
                submit(units, 0, {})
        try:
            for future in finished:
                units, index = pending.pop(future)
                try:
                    result = future.result()
                except KilledWorker:
                    lost += [k for unit in units[index:] for k in unit]
                    budget = (units[0][0][0], units[0][0][1], units[0][0][5])
                    if budget not in chosen and waiting.get(budget):   # another chain calibrates
                        submit(waiting[budget].pop(0), 0, {})
                    continue
                self.workers.setdefault(result.worker["address"], result.worker)
                chosen.update(result.chosen)
                on_result(result)
                for budget in result.chosen:
                    for other in waiting.pop(budget, []):
                        submit(other, 0, {})
                if index + 1 < len(units):
                    submit(units, index + 1, result.maps)
        except BaseException:   # an error, or Ctrl-C: nothing more is rendered for this run
            for future in pending:
                future.cancel()
            raise
        return lost

    @property
    def dashboard(self) -> str | None:
        with contextlib.suppress(Exception):
            return self.client.dashboard_link
        return None


@contextlib.contextmanager
def cluster(config: RunConfig):
    """The run's Dask cluster: a LocalCluster of ``config.workers`` spawned processes, or the
    scheduler at ``config.scheduler``; its workers get the plugin before the first unit."""
    import dask
    from distributed import Client, LocalCluster

    settings = {"distributed.worker.multiprocessing-method": "spawn"}
    with dask.config.set(settings), contextlib.ExitStack() as stack:
        local = None
        if config.scheduler is not None:   # a bad address: one line within seconds
            check_scheduler(config.scheduler)
        else:
            local = stack.enter_context(LocalCluster(
                n_workers=config.workers, threads_per_worker=1, processes=True,
                dashboard_address=":0", silence_logs=logging.ERROR))
        try:
            client = stack.enter_context(Client(local or config.scheduler, timeout="10s"))
        except OSError as error:
            raise InputError(None, f"{argument('scheduler', config.scheduler)}: no Dask "
                                   f"scheduler answers there ({error})") from None
        try:
            client.wait_for_workers(1, timeout=WORKER_WAIT_S)
        except TimeoutError:
            where = config.scheduler or "of the LocalCluster"
            raise InputError(None, f"no worker joined the scheduler {where} in "
                                   f"{WORKER_WAIT_S} s; start one with 'dask worker "
                                   f"{config.scheduler or 'ADDRESS'}'") from None
        client.register_plugin(OpenCLWorker(config.device, str(cache_dir()), config.launch_shape))
        engine = Cluster(client)
        print(f"iblbench: {len(engine.workers)} Dask workers on "
              f"{', '.join(sorted(engine.devices))}"
              + (f"; dashboard {engine.dashboard}" if engine.dashboard else ""), file=sys.stderr)
        if local is not None and config.workers > 1:
            print(f"iblbench: the {config.workers} workers share this machine's device: each "
                  "cell's time includes the others' load (times to compare come from one worker "
                  "per device, or a run in process)", file=sys.stderr)
        yield engine
