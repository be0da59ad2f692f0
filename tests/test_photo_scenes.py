"""The built-in scenes lit by the shipped CC0 photographs (sphere-park, sphere-studio, park-turn)
and the ``turntable`` sequence (scenes/sequences.py).  The turntable's exactness is checked on a
map made here; the shipped scenes are loaded as any user would load them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from iblbench.scenes import cubemap, registry, sequences, sky
from iblbench.scenes.imageio import write_exr


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
