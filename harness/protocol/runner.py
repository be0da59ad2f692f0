"""``iblbench run``: scenes × estimators × spp × frames × seeds → results table, manifest, images.

The runner is a run's client and its one writer: it plans the sweep (:mod:`.run_plan`), traces
the G-buffers, keeps the folder's lock, journal, table and manifest, and hands the cells left to
an :class:`~iblbench.harness.protocol.executor.Executor`, which renders, scores and writes their
images and gives back rows.  In process (the default) one executor on the run's device takes
them all, in the order below.  With ``RunConfig.workers`` (a Dask LocalCluster) or
``RunConfig.scheduler`` (a running dask-scheduler), the workers' executors take them unit by
unit (:mod:`.distributed`), and their rows come back here to be journalled; the table is the
same apart from the time columns, which are each worker's device's.

The runner skips what a scene does not need (ARCHITECTURE.md §Data flow): the G-buffer is traced once per scene
(and read from its on-disk cache, :func:`iblbench.scenes.gbuffer.cached_trace`, when an earlier
run traced the same one), a frame cache builds only the products the chosen estimators require,
and a cached reference is never recomputed.  Every skipped stage is recorded in the manifest.

Resumption.  Before rendering, the runner plans every cell of the sweep and counts a cell as
done when ``out`` already holds its row made with the same configuration (cell key, image size,
cube face size, estimator parameters), the same code (``estimator_version``, ``schema_version``,
protocol) and on the run's device (a cluster's: one of the devices of the workers there when
it starts); it prints ``resumed: N cells already done, M to run`` and runs only the M
(``force`` runs them all).  A cell also counts as done only while its image files exist.  Each
finished cell is appended to the results journal as it comes back (in process, before the next
one starts; see :mod:`iblbench.harness.protocol.results`), so a killed run, ``kill -9``
included, loses only what is in flight: in process the cell, on a cluster the units (a temporal
one is its whole sequence); Ctrl-C folds the journal into the table and marks the manifest
"interrupted", and an error (a full disk) marks it "failed", with the error as its "failure".
A run that ends with a cell to run that it never journalled (lost with Dask workers that died,
or however else) marks it "incomplete" and raises an InputError (exit 2), never "complete": the
runner counts those cells from its journal, not only from what the cluster says it lost.
A scene none of whose cells is left is not even traced.

One folder, one run at a time, one image configuration.  ``out``'s rows and manifest are read
only under its lock (``_locked``), so a run folds back what the folder holds then, not a stale
snapshot.  Rows of a scene made with another (width, height, env_res) make the run refuse the
folder, unless ``force``, which drops them; the manifest's ``runs`` lists every run's config.

The unit of work is a property of the estimator's ``Tags.temporal``.  A frame-by-frame estimator
resumes cell by cell.  A temporal estimator carries state from frame to frame, so its unit of
work and of resumption is the whole frame sequence of one (scene, estimator, spp, seed): unless
every frame of that sequence is done, all of them are run again, in order, on one instance that
starts from ``reset()`` (ARCHITECTURE.md §Results and units of work).

Frames.  The frames run are ``RunConfig.frames`` (a Python slice of each sequence's frames, a
list, or all); a static scene runs frame 0.  Each frame gets its own FrameCache, built on the
device and timed per stage (manifest ``stages``), unless the sequence returns the very same
array as the frame the cache was built for: then the cache is reused and the manifest's
``skipped`` says so.  A static scene builds its one FrameCache once per run, shared by every
estimator, spp and seed (also recorded in ``skipped``).

Flicker.  Each row's ``flicker`` compares its per-pixel ΔE76 map with the one of the previous
frame in the run's frame list for the same (scene, estimator, spp, budget, seed), kept in memory
(frames are the outer loop); NaN on the first frame.  When the previous frame was done by an
earlier run (resumption), its map is recomputed from that frame's saved estimate and reference
EXRs (``images/<scene>/f<frame>/``), and flicker is NaN if they are gone.

Timing (:mod:`iblbench.harness.protocol.timing` defines a cell's time).  Each cell is rendered
``repeats`` times after a warm-up (``repeats_for`` may give a slow estimator, say ``bis`` or
``smc``, fewer: the manifest's ``timing.repeats``, the report's manifest section and
``time_repeats`` record it), and its time columns summarise those renders:

- Warm-up: per frame and estimator, one render at 1 spp on a G-buffer of a few of the scene's
  pixels (``WARMUP_PIXELS``), on a throwaway instance and seed: it compiles the estimator's
  programs and runs each of its kernels once, and costs no whole frame.  A full-size launch may
  still make PoCL compile a new work-group size, but that happens before the event's start
  stamp, outside the device time (see the timing module).
- Render 0 is the scored one: the cell's seed, on the instance that carries a temporal
  estimator's state.  Renders 1..R-1 use seeds no cell uses (:func:`timing_seed`), so each draws
  its own light pool rather than reusing render 0's.  A frame-by-frame estimator renders them on
  the same instance (it keeps no state).  A temporal estimator renders them on R-1 *twin*
  instances that follow the same sequence (reset together, every frame in order, one timing seed
  each), so each twin takes the same path as the scored instance (initialisation on the first
  frame, carried state later, re-initialisation where the map jumps) while the scored state is
  never touched by a timing render.
- Rounds: a frame's cells render in interleaved rounds, render r of every cell in round r
  (:meth:`~iblbench.harness.protocol.executor.Executor._run_frame`; the timing module's
  "Rounds"), so a cell's renders fall in different spells of the device.  On a cluster a unit
  is one cell (or one sequence), so its renders go back to back there.
- Build: a frame builds its cache once (ARCHITECTURE.md §Data flow), so the device time of that one build of the
  products the estimator requires counts in each of its timed renders (``time_ms_build`` is
  that one measurement); a frame that reused an identical frame's cache built nothing, and its
  build is 0.

Equal time.  For each budget T in ``time_budget_ms`` and each (scene, estimator), the runner
calibrates the estimator's cell time (build + sample + shade) against spp
(:mod:`iblbench.harness.protocol.equal_time`), just before the first of those cells, and runs the spp it
chose.  The first cell of each budget is then corrected on its own time, in its own context,
before the rounds: its renders, back to back on its own seeds, while their median lies outside
half of ±10% of T, up to ``CELL_CORRECTIONS`` times, the per-spp slope re-estimated as the median
slope through the cell's measured points (keeping the calibration's intercept), each time from
``reset()``, at the spp that predicts T.  The spp kept is the best of those measured
(:func:`~iblbench.harness.protocol.equal_time.best_measured`); every cell of the budget then
renders at it, in the rounds.
Those rows carry ``time_budget_ms = T`` and the chosen ``spp``; the calibration runs, fits and
the cell's corrections (``cell_runs``) are in the manifest under ``time_budget``.  A resumed run
reuses the spp its earlier rows chose.  At the end, each equal-time cell's time is compared
with its budget: one outside ±10% is printed and listed in the manifest
(``time_budget.achieved``, with the reason), and the report shows the achieved time; the
equal-time answer marks a verdict that rests on such a cell (:mod:`.ranking`).

Scores.  The reference-side work of the metrics (exposure, L*a*b*, FLIP's exposure range) is
done once per frame (:class:`iblbench.harness.protocol.metrics.Scorer`); ``metrics`` leaves metrics out.
Render 0 is scored in full (its row's metrics, its EXR); every other planned timed render is
scored on ΔE76, ΔE2000 and relMSE too (``Scorer.errors``), and the row keeps each render's
values (``*_renders``): the cell's replicates, from which its intervals come
(:mod:`iblbench.harness.protocol.stats`).
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import datetime
import fcntl
import math
import os
import pathlib
import platform
import shutil
import signal
import sys
import threading
import time

import numpy as np
from tqdm import tqdm

from iblbench.estimators.runtime.device import cache_dir, check_launch_shape, get_compute
from iblbench.estimators.runtime.framecache import PRODUCTS
from iblbench.harness.protocol.executor import WARMUP_PIXELS, Executor, device_record
from iblbench.harness.protocol.metric import default_names
from iblbench.harness.protocol.metrics import PROTOCOL
from iblbench.harness.protocol.results import (FOLD_SECONDS, SCHEMA_VERSION, TABLE, Journal,
                                               backup_name, cell_files_intact,
                                               configuration_differences, image_configuration,
                                               prepare_out, read_manifest, read_results,
                                               remove_cells, row_key, schema_versions,
                                               write_manifest, write_results)
from iblbench.harness.protocol.equal_time import CALIBRATION_REPEATS, TOLERANCE
from iblbench.harness.protocol.progress import BAR_FORMAT, Progress
from iblbench.harness.protocol.provenance import git_revision, package_version
from iblbench.harness.protocol.run_plan import (RunConfig, ScenePlan, cell_order, plan_run,
                                               sequences)
from iblbench.harness.protocol.shadows import (attach_visibility, measured_record,
                                               traces_visibility)
from iblbench.harness.protocol.timing import (MEASURE, SPREAD_LIMIT, cell_times,
                                              cpu_snapshot, host_threads_capped,
                                              measure_timing_floor, others_cores,
                                              timing_floor_text)
from iblbench.harness.protocol.sweep import frames_text
from iblbench.foundation.atomic import atomic_path
from iblbench.foundation.errors import InputError, argument
from iblbench.scenes.framing import warn_about_framing
from iblbench.scenes.gbuffer import cached_trace
from iblbench.scenes.registry import scene_entry
LOCK = ".iblbench.lock"


@contextlib.contextmanager
def _locked(out: pathlib.Path):
    """One run at a time per folder (the OS drops the lock when a killed run dies).  The lock
    file stays: unlinking it would let a run that opened it before the unlink and one that
    creates a new file after it both hold "the" lock."""
    with open(out / LOCK, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise InputError(out, "another iblbench run is writing to this folder") from None
        yield


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored inside (the main thread only may set signal handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _remove_stale_temporaries(out: pathlib.Path) -> None:
    """Temporary files of atomic writes a killed run left (``.<stem>.<random><suffix>``)."""
    candidates = list(out.glob(".results.*")) + list(out.glob(".manifest.*"))
    for folder in ("images", "inputs"):
        if (out / folder).is_dir():
            candidates += [p for p in (out / folder).rglob(".*") if p.is_file()]
    for path in candidates:
        path.unlink(missing_ok=True)


class Runner:
    """Runs every cell of the sweep not already in ``out`` (see the module docstring)."""

    def __init__(self, config: RunConfig):
        self.plan = plan_run(config)
        self.config = config
        self.specs, self.plans = self.plan.specs, self.plan.plans
        for plan in self.plans:
            environment = plan.scene.environment
            if environment.texels_fixed:
                print(f"iblbench: {argument('sanitize', True)} replaced "
                      f"{environment.texels_fixed} bad texels in {environment.source}",
                      file=sys.stderr)
        self.distributed = config.scheduler is not None or config.workers is not None
        if config.workers is not None and config.workers < 1:
            raise InputError(None, f"{argument('workers', config.workers)}: at least one worker")
        check_launch_shape(config.launch_shape)   # before a cluster's workers meet it
        # In process, the run's device; on a cluster, the workers' (and this process's default
        # device only measures the visibility masks' error for the manifest).
        self.compute = None if self.distributed else get_compute(config.device, config.launch_shape)
        self.devices = set() if self.distributed else {self.compute.device_name}
        self.out = pathlib.Path(config.out)
        if self.out.exists() and not self.out.is_dir():
            raise InputError(self.out, f"{argument('out')} exists and is not a directory")
        # The manifest's "stages" and "skipped": G-buffers may be traced before it is made.
        self.stages, self.skipped, self.visibility = [], [], []
        self.skipped += [{"stage": metric, "why": "not in the sweep's metrics: its columns are NaN"}
                         for metric in default_names() if metric not in config.metrics]
        self.engine, self.executor = None, None
        # _table_order's ranks of scenes, (scene, frame) and estimators, as the sweep plans them
        self._ranks = ({p.scene.name: (0, i) for i, p in enumerate(self.plans)},
                       {(p.scene.name, f): (0, j)
                        for p in self.plans for j, f in enumerate(p.frames)},
                       {s.label: (0, i) for i, s in enumerate(self.specs)})

    def _read_state(self) -> None:
        """What ``out`` holds, read under its lock (a snapshot read before it could be stale by
        the time the run folds it back, and drop another run's cells): its rows, checked against
        this configuration, its manifest, and the plan of the cells left."""
        rows = read_results(self.out)
        older = [row for row in rows if row.get("schema_version") != SCHEMA_VERSION]
        backup = self._back_up_older_table(older)
        configured = {p.scene.name: (p.width, p.height, p.env_res) for p in self.plans}
        differences = configuration_differences(rows, configured)
        if differences and not self.config.force:
            raise InputError(self.out, f"holds results of another configuration ("
                                       f"{'; '.join(differences)}); use another "
                                       f"{argument('out')}, or {argument('force', True)} to "
                                       "replace them")
        if differences:   # force: this configuration replaces the scenes' other cells
            kept, dropped = [], []
            for row in rows:
                same = (row["scene"] not in configured
                        or image_configuration(row) == configured[row["scene"]])
                (kept if same else dropped).append(row)
            # The table first: a Ctrl-C (or a full disk) before the run's first fold must not
            # leave rows whose images are gone.
            write_results(self.out, sorted(kept, key=self._table_order))
            remove_cells(self.out, dropped, kept)
            print(f"iblbench: {argument('force', True)}: removed the {len(dropped)} cells of "
                  f"another image configuration, rows, images and saved inputs "
                  f"({'; '.join(differences)})", file=sys.stderr)
            rows = kept
        self.rows = {row_key(row): row for row in rows}
        self.previous_manifest = read_manifest(self.out)
        self.todo, self.cells, self.chosen = self._plan_cells()
        self.total = len(self.cells)
        self.resumed = self.total - len(self.todo)
        self.manifest = self._new_manifest()
        if older:
            self._say_what_replaces_older_rows(older, backup)

    def _back_up_older_table(self, older: list[dict]) -> pathlib.Path | None:
        """Where ``out``'s table, holding the rows ``older`` of an older schema, is kept before
        this run's fold rewrites it: ``results.schema<N>.parquet``, N its oldest schema (a copy
        an earlier run made is kept as it is); None without such rows or table."""
        table = self.out / TABLE
        if not older or not table.exists():
            return None
        oldest = schema_versions(row.get("schema_version") for row in older)[0]
        backup = self.out / backup_name(oldest)
        if not backup.exists():
            with atomic_path(backup) as tmp:
                shutil.copyfile(table, tmp)
        return backup

    def _say_what_replaces_older_rows(self, older: list[dict], backup) -> None:
        """One line before anything is rendered or folded: how many rows of an older schema this
        run renders again (each that is a cell of its sweep: such rows never count as done) and
        replaces, how many stay as they are, and where the old table is kept."""
        again = sum(row_key(row) in self.todo for row in older)
        versions = ", ".join(map(str, schema_versions(row.get("schema_version") for row in older)))
        kept = f"; the old table is kept as {backup}" if backup else ""
        print(f"iblbench: {self.out / TABLE} holds {len(older)} rows of schema {versions} (this "
              f"iblbench writes schema {SCHEMA_VERSION}): this run renders {again} of them again "
              f"and replaces their rows, {len(older) - again} not in its sweep stay as they "
              f"are{kept}", file=sys.stderr)

    # ---- planning ----------------------------------------------------------------------------

    def _valid(self, row: dict | None, plan: ScenePlan, spec) -> bool:
        """A row made with this configuration and code, on this run's device (a cluster: on one
        of its workers' devices)."""
        return (row is not None and row.get("schema_version") == SCHEMA_VERSION
                and row.get("estimator_version") == spec.cls.version()
                and row.get("estimator_params") == self.plan.params[spec.label]
                and row.get("device") in self.devices and row.get("protocol") == PROTOCOL
                and set(self.config.metrics) <= set(str(row.get("metrics")).split(","))
                and row.get("time_repeats", 0) >= self.plan.repeats[spec.label]
                and (row.get("width"), row.get("height"), row.get("env_res"))
                == (plan.width, plan.height, plan.env_res)
                and cell_files_intact(self.out, row))

    def _plan_cells(self):
        """The keys of the cells to run, the keys of every cell of the sweep, and the spp earlier
        rows chose for each (scene, estimator, budget)."""
        todo, cells, chosen = set(), set(), {}
        for plan, spec, keys in sequences(self.plan, self.config):
            cells.update(keys)
            done = [not self.config.force and self._valid(self.rows.get(k), plan, spec)
                    for k in keys]
            if spec.cls.tags.temporal and not all(done):
                todo.update(keys)       # a sequence is one unit of work
            else:
                todo.update(k for k, d in zip(keys, done) if not d)
            for key, d in zip(keys, done):
                if d and key[5] is not None:   # an equal-time cell done: the spp it chose
                    chosen[(plan.scene.name, spec.label, key[5])] = int(self.rows[key]["spp"])
        return todo, cells, chosen

    def _new_manifest(self) -> dict:
        c = self.config
        sweep = c.sweep or {"source": "RunConfig (Python API)"}
        manifest = {
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(),
            "config": {"scenes": [scene_entry(s) for s in c.scenes],
                       "estimators": [s.label for s in self.specs],
                       "spp": list(c.spp), "spp_for": {n: list(v) for n, v in c.spp_for},
                       "seeds": c.seeds, "first_seed": c.first_seed,
                       "resolution": c.resolution,
                       "frames": frames_text(c.frames),
                       "frames_for": {n: frames_text(v) for n, v in c.frames_for},
                       "time_budget_ms": list(c.time_budget_ms), "force": c.force,
                       "repeats": c.repeats, "repeats_for": dict(c.repeats_for),
                       "metrics": list(c.metrics), "control": list(c.control),
                       "save_inputs": c.save_inputs, "sanitize": c.sanitize, "env_res": c.env_res},
            "sweep": sweep,
            "protocol": PROTOCOL,
            "schema_version": SCHEMA_VERSION,
            "git_revision": git_revision(),
            "versions": {"iblbench": package_version("iblbench"), "python": platform.python_version(),
                         **{p: package_version(p) for p in ("numpy", "pyopencl", "embreex",
                                                            "colour-science", "pandas")}},
            "estimator_versions": {s.label: s.cls.version() for s in self.specs},
            "estimator_params": dict(self.plan.params),
            # How the report shows each estimator's extra columns (Estimator.extra_columns):
            # the folder's earlier runs' too, whose rows stay in the table.
            "extra_columns": {**self.previous_manifest.get("extra_columns", {}),
                              **{column: dataclasses.asdict(extra) for s in self.specs
                                 for column, extra in s.cls.extra_columns.items()}},
            "device": self._device_manifest(),
            "sanitized": {p.scene.name: p.scene.environment.texels_fixed for p in self.plans},
            "runs": self._run_history(),
            "resumed_cells": self.resumed,
            "cells_to_run": len(self.todo),
            "stages": self.stages,
            "skipped": self.skipped,
            "visibility": self.visibility,
            "timing": {"measure": MEASURE, "repeats": dict(self.plan.repeats),
                       "cell": "median of the cell's timed renders after warm-up (the "
                               "estimator's repeats); min and IQR beside it "
                               "(harness/protocol/timing.py)",
                       "context": "BLAS and OpenMP pools at one host thread for the whole run "
                                  "(threadpoolctl); a round's renders (and a calibration's) "
                                  "back to back, scored after it",
                       "pocl_affinity": os.environ.get("POCL_AFFINITY"),
                       "warm_up": f"1 spp on {WARMUP_PIXELS} pixels per frame and estimator",
                       "wall": "wall_s: host wall time from the first frame's set-up to the "
                               "last cell's write; start-up (imports, "
                               "scenes, G-buffers, the device) before it; device_s: the run's "
                               "device time, timed renders, warm-ups, calibrations, builds and "
                               "references",
                       "temporal": "timing renders on repeats - 1 twin instances per "
                                   "sequence; the scored render is the real state's",
                       "rounds": "a frame's cells render in interleaved rounds, one render "
                                 "of each cell a round, each round in a seeded order of its "
                                 "own, so that a cell's renders fall in different spells of "
                                 "the device",
                       "spread": {"rule": f"wide_cells: cells whose renders' IQR/median is "
                                          f"above {SPREAD_LIMIT:.0%}",
                                  "cells": 0, "wide_cells": 0}},
            "time_budget": ({"budgets_ms": list(c.time_budget_ms), "measure": MEASURE,
                             "model": "time = a_ms + b_ms_per_spp * spp, least squares on "
                                      "relative error over the median of "
                                      f"{CALIBRATION_REPEATS} renders per spp (in rounds), "
                                      "then refined on "
                                      "renders at the chosen spp and on the budget's first "
                                      "cell (cell_runs), each step by the median slope "
                                      "through the points measured so far",
                             "chosen": f"a measured spp within ±{TOLERANCE:.0%} of the budget, "
                                       "the largest within it first, in the calibration and "
                                       "again on the first cell (harness/protocol/equal_time.py)",
                             "calibrations": self._resumed_calibrations()}
                            if c.time_budget_ms else None),
        }
        manifest["runs"].append({"created": manifest["created"], "config": manifest["config"]})
        return manifest

    def _run_history(self) -> list[dict]:
        """The runs into ``out`` before this one, oldest first: when each started and its
        ``config`` (several sweeps with one image configuration share the table)."""
        previous = self.previous_manifest
        if "runs" in previous or "config" not in previous:
            return list(previous.get("runs", []))
        return [{"created": previous.get("created"), "config": previous["config"]}]

    def _resumed_calibrations(self) -> list[dict]:
        """The earlier manifest's calibrations of the budgets whose spp resumed rows chose."""
        old = (self.previous_manifest.get("time_budget") or {}).get("calibrations", [])
        kept = []
        for entry in old:
            key = (entry.get("scene"), entry.get("estimator"), entry.get("budget_ms"))
            if key in self.chosen and self.chosen[key] == entry.get("chosen_spp"):
                kept.append(dict(entry, resumed=True))
        return kept

    # ---- running -----------------------------------------------------------------------------

    def run(self):
        # A new --out is made only after its scenes are traced: a camera that sees no geometry
        # is bad input, and bad input must leave no partial output behind.  In an existing --out,
        # the scenes with cells left are traced once its state has been read under the lock.
        # The cluster first: a bad --scheduler is refused before the scenes are traced, and
        # leaves no --out behind.
        with self._cluster():
            gbuffers = ({} if self.out.exists()
                        else {plan.scene.name: self._trace(plan) for plan in self.plans})
            return self._run_locked(gbuffers)

    def _run_locked(self, gbuffers: dict):
        prepare_out(self.out)
        with _locked(self.out), host_threads_capped():
            self._read_state()
            for plan in self.plans:
                if plan.scene.name not in gbuffers and any(key[0] == plan.scene.name
                                                           for key in self.todo):
                    gbuffers[plan.scene.name] = self._trace(plan)
            if self.resumed:
                print(f"resumed: {self.resumed} cells already done, {len(self.todo)} to run",
                      file=sys.stderr)
            _remove_stale_temporaries(self.out)
            self.journal = Journal(self.out)
            self.journalled = set()   # the keys of the cells this run journalled
            self._fold()   # a journal a killed run left becomes part of the table now
            self._last_fold = time.monotonic()
            self.manifest["status"] = "running"   # a killed run leaves this, not a missing manifest
            write_manifest(self.out, self.manifest)
            # An error (a full disk above all, also under a Ctrl-C's save) ends "failed".
            try:
                try:   # from here on a Ctrl-C, before the first cell too, ends "interrupted"
                    table = self._run_cells(gbuffers)
                except KeyboardInterrupt:
                    saved = len(self._save_interrupted())
                    raise KeyboardInterrupt(f"{saved} cells saved; rerun to resume") from None
            except Exception as error:
                self._mark_failed(error)
                raise
            finally:
                self.journal.close()
        return table

    @contextlib.contextmanager
    def _cluster(self):
        """In process: nothing.  On a cluster: the Dask client and its workers, whose devices
        are the run's (:mod:`.distributed`, imported only here: Dask is not loaded otherwise)."""
        if not self.distributed:
            yield
            return
        from iblbench.harness.protocol.distributed import cluster

        with cluster(self.config) as engine:
            self.engine = engine
            self.devices = engine.devices
            yield

    def _run_cells(self, gbuffers: dict):
        """Every cell left, in process between two measurements of the timing floor, or on the
        cluster; the manifest ends "complete", or "incomplete" with an InputError where a cell
        to run has no row in the journal; returns the table."""
        left = collections.Counter((key[0], key[3]) for key in self.todo)   # (scene, frame)
        self._record_skips(left)
        self._save_inputs(gbuffers, left)
        with tqdm(total=self.total, unit="cell", disable=self._bar_disabled(),
                  bar_format=BAR_FORMAT, initial=self.resumed) as bar:
            self.progress = Progress(bar, self.todo, {scene: gbuffer.covered
                                                      for scene, gbuffer in gbuffers.items()})
            self.device_ms_total = 0.0
            # The load of this host; on a cluster the client's, not the workers' (it still
            # tells a busy machine where --workers share it, and the floors cover the workers).
            loads, cpu = [os.getloadavg()[0]], cpu_snapshot()
            if self.engine is None:
                (floors, wall_s), lost = self._render_here(gbuffers), []
            else:
                start = time.perf_counter()
                lost = self._render_on_cluster()
                wall_s = time.perf_counter() - start
                floors = [w["floor"] for w in self.engine.workers.values()] if self.todo else []
            loads.append(os.getloadavg()[0])
            others = others_cores(cpu, cpu_snapshot())
        table = self._fold()
        if self.todo:
            self.manifest["timing"].update(
                wall_s=wall_s, device_s=self.device_ms_total / 1e3,
                wall_per_device=wall_s / max(self.device_ms_total / 1e3, 1e-9))
            self.manifest["timing"]["floor"] = {
                "kernel": f"fma_throughput, {floors[0].median_ms:.2g} ms, "
                          f"{floors[0].launches} launches back to back, "
                          + ("at the run's start and end" if self.engine is None
                             else "at each worker's start, in the order of manifest.workers")
                          + " (harness/protocol/timing.py, \"The device's own floor\")",
                "groups_within": [round(f.groups_within, 3) for f in floors],
                "p90_over_p10": [round(f.p90_over_p10, 3) for f in floors]}
            # A --scheduler run's cells ran on other hosts: this one's CPU says nothing of them.
            self.manifest["timing"]["load"] = {
                "cores": os.cpu_count(), "load_1min": [round(v, 2) for v in loads],
                "others_cores": None if self.config.scheduler else round(others, 3)}
        if self.engine is not None:
            self.manifest["workers"] = [dict(w["record"], address=address)
                                        for address, w in self.engine.workers.items()]
        self._report_spread(floors)
        if self.config.time_budget_ms:
            self.manifest["time_budget"]["achieved"] = self._check_budgets(table)
        # Counted from the journal too, not only from what the cluster says it lost: a cell to
        # run that has no row, however it went missing, leaves the run incomplete.
        missing = set(lost) | (self.todo - self.journalled)
        if missing:
            self.manifest["status"] = "incomplete"
            write_manifest(self.out, self.manifest)
            died = " with Dask workers that died running them" if lost else ""
            raise InputError(self.out, f"{len(missing)} cells were lost{died}; rerun to resume")
        self.manifest["status"] = "complete"
        write_manifest(self.out, self.manifest)
        return table

    def _render_here(self, gbuffers: dict) -> tuple[list, float]:
        """Every cell left, on this process's device; returns the timing floors measured at the
        start and the end, and the wall seconds between them."""
        self.progress.stage(f"timing floor of {self.compute.info.device.name.strip()}")
        floors = [measure_timing_floor(self.compute)] if self.todo else []
        start = time.perf_counter()
        self.executor = Executor(self.config, self.plan, self.compute, self.progress,
                                 warn=lambda text: print(f"iblbench: {text}", file=sys.stderr))
        self.executor.gbuffers.update(gbuffers)
        self.executor.chosen.update(self.chosen)
        self.executor.render(self.todo, self._journal_cell)
        self._merge(self.executor.drain())
        wall_s = time.perf_counter() - start
        if self.todo:
            floors.append(measure_timing_floor(self.compute))
        return floors, wall_s

    def _render_on_cluster(self) -> list:
        """Every cell left, on the cluster's workers; returns the keys of the cells lost."""
        self.progress.stage(f"on {len(self.engine.workers)} Dask workers")

        def finished(result) -> None:
            for row in result.rows:
                self._journal_cell(row)
                key = row_key(row)
                self.progress.finished(key, result.seconds[key] / len(self.engine.workers))
            self._merge(result.records)

        return self.engine.render(self.config, self.plan, self.todo, self.chosen, finished)

    def _merge(self, records: dict) -> None:
        """An executor's manifest records (Executor.drain) into the manifest."""
        self.manifest["stages"] += records["stages"]
        self.manifest["skipped"] += records["skipped"]
        if self.config.time_budget_ms:
            self.manifest["time_budget"]["calibrations"] += records["calibrations"]
        for name, count in records["spread"].items():
            self.manifest["timing"]["spread"][name] += count
        self.device_ms_total += records["device_ms"]
        for warning in records["warnings"]:
            print(f"iblbench: {warning}", file=sys.stderr)

    def _device_manifest(self) -> dict:
        """The manifest's device: this process's, or the workers' where they share one (each
        worker is in ``workers``)."""
        if self.engine is None:
            return device_record(self.compute)
        records = [w["record"] for w in self.engine.workers.values()]
        names = sorted({record["name"] for record in records})
        if all(record == records[0] for record in records):
            return records[0]
        return {"name": "; ".join(names), "hosts": sorted({r["host"] for r in records}),
                "several": True}

    def sweep_rows(self, table):
        """The rows of ``table`` (after :meth:`run`) that are cells of this sweep: ``out`` may
        also hold other sweeps' cells."""
        return table[[row_key(row) in self.cells for row in table.to_dict("records")]]

    def _report_spread(self, floors) -> None:
        """Says how many cells needed more timed renders, how many stayed too wide, and, only
        where it was poor, how repeatable the device itself was (``floors``: TimingFloor at the
        start and end, or at each worker's start; the manifest and the report always have
        it)."""
        counts = self.manifest["timing"]["spread"]
        if counts["wide_cells"] > counts["cells"] / 2:
            print(f"iblbench: timing: {counts['wide_cells']} of {counts['cells']} cells' renders "
                  f"spread wider than {SPREAD_LIMIT:.0%} (IQR/median): the machine's speed moved "
                  "during the run, and the intervals are wider for it", file=sys.stderr)
        if any(floor.poor for floor in floors):
            measured = (timing_floor_text(floors) if self.engine is None else "; ".join(
                f"{w['floor'].text()} on the worker at {address}"
                for address, w in self.engine.workers.items()))
            print("iblbench: timing: the device itself was not repeatable (a fixed kernel "
                  f"launched back to back: {measured}); compare times with care",
                  file=sys.stderr)

    def _check_budgets(self, table) -> list[dict]:
        """Each equal-time cell's time against its budget, per device (a cluster's devices each
        take the spp its first cell chose); prints those outside ±TOLERANCE."""
        timed = table[table.time_budget_ms.notna()]
        if timed.empty:
            return []
        keys = ["scene", "estimator", "time_budget_ms", "device"]
        times = cell_times(timed, keys)
        spp = timed.groupby(keys, sort=False).spp.first()
        calibrated = {(c["scene"], c["estimator"], c["budget_ms"], c.get("device")): c
                      for c in self.manifest["time_budget"]["calibrations"]}
        achieved = []
        for key, ms in times.items():
            scene, label, budget, device = key
            within = abs(ms - budget) <= TOLERANCE * budget
            why = None if within else _missed_why(calibrated.get(key), int(spp[key]), ms, budget)
            achieved.append({"scene": scene, "estimator": label, "budget_ms": budget,
                             "device": device, "spp": int(spp[key]), "time_ms": ms,
                             "within_tolerance": bool(within), "why": why})
            if not within:
                print(f"iblbench: {label} on {scene}: {ms:.3g} ms at {spp[key]} spp against the "
                      f"{budget:g} ms budget ({ms / budget - 1:+.0%}) on {device}, outside "
                      f"±{TOLERANCE:.0%}: {why}; a verdict that reads it says so",
                      file=sys.stderr)
        return achieved

    def _save_interrupted(self):
        """Ctrl-C: fold the finished cells into the table and mark the manifest "interrupted"
        (a second Ctrl-C meanwhile is ignored, as it would lose them); returns the table."""
        with _sigint_ignored():
            table = self._fold()
            if self.executor is not None:
                self._merge(self.executor.drain())
            self.manifest["status"] = "interrupted"
            write_manifest(self.out, self.manifest)
        return table

    def _mark_failed(self, error: Exception) -> None:
        """The manifest of a run that ``error`` ended (a full disk, a failing device) says
        "failed" and why, not "running", where the disk still takes it; the journal keeps the
        finished cells, which a rerun resumes from."""
        if self.manifest["status"] != "running":   # already says how it ended ("incomplete")
            return
        self.manifest.update(status="failed", failure=str(error))
        try:
            write_manifest(self.out, self.manifest)
        except OSError:   # not even the manifest fits: it says "running", as a killed run's does
            pass

    def _fold(self):
        self.journal.close()
        return write_results(self.out, sorted(self.rows.values(), key=self._table_order))

    def _table_order(self, row: dict) -> tuple:
        """The table's row order: the in-process run's (scenes and estimators in the sweep's
        order, frames in order, then :func:`cell_order`), whatever order the rows came in (a
        cluster's finish in any); rows of scenes or estimators this sweep does not name after
        those it does, by name."""
        key = row_key(row)
        _, spp_first, spp, budget, seed = cell_order(key)
        scenes, frames, labels = self._ranks
        return (scenes.get(key[0], (1, key[0])), frames.get(key[:4:3], (1, key[3])),
                labels.get(key[1], (1, key[1])), spp_first, spp, budget, seed)

    def _bar_disabled(self):
        return None if self.config.progress is None else not self.config.progress

    def _stage(self, scene: str, frame, stage: str, ms: float) -> None:
        self.stages.append({"scene": scene, "frame": frame, "stage": stage, "ms": ms})

    def _trace(self, plan: ScenePlan):
        scene = plan.scene
        start = time.perf_counter()
        gbuffer, cached = cached_trace(scene.mesh, scene.material, scene.camera, plan.width,
                                       plan.height, cache_dir() / "gbuffer")
        if cached:
            self.skipped.append({"scene": scene.name, "stage": "gbuffer", "why": "cached"})
        else:
            self._stage(scene.name, None, "gbuffer", (time.perf_counter() - start) * 1e3)
        if gbuffer.covered == 0:
            mesh = f" {scene.mesh_source}" if scene.mesh_source else ""
            raise InputError(scene.source or scene.name,
                             f"the camera sees none of the mesh{mesh}; check the camera's eye "
                             "and target, and the mesh's position and size")
        warn_about_framing(scene, gbuffer)   # too few mesh pixels, or the camera inside the mesh
        with tqdm(total=gbuffer.covered, unit="px", leave=False,
                  disable=self._bar_disabled() if traces_visibility(scene) else True,
                  desc=f"{scene.name}: tracing visibility") as bar:
            gbuffer, record = attach_visibility(scene, gbuffer, plan.env_res, cache_dir() / "visibility",
                                                bar.update)
        if record is not None:
            record = measured_record(scene, gbuffer, scene.environment.frame(plan.frames[0]), record)
            self.visibility.append(record)
            if record.get("cached") or "skipped" in record:
                self.skipped.append({"scene": scene.name, "stage": "visibility",
                                     "why": record.get("skipped", "cached")})
            else:
                self._stage(scene.name, None, "visibility", record["seconds"] * 1e3)
        return gbuffer

    def _record_skips(self, left: collections.Counter) -> None:
        """The manifest's records of what the run will not do: scenes and frames whose cells are
        all done, products no selected estimator requires, a static map's one frame cache
        (``left``: the cells to run by (scene, frame))."""
        required = {p for spec in self.specs for p in spec.cls.requires}
        for plan in self.plans:
            scene = plan.scene
            cells = sum(left[(scene.name, frame)] for frame in plan.frames)
            if not cells:
                self.manifest["skipped"].append({"scene": scene.name, "stage": "scene",
                                                 "why": "every cell already done (resumed)"})
                self.manifest["stages"] += [dict(stage, resumed=True) for stage
                                            in self.previous_manifest.get("stages", [])
                                            if stage.get("scene") == scene.name]
                self.visibility += [record for record
                                    in self.previous_manifest.get("visibility") or []
                                    if record.get("scene") == scene.name]   # not traced again
                continue
            self.manifest["skipped"] += [{"scene": scene.name, "stage": product,
                                          "why": "no selected estimator requires it"}
                                         for product in PRODUCTS
                                         if product not in required and product != "env"]
            self.manifest["skipped"] += [{"scene": scene.name, "frame": frame, "stage": "frame",
                                          "why": "every cell already done (resumed)"}
                                         for frame in plan.frames if not left[(scene.name, frame)]]
            if scene.environment.is_static:
                self.manifest["skipped"].append({
                    "scene": scene.name, "stage": "framecache",
                    "why": f"static environment: one FrameCache built for frame 0 and reused "
                           f"by every estimator, spp and seed ({cells} cells)"})

    def _save_inputs(self, gbuffers: dict, left: collections.Counter) -> None:
        """``save_inputs``: each scene's G-buffer and each frame's map, where cells are left
        (``left``: the cells to run by (scene, frame))."""
        if not self.config.save_inputs:
            return
        for plan in self.plans:
            inputs = self.out / "inputs" / plan.scene.name
            if plan.scene.name in gbuffers:
                gbuffers[plan.scene.name].save_npz(inputs / "gbuffer.npz")
            for frame in plan.frames:
                if left[(plan.scene.name, frame)]:
                    with atomic_path(inputs / f"env_f{frame}.npy") as tmp:
                        np.save(tmp, np.asarray(plan.scene.environment.frame(frame), np.float32))

    def _journal_cell(self, row: dict) -> None:
        """The row goes to the journal (after its images: a journalled cell is complete), and
        the journal is folded into the table every FOLD_SECONDS.  Recorded before it is
        journalled: a fold (a Ctrl-C's too) writes the table from ``rows`` and drops the journal,
        so a Ctrl-C between the two would have lost a journalled cell."""
        self.rows[row_key(row)] = row
        self.journalled.add(row_key(row))
        self.journal.append(row)
        if time.monotonic() - self._last_fold > FOLD_SECONDS:
            self._fold()
            self._last_fold = time.monotonic()


def _missed_why(calibration: dict | None, spp: int, ms: float, budget: float) -> str:
    """Why an equal-time cell missed its budget, from its calibration (None: an earlier run's
    or another device's)."""
    if not math.isfinite(ms):
        return "no time was measured"
    if spp == 1 and ms > budget:
        return "even 1 spp takes longer than the budget"
    if calibration is None:
        return "its spp was chosen by an earlier run"
    if ms < budget and spp >= calibration.get("limit", spp + 1):
        return f"{spp} spp is the most it may take"
    cheapest = min(calibration["runs"], key=lambda run: run["median_device_ms"])
    if ms > budget and cheapest["median_device_ms"] > budget:
        return (f"no spp fitted: its fastest in calibration, {cheapest['spp']} spp, took "
                f"{cheapest['median_device_ms']:.3g} ms (the frame's fixed work)")
    return (f"calibrated at {calibration['measured_ms']:.3g} ms, its cells ran at {ms:.3g} ms: "
            "the device's speed changed between the calibration and the cells")


def run(config: RunConfig):
    """Run a benchmark; returns the results table (also written under ``config.out``)."""
    return Runner(config).run()
