/* Sampling-importance-resampling shared by `bis` and `smc` (Kronander et al. §5, Burke 2005).
 *
 * Target (Kronander Eq. 3): γ(ω) = L_Y(ω) · ρ_Y(ω) · cos⁺(n, ω), the luminance of the radiance
 * times the luminance of the BRDF times the cosine; the integrand is f(ω) = L(ω) ρ(ω) cos⁺ V(x, ω)
 * (RGB; V = 1 in a scene without visibility).  Kronander's §5 target leaves V out, because V is
 * the expensive factor: so does `bis`, whose f/γ carries V, evaluated at the N resampled samples
 * only.  `smc` (SIR_TARGET_VISIBILITY = 1) targets γ·V, as its MH moves evaluate V (issue 22):
 * then f/γ needs no V.  f/γ = L ρ V / (L_Y ρ_Y) wherever γ > 0, and γ = 0 ⇒ f = 0 (a
 * non-negative colour of zero luminance is black), so γ covers f's support.
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
 * Only the candidates' cumulative weights are stored (bis_pixel): the resampled candidates are
 * regenerated from their Philox counters for f/γ.
 *
 * Speed (issue 10).  The M candidates, and then the N resampled ones regenerated, run in
 * explicit vectors, POOL_LANES per work item (sir_candidate_lanes).  The loop between them (the
 * resampled positions' searches) runs the same count in every work item, with
 * no early exit, ends each iteration at LOCKSTEP and uses common.cl's scalar helpers, so PoCL runs
 * the work items of a group as SIMD lanes (lanes.cl says why each rule matters).  Data-dependent
 * work is masked: each resampled position finds its candidate by a fixed-step binary search over
 * the candidates' cumulative sums, not by a walk over all M.  The pixel's shading is loaded once
 * (its scalars are carried across the barriers), the proposal is rebuilt after them (a struct
 * carried across would stop the vectorisation), and the specular lobe's power is computed once
 * per candidate and shared by q, γ and f/γ. */
#ifndef IBLBENCH_SIR_CL
#define IBLBENCH_SIR_CL

#include "lanes.cl"

#ifndef SIR_TARGET_VISIBILITY
#define SIR_TARGET_VISIBILITY 0
#endif

#define STREAM_SIR_CANDIDATE 20u
#define STREAM_SIR_RESAMPLE 21u

/* Nearest-texel radiance of the map in direction w (ARCHITECTURE.md §Conventions: piecewise constant). */
ALWAYS_INLINE vec3_t env_radiance(__global const float4 *env, int res, vec3_t w)
{
    return vec3_load(env, lane_texel(w, res));
}

/* ρ_Y = Y(ρ) = Y(kd)/π + Y(ks)·(m+2)/(2π)·power (Y is linear): from the luminances of kd and ks,
 * not of ρ's three channels, a sum the optimiser would fuse into a vector (lanes.cl). */
ALWAYS_INLINE float brdf_luminance(const shading_t *s, float power)
{
    return vec3_luminance(s->kd) / IBL_PI + vec3_luminance(s->ks) * ((s->m + 2.0f) / (2.0f * IBL_PI) * power);
}

/* γ(ω) of the map `env` at a direction of lobe power `power` (times V(x_p, ω) where
 * SIR_TARGET_VISIBILITY); *radiance gets L(ω) (for f/γ). */
ALWAYS_INLINE float sir_target(const shading_t *s, __global const float4 *env, int res, vec3_t w,
                      float power, vec3_t *radiance, __global const uint *visibility, int p)
{
    float cosine = vec3_dot(s->n, w);
    *radiance = env_radiance(env, res, w);
    int open = SIR_TARGET_VISIBILITY ? visible(visibility, p, w) : 1;
    return cosine > 0.0f && open ? vec3_luminance(*radiance) * brdf_luminance(s, power) * cosine : 0.0f;
}

/* f(ω)/γ(ω) = L ρ / (L_Y ρ_Y), for γ(ω) > 0. */
ALWAYS_INLINE vec3_t sir_ratio(const shading_t *s, vec3_t radiance, float power)
{
    vec3_t f = vec3_mul(radiance, phong_value(s->kd, s->ks, s->m, power));
    float gamma = vec3_luminance(radiance) * brdf_luminance(s, power);
    return vec3(f.x / gamma, f.y / gamma, f.z / gamma);
}

/* ---- the map proposal: alias tables (Walker 1977), built each frame by smc.cl -------------------
 * A map draw picks a texel in two alias draws: the pair (face, row) from one table of 6R slots,
 * P(f, row) ∝ max(I_f, 0)·P(row|f) (the frame cache's face integrals I_f and marginal CDFs), then
 * the column from that pair's table of R slots, P(col|f, row) (its conditional CDF), and a point
 * uniform in the texel's face square.  That is the distribution of "face f with probability
 * μ_f = I_f/Σ I, then sample_face" (ARCHITECTURE.md §Conventions's light pdf), drawn with two loads where the CDFs
 * need two binary searches of dependent loads.
 * The tables are exact in integers: every slot holds ALIAS_ONE (2^40) of mass, a bin's mass is
 * its CDF width scaled to n·ALIAS_ONE over the table (rounded down, at least 1 where the width is
 * positive, the rounding remainder given to the largest bin: so a texel of positive luminance
 * keeps a positive probability, as the fixed-point CDFs guarantee), and a bin of mass m is drawn
 * with probability m/(n·ALIAS_ONE), which the build stores (in the texels' .w): the density
 * evaluated is the one sampled.  Up to the uniformity of the 64-bit variates: the slot
 * ⌊r·n/2^64⌋ of a word r is uniform within n·2^-64, and the fraction r·n mod 2^64 that chooses
 * between a slot's two bins and places the point is a progression of step n, so a slot part of
 * t units is hit with relative error ≤ n/(t·2^24) (≤ 4e-4 at the smallest t = 1 and n = 6·1024).
 * An entry is one 64-bit word: threshold t << ALIAS_INDEX_BITS | alias; the slot's fraction
 * below t·2^-40 keeps the slot's own bin, the rest goes to the alias (a full slot has t = 2^40 − 1
 * and itself as alias). */
#define ALIAS_INDEX_BITS 24
#define ALIAS_ONE ((ulong)1 << 40)
#define ALIAS_INDEX_MASK (((ulong)1 << ALIAS_INDEX_BITS) - 1)

/* The proposal candidates are drawn from: the BRDF mixture p_B (Burke, env_pick = 0) or, with
 * probability env_pick, the map (the alias tables above):
 * q(ω) = (1 − env_pick) p_B(ω) + env_pick P(texel of ω)·(R²/4)·area_per_solid_angle(ω). */
typedef struct {
    __global const ulong *alias;       /* the pairs' table (6R), then each pair's columns' (R each) */
    __global const float4 *texels;     /* the map's radiance, and in .w P(texel)·R²/4 (map_pdf) */
    float env_pick;
} sir_proposal_t;

/* `alias` and `texels` as smc.cl's map_alias_pairs and map_alias_columns build them, or null
 * for the BRDF alone; map_power[0] is the map's Σ max(I_f, 0) (an all-black map: BRDF only). */
ALWAYS_INLINE sir_proposal_t make_proposal(__global const ulong *alias, __global const float4 *texels,
                                           __global const float *map_power, float env_pick)
{
    sir_proposal_t q;
    q.alias = alias;
    q.texels = texels;
    q.env_pick = map_power && map_power[0] > 0.0f ? env_pick : 0.0f;
    return q;
}

/* The bin of the alias table `table` of n slots for the 64-bit word r, and in *position a variate
 * uniform in [0, 1) given the bin: the slot's fraction within the part of the slot it fell in. */
ALWAYS_INLINE int alias_draw(__global const ulong *table, int n, ulong r, float *position)
{
    int slot = (int)mul_hi(r, (ulong)n);
    ulong fraction = r * (ulong)n;
    ulong entry = table[slot];
    ulong threshold = entry >> ALIAS_INDEX_BITS, split = threshold << ALIAS_INDEX_BITS;
    int own = fraction < split;
    float offset = (float)(own ? fraction : fraction - split);
    float width = (float)(own ? threshold : ALIAS_ONE - threshold) * 0x1p24f;
    *position = min(offset / width, 0x1.fffffep-1f);
    return own ? slot : (int)(entry & ALIAS_INDEX_MASK);
}

/* The face of the pair face·R + row: ⌊(pair + ½)/R⌋ in float, exact for 6R < 2^20 (½/R of margin
 * against a relative rounding of 2^-24), where an integer division of the lanes is no vector
 * instruction. */
ALWAYS_INLINE int pair_face(int pair, int res) { return (int)(((float)pair + 0.5f) / (float)res); }

/* A map direction from the 64-bit words `point` (x: the pair, y: the column). */
ALWAYS_INLINE vec3_t map_sample(const sir_proposal_t *q, int res, words2_t point)
{
    float x, y;
    int pair = alias_draw(q->alias, 6 * res, point.x, &y);
    int col = alias_draw(q->alias + 6 * res + pair * res, res, point.y, &x);
    int face = pair_face(pair, res);
    return vec3_normalize(lane_face_dir(face, -1.0f + 2.0f * ((float)col + x) / (float)res,
                                        -1.0f + 2.0f * ((float)(pair - face * res) + y) / (float)res));
}

/* The map's density at ω: P(texel of ω)·(R²/4)·(1 + u² + v²)^{3/2} (ARCHITECTURE.md §Conventions's light pdf). */
ALWAYS_INLINE float map_pdf(const sir_proposal_t *q, int res, vec3_t w)
{
    float s, t;
    int face = cube_face_st(w, &s, &t);
    return load_w(q->texels, texel_index(face, clamp_index(t, res), clamp_index(s, res), res))
         * area_per_solid_angle(2.0f * s - 1.0f, 2.0f * t - 1.0f);
}

/* q(ω), given ω's lobe power. */
ALWAYS_INLINE float proposal_pdf(const shading_t *s, const sir_proposal_t *q, int res, vec3_t w, float power)
{
    float density = (1.0f - q->env_pick) * phong_mixture_pdf(s->p_spec, s->m, vec3_dot(s->n, w), power);
    if (q->env_pick > 0.0f)
        density += q->env_pick * map_pdf(q, res, w);
    return density;
}

/* Does the draw with uniforms xi take the map (else the BRDF)? */
ALWAYS_INLINE int proposal_uses_map(const sir_proposal_t *q, uniform4_t xi)
{
    return q->env_pick > 0.0f && xi.w < q->env_pick;
}

/* A direction from q: xi.w picks the strategy, xi.xyz a BRDF direction, and a map direction
 * takes its texel and point from the 64-bit words `point` (map_sample; only read when
 * proposal_uses_map).  Its density is proposal_pdf.  With env_pick = 0 this is exactly
 * sample_phong on xi.xyz (Burke's candidates). */
ALWAYS_INLINE vec3_t proposal_sample(const shading_t *s, const sir_proposal_t *q, int res, uniform4_t xi,
                            words2_t point)
{
    vec3_t brdf = sample_phong_direction(s->n, s->r, s->p_spec, s->m, xi.x, xi.y, xi.z);
    float x = brdf.x, y = brdf.y, z = brdf.z;   /* scalars: a phi or select of structs becomes a vector */
    if (q->env_pick > 0.0f) {
        vec3_t w = map_sample(q, res, point);
        int map = proposal_uses_map(q, xi);
        x = map ? w.x : x;
        y = map ? w.y : y;
        z = map ? w.z : z;
    }
    return vec3(x, y, z);
}

/* Candidate i of M: direction, and weight γ/q (0 where q or γ vanish or the ratio overflows);
 * *gamma, *radiance and *power (its lobe power) serve f/γ.
 * The strategy is stratified, not drawn: candidate i comes from the map iff (i + ½)/M <
 * env_pick, so exactly env_pick·M candidates do (bis_pixel makes env_pick a multiple of 1/M).
 * That is the deterministic mixture (Veach's multi-sample MIS with the balance heuristic):
 * γ/q with the mixture q stays unbiased for fixed counts, without the binomial variance of a
 * random pick per candidate (√((1 − env_pick)/(M·env_pick)) relative, 7.9% at M = 160 and env_pick ½, on a small light
 * that only the map samples find). */
ALWAYS_INLINE float sir_candidate(const shading_t *s, const sir_proposal_t *q,
                         __global const float4 *env, int res, uint seed, uint frame, uint pixel,
                         int i, int M, vec3_t *w, float *gamma, vec3_t *radiance, float *power,
                         __global const uint *visibility, int p)
{
    uniform4_t xi = lane_uniform4(seed, frame, STREAM_SIR_CANDIDATE, pixel, (uint)i, 0u);
    xi.w = ((float)i + 0.5f) / (float)M;
    words2_t none = {0, 0};
    words2_t point = proposal_uses_map(q, xi)
        ? lane_words2(seed, frame, STREAM_SIR_CANDIDATE, pixel, (uint)i, 1u) : none;
    *w = proposal_sample(s, q, res, xi, point);
    *power = phong_lobe_power(s->r, *w, s->m);
    float pdf = proposal_pdf(s, q, res, *w, *power);
    *gamma = sir_target(s, env, res, *w, *power, radiance, visibility, p);
    float weight = (pdf > 0.0f && *gamma > 0.0f) ? *gamma / pdf : 0.0f;
    return isfinite(weight) ? weight : 0.0f;
}

/* The RGB of the lanes' texels of a float4 map. */
ALWAYS_INLINE lanes3_t lanes_radiance(__global const float *texels, lane_ints_t texel)
{
    return make_lanes3(GATHER(lanes_t, texels, 4 * texel), GATHER(lanes_t, texels, 4 * texel + 1),
                       GATHER(lanes_t, texels, 4 * texel + 2));
}

/* alias_draw for the lanes' words r, in the tables of n slots at table + first (per lane). */
ALWAYS_INLINE lane_ints_t alias_draw_lanes(__global const ulong *table, lane_ints_t first, int n,
                                           lane_words_t r, lanes_t *position)
{
    lane_words_t slot = mul_hi(r, (lane_words_t)n), fraction = r * (ulong)n;
    lane_words_t entry = GATHER(lane_words_t, table, first + convert_lane_ints(slot));
    lane_words_t threshold = entry >> ALIAS_INDEX_BITS, split = threshold << ALIAS_INDEX_BITS;
    lane_longs_t own = fraction < split;
    lanes_t offset = convert_lanes(select(fraction - split, fraction, own));
    lanes_t width = convert_lanes(select(ALIAS_ONE - threshold, threshold, own)) * 0x1p24f;
    *position = min(offset / width, 0x1.fffffep-1f);
    return convert_lane_ints(select(entry & ALIAS_INDEX_MASK, slot, own));
}

/* sir_candidate for the POOL_LANES candidates `index` in explicit vectors (lanes.cl), the same
 * arithmetic lane by lane: their weights (0 past M), their directions and γ, and in *ratio their
 * f/γ (sir_ratio; meaningful where the weight is positive). */
ALWAYS_INLINE lanes_t sir_candidate_lanes(const shading_t *s, const sir_proposal_t *q,
                                          __global const float4 *env, int res, uint seed, uint frame,
                                          uint pixel, lane_ints_t index, int M, lanes3_t *direction,
                                          lanes_t *target, lanes3_t *ratio,
                                          __global const uint *visibility, int p)
{
    lane_block_t block = rng_block_lanes(seed, frame, STREAM_SIR_CANDIDATE, pixel, convert_lane_uints(index), 0u);
    lanes_t xi_cos = lanes_unit(block.v[0]), xi_azimuth = lanes_unit(block.v[1]);
    lanes_t strategy = (convert_lanes(index) + 0.5f) / (float)M;
    /* The strategy is stratified (sir_candidate), so all the lanes of a block but one come from
     * the same strategy: a block samples only the strategies its lanes use. */
    lane_ints_t from_map = strategy < q->env_pick;
    lanes3_t w = splat_lanes3(s->n);
    if (!all(from_map)) {
        /* sample_phong_direction */
#if SPECULAR_LOBE
        lane_ints_t specular = lanes_unit(block.v[2]) < s->p_spec;
        lanes3_t axis = select_lanes3(splat_lanes3(s->n), splat_lanes3(s->r), specular);
        lanes_t cos_theta = select(sqrt(xi_cos), phong_power_lanes(xi_cos, (lanes_t)(1.0f / (s->m + 1.0f))), specular);
#else
        lanes3_t axis = splat_lanes3(s->n);
        lanes_t cos_theta = sqrt(xi_cos);
#endif
        w = direction_about_axis_lanes(axis, cos_theta, xi_azimuth);
    }
    if (any(from_map)) {
        /* map_sample */
        lane_block_t words = rng_block_lanes(seed, frame, STREAM_SIR_CANDIDATE, pixel, convert_lane_uints(index), 1u);
        lanes_t x, y;
        lane_ints_t pair = alias_draw_lanes(q->alias, 0, 6 * res, upsample(words.v[0], words.v[1]), &y);
        lane_ints_t col = alias_draw_lanes(q->alias + 6 * res, pair * res, res,
                                           upsample(words.v[2], words.v[3]), &x);
        lane_ints_t face = convert_lane_ints((convert_lanes(pair) + 0.5f) / (float)res);   /* pair_face */
        lanes_t row = convert_lanes(pair - face * res);
        lanes3_t map = lanes_face_direction(face, -1.0f + 2.0f * (convert_lanes(col) + x) / (float)res,
                                            -1.0f + 2.0f * (row + y) / (float)res);
        w = select_lanes3(w, map, from_map);
    }
    __global const float *texels = (__global const float *)env;
    lane_ints_t face, row, col, texel;
    lanes_t area;
    lanes3_t radiance;
    if (q->env_pick > 0.0f) {
        /* With map draws, the texel of w and its radiance first: the gather misses the cache
         * (the map draws spread over the map), and the lobe's power and the pdfs overlap it. */
        area = lanes_texel_of(res, w, &face, &row, &col);
        texel = (face * res + row) * res + col;
        radiance = lanes_radiance(texels, texel);
    }
    lanes_t power = phong_power_lanes(max(lanes_dot(s->r, w), 0.0f), (lanes_t)s->m);
    lanes_t cosine = lanes_dot(s->n, w);
    /* proposal_pdf */
    lanes_t pdf = (1.0f - q->env_pick) * phong_mixture_pdf_lanes(s->p_spec, s->m, cosine, power);
    if (q->env_pick > 0.0f) {
        /* map_pdf, from the cache lines of the radiance (`env` is q->texels in smc_init) */
        pdf += q->env_pick * GATHER(lanes_t, (__global const float *)q->texels + 3, 4 * texel) * area;
    } else {
        lanes_t u, v;
        face = cube_face_st_lanes(w, &u, &v);
        texel = (face * res + lanes_clamp_index(v, res)) * res + lanes_clamp_index(u, res);
        radiance = lanes_radiance(texels, texel);
    }
    /* sir_target and sir_ratio */
    lanes_t lobe = (s->m + 2.0f) / (2.0f * IBL_PI) * power;
    lanes_t rho_y = vec3_luminance(s->kd) / IBL_PI + vec3_luminance(s->ks) * lobe;
    lanes_t radiance_y = 0.2126f * radiance.x + 0.7152f * radiance.y + 0.0722f * radiance.z;
    lane_ints_t counted = cosine > 0.0f;
#if SIR_TARGET_VISIBILITY
    counted &= lanes_visible(visibility, p, w);
#endif
    lanes_t gamma = select((lanes_t)0.0f, radiance_y * rho_y * cosine, counted);
    lanes_t gamma_all = radiance_y * rho_y;
    *direction = w;
    *target = gamma;
    *ratio = make_lanes3(radiance.x * (s->kd.x / IBL_PI + s->ks.x * lobe) / gamma_all,
                         radiance.y * (s->kd.y / IBL_PI + s->ks.y * lobe) / gamma_all,
                         radiance.z * (s->kd.z / IBL_PI + s->ks.z * lobe) / gamma_all);
    lanes_t weight = select((lanes_t)0.0f, gamma / pdf, (pdf > 0.0f) & (gamma > 0.0f));
    return select((lanes_t)0.0f, weight, isfinite(weight) & (index < M));
}

/* Systematic resampling position k of N on a total `total`: (k + u)·total/N. */
ALWAYS_INLINE acc_t systematic_position(int k, int n, float u, acc_t total)
{
    return ((acc_t)k + (acc_t)u) * (total / (acc_t)n);
}

/* The pixel's inputs: its G-buffer entry p and the proposal's (make_proposal). */
#define SIR_PIXEL_ARGS __global const float4 *normal, __global const float4 *view, \
    __global const float4 *kd, __global const float4 *ks_m, __global const uint *visibility, int p, \
    __global const ulong *alias, __global const float4 *texels, __global const float *map_power, \
    float env_pick

/* A work item's scratch: chosen[k·stride + slot] the candidate chosen by resampled position k,
 * bounds[i·stride + slot] the largest cumulative weight of a candidate ≤ i of positive weight
 * (bis_pixel), and sums[c·stride + slot] the candidates' w·f/γ sums, per channel.  Slot-minor,
 * so the work items of a group read and write them as contiguous vectors; the sums live in
 * memory rather than in three variables across the LOCKSTEPs, which the optimiser would fuse
 * into a vector (lanes.cl). */
#define SIR_SCRATCH_ARGS __global int *chosen, __global acc_t *bounds, __global acc_t *sums, \
    int slot, int stride

/* A work group's block of a scratch buffer of `planes` planes: with slot = the local id and
 * stride = the group size, the group's candidates stay within a few pages (with the global id
 * and size, each candidate's plane was a page of its own). */
#define GROUP_SCRATCH(buffer, planes) ((buffer) + (size_t)get_group_id(0) * (size_t)(planes) * get_local_size(0))

/* SMC's particles, as planes (smc.cl): component c of particle i of a pixel lies at
 * planes[(c·N + i)·plane] from the pixel's base, so the work items of a group touch contiguous
 * words (a float4 per particle would be four adjacent stores, which the optimiser fuses into a
 * vector store that stops PoCL's vectorisation; lanes.cl).  The gammas have planes 0 and 1. */
ALWAYS_INLINE void store_planes(__global float *planes, int N, int plane, int i, float x, float y, float z, float w)
{
    planes[i * plane] = x;
    planes[(N + i) * plane] = y;
    planes[(2 * N + i) * plane] = z;
    planes[(3 * N + i) * plane] = w;
}

/* BIS of one pixel (see the header).  Returns Ẑ; *sum gets Σ_k f/γ over the N resampled
 * samples (0 when every weight is 0).  When `particles` is not null, resampled sample k is
 * written to the particle planes (store_planes) as (ω, 1/N) and to the gamma planes as
 * (γ(ω), 0).  When `candidate_ratio` is
 * not null it gets Σ_i w_i (f/γ)(ω_i) / Σ_i w_i over the candidates: Ẑ times it is
 * (1/M) Σ_i f/q = E[Ẑ/N Σ_k f/γ | candidates], the estimate with the resampling
 * Rao-Blackwellised.  Every work item of the group must call it (LOCKSTEP); `pixel` keys the
 * random streams.
 * Three passes: the M candidates, their weights' total and cumulative bounds stored; the N
 * resampled positions, each finding its candidate by a binary search of the bounds; the chosen
 * candidates regenerated (same Philox counters, same float operations) for f/γ.  So the device
 * evaluates M + N candidates, as `evaluations` counts, with M acc_t and N words of scratch. */
ALWAYS_INLINE float bis_pixel(SIR_PIXEL_ARGS, __global const float4 *env, int res, int M, int N, uint seed,
                     uint frame, uint pixel, SIR_SCRATCH_ARGS, vec3_t *sum,
                     __global float *particles, __global float *gammas, int plane,
                     vec3_t *candidate_ratio)
{
    /* The weights' total in double where the device has it (M float weights sum to within
     * M·2^-53), else compensated: a zero-variance case (white furnace) must not pick up M·ε of
     * rounding. */
    float stratified_pick = round(env_pick * (float)M) / (float)M;
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    acc_t total = 0, carry = 0;
    /* The candidates in explicit vectors, POOL_LANES at a time (lanes.cl; no LOCKSTEP: each work
     * item runs its own vector loop); their weights leave the lanes one by one, in the
     * candidates' order, into the total, the w·f/γ sums and bounds[i] = the largest cumulative
     * sum of a candidate i' ≤ i of positive weight (−1 before the first). */
    sir_proposal_t q = make_proposal(alias, texels, map_power, stratified_pick);
    acc_t ratio_x = 0, ratio_y = 0, ratio_z = 0, bound = -1;
    int last = 0;
    for (int i = 0; i < M; i += POOL_LANES) {
        lanes3_t direction, ratio;
        lanes_t gamma;
        float lane_weight[POOL_LANES], lane_x[POOL_LANES], lane_y[POOL_LANES], lane_z[POOL_LANES];
        lanes_t weight = sir_candidate_lanes(&s, &q, env, res, seed, frame, pixel, i + LANE_NUMBERS, M,
                                             &direction, &gamma, &ratio, visibility, p);
        /* f/γ zeroed where the weight is 0 (it may be NaN there), so that each candidate adds
         * w·f/γ without a branch: +0 for those, which leaves the sums as they were. */
        lane_ints_t positive = weight > 0.0f;
        vstore_lanes(weight, 0, lane_weight);
        vstore_lanes(select((lanes_t)0.0f, ratio.x, positive), 0, lane_x);
        vstore_lanes(select((lanes_t)0.0f, ratio.y, positive), 0, lane_y);
        vstore_lanes(select((lanes_t)0.0f, ratio.z, positive), 0, lane_z);
        for (int k = 0; k < min(POOL_LANES, M - i); ++k) {
            float w = lane_weight[k];
#ifdef HAVE_FP64
            total += (acc_t)w;
#else
            kahan_add_to(&total, &carry, (acc_t)w);
#endif
            last = w > 0.0f ? i + k : last;
            bound = w > 0.0f ? max(bound, total) : bound;
            bounds[(i + k) * stride + slot] = bound;
            if (candidate_ratio) {
                ratio_x += (acc_t)w * lane_x[k];
                ratio_y += (acc_t)w * lane_y[k];
                ratio_z += (acc_t)w * lane_z[k];
            }
        }
    }
    sums[slot] = ratio_x;
    sums[stride + slot] = ratio_y;
    sums[2 * stride + slot] = ratio_z;
    LOCKSTEP();
    int positive = total > 0 && isfinite(total);
    /* Systematic resampling: position k, (k + u)·Σw/N, takes the first candidate of positive
     * weight whose cumulative sum exceeds it, which is the first i with bounds[i] above it (a
     * binary search of ⌈log2 M⌉ steps, each a LOCKSTEP); positions that float rounding leaves at
     * or above every cumulative sum take the last candidate of positive weight, whose number
     * goes to chosen[k]. */
    float u = lane_uniform4(seed, frame, STREAM_SIR_RESAMPLE, pixel, 0u, 0u).x;
    int search_steps = 32 - clz(max(M - 1, 1));
    for (int k = N - 1; k >= 0; --k) {
        acc_t position = systematic_position(k, N, u, total);
        int base = 0, n = M;
        for (int step = 0; step < search_steps; ++step) {
            int width = n >> 1;
            base = width > 0 && bounds[(base + width - 1) * stride + slot] <= position ? base + width : base;
            n -= width;
            LOCKSTEP();
        }
        chosen[k * stride + slot] = positive && bounds[base * stride + slot] > position ? base : last;
        LOCKSTEP();
    }
    /* The chosen candidates regenerated for f/γ in explicit vectors, as the candidates' loop drew
     * them (same Philox counters, same float operations), and their f/γ summed from position
     * N − 1 down to 0. */
    acc_t sum_x = 0, sum_y = 0, sum_z = 0;
    for (int k0 = (N - 1) / POOL_LANES * POOL_LANES; k0 >= 0; k0 -= POOL_LANES) {
        sir_proposal_t q = make_proposal(alias, texels, map_power, stratified_pick);
        lanes3_t w, ratio;
        lanes_t gamma;
        lane_ints_t resampled = min(k0 + LANE_NUMBERS, (lane_ints_t)(N - 1));   /* vector bound: see POOL_LANES */
        lane_ints_t candidate = GATHER(lane_ints_t, chosen, resampled * stride + slot);
        sir_candidate_lanes(&s, &q, env, res, seed, frame, pixel, candidate, M, &w, &gamma, &ratio,
                            visibility, p);
#if !SIR_TARGET_VISIBILITY
        /* f's V at the resampled samples (the target has none). */
        lane_ints_t open = lanes_visible(visibility, p, w);
        ratio = make_lanes3(select((lanes_t)0.0f, ratio.x, open), select((lanes_t)0.0f, ratio.y, open),
                            select((lanes_t)0.0f, ratio.z, open));
#endif
        float lane_x[POOL_LANES], lane_y[POOL_LANES], lane_z[POOL_LANES];
        float lane_wx[POOL_LANES], lane_wy[POOL_LANES], lane_wz[POOL_LANES], lane_gamma[POOL_LANES];
        vstore_lanes(ratio.x, 0, lane_x);
        vstore_lanes(ratio.y, 0, lane_y);
        vstore_lanes(ratio.z, 0, lane_z);
        vstore_lanes(w.x, 0, lane_wx);
        vstore_lanes(w.y, 0, lane_wy);
        vstore_lanes(w.z, 0, lane_wz);
        vstore_lanes(gamma, 0, lane_gamma);
        for (int j = min(POOL_LANES, N - k0) - 1; j >= 0; --j) {
            sum_x += positive ? lane_x[j] : 0.0f;
            sum_y += positive ? lane_y[j] : 0.0f;
            sum_z += positive ? lane_z[j] : 0.0f;
            if (particles) {
                int k = k0 + j;
                store_planes(particles, N, plane, k, positive ? lane_wx[j] : s.n.x,
                             positive ? lane_wy[j] : s.n.y, positive ? lane_wz[j] : s.n.z,
                             positive ? 1.0f / (float)N : 0.0f);
                gammas[k * plane] = positive ? lane_gamma[j] : 0.0f;
                gammas[(N + k) * plane] = 0.0f;
            }
        }
    }
    *sum = vec3((float)sum_x, (float)sum_y, (float)sum_z);
    if (candidate_ratio)
        *candidate_ratio = positive ? vec3((float)(sums[slot] / total), (float)(sums[stride + slot] / total),
                                           (float)(sums[2 * stride + slot] / total))
                                    : vec3(0.0f, 0.0f, 0.0f);
    return positive ? (float)(total / (acc_t)M) : 0.0f;
}

/* Systematic resampling of n normalised weights (for the tests and SMC): out[k] = the index
 * of position (k + u)/n in the cumulative weights. */
static inline void systematic_indices(__global const float *weights, int n, float u, __global int *out)
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
