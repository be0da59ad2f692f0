"""``iblbench run``: scenes × estimators × spp × frames × seeds → results table, manifest, images.

The runner skips what a scene does not need (DESIGN §2): the G-buffer is traced once per scene
(and read from its on-disk cache, :func:`iblbench.scenes.gbuffer.cached_trace`, when an earlier
run traced the same one), a frame cache builds only the products the chosen estimators require,
and a cached reference is never recomputed.  Every skipped stage is recorded in the manifest.

Resumption.  Before rendering, the runner plans every cell of the sweep and counts a cell as
done when ``out`` already holds its row made with the same configuration (cell key, image size,
cube face size, estimator parameters), the same code (``estimator_version``, ``schema_version``,
protocol) and on the same device; it prints ``resumed: N cells already done, M to run`` and runs
only the M (``force`` runs them all).  A cell also counts as done only while its image files
exist.  Each finished cell is appended to the results journal before the next one starts (see
:mod:`iblbench.harness.protocol.results`), so a killed run, ``kill -9`` included, loses only the cell in
flight; Ctrl-C folds the journal into the table and marks the manifest "interrupted".  A scene
none of whose cells is left is not even traced.

One folder, one run at a time, one image configuration.  ``out``'s rows and manifest are read
only under its lock (``_locked``), so a run folds back what the folder holds then, not a stale
snapshot.  Rows of a scene made with another (width, height, env_res) make the run refuse the
folder, unless ``force``, which drops them; the manifest's ``runs`` lists every run's config.

The unit of work is a property of the estimator's ``Tags.temporal``.  A frame-by-frame estimator
resumes cell by cell.  A temporal estimator carries state from frame to frame, so its unit of
work and of resumption is the whole frame sequence of one (scene, estimator, spp, seed): unless
every frame of that sequence is done, all of them are run again, in order, on one instance that
starts from ``reset()`` (DESIGN §6).

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
- More renders: a frame-by-frame estimator's cell whose renders spread wider than the timing
  module's limit gets renders R, R+1, ... (seeds :func:`timing_seed`) one at a time, up to
  ``EXTENSION`` × R (:meth:`Runner._cell_renders`); the run says how many cells got more.
- Build: a frame builds its cache once (DESIGN §2), so the device time of that one build of the
  products the estimator requires counts in each of its timed renders (``time_ms_build`` is
  that one measurement); a frame that reused an identical frame's cache built nothing, and its
  build is 0.

Equal time.  For each budget T in ``time_budget_ms`` and each (scene, estimator), the runner
calibrates the estimator's cell time (build + sample + shade) against spp
(:mod:`iblbench.harness.protocol.equal_time`), just before the first of those cells, and runs the spp it
chose.  The first cell of each budget is then corrected on its own time, in its own context
(after scoring and image writes, on its own seeds): while its median lies outside half of ±10%
of T, up to ``CELL_CORRECTIONS`` times, the per-spp slope is re-estimated as the median slope
through the cell's measured points (keeping the calibration's intercept) and the cell is
rendered again, from ``reset()``, at the spp that predicts T.  The spp kept is the best of
those measured (:func:`~iblbench.harness.protocol.equal_time.best_measured`), rendered once more if it
was not the last; the last rendering is the cell, and its spp is every other cell's of that
budget.
Those rows carry ``time_budget_ms = T`` and the chosen ``spp``; the calibration runs, fits and
the cell's corrections (``cell_runs``) are in the manifest under ``time_budget``.  A resumed run
reuses the spp its earlier rows chose.  At the end, each equal-time cell's time is compared
with its budget: one outside ±10% is printed and listed in the manifest
(``time_budget.achieved``), and the report shows the achieved time.

Scores.  The reference-side work of the metrics (exposure, L*a*b*, FLIP's exposure range) is
done once per frame (:class:`iblbench.harness.protocol.metrics.Scorer`); ``metrics`` leaves metrics out.
Render 0 is scored in full (its row's metrics, its EXR); every other planned timed render is
scored on ΔE76, ΔE2000 and relMSE too (``Scorer.errors``), and the row keeps each render's
values (``*_renders``): the cell's replicates, from which its intervals come
(:mod:`iblbench.harness.protocol.stats`).  Renders added for a wide timing spread are not scored.
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime
import fcntl
import math
import os
import pathlib
import platform
import signal
import sys
import threading
import time

import numpy as np
from tqdm import tqdm

from iblbench.estimators.registry import get_estimator_class
from iblbench.estimators.runtime.device import cache_dir, get_compute
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import PRODUCTS, FrameCache
from iblbench.harness.protocol.metrics import METRICS, PROTOCOL, Scorer, delta_e_images, flicker
from iblbench.estimators.runtime.reference import Reference
from iblbench.harness.protocol.stats import RENDERS, renders_text
from iblbench.harness.protocol.results import (FOLD_SECONDS, REPLICATED, SCHEMA_VERSION, Journal,
                                               cell_files_intact,
                                               configuration_differences, image_configuration,
                                               image_stem, prepare_out, read_manifest, read_results,
                                               remove_cells, row_key, write_manifest,
                                               write_results)
from iblbench.harness.protocol.equal_time import (CALIBRATION_REPEATS, CALIBRATION_SEED,
                                                  CELL_CORRECTIONS, TOLERANCE, Calibration,
                                                  best_measured, corrected_spp, spp_limit)
from iblbench.harness.protocol.progress import BAR_FORMAT, Progress
from iblbench.harness.protocol.provenance import git_revision, package_version
from iblbench.harness.protocol.shadows import attach_visibility, measured_record
from iblbench.harness.protocol.timing import (EXTENSION, MEASURE, SPREAD_LIMIT, cell_times,
                                              device_ms, host_threads_capped, required_build_ms,
                                              time_columns, measure_timing_floor, timed_renders,
                                              timing_floor_text, too_wide)
from iblbench.harness.protocol.sweep import (DEFAULT_REPEATS, MAX_REPEATS, frames_text,
                                             parse_estimator, select_frames)
from iblbench.scenes.atomic import atomic_path
from iblbench.scenes.errors import InputError, argument
from iblbench.scenes.framing import warn_about_framing
from iblbench.scenes.gbuffer import cached_trace
from iblbench.scenes.imageio import read_exr, write_exr
from iblbench.scenes.registry import load_scene, scene_entry

DEFAULT_SCENES = ("sphere-sun",)
DEFAULT_ESTIMATORS = ("uniform",)
DEFAULT_SPP = (16, 64, 256)
DEFAULT_SEEDS = 2
WARMUP_SEED = 0xFFFFFFFF   # a seed no benchmark cell uses
WARMUP_PIXELS = 64
TIMING_SEED = 0x80000000   # timing renders: TIMING_SEED + 256·seed + repeat (timing_seed)
# The largest cell seed whose timing seeds stay below the calibration seeds.
MAX_SEED = (CALIBRATION_SEED - TIMING_SEED) // 256 - 1
# Seeds per cell at most: a sweep plans every (cell, seed) up front, and 8,388,607 seeds took
# 2.7 GB before the first cell (issue 23); a study needs tens, a coverage simulation hundreds.
MAX_SEEDS = 10_000
LOCK = ".iblbench.lock"


@dataclasses.dataclass
class RunConfig:
    out: pathlib.Path
    scenes: tuple[str, ...] = DEFAULT_SCENES
    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS   # labels: "name" or "name{param=value}"
    spp: tuple[int, ...] = DEFAULT_SPP
    seeds: int = DEFAULT_SEEDS
    first_seed: int = 0        # cells use seeds first_seed .. first_seed + seeds - 1
    resolution: tuple[int, int] | None = None
    device: str | None = None
    save_inputs: bool = False
    sanitize: bool = False
    env_res: int | None = None
    progress: bool | None = None   # None: a bar only on a TTY
    frames: tuple[int, ...] | slice | None = None   # None: every frame; a slice: Python slice
                                                    # semantics over each sequence's frames;
                                                    # static scenes run frame 0
    frames_for: tuple[tuple[str, object], ...] = ()   # (scene name, its own frame selection)
    time_budget_ms: tuple[float, ...] = ()     # equal-time cells, besides the spp list
    force: bool = False                        # recompute finished cells too
    repeats: int = DEFAULT_REPEATS             # timed renders per cell (timing module)
    repeats_for: tuple[tuple[str, int], ...] = ()   # (estimator name, repeats): its own count
    spp_for: tuple[tuple[str, tuple[int, ...]], ...] = ()   # (estimator name, its own spp levels)
    metrics: tuple[str, ...] = METRICS         # ΔE76 always; see harness.metrics
    sweep: dict | None = None                  # the resolved sweep and its source (manifest)

    def frames_of(self, scene_name: str):
        """The frame selection of one scene: its own (``frames_for``) or the sweep's."""
        return dict(self.frames_for).get(scene_name.lower(), self.frames)


def timing_seed(seed: int, repeat: int) -> int:
    """The seed of timing render ``repeat`` (1..MAX_REPEATS-1) of cell seed ``seed``: above
    every cell's seed and below the calibration and warm-up seeds, and distinct per cell seed,
    so that no timing render reuses a light pool another render drew."""
    return TIMING_SEED + (int(seed) << 8) + int(repeat)


def warm_up_gbuffer(gbuffer):
    """A G-buffer of at most ``WARMUP_PIXELS`` of ``gbuffer``'s covered pixels, specular where
    the scene is (so the warm-up compiles the same kernel variants)."""
    covered = np.flatnonzero(gbuffer.mask)
    keep = covered[:WARMUP_PIXELS].copy()
    specular = gbuffer.ks.reshape(-1, 3)[covered].max(axis=1) > 0
    if specular.any() and not specular[:WARMUP_PIXELS].any():
        keep[-1] = covered[np.argmax(specular)]
    mask = np.zeros(gbuffer.mask.size, bool)
    mask[keep] = True
    return dataclasses.replace(gbuffer, mask=mask.reshape(gbuffer.mask.shape))


def _device_record(compute) -> dict:
    info = compute.info
    return {"name": info.device.name.strip(), "platform": info.platform.name.strip(),
            "platform_version": info.platform.version.strip(),
            "driver": info.device.driver_version.strip(), "fp64": info.has_fp64}


def _require_unique_names(scenes) -> None:
    """Scene names key the results rows and the image folders, so two scenes may not share one."""
    seen = {}
    for scene in scenes:
        if scene.name in seen:
            raise InputError(scene.source or scene.name,
                             f"scene name '{scene.name}' is also the name of "
                             f"{seen[scene.name] or 'a built-in scene'}; rename one of the files")
        seen[scene.name] = scene.source


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


def _require_spp_within_bounds(specs, spp_of: dict) -> None:
    """Every spp of the sweep within each selected estimator's ``max_spp`` (``spp_of``: label →
    its spp levels), checked before anything is written (a render past the bound fails mid-run)."""
    for spec in specs:
        bound = spec.cls.max_spp
        above = [spp for spp in spp_of[spec.label] if bound is not None and spp > bound]
        if above:
            raise InputError(None, f"{argument('spp', max(above))} is above {spec.label}'s "
                                   f"limit of {bound} samples per pixel")


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


@dataclasses.dataclass
class _ScenePlan:
    scene: object
    width: int
    height: int
    env_res: int
    frames: list[int]


def _where(plan: _ScenePlan, frame: int) -> str:
    """The progress bar's name of a frame: the scene, and the frame in a sequence."""
    return plan.scene.name if len(plan.frames) == 1 else f"{plan.scene.name} f{frame}"


class Runner:
    """Runs every cell of the sweep not already in ``out`` (see the module docstring)."""

    def __init__(self, config: RunConfig):
        for spp in tuple(config.spp) + tuple(v for _, levels in config.spp_for for v in levels):
            if spp < 1:
                raise InputError(None, f"{argument('spp')} values must be positive integers, "
                                       f"got {spp}")
        if not 1 <= config.seeds <= MAX_SEEDS:
            raise InputError(None, f"{argument('seeds')} must be in 1..{MAX_SEEDS} (every seed "
                                   f"renders every cell again), got {config.seeds}")
        if not 0 <= config.first_seed <= MAX_SEED - config.seeds + 1:
            raise InputError(None, f"{argument('first_seed', config.first_seed)} with "
                                   f"{argument('seeds', config.seeds)}: the seeds must lie in "
                                   f"0..{MAX_SEED}")
        for name, repeats in (("default", config.repeats),) + tuple(config.repeats_for):
            if not 1 <= repeats <= MAX_REPEATS:
                raise InputError(None, f"{argument('repeats')} ({name}) must be in "
                                       f"1..{MAX_REPEATS}, got {repeats}")
        for budget in config.time_budget_ms:
            if not (math.isfinite(budget) and budget > 0):
                raise InputError(None, f"{argument('time_budget_ms')} must be positive, "
                                       f"got {budget}")
        if not config.spp and not config.time_budget_ms:
            raise InputError(None, "no spp and no time budget: the sweep has no cells")
        self.config = config
        self.seeds = range(config.first_seed, config.first_seed + config.seeds)
        self.specs = [parse_estimator(label) for label in config.estimators]
        labels = [spec.label for spec in self.specs]
        if len(set(labels)) != len(labels):
            raise InputError(None, f"an estimator is listed twice: {', '.join(labels)}")
        levels = {get_estimator_class(name).name: tuple(v) for name, v in config.spp_for}
        self.spp_levels = {spec.label: levels.get(spec.cls.name, tuple(config.spp))
                           for spec in self.specs}
        _require_spp_within_bounds(self.specs, self.spp_levels)
        self.scenes = [load_scene(name, sanitize=config.sanitize, env_res=config.env_res)
                       for name in config.scenes]
        _require_unique_names(self.scenes)
        for scene in self.scenes:
            if scene.environment.texels_fixed:
                print(f"iblbench: {argument('sanitize', True)} replaced "
                      f"{scene.environment.texels_fixed} bad texels "
                      f"in {scene.environment.source}", file=sys.stderr)
        self.plans = [self._plan_scene(scene) for scene in self.scenes]
        self.compute = get_compute(config.device)
        self.device_name = self.compute.device_name
        self.reference = Reference(self.compute)
        self.out = pathlib.Path(config.out)
        if self.out.exists() and not self.out.is_dir():
            raise InputError(self.out, f"{argument('out')} exists and is not a directory")
        self.params = {spec.label: spec.params_json() for spec in self.specs}
        overrides = {get_estimator_class(name).name: n for name, n in config.repeats_for}
        self.repeats = {spec.label: overrides.get(spec.cls.name, config.repeats)
                        for spec in self.specs}
        # The manifest's "stages" and "skipped": G-buffers may be traced before it is made.
        self.stages, self.skipped, self.visibility = [], [], []
        self.skipped += [{"stage": metric, "why": "not in the sweep's metrics: its columns are NaN"}
                         for metric in METRICS if metric not in config.metrics]

    def _read_state(self) -> None:
        """What ``out`` holds, read under its lock (a snapshot read before it could be stale by
        the time the run folds it back, and drop another run's cells): its rows, checked against
        this configuration, its manifest, and the plan of the cells left."""
        rows = read_results(self.out)
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
            remove_cells(self.out, dropped, kept)
            print(f"iblbench: {argument('force', True)}: removed the {len(dropped)} cells of "
                  f"another image configuration, rows, images and saved inputs "
                  f"({'; '.join(differences)})", file=sys.stderr)
            rows = kept
        self.rows = {row_key(row): row for row in rows}
        self.previous_manifest = read_manifest(self.out)
        self.todo, self.cells, self.chosen = self._plan_cells()
        self.total = len(self.cells)
        self.unverified = {}   # (scene, label, budget) → its calibration, until its first cell
        self.resumed = self.total - len(self.todo)
        self.manifest = self._new_manifest()

    def _plan_scene(self, scene) -> _ScenePlan:
        frames_available = scene.environment.num_frames
        if scene.environment.is_static:
            frames = [0]
        else:
            selection = self.config.frames_of(scene.name)
            frames = select_frames(selection, frames_available)
            if not frames:
                raise InputError(scene.source or scene.name,
                                 f"{argument('frames', frames_text(selection))} selects "
                                 f"no frame of scene '{scene.name}', which has {frames_available} "
                                 "frames")
            if max(frames) >= frames_available:
                raise InputError(scene.source or scene.name,
                                 f"frame {max(frames)} selected, but scene '{scene.name}' has "
                                 f"{frames_available} frames (0..{frames_available - 1})")
        width, height = self.config.resolution or scene.resolution
        env_res = int(np.shape(scene.environment.frame(frames[0]))[1])
        return _ScenePlan(scene, int(width), int(height), env_res, frames)

    # ---- planning ----------------------------------------------------------------------------

    def _variants(self, spec):
        """(spp, budget) of each cell family of ``spec``: its spp levels (``spp_for`` or the
        sweep's), then each time budget."""
        return ([(spp, None) for spp in self.spp_levels[spec.label]]
                + [(None, float(b)) for b in self.config.time_budget_ms])

    def _valid(self, row: dict | None, plan: _ScenePlan, spec) -> bool:
        """A row made with this configuration, code and device."""
        return (row is not None and row.get("schema_version") == SCHEMA_VERSION
                and row.get("estimator_version") == spec.cls.version()
                and row.get("estimator_params") == self.params[spec.label]
                and row.get("device") == self.device_name and row.get("protocol") == PROTOCOL
                and set(self.config.metrics) <= set(str(row.get("metrics")).split(","))
                and row.get("time_repeats", 0) >= self.repeats[spec.label]
                and (row.get("width"), row.get("height"), row.get("env_res"))
                == (plan.width, plan.height, plan.env_res)
                and cell_files_intact(self.out, row))

    def _plan_cells(self):
        """The keys of the cells to run, the keys of every cell of the sweep, and the spp earlier
        rows chose for each (scene, estimator, budget)."""
        todo, cells, chosen = set(), set(), {}
        for plan in self.plans:
            for spec in self.specs:
                for spp, budget in self._variants(spec):
                    for seed in self.seeds:
                        keys = [(plan.scene.name, spec.label, spp, frame, seed, budget)
                                for frame in plan.frames]
                        cells.update(keys)
                        done = [not self.config.force and self._valid(self.rows.get(k), plan, spec)
                                for k in keys]
                        if spec.cls.tags.temporal and not all(done):
                            todo.update(keys)       # a sequence is one unit of work
                        else:
                            todo.update(k for k, d in zip(keys, done) if not d)
                        if budget is not None:
                            for key, d in zip(keys, done):
                                if d:
                                    chosen[(plan.scene.name, spec.label, budget)] = int(
                                        self.rows[key]["spp"])
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
                       "metrics": list(c.metrics),
                       "save_inputs": c.save_inputs, "sanitize": c.sanitize, "env_res": c.env_res},
            "sweep": sweep,
            "protocol": PROTOCOL,
            "schema_version": SCHEMA_VERSION,
            "git_revision": git_revision(),
            "versions": {"iblbench": package_version("iblbench"), "python": platform.python_version(),
                         **{p: package_version(p) for p in ("numpy", "pyopencl", "embreex",
                                                            "colour-science", "pandas")}},
            "estimator_versions": {s.label: s.cls.version() for s in self.specs},
            "estimator_params": dict(self.params),
            "device": _device_record(self.compute),
            "sanitized": {p.scene.name: p.scene.environment.texels_fixed for p in self.plans},
            "runs": self._run_history(),
            "resumed_cells": self.resumed,
            "cells_to_run": len(self.todo),
            "stages": self.stages,
            "skipped": self.skipped,
            "visibility": self.visibility,
            "timing": {"measure": MEASURE, "repeats": dict(self.repeats),
                       "cell": "median of the cell's timed renders after warm-up: the "
                               "estimator's repeats, more where they spread (timing.spread); "
                               "min and IQR beside it (harness/protocol/timing.py)",
                       "context": "BLAS and OpenMP pools at one host thread for the whole run "
                                  "(threadpoolctl); a cell's repeats (or a calibration spp's "
                                  "renders) back to back before scoring",
                       "pocl_affinity": os.environ.get("POCL_AFFINITY"),
                       "warm_up": f"1 spp on {WARMUP_PIXELS} pixels per frame and estimator",
                       "wall": "wall_s: host wall time from the first frame's set-up to the "
                               "last cell's write; start-up (imports, "
                               "scenes, G-buffers, the device) before it; device_s: the run's "
                               "device time, timed renders, warm-ups, calibrations, builds and "
                               "references",
                       "temporal": "timing renders on repeats - 1 twin instances per "
                                   "sequence; the scored render is the real state's",
                       "spread": {"rule": f"a frame-by-frame estimator's cell whose renders' "
                                          f"IQR/median is above {SPREAD_LIMIT:.0%} gets one "
                                          f"more timed render at a time, up to {EXTENSION}x "
                                          "its repeats; its columns cover every render",
                                  "cells": 0, "extended_cells": 0, "wide_cells": 0}},
            "time_budget": ({"budgets_ms": list(c.time_budget_ms), "measure": MEASURE,
                             "model": "time = a_ms + b_ms_per_spp * spp, least squares on "
                                      "relative error over the median of "
                                      f"{CALIBRATION_REPEATS} renders per spp (more while "
                                      "they spread too wide), then refined on "
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
        gbuffers = ({} if self.out.exists()
                    else {plan.scene.name: self._trace(plan) for plan in self.plans})
        prepare_out(self.out)
        with _locked(self.out), host_threads_capped():
            self._read_state()
            for plan in self.plans:
                if plan.scene.name not in gbuffers and self._scene_todo(plan.scene.name):
                    gbuffers[plan.scene.name] = self._trace(plan)
            if self.resumed:
                print(f"resumed: {self.resumed} cells already done, {len(self.todo)} to run",
                      file=sys.stderr)
            _remove_stale_temporaries(self.out)
            self.journal = Journal(self.out)
            self._fold()   # a journal a killed run left becomes part of the table now
            self._last_fold = time.monotonic()
            self.manifest["status"] = "running"   # a killed run leaves this, not a missing manifest
            write_manifest(self.out, self.manifest)
            try:   # from here on a Ctrl-C, before the first cell too, ends "interrupted"
                table = self._run_cells(gbuffers)
            except KeyboardInterrupt:
                saved = len(self._save_interrupted())
                raise KeyboardInterrupt(f"{saved} cells saved; rerun to resume") from None
            finally:
                self.journal.close()
        return table

    def _run_cells(self, gbuffers: dict):
        """Every cell left, between two measurements of the timing floor; the manifest ends
        "complete"; returns the table."""
        with tqdm(total=self.total, unit="cell", disable=self._bar_disabled(),
                  bar_format=BAR_FORMAT, initial=self.resumed) as bar:
            self.progress = Progress(bar, self.todo)
            self.progress.stage(f"timing floor of {self.compute.info.device.name.strip()}")
            floors = [measure_timing_floor(self.compute)] if self.todo else []
            self.device_ms_total, start = 0.0, time.perf_counter()
            for plan in self.plans:
                self._run_scene(plan, gbuffers.pop(plan.scene.name, None))
        table = self._fold()
        if self.todo:
            wall_s = time.perf_counter() - start
            self.manifest["timing"].update(
                wall_s=wall_s, device_s=self.device_ms_total / 1e3,
                wall_per_device=wall_s / max(self.device_ms_total / 1e3, 1e-9))
            floors.append(measure_timing_floor(self.compute))
            self.manifest["timing"]["floor"] = {
                "kernel": f"fma_throughput, {floors[0].median_ms:.2g} ms, "
                          f"{floors[0].launches} launches back to back, at the run's start "
                          "and end (harness/protocol/timing.py, \"The device's own floor\")",
                "groups_within": [round(f.groups_within, 3) for f in floors],
                "p90_over_p10": [round(f.p90_over_p10, 3) for f in floors]}
        self._report_spread(floors)
        if self.config.time_budget_ms:
            self.manifest["time_budget"]["achieved"] = self._check_budgets(table)
        self.manifest["status"] = "complete"
        write_manifest(self.out, self.manifest)
        return table

    def sweep_rows(self, table):
        """The rows of ``table`` (after :meth:`run`) that are cells of this sweep: ``out`` may
        also hold other sweeps' cells."""
        return table[[row_key(row) in self.cells for row in table.to_dict("records")]]

    def _report_spread(self, floors) -> None:
        """Says how many cells needed more timed renders, how many stayed too wide, and, only
        where it was poor, how repeatable the device itself was (``floors``: TimingFloor at the
        start and end; the manifest and the report always have it)."""
        counts = self.manifest["timing"]["spread"]
        if counts["extended_cells"] or counts["wide_cells"]:
            print(f"iblbench: timing: {counts['extended_cells']} of {counts['cells']} cells got "
                  f"more timed renders (IQR/median above {SPREAD_LIMIT:.0%}, up to {EXTENSION}x "
                  f"the repeats); {counts['wide_cells']} stayed above it", file=sys.stderr)
        if any(floor.poor for floor in floors):
            print("iblbench: timing: the device itself was not repeatable (a fixed kernel "
                  f"launched back to back: {timing_floor_text(floors)}); compare times with "
                  "care", file=sys.stderr)

    def _check_budgets(self, table) -> list[dict]:
        """Each equal-time cell's time against its budget; prints those outside ±TOLERANCE."""
        timed = table[table.time_budget_ms.notna()]
        if timed.empty:
            return []
        keys = ["scene", "estimator", "time_budget_ms"]
        times = cell_times(timed, keys)
        spp = timed.groupby(keys, sort=False).spp.first()
        achieved = []
        for (scene, label, budget), ms in times.items():
            within = abs(ms - budget) <= TOLERANCE * budget
            achieved.append({"scene": scene, "estimator": label, "budget_ms": budget,
                             "spp": int(spp[(scene, label, budget)]), "time_ms": ms,
                             "within_tolerance": bool(within)})
            if not within:
                print(f"iblbench: {label} on {scene}: {ms:.3g} ms at {spp[(scene, label, budget)]}"
                      f" spp against the {budget:g} ms budget ({ms / budget - 1:+.0%}), outside "
                      f"±{TOLERANCE:.0%}", file=sys.stderr)
        return achieved

    def _save_interrupted(self):
        """Ctrl-C: fold the finished cells into the table and mark the manifest "interrupted"
        (a second Ctrl-C meanwhile is ignored, as it would lose them); returns the table."""
        with _sigint_ignored():
            table = self._fold()
            self.manifest["status"] = "interrupted"
            write_manifest(self.out, self.manifest)
        return table

    def _fold(self):
        self.journal.close()
        return write_results(self.out, list(self.rows.values()))

    def _bar_disabled(self):
        return None if self.config.progress is None else not self.config.progress

    def _scene_todo(self, name: str, frame: int | None = None) -> list[tuple]:
        return sorted((k for k in self.todo if k[0] == name and (frame is None or k[3] == frame)),
                      key=lambda k: (k[1], k[5] is not None, k[2] or 0, k[5] or 0, k[4]))

    def _trace(self, plan: _ScenePlan):
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
        with tqdm(total=gbuffer.covered, unit="px", disable=self._bar_disabled(), leave=False,
                  desc=f"{scene.name}: tracing visibility") as bar:
            gbuffer, record = attach_visibility(scene, gbuffer, plan.env_res, cache_dir() / "visibility",
                                                bar.update)
        if record is not None:
            record = measured_record(self.compute, scene, gbuffer,
                                     scene.environment.frame(plan.frames[0]), record)
            self.visibility.append(record)
            if record.get("cached") or "skipped" in record:
                self.skipped.append({"scene": scene.name, "stage": "visibility",
                                     "why": record.get("skipped", "cached")})
            else:
                self._stage(scene.name, None, "visibility", record["seconds"] * 1e3)
        return gbuffer

    def _run_scene(self, plan: _ScenePlan, gbuffer) -> None:
        """``gbuffer``: the scene's, traced by :meth:`run`; None when no cell of it is left."""
        scene = plan.scene
        if not self._scene_todo(scene.name):
            self.manifest["skipped"].append({"scene": scene.name, "stage": "scene",
                                             "why": "every cell already done (resumed)"})
            self.manifest["stages"] += [dict(stage, resumed=True) for stage
                                        in self.previous_manifest.get("stages", [])
                                        if stage.get("scene") == scene.name]
            self.visibility += [record for record in self.previous_manifest.get("visibility") or []
                                if record.get("scene") == scene.name]   # not traced again
            return
        inputs = self.out / "inputs" / scene.name
        if self.config.save_inputs:
            gbuffer.save_npz(inputs / "gbuffer.npz")
        device_gbuffer = DeviceGBuffer(self.compute, gbuffer)
        warm_up = DeviceGBuffer(self.compute, warm_up_gbuffer(gbuffer))
        required = {p for spec in self.specs for p in spec.cls.requires}
        for product in PRODUCTS:
            if product not in required and product != "env":
                self.manifest["skipped"].append({"scene": scene.name, "stage": product,
                                                 "why": "no selected estimator requires it"})
        sequences = {}   # temporal estimators: (label, spp, budget, seed) → [scored, twins...]
        self._previous_delta_e = {}   # (label, spp, budget, seed) → (frame, ΔE76 map): flicker
        cache, cache_env, cache_frame = None, None, None
        for index, frame in enumerate(plan.frames):
            if not self._scene_todo(scene.name, frame):
                self.manifest["skipped"].append({"scene": scene.name, "frame": frame,
                                                 "stage": "frame",
                                                 "why": "every cell already done (resumed)"})
                continue
            env = scene.environment.frame(frame)
            if self.config.save_inputs:
                with atomic_path(inputs / f"env_f{frame}.npy") as tmp:
                    np.save(tmp, np.asarray(env, np.float32))
            if cache is not None and env is cache_env:
                # The sequence returned the very same map as the frame the cache was built for.
                cache.retarget(frame)
                built = {}
                self.manifest["skipped"].append({
                    "scene": scene.name, "frame": frame, "stage": "framecache",
                    "why": f"environment identical to frame {cache_frame}'s: its FrameCache "
                           f"({', '.join(['upload'] + sorted(required))}) reused"})
            else:
                cache = None   # release the previous frame's device buffers first
                self.progress.stage("frame cache", _where(plan, frame))
                cache = FrameCache(self.compute, env, frame)
                cache.require(sorted(required))
                cache_env, cache_frame = env, frame
                built = {k: v for k, v in cache.timings_ms.items() if k != "pool"}
                for stage, ms in built.items():
                    self._stage(scene.name, frame, stage, ms)
                    self.device_ms_total += ms
            previous = plan.frames[index - 1] if index > 0 else None
            self._run_frame(plan, device_gbuffer, warm_up, cache, built, sequences,
                            previous)
        if scene.environment.is_static:
            renders = sum(1 for key in self.todo if key[0] == scene.name)
            self.manifest["skipped"].append({
                "scene": scene.name, "stage": "framecache",
                "why": f"static environment: one FrameCache built for frame 0 and reused by "
                       f"every estimator, spp and seed ({renders} cells)"})

    def _stage(self, scene: str, frame, stage: str, ms: float) -> None:
        self.stages.append({"scene": scene, "frame": frame, "stage": stage, "ms": ms})

    def _timed_renders(self, renderers, gbuffer, cache, spp: int, seeds,
                       build_ms: float) -> list[tuple]:
        """(estimate, TimedRender) per (renderer, seed) (:func:`timed_renders`), counted in the
        run's device time."""
        renders = timed_renders(renderers, gbuffer, cache, spp, seeds, build_ms)
        self.device_ms_total += sum(device_ms(e.timings_ms) for e, _ in renders)
        return renders

    def _run_frame(self, plan: _ScenePlan, gbuffer: DeviceGBuffer, warm_up: DeviceGBuffer,
                   cache: FrameCache, built: dict[str, float], sequences: dict,
                   previous_frame: int | None = None) -> None:
        """Every cell of one frame; ``warm_up``: the scene's warm-up pixels; ``built``: device
        ms per product built for this frame (empty where ``cache`` was reused from an identical
        earlier frame); ``previous_frame``: the frame before this one in the run's frame list
        (flicker), None on the first.  Each cell is rendered, scored, written and journalled,
        in that order (a journalled cell is complete)."""
        images = self.out / "images" / plan.scene.name / f"f{cache.frame}"
        where = _where(plan, cache.frame)
        self.progress.stage("reference", where)
        reference = self._frame_reference(plan.scene.name, gbuffer, cache)
        scorer = Scorer(reference, gbuffer.gbuffer.mask, self.config.metrics)
        write_exr(images / "reference.exr", reference)
        todo = self._scene_todo(plan.scene.name, cache.frame)
        for spec in self.specs:
            cells = [key for key in todo if key[1] == spec.label]
            if not cells:
                continue
            build_ms = required_build_ms(built, spec.cls.requires)
            estimator = spec.make()   # frame-by-frame estimators: a fresh instance per frame
            # Compiles and touches each kernel once (not timed).
            self.progress.stage("warm-up", where, spec.label)
            warmed = spec.make().render(warm_up, cache, 1, WARMUP_SEED)
            self.device_ms_total += device_ms(warmed.timings_ms)
            for key in cells:
                self.progress.start_cell(key)
                self.progress.stage("rendering")
                spp, estimates, renders, sequence_key = self._render_cell(
                    plan, spec, estimator, key, cells, gbuffer, cache, build_ms, sequences)
                self.progress.stage("scoring")
                row = self._score_cell(plan, spec, key, spp, estimates, renders, scorer,
                                       sequence_key, previous_frame)
                write_exr(images / f"{image_stem(row)}.exr", estimates[0].radiance)
                self._journal_cell(row)

    def _frame_reference(self, scene_name: str, gbuffer: DeviceGBuffer, cache: FrameCache):
        """The frame's exact reference, its stage timed or marked skipped (cached)."""
        reference = self.reference.image(gbuffer, cache)
        if self.reference.last_ms is None:
            self.manifest["skipped"].append({"scene": scene_name, "frame": cache.frame,
                                             "stage": "reference", "why": "cached"})
        else:
            self._stage(scene_name, cache.frame, "reference", self.reference.last_ms)
            self.device_ms_total += self.reference.last_ms
        return reference

    def _render_cell(self, plan: _ScenePlan, spec, estimator, key, cells, gbuffer, cache,
                     build_ms: float, sequences: dict):
        """A cell's timed renders: (spp, the estimates of its planned renders, the scored one
        first, every TimedRender, the key of its sequence).  An equal-time cell takes the spp
        calibrated for it (just before its first cell); a temporal estimator renders on the
        instances that carry its sequence."""
        _, label, spp, frame, seed, budget = key
        repeats = self.repeats[spec.label]
        budget_key = (plan.scene.name, label, budget)
        if budget is not None:
            if budget_key not in self.chosen:   # calibrated just before its cells
                self._calibrate(spec, estimator, gbuffer, cache, cells, build_ms)
            spp = self.chosen[budget_key]
        sequence_key = (label, key[2], budget, seed)
        if spec.cls.tags.temporal:
            if sequence_key not in sequences:
                sequences[sequence_key] = [spec.make() for _ in range(repeats)]
                for instance in sequences[sequence_key]:
                    instance.reset()
            renderers = sequences[sequence_key]
        else:
            renderers = [estimator] * repeats
        timed = self._cell_renders(spec, renderers, gbuffer, cache, spp, seed, build_ms)
        if budget_key in self.unverified:
            spp, timed = self._correct_budget_cell(budget_key, spec, renderers, gbuffer,
                                                   cache, spp, seed, build_ms, timed)
        renders = [render for _, render in timed]
        self._count_spread(renders, repeats)
        # Renders added for a wide spread are timed, not scored: the replicates a row carries
        # must not depend on the machine's noise.
        return spp, [estimate for estimate, _ in timed[:repeats]], renders, sequence_key

    def _score_cell(self, plan: _ScenePlan, spec, key, spp: int, estimates, renders,
                    scorer: Scorer, sequence_key, previous_frame: int | None) -> dict:
        """The cell's results row: the scored render's (``estimates[0]``) metrics against the
        reference, every planned render's errors (the replicates), its time columns and its
        flicker against the previous frame of its sequence."""
        _, label, _, frame, seed, budget = key
        estimate, mask = estimates[0], scorer.mask
        metrics, delta_e = scorer.score(estimate)
        others = [scorer.errors(other.radiance)[0] for other in estimates[1:]]
        replicates = {metric + RENDERS: renders_text([metrics[metric]]
                                                     + [errors[metric] for errors in others])
                      if math.isfinite(metrics[metric]) else "" for metric in REPLICATED}
        row = {
            "scene": plan.scene.name, "estimator": label, "spp": int(spp), "frame": frame,
            "seed": seed, "time_budget_ms": float("nan") if budget is None else budget,
            "width": plan.width, "height": plan.height, "env_res": plan.env_res,
            "estimator_params": self.params[label],
            "estimator_version": spec.cls.version(), "schema_version": SCHEMA_VERSION,
            "metrics": ",".join(self.config.metrics),
            **metrics, **replicates, **time_columns(renders),
            "device": self.device_name, "protocol": PROTOCOL,
        }
        # Estimator-specific per-frame scalars (e.g. smc's ess, reinits): extra columns
        # after the fixed ones; they never replace a fixed column.
        row.update({name: float(value) for name, value in estimate.extras.items()
                    if name not in row})
        stem = image_stem(row)
        row["flicker"] = flicker(delta_e, self._previous_map(
            plan, sequence_key, previous_frame, stem, mask), mask)
        self._previous_delta_e[sequence_key] = (frame, delta_e.astype(np.float32))
        return row

    def _journal_cell(self, row: dict) -> None:
        """The row goes to the journal (after its images: a journalled cell is complete), and
        the journal is folded into the table every FOLD_SECONDS."""
        self.journal.append(row)
        self.rows[row_key(row)] = row
        self.progress.cell_done(row["spp"])
        if time.monotonic() - self._last_fold > FOLD_SECONDS:
            self._fold()
            self._last_fold = time.monotonic()

    def _cell_renders(self, spec, renderers, gbuffer, cache, spp: int, seed: int,
                      build_ms: float) -> list[tuple]:
        """(estimate, TimedRender) of a cell's renders, back to back before scoring: render 0
        the scored one (seed ``seed``), one timing render per other renderer, then, for a
        frame-by-frame estimator whose renders spread wider than ``SPREAD_LIMIT``, one more at
        a time until they do not or there are ``EXTENSION`` × repeats (module docstring)."""
        seeds = [seed] + [timing_seed(seed, r) for r in range(1, len(renderers))]
        timed = self._timed_renders(renderers, gbuffer, cache, spp, seeds, build_ms)
        limit = (len(renderers) if spec.cls.tags.temporal
                 else min(MAX_REPEATS, EXTENSION * len(renderers)))
        while len(timed) < limit and too_wide([render for _, render in timed]):
            timed += self._timed_renders(renderers[:1], gbuffer, cache, spp,
                                         [timing_seed(seed, len(timed))], build_ms)
        return timed

    def _count_spread(self, renders, repeats: int) -> None:
        """The run's count of cells that got more renders, and of those still too wide."""
        counts = self.manifest["timing"]["spread"]
        counts["cells"] += 1
        counts["extended_cells"] += len(renders) > repeats
        counts["wide_cells"] += too_wide(renders)

    def _correct_budget_cell(self, budget_key: tuple, spec, renderers, gbuffer, cache, spp: int,
                             seed: int, build_ms: float, timed: list) -> tuple[int, list]:
        """The first cell of a budget this run calibrated, timed at the calibrated spp
        (``timed``), corrected on its own time: up to ``CELL_CORRECTIONS`` steps of
        :func:`corrected_spp` over the cell's measured spp, each rendering the cell again from
        ``reset()`` (it is the first frame the renderers see); then the best of those spp
        (:func:`best_measured`), rendered once more where it was not the last; the last
        rendering is the cell, and its spp the budget's for every other cell (module docstring,
        "Equal time")."""
        fit = self.unverified.pop(budget_key)
        measured = {}   # spp → the cell's median device ms there
        for correction in range(CELL_CORRECTIONS + 2):
            measured[spp] = float(np.median([device_ms(render.stages) for _, render in timed]))
            fit["cell_runs"].append({"spp": spp, "median_device_ms": measured[spp]})
            step = (corrected_spp(fit["a_ms"], measured, spp, fit["budget_ms"], spp_limit(spec.cls))
                    if correction < CELL_CORRECTIONS else None)
            if step is None or step in measured:
                step = best_measured(measured, fit["budget_ms"])
                if step == spp or correction > CELL_CORRECTIONS:
                    break
            for renderer in set(renderers):
                renderer.reset()
            spp = step
            timed = self._cell_renders(spec, renderers, gbuffer, cache, spp, seed, build_ms)
        fit["chosen_spp"] = self.chosen[budget_key] = spp
        return spp, timed

    def _previous_map(self, plan: _ScenePlan, sequence_key: tuple, previous_frame: int | None,
                      stem: str, mask: np.ndarray) -> np.ndarray | None:
        """The ΔE76 map of ``previous_frame`` for one (estimator, spp, budget, seed): from memory,
        or, when that frame was done by an earlier (resumed) run, recomputed from its saved
        estimate and reference EXRs; None on the first frame or when those files are gone."""
        if previous_frame is None:
            return None
        kept = self._previous_delta_e.get(sequence_key)
        if kept is not None and kept[0] == previous_frame:
            return kept[1]
        folder = self.out / "images" / plan.scene.name / f"f{previous_frame}"
        try:
            estimate = read_exr(folder / f"{stem}.exr")
            reference = read_exr(folder / "reference.exr")
        except InputError:
            return None
        if estimate.shape[:2] != mask.shape or reference.shape[:2] != mask.shape:
            return None
        estimate = np.where(np.isfinite(estimate), estimate, 0.0)
        return delta_e_images(estimate, reference, mask)[0]

    def _calibrate(self, spec, estimator, gbuffer, cache, cells, build_ms: float) -> None:
        """Choose the spp of every budget of this estimator not chosen yet (module docstring);
        ``build_ms``: the frame's build time for this estimator."""
        scene_name = cells[0][0]
        budgets = sorted({key[5] for key in cells if key[5] is not None
                          and (scene_name, spec.label, key[5]) not in self.chosen})
        if not budgets:
            return
        self.progress.stage("calibrating")
        calibration = Calibration(estimator, gbuffer, cache, build_ms)
        for budget in budgets:
            fit = calibration.choose(budget)
            key = (scene_name, spec.label, budget)
            self.chosen[key] = fit["chosen_spp"]
            entry = {"scene": scene_name, "estimator": spec.label, "frame": cache.frame,
                     **fit, "calibrated_spp": fit["chosen_spp"], "cell_runs": []}
            self.unverified[key] = entry
            self.manifest["time_budget"]["calibrations"].append(entry)
            if fit["over_budget"] and fit["chosen_spp"] == 1:
                print(f"iblbench: {spec.label} on {scene_name}: even 1 spp takes "
                      f"{fit['measured_ms']:.3g} ms > the {budget:g} ms budget; running 1 spp",
                      file=sys.stderr)
        self.device_ms_total += sum(device_ms(r.stages) - build_ms for r in calibration.renders)
        estimator.reset()
        self.progress.stage("rendering")


def run(config: RunConfig):
    """Run a benchmark; returns the results table (also written under ``config.out``)."""
    return Runner(config).run()
