"""Device CDFs and face integrals against NumPy; the reference without fp64."""
import numpy as np
import pytest

from iblbench.harness.conformance import fibonacci_directions, smooth_map
from iblbench.harness.device import Compute, DeviceInfo
from iblbench.harness.device_gbuffer import DeviceGBuffer
from iblbench.harness.framecache import CDF_ONE, FrameCache
from iblbench.harness.reference import Reference
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
