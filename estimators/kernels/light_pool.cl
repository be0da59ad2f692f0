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
inline float face_form_factor(float3 n, int face)
{
    float sum = 0.0f;
    for (int j = 0; j < 4; ++j) {
        float3 corner = face_uv_to_dir(face, (j & 1) ? 1.0f : -1.0f, (j & 2) ? 1.0f : -1.0f);
        sum += max(0.0f, dot(n, corner));
    }
    return sum * 0.57735026918962576f;   /* corners have length √3 */
}

/* Split `total` ticks among the faces in proportion to `weight`.  Cumulative rounding makes the
 * parts sum to exactly `total` (the running sum reaches the total sum bit-for-bit, in the same
 * order); a face of positive weight gets at least one tick, taken from the largest part, so no
 * face that can contribute is dropped.  The estimator divides by the ticks it actually uses,
 * so this rounding of μ_f (≤ a few ticks in Q·N_s) leaves it unbiased. */
inline void split_ticks(const float weight[6], int total, int ticks[6])
{
    float sum = 0.0f;
    for (int f = 0; f < 6; ++f) sum += weight[f];
    if (!(sum > 0.0f)) {
        for (int f = 0; f < 6; ++f) ticks[f] = 0;
        return;
    }
    float running = 0.0f;
    int previous = 0, largest = 0, deficit = 0;
    for (int f = 0; f < 6; ++f) {
        running += weight[f];
        /* The guards keep the parts non-negative and the last one exact even where the
         * device's division is not correctly rounded. */
        int cumulative = running >= sum ? total
                       : clamp((int)((float)total * (running / sum) + 0.5f), previous, total);
        ticks[f] = cumulative - previous;
        previous = cumulative;
        if (weight[f] > 0.0f && ticks[f] == 0) { ticks[f] = 1; ++deficit; }
        if (ticks[f] > ticks[largest]) largest = f;
    }
    ticks[largest] -= deficit;
}

/* Ticks of every strategy for a pixel: six light faces, then the BRDF.  `balanced_faces` picks
 * μ_f(n) of Eq. 3 (else μ_f = 1/6); `brdf_samples` gives half the budget to BRDF sampling
 * (Eq. 6).  Faces with zero luminance integral are never drawn (their ticks are dropped, so they
 * count neither as used nor in the MIS denominator; their integrand is zero). */
inline void strategy_ticks(float3 n, __global const float *face_integral, int spp,
                           int balanced_faces, int brdf_samples, int ticks[7])
{
    int total = spp * TICKS_PER_SAMPLE;
    int light_total = brdf_samples ? total / 2 : total;
    float weight[6];
    for (int f = 0; f < 6; ++f)
        weight[f] = balanced_faces ? face_form_factor(n, f) * face_integral[f] : 1.0f;
    split_ticks(weight, light_total, ticks);
    for (int f = 0; f < 6; ++f)
        if (!(face_integral[f] > 0.0f)) ticks[f] = 0;
    ticks[6] = total - light_total;
}

/* ---- shading (Algorithm 2) ------------------------------------------------------------------ */

typedef struct {
    float3 sum;
    int used, effective, evaluations;   /* ticks, ticks, samples */
} accumulator_t;

/* Add one sample of strategy weight β (in ticks): β·s(ω) / D(ω), where D(ω) = Σ_k t_k p_k(ω) is
 * the balance-heuristic denominator in ticks.  With counts N_k = t_k/Q this is
 * (1/N_s)·β_i·s/(Σ_k (N_k/N_s) p_k), i.e. Eq. 4 when only the light faces have ticks and Eq. 6
 * with the BRDF. */
inline void add_sample(accumulator_t *acc, const surface_t *s, int beta, float3 w, float3 radiance,
                       float denominator)
{
    float cosine = dot(s->n, w);
    acc->used += beta;
    acc->evaluations += 1;
    if (cosine > 0.0f && denominator > 0.0f) {
        acc->effective += beta;
        float3 value = phong_brdf(s->r, w, s->kd, s->ks, s->m) * cosine * radiance;
        acc->sum += ((float)beta / denominator) * value;
    }
}

/* Number of draws for t ticks and β (in ticks) of draw i: Eq. 5. */
inline int draws_for(int ticks) { return (ticks + TICKS_PER_SAMPLE - 1) / TICKS_PER_SAMPLE; }

inline int beta_ticks(int ticks, int i)
{
    return min(TICKS_PER_SAMPLE, ticks - i * TICKS_PER_SAMPLE);
}

/* Light samples of every face (Eq. 4, or the g_{f,i} of Eq. 6).  A pixel reads draws_for(t_f)
 * consecutive pool entries of face f from `offset` (0 for the shared sequence), wrapping at
 * pool_size; the pool holds at least that many (min() only guards memory).  One loop over all
 * the pixel's draws, not one per face: its trip count (≈ N_s whatever μ_f(n)) is nearly the same
 * for every pixel, so the work items of a vector or warp stay in step (Lu's Algorithm 2 bounds
 * the loop for the same reason). */
inline void shade_light_faces(accumulator_t *acc, const surface_t *s, const int ticks[7],
                              __global const float4 *pool_dir_pdf, __global const float4 *pool_radiance,
                              int pool_size, int offset)
{
    int draws[6], total = 0;
    for (int f = 0; f < 6; ++f) {
        draws[f] = min(draws_for(ticks[f]), pool_size);
        total += draws[f];
    }
    for (int j = 0, f = 0, i = 0; j < total; ++j, ++i) {
        while (i >= draws[f]) { ++f; i = 0; }
        int entry = f * pool_size + (offset + i) % pool_size;
        float4 dir_pdf = pool_dir_pdf[entry];
        float3 w = dir_pdf.xyz;
        float denominator = (float)ticks[f] * dir_pdf.w;
        if (ticks[6] > 0)
            denominator += (float)ticks[6] * phong_pdf(s->n, s->r, s->p_spec, s->m, w);
        add_sample(acc, s, beta_ticks(ticks[f], i), w, pool_radiance[entry].xyz, denominator);
    }
}

/* BRDF samples of Eq. 6 (f_i): the denominator holds the full light mixture, which is the one
 * face term t_{f(ω)}·pdf_L(ω|f(ω)) because pdf_L(ω|f) = 0 off face f. */
inline void shade_brdf(accumulator_t *acc, const surface_t *s, const int ticks[7],
                       __global const float4 *env, __global const cdf_word_t *marginal,
                       __global const cdf_word_t *conditional, int res, uint seed, uint frame, uint stream_pixel)
{
    int draws = draws_for(ticks[6]);
    for (int i = 0; i < draws; ++i) {
        float3 w;
        float3 xi = rng_uniform4(seed, frame, STREAM_BRDF, stream_pixel, (uint)i, 0u).xyz;
        float pdf_brdf = sample_phong(s->n, s->r, s->p_spec, s->m, xi, &w);
        int texel;
        float pdf_light = light_pdf(marginal, conditional, res, w, &texel);
        float denominator = (float)ticks[texel / (res * res)] * pdf_light + (float)ticks[6] * pdf_brdf;
        add_sample(acc, s, beta_ticks(ticks[6], i), w, env[texel].xyz, denominator);
    }
}

/* Density of all directions the estimator draws for one pixel, pooled over its strategies:
 * Σ_k t_k p_k(ω) / Σ_k t_k (what the χ² hooks check), given ω's light pdf on its face. */
inline float pooled_density(const surface_t *s, const int ticks[7], int face, float pdf_light,
                            float3 w)
{
    int total = ticks[6];
    for (int f = 0; f < 6; ++f) total += ticks[f];
    float density = (float)ticks[6] * phong_pdf(s->n, s->r, s->p_spec, s->m, w)
                  + (float)ticks[face] * pdf_light;
    return total > 0 ? density / (float)total : 0.0f;
}

/* pooled_density with ω's light pdf looked up from its texel (light_pdf of common.cl). */
inline float pooled_pdf(const surface_t *s, const int ticks[7], __global const cdf_word_t *marginal,
                        __global const cdf_word_t *conditional, int res, float3 w)
{
    int texel;
    float pdf_light = light_pdf(marginal, conditional, res, w, &texel);
    return pooled_density(s, ticks, texel / (res * res), pdf_light, w);
}

#endif
