"""Sweep configs: which cells ``iblbench run`` renders, described in a TOML file.

A sweep is scenes × estimators × spp × frames × seeds at one resolution, under one error
protocol.  ``iblbench run --config NAME|FILE`` takes a shipped config by name (``quick``,
``default``, ``full``, ``temporal``, ``frontier``: ``harness/configs/NAME.toml``) or a path to a ``.toml`` file; explicit
command-line flags replace the config's fields one by one.  ``iblbench run`` with no
``--config`` uses ``default``.

Format (every key at the top level)::

    protocol = "lab-reinhard-v1"        # required; the only protocol there is
    description = "what this sweep is"  # optional, recorded in the manifest
    scenes = ["sphere-sun", "my/scene.toml"]   # required: built-in names or scene .toml files
                                        # (relative paths: from this file's folder)
    estimators = ["uniform", "balanced_mis{shared_sequence=false}"]   # required; or "declared":
                                        # each registered estimator's own ``sweep`` labels
                                        # (``Estimator.sweep``, in their ``order``), each at its
                                        # own spp levels unless the spp table names it
    spp = [16, 64, 256]                 # required unless time_budget_ms is given
    seeds = 2                           # required: seeds 0..N-1
    first_seed = 0                      # optional: seeds first_seed..first_seed+N-1 instead
                                        # (a seeds-only rerun: --first-seed 8 after --seeds 8)
    frames = "0:67:6"                   # optional: "START:STOP[:STEP]", a Python slice of each
                                        # sequence's frames ("::6", "10:", "-5:" all work; the
                                        # default "all" is ":"); also a list [0, 5, 9] or "A..B"
                                        # (inclusive); static environments always run frame 0;
                                        # or a table giving scenes (by name) their own:
                                        # frames = { default = "all", blob-day = "30:36" }
    resolution = "128x128"              # optional: "WxH" or [W, H]; default: each scene's own
    env_res = 64                        # optional cube face resolution; default: each scene's own
    time_budget_ms = [20.0]             # optional: equal-time cells instead of the spp list
    repeats = 5                         # optional: timed renders per cell (default 5; a cell's
                                        # time is their median, harness/protocol/timing.py); or a table
                                        # with counts of its own for slow estimators:
                                        # repeats = { default = 5, bis = 3, smc = 3 }
    metrics = ["de76", "de2000", "relmse", "flip"]   # optional: the metrics to compute (ΔE76
                                        # always; default: the registry's default ones,
                                        # harness/protocol/metric; leave "flip" out to save time)
    sanitize = false                    # optional: repair bad environment texels
    control = ["envmap"]                # optional: the A/A control, an unchanged copy of each
                                        # named estimator run beside it as NAME@control

Estimator overrides are written ``name{param=value,...}``: the braces hold a TOML inline table
of the estimator's ``Params`` fields (values are TOML scalars: ``true``, ``3``, ``0.5``,
``"text"``).  The canonical spelling (lower-case name, parameters sorted, TOML values) is the
estimator's label in the results table, so ``balanced_mis`` and
``balanced_mis{shared_sequence=false}`` are two estimators of one table.  A control's label is
its estimator's with :data:`CONTROL_SUFFIX` (``envmap@control``): the same class and parameters,
so the same images at equal spp and seed, ranked as if it were another estimator (the A/A
control, :mod:`iblbench.harness.protocol.control`).

Every problem (missing file, TOML syntax, unknown key, wrong type, unknown scene, estimator or
parameter) is an :class:`InputError` naming the config file and the problem.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import sys
from importlib.resources import files
from pathlib import Path
from typing import Any

from iblbench.harness.protocol.metric import default_names, names, parse_metrics
from iblbench.harness.protocol.metrics import PROTOCOL
from iblbench.harness.protocol.run_config import (DEFAULT_REPEATS, MAX_REPEATS, SWEEP_FIELDS,
                                                  SweepSettings)
from iblbench.foundation.errors import InputError
from iblbench.foundation.tomlfile import read_toml

if sys.version_info >= (3, 11):
    import tomllib
else:   # pragma: no cover
    import tomli as tomllib

CONFIG_PACKAGE = "iblbench.harness.configs"
# The shipped configs' names, read from their folder so that a new one is listed everywhere.
SHIPPED = tuple(sorted(entry.name.removesuffix(".toml") for entry in files(CONFIG_PACKAGE).iterdir()
                       if entry.name.endswith(".toml")))
# A sweep file's keys: its settings, a per-name one (``spp_for``) given in its own (``spp``).
KEYS = {"protocol", "description", *(name for name in SWEEP_FIELDS if not name.endswith("_for"))}
REQUIRED = ("protocol", "scenes", "estimators", "seeds")
_NAME = re.compile(r"^\s*([A-Za-z0-9_.\-]+)\s*(?:\{(.*)\})?\s*$", re.S)
CONTROL_SUFFIX = "@control"   # a control's label: its estimator's label and this
DECLARED = "declared"   # estimators = "declared": the estimators' own sweep declarations


# ---- estimator labels --------------------------------------------------------------------------

def toml_value(value: Any) -> str:
    """A scalar spelled as TOML (and as it appears in labels)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    return str(value)


@dataclasses.dataclass(frozen=True)
class EstimatorSpec:
    """A registered estimator class with parameter overrides; ``label`` names its rows.
    ``control``: the A/A control's copy, the same estimator under its own label."""

    cls: type
    overrides: tuple[tuple[str, Any], ...] = ()
    control: bool = False

    @property
    def label(self) -> str:
        name = self.cls.name
        if self.overrides:
            name += "{" + ",".join(f"{k}={toml_value(v)}" for k, v in self.overrides) + "}"
        return name + CONTROL_SUFFIX if self.control else name

    def make(self):
        return self.cls(**dict(self.overrides))

    def params_json(self) -> str:
        """Every parameter of the estimator, defaults included, as sorted JSON."""
        return json.dumps(dataclasses.asdict(self.make().params), sort_keys=True, default=str)


def _params_of(cls) -> dict[str, dataclasses.Field]:
    return {field.name: field for field in dataclasses.fields(cls.Params)}


def _check_type(cls, name: str, field: dataclasses.Field, value: Any) -> None:
    default = field.default
    if default is dataclasses.MISSING:
        return
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = True
    if not ok:
        raise InputError(None, f"estimator '{cls.name}' parameter '{name}' must be "
                               f"{type(default).__name__} like its default "
                               f"{toml_value(default)}, got {toml_value(value)}")


def parse_estimator(text: str) -> EstimatorSpec:
    """``name`` or ``name{param=value,...}``, either with :data:`CONTROL_SUFFIX` (a control's
    label, as results tables hold it) → an :class:`EstimatorSpec` (InputError if bad)."""
    from iblbench.estimators.registry import get_estimator_class

    if not isinstance(text, str):
        raise InputError(None, f"an estimator must be a string such as 'uniform', got {text!r}")
    control = text.strip().endswith(CONTROL_SUFFIX)
    match = _NAME.match(text.strip()[:-len(CONTROL_SUFFIX)] if control else text)
    if not match:
        raise InputError(None, f"cannot read estimator {text!r}; write NAME or "
                               "NAME{param=value,...}")
    name, body = match.groups()
    cls = get_estimator_class(name)
    overrides: dict[str, Any] = {}
    if body is not None and body.strip():
        try:
            overrides = tomllib.loads(f"x = {{{body}}}")["x"]
        except tomllib.TOMLDecodeError as error:
            raise InputError(None, f"cannot read the parameters of estimator {text!r} ({error}); "
                                   "write NAME{param=value,...} with TOML values") from None
    valid = _params_of(cls)
    for key, value in overrides.items():
        if key not in valid:
            names = ", ".join(sorted(valid)) or "none (it has no parameters)"
            raise InputError(None, f"estimator '{cls.name}' has no parameter '{key}'; "
                                   f"valid parameters: {names}")
        if isinstance(value, (dict, list)):
            raise InputError(None, f"estimator '{cls.name}' parameter '{key}' must be a TOML "
                                   f"scalar, got {value!r}")
        _check_type(cls, key, valid[key], value)
    spec = EstimatorSpec(cls, tuple(sorted(overrides.items())), control)
    try:
        spec.make()
    except (TypeError, ValueError) as error:
        raise InputError(None, f"estimator {text!r}: {error}") from None
    return spec


def estimator_tags(label: str):
    """The tags of the estimator a results label names, an instance's (a parameter may change
    them: ``restir{unbiased=false}`` is biased; building one opens no device); None where this
    installation lacks the estimator."""
    try:
        return parse_estimator(label).make().tags
    except InputError:
        return None


# ---- the sweep ---------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Sweep(SweepSettings):
    """A resolved sweep (its cells: :class:`SweepSettings`); ``source`` says where it came from."""

    protocol: str = PROTOCOL
    description: str = ""
    source: str = ""

    def replace(self, **changes) -> "Sweep":
        """A copy with the given (non-None) fields replaced, labels canonicalised."""
        changes = {k: v for k, v in changes.items() if v is not None}
        for field in ("estimators", "control"):
            if field in changes:
                changes[field] = tuple(parse_estimator(e).label for e in changes[field])
        return dataclasses.replace(self, **changes)

    def to_manifest(self) -> dict:
        """The manifest's ``sweep`` record: where the sweep came from, then every setting."""
        return {"source": self.source, "description": self.description,
                "protocol": self.protocol,
                **{name: _manifest_value(name, getattr(self, name)) for name in SWEEP_FIELDS}}


def _manifest_value(name: str, value):
    """A setting as the manifest spells it: frames as :func:`frames_text`, a per-name setting
    (``spp_for``: ((name, value), ...)) as a table, tuples as lists."""
    if name == "frames":
        return frames_text(value)
    if name.endswith("_for"):
        return {key: _manifest_value(name[:-len("_for")], entry) for key, entry in value}
    return list(value) if isinstance(value, tuple) else value


def config_path(name_or_path: str | os.PathLike) -> tuple[Path, str]:
    """The file of a shipped config name or a path, and a description of the source."""
    text = os.fspath(name_or_path)
    if text in SHIPPED:
        path = Path(str(files(CONFIG_PACKAGE).joinpath(f"{text}.toml")))
        return path, f"shipped:{text}"
    if not text.lower().endswith(".toml") and os.sep not in text and not os.path.exists(text):
        raise InputError(text, f"unknown sweep config; shipped configs: {', '.join(SHIPPED)}, "
                               "or give the path of a .toml file")
    return Path(text), str(Path(text).resolve())


def _positive_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


def parse_resolution(value) -> tuple[int, int]:
    """``"WxH"`` or ``[W, H]`` → (W, H), each side at most MAX_IMAGE_SIDE; ValueError if not."""
    from iblbench.scenes.registry import MAX_IMAGE_SIDE   # (trimesh: not at CLI start-up)

    if isinstance(value, str):
        parts = value.lower().split("x")
        if len(parts) == 2 and all(p.strip().isdigit() for p in parts):
            value = [int(p) for p in parts]
    if isinstance(value, list) and len(value) == 2 and all(
            _positive_int(v) and v <= MAX_IMAGE_SIDE for v in value):
        return int(value[0]), int(value[1])
    raise ValueError(f"resolution must be \"WxH\" or [W, H] with integers in 1..{MAX_IMAGE_SIDE}, "
                     f"got {value!r}")


def check_env_res(value) -> int:
    """A cube-face resolution override: an integer in 1..MAX_RES; ValueError if not."""
    from iblbench.scenes.envmap import MAX_RES

    if not (_positive_int(value) and value <= MAX_RES):
        raise ValueError(f"env_res must be an integer in 1..{MAX_RES}, got {value!r}")
    return int(value)


_SLICE = re.compile(r"\s*(-?\d+)?\s*:\s*(-?\d+)?\s*(?::\s*(-?\d+)?\s*)?")


def parse_frames(value) -> tuple[int, ...] | slice | None:
    """A frame selection → None (every frame), a ``slice`` or a tuple of frame indices.

    ``"START:STOP[:STEP]"`` is a Python slice over each sequence's frames (parts may be omitted
    or negative: ``"::6"``, ``"10:"``, ``"-5:"``; ``":"`` is every frame); ``"all"`` → None;
    ``"A..B"`` (inclusive) and a list ``[0, 5]`` → frame indices.  ValueError if malformed.
    """
    if value == "all":
        return None
    if isinstance(value, str):
        match = _SLICE.fullmatch(value)
        if match:
            start, stop, step = (None if part is None else int(part) for part in match.groups())
            if step == 0:
                raise ValueError(f"frames slice step must not be zero, got {value!r}")
            if start is None and stop is None and step in (None, 1):
                return None
            return slice(start, stop, step)
        match = re.fullmatch(r"\s*(\d+)\s*\.\.\s*(\d+)\s*", value)
        if match and int(match[1]) <= int(match[2]):
            return tuple(range(int(match[1]), int(match[2]) + 1))
    elif (isinstance(value, list) and value and all(isinstance(v, int) and not isinstance(v, bool)
                                                     and v >= 0 for v in value)):
        return tuple(sorted(set(value)))
    raise ValueError(f"frames must be \"START:STOP[:STEP]\" (a Python slice such as 0:67:6), "
                     f"\"all\", \"A..B\" or a list of frame indices >= 0, got {value!r}")


def frames_text(frames) -> str | list[int]:
    """The manifest's spelling of a frame selection."""
    if frames is None or frames == slice(None):
        return "all"
    if isinstance(frames, slice):
        parts = ["" if v is None else str(v) for v in (frames.start, frames.stop)]
        return ":".join(parts + ([str(frames.step)] if frames.step is not None else []))
    return list(frames)


def select_frames(frames, num_frames: int) -> list[int]:
    """The frame indices a selection picks from a sequence of ``num_frames`` (in run order)."""
    if frames is None:
        return list(range(num_frames))
    if isinstance(frames, slice):
        return list(range(num_frames))[frames]
    return list(frames)


def _scene(entry, folder: Path, path: Path) -> str:
    from iblbench.scenes.registry import scene_names

    if not isinstance(entry, str) or not entry:
        raise InputError(path, f"scenes must be a list of scene names or .toml paths, got {entry!r}")
    if entry.lower().endswith(".toml"):
        scene = Path(entry) if Path(entry).is_absolute() else folder / entry
        if not scene.is_file():
            raise InputError(path, f"scene file {str(scene)!r} not found")
        return str(scene)
    if entry.lower() not in scene_names():
        raise InputError(path, f"unknown scene {entry!r}; valid scenes: {', '.join(scene_names())}")
    return entry.lower()


def parse_sweep(document: dict, path: Path, source: str) -> Sweep:
    """Validate a parsed TOML document; every problem is an InputError naming ``path``."""
    unknown = sorted(set(document) - KEYS)
    if unknown:
        raise InputError(path, f"unknown key {unknown[0]!r}; valid keys: {', '.join(sorted(KEYS))}")
    missing = [key for key in REQUIRED if key not in document]
    if "spp" not in document and "time_budget_ms" not in document:
        missing.append("spp")
    if missing:
        raise InputError(path, f"missing required key {missing[0]!r}")

    def fail(problem: str):
        raise InputError(path, problem)

    protocol = document["protocol"]
    if protocol != PROTOCOL:
        fail(f"protocol must be {PROTOCOL!r} (the only one implemented), got {protocol!r}")
    description = document.get("description", "")
    if not isinstance(description, str):
        fail(f"description must be a string, got {description!r}")
    scenes = document["scenes"]
    if not isinstance(scenes, list) or not scenes:
        fail(f"scenes must be a non-empty list, got {scenes!r}")
    scenes = tuple(_scene(entry, path.parent, path) for entry in scenes)
    if len(set(scenes)) != len(scenes):
        fail(f"scenes lists a scene twice: {list(scenes)}")
    declared = document["estimators"] == DECLARED
    labels = _estimator_labels(declared_labels() if declared else document["estimators"], fail)
    try:
        spp, spp_for = parse_spp(document.get("spp", []))
    except ValueError as error:
        fail(str(error))
    if declared:
        spp_for = tuple(sorted({**declared_spp(), **dict(spp_for)}.items()))
    seeds = document["seeds"]
    if not _positive_int(seeds):
        fail(f"seeds must be a positive integer (seeds 0..N-1), got {seeds!r}")
    first_seed = document.get("first_seed", 0)
    if type(first_seed) is not int or first_seed < 0:
        fail(f"first_seed must be a non-negative integer, got {first_seed!r}")
    try:
        frames, frames_for = parse_scene_frames(document.get("frames", "all"))
        resolution = (parse_resolution(document["resolution"]) if "resolution" in document
                      else None)
    except ValueError as error:
        fail(str(error))
    env_res = document.get("env_res")
    if env_res is not None:
        try:
            check_env_res(env_res)
        except ValueError as error:
            fail(str(error))
    budgets = _time_budgets(document.get("time_budget_ms", []), fail)
    without = [] if spp or budgets else _without_own_levels(labels, spp_for)
    if without:
        fail(f"spp gives {', '.join(without)} no levels and there is no time_budget_ms: give "
             "spp.default, or levels to each estimator (spp = {NAME = [...], ...})")
    sanitize = document.get("sanitize", False)
    if not isinstance(sanitize, bool):
        fail(f"sanitize must be true or false, got {sanitize!r}")
    try:
        repeats, repeats_for = parse_repeats(document.get("repeats", DEFAULT_REPEATS))
    except ValueError as error:
        fail(str(error))
    metrics = _metric_names(document.get("metrics", list(default_names())), fail)
    control = _controls(document.get("control", []), labels, fail)
    names = {Path(entry).stem.lower() if entry.lower().endswith(".toml") else entry.lower()
             for entry in scenes}
    for name, _ in frames_for:
        if name not in names:
            fail(f"frames gives frames to scene {name!r}, which scenes does not list "
                 f"(scenes: {', '.join(sorted(names))})")
    return Sweep(scenes=scenes, estimators=tuple(labels), spp=spp, spp_for=spp_for, seeds=seeds,
                 first_seed=first_seed, frames=frames, frames_for=frames_for, resolution=resolution, env_res=env_res,
                 time_budget_ms=tuple(float(v) for v in budgets), sanitize=sanitize,
                 repeats=repeats, repeats_for=repeats_for, metrics=metrics, control=control,
                 protocol=protocol, description=description, source=source)


def _declared_parts() -> list:
    """(class, its SweepPart) of every registered estimator that takes part in the default
    sweep, in the parts' order (ties by name)."""
    from iblbench.estimators.base import own
    from iblbench.estimators.registry import estimator_classes

    parts = [(cls, own(cls, "sweep")) for cls in estimator_classes()]
    return sorted(((cls, part) for cls, part in parts if part is not None),
                  key=lambda pair: (pair[1].order, pair[0].name))


def declared_labels() -> list[str]:
    """The labels of ``estimators = "declared"``: each estimator's own ``sweep`` labels."""
    return [label for _, part in _declared_parts() for label in part.labels]


def declared_spp() -> dict[str, tuple[int, ...]]:
    """Name -> the spp levels its ``sweep`` declares, of those that declare their own."""
    return {cls.name: tuple(sorted(set(part.spp))) for cls, part in _declared_parts()
            if part.spp is not None}


def _without_own_levels(labels, spp_for) -> list[str]:
    """The estimators of ``labels`` that ``spp_for`` gives no spp levels of their own."""
    own = {name for name, levels in spp_for if levels}
    return [label for label in labels if parse_estimator(label).cls.name not in own]


def _estimator_labels(estimators, fail) -> list[str]:
    """The sweep's ``estimators``: a non-empty list of labels, none twice."""
    if not isinstance(estimators, list) or not estimators:
        fail(f"estimators must be a non-empty list, got {estimators!r}")
    labels = []
    for entry in estimators:
        try:
            labels.append(parse_estimator(entry).label)
        except InputError as error:
            fail(error.problem)
    if len(set(labels)) != len(labels):
        fail(f"estimators lists an estimator twice: {labels}")
    return labels


def _controls(control, labels, fail) -> tuple[str, ...]:
    """The sweep's ``control``: a list of its estimators (:func:`control_labels`)."""
    if not isinstance(control, list):
        fail(f"control must be a list of estimators, got {control!r}")
    try:
        return control_labels(control, labels)
    except InputError as error:
        fail(error.problem)


def control_labels(names, labels) -> tuple[str, ...]:
    """The estimators given an A/A control (``names``) as canonical labels, each one of the
    run's ``labels`` and none twice; InputError naming the first that is not."""
    controls = []
    for name in names:
        label = parse_estimator(name).label
        if label not in labels:
            raise InputError(None, f"control {name!r} is not one of the run's estimators "
                                   f"({', '.join(labels)})")
        if label in controls:
            raise InputError(None, f"control {name!r} is given twice")
        controls.append(label)
    return tuple(controls)


def _time_budgets(budgets, fail) -> list:
    """The sweep's ``time_budget_ms``: a positive number or a list of them."""
    if isinstance(budgets, (int, float)) and not isinstance(budgets, bool):
        budgets = [budgets]
    if not isinstance(budgets, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
            for v in budgets):
        fail(f"time_budget_ms must be a positive number or a list of them, got {budgets!r}")
    return budgets


def _metric_names(metrics, fail) -> tuple[str, ...]:
    """The sweep's ``metrics``: a list of metric names."""
    if not isinstance(metrics, list) or not all(isinstance(m, str) for m in metrics):
        fail(f"metrics must be a list of metric names ({', '.join(names())}), got {metrics!r}")
    try:
        return parse_metrics(",".join(metrics))
    except ValueError as error:
        fail(f"metrics: {error}")


def load_sweep(name_or_path: str | os.PathLike) -> Sweep:
    """A shipped config by name (:data:`SHIPPED`) or a sweep .toml file."""
    path, source = config_path(name_or_path)
    return parse_sweep(read_toml(path, "sweep config"), path, source)


def _per_estimator(value, fallback, parse, field: str, expected: str):
    """A setting given once or per estimator: ``value``, or a table ``{default = ..., NAME =
    ..., ...}`` whose other keys are estimator names with a value of their own → (the default,
    ((name, its value), ...) sorted); each value through ``parse`` (None for a bad one), and a
    bad one is a ValueError naming ``field`` (and the estimator) and what was ``expected``."""
    table = value if isinstance(value, dict) else {"default": value}

    def checked(key, entry):
        parsed = parse(entry)
        if parsed is None:
            where = "" if key == "default" else f" for {key}"
            raise ValueError(f"{field}{where} must be {expected}, got {entry!r}")
        return parsed

    return checked("default", table.get("default", fallback)), tuple(sorted(
        (str(key).lower(), checked(key, entry)) for key, entry in table.items() if key != "default"))


def parse_scene_frames(value) -> tuple[Any, tuple[tuple[str, Any], ...]]:
    """The frames: one selection (:func:`parse_frames`) for every sequence, or a table
    ``{default = ..., SCENE = ..., ...}`` giving scenes (by name) selections of their own, so that
    one sweep can shorten a long sequence and keep a short one whole → (the default, ((scene,
    selection), ...) sorted); ValueError naming the problem (and the scene)."""
    table = value if isinstance(value, dict) else {"default": value}

    def parsed(key, entry):
        try:
            return parse_frames(entry)
        except ValueError as error:
            if key == "default":
                raise
            raise ValueError(f"frames for {key}: {error}") from None

    names = [str(key).lower() for key in table if key != "default"]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise ValueError(f"frames for {twice[0]}: given twice (scene names ignore case)")
    return parsed("default", table.get("default", "all")), tuple(sorted(
        ((str(key).lower(), parsed(key, entry)) for key, entry in table.items() if key != "default"),
        key=lambda pair: pair[0]))


def parse_spp(value) -> tuple[tuple[int, ...], tuple[tuple[str, tuple[int, ...]], ...]]:
    """The spp levels: a list, or a table ``{default = [...], NAME = [...], ...}`` giving
    estimators levels of their own (so that an estimator 100× as costly a sample covers the same
    time range as the others) → (levels, ((name, levels), ...) sorted), each sorted without
    repeats; ValueError naming the problem."""
    def levels(values):
        return (tuple(sorted(set(values))) if isinstance(values, list)
                and all(_positive_int(v) for v in values) else None)

    return _per_estimator(value, [], levels, "spp", "a list of positive integers")


def parse_repeats(value) -> tuple[int, tuple[tuple[str, int], ...]]:
    """Timed renders per cell: ``N``, or a table ``{default = N, NAME = M, ...}`` giving
    estimators a count of their own (fewer for a slow estimator) → (N, ((name, M), ...) sorted);
    ValueError naming the problem."""
    def count(number):
        return int(number) if _positive_int(number) and number <= MAX_REPEATS else None

    return _per_estimator(value, DEFAULT_REPEATS, count, "repeats",
                          f"an integer in 1..{MAX_REPEATS}")
