"""What a run plans from what it is asked to do (:class:`RunConfig`, defined in
:mod:`.run_config`): each scene's image and frames (:class:`ScenePlan`) and the estimators'
settings (:class:`RunPlan`).

The client of a run (:mod:`.runner`) and every worker that renders its cells (:mod:`.executor`,
:mod:`.distributed`) plan from the same ``RunConfig`` with :func:`plan_run`, so they agree on
the scenes, frames, spp levels, parameters and repeats without sending scenes or estimators
between processes.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from iblbench.estimators.registry import get_estimator_class
from iblbench.harness.protocol.equal_time import CALIBRATION_SEED
from iblbench.harness.protocol.run_config import MAX_REPEATS, RunConfig
from iblbench.harness.protocol.sweep import (CONTROL_SUFFIX, control_labels, frames_text,
                                             parse_estimator, select_frames)
from iblbench.foundation.errors import InputError, argument
from iblbench.scenes.registry import load_scene

TIMING_SEED = 0x80000000   # timing renders: TIMING_SEED + 256·seed + repeat (executor.timing_seed)
# The largest cell seed whose timing seeds stay below the calibration seeds.
MAX_SEED = (CALIBRATION_SEED - TIMING_SEED) // 256 - 1
# Seeds per cell at most: a sweep plans every (cell, seed) up front, and 8,388,607 seeds took
# 2.7 GB before the first cell (issue 23); a study needs tens, a coverage simulation hundreds.
MAX_SEEDS = 10_000


@dataclasses.dataclass
class ScenePlan:
    scene: object
    width: int
    height: int
    env_res: int
    frames: list[int]


@dataclasses.dataclass
class RunPlan:
    """The estimators' settings and the scenes' plans of one ``RunConfig``."""
    specs: list                      # EstimatorSpec per label, in the config's order, then
                                     # the controls' (spec.control) in theirs
    params: dict[str, str]           # label → every parameter as sorted JSON (results rows)
    repeats: dict[str, int]          # label → timed renders per cell
    spp_levels: dict[str, tuple]     # label → its spp levels
    plans: list[ScenePlan]

    def scene(self, name: str) -> ScenePlan:
        return next(plan for plan in self.plans if plan.scene.name == name)


def plan_run(config: RunConfig) -> RunPlan:
    """Check ``config`` (InputError, before anything is written) and plan it: its estimators,
    their spp levels and repeats, and every scene's size and frames."""
    _require_sound_numbers(config)
    specs = _estimator_specs(config)
    levels = {get_estimator_class(name).name: tuple(v) for name, v in config.spp_for}
    spp_levels = {spec.label: levels.get(spec.cls.name, tuple(config.spp)) for spec in specs}
    without = [label for label, spp in spp_levels.items() if not spp]
    if without and not config.time_budget_ms:
        raise InputError(None, f"no spp for {', '.join(without)} and no time budget: give "
                               f"{argument('spp')}, or levels to each estimator")
    _require_spp_within_bounds(specs, spp_levels)
    scenes = [load_scene(name, sanitize=config.sanitize, env_res=config.env_res)
              for name in config.scenes]
    _require_unique_names(scenes)
    overrides = {get_estimator_class(name).name: n for name, n in config.repeats_for}
    return RunPlan(specs=specs, params={spec.label: spec.params_json() for spec in specs},
                   repeats={spec.label: overrides.get(spec.cls.name, config.repeats)
                            for spec in specs},
                   spp_levels=spp_levels,
                   plans=[_plan_scene(config, scene) for scene in scenes])


def _estimator_specs(config: RunConfig) -> list:
    """The estimators' specs, then an unchanged copy of each in ``config.control`` under its
    control's label (their renders share the frame's rounds with every estimator's, each
    round in an order of its own)."""
    specs = [parse_estimator(label) for label in config.estimators]
    labels = [spec.label for spec in specs]
    if len(set(labels)) != len(labels):
        raise InputError(None, f"an estimator is listed twice: {', '.join(labels)}")
    for spec in specs:
        if spec.control:
            raise InputError(None, f"estimator {spec.label!r}: ask for a control with "
                                   f"{argument('control', spec.label[:-len(CONTROL_SUFFIX)])}")
    by_label = dict(zip(labels, specs))
    return specs + [dataclasses.replace(by_label[label], control=True)
                    for label in control_labels(config.control, labels)]


def sequences(run: RunPlan, config: RunConfig):
    """Each sequence of a sweep, in its order: (scene plan, estimator spec, keys of its cells).
    A cell is one rendered and scored image, keyed (scene, estimator label, spp, frame, seed,
    time budget): a sequence's cells are its frames, at each of the estimator's spp levels
    (budget None), then at each time budget (spp None), for each seed."""
    seeds = range(config.first_seed, config.first_seed + config.seeds)
    for plan in run.plans:
        for spec in run.specs:
            variants = ([(spp, None) for spp in run.spp_levels[spec.label]]
                        + [(None, float(budget)) for budget in config.time_budget_ms])
            for spp, budget in variants:
                for seed in seeds:
                    yield plan, spec, [(plan.scene.name, spec.label, spp, frame, seed, budget)
                                       for frame in plan.frames]


def cell_order(key: tuple):
    """The order in which a frame's cells run: by estimator, its spp cells before its equal-time
    ones, then spp, budget and seed (an equal-time budget is calibrated on its first cell)."""
    return key[1], key[5] is not None, key[2] or 0, key[5] or 0, key[4]


def sequence_key(key: tuple) -> tuple:
    """(scene, estimator, spp, budget, seed) of a cell: its sequence over the frames, whose
    flicker links consecutive frames and whose state a temporal estimator carries."""
    return key[0], key[1], key[2], key[5], key[4]


def _require_sound_numbers(config: RunConfig) -> None:
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


def _require_unique_names(scenes) -> None:
    """Scene names key the results rows and the image folders, so two scenes may not share one."""
    seen = {}
    for scene in scenes:
        if scene.name in seen:
            raise InputError(scene.source or scene.name,
                             f"scene name '{scene.name}' is also the name of "
                             f"{seen[scene.name] or 'a built-in scene'}; rename one of the files")
        seen[scene.name] = scene.source


def _require_spp_within_bounds(specs, spp_of: dict) -> None:
    """Every spp of the sweep within each selected estimator's ``max_spp`` (``spp_of``: label →
    its spp levels), checked before anything is written (a render past the bound fails mid-run)."""
    for spec in specs:
        bound = spec.cls.max_spp
        above = [spp for spp in spp_of[spec.label] if bound is not None and spp > bound]
        if above:
            raise InputError(None, f"{argument('spp', max(above))} is above {spec.label}'s "
                                   f"limit of {bound} samples per pixel")


def _plan_scene(config: RunConfig, scene) -> ScenePlan:
    frames_available = scene.environment.num_frames
    if scene.environment.is_static:
        frames = [0]
    else:
        selection = config.frames_of(scene.name)
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
    width, height = config.resolution or scene.resolution
    env_res = int(np.shape(scene.environment.frame(frames[0]))[1])
    return ScenePlan(scene, int(width), int(height), env_res, frames)
