/* `smc`: Ghosh et al. 2006 sequential Monte Carlo sampling as Kronander et al. §6 describe it;
 * the algorithm, its acceptance ratio and its re-initialisation rule are documented in smc.py.
 * One work item per covered pixel; its N particles live in global memory across frames:
 *   particles[p·N + i] = (ω_i, W_i)  (W normalised),  gammas[p·N + i].x = γ_{t−1}(ω_i) between
 *   frames (γ of the frame that placed the particle), state[p] = (Z_{t−1}, ·). */
#include "sir.cl"

#define STREAM_SMC_MOVE 30u
#define STREAM_SMC_RESAMPLE 31u

/* The tempered target π_α = γ_{t−1}^{1−α} γ_t^α of one step (α = 1: γ_t itself). */
inline float tempered(float g0, float g1, float alpha)
{
    if (alpha >= 1.0f) return g1;
    if (!(g0 > 0.0f) || !(g1 > 0.0f)) return 0.0f;
    return exp((1.0f - alpha) * log(g0) + alpha * log(g1));
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
                         __global const float *marginal, __global const float *conditional,
                         __global const float *face_integral, const int res, const int N,
                         const int M_init, const float init_env_pick, const int steps,
                         const float nu, const float cos_delta,
                         const float threshold, const int have_state, const uint seed,
                         const uint frame, __global float4 *all_particles,
                         __global float2 *all_gammas, __global float4 *all_scratch_p,
                         __global float2 *all_scratch_g, __global float2 *state,
                         __global float4 *radiance, __global float2 *counts, __global float4 *stats)
{
    int p = get_global_id(0);
    surface_t s = make_surface(normal[p], view[p], kd[p], ks_m[p]);
    __global float4 *particles = all_particles + (size_t)p * N;
    __global float2 *gammas = all_gammas + (size_t)p * N;
    __global float4 *scratch_p = all_scratch_p + (size_t)p * N;
    __global float2 *scratch_g = all_scratch_g + (size_t)p * N;

    /* MH's independent proposal q_I = ½ p_env + ½ p_B; the (re-)init's BIS candidates. */
    sir_proposal_t q_move = make_proposal(marginal, conditional, face_integral, 0.5f);
    sir_proposal_t q_init = make_proposal(marginal, conditional, face_integral, init_env_pick);

    float z_prev = have_state ? state[p].x : 0.0f;
    int reinit = !(have_state && z_prev > 0.0f && isfinite(z_prev));
    float evaluations = 0.0f, ess_min = -1.0f, resampled = 0.0f;
    float z = z_prev;

    if (!reinit) {
        /* γ_t at the particles (g1); g0 = γ_{t−1} was stored by the previous frame. */
        for (int i = 0; i < N; ++i) {
            float3 L;
            float2 g = gammas[i];
            g.y = sir_target(&s, env, res, particles[i].xyz, &L);
            gammas[i] = g;
            if (particles[i].w > 0.0f && !(g.x > 0.0f)) reinit = 1;   /* guard: γ_{t−1} = 0 */
        }
        evaluations += (float)N;
        ess_min = (float)N;
        for (int step = 1; step <= steps && !reinit; ++step) {
            float alpha = (float)step / (float)steps;
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
            float sum_sq = 0.0f;
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
            /* One MH move targeting π_α (Eq. 6) with the mixture of kernels of smc.py. */
            for (int i = 0; i < N; ++i) {
                float4 q = particles[i];
                if (!(q.w > 0.0f)) continue;
                float2 g = gammas[i];
                float4 a = rng_uniform4(seed, frame, STREAM_SMC_MOVE, (uint)p, (uint)i, 2u * (uint)step);
                float4 b = rng_uniform4(seed, frame, STREAM_SMC_MOVE, (uint)p, (uint)i, 2u * (uint)step + 1u);
                float3 w = q.xyz, w_new;
                int is_local = a.x < nu;
                float q_new = 0.0f;
                if (is_local)
                    w_new = direction_about(w, 1.0f - b.x * (1.0f - cos_delta), b.y);
                else
                    q_new = proposal_sample(&s, &q_move, res, (float4)(a.z, b.x, b.y, a.y), &w_new);
                float3 L;
                float g1_new = sir_target(&s, env, res, w_new, &L);
                float g0_new = 0.0f;
                evaluations += 1.0f;
                if (alpha < 1.0f) {
                    g0_new = sir_target(&s, prev_env, res, w_new, &L);
                    evaluations += 1.0f;
                }
                float pi_new = tempered(g0_new, g1_new, alpha);
                float pi_old = tempered(g.x, g.y, alpha);
                float ratio;
                if (is_local) {
                    ratio = pi_new / pi_old;
                } else {
                    float q_old = proposal_pdf(&s, &q_move, res, w);
                    ratio = (pi_new * q_old) / (pi_old * q_new);
                }
                if (pi_new > 0.0f && (!(pi_old > 0.0f) || a.w < ratio)) {   /* NaN: reject */
                    particles[i] = (float4)(w_new, q.w);
                    gammas[i] = (float2)(g0_new, g1_new);
                }
            }
        }
        if (!reinit) {
            float ratio = z / z_prev;
            if (!(ratio <= threshold && ratio >= 1.0f / threshold)) reinit = 1;
        }
    }
    if (reinit) {
        float3 sum;
        z = bis_pixel(&s, &q_init, env, res, M_init, N, seed, frame, (uint)p, &sum, particles, gammas);
        evaluations += (float)(M_init + N);
        for (int i = 0; i < N; ++i) gammas[i] = (float2)(gammas[i].x, gammas[i].x);
    }
    /* Eq. 7: L̂ = Z_t Σ W_i f(ω_i)/γ_t(ω_i), and γ_t stored as next frame's γ_{t−1}. */
    float3 estimate = (float3)(0.0f);
    float effective = 0.0f;
    for (int i = 0; i < N; ++i) {
        float4 q = particles[i];
        float2 g = gammas[i];
        if (q.w > 0.0f && g.y > 0.0f) {
            float3 L = env_radiance(env, res, q.xyz);
            estimate += q.w * sir_ratio(&s, q.xyz, L);
            effective += 1.0f;
        }
        gammas[i] = (float2)(g.y, 0.0f);
    }
    if (!reinit) evaluations += (float)N;   /* the BIS re-init already counted its N */
    state[p] = (float2)(z, 0.0f);
    float3 out = z > 0.0f ? z * estimate : (float3)(0.0f);
    radiance[p] = (float4)(out, 0.0f);
    counts[p] = (float2)(z > 0.0f ? (float)N : 0.0f, z > 0.0f ? effective : 0.0f);
    stats[p] = (float4)(ess_min, (float)(reinit && have_state), evaluations, resampled);
}
