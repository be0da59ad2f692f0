"""Visibility (issue 22): the masks' layout, Embree's masks against analytic geometry, the cache,
the masked exact reference against its independent NumPy twin, the unbiased estimators' z-test
on the ground-plane scene, and what a run records.

The stress battery's ``occlusion`` case (harness/verify/stress_cases.py) holds every estimator
to an enclosed pixel (exactly 0), one open cell, random cells, the ground plane alone (the white
furnace) and a traced sphere on the ground; the mutation catalogue's four visibility bugs show
that it can fail."""
import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from iblbench.estimators import registry
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.harness.protocol.visibility_error import visibility_error
from iblbench.harness.verify.conformance import bias_test, sidak_z
from iblbench.harness.verify.fixtures import face_pattern_map, glossy_gbuffer, smooth_map
from iblbench.harness.verify.twins.reference_twin import twin_image
from iblbench.scenes import cubemap, meshes, visibility
from iblbench.scenes.gbuffer import trace_gbuffer
from iblbench.scenes.registry import load_scene
from iblbench.scenes.scene import Camera, Material


def test_bits_are_packed_little_endian_in_cell_order():
    """Bit b of a mask is bit b % 32 of word b // 32, and unpacking inverts packing."""
    vis_res = 4
    cells = 6 * vis_res * vis_res
    for b in (0, 31, 32, 95):
        bits = np.arange(cells) == b
        words = visibility.pack_bits(bits)
        expected = np.zeros(visibility.words(vis_res), np.uint64)
        expected[b // 32] = 1 << (b % 32)
        assert np.array_equal(words, expected)
    rng = np.random.default_rng(1)
    bits = rng.random((3, 5, cells)) < 0.5
    assert np.array_equal(visibility.unpack_bits(visibility.pack_bits(bits), vis_res), bits)


def test_the_kernels_cell_of_a_direction_is_its_texel_at_the_visibility_resolution(compute):
    """common.cl's visibility_cell (through havran's light_cells) against NumPy's
    direction_to_texel at Rv: the centre of every cell maps to itself, and random directions to
    (face, ⌊t·Rv⌋, ⌊s·Rv⌋)."""
    vis_res = 8
    centres = cubemap.texel_directions(vis_res).reshape(-1, 3)
    rng = np.random.default_rng(3)
    random = rng.standard_normal((4096, 3))
    directions = np.concatenate([centres, random / np.linalg.norm(random, axis=1, keepdims=True)])
    light_dir = np.zeros((len(directions), 4), np.float32)
    light_dir[:, :3] = directions
    cells = compute.empty(4 * len(directions))
    kernel = compute.kernel("iblbench.estimators", "havran.cl", "light_cells",
                            {"VISIBILITY": 1, "VIS_RES": vis_res})
    compute.run(kernel, len(directions), compute.to_device(light_dir), cells)
    got = compute.to_host(cells, (len(directions),), np.int32)
    face, row, col = cubemap.direction_to_texel(light_dir[:, :3].astype(np.float64), vis_res)
    assert np.array_equal(got[:len(centres)], np.arange(6 * vis_res * vis_res))
    assert np.array_equal(got, (face * vis_res + row) * vis_res + col)


def _sphere_hit(origins: np.ndarray, dirs: np.ndarray, centre, radius: float) -> np.ndarray:
    """Whether each ray (unit direction) meets the sphere ahead of its origin."""
    oc = origins - np.asarray(centre)
    b = np.einsum("ij,ij->i", oc, dirs)
    c = np.einsum("ij,ij->i", oc, oc) - radius * radius
    disc = b * b - c
    return (disc > 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 0)


def test_embree_masks_match_an_analytic_sphere_over_a_plane():
    """Pixels on the ground beside a unit sphere resting on it: every traced cell's bit is the
    answer of the ray through its centre against the exact sphere (an independent ray test), up
    to the tessellation's silhouette (at most 1% of the cells)."""
    mesh = meshes.on_ground(meshes.sphere(5))
    camera = Camera(eye=(0.0, 2.0, 4.2), target=(0.0, -0.6, 0.0))
    size, vis_res = 16, 8
    gbuffer = trace_gbuffer(mesh, Material(), camera, size, size)
    masks, stats = visibility.trace_visibility(mesh, camera, gbuffer.normal, size, size, vis_res)
    assert stats.rays > 0 and stats.rays_per_second > 0
    ground = gbuffer.mask & (gbuffer.position[..., 1] < -0.999)
    assert ground.sum() > 50
    origins, _ = visibility.offset_points(mesh, camera, size, size)
    covered = np.flatnonzero(gbuffer.mask)
    rays, corners = visibility.cell_rays(vis_res)
    compared = agree = 0
    for i in np.flatnonzero(ground.reshape(-1)[covered]):
        traced = corners[:, :, 1].max(axis=1) > 0          # cells above the plane (normal +Y)
        expected = ~_sphere_hit(np.repeat(origins[i][None], rays.shape[0], 0), rays, (0.0, 0.0, 0.0), 1.0)
        got = visibility.unpack_bits(masks.reshape(-1, masks.shape[-1])[covered[i]], vis_res)
        compared += traced.sum()
        agree += (got[traced] == expected[traced]).sum()
        assert not got[~traced].any()   # cells below the horizon hold 0
    assert agree / compared >= 0.99, (agree, compared)


def test_a_convex_mesh_alone_needs_no_visibility():
    assert not visibility.needs_visibility(meshes.sphere())
    assert visibility.needs_visibility(meshes.on_ground(meshes.sphere()))
    assert visibility.needs_visibility(meshes.torus())


def test_resolution_must_be_a_power_of_two_dividing_the_faces():
    visibility.check_resolution(16, 64)
    for vis_res, env_res in ((12, 48), (16, 24), (0, 8)):
        with pytest.raises(ValueError):
            visibility.check_resolution(vis_res, env_res)


def test_the_cache_serves_a_rerun_and_keys_the_resolution(tmp_path):
    scene = load_scene("sphere-ground")
    gbuffer = trace_gbuffer(scene.mesh, scene.material, scene.camera, 8, 8)
    first, _, hit = visibility.cached_visibility(scene.mesh, scene.camera, gbuffer.normal, 4, tmp_path)
    again, stats, hit_again = visibility.cached_visibility(scene.mesh, scene.camera, gbuffer.normal, 4, tmp_path)
    assert (hit, hit_again) == (False, True) and np.array_equal(first, again) and stats.rays > 0
    _, _, other = visibility.cached_visibility(scene.mesh, scene.camera, gbuffer.normal, 8, tmp_path)
    assert not other


@pytest.mark.parametrize("vis_res", [1, 2, 4])
def test_masked_reference_matches_its_numpy_twin(compute, vis_res):
    """The kernel's Σ_t V_cell(t)·L_t·∫_t ρ cos⁺ against the twin's, on random masks (half the
    cells open), every shininess of the glossy fixture, within the reference's 1e-4."""
    gb = glossy_gbuffer(3)
    cells = 6 * vis_res * vis_res
    open_cells = np.random.default_rng(vis_res).random(gb.shape + (cells,)) < 0.5
    gb = dataclasses.replace(gb, visibility=visibility.pack_bits(open_cells), visibility_res=vis_res)
    env = face_pattern_map(8)
    got = Reference(compute, use_cache=False).image(DeviceGBuffer(compute, gb), FrameCache(compute, env))
    twin = twin_image(gb, env)
    scale = np.abs(twin).max()
    assert np.abs(got - twin).max() <= 1e-4 * scale
    unmasked = twin_image(dataclasses.replace(gb, visibility=None), env)
    assert np.abs(unmasked - twin).max() > 0.05 * scale   # the masks matter here


def test_every_shut_cell_gives_an_exact_zero_reference(compute):
    gb = glossy_gbuffer(3)
    gb = dataclasses.replace(gb, visibility=np.zeros(gb.shape + (visibility.words(2),), np.uint32),
                             visibility_res=2)
    got = Reference(compute, use_cache=False).image(DeviceGBuffer(compute, gb),
                                                   FrameCache(compute, face_pattern_map(8)))
    assert not got.any()


@pytest.mark.slow
@pytest.mark.parametrize("lighting", ["smooth", "sun-sky"])
def test_unbiased_estimators_pass_the_z_test_on_the_ground_plane_scene(compute, lighting):
    """sphere-ground at 10 × 10 pixels, 16² faces and Rv = 16: the mean over 300 seeds of 8 spp
    of every unbiased built-in against the masked exact reference, α = 1e-3 with Šidák
    correction.  Under a smooth map: every pixel and channel, and the image mean per channel.
    Under the scene's own sun and sky: the image mean per channel only, since light-blind
    strategies (brdf) reach the one-texel sun of a 16² face in a few pixels over all seeds, where
    a per-pixel standard error over seeds says nothing."""
    scene = load_scene("sphere-ground", env_res=16)
    gb = trace_gbuffer(scene.mesh, scene.material, scene.camera, 10, 10)
    masks, _ = visibility.trace_visibility(scene.mesh, scene.camera, gb.normal, 10, 10, 16)
    gb = dataclasses.replace(gb, visibility=masks, visibility_res=16)
    gbuffer = DeviceGBuffer(compute, gb)
    env = smooth_map(16) if lighting == "smooth" else scene.environment.frame(0)
    cache = FrameCache(compute, env)
    reference = Reference(compute, use_cache=False).image(gbuffer, cache)[gb.mask]
    failures = []
    for name in registry.builtin_names():
        cls = registry.get_estimator_class(name)
        if not cls.tags.unbiased:
            continue
        estimator = cls()
        cache.require(cls.requires)
        samples = np.stack([estimator.render(gbuffer, cache, 8, seed).radiance[gb.mask]
                            for seed in range(300)])
        test = bias_test(samples, reference)
        pixel_z = np.abs(test.pixel_z).max() if lighting == "smooth" else 0.0
        if np.abs(test.pooled_z).max() >= sidak_z(3) or pixel_z >= sidak_z(test.pixel_z.size):
            failures.append(f"{name}: pooled z {np.round(test.pooled_z, 2)}, max pixel |z| {pixel_z:.2f}")
    assert not failures, failures


def _visibility_rows(scene, seed):
    gb = trace_gbuffer(scene.mesh, scene.material, scene.camera, 96, 96)
    return {row["visibility_res"]: row for row in visibility_error(scene, gb, scene.environment.frame(0), seed=seed)}


def _check_against_shadow_rays(rows):
    """The masked reference at the default Rv = 32 within 0.15% of real shadow rays over the
    image (issue 34's bound; the earlier default, four rays a cell at Rv = 16 with 2-2 ties lit,
    was +0.5%), every pixel's difference under 2% of the image's mean at the 90th percentile, the difference
    shrinking from Rv = 16 to 32 to 64 (beyond the coarser one's interval), and the unmasked
    reference more than 5% off."""
    assert sorted(rows) == [0, 16, 32, 64]
    assert abs(rows[32]["relative_difference"]) + rows[32]["interval"] <= 0.0015
    assert rows[32]["pixel_difference_p90"] <= 0.02
    for coarse, fine in ((16, 32), (32, 64)):
        assert abs(rows[fine]["relative_difference"]) <= abs(rows[coarse]["relative_difference"]) + rows[coarse]["interval"]
    assert rows[0]["relative_difference"] >= 0.05


def test_masked_reference_agrees_with_real_shadow_rays():
    """sphere-ground at 96 × 96 (every covered pixel), as _check_against_shadow_rays says."""
    _check_against_shadow_rays(_visibility_rows(load_scene("sphere-ground"), seed=0))


def test_the_visibility_figure_moves_within_its_interval_between_pixel_draws():
    """park-ground at 96 × 96 (7,854 covered pixels, 4,096 strata): five draws of pixels and
    samples, each holding _check_against_shadow_rays (measured: +0.06% to +0.10% at Rv = 32), and
    each draw's figure within its own stated 95% interval of the five draws' mean (which the
    earlier 48-pixel figure, whose error left out the pixel sampling, missed 5-20×)."""
    scene = load_scene("park-ground")
    draws = [_visibility_rows(scene, seed) for seed in range(5)]
    assert draws[0][32]["pixels"] < draws[0][32]["covered"] and draws[0][32]["pixel_sampling_error"] > 0
    for draw in draws:
        _check_against_shadow_rays(draw)
    for vis_res in (0, 16, 32, 64):
        figures = np.array([draw[vis_res]["relative_difference"] for draw in draws])
        intervals = np.array([draw[vis_res]["interval"] for draw in draws])
        assert np.all(np.abs(figures - figures.mean()) <= intervals), (vis_res, figures, intervals)


def test_the_whole_image_has_no_pixel_sampling_error():
    gb = glossy_gbuffer(3)
    from iblbench.harness.protocol.visibility_error import pixel_sampling_error, sample_pixels
    assert np.array_equal(sample_pixels(gb, count=gb.covered), gb.mask)
    rng = np.random.default_rng(2)
    y = rng.random(gb.covered) + 1.0
    assert pixel_sampling_error(rng.standard_normal(gb.covered), y, gb.covered) == 0.0
    assert pixel_sampling_error(rng.standard_normal(gb.covered), y, 4 * gb.covered) > 0.0


def _run(tmp_path, *args):
    return subprocess.run([sys.executable, "-m", "iblbench.cli", "run", "--no-progress", *args],
                          capture_output=True, text=True, cwd=tmp_path)


def test_a_run_records_visibility_and_shadow_rays(tmp_path):
    """sphere-ground: the manifest keeps the trace's rays and Embree rate, every row counts its
    shadow rays; sphere-sun has none."""
    out = tmp_path / "out"
    args = ("--scene", "sphere-ground", "--scene", "sphere-sun", "--estimator", "envmap", "--estimator", "bis",
            "--estimator", "smc", "--spp", "4", "--seeds", "1", "--res", "12x12", "--repeats", "1",
            "--out", str(out))
    result = _run(tmp_path, *args)
    assert result.returncode == 0, result.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    (record,) = manifest["visibility"]
    assert record["scene"] == "sphere-ground" and record["visibility_res"] == 32
    assert record["rays"] > 0 and record["embree_rays_per_s"] > 0
    error = {row["visibility_res"]: row for row in record["geometric_error"]}
    assert sorted(error) == [0, 16, 32, 64]
    # Recorded: the masks against real shadow rays (held to their tolerance by the next test; at
    # 12 × 12 pixels a pixel near the sun's shadow edge weighs a lot), and no visibility at all,
    # far off (the ground's shadow, the sphere's lower half).
    assert all(abs(row["relative_difference"]) <= 0.03 for row in error.values() if row["visibility_res"])
    assert error[0]["relative_difference"] >= 0.05
    import pandas as pd
    table = pd.read_parquet(out / "results.parquet").set_index(["scene", "estimator"])
    assert table.loc[("sphere-ground", "envmap"), "shadow_rays"] == 4
    assert table.loc[("sphere-ground", "bis"), "shadow_rays"] == 4          # N, not M + N
    assert table.loc[("sphere-ground", "bis"), "evaluations"] > 4
    assert table.loc[("sphere-ground", "smc"), "shadow_rays"] == 80       # its init's M = 20 N candidates
    assert (table.loc["sphere-sun", "shadow_rays"] == 0).all()
    # The report: the visibility table in the manifest section, and error against time plus
    # shadow rays for sphere-ground only, at the measured rate or the one asked for.
    from iblbench.reports.report import write_report
    context = write_report(out, ray_cost_ns=250.0)
    html = context["path"].read_text()
    assert "<h3>Visibility</h3>" in html and "Error against time and shadow rays" in html
    def time_figures(context):   # one device: one part of each scene holds its time figures
        assert all(len(s["devices"]) == 1 for s in context["scenes"])
        return {s["name"]: s["devices"][0]["figures"] for s in context["scenes"]}

    figures = time_figures(context)
    assert figures["sphere-ground"]["ns_per_ray"] == 250.0 and "ray_cost" not in figures["sphere-sun"]
    assert (out / "report" / figures["sphere-ground"]["ray_cost"]).is_file()
    default = time_figures(write_report(out))
    assert default["sphere-ground"]["ns_per_ray"] == pytest.approx(1e9 / record["embree_rays_per_s"])
    # A rerun resumes every cell and traces nothing: the record is carried over.
    assert _run(tmp_path, *args).returncode == 0
    assert json.loads((out / "manifest.json").read_text())["visibility"] == [record]


def test_ray_cost_adds_each_cells_shadow_rays_to_its_time_and_interval():
    import pandas as pd
    from iblbench.reports.tables import with_ray_cost
    cells = pd.DataFrame({"shadow_rays": [10.0, 0.0], "time_ms": [2.0, 3.0], "time_ms_low": [1.5, 2.5],
                          "time_ms_high": [2.5, 3.5]})
    charged = with_ray_cost(cells, ns_per_ray=1000.0, pixels=100)    # 10 × 100 × 1 µs = 1 ms
    assert charged.time_ms.tolist() == [3.0, 3.0]
    assert charged.time_ms_low.tolist() == [2.5, 2.5] and charged.time_ms_high.tolist() == [3.5, 3.5]


def _user_scene(tmp_path, mesh, render: str) -> str:
    mesh.export(tmp_path / "mesh.obj")
    np.save(tmp_path / "env.npy", np.ones((6, 8, 8, 3), np.float32))
    path = tmp_path / "scene.toml"
    path.write_text('[mesh]\npath = "mesh.obj"\n[environment]\npath = "env.npy"\n'
                    '[camera]\neye = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\n[render]\n' + render)
    return str(path)


def test_a_convex_mesh_with_visibility_on_skips_the_trace(tmp_path):
    scene = _user_scene(tmp_path, trimesh.creation.icosphere(2),
                        "width = 8\nheight = 8\nvisibility = true\nvisibility_res = 4\n")
    out = tmp_path / "out"
    result = _run(tmp_path, "--scene", scene, "--estimator", "uniform", "--spp", "2", "--seeds", "1",
                  "--repeats", "1", "--out", str(out))
    assert result.returncode == 0, result.stderr
    (record,) = json.loads((out / "manifest.json").read_text())["visibility"]
    assert "convex" in record["skipped"] and "rays" not in record


def test_a_bad_visibility_resolution_is_a_one_line_error_naming_the_scene(tmp_path):
    scene = _user_scene(tmp_path, trimesh.creation.icosphere(2), "visibility = true\nvisibility_res = 3\n")
    result = _run(tmp_path, "--scene", scene, "--estimator", "uniform", "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert "scene.toml" in result.stderr and "power of two" in result.stderr
    assert not (tmp_path / "out").exists()


def test_the_report_shows_a_visibility_record_of_a_run_before_issue_34():
    """A manifest written before issue 34 has no ``covered``, ``interval`` or noise floor in its
    visibility rows: the report's table shows what it has and dashes, not a KeyError."""
    from iblbench.reports.tables import _visibility_table
    old = {"visibility_res": 16, "pixels": 48, "samples": 65536, "relative_difference": 0.0026,
           "pixel_difference_p90": 0.011, "relative_standard_error": 0.0007}
    manifest = {"visibility": [{"scene": "park-ground", "visibility_res": 16, "cached": False,
                                "trace_seconds": 1.0, "embree_rays_per_s": 1e6, "geometric_error": [old]}]}
    html = str(_visibility_table(manifest))
    assert "48 × 65536" in html and "–" in html
