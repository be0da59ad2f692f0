"""The exact reference (estimators/runtime/reference.cl) against its independent NumPy twin
(harness/verify/twins/reference_twin.py, whose docstring says how it integrates), at the 1e-4 level; the
twin's own accuracy is checked against closed forms (the white furnace, and the lobe's
hemisphere integral 2π/(m+2) on a constant map seen head-on), and its rule against a rule of
twice the order.  A third quadrature (``nested_gauss_texel``) settles one texel lit alone on a
lobe's flank, where the reference's texel error is not hidden under the rest of the map (issue 34).
"""
import dataclasses
import warnings

import numpy as np
import pytest

from iblbench.harness.verify.conformance import face_pattern_map, fibonacci_directions
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.harness.verify.twins.reference_twin import GAUSS_ORDER, texel_integrals, twin_image
from iblbench.harness.verify.stress_cases import with_masks
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import GBuffer

SHININESS = (0.0, 1.0, 2.0, 20.0, 150.0, 1e3, 1e4)
VIEW_DEGREES = (89.94, 85.0, 45.0, 0.0)     # angle between view and normal (89.94°: n·v = 1e-3)
RTOL = 1e-4


def twin_scene(kd: float, ks: float) -> GBuffer:
    """Every shininess of ``SHININESS`` under every view angle of ``VIEW_DEGREES``, on normals
    spread over the sphere, views tilted toward an arbitrary side."""
    count = len(SHININESS) * len(VIEW_DEGREES)
    normal = fibonacci_directions(count)
    side = np.cross(normal, [0.3, 0.5, 0.81])
    side /= np.linalg.norm(side, axis=-1, keepdims=True)
    angle = np.radians(np.tile(VIEW_DEGREES, len(SHININESS)))[:, None]
    view = np.cos(angle) * normal + np.sin(angle) * side
    shape = (len(SHININESS), len(VIEW_DEGREES))
    return GBuffer.from_pixels(normal.reshape(shape + (3,)), view.reshape(shape + (3,)), kd, ks,
                               np.repeat(SHININESS, len(VIEW_DEGREES)).reshape(shape))


def kernel_image(compute, gbuffer: GBuffer, env: np.ndarray) -> np.ndarray:
    return Reference(compute, use_cache=False).image(DeviceGBuffer(compute, gbuffer),
                                                     FrameCache(compute, env))


def test_twin_matches_closed_forms():
    """A constant map: ∫ cos⁺ dω = π over the sphere, and head-on (r = n) the lobe integrates
    to 2π/(m+2) over the hemisphere, for every m, on faces of 1 and 8 texels."""
    for res in (1, 8):
        for m in (0.0, 1.0, 150.0, 1e4):
            normal = fibonacci_directions(7)[2]
            cosine, lobe = texel_integrals(normal, normal, m, res)
            assert cosine.sum() == pytest.approx(np.pi, rel=1e-12)
            assert lobe.sum() == pytest.approx(2 * np.pi / (m + 2), rel=1e-11)


def test_twin_rule_is_converged():
    """Twice the Gauss order changes no texel integral by more than 1e-9 of the pixel's total,
    at grazing views and every shininess."""
    gbuffer = twin_scene(0.5, 0.5)
    for index in [(i, 0) for i in range(len(SHININESS))]:
        args = gbuffer.normal[index], gbuffer.view[index], float(gbuffer.shininess[index]), 8
        for coarse, fine in zip(texel_integrals(*args), texel_integrals(*args, order=2 * GAUSS_ORDER)):
            assert np.abs(coarse - fine).max() <= 1e-9 * max(fine.sum(), 1e-300)


DIFFUSE_RTOL = 1e-5            # measured ≤ 1.1e-7 (float32 output) at R = 2, 8, 16
# The specular part (Gauss–Legendre sub-cells, the horizon cut exactly, sin² without
# cancellation): measured ≤ 2.9e-6 at R = 2, 8, 16 for m from 1 to 1e4 with reference.py's
# density of 8 (1.5e-5 with 4, issue 13 §4).
SPECULAR_RTOL = RTOL


_compared: dict[tuple, tuple] = {}   # (res, kd, ks) → _relative_error's answer, one per session


def _relative_error(compute, res: int, kd: float, ks: float):
    """(G-buffer, reference, twin, relative error) of ``twin_scene`` on ``face_pattern_map``."""
    if (res, kd, ks) not in _compared:
        gbuffer = twin_scene(kd, ks)
        env = face_pattern_map(res)
        expected = twin_image(gbuffer, env)
        got = kernel_image(compute, gbuffer, env).astype(np.float64)
        _compared[res, kd, ks] = gbuffer, got, expected, np.abs(got - expected) / expected
    return _compared[res, kd, ks]


def _assert_within(gbuffer, got, expected, error, tolerance, what):
    worst = np.unravel_index(np.argmax(error), error.shape)
    assert error.max() <= tolerance, (
        f"{what}: relative error {error.max():.2e} > {tolerance:g} at m = "
        f"{gbuffer.shininess[worst[:2]]:g}, view {VIEW_DEGREES[worst[1]]}° (reference "
        f"{got[worst]:.7g}, twin {expected[worst]:.7g})")


@pytest.mark.parametrize("res", [2, 8])
def test_reference_diffuse_matches_the_twin(compute, res):
    """reference.cl's diffuse part against the twin, per pixel and channel, on the map with an
    asymmetric pattern on every face, at grazing views (n·v = 1e-3)."""
    _assert_within(*_relative_error(compute, res, 1.0, 0.0), DIFFUSE_RTOL, f"diffuse, R = {res}")


@pytest.mark.parametrize("res", [2, 8])
def test_reference_specular_matches_the_twin(compute, res):
    """reference.cl's specular part against the twin for m from 0 to 1e4 at grazing views, to
    ``SPECULAR_RTOL`` (m = 0, the clipped half-space, to ``DIFFUSE_RTOL``)."""
    gbuffer, got, expected, error = _relative_error(compute, res, 0.0, 1.0)
    _assert_within(gbuffer, got, expected, error, SPECULAR_RTOL, f"specular, R = {res}")
    half_space = gbuffer.shininess == 0
    _assert_within(gbuffer, got, expected, np.where(half_space[..., None], error, 0.0),
                   DIFFUSE_RTOL, f"specular m = 0, R = {res}")


@pytest.mark.parametrize("kd, ks", [(1.0, 0.0), (0.0, 1.0)])
def test_reference_without_fp64_stays_within_its_error(compute, kd, ks):
    """fp64 is optional (many GPUs have slow double or none): the float path of reference.cl,
    built as on a device without cl_khr_fp64, against the twin to ``SPECULAR_RTOL``."""
    from iblbench.estimators.runtime.device import Compute

    float_only = Compute(compute.info, fp64=False)
    gbuffer, env = twin_scene(kd, ks), face_pattern_map(8)
    got = kernel_image(float_only, gbuffer, env).astype(np.float64)
    if compute.info.has_fp64:   # the float path is a path of its own: its sums round otherwise
        assert not np.array_equal(got, kernel_image(compute, gbuffer, env))
    expected = twin_image(gbuffer, env)
    _assert_within(gbuffer, got, expected, np.abs(got - expected) / expected, SPECULAR_RTOL,
                   f"float path, kd = {kd}, ks = {ks}")


def nested_gauss_texel(normal, r, m: float, face: int, row: int, col: int, res: int,
                       cells: int, order: int) -> np.ndarray:
    """(∫_texel cos⁺(n·ω) dω, ∫_texel max(0, r·ω)^m cos⁺(n·ω) dω), float64, a third way: on the
    face plane (direction u·U + v·V + W, dω = du dv / q^{3/2}), an outer Gauss–Legendre rule in
    u split where the horizon or the lobe's plane crosses the texel's edges v = v0, v1, and for
    each u an inner rule over the v where n·ω ≥ 0 and r·ω ≥ 0 (the limits exact), each side in
    ``cells`` pieces of ``order`` points: the integrand is smooth on every piece."""
    basis_u, basis_v, basis_w = cubemap.face_basis(face)
    forms = [np.array([x @ basis_w, x @ basis_u, x @ basis_v]) for x in (normal, r)]
    u0, v0, side = -1 + 2 * col / res, -1 + 2 * row / res, 2 / res
    crossings = [-(a + c * v) / b for a, b, c in forms if b for v in (v0, v0 + side)]
    breaks = np.unique(np.clip([u0, u0 + side, *crossings], u0, u0 + side))
    x, w = np.polynomial.legendre.leggauss(order)
    x, w = (x + 1) / 2, w / 2

    def composite(lo, hi):   # nodes and weights [..., cells·order] on [lo, hi]
        edges = lo[..., None] + (hi - lo)[..., None] * np.linspace(0, 1, cells + 1)
        step = np.diff(edges)[..., None]
        shape = np.shape(lo) + (cells * order,)
        return (edges[..., :-1, None] + step * x).reshape(shape), (step * w).reshape(shape)

    total = np.zeros(2)
    for lo, hi in zip(breaks[:-1], breaks[1:]):
        u, u_weight = composite(np.float64(lo), np.float64(hi))
        v_lo, v_hi = np.full_like(u, v0), np.full_like(u, v0 + side)
        for a, b, c in forms:   # a + b·u + c·v ≥ 0
            if c > 0:
                v_lo = np.maximum(v_lo, -(a + b * u) / c)
            elif c < 0:
                v_hi = np.minimum(v_hi, -(a + b * u) / c)
            else:
                v_hi = np.where(a + b * u >= 0, v_hi, v_lo)
        v, v_weight = composite(v_lo, np.maximum(v_lo, v_hi))
        d = u[:, None, None] * basis_u + v[..., None] * basis_v + basis_w
        q = np.sum(d * d, axis=-1)
        cosine = np.maximum(d @ normal, 0.0) / q ** 2
        sin2 = np.sum(np.cross(d, r) ** 2, axis=-1) / q   # no 1 − cos² cancellation
        lobe = np.exp(0.5 * m * np.log1p(-np.minimum(sin2, 1 - 1e-16)))
        for k, integrand in enumerate((cosine, lobe * cosine)):
            total[k] += u_weight @ np.sum(v_weight * integrand, axis=1)
    return total


# One pixel lit by one texel, where the reference's texel error is not hidden under the rest of
# the map (issue 34).  The lobe's flank: m = 3000, the texel's nearest cos^m ~3e-3 of the peak,
# Rv = 2; the reference was 2.0e-4 off with 4 points per lobe width, 1.4e-5 with reference.py's 8.
# The horizon at grazing views (n·v ≈ 0.03), m = 20, the texel cut by it: 3.9e-3 off while rows
# wholly below the horizon were in the rule's cells, 1.8e-6 since lobe_cells cuts them; the
# second, 3.6e-4 off at the kink where the horizon enters the rows, 5.6e-5 with reference.cl's
# HORIZON_DENSITY.
LIT_ALONE = {
    "lobe flank": dict(normal=(0.6081649, -0.4466223, 0.65625), m=3000.0, texel=(4, 7, 5),
                       view=(0.9142780, -0.1085260, 0.3902791), res=8, vis_res=2),
    "grazing horizon": dict(normal=(-0.5659814, 0.1396740, -0.8125), m=20.0, texel=(2, 3, 6),
                            view=(-0.7053292, -0.6209019, 0.3420403), res=8, vis_res=2),
    "grazing horizon, R = 16": dict(normal=(0.7471854, -0.5487158, -0.375), m=20.0,
                                    texel=(4, 14, 7), view=(0.0135431, 0.5289572, -0.8485404),
                                    res=16, vis_res=2),
}


@pytest.mark.parametrize("case", LIT_ALONE)
def test_one_lit_texel_matches_a_nested_quadrature(compute, case):
    """The masked reference of one pixel (kd = 0.2, ks = 0.8) lit by one texel (its cell the only
    open one) against (kd/π·∫cos⁺ + ks·(m+2)/(2π)·∫lobe·cos⁺)·L of ``nested_gauss_texel``, to
    ``RTOL``; the nested rule converged (doubling its pieces moves it < 1e-12) and the twin on it
    to 1e-9."""
    lit = LIT_ALONE[case]
    face, row, col = lit["texel"]
    res, vis_res, m = lit["res"], lit["vis_res"], lit["m"]
    gbuffer = GBuffer.from_pixels(np.array([[lit["normal"]]]), lit["view"], 0.2, 0.8, m)
    cell = (face * vis_res + row * vis_res // res) * vis_res + col * vis_res // res
    gbuffer = with_masks(gbuffer, np.arange(6 * vis_res ** 2)[None, None] == cell, vis_res)
    env = np.zeros((6, res, res, 3), np.float32)
    env[face, row, col] = (1.0, 0.5, 0.25)

    normal, view = gbuffer.normal[0, 0].astype(np.float64), gbuffer.view[0, 0].astype(np.float64)
    r = 2 * (normal @ view) * normal - view
    r /= np.linalg.norm(r)
    coarse, fine = (nested_gauss_texel(normal, r, m, face, row, col, res, cells, order)
                    for cells, order in ((16, 12), (32, 16)))
    assert np.abs(coarse - fine).max() <= 1e-12 * fine.max()
    cosine, lobe = fine
    kd, ks = gbuffer.kd[0, 0].astype(np.float64), gbuffer.ks[0, 0].astype(np.float64)   # as stored
    diffuse, specular = kd / np.pi * cosine, ks * (m + 2) / (2 * np.pi) * lobe
    assert np.all(specular > diffuse / 2)   # the lobe's share is one the test can see
    expected = (diffuse + specular) * env[face, row, col]

    twin = twin_image(gbuffer, env)[0, 0]
    assert np.abs(twin - expected).max() <= 1e-9 * expected.max()
    got = kernel_image(compute, gbuffer, env)[0, 0].astype(np.float64)
    error = np.abs(got - expected) / expected
    assert error.max() <= RTOL, f"reference {got}, nested quadrature {expected}: {error.max():.2e}"


def test_twin_leaves_uncovered_pixels_black_without_warnings():
    """Uncovered pixels hold zero vectors (scenes/gbuffer.py): the twin gives them 0, as the
    reference does, and divides no zero by zero on the way."""
    gbuffer = twin_scene(0.5, 0.5)
    mask = np.ones(gbuffer.shape, bool)
    mask[1, 2] = False
    holed = dataclasses.replace(gbuffer, mask=mask, normal=gbuffer.normal * mask[..., None],
                                view=gbuffer.view * mask[..., None])
    env = face_pattern_map(2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image = twin_image(holed, env)
    assert not image[1, 2].any()
    assert np.array_equal(image[mask], twin_image(gbuffer, env)[mask])
