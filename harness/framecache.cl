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
 * few units per bin plus W's rounding: 1e-15 of the total with fp64, up to n·2^-24 without)
 * goes to the largest bin, so the scan ends at exactly CDF_ONE.  An all-zero run gets a uniform CDF (it is
 * never selected: its own weight is 0), and so does a run whose 1/W overflows (a denormal W in
 * float): still exactly the pdf it samples.
 * Two passes per run (one work item scans it): cdf_run_add stores each weight's float bits in
 * cdf[i] and accumulates W and the largest bin; write_cdf turns them into the widths' prefix
 * sums in place and adds the remainder (mod 2^64: it may be negative) from the largest bin on. */
typedef struct { kahan_t sum; float largest_weight; int largest; } cdf_run_t;

inline void cdf_run_add(cdf_run_t *run, __global cdf_word_t *cdf, int i, float w)
{
    cdf[i] = as_uint(w);
    kahan_add(&run->sum, w);
    if (w > run->largest_weight) { run->largest_weight = w; run->largest = i; }
}

/* Returns W. */
inline acc_t write_cdf(__global cdf_word_t *cdf, int n, const cdf_run_t *run)
{
    acc_t total = run->sum.sum, inverse = (acc_t)1 / total;   /* a product per bin, not a division */
    int uniform = !(total > 0) || isinf(inverse);
    if (uniform) inverse = (acc_t)1 / n;
    cdf_word_t running = 0;
    for (int i = 0; i < n; ++i) {
        float w = uniform ? 1.0f : as_float((uint)cdf[i]);
        running += w > 0.0f ? max((cdf_word_t)1, convert_ulong_sat((acc_t)w * inverse * (acc_t)0x1p63)) : 0;
        cdf[i] = running;
    }
    cdf_word_t remainder = CDF_ONE - running;
    for (int i = run->largest; i < n; ++i) cdf[i] += remainder;
    return total;
}

__kernel void row_cdfs(__global const float4 *env, __global const float *omega, const int res,
                       __global cdf_word_t *conditional, __global float *row_weight)
{
    int face_row = get_global_id(0);
    int row = face_row % res;
    __global cdf_word_t *cdf = conditional + face_row * res;
    cdf_run_t run = {{0, 0}, 0.0f, 0};
    for (int col = 0; col < res; ++col)
        cdf_run_add(&run, cdf, col, luminance(env[face_row * res + col].xyz) * omega[row * res + col]);
    row_weight[face_row] = (float)write_cdf(cdf, res, &run);
}

__kernel void face_cdfs(__global const float *row_weight, const int res,
                        __global cdf_word_t *marginal, __global float *face_integral)
{
    int face = get_global_id(0);
    __global cdf_word_t *cdf = marginal + face * res;
    cdf_run_t run = {{0, 0}, 0.0f, 0};
    for (int row = 0; row < res; ++row) cdf_run_add(&run, cdf, row, row_weight[face * res + row]);
    face_integral[face] = (float)write_cdf(cdf, res, &run);
}

/* The pool (Algorithm 1, line 10): `per_face` samples of each lit face f, entry f·per_face + i
 * drawn from pool point i by the face's CDFs.  Entries store (ω, pdf_L(ω|f)) and the radiance. */
__kernel void build_light_pool(__global const float4 *env, __global const cdf_word_t *marginal,
                               __global const cdf_word_t *conditional, __global const float *face_integral,
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
    float pdf = sample_face(marginal, conditional, face, res, u, &w, &texel);
    pool_dir_pdf[entry] = (float4)(w, pdf);
    pool_radiance[entry] = env[texel];
}
