"""Warnings about a badly framed camera (issue 11, item 14): too few mesh pixels, or the camera
inside the mesh.  Expected counts come from the geometry, not from the code under test."""
from __future__ import annotations

import math

import numpy as np
import pytest

from iblbench.harness.protocol.runner import RunConfig, Runner
from iblbench.scenes import framing, gbuffer, meshes
from iblbench.scenes.scene import Camera, EnvSequence, Material, Scene


def sphere_scene(eye, size=32, fov_y=45.0, target=(0.0, 0.0, 0.0)) -> tuple[Scene, gbuffer.GBuffer]:
    camera = Camera(eye=eye, target=target, up=(0.0, 1.0, 0.0), fov_y=fov_y)
    scene = Scene("ball", meshes.sphere(3), Material(), camera,
                  EnvSequence.static(np.ones((6, 2, 2, 3), np.float32)), (size, size))
    return scene, gbuffer.trace_gbuffer(scene.mesh, scene.material, camera, size, size)


def test_a_well_framed_camera_gets_no_warning():
    scene, buffer = sphere_scene((0.0, 0.0, 3.0))
    assert buffer.covered > framing.MIN_MESH_PIXELS
    assert framing.framing_warnings(scene, buffer) == []


def test_a_camera_that_sees_a_few_pixels_is_warned_about():
    # The unit sphere from 20 away subtends 2·asin(1/20) = 5.7°: with a 45° fov over 32 pixels
    # (1.4° a pixel) it covers about π(5.7/2/1.4)² ≈ 13 pixels, below the limit.
    scene, buffer = sphere_scene((0.0, 0.0, 20.0))
    expected = math.pi * (math.degrees(math.asin(1 / 20)) / (45.0 / 32)) ** 2
    assert 0.5 * expected < buffer.covered < 2 * expected < framing.MIN_MESH_PIXELS
    warnings = framing.framing_warnings(scene, buffer)
    assert len(warnings) == 1 and "\n" not in warnings[0]
    assert f"sees only {buffer.covered} of 1024 pixels" in warnings[0]


def test_a_camera_inside_the_mesh_is_warned_about():
    scene, buffer = sphere_scene((0.0, 0.0, 0.5), target=(0.0, 0.0, -1.0))
    assert buffer.covered == 32 * 32   # every ray hits the sphere from inside
    assert framing.back_face_fraction(scene.mesh, scene.camera, 32, 32) == 1.0
    warnings = framing.framing_warnings(scene, buffer)
    assert len(warnings) == 1 and "seems to be inside the mesh (100% of the rays" in warnings[0]


def test_a_camera_inside_the_bounding_box_but_outside_the_mesh_is_not_warned_about():
    # At (0.9, 0.9, 0.9) the eye is inside the sphere's box but 1.56 from its centre.
    scene, buffer = sphere_scene((0.9, 0.9, 0.9))
    assert buffer.covered > framing.MIN_MESH_PIXELS
    assert framing.back_face_fraction(scene.mesh, scene.camera, 32, 32) == 0.0
    assert framing.framing_warnings(scene, buffer) == []


@pytest.mark.parametrize("eye, needle", [((0.0, 0.0, 20.0), "sees only"), ((0.0, 0.0, 0.5), "inside the mesh")])
def test_the_runner_prints_the_warning_on_one_line(tmp_path, capsys, eye, needle):
    """The runner's scene preparation warns on stderr and carries on."""
    folder = tmp_path / "scene"
    folder.mkdir()
    np.save(folder / "env.npy", np.full((6, 4, 4, 3), 0.5, np.float32))
    meshes.sphere(3).export(folder / "ball.obj")
    (folder / "scene.toml").write_text(
        '[mesh]\npath = "ball.obj"\n[environment]\npath = "env.npy"\n'
        f"[camera]\neye = {list(eye)}\ntarget = [0.0, 0.0, -1.0]\n")
    runner = Runner(RunConfig(out=tmp_path / "out", scenes=(str(folder / "scene.toml"),),
                              estimators=("uniform",), spp=(1,), seeds=1, resolution=(32, 32),
                              progress=False))
    runner._trace(runner.plans[0])
    lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(lines) == 1 and lines[0].startswith("iblbench: warning: scene scene: ") and needle in lines[0]
