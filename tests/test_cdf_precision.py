"""Issue 6 (stress case sun-1e9): the light CDFs give every lit texel its exact probability.

Float32 CDFs collapsed the bins of texels after a bright sun (probability < 6e-8 near c ≈ 1) and
a float32 variate cannot reach bins under 2^-24 anyway: pure light sampling then missed 3.6% of
∫L cos⁺ on normals that see only the dim part of the sun's face (harness/verify/cdf_precision.py).  The
fixed-point CDFs (kernels/common.cl) searched with 63-bit variates fix both.  Tolerances:

- REL_TOL = 1e-6 on P(texel|f): the device rounds Y·Ω and the row totals in float32 (a few ulps,
  2^-24 ≈ 6e-8 each), the fixed-point widths round each w_i/W relatively (1e-16 with fp64), and
  P is a product of two levels; measured ≤ 3.3e-7.  Without fp64 the rounding remainder of a run
  lands on its largest bin: up to n·2^-24 relative there (6e-5 for n = 1024), so 1e-4.
- BIAS_TOL = 1e-6: a light sampler's exact relative bias is a weighted mean of
  p_sampled/p_eval − 1, where p_eval is the float32 rounding of the exact width (≤ 2^-23 per
  texel, two levels and a product).
"""
import numpy as np
import pyopencl as cl
import pytest
from scipy import stats

from iblbench.harness.verify import cdf_precision
from iblbench.harness.verify.conformance import smooth_map
from iblbench.estimators.runtime.device import Compute, DeviceInfo, include_dirs
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.scenes import cubemap

CDF_ONE = cdf_precision.FIXED_POINT_ONE
REL_TOL = 1e-6
REL_TOL_NO_FP64 = 1e-4
BIAS_TOL = 1e-6


def exact_probabilities(env):
    """P(texel | face) = Y·Ω / I_f in float64, independent of the device and of the audit."""
    weight = cubemap.luminance(env.astype(np.float64)) * cubemap.texel_solid_angles(env.shape[1])
    return weight / weight.sum(axis=(1, 2), keepdims=True)


_built = {}


def device_cdfs(compute, name):
    key = (id(compute), name)
    if key not in _built:
        env = cdf_precision.stress_map(name)
        _built[key] = (env,) + FrameCache(compute, env).host_cdfs()
    return _built[key]


def check_probabilities(env, marginal, conditional, rel_tol):
    p_eval, p_sampled = cdf_precision.sampler_probabilities(marginal, conditional)
    exact = exact_probabilities(env)
    lit = exact > 0
    assert np.all(p_sampled[lit] > 0), f"{np.sum(p_sampled[lit] == 0)} lit texels are never drawn"
    assert np.all(p_eval[lit] > 0)
    assert np.all(p_sampled[~lit] == 0)
    for p in (p_sampled, p_eval.astype(np.float64)):
        rel = np.abs(p[lit] - exact[lit]) / exact[lit]
        assert rel.max() <= rel_tol, f"max relative error {rel.max():.3g} > {rel_tol:g}"


@pytest.mark.parametrize("name", ["sun-1e9", "huge-faces"])
def test_every_lit_texel_is_drawn_with_its_exact_probability(compute, name):
    env, marginal, conditional = device_cdfs(compute, name)
    check_probabilities(env, marginal, conditional, REL_TOL)
    assert marginal.dtype == np.uint64 and np.all(marginal[:, -1] == CDF_ONE)


@pytest.mark.parametrize("name", ["sun-1e9", "huge-faces"])
def test_without_fp64_every_lit_texel_is_still_drawn(compute, monkeypatch, name):
    """The float fallback of the build (Kahan in float) loses accuracy, never bins."""
    monkeypatch.setattr(DeviceInfo, "has_fp64", property(lambda self: False))
    env = cdf_precision.stress_map(name)
    marginal, conditional = FrameCache(Compute(compute.info), env).host_cdfs()
    check_probabilities(env, marginal, conditional, REL_TOL_NO_FP64)


@pytest.mark.parametrize("name", ["sun-1e6", "sun-1e9"])
def test_no_missed_mass_on_normals_that_see_only_the_dim_part_of_the_sun_face(compute, name):
    env, marginal, conditional = device_cdfs(compute, name)
    sun = np.unravel_index(np.argmax(cubemap.luminance(env)), env.shape[:3])
    sun_dir = cubemap.texel_directions(env.shape[1])[sun]
    figures = cdf_precision.light_sampler_figures(env, marginal, conditional)
    for normal, f in figures["normals"].items():
        n = np.asarray(cdf_precision.DIM_NORMALS[normal])
        assert n @ sun_dir < 0                         # the sun is below this normal's horizon
        assert f["missed"] == 0 and f["missed_on_face"] == 0, (normal, f)
        assert abs(f["bias"]) <= BIAS_TOL, (normal, f)
    assert figures["zero_bins"] == 0


def test_the_audit_counts_what_a_variate_reaches():
    """The audit itself, by hand: fixed-point bins are drawn with their width by 63-bit
    variates; a 24-bit variate never reaches a bin narrower than its 2^-24 grid."""
    fixed = np.array([[1, 2, CDF_ONE // 2, CDF_ONE]], np.uint64)
    p_eval, p_drawn = cdf_precision._fixed_bins(fixed)
    assert p_drawn[0, 0] == 2.0 ** -63 and p_drawn[0, 3] == 0.5
    _, p_coarse = cdf_precision._fixed_bins(fixed, variate_bits=24)
    assert p_coarse[0, 1] == 0 and p_coarse[0, 0] == 2.0 ** -24   # u = 0 lands in bin 0


DRAW_SOURCE = """
#include "common.cl"
__kernel void draw(__global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                   const int face, const int res, __global const ulong2 *u,
                   __global float4 *dir_pdf, __global int *texel)
{
    int i = get_global_id(0), t;
    float3 w;
    float pdf = sample_face(marginal, conditional, face, res, u[i], &w, &t);
    dir_pdf[i] = (float4)(w, pdf);
    texel[i] = t;
}
"""


def test_sample_face_reaches_every_texel_of_the_sun_face_continuously(compute):
    """Every bin of the sun face of sun-1e9 is reached by the variates at its ends and middle,
    with pdf P(texel|f)·(1+x²+y²)^{3/2}/a_texel; the end of one bin and the start of the next
    give the same direction (the inversion is continuous, as havran's and Lu's point sets need)."""
    env, marginal, conditional = device_cdfs(compute, "sun-1e9")
    face, res = cdf_precision.SUN_FACE, env.shape[1]
    lower_m = np.concatenate([np.zeros(1, np.uint64), marginal[face, :-1]])
    lower_c = np.concatenate([np.zeros((res, 1), np.uint64), conditional[face, :, :-1]], axis=1)
    rows, cols = np.meshgrid(np.arange(res), np.arange(res), indexing="ij")
    row_lo, row_hi = lower_m[rows], marginal[face][rows]
    col_lo, col_hi = lower_c[rows, cols], conditional[face][rows, cols]
    one, two = np.uint64(1), np.uint64(2)
    row_mid, col_mid = row_lo + (row_hi - row_lo) // two, col_lo + (col_hi - col_lo) // two
    variates = {"lo": (row_lo, col_lo), "mid": (row_mid, col_mid), "hi": (row_hi - one, col_hi - one),
                "col_start": (row_mid, col_lo), "col_end": (row_mid, col_hi - one)}
    options = [f"-I{d}" for d in include_dirs()] + (["-DHAVE_FP64=1"] if compute.info.has_fp64 else [])
    kernel = cl.Program(compute.context, DRAW_SOURCE).build(options=options).draw
    m_buf, c_buf = compute.to_device(marginal), compute.to_device(conditional)
    out = {}
    for key, (ux, uy) in variates.items():
        u = np.stack([ux.ravel(), uy.ravel()], -1).astype(np.uint64)
        dir_pdf, texel = compute.empty(u.shape[0] * 16), compute.empty(u.shape[0] * 4)
        compute.run(kernel, u.shape[0], m_buf, c_buf, np.int32(face), np.int32(res),
                    compute.to_device(u), dir_pdf, texel)
        out[key] = (compute.to_host(dir_pdf, (res, res, 4), np.float32),
                    compute.to_host(texel, (res, res), np.int32))
        expected_texel = (face * res + rows) * res + cols
        np.testing.assert_array_equal(out[key][1], expected_texel, err_msg=key)
    dirs, pdf = out["mid"][0][..., :3].astype(np.float64), out["mid"][0][..., 3]
    f, r, c = cubemap.direction_to_texel(dirs, res)
    assert np.all(f == face) and np.all(r == rows) and np.all(c == cols)
    _, s, t = cubemap.direction_to_face_st(dirs)
    jacobian = (1 + (2 * s - 1) ** 2 + (2 * t - 1) ** 2) ** 1.5
    expected_pdf = exact_probabilities(env)[face] * jacobian / (4.0 / res ** 2)
    np.testing.assert_allclose(pdf, expected_pdf, rtol=1e-5)
    end, start = out["col_end"][0][:, :-1, :3], out["col_start"][0][:, 1:, :3]   # next column
    assert np.max(np.linalg.norm(end - start, axis=-1)) < 1e-5


def test_pool_samples_follow_the_exact_texel_probabilities(compute):
    """χ² of the pool's draws (pool_point → sample_face on the device) per face against the
    float64 texel probabilities, on a moderate-contrast sun map; and each stored pdf is exact."""
    res, per_face = 16, 1 << 16
    env = smooth_map(res)
    env[4, res // 2, res // 2] = 100 * env.max()       # about half the +Z face's power
    cache = FrameCache(compute, env)
    pool = cache.light_pool(per_face, seed=3)
    dir_pdf = compute.to_host(pool.dir_pdf, (6, per_face, 4), np.float32).astype(np.float64)
    exact = exact_probabilities(env)
    p_values = []
    for face in range(6):
        f, r, c = cubemap.direction_to_texel(dir_pdf[face, :, :3], res)
        _, s, t = cubemap.direction_to_face_st(dir_pdf[face, :, :3])
        assert np.all(f == face)
        # A float32 direction within rounding of a texel edge may look up the neighbour.
        inside = np.minimum(np.abs(s * res - np.round(s * res)), np.abs(t * res - np.round(t * res))) > 1e-4
        assert inside.mean() > 0.99
        counts = np.bincount(r * res + c, minlength=res * res)
        expected = exact[face].ravel() * per_face
        order = np.argsort(expected)                  # pool cells of expectation < 5
        merged_obs, merged_exp, acc_o, acc_e = [], [], 0.0, 0.0
        for k in order:
            acc_o, acc_e = acc_o + counts[k], acc_e + expected[k]
            if acc_e >= 5:
                merged_obs.append(acc_o), merged_exp.append(acc_e)
                acc_o = acc_e = 0.0
        merged_obs[-1] += acc_o
        merged_exp[-1] += acc_e
        p_values.append(stats.chisquare(merged_obs, merged_exp).pvalue)
        jacobian = (1 + (2 * s - 1) ** 2 + (2 * t - 1) ** 2) ** 1.5
        expected_pdf = exact[face][r, c] * jacobian / (4.0 / res ** 2)
        np.testing.assert_allclose(dir_pdf[face, inside, 3], expected_pdf[inside], rtol=1e-5)
    assert min(p_values) > 1 - (1 - 1e-3) ** (1 / 6), p_values   # Šidák over the six faces
