/* Lockstep loops for kernels that PoCL vectorises across work items (issue 10), on top of the
 * scalar vec3_t / shading_t helpers of common.cl.
 *
 * PoCL 3.1 (LLVM 15) runs the work items of a group as SIMD lanes only over a region of code that
 *   - holds no inner loop: a kernel's own loop (over samples, candidates) must end each iteration
 *     at LOCKSTEP, a barrier, which makes the loop body a region of its own (PoCL then vectorises
 *     the work-item loop inside it); loops of a fixed small count must unroll;
 *   - holds no value of an OpenCL vector type: float3/float4 arithmetic, loads and returns stop
 *     it ("instruction return type cannot be vectorized"), and so do the 2- and 4-vectors the
 *     optimiser fuses out of adjacent stores, of a select or phi of structs, or of isomorphic
 *     sums (three running sums per channel, six quotients);
 *   - holds no call (helpers are forced inline; the library sin/cos are calls);
 *   - carries only scalars across a barrier: a struct or float3 live there becomes a context array
 *     of aggregates, which stops it too.
 * Measured on small kernels: 10× per work item and iteration for the barrier, 8× for scalar
 * instead of float3 code.  The helpers here complete common.cl's for the map's CDFs and the
 * random streams; a GPU runs either form, one work item per lane. */
#ifndef IBLBENCH_LANES_CL
#define IBLBENCH_LANES_CL

/* common.cl helpers on the hot paths that it does not force inline: forced here by a declaration
 * before their definition. */
#define FORCE_INLINE static inline __attribute__((always_inline))   /* common.cl's ALWAYS_INLINE */
FORCE_INLINE int cdf_search(__global const ulong *cdf, int n, ulong u);
FORCE_INLINE ulong cdf_lower(__global const ulong *cdf, int i);
FORCE_INLINE float cdf_bin(__global const ulong *cdf, int i);
FORCE_INLINE float cdf_bin_position(__global const ulong *cdf, int i, ulong u);
FORCE_INLINE int clamp_index(float x, int res);
FORCE_INLINE int texel_index(int face, int row, int col, int res);
FORCE_INLINE float area_per_solid_angle(float u, float v);
#undef FORCE_INLINE
#include "common.cl"
/* Explicit vectors of POOL_LANES lanes (lanes_t, GATHER, lanes_light_pdf, …), for loops that run
 * their own lanes instead of PoCL's work-item vectorisation. */
#include "light_pool.cl"

/* A light sampler's per-pixel state (envmap.cl's hooks): none, unless the sampler's distribution
 * depends on the pixel and its file defines PIXEL_LIGHT_STATE and its own light_state_t before
 * it includes this one (product.cl: the pixel's table of product choices). */
#ifndef PIXEL_LIGHT_STATE
typedef struct { int none; } light_state_t;
#endif

/* Ends one iteration of a loop whose trip count is the same in every work item of the group (see
 * the header).  Every work item must reach it: no early exit before or inside such a loop, and
 * the host launches whole, padded groups (estimators/bis.py, run_lockstep). */
#define LOCKSTEP() barrier(CLK_LOCAL_MEM_FENCE)

/* Compensated sum (common.cl's kahan_add) on two scalars, which may be carried across LOCKSTEP. */
ALWAYS_INLINE void kahan_add_to(acc_t *sum, acc_t *carry, acc_t x)
{
    acc_t y = x - *carry;
    acc_t t = *sum + y;
    *carry = (t - *sum) - y;
    *sum = t;
}

/* ---- random numbers: common.cl's rng_uniform4 / rng_words2 without vector types --------------- */

typedef struct { float x, y, z, w; } uniform4_t;
typedef struct { ulong x, y; } words2_t;

ALWAYS_INLINE uniform4_t lane_uniform4(uint seed, uint frame, uint stream, uint pixel, uint sample, uint draw)
{
    philox4x32_ctr_t r = rng_block(seed, frame, stream, pixel, sample, draw);
    uniform4_t u = {rng_unit(r.v[0]), rng_unit(r.v[1]), rng_unit(r.v[2]), rng_unit(r.v[3])};
    return u;
}

ALWAYS_INLINE words2_t lane_words2(uint seed, uint frame, uint stream, uint pixel, uint sample, uint draw)
{
    philox4x32_ctr_t r = rng_block(seed, frame, stream, pixel, sample, draw);
    words2_t u = {upsample(r.v[0], r.v[1]), upsample(r.v[2], r.v[3])};
    return u;
}

/* ---- the map: nearest texel, and common.cl's sample_face in scalars -------------------------- */

/* The texel that holds direction w (nearest lookup, ARCHITECTURE.md §Conventions). */
ALWAYS_INLINE int lane_texel(vec3_t w, int res)
{
    float s, t;
    int face = cube_face_st(w, &s, &t);
    return texel_index(face, clamp_index(t, res), clamp_index(s, res), res);
}

/* face_uv_to_dir: face-plane point (u, v) -> (unnormalised) direction on the cube. */
ALWAYS_INLINE vec3_t lane_face_dir(int face, float u, float v)
{
    float sign = (face & 1) ? -1.0f : 1.0f;
    int x_major = face < 2, y_major = face == 2 || face == 3;
    return vec3(x_major ? sign : y_major ? u : sign * u, y_major ? sign : -v,
                x_major ? -sign * u : y_major ? sign * v : sign);
}

/* common.cl's cdf_search (first i with cdf[i] > u) with a fixed trip count: CDF_STEPS =
 * ⌈log2 R⌉ halvings (the host defines it with ENV_RES), each a no-op once n = 1, so the loop
 * unrolls and a loop body that samples the map stays one region (header).  The halvings go in
 * pairs: the second's probe for either outcome of the first is loaded with the first's, so a
 * pair costs one dependent load instead of two (the search is a chain of loads that miss L1);
 * the probes compared and the result are cdf_search's.  Without CDF_STEPS it is cdf_search. */
ALWAYS_INLINE int lane_cdf_search(__global const cdf_word_t *cdf, int n, cdf_word_t u)
{
#ifdef CDF_STEPS
    int base = 0;
    UNROLL
    for (int i = 0; i < (CDF_STEPS + 1) / 2; ++i) {
        int step = n >> 1, rest = n - step, next = rest >> 1;
        /* Indices clamped where a halving is a no-op (step or next 0): never read, never past n. */
        cdf_word_t probe = cdf[base + max(step - 1, 0)];
        cdf_word_t probe_low = cdf[base + max(next - 1, 0)], probe_high = cdf[base + step + max(next - 1, 0)];
        int taken = step > 0 && probe <= u;
        cdf_word_t second = taken ? probe_high : probe_low;
        base = taken ? base + step : base;
        base = (next > 0 && second <= u) ? base + next : base;
        n = rest - next;
    }
    return base;
#else
    return cdf_search(cdf, n, u);
#endif
}

/* sample_face: a direction of face `face` from the 63-bit point u by its marginal and
 * conditional CDFs; returns pdf_L(ω|f) and sets *texel. */
ALWAYS_INLINE float lane_sample_face(__global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                                     int face, int res, words2_t u, vec3_t *dir, int *texel)
{
    __global const cdf_word_t *rows = marginal + face * res;
    int row = lane_cdf_search(rows, res, u.x);
    __global const cdf_word_t *cols = conditional + (face * res + row) * res;
    int col = lane_cdf_search(cols, res, u.y);
    float x, y;
    float pdf = face_point_pdf(rows, cols, row, col, res, u.x, u.y, &x, &y);
    *dir = vec3_normalize(lane_face_dir(face, x, y));
    *texel = texel_index(face, row, col, res);
    return pdf;
}

/* ---- explicit lanes: POOL_LANES candidates of one work item at a time ------------------------ */

#if POOL_LANES == 16
#define direction_about_axis_lanes direction_about_axis16
#define vstore_lanes vstore16
#else
#define direction_about_axis_lanes direction_about_axis8
#define vstore_lanes vstore8
#endif

ALWAYS_INLINE lanes3_t splat_lanes3(vec3_t a) { return make_lanes3((lanes_t)a.x, (lanes_t)a.y, (lanes_t)a.z); }

ALWAYS_INLINE lanes3_t select_lanes3(lanes3_t a, lanes3_t b, lane_ints_t take_b)
{
    return make_lanes3(select(a.x, b.x, take_b), select(a.y, b.y, take_b), select(a.z, b.z, take_b));
}

/* lane_cdf_search for the lanes: the first i with cdf[first + i] > u, per lane (n is the work
 * item's, so the halvings are a plain loop), the halvings in pairs as there (one dependent
 * gather per pair). */
ALWAYS_INLINE lane_ints_t lanes_cdf_search(__global const cdf_word_t *cdf, lane_ints_t first, int n,
                                           lane_words_t u)
{
    lane_ints_t base = 0;
    for (; n > 1; ) {
        int step = n >> 1, rest = n - step, next = rest >> 1;
        lane_words_t probe = GATHER(lane_words_t, cdf, first + base + step - 1);
        if (next > 0) {
            lane_words_t probe_low = GATHER(lane_words_t, cdf, first + base + next - 1);
            lane_words_t probe_high = GATHER(lane_words_t, cdf, first + base + step + next - 1);
            lane_longs_t taken = probe <= u;
            lane_words_t second = select(probe_low, probe_high, taken);
            base = select(base, base + step, convert_lane_ints(taken));
            base = select(base, base + next, convert_lane_ints(second <= u));
        } else {
            base = select(base, base + step, convert_lane_ints(probe <= u));
        }
        n = rest - next;
    }
    return base;
}

/* cdf_bin_position for the lanes' bins first + i; *bin gets lanes_cdf_bin of the same words. */
ALWAYS_INLINE lanes_t lanes_cdf_bin_position(__global const cdf_word_t *cdf, lane_ints_t first,
                                             lane_ints_t i, lane_words_t u, lanes_t *bin)
{
    lane_words_t upper = GATHER(lane_words_t, cdf, first + i);
    lane_words_t lower = GATHER(lane_words_t, cdf, first + max(i - 1, (lane_ints_t)0));
    lower = select((lane_words_t)0, lower, convert_lane_longs(i > 0));
    *bin = convert_lanes(upper - lower) * 0x1p-63f;
    return clamp(convert_lanes(u - lower) / convert_lanes(upper - lower), 0.0f, 0x1.fffffep-1f);
}

/* The unit direction through face-plane point (x, y) of each lane's face: lane_face_dir,
 * normalised. */
ALWAYS_INLINE lanes3_t lanes_face_direction(lane_ints_t face, lanes_t x, lanes_t y)
{
    lanes_t sign = select((lanes_t)1.0f, (lanes_t)-1.0f, (face & 1) != 0);
    lane_ints_t x_major = face < 2, y_major = (face == 2) | (face == 3);
    lanes_t dx = select(select(sign * x, x, y_major), sign, x_major);
    lanes_t dy = select(-y, sign, y_major);
    lanes_t dz = select(select(sign, sign * y, y_major), -sign * x, x_major);
    lanes_t k = 1.0f / sqrt(dx * dx + dy * dy + dz * dz);   /* vec3_normalize */
    return make_lanes3(dx * k, dy * k, dz * k);
}

/* lane_sample_face's direction for the lanes' faces and 63-bit points (ux, uy); *texel gets the
 * texel drawn and *p_texel its probability, lanes_light_pdf's product of the two bins, so a
 * caller whose direction falls back into that texel needs no second look-up of the CDFs. */
ALWAYS_INLINE lanes3_t lanes_sample_face(__global const cdf_word_t *marginal,
                                         __global const cdf_word_t *conditional, lane_ints_t face,
                                         int res, lane_words_t ux, lane_words_t uy,
                                         lane_ints_t *texel, lanes_t *p_texel)
{
    lane_ints_t rows = face * res;
    lane_ints_t row = lanes_cdf_search(marginal, rows, res, ux);
    lane_ints_t cols = (face * res + row) * res;
    lane_ints_t col = lanes_cdf_search(conditional, cols, res, uy);
    lanes_t row_bin, col_bin;
    lanes_t x = -1.0f + 2.0f * (convert_lanes(col) + lanes_cdf_bin_position(conditional, cols, col, uy, &col_bin)) / (float)res;
    lanes_t y = -1.0f + 2.0f * (convert_lanes(row) + lanes_cdf_bin_position(marginal, rows, row, ux, &row_bin)) / (float)res;
    *texel = cols + col;
    *p_texel = row_bin * col_bin;
    return lanes_face_direction(face, x, y);
}

#endif
