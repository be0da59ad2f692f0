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
inline ulong2 pool_point(int face, int i, uint seed, uint frame)
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
inline int light_ticks(int spp, int brdf_samples)
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

/* The sample loops run trip counts that depend on the budget alone, the same for every pixel,
 * and mask the draws past a pixel's own count: PoCL then runs each loop iteration across the
 * work items in SIMD (and a GPU's warp stays converged), which a per-pixel trip count or a
 * data-dependent branch prevents. */

/* The BRDF samples' running estimate.  The radiance sum accumulates in the output's colour planes
 * (R, G, B at sum[0], sum[plane], sum[2·plane]), not in three registers: PoCL's compiler first
 * pairs such x/y accumulators into 2-vectors (its early SLP pass), and the work-item vectoriser
 * then rejects the loop; planes an unknown stride apart are never paired.  (The compiler hoists
 * the pixel's plane addresses out of the sample loop, so the vector code gathers and scatters
 * them.)  The counts that do not depend on the samples (used ticks, evaluations) are set by the
 * kernel. */
typedef struct {
    __global float *sum;
    int plane;
    int effective;   /* ticks of the samples with a positive cosine and denominator */
} accumulator_t;

/* Add one sample of strategy weight β (in ticks) if `active`: β·s(ω) / D(ω), where
 * D(ω) = Σ_k t_k p_k(ω) is the balance-heuristic denominator in ticks.  With counts N_k = t_k/Q
 * this is (1/N_s)·β_i·s/(Σ_k (N_k/N_s) p_k), i.e. Eq. 4 when only the light faces have ticks
 * and Eq. 6 with the BRDF.  `power` is the lobe power cos⁺(r, ω)^m. */
ALWAYS_INLINE void add_sample(accumulator_t *acc, const shading_t *s, int active, int beta,
                              vec3_t w, float power, vec3_t radiance, float denominator)
{
    float cosine = vec3_dot(s->n, w);
    int counts = active && cosine > 0.0f && denominator > 0.0f;
    float weight = counts ? (float)beta / denominator * cosine : 0.0f;
    vec3_t value = vec3_scale(vec3_mul(phong_value(s->kd, s->ks, s->m, power), radiance), weight);
    acc->effective += counts ? beta : 0;
    acc->sum[0] += value.x;
    acc->sum[acc->plane] += value.y;
    acc->sum[2 * acc->plane] += value.z;
}

/* Number of draws for t ticks and β (in ticks) of draw i: Eq. 5. */
inline int draws_for(int ticks) { return (ticks + TICKS_PER_SAMPLE - 1) / TICKS_PER_SAMPLE; }

inline int beta_ticks(int ticks, int i)
{
    return min(TICKS_PER_SAMPLE, ticks - i * TICKS_PER_SAMPLE);
}

/* Draws of a light face with t ticks: draws_for(t), which the pool always holds (min() only
 * guards memory). */
inline int face_draws(int ticks, int pool_size) { return min(draws_for(ticks), pool_size); }

/* The sample counts of a pixel that its samples do not change: the β-weighted ticks of every
 * draw (Σ_i β_i = t for a strategy drawn in full) and the number of draws. */
inline void drawn_counts(const int ticks[7], int pool_size, int *used, int *draws)
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

/* ---- light samples in explicit vectors -------------------------------------------------------- */

/* A pixel's light samples run POOL_LANES draws at a time in explicit vectors (the lanes of one
 * work item are consecutive draws of one face), so they are SIMD on any device and compiler, not
 * only where PoCL vectorises across work items.  The pool is read as planes (pool_planes kernel):
 * x, y, z, pdf, R, G, B, each of POOL_PLANE_STRIDE(size) floats, face f's entries at
 * [2·size·f, 2·size·f + size) and again after them, so a pixel's window of draws from any
 * offset < size is contiguous (no wrap), and zeros past the last face pad the last lanes. */
#ifndef POOL_LANES
#define POOL_LANES 16
#endif
#if POOL_LANES == 16
typedef float16 lanes_t;
typedef int16 lane_ints_t;
#define vload_lanes vload16
#define convert_lanes convert_float16
#define phong_power_lanes phong_power16
#define phong_mixture_pdf_lanes phong_mixture_pdf16
#define LANE_NUMBERS ((int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define to8(v) ((v).lo + (v).hi)
#else
typedef float8 lanes_t;
typedef int8 lane_ints_t;
#define vload_lanes vload8
#define convert_lanes convert_float8
#define phong_power_lanes phong_power8
#define phong_mixture_pdf_lanes phong_mixture_pdf8
#define LANE_NUMBERS ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#define to8(v) (v)
#endif
#define POOL_PLANES 7
#define POOL_PLANE_STRIDE(size) (12 * (size) + 16)

/* Sums of a block's lanes, pairwise. */
inline float sum_of8(float8 v)
{
    float4 q = v.lo + v.hi;
    return (q.x + q.z) + (q.y + q.w);
}

inline int int_sum_of8(int8 v)
{
    int4 q = v.lo + v.hi;
    return (q.x + q.z) + (q.y + q.w);
}

/* A 3-vector of lanes and its dot product with a (per-pixel) vec3_t. */
typedef struct { lanes_t x, y, z; } lanes3_t;

ALWAYS_INLINE lanes_t lanes_dot(vec3_t a, lanes3_t b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

ALWAYS_INLINE lanes3_t lanes3_load(__global const float *plane0, int stride, int i)
{
    lanes3_t v = {vload_lanes(0, plane0 + i), vload_lanes(0, plane0 + stride + i),
                  vload_lanes(0, plane0 + 2 * stride + i)};
    return v;
}

/* Light samples of every face (Eq. 4, or the g_{f,i} of Eq. 6): face f's draws_for(t_f) draws
 * read consecutive pool entries from `offset` (0 for the shared sequence; offset < pool_size).
 * A draw adds β·s(ω)/D(ω) as add_sample does (D = Σ_k t_k p_k(ω), the balance denominator in
 * ticks; brdf_samples = 0 leaves the BRDF term out, t_6 = 0 there); lanes past the face's draws
 * are masked.  Returns the radiance sum; *effective gets the ticks of the samples that counted. */
ALWAYS_INLINE vec3_t shade_light_faces(const shading_t *s, const int ticks[7], int brdf_samples,
                                       __global const float *planes, int pool_size, int offset,
                                       int *effective)
{
    int stride = POOL_PLANE_STRIDE(pool_size);
    float lobe = (s->m + 2.0f) / (2.0f * IBL_PI);   /* phong_value's lobe factor */
    lanes_t sum_r = 0.0f, sum_g = 0.0f, sum_b = 0.0f;
    lane_ints_t counted = 0;
    for (int f = 0; f < 6; ++f) {
        int draws = face_draws(ticks[f], pool_size);
        float face_ticks = (float)ticks[f];
        int first = 2 * pool_size * f + offset;
        for (int i = 0; i < draws; i += POOL_LANES) {
            lanes3_t w = lanes3_load(planes, stride, first + i);
            lanes_t pdf = vload_lanes(0, planes + 3 * stride + first + i);
            lanes3_t radiance = lanes3_load(planes + 4 * stride, stride, first + i);
            /* β of Eq. 5, from the ticks left before this block (never overflows). */
            lane_ints_t beta = min(TICKS_PER_SAMPLE, ticks[f] - i * TICKS_PER_SAMPLE - LANE_NUMBERS * TICKS_PER_SAMPLE);
            lanes_t power = phong_power_lanes(max(lanes_dot(s->r, w), 0.0f), (lanes_t)s->m);
            lanes_t cosine = lanes_dot(s->n, w);
            lanes_t denominator = face_ticks * pdf;
            if (brdf_samples)
                denominator += (float)ticks[6] * phong_mixture_pdf_lanes(s->p_spec, s->m, cosine, power);
            lane_ints_t counts = (i + LANE_NUMBERS < draws) & (cosine > 0.0f) & (denominator > 0.0f);
            lanes_t weight = convert_lanes(beta) / denominator * cosine;
            lanes_t lobe_power = lobe * power;
            sum_r += select((lanes_t)0.0f, (s->kd.x / IBL_PI + s->ks.x * lobe_power) * radiance.x * weight, counts);
            sum_g += select((lanes_t)0.0f, (s->kd.y / IBL_PI + s->ks.y * lobe_power) * radiance.y * weight, counts);
            sum_b += select((lanes_t)0.0f, (s->kd.z / IBL_PI + s->ks.z * lobe_power) * radiance.z * weight, counts);
            counted += select((lane_ints_t)0, beta, counts);
        }
    }
    *effective = int_sum_of8(to8(counted));
    return vec3(sum_of8(to8(sum_r)), sum_of8(to8(sum_g)), sum_of8(to8(sum_b)));
}

/* BRDF samples of Eq. 6 (f_i): the denominator holds the full light mixture, which is the one
 * face term t_{f(ω)}·pdf_L(ω|f(ω)) because pdf_L(ω|f) = 0 off face f.  Every pixel draws
 * draws_for(t_6) samples (t_6 depends on the budget alone). */
ALWAYS_INLINE void shade_brdf(accumulator_t *acc, const shading_t *s, const int ticks[7],
                       __global const float4 *env, __global const cdf_word_t *marginal,
                       __global const cdf_word_t *conditional, int res, uint seed, uint frame, uint stream_pixel)
{
    int draws = draws_for(ticks[6]);
    for (int i = 0; i < draws; ++i) {
        philox4x32_ctr_t xi = rng_block(seed, frame, STREAM_BRDF, stream_pixel, (uint)i, 0u);
        vec3_t w = sample_phong_direction(s->n, s->r, s->p_spec, s->m, rng_unit(xi.v[0]),
                                          rng_unit(xi.v[1]), rng_unit(xi.v[2]));
        float power = phong_lobe_power(s->r, w, s->m);
        float pdf_brdf = phong_mixture_pdf(s->p_spec, s->m, vec3_dot(s->n, w), power);
        int face, texel;
        float pdf_light = light_pdf_on_face(marginal, conditional, res, w, &face, &texel);
        int face_ticks = ticks[0];
        #pragma unroll
        for (int k = 1; k < 6; ++k) face_ticks = face == k ? ticks[k] : face_ticks;
        float denominator = (float)face_ticks * pdf_light + (float)ticks[6] * pdf_brdf;
        add_sample(acc, s, 1, beta_ticks(ticks[6], i), w, power, vec3_load(env, texel), denominator);
    }
}

/* Density of all directions the estimator draws for one pixel, pooled over its strategies:
 * Σ_k t_k p_k(ω) / Σ_k t_k (what the χ² hooks check), given ω's light pdf on its face. */
inline float pooled_density(const shading_t *s, const int ticks[7], int face, float pdf_light,
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
inline float pooled_pdf(const shading_t *s, const int ticks[7], __global const cdf_word_t *marginal,
                        __global const cdf_word_t *conditional, int res, vec3_t w)
{
    int face, texel;
    float pdf_light = light_pdf_on_face(marginal, conditional, res, w, &face, &texel);
    return pooled_density(s, ticks, face, pdf_light, w);
}

#endif
