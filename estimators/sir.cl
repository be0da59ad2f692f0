/* Sampling-importance-resampling shared by `bis` and `smc` (Kronander et al. §5, Burke 2005).
 *
 * Target (Kronander Eq. 3): γ(ω) = L_Y(ω) · ρ_Y(ω) · cos⁺(n, ω), the luminance of the radiance
 * times the luminance of the BRDF times the cosine; the integrand is f(ω) = L(ω) ρ(ω) cos⁺ (RGB,
 * no visibility: DESIGN §3's reference has none).  f/γ = L ρ / (L_Y ρ_Y) wherever γ > 0, and
 * γ = 0 ⇒ f = 0 (a non-negative colour of zero luminance is black), so γ covers f's support.
 *
 * BIS of one pixel (bis_pixel): M candidates ω_i ~ q (sir_proposal_t: Burke's p_B, the Phong
 * mixture of common.cl, or that mixed with map sampling), weights w_i = γ(ω_i)/q(ω_i),
 * Ẑ = (1/M) Σ w_i; N samples resampled from the candidates by
 * SYSTEMATIC resampling (one uniform u, positions (k + u)/N, k < N, on the normalised cumulative
 * weights: candidate i gets ⌊·⌋ or ⌈·⌉ of N·w_i/Σw copies, E[copies] = N·w_i/Σw exactly);
 * estimate (Eq. 4 with the candidates' Ẑ)  L̂ = Ẑ/N · Σ_k f(ω_k)/γ(ω_k).
 * Unbiased: given the candidates, E[f(ω_k)/γ(ω_k)] = Σ_i (w_i/Σw) f(ω_i)/γ(ω_i)
 * = Σ_i (f/q)(ω_i) / Σw, so E[L̂ | candidates] = (1/M) Σ_i f(ω_i)/q(ω_i), the plain
 * importance-sampling estimate, whose expectation is the integral.  (Kronander's Eq. 4 as printed
 * computes Ẑ from the resampled points, which is biased; Burke's and Talbot's use the candidates.)
 *
 * The candidates are not stored: a first pass sums their weights, a second regenerates the same
 * candidates (same Philox counters, same float operations in the same order) and walks the
 * cumulative sum, so memory is O(1) per pixel whatever M. */
#ifndef IBLBENCH_SIR_CL
#define IBLBENCH_SIR_CL

#include "common.cl"

#define STREAM_SIR_CANDIDATE 20u
#define STREAM_SIR_RESAMPLE 21u

/* Nearest-texel radiance of the map in direction w (DESIGN §3: piecewise constant). */
inline float3 env_radiance(__global const float4 *env, int res, float3 w)
{
    float s, t;
    int face = dir_to_face_st(w, &s, &t);
    return env[texel_index(face, clamp_index(t, res), clamp_index(s, res), res)].xyz;
}

/* ρ_Y(ω) = Y(ρ(ω)): ρ is kd/π + ks·lobe, and Y is linear. */
inline float phong_luminance(const surface_t *s, float3 w)
{
    float c = max(dot(s->r, w), 0.0f);
    float lobe = (c > 0.0f) ? (s->m + 2.0f) / (2.0f * IBL_PI) * exp2(s->m * log2(c)) : 0.0f;
    return s->rho_y_kd / IBL_PI + s->rho_y_ks * lobe;
}

/* γ(ω) of the map `env`; *radiance gets L(ω) (for f/γ). */
inline float sir_target(const surface_t *s, __global const float4 *env, int res, float3 w,
                        float3 *radiance)
{
    float cosine = dot(s->n, w);
    *radiance = env_radiance(env, res, w);
    if (!(cosine > 0.0f)) return 0.0f;
    return luminance(*radiance) * phong_luminance(s, w) * cosine;
}

/* f(ω)/γ(ω) = L ρ / (L_Y ρ_Y), for γ(ω) > 0. */
inline float3 sir_ratio(const surface_t *s, float3 w, float3 radiance)
{
    float3 rho = phong_brdf(s->r, w, s->kd, s->ks, s->m);
    return (radiance * rho) / (luminance(radiance) * phong_luminance(s, w));
}

/* The proposal candidates are drawn from: the BRDF mixture p_B (Burke, env_pick = 0) or, with
 * probability env_pick, the map (face f with probability μ_f = I_f/Σ I, then sample_face):
 * q(ω) = (1 − env_pick) p_B(ω) + env_pick μ_{f(ω)} pdf_L(ω|f(ω)) (pdf_L vanishes off face f). */
typedef struct {
    __global const cdf_word_t *marginal, *conditional;
    float mu[6];
    float env_pick;
} sir_proposal_t;

inline sir_proposal_t make_proposal(__global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                                    __global const float *face_integral, float env_pick)
{
    sir_proposal_t q;
    q.marginal = marginal;
    q.conditional = conditional;
    float total = 0.0f;
    for (int f = 0; f < 6; ++f) total += face_integral ? max(face_integral[f], 0.0f) : 0.0f;
    for (int f = 0; f < 6; ++f) q.mu[f] = total > 0.0f ? max(face_integral[f], 0.0f) / total : 0.0f;
    q.env_pick = total > 0.0f ? env_pick : 0.0f;   /* an all-black map: BRDF only */
    return q;
}

inline float proposal_pdf(const surface_t *s, const sir_proposal_t *q, int res, float3 w)
{
    float density = (1.0f - q->env_pick) * phong_pdf(s->n, s->r, s->p_spec, s->m, w);
    if (q->env_pick > 0.0f) {
        int texel;
        float pl = light_pdf(q->marginal, q->conditional, res, w, &texel);
        density += q->env_pick * q->mu[texel / (res * res)] * pl;
    }
    return density;
}

/* Does the draw with uniforms xi take the map (else the BRDF)? */
inline int proposal_uses_map(const sir_proposal_t *q, float4 xi)
{
    return q->env_pick > 0.0f && xi.w < q->env_pick;
}

/* A direction from q: xi.w picks the strategy, xi.x the face, xi.xyz a BRDF direction, and a
 * map direction takes its texel and point from the 63-bit words `point` (sample_face; only
 * read when proposal_uses_map).  Returns q(ω).  With env_pick = 0 this is exactly sample_phong
 * on xi.xyz (Burke's candidates). */
inline float proposal_sample(const surface_t *s, const sir_proposal_t *q, int res, float4 xi,
                             ulong2 point, float3 *w)
{
    if (!(q->env_pick > 0.0f)) return sample_phong(s->n, s->r, s->p_spec, s->m, xi.xyz, w);
    if (proposal_uses_map(q, xi)) {
        float cumulative = 0.0f;
        int face = 0;
        for (int f = 0; f < 6; ++f) {   /* the last face with μ > 0 takes any rounding remainder */
            if (q->mu[f] > 0.0f) face = f;
            cumulative += q->mu[f];
            if (xi.x < cumulative && q->mu[f] > 0.0f) break;
        }
        int texel;
        sample_face(q->marginal, q->conditional, face, res, point >> 1, w, &texel);
    } else {
        sample_phong(s->n, s->r, s->p_spec, s->m, xi.xyz, w);
    }
    return proposal_pdf(s, q, res, *w);
}

/* Candidate i of M: direction, and weight γ/q (0 where q or γ vanish or the ratio overflows).
 * The strategy is stratified, not drawn: candidate i comes from the map iff (i + ½)/M <
 * env_pick, so exactly env_pick·M candidates do (bis_pixel makes env_pick a multiple of 1/M).
 * That is the deterministic mixture (Veach's multi-sample MIS with the balance heuristic):
 * γ/q with the mixture q stays unbiased for fixed counts, without the binomial variance of a
 * random pick per candidate (√((1 − env_pick)/(M·env_pick)) relative, 7.9% at M = 160 and env_pick ½, on a small light
 * that only the map samples find). */
inline float sir_candidate(const surface_t *s, const sir_proposal_t *q,
                           __global const float4 *env, int res, uint seed, uint frame, uint pixel,
                           int i, int M, float3 *w, float *gamma, float3 *radiance)
{
    float4 xi = rng_uniform4(seed, frame, STREAM_SIR_CANDIDATE, pixel, (uint)i, 0u);
    xi.w = ((float)i + 0.5f) / (float)M;
    ulong2 point = proposal_uses_map(q, xi)
        ? rng_words2(seed, frame, STREAM_SIR_CANDIDATE, pixel, (uint)i, 1u) : (ulong2)(0);
    float pdf = proposal_sample(s, q, res, xi, point, w);
    *gamma = sir_target(s, env, res, *w, radiance);
    float weight = (pdf > 0.0f && *gamma > 0.0f) ? *gamma / pdf : 0.0f;
    return isfinite(weight) ? weight : 0.0f;
}

/* Systematic resampling position k of N on a total `total`: (k + u)·total/N. */
inline acc_t systematic_position(int k, int n, float u, acc_t total)
{
    return ((acc_t)k + (acc_t)u) * (total / (acc_t)n);
}

/* BIS of one pixel (see the header).  Returns Ẑ; *sum gets Σ_k f/γ over the N resampled
 * samples (0 when every weight is 0).  When `particles` is not null, resampled sample k is
 * written to particles[k] = (ω, 1/N) and gammas[k] = (γ(ω), 0).  When `candidate_ratio` is
 * not null it gets Σ_i w_i (f/γ)(ω_i) / Σ_i w_i over the candidates: Ẑ times it is
 * (1/M) Σ_i f/q = E[Ẑ/N Σ_k f/γ | candidates], the estimate with the resampling
 * Rao-Blackwellised. */
inline float bis_pixel(const surface_t *s, const sir_proposal_t *q, __global const float4 *env,
                       int res, int M, int N, uint seed, uint frame, uint pixel, float3 *sum,
                       __global float4 *particles, __global float2 *gammas, float3 *candidate_ratio)
{
    /* Compensated sums (double where the device has it): a zero-variance case (white furnace)
     * must not pick up M·ε of rounding.  Both passes accumulate identically. */
    sir_proposal_t stratified = *q;
    stratified.env_pick = round(q->env_pick * (float)M) / (float)M;
    kahan_t acc = {0, 0};
    acc_t ratio_x = 0, ratio_y = 0, ratio_z = 0;
    for (int i = 0; i < M; ++i) {
        float3 w, radiance;
        float gamma;
        float weight = sir_candidate(s, &stratified, env, res, seed, frame, pixel, i, M, &w, &gamma, &radiance);
        kahan_add(&acc, (acc_t)weight);
        if (candidate_ratio && weight > 0.0f) {
            float3 ratio = sir_ratio(s, w, radiance);
            ratio_x += (acc_t)weight * ratio.x;
            ratio_y += (acc_t)weight * ratio.y;
            ratio_z += (acc_t)weight * ratio.z;
        }
    }
    acc_t total = acc.sum;
    if (candidate_ratio)
        *candidate_ratio = total > 0 && isfinite(total)
            ? (float3)((float)(ratio_x / total), (float)(ratio_y / total), (float)(ratio_z / total))
            : (float3)(0.0f);
    *sum = (float3)(0.0f);
    if (!(total > 0.0f) || !isfinite(total)) {
        if (particles)
            for (int k = 0; k < N; ++k) {
                particles[k] = (float4)(s->n, 0.0f);
                gammas[k] = (float2)(0.0f);
            }
        return 0.0f;
    }
    float u = rng_uniform4(seed, frame, STREAM_SIR_RESAMPLE, pixel, 0u, 0u).x;
    kahan_t cumulative = {0, 0};
    float3 last_w = s->n, last_ratio = (float3)(0.0f);
    float last_gamma = 0.0f;
    int k = 0;
    for (int i = 0; i < M && k < N; ++i) {
        float3 w, radiance;
        float gamma;
        float weight = sir_candidate(s, &stratified, env, res, seed, frame, pixel, i, M, &w, &gamma, &radiance);
        kahan_add(&cumulative, (acc_t)weight);
        if (weight > 0.0f) {
            last_w = w;
            last_gamma = gamma;
            last_ratio = sir_ratio(s, w, radiance);
        }
        while (k < N && weight > 0.0f && systematic_position(k, N, u, total) < cumulative.sum) {
            *sum += last_ratio;
            if (particles) {
                particles[k] = (float4)(w, 1.0f / (float)N);
                gammas[k] = (float2)(gamma, 0.0f);
            }
            ++k;
        }
    }
    /* Float rounding can leave the last position(s) at or above the final cumulative sum: they
     * belong to the last candidate of positive weight. */
    for (; k < N; ++k) {
        *sum += last_ratio;
        if (particles) {
            particles[k] = (float4)(last_w, 1.0f / (float)N);
            gammas[k] = (float2)(last_gamma, 0.0f);
        }
    }
    return (float)(total / (acc_t)M);
}

/* Systematic resampling of n normalised weights (for the tests and SMC): out[k] = the index
 * of position (k + u)/n in the cumulative weights. */
inline void systematic_indices(__global const float *weights, int n, float u, __global int *out)
{
    acc_t total = 0, cumulative = 0;
    for (int i = 0; i < n; ++i) total += weights[i];
    int k = 0, last = 0;
    for (int i = 0; i < n && k < n; ++i) {
        cumulative += weights[i];
        if (weights[i] > 0.0f) last = i;
        while (k < n && weights[i] > 0.0f && systematic_position(k, n, u, total) < cumulative)
            out[k++] = i;
    }
    for (; k < n; ++k) out[k] = last;
}

#endif
