/* `smc`: Ghosh et al. 2006 sequential Monte Carlo sampling as Kronander et al. §6 describe it;
 * the algorithm, its acceptance ratio and its re-initialisation rule are documented in smc.py.
 * Each pixel's N particles live in global memory across frames, as planes (sir.cl, store_planes):
 *   particles (ω_i, W_i) (W normalised) and gammas (γ_{t−1}(ω_i), ·) between frames (γ of the
 *   frame that placed the particle); state[p] = (Z, n, ·, ·) and carried_estimate[p] = the last
 *   estimate (n: the importance samples behind Z and the estimate, which a static frame averages
 *   with its fresh ones; smc.py).
 * Kernels per frame: smc_advance (every pixel that carries state: reweight, resample, MH
 * moves, the re-init test, Eq. 7), smc_list_reinit (the list of the pixels it flagged) and
 * smc_init, the BIS (re-)initialisation of the listed pixels (all of them on a first frame), in
 * lockstep groups over their list; before them, map_alias_pairs and map_alias_columns build the
 * map proposal's alias tables of the frame (sir.cl), and map_change compares the frame's map
 * distribution with last frame's (smc.py step 5).  Last frame's texels (radiance and map
 * probability) are kept: they are γ_{t−1}'s map.  ENV_RES, the map's face size, is a
 * compile-time constant (smc.py defines it).
 * smc_advance still runs one work item per pixel without LOCKSTEP (its loops exit early per
 * pixel), so PoCL does not vectorise it. */
/* The SMC target is γ·V: its MH moves and reweighting evaluate V (sir.cl). */
#define SIR_TARGET_VISIBILITY 1
#include "sir.cl"

#define STREAM_SMC_MOVE 30u
#define STREAM_SMC_RESAMPLE 31u
#define STREAM_SMC_MAP_POINT 32u

/* Component c of particle i from the planes of a pixel. */
static inline float plane_at(__global const float *planes, int N, int plane, int i, int c)
{
    return planes[(c * N + i) * plane];
}

static inline float4 load_particle(__global const float *planes, int N, int plane, int i)
{
    return (float4)(plane_at(planes, N, plane, i, 0), plane_at(planes, N, plane, i, 1),
                    plane_at(planes, N, plane, i, 2), plane_at(planes, N, plane, i, 3));
}

static inline void store_particle(__global float *planes, int N, int plane, int i, float4 q)
{
    store_planes(planes, N, plane, i, q.x, q.y, q.z, q.w);
}

static inline float2 load_gammas(__global const float *planes, int N, int plane, int i)
{
    return (float2)(plane_at(planes, N, plane, i, 0), plane_at(planes, N, plane, i, 1));
}

static inline void store_gammas(__global float *planes, int N, int plane, int i, float2 g)
{
    planes[i * plane] = g.x;
    planes[(N + i) * plane] = g.y;
}

static inline vec3_t particle_direction(float4 q) { return vec3(q.x, q.y, q.z); }

/* The tempered target π_α = γ_{t−1}^{1−α} γ_t^α of one step (α = 1: γ_t itself). */
static inline float tempered(float g0, float g1, float alpha)
{
    if (alpha >= 1.0f) return g1;
    if (!(g0 > 0.0f) || !(g1 > 0.0f)) return 0.0f;
    return exp((1.0f - alpha) * log(g0) + alpha * log(g1));
}

/* The kernel of move j = (step − 1)·N + i: 0 local, 1 independent from the map, 2 independent
 * from the BRDF.  Beatty sequences fix it (smc.py): of any run of moves a ν share is local,
 * and the independent ones alternate map, BRDF. */
static inline int move_kind(int j, float nu)
{
    int local_before = (int)floor((float)j * nu);
    if ((int)floor((float)(j + 1) * nu) > local_before) return 0;
    return ((j - local_before) & 1) ? 2 : 1;
}

/* Systematic resampling of the pixel's particles in place (through the scratch copies). */
static inline void resample_particles(__global float *particles, __global float *gammas,
                                      __global float *scratch_p, __global float *scratch_g, int N,
                                      int plane, float u)
{
    acc_t total = 0, cumulative = 0;
    for (int i = 0; i < N; ++i) {
        store_particle(scratch_p, N, plane, i, load_particle(particles, N, plane, i));
        store_gammas(scratch_g, N, plane, i, load_gammas(gammas, N, plane, i));
        total += plane_at(scratch_p, N, plane, i, 3);
    }
    int k = 0, last = 0;
    for (int i = 0; i < N && k < N; ++i) {
        float w = plane_at(scratch_p, N, plane, i, 3);
        cumulative += w;
        if (w > 0.0f) last = i;
        while (k < N && w > 0.0f && systematic_position(k, N, u, total) < cumulative) {
            float4 q = load_particle(scratch_p, N, plane, i);
            store_particle(particles, N, plane, k, (float4)(q.xyz, 1.0f / (float)N));
            store_gammas(gammas, N, plane, k++, load_gammas(scratch_g, N, plane, i));
        }
    }
    for (; k < N; ++k) {
        float4 q = load_particle(scratch_p, N, plane, last);
        store_particle(particles, N, plane, k, (float4)(q.xyz, 1.0f / (float)N));
        store_gammas(gammas, N, plane, k, load_gammas(scratch_g, N, plane, last));
    }
}

/* ---- the map proposal's alias tables (sir.cl), built each frame --------------------------------- */

/* The integer mass of bin i of a table of n slots (ALIAS_ONE each): its CDF width (the CDF
 * restarts every `run` bins) times its run's share (null: 1), scaled to n·ALIAS_ONE over the
 * table and rounded down, and at least 1 where the weight is positive. */
static inline ulong alias_base_mass(__global const cdf_word_t *cdf, int run, const acc_t *share, int n, int i)
{
    ulong width = cdf[i] - (i % run > 0 ? cdf[i - 1] : 0);
    ulong weight = share ? (ulong)((acc_t)width * share[i / run]) : width;
    ulong mass = mul_hi(weight, (ulong)n << 41);   /* weight·n·ALIAS_ONE/2^63: weights total 2^63 */
    return mass > 0 || weight == 0 ? mass : 1;
}

/* The table of n slots of the bins of alias_base_mass, whose masses the largest bin's correction
 * makes total exactly n·ALIAS_ONE (the correction is the rounding: under n units either way),
 * and each bin's probability, mass/(n·ALIAS_ONE), times `scale`, in probability[i·stride].
 * One work item, by a sweep of two cursors (light: the next bin of mass < ALIAS_ONE to fill;
 * heavy: the bin whose mass fills it, until what it has left is ≤ ALIAS_ONE and it fills its own
 * slot with that, the next heavy bin the rest): each slot is written once, in O(n). */
static inline void build_alias_table(__global const cdf_word_t *cdf, int run, const acc_t *share, int n,
                                     __global ulong *table, __global float *probability, int stride,
                                     float scale)
{
    ulong total = 0, largest = 0;
    int argmax = 0;
    for (int i = 0; i < n; ++i) {
        ulong mass = alias_base_mass(cdf, run, share, n, i);
        total += mass;
        argmax = mass > largest ? i : argmax;
        largest = max(largest, mass);
    }
    ulong correction = (ulong)n * ALIAS_ONE - total;   /* modulo 2^64: a negative one wraps back */
#define ALIAS_MASS(i) (alias_base_mass(cdf, run, share, n, (i)) + ((i) == argmax ? correction : 0))
    for (int i = 0; i < n; ++i)
        probability[i * stride] = (float)ALIAS_MASS(i) * (scale / (float)n * 0x1p-40f);
    int light = 0, heavy = 0;
    while (light < n && ALIAS_MASS(light) >= ALIAS_ONE) ++light;
    while (heavy < n && ALIAS_MASS(heavy) < ALIAS_ONE) ++heavy;
    ulong left = heavy < n ? ALIAS_MASS(heavy) : 0;   /* the heavy bin's mass not given out yet */
    while (heavy < n) {
        if (left > ALIAS_ONE && light < n) {
            ulong mass = ALIAS_MASS(light);
            table[light] = mass << ALIAS_INDEX_BITS | (ulong)heavy;
            left -= ALIAS_ONE - mass;
            do ++light; while (light < n && ALIAS_MASS(light) >= ALIAS_ONE);
        } else {
            int next = heavy + 1;
            while (next < n && ALIAS_MASS(next) < ALIAS_ONE) ++next;
            /* Exact masses leave the last heavy bin exactly ALIAS_ONE: a full slot. */
            int full = left >= ALIAS_ONE || next >= n;
            table[heavy] = full ? (ALIAS_ONE - 1) << ALIAS_INDEX_BITS | (ulong)heavy
                                : left << ALIAS_INDEX_BITS | (ulong)next;
            left = next < n ? ALIAS_MASS(next) - (full ? 0 : ALIAS_ONE - left) : 0;
            heavy = next;
        }
    }
#undef ALIAS_MASS
}

/* One work item: the pairs' table (face·R + row, P ∝ max(I_f, 0)·P(row|f), the marginal CDFs'
 * widths) into alias[0 … 6R − 1], the pairs' probabilities, and map_power = (Σ_f max(I_f, 0),
 * last frame's). */
__kernel void map_alias_pairs(__global const cdf_word_t *marginal, __global const float *face_integrals,
                              __global ulong *alias, __global float *pair_probability,
                              __global float *map_power)
{
    acc_t share[6], total = 0;
    for (int f = 0; f < 6; ++f) total += (acc_t)max(face_integrals[f], 0.0f);
    for (int f = 0; f < 6; ++f) share[f] = total > 0 ? (acc_t)max(face_integrals[f], 0.0f) / total : 0;
    build_alias_table(marginal, ENV_RES, share, 6 * ENV_RES, alias, pair_probability, 1, 1.0f);
    map_power[1] = map_power[0];
    map_power[0] = (float)total;
}

/* One work item per pair: its columns' table (P(col|f, row), the conditional CDF's widths) into
 * alias[6R + pair·R …], and its texels: the map's radiance, and in .w P(pair)·P(col|pair)·R²/4
 * (map_pdf), so that a candidate's radiance and map density share their cache lines. */
__kernel void map_alias_columns(__global const float4 *env, __global const cdf_word_t *conditional,
                                __global const float *pair_probability, __global ulong *alias,
                                __global float4 *texels)
{
    const int res = ENV_RES, pair = get_global_id(0);
    for (int col = 0; col < res; ++col)
        texels[pair * res + col] = (float4)(env[pair * res + col].xyz, 0.0f);
    build_alias_table(conditional + pair * res, res, 0, res, alias + 6 * res + pair * res,
                      (__global float *)(texels + pair * res) + 3, 4,
                      pair_probability[pair] * (float)(res * res) / 4.0f);
}

/* One work group (on a changed frame that carries state): map_power[2] = 1 + χ²(P_t ‖ P_{t−1}) =
 * Σ_x P_t(x)²/P_{t−1}(x) over the texels' map probabilities P (their .w is P·R²/4), this frame's
 * against last frame's: +∞ where a texel black last frame is lit now (smc.py step 5).  Each work
 * item sums every get_local_size(0)-th texel, and the group adds its partial sums in a tree in
 * local memory, a barrier before each level (a serial sum over the 6R² texels by one work item
 * kept a GPU's other cores idle).  Launched as one group of a power of two ≤ MAP_CHANGE_GROUP
 * (smc.py), the local array's size. */
__kernel void map_change(__global const float4 *texels, __global const float4 *prev_texels,
                         __global float *map_power)
{
    __local acc_t partial[MAP_CHANGE_GROUP];
    const int n = 6 * ENV_RES * ENV_RES, item = get_local_id(0), items = get_local_size(0);
    acc_t sum = 0;
    for (int i = item; i < n; i += items) {
        acc_t now = texels[i].w, before = prev_texels[i].w;
        if (now > 0) sum += before > 0 ? now * now / before : (acc_t)INFINITY;
    }
    partial[item] = sum;
    for (int width = items / 2; width > 0; width /= 2) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (item < width) partial[item] += partial[item + width];
    }
    if (item == 0)
        map_power[2] = (float)(partial[0] * (acc_t)(4.0f / (float)(ENV_RES * ENV_RES)));
}

/* Debug twin for the tests: map draw i of the tables (map_sample on pixel i's words of
 * STREAM_SMC_MAP_POINT) as the texel that holds its direction. */
__kernel void map_draws(__global const ulong *alias, const uint seed, __global int *texel)
{
    int i = get_global_id(0);
    sir_proposal_t q = {alias, 0, 1.0f};
    texel[i] = lane_texel(map_sample(&q, ENV_RES, lane_words2(seed, 0u, STREAM_SMC_MAP_POINT, (uint)i, 0u, 0u)),
                          ENV_RES);
}

/* One frame of every pixel that carries state (smc.py steps 2-6).  A pixel that needs a BIS
 * re-init gets reinit[p] = 1 and stats[p] = (smallest ESS, ·, evaluations so far, resamplings);
 * smc_init finishes it.  Every other pixel's outputs are final.  Launched in whole groups over
 * pixels get_global_offset(0) … (chunks.py); items past `count` do nothing. */
__kernel void smc_advance(__global const float4 *normal, __global const float4 *view,
                          __global const float4 *kd, __global const float4 *ks_m,
                          __global const uint *visibility, __global const float4 *env, __global const float4 *prev_texels,
                          __global const ulong *alias, __global const float4 *texels,
                          __global const float *map_power, const int count, const int N,
                          const int steps, const float nu, const float cos_delta,
                          const float threshold, const float map_ess, const int static_frame,
                          const uint seed, const uint frame, __global float *all_particles,
                          __global float *all_gammas, __global float *all_scratch_p,
                          __global float *all_scratch_g,
                          __global float4 *state, __global float4 *carried_estimate,
                          __global float4 *radiance, __global float2 *counts, __global float4 *stats,
                          __global int *reinit_flag, __global float *rays)
{
    const int res = ENV_RES, plane = count;
    int p = get_global_id(0);
    if (p >= count) return;   /* padding of the last launch to whole groups (smc.py) */
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    __global float *particles = all_particles + p, *gammas = all_gammas + p;
    __global float *scratch_p = all_scratch_p + p, *scratch_g = all_scratch_g + p;

    /* MH's independent proposals: the map and the BRDF. */
    sir_proposal_t q_map = make_proposal(alias, texels, map_power, 1.0f);
    sir_proposal_t q_brdf = make_proposal(0, 0, 0, 0.0f);

    float4 carried = state[p];
    float z_prev = carried.x, z = z_prev, z_count = carried.y;
    /* The map-level tests (smc.py step 5): the map's power left [1/threshold, threshold]× last
     * frame's, or turned on or off; or its distribution changed so much that particles drawn
     * from last frame's would keep an ESS N/(1 + χ²) under map_ess·N (NaN too; map_ess = 0: off). */
    float power = map_power[0], previous = map_power[1];
    int map_jumped = power > 0.0f && previous > 0.0f
        ? !(power / previous <= threshold && power / previous >= 1.0f / threshold) : power != previous;
    int map_moved = !static_frame && map_ess > 0.0f && !(map_ess * map_power[2] <= 1.0f);
    int reinit = map_jumped || map_moved || !(z_prev > 0.0f && isfinite(z_prev));
    /* rays: visibility queries at new directions (the MH proposals); γ_t at a particle, γ_{t−1}
     * at a proposal and f at the particles reuse a direction whose V is known. */
    float evaluations = 0.0f, ess_min = -1.0f, resampled = 0.0f, moves = 0.0f;
    /* A static frame's independent MH proposals, n_map from the map and n_brdf from the BRDF
     * (fixed by the schedule), give a fresh estimate of Z_t, Σ γ_t(ω)/(n_map p_map(ω) +
     * n_brdf p_B(ω)) (multi-sample MIS, balance heuristic), from n_map + n_brdf samples. */
    acc_t fresh = 0, fresh_x = 0, fresh_y = 0, fresh_z = 0;
    int n_map = 0, n_brdf = 0;
    for (int j = 0; static_frame && j < steps * N; ++j) {
        int kind = plane_at(particles, N, plane, j % N, 3) > 0.0f ? move_kind(j, nu) : 0;
        n_map += kind == 1;
        n_brdf += kind == 2;
    }

    if (!reinit) {
        /* γ_t at the particles (g1); g0 = γ_{t−1} was stored by the previous frame.  On a
         * static frame γ_t = γ_{t−1}: nothing to evaluate, and no reweighting (Eq. 5's
         * increments are 1, Eq. 8 leaves Z unchanged). */
        float sum_sq = 0.0f;
        for (int i = 0; i < N; ++i) {
            float4 q = load_particle(particles, N, plane, i);
            float2 g = load_gammas(gammas, N, plane, i);
            vec3_t L, w = particle_direction(q);
            g.y = static_frame ? g.x : sir_target(&s, env, res, w, phong_lobe_power(s.r, w, s.m), &L, visibility, p);
            store_gammas(gammas, N, plane, i, g);
            if (q.w > 0.0f && !(g.x > 0.0f)) reinit = 1;   /* guard: γ_{t−1} = 0 */
            sum_sq += q.w * q.w;
        }
        if (!static_frame) evaluations += (float)N;
        ess_min = sum_sq > 0.0f ? 1.0f / sum_sq : 0.0f;
        for (int step = 1; step <= steps && !reinit; ++step) {
            float alpha = static_frame ? 1.0f : (float)step / (float)steps;
            if (!static_frame) {
                /* Reweight (Eq. 5, tempered): w_i = W_i (γ_t/γ_{t−1})(ω_i)^{1/steps}. */
                float sum = 0.0f;
                for (int i = 0; i < N; ++i) {
                    float4 q = load_particle(particles, N, plane, i);
                    float2 g = load_gammas(gammas, N, plane, i);
                    /* (γ_t/γ_{t−1})^{1/steps} as exp(log(·)/steps): equal to float rounding, and
                     * PoCL's pow (an extended-precision log and exp) cost a quarter of the frame. */
                    float incr = (q.w > 0.0f && g.x > 0.0f) ? exp(log(g.y / g.x) / (float)steps) : 0.0f;
                    q.w *= incr;
                    store_particle(particles, N, plane, i, q);
                    sum += q.w;
                }
                z *= sum;                                   /* Eq. 8, one factor per step */
                if (!(sum > 0.0f) || !isfinite(sum) || !isfinite(z)) { reinit = 1; break; }
                sum_sq = 0.0f;
                for (int i = 0; i < N; ++i) {
                    float4 q = load_particle(particles, N, plane, i);
                    q.w /= sum;
                    store_particle(particles, N, plane, i, q);
                    sum_sq += q.w * q.w;
                }
                float ess = 1.0f / sum_sq;
                ess_min = min(ess_min, ess);
                if (ess < 2.0f * (float)N / 3.0f) {
                    float u = lane_uniform4(seed, frame, STREAM_SMC_RESAMPLE, (uint)p, (uint)step, 0u).x;
                    resample_particles(particles, gammas, scratch_p, scratch_g, N, plane, u);
                    resampled += 1.0f;
                }
            }
            /* One MH move targeting π_α (Eq. 6) with the mixture of kernels of smc.py. */
            for (int i = 0; i < N; ++i) {
                float4 q = load_particle(particles, N, plane, i);
                if (!(q.w > 0.0f)) continue;
                float2 g = load_gammas(gammas, N, plane, i);
                uniform4_t a = lane_uniform4(seed, frame, STREAM_SMC_MOVE, (uint)p, (uint)i, 2u * (uint)step);
                uniform4_t b = lane_uniform4(seed, frame, STREAM_SMC_MOVE, (uint)p, (uint)i, 2u * (uint)step + 1u);
                vec3_t w = particle_direction(q), w_new;
                int kind = move_kind((step - 1) * N + i, nu);
                const sir_proposal_t *independent = kind == 1 ? &q_map : &q_brdf;
                if (kind == 0) {
                    w_new = direction_about_axis(w, 1.0f - b.x * (1.0f - cos_delta), b.y);
                } else {
                    uniform4_t xi = {a.z, b.x, b.y, 0.0f};
                    words2_t none = {0, 0};
                    w_new = proposal_sample(&s, independent, res, xi,
                                            kind == 1 ? lane_words2(seed, frame, STREAM_SMC_MAP_POINT,
                                                                    (uint)p, (uint)i, (uint)step) : none);
                }
                float power_new = phong_lobe_power(s.r, w_new, s.m);
                vec3_t L, L_prev;
                float g1_new = sir_target(&s, env, res, w_new, power_new, &L, visibility, p);
                float g0_new = static_frame ? g1_new : 0.0f;
                evaluations += 1.0f;
                moves += 1.0f;
                if (alpha < 1.0f) {
                    g0_new = sir_target(&s, prev_texels, res, w_new, power_new, &L_prev, visibility, p);
                    evaluations += 1.0f;
                }
                if (static_frame && kind != 0 && g1_new > 0.0f) {
                    float mixture = (float)n_map * proposal_pdf(&s, &q_map, res, w_new, power_new)
                                  + (float)n_brdf * proposal_pdf(&s, &q_brdf, res, w_new, power_new);
                    float term = g1_new / mixture;
                    if (isfinite(term)) {
                        vec3_t f = vec3_scale(sir_ratio(&s, L, power_new), term);   /* f/(n_map p_map + n_brdf p_B) */
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
                    float q_new = proposal_pdf(&s, independent, res, w_new, power_new);
                    float q_old = proposal_pdf(&s, independent, res, w, phong_lobe_power(s.r, w, s.m));
                    ratio = (pi_new * q_old) / (pi_old * q_new);
                }
                if (pi_new > 0.0f && (!(pi_old > 0.0f) || a.w < ratio)) {   /* NaN: reject */
                    store_particle(particles, N, plane, i, (float4)(w_new.x, w_new.y, w_new.z, q.w));
                    store_gammas(gammas, N, plane, i, (float2)(g0_new, g1_new));
                }
            }
        }
        if (!reinit && !static_frame) {
            float ratio = z / z_prev;
            if (!(ratio <= threshold && ratio >= 1.0f / threshold)) reinit = 1;
        }
    }
    reinit_flag[p] = reinit;
    stats[p] = (float4)(ess_min, 0.0f, evaluations, resampled);
    rays[p] = moves;
    if (reinit) return;
    float3 estimate = carried_estimate[p].xyz;
    if (static_frame && n_map + n_brdf > 0) {
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
        float4 q = load_particle(particles, N, plane, i);
        float2 g = load_gammas(gammas, N, plane, i);
        if (q.w > 0.0f && g.y > 0.0f) {
            if (!static_frame) {
                vec3_t w = particle_direction(q);
                vec3_t f_over_gamma = sir_ratio(&s, env_radiance(env, res, w), phong_lobe_power(s.r, w, s.m));
                ratio += q.w * (float3)(f_over_gamma.x, f_over_gamma.y, f_over_gamma.z);
            }
            effective += 1.0f;
        }
        store_gammas(gammas, N, plane, i, (float2)(g.y, 0.0f));
    }
    if (!static_frame) {
        estimate = z * ratio;
        z_count = (float)N;        /* Eq. 7 rests on the N particles, whatever Z was built on */
        evaluations += (float)N;   /* f at the particles */
    }
    state[p] = (float4)(z, z_count, 0.0f, 0.0f);
    carried_estimate[p] = (float4)(estimate, 0.0f);
    float3 out = z > 0.0f ? estimate : (float3)(0.0f);
    radiance[p] = (float4)(out, 0.0f);
    counts[p] = (float2)(z > 0.0f ? (float)N : 0.0f, z > 0.0f ? effective : 0.0f);
    stats[p] = (float4)(ess_min, 0.0f, evaluations, resampled);
}

/* The pixels smc_advance flagged, in ascending order, into pixels[0 … listed[0] − 1]: one work
 * item's branch-free scan (tens of µs at 256²), so that smc_init takes its list from the device
 * and a frame needs no round trip to the host. */
__kernel void smc_list_reinit(__global const int *reinit_flag, const int count, __global int *pixels,
                              __global int *listed)
{
    int n = 0;
    for (int p = 0; p < count; ++p) {
        pixels[n] = p;   /* kept when flagged, overwritten by the next pixel otherwise */
        n += reinit_flag[p] != 0;
    }
    listed[0] = n;
}

/* BIS (re-)initialisation (smc.py step 1) of the pixels pixels[offset …  listed[0] − 1] (at most
 * the launch's size), in lockstep groups (sir.cl): N particles resampled from M candidates,
 * W = 1/N, Z = Ẑ, and the frame's estimate Ẑ·(the candidates' f/γ), the resampling
 * Rao-Blackwellised.  The list's length is the device's (smc_list_reinit): groups past it return
 * at once (all their work items alike, before any LOCKSTEP).
 * `have_state`: the pixel's stats already hold smc_advance's partial counts (else it starts
 * them); its re-init then counts in stats.y. */
__kernel void smc_init(__global const float4 *normal, __global const float4 *view,
                       __global const float4 *kd, __global const float4 *ks_m,
                       __global const uint *visibility, __global const float4 *texels, __global const ulong *alias,
                       __global const float *map_power,
                       const int count, const int N, const int M, const float init_env_pick,
                       const int have_state, const uint seed, const uint frame,
                       __global const int *pixels, __global const int *listed_total, const int offset,
                       __global int *chosen, __global acc_t *bounds, __global acc_t *sums,
                       __global float *all_particles, __global float *all_gammas,
                       __global float4 *state, __global float4 *carried_estimate,
                       __global float4 *radiance, __global float2 *counts, __global float4 *stats,
                       __global float *rays)
{
    /* Items past `listed` redo the last listed pixel in their own scratch slot (every work item
     * must reach the LOCKSTEPs) and store nothing: no particles (null planes), which the last
     * listed item writes and reads (the same values, but a data race all the same). */
    int listed = listed_total[0] - offset;
    if ((int)(get_group_id(0) * get_local_size(0)) >= listed) return;
    int item = get_global_id(0), p = pixels[offset + min(item, listed - 1)];
    __global float *particles = item < listed ? all_particles + p : 0, *gammas = all_gammas + p;
    vec3_t sum, candidate_ratio;
    float z = bis_pixel(normal, view, kd, ks_m, visibility, p, alias, texels, map_power, init_env_pick,
                        texels, ENV_RES, M, N, seed, frame, (uint)p, GROUP_SCRATCH(chosen, N),
                        GROUP_SCRATCH(bounds, M), GROUP_SCRATCH(sums, 3), get_local_id(0),
                        get_local_size(0), &sum,
                        particles, gammas, count, &candidate_ratio);
    if (item >= listed) return;
    float effective = 0.0f;
    for (int i = 0; i < N; ++i)
        effective += plane_at(particles, N, count, i, 3) > 0.0f && plane_at(gammas, N, count, i, 0) > 0.0f;
    /* The init's estimate: its candidates' (the resampling Rao-Blackwellised, sir.cl). */
    float3 estimate = z * (float3)(candidate_ratio.x, candidate_ratio.y, candidate_ratio.z);
    float4 before = have_state ? stats[p] : (float4)(-1.0f, 0.0f, 0.0f, 0.0f);
    state[p] = (float4)(z, (float)M, 0.0f, 0.0f);
    carried_estimate[p] = (float4)(estimate, 0.0f);
    radiance[p] = (float4)(z > 0.0f ? estimate : (float3)(0.0f), 0.0f);
    counts[p] = (float2)(z > 0.0f ? (float)N : 0.0f, z > 0.0f ? effective : 0.0f);
    stats[p] = (float4)(before.x, (float)have_state, before.z + (float)(M + N), before.w);
    rays[p] = (have_state ? rays[p] : 0.0f) + (float)M;   /* the candidates' V (γ·V); the N resampled reuse them */
}
