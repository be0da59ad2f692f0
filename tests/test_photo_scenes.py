"""The built-in scenes lit by the shipped CC0 photographs (sphere-park, sphere-studio, park-turn)
and the ``turntable`` sequence (scenes/sequences.py).  The turntable's exactness is checked on a
map made here; the shipped scenes are loaded as any user would load them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from iblbench.scenes import cubemap, registry, sequences, sky
from iblbench.scenes.imageio import read_image, write_exr


def sky_azimuth_deg(direction) -> float:
    """Sky azimuth as :mod:`iblbench.scenes.sky` measures it: 0° → +Z, 90° → +X."""
    return math.degrees(math.atan2(direction[0], direction[2]))


def brightest_direction(env: np.ndarray) -> np.ndarray:
    luminance = cubemap.luminance(env)
    return cubemap.texel_directions(env.shape[1])[np.unravel_index(luminance.argmax(), luminance.shape)]


def test_the_photographs_and_their_terms_are_package_data():
    for name in (registry.PARK_MAP, registry.STUDIO_MAP):
        path = registry.shipped_map(name)
        assert open(path, "rb").read(2) == b"#?"          # Radiance RGBE
    terms = open(registry.shipped_map("README.md"), encoding="utf-8").read()
    assert "CC0" in terms and "polyhaven.com/a/rooitou_park" in terms
    assert "polyhaven.com/a/studio_small_03" in terms and "pmndrs/drei-assets" in terms


@pytest.mark.parametrize("name", ["sphere-park", "sphere-studio", "park-turn"])
def test_the_brightest_light_stands_where_sphere_suns_sun_does(name):
    """The camera is placed from the map as loaded: its brightest texel lies 60° to the right of
    the view in azimuth (sky.DEFAULT_SUN_AZIMUTH_DEG, sphere-sun's sun), within 1.5 texels."""
    scene = registry.load_scene(name, env_res=32)
    light = brightest_direction(scene.environment.frame(0))
    eye = np.array(scene.camera.eye)
    offset = (sky_azimuth_deg(light) - sky_azimuth_deg(eye) + 180.0) % 360.0 - 180.0
    assert offset == pytest.approx(sky.DEFAULT_SUN_AZIMUTH_DEG, abs=1.5 * 90.0 / 32)
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, scene.camera.up)
    assert light @ right > 0.5                      # on the right of the picture
    assert light[1] > 0.1                           # above the horizon (10° and 43° up)


def test_a_turntable_frame_is_the_map_turned_by_its_step(tmp_path):
    """A lat-long map that varies smoothly in azimuth φ (Debevec's convention, envmap.py): frame t
    must read f(φ − t·Δ) at every texel, Δ = 360°·TURNTABLE_STEP_COLUMNS / width; a turn in the
    other sense or by another angle moves every texel by a whole step (≥ 10% here)."""
    height, width = 64, 128
    phi = 2.0 * np.pi * ((np.arange(width) + 0.5) / width - 0.5)

    def pattern(angle):
        return 1.0 + 0.5 * np.cos(angle) + 0.25 * np.sin(2.0 * angle)

    image = np.repeat(pattern(phi)[None, :, None], height, axis=0).repeat(3, axis=2)
    path = tmp_path / "stripes.exr"
    write_exr(path, image.astype(np.float32))
    sequence = sequences.turntable(str(path), res=16)
    assert sequence.num_frames == sequences.TURNTABLE_FRAMES and not sequence.is_static
    x, y, z = np.moveaxis(cubemap.texel_directions(16), -1, 0)
    texel_phi = np.arctan2(x, -z)                    # direction = (sin θ sin φ, cos θ, −sin θ cos φ)
    # Near the poles a texel spans many φ and its box filter averages the pattern away.
    away_from_poles = np.abs(y) < 0.8
    step = 2.0 * np.pi * sequences.TURNTABLE_STEP_COLUMNS / width
    for t in (0, 1, sequences.TURNTABLE_FRAMES - 1):
        frame = sequence.frame(t)
        assert not frame.flags.writeable and sequence.frame(t) is frame     # made once
        # Tolerance: away from the poles, the box filter over a texel and the bilinear lookup
        # blur the pattern by well under 2% at 16² faces (its harmonics are 1 and 2 per turn).
        np.testing.assert_allclose(frame[..., 1][away_from_poles],
                                   pattern(texel_phi - t * step)[away_from_poles], rtol=0.02)
    with pytest.raises(IndexError):
        sequence.frame(sequences.TURNTABLE_FRAMES)


def test_park_turn_runs_every_frame_with_the_temporal_estimators(tmp_path):
    """park-turn end to end at a tiny size: every frame scored, smc's state kept across frames,
    nothing non-finite, and its error bounded like the frame-by-frame uniform estimator's."""
    from iblbench.harness.protocol.runner import RunConfig, run

    table = run(RunConfig(out=tmp_path, scenes=("park-turn",), estimators=("uniform", "smc"),
                          spp=(8,), seeds=1, resolution=(12, 12), env_res=8,
                          frames=slice(0, 3), progress=False))
    assert sorted(table.frame.unique()) == [0, 1, 2]
    assert (table.nonfinite == 0).all() and table.rel_mse.notna().all()
    smc = table[table.estimator == "smc"].set_index("frame")
    # An init, then each frame carried or re-initialised where the sun moved (smc.py step 5).
    assert np.isnan(smc.ess[0]) and (smc.ess[1:].notna() | (smc.reinits[1:] > 0)).all()


# ---- photographed lights: separation, moving and switching (issue 24) ----------------------------

from iblbench.scenes import photo_lights   # noqa: E402


def test_harmonic_fill_reproduces_a_harmonic_image():
    """An image linear in the row is discretely harmonic (4·f − its four neighbours = 0 away from
    the poles), so filling any hole must give it back exactly; a hole next to the wrap seam
    checks the azimuth wrap."""
    height, width = 24, 48
    rows = np.arange(height, dtype=np.float64)[:, None, None]
    image = np.broadcast_to(1.0 + 0.25 * rows * np.array([1.0, 2.0, 3.0]), (height, width, 3))
    mask = np.zeros((height, width), bool)
    mask[5:12, 20:31] = True
    mask[8:14, :3] = mask[8:14, -2:] = True
    broken = image.copy()
    broken[mask] = 100.0
    np.testing.assert_allclose(photo_lights.harmonic_fill(broken, mask), image, atol=1e-9)


def synthetic_light(tmp_path, elevation_deg=20.0, azimuth_deg=50.0):
    """A lat-long map: a background of 0.5 and a 3°-radius disc of luminance 400 (grey)."""
    height, width = 128, 256
    rows, cols = np.mgrid[0:height, 0:width] + 0.5
    directions = photo_lights.latlong_directions(rows, cols, height, width)
    centre = sky.sun_direction(elevation_deg, azimuth_deg)
    disc = directions @ centre >= math.cos(math.radians(3.0))
    image = np.where(disc[..., None], 400.0, 0.5) * np.ones(3)
    path = tmp_path / "light.exr"
    write_exr(path, image.astype(np.float32))
    return str(path), disc, centre


def degrees_between(a, b) -> float:
    return math.degrees(math.acos(np.clip(a @ b, -1.0, 1.0)))


def power_weighted_direction(cube: np.ndarray) -> np.ndarray:
    res = cube.shape[1]
    weight = cubemap.luminance(cube) * cubemap.texel_solid_angles(res)
    mean = np.einsum("frc,frcx->x", weight, cubemap.texel_directions(res))
    return mean / np.linalg.norm(mean)


def test_a_separated_light_keeps_its_power_and_turns_by_its_azimuth(tmp_path):
    """The disc's power (400 − 0.5 per pixel times its solid angle, summed independently here) is
    the light layer's; splatted into cubes of two sizes at three azimuths, Σ Y·Ω stays it to 1e-9,
    the splat points' power-weighted direction turns by the azimuth about +Y (sky azimuth grows,
    elevation stays) and the cube's (from texel centres) lies within a third of a texel of it."""
    path, disc, centre = synthetic_light(tmp_path)
    light = photo_lights.separate(path, threshold=100.0, cap_deg=10.0)
    assert (light.mask == disc).all()
    height, width = disc.shape
    theta = np.pi * np.arange(height + 1) / height
    pixel_omega = 2 * np.pi / width * (np.cos(theta[:-1]) - np.cos(theta[1:]))
    expected = float(((400.0 - 0.5) * pixel_omega[:, None] * disc).sum())
    assert light.power == pytest.approx(expected, rel=1e-9)
    assert np.allclose(light.remainder, 0.5)          # the background is constant, so is its fill
    start = cubemap.luminance(light.point_power) @ light.points
    start /= np.linalg.norm(start)
    assert degrees_between(start, centre) < 0.5      # the disc's pixels are 1.4° across
    for res in (16, 32):
        for azimuth in (0.0, 30.0, -75.0):
            cube = photo_lights.light_cube(light, res, azimuth)
            assert sequences.total_power(cube) == pytest.approx(expected, rel=1e-9)
            mean = cubemap.luminance(light.point_power) @ photo_lights.turned(light.points, azimuth)
            mean /= np.linalg.norm(mean)
            assert sky_azimuth_deg(mean) == pytest.approx(sky_azimuth_deg(start) + azimuth, abs=1e-9)
            assert mean[1] == pytest.approx(start[1], abs=1e-12)
            assert degrees_between(power_weighted_direction(cube), mean) < 90.0 / res / 3


@pytest.fixture(scope="module")
def studio_moving():
    return registry.load_scene("sphere-studio-moving", env_res=16).environment


def test_sphere_studio_moving_moves_only_its_light(studio_moving):
    """Every frame: finite, non-negative, Σ Y·Ω the same to 1e-6 (the light is moved, not
    resampled); the light's power-weighted direction (over texel centres) is within a third of a
    texel of the light's own turned LIGHT_MOVING_STEP_DEG a frame about +Y; texels the light never
    reaches are bit-identical in every frame (the remainder)."""
    path = registry.shipped_map(registry.STUDIO_MAP)
    remainder = sequences.remainder_cube(path, registry.STUDIO_LIGHT_THRESHOLD, 16)
    frames = [studio_moving.frame(i) for i in range(studio_moving.num_frames)]
    assert len(frames) == sequences.LIGHT_MOVING_FRAMES == 16
    powers = np.array([sequences.total_power(f) for f in frames])
    assert all(np.isfinite(f).all() and f.min() >= 0.0 for f in frames)
    assert np.ptp(powers) <= 1e-6 * powers.mean()
    light = sequences.separated_light(path, registry.STUDIO_LIGHT_THRESHOLD)
    assert powers[0] == pytest.approx(sequences.total_power(remainder) + light.power, rel=1e-6)
    start = cubemap.luminance(light.point_power) @ light.points
    for index, frame in enumerate(frames):
        turned = sky.sun_direction(math.degrees(math.asin(start[1] / np.linalg.norm(start))),
                                   sky_azimuth_deg(start) + index * sequences.LIGHT_MOVING_STEP_DEG)
        assert degrees_between(power_weighted_direction(frame - remainder), turned) < 90.0 / 16 / 3
    untouched = ~np.any([(f - remainder.astype(np.float32) > 0).any(-1) for f in frames], axis=0)
    assert untouched.mean() > 0.8
    for frame in frames[1:]:
        assert np.array_equal(frame[untouched], frames[0][untouched])


def test_sphere_park_switch_switches_the_sun_off_and_on():
    """On frames hold the park's sun, off frames none of its texels: no texel reaches the
    threshold (the fill never exceeds its boundary); Σ Y·Ω is the photograph's (its lat-long
    pixels' Σ Y·Ω, summed here) when on, less the light's when off; on frames are one array object, off frames another, so the runner
    reuses their FrameCache."""
    sequence = registry.load_scene("sphere-park-switch", env_res=16).environment
    frames = [sequence.frame(i) for i in range(sequence.num_frames)]
    on = [sequences.light_switch_is_on(i) for i in range(len(frames))]
    assert on == [True] * 4 + [False] * 4 + [True] * 4
    assert frames[0] is frames[3] is frames[8] is frames[11] and frames[4] is frames[7]
    assert frames[3] is not frames[4]
    peak = [cubemap.luminance(f.astype(np.float64)).max() for f in frames]
    assert peak[4] < registry.PARK_SUN_THRESHOLD < peak[0]
    image = read_image(registry.shipped_map(registry.PARK_MAP)).astype(np.float64)
    theta = np.pi * np.arange(image.shape[0] + 1) / image.shape[0]
    pixel_omega = 2 * np.pi / image.shape[1] * (np.cos(theta[:-1]) - np.cos(theta[1:]))
    photograph = float((cubemap.luminance(image) * pixel_omega[:, None]).sum())
    assert sequences.total_power(frames[0]) == pytest.approx(photograph, rel=1e-3)
    light = sequences.separated_light(registry.shipped_map(registry.PARK_MAP),
                                      registry.PARK_SUN_THRESHOLD)
    assert (sequences.total_power(frames[0]) - sequences.total_power(frames[4])
            == pytest.approx(light.power, rel=1e-6))
    assert light.power / sequences.total_power(frames[0]) == pytest.approx(0.67, abs=0.01)


@pytest.mark.parametrize("name, frames", [("sphere-park-switch", slice(3, 6)),
                                          ("sphere-studio-moving", slice(0, 3))])
def test_photographed_sequences_run_with_the_exact_reference(tmp_path, name, frames):
    """End to end at a tiny size across a switch (frames 3→4: the sun goes off) and a move:
    every frame scored against the exact reference, nothing non-finite."""
    from iblbench.harness.protocol.runner import RunConfig, run

    table = run(RunConfig(out=tmp_path, scenes=(name,), estimators=("uniform", "smc"),
                          spp=(8,), seeds=1, resolution=(12, 12), env_res=8,
                          frames=frames, progress=False))
    assert sorted(table.frame.unique()) == list(range(frames.start, frames.stop))
    assert (table.nonfinite == 0).all() and table.rel_mse.notna().all()
    assert table.mean_delta_e76.between(0, 100).all()
