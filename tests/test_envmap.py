"""Environment loading: lat-long resampling, crosses, face files, validation.

The expected values come from the written specification, not from the loader: the lat-long
formula of the module docstring, a cross built by folding paper onto the cube, analytic
integrals over the sphere.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from iblbench.scenes import cubemap
from iblbench.scenes.envmap import BLACK_LEVEL, default_latlong_res, load_environment, resample_latlong
from iblbench.foundation.errors import InputError
from iblbench.scenes.imageio import write_exr, write_hdr

FACE_FILES = ("px", "nx", "py", "ny", "pz", "nz")


def smooth_radiance(d: np.ndarray) -> np.ndarray:
    """A smooth, asymmetric RGB function of direction with known sphere integrals."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    # R = 1 + 0.5 cos θ + 0.3 sin θ cos φ in the lat-long angles (sin θ cos φ = −z).
    return np.stack([1 + 0.5 * y - 0.3 * z, 1 + 0.8 * y * y, np.exp(2 * x)], axis=-1)


# ∫ dω = 4π, ∫ y² dω = 4π/3, ∫ e^{2x} dω = 4π sinh(2)/2; odd terms vanish.
SMOOTH_INTEGRAL = 4 * np.pi * np.array([1.0, 1 + 0.8 / 3, np.sinh(2.0) / 2])


def latlong_directions(height: int) -> np.ndarray:
    """Pixel-centre directions of a [H, 2H] lat-long image, from the documented formula."""
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(2 * height) + 0.5) / (2 * height)
    theta, phi = np.pi * v[:, None], 2 * np.pi * (u[None, :] - 0.5)
    return np.stack(
        np.broadcast_arrays(np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)),
        axis=-1,
    )


def latlong_pixel_integral(image: np.ndarray) -> np.ndarray:
    height, width = image.shape[:2]
    theta = np.linspace(0, np.pi, height + 1)
    pixel_omega = (2 * np.pi / width) * (np.cos(theta[:-1]) - np.cos(theta[1:]))
    return np.einsum("hwc,h->c", image.astype(np.float64), pixel_omega)


def cross_directions(layout: str, size: int) -> np.ndarray:
    """Direction of every pixel centre of a cross, from the image-to-direction mapping of the
    vertical cross in Reinhard, Ward, Pattanaik and Debevec, *High Dynamic Range Imaging* (2005),
    §9.4.4 (HDRShop's layout; the horizontal cross hangs +Z right of +X instead).

    (a, b) are paper coordinates in face half-widths, a to the right and b down, with the front
    (-Z) cell at [-1, 1]² in cell (1, 1); pixels outside the cross are NaN.
    """
    rows, columns = (4, 3) if layout == "vcross" else (3, 4)
    b = 2 * (np.arange(rows * size) + 0.5) / size - 3
    a = 2 * (np.arange(columns * size) + 0.5) / size - 3
    a, b = np.meshgrid(a, b)
    one = np.ones_like(a)
    middle_column, middle_row = np.abs(a) < 1, np.abs(b) < 1
    pieces = [
        (middle_column & middle_row, (a, -b, -one)),  # -Z, forward
        (middle_column & (b < -1), (a, one, -(b + 2))),  # +Y, above the front
        (middle_column & (b > 1) & (b < 3), (a, -one, b - 2)),  # -Y, below the front
        (middle_column & (b > 3), (a, b - 4, one)),  # +Z, upside down below -Y (vertical cross)
        (middle_row & (a > 1) & (a < 3), (one, -b, a - 2)),  # +X, right of the front
        (middle_row & (a < -1), (-one, -b, -(a + 2))),  # -X, left of the front
        (middle_row & (a > 3), (4 - a, -b, one)),  # +Z, right of +X (horizontal cross)
    ]
    points = np.full(a.shape + (3,), np.nan)
    for inside, point in pieces:
        points[inside] = np.stack(point, axis=-1)[inside]
    return points / np.linalg.norm(points, axis=-1, keepdims=True)


def angle(d0: np.ndarray, d1: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(np.sum(d0 * d1, axis=-1), -1, 1))


# --- lat-long -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def smooth_latlong(tmp_path_factory):
    image = smooth_radiance(latlong_directions(64)).astype(np.float32)
    path = tmp_path_factory.mktemp("latlong") / "sky.exr"
    write_exr(path, image)
    return path, image


def test_latlong_is_energy_preserving_on_a_smooth_map(smooth_latlong):
    path, image = smooth_latlong
    env, report = load_environment(path)
    assert (report.layout, report.resolution, report.source_size) == ("latlong", 32, (128, 64))
    assert env.dtype == np.float32 and env.shape == (6, 32, 32, 3)
    cube_integral = cubemap.integrate(env)
    np.testing.assert_allclose(cube_integral, latlong_pixel_integral(image), rtol=0.01)
    np.testing.assert_allclose(cube_integral, SMOOTH_INTEGRAL, rtol=0.01)


def test_latlong_texels_match_the_function_at_texel_centres(smooth_latlong):
    env, _ = load_environment(smooth_latlong[0], res=16)
    expected = smooth_radiance(cubemap.texel_directions(16))
    np.testing.assert_allclose(env, expected, rtol=0.03)


@pytest.mark.parametrize(
    "row, column, direction",
    [
        (16, 32, (0, 0, -1)),  # image centre looks toward -Z
        (16, 48, (1, 0, 0)),  # u = 0.75 toward +X
        (16, 16, (-1, 0, 0)),  # u = 0.25 toward -X
        (16, 0, (0, 0, 1)),  # u = 0 toward +Z
        (0, 7, (0, 1, 0)),  # top row is up
        (31, 50, (0, -1, 0)),  # bottom row is down
    ],
)
def test_latlong_orientation(row, column, direction):
    image = np.zeros((32, 64, 3), np.float32)
    image[row, column] = 1000.0
    env = resample_latlong(image, 8)
    brightest = np.unravel_index(np.argmax(env[..., 0]), env.shape[:3])
    texel_direction = cubemap.texel_directions(8)[brightest]
    assert angle(texel_direction, np.array(direction, float)) < np.radians(25)


def test_constant_latlong_stays_exactly_constant():
    env = resample_latlong(np.full((20, 40, 3), 2.5, np.float32), 7)
    np.testing.assert_allclose(env, 2.5, rtol=1e-6)


def test_default_and_explicit_resolution(tmp_path):
    assert [default_latlong_res(h) for h in (1, 64, 100, 512, 4096)] == [1, 32, 64, 256, 512]
    write_exr(tmp_path / "a.exr", np.ones((16, 32, 3)))
    env, report = load_environment(tmp_path / "a.exr", res=5)
    assert env.shape == (6, 5, 5, 3) and report.resolution == 5


# --- crosses and face files ---------------------------------------------------------------

@pytest.mark.parametrize("layout", ["vcross", "hcross"])
def test_cross_extraction_matches_the_folded_cube(tmp_path, layout):
    size = 8
    cross = np.nan_to_num(smooth_radiance(cross_directions(layout, size))).astype(np.float32)
    write_exr(tmp_path / "cross.exr", cross)
    for requested in ("auto", layout):
        env, report = load_environment(tmp_path / "cross.exr", layout=requested)
        assert (report.layout, report.resolution) == (layout, size)
        np.testing.assert_allclose(env, smooth_radiance(cubemap.texel_directions(size)), rtol=1e-6)


@pytest.mark.parametrize(
    "layout, rows, columns, step",
    [
        ("vcross", 23, range(8, 16), (1, 0)),  # -Y above the rotated +Z
        ("hcross", range(8, 16), 23, (0, 1)),  # +X left of +Z
        ("hcross", 7, range(8, 16), (1, 0)),  # +Y above -Z
    ],
)
def test_cross_is_continuous_across_folds(layout, rows, columns, step):
    """Stepping over a fold turns the direction no more than stepping inside a face."""
    directions = cross_directions(layout, 8)
    rows, columns = np.broadcast_arrays(np.array(rows), np.array(columns))
    edge = directions[rows, columns]
    across = angle(edge, directions[rows + step[0], columns + step[1]])
    inside = angle(edge, directions[rows - step[0], columns - step[1]])
    assert np.all(across < 1.5 * inside.max())


def test_cross_is_resampled_energy_exactly_when_halved(tmp_path):
    rng = np.random.default_rng(7)
    cross = rng.random((16, 12, 3)).astype(np.float32)
    write_exr(tmp_path / "c.exr", cross)
    full, _ = load_environment(tmp_path / "c.exr", layout="vcross")
    half, report = load_environment(tmp_path / "c.exr", layout="vcross", res=2)
    assert report.resolution == 2
    np.testing.assert_allclose(cubemap.integrate(half), cubemap.integrate(full), rtol=1e-5)


def nearest_latlong(image: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The lat-long pixel nearest to each direction, from the documented formula (NaN -> 0)."""
    height, width = image.shape[:2]
    d = np.nan_to_num(d)
    u = (np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi) + 0.5) % 1.0
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    row = np.minimum((v * height).astype(int), height - 1)
    column = np.minimum((u * width).astype(int), width - 1)
    return np.where(np.linalg.norm(d, axis=-1, keepdims=True) > 0, image[row, column], 0.0)


def test_one_panorama_gives_one_cube_map_in_every_layout(tmp_path):
    """Issue 11, defect 11: a lat-long, the HDRShop crosses and six face files cut from it light
    the scene alike (a cross read mirrored in z differs by up to 0.6 in red: -0.3 z)."""
    size = 16
    latlong = smooth_radiance(latlong_directions(256)).astype(np.float32)
    write_exr(tmp_path / "pano.exr", latlong)
    for layout in ("vcross", "hcross"):
        write_exr(tmp_path / f"{layout}.exr", nearest_latlong(latlong, cross_directions(layout, size)))
    faces = nearest_latlong(latlong, cubemap.texel_directions(size))
    _write_faces(tmp_path, faces)
    sources = {"latlong": tmp_path / "pano.exr", "vcross": tmp_path / "vcross.exr",
               "hcross": tmp_path / "hcross.exr", "faces": str(tmp_path / "env_{face}.exr")}
    expected = smooth_radiance(cubemap.texel_directions(size))
    for layout, source in sources.items():
        env, report = load_environment(source, res=size)
        assert report.layout == layout
        # Nearest lat-long pixels (0.7° apart) against the exact function: within 3%.
        np.testing.assert_allclose(env, expected, rtol=0.03, err_msg=layout)


@pytest.mark.parametrize("layout, crop", [("vcross", (slice(None), slice(40, 88))),
                                          ("hcross", (slice(10, 46), slice(16, 64)))])
def test_auto_refuses_a_latlong_crop_with_a_cross_aspect(tmp_path, smooth_latlong, layout, crop):
    """Issue 11, defect 7: a 3:4 (or 4:3) crop of a lat-long is not read as a cross."""
    write_exr(tmp_path / "crop.exr", smooth_latlong[1][crop])
    with pytest.raises(InputError, match=f"unused cells are not black.*layout = \"{layout}\"") as err:
        load_environment(tmp_path / "crop.exr")
    assert err.value.source == str(tmp_path / "crop.exr")
    env, report = load_environment(tmp_path / "crop.exr", layout=layout)
    assert report.layout == layout


def test_a_latlong_crop_stops_a_run_with_exit_2_on_one_line(tmp_path, smooth_latlong):
    """Issue 11, defect 7, through the command line: nothing is run or written."""
    write_exr(tmp_path / "crop.exr", smooth_latlong[1][:, 40:88])   # 48 x 64: a 3:4 crop
    trimesh.creation.icosphere(1).export(tmp_path / "ball.obj")
    (tmp_path / "scene.toml").write_text('[mesh]\npath = "ball.obj"\n[environment]\npath = "crop.exr"\n'
                                         "[camera]\neye = [0, 0, 3]\ntarget = [0, 0, 0]\n")
    result = subprocess.run([sys.executable, "-m", "iblbench.cli", "run", "--scene",
                             str(tmp_path / "scene.toml"), "--estimator", "uniform", "--spp", "1",
                             "--seeds", "1", "--out", str(tmp_path / "out"), "--no-progress"],
                            capture_output=True, text=True, timeout=120,
                            env=dict(os.environ, IBLBENCH_CACHE=str(tmp_path / "cache")))
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith(f"iblbench: error: {tmp_path / 'crop.exr'}: ")
    assert result.stderr.count("\n") == 1 and 'layout = "vcross"' in result.stderr
    assert not (tmp_path / "out" / "results.parquet").exists()


@pytest.mark.parametrize("fraction_of_the_limit, accepted", [(0.5, True), (2.0, False)])
def test_black_level_of_the_unused_cross_cells(tmp_path, fraction_of_the_limit, accepted):
    size = 4
    inside = np.isfinite(cross_directions("vcross", size)[..., 0])
    cross = np.where(inside[..., None], np.full(3, 2.0), 0.0).astype(np.float32)
    cross[0, 0] = fraction_of_the_limit * BLACK_LEVEL * 2.0   # one texel of one unused cell
    write_exr(tmp_path / "cross.exr", cross)
    if accepted:
        assert load_environment(tmp_path / "cross.exr")[1].layout == "vcross"
    else:
        with pytest.raises(InputError, match="not black"):
            load_environment(tmp_path / "cross.exr")


def _write_faces(tmp_path, faces, ext="exr"):
    for name, face in zip(FACE_FILES, faces):
        (write_exr if ext == "exr" else write_hdr)(tmp_path / f"env_{name}.{ext}", face)
    return [tmp_path / f"env_{name}.{ext}" for name in FACE_FILES]


def test_six_face_files_by_list_and_by_pattern(tmp_path):
    faces = np.random.default_rng(8).random((6, 4, 4, 3)).astype(np.float32)
    paths = _write_faces(tmp_path, faces)
    for source in (paths, str(tmp_path / "env_{face}.exr")):
        env, report = load_environment(source)
        assert report.layout == "faces" and report.paths == tuple(map(str, paths))
        np.testing.assert_array_equal(env, faces)


def test_face_files_in_hdr(tmp_path):
    faces = np.random.default_rng(9).random((6, 8, 8, 3)).astype(np.float32)
    env, _ = load_environment(_write_faces(tmp_path, faces, "hdr"), layout="faces")
    np.testing.assert_allclose(env, faces, atol=1 / 256)


# --- bad input ------------------------------------------------------------------------------

def test_non_square_and_mismatched_faces(tmp_path):
    faces = [np.ones((4, 4, 3))] * 6
    paths = _write_faces(tmp_path, faces)
    write_exr(paths[3], np.ones((4, 5, 3)))
    with pytest.raises(InputError, match="not square") as err:
        load_environment(paths)
    assert err.value.source == str(paths[3])
    write_exr(paths[3], np.ones((5, 5, 3)))
    with pytest.raises(InputError, match="face is 5x5 but") as err:
        load_environment(paths)
    assert err.value.source == str(paths[3])


def test_aspect_ratio_matching_no_layout(tmp_path):
    write_exr(tmp_path / "odd.exr", np.ones((30, 100, 3)))
    with pytest.raises(InputError, match="aspect ratio 100x30 matches no cube-map layout") as err:
        load_environment(tmp_path / "odd.exr")
    assert err.value.source == str(tmp_path / "odd.exr")


@pytest.mark.parametrize("shape, layout", [((16, 12, 3), "latlong"), ((8, 16, 3), "hcross"), ((9, 12, 3), "vcross")])
def test_explicit_layout_with_the_wrong_aspect(tmp_path, shape, layout):
    write_exr(tmp_path / "a.exr", np.ones(shape))
    with pytest.raises(InputError, match=f"layout '{layout}' needs aspect"):
        load_environment(tmp_path / "a.exr", layout=layout)


def test_layout_and_source_mismatches(tmp_path):
    write_exr(tmp_path / "a.exr", np.ones((8, 16, 3)))
    with pytest.raises(InputError, match="needs six face files"):
        load_environment(tmp_path / "a.exr", layout="faces")
    with pytest.raises(InputError, match="got 2"):
        load_environment([tmp_path / "a.exr"] * 2)
    with pytest.raises(InputError, match="takes one image"):
        load_environment([tmp_path / "a.exr"] * 6, layout="latlong")
    with pytest.raises(InputError, match="unknown layout 'cubic'"):
        load_environment(tmp_path / "a.exr", layout="cubic")
    for res in (0, 4097):
        with pytest.raises(InputError, match=r"an integer in 1\.\.4096"):
            load_environment(tmp_path / "a.exr", res=res)


@pytest.mark.parametrize("name, content", [("gone.exr", None), ("bad.exr", b"x" * 500), ("bad.hdr", b"#?RADIANCE\n")])
def test_missing_and_corrupt_files(tmp_path, name, content):
    if content is not None:
        (tmp_path / name).write_bytes(content)
    with pytest.raises(InputError) as err:
        load_environment(tmp_path / name)
    assert err.value.source == str(tmp_path / name)


def test_truncated_hdr(tmp_path):
    write_hdr(tmp_path / "a.hdr", np.random.default_rng(10).random((16, 32, 3)))
    data = (tmp_path / "a.hdr").read_bytes()
    (tmp_path / "a.hdr").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated"):
        load_environment(tmp_path / "a.hdr")


def _faces_with_bad_texels():
    faces = np.ones((6, 4, 4, 3), np.float32)
    faces[0, 0, 0] = [np.nan, 1, 1]
    faces[0, 0, 1] = [np.nan, -1, np.inf]  # counted once, as NaN
    faces[1, 1, 1, 2] = np.inf
    faces[2, 2, 2, 0] = -np.inf
    faces[3, 3, 3] = [7, 1, 1]  # the largest finite value
    faces[4, 0, 0, 1] = -0.5
    faces[5, 1, 2] = -2.0
    faces[5, 3, 0, 2] = 3e38  # overflows float32 sums on the device (found by test_fuzz.py)
    return faces


def test_bad_texels_are_refused_with_counts(tmp_path):
    # Face files keep the texels where they are; one lat-long file checks the count itself.
    image = _faces_with_bad_texels().transpose(1, 0, 2, 3).reshape(4, 24, 3)[:, :8]
    write_exr(tmp_path / "a.exr", image)
    with pytest.raises(InputError, match=r"2 NaN, 1 Inf and 0 negative texels; pass --sanitize"):
        load_environment(tmp_path / "a.exr")
    paths = _write_faces(tmp_path, _faces_with_bad_texels())
    with pytest.raises(InputError, match=r"2 NaN, 0 Inf and 0 negative.*--sanitize") as err:
        load_environment(paths)
    assert err.value.source == str(paths[0])
    with pytest.raises(InputError, match=r"0 NaN, 0 Inf, 1 above 1e\+20 and 1 negative texels"):
        load_environment(paths[5:] * 6)


def test_sanitize_fixes_and_counts_bad_texels(tmp_path):
    faces = _faces_with_bad_texels()
    env, report = load_environment(_write_faces(tmp_path, faces), sanitize=True)
    assert report.texels_fixed == 7
    assert np.all(np.isfinite(env)) and env.min() >= 0
    np.testing.assert_array_equal(env[0, 0, 0], [0, 1, 1])
    np.testing.assert_array_equal(env[0, 0, 1], [0, 0, 7])  # NaN and -1 to 0, +Inf to the max
    np.testing.assert_array_equal(env[1, 1, 1], [1, 1, 7])
    np.testing.assert_array_equal(env[2, 2, 2], [0, 1, 1])
    np.testing.assert_array_equal(env[5, 1, 2], [0, 0, 0])
    np.testing.assert_array_equal(env[5, 3, 0], [1, 1, 7])   # 3e38 to the max
    good = np.isfinite(faces).all(-1) & (faces >= 0).all(-1) & (faces <= 1e20).all(-1)
    np.testing.assert_array_equal(env[good], faces[good])
