"""Renders, scores and writes the cells it is given, on one device: the part of a run that does
not care where the run's table lives or who else renders.

The runner (:mod:`.runner`) plans a sweep, keeps its journal and manifest and hands cells to an
``Executor``: in process, all of them to one executor on the run's own device; on a Dask cluster
(:mod:`.distributed`), each unit of work to the executor of the worker that took it.  An
executor writes the cell's images into the run's folder (through atomic renames) and gives each
finished row to its caller; it never writes the results table, the journal or the manifest.
Its manifest records (stages built, stages skipped, calibrations, the timing spread's counts,
device time) are collected by :meth:`Executor.drain`.

The cell's work is the runner module's docstring ("Timing", "Equal time", "Scores", "Flicker"):
per frame a FrameCache (reused while the next frame is the same scene's same frame, or the very
same map), the exact reference, a warm-up per estimator (and its budgets' calibration), then the
cells' timed renders in interleaved rounds, each round scored after its renders (render 0's EXR
written), then each cell's row.

**Rounds** (issue 32; the timing module's "Rounds"): round r renders render r of every cell of
the frame, so a cell's renders fall in different spells of the device.  Only the frame's cells
go round: a frame's cells share its cache, and a temporal estimator's twins must each render
the frame once before the next.  A round's renders run back to back and are scored after it,
so no host work comes between two renders.  A cell's row is given once its last round is done,
so a killed run loses the frame in flight.  Rows name the ``host`` and the ``device`` that made
them, and their times are that device's.

An executor keeps, between calls of :meth:`Executor.render`, what does not depend on the cells:
the scene's G-buffer on the device and the last frame's cache.  What a cell depends on comes in
with its keys: the seed (so nothing depends on which process rendered a cell), an equal-time
budget's chosen spp (``chosen``) and, for flicker, the ΔE76 map of the frame before the first
one given (``maps``).
"""
from __future__ import annotations

import dataclasses
import math
import pathlib
import platform
import time

import numpy as np

from iblbench.estimators.runtime.device import cache_dir
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.light_pool import TICKS_PER_SAMPLE, PoolEstimator
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.pool_reads import pool_reads
from iblbench.estimators.runtime.reference import Reference
from iblbench.harness.protocol.equal_time import (CELL_CORRECTIONS, Calibration, best_measured,
                                                  corrected_spp, spp_limit)
from iblbench.harness.protocol.metrics import PROTOCOL, Scorer, delta_e_images, flicker
from iblbench.harness.protocol.report_inputs import (SEED as PICTURE_SEED, PoolPicture,
                                                     picture_spp, write_pool_picture,
                                                     write_surface)
from iblbench.harness.protocol.results import REPLICATED, SCHEMA_VERSION, image_stem
from iblbench.harness.protocol.run_plan import (TIMING_SEED, RunConfig, RunPlan, ScenePlan,
                                                cell_order, sequence_key)
from iblbench.harness.protocol.shadows import attach_visibility
from iblbench.harness.protocol.stats import RENDERS, renders_text
from iblbench.harness.protocol.timing import (device_ms, required_build_ms, robust_ms, round_orders,
                                              time_columns, timed_renders, too_wide)
from iblbench.foundation.errors import InputError
from iblbench.scenes.gbuffer import cached_trace
from iblbench.scenes.imageio import read_exr, write_exr

WARMUP_SEED = 0xFFFFFFFF   # a seed no benchmark cell uses
WARMUP_PIXELS = 64


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


def device_record(compute) -> dict:
    """The manifest's record of a device, with the host it is on, and how the kernels ran there:
    their lane width and launch shape, which set a cell's time as much as the device does."""
    info = compute.info
    return {"name": info.device.name.strip(), "platform": info.platform.name.strip(),
            "platform_version": info.platform.version.strip(),
            "driver": info.device.driver_version.strip(), "fp64": info.has_fp64,
            "lanes": compute.pool_lanes, "launch_shape": compute.launch_shape,
            "host": platform.node()}


def where(plan: ScenePlan, frame: int) -> str:
    """The progress bar's name of a frame: the scene, and the frame in a sequence."""
    return plan.scene.name if len(plan.frames) == 1 else f"{plan.scene.name} f{frame}"


class CellClock:
    """The progress of an executor that shows no bar (a worker's): each cell's host seconds,
    for its client's time left (:meth:`iblbench.harness.protocol.progress.Progress.finished`)."""

    def __init__(self):
        self.seconds: dict[tuple, float] = {}

    def stage(self, stage: str, *where: str) -> None:
        pass

    def finished(self, key: tuple, seconds: float) -> None:
        self.seconds[key] = seconds


def _new_records() -> dict:
    """An executor's manifest records before its first cell (:meth:`Executor.drain`)."""
    return {"stages": [], "skipped": [], "calibrations": [], "warnings": [], "device_ms": 0.0,
            "spread": {"cells": 0, "wide_cells": 0}}


@dataclasses.dataclass
class _HeldCache:
    """The frame cache an executor keeps: built for ``built_frame``, now targeted at ``frame``."""
    scene: str
    built_frame: int
    frame: int
    env: object
    cache: FrameCache
    built: dict[str, float]   # device ms per product built


@dataclasses.dataclass
class _Cell:
    """One cell of a frame while its renders go round: what it renders, and what it has so
    far (every TimedRender; render 0's metrics, ΔE76 map and extras; each later render's
    errors; the host seconds it took)."""
    spec: object
    key: tuple
    spp: int
    renderers: list
    seeds: list[int]
    sequence: tuple
    build_ms: float
    renders: list = dataclasses.field(default_factory=list)
    metrics: dict | None = None
    delta_e: np.ndarray | None = None
    extras: dict = dataclasses.field(default_factory=dict)
    errors: list = dataclasses.field(default_factory=list)
    seconds: float = 0.0

    def stem(self) -> str:
        """The file stem of the cell's image (:func:`image_stem`)."""
        _, label, _, _, seed, budget = self.key
        return image_stem({"estimator": label, "spp": self.spp, "seed": seed,
                           "time_budget_ms": math.nan if budget is None else budget})


class Executor:
    """Renders the cells it is given on ``compute`` (module docstring)."""

    def __init__(self, config: RunConfig, plan: RunPlan, compute, progress=None, warn=None):
        """``warn``: called with a warning's text as it happens (default: kept in the records
        for :meth:`drain`, for a worker's client to print)."""
        self.config, self.plan, self.compute = config, plan, compute
        self.warn = warn or (lambda text: self._records["warnings"].append(text))
        self.out = pathlib.Path(config.out)
        self.reference = Reference(compute)
        self.device_name = compute.device_name
        self.host = platform.node()
        self.progress = progress or CellClock()
        self.chosen = {}       # (scene, label, budget) → the spp chosen for it
        self.unverified = {}   # (scene, label, budget) → its calibration, until its first cell
        self.gbuffers = {}     # scene name → its traced G-buffer, where the caller has it
        self._device = None    # (scene name, DeviceGBuffer, its warm-up pixels' DeviceGBuffer)
        self._held: _HeldCache | None = None
        self._previous_delta_e = {}   # (scene, label, spp, budget, seed) → (frame, ΔE76 map)
        self._records = _new_records()

    def drain(self) -> dict:
        """The manifest records gathered since the last call (module docstring), and the
        warnings for the run's terminal."""
        records, self._records = self._records, _new_records()
        return records

    def render(self, todo, on_row, maps: dict | None = None) -> dict:
        """Render, score and write the cells ``todo`` (keys: scene, estimator, spp, frame, seed,
        budget), scene by scene, frames in order, giving each finished row to ``on_row`` after
        its images are written; ``maps``: the ΔE76 maps, (frame, map) by (scene, label, spp,
        budget, seed), of the frames before ``todo``'s first ones (flicker).  Returns the ΔE76
        map of the last frame rendered of each of those sequences."""
        self._previous_delta_e = dict(maps or {})
        for plan in self.plan.plans:
            keys = [key for key in todo if key[0] == plan.scene.name]
            if keys:
                self._previous_delta_e = {k: v for k, v in self._previous_delta_e.items()
                                          if k[0] == plan.scene.name}
                self._run_scene(plan, keys, on_row)
        return self._previous_delta_e

    def _run_scene(self, plan: ScenePlan, keys: list, on_row) -> None:
        gbuffer, warm_up = self._device_gbuffers(plan)
        write_surface(self.out, plan.scene.name, gbuffer.gbuffer.normal, gbuffer.gbuffer.mask)
        required = sorted({p for spec in self.plan.specs for p in spec.cls.requires})
        sequences = {}   # temporal estimators: (label, spp, budget, seed) → [scored, twins...]
        for index, frame in enumerate(plan.frames):
            frame_keys = sorted((key for key in keys if key[3] == frame), key=cell_order)
            if not frame_keys:
                continue
            cache, built = self._frame_cache(plan, frame, required)
            previous = plan.frames[index - 1] if index > 0 else None
            self._run_frame(plan, gbuffer, warm_up, cache, built, sequences, previous,
                            frame_keys, on_row)

    def _device_gbuffers(self, plan: ScenePlan):
        """The scene's G-buffer and its warm-up pixels on the device, made once per scene."""
        name = plan.scene.name
        if self._device is None or self._device[0] != name:
            self._device = self._held = None   # release the previous scene's buffers first
            gbuffer = self.gbuffers.pop(name, None) or self._read_gbuffer(plan)
            self._device = (name, DeviceGBuffer(self.compute, gbuffer),
                            DeviceGBuffer(self.compute, warm_up_gbuffer(gbuffer)))
        return self._device[1:]

    @staticmethod
    def _read_gbuffer(plan: ScenePlan):
        """The scene's G-buffer and masks from the on-disk caches the client filled (traced here
        where this machine does not share them)."""
        scene = plan.scene
        gbuffer, _ = cached_trace(scene.mesh, scene.material, scene.camera, plan.width,
                                  plan.height, cache_dir() / "gbuffer")
        return attach_visibility(scene, gbuffer, plan.env_res, cache_dir() / "visibility")[0]

    def _frame_cache(self, plan: ScenePlan, frame: int, required: list[str]):
        """(FrameCache, device ms per product built for it) of ``frame``: the one held where it
        was built for this frame or for the very same map (the sequence returned the same
        array: then nothing is built, and ``skipped`` says so), else built now."""
        name, env = plan.scene.name, plan.scene.environment.frame(frame)
        held = self._held
        if held is not None and held.scene == name and (frame == held.built_frame
                                                        or env is held.env):
            if held.frame != frame:
                held.cache.retarget(frame)
                held.frame = frame
                if frame != held.built_frame:
                    self._records["skipped"].append({
                        "scene": name, "frame": frame, "stage": "framecache",
                        "why": f"environment identical to frame {held.built_frame}'s: its "
                               f"FrameCache ({', '.join(['upload'] + required)}) reused"})
            return held.cache, (held.built if frame == held.built_frame else {})
        self._held = None   # release the previous frame's device buffers first
        self.progress.stage("frame cache", where(plan, frame))
        cache = FrameCache(self.compute, env, frame)
        cache.require(required)
        built = {k: v for k, v in cache.timings_ms.items() if k != "pool"}
        for stage, ms in built.items():
            self._stage(name, frame, stage, ms)
            self._records["device_ms"] += ms
        self._held = _HeldCache(name, frame, frame, env, cache, built)
        return cache, built

    def _stage(self, scene: str, frame, stage: str, ms: float) -> None:
        self._records["stages"].append({"scene": scene, "frame": frame, "stage": stage, "ms": ms})

    def _timed_renders(self, renderers, gbuffer, cache, spp: int, seeds,
                       build_ms: float) -> list[tuple]:
        """(estimate, TimedRender) per (renderer, seed) (:func:`timed_renders`), counted in the
        run's device time."""
        renders = timed_renders(renderers, gbuffer, cache, spp, seeds, build_ms)
        self._records["device_ms"] += sum(device_ms(e.timings_ms) for e, _ in renders)
        return renders

    def _run_frame(self, plan: ScenePlan, gbuffer: DeviceGBuffer, warm_up: DeviceGBuffer,
                   cache: FrameCache, built: dict[str, float], sequences: dict,
                   previous_frame: int | None, todo: list, on_row) -> None:
        """The cells ``todo`` of one frame; ``warm_up``: the scene's warm-up pixels; ``built``:
        device ms per product built for this frame (empty where ``cache`` was reused from an
        identical earlier frame); ``previous_frame``: the frame before this one in the run's
        frame list (flicker), None on the first.  Every estimator is warmed up (and its budgets
        calibrated) first; then the cells' renders go in interleaved rounds (module docstring,
        "Rounds"), each round scored after its renders; then each cell's row is given to ``on_row``
        (a row given is a complete cell)."""
        images = self.out / "images" / plan.scene.name / f"f{cache.frame}"
        here = where(plan, cache.frame)
        self.progress.stage("reference", here)
        reference = self._frame_reference(plan.scene.name, gbuffer, cache)
        scorer = Scorer(reference, gbuffer.gbuffer.mask, self.config.metrics)
        write_exr(images / "reference.exr", reference)
        cells = []
        for spec in self.plan.specs:
            keys = [key for key in todo if key[1] == spec.label]
            if not keys:
                continue
            build_ms = required_build_ms(built, spec.cls.requires)
            estimator = spec.make()   # frame-by-frame estimators: a fresh instance per frame
            # Compiles and touches each kernel once (not timed).
            self.progress.stage("warm-up", here, spec.label)
            warmed = spec.make().render(warm_up, cache, 1, WARMUP_SEED)
            self._records["device_ms"] += device_ms(warmed.timings_ms)
            cells += [self._prepare_cell(plan, spec, estimator, key, keys, gbuffer, cache,
                                         build_ms, sequences) for key in keys]
        rounds = max(len(cell.renderers) for cell in cells)
        # Each round in its own order, the same in every run (timing.round_orders).
        shuffle = round_orders(cache.frame)
        for turn in range(rounds):
            self.progress.stage(f"rendering, round {turn + 1} of {rounds}", here)
            going = [cells[i] for i in shuffle(len(cells)) if turn < len(cells[i].renderers)]
            # The round's renders back to back, then their scores: host work between two
            # renders made every render the first after it (timing module, "Rounds").  After
            # render 0 only the radiance is scored, and only it is held through the round.
            estimates = [self._render_turn(cell, turn, gbuffer, cache) for cell in going]
            for cell, estimate in zip(going, estimates):
                self._score_turn(cell, turn, estimate, scorer, images)
        # Before the rows: a run stopped between the two redoes the frame, so no journalled
        # frame is left without its picture.
        self._save_pool_picture(plan, gbuffer.gbuffer, cache)
        for cell in cells:
            row = self._row(plan, cell, scorer, previous_frame)
            on_row(row)
            self.progress.finished(cell.key, cell.seconds)

    def _save_pool_picture(self, plan: ScenePlan, gbuffer, cache: FrameCache) -> None:
        """The frame's sample-picture inputs for the report (:mod:`.report_inputs`): the pool
        of the shared-sequence pool estimators at the picture's spp and every pixel's split;
        after the frame's renders, so that building its pool times no cell, and before its rows
        are handed on."""
        pool_estimators = {spec.label: instance for spec in self.plan.specs
                           for instance in [spec.make()] if isinstance(instance, PoolEstimator)}
        pooled = {label: instance for label, instance in pool_estimators.items()
                  if instance.params.shared_sequence}
        levels = {label: set(spp) for label, spp in self.plan.spp_levels.items() if spp}
        if not levels:   # an equal-time run: its cells' spp are the ones its budgets chose
            for (scene, label, _), spp in self.chosen.items():
                if scene == plan.scene.name:
                    levels.setdefault(label, set()).add(spp)
        spp = picture_spp(levels, pooled)
        if spp is None:
            return
        normal = gbuffer.normal.astype(np.float64)
        length = np.linalg.norm(normal, axis=-1, keepdims=True)
        normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
        reads = pool_reads(cache, pooled, normal.reshape(-1, 3), spp, PICTURE_SEED)
        first = next(iter(reads.values()))
        write_pool_picture(self.out, plan.scene.name, cache.frame, PoolPicture(
            np.asarray(plan.scene.environment.frame(cache.frame), np.float32), spp,
            first.directions, first.per_face, first.face_integrals, TICKS_PER_SAMPLE,
            {label: read.ticks.reshape(*normal.shape[:2], 7) for label, read in reads.items()},
            tuple(label for label in pool_estimators if label not in pooled)))

    def _prepare_cell(self, plan: ScenePlan, spec, estimator, key, cells, gbuffer, cache,
                      build_ms: float, sequences: dict) -> "_Cell":
        """A cell before its renders: its spp (an equal-time cell's, calibrated and corrected
        before its budget's first cell), its renderers (a temporal estimator's: the instances
        that carry its sequence) and their seeds (render 0 the scored one, the cell's seed)."""
        _, label, spp, frame, seed, budget = key
        repeats = self.plan.repeats[spec.label]
        budget_key = (plan.scene.name, label, budget)
        sequence = sequence_key(key)
        if spec.cls.tags.temporal:
            if sequence not in sequences:
                sequences[sequence] = [spec.make() for _ in range(repeats)]
                for instance in sequences[sequence]:
                    instance.reset()
            renderers = sequences[sequence]
        else:
            renderers = [estimator] * repeats
        seeds = [seed] + [timing_seed(seed, r) for r in range(1, len(renderers))]
        if budget is not None:
            if budget_key not in self.chosen:   # calibrated just before its cells
                self._calibrate(spec, estimator, gbuffer, cache, cells, build_ms)
            if budget_key in self.unverified:
                self._correct_budget(budget_key, spec, renderers, gbuffer, cache, seeds, build_ms)
            spp = self.chosen[budget_key]
        return _Cell(spec, key, spp, renderers, seeds, sequence, build_ms)

    def _render_turn(self, cell: "_Cell", turn: int, gbuffer, cache):
        """Render ``turn`` of ``cell``, timed; its estimate."""
        start = time.perf_counter()
        [(estimate, render)] = self._timed_renders(
            cell.renderers[turn:turn + 1], gbuffer, cache, cell.spp, cell.seeds[turn:turn + 1],
            cell.build_ms)
        cell.renders.append(render)
        cell.seconds += time.perf_counter() - start
        return estimate if turn == 0 else estimate.radiance

    def _score_turn(self, cell: "_Cell", turn: int, estimate, scorer: Scorer,
                    images: pathlib.Path) -> None:
        """Score render ``turn`` of ``cell`` (``estimate``: render 0's Estimate, a later
        render's radiance): render 0 in full (its EXR written), the others on the replicated
        errors (``Scorer.errors``)."""
        start = time.perf_counter()
        if turn == 0:
            cell.metrics, cell.delta_e = scorer.score(estimate)
            cell.extras = dict(estimate.extras)
            write_exr(images / f"{cell.stem()}.exr", estimate.radiance)
        else:
            cell.errors.append(scorer.errors(estimate)[0])
        cell.seconds += time.perf_counter() - start

    def _row(self, plan: ScenePlan, cell: "_Cell", scorer: Scorer,
             previous_frame: int | None) -> dict:
        """The cell's results row: the scored render's metrics against the reference, every
        render's errors (the replicates), its time columns and its flicker against the previous
        frame of its sequence."""
        _, label, _, frame, seed, budget = cell.key
        spec, metrics = cell.spec, cell.metrics
        replicates = {metric + RENDERS: renders_text([metrics[metric]]
                                                     + [errors[metric] for errors in cell.errors])
                      if math.isfinite(metrics[metric]) else "" for metric in REPLICATED}
        counts = self._records["spread"]
        counts["cells"] += 1
        counts["wide_cells"] += too_wide(cell.renders)
        row = {
            "scene": plan.scene.name, "estimator": label, "spp": int(cell.spp), "frame": frame,
            "seed": seed, "time_budget_ms": float("nan") if budget is None else budget,
            "width": plan.width, "height": plan.height, "env_res": plan.env_res,
            "estimator_params": self.plan.params[label],
            "estimator_version": spec.cls.version(), "schema_version": SCHEMA_VERSION,
            "metrics": ",".join(self.config.metrics),
            **metrics, **replicates, **time_columns(cell.renders),
            "device": self.device_name, "host": self.host, "protocol": PROTOCOL,
        }
        # Estimator-specific per-frame scalars (e.g. smc's ess, reinits): extra columns
        # after the fixed ones; they never replace a fixed column.
        row.update({name: float(value) for name, value in cell.extras.items()
                    if name not in row})
        row["flicker"] = flicker(cell.delta_e, self._previous_map(
            plan, cell.sequence, previous_frame, cell.stem(), scorer.mask), scorer.mask)
        self._previous_delta_e[cell.sequence] = (frame, cell.delta_e.astype(np.float32))
        return row

    def _correct_budget(self, budget_key: tuple, spec, renderers, gbuffer, cache, seeds: list,
                        build_ms: float) -> None:
        """Before the first cell of a budget this run calibrated: the cell's renders, back to
        back at the calibrated spp, corrected on their own time, up to ``CELL_CORRECTIONS``
        steps of :func:`corrected_spp` over the spp measured; the best of those
        (:func:`best_measured`) is the budget's spp for every cell.  The renderers start from
        ``reset()`` again after each rendering (it is the first frame they see), so the cells
        render as if the correction had not happened (module docstring, "Equal time")."""
        fit = self.unverified.pop(budget_key)
        spp, measured = self.chosen[budget_key], {}   # spp → the cell's robust device ms there
        for correction in range(CELL_CORRECTIONS + 1):
            timed = self._timed_renders(renderers, gbuffer, cache, spp, seeds, build_ms)
            for renderer in set(renderers):
                renderer.reset()
            measured[spp] = robust_ms([device_ms(render.stages) for _, render in timed])
            fit["cell_runs"].append({"spp": spp, "median_device_ms": measured[spp]})
            if correction == CELL_CORRECTIONS:
                break
            step = corrected_spp(fit["a_ms"], measured, spp, fit["budget_ms"], spp_limit(spec.cls))
            if step is None or step in measured:
                break
            spp = step
        fit["chosen_spp"] = self.chosen[budget_key] = best_measured(measured, fit["budget_ms"])

    def _frame_reference(self, scene_name: str, gbuffer: DeviceGBuffer, cache: FrameCache):
        """The frame's exact reference, its stage timed or marked skipped (cached)."""
        reference = self.reference.image(gbuffer, cache)
        if self.reference.last_ms is None:
            self._records["skipped"].append({"scene": scene_name, "frame": cache.frame,
                                             "stage": "reference", "why": "cached"})
        else:
            self._stage(scene_name, cache.frame, "reference", self.reference.last_ms)
            self._records["device_ms"] += self.reference.last_ms
        return reference

    def _previous_map(self, plan: ScenePlan, sequence: tuple, previous_frame: int | None,
                      stem: str, mask: np.ndarray) -> np.ndarray | None:
        """The ΔE76 map of ``previous_frame`` for one (estimator, spp, budget, seed): from memory,
        or, when that frame was done by an earlier (resumed) run, recomputed from its saved
        estimate and reference EXRs; None on the first frame or when those files are gone."""
        if previous_frame is None:
            return None
        kept = self._previous_delta_e.get(sequence)
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
                     "device": self.device_name, **fit, "calibrated_spp": fit["chosen_spp"],
                     "cell_runs": []}
            self.unverified[key] = entry
            self._records["calibrations"].append(entry)
            if fit["over_budget"] and fit["chosen_spp"] == 1:
                self.warn(
                    f"{spec.label} on {scene_name}: even 1 spp takes {fit['measured_ms']:.3g} "
                    f"ms > the {budget:g} ms budget; running 1 spp")
        self._records["device_ms"] += sum(device_ms(r.stages) - build_ms
                                          for r in calibration.renders)
        estimator.reset()
