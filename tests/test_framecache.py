"""Device CDFs and face integrals against NumPy; the reference without fp64."""
import math

import numpy as np
import pytest

from iblbench.harness.verify.conformance import fibonacci_directions, smooth_map
from iblbench.estimators.runtime.device import Compute, DeviceInfo
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import CDF_ONE, FrameCache, build_fixed_point_cdfs
from iblbench.estimators.runtime.reference import Reference
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import GBuffer


def numpy_texel_probabilities(env):
    """P(texel | face) ∝ Y·Ω, computed independently of the OpenCL scans."""
    weight = cubemap.luminance(env) * cubemap.texel_solid_angles(env.shape[1])
    return weight / weight.sum(axis=(1, 2), keepdims=True)


@pytest.mark.parametrize("res", [8, 1024])
def test_cdfs_match_numpy(compute, res):
    rng = np.random.default_rng(5)
    env = (rng.random((6, res, res, 3)) ** 3).astype(np.float32)
    env[2] = 0.0                                     # a black face
    env[4, res // 3, :] = 0.0                        # a black row
    env[0, 1, 2] = 1e6                               # a sun 1e6 times the rest
    cache = FrameCache(compute, env)
    marginal, conditional = cache.host_cdfs()        # fixed point: uint64, ending at 2^63
    assert marginal.dtype == np.uint64 and conditional.dtype == np.uint64
    assert np.all(marginal[:, 1:] >= marginal[:, :-1])
    assert np.all(conditional[..., 1:] >= conditional[..., :-1])
    assert np.all(marginal[:, -1] == CDF_ONE) and np.all(conditional[..., -1] == CDF_ONE)
    expected_if = cubemap.face_luminance_integrals(env)
    assert cache.face_integrals[2] == 0
    assert np.allclose(cache.face_integrals, expected_if, rtol=1e-5)
    p_row = np.diff(marginal, axis=1, prepend=np.uint64(0)) / CDF_ONE
    p_col = np.diff(conditional, axis=2, prepend=np.uint64(0)) / CDF_ONE
    lit = [0, 1, 3, 4, 5]
    p_texel = (p_row[:, :, None] * p_col)[lit]
    expected = numpy_texel_probabilities(env[lit])
    # Relative, for every texel: the widths are rounded relatively from float32 Y·Ω (a few ulps).
    positive = expected > 0
    assert np.all(p_texel[positive] > 0)
    assert np.allclose(p_texel[positive], expected[positive], rtol=1e-6, atol=0)
    assert np.all(p_texel[expected == 0] == 0)       # black texels are never sampled


def numpy_fixed_point_cdfs(weights):
    """The fixed-point CDF of each run (row) of float32 ``weights``, built independently of the
    device: W by math.fsum (exactly rounded), widths max(1, ⌊(w·(1/W))·2^63⌋) for w > 0 in
    float64, the remainder 2^63 − Σ q added to the first largest bin, inclusive sums mod 2^64;
    an all-zero run is uniform.  Returns (cdfs uint64, W as float32)."""
    cdfs, totals = [], []
    for run in np.asarray(weights, np.float32).astype(np.float64):
        total = math.fsum(run)
        weight, inverse = (run, 1.0 / total) if total > 0 else (np.ones_like(run), 1.0 / run.size)
        scaled = np.floor(weight * inverse * 2.0 ** 63)
        widths = np.where(weight > 0, np.maximum(scaled, 1.0), 0.0).astype(np.uint64)
        largest = int(np.argmax(run)) if total > 0 else 0
        remainder = CDF_ONE - int(widths.sum(dtype=np.uint64))
        widths[largest] = np.uint64((int(widths[largest]) + remainder) % 2 ** 64)
        cdfs.append(np.cumsum(widths, dtype=np.uint64))
        totals.append(np.float32(total))
    return np.array(cdfs), np.array(totals)


def contrast_weights(rng, runs, n):
    """Weights over 40 decades, with zeros, ties for the largest, a sun per run, an all-zero
    run, and a run whose sum a plain double sum rounds wrongly: the cases where relative
    rounding, the remainder and W's compensation matter."""
    weights = (10.0 ** rng.uniform(-30, 10, (runs, n))).astype(np.float32)
    weights[rng.random((runs, n)) < 0.2] = 0.0
    weights[:, rng.integers(n)] = 1e20
    weights[0] = 0.0
    if n > 2:
        weights[1, [1, n - 1]] = weights[1].max()   # a tie: the first one takes the remainder
        weights[2] = 2.0 ** -53                       # each lost in 1 + 2^-53, not in the sum,
        weights[2, :2] = 1.0, 0.5                     # which sets the width of the second bin
    return weights


@pytest.mark.parametrize("n", [1, 7, 8, 13, 1000])
def test_weight_cdfs_equal_an_independent_numpy_construction(compute, n):
    weights = contrast_weights(np.random.default_rng(n), 5, n)
    cdfs, totals, _ = build_fixed_point_cdfs(compute, compute.to_device(weights), 5, n)
    expected, expected_totals = numpy_fixed_point_cdfs(weights)
    np.testing.assert_array_equal(compute.to_host(cdfs, (5, n), np.uint64), expected)
    np.testing.assert_array_equal(compute.to_host(totals, (5,), np.float32), expected_totals)
    assert np.all(expected[:, -1] == CDF_ONE)


def test_frame_cdfs_equal_an_independent_numpy_construction(compute):
    """The frame cache's conditional (rows of Y·Ω) and marginal (row totals) CDFs, bit for bit.
    Only the green channel is lit, so Y·Ω in float32 is (0.7152·G)·Ω however the device
    contracts the luminance's multiply-adds."""
    res = 37                                          # rows of whole vector blocks and a tail
    rng = np.random.default_rng(8)
    env = np.zeros((6, res, res, 3), np.float32)
    env[..., 1] = contrast_weights(rng, 6 * res, res).reshape(6, res, res)
    env[3] = 0.0
    omega = cubemap.texel_solid_angles(res).astype(np.float32)
    weights = (np.float32(0.7152) * env[..., 1]) * omega
    conditional, row_totals = numpy_fixed_point_cdfs(weights.reshape(6 * res, res))
    marginal, face_totals = numpy_fixed_point_cdfs(row_totals.reshape(6, res))
    cache = FrameCache(compute, env)
    device_marginal, device_conditional = cache.host_cdfs()
    np.testing.assert_array_equal(device_conditional, conditional.reshape(6, res, res))
    np.testing.assert_array_equal(device_marginal, marginal)
    np.testing.assert_array_equal(cache.face_integrals, face_totals)


def test_reference_without_fp64_matches(compute, monkeypatch):
    """The compensated float path (devices without cl_khr_fp64) agrees with the double path."""
    normals = fibonacci_directions(64).reshape(8, 8, 3)
    gbuffer = GBuffer.from_pixels(normals, (0.2, 0.1, 1.0), 0.5, 0.3, 50.0)
    env = smooth_map(8)
    with_fp64 = Reference(compute, use_cache=False).image(DeviceGBuffer(compute, gbuffer),
                                                          FrameCache(compute, env))
    monkeypatch.setattr(DeviceInfo, "has_fp64", property(lambda self: False))
    single = Compute(compute.info)
    without = Reference(single, use_cache=False).image(DeviceGBuffer(single, gbuffer),
                                                       FrameCache(single, env))
    assert np.allclose(without, with_fp64, rtol=1e-3)
    furnace = GBuffer.from_pixels(normals, (0, 0, 1), 1.0, 0.0, 1.0)
    flat = Reference(single, use_cache=False).image(DeviceGBuffer(single, furnace),
                                                    FrameCache(single, np.full((6, 8, 8, 3), 0.7, np.float32)))
    assert np.abs(flat - 0.7).max() < 1e-4


def spans_around_the_plain_sum_limit(rng, n):
    """Runs of n > 16 weights: most are the largest, a power of two; a share are in (1/2, 1) with
    odd mantissas (their last bit is the exact sum's last bit); three bins are zero.  Two runs
    lie at the span within which any plain double sum of floats is exact, n · max ≤ 2^29 · min
    (framecache.cl's fast path for W), eight runs 2^4 and 2^5 times past it, where the exact sum
    needs more than 53 bits and a plain sum rounds it at several joins: about a third of such
    runs then lose their last bit (simulated in the device's order; the limit is sufficient,
    not tight, so a run just past it still sums exactly).  The compensated sum rounds once."""
    runs = []
    for past, share in [(0, 1 / 8), (0, 1 / 2)] + [(p, s) for p in (4, 5) for s in (1 / 8, 1 / 4, 1 / 2, 3 / 4)]:
        run = np.full(n, 2.0 ** (np.floor(np.log2(2.0 ** 29 / n)) - 1 + past), np.float32)
        odd = rng.choice(n, size=int(n * share), replace=False)
        run[odd] = (2 * rng.integers(2 ** 22, 2 ** 23, odd.size) + 1) * 2.0 ** -24
        run[rng.choice(n, size=3, replace=False)] = 0.0
        runs.append(run)
    return np.array(runs, np.float32)


@pytest.mark.parametrize("n", [1000, 1024])
def test_weight_cdfs_are_exact_around_the_plain_sum_limit(compute, n):
    weights = spans_around_the_plain_sum_limit(np.random.default_rng(n), n)
    runs = len(weights)
    cdfs, totals, _ = build_fixed_point_cdfs(compute, compute.to_device(weights), runs, n)
    expected, expected_totals = numpy_fixed_point_cdfs(weights)
    np.testing.assert_array_equal(compute.to_host(cdfs, (runs, n), np.uint64), expected)
    np.testing.assert_array_equal(compute.to_host(totals, (runs,), np.float32), expected_totals)


def test_opencl_shuffles_build_the_same_cdfs(compute, monkeypatch):
    """framecache.cl picks vector lanes with clang's __builtin_shufflevector, or with OpenCL's
    shuffle2 on a compiler that is not clang (a GPU's): forced here, both give the same words."""
    rng = np.random.default_rng(11)
    env = (rng.random((6, 37, 37, 3)) ** 3).astype(np.float32)
    env[1, 5, 7] = 1e6                               # a sun: the compensated sum's path
    env[3] = 0.0
    expected = FrameCache(compute, env).host_cdfs()
    plain_kernel = Compute.kernel

    def with_opencl_shuffles(self, package, filename, name, defines=None):
        if filename == "framecache.cl":
            defines = {**(defines or {}), "OPENCL_SHUFFLES": 1}
        return plain_kernel(self, package, filename, name, defines)

    monkeypatch.setattr(Compute, "kernel", with_opencl_shuffles)
    forced = FrameCache(Compute(compute.info), env).host_cdfs()
    for got, want in zip(forced, expected):
        np.testing.assert_array_equal(got, want)
