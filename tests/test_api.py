"""The Python API (issue 11): ``iblbench.run`` runs a sweep from a notebook, with scenes as
dicts, TOML paths or built-in names, and returns the sweep's rows of the results table; a bad
dict is a one-line InputError naming the key, and leaves nothing behind.

Tiny sizes (16×16 pixels, 4×4 cube faces, 1 timed render) keep each run to seconds.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

import iblbench
from iblbench.harness.protocol.results import TABLE, read_manifest

TINY = dict(resolution="16x16", env_res=4, repeats=1, metrics="de76,relmse", progress=False)


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """A mesh and a cube map (a bright +Z face) for scene dicts."""
    folder = tmp_path_factory.mktemp("api")
    trimesh.creation.icosphere(subdivisions=1).export(folder / "ball.obj")
    env = np.full((6, 4, 4, 3), 0.5, np.float32)
    env[4] *= 4.0
    np.save(folder / "sky.npy", env)
    return folder


def ball(folder: Path, **changes) -> dict:
    return {"name": "ball", "mesh": {"path": str(folder / "ball.obj")},
            "environment": {"path": str(folder / "sky.npy")},
            "material": {"kd": 0.6, "ks": 0.2, "shininess": 40},
            "camera": {"eye": [0.0, 0.0, 3.0], "target": [0, 0, 0]}} | changes


@pytest.fixture(scope="module")
def swept(folder, tmp_path_factory):
    """A dict scene and a built-in scene × uniform × spp 4, 8 × 2 seeds."""
    out = tmp_path_factory.mktemp("api-run") / "run"
    table = iblbench.run(scenes=[ball(folder), "sphere-sun"], estimators="uniform", spp=[4, 8],
                         seeds=2, out=out, **TINY)
    return out, table


def test_run_returns_the_rows_of_the_sweep(swept):
    out, table = swept
    assert isinstance(table, pd.DataFrame)
    expected = {(scene, "uniform", spp, 0, seed) for scene in ("ball", "sphere-sun")
                for spp in (4, 8) for seed in (0, 1)}
    assert set(zip(table.scene, table.estimator, table.spp, table.frame, table.seed)) == expected
    assert len(table) == len(expected)
    assert (table.width == 16).all() and (table.env_res == 4).all()
    assert table.mean_delta_e76.notna().all() and (table.mean_delta_e76 > 0).all()
    written = pd.read_parquet(out / TABLE)
    assert len(written) == len(expected)


def test_a_dict_scene_is_recorded_as_a_file_in_out(swept, folder):
    out, _ = swept
    manifest = read_manifest(out)
    scene_file = out / "scenes" / "ball.toml"
    assert str(scene_file.resolve()) in manifest["config"]["scenes"]
    assert "sphere-sun" in manifest["config"]["scenes"]
    assert manifest["sweep"]["via"] == "iblbench.run (Python API)"
    text = scene_file.read_text(encoding="utf-8")
    assert f'path = "{folder / "ball.obj"}"' in text and "shininess = 40" in text


def test_a_rerun_resumes_and_a_second_sweep_returns_only_its_rows(swept, folder, capsys):
    out, first = swept
    again = iblbench.run(scenes=[ball(folder), "sphere-sun"], estimators="uniform", spp=[4, 8],
                         seeds=2, out=out, **TINY)
    assert "resumed: 8 cells already done, 0 to run" in capsys.readouterr().err
    key = ["scene", "spp", "seed"]
    pd.testing.assert_frame_equal(again.sort_values(key).reset_index(drop=True),
                                  first.sort_values(key).reset_index(drop=True))
    other = iblbench.run(scenes="sphere-sun", estimators=["uniform"], spp=2, seeds=1, out=out, **TINY)
    assert set(zip(other.scene, other.spp, other.seed)) == {("sphere-sun", 2, 0)}
    assert len(pd.read_parquet(out / TABLE)) == 9


def test_relative_paths_in_a_dict_are_taken_from_the_working_directory(folder, tmp_path,
                                                                      monkeypatch):
    monkeypatch.chdir(folder)
    scene = ball(folder, mesh={"path": "ball.obj"}, environment={"path": "sky.npy"})
    table = iblbench.run(scenes=[scene], estimators="uniform", spp=2, seeds=1,
                         out=tmp_path / "rel", **TINY)
    assert list(table.scene) == ["ball"]
    assert f'"{folder / "sky.npy"}"' in (tmp_path / "rel" / "scenes" / "ball.toml").read_text()


@pytest.mark.parametrize("change, needles", [
    ({"material": {"kdd": 0.3}}, ["scene dict 'ball'", "unknown key 'kdd' in [material]"]),
    ({"camera": {"eye": [0, 0], "target": [0, 0, 0]}}, ["scene dict 'ball'", "camera.eye"]),
    ({"camera": {"eye": None, "target": [0, 0, 0]}}, ["scene dict 'ball'", "camera.eye", "NoneType"]),
    ({"lights": {"sun": 1}}, ["scene dict 'ball'", "unknown section [lights]"]),
    ({"environment": {"path": "no-such.exr"}}, ["no-such.exr", "not found"]),
    ({"name": "sphere-sun"}, ["scene dict 'sphere-sun'", "built-in"]),
    ({"name": "a b"}, ["'name' must be"]),
])
def test_a_bad_dict_is_one_line_naming_the_key_and_leaves_nothing(folder, tmp_path, change, needles):
    out = tmp_path / "bad"
    with pytest.raises(iblbench.InputError) as error:
        iblbench.run(scenes=[ball(folder, **change)], estimators="uniform", spp=2, seeds=1,
                     out=out, **TINY)
    message = str(error.value)
    assert "\n" not in message
    for needle in needles:
        assert needle in message, message
    assert not out.exists()


def test_two_dicts_of_one_name_and_a_changed_dict_are_refused(swept, folder):
    out, _ = swept
    with pytest.raises(iblbench.InputError, match="two scene dicts have this name"):
        iblbench.run(scenes=[ball(folder), ball(folder)], estimators="uniform", spp=2, seeds=1,
                     out=out, **TINY)
    brighter = ball(folder, material={"kd": 0.8, "ks": 0.1})
    before = (out / "scenes" / "ball.toml").read_text()
    with pytest.raises(iblbench.InputError, match="holds another scene named 'ball'"):
        iblbench.run(scenes=[brighter], estimators="uniform", spp=2, seeds=1, out=out, **TINY)
    assert (out / "scenes" / "ball.toml").read_text() == before
    # force=True replaces the file, but bad input elsewhere puts the old scene back
    with pytest.raises(iblbench.InputError, match="unifrom"):
        iblbench.run(scenes=[brighter], estimators="unifrom", spp=2, seeds=1, out=out,
                     force=True, **TINY)
    assert (out / "scenes" / "ball.toml").read_text() == before


def test_a_typo_in_a_dict_under_a_name_out_already_has_is_reported_as_the_typo(swept, folder):
    """Issue 23: a dict scene with a typo'd key, under a name already used in that out, was
    reported as a name clash instead of the typo."""
    out, _ = swept
    typo = ball(folder, material={"kd": 0.5, "shinyness": 20})
    with pytest.raises(iblbench.InputError, match="unknown key 'shinyness' in \\[material\\]"):
        iblbench.run(scenes=[typo], estimators="uniform", spp=2, seeds=1, out=out, **TINY)


def test_bad_arguments_are_input_errors(tmp_path):
    for arguments, needle in ((dict(resolution="16by16"), "resolution"),
                              (dict(metrics=["de76", "de99"]), "de99"),
                              (dict(spp=0), "spp"), (dict(estimators="unifrom"), "unifrom"),
                              (dict(scenes=[3.5]), "scenes must be a string, a path, a dict"),
                              # issue 23: spp=[16.5] ran as 16; "16,64" and seeds="2" raised
                              # a raw ValueError or TypeError
                              (dict(spp=[16.5]), r"spp must be a whole number.*16\.5"),
                              (dict(spp="16,64"), r"spp must be a whole number.*'16,64'"),
                              (dict(seeds="2"), r"seeds must be a whole number.*'2'"),
                              (dict(seeds=True), "seeds must be a whole number")):
        with pytest.raises(iblbench.InputError, match=needle):
            iblbench.run(**({"scenes": "sphere-sun", "estimators": "uniform", "spp": 2,
                             "seeds": 1, "out": tmp_path / "x"} | arguments))
        assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("arguments, message", [
    (dict(device=5), "device must be a string or None, got 5"),
    (dict(out=123), "out must be a path, got 123"),
    (dict(metrics=["de76", 5]), "metrics must be a string or a list of strings, got ['de76', 5]"),
    (dict(force="no"), "force must be True or False, got 'no'"),
    (dict(sanitize="no"), "sanitize must be True or False, got 'no'"),
    (dict(save_inputs=3), "save_inputs must be True or False, got 3"),
    (dict(progress="yes"), "progress must be True, False or None, got 'yes'"),
    (dict(workers=2.0), "workers must be a whole number or None, got 2.0"),
    (dict(scheduler=8786), "scheduler must be a string or None, got 8786"),
    (dict(control=[1]), "control must be a string or a list of strings, got [1]"),
    (dict(time_budget_ms=["5"]), "time_budget_ms must be a number or a list of numbers, got ['5']"),
    (dict(repeats={"default": "3"}),
     "repeats must be a whole number or a dict of whole numbers, got {'default': '3'}"),
    (dict(config=3), "config must be a string, a path or None, got 3"),
])
def test_every_keyword_of_run_is_type_checked(tmp_path, arguments, message):
    """Issue 35: each keyword's type is checked against its RunConfig field's before any is
    used; device=5, out=123 and metrics=["de76", 5] raised AttributeError or TypeError, and
    force="no", sanitize="no" and save_inputs=3 ran as True."""
    with pytest.raises(iblbench.InputError) as caught:
        iblbench.run(**({"scenes": "sphere-sun", "estimators": "uniform", "spp": 2, "seeds": 1,
                         "out": tmp_path / "x"} | TINY | arguments))
    assert str(caught.value) == message
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("call, arguments, message", [
    ("run_config", dict(device=5), "device must be a string or None, got 5"),
    ("run_config", dict(force="no"), "force must be True or False, got 'no'"),
    ("run_config", dict(spp=["4"]), "spp must be a list of whole numbers, got ['4']"),
    ("run_config", dict(note=3), "note must be a dict or None, got 3"),
    ("check", dict(budgets=5), "budgets must be a path, got 5"),
    ("report", dict(spp="5"), "spp must be a whole number or None, got '5'"),
    ("report", dict(pixel=(1,)), "pixel must be a list of 2 whole numbers or None, got (1,)"),
    ("report", dict(progress=1), "progress must be True, False or None, got 1"),
])
def test_the_other_functions_check_their_types(tmp_path, call, arguments, message):
    """run_config takes parsed values, of its fields' types; check and report their
    parameters'."""
    with pytest.raises(iblbench.InputError) as caught:
        getattr(iblbench, call)(tmp_path, **arguments)
    assert str(caught.value) == message


def test_numpy_numbers_are_taken_as_pythons(tmp_path):
    """A NumPy integer is a whole number; the RunConfig holds Python's (its manifest is JSON)."""
    config = iblbench.run_config(tmp_path, spp=np.array([4, 8]).tolist() + [np.int64(16)],
                                 seeds=np.int64(2), workers=np.int32(1))
    assert config.spp == (4, 8, 16) and config.seeds == 2 and config.workers == 1
    assert all(type(value) is int for value in (*config.spp, config.seeds, config.workers))


def test_import_is_light_and_documented():
    """``import iblbench`` starts no OpenCL, pandas or trimesh; ``help(iblbench)`` shows run."""
    code = ("import sys, iblbench; print(json.dumps([m for m in ('pyopencl', 'pandas', 'trimesh')"
            " if m in sys.modules]))")
    done = subprocess.run([sys.executable, "-c", "import json; " + code], capture_output=True,
                          text=True, check=True)
    assert json.loads(done.stdout) == []
    assert "iblbench.run(" in iblbench.__doc__ and "scene dict" in iblbench.__doc__
    assert set(iblbench.__all__) >= {"run", "check", "report", "InputError"}


# run_config's keywords before RunConfig's fields were read from one definition (issue 33).
RUN_CONFIG_KEYWORDS = {
    "out", "config", "scenes", "estimators", "spp", "seeds", "first_seed", "frames", "resolution",
    "env_res", "time_budget_ms", "repeats", "repeats_for", "metrics", "sanitize", "device",
    "launch_shape", "save_inputs", "force", "progress", "workers", "scheduler", "control", "note"}


def test_run_config_keeps_its_keywords_and_refuses_others(tmp_path):
    import inspect

    parameters = inspect.signature(iblbench.run_config).parameters
    assert set(parameters) == RUN_CONFIG_KEYWORDS
    assert parameters["save_inputs"].default is False and parameters["force"].default is False
    assert parameters["seeds"].default is None   # None: the sweep config's
    with pytest.raises(TypeError, match="spp_levels"):
        iblbench.run_config(tmp_path, spp_levels=[4])


def test_runs_keywords_are_checked_against_the_fields():
    """A keyword of ``run`` that is no documented field of RunConfig, or a field that ``run``
    lacks, fails at definition (so at ``import iblbench``); each field is in its docstring."""
    from iblbench import _keywords_of_run_config
    from iblbench.harness.protocol.run_config import api_fields

    names = [name for name in inspect_parameters(iblbench.run) if name != "config"]
    for keywords in (names + ["spp_levels"], [n for n in names if n != "control"]):
        function = eval(f"lambda *, {', '.join(keywords)}: None")
        function.__doc__ = ""
        with pytest.raises(TypeError, match="spp_levels|control"):
            _keywords_of_run_config(function)
    assert all(f"``{name}``: " in iblbench.run.__doc__ for name in api_fields())


def inspect_parameters(function) -> list[str]:
    import inspect

    return list(inspect.signature(function).parameters)


def test_the_flags_and_the_keywords_give_one_config(tmp_path):
    """``iblbench run``'s flags and run_config's keywords of the same values give equal
    RunConfigs, every field away from its default."""
    import dataclasses

    from iblbench.cli import build_parser
    from iblbench.commands.run import run_settings
    from iblbench.harness.protocol.run_config import RunConfig

    args = build_parser().parse_args([
        "run", "--config", "quick", "--scene", "sphere-switch", "--estimator", "uniform",
        "--estimator", "envmap", "--control", "envmap", "--spp", "4,8", "--seeds", "3",
        "--first-seed", "5", "--frames", "1:3", "--res", "16x8", "--env-res", "8",
        "--time-budget-ms", "5,7", "--repeats", "3,envmap=2", "--metrics", "de76,relmse",
        "--force", "--out", str(tmp_path), "--save-inputs", "--sanitize", "--workers", "2",
        "--device", "cpu", "--launch-shape", "sample-block", "--no-progress"])
    settings, flags = run_settings(args)
    from_flags = iblbench.run_config(args.out, config="quick", **settings, note={})
    from_keywords = iblbench.run_config(
        tmp_path, config="quick", scenes=["sphere-switch"], estimators=["uniform", "envmap"],
        control=["envmap"], spp=[4, 8], seeds=3, first_seed=5, frames=slice(1, 3),
        resolution=(16, 8), env_res=8, time_budget_ms=[5, 7], repeats=3,
        repeats_for=(("envmap", 2),), metrics=("de76", "relmse"), force=True, save_inputs=True,
        sanitize=True, workers=2, device="cpu", launch_shape="sample_block", progress=False,
            note={})
    assert from_flags == from_keywords
    defaults = RunConfig(out=tmp_path / "elsewhere")
    same = [field.name for field in dataclasses.fields(RunConfig)
            if getattr(from_flags, field.name) == getattr(defaults, field.name)]
    # the per-name fields have no flag; --scheduler excludes --workers
    assert same == ["frames_for", "spp_for", "scheduler"], same
    assert flags == ["--scene", "--estimator", "--spp", "--seeds", "--first-seed", "--frames",
                     "--res", "--env-res", "--time-budget-ms", "--sanitize", "--repeats",
                     "--metrics", "--control"]


FLAG = re.compile(r"(?<![\w-])--[a-z]")   # a command-line flag such as --first-seed


ONE_CELL = {"scenes": "sphere-sun", "estimators": "uniform", "spp": 2, "seeds": 1} | TINY


@pytest.fixture(scope="module")
def one_cell(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("api-one") / "run"
    iblbench.run(out=out, **ONE_CELL)
    return out


@pytest.mark.parametrize("call, arguments, named", [
    ("run", dict(spp=0), "spp values"),
    ("run", dict(spp=40000), "spp=40000 is above"),
    ("run", dict(seeds=0), "seeds must be in"),
    ("run", dict(first_seed=8388607, seeds=2), "first_seed=8388607 with seeds=2"),
    ("run", dict(time_budget_ms=-1), "time_budget_ms must be positive"),
    ("run", dict(scenes="park-turn", frames="100:200"), "frames='100:200' selects no frame"),
    ("run", dict(out=Path(__file__)), "out exists and is not a directory"),
    ("run", dict(used_out=True, resolution="20x12"), "resolution='16x16' (now 20x12)"),
    ("run", dict(used_out=True, resolution="20x12"), "use another out, or force=True"),
    ("run", dict(unreadable=True), "use a new out"),
    ("run", dict(nan_sky=True), "pass sanitize=True"),
    ("report", dict(spp=5), "spp=5 is not in the run"),
    ("report", dict(seed=7), "seed=7 is not in the run"),
    ("report", dict(frame=3), "frame=3 is not in the run"),
    ("report", dict(pixel=(0, 0)), "pixel=(0, 0) is not a covered pixel"),
    ("report", dict(no_table=True), "run iblbench.run(out=...) first"),
    ("check", dict(no_table=True), "run iblbench.run(out=...) first"),
])
def test_api_errors_name_its_keywords_not_the_command_lines_flags(tmp_path, folder, one_cell, call,
                                                                  arguments, named):
    """Issue 23: errors raised from the Python API named flags it does not have (--first-seed,
    --spp, --force, report's --pixel); each names the keyword instead."""
    arguments = dict(arguments)
    if arguments.pop("unreadable", False):
        (tmp_path / "x").mkdir()
        (tmp_path / "x" / TABLE).write_text("not parquet")
    if arguments.pop("nan_sky", False):
        np.save(tmp_path / "nan.npy", np.full((6, 4, 4, 3), np.nan, np.float32))
        arguments["scenes"] = ball(folder, environment={"path": str(tmp_path / "nan.npy")})
    with pytest.raises(iblbench.InputError) as caught:
        if arguments.pop("no_table", False):
            getattr(iblbench, call)(tmp_path)
        elif call == "report":
            iblbench.report(one_cell, **arguments)
        else:
            out = one_cell if arguments.pop("used_out", False) else tmp_path / "x"
            iblbench.run(**(ONE_CELL | {"out": out} | arguments))
    message = str(caught.value)
    assert named in message and not FLAG.search(message), message


def test_the_command_line_still_names_its_flags(tmp_path, capsys):
    """The same errors from ``iblbench run`` and ``report`` name the flags."""
    from iblbench.cli import main

    flags = ["--scene", "sphere-sun", "--estimator", "uniform", "--seeds", "1", "--res", "16x16"]
    assert main(["run", "--out", str(tmp_path / "x"), *flags, "--first-seed", "8388607",
                 "--seeds", "2"]) == 2
    assert "--first-seed 8388607 with --seeds 2" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 2
    assert "run 'iblbench run --out DIR' first" in capsys.readouterr().err


def test_the_device_error_names_the_keyword_inside_the_api(monkeypatch):
    """Only a simulator installed: the hint names ``device=`` from the API, --device otherwise."""
    from iblbench.estimators.runtime import device
    from iblbench.foundation.errors import python_keywords

    simulator = type("Simulator", (), {"is_simulator": True, "label": "Oclgrind"})()
    monkeypatch.setattr(device, "all_devices", lambda: [simulator])
    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    with pytest.raises(iblbench.InputError, match=r"\(--device oclgrind\)"):
        device.choose_device()
    with python_keywords(), pytest.raises(iblbench.InputError, match=r"\(device='oclgrind'\)"):
        device.choose_device()
