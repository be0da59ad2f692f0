"""The exact reference (estimators/runtime/reference.cl) against closed forms and brute-force quadrature."""
import numpy as np
import pytest

from iblbench.harness.verify.conformance import face_pattern_map, fibonacci_directions
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import GBuffer


def _reference(compute, gbuffer, env):
    return Reference(compute, use_cache=False).image(DeviceGBuffer(compute, gbuffer),
                                                     FrameCache(compute, env))


def _one_texel_map(res, face, row, col, value=1.0):
    env = np.zeros((6, res, res, 3), np.float32)
    env[face, row, col] = value
    return env


def _corner_directions(res, face, row, col):
    """The texel's four corners on the unit sphere, in order around the quad."""
    s0, s1, t0, t1 = col / res, (col + 1) / res, row / res, (row + 1) / res
    st = [(s0, t0), (s1, t0), (s1, t1), (s0, t1)]
    return np.array([cubemap.face_st_to_direction(face, s, t) for s, t in st])


def lambert_polygon(normal, corners):
    """Lambert's formula: ∫_P cos dω = ½ Σ_i θ_i (n·γ_i) for a spherical polygon above the horizon."""
    total = 0.0
    for i in range(len(corners)):
        a, b = corners[i], corners[(i + 1) % len(corners)]
        theta = np.arccos(np.clip(np.dot(a, b), -1, 1))
        gamma = np.cross(a, b) / np.linalg.norm(np.cross(a, b))
        total += theta * np.dot(normal, gamma)
    return abs(0.5 * total)


def brute_force(res, face, row, col, integrand, sub=400):
    """∫_texel integrand(ω) dω by the midpoint rule on sub² cells with exact cell solid angles."""
    s = (col + (np.arange(sub) + 0.5) / sub) / res
    t = (row + (np.arange(sub) + 0.5) / sub) / res
    ss, tt = np.meshgrid(s, t)
    w = cubemap.face_st_to_direction(face, ss, tt)
    u, v = 2 * ss - 1, 2 * tt - 1
    cell = (2 / (res * sub)) ** 2 / (1 + u * u + v * v) ** 1.5
    return float(np.sum(integrand(w) * cell))


def test_white_furnace_is_exact(compute):
    normals = fibonacci_directions(400).reshape(20, 20, 3)
    env = np.full((6, 16, 16, 3), 0.7, np.float32)
    image = _reference(compute, GBuffer.from_pixels(normals, (0, 0, 1), 1.0, 0.0, 1.0), env)
    assert np.abs(image - 0.7).max() < 1e-4


def test_lambert_formula_matches_brute_force():
    # The closed form used below is itself checked against quadrature.
    res, face, row, col = 8, 4, 2, 5
    corners = _corner_directions(res, face, row, col)
    normal = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0])
    exact = lambert_polygon(normal, corners)
    assert brute_force(res, face, row, col, lambda w: w @ normal) == pytest.approx(exact, rel=1e-5)


@pytest.mark.parametrize("texel", [(4, 2, 5), (0, 0, 0), (2, 7, 3)])
def test_one_texel_map_equals_lambert_polygon_formula(compute, texel):
    res, value = 8, 3.0
    face, row, col = texel
    corners = _corner_directions(res, face, row, col)
    centre = corners.mean(axis=0) / np.linalg.norm(corners.mean(axis=0))
    # Normals that see the whole texel: around its centre, tilted by up to 40°.
    rng = np.random.default_rng(1)
    normals = centre + 0.8 * rng.uniform(-1, 1, size=(6, 6, 3)) * 0.5
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    assert np.all(normals.reshape(-1, 3) @ corners.T > 0)
    image = _reference(compute, GBuffer.from_pixels(normals, (0, 0, 1), 1.0, 0.0, 1.0),
                       _one_texel_map(res, face, row, col, value))
    expected = np.array([[value / np.pi * lambert_polygon(n, corners) for n in line] for line in normals])
    assert np.allclose(image[..., 0], expected, rtol=1e-4, atol=0)


def test_texel_cut_by_the_horizon(compute):
    res, face, row, col = 4, 4, 1, 2
    corners = _corner_directions(res, face, row, col)
    # A horizon through the texel's centre, oblique to its edges: it cuts the quad in two.
    centre = corners.mean(axis=0)
    normal = np.cross(centre, corners[1] - corners[0] + 0.3 * (corners[3] - corners[0]))
    normal /= np.linalg.norm(normal)
    heights = corners @ normal
    assert heights.min() < 0 < heights.max()
    image = _reference(compute, GBuffer.from_pixels(normal[None, None], (0, 0, 1), 1.0, 0.0, 1.0),
                       _one_texel_map(res, face, row, col))
    expected = brute_force(res, face, row, col, lambda w: np.maximum(w @ normal, 0), sub=2000) / np.pi
    assert image[0, 0, 0] == pytest.approx(expected, rel=1e-4)


@pytest.mark.parametrize("shininess", [150.0, 1e4])
def test_glossy_one_texel_matches_brute_force(compute, shininess):
    res, face, row, col = 16, 4, 7, 9
    centre = cubemap.face_st_to_direction(face, (col + 0.5) / res, (row + 0.5) / res)
    normal = centre + np.array([0.1, 0.05, 0.0])
    normal /= np.linalg.norm(normal)
    # A view whose mirror direction r points at a corner region of the texel.
    corner = cubemap.face_st_to_direction(face, (col + 0.8) / res, (row + 0.3) / res)
    view = 2 * np.dot(normal, corner) * normal - corner
    ks = 0.6
    image = _reference(compute, GBuffer.from_pixels(normal[None, None], view, 0.0, ks, shininess),
                       _one_texel_map(res, face, row, col))
    r = 2 * np.dot(normal, view) * normal - view
    lobe = lambda w: (ks * (shininess + 2) / (2 * np.pi) * np.maximum(w @ r, 0) ** shininess
                      * np.maximum(w @ normal, 0))
    assert image[0, 0, 0] == pytest.approx(brute_force(res, face, row, col, lobe, sub=1500), rel=2e-3)


@pytest.mark.parametrize("shininess, tolerance", [(0.0, 5e-4), (1.0, 1e-4)])
def test_lobe_boundary_through_a_texel(compute, shininess, tolerance):
    """The lobe's plane r·ω = 0 cuts the texel in half: at m = 0 the lobe is a step there, at
    m = 1 a kink (stress case shininess; a 2×2 midpoint rule missed them by ~1e-2 of the texel)."""
    res, face, row, col = 16, 4, 7, 9
    centre = cubemap.face_st_to_direction(face, (col + 0.5) / res, (row + 0.5) / res)
    r = np.cross(centre, [0.3, 1.0, 0.2])
    r /= np.linalg.norm(r)
    normal = centre + 0.3 * r
    normal /= np.linalg.norm(normal)
    view = 2 * np.dot(normal, r) * normal - r
    image = _reference(compute, GBuffer.from_pixels(normal[None, None], view, 0.0, 1.0, shininess),
                       _one_texel_map(res, face, row, col))
    lobe = lambda w: ((shininess + 2) / (2 * np.pi) * np.where(w @ r > 0, np.maximum(w @ r, 0) ** shininess, 0)
                      * np.maximum(w @ normal, 0))
    assert image[0, 0, 0] == pytest.approx(brute_force(res, face, row, col, lobe, sub=2000), rel=tolerance)


def test_reference_is_cached_by_content(compute):
    gbuffer = DeviceGBuffer(compute, GBuffer.from_pixels(fibonacci_directions(16).reshape(4, 4, 3),
                                                         (0, 0, 1), 0.5, 0.3, 20.0))
    env = np.random.default_rng(3).random((6, 4, 4, 3)).astype(np.float32)
    reference = Reference(compute)
    first = reference.image(gbuffer, FrameCache(compute, env))
    assert reference.last_ms is not None
    again = reference.image(gbuffer, FrameCache(compute, env))
    assert reference.last_ms is None and np.array_equal(first, again)
    env[0, 0, 0] += 1.0
    changed = reference.image(gbuffer, FrameCache(compute, env))
    assert reference.last_ms is not None and not np.array_equal(first, changed)


@pytest.mark.parametrize("shininess", [20.0, 150.0, 1e4])
def test_lobe_tail_texels_are_not_skipped(compute, shininess):
    """A lit texel where the lobe is 1e-6 of its peak (above the 1e-9 skip cutoff) still counts."""
    res = 32
    r = np.array([0.3, 0.5, 0.81])
    r /= np.linalg.norm(r)
    theta = np.arccos(1e-6 ** (1 / shininess))
    side = np.cross(r, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    direction = np.cos(theta) * r + np.sin(theta) * side
    face, row, col = (int(i) for i in cubemap.direction_to_texel(direction, res))
    normal = (r + direction) / np.linalg.norm(r + direction)
    view = 2 * np.dot(normal, r) * normal - r
    image = _reference(compute, GBuffer.from_pixels(normal[None, None], view, 0.0, 1.0, shininess),
                       _one_texel_map(res, face, row, col))
    lobe = lambda w: ((shininess + 2) / (2 * np.pi) * np.maximum(w @ r, 0) ** shininess
                      * np.maximum(w @ normal, 0))
    expected = brute_force(res, face, row, col, lobe, sub=600)
    assert expected > 0
    # Skipping would give 0.  In the far tail the lobe changes by e^3 across a texel, so the
    # reference's few sub-cells there are only good to ~1%: 1e-8 of the peak, far below MC noise.
    assert image[0, 0, 0] == pytest.approx(expected, rel=3e-2)


@pytest.mark.parametrize("shininess", [20.0, 150.0, 1e3])
def test_batched_single_cell_texels_match_the_per_texel_table(compute, shininess):
    """At R = 64 most lobe texels are one sub-cell, which the reference kernel evaluates four
    texels to a vector step (flush_single_cells); the per-texel table (texel_integral_table)
    takes them one by one.  The image is Σ L_t (kd/π·cos + ks·(m+2)/(2π)·lobe) of the table."""
    res = 64
    normal = fibonacci_directions(6)
    side = np.cross(normal, [0.3, 0.5, 0.81])
    side /= np.linalg.norm(side, axis=-1, keepdims=True)
    view = np.cos(1.2) * normal + np.sin(1.2) * side
    gbuffer = GBuffer.from_pixels(normal.reshape(2, 3, 3), view.reshape(2, 3, 3), 0.0, 1.0, shininess)
    env = face_pattern_map(res)
    image = _reference(compute, gbuffer, env)
    expected = [(shininess + 2) / (2 * np.pi) * np.einsum("frc,frck->k", table[..., 1], env)
                for table in Reference(compute).texel_integrals(DeviceGBuffer(compute, gbuffer), res)]
    assert np.allclose(image.reshape(-1, 3), expected, rtol=1e-5, atol=0)
