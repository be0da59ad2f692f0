/* `smc`: Ghosh et al. 2006 sequential Monte Carlo sampling as Kronander et al. §6 describe it;
 * the algorithm, its acceptance ratio and its re-initialisation rule are documented in smc.py.
 * One work item per covered pixel; its N particles live in global memory across frames:
 *   particles[p·N + i] = (ω_i, W_i)  (W normalised),  gammas[p·N + i].x = γ_{t−1}(ω_i) between
 *   frames (γ of the frame that placed the particle), state[p] = (Z, n, ·, ·) and
 *   carried_estimate[p] = the last estimate (n: the importance samples behind Z and the
 *   estimate, which a static frame averages with its fresh ones; smc.py). */
#include "sir.cl"

#define STREAM_SMC_MOVE 30u
#define STREAM_SMC_RESAMPLE 31u
#define STREAM_SMC_MAP_POINT 32u

/* The tempered target π_α = γ_{t−1}^{1−α} γ_t^α of one step (α = 1: γ_t itself). */
inline float tempered(float g0, float g1, float alpha)
{
    if (alpha >= 1.0f) return g1;
    if (!(g0 > 0.0f) || !(g1 > 0.0f)) return 0.0f;
    return exp((1.0f - alpha) * log(g0) + alpha * log(g1));
}

/* The kernel of move j = (step − 1)·N + i: 0 local, 1 independent from the map, 2 independent
 * from the BRDF.  Beatty sequences fix it (smc.py): of any run of moves a ν share is local,
 * and the independent ones alternate map, BRDF. */
inline int move_kind(int j, float nu)
{
    int local_before = (int)floor((float)j * nu);
    if ((int)floor((float)(j + 1) * nu) > local_before) return 0;
    return ((j - local_before) & 1) ? 2 : 1;
}

/* Systematic resampling of the pixel's particles in place (through the scratch copies). */
inline void resample_particles(__global float4 *particles, __global float2 *gammas,
                               __global float4 *scratch_p, __global float2 *scratch_g, int N, float u)
{
    acc_t total = 0, cumulative = 0;
    for (int i = 0; i < N; ++i) {
        scratch_p[i] = particles[i];
        scratch_g[i] = gammas[i];
        total += scratch_p[i].w;
    }
    int k = 0, last = 0;
    for (int i = 0; i < N && k < N; ++i) {
        float w = scratch_p[i].w;
        cumulative += w;
        if (w > 0.0f) last = i;
        while (k < N && w > 0.0f && systematic_position(k, N, u, total) < cumulative) {
            particles[k] = (float4)(scratch_p[i].xyz, 1.0f / (float)N);
            gammas[k++] = scratch_g[i];
        }
    }
    for (; k < N; ++k) {
        particles[k] = (float4)(scratch_p[last].xyz, 1.0f / (float)N);
        gammas[k] = scratch_g[last];
    }
}

__kernel void render_smc(__global const float4 *normal, __global const float4 *view,
                         __global const float4 *kd, __global const float4 *ks_m,
                         __global const float4 *env, __global const float4 *prev_env,
                         __global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                         __global const float *face_integral, const int res, const int N,
                         const int M_init, const float init_env_pick, const int steps,
                         const float nu, const float cos_delta, const float threshold,
                         const int have_state, const int static_frame, const uint seed,
                         const uint frame, __global float4 *all_particles,
                         __global float2 *all_gammas, __global float4 *all_scratch_p,
                         __global float2 *all_scratch_g, __global float4 *state,
                         __global float4 *carried_estimate, __global float4 *radiance,
                         __global float2 *counts, __global float4 *stats)
{
    int p = get_global_id(0);
    surface_t s = make_surface(normal[p], view[p], kd[p], ks_m[p]);
    __global float4 *particles = all_particles + (size_t)p * N;
    __global float2 *gammas = all_gammas + (size_t)p * N;
    __global float4 *scratch_p = all_scratch_p + (size_t)p * N;
    __global float2 *scratch_g = all_scratch_g + (size_t)p * N;

    /* MH's independent proposals (the map, the BRDF) and the (re-)init's BIS candidates. */
    sir_proposal_t q_map = make_proposal(marginal, conditional, face_integral, 1.0f);
    sir_proposal_t q_brdf = make_proposal(0, 0, 0, 0.0f);
    sir_proposal_t q_init = make_proposal(marginal, conditional, face_integral, init_env_pick);

    float4 carried = have_state ? state[p] : (float4)(0.0f);
    float z_prev = carried.x, z = z_prev, z_count = carried.y;
    int reinit = !(have_state && z_prev > 0.0f && isfinite(z_prev));
    float evaluations = 0.0f, ess_min = -1.0f, resampled = 0.0f;
    /* A static frame's independent MH proposals, n_map from the map and n_brdf from the BRDF
     * (fixed by the schedule), give a fresh estimate of Z_t, Σ γ_t(ω)/(n_map p_map(ω) +
     * n_brdf p_B(ω)) (multi-sample MIS, balance heuristic), from n_map + n_brdf samples. */
    acc_t fresh = 0, fresh_x = 0, fresh_y = 0, fresh_z = 0;
    int n_map = 0, n_brdf = 0;
    for (int j = 0; static_frame && j < steps * N; ++j) {
        int kind = particles[j % N].w > 0.0f ? move_kind(j, nu) : 0;
        n_map += kind == 1;
        n_brdf += kind == 2;
    }

    if (!reinit) {
        /* γ_t at the particles (g1); g0 = γ_{t−1} was stored by the previous frame.  On a
         * static frame γ_t = γ_{t−1}: nothing to evaluate, and no reweighting (Eq. 5's
         * increments are 1, Eq. 8 leaves Z unchanged). */
        float sum_sq = 0.0f;
        for (int i = 0; i < N; ++i) {
            float3 L;
            float2 g = gammas[i];
            g.y = static_frame ? g.x : sir_target(&s, env, res, particles[i].xyz, &L);
            gammas[i] = g;
            if (particles[i].w > 0.0f && !(g.x > 0.0f)) reinit = 1;   /* guard: γ_{t−1} = 0 */
            sum_sq += particles[i].w * particles[i].w;
        }
        if (!static_frame) evaluations += (float)N;
        ess_min = sum_sq > 0.0f ? 1.0f / sum_sq : 0.0f;
        for (int step = 1; step <= steps && !reinit; ++step) {
            float alpha = static_frame ? 1.0f : (float)step / (float)steps;
            if (!static_frame) {
                /* Reweight (Eq. 5, tempered): w_i = W_i (γ_t/γ_{t−1})(ω_i)^{1/steps}. */
                float sum = 0.0f;
                for (int i = 0; i < N; ++i) {
                    float4 q = particles[i];
                    float2 g = gammas[i];
                    float incr = (q.w > 0.0f && g.x > 0.0f) ? pow(g.y / g.x, 1.0f / (float)steps) : 0.0f;
                    q.w *= incr;
                    particles[i] = q;
                    sum += q.w;
                }
                z *= sum;                                   /* Eq. 8, one factor per step */
                if (!(sum > 0.0f) || !isfinite(sum) || !isfinite(z)) { reinit = 1; break; }
                sum_sq = 0.0f;
                for (int i = 0; i < N; ++i) {
                    float4 q = particles[i];
                    q.w /= sum;
                    particles[i] = q;
                    sum_sq += q.w * q.w;
                }
                float ess = 1.0f / sum_sq;
                ess_min = min(ess_min, ess);
                if (ess < 2.0f * (float)N / 3.0f) {
                    float u = rng_uniform4(seed, frame, STREAM_SMC_RESAMPLE, (uint)p, (uint)step, 0u).x;
                    resample_particles(particles, gammas, scratch_p, scratch_g, N, u);
                    resampled += 1.0f;
                }
            }
            /* One MH move targeting π_α (Eq. 6) with the mixture of kernels of smc.py. */
            for (int i = 0; i < N; ++i) {
                float4 q = particles[i];
                if (!(q.w > 0.0f)) continue;
                float2 g = gammas[i];
                float4 a = rng_uniform4(seed, frame, STREAM_SMC_MOVE, (uint)p, (uint)i, 2u * (uint)step);
                float4 b = rng_uniform4(seed, frame, STREAM_SMC_MOVE, (uint)p, (uint)i, 2u * (uint)step + 1u);
                float3 w = q.xyz, w_new;
                int kind = move_kind((step - 1) * N + i, nu);
                const sir_proposal_t *independent = kind == 1 ? &q_map : &q_brdf;
                float q_new = 0.0f;
                if (kind == 0)
                    w_new = direction_about(w, 1.0f - b.x * (1.0f - cos_delta), b.y);
                else
                    q_new = proposal_sample(&s, independent, res, (float4)(a.z, b.x, b.y, 0.0f),
                                            kind == 1 ? rng_words2(seed, frame, STREAM_SMC_MAP_POINT,
                                                                   (uint)p, (uint)i, (uint)step)
                                                      : (ulong2)(0), &w_new);
                float3 L;
                float g1_new = sir_target(&s, env, res, w_new, &L);
                float g0_new = static_frame ? g1_new : 0.0f;
                evaluations += 1.0f;
                if (alpha < 1.0f) {
                    g0_new = sir_target(&s, prev_env, res, w_new, &L);
                    evaluations += 1.0f;
                }
                if (static_frame && kind != 0 && g1_new > 0.0f) {
                    float mixture = (float)n_map * proposal_pdf(&s, &q_map, res, w_new)
                                  + (float)n_brdf * proposal_pdf(&s, &q_brdf, res, w_new);
                    float term = g1_new / mixture;
                    if (isfinite(term)) {
                        float3 f = term * sir_ratio(&s, w_new, L);   /* f/(n_map p_map + n_brdf p_B) */
                        fresh += (acc_t)term;
                        fresh_x += (acc_t)f.x;
                        fresh_y += (acc_t)f.y;
                        fresh_z += (acc_t)f.z;
                    }
                }
                float pi_new = tempered(g0_new, g1_new, alpha);
                float pi_old = tempered(g.x, g.y, alpha);
                float ratio;
                if (kind == 0) {
                    ratio = pi_new / pi_old;
                } else {
                    float q_old = proposal_pdf(&s, independent, res, w);
                    ratio = (pi_new * q_old) / (pi_old * q_new);
                }
                if (pi_new > 0.0f && (!(pi_old > 0.0f) || a.w < ratio)) {   /* NaN: reject */
                    particles[i] = (float4)(w_new, q.w);
                    gammas[i] = (float2)(g0_new, g1_new);
                }
            }
        }
        if (!reinit && !static_frame) {
            float ratio = z / z_prev;
            if (!(ratio <= threshold && ratio >= 1.0f / threshold)) reinit = 1;
        }
    }
    float3 estimate = have_state ? carried_estimate[p].xyz : (float3)(0.0f);
    if (reinit) {
        float3 sum, candidate_ratio;
        z = bis_pixel(&s, &q_init, env, res, M_init, N, seed, frame, (uint)p, &sum, particles,
                      gammas, &candidate_ratio);
        evaluations += (float)(M_init + N);
        for (int i = 0; i < N; ++i) gammas[i] = (float2)(gammas[i].x, gammas[i].x);
        /* The init's estimate: its candidates' (the resampling Rao-Blackwellised, sir.cl). */
        z_count = (float)M_init;
        estimate = z * candidate_ratio;
    } else if (static_frame && n_map + n_brdf > 0) {
        /* A static frame: Z_t = Z_{t−1} and the integral is last frame's; average both with the
         * fresh estimates, by sample counts. */
        acc_t n_fresh = (acc_t)(n_map + n_brdf), n_old = (acc_t)z_count, n_all = n_old + n_fresh;
        z = (float)((n_old * (acc_t)z + n_fresh * fresh) / n_all);
        estimate = (float3)((float)((n_old * (acc_t)estimate.x + n_fresh * fresh_x) / n_all),
                            (float)((n_old * (acc_t)estimate.y + n_fresh * fresh_y) / n_all),
                            (float)((n_old * (acc_t)estimate.z + n_fresh * fresh_z) / n_all));
        z_count = (float)n_all;
    }
    /* Eq. 7 on a changed map: L̂ = Z_t Σ_i W_i f(ω_i)/γ_t(ω_i).  γ_t is stored as next frame's
     * γ_{t−1}. */
    float3 ratio = (float3)(0.0f);
    float effective = 0.0f;
    for (int i = 0; i < N; ++i) {
        float4 q = particles[i];
        float2 g = gammas[i];
        if (q.w > 0.0f && g.y > 0.0f) {
            if (!reinit && !static_frame)
                ratio += q.w * sir_ratio(&s, q.xyz, env_radiance(env, res, q.xyz));
            effective += 1.0f;
        }
        gammas[i] = (float2)(g.y, 0.0f);
    }
    if (!reinit && !static_frame) {
        estimate = z * ratio;
        z_count = (float)N;        /* Eq. 7 rests on the N particles, whatever Z was built on */
        evaluations += (float)N;   /* f at the particles */
    }
    state[p] = (float4)(z, z_count, 0.0f, 0.0f);
    carried_estimate[p] = (float4)(estimate, 0.0f);
    float3 out = z > 0.0f ? estimate : (float3)(0.0f);
    radiance[p] = (float4)(out, 0.0f);
    counts[p] = (float2)(z > 0.0f ? (float)N : 0.0f, z > 0.0f ? effective : 0.0f);
    stats[p] = (float4)(ess_min, (float)(reinit && have_state), evaluations, resampled);
}
