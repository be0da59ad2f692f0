/* Per-face luminance CDFs (Lu 2013 Algorithm 1, lines 6-9) and the light-sample pool (line 10)
 * on the device.
 * Weights are Y·Ω per texel so that pdf_L(ω|f) ≈ Y(ω)/I_f; I_f = Σ Y·Ω is the face's luminance
 * integral of Lu Eq. 3.  Rows are scanned in parallel, one work item per (face, row). */
#include "light_pool.cl"

/* The fixed-point CDFs of common.cl.  A run of n weights w_i ≥ 0 (a row's Y·Ω, or a face's row
 * totals) with total W = Σ w (Kahan, double where the device has it) gets integer widths
 *     q_i = max(1, ⌊2^63 · w_i / W⌋) for w_i > 0,  q_i = 0 for w_i = 0,
 * each rounded relatively (w_i · (1/W) in acc_t), so every positive weight keeps a positive and
 * relatively exact probability however bright the rest of its run.  The remainder 2^63 − Σ q (a
 * few units per bin plus W's rounding: relative 1e-15, or about n·1e-7 without fp64) goes to the
 * largest bin, so the scan ends at exactly CDF_ONE.  An all-zero run gets a uniform CDF (it is
 * never selected: its own weight is 0), and so does a run whose 1/W overflows (a denormal W in
 * float): still exactly the pdf it samples.
 * On entry cdf[i] holds w_i's float bits (as_uint); three passes: W and the largest bin, the
 * widths' prefix sums in place, the remainder (mod 2^64: it may be negative) from the largest
 * bin on.  Returns W. */
inline acc_t write_cdf(__global cdf_word_t *cdf, int n)
{
    kahan_t k = {0, 0};
    int largest = 0;
    float max_weight = 0.0f;
    for (int i = 0; i < n; ++i) {
        float w = as_float((uint)cdf[i]);
        kahan_add(&k, w);
        if (w > max_weight) { max_weight = w; largest = i; }
    }
    acc_t total = k.sum, inverse = (acc_t)1 / total;   /* a product per bin, not a division */
    int uniform = !(total > 0) || isinf(inverse);
    if (uniform) inverse = (acc_t)1 / n;
    cdf_word_t running = 0;
    for (int i = 0; i < n; ++i) {
        float w = uniform ? 1.0f : as_float((uint)cdf[i]);
        running += w > 0.0f ? max((cdf_word_t)1, convert_ulong_sat((acc_t)w * inverse * (acc_t)0x1p63)) : 0;
        cdf[i] = running;
    }
    cdf_word_t remainder = CDF_ONE - cdf[n - 1];
    for (int i = largest; i < n; ++i) cdf[i] += remainder;
    return total;
}

__kernel void row_cdfs(__global const float4 *env, __global const float *omega, const int res,
                       __global cdf_word_t *conditional, __global float *row_weight)
{
    int face_row = get_global_id(0);
    int row = face_row % res;
    __global cdf_word_t *cdf = conditional + face_row * res;
    for (int col = 0; col < res; ++col)
        cdf[col] = as_uint(luminance(env[face_row * res + col].xyz) * omega[row * res + col]);
    row_weight[face_row] = (float)write_cdf(cdf, res);
}

__kernel void face_cdfs(__global const float *row_weight, const int res,
                        __global cdf_word_t *marginal, __global float *face_integral)
{
    int face = get_global_id(0);
    __global cdf_word_t *cdf = marginal + face * res;
    for (int row = 0; row < res; ++row) cdf[row] = as_uint(row_weight[face * res + row]);
    face_integral[face] = (float)write_cdf(cdf, res);
}

/* The pool (Algorithm 1, line 10): `per_face` samples of each lit face f, entry f·per_face + i
 * drawn from pool point i by the face's CDFs.  Entries store (ω, pdf_L(ω|f)) and the radiance. */
__kernel void build_light_pool(__global const float4 *env, __global const cdf_buffer_t *marginal,
                               __global const cdf_buffer_t *conditional, __global const float *face_integral,
                               const int res, const int per_face, const uint seed, const uint frame,
                               __global float4 *pool_dir_pdf, __global float4 *pool_radiance)
{
    int entry = get_global_id(0);
    int face = entry / per_face;
    if (!(face_integral[face] > 0.0f)) {   /* never read: black faces get no samples */
        pool_dir_pdf[entry] = (float4)(0.0f);
        pool_radiance[entry] = (float4)(0.0f);
        return;
    }
    float3 w;
    int texel;
    ulong2 u = pool_point(face, entry % per_face, seed, frame);
    float pdf = sample_face_fixed(marginal, conditional, face, res, u, &w, &texel);
    pool_dir_pdf[entry] = (float4)(w, pdf);
    pool_radiance[entry] = env[texel];
}
