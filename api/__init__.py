"""iblbench's Python API: run a benchmark sweep from a notebook and get the results table.

::

    import iblbench

    ball = {"name": "ball",                                  # the keys of a scene TOML file
            "mesh": {"path": "ball.obj"},
            "environment": {"path": "park.exr", "res": 32},
            "material": {"kd": 0.6, "ks": 0.2, "shininess": 80},
            "camera": {"eye": [0, 0, 3], "target": [0, 0, 0]}}
    table = iblbench.run(scenes=["sphere-sun", ball, "my/scene.toml"],
                         estimators=["uniform", "balanced_mis{shared_sequence=false}"],
                         spp=[16, 64], seeds=4, resolution="64x64", out="runs/nb")
    table.groupby(["scene", "estimator", "spp"]).mean_delta_e76.mean()
    iblbench.report("runs/nb")                              # runs/nb/report/index.html
    checks, verdict, status = iblbench.check("runs/q", "budgets.toml")

:func:`run` is ``iblbench run`` as a function: the same runner (:mod:`iblbench.harness.protocol.runner`),
the same sweep configs and overrides (:mod:`iblbench.harness.protocol.sweep`), the same files in
``out``, the same resumption.  It returns the rows of this sweep (the folder may also hold
other sweeps' cells) as a pandas DataFrame: one row per (scene, estimator, spp, frame, seed),
the columns of ``results.parquet`` (docs/results.md).  Bad input raises
:class:`InputError`, whose one-line message names the file, argument (as its keyword,
``first_seed=-1``, where the command line names a flag) or key; so does an argument of the
wrong type (``force="no"``: booleans take only True or False), each checked against its
:class:`~iblbench.harness.protocol.run_config.RunConfig` field's type before any is used.

**Scenes** are built-in names (``iblbench list scenes``), paths of scene ``.toml`` files, or
dicts with the keys of a scene TOML file (sections ``mesh``, ``environment``, ``material``,
``camera``, ``render``; format in :mod:`iblbench.scenes.registry` and docs/scenes.md), plus an
optional ``name`` (default: the mesh file's stem; it names the rows and image folders, so two
scenes of one run need two names, and a built-in scene's name is refused).  Relative paths in a
dict (``mesh.path``, ``environment.path``) are taken from the current working directory.  A
dict is written as ``out/scenes/<name>.toml`` and run as that file, so the manifest and
``iblbench report`` find it later; a dict whose name is already in ``out/scenes`` with other
content is refused (its earlier rows would be resumed as if they were this scene's) unless
``force``.  Errors in a dict name the dict and the key (``scene dict 'ball': unknown key 'kdd'
in [material]; ...``); nothing is left in ``out`` by one.  (An error found only when the scene
is traced, such as a camera that sees no geometry, may leave the scene file behind.)
"""
from __future__ import annotations

import functools
import inspect
import json
import numbers
import os
import pathlib
import re
import typing

from iblbench.foundation.errors import InputError, python_keywords
from iblbench.foundation.hints import check_type

__all__ = ["run", "run_config", "check", "report", "InputError"]

SCENE_FOLDER = "scenes"     # out/scenes/<name>.toml: the scenes given as dicts
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_PATH_KEYS = (("mesh", "path"), ("environment", "path"))
_CONFIG = str | os.PathLike | None   # a shipped sweep's name or a sweep file


def _naming_keywords(function):
    """``function`` with its messages naming the API's keywords (``first_seed=-1``), not the
    command line's flags (``--first-seed -1``): issue 23."""
    @functools.wraps(function)
    def named(*args, **kwargs):
        with python_keywords():
            return function(*args, **kwargs)
    return named


def _keywords_of_run_config(function):
    """``function`` (:func:`run`) checked against :class:`RunConfig`'s fields: each of its
    keywords but ``config`` is a field the API documents, and each such field is a keyword of
    it (a mismatch fails ``import iblbench``); its docstring ends with their descriptions."""
    from iblbench.harness.protocol.run_config import api_fields, keyword_lines

    keywords = [name for name in inspect.signature(function).parameters if name != "config"]
    if set(keywords) != set(api_fields()):
        raise TypeError(f"{function.__name__}'s keywords differ from RunConfig's: "
                        f"{sorted(set(keywords) ^ set(api_fields()))}")
    if function.__doc__ is not None:   # None under python -OO
        function.__doc__ += "\n".join("    " + line for line in keyword_lines(keywords)) + "\n"
    return function


@_naming_keywords
@_keywords_of_run_config
def run(scenes=None, estimators=None, spp=None, seeds=None, *, out, config=None, first_seed=None,
        frames=None, resolution=None, env_res=None, time_budget_ms=None, repeats=None, metrics=None,
        sanitize=None, device=None, launch_shape=None, save_inputs=False, force=False, progress=None, workers=None,
        scheduler=None, control=None):
    """Run a sweep and return its results table (a pandas DataFrame); see the module docstring.

    Each argument left None takes its value from ``config``: a shipped sweep name (``quick``,
    ``default``, ``full``, ``temporal``, ``frontier``) or a sweep ``.toml`` file (default ``default``), as
    the flags of ``iblbench run`` do.  The keywords are the fields of
    :class:`~iblbench.harness.protocol.run_config.RunConfig`:

"""
    settings = {name: value for name, value in locals().items() if name not in ("out", "config")}
    from iblbench.harness.protocol.run_config import SWEEP_FIELDS, check_settings
    from iblbench.harness.protocol.runner import Runner

    check_type("config", config, _CONFIG)   # every argument's type before any is used
    check_settings({"out": out} | settings, keywords=True)

    given = sorted(name for name, value in settings.items()
                   if value is not None and name in SWEEP_FIELDS)
    settings = _parsed(settings)
    out = pathlib.Path(out)
    entries, written, created = ((None, [], {}) if scenes is None
                                 else _scene_entries(_listed(scenes), out, force))
    try:
        runner = Runner(run_config(
            out, config=config, **(settings | {"scenes": entries}),
            note={"overridden_by_arguments": given, "via": "iblbench.run (Python API)"}))
    except InputError as error:
        _remove(created)
        labels = {str(path): f"scene dict {path.stem!r}" for path in written}
        if error.source in labels:
            raise InputError(labels[error.source], error.problem) from None
        raise
    return runner.sweep_rows(runner.run()).reset_index(drop=True)


def _parsed(settings: dict) -> dict:
    """:func:`run`'s values as :func:`run_config` takes them (InputError if bad): frames,
    resolution, env_res and metrics parsed as a sweep file's are, ``repeats`` split into its
    default and ``repeats_for``, a single value of a list as a list of one."""
    from iblbench.harness.protocol.metric import parse_metrics
    from iblbench.harness.protocol.run_config import element_type
    from iblbench.harness.protocol.sweep import (check_env_res, parse_frames, parse_repeats,
                                                 parse_resolution)

    def listed(value):   # a tuple of the API means a list, not a sweep file's value
        return list(value) if isinstance(value, tuple) else value

    parsers = {
        # "all" parses to None, which would keep the config's frames: the full slice instead
        "frames": lambda value: parse_frames(listed(value)) or slice(None),
        "resolution": lambda value: parse_resolution(listed(value)),
        "env_res": check_env_res,
        "metrics": lambda value: parse_metrics(value if isinstance(value, str)
                                               else ",".join(value))}
    settings = dict(settings)
    try:
        for name, parse in parsers.items():
            if settings[name] is not None:
                settings[name] = parse(settings[name])
        settings["repeats"], settings["repeats_for"] = (
            parse_repeats(settings["repeats"]) if settings["repeats"] is not None else (None, None))
    except ValueError as error:
        raise InputError(None, str(error)) from None
    return {name: _listed(value) if element_type(name) else value
            for name, value in settings.items()}


def run_config(out, *, config=None, note=None, **settings):
    """The :class:`~iblbench.harness.protocol.run_config.RunConfig` of a sweep config
    (``config``, default ``default``) whose fields given here (not None) are replaced, values
    already parsed (``iblbench run`` and :func:`run` share it); ``note`` is added to the
    manifest's ``sweep`` record.  ``estimators`` given without ``control`` drops the config's
    control, which named the config's estimators; ``spp`` and ``frames`` given replace the
    config's levels and frames of each estimator and scene too."""
    from iblbench.harness.protocol.run_config import (SWEEP_FIELDS, RunConfig, check_settings,
                                                      config_keywords, element_type)
    from iblbench.harness.protocol.sweep import load_sweep

    unknown = sorted(set(settings) - set(config_keywords()))
    if unknown:
        raise TypeError(f"run_config() got an unexpected keyword argument {unknown[0]!r}")
    check_type("config", config, _CONFIG)
    check_type("note", note, dict | None)
    check_settings({"out": out} | settings, keywords=False)
    if settings.get("control") is None and settings.get("estimators") is not None:
        settings["control"] = ()   # the config's control named the config's estimators
    for name in ("spp", "frames"):   # given: the same for every estimator or scene
        if settings.get(name) is not None:
            settings[f"{name}_for"] = ()
    for name, value in settings.items():   # NumPy's numbers as Python's
        kind = element_type(name)
        if kind is not None and value is not None:
            settings[name] = tuple(map(kind, value))
        elif isinstance(value, numbers.Integral) and not isinstance(value, bool):
            settings[name] = int(value)
    sweep = load_sweep(config or "default").replace(
        **{name: settings.pop(name) for name in SWEEP_FIELDS if name in settings})
    return RunConfig(out=pathlib.Path(out), **{name: getattr(sweep, name) for name in SWEEP_FIELDS},
                     **settings, sweep={**sweep.to_manifest(), **(note or {})})


def _run_config_signature() -> inspect.Signature:
    """:func:`run_config`'s signature as ``help`` shows it: ``out``, then its keywords."""
    from iblbench.harness.protocol.run_config import config_keywords, keyword_default

    keyword = inspect.Parameter.KEYWORD_ONLY
    return inspect.Signature(
        [inspect.Parameter("out", inspect.Parameter.POSITIONAL_OR_KEYWORD),
         inspect.Parameter("config", keyword, default=None),
         *(inspect.Parameter(name, keyword, default=keyword_default(name))
           for name in config_keywords()),
         inspect.Parameter("note", keyword, default=None)])


run_config.__signature__ = _run_config_signature()


@_naming_keywords
def check(out, budgets="budgets.toml"):
    """``iblbench check``: (checks DataFrame, verdict line, exit status 0 or 1); InputError on
    bad input (:func:`iblbench.harness.protocol.budgets.check`)."""
    from iblbench.harness.protocol.budgets import check as check_budgets

    check_type("out", out, pathlib.Path)
    check_type("budgets", budgets, pathlib.Path)
    return check_budgets(out, budgets)


@_naming_keywords
def report(out, **options) -> pathlib.Path:
    """``iblbench report``: write ``out/report/index.html`` and return its path; ``options``
    are those of :func:`iblbench.reports.report.write_report` (spp, seed, frame, pixel,
    ray_cost_ns, progress)."""
    from iblbench.reports.report import write_report

    check_type("out", out, pathlib.Path)
    hints = typing.get_type_hints(write_report)
    for name, value in options.items():   # an unknown one: write_report's TypeError
        if name in hints:
            check_type(name, value, hints[name])
    return pathlib.Path(write_report(out, **options)["path"])


# ---- scene dicts ---------------------------------------------------------------------------------

def _listed(value):
    """A single value as a list of one; None stays None."""
    if value is None or isinstance(value, (list, tuple)):
        return value
    return [value]


def _scene_entries(scenes, out: pathlib.Path, force: bool):
    """The runner's scene entries (names and .toml paths as given, each dict written as
    ``out/scenes/<name>.toml``), the files written, and the files and folders created."""
    from iblbench.scenes.registry import scene_key_problem

    entries, documents = [], {}
    for scene in scenes:
        if isinstance(scene, dict):
            name = _scene_name(scene)
            problem = scene_key_problem({k: v for k, v in scene.items() if k != "name"})
            if problem:   # before any name clash: a typo is the problem to report (issue 23)
                raise InputError(f"scene dict {name!r}", problem)
            if name in documents:
                raise InputError(f"scene dict {name!r}", "two scene dicts have this name; give "
                                                         "each its own 'name'")
            documents[name] = scene_toml(scene, name)
            entries.append(os.fspath(out / SCENE_FOLDER / f"{name}.toml"))
        else:   # a name or a path (run checked the types)
            entries.append(os.fspath(scene))
    written, created = [], {}   # created: path -> the text it held before (None: it was new)
    for name, text in documents.items():
        path = out / SCENE_FOLDER / f"{name}.toml"
        before = path.read_text(encoding="utf-8") if path.is_file() else None
        if before not in (None, text) and not force:
            _remove(created)
            raise InputError(path, f"holds another scene named {name!r}; give this dict another "
                                   "'name', use another out, or force=True to replace it")
        created |= {p: None for p in (out, path.parent) if not p.exists()}
        created[path] = before
        _write_scene(path, text)
        written.append(path)
    return entries, written, created


def _scene_name(scene: dict) -> str:
    from iblbench.scenes.registry import scene_names

    mesh = scene.get("mesh")
    default = (pathlib.Path(os.fspath(mesh["path"])).stem
               if isinstance(mesh, dict) and isinstance(mesh.get("path"), (str, os.PathLike))
               else None)
    name = scene.get("name", default)
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise InputError(f"scene dict {name!r}", "'name' must be letters, digits, '.', '_' or "
                                                 "'-' (it names files), e.g. 'bunny-park'")
    if name.lower() in scene_names():
        raise InputError(f"scene dict {name!r}", "'name' is a built-in scene's; give it another")
    return name


def scene_toml(scene: dict, name: str) -> str:
    """The TOML text of a scene dict, its relative ``mesh.path`` and ``environment.path`` made
    absolute (from the working directory); an InputError naming a key whose value TOML cannot
    hold."""
    where = f"scene dict {name!r}"
    top, tables = [], []
    for key, value in scene.items():
        if key == "name":
            continue
        if isinstance(value, dict):
            value = {k: (os.path.abspath(os.path.expanduser(os.fspath(v)))
                         if (key, k) in _PATH_KEYS and isinstance(v, (str, os.PathLike)) else v)
                     for k, v in value.items()}
            tables += ["", f"[{_toml_key(key, where)}]"] + [
                f"{_toml_key(k, where)} = {_toml_value(v, f'{key}.{k}', where)}"
                for k, v in value.items()]
        else:   # the registry reports what this section should have been
            top.append(f"{_toml_key(key, where)} = {_toml_value(value, key, where)}")
    return "\n".join(top + tables).strip() + "\n"


def _toml_key(key, where: str) -> str:
    if not isinstance(key, str):
        raise InputError(where, f"keys must be strings, got {key!r}")
    return key if _BARE_KEY.fullmatch(key) else json.dumps(key)


def _toml_value(value, key: str, where: str) -> str:
    from iblbench.harness.protocol.sweep import toml_value

    if hasattr(value, "tolist"):           # NumPy arrays and scalars
        value = value.tolist()
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if isinstance(value, (bool, int, float, str)):
        return toml_value(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v, key, where) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k, where)} = {_toml_value(v, f'{key}.{k}', where)}"
                                for k, v in value.items()) + " }"
    raise InputError(where, f"{key} must be a number, string, boolean, list or table, got "
                            f"{type(value).__name__}")


def _write_scene(path: pathlib.Path, text: str) -> None:
    from iblbench.foundation.atomic import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _remove(created: dict) -> None:
    """Undo :func:`_scene_entries` on bad input, newest first: a replaced scene file gets its
    previous text back; the files and folders it created go (a folder only when empty)."""
    for path, before in reversed(created.items()):
        if before is not None:
            _write_scene(path, before)
        elif path.is_dir():
            if not any(path.iterdir()):
                path.rmdir()
        else:
            path.unlink(missing_ok=True)
