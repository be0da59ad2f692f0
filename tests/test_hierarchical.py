"""``hierarchical``: light sampling by descent through the weight pyramid (issue 12, item 3).

The default estimator passes the conformance suite in test_estimators.py; here its texel
probabilities match the ideal w/W of an independent NumPy pyramid within the fixed-point bound
of each choice (plain and compensated, odd face sizes too), sum to 1, are positive on every lit
texel of a 1e6:1 sun (and of a sibling 1e-13 of a sun's weight), and it never builds the
``cdf`` product.  test_brdf_envmap.py runs its χ² on that sun, its MIS variants' conformance and
compensation on black and constant maps beside envmap's."""
import numpy as np
import pytest

from iblbench.estimators import registry
from iblbench.estimators.hierarchical import Hierarchical
from iblbench.harness.verify import conformance
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.harness.protocol.sweep import parse_estimator
from iblbench.scenes import cubemap
from iblbench.foundation.errors import InputError

from test_brdf_envmap import SUN_RES, numpy_weights
from test_mips import numpy_chain

ONE = 2.0 ** 31   # a descent choice's widths total (hierarchical.cl)


def texel_probabilities(compute, cache, compensated: bool) -> np.ndarray:
    """P(texel) ``[6, R, R]`` of the light sampler (plain or compensated, without BRDF samples,
    so the pooled density is the light density), from its density at the texel centres:
    pdf · a_texel / (1+x²+y²)^{3/2}."""
    light_only = type("LightOnly", (Hierarchical,), {"compensated": compensated})   # past the MIS check
    res = cache.res
    dirs = cubemap.texel_directions(res).reshape(-1, 3).astype(np.float32)
    pdf = light_only().pdf(cache, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.6, 0.8]), dirs).astype(np.float64)
    centres = (np.arange(res) + 0.5) / res * 2 - 1
    y, x = np.meshgrid(centres, centres, indexing="ij")
    jacobian = (1 + x * x + y * y) ** 1.5
    return (pdf.reshape(6, res, res) * (4.0 / res ** 2) / jacobian[None])


def ideal_and_bound(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(w/W per texel, the relative bound of the fixed-point descent on it): each choice of
    ideal probability p is off by at most n/2^31 (the floor of up to n − 1 siblings' widths, all
    landing on the largest child) plus float rounding, so P/P_ideal − 1 is within
    Σ_choices 6/(2^31·p) + 1e-5."""
    levels = numpy_chain(weights[..., None], average=False)
    totals = levels[-1].reshape(6)
    res = weights.shape[1]
    face_p = totals / totals.sum()
    bound = np.broadcast_to(6.0 / (ONE * np.maximum(face_p, 1e-300))[:, None, None], weights.shape).copy()
    rows, cols = np.meshgrid(np.arange(res), np.arange(res), indexing="ij")
    for l in range(len(levels) - 1):
        child = levels[l][..., 0][:, rows >> l, cols >> l]
        parent = levels[l + 1][..., 0][:, rows >> (l + 1), cols >> (l + 1)]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound += 6.0 / (ONE * (child / parent))
    return weights / weights.sum(), bound + 1e-5


@pytest.mark.parametrize("compensated", [False, True])
@pytest.mark.parametrize("env", [conformance.face_pattern_map(8), conformance.sun_map(SUN_RES, 1e6),
                                 conformance.sun_map(12, 1e6)], ids=["face-pattern", "sun-1e6", "sun-1e6-res12"])
def test_texel_probabilities_are_the_weights_shares(compute, env, compensated):
    """Every texel's probability is its weight over the map's total within the fixed-point
    bound, positive for every lit texel (the 1e6:1 sun's dim sky included), 0 for the unlit,
    and they sum to 1."""
    cache = FrameCache(compute, env)
    p = texel_probabilities(compute, cache, compensated)
    weights = numpy_weights(env, compensated)
    expected, bound = ideal_and_bound(weights)
    if compensated:   # the device's float Y − Ȳ: a few ulps of Y + Ȳ, relative to the difference
        plain = numpy_weights(env, False)
        mean = plain.sum() / (4 * np.pi)
        omega = cubemap.texel_solid_angles(env.shape[1])[None]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound += 1e-6 * (plain + mean * omega) / weights
    lit = weights > 0
    assert np.all(p[lit] > 0), f"{np.count_nonzero(p[lit] <= 0)} lit texels are never drawn"
    assert np.all(p[~lit] == 0)
    relative = np.abs(p[lit] / expected[lit] - 1)
    assert np.all(relative <= bound[lit]), f"worst {relative.max():.3g} against bound {bound[lit][relative.argmax()]:.3g}"
    assert abs(p.sum() - 1) < 1e-5
    assert "cdf" not in cache.built


def test_a_sibling_below_float_resolution_stays_reachable(compute):
    """A texel 1e-13 of its 2×2 sibling sun (below 2^-31 and far below a float threshold's
    2^-24) keeps the smallest width, 1/2^31, at its own choice: P ≥ 2^-31 · P(its parent)."""
    res = 8
    env = np.full((6, res, res, 3), 1e-3, np.float32)
    env[2, 4, 4] = 1e10
    env[2, 4, 5] = 1e-3
    cache = FrameCache(compute, env)
    p = texel_probabilities(compute, cache, compensated=False)
    weights = numpy_weights(env, False)
    parent = weights[2, 4:6, 4:6].sum() / weights.sum()
    assert p[2, 4, 5] >= 0.99 * parent / ONE
    assert p[2, 4, 5] <= 6.0 * parent / ONE


def test_render_builds_the_pyramid_and_draws_its_tables(compute):
    """The per-frame product is the plain pyramid (the build stage); its descent tables, and the
    compensated pyramid and its tables, are drawn on first use and timed in the render's sample
    stage."""
    gbuffer = DeviceGBuffer(compute, conformance.glossy_gbuffer(4))
    cache = FrameCache(compute, conformance.smooth_map(8))
    cache.require(registry.get_estimator_class("hierarchical").requires)
    assert cache.built == ["env", "weight_pyramid"]
    plain = registry.make_estimator("hierarchical").render(gbuffer, cache, 4, 1)
    assert plain.timings_ms["sample"] == cache.timings_ms["descent_tables"] > 0
    compensated = parse_estimator('hierarchical{mis="brdf",mis_compensation=true}').make()
    estimate = compensated.render(gbuffer, cache, 4, 1)
    assert estimate.timings_ms["sample"] == (cache.timings_ms["compensated_descent_tables"]
                                             + cache.timings_ms["compensated_weight_pyramid"])
    assert cache.timings_ms["compensated_weight_pyramid"] > 0
    assert "cdf" not in cache.built and np.all(np.isfinite(estimate.radiance))


def test_black_map_hooks(compute):
    """On an all-black map the hook draws nothing (every sample weighs 0), as envmap's."""
    estimator = registry.make_estimator("hierarchical")
    cache = FrameCache(compute, conformance.constant_map(0.0, 4))
    dirs, pdf = estimator.sample_directions(cache, np.array([0, 0, 1.0]), np.array([0, 0, 1.0]), 64, 1)
    assert dirs.shape == (0, 3) and pdf.shape == (0,)


def test_parameters_and_version():
    with pytest.raises(InputError, match="mis_compensation needs MIS"):
        parse_estimator("hierarchical{mis_compensation=true}")
    hierarchical, envmap = (registry.get_estimator_class(name) for name in ("hierarchical", "envmap"))
    assert {"hierarchical.cl", "envmap.cl"} <= set(hierarchical.kernel_files)
    assert hierarchical.version() != envmap.version()
    assert "cdf" not in hierarchical.requires


def numpy_widths(w: np.ndarray, exists: np.ndarray) -> np.ndarray:
    """descent_choice.cl's widths (uint64 here) of N children of float32 weights ``w [..., N]``,
    in float32 as the kernel rounds them: q = max(1, ⌊w·(2^31/Σw)⌋) for w > 0, the rest to the
    first largest; where Σw is 0, 2^31/N for each child that exists."""
    n = w.shape[-1]
    total = np.zeros(w.shape[:-1], np.float32)
    for k in range(n):   # the kernel's order
        total = (total + w[..., k]).astype(np.float32)
    with np.errstate(divide="ignore"):
        scale = np.float32(ONE) / total
    fallback = ~(total > 0) | np.isinf(scale)
    weight = np.where(fallback[..., None], exists.astype(np.float32), w)
    share = weight * np.where(fallback, np.float32(ONE / n), scale)[..., None]
    q = np.where(weight > 0, np.maximum(1, np.minimum(share, np.float32(ONE)).astype(np.uint64)), 0)
    largest = np.argmax(weight, axis=-1)[..., None]
    others = q.sum(-1, keepdims=True) - np.take_along_axis(q, largest, -1)
    np.put_along_axis(q, largest, int(ONE) - others, -1)
    return q


def test_descent_tables_are_the_sums_choices(compute):
    """The frame cache's descent tables against a NumPy twin on a face size of 6 (levels 6, 3,
    2, 1: parents with 1, 2 and 4 children) with a black 2×2 block (the fallback's widths): every
    record's prefix widths at its heap index 2·4^k + f·4^k + Morton(row, col), the faces'
    record, and every texel's probability, the product of its choices' q/2^31 in float32 from
    the faces down."""
    res = 6
    env = np.random.default_rng(5).uniform(0.0, 2.0, (6, res, res, 3)).astype(np.float32)
    env[3, 2:4, 2:4] = 0.0
    cache = FrameCache(compute, env)
    levels = [level[..., 0] for level in cache.weight_pyramid().host_levels(compute)]
    tables = cache.descent_tables()
    depths = len(levels) - 1
    bounds = compute.to_host(tables.bounds, (2 * 4 ** depths, 4), np.uint32).astype(np.uint64)
    faces = numpy_widths(levels[-1].reshape(1, 6), np.ones((1, 6), bool))[0]
    assert list(bounds.reshape(-1)[:8]) == list(np.cumsum(faces)[:5]) + [ONE] * 3
    probability = np.empty((6, res, res), np.float32)
    for face in range(6):
        for row in range(res):
            for col in range(res):
                p = np.float32(faces[face]) * np.float32(1 / ONE)
                record = 2 + face
                for k in range(depths):
                    l, n = depths - 1 - k, levels[depths - 1 - k].shape[1]
                    r, c = row >> (l + 1), col >> (l + 1)
                    rows, cols = 2 * r + np.array([0, 0, 1, 1]), 2 * c + np.array([0, 1, 0, 1])
                    exists = (rows < n) & (cols < n)
                    w = np.where(exists, levels[l][face, np.minimum(rows, n - 1), np.minimum(cols, n - 1)], 0)
                    q = numpy_widths(w.astype(np.float32)[None], exists[None])[0]
                    assert list(bounds[record]) == list(np.cumsum(q)[:3]) + [ONE], (face, row, col, k)
                    child = 2 * ((row >> l) & 1) + ((col >> l) & 1)
                    p = np.float32(p * np.float32(np.float32(q[child]) * np.float32(1 / ONE)))
                    record = 4 * record + child
                probability[face, row, col] = p
    device = compute.to_host(tables.probability, (6 * res * res,), np.float32).reshape(6, res, res)
    assert np.array_equal(device, probability)
