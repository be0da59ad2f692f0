/* Per-face luminance CDFs (Lu 2013 Algorithm 1, lines 6-9) and the light-sample pool (line 10)
 * on the device.
 * Weights are Y·Ω per texel so that pdf_L(ω|f) ≈ Y(ω)/I_f; I_f = Σ Y·Ω is the face's luminance
 * integral of Lu Eq. 3.  Rows are scanned in parallel, one work item per (face, row), each in
 * vector steps of sixteen weights and eight CDF words. */
#include "light_pool.cl"
#include "descent_choice.cl"

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
 * One work item builds one run in explicit vectors (so the steps vectorise whatever PoCL does
 * with the work-item loop), in three passes; only the first reads the map, the others work on
 * the run's words, which stay in cache:
 * (1) each weight (sixteen per step), kept as a float in the run's words (run_weights_kept);
 *     the first largest bin; W as a plain sum, exact when n · max w ≤ 2^(p−24) · min w>0
 *     (p = acc_t's precision: every weight is a multiple of the least one's ulp, so every
 *     partial sum, in any order, then fits p bits; 2^29 in double, a span up to 5e5 : 1 in a
 *     row of 1024).  Otherwise (a sun in the run) W is summed again from the kept weights as
 *     LANES partial sums compensated by two-sums (their errors summed aside) and joined by
 *     two-sums: the exactly rounded sum unless that lies within ~n·2^-106 of a rounding
 *     midpoint (n·2^-48 in float).  Both give the exact sum wherever it is representable, so
 *     the fast path changes no word;
 * (2) the widths from those weights, their inclusive prefix sums (a log-step scan in each block
 *     of LANES, chained by the block totals), stored in place; on a CPU it prefetches the
 *     next run's texels, solid angles and words meanwhile, so the memory works while the
 *     cached passes compute;
 * (3) the remainder 2^63 − Σ q joins every entry from the largest bin on.
 * Integer words are exact in any order, so the CDF is bit for bit that of the serial
 * construction (widths, remainder at the largest bin, running sum). */
#define LANES 8        /* words per step: a ulong8 (one AVX-512 register) */
#define WIDE_LANES 16  /* weights per step of pass (1) */
typedef ulong8 cdf_word8_t;

#ifdef HAVE_FP64
#define EXACT_SUM_SPAN 0x1p29   /* 2^(53 − 24): double sums of floats within this span are exact */
#else
#define EXACT_SUM_SPAN 1.0f
#endif

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

/* A run's weights: Y·Ω of `count` texels (env_row and omega_row), or stored weights.  A run of
 * texels names the texels and solid angles of the run its work item builds next (next_env_row,
 * next_omega_row), which pass (2) prefetches. */
typedef struct {
    __global const float4 *env_row;
    __global const float *omega_row;
    __global const float *weight;
    int count;
    __global const float4 *next_env_row;
    __global const float *next_omega_row;
} run_t;

/* A hint that memory is about to be read (for_write = 0) or written (1): a prefetch instruction on
 * a CPU, where PoCL's prefetch() is a no-op and a run's passes (2) and (3), in cache, would
 * otherwise leave the memory idle; nothing on other devices. */
#if defined(__x86_64__) || defined(__aarch64__)
#define PREFETCH(address, for_write) __builtin_prefetch((address), (for_write))
#else
#define PREFETCH(address, for_write)
#endif

/* Loops over the blocks of `size` bins of a run of n bins from bin `first` (a block start, or
 * n): `body` sees the block's start i and full = 1 for whole blocks, full = 0 for a last,
 * partial one, a constant in each copy so that whole blocks compile to plain vector loads and
 * stores. */
#define FOR_EACH_BLOCK(first, n, size, body) { \
    int block_ = (first); \
    for (; block_ + (size) <= (n); block_ += (size)) { const int i = block_, full = 1; body } \
    if (block_ < (n)) { const int i = block_, full = 0; body } }

/* Lanes of two vectors picked by constant indices into their concatenation: clang's
 * __builtin_shufflevector where the compiler is clang (PoCL: one instruction), OpenCL's shuffle2
 * elsewhere, with the same lanes (a GPU compiler need not be clang; OPENCL_SHUFFLES forces this
 * path, which tests/test_framecache.py checks bit for bit against the other). */
#if defined(__clang__) && !defined(OPENCL_SHUFFLES)
#define PICK(a, b, mask_t, ...) __builtin_shufflevector((a), (b), __VA_ARGS__)
#else
#define PICK(a, b, mask_t, ...) shuffle2((a), (b), (mask_t)(__VA_ARGS__))
#endif

/* The luminance of sixteen float4 texels given as their (x, y) and (z, w) pairs, bit for bit
 * luminance()'s sum, with every lane of the arithmetic a texel: the pairs are gathered as 64-bit
 * lanes, then split into channel planes.  Shuffling whole pairs keeps the loads whole: a float
 * shuffle that drops w lets LLVM narrow each load to 8-byte pieces (32 loads and lane inserts
 * per block), and OpenCL's .even/.odd swizzles split each load in two. */
__attribute__((always_inline)) inline float16 luminance_of_sixteen(ulong8 a, ulong8 b, ulong8 c, ulong8 d)
{
    float16 xy_ab = as_float16(PICK(a, b, ulong8, 0, 2, 4, 6, 8, 10, 12, 14));
    float16 xy_cd = as_float16(PICK(c, d, ulong8, 0, 2, 4, 6, 8, 10, 12, 14));
    float16 zw_ab = as_float16(PICK(a, b, ulong8, 1, 3, 5, 7, 9, 11, 13, 15));
    float16 zw_cd = as_float16(PICK(c, d, ulong8, 1, 3, 5, 7, 9, 11, 13, 15));
    float16 x = PICK(xy_ab, xy_cd, uint16, 0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
    float16 y = PICK(xy_ab, xy_cd, uint16, 1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
    float16 z = PICK(zw_ab, zw_cd, uint16, 0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
    return 0.2126f * x + 0.7152f * y + 0.0722f * z;
}

/* Weights of bins i … i + WIDE_LANES − 1 of the run; 0 past its end.  A last, partial block
 * copies its bins, zeros past the end, and takes the same arithmetic as whole blocks. */
__attribute__((always_inline)) inline float16 run_weights(const run_t *run, int i, int full)
{
    if (!run->env_row) {
        if (full) return vload16(0, run->weight + i);
        float w[WIDE_LANES];
        for (int k = 0; k < WIDE_LANES; ++k)   /* j: inside the run; read and dropped past its end */
            w[k] = i + k < run->count ? run->weight[min(i + k, run->count - 1)] : 0.0f;
        return vload16(0, w);
    }
    __global const ulong *pairs = (__global const ulong *)(run->env_row + i);
    ulong8 a, b, c, d;
    float16 omega;
    if (full) {
        a = vload8(0, pairs), b = vload8(1, pairs), c = vload8(2, pairs), d = vload8(3, pairs);
        omega = vload16(0, run->omega_row + i);
    } else {
        ulong texel_pairs[2 * WIDE_LANES];
        float omega_copy[WIDE_LANES];
        for (int k = 0; k < WIDE_LANES; ++k) {
            int j = min(k, run->count - i - 1), inside = i + k < run->count;
            texel_pairs[2 * k] = inside ? pairs[2 * j] : 0;
            texel_pairs[2 * k + 1] = inside ? pairs[2 * j + 1] : 0;
            omega_copy[k] = inside ? run->omega_row[i + j] : 0.0f;
        }
        a = vload8(0, texel_pairs), b = vload8(1, texel_pairs), c = vload8(2, texel_pairs),
        d = vload8(3, texel_pairs);
        omega = vload16(0, omega_copy);
    }
    return luminance_of_sixteen(a, b, c, d) * omega;
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

/* Pass (1) keeps a run's weights as floats in the upper half of its words' bytes, from byte 4n:
 * writing entry j (bytes 8j … 8j + 7) overwrites the weights of bins 2j − n and 2j + 1 − n,
 * which pass (2), going up a block at a time, has read by then (a whole block i … i + 7 reads
 * before it writes, and 2i + 15 − n < i + 8 while i + 8 ≤ n). */
__attribute__((always_inline)) inline __global float *run_weights_kept(__global cdf_word_t *cdf, int n)
{
    return (__global float *)cdf + n;
}

/* kept[i … i + WIDE_LANES) = w, as far as the run's n bins go. */
__attribute__((always_inline)) inline void keep_weights(__global float *kept, int i, int n, int full, float16 w)
{
    if (full) vstore16(w, 0, kept + i);
    else for (int k = 0; i + k < n; ++k) kept[i + k] = ((float *)&w)[k];
}

/* kept[i … i + LANES), 0 past the run's n bins. */
__attribute__((always_inline)) inline float8 kept_weights(__global const float *kept, int i, int n, int full)
{
    if (full) return vload8(0, kept + i);
    float v[LANES];
    for (int k = 0; k < LANES; ++k) v[k] = i + k < n ? kept[i + k] : 0.0f;
    return vload8(0, v);
}

/* Inclusive prefix sums of the lanes: three adds of the lanes shifted up by 1, 2 and 4, zeros
 * shifted in, written as alignments of (zero, v) with PICK (clang's __builtin_shufflevector): one
 * valignq each on PoCL's AVX-512 target, where a shift with zero's lane 0 (or OpenCL's vector
 * literals of a 0 and swizzles) compiled to slower lane expansions (vpexpandq). */
__attribute__((always_inline)) inline cdf_word8_t inclusive_scan(cdf_word8_t v)
{
    const cdf_word8_t zero = 0;
    v += PICK(zero, v, ulong8, 7, 8, 9, 10, 11, 12, 13, 14);
    v += PICK(zero, v, ulong8, 6, 7, 8, 9, 10, 11, 12, 13);
    return v + PICK(zero, v, ulong8, 4, 5, 6, 7, 8, 9, 10, 11);
}

/* Σ w of the n kept weights, compensated: LANES partial sums by two-sums, their
 * errors summed aside, joined by two-sums. */
__attribute__((always_inline)) inline acc_t compensated_sum(__global const float *kept, int n)
{
    acc8_t sum = 0, error = 0;
    FOR_EACH_BLOCK(0, n, LANES, {
        error += two_sum8(sum, convert_acc8(kept_weights(kept, i, n, full)), &sum);
    })
    acc_t total = 0, total_error = 0;
    for (int k = 0; k < LANES; ++k)
        total_error += two_sum(total, ((acc_t *)&sum)[k], &total) + ((acc_t *)&error)[k];
    return total + total_error;
}

/* The fixed-point CDF of `run` into cdf[0 … count); returns W. */
__attribute__((always_inline)) inline acc_t write_cdf(__global cdf_word_t *cdf, const run_t *run)
{
    int n = run->count;
    __global float *kept = run_weights_kept(cdf, n);
    const int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    const int16 wide_lane = (int16)(lane, lane + LANES);
    acc8_t sum_lo = 0, sum_hi = 0;
    float16 largest_weight = 0.0f;
    int16 largest = 0;
    uint16 least_bits = UINT_MAX;   /* the least positive weight's bits − 1: zeros wrap to the top */
    FOR_EACH_BLOCK(0, n, WIDE_LANES, {
        float16 w = run_weights(run, i, full);
        keep_weights(kept, i, n, full, w);
        sum_lo += convert_acc8(w.lo);
        sum_hi += convert_acc8(w.hi);
        int16 larger = w > largest_weight;
        largest_weight = select(largest_weight, w, larger);
        largest = select(largest, i + wide_lane, larger);
        least_bits = min(least_bits, as_uint16(w) - 1u);
    })
    /* Join the lanes: the first bin of the largest weight, and the least positive weight. */
    float top = 0.0f;
    int top_bin = 0;
    uint least = UINT_MAX;
    for (int k = 0; k < WIDE_LANES; ++k) {
        float w = ((float *)&largest_weight)[k];
        int bin = ((int *)&largest)[k];
        if (w > top || (w == top && bin < top_bin)) { top = w; top_bin = bin; }
        least = min(least, ((uint *)&least_bits)[k]);
    }
    acc_t total = sum_acc8(sum_lo + sum_hi);
    if (!(isfinite(total) && (acc_t)n * top <= EXACT_SUM_SPAN * (acc_t)as_float(least + 1u)))
        total = compensated_sum(kept, n);
    acc_t inverse = (acc_t)1 / total;   /* a product per bin, not a division */
    int uniform = !(total > 0) || isinf(inverse);
    if (uniform) inverse = (acc_t)1 / n;
    cdf_word8_t running = 0;   /* the entries so far: Σ q, in every lane */
    FOR_EACH_BLOCK(0, n, LANES, {
        if (run->next_env_row) {   /* the next run's texels (two lines), solid angles and words */
            PREFETCH(run->next_env_row + i, 0);
            PREFETCH(run->next_env_row + i + LANES / 2, 0);
            if (i % (2 * LANES) == 0) PREFETCH(run->next_omega_row + i, 0);
            PREFETCH(cdf + n + i, 1);
        }
        float8 w = uniform ? select((float8)0.0f, (float8)1.0f, i + lane < n)
                           : kept_weights(kept, i, n, full);
        acc8_t scaled = convert_acc8(w) * inverse * ACC_LITERAL(0x1p63);
        /* min: w ≤ W up to rounding, so only the largest bin can exceed 2^63, and its width
         * cancels out of the CDF (entry i ≥ largest is 2^63 − Σ_{j>i} q_j). */
        cdf_word8_t width = select(max((cdf_word8_t)1, convert_ulong8(min(scaled, (acc8_t)ACC_LITERAL(0x1p63)))),
                                   (cdf_word8_t)0, convert_long8(w > 0.0f) == 0);
        cdf_word8_t sums = inclusive_scan(width);
        store_words(cdf, i, n, full, sums + running);
        /* The block's total, spread from its own sums: one add per block on the chain. */
        running += PICK(sums, sums, ulong8, 7, 7, 7, 7, 7, 7, 7, 7);
    })
    /* The remainder joins the largest bin's width, so the entries end at CDF_ONE. */
    cdf_word_t remainder = CDF_ONE - running.s0;
    int first = top_bin;
    for (; first < n && first % LANES; ++first) cdf[first] += remainder;
    FOR_EACH_BLOCK(first, n, LANES, {
        store_words(cdf, i, n, full, load_words(cdf, i, n, full) + remainder);
    })
    return total;
}

/* One work item per (face, row): the conditional CDF of the row's Y·Ω, and its total. */
__kernel void row_cdfs(__global const float4 *env, __global const float *omega, const int res,
                       __global cdf_word_t *conditional, __global float *row_weight)
{
    int face_row = get_global_id(0), row = face_row % res;
    __global const float4 *env_row = env + (size_t)face_row * res;
    run_t run = {env_row, omega + (size_t)row * res, 0, res, env_row + res, omega + (size_t)(row + 1) % res * res};
    row_weight[face_row] = (float)write_cdf(conditional + (size_t)face_row * res, &run);
}

/* One work item per run of `n` weights (runs × n, run-major): its fixed-point CDF and total W
 * (float).  The faces' marginal CDFs over their row totals, and any other sampler's. */
__kernel void weight_cdfs(__global const float *weight, const int n, __global cdf_word_t *cdfs,
                          __global float *totals)
{
    int r = get_global_id(0);
    run_t run = {0, 0, weight + (size_t)r * n, n, 0, 0};
    totals[r] = (float)write_cdf(cdfs + (size_t)r * n, &run);
}

/* Walker's alias tables (Walker 1977; built by Vose 1991's worklists) of fixed-point CDFs, one
 * run of n bins per work item, in integers.  A table has M = 2^alias_bits(n) bins of S = 2^63 / M
 * units each; bin i holds a threshold t_i ≤ S and an alias a_i, packed as t_i·M + a_i (< 2^64).
 * A draw takes bin i uniformly and u uniform in [0, S): bin i where u < t_i, else a_i.
 * Construction from the run's widths q_j (zeros past n, Σ q = 2^63 = M·S): pair the last
 * under-full bin l (q_l < S) with the last over-full one g, t_l = q_l, a_l = g, and g keeps
 * q_g − (S − q_l), under-full or not; over-full bins left over get t = S.  Each pairing removes
 * one bin and S units, so Σ of the remaining widths = (bins left)·S holds exactly: the lists run
 * out together (none under-full is left), and bin j is drawn with probability
 * (t_j + Σ_{a_i = j} (S − t_i)) / 2^63 = q_j / 2^63, exactly the CDF's.  Run r's table goes to
 * words[first + r·M …]; `worklist` holds M ints per run: the under-full bins from the bottom, the
 * over-full ones from the top. */
__kernel void alias_tables(__global const cdf_word_t *cdfs, const int n, const int first,
                           __global cdf_word_t *words, __global int *worklist)
{
    int bits = alias_bits(n), bins = 1 << bits, under = 0, over = bins, r = get_global_id(0);
    __global const cdf_word_t *cdf = cdfs + (size_t)r * n;
    __global cdf_word_t *table = words + first + (size_t)r * bins;
    __global int *list = worklist + (size_t)r * bins;
    cdf_word_t unit = CDF_ONE >> bits;
    for (int j = 0; j < bins; ++j) {
        cdf_word_t width = j < n ? cdf[j] - cdf_lower(cdf, j) : 0;
        table[j] = width;
        if (width < unit) list[under++] = j;
        else list[--over] = j;
    }
    while (under > 0 && over < bins) {
        int l = list[--under], g = list[over];
        cdf_word_t rest = table[g] - (unit - table[l]);
        table[l] = (table[l] << bits) | (cdf_word_t)g;
        table[g] = rest;
        if (rest < unit) {   /* g turns under-full: off the over-full list, onto the other */
            ++over;
            list[under++] = g;
        }
    }
    for (; over < bins; ++over) table[list[over]] = (unit << bits) | (cdf_word_t)list[over];
}

/* P(texel) of the map's two-level distribution, one work item per texel: the probability of its
 * row in `marginal` (over the map's 6·R rows) times that of its column in the row's conditional,
 * each its width·2^-63 in float (cdf_bin), their product rounded once more. */
__kernel void texel_probabilities(__global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                                  const int res, __global float *probability)
{
    int texel = get_global_id(0), map_row = texel / res;
    probability[texel] = cdf_bin(marginal, map_row) * cdf_bin(conditional + (size_t)map_row * res, texel - map_row * res);
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

/* ---- descent tables (estimators/descent.cl's header has their layout) ------------------------ */

/* The records of depth k = `depth` (0 … L − 2) from the weight pyramid over faces of `res`, a
 * work item per POOL_LANES consecutive nodes Q of the 6·4^k, and their children's probabilities:
 * the node's (`node_probability` from 2·(4^k − 1), in heap order) times q_c/2^31, to the next
 * depth's nodes, or at the last depth to the texels (`probability`, [6, res, res]); `depth` −1:
 * records 0 and 1, the faces', and the faces' probabilities (work item 0 alone).  Each choice's
 * widths are descent_widths##N's of the sums, as a descent computes them from the pyramid, and
 * each probability the product a descent forms, in its order (the faces' first). */
__kernel void descent_bounds(__global const float *pyramid, const int res, const int depth, __global uint *bounds,
                             __global float *node_probability, __global float *probability)
{
    int top, levels = descent_levels(res, &top);
    if (depth < 0) {
        lanes_t w[6];
        lane_ints_t exists[6];
        lane_uints_t q[6];
        for (int f = 0; f < 6; ++f) {
            w[f] = pyramid[top + f];
            exists[f] = -1;
        }
        descent_widths6(w, exists, q);
        uint words[8];
        face_record_words(q, words);
        for (int f = 0; f < 8; ++f) bounds[f] = words[f];
        for (int f = 0; f < 6; ++f)   /* a face size of 1: the faces are the texels */
            (levels > 1 ? node_probability : probability)[f] = (float)q[f].s0 * (1.0f / DESCENT_ONE);
        return;
    }
    int nodes = 6 << (2 * depth), first = get_global_id(0) * POOL_LANES, l = levels - 2 - depth, level = 0;
    for (int finer = 0; finer < l; ++finer) level += 6 * level_size(res, finer) * level_size(res, finer);
    int here = 2 * ((1 << (2 * depth)) - 1), next = 2 * ((1 << (2 * depth + 2)) - 1);
    lane_ints_t node = min(first + LANE_NUMBERS, (lane_ints_t)(nodes - 1)), morton = node & ((1 << (2 * depth)) - 1);
    lane_ints_t face = node >> (2 * depth), row = morton_half(morton >> 1), col = morton_half(morton);
    lanes_t w[4];
    lane_ints_t exists[4];
    lane_uints_t q[4];
    child_sums(pyramid, level, level_size(res, l), face, row, col, w, exists);
    descent_widths4(w, exists, q);
    lanes_t parent = GATHER(lanes_t, node_probability, here + node), p[4];
    for (int c = 0; c < 4; ++c) p[c] = parent * (convert_lanes(q[c]) * (1.0f / DESCENT_ONE));
    lane_uints_t words[3] = {q[0], q[0] + q[1], q[0] + q[1] + q[2]};
    lane_ints_t texel = (face * res + 2 * row) * res + 2 * col, present[4] = {exists[0], exists[1], exists[2], exists[3]};
    /* lane i of a vector v at ((T *)&v)[i] */
    const uint *word = (const uint *)words;
    const float *child = (const float *)p;
    const int *at = (const int *)&texel, *opened = (const int *)present;
    for (int i = 0; i < POOL_LANES && first + i < nodes; ++i) {
        vstore4((uint4)(word[i], word[POOL_LANES + i], word[2 * POOL_LANES + i], 1u << DESCENT_BITS),
                (2 << (2 * depth)) + first + i, bounds);
        for (int c = 0; c < 4; ++c) {
            if (l > 0)
                node_probability[next + 4 * (first + i) + c] = child[c * POOL_LANES + i];
            else if (opened[c * POOL_LANES + i])
                probability[at[i] + (c >> 1) * res + (c & 1)] = child[c * POOL_LANES + i];
        }
    }
}
