"""The runner in-process: resumption, refusing ambiguous scenes and unusable --out, the ΔE trend."""
import numpy as np
import pandas as pd
import pytest
import trimesh

from iblbench.harness.protocol.runner import RunConfig, run
from iblbench.foundation.errors import InputError


def tiny(out, **overrides):
    config = dict(out=out, scenes=("sphere-sun",), estimators=("uniform",), spp=(4,), seeds=1,
                  resolution=(16, 16), env_res=8, progress=False)
    config.update(overrides)
    return RunConfig(**config)


def test_rerun_keeps_finished_cells_and_adds_new_ones(tmp_path):
    first = run(tiny(tmp_path))
    second = run(tiny(tmp_path, spp=(4, 8)))
    assert sorted(second.spp) == [4, 8]
    kept = second[second.spp == 4].iloc[0]
    # Not recomputed: the measured times of the first run are carried over unchanged.
    assert kept.time_ms_host == first.iloc[0].time_ms_host
    third = run(tiny(tmp_path, spp=(8,)))
    assert sorted(third.spp) == [4, 8]   # a narrower rerun does not drop other cells


def test_error_falls_with_spp(tmp_path):
    table = run(tiny(tmp_path, spp=(4, 64), seeds=2, resolution=(24, 24)))
    means = table.groupby("spp").mean_delta_e76.mean()
    assert means[64] < means[4]
    assert (table.nonfinite == 0).all()
    assert np.all((table.effective_samples <= table.used_samples) & (table.used_samples <= table.spp))


def user_scene(folder, target=(0, 0, 0)):
    folder.mkdir()
    np.save(folder / "env.npy", np.full((6, 4, 4, 3), 0.5, np.float32))
    trimesh.creation.icosphere(1).export(folder / "ball.obj")
    (folder / "scene.toml").write_text(
        '[mesh]\npath = "ball.obj"\n[environment]\npath = "env.npy"\n'
        f'[camera]\neye = [0, 0, 3]\ntarget = {list(target)}\n')
    return str(folder / "scene.toml")


def test_two_scenes_with_one_name_are_refused(tmp_path):
    scenes = (user_scene(tmp_path / "a"), user_scene(tmp_path / "b"))
    with pytest.raises(InputError, match="scene name 'scene' is also the name of"):
        run(tiny(tmp_path / "out", scenes=scenes))
    assert not (tmp_path / "out").exists()


def test_out_that_is_a_file_is_refused(tmp_path):
    target = tmp_path / "file"
    target.write_text("not a folder")
    with pytest.raises(InputError, match="not a directory"):
        run(tiny(target))
    with pytest.raises(InputError, match="cannot create the output directory"):
        run(tiny(target / "below"))


def test_a_camera_that_sees_no_geometry_is_refused_before_out_is_made(tmp_path):
    # The fuzz test's meshes moved out of view left a half-written --out behind.
    scene = user_scene(tmp_path / "a", target=(0, 0, 6))
    with pytest.raises(InputError, match="the camera sees none of the mesh .*ball.obj"):
        run(tiny(tmp_path / "out", scenes=(scene,)))
    assert not (tmp_path / "out").exists()


def test_metrics_and_repeats_flags_and_what_a_rerun_keeps(tmp_path, capsys):
    from iblbench.cli import main

    flags = ["run", "--scene", "sphere-sun", "--estimator", "uniform", "--spp", "4", "--seeds", "1",
             "--res", "16x16", "--env-res", "8", "--no-progress", "--out", str(tmp_path)]
    assert main(flags + ["--no-flip", "--repeats", "2"]) == 0
    table = pd.read_parquet(tmp_path / "results.parquet")
    assert table.flip.isna().all() and (table.metrics == "de76,de2000,relmse").all()
    assert (table.time_repeats >= 2).all() and table.mean_delta_e2000.notna().all()
    capsys.readouterr()
    # Fewer repeats and fewer metrics than the row has: resumed.  More of either: recomputed
    # (7 renders are more than the 2 asked for can become: at most 3 × 2, timing module).
    assert main(flags + ["--metrics", "de76", "--repeats", "1"]) == 0
    assert "resumed: 1 cells already done, 0 to run" in capsys.readouterr().err
    assert main(flags + ["--no-flip", "--repeats", "7"]) == 0
    assert "resumed" not in capsys.readouterr().err
    assert (pd.read_parquet(tmp_path / "results.parquet").time_repeats >= 7).all()


def test_the_git_revision_is_found_from_the_checkout():
    """Tests run from the project's git checkout (make test, CI's clone), so the manifest's
    revision is a commit, not "unknown": provenance counts its depth below the checkout right."""
    import re

    from iblbench.harness.protocol import provenance

    assert re.fullmatch(r"[0-9a-f]{40}(-dirty)?", provenance.git_revision())


@pytest.mark.parametrize("scene, traced", [("sphere-sun", False), ("park-ground", True)])
def test_a_tracing_visibility_bar_only_for_a_scene_with_shadows(tmp_path, capsys, scene, traced):
    """sphere-sun asks for no visibility, so no bar says it is being traced (issue 35)."""
    from iblbench.harness.protocol.runner import Runner

    runner = Runner(RunConfig(out=tmp_path / "out", scenes=(scene,), estimators=("uniform",),
                              spp=(1,), seeds=1, resolution=(16, 16), progress=True))
    runner._trace(runner.plans[0])
    assert ("tracing visibility" in capsys.readouterr().err) == traced
