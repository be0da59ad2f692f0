"""The production baselines ``brdf`` and ``envmap``, and MIS compensation (issue 12).

The default-parameter estimators pass the conformance suite in test_estimators.py; here the MIS
variants pass it too, the samplers' texel probabilities match an independent NumPy construction
of their weights (plain and compensated), every lit texel of a 1e6:1 sun map is reachable and
the χ² accepts the sampler there, and the analytic cases hold."""
import numpy as np
import pytest

from iblbench.estimators import registry
from iblbench.harness.verify import conformance
from iblbench.harness.verify.conformance import ALPHA_CHI2, check_estimator, chi2_sampling
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import CDF_ONE, FrameCache
from iblbench.harness.protocol.sweep import parse_estimator
from iblbench.scenes import cubemap
from iblbench.foundation.errors import InputError

SUN_RES = 16


def bins(cdf: np.ndarray) -> np.ndarray:
    """Probabilities of a fixed-point CDF's bins along its last axis (float64)."""
    widths = np.diff(cdf.astype(np.uint64), axis=-1, prepend=np.zeros(cdf.shape[:-1] + (1,), np.uint64))
    return widths.astype(np.float64) / CDF_ONE


def alias_probabilities(words: np.ndarray, n: int) -> np.ndarray:
    """P(bin) ``[..., n]`` of alias tables ``[..., M]`` (framecache.cl's words), read off them as
    a draw makes it (bin i of M uniformly, kept with probability t_i/S, else its alias a_i) in
    exact integers, as a float64 fraction of 2^63; each table must hold exactly 2^63."""
    bins = words.shape[-1]
    bits = bins.bit_length() - 1
    unit = CDF_ONE >> bits
    thresholds, aliases = words >> np.uint64(bits), (words & np.uint64(bins - 1)).astype(np.int64)
    assert np.all(thresholds <= unit) and np.all(aliases < n)
    tables = words.reshape(-1, bins)
    out = np.zeros((len(tables), n))
    for k in range(len(tables)):
        units = [0] * bins   # Python ints: 2^63 overflows int64
        for i, (t, a) in enumerate(zip(thresholds.reshape(-1, bins)[k].tolist(), aliases.reshape(-1, bins)[k])):
            units[i] += t
            units[a] += unit - t
        assert sum(units) == CDF_ONE and not any(units[n:])
        out[k] = np.array(units[:n], np.float64) / CDF_ONE
    return out.reshape(words.shape[:-1] + (n,))


def map_texel_probabilities(compute, cache: FrameCache, compensated: bool) -> np.ndarray:
    """P(texel) ``[6, R, R]`` of envmap's light sampler: the rows' alias table's P(row) times the
    row's table's P(col | row), read off the tables; the float probabilities the kernels divide
    by must be these, rounded."""
    res = cache.res
    row_bins, col_bins = (1 << (n - 1).bit_length() for n in (6 * res, res))
    table = cache.map_alias(compensated)
    words = compute.to_host(table.words, (row_bins + 6 * res * col_bins,), np.uint64)
    rows = alias_probabilities(words[:row_bins], 6 * res)
    cols = alias_probabilities(words[row_bins:].reshape(6 * res, col_bins), res)
    exact = rows[:, None] * cols
    stored = compute.to_host(table.probability, (6 * res, res), np.float32)
    np.testing.assert_allclose(stored, exact, rtol=2.0 ** -22, atol=0)   # three roundings to float
    return exact.reshape(6, res, res)


def numpy_weights(env: np.ndarray, compensated: bool) -> np.ndarray:
    """Independent weights ``[6, R, R]``: Y·Ω, or pbrt-v4's compensated
    max(Y − Ȳ, min(Ȳ/1000, Y))·Ω with Ȳ the mean over the sphere (float64)."""
    env = env.astype(np.float64)
    y = env @ np.array([0.2126, 0.7152, 0.0722])
    omega = cubemap.texel_solid_angles(env.shape[1])[None]
    if compensated:
        mean = np.sum(y * omega) / (4 * np.pi)
        y = np.maximum(y - mean, np.minimum(1e-3 * mean, y))
    return y * omega


@pytest.mark.parametrize("compensated", [False, True])
@pytest.mark.parametrize("env", [conformance.face_pattern_map(8), conformance.sun_map(SUN_RES, 1e6)],
                         ids=["face-pattern", "sun-1e6"])
def test_map_distribution_is_proportional_to_its_weights(compute, env, compensated):
    """Every texel's probability is its weight over the map's total, relatively to 1e-5, and
    positive for every lit texel (the 1e6:1 sun's dim sky included)."""
    cache = FrameCache(compute, env)
    cache.require(registry.get_estimator_class("envmap").requires)
    p = map_texel_probabilities(compute, cache, compensated)
    weights = numpy_weights(env, compensated)
    expected = weights / weights.sum()
    lit = weights > 0
    assert np.all(p[lit] > 0), f"{np.count_nonzero(p[lit] == 0)} lit texels are never drawn"
    assert np.all(p[~lit] == 0)
    np.testing.assert_allclose(p[lit], expected[lit], rtol=1e-5)


def test_compensation_moves_probability_to_the_bright_texels(compute):
    """Compensation keeps a positive pdf on the dim sky but gives the sun more: on the sun map
    the compensated sun texel's probability exceeds the plain one's."""
    env = conformance.sun_map(SUN_RES, 30.0)
    cache = FrameCache(compute, env)
    cache.require(("cdf",))
    plain, compensated = (map_texel_probabilities(compute, cache, c) for c in (False, True))
    sun = (conformance.SUN_FACE, SUN_RES // 2, SUN_RES // 2)
    assert compensated[sun] > plain[sun]
    assert np.all(compensated[env.sum(-1) > 0] > 0)


def test_compensated_per_face_cdfs_match_their_weights(compute):
    """balanced_mis's compensated face integrals and per-face CDFs are those of the compensated
    weights."""
    env = conformance.face_pattern_map(8)
    cache = FrameCache(compute, env)
    cache.require(("cdf",))
    cdfs = cache.light_cdfs(compensated=True)
    weights = numpy_weights(env, compensated=True)
    integral = compute.to_host(cdfs.face_integral, (6,), np.float32)
    np.testing.assert_allclose(integral, weights.sum(axis=(1, 2)), rtol=1e-5)
    marginal = compute.to_host(cdfs.marginal, (6, 8), np.uint64)
    conditional = compute.to_host(cdfs.conditional, (6, 8, 8), np.uint64)
    p = bins(marginal)[:, :, None] * bins(conditional)
    np.testing.assert_allclose(p, weights / weights.sum(axis=(1, 2), keepdims=True), rtol=1e-5)


@pytest.mark.parametrize("params", [{}, {"mis": "brdf"}, {"mis": "brdf", "mis_compensation": True}],
                         ids=["light-only", "mis", "mis-compensated"])
@pytest.mark.parametrize("name", ["envmap", "hierarchical"])
def test_envmap_chi2_passes_on_a_sun_map(compute, name, params):
    """On a map whose sun is 1e6× its brightest sky texel, the sampler's directions follow its
    pdf (χ², pooled low-count cells) at two surfaces."""
    estimator = registry.make_estimator(name, **params)
    cache = FrameCache(compute, conformance.sun_map(SUN_RES, 1e6))
    cache.require(type(estimator).requires)
    gb = conformance.glossy_gbuffer(2)
    for case, (i, j) in enumerate(((0, 0), (1, 1))):
        result = chi2_sampling(estimator, cache, gb.normal[i, j], gb.view[i, j], seed=11 + case)
        assert not result.problems, result.problems
        assert result.p_value >= ALPHA_CHI2 / 2, f"χ² p = {result.p_value:.3g}"


@pytest.mark.parametrize("label", ['envmap{mis="brdf",heuristic="balance"}',
                                   'envmap{mis="brdf",mis_compensation=true}',
                                   "balanced_mis{mis_compensation=true}",
                                   'hierarchical{mis="brdf",heuristic="balance"}',
                                   'hierarchical{mis="brdf",mis_compensation=true}'])
def test_mis_variants_pass_the_conformance_suite(compute, label):
    """The z-test against the reference, χ², convergence, stress maps and counts hold with MIS,
    with either heuristic, and with compensation."""
    outcome = check_estimator(parse_estimator(label).make(), compute=compute)
    assert outcome["check_unbiased"] == "passed" and outcome["check_chi2_sampling"] == "passed"


def test_brdf_pdf_is_the_phong_mixture(compute):
    """``brdf``'s pdf hook against the mixture pdf of ARCHITECTURE.md §Conventions written out in NumPy."""
    estimator = registry.make_estimator("brdf")
    cache = FrameCache(compute, conformance.smooth_map(8))
    normal, view = np.array([0.2, 0.9, 0.1]), np.array([0.6, 0.5, -0.3])
    n, v = normal / np.linalg.norm(normal), view / np.linalg.norm(view)
    r = 2 * (n @ v) * n - v
    dirs = conformance.fibonacci_directions(1000).astype(np.float32)
    kd, ks, m = 0.5, 0.3, 20.0   # the hooks' material; luminances of grey are the grey value
    p_spec = ks / (kd + ks)
    expected = ((1 - p_spec) * np.maximum(dirs @ n, 0) / np.pi
                + p_spec * (m + 1) / (2 * np.pi) * np.maximum(dirs @ r, 0) ** m)
    np.testing.assert_allclose(estimator.pdf(cache, normal, view, dirs), expected, rtol=1e-4, atol=1e-7)


def test_brdf_white_furnace_is_exact(compute):
    """Cosine-weighted samples of a white Lambertian under a constant map weigh exactly the map's
    value each: zero variance."""
    gb = conformance.white_lambertian(4)
    cache = FrameCache(compute, conformance.constant_map(0.7, 8))
    estimate = registry.make_estimator("brdf").render(DeviceGBuffer(compute, gb), cache, 3, 5)
    np.testing.assert_allclose(estimate.radiance[gb.mask], 0.7, rtol=1e-5)


@pytest.mark.parametrize("label", ['envmap{mis="brdf",mis_compensation=true}',
                                   "balanced_mis{mis_compensation=true}",
                                   'hierarchical{mis="brdf",mis_compensation=true}'])
def test_compensation_on_black_and_constant_maps(compute, label):
    """Mitsuba 3 #1271: a black map with compensation must give exactly 0, a constant one finite
    values around its value, never NaN."""
    estimator = parse_estimator(label).make()
    gbuffer = DeviceGBuffer(compute, conformance.white_lambertian(4))
    for value in (0.0, 0.7):
        cache = FrameCache(compute, conformance.constant_map(value, 8))
        cache.require(type(estimator).requires)
        images = np.stack([estimator.render(gbuffer, cache, 4, seed).radiance for seed in range(50)])
        assert np.all(np.isfinite(images))
        if value == 0.0:
            assert np.all(images == 0.0)
        else:
            assert abs(images.mean() - value) < 0.02 * value


def test_compensation_without_mis_is_refused():
    with pytest.raises(InputError, match="mis_compensation needs MIS"):
        parse_estimator("envmap{mis_compensation=true}")
    with pytest.raises(InputError, match="heuristic"):
        parse_estimator('envmap{heuristic="veach"}')


def test_versions_differ_and_hash_the_shared_kernel():
    """brdf and envmap hash their own and envmap.cl's sources."""
    brdf, envmap = (registry.get_estimator_class(name) for name in ("brdf", "envmap"))
    assert "envmap.cl" in brdf.kernel_files and brdf.version() != envmap.version()
