"""Scenes: Preetham sun + sky, procedural meshes, the Embree G-buffer and the scene registry."""
from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
import trimesh

from iblbench.scenes import cubemap, gbuffer, meshes, registry, sky
from iblbench.foundation.errors import InputError
from iblbench.scenes.scene import Camera, Material

# --- G-buffer ----------------------------------------------------------------------------------


def sphere_gbuffer(width=128, height=128, distance=3.0, fov_y=45.0):
    camera = Camera(eye=(0.0, 0.0, distance), fov_y=fov_y)
    return gbuffer.trace_gbuffer(meshes.sphere(), Material(), camera, width, height), camera


@pytest.mark.parametrize("width, height", [(128, 128), (160, 120)])
def test_sphere_mask_covers_the_projected_disc(width, height):
    distance, fov_y = 3.0, 45.0
    buffer, _ = sphere_gbuffer(width, height, distance, fov_y)
    # The silhouette is a cone of half-angle asin(r/D); on the image plane at distance 1 it is a
    # disc of radius tan(asin(r/D)), inside a (2 tan(fov/2)·aspect) × (2 tan(fov/2)) rectangle.
    disc_radius = math.tan(math.asin(1.0 / distance))
    half_height = math.tan(math.radians(fov_y) / 2)
    expected = math.pi * disc_radius**2 / (4 * half_height**2 * width / height)
    assert buffer.mask.shape == (height, width)
    assert buffer.mask.mean() == pytest.approx(expected, rel=0.03)


def test_sphere_normals_positions_and_views():
    buffer, camera = sphere_gbuffer()
    covered = buffer.mask
    position, normal, view = (getattr(buffer, k)[covered].astype(np.float64) for k in ("position", "normal", "view"))
    radius = np.linalg.norm(position, axis=1)
    assert radius.max() <= 1.0 + 1e-5 and radius.min() > 0.99  # inscribed icosphere, 5120 faces
    assert np.degrees(np.arccos(np.clip(np.sum(normal * position / radius[:, None], 1), -1, 1))).max() < 0.5
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-5)
    assert np.allclose(np.linalg.norm(view, axis=1), 1.0, atol=1e-5)
    to_eye = np.asarray(camera.eye) - position
    assert np.allclose(view, to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True), atol=1e-5)
    assert np.all(np.sum(normal * view, axis=1) > 0)
    assert not buffer.normal[~covered].any() and not buffer.kd[~covered].any()
    assert np.allclose(buffer.kd[covered], 0.5) and np.allclose(buffer.shininess[covered], 150.0)
    assert all(a.dtype == np.float32 for name, a in buffer.arrays().items() if name != "mask")


def test_sphere_is_symmetric_about_the_image_centre():
    buffer, _ = sphere_gbuffer()
    assert np.array_equal(buffer.mask, buffer.mask[::-1, ::-1])
    top = np.argwhere(buffer.mask)[0]  # the first covered row is at the top of the image: +Y up
    assert buffer.position[tuple(top)][1] > 0.9


def single_triangle(vertex_normals):
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    return trimesh.Trimesh(vertices, [[0, 1, 2]], vertex_normals=vertex_normals, process=False)


def test_embree_barycentrics_weight_vertex_normals_as_1_minus_u_minus_v_u_v():
    n = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], float)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    hit = np.array([0.2, 0.3, 0.0])  # barycentrics (0.5, 0.2, 0.3) of (v0, v1, v2)
    camera = Camera(eye=tuple(hit + [0, 0, 5]), target=tuple(hit), up=(0, 1, 0), fov_y=10.0)
    buffer = gbuffer.trace_gbuffer(single_triangle(n), Material(), camera, 1, 1)
    expected = 0.5 * n[0] + 0.2 * n[1] + 0.3 * n[2]
    assert buffer.mask[0, 0]
    assert np.allclose(buffer.position[0, 0], hit, atol=1e-6)
    assert np.allclose(buffer.normal[0, 0], expected / np.linalg.norm(expected), atol=1e-5)


@pytest.mark.parametrize("eye_z, normal_sign", [(5.0, 1.0), (-5.0, -1.0)])
def test_two_sided_normals_face_the_camera(eye_z, normal_sign):
    inverted = np.tile([0.0, 0.0, -1.0], (3, 1))  # vertex normals against the winding
    camera = Camera(eye=(0.2, 0.3, eye_z), target=(0.2, 0.3, 0.0), up=(0, 1, 0), fov_y=10.0)
    buffer = gbuffer.trace_gbuffer(single_triangle(inverted), Material(), camera, 1, 1)
    assert np.allclose(buffer.normal[0, 0], [0, 0, normal_sign], atol=1e-6)


def test_gbuffer_npz_round_trip_leaves_no_temporary(tmp_path):
    buffer, _ = sphere_gbuffer(32, 24)
    path = tmp_path / "gbuffer.npz"
    buffer.save_npz(path)
    assert [p.name for p in tmp_path.iterdir()] == ["gbuffer.npz"]
    loaded = gbuffer.GBuffer.load_npz(path)
    for name, array in buffer.arrays().items():
        assert np.array_equal(getattr(loaded, name), array), name


# --- sky ---------------------------------------------------------------------------------------


def assert_same_gbuffer(a, b):
    for name in gbuffer.GBUFFER_ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_cached_trace_hits_on_the_same_inputs_and_misses_on_any_changed_one(tmp_path):
    mesh, material, camera = meshes.sphere(2), Material(), Camera()
    traced = gbuffer.trace_gbuffer(mesh, material, camera, 24, 16)
    first, hit = gbuffer.cached_trace(mesh, material, camera, 24, 16, tmp_path)
    assert not hit and len(list(tmp_path.glob("*.npz"))) == 1
    assert_same_gbuffer(first, traced)
    again, hit = gbuffer.cached_trace(meshes.sphere(2), Material(), Camera(), 24, 16, tmp_path)
    assert hit
    assert_same_gbuffer(again, traced)
    moved = meshes.sphere(2)
    moved.vertices[0] += 0.01
    bent = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False,
                           vertex_normals=mesh.vertex_normals + [0.0, 0.3, 0.0])
    changes = [(moved, material, camera, 24, 16), (bent, material, camera, 24, 16),
               (meshes.sphere(2, radius=0.9), material, camera, 24, 16),
               (mesh, Material(kd=(0.4, 0.5, 0.5)), camera, 24, 16),
               (mesh, Material(shininess=20.0), camera, 24, 16),
               (mesh, material, Camera(eye=(0.0, 0.1, 3.0)), 24, 16),
               (mesh, material, Camera(fov_y=40.0), 24, 16),
               (mesh, material, camera, 16, 24), (mesh, material, camera, 24, 24)]
    for inputs in changes:
        changed, hit = gbuffer.cached_trace(*inputs, tmp_path)
        assert not hit, inputs[1:]
        assert_same_gbuffer(changed, gbuffer.trace_gbuffer(*inputs))
    assert len(list(tmp_path.glob("*.npz"))) == 1 + len(changes)
    assert not list(tmp_path.glob(".*"))   # atomic writes leave no temporary behind


def test_a_damaged_cached_gbuffer_is_traced_again_and_replaced(tmp_path):
    mesh, material, camera = meshes.sphere(2), Material(), Camera()
    gbuffer.cached_trace(mesh, material, camera, 24, 16, tmp_path)
    path, = tmp_path.glob("*.npz")
    path.write_bytes(path.read_bytes()[:100])
    repaired, hit = gbuffer.cached_trace(mesh, material, camera, 24, 16, tmp_path)
    assert not hit
    assert_same_gbuffer(repaired, gbuffer.trace_gbuffer(mesh, material, camera, 24, 16))
    assert gbuffer.cached_trace(mesh, material, camera, 24, 16, tmp_path)[1]


def test_preetham_zenith_luminance_by_hand():
    # T = 2, θ_s = 60° = π/3:  χ = (4/9 − 2/120)(π − 2π/3) = 0.427778 · 1.047198 = 0.447968,
    # tan χ = 0.480551;  Y_z = (4.0453·2 − 4.9710)·0.480551 − 0.2155·2 + 2.4192
    #                        = 3.1196 · 0.480551 + 1.9882 = 1.499127 + 1.9882 = 3.487327 kcd/m².
    assert sky.zenith_luminance(2.0, math.pi / 3) == pytest.approx(3.487327, abs=1e-5)


def test_sky_at_zenith_has_the_zenith_luminance():
    sun = sky.sun_direction(35.0, 60.0)
    zenith_rgb = sky.sky_radiance(np.array([0.0, 1.0, 0.0]), sun, turbidity=3.0)
    assert cubemap.luminance(zenith_rgb) == pytest.approx(sky.zenith_luminance(3.0, math.radians(55.0)), rel=1e-3)
    assert zenith_rgb[2] > zenith_rgb[0]  # a clear sky is blue


def test_sun_direction_is_y_up():
    assert np.allclose(sky.sun_direction(90.0, 123.0), [0, 1, 0])
    assert np.allclose(sky.sun_direction(0.0, 0.0), [0, 0, 1])
    assert np.allclose(sky.sun_direction(0.0, 90.0), [1, 0, 0])


def test_sun_sky_shape_values_and_sun_position():
    env = sky.sun_sky(res=32)
    assert env.shape == (6, 32, 32, 3) and env.dtype == np.float32
    assert np.all(np.isfinite(env)) and env.min() >= 0
    face, row, col = np.unravel_index(np.argmax(cubemap.luminance(env)), env.shape[:3])
    brightest = cubemap.texel_directions(32)[face, row, col]
    sun = sky.sun_direction(sky.DEFAULT_SUN_ELEVATION_DEG, sky.DEFAULT_SUN_AZIMUTH_DEG)
    assert np.degrees(np.arccos(brightest @ sun)) < 3.0  # within one texel at R = 32


def test_sun_peak_dominates_the_sky_median():
    luminance = cubemap.luminance(sky.sun_sky())
    assert luminance.max() >= 1e4 * np.median(luminance)


def sun_power(res):
    return cubemap.integrate(sky.sun_sky(res=res)) - cubemap.integrate(sky.sun_sky(res=res, sun_luminance=0.0))


def test_sun_power_is_independent_of_resolution():
    coarse, fine = sun_power(32), sun_power(128)
    assert np.allclose(coarse, fine, rtol=0.02)
    half_angle = math.radians(sky.SUN_ANGULAR_RADIUS_DEG)
    disc_solid_angle = 2 * math.pi * (1 - math.cos(half_angle))
    assert cubemap.luminance(fine) == pytest.approx(sky.SUN_LUMINANCE * disc_solid_angle, rel=0.02)
    assert np.allclose(cubemap.integrate(sky.sun_sky(res=32)), cubemap.integrate(sky.sun_sky(res=128)), rtol=0.02)


# --- meshes ------------------------------------------------------------------------------------


def test_sphere_mesh_normals_are_normalised_positions():
    mesh = meshes.sphere(subdivisions=2, radius=2.0)
    assert np.allclose(np.linalg.norm(mesh.vertices, axis=1), 2.0)
    assert np.allclose(mesh.vertex_normals, mesh.vertices / 2.0)


def test_load_mesh_merges_a_multi_object_file(tmp_path):
    path = tmp_path / "two.glb"
    trimesh.Scene([trimesh.creation.box(), trimesh.creation.icosphere(1).apply_translation([3, 0, 0])]).export(path)
    assert len(meshes.load_mesh(path).faces) == 12 + 80


@pytest.mark.parametrize(
    "name, content, problem",
    [
        ("missing.obj", None, "not found"),
        ("empty.obj", "# nothing\n", "no triangles"),
        ("corrupt.glb", b"\x00garbage", "cannot read"),
        ("mesh.xyz", "1 2 3\n", "unsupported"),
        # trimesh's processing drops the NaN vertex and its faces without a word.
        ("nan.obj", "v nan 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 3 4\n", "non-finite vertex"),
        ("flat.obj", "v 0.5\nv 1\nv 2\nf 1 2 3\n", "not 3D points and triangles"),
        ("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 3 0 1\n", "line 5: face vertex index 0"),
        ("huge.obj", "v 1e30 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n", "coordinates reach 1e\\+30; at most ±1e\\+09"),
    ],
)
def test_load_mesh_errors_name_the_file(tmp_path, name, content, problem):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(InputError, match=problem) as error:
        meshes.load_mesh(path)
    assert error.value.source == str(path)


def test_load_mesh_says_a_file_is_not_utf8_text(tmp_path):
    # trimesh reports a missing module (found by test_fuzz.py with OBJ bit flips).
    if importlib.util.find_spec("charset_normalizer"):
        pytest.skip("with charset_normalizer, trimesh guesses the encoding")
    path = tmp_path / "latin1.obj"
    path.write_bytes("# caf\xe9\nv 0 0 0\n".encode("latin-1"))
    with pytest.raises(InputError, match="cannot read mesh: not UTF-8 text"):
        meshes.load_mesh(path)


# --- registry ----------------------------------------------------------------------------------


def test_builtin_sphere_sun_scene_is_case_insensitive():
    scene = registry.load_scene("Sphere-Sun", env_res=16)
    assert scene.name == "sphere-sun" and scene.resolution == (128, 128)
    assert scene.material == Material(kd=(0.5,) * 3, ks=(0.3,) * 3, shininess=150.0)
    assert scene.environment.is_static and scene.environment.frame(0).shape == (6, 16, 16, 3)


EXPECTED_SCENES = ("blob-sun", "sphere-backlit", "sphere-sun", "torus-sun", "plane-grazing", "sphere-park",
                   "sphere-studio", "blob-day", "torus-moving", "sphere-switch", "park-turn",
                   "sphere-ground", "park-ground", "torus-day", "blob-minutes", "sphere-studio-moving",
                   "sphere-park-switch")
SEQUENCE_SCENES = ("blob-day", "torus-moving", "sphere-switch", "park-turn", "torus-day", "blob-minutes",
                   "sphere-studio-moving", "sphere-park-switch")
# park-turn, the default sweep's short sequence, and the photographed sequences (issue 24) are small
# by default (scenes/registry.py).
OWN_SIZE = {"park-turn": ((48, 48), 32), "park-ground": ((96, 96), 64),
            "sphere-studio-moving": ((48, 48), 32), "sphere-park-switch": ((48, 48), 32)}


def test_scene_names_lists_every_builtin_scene():
    assert registry.scene_names() == sorted(EXPECTED_SCENES)
    assert set(registry.BUILTIN_SCENES) == set(EXPECTED_SCENES)


@pytest.mark.parametrize("name", EXPECTED_SCENES)
def test_every_builtin_scene_loads_by_name(name):
    scene = registry.load_scene(name.upper(), env_res=8)
    resolution, env_res = OWN_SIZE.get(name, ((128, 128), registry.DEFAULT_ENV_RES))
    assert scene.name == name and scene.source == f"builtin:{name}" and scene.resolution == resolution
    assert scene.material == Material(kd=(0.5,) * 3, ks=(0.3,) * 3, shininess=150.0)
    # The *-sun, *-park and *-studio scenes are static; the others are lit by sequences
    # (tests/test_sequences.py, tests/test_photo_scenes.py).
    assert scene.environment.is_static == (name not in SEQUENCE_SCENES)
    assert scene.environment.frame(0).shape == (6, 8, 8, 3)
    assert registry.load_scene(name).environment.frame(0).shape == (6, env_res, env_res, 3)
    normals = np.asarray(scene.mesh.vertex_normals)
    assert normals.shape == scene.mesh.vertices.shape
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    assert np.all(np.isfinite(scene.mesh.vertices))


def scene_gbuffer(name, size=64):
    scene = registry.load_scene(name, env_res=32)
    return scene, gbuffer.trace_gbuffer(scene.mesh, scene.material, scene.camera, size, size)


def brightest_direction(env):
    luminance = cubemap.luminance(env)
    face, row, col = np.unravel_index(np.argmax(luminance), luminance.shape)
    return cubemap.texel_directions(env.shape[1])[face, row, col]


def test_blob_has_over_100k_triangles_and_smooth_normals_of_the_displaced_surface():
    mesh = registry.load_scene("blob-sun", env_res=8).mesh
    assert len(mesh.faces) > 100_000
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert radius.min() < 0.95 and radius.max() > 1.05  # really displaced, not a sphere
    assert radius.min() > 1 - meshes.BLOB_AMPLITUDE and radius.max() < 1 + meshes.BLOB_AMPLITUDE
    vertex_normals = np.asarray(mesh.vertex_normals)
    assert np.allclose(np.linalg.norm(vertex_normals, axis=1), 1.0, atol=1e-6)
    # Each corner's vertex normal agrees with the face's geometric normal (outward winding).
    cosines = np.einsum("fkj,fj->fk", vertex_normals[mesh.faces], mesh.face_normals)
    angles = np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))
    assert angles.mean() < 1.0 and angles.max() < 5.0
    # The normals are those of the displaced surface, not the sphere's radial directions.
    radial = mesh.vertices / radius[:, None]
    assert np.degrees(np.arccos(np.clip(np.sum(vertex_normals * radial, 1), -1, 1))).max() > 10.0
    # Both convex and concave regions: some adjacent face pairs fold inwards.
    assert 0.02 < 1.0 - mesh.face_adjacency_convex.mean() < 0.5


def test_blob_is_deterministic_and_callers_get_their_own_copy():
    first, second = meshes.blob(), meshes.blob()
    assert first is not second and np.array_equal(first.vertices, second.vertices)
    first.vertices[0] = [9.0, 9.0, 9.0]
    assert not np.array_equal(meshes.blob().vertices[0], [9.0, 9.0, 9.0])


def test_blob_gbuffer_fills_most_of_the_frame_without_being_cut():
    _, buffer = scene_gbuffer("blob-sun")
    mask = buffer.mask
    assert 0.4 < mask.mean() < 0.8
    assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
    assert np.allclose(np.linalg.norm(buffer.normal[mask], axis=1), 1.0, atol=1e-5)


def sun_facing_away_fraction(name):
    scene, buffer = scene_gbuffer(name)
    sun = brightest_direction(scene.environment.frame(0))
    return np.mean(buffer.normal[buffer.mask] @ sun <= 0.02), sun


def test_sphere_backlit_sun_is_low_behind_the_sphere_and_below_most_visible_normals():
    away, sun = sun_facing_away_fraction("sphere-backlit")
    expected = sky.sun_direction(registry.BACKLIT_SUN_ELEVATION_DEG, registry.BACKLIT_SUN_AZIMUTH_DEG)
    assert np.degrees(np.arccos(sun @ expected)) < 3.0
    assert 0.0 < sun[1] < 0.2 and sun[2] < -0.9  # low, on the far side from the camera at +Z
    assert away > 0.5
    sun_side_away, _ = sun_facing_away_fraction("sphere-sun")
    assert sun_side_away < 0.5  # the contrast: in sphere-sun most visible normals see the sun


def test_torus_is_in_frame_and_has_a_hole():
    scene, buffer = scene_gbuffer("torus-sun")
    mask = buffer.mask
    assert len(scene.mesh.faces) > 1000 and 0.2 < mask.mean() < 0.8
    assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
    assert not mask[32, 32]  # the camera looks at the centre of the hole


def test_unknown_scene_lists_the_valid_names():
    with pytest.raises(InputError, match=r"unknown scene 'nope'; valid scenes: .*sphere-sun"):
        registry.load_scene("nope")


SCENE_TOML = """
[mesh]
path = "ball.obj"

[environment]
path = "env.npy"

[material]
kd = [0.6, 0.5, 0.4]
ks = 0.2
shininess = 80

[camera]
eye = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
fov_y = 40

[render]
width = 48
height = 32
"""


@pytest.fixture
def scene_folder(tmp_path):
    trimesh.creation.icosphere(2).export(tmp_path / "ball.obj")
    np.save(tmp_path / "env.npy", np.full((6, 8, 8, 3), 0.5, np.float32))
    (tmp_path / "scene.toml").write_text(SCENE_TOML)
    return tmp_path


def test_toml_scene_round_trip(scene_folder):
    scene = registry.load_scene(scene_folder / "scene.toml")
    assert scene.name == "scene" and scene.resolution == (48, 32)
    assert scene.material == Material(kd=(0.6, 0.5, 0.4), ks=(0.2, 0.2, 0.2), shininess=80.0)
    assert scene.camera == Camera(eye=(0.0, 0.0, 4.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=40.0)
    assert len(scene.mesh.faces) == 320
    assert np.array_equal(scene.environment.frame(0), np.full((6, 8, 8, 3), 0.5, np.float32))
    buffer = gbuffer.trace_gbuffer(scene.mesh, scene.material, scene.camera, *scene.resolution)
    assert buffer.mask.shape == (32, 48) and buffer.covered > 0


def test_toml_scene_reads_an_hdr_environment_with_layout_and_res(scene_folder):
    from iblbench.scenes.imageio import write_hdr

    write_hdr(scene_folder / "sky.hdr", np.full((16, 32, 3), 2.0, np.float32))
    text = edit(SCENE_TOML, 'path = "env.npy"', 'path = "sky.hdr"\nlayout = "latlong"\nres = 4')
    (scene_folder / "scene.toml").write_text(text)
    scene = registry.load_scene(scene_folder / "scene.toml")
    assert np.allclose(scene.environment.frame(0), np.full((6, 4, 4, 3), 2.0))
    assert registry.load_scene(scene_folder / "scene.toml", env_res=2).environment.frame(0).shape == (6, 2, 2, 3)


def test_toml_glob_environment_is_a_sequence_in_name_order(scene_folder):
    for index in range(3):
        np.save(scene_folder / f"frame{index:02d}.npy", np.full((6, 4, 4, 3), index, np.float32))
    (scene_folder / "scene.toml").write_text(edit(SCENE_TOML, '"env.npy"', '"frame*.npy"'))
    sequence = registry.load_scene(scene_folder / "scene.toml").environment
    assert sequence.num_frames == 3 and not sequence.is_static
    assert [float(sequence.frame(i).max()) for i in range(3)] == [0.0, 1.0, 2.0]


def test_toml_glob_frames_must_match_in_size(scene_folder):
    np.save(scene_folder / "frame00.npy", np.zeros((6, 4, 4, 3), np.float32))
    np.save(scene_folder / "frame01.npy", np.zeros((6, 8, 8, 3), np.float32))
    (scene_folder / "scene.toml").write_text(edit(SCENE_TOML, '"env.npy"', '"frame*.npy"'))
    with pytest.raises(InputError, match="frame faces are 8² but .*frame00.npy has 4²") as error:
        registry.load_scene(scene_folder / "scene.toml")
    assert error.value.source.endswith("frame01.npy")
    assert registry.load_scene(scene_folder / "scene.toml", env_res=4).environment.num_frames == 2


def edit(text, old, new):
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize(
    "change, problem",
    [
        (lambda t: t + "[oops\n", "TOML syntax error"),
        (lambda t: edit(t, "[camera]", "[camera]\nfov = 3"), "unknown key 'fov' in \\[camera\\]"),
        (lambda t: edit(t, "[render]", "[lights]"), "unknown section \\[lights\\]"),
        (lambda t: edit(t, 'eye = [0.0, 0.0, 4.0]', ""), "missing required key 'eye' in \\[camera\\]"),
        (lambda t: edit(t, '[mesh]\npath = "ball.obj"', ""), "missing required section \\[mesh\\]"),
        (lambda t: edit(t, "eye = [0.0, 0.0, 4.0]", 'eye = "far"'), "camera.eye must be a list of 3"),
        (lambda t: edit(t, "width = 48", "width = 4.5"), "render.width must be a positive integer"),
        (lambda t: edit(t, "shininess = 80", "shininess = true"), "material.shininess must be a finite number"),
        (lambda t: edit(t, "ks = 0.2", "ks = 0.6"), "kd \\+ ks must be <= 1"),
        (lambda t: edit(t, "fov_y = 40", "fov_y = 180"), "fov_y must be in"),
        (lambda t: edit(t, "target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 4.0]"), "must differ"),
        (lambda t: edit(t, '"env.npy"', '"env.npy"\nlayout = "globe"'), "environment.layout must be one of"),
        (lambda t: edit(t, '"env.npy"', '"day*.npy"'), "matches no files"),
        # Sizes that exhaust memory or overflow float32 on the device (found by test_fuzz.py).
        (lambda t: edit(t, "width = 48", "width = 1000000000"), "render.width must be at most 16384"),
        (lambda t: edit(t, '"env.npy"', '"env.npy"\nres = 65536'), "environment.res must be at most 4096"),
        (lambda t: edit(t, "shininess = 80", "shininess = 1e308"), "material.shininess must be <= 1e\\+06"),
        (lambda t: edit(t, "eye = [0.0, 0.0, 4.0]", "eye = [0.0, 0.0, 1e300]"), "camera.eye must lie within ±1e\\+09"),
    ],
)
def test_toml_errors_name_the_scene_file(scene_folder, change, problem):
    path = scene_folder / "scene.toml"
    path.write_text(change(SCENE_TOML))
    with pytest.raises(InputError, match=problem) as error:
        registry.load_scene(path)
    assert error.value.source == str(path)


@pytest.mark.parametrize(
    "referenced, content, problem",
    [
        ("ball.obj", None, "mesh file not found"),
        ("ball.obj", "v 0 0 0\n", "no triangles"),
        ("env.npy", None, "file not found"),
        ("env.npy", np.zeros((6, 8, 8, 4), np.float32), r"shape \[6, R, R, 3\]"),
        ("env.npy", np.zeros((6, 8, 4, 3), np.float32), "not square"),
        ("env.npy", np.full((6, 8, 8, 3), np.nan, np.float32), "64 NaN, 0 Inf and 0 negative texels; pass --sanitize"),
    ],
)
def test_toml_errors_name_the_referenced_file(scene_folder, referenced, content, problem):
    target = scene_folder / referenced
    target.unlink()
    if isinstance(content, np.ndarray):
        np.save(target, content)
    elif content is not None:
        target.write_text(content)
    with pytest.raises(InputError, match=problem) as error:
        registry.load_scene(scene_folder / "scene.toml")
    assert error.value.source == str(target)


def test_sanitize_fixes_bad_npy_texels_and_counts_them(scene_folder):
    env = np.full((6, 8, 8, 3), 0.5, np.float32)
    env[0, 0, 0] = [np.nan, -1.0, np.inf]
    env[2, 3, 4] = [-2.0, 0.5, 0.5]
    np.save(scene_folder / "env.npy", env)
    sequence = registry.load_scene(scene_folder / "scene.toml", sanitize=True).environment
    frame = sequence.frame(0)
    # NaN and negatives become 0, +Inf the largest finite value (0.5); two texels were bad.
    assert frame[0, 0, 0].tolist() == [0.0, 0.0, 0.5] and frame[2, 3, 4].tolist() == [0.0, 0.5, 0.5]
    assert sequence.texels_fixed == 2


def test_missing_toml_file(tmp_path):
    with pytest.raises(InputError, match="scene file not found"):
        registry.load_scene(tmp_path / "absent.toml")


# --- [mesh] placement (issue 11, defect 12) -----------------------------------------------------

def _z_up_box(folder):
    """A 1 × 2 × 3 box standing on z = 0 (Z up: 3 tall), corner at the origin, as an OBJ."""
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    box.apply_translation((0.5, 1.0, 1.5))
    box.export(folder / "ball.obj")
    return box


def test_mesh_up_z_stands_a_z_up_mesh_up(scene_folder):
    box = _z_up_box(scene_folder)
    (scene_folder / "scene.toml").write_text(edit(SCENE_TOML, 'path = "ball.obj"', 'path = "ball.obj"\nup = "z"'))
    mesh = registry.load_scene(scene_folder / "scene.toml").mesh
    # Z up becomes Y up, Y (Blender's back) becomes -Z: x in [0, 1], y in [0, 3], z in [-2, 0].
    np.testing.assert_allclose(mesh.bounds, [[0.0, 0.0, -2.0], [1.0, 3.0, 0.0]], atol=1e-12)
    # The box's top face (normal +Z in the file) is now the face with normal +Y, at y = 3.
    top = np.isclose(np.asarray(box.vertices)[:, 2], 3.0)
    normals = np.asarray(mesh.vertex_normals)
    assert np.all(normals[top, 1] > 0.5) and np.all(normals[~top, 1] < 0.0)
    np.testing.assert_allclose(normals[:, [0, 2]] @ [[1, 0], [0, -1]], np.asarray(box.vertex_normals)[:, [0, 1]], atol=1e-12)
    buffer = gbuffer.trace_gbuffer(mesh, Material(), Camera(eye=(0.5, 10.0, -1.0), target=(0.5, 0.0, -1.0),
                                                           up=(0.0, 0.0, -1.0)), 8, 8)
    # Seen from straight above, every covered pixel is the top face at y = 3, its (smoothed
    # corner) normals leaning up.
    assert buffer.covered > 0
    np.testing.assert_allclose(buffer.position[buffer.mask][:, 1], 3.0, atol=1e-5)
    assert np.all(buffer.normal[buffer.mask][:, 1] > 0.5)


def test_mesh_scale_rotate_translate(scene_folder):
    box = _z_up_box(scene_folder)
    placement = 'path = "ball.obj"\nscale = 2\nrotate = [0, 90, 0]\ntranslate = [10, 0, 0]'
    (scene_folder / "scene.toml").write_text(edit(SCENE_TOML, 'path = "ball.obj"', placement))
    mesh = registry.load_scene(scene_folder / "scene.toml").mesh
    # Scaled to 2 × 4 × 6, then 90° about Y takes x to -z and z to x: x in [0, 6] + 10, z in [-2, 0].
    np.testing.assert_allclose(mesh.bounds, [[10.0, 0.0, -2.0], [16.0, 4.0, 0.0]], atol=1e-12)
    assert len(mesh.faces) == len(box.faces)


def test_mesh_non_uniform_scale_gives_ellipsoid_normals(scene_folder):
    trimesh.creation.icosphere(4).export(scene_folder / "ball.obj")
    (scene_folder / "scene.toml").write_text(edit(SCENE_TOML, 'path = "ball.obj"', 'path = "ball.obj"\nscale = [3, 1, 1]'))
    mesh = registry.load_scene(scene_folder / "scene.toml").mesh
    # The ellipsoid x²/9 + y² + z² = 1 has normal ∝ (x/9, y, z); the vertex normals (the sphere's,
    # carried by the inverse transpose) must match it to within the tessellation's 2°.
    v = np.asarray(mesh.vertices)
    analytic = v * [1 / 9, 1, 1]
    analytic /= np.linalg.norm(analytic, axis=1, keepdims=True)
    cosines = np.einsum("ij,ij->i", np.asarray(mesh.vertex_normals), analytic)
    assert np.degrees(np.arccos(np.clip(cosines, -1, 1))).max() < 2.0


@pytest.mark.parametrize(
    "placement, problem",
    [
        ('up = "x"', 'mesh.up must be "y" or "z", got \'x\''),
        ("up = 1", "mesh.up must be a non-empty string"),
        ("scale = 0", "mesh.scale must be positive"),
        ("scale = [1, -1, 1]", "mesh.scale must be positive"),
        ('scale = "big"', "mesh.scale must be a finite number"),
        ("rotate = [90, 0]", "mesh.rotate must be a list of 3 finite numbers"),
        ("translate = [0, 0, 1e300]", "mesh.translate must lie within ±1e\\+09"),
        ("scale = 1e300", "the placed mesh reaches 1e\\+300; coordinates must stay within ±1e\\+09"),
        ("turn = 3", "unknown key 'turn' in \\[mesh\\]"),
    ],
)
def test_mesh_placement_errors_name_the_scene_file(scene_folder, placement, problem):
    path = scene_folder / "scene.toml"
    path.write_text(edit(SCENE_TOML, 'path = "ball.obj"', f'path = "ball.obj"\n{placement}'))
    with pytest.raises(InputError, match=problem) as error:
        registry.load_scene(path)
    assert error.value.source == str(path) and "\n" not in str(error.value)
