"""Sweep configs: estimator overrides, the shipped configs, every config error, CLI overrides."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from iblbench.cli import main
from iblbench.commands.common import repeats_arg
from iblbench.harness.protocol.sweep import load_sweep, parse_estimator
from iblbench.foundation.errors import InputError

VALID = """\
protocol = "lab-reinhard-v1"
scenes = ["sphere-sun"]
estimators = ["uniform"]
spp = [4]
seeds = 1
resolution = "16x16"
env_res = 8
"""


def write(folder: Path, text: str, name: str = "sweep.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


# ---- estimator overrides ------------------------------------------------------------------------


def test_override_label_is_canonical_and_builds_the_parameter():
    spec = parse_estimator("Balanced_MIS{ shared_sequence = false }")
    assert spec.label == "balanced_mis{shared_sequence=false}"
    assert spec.make().params.shared_sequence is False
    assert json.loads(spec.params_json()) == {"shared_sequence": False, "mis_compensation": False}
    plain = parse_estimator("balanced_mis")
    assert plain.label == "balanced_mis" and plain.make().params.shared_sequence is True
    assert parse_estimator("uniform{}").label == "uniform"


@pytest.mark.parametrize("text, needles", [
    ("balanced_mis{shared_seq=false}", ("'balanced_mis' has no parameter 'shared_seq'",
                                        "valid parameters: mis_compensation, shared_sequence")),
    ("balanced_mis{shared_sequence=3}", ("shared_sequence", "must be bool", "got 3")),
    ("balanced_mis{shared_sequence=}", ("cannot read the parameters",)),
    ("balanced_mis{shared_sequence=[true]}", ("must be a TOML scalar",)),
    ("no_such{x=1}", ("unknown estimator 'no_such'", "uniform")),
    ("uniform{", ("cannot read estimator",)),
])
def test_bad_overrides(text, needles):
    with pytest.raises(InputError) as error:
        parse_estimator(text)
    for needle in needles:
        assert needle in str(error.value), str(error.value)


# ---- shipped configs ----------------------------------------------------------------------------


def test_quick_is_the_documented_sweep():
    quick = load_sweep("quick")
    assert quick.scenes == ("sphere-sun", "sphere-backlit")
    assert quick.estimators == ("uniform", "balanced", "balanced_mis")
    assert quick.spp == (64, 256) and quick.seeds == 16 and quick.first_seed == 0
    assert "flip" not in quick.metrics   # the mutation suite's budgets layer runs --no-flip
    assert quick.resolution == (48, 48) and quick.env_res == 32
    assert quick.frames is None and quick.time_budget_ms == () and not quick.sanitize
    assert quick.protocol == "lab-reinhard-v1" and quick.source == "shipped:quick"


# The default sweep's estimators and their spp levels, as harness/configs/default.toml listed them
# before each estimator declared its own part (Estimator.sweep): the declarations must give the
# very same cells, in the same order (the table's rows, the report's colours); product at the
# default levels since its sample cost about hierarchical's (issue 37), 4-256 before.
DEFAULT_ESTIMATORS = ["uniform", "balanced", "balanced_mis", "havran", "bis", "smc", "brdf", "envmap",
                      'envmap{mis="brdf"}', 'envmap{mis="brdf",mis_compensation=true}',
                      "hierarchical", "fis", "restir", "product"]
DEFAULT_SPP = {"uniform": (64, 256, 1024, 4096), "balanced": (64, 256, 1024, 4096),
               "balanced_mis": (16, 64, 256, 1024), "bis": (1, 4, 16), "smc": (1, 4, 16),
               "restir": (1, 4, 16, 64)}


def test_default_and_full_parse():
    default = load_sweep("default")
    # The built-ins' declarations give today's cells; an installed plugin may add its own.
    from iblbench.estimators.registry import builtin_names
    builtin = [label for label in default.estimators if label.split("{")[0] in builtin_names()]
    assert builtin == DEFAULT_ESTIMATORS
    assert {name: v for name, v in default.spp_for if name in builtin_names()} == DEFAULT_SPP
    assert default.spp == (8, 32, 128, 512)
    assert {"sphere-park", "park-turn"} <= set(default.scenes)
    assert default.repeats == 10 and default.repeats_for == () and default.seeds == 2
    full = load_sweep("full")
    assert "balanced_mis{shared_sequence=false}" in full.estimators
    assert "balanced_mis" in full.estimators and full.seeds == 8
    assert full.resolution == (256, 256) and min(full.spp) == 15 and max(full.spp) == 1024
    from iblbench.scenes.registry import load_scene, scene_names
    # full covers every static built-in scene; the sequence scenes (blob-day, torus-moving,
    # sphere-switch: 30-67 frames each) have their own sweep, temporal.
    static = [n for n in scene_names() if load_scene(n, env_res=4).environment.is_static]
    assert sorted(full.scenes) == static
    temporal = load_sweep("temporal")
    assert sorted(temporal.scenes) == sorted(set(scene_names()) - set(static))
    assert {"havran", "bis", "smc"} <= set(temporal.estimators)


def test_config_fields(tmp_path):
    sweep = load_sweep(write(tmp_path, VALID.replace('resolution = "16x16"', "resolution = [20, 12]")
                             + 'frames = "2..4"\ntime_budget_ms = 5\nsanitize = true\n'
                             'description = "d"\n'))
    assert sweep.resolution == (20, 12) and sweep.frames == (2, 3, 4)
    assert sweep.time_budget_ms == (5.0,) and sweep.sanitize and sweep.description == "d"
    assert sweep.repeats == 5 and sweep.metrics == ("de76", "de2000", "relmse", "flip")
    sweep = load_sweep(write(tmp_path, VALID + 'repeats = 3\nmetrics = ["flip", "relmse"]\n'))
    assert sweep.repeats == 3 and sweep.metrics == ("de76", "relmse", "flip")   # ΔE76 always
    sweep = load_sweep(write(tmp_path, VALID + "repeats = { default = 7, SMC = 2, bis = 3 }\n"))
    assert sweep.repeats == 7 and sweep.repeats_for == (("bis", 3), ("smc", 2))
    assert repeats_arg("4,smc=2") == (4, (("smc", 2),)) and repeats_arg("6") == (6, ())
    with pytest.raises(argparse.ArgumentTypeError, match="repeats for smc must be an integer"):
        repeats_arg("4,smc=0")
    assert load_sweep(write(tmp_path, VALID + "frames = [3, 1]\n")).frames == (1, 3)
    sweep = load_sweep(write(tmp_path, VALID.replace("spp = [4]",
                                                     "spp = { default = [8, 2, 8], BIS = [1] }")))
    assert sweep.spp == (2, 8) and sweep.spp_for == (("bis", (1,)),)
    for bad, needle in (("{ bis = [0] }", "spp for bis must be a list of positive integers"),
                        ('{ default = "4" }', "spp must be a list of positive integers")):
        with pytest.raises(InputError, match=needle):
            load_sweep(write(tmp_path, VALID.replace("spp = [4]", f"spp = {bad}")))


def test_estimators_run_their_own_spp_levels_unless_spp_is_given(tmp_path, capsys):
    """A sweep's ``spp`` table gives an estimator its own levels (issue 23); ``--spp`` gives
    every estimator the same ones again, and the manifest records both."""
    path = write(tmp_path, VALID.replace('["uniform"]', '["uniform", "envmap"]').replace(
        "spp = [4]", "spp = { default = [4], uniform = [2, 16] }"))
    out = tmp_path / "out"
    assert main(["run", "--config", str(path), "--out", str(out), "--no-progress"]) == 0
    table = pd.read_parquet(out / "results.parquet")
    assert sorted(zip(table.estimator, table.spp)) == [("envmap", 4), ("uniform", 2), ("uniform", 16)]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["spp_for"] == {"uniform": [2, 16]}
    assert main(["run", "--config", str(path), "--out", str(tmp_path / "flag"), "--spp", "8",
                 "--no-progress"]) == 0
    table = pd.read_parquet(tmp_path / "flag" / "results.parquet")
    assert sorted(zip(table.estimator, table.spp)) == [("envmap", 8), ("uniform", 8)]
    capsys.readouterr()


def test_an_spp_table_without_a_default_runs_each_estimators_own_levels(tmp_path, capsys):
    """``spp = { uniform = [4] }`` was refused as "spp is empty" (issue 35): every estimator of
    the sweep has levels of its own, so it has cells."""
    path = write(tmp_path, VALID.replace('["uniform"]', '["uniform", "envmap"]').replace(
        "spp = [4]", "spp = { uniform = [4], envmap = [2] }"))
    assert main(["run", "--config", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    table = pd.read_parquet(tmp_path / "out" / "results.parquet")
    assert sorted(zip(table.estimator, table.spp)) == [("envmap", 2), ("uniform", 4)]
    capsys.readouterr()


def test_relative_scene_files_are_found_from_the_config_folder(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "ball.toml").write_text("")
    sweep = load_sweep(write(tmp_path, VALID.replace('["sphere-sun"]', '["sub/ball.toml"]')))
    assert sweep.scenes == (str(tmp_path / "sub" / "ball.toml"),)


# ---- config errors: InputError naming the file and the problem ----------------------------------


@pytest.mark.parametrize("edit, needle", [
    (lambda t: t + "colour = 1\n", "unknown key 'colour'"),
    (lambda t: t + "spp = [8]\n", "TOML syntax error"),            # a key given twice
    (lambda t: t.replace("seeds = 1\n", ""), "missing required key 'seeds'"),
    (lambda t: t.replace("spp = [4]\n", ""), "missing required key 'spp'"),
    (lambda t: t.replace("lab-reinhard-v1", "srgb-v0"), "protocol must be 'lab-reinhard-v1'"),
    (lambda t: t.replace("spp = [4]", 'spp = "4"'), "spp must be a list of positive integers"),
    (lambda t: t.replace("spp = [4]", "spp = [0]"), "spp must be a list of positive integers"),
    (lambda t: t.replace("seeds = 1", "seeds = 0"), "seeds must be a positive integer"),
    (lambda t: t.replace("seeds = 1", "seeds = true"), "seeds must be a positive integer"),
    (lambda t: t.replace('"16x16"', '"16"'), "resolution must be"),
    (lambda t: t.replace("env_res = 8", "env_res = 2.5"), "env_res must be an integer in 1..4096"),
    (lambda t: t.replace("env_res = 8", "env_res = 100000"), "env_res must be an integer in 1..4096"),
    (lambda t: t.replace('"16x16"', '"100000x16"'), "integers in 1..16384"),
    (lambda t: t + 'frames = "some"\n', "frames must be"),
    (lambda t: t + "time_budget_ms = -1\n", "time_budget_ms must be a positive number"),
    (lambda t: t + 'sanitize = "yes"\n', "sanitize must be true or false"),
    (lambda t: t + "repeats = 0\n", "repeats must be an integer in 1..255"),
    (lambda t: t + "repeats = { smc = 1.5 }\n", "repeats for smc must be an integer in 1..255"),
    (lambda t: t + 'metrics = ["de76", "de99"]\n', "unknown metric 'de99'"),
    (lambda t: t.replace('["sphere-sun"]', '["no-such-scene"]'), "unknown scene 'no-such-scene'"),
    (lambda t: t.replace('["sphere-sun"]', '["missing.toml"]'), "not found"),
    (lambda t: t.replace('["sphere-sun"]', "[]"), "scenes must be a non-empty list"),
    (lambda t: t.replace('["uniform"]', '["nope"]'), "unknown estimator 'nope'"),
    (lambda t: t.replace('["uniform"]', '["uniform{beta=1}"]'), "valid parameters: shared_sequence"),
    (lambda t: t.replace('["uniform"]', '["uniform", "Uniform"]'), "lists an estimator twice"),
    (lambda t: t.replace('["uniform"]', '["uniform", "envmap"]').replace(
        "spp = [4]", "spp = { uniform = [4] }"), "spp gives envmap no levels"),
])
def test_bad_config(tmp_path, edit, needle):
    path = write(tmp_path, edit(VALID))
    with pytest.raises(InputError) as error:
        load_sweep(path)
    assert error.value.source == str(path)
    assert needle in str(error.value), str(error.value)


def test_missing_config_and_unknown_name(tmp_path):
    with pytest.raises(InputError, match="sweep config not found") as error:
        load_sweep(tmp_path / "nowhere.toml")
    assert str(tmp_path / "nowhere.toml") in str(error.value)
    with pytest.raises(InputError, match="shipped configs: default, frontier, full, quick, temporal"):
        load_sweep("quik")


def test_cli_bad_config_exits_2_and_writes_nothing(tmp_path, capsys):
    path = write(tmp_path, VALID + "colour = 1\n")
    out = tmp_path / "out"
    assert main(["run", "--config", str(path), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("iblbench: error: ") and str(path) in err and "colour" in err
    assert err.count("\n") == 1 and not out.exists()
    assert main(["run", "--config", "quick", "--estimator", "uniform{x=1}", "--out", str(out)]) == 2
    assert "valid parameters: shared_sequence" in capsys.readouterr().err and not out.exists()


# ---- the CLI: config fields, overridden by flags ------------------------------------------------


def test_flags_override_config_fields(tmp_path, capsys):
    path = write(tmp_path, VALID.replace("seeds = 1", "seeds = 2"))
    out = tmp_path / "out"
    code = main(["run", "--config", str(path), "--spp", "8", "--estimator",
                 "uniform{shared_sequence=false}", "--out", str(out), "--no-progress"])
    assert code == 0, capsys.readouterr().err
    table = pd.read_parquet(out / "results.parquet")
    # spp and estimator from the flags, seeds and sizes from the file.
    assert sorted(zip(table.estimator, table.spp, table.seed)) == [
        ("uniform{shared_sequence=false}", 8, 0), ("uniform{shared_sequence=false}", 8, 1)]
    assert (table.width == 16).all() and (table.height == 16).all() and (table.env_res == 8).all()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sweep"]["source"] == str(path.resolve())
    assert manifest["sweep"]["overridden_by_flags"] == ["--estimator", "--spp"]
    assert manifest["sweep"]["spp"] == [8] and manifest["sweep"]["seeds"] == 2
    assert manifest["estimator_params"] == {"uniform{shared_sequence=false}":
                                            '{"shared_sequence": false}'}
    images = out / "images" / "sphere-sun" / "f0"
    assert (images / "uniform-shared_sequence=false_spp8_s1.exr").is_file()


def test_both_variants_share_one_table(tmp_path, capsys):
    path = write(tmp_path, VALID.replace('["uniform"]',
                                         '["balanced_mis", "balanced_mis{shared_sequence=false}"]'))
    out = tmp_path / "out"
    assert main(["run", "--config", str(path), "--out", str(out), "--no-progress"]) == 0
    table = pd.read_parquet(out / "results.parquet").set_index("estimator")
    assert sorted(table.index) == ["balanced_mis", "balanced_mis{shared_sequence=false}"]
    shared, interleaved = (table.loc[label] for label in table.index)
    assert shared.estimator_version == interleaved.estimator_version
    # The parameter reaches the kernel: one seed, one spp, different images.
    assert shared.mean_delta_e76 != interleaved.mean_delta_e76
    assert "balanced_mis{shared_sequence=false}" in capsys.readouterr().out


def test_static_scene_runs_frame_0_whatever_frames_says(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", "--config", str(write(tmp_path, VALID)), "--frames", "3..5",
                 "--out", str(out), "--no-progress"]) == 0
    assert list(pd.read_parquet(out / "results.parquet").frame) == [0]


def test_frames_beyond_a_sequence_are_refused(tmp_path, capsys):
    (tmp_path / "day").mkdir()
    for index in range(2):
        np.save(tmp_path / "day" / f"f{index}.npy", np.full((6, 4, 4, 3), 0.5 + index, np.float32))
    trimesh.creation.icosphere(1).export(tmp_path / "ball.obj")
    scene = write(tmp_path, '[mesh]\npath = "ball.obj"\n[environment]\npath = "day/*.npy"\n'
                            '[camera]\neye = [0, 0, 3]\ntarget = [0, 0, 0]\n', "seq.toml")
    out = tmp_path / "out"
    assert main(["run", "--config", str(write(tmp_path, VALID)), "--scene", str(scene),
                 "--frames", "0,2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "frame 2 selected" in err and "2 frames" in err and not out.exists()


# ---- frames per scene (issue 24) -----------------------------------------------------------------

PER_SCENE = VALID.replace('["sphere-sun"]', '["sphere-switch", "sphere-park-switch"]') + \
    'frames = { default = "0:2", SPHERE-SWITCH = "10:12" }\n'


def test_a_frames_table_gives_scenes_their_own_frames(tmp_path, capsys):
    """Each scene runs its own selection or the default; the manifest records both; --frames
    gives every scene one selection again."""
    path = write(tmp_path, PER_SCENE)
    sweep = load_sweep(path)
    assert sweep.frames == slice(0, 2) and sweep.frames_for == (("sphere-switch", slice(10, 12)),)
    out = tmp_path / "out"
    assert main(["run", "--config", str(path), "--out", str(out), "--no-progress"]) == 0
    table = pd.read_parquet(out / "results.parquet")
    assert sorted(set(zip(table.scene, table.frame))) == [
        ("sphere-park-switch", 0), ("sphere-park-switch", 1), ("sphere-switch", 10),
        ("sphere-switch", 11)]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["frames_for"] == {"sphere-switch": "10:12"}
    assert manifest["config"]["frames"] == "0:2"
    flag = tmp_path / "flag"
    assert main(["run", "--config", str(path), "--out", str(flag), "--frames", "3..4",
                 "--no-progress"]) == 0
    table = pd.read_parquet(flag / "results.parquet")
    assert sorted(set(zip(table.scene, table.frame))) == [
        ("sphere-park-switch", 3), ("sphere-park-switch", 4), ("sphere-switch", 3),
        ("sphere-switch", 4)]
    capsys.readouterr()


@pytest.mark.parametrize("frames, needle", [
    ('{ sphere-sun = "0:2" }', "frames gives frames to scene 'sphere-sun', which scenes does not list"),
    ('{ default = "some" }', "frames must be"),
    ("{ sphere-switch = 3 }", "frames for sphere-switch: frames must be"),
    ('{ sphere-switch = "0:9:0" }', "frames for sphere-switch: frames slice step must not be zero"),
    ('{ sphere-switch = "0:2", SPHERE-SWITCH = [1, 2] }', "frames for sphere-switch: given twice"),
])
def test_a_bad_frames_table_names_the_problem(tmp_path, frames, needle):
    text = PER_SCENE.replace('{ default = "0:2", SPHERE-SWITCH = "10:12" }', frames)
    with pytest.raises(InputError, match=needle):
        load_sweep(write(tmp_path, text))


def test_frontier_runs_every_estimator_on_the_sequences_at_their_own_frames():
    """The shipped frontier sweep (issue 24): every estimator (those of the default sweep, and
    restir and product), the six sequence scenes, per-estimator spp levels (equal time), and per-scene frames that
    each scene has."""
    from iblbench.scenes.registry import builtin_frames
    from iblbench.harness.protocol.sweep import select_frames

    frontier = load_sweep("frontier")
    assert set(frontier.estimators) == set(DEFAULT_ESTIMATORS) | {"restir", "product"}
    assert set(frontier.scenes) == {"blob-day", "blob-minutes", "sphere-switch", "park-turn",
                                    "sphere-studio-moving", "sphere-park-switch"}
    assert dict(frontier.spp_for)["smc"] == (1, 4, 16) and frontier.seeds == 2
    own = dict(frontier.frames_for)
    for scene in frontier.scenes:
        frames = select_frames(own.get(scene, frontier.frames), builtin_frames(scene))
        assert len(frames) >= 6 and max(frames) < builtin_frames(scene)
        assert frames == list(range(frames[0], frames[-1] + 1))     # consecutive: flicker
    switch = select_frames(own["sphere-switch"], builtin_frames("sphere-switch"))
    assert switch[0] < 10 <= 19 < switch[-1]                          # both switches
