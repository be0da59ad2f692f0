"""Environment sequences (day, moving-lights, switch, user globs), --frames slices, per-frame
FrameCache builds and reuse, and the flicker metric."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from iblbench.estimators.runtime import framecache
from iblbench.cli import main
from iblbench.harness.protocol.metrics import delta_e_images
from iblbench.commands.common import frames_arg
from iblbench.harness.protocol.sweep import parse_frames, select_frames
from iblbench.scenes import cubemap, registry, sequences, sky
from iblbench.foundation.errors import InputError
from iblbench.scenes.gbuffer import trace_gbuffer
from iblbench.scenes.imageio import read_exr, write_exr

RES = 8   # cube faces of the sequence tests


# ---- day ----------------------------------------------------------------------------------------

def independent_sun(hour: float, latitude_deg: float, declination_deg: float) -> np.ndarray:
    """The sun's unit vector in (east, north, up) by rotating its equatorial position: an
    independent route to the elevation and azimuth of ``sequences.solar_position``."""
    delta, phi, hour_angle = map(math.radians, (declination_deg, latitude_deg, 15.0 * (hour - 12)))
    # Equatorial frame: x towards the meridian's equator point, y east (z × x), z the celestial
    # pole; the hour angle grows westwards.
    s = np.array([math.cos(delta) * math.cos(hour_angle), -math.cos(delta) * math.sin(hour_angle),
                  math.sin(delta)])
    up = np.array([math.cos(phi), 0.0, math.sin(phi)])
    north = np.array([-math.sin(phi), 0.0, math.cos(phi)])
    east = np.cross(north, up)
    return np.array([s @ east, s @ north, s @ up])


@pytest.mark.parametrize("index", [0, 20, 33, 50])
def test_day_sun_follows_an_independent_solar_position(index):
    hour = sequences.day_hours()[index]
    enu = independent_sun(hour, sequences.DAY_LATITUDE_DEG, sequences.DAY_DECLINATION_DEG)
    elevation, azimuth = sequences.day_sun(index)
    assert elevation == pytest.approx(math.degrees(math.asin(enu[2])), abs=1e-6)
    # The map's compass: +X east, +Z south, Y up.
    expected = np.array([enu[0], enu[2], -enu[1]])
    assert np.allclose(sky.sun_direction(elevation, azimuth), expected, atol=1e-9)


def test_day_spans_a_real_solar_day():
    hours = sequences.day_hours()
    elevations = np.array([sequences.day_sun(i)[0] for i in range(sequences.DAY_FRAMES)])
    assert len(hours) == 67 == sequences.DAY_FRAMES
    assert elevations.max() == pytest.approx(90 - 45 + 23.44, abs=0.05)   # solar noon, 45° N
    assert elevations[0] < -5 and elevations[-1] < -5                     # below at both ends
    # Sunrise/sunset (cos H0 = −tan φ tan δ) fall between the frames where the sign changes.
    h0 = math.degrees(math.acos(-math.tan(math.radians(45)) * math.tan(math.radians(23.44)))) / 15
    rise = np.flatnonzero(elevations > 0)[0]
    assert hours[rise - 1] < 12 - h0 < hours[rise]


def test_day_brightest_texel_is_the_sun():
    index = 20
    env = sequences.day_frame(index, 16)
    y = cubemap.luminance(env.astype(np.float64))
    face, row, col = np.unravel_index(np.argmax(y), y.shape)
    direction = cubemap.texel_directions(16)[face, row, col]
    sun = sky.sun_direction(*sequences.day_sun(index))
    assert math.degrees(math.acos(np.clip(direction @ sun, -1, 1))) < 6.0   # within a texel


def test_day_night_frames_are_dim_finite_and_non_negative():
    noon = sequences.total_power(sequences.day_frame(33, RES))
    for index in (0, 1, 66):
        env = sequences.day_frame(index, RES)
        assert sequences.day_sun(index)[0] < 0
        assert np.isfinite(env).all() and env.min() >= 0 and env.max() > 0
        assert 0 < sequences.total_power(env) < 1e-3 * noon


def test_day_total_power_spans_orders_of_magnitude():
    powers = np.array([sequences.total_power(sequences.day_frame(i, RES))
                       for i in range(sequences.DAY_FRAMES)])
    assert np.isfinite(powers).all() and powers.min() > 0
    assert powers.max() / powers.min() >= 1e2      # ~1e5 with the documented twilight model
    assert np.argmax(powers) in range(30, 37)      # around solar noon


# ---- switch and moving lights ---------------------------------------------------------------------

def test_switch_turns_a_strong_light_on_and_off_at_the_documented_frames():
    frames = [sequences.switch_frame(i, RES) for i in range(sequences.SWITCH_FRAMES)]
    power = np.array([sequences.total_power(f) for f in frames])
    on = np.arange(30)[(np.arange(30) >= 10) & (np.arange(30) < 20)]
    assert (sequences.SWITCH_ON, sequences.SWITCH_OFF) == (10, 20)
    assert power[10] / power[9] == pytest.approx(1 + sequences.SWITCH_POWER_RATIO, rel=0.02)
    assert power[20] / power[19] == pytest.approx(1 / (1 + sequences.SWITCH_POWER_RATIO), rel=0.02)
    assert np.ptp(power[on]) == 0 and np.ptp(np.delete(power, on)) == 0
    # Unchanged frames are the same array, so the runner can reuse their FrameCache.
    assert frames[0] is frames[9] is frames[25] and frames[10] is frames[19]
    assert frames[9] is not frames[10]


def test_moving_lights_move_smoothly_and_periodically():
    def angle(a, b):
        return math.degrees(math.acos(np.clip(a @ b, -1.0, 1.0)))

    n = sequences.MOVING_FRAMES
    paths = [[sky.sun_direction(*p) for p in sequences.moving_light_positions(t)] for t in range(n + 1)]
    steps = [angle(paths[t][i], paths[t + 1][i]) for t in range(n) for i in range(sequences.MOVING_LIGHTS)]
    assert max(steps) < 20.0 and min(steps) > 0.5          # moving, but in small steps
    assert all(angle(a, b) < 1e-6 for a, b in zip(paths[0], paths[n]))   # closed paths
    frame = sequences.moving_lights_frame(5, RES)
    assert np.isfinite(frame).all() and frame.min() > 0
    background = sequences.total_power(sequences._gradient_background(RES, *sequences.MOVING_BACKGROUND))
    assert sequences.total_power(frame) == pytest.approx(
        background + sequences.MOVING_LIGHTS * sequences.MOVING_POWER, rel=0.05)


def test_sequence_scenes_are_registered():
    for name, frames in (("blob-day", 67), ("torus-moving", 48), ("sphere-switch", 30),
                         ("blob-minutes", 24)):
        scene = registry.load_scene(name, env_res=RES)
        assert scene.environment.num_frames == frames and not scene.environment.is_static
        assert scene.environment.frame(frames - 1).shape == (6, RES, RES, 3)
    blob = registry.load_scene("blob-day", env_res=RES)
    assert len(blob.mesh.faces) > 100_000 and blob.material.shininess == 150


# ---- user sequences -----------------------------------------------------------------------------

SCENE = """
[mesh]
path = "ball.obj"
[environment]
path = "day/*.exr"
[camera]
eye = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
"""


@pytest.fixture
def exr_sequence(tmp_path):
    trimesh.creation.icosphere(2).export(tmp_path / "ball.obj")
    (tmp_path / "day").mkdir()
    for index in range(3):
        write_exr(tmp_path / "day" / f"f{index:02d}.exr", np.full((8, 16, 3), 1.0 + index, np.float32))
    (tmp_path / "scene.toml").write_text(SCENE)
    return tmp_path


def test_user_exr_glob_loads_as_a_sequence(exr_sequence):
    sequence = registry.load_scene(exr_sequence / "scene.toml").environment
    assert sequence.num_frames == 3
    assert [round(float(sequence.frame(i).mean()), 4) for i in range(3)] == [1.0, 2.0, 3.0]


def test_user_sequence_with_mismatched_sizes_names_the_file(exr_sequence, capsys):
    write_exr(exr_sequence / "day" / "f01.exr", np.full((16, 32, 3), 2.0, np.float32))
    with pytest.raises(InputError, match="frame faces are") as error:
        registry.load_scene(exr_sequence / "scene.toml")
    assert error.value.source.endswith("f01.exr") and "\n" not in str(error.value)
    out = exr_sequence / "out"
    assert main(["run", "--scene", str(exr_sequence / "scene.toml"), "--estimator", "uniform",
                 "--spp", "1", "--seeds", "1", "--res", "8x8", "--out", str(out),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "f01.exr" in err and "frame faces are" in err
    assert not out.exists()


# ---- --frames -----------------------------------------------------------------------------------

def test_parse_frames_slices():
    assert parse_frames("0:67:6") == slice(0, 67, 6)
    assert select_frames(parse_frames("0:67:6"), 67) == list(range(0, 67, 6))
    assert select_frames(parse_frames("::10"), 30) == [0, 10, 20]
    assert select_frames(parse_frames("-2:"), 30) == [28, 29]
    assert select_frames(parse_frames("5:100"), 30) == list(range(5, 30))
    assert parse_frames(":") is None and parse_frames("all") is None
    assert parse_frames("2..4") == (2, 3, 4) and parse_frames([3, 1]) == (1, 3)   # older forms
    for bad in ("1:2:0", "a:b", "1:2:3:4", "1.5:3", "", "x"):
        with pytest.raises(ValueError):
            parse_frames(bad)
        with pytest.raises(InputError, match="--frames"):
            frames_arg(bad)


def run_cli(out: Path, scene: str, *extra: str, estimators=("uniform",), spp="2", seeds="1") -> int:
    args = ["run", "--scene", scene, "--spp", spp, "--seeds", seeds, "--res", "12x12",
            "--env-res", str(RES), "--out", str(out), "--no-progress", *extra]
    for estimator in estimators:
        args += ["--estimator", estimator]
    return main(args)


def test_frames_slice_on_the_command_line(tmp_path, capsys):
    assert run_cli(tmp_path / "a", "sphere-switch", "--frames", "8:14:2") == 0
    table = pd.read_parquet(tmp_path / "a" / "results.parquet")
    assert sorted(table.frame) == [8, 10, 12]
    manifest = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert manifest["config"]["frames"] == "8:14:2"
    assert run_cli(tmp_path / "b", "sphere-switch", "--frames=-2:") == 0   # "=": argparse
    assert sorted(pd.read_parquet(tmp_path / "b" / "results.parquet").frame) == [28, 29]


@pytest.mark.parametrize("spec, message", [("3:1:0", "step must not be zero"),
                                           ("x:y", "START:STOP"), ("20:10", "selects no frame")])
def test_bad_frames_exit_2_with_one_line(tmp_path, capsys, spec, message):
    out = tmp_path / "out"
    assert run_cli(out, "sphere-switch", "--frames", spec) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and err.startswith("iblbench: error:")
    assert not out.exists()


def test_frames_slice_in_a_sweep_config(tmp_path):
    from iblbench.harness.protocol.sweep import load_sweep

    path = tmp_path / "sweep.toml"
    path.write_text('protocol = "lab-reinhard-v1"\nscenes = ["sphere-switch"]\n'
                    'estimators = ["uniform"]\nspp = [1]\nseeds = 1\nframes = "0:30:10"\n')
    sweep = load_sweep(path)
    assert sweep.frames == slice(0, 30, 10) and sweep.to_manifest()["frames"] == "0:30:10"
    path.write_text(path.read_text().replace('"0:30:10"', '"0:30:0"'))
    with pytest.raises(InputError, match="step must not be zero"):
        load_sweep(path)


# ---- FrameCache builds --------------------------------------------------------------------------

@pytest.fixture
def count_builds(monkeypatch):
    counts = {"init": 0, "cdf": 0, "frames": []}
    init, build_cdf = framecache.FrameCache.__init__, framecache.FrameCache._build_cdf

    def counted_init(self, compute, env, frame=0):
        counts["init"] += 1
        counts["frames"].append(frame)
        init(self, compute, env, frame)

    def counted_cdf(self):
        if self._cdf is None:
            counts["cdf"] += 1
        return build_cdf(self)

    monkeypatch.setattr(framecache.FrameCache, "__init__", counted_init)
    monkeypatch.setattr(framecache.FrameCache, "_build_cdf", counted_cdf)
    return counts


def test_static_scene_builds_its_frame_cache_once_per_run(tmp_path, count_builds):
    out = tmp_path / "out"
    assert run_cli(out, "sphere-sun", estimators=("uniform", "balanced_mis"), spp="1,2",
                   seeds="2") == 0
    assert len(pd.read_parquet(out / "results.parquet")) == 8     # 2 estimators × 2 spp × 2 seeds
    assert count_builds["init"] == 1 and count_builds["cdf"] == 1
    manifest = json.loads((out / "manifest.json").read_text())
    reuse = [s for s in manifest["skipped"] if s["stage"] == "framecache"]
    assert len(reuse) == 1 and "static environment" in reuse[0]["why"] and "8 cells" in reuse[0]["why"]
    assert [s["stage"] for s in manifest["stages"] if s["frame"] == 0].count("cdf") == 1


def test_sequence_builds_a_frame_cache_per_frame_and_reuses_identical_frames(tmp_path, count_builds):
    out = tmp_path / "moving"
    assert run_cli(out, "torus-moving", "--frames", "0:3", estimators=("uniform", "balanced_mis")) == 0
    assert count_builds["init"] == 3 and count_builds["cdf"] == 3 and count_builds["frames"] == [0, 1, 2]
    manifest = json.loads((out / "manifest.json").read_text())
    for frame in range(3):   # each frame's builds are timed in the manifest
        stages = {s["stage"] for s in manifest["stages"] if s["frame"] == frame}
        assert {"upload", "cdf"} <= stages
    table = pd.read_parquet(out / "results.parquet")
    assert (table.time_ms_build > 0).all()

    count_builds.update(init=0, cdf=0, frames=[])
    out = tmp_path / "switch"
    assert run_cli(out, "sphere-switch", "--frames", "8:13") == 0
    assert count_builds["frames"] == [8, 10] and count_builds["cdf"] == 2   # switched on at 10
    manifest = json.loads((out / "manifest.json").read_text())
    reused = sorted(s["frame"] for s in manifest["skipped"] if s["stage"] == "framecache")
    assert reused == [9, 11, 12]
    table = pd.read_parquet(out / "results.parquet").set_index("frame")
    assert (table.loc[[9, 11, 12], "time_ms_build"] == 0).all()
    assert (table.loc[[8, 10], "time_ms_build"] > 0).all()


# ---- flicker ------------------------------------------------------------------------------------

def hand_flicker(out: Path, scene_name: str, frames, stem: str) -> float:
    scene = registry.load_scene(scene_name, env_res=RES)
    mask = trace_gbuffer(scene.mesh, scene.material, scene.camera, 12, 12).mask
    maps = []
    for frame in frames:
        folder = out / "images" / scene_name / f"f{frame}"
        maps.append(delta_e_images(read_exr(folder / f"{stem}.exr"),
                                   read_exr(folder / "reference.exr"), mask)[0])
    return float(np.abs(maps[1][mask] - maps[0][mask]).mean())


def test_flicker_is_the_mean_change_of_the_delta_e_map(tmp_path):
    out = tmp_path / "out"
    assert run_cli(out, "torus-moving", "--frames", "0:6:2", estimators=("uniform", "balanced_mis"),
                   seeds="2") == 0
    table = pd.read_parquet(out / "results.parquet")
    assert table[table.frame == 0].flicker.isna().all()
    later = table[table.frame > 0]
    assert later.flicker.notna().all() and (later.flicker > 0).all()
    for _, row in later.iterrows():
        stem = f"{row.estimator}_spp2_s{row.seed}"
        expected = hand_flicker(out, "torus-moving", (row.frame - 2, row.frame), stem)
        assert row.flicker == pytest.approx(expected, rel=1e-5)
    # A single-frame run has no flicker.
    assert run_cli(tmp_path / "one", "sphere-sun") == 0
    assert pd.read_parquet(tmp_path / "one" / "results.parquet").flicker.isna().all()


def test_flicker_survives_resumption(tmp_path, capsys):
    whole, resumed = tmp_path / "whole", tmp_path / "resumed"
    assert run_cli(whole, "torus-moving", "--frames", "0:2") == 0
    assert run_cli(resumed, "torus-moving", "--frames", "0:1") == 0
    assert run_cli(resumed, "torus-moving", "--frames", "0:2") == 0   # frame 0 resumed from disk
    assert "resumed: 1 cells already done" in capsys.readouterr().err
    a = pd.read_parquet(whole / "results.parquet").set_index("frame")
    b = pd.read_parquet(resumed / "results.parquet").set_index("frame")
    assert math.isnan(b.loc[0, "flicker"]) and b.loc[1, "flicker"] > 0
    assert b.loc[1, "flicker"] == pytest.approx(a.loc[1, "flicker"], rel=1e-6)


# ---- minutes --------------------------------------------------------------------------------------

def test_minutes_is_the_day_sun_one_minute_a_frame():
    """Each frame's sun is the independent solar position at 9:00 + t minutes, consecutive suns
    are 15°·cos δ / 60 apart (the sun's daily circle at one minute of hour angle), and frame 0
    is day's frame at the same solar time (day's frame 22 is 3:00 + 22 · 18 h / 66 = 9:00)."""
    step = math.radians(15.0 / 60.0)
    expected = math.degrees(2 * math.asin(math.cos(math.radians(sequences.DAY_DECLINATION_DEG))
                                          * math.sin(step / 2)))
    suns = []
    for index in range(sequences.MINUTES_FRAMES):
        enu = independent_sun(9.0 + index / 60.0, sequences.DAY_LATITUDE_DEG,
                              sequences.DAY_DECLINATION_DEG)
        sun = sky.sun_direction(*sequences.sun_at(sequences.minutes_hour(index)))
        assert np.allclose(sun, [enu[0], enu[2], -enu[1]], atol=1e-9)
        suns.append(sun)
    steps = [math.degrees(math.acos(np.clip(a @ b, -1, 1))) for a, b in zip(suns, suns[1:])]
    assert np.allclose(steps, expected, atol=1e-5)
    assert sequences.day_hours()[22] == pytest.approx(9.0)
    np.testing.assert_allclose(sequences.minutes_frame(0, RES), sequences.day_frame(22, RES),
                               rtol=1e-5)
    up = [sequences.sun_at(sequences.minutes_hour(i))[0] for i in (0, sequences.MINUTES_FRAMES - 1)]
    assert 45.0 < up[0] < up[1] < 55.0          # well up all the way, climbing
    with pytest.raises(IndexError):
        sequences.minutes_frame(sequences.MINUTES_FRAMES, RES)


def test_minutes_frames_change_little_and_their_brightest_texel_follows_the_sun():
    """The smooth sequence: Σ Y·Ω changes by well under 1% a frame (the sun climbs 0.2° a minute),
    and the brightest texel of frame t is the one the sun's direction falls in."""
    frames = [sequences.minutes_frame(i, 16) for i in range(sequences.MINUTES_FRAMES)]
    powers = np.array([sequences.total_power(f) for f in frames])
    assert np.all(np.abs(np.diff(powers)) / powers[:-1] < 0.002)
    for index in (0, 12, sequences.MINUTES_FRAMES - 1):
        luminance = cubemap.luminance(frames[index].astype(np.float64))
        sun = sky.sun_direction(*sequences.sun_at(sequences.minutes_hour(index)))
        texel = tuple(int(v[0]) for v in cubemap.direction_to_texel(sun[None], 16))
        assert np.unravel_index(luminance.argmax(), luminance.shape) == texel
