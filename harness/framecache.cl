/* Per-face luminance CDFs (Lu 2013 Algorithm 1, lines 6-9) and the light-sample pool (line 10)
 * on the device.
 * Weights are Y·Ω per texel so that pdf_L(ω|f) ≈ Y(ω)/I_f; I_f = Σ Y·Ω is the face's luminance
 * integral of Lu Eq. 3.  Rows are scanned in parallel, one work item per (face, row), each
 * eight bins per vector step. */
#include "light_pool.cl"

/* The fixed-point CDFs of common.cl.  A run of n weights w_i ≥ 0 (a row's Y·Ω, or a face's row
 * totals) with total W = Σ w (compensated, double where the device has it) gets integer widths
 *     q_i = max(1, ⌊2^63 · w_i / W⌋) for w_i > 0,  q_i = 0 for w_i = 0,
 * each rounded relatively (w_i · (1/W) in acc_t), so every positive weight keeps a positive and
 * relatively exact probability however bright the rest of its run.  The remainder 2^63 − Σ q (a
 * few units per bin plus W's rounding: 1e-15 of the total with fp64, about 2^-24 without) goes
 * to the largest bin (the first of equal ones) and every bin after it, so the scan ends at
 * exactly CDF_ONE.  An all-zero run gets a uniform CDF (it is never selected: its own weight is
 * 0), and so does a run whose 1/W overflows (a denormal W in float): still exactly the pdf it
 * samples.
 *
 * One work item builds one run, LANES bins per step in explicit vectors (so the steps vectorise
 * whatever PoCL does with the work-item loop), in three passes over the run, which stays in cache:
 * (1) W, as LANES partial sums compensated by two-sums (their errors summed aside) and joined by
 *     two-sums: the exactly rounded sum unless that lies within ~n·2^-106 of a rounding midpoint
 *     (n·2^-48 in float; the serial Kahan sum before could be an ulp off; wherever the double
 *     sum is exact the two agree bit for bit); the first largest bin; each weight's bits stored
 *     in its cdf word;
 * (2) the widths from those bits, stored in place, and Σ q;
 * (3) the remainder joins the largest bin's width, and a running sum turns the widths into the
 *     CDF in place: a scalar chain of one add per bin (a log-step scan inside the vector
 *     compiled to slow lane expansions on PoCL's AVX-512 target). */
#define LANES 8
typedef ulong8 cdf_word8_t;
typedef ulong4 cdf_word4_t;

/* a + b = *sum + error exactly (Knuth's two-sum); returns the error.  Lane-wise and scalar. */
__attribute__((always_inline)) inline acc8_t two_sum8(acc8_t a, acc8_t b, acc8_t *sum)
{
    acc8_t s = a + b, b_part = s - a;
    *sum = s;
    return (a - (s - b_part)) + (b - b_part);
}

__attribute__((always_inline)) inline acc_t two_sum(acc_t a, acc_t b, acc_t *sum)
{
    acc_t s = a + b, b_part = s - a;
    *sum = s;
    return (a - (s - b_part)) + (b - b_part);
}

/* A run's weights: Y·Ω of `count` texels (env_row and omega_row), or stored weights. */
typedef struct {
    __global const float4 *env_row;
    __global const float *omega_row;
    __global const float *weight;
    int count;
} run_t;

/* Loops over the blocks of LANES bins of a run of n bins from bin `first` (a block start):
 * `body` sees the block's start i and full = 1 for whole blocks, full = 0 for a last, partial
 * one, a constant in each copy so that whole blocks compile to plain vector loads and stores. */
#define FOR_EACH_BLOCK(first, n, body) \
    for (int i = (first); i + LANES <= (n); i += LANES) { const int full = 1; body } \
    if ((n) % LANES) { const int i = (n) - (n) % LANES, full = 0; body }

/* The luminance of four float4 texels, each texel's in its four lanes: the channels spread by
 * in-lane shuffles, bit for bit the same sum (a gather of channel planes across two vectors
 * compiled to sixteen 8-byte loads and lane inserts on PoCL's AVX-512 target: 60 instructions
 * per block of the first pass against 47). */
__attribute__((always_inline)) inline float16 luminance_of_four(float16 texels)
{
    return 0.2126f * texels.s000044448888cccc + 0.7152f * texels.s111155559999dddd
         + 0.0722f * texels.s22226666aaaaeeee;
}

/* Weights of bins i … i + LANES − 1 of the run; 0 past its end. */
__attribute__((always_inline)) inline float8 run_weights(const run_t *run, int i, int full)
{
    if (full) {
        if (!run->env_row) return vload8(0, run->weight + i);
        /* Eight float4 texels as two float16; one lane of each texel's luminance. */
        float16 first = luminance_of_four(vload16(0, (__global const float *)(run->env_row + i)));
        float16 second = luminance_of_four(vload16(0, (__global const float *)(run->env_row + i + 4)));
        return (float8)(first.s048c, second.s048c) * vload8(0, run->omega_row + i);
    }
    float w[LANES];
    for (int k = 0; k < LANES; ++k) {
        int j = min(i + k, run->count - 1);
        float wk = run->env_row ? luminance(run->env_row[j].xyz) * run->omega_row[j] : run->weight[j];
        w[k] = i + k < run->count ? wk : 0.0f;
    }
    return vload8(0, w);
}

/* cdf[i … i + LANES) = v, as far as the run's n bins go. */
__attribute__((always_inline)) inline void store_words(__global cdf_word_t *cdf, int i, int n, int full,
                                                       cdf_word8_t v)
{
    if (full) vstore8(v, 0, cdf + i);
    else for (int k = 0; i + k < n; ++k) cdf[i + k] = ((cdf_word_t *)&v)[k];
}

/* cdf[i … i + LANES), 0 past the run's n bins. */
__attribute__((always_inline)) inline cdf_word8_t load_words(__global const cdf_word_t *cdf, int i, int n,
                                                             int full)
{
    if (full) return vload8(0, cdf + i);
    cdf_word_t v[LANES];
    for (int k = 0; k < LANES; ++k) v[k] = i + k < n ? cdf[i + k] : 0;
    return vload8(0, v);
}

__attribute__((always_inline)) inline cdf_word_t sum_lanes(cdf_word8_t v)
{
    cdf_word4_t quarter = v.lo + v.hi;
    return quarter.x + quarter.y + quarter.z + quarter.w;
}

/* The fixed-point CDF of `run` into cdf[0 … count); returns W. */
__attribute__((always_inline)) inline acc_t write_cdf(__global cdf_word_t *cdf, const run_t *run)
{
    int n = run->count;
    const int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    acc8_t sum = 0, error = 0;
    float8 largest_weight = 0.0f;
    int8 largest = 0;
    FOR_EACH_BLOCK(0, n, {
        float8 w = run_weights(run, i, full);
        store_words(cdf, i, n, full, convert_ulong8(as_uint8(w)));   /* the weights' bits, for pass 2 */
        error += two_sum8(sum, convert_acc8(w), &sum);
        int8 larger = w > largest_weight;
        largest_weight = select(largest_weight, w, larger);
        largest = select(largest, i + lane, larger);
    })
    /* Join the lanes: W, and the first bin of the largest weight. */
    acc_t total = 0, total_error = 0;
    float top = 0.0f;
    int top_bin = 0;
    for (int k = 0; k < LANES; ++k) {
        total_error += two_sum(total, ((acc_t *)&sum)[k], &total) + ((acc_t *)&error)[k];
        float w = ((float *)&largest_weight)[k];
        int bin = ((int *)&largest)[k];
        if (w > top || (w == top && bin < top_bin)) { top = w; top_bin = bin; }
    }
    total += total_error;
    acc_t inverse = (acc_t)1 / total;   /* a product per bin, not a division */
    int uniform = !(total > 0) || isinf(inverse);
    if (uniform) inverse = (acc_t)1 / n;
    cdf_word8_t width_sum = 0;
    FOR_EACH_BLOCK(0, n, {
        float8 w = uniform ? select((float8)0.0f, (float8)1.0f, i + lane < n)
                           : as_float8(convert_uint8(load_words(cdf, i, n, full)));
        acc8_t scaled = convert_acc8(w) * inverse * (acc_t)0x1p63;
        /* min: w ≤ W up to rounding, so only the largest bin can exceed 2^63, and its width
         * cancels out of the CDF (entry i ≥ largest is 2^63 − Σ_{j>i} q_j). */
        cdf_word8_t width = select(max((cdf_word8_t)1, convert_ulong8(min(scaled, (acc8_t)0x1p63))),
                                   (cdf_word8_t)0, convert_long8(w > 0.0f) == 0);
        store_words(cdf, i, n, full, width);
        width_sum += width;
    })
    /* The remainder joins the largest bin's width, so the prefix sums end at CDF_ONE. */
    cdf[top_bin] += CDF_ONE - sum_lanes(width_sum);
    cdf_word_t running = 0;
    for (int i = 0; i < n; ++i) {
        running += cdf[i];
        cdf[i] = running;
    }
    return total;
}

/* One work item per (face, row): the conditional CDF of the row's Y·Ω, and its total. */
__kernel void row_cdfs(__global const float4 *env, __global const float *omega, const int res,
                       __global cdf_word_t *conditional, __global float *row_weight)
{
    int face_row = get_global_id(0), row = face_row % res;
    run_t run = {env + (size_t)face_row * res, omega + (size_t)row * res, 0, res};
    row_weight[face_row] = (float)write_cdf(conditional + (size_t)face_row * res, &run);
}

/* One work item per run of `n` weights (runs × n, run-major): its fixed-point CDF and total W
 * (float).  The faces' marginal CDFs over their row totals, and any other sampler's. */
__kernel void weight_cdfs(__global const float *weight, const int n, __global cdf_word_t *cdfs,
                          __global float *totals)
{
    int r = get_global_id(0);
    run_t run = {0, 0, weight + (size_t)r * n, n};
    totals[r] = (float)write_cdf(cdfs + (size_t)r * n, &run);
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

/* Sampling weights of the production light samplers (estimators/envmap.py, and `balanced_mis` with
 * MIS compensation), one work item per (face, row) of the map: the row's total weight, and with
 * `store_texels` each texel's weight in `texels` (the uncompensated CDFs need only the rows':
 * their conditionals are row_cdfs'; the weight pyramids of harness/mips.py need every texel's).
 * `face_integral` is read only with `compensate`.  A texel's weight is Y·Ω, or with MIS
 * compensation max(Y − Ȳ, min(Ȳ/1000, Y))·Ω (pbrt-v4's ImageInfiniteLight, see
 * FrameCache.light_cdfs), where Ȳ = Σ_f I_f / 4π is the map's mean luminance over the sphere. */
__kernel void sampling_weights(__global const float4 *env, __global const float *omega,
                               __global const float *face_integral, const int res, const int compensate,
                               const int store_texels, __global float *texels, __global float *row_weight)
{
    int face_row = get_global_id(0), row = face_row % res;
    acc_t integral = 0;
    for (int f = 0; compensate && f < 6; ++f) integral += face_integral[f];
    float mean = (float)integral / (4.0f * IBL_PI);
    float least = 0.001f * mean;
    acc_t sum = 0;
    for (int col = 0; col < res; ++col) {
        int texel = face_row * res + col;
        float y = vec3_luminance(vec3_load(env, texel));
        float weight = (compensate ? max(y - mean, min(least, y)) : y) * omega[row * res + col];
        if (store_texels) texels[texel] = weight;
        sum += weight;
    }
    row_weight[face_row] = (float)sum;
}
