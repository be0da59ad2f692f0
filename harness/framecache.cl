/* Per-face luminance CDFs (Lu 2013 Algorithm 1, lines 6-9) and the light-sample pool (line 10)
 * on the device.
 * Weights are Y·Ω per texel so that pdf_L(ω|f) ≈ Y(ω)/I_f; I_f = Σ Y·Ω is the face's luminance
 * integral of Lu Eq. 3.  Rows are scanned in parallel, one work item per (face, row). */
#include "light_pool.cl"

/* Inclusive scan of w[0..n) in place-normalised to a CDF ending at exactly 1; returns the total.
 * An all-zero run gets a uniform CDF (it is never selected: its own weight is 0). */
inline acc_t write_cdf(__global float *cdf, int n)
{
    kahan_t k = {0, 0};
    for (int i = 0; i < n; ++i) { kahan_add(&k, cdf[i]); cdf[i] = (float)k.sum; }
    acc_t total = k.sum;
    for (int i = 0; i < n; ++i)
        cdf[i] = total > 0 ? (float)(cdf[i] / total) : (float)(i + 1) / n;
    cdf[n - 1] = 1.0f;
    return total;
}

__kernel void row_cdfs(__global const float4 *env, __global const float *omega, const int res,
                       __global float *conditional, __global float *row_weight)
{
    int face_row = get_global_id(0);
    int row = face_row % res;
    __global float *cdf = conditional + face_row * res;
    for (int col = 0; col < res; ++col)
        cdf[col] = luminance(env[face_row * res + col].xyz) * omega[row * res + col];
    row_weight[face_row] = (float)write_cdf(cdf, res);
}

__kernel void face_cdfs(__global const float *row_weight, const int res,
                        __global float *marginal, __global float *face_integral)
{
    int face = get_global_id(0);
    __global float *cdf = marginal + face * res;
    for (int row = 0; row < res; ++row) cdf[row] = row_weight[face * res + row];
    face_integral[face] = (float)write_cdf(cdf, res);
}

/* The pool (Algorithm 1, line 10): `per_face` samples of each lit face f, entry f·per_face + i
 * drawn from pool point i by the face's CDFs.  Entries store (ω, pdf_L(ω|f)) and the radiance. */
__kernel void build_light_pool(__global const float4 *env, __global const float *marginal,
                               __global const float *conditional, __global const float *face_integral,
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
    float2 u = pool_point(face, entry % per_face, seed, frame);
    float pdf = sample_face(marginal, conditional, face, res, u, &w, &texel);
    pool_dir_pdf[entry] = (float4)(w, pdf);
    pool_radiance[entry] = env[texel];
}
