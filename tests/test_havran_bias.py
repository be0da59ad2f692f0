"""``havran``'s bias bound (estimators/havran.py, "Bias bound") and the map pdf on a sharp map.

The map's density and cell probabilities come from their definition (``stress.havran_map_density``
and ``havran_cell_probabilities``, which the stress battery also checks the map with), not from
``EqualAreaMap.sample``, and the variance V of one light is integrated by quadrature, so a pdf
that disagrees with the sampler, or a bias that does not shrink with K, fails.
"""
import numpy as np
import pytest
from scipy import stats

from iblbench.estimators.havran import EqualAreaMap, Havran, equal_area_to_direction, frame_map
from iblbench.harness.verify.conformance import Harness, glossy_gbuffer, sidak_z, sun_map
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.harness.verify.stress import havran_map_chi2, havran_map_density

K_LARGE = 4096
SEEDS = 16
QUADRATURE = 4          # quadrature points per grid cell and axis for V
FLOAT_SHADING = 2.0 ** -24


@pytest.fixture(scope="module")
def h(compute):
    return Harness(compute)


def sharp_map(res: int = 16) -> np.ndarray:
    """A 1e6 sun, hot texels on a face edge and corner, and two black faces: steps everywhere."""
    env = sun_map(res, 1e6)
    env[0, 0, res - 1] = env[2, res // 2, 0] = 1e3 * env[0].max()
    env[[1, 3]] = 0.0
    return env


def test_map_pdf_on_a_sharp_map(compute):
    """The pdf ``sample`` returns is the map's density at its samples, and 2·10^5 samples fall in
    the grid cells as the closed-form cell probabilities say (χ², α = 1e-3)."""
    env = sharp_map()
    envmap = EqualAreaMap.of_device_map(frame_map(FrameCache(compute, env)), env)
    p_value, problems = havran_map_chi2(envmap, 200_000, seed=3)
    assert not problems, problems
    assert p_value > 1e-3, f"χ² rejects the map's sampler on a sharp map: p = {p_value:.2e}"


def one_light_variance(envmap, gbuffer) -> tuple[np.ndarray, np.ndarray]:
    """(I, V) per channel of the image sum F(ω) = Σ_pixels L(ω) ρ(ω) cos⁺: I = ∫F dω and the
    variance of one light V = ∫F²/p dω − I², by the midpoint rule on QUADRATURE² points per
    grid cell of the equal-area square (dω = 4π dx dy)."""
    nz, nphi = envmap.nz, envmap.nphi
    x = (np.arange(nphi * QUADRATURE) + 0.5) / (nphi * QUADRATURE)
    y = (np.arange(nz * QUADRATURE) + 0.5) / (nz * QUADRATURE)
    x, y = (a.reshape(-1) for a in np.meshgrid(x, y))
    w = equal_area_to_direction(x, y)
    p = havran_map_density(envmap, x, y)
    radiance = envmap.radiance(w)
    mask = gbuffer.mask
    normal, view = gbuffer.normal[mask], gbuffer.view[mask]
    mirror = 2 * np.sum(normal * view, -1, keepdims=True) * normal - view
    F = np.zeros((len(w), 3))
    for n, r, kd, ks, m in zip(normal, mirror, gbuffer.kd[mask], gbuffer.ks[mask], gbuffer.shininess[mask]):
        lobe = np.maximum(w @ r, 0.0)[:, None] ** m
        F += radiance * (kd / np.pi + ks * (m + 2) / (2 * np.pi) * lobe) * np.maximum(w @ n, 0.0)[:, None]
    d_omega = 4 * np.pi / len(w)
    integral = F.sum(0) * d_omega
    return integral, (F * F / p[:, None]).sum(0) * d_omega - integral ** 2


def test_bias_shrinks_with_k_to_the_reference_on_a_static_sun_map(h):
    """K = 4096 lights on a static 1e3 sun map, 16 seeds: the image sum's relative error per
    seed is the sequence bias of that seed.  Its mean over seeds is within the bound's
    z_Šidák(3 channels, α = 1e-3)·√(V/(K·S))/I + (K + 8)·2^-24 (float32 shading), and its RMS over
    seeds within √(V/K)/I times the χ²(S − 1) upper 1e-3 quantile's √(q/(S − 1)) (the bound's
    assumption, that the relaxed set does no worse than independent lights)."""
    gb = glossy_gbuffer()
    env = sun_map(16, 1e3)
    gbuffer, cache = h.inputs(gb, env)
    reference = h.reference(gbuffer, cache)[gb.mask].astype(np.float64).sum(0)
    integral, variance = one_light_variance(EqualAreaMap.of_device_map(frame_map(cache), env), gb)
    np.testing.assert_allclose(integral, reference, rtol=5e-3)   # the quadrature sees the map
    estimator = Havran()
    sums = np.array([h.render(estimator, gbuffer, cache, K_LARGE, seed).radiance[gb.mask].sum(0)
                     for seed in range(SEEDS)], np.float64)
    errors = sums / reference - 1.0
    sequence_bias = np.sqrt(variance / K_LARGE) / reference          # the bound, per channel
    tolerance = sidak_z(3) * sequence_bias / np.sqrt(SEEDS) + (K_LARGE + 8) * FLOAT_SHADING
    assert np.all(np.abs(errors.mean(0)) <= tolerance), \
        f"mean relative error over seeds {errors.mean(0)} beyond the bound's {tolerance}"
    spread = np.sqrt(stats.chi2.isf(1e-3, SEEDS - 1) / (SEEDS - 1))
    assert np.all(np.sqrt(np.mean(errors ** 2, 0)) <= spread * sequence_bias), \
        f"RMS error over seeds {np.sqrt(np.mean(errors ** 2, 0))} beyond the bound {spread * sequence_bias}"
