"""What a run is asked to do, defined once: :class:`SweepSettings` (the cells a sweep renders, as
a sweep file, ``iblbench run``'s flags and :func:`iblbench.run`'s keywords give them) and
:class:`RunConfig` (those and where and how this run renders them).

Each field's metadata (:func:`setting`) holds what the command line and the Python API say about
it: ``flag`` (its flag of ``iblbench run``; None where it has none), ``help`` (the flag's help
text), ``python`` (the keyword's line in :func:`iblbench.run`'s docstring; None where the API
has no such keyword) and ``python_type`` (the keyword's type where it is not the field's).  The
field's type and ``python_type`` are the types the API checks its arguments against
(:func:`check_settings`).  The sweep (:mod:`.sweep`), the API (:func:`iblbench.run_config`) and the
CLI (:mod:`iblbench.commands.run`) read their fields from here.

Light to import (the CLI builds its parser from it): no estimator, no scene.  The metrics
field's default and help read the metric registry, whose modules import the scoring module,
so NumPy comes with it (about 0.06 s of ``import iblbench`` here).
"""
from __future__ import annotations

import dataclasses
import os
import pathlib
import textwrap
import typing
from typing import Any

from iblbench.foundation.hints import check_type
from iblbench.harness.protocol.metric import default_names, names

DEFAULT_SCENES = ("sphere-sun",)
DEFAULT_ESTIMATORS = ("uniform",)
DEFAULT_SPP = (16, 64, 256)
DEFAULT_SEEDS = 2
DEFAULT_REPEATS = 5   # timed renders per cell (harness/protocol/timing.py)
MAX_REPEATS = 255     # the timing seeds hold the repeat in 8 bits (executor.timing_seed)


def setting(default=dataclasses.MISSING, *, flag: str | None = None, help: str | None = None,
            python: str | None = None, python_type=None):
    """A field of a run's configuration with what the CLI and the API say about it;
    ``python_type``: the type the API's keyword takes where it is not the field's (text it
    parses, such as ``"64x64"``; :func:`keyword_type`)."""
    return dataclasses.field(default=default, metadata={
        "flag": flag, "help": help, "python": python, "python_type": python_type})


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """The cells of a sweep: scenes × estimators × spp × frames × seeds, at one resolution."""

    scenes: tuple[str, ...] = setting(
        DEFAULT_SCENES, flag="--scene",
        help="built-in scene name or a scene .toml file; repeatable",
        python="a built-in name, a scene ``.toml`` path or a scene dict, or a list of them",
        python_type=tuple[str | os.PathLike | dict, ...])
    estimators: tuple[str, ...] = setting(   # labels: "name" or "name{param=value}"
        DEFAULT_ESTIMATORS, flag="--estimator",
        help="estimator name, optionally with parameters as NAME{param=value,...}; "
             "repeatable (see 'iblbench list estimators')",
        python='names, optionally with parameters (``"balanced{uniform_faces=true}"``)')
    spp: tuple[int, ...] = setting(
        DEFAULT_SPP, flag="--spp",
        help="samples per pixel, comma-separated, the same for every estimator "
             "(a sweep config may give estimators levels of their own, as the "
             "default sweep does: spp = {default = [...], NAME = [...]})",
        python="samples per pixel, an int or a list")
    seeds: int = setting(
        DEFAULT_SEEDS, flag="--seeds",
        help="seeds per cell, 0..N-1; each seed's timed renders (--repeats) are "
             "all scored, so one seed already gives a cell an interval",
        python="how many seeds (seeds 0..N-1, or from ``first_seed``)")
    first_seed: int = setting(   # cells use seeds first_seed .. first_seed + seeds - 1
        0, flag="--first-seed",
        help="the first seed instead of 0: seeds S..S+N-1 (a seeds-only rerun)",
        python="the first seed instead of 0")
    # None: every frame; a slice: Python slice semantics over each sequence's frames; static
    # scenes run frame 0.
    frames: tuple[int, ...] | slice | None = setting(
        None, flag="--frames",
        help="frames of environment sequences, a Python slice of each sequence's "
             "frames such as 0:67:6 or ::4 (default: all; also all, A..B inclusive "
             "or N,N,...; write --frames=-5: for a negative start); static scenes "
             "run frame 0",
        python='``"START:STOP[:STEP]"``, ``"all"``, ``"A..B"`` or a list of frame indices',
        python_type=str | tuple[int, ...])
    frames_for: tuple[tuple[str, Any], ...] = setting(())   # (scene name, its own frames)
    resolution: tuple[int, int] | None = setting(
        None, flag="--res", help="image resolution (default: the scene's own)",
        python='``"WxH"`` or ``(W, H)`` (default: each scene\'s own)',
        python_type=str | tuple[int, int])
    env_res: int | None = setting(
        None, flag="--env-res",
        help="cube face resolution for built-in skies and resampled maps",
        python="the cube face size")
    time_budget_ms: tuple[float, ...] = setting(
        (), flag="--time-budget-ms",
        help="equal-time cells besides the spp list: per (scene, estimator), the spp "
             "whose calibrated device time per frame (build+sample+shade) lands "
             "within 10%% of T ms; the run says where it cannot",
        python="a number or a list (equal-time cells besides the spp list)")
    sanitize: bool = setting(
        False, flag="--sanitize",
        help="replace NaN/Inf/negative texels in environment maps instead of refusing",
        python="replace NaN/Inf/negative texels in environment maps instead of refusing")
    repeats: int = setting(
        DEFAULT_REPEATS, flag="--repeats",
        help=f"timed renders per cell after warm-up (default: the sweep's; "
             f"{DEFAULT_REPEATS} where it gives none, 10 in the shipped "
             "default sweep), each in a round of the frame's cells; a cell's "
             "time is the median of their device times (build+sample+shade), "
             "with min and IQR beside it; "
             "NAME=M gives estimator NAME M of its own (e.g. 5,smc=3)",
        python='timed renders per cell, an int or ``{"default": 5, "bis": 3}``',
        python_type=int | dict[str, int])
    repeats_for: tuple[tuple[str, int], ...] = setting(())   # (estimator name, its repeats)
    spp_for: tuple[tuple[str, tuple[int, ...]], ...] = setting(())   # (name, its spp levels)
    metrics: tuple[str, ...] = setting(   # ΔE76 always; see harness.protocol.metric
        default_names(), flag="--metrics",
        help=f"metrics to compute, of {','.join(names())} (default: the "
             "sweep's own: de76,de2000,relmse for the shipped default, which leaves "
             "the slow FLIP out, all four for full; de76 always: heat maps and "
             "flicker use it); one left out is NaN",
        python='``"de76,relmse"`` or a list (default: the registry\'s default ones, '
               ':mod:`iblbench.harness.protocol.metric`; ΔE76 always)')
    control: tuple[str, ...] = setting(   # labels run again as LABEL@control (A/A control)
        (), flag="--control",
        help="the A/A control: run estimator NAME (one of the run's, spelt as for "
             "--estimator) a second time, unchanged, as NAME@control (the same "
             "images at equal spp and seed, its own timings), and count the "
             "equal-time verdicts that call the two apart: each is a false call, "
             "and the stated 95%% level allows about 5%%; repeatable or "
             "comma-separated; --estimator without --control drops the config's "
             "control",
        python="an estimator label or a list of them, each run again unchanged as "
               "``LABEL@control`` (the A/A control: how often the answer calls an estimator "
               "apart from itself); ``estimators`` given without it drops the config's")


@dataclasses.dataclass(frozen=True, kw_only=True)   # out has no default: keywords only
class RunConfig(SweepSettings):
    """A sweep's settings and where and how this run renders them."""

    out: pathlib.Path = setting(
        flag="--out", help="output directory (default: results/latest)",
        python="the output folder (required)")
    device: str | None = setting(
        None, flag="--device",
        python="an OpenCL platform/device substring, as ``iblbench run --device``")
    launch_shape: str | None = setting(
        None, flag="--launch-shape",
        help="how the kernels that sum a pixel's samples in lanes (envmap, brdf, hierarchical, "
             "product, fis and the pool estimators) launch: pixel, one work item a pixel, its "
             "samples in a loop (the CPU shape); sample-block, one work item a pixel and block "
             "of its samples, the blocks' partial sums added in a fixed order by a second "
             "kernel (the GPU shape: enough work items to fill a GPU); auto (default), "
             "sample-block where the OpenCL device's type is GPU, else pixel.  Both shade the "
             "same samples: images agree within float rounding (1e-5); the others (restir, "
             "smc, bis, havran, cosine) keep the pixel shape",
        python='``"pixel"``, ``"sample_block"`` or ``"auto"`` (None: auto), as ``iblbench run '
               '--launch-shape``')
    save_inputs: bool = setting(
        False, flag="--save-inputs",
        help="also write inputs/<scene>/gbuffer.npz and env_f<frame>.npy",
        python="also write ``inputs/<scene>/gbuffer.npz`` and ``env_f<frame>.npy``")
    progress: bool | None = setting(
        None, flag="--no-progress",
        python="a progress bar (None: only on a terminal)")
    force: bool = setting(
        False, flag="--force",
        help="recompute the selected cells even where --out already has them, and "
             "replace the results of another --res or --env-res there (without it, "
             "a run refuses an --out made with another of those)",
        python="recompute cells ``out`` already has")
    # Where the cells run (:mod:`.distributed`); neither: in this process.
    workers: int | None = setting(
        None, flag="--workers",
        help="run the cells on a Dask LocalCluster of N worker processes on this "
             "machine (spawned; one OpenCL context each); this process alone "
             "writes --out's table; default: in this process",
        python="run the cells on a Dask LocalCluster of this many worker processes")
    scheduler: str | None = setting(
        None, flag="--scheduler",
        help="run the cells on the Dask cluster whose dask-scheduler is at "
             "ADDRESS (e.g. tcp://node1:8786); its workers need this iblbench, "
             "and --out and the cache (IBLBENCH_CACHE) on a filesystem they share "
             "(docs/user-guide.md, 'Running on a cluster')",
        python="run the cells on the Dask cluster whose scheduler is at this address "
               "(see :mod:`iblbench.harness.protocol.distributed`)")
    sweep: dict | None = setting(None)   # the resolved sweep and its source

    def frames_of(self, scene_name: str):
        """The frame selection of one scene: its own (``frames_for``) or the sweep's."""
        return dict(self.frames_for).get(scene_name.lower(), self.frames)


SWEEP_FIELDS = tuple(field.name for field in dataclasses.fields(SweepSettings))
# Read from a sweep file only: spp or frames given to a run replace them (its levels or frames
# for every estimator or scene).
PER_NAME_FIELDS = ("frames_for", "spp_for")


def field_of(name: str) -> dataclasses.Field:
    """The field ``name`` of :class:`RunConfig` (KeyError if there is none)."""
    return {field.name: field for field in dataclasses.fields(RunConfig)}[name]


def api_fields() -> tuple[str, ...]:
    """The fields that :func:`iblbench.run` takes as keywords: those it documents."""
    return tuple(field.name for field in dataclasses.fields(RunConfig)
                 if field.metadata.get("python"))


def config_keywords() -> tuple[str, ...]:
    """The fields that :func:`iblbench.run_config` takes as keywords: all but ``out`` (its
    argument), ``sweep`` (the record it makes) and :data:`PER_NAME_FIELDS`."""
    return tuple(field.name for field in dataclasses.fields(RunConfig)
                 if field.name not in ("out", "sweep", *PER_NAME_FIELDS))


def flag_of(name: str) -> str:
    """The flag of ``iblbench run`` that sets field ``name``."""
    return field_of(name).metadata["flag"]


def flag_help(name: str) -> str:
    """The help text of field ``name``'s flag of ``iblbench run``."""
    return field_of(name).metadata["help"]


def keyword_lines(names) -> list[str]:
    """The docstring lines of the API keywords ``names``: ``- ``name``: what it is;``, wrapped."""
    return [line for name in names for line in textwrap.wrap(
        f"- ``{name}``: {field_of(name).metadata['python']};", width=92, subsequent_indent="  ")]


def keyword_default(name: str):
    """The default of :func:`iblbench.run_config`'s keyword ``name``: None for a sweep's setting
    (None: the sweep config's), the field's own default for the others."""
    field = field_of(name)
    return None if name in SWEEP_FIELDS else field.default


def element_type(name: str):
    """The type of each element of a ``tuple[T, ...]`` field (str, int or float); None for any
    other field."""
    hint = typing.get_type_hints(RunConfig)[name]
    args = typing.get_args(hint)
    if typing.get_origin(hint) is tuple and len(args) == 2 and args[1] is Ellipsis:
        return args[0] if args[0] in (str, int, float) else None
    return None


def keyword_type(name: str):
    """The type :func:`iblbench.run`'s keyword ``name`` takes: the field's ``python_type``, else
    its type; a list (``tuple[T, ...]``) takes a single T too, as a list of one."""
    hint = field_of(name).metadata["python_type"] or typing.get_type_hints(RunConfig)[name]
    args = typing.get_args(hint)
    if typing.get_origin(hint) is tuple and len(args) == 2 and args[1] is Ellipsis:
        return typing.Union[args[0], hint]
    return hint


def check_settings(values: dict, *, keywords: bool) -> None:
    """An InputError naming the first of ``values`` (field name → value) whose type is not its
    field's: the values of :func:`iblbench.run_config`, or with ``keywords`` the keywords of
    :func:`iblbench.run` (:func:`keyword_type`).  None is any sweep setting's: the sweep
    config's value."""
    hints = typing.get_type_hints(RunConfig)
    for name, value in values.items():
        if not (value is None and name in SWEEP_FIELDS):
            check_type(name, value, keyword_type(name) if keywords else hints[name])
