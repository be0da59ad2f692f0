"""The frame cache's mip products (estimators/runtime/mips.py) against a NumPy twin of the 2×2 reduction."""
import numpy as np
import pytest

from iblbench.estimators.runtime import mips
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.scenes import cubemap


def numpy_chain(level0, average):
    """Levels of ⌈n/2⌉ from ``level0`` [6, n, n, c]: each parent the sum (or mean) of the 2×2
    children that exist, in float64."""
    levels = [np.asarray(level0, np.float64)]
    while levels[-1].shape[1] > 1:
        child = levels[-1]
        n = child.shape[1]
        m = (n + 1) // 2
        padded = np.zeros((6, 2 * m, 2 * m, child.shape[3]))
        exists = np.zeros((6, 2 * m, 2 * m, 1))
        padded[:, :n, :n] = child
        exists[:, :n, :n] = 1.0
        blocks = padded.reshape(6, m, 2, m, 2, -1).sum(axis=(2, 4))
        counts = exists.reshape(6, m, 2, m, 2, 1).sum(axis=(2, 4))
        levels.append(blocks / counts if average else blocks)
    return levels


def test_layout():
    assert mips.level_sizes(1) == (1,)
    assert mips.level_sizes(8) == (8, 4, 2, 1)
    assert mips.level_sizes(5) == (5, 3, 2, 1)
    assert mips.level_offsets(5, 1) == (0, 150, 204, 228, 234)
    assert mips.level_offsets(2, 4) == (0, 96, 120)


def sun_map(res, seed=3):
    rng = np.random.default_rng(seed)
    env = (rng.random((6, res, res, 3)) ** 4).astype(np.float32)
    env[1] = 0.0                        # a black face
    env[0, 0, res - 1] = 1e6            # a 1e6:1 sun in a corner (the last parent when res is odd)
    return env


@pytest.mark.parametrize("res", [1, 5, 8, 12, 64])
def test_weight_pyramid_matches_numpy(compute, res):
    env = sun_map(res)
    cache = FrameCache(compute, env)
    pyramid = cache.weight_pyramid()
    assert "cdf" not in cache.built and "weight_pyramid" in cache.built
    assert pyramid.sizes == mips.level_sizes(res) and pyramid.channels == 1
    weights = cubemap.luminance(env.astype(np.float64)) * cubemap.texel_solid_angles(res)
    expected = numpy_chain(weights[..., None], average=False)
    got = pyramid.host_levels(compute)
    assert len(got) == len(expected)
    for level, (g, e) in enumerate(zip(got, expected)):
        assert np.allclose(g, e, rtol=2e-6, atol=0), f"level {level}"
    assert np.allclose(got[-1].ravel(), cubemap.face_luminance_integrals(env), rtol=1e-5)
    assert got[-1][1].item() == 0.0 and np.all(got[-1][[0, 2, 3, 4, 5]] > 0)
    assert cache.timings_ms["weight_pyramid"] > 0
    # face_totals reads the 1×1 level alone: the faces' integrals, in face order
    assert np.allclose(pyramid.face_totals(compute).ravel(), cubemap.face_luminance_integrals(env), rtol=1e-5)


@pytest.mark.parametrize("res", [5, 16])
def test_compensated_pyramid_matches_numpy(compute, res):
    """pbrt-v4's compensated weights max(Y − Ȳ, min(Ȳ/1000, Y))·Ω with Ȳ = Σ I_f / 4π, summed."""
    env = sun_map(res)
    env[3] = 0.02                       # a dim constant face, below the mean: min(Ȳ/1000, Y)
    cache = FrameCache(compute, env)
    pyramid = cache.weight_pyramid(compensated=True)
    assert "cdf" not in cache.built
    y = cubemap.luminance(env.astype(np.float64))
    omega = cubemap.texel_solid_angles(res)
    mean = (y * omega).sum() / (4 * np.pi)
    weights = np.maximum(y - mean, np.minimum(mean / 1000, y)) * omega
    for level, (g, e) in enumerate(zip(pyramid.host_levels(compute), numpy_chain(weights[..., None], False))):
        assert np.allclose(g, e, rtol=1e-5, atol=0), f"level {level}"
    assert cache.timings_ms["compensated_weight_pyramid"] == pyramid.build_ms > 0


@pytest.mark.parametrize("res", [1, 5, 8, 12])
def test_radiance_mips_match_numpy(compute, res):
    env = sun_map(res)
    cache = FrameCache(compute, env)
    cache.require(["radiance_mips"])
    assert cache.built == ["env", "radiance_mips"]
    chain = cache.radiance_mips()
    assert chain.channels == 4 and chain.sizes == mips.level_sizes(res)
    got = chain.host_levels(compute)
    assert np.array_equal(got[0][..., :3], env) and np.all(got[0][..., 3] == 0)
    for level, (g, e) in enumerate(zip(got, numpy_chain(env, average=True))):
        assert np.allclose(g[..., :3], e, rtol=2e-6, atol=0), f"level {level}"
        assert np.all(g[..., 3] == 0)
    if res & (res - 1) == 0:   # equal boxes: the 1×1 level is each face's mean
        assert np.allclose(got[-1][..., :3].reshape(6, 3), env.reshape(6, -1, 3).mean(axis=1), rtol=1e-5)


def test_black_map_pyramids(compute):
    """All-zero weights: zero pyramids, no NaN (the compensated Ȳ is 0)."""
    cache = FrameCache(compute, np.zeros((6, 4, 4, 3), np.float32))
    for compensated in (False, True):
        levels = cache.weight_pyramid(compensated).host_levels(compute)
        assert all(np.all(level == 0) for level in levels)
