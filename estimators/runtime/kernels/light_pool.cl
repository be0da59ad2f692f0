/* Lu 2013's shared light-sample pool (Algorithm 1) and the per-pixel estimator that reads it
 * (Algorithm 2, Eq. 4-6), shared by `uniform`, `balanced` and `balanced_mis`.
 *
 * Sample counts are fixed point: TICKS_PER_SAMPLE ticks make one sample.  A pixel's budget of
 * N_s samples is Q·N_s ticks (Q = TICKS_PER_SAMPLE), split among the strategies (six faces, and
 * the BRDF for Eq. 6) as integers that sum to exactly Q·N_s.  A strategy with t ticks has the
 * floating count N = t/Q: floor(N) samples of weight β = 1 and one of β = frac(N) (Eq. 5).
 * used and effective are summed in integer ticks (≤ Q·N_s < 2^31 for N_s < 32768), so they never
 * exceed N_s, not even by float rounding: int → float rounding is monotone, Q·N_s is exactly a
 * float, and dividing by Q = 2^16 is exact. */
#ifndef IBLBENCH_LIGHT_POOL_CL
#define IBLBENCH_LIGHT_POOL_CL

#include "common.cl"

#define TICKS_PER_SAMPLE 65536

#define STREAM_POOL_SEQUENCE 2u
#define STREAM_POOL_ROTATION 3u
#define STREAM_POOL_OFFSET 4u
#define STREAM_BRDF 5u
#define STREAM_HOOK 6u
#define POOL_SEQUENCE_SEED 0x2013u

/* ---- the pool (Algorithm 1, line 10) -------------------------------------------------------- */

/* Point i of face f's 2-D sequence, as fixed-point CDF variates (63 bits per coordinate, so
 * sample_face reaches every bin of the fixed-point CDFs; common.cl).  The sequence is fixed
 * (Lu's "precomputed random sequence", Sec. 2.2) and rotated modulo 1 by a random shift per
 * (seed, frame, face) (Cranley–Patterson): every rotated point is uniform on [0, 1)², so an
 * estimate that reads any of them is unbiased over seeds even when all pixels read the same
 * ones.  The rotation is the wrapping add of 64-bit words (mod 2^64), then the top 63 bits. */
static inline ulong2 pool_point(int face, int i, uint seed, uint frame)
{
    ulong2 base = rng_words2(POOL_SEQUENCE_SEED, 0u, STREAM_POOL_SEQUENCE, (uint)face, (uint)i, 0u);
    ulong2 shift = rng_words2(seed, frame, STREAM_POOL_ROTATION, (uint)face, 0u, 0u);
    return (base + shift) >> (ulong2)(1);
}

/* ---- the face split (Eq. 3) ------------------------------------------------------------------- */

/* F_f(n) of Eq. 3: Σ over the face's four normalised corners c_j of max(0, n·c_j).
 * F_f(n) = 0 means the face lies wholly in the closed lower hemisphere of n: every direction on
 * the face is a positive multiple of a convex combination Σ λ_j c_j of its corners (the face is
 * the convex square they span, projected onto the sphere), and n·Σ λ_j c_j = Σ λ_j (n·c_j) ≤ 0.
 * So cos⁺ = 0 on the whole face, and skipping it (μ_f = 0) loses nothing. */
ALWAYS_INLINE float face_form_factor(vec3_t n, int face)
{
    float sum = 0.0f;
    #pragma unroll
    for (int j = 0; j < 4; ++j) {
        vec3_t corner = vec3_of(face_uv_to_dir(face, (j & 1) ? 1.0f : -1.0f, (j & 2) ? 1.0f : -1.0f));
        sum += max(0.0f, vec3_dot(n, corner));
    }
    return sum * 0.57735026918962576f;   /* corners have length √3 */
}

/* Split `total` ticks among the faces in proportion to `weight`.  Cumulative rounding makes the
 * parts sum to exactly `total` (the running sum reaches the total sum bit-for-bit, in the same
 * order); a face of positive weight gets at least one tick, taken from the largest part (the
 * first of equal ones), so no face that can contribute is dropped.  The estimator divides by the
 * ticks it actually uses, so this rounding of μ_f (≤ a few ticks in Q·N_s) leaves it unbiased.
 * Branch-free (selects over fixed trip counts), so the split vectorises across pixels. */
ALWAYS_INLINE void split_ticks(const float weight[6], int total, int ticks[6])
{
    float sum = 0.0f;
    #pragma unroll
    for (int f = 0; f < 6; ++f) sum += weight[f];
    int positive = sum > 0.0f;
    float divisor = positive ? sum : 1.0f;   /* all weights zero: no ticks, and no 0/0 */
    float running = 0.0f;
    int previous = 0, deficit = 0;
    #pragma unroll
    for (int f = 0; f < 6; ++f) {
        running += weight[f];
        /* The guards keep the parts non-negative and the last one exact even where the
         * device's division is not correctly rounded. */
        int cumulative = running >= sum ? total
                       : clamp((int)((float)total * (running / divisor) + 0.5f), previous, total);
        int part = cumulative - previous;
        previous = cumulative;
        int raised = weight[f] > 0.0f && part == 0;
        deficit += raised;
        ticks[f] = positive ? part + raised : 0;
    }
    int largest = 0, most = ticks[0];
    #pragma unroll
    for (int f = 1; f < 6; ++f) {
        largest = ticks[f] > most ? f : largest;
        most = max(most, ticks[f]);
    }
    #pragma unroll
    for (int f = 0; f < 6; ++f) ticks[f] -= (f == largest && positive) ? deficit : 0;
}

/* Ticks of the light faces together: the whole budget, or half of it with BRDF samples (Eq. 6). */
static inline int light_ticks(int spp, int brdf_samples)
{
    int total = spp * TICKS_PER_SAMPLE;
    return brdf_samples ? total / 2 : total;
}

/* Ticks of every strategy for a pixel: six light faces, then the BRDF.  `balanced_faces` picks
 * μ_f(n) of Eq. 3 (else μ_f = 1/6); `brdf_samples` gives half the budget to BRDF sampling
 * (Eq. 6).  Faces with zero luminance integral are never drawn (their ticks are dropped, so they
 * count neither as used nor in the MIS denominator; their integrand is zero). */
ALWAYS_INLINE void strategy_ticks(vec3_t n, __global const float *face_integral, int spp,
                           int balanced_faces, int brdf_samples, int ticks[7])
{
    int total = spp * TICKS_PER_SAMPLE;
    int light_total = light_ticks(spp, brdf_samples);
    float weight[6];
    #pragma unroll
    for (int f = 0; f < 6; ++f)
        weight[f] = balanced_faces ? face_form_factor(n, f) * face_integral[f] : 1.0f;
    split_ticks(weight, light_total, ticks);
    #pragma unroll
    for (int f = 0; f < 6; ++f)
        ticks[f] = face_integral[f] > 0.0f ? ticks[f] : 0;
    ticks[6] = total - light_total;
}

/* ---- shading (Algorithm 2) ------------------------------------------------------------------ */

/* Number of draws for t ticks: Eq. 5. */
static inline int draws_for(int ticks) { return (ticks + TICKS_PER_SAMPLE - 1) / TICKS_PER_SAMPLE; }

/* Draws of a light face with t ticks: draws_for(t), which the pool always holds (min() only
 * guards memory). */
static inline int face_draws(int ticks, int pool_size) { return min(draws_for(ticks), pool_size); }

/* The sample counts of a pixel that its samples do not change: the β-weighted ticks of every
 * draw (Σ_i β_i = t for a strategy drawn in full) and the number of draws. */
static inline void drawn_counts(const int ticks[7], int pool_size, int *used, int *draws)
{
    *used = ticks[6];
    *draws = draws_for(ticks[6]);
    #pragma unroll
    for (int f = 0; f < 6; ++f) {
        int d = face_draws(ticks[f], pool_size);
        *used += d == draws_for(ticks[f]) ? ticks[f] : d * TICKS_PER_SAMPLE;
        *draws += d;
    }
}

/* A pixel's samples run POOL_LANES draws at a time in explicit vectors (the lanes of one work
 * item are consecutive draws of one strategy), so they are SIMD on any device and compiler, not
 * only where PoCL vectorises across work items (PoCL's work-item vectoriser rejects vector
 * types, so each work item runs its own vector loop).  Lanes past a strategy's draws are masked.
 * Integer min/max/clamp of lanes take their bounds as vectors, never the (gentype, sgentype)
 * forms: Oclgrind 21.10 does not broadcast a scalar bound of those integer built-ins (lanes past
 * the first get garbage bounds, and indices clamped by them read outside their buffers). */
#ifndef POOL_LANES
#define POOL_LANES 16
#endif
#if POOL_LANES == 16
typedef float16 lanes_t;
typedef int16 lane_ints_t;
typedef long16 lane_longs_t;
typedef ulong16 lane_words_t;
typedef uint16 lane_uints_t;
typedef vec3x16_t lanes3_t;
typedef rng_block16_t lane_block_t;
#define convert_lane_uints convert_uint16
#define vload_lanes vload16
#define convert_lanes convert_float16
#define convert_lane_ints convert_int16
#define convert_lane_longs convert_long16
#define phong_power_lanes phong_power16
#define phong_power_log2_lanes phong_power16_log2
#define phong_power_of_log2_lanes phong_power16_of_log2
#define phong_mixture_pdf_lanes phong_mixture_pdf16
#define direction_in_lanes direction_about_axis16_in
#define sincos_turn_lanes sincos_turn16
#define cube_face_st_lanes cube_face_st16
#define rng_block_lanes rng_block16
#define rng_block_draws_lanes rng_block16_draws
#define make_lanes3 vec3x16
#define LANE_NUMBERS ((int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define to8(v) ((v).lo + (v).hi)
/* (p[i.s0], …, p[i.sf]) as a `type`: loads of one element per lane. */
#define GATHER(type, p, i) ((type)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], (p)[(i).s4], \
    (p)[(i).s5], (p)[(i).s6], (p)[(i).s7], (p)[(i).s8], (p)[(i).s9], (p)[(i).sa], (p)[(i).sb],     \
    (p)[(i).sc], (p)[(i).sd], (p)[(i).se], (p)[(i).sf]))
#else
typedef float8 lanes_t;
typedef int8 lane_ints_t;
typedef long8 lane_longs_t;
typedef ulong8 lane_words_t;
typedef uint8 lane_uints_t;
typedef vec3x8_t lanes3_t;
typedef rng_block8_t lane_block_t;
#define convert_lane_uints convert_uint8
#define vload_lanes vload8
#define convert_lanes convert_float8
#define convert_lane_ints convert_int8
#define convert_lane_longs convert_long8
#define phong_power_lanes phong_power8
#define phong_power_log2_lanes phong_power8_log2
#define phong_power_of_log2_lanes phong_power8_of_log2
#define phong_mixture_pdf_lanes phong_mixture_pdf8
#define direction_in_lanes direction_about_axis8_in
#define sincos_turn_lanes sincos_turn8
#define cube_face_st_lanes cube_face_st8
#define rng_block_lanes rng_block8
#define rng_block_draws_lanes rng_block8_draws
#define make_lanes3 vec3x8
#define LANE_NUMBERS ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#define to8(v) (v)
#define GATHER(type, p, i) ((type)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], (p)[(i).s4], \
    (p)[(i).s5], (p)[(i).s6], (p)[(i).s7]))
#endif

/* Sums of a block's lanes, pairwise. */
static inline float sum_of8(float8 v)
{
    float4 q = v.lo + v.hi;
    return (q.x + q.z) + (q.y + q.w);
}

static inline int int_sum_of8(int8 v)
{
    int4 q = v.lo + v.hi;
    return (q.x + q.z) + (q.y + q.w);
}

/* rng_unit of each lane's word. */
ALWAYS_INLINE lanes_t lanes_unit(lane_uints_t word) { return convert_lanes(word >> 8) * (1.0f / 16777216.0f); }

ALWAYS_INLINE lanes_t lanes_dot(vec3_t a, lanes3_t b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

/* β (in ticks) of the draws i, i+1, … of the lanes, for a strategy of t ticks (Eq. 5); from the
 * ticks left before the block, so it never overflows. */
ALWAYS_INLINE lane_ints_t lanes_beta(int ticks, int i)
{
    return min(TICKS_PER_SAMPLE, ticks - i * TICKS_PER_SAMPLE - LANE_NUMBERS * TICKS_PER_SAMPLE);
}

/* clamp_index of common.cl for the lanes (vector bounds: see POOL_LANES). */
ALWAYS_INLINE lane_ints_t lanes_clamp_index(lanes_t x, int res)
{
    return clamp(convert_lane_ints(floor(x * (float)res)), (lane_ints_t)0, (lane_ints_t)(res - 1));
}

/* The pixel's mask bits of the lanes' visibility cells (visibility_cell of common.cl), as a mask:
 * -1 where open, 0 where shadowed; all open without VISIBILITY. */
ALWAYS_INLINE lane_ints_t lanes_cells_open(__global const uint *visibility, int pixel, lane_ints_t cell)
{
#if VISIBILITY
    lane_uints_t word = GATHER(lane_uints_t, visibility + (size_t)pixel * VIS_WORDS, cell >> 5);
    return ((word >> convert_lane_uints(cell & 31)) & 1u) != 0u;
#else
    return (lane_ints_t)(-1);
#endif
}

/* visibility_cell of common.cl for the lanes' directions w (found once where several pixels'
 * masks are read at the same directions: restir's spatial reuse). */
ALWAYS_INLINE lane_ints_t lanes_visibility_cell(lanes3_t w)
{
    lanes_t s, t;
    lane_ints_t face = cube_face_st_lanes(w, &s, &t);
    return (face * VIS_RES + lanes_clamp_index(t, VIS_RES)) * VIS_RES + lanes_clamp_index(s, VIS_RES);
}

/* visible() of common.cl for the lanes' directions w, as lanes_cells_open's mask. */
ALWAYS_INLINE lane_ints_t lanes_visible(__global const uint *visibility, int pixel, lanes3_t w)
{
#if VISIBILITY
    return lanes_cells_open(visibility, pixel, lanes_visibility_cell(w));
#else
    return (lane_ints_t)(-1);
#endif
}

/* ---- launch shapes (issue 37) -----------------------------------------------------------------
 * The kernels that sum a pixel's draws in lanes (envmap.cl's render_map, render_light_pool,
 * fis.cl's render_fis) launch in one of two shapes (Compute.launch_shape; DeviceGBuffer.run_sampled):
 *   pixel (CPUs): work item p shades every draw of pixel p and writes its sums;
 *   sample block (SAMPLE_BLOCKS, GPUs): work item g = b·n + p shades the lane chunks (POOL_LANES
 *     draws each) [b·K, (b + 1)·K) of pixel p, K = block_chunks, its strategies' chunks counted
 *     one after another in the kernel's order (strategy_window); it writes its sums to
 *     `partial`, and sum_sample_blocks adds pixel p's blocks in the order b = 0, 1, ….
 * A chunk holds the same draws in either shape, each keyed by (pixel, draw index) as before, so
 * both shapes shade the same samples; only the order of the float sums differs.  The kernels
 * with state per pixel keep the pixel shape on every device: restir's reservoirs (its chains
 * are a pixel's, resampled together; on a GPU built with CHAIN_LANES=0, scalar chains), smc's
 * particles across frames, and bis's resampling among all of a pixel's candidates; so do
 * cosine's scalar loop and havran's lights, which do not sum lane chunks. */
#if SAMPLE_BLOCKS
#define LAUNCH_PARAMS , const int block_chunks, const int blocks, __global float *partial
#define LAUNCH_ITEM(n) launch_item(n, block_chunks, blocks)
#define PARTIAL_SUMS partial
#else
#define LAUNCH_PARAMS
#define LAUNCH_ITEM(n) launch_item(n, 0, 0)
#define PARTIAL_SUMS 0
#endif

/* A work item's pixel, its block and the planes' stride of `partial` (n·blocks), its window of
 * lane chunks [first, end) (the pixel shape's: all; the last block's reaches past the host's
 * bound on a pixel's chunks, so no draw is left out even were it short), and the chunks of the
 * strategies before the next one (`base`). */
typedef struct { int pixel, block, stride, first, end, base; } launch_item_t;

ALWAYS_INLINE launch_item_t launch_item(int n, int block_chunks, int blocks)
{
    int g = get_global_id(0);
#if SAMPLE_BLOCKS
    int block = g / n;
    int end = block + 1 < blocks ? (block + 1) * block_chunks : INT_MAX;
    launch_item_t item = {g - block * n, block, n * blocks, block * block_chunks, end, 0};
#else
    launch_item_t item = {g, 0, 0, 0, 0, 0};
#endif
    return item;
}

/* The draws [*first, *end) that the work item shades of the next strategy, of `draws` draws. */
ALWAYS_INLINE void strategy_window(launch_item_t *item, int draws, int *first, int *end)
{
#if SAMPLE_BLOCKS
    int chunks = (draws + POOL_LANES - 1) / POOL_LANES;
    *first = clamp(item->first - item->base, 0, chunks) * POOL_LANES;
    *end = min(clamp(item->end - item->base, 0, chunks) * POOL_LANES, draws);
    item->base += chunks;
#else
    *first = 0;
    *end = draws;
#endif
}

/* A pixel's running estimate, one partial sum per lane. */
typedef struct {
    lanes_t r, g, b;
    lane_ints_t effective;   /* ticks of the samples with a positive cosine and denominator */
} lanes_sum_t;

/* The work item's sums into planes of n floats: radiance R, G, B; counts used and effective (in
 * samples, from ticks); evaluations per pixel.  In the sample-block shape its radiance and
 * effective ticks (as_float) go to `partial`'s planes of n·blocks at its global id, and block 0
 * writes the pixel's used ticks and evaluations, which no draw changes. */
ALWAYS_INLINE void store_sums(const lanes_sum_t *acc, launch_item_t item, int n, int used, int evaluation_count,
                              __global float *radiance, __global float *counts, __global int *evaluations,
                              __global float *partial)
{
    int p = item.pixel;
#if SAMPLE_BLOCKS
    int at = get_global_id(0), stride = item.stride;
    partial[at] = sum_of8(to8(acc->r));
    partial[stride + at] = sum_of8(to8(acc->g));
    partial[2 * stride + at] = sum_of8(to8(acc->b));
    partial[3 * stride + at] = as_float(int_sum_of8(to8(acc->effective)));
    if (item.block == 0) {
        counts[p] = (float)used * (1.0f / TICKS_PER_SAMPLE);
        evaluations[p] = evaluation_count;
    }
#else
    radiance[p] = sum_of8(to8(acc->r));
    radiance[n + p] = sum_of8(to8(acc->g));
    radiance[2 * n + p] = sum_of8(to8(acc->b));
    counts[p] = (float)used * (1.0f / TICKS_PER_SAMPLE);
    counts[n + p] = (float)int_sum_of8(to8(acc->effective)) * (1.0f / TICKS_PER_SAMPLE);
    evaluations[p] = evaluation_count;
#endif
}

#if SAMPLE_BLOCKS
/* Pixel p's radiance and effective count from its `blocks` blocks' partial sums (store_sums),
 * added in block order; the effective ticks as integers, exactly the pixel shape's. */
__kernel void sum_sample_blocks(__global const float *partial, const int n, const int blocks,
                                __global float *radiance, __global float *counts)
{
    int p = get_global_id(0), stride = n * blocks, effective = 0;
    float r = 0.0f, g = 0.0f, b = 0.0f;
    for (int at = p; at < stride; at += n) {
        r += partial[at];
        g += partial[stride + at];
        b += partial[2 * stride + at];
        effective += as_int(partial[3 * stride + at]);
    }
    radiance[p] = r;
    radiance[n + p] = g;
    radiance[2 * n + p] = b;
    counts[n + p] = (float)effective * (1.0f / TICKS_PER_SAMPLE);
}
#endif

/* Add the lanes' samples of strategy weight β (in ticks) where `active` and `open` (V(x, ω) = 1,
 * lanes_visible; a shadowed sample adds 0, but counts as effective: Lu 2013's effective samples
 * are those of positive cosine): β·s(ω) / D(ω), where
 * D(ω) = Σ_k t_k p_k(ω) is the balance-heuristic denominator in ticks.  With counts N_k = t_k/Q
 * this is (1/N_s)·β_i·s/(Σ_k (N_k/N_s) p_k), i.e. Eq. 4 when only the light faces have ticks
 * and Eq. 6 with the BRDF.  `power` is the lobe power cos⁺(r, ω)^m, `cosine` is n·ω; the
 * arithmetic is phong_value's, times the radiance, times the weight. */
ALWAYS_INLINE void add_samples(lanes_sum_t *acc, const shading_t *s, lane_ints_t active,
                               lane_ints_t beta, lanes_t cosine, lanes_t power, lanes3_t radiance,
                               lanes_t denominator, lane_ints_t open)
{
    lane_ints_t counts = active & (cosine > 0.0f) & (denominator > 0.0f), lit = counts & open;
    lanes_t weight = convert_lanes(beta) / denominator * cosine;
    lanes_t lobe = (s->m + 2.0f) / (2.0f * IBL_PI) * power;
    acc->r += select((lanes_t)0.0f, (s->kd.x / IBL_PI + s->ks.x * lobe) * radiance.x * weight, lit);
    acc->g += select((lanes_t)0.0f, (s->kd.y / IBL_PI + s->ks.y * lobe) * radiance.y * weight, lit);
    acc->b += select((lanes_t)0.0f, (s->kd.z / IBL_PI + s->ks.z * lobe) * radiance.z * weight, lit);
    acc->effective += select((lane_ints_t)0, beta, counts);
}

/* The pool is read as planes (pool_planes kernel): x, y, z, pdf, R, G, B and the visibility cell
 * of the direction (a whole number, exact in a float below 2^24 cells; shared by every pixel, so
 * no pixel finds it again), each of
 * POOL_PLANE_STRIDE(size) floats, face f's entries at [2·size·f, 2·size·f + size) and again after
 * them, so a pixel's window of draws from any offset < size is contiguous (no wrap), and zeros
 * past the last face pad the last lanes. */
#define POOL_PLANES 8
#define POOL_PLANE_STRIDE(size) (12 * (size) + 16)

ALWAYS_INLINE lanes3_t lanes3_load(__global const float *plane0, int stride, int i)
{
    return make_lanes3(vload_lanes(0, plane0 + i), vload_lanes(0, plane0 + stride + i),
                       vload_lanes(0, plane0 + 2 * stride + i));
}

/* Light samples of every face (Eq. 4, or the g_{f,i} of Eq. 6): face f's draws_for(t_f) draws
 * read consecutive pool entries from `offset` (0 for the shared sequence; offset < pool_size),
 * those of the work item's window (strategy_window, the faces in order).
 * brdf_samples = 0 leaves the BRDF term out of the denominator (t_6 = 0 there). */
ALWAYS_INLINE void shade_light_faces(lanes_sum_t *acc, launch_item_t *item, const shading_t *s, const int ticks[7],
                                     int brdf_samples, __global const float *planes, int pool_size,
                                     int offset, __global const uint *visibility, int pixel)
{
    int stride = POOL_PLANE_STRIDE(pool_size);
    for (int f = 0; f < 6; ++f) {
        int draws = face_draws(ticks[f], pool_size), from, to;
        strategy_window(item, draws, &from, &to);
        float face_ticks = (float)ticks[f];
        int first = 2 * pool_size * f + offset;
        for (int i = from; i < to; i += POOL_LANES) {
            lanes3_t w = lanes3_load(planes, stride, first + i);
            lanes_t pdf = vload_lanes(0, planes + 3 * stride + first + i);
            lanes_t power = phong_power_lanes(max(lanes_dot(s->r, w), 0.0f), (lanes_t)s->m);
            lanes_t cosine = lanes_dot(s->n, w);
            lanes_t denominator = face_ticks * pdf;
            if (brdf_samples)
                denominator += (float)ticks[6] * phong_mixture_pdf_lanes(s->p_spec, s->m, cosine, power);
            lane_ints_t cell = convert_lane_ints(vload_lanes(0, planes + 7 * stride + first + i));
            add_samples(acc, s, i + LANE_NUMBERS < draws, lanes_beta(ticks[f], i), cosine, power,
                        lanes3_load(planes + 4 * stride, stride, first + i), denominator,
                        lanes_cells_open(visibility, pixel, cell));
        }
    }
}

/* cdf_bin of common.cl for the bins base + i of the lanes. */
ALWAYS_INLINE lanes_t lanes_cdf_bin(__global const cdf_word_t *cdf, lane_ints_t base, lane_ints_t i)
{
    lane_words_t upper = GATHER(lane_words_t, cdf, base + i);
    lane_words_t lower = GATHER(lane_words_t, cdf, base + max(i - 1, (lane_ints_t)0));
    lower = select((lane_words_t)0, lower, convert_lane_longs(i > 0));
    return convert_lanes(upper - lower) * 0x1p-63f;
}

/* The texel of each lane's direction (*face, *row, *col) and its area_per_solid_angle, as
 * light_pdf_on_face of common.cl finds them. */
ALWAYS_INLINE lanes_t lanes_texel_of(int res, lanes3_t w, lane_ints_t *face, lane_ints_t *row,
                                     lane_ints_t *col)
{
    lanes_t s, t;
    *face = cube_face_st_lanes(w, &s, &t);
    *row = lanes_clamp_index(t, res);
    *col = lanes_clamp_index(s, res);
    lanes_t u = 2.0f * s - 1.0f, v = 2.0f * t - 1.0f;
    lanes_t q = 1.0f + u * u + v * v;
    return q * sqrt(q);   /* area_per_solid_angle */
}

/* light_pdf_on_face of common.cl for the lanes' directions, the same arithmetic (ARCHITECTURE.md
 * §Conventions's light pdf, one marginal CDF per face); *face and *texel get the face and the
 * texel of each. */
ALWAYS_INLINE lanes_t lanes_light_pdf(__global const cdf_word_t *marginal,
                                      __global const cdf_word_t *conditional, int res, lanes3_t w,
                                      lane_ints_t *face, lane_ints_t *texel)
{
    lane_ints_t f, row, col;
    lanes_t area = lanes_texel_of(res, w, &f, &row, &col);
    lane_ints_t map_row = f * res + row;
    lanes_t p_texel = lanes_cdf_bin(marginal, f * res, row) * lanes_cdf_bin(conditional, map_row * res, col);
    *face = f;
    *texel = map_row * res + col;
    return p_texel * area * (float)(res * res) / 4.0f;
}

/* The BRDF draws' numbers where every pixel draws the same ones (the shared sequence), as planes
 * of BRDF_NUMBERS_STRIDE(spp) floats (the brdf_numbers kernel), so the pixels do not each
 * recompute them: those of draw_numbers, and the parts of the polar cosine that do not depend on
 * the pixel (√ξ_cos of the diffuse lobe, log2 ξ_cos of the specular lobe's ξ_cos^{1/(m+1)}). */
#define BRDF_NUMBERS_STRIDE(spp) (16 * ((spp) / 16 + 1))

/* Draw i's numbers: rng_block(seed, frame, STREAM_BRDF, stream_pixel, i, 0) as uniforms, the
 * azimuth through sincos_turn. */
ALWAYS_INLINE void draw_numbers(uint seed, uint frame, uint stream_pixel, lane_ints_t draw,
                                lanes_t *xi_cos, lanes_t *xi_lobe, lanes_t *sine, lanes_t *cosine)
{
    lane_block_t xi = rng_block_lanes(seed, frame, STREAM_BRDF, stream_pixel, convert_lane_uints(draw), 0u);
    *xi_cos = lanes_unit(xi.v[0]);
    *xi_lobe = lanes_unit(xi.v[2]);
    sincos_turn_lanes(lanes_unit(xi.v[1]), sine, cosine);
}

/* lanes3_t of a where `pick`, else of b. */
ALWAYS_INLINE lanes3_t lanes3_pick(lane_ints_t pick, vec3_t a, vec3_t b)
{
    return make_lanes3(select((lanes_t)b.x, (lanes_t)a.x, pick), select((lanes_t)b.y, (lanes_t)a.y, pick),
                       select((lanes_t)b.z, (lanes_t)a.z, pick));
}

/* The lanes' BRDF directions, sample_phong_direction's arithmetic from a draw's numbers: ξ_cos
 * (with √ξ_cos and log2 ξ_cos), ξ_lobe and the azimuth's sine and cosine; (t_n, b_n) and (t_r,
 * b_r) are the bases about n and r (direction_about_axis_basis), computed once per pixel. */
ALWAYS_INLINE lanes3_t lanes_phong_direction(const shading_t *s, vec3_t t_n, vec3_t b_n, vec3_t t_r, vec3_t b_r,
                                             lanes_t xi_cos, lanes_t sqrt_xi_cos, lanes_t log2_xi_cos,
                                             lanes_t xi_lobe, lanes_t azimuth_sin, lanes_t azimuth_cos)
{
#if SPECULAR_LOBE
    lane_ints_t specular = xi_lobe < s->p_spec;
    lanes_t cos_theta = select(sqrt_xi_cos, phong_power_of_log2_lanes(xi_cos, log2_xi_cos,
                                                                      (lanes_t)(1.0f / (s->m + 1.0f))),
                               specular);
#else
    lane_ints_t specular = 0;
    lanes_t cos_theta = sqrt_xi_cos;
#endif
    return direction_in_lanes(lanes3_pick(specular, s->r, s->n), lanes3_pick(specular, t_r, t_n),
                              lanes3_pick(specular, b_r, b_n), cos_theta, azimuth_sin, azimuth_cos);
}

/* The radiance of the lanes' texels (nearest lookup). */
ALWAYS_INLINE lanes3_t lanes_texel_radiance(__global const float4 *env, lane_ints_t texel)
{
    __global const float *texels = (__global const float *)env;
    lane_ints_t at = 4 * texel;
    return make_lanes3(GATHER(lanes_t, texels, at), GATHER(lanes_t, texels, at + 1), GATHER(lanes_t, texels, at + 2));
}

/* BRDF samples of Eq. 6 (f_i): the denominator holds the full light mixture, which is the one
 * face term t_{f(ω)}·pdf_L(ω|f(ω)) because pdf_L(ω|f) = 0 off face f.  Every pixel draws
 * draws_for(t_6) samples (t_6 depends on the budget alone), the work item those of its window;
 * draw i's numbers are draw_numbers (read from `shared_numbers` for the shared sequence), its
 * direction sample_phong_direction's arithmetic, with the bases about n and r computed once per
 * work item. */
ALWAYS_INLINE void shade_brdf(lanes_sum_t *acc, launch_item_t *item, const shading_t *s, const int ticks[7],
                              __global const float4 *env, __global const cdf_word_t *marginal,
                              __global const cdf_word_t *conditional, int res, uint seed,
                              uint frame, int shared_sequence, uint stream_pixel,
                              __global const float *shared_numbers, int numbers_stride,
                              __global const uint *visibility, int pixel)
{
    int draws = draws_for(ticks[6]), from, to;
    strategy_window(item, draws, &from, &to);
    vec3_t t_n, b_n, t_r, b_r;
    direction_about_axis_basis(s->n, &t_n, &b_n);
    direction_about_axis_basis(s->r, &t_r, &b_r);
    for (int i = from; i < to; i += POOL_LANES) {
        lane_ints_t draw = i + LANE_NUMBERS;
        lanes_t xi_cos, xi_lobe, azimuth_sin, azimuth_cos, sqrt_xi_cos, log2_xi_cos;
        if (shared_sequence) {
            __global const float *numbers = shared_numbers + i;
            xi_cos = vload_lanes(0, numbers);
            xi_lobe = vload_lanes(0, numbers + numbers_stride);
            azimuth_sin = vload_lanes(0, numbers + 2 * numbers_stride);
            azimuth_cos = vload_lanes(0, numbers + 3 * numbers_stride);
            sqrt_xi_cos = vload_lanes(0, numbers + 4 * numbers_stride);
            log2_xi_cos = vload_lanes(0, numbers + 5 * numbers_stride);
        } else {
            draw_numbers(seed, frame, stream_pixel, draw, &xi_cos, &xi_lobe, &azimuth_sin, &azimuth_cos);
            sqrt_xi_cos = sqrt(xi_cos);
            log2_xi_cos = phong_power_log2_lanes(xi_cos);
        }
        lanes3_t w = lanes_phong_direction(s, t_n, b_n, t_r, b_r, xi_cos, sqrt_xi_cos, log2_xi_cos, xi_lobe,
                                           azimuth_sin, azimuth_cos);
        lanes_t power = phong_power_lanes(max(lanes_dot(s->r, w), 0.0f), (lanes_t)s->m);
        lanes_t cosine = lanes_dot(s->n, w);
        lanes_t pdf_brdf = phong_mixture_pdf_lanes(s->p_spec, s->m, cosine, power);
        lane_ints_t face, texel;
        lanes_t pdf_light = lanes_light_pdf(marginal, conditional, res, w, &face, &texel);
        lane_ints_t face_ticks = ticks[0];
        #pragma unroll
        for (int k = 1; k < 6; ++k) face_ticks = select(face_ticks, (lane_ints_t)ticks[k], face == k);
        lanes_t denominator = convert_lanes(face_ticks) * pdf_light + (float)ticks[6] * pdf_brdf;
        add_samples(acc, s, draw < draws, lanes_beta(ticks[6], i), cosine, power, lanes_texel_radiance(env, texel),
                    denominator, lanes_visible(visibility, pixel, w));
    }
}

/* Density of all directions the estimator draws for one pixel, pooled over its strategies:
 * Σ_k t_k p_k(ω) / Σ_k t_k (what the χ² hooks check), given ω's light pdf on its face.  It and
 * pooled_pdf are forced inline: a call that takes the hook kernels' shading_t by address keeps it
 * in memory, with an llvm.experimental.noalias.scope.decl from load_shading that Oclgrind 21.10
 * cannot run. */
ALWAYS_INLINE float pooled_density(const shading_t *s, const int ticks[7], int face, float pdf_light,
                                   vec3_t w)
{
    int total = ticks[6];
    #pragma unroll
    for (int f = 0; f < 6; ++f) total += ticks[f];
    float pdf_brdf = phong_mixture_pdf(s->p_spec, s->m, vec3_dot(s->n, w), phong_lobe_power(s->r, w, s->m));
    float density = (float)ticks[6] * pdf_brdf + (float)ticks[face] * pdf_light;
    return total > 0 ? density / (float)total : 0.0f;
}

/* pooled_density with ω's light pdf looked up from its texel (light_pdf of common.cl). */
ALWAYS_INLINE float pooled_pdf(const shading_t *s, const int ticks[7], __global const cdf_word_t *marginal,
                               __global const cdf_word_t *conditional, int res, vec3_t w)
{
    int face, texel;
    float pdf_light = light_pdf_on_face(marginal, conditional, res, w, &face, &texel);
    return pooled_density(s, ticks, face, pdf_light, w);
}

#endif
