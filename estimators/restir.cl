/* `restir`: reservoir-based spatiotemporal importance resampling of the environment map (Bitterli
 * et al. 2020) with generalised RIS weights (Lin et al. 2022); the algorithm, its MIS weights and
 * its deviations are documented in restir.py.  Kernels per frame:
 *   restir_presample        the frame's tiles of light presamples, drawn by hierarchical.cl's
 *                           light sampler (descent.cl's descent through the luminance pyramid;
 *                           RTXDI's environment presampling);
 *   restir_target_scales    each pixel's MIS scale 1/Z̃ under the frame's map;
 *   restir_initial_temporal each chain's initial RIS over M candidates (light candidates from one
 *                           tile, BRDF candidates), combined with its reservoir of last frame: the
 *                           result is the next frame's history;
 *   restir_spatial_shade    each chain's reservoir combined with k neighbours' (of pass 1), and
 *                           shaded; POOL_LANES chains at a time in explicit lanes, a chain a
 *                           lane (pass 1 runs a chain's candidates in lanes).
 * A reservoir is two float4s: (ω, W) and (c, p̂, ·, ·): its sample, its unbiased contribution
 * weight W, its confidence c (the candidates behind it) and p̂ of its own pixel at ω under the
 * frame's map (the next frame's p̂_{t−1}(ω), no re-evaluation under the old map). */
/* sir.cl's map lookup and BRDF luminance (its γ with V is restir_target). */
#include "sir.cl"
#include "hierarchical.cl"

#define STREAM_RESTIR_CANDIDATE 50u
#define STREAM_RESTIR_REUSE 51u
#define MAX_NEIGHBOURS 8
/* RTXDI's spatial-reuse tests (its defaults): a neighbour whose normal is within acos 0.5 of the
 * pixel's and whose depth is within 10% of it. */
#define NORMAL_THRESHOLD 0.5f
#define DEPTH_THRESHOLD 0.1f

typedef struct {
    vec3_t w;
    float weight;       /* W: the unbiased contribution weight, 1/p̂-scaled */
    float confidence;   /* c */
    float target;       /* p̂ of the reservoir's pixel at w, this frame's map */
} reservoir_t;

/* Written through a pointer, not returned: an inlined struct return leaves an
 * llvm.experimental.noalias.scope.decl that Oclgrind 21.10 cannot run. */
ALWAYS_INLINE void load_reservoir(__global const float4 *sample, __global const float4 *info, int p, reservoir_t *r)
{
    r->w = vec3_load(sample, p);
    r->weight = load_w(sample, p);
    r->confidence = info[p].x;
    r->target = info[p].y;
}

ALWAYS_INLINE void store_reservoir(__global float4 *sample, __global float4 *info, int p, reservoir_t r)
{
    sample[p] = (float4)(r.w.x, r.w.y, r.w.z, r.weight);
    info[p] = (float4)(r.confidence, r.target, 0.0f, 0.0f);
}

/* p̂ without V (the biased mode's neighbour targets). */
ALWAYS_INLINE float target_without_visibility(const shading_t *s, __global const float4 *env, int res, vec3_t w)
{
    float cosine = vec3_dot(s->n, w);
    return cosine > 0.0f ? vec3_luminance(env_radiance(env, res, w)) * brdf_luminance(s, phong_lobe_power(s->r, w, s->m)) * cosine
                         : 0.0f;
}

/* p̂ = L_Y·ρ_Y·cos⁺·V of a pixel of shading s at w under the map env (V from pixel p's mask). */
ALWAYS_INLINE float restir_target(const shading_t *s, __global const float4 *env, int res, vec3_t w,
                                  __global const uint *visibility, int p)
{
    return visible(visibility, p, w) ? target_without_visibility(s, env, res, w) : 0.0f;
}

/* The frame's presamples: `tiles` × tile_size light directions by the pyramid's descent, as planes
 * x, y, z, density (solid angle) of n = global size × POOL_LANES floats.  Slot i of the planes is
 * draw i of presample stream 0: the tiles are consecutive runs of the one stream. */
__kernel void restir_presample(LIGHT_PARAMS, const int res, const uint seed,
                               const uint frame, __global float *presamples)
{
    int at = get_global_id(0) * POOL_LANES, n = get_global_size(0) * POOL_LANES;
    lane_ints_t texel;
    lanes_t pdf;
    light_state_t none = {0};   /* hierarchical's light sampler keeps no per-pixel state */
    lanes3_t w = lanes_sample_light(LIGHT_ARGS, &none, res, seed, frame, 0u, at + LANE_NUMBERS, &texel, &pdf);
    vstore_lanes(w.x, 0, presamples + at);
    vstore_lanes(w.y, 0, presamples + n + at);
    vstore_lanes(w.z, 0, presamples + 2 * n + at);
    vstore_lanes(pdf, 0, presamples + 3 * n + at);
}

/* The map's luminance power Σ Y·Ω: the pyramid's six face totals. */
ALWAYS_INLINE float map_power(__global const float *pyramid, int res)
{
    int top;
    descent_levels(res, &top);
    float power = 0.0f;
    for (int f = 0; f < 6; ++f) power += pyramid[top + f];
    return power;
}

#define SCALE_CELLS 2   /* the coarsest pyramid level of at most 2 × 2 cells a face */

/* The scale of pixel p's target under the frame's map in the MIS weights (restir.py): 1/Z̃, Z̃ a
 * deterministic stand-in for ∫p̂: over the pyramid's level of at most SCALE_CELLS² cells a face,
 * Σ the cell's Y·Ω times ρ_Y·cos⁺ at its centre; 1/the map's power where that is 0 (every lit
 * cell's centre below the horizon), and 0 for a black map (whose targets are all 0). */
__kernel void restir_target_scales(__global const float4 *normal, __global const float4 *view,
                                   __global const float4 *kd, __global const float4 *ks_m,
                                   __global const float *pyramid, const int res, __global float *scales)
{
    int p = get_global_id(0);
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    int level = 0;
    while (level_size(res, level) > SCALE_CELLS) ++level;
    int n = level_size(res, level), offset = 0;
    for (int l = 0; l < level; ++l) offset += 6 * level_size(res, l) * level_size(res, l);
    float total = 0.0f;
    for (int f = 0; f < 6; ++f) {
        for (int a = 0; a < n; ++a)
            for (int b = 0; b < n; ++b) {
                vec3_t w = vec3_normalize(vec3_of(face_uv_to_dir(f, (float)(2 * b + 1) / (float)n - 1.0f,
                                                                 (float)(2 * a + 1) / (float)n - 1.0f)));
                float cosine = vec3_dot(s.n, w);
                if (cosine > 0.0f)
                    total += pyramid[offset + (f * n + a) * n + b] * brdf_luminance(&s, phong_lobe_power(s.r, w, s.m)) * cosine;
            }
    }
    /* Clamped to float's normal range: a denormal or infinite Z̃ (1e30 texels) keeps a finite,
     * positive scale. */
    float normaliser = total > 0.0f ? total : map_power(pyramid, res);
    scales[p] = normaliser > 0.0f ? 1.0f / clamp(normaliser, FLT_MIN, FLT_MAX) : 0.0f;
}

/* The index i of the n non-negative `weights` (of sum `total`) with probability weights[i]/total
 * by the uniform u; -1 if none is positive (rounding at the top of the sum: the last positive). */
ALWAYS_INLINE int pick_by_weight(const float *weights, int n, float total, float u)
{
    float threshold = u * total, running = 0.0f;
    int chosen = -1;
    for (int i = 0; i < n; ++i) {
        running += weights[i];
        if (chosen < 0 && weights[i] > 0.0f && threshold < running) chosen = i;
    }
    if (chosen < 0)
        for (int i = 0; i < n; ++i) if (weights[i] > 0.0f) chosen = i;
    return chosen;
}

/* Y of the lanes' colours (vec3_luminance's arithmetic). */
ALWAYS_INLINE lanes_t lanes_luminance(lanes3_t c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }

/* One reservoir per lane over the lanes' candidates seen so far (Bitterli Alg. 2's streaming
 * update, each lane its own stream of candidates). */
typedef struct {
    lanes_t sum, target, x, y, z;
} lane_reservoirs_t;

/* Stream the lanes' candidates w (where `active`) into r.  Each is weighed by RIS with the
 * balance heuristic over the two candidate strategies (Talbot 2005; Veach's weights with counts):
 * w = m_s(ω)·p̂(ω)/p_s(ω), m_s = p̃_s / (M_L p̃_L + M_B p_B), with p_s the exact density of the
 * candidate's own strategy (a light candidate's presample density `presample_pdf`, the BRDF's
 * mixture pdf)
 * and p̃_L the MIS weights' light density: the texel's share of the pyramid's total times the
 * point's Jacobian (the density of the descent but for its fixed-point rounding, one load where
 * the exact density re-descends the pyramid).  The m_s are a partition of unity whatever p̃_L is,
 * so the weights stay RIS's; a candidate is kept with probability weight/sum by the uniforms u. */
ALWAYS_INLINE void stream_candidates(lane_reservoirs_t *r, const shading_t *s, __global const float4 *env,
                                     __global const float *pyramid, float inverse_total, int res, lanes3_t w,
                                     lanes_t presample_pdf, lane_ints_t is_light, lane_ints_t active, float light_count,
                                     float brdf_count, lanes_t u, __global const uint *visibility, int p)
{
    lanes_t cosine = lanes_dot(s->n, w);
    lanes_t power = phong_power_lanes(max(lanes_dot(s->r, w), 0.0f), (lanes_t)s->m);
    lane_ints_t face, row, col;
    lanes_t jacobian = lanes_texel_of(res, w, &face, &row, &col);
    lane_ints_t texel = (face * res + row) * res + col;
    lanes_t luminance = lanes_luminance(lanes_texel_radiance(env, texel));
    lanes_t rho = vec3_luminance(s->kd) / IBL_PI + vec3_luminance(s->ks) * ((s->m + 2.0f) / (2.0f * IBL_PI)) * power;
    lane_ints_t counted = active & (cosine > 0.0f);
    lanes_t target = select((lanes_t)0.0f, luminance * rho * cosine, counted & lanes_visible(visibility, p, w));
    lanes_t pdf_light = GATHER(lanes_t, pyramid, texel) * inverse_total * jacobian * (float)(res * res) * 0.25f;
    lanes_t pdf_brdf = phong_mixture_pdf_lanes(s->p_spec, s->m, cosine, power);
    lanes_t own = select(pdf_brdf, presample_pdf, is_light);
    lanes_t weight = target * select(pdf_brdf, pdf_light, is_light) / (own * (light_count * pdf_light + brdf_count * pdf_brdf));
    weight = select((lanes_t)0.0f, weight, (target > 0.0f) & (own > 0.0f) & isfinite(weight));
    r->sum += weight;
    lane_ints_t keep = (u * r->sum < weight);
    r->target = select(r->target, target, keep);
    r->x = select(r->x, w.x, keep);
    r->y = select(r->y, w.y, keep);
    r->z = select(r->z, w.z, keep);
}

/* Initial RIS (Talbot 2005; Bitterli Alg. 3) of one chain: M = light_count + brdf_count
 * candidates, candidate j < light_count read uniformly from one tile of presamples (the chain's,
 * drawn each frame), the others drawn from the Phong mixture, POOL_LANES at a time (a block
 * holds both kinds: every lane draws both directions and keeps its own), each weighted by
 * stream_candidates; one is kept with probability ∝ its weight.  W = Σ weights / p̂(kept),
 * c = M. */
ALWAYS_INLINE reservoir_t initial_reservoir(const shading_t *s, int p, __global const float4 *env, int res,
                                            __global const float *pyramid, __global const float *presamples,
                                            int presample_count, int tiles, int tile_size,
                                            int light_count, int brdf_count, float inverse_total, int chain,
                                            uint seed, uint frame, __global const uint *visibility)
{
    lane_reservoirs_t r = {(lanes_t)0.0f, (lanes_t)0.0f, (lanes_t)0.0f, (lanes_t)0.0f, (lanes_t)0.0f};
    philox4x32_ctr_t pick = rng_block(seed, frame, STREAM_RESTIR_REUSE, (uint)p, 0u, (uint)chain);
    int first = (int)(pick.v[0] & (uint)(tiles - 1)) * tile_size, count = light_count + brdf_count;
    __global const float *planes = presamples + first;
    vec3_t t_n, b_n, t_r, b_r;
    direction_about_axis_basis(s->n, &t_n, &b_n);
    direction_about_axis_basis(s->r, &t_r, &b_r);
    for (int i = 0; i < count; i += POOL_LANES) {
        lane_ints_t draw = i + LANE_NUMBERS, is_light = draw < light_count;
        lane_block_t xi = rng_block_lanes(seed, frame, STREAM_RESTIR_CANDIDATE, (uint)p, convert_lane_uints(draw),
                                          (uint)chain);
        lane_ints_t slot = convert_lane_ints(xi.v[0] & (uint)(tile_size - 1));
        lanes3_t light = make_lanes3(GATHER(lanes_t, planes, slot), GATHER(lanes_t, planes + presample_count, slot),
                                     GATHER(lanes_t, planes + 2 * presample_count, slot));
        lanes3_t brdf = lanes_brdf_draw(s, t_n, b_n, t_r, b_r, seed, frame, (uint)p, chain * count + draw);
        lanes3_t w = make_lanes3(select(brdf.x, light.x, is_light), select(brdf.y, light.y, is_light),
                                 select(brdf.z, light.z, is_light));
        stream_candidates(&r, s, env, pyramid, inverse_total, res, w, GATHER(lanes_t, planes + 3 * presample_count, slot),
                          is_light, draw < count,
                          (float)light_count, (float)brdf_count, lanes_unit(xi.v[1]), visibility, p);
    }
    /* The lanes' reservoirs merged: lane k with probability ∝ its sum (Bitterli Alg. 4, one target). */
    float sums[POOL_LANES], targets[POOL_LANES], xs[POOL_LANES], ys[POOL_LANES], zs[POOL_LANES];
    vstore_lanes(r.sum, 0, sums);
    vstore_lanes(r.target, 0, targets);
    vstore_lanes(r.x, 0, xs);
    vstore_lanes(r.y, 0, ys);
    vstore_lanes(r.z, 0, zs);
    float total = 0.0f;
    for (int k = 0; k < POOL_LANES; ++k) total += sums[k];
    int chosen = pick_by_weight(sums, POOL_LANES, total, rng_unit(pick.v[1]));
    reservoir_t out = {vec3(0.0f, 0.0f, 1.0f), 0.0f, (float)(light_count + brdf_count), 0.0f};
    if (chosen >= 0 && total > 0.0f && isfinite(total)) {
        out.w = vec3(xs[chosen], ys[chosen], zs[chosen]);
        out.target = targets[chosen];
        float weight = total / out.target;
        out.weight = isfinite(weight) ? weight : 0.0f;
    }
    return out;
}

/* Resampling of n reservoirs r (their samples reused unchanged: the identity shift, exact for
 * directions to a map at infinity, Jacobian 1) into one for domain 0.  targets[j·n + i] is
 * p̂_j(ω_i), domain j's target at input i's sample (its diagonal the inputs' own p̂); scales[j]
 * a positive constant of domain j (restir_target_scales).
 *   unbiased: GRIS (Lin et al. 2022) with the generalised balance heuristic and confidence
 *     weights c: w_i = m_i(ω_i)·p̂_0(ω_i)·W_i with
 *     m_i(ω) = c_i s_i p̂_i(ω) / Σ_j c_j s_j p̂_j(ω), which sum to 1 wherever p̂_0 > 0, and are
 *     0 for an input that cannot produce ω (p̂_i(ω) = 0);
 *   biased (the biased mode's spatial reuse): Bitterli Alg. 6's 1/Z combination without
 *     visibility in Z: w_i = p̂_0(ω_i)·W_i·c_i, W = Σ w / (p̂_0(ω)·Z(ω)), Z(ω) = Σ c_j over the
 *     domains j with p̂_j(ω) > 0, where the targets off row 0 are p̂_j without V
 *     (target_without_visibility): unbiased where no domain's V differs from another's, biased
 *     at shadow boundaries (Bitterli §4.3: Z needs visibility to be exact, which costs a shadow
 *     ray a neighbour).
 * The kept sample is input i with probability w_i/Σ w (uniform u); c = Σ c_i. */
ALWAYS_INLINE reservoir_t combine_reservoirs(const reservoir_t *r, const float *targets, const float *scales,
                                             int n, int unbiased, float u)
{
    float weights[MAX_NEIGHBOURS + 1], total = 0.0f, confidence = 0.0f;
    for (int i = 0; i < n; ++i) confidence += r[i].confidence;
    for (int i = 0; i < n; ++i) {
        float w = targets[i] * r[i].weight;
        if (unbiased) {
            float denominator = 0.0f;
            for (int j = 0; j < n; ++j) denominator += r[j].confidence * scales[j] * targets[j * n + i];
            w *= r[i].confidence * scales[i] * targets[i * n + i] / denominator;
        } else {
            w *= r[i].confidence;
        }
        weights[i] = w > 0.0f && isfinite(w) ? w : 0.0f;
        total += weights[i];
    }
    int chosen = pick_by_weight(weights, n, total, u);
    reservoir_t out = {r[0].w, 0.0f, confidence, 0.0f};
    if (chosen >= 0 && isfinite(total)) {
        out.w = r[chosen].w;
        out.target = targets[chosen];
        float normaliser = 1.0f;   /* Z(ω) of the biased combination */
        if (!unbiased) {
            normaliser = 0.0f;
            for (int j = 0; j < n; ++j) normaliser += targets[j * n + chosen] > 0.0f ? r[j].confidence : 0.0f;
        }
        float weight = total / (out.target * normaliser);
        out.weight = isfinite(weight) ? weight : 0.0f;
    }
    return out;
}

/* Pass 1: each pixel's initial reservoir of each chain, combined with that chain's history (last
 * frame's pass-1 reservoir, its confidence capped at history_cap × this frame's M) where
 * `temporal`.  Under GRIS the history's sample is weighed with p̂_{t−1} of this pixel under last
 * frame's map (prev_env), so a map that changed, or switched, keeps the estimator unbiased; each
 * domain's target scaled by the pixel's restir_target_scales under its map (`scales`, `prev_scales`).  Chain c of pixel
 * p is slot c·n + p of the reservoir buffers (n: the G-buffer's launch_size; a launch covers part of it,
 * chunks.py).  stats[p] gets (evaluations,
 * ·, ·, shadow rays: the evaluations with V), summed over the chains. */
__kernel void restir_initial_temporal(__global const float4 *normal, __global const float4 *view,
                                      __global const float4 *kd, __global const float4 *ks_m,
                                      __global const uint *visibility, const int n, __global const float4 *env,
                                      __global const float4 *prev_env, __global const float *pyramid,
                                      __global const float *presamples, __global const float *scales,
                                      __global const float *prev_scales, const int res,
                                      const int presample_count, const int tiles, const int tile_size,
                                      const int light_count, const int brdf_count, const int chains,
                                      const int temporal, const float history_cap,
                                      const uint seed, const uint frame, __global const float4 *history_sample,
                                      __global const float4 *history_info, __global float4 *out_sample,
                                      __global float4 *out_info, __global float4 *stats)
{
    int p = get_global_id(0);
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    /* Last frame's scale is read only where there is a last frame (`temporal`).  The history's
     * confidence is scaled by min(Z̃_t/Z̃_{t−1}, Z̃_{t−1}/Z̃_t) (restir.py): a map that lost or
     * gained most of the pixel's light leaves the history few samples where the light now is;
     * none where either map is black to the pixel. */
    float domain_scales[2] = {scales[p], temporal ? prev_scales[p] : 0.0f};
    float history_share = domain_scales[0] > 0.0f && domain_scales[1] > 0.0f
                          ? min(domain_scales[1] / domain_scales[0], domain_scales[0] / domain_scales[1]) : 0.0f;
    float evaluations = 0.0f, shadow_rays = 0.0f, power = map_power(pyramid, res);
    float inverse_total = power > 0.0f ? 1.0f / power : 0.0f;   /* the MIS weights' light density's */
    for (int c = 0; c < chains; ++c) {
        reservoir_t current = initial_reservoir(&s, p, env, res, pyramid, presamples, presample_count, tiles,
                                                tile_size, light_count, brdf_count, inverse_total, c, seed, frame,
                                                visibility);
        evaluations += (float)(light_count + brdf_count);
        shadow_rays += (float)(light_count + brdf_count);
        if (temporal) {
            reservoir_t inputs[2];
            inputs[0] = current;
            load_reservoir(history_sample, history_info, c * n + p, &inputs[1]);
            inputs[1].confidence = min(inputs[1].confidence, history_cap * current.confidence) * history_share;
            float targets[4] = {current.target, restir_target(&s, env, res, inputs[1].w, visibility, p),
                                restir_target(&s, prev_env, res, current.w, visibility, p), inputs[1].target};
            evaluations += 2.0f;
            shadow_rays += 2.0f;
            philox4x32_ctr_t u = rng_block(seed, frame, STREAM_RESTIR_REUSE, (uint)p, 0u, (uint)c);
            current = combine_reservoirs(inputs, targets, domain_scales, 2, 1, rng_unit(u.v[2]));
        }
        store_reservoir(out_sample, out_info, c * n + p, current);
    }
    stats[p] = (float4)(evaluations, 0.0f, 0.0f, shadow_rays);
}

/* Neighbour j of chain c of pixel p (image position `at` of a width × height image): a pixel
 * uniform in the disc of `radius` pixels about it, clamped to the image, not p itself, covered,
 * and passing RTXDI's normal and depth tests; -1 if none. */
ALWAYS_INLINE int spatial_neighbour(int p, int at, int width, int height, float radius, uint seed, uint frame,
                                    int c, int j, __global const int *pixel_at, __global const float4 *normal,
                                    __global const float *depth)
{
    philox4x32_ctr_t xi = rng_block(seed, frame, STREAM_RESTIR_REUSE, (uint)p, (uint)(1 + j), (uint)c);
    float sine, cosine, distance = radius * sqrt(rng_unit(xi.v[0]));
    sincos_turn(rng_unit(xi.v[1]), &sine, &cosine);
    int x = clamp(at % width + (int)rint(distance * cosine), 0, width - 1);
    int y = clamp(at / width + (int)rint(distance * sine), 0, height - 1);
    int q = pixel_at[y * width + x];
    if (q < 0 || q == p) return -1;
    if (vec3_dot(vec3_load(normal, p), vec3_load(normal, q)) < NORMAL_THRESHOLD) return -1;
    if (fabs(depth[q] - depth[p]) > DEPTH_THRESHOLD * depth[p]) return -1;
    return q;
}

/* The scalar path's loop over a domain's targets stays a scalar loop: it has at most 9 passes, and
 * LLVM's loop vectoriser (which takes it once nothing else is in it) made a lone chain 10% slower
 * (PoCL on AVX2). */
#ifdef __clang__
#define NO_VECTORIZE _Pragma("clang loop vectorize(disable)")
#else
#define NO_VECTORIZE
#endif

/* Spatial reuse's work over `count` inputs (the pixel's and its neighbours'): *evaluations and
 * *shadow_rays grow by the targets p̂_j(ω_i), i ≠ j, it evaluates and those with V (the biased Z's
 * support tests leave V out). */
ALWAYS_INLINE void count_reuse(int count, int unbiased, float *evaluations, float *shadow_rays)
{
    for (int j = 0; j < count; ++j)
        for (int i = 0; i < count; ++i) {
            int visible_too = unbiased || j == 0;
            *evaluations += i != j ? 1.0f : 0.0f;
            *shadow_rays += i != j && visible_too ? 1.0f : 0.0f;
        }
}

/* Chain c of pixel p's reservoir of pass 1 combined with up to `neighbours` neighbours' of the
 * same chain (also of pass 1, so no pixel reads what another writes); *evaluations, *shadow_rays
 * and *reused grow by the targets evaluated, those with V, and the neighbours found. */
ALWAYS_INLINE reservoir_t spatial_reuse(__global const float4 *normal, __global const float4 *view,
                                        __global const float4 *kd, __global const float4 *ks_m,
                                        __global const uint *visibility, __global const float4 *env, int res,
                                        int p, int n, int c, int at, __global const int *pixel_at,
                                        __global const float *depth, int width, int height, int neighbours,
                                        float radius, int unbiased, uint seed, uint frame,
                                        __global const float4 *in_sample, __global const float4 *in_info,
                                        __global const float *scales, float *evaluations, float *shadow_rays,
                                        float *reused)
{
    reservoir_t inputs[MAX_NEIGHBOURS + 1];
    int pixels[MAX_NEIGHBOURS + 1], count = 1;
    pixels[0] = p;
    load_reservoir(in_sample, in_info, c * n + p, &inputs[0]);
    for (int j = 0; j < neighbours; ++j) {
        int q = spatial_neighbour(p, at, width, height, radius, seed, frame, c, j, pixel_at, normal, depth);
        if (q < 0) continue;
        pixels[count] = q;
        load_reservoir(in_sample, in_info, c * n + q, &inputs[count++]);
    }
    *reused += (float)(count - 1);
    if (count == 1) return inputs[0];
    float targets[(MAX_NEIGHBOURS + 1) * (MAX_NEIGHBOURS + 1)], domain_scales[MAX_NEIGHBOURS + 1];
    for (int j = 0; j < count; ++j) {
        shading_t s = load_shading(normal, view, kd, ks_m, pixels[j]);
        domain_scales[j] = scales[pixels[j]];
        NO_VECTORIZE
        for (int i = 0; i < count; ++i) {
            int visible_too = unbiased || j == 0;   /* the biased Z's support tests leave V out */
            targets[j * count + i] = i == j ? inputs[i].target
                                   : visible_too ? restir_target(&s, env, res, inputs[i].w, visibility, pixels[j])
                                   : target_without_visibility(&s, env, res, inputs[i].w);
        }
    }
    count_reuse(count, unbiased, evaluations, shadow_rays);
    philox4x32_ctr_t u = rng_block(seed, frame, STREAM_RESTIR_REUSE, (uint)p, 0u, (uint)c);
    return combine_reservoirs(inputs, targets, domain_scales, count, unbiased, rng_unit(u.v[3]));
}

/* ---- pass 2 in explicit lanes: POOL_LANES chains of one pixel at a time, a chain a lane --------
 * Each lane runs spatial reuse's arithmetic of one chain (combine_reservoirs' and restir_target's,
 * bit for bit): the inputs keep fixed slots (0: the pixel's own reservoir, 1 + j: neighbour j's)
 * instead of being packed, a slot without a neighbour masked; it adds exactly 0 to every sum
 * and is never chosen, so the sums, the pick and the result are those of the packed inputs. */

/* Reservoirs of the lanes' chains (reservoir_t's fields). */
typedef struct {
    lanes_t x, y, z, weight, confidence, target;
} lane_reservoirs_of_chains_t;

/* What p̂ needs of the lanes' pixels' shading: n, r, m, Y(kd)/π and Y(ks) (load_shading's and
 * brdf_luminance's arithmetic). */
typedef struct {
    lanes3_t n, r;
    lanes_t m, diffuse, specular;
} lane_targets_t;

ALWAYS_INLINE lanes3_t gather_lanes3(__global const float4 *buffer, lane_ints_t i)
{
    __global const float *f = (__global const float *)buffer;
    return make_lanes3(GATHER(lanes_t, f, 4 * i), GATHER(lanes_t, f, 4 * i + 1), GATHER(lanes_t, f, 4 * i + 2));
}

ALWAYS_INLINE lanes_t lanes_dot3(lanes3_t a, lanes3_t b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

/* Chains `chain`'s reservoirs of pass 1 at the lanes' pixels q. */
ALWAYS_INLINE void load_lane_reservoirs(__global const float4 *sample, __global const float4 *info, int n,
                                        lane_ints_t chain, lane_ints_t q, lane_reservoirs_of_chains_t *r)
{
    lane_ints_t at = 4 * (chain * n + q);
    __global const float *samples = (__global const float *)sample, *infos = (__global const float *)info;
    r->x = GATHER(lanes_t, samples, at);
    r->y = GATHER(lanes_t, samples, at + 1);
    r->z = GATHER(lanes_t, samples, at + 2);
    r->weight = GATHER(lanes_t, samples, at + 3);
    r->confidence = GATHER(lanes_t, infos, at);
    r->target = GATHER(lanes_t, infos, at + 1);
}

ALWAYS_INLINE void load_lane_targets(__global const float4 *normal, __global const float4 *view,
                                     __global const float4 *kd, __global const float4 *ks_m, lane_ints_t q,
                                     lane_targets_t *s)
{
    lanes3_t n = gather_lanes3(normal, q), v = gather_lanes3(view, q);
    lanes_t k = 2.0f * lanes_dot3(n, v);   /* vec3_reflect_view */
    s->n = n;
    s->r = make_lanes3(k * n.x - v.x, k * n.y - v.y, k * n.z - v.z);
    s->m = GATHER(lanes_t, (__global const float *)ks_m, 4 * q + 3);
    s->diffuse = lanes_luminance(gather_lanes3(kd, q)) / IBL_PI;
    s->specular = lanes_luminance(gather_lanes3(ks_m, q));
}

/* p̂ of the lanes' pixels s at the lanes' directions w (restir_target's arithmetic), given L_Y(w)
 * and V as the mask `open`. */
ALWAYS_INLINE lanes_t lanes_restir_target(const lane_targets_t *s, lanes3_t w, lanes_t luminance, lane_ints_t open)
{
    lanes_t cosine = lanes_dot3(s->n, w);
    lanes_t power = phong_power_lanes(max(lanes_dot3(s->r, w), 0.0f), s->m);
    lanes_t rho = s->diffuse + s->specular * ((s->m + 2.0f) / (2.0f * IBL_PI) * power);
    return select((lanes_t)0.0f, luminance * rho * cosine, (cosine > 0.0f) & open);
}

/* lanes_cells_open of light_pool.cl with a pixel per lane. */
ALWAYS_INLINE lane_ints_t lanes_cells_open_of(__global const uint *visibility, lane_ints_t pixel, lane_ints_t cell)
{
#if VISIBILITY
    lane_longs_t word = convert_lane_longs(pixel) * VIS_WORDS + convert_lane_longs(cell >> 5);
    return ((GATHER(lane_uints_t, visibility, word) >> convert_lane_uints(cell & 31)) & 1u) != 0u;
#else
    return (lane_ints_t)(-1);
#endif
}

/* Neighbour j of the lanes' chains of pixel p (image position `at` of a width × height image): a
 * pixel uniform in the disc of `radius` pixels about it, clamped to the image, not p itself,
 * covered, and passing RTXDI's normal and depth tests; -1 where none. */
ALWAYS_INLINE lane_ints_t lanes_spatial_neighbour(int p, int at, int width, int height, float radius, uint seed,
                                            uint frame, lane_ints_t chain, int j, __global const int *pixel_at,
                                            __global const float4 *normal, __global const float *depth)
{
    lane_block_t xi = rng_block_draws_lanes(seed, frame, STREAM_RESTIR_REUSE, (uint)p, (uint)(1 + j),
                                            convert_lane_uints(chain));
    lanes_t sine, cosine, distance = radius * sqrt(lanes_unit(xi.v[0]));
    sincos_turn_lanes(lanes_unit(xi.v[1]), &sine, &cosine);
    lane_ints_t x = clamp(at % width + convert_lane_ints(rint(distance * cosine)), (lane_ints_t)0, (lane_ints_t)(width - 1));
    lane_ints_t y = clamp(at / width + convert_lane_ints(rint(distance * sine)), (lane_ints_t)0, (lane_ints_t)(height - 1));
    lane_ints_t q = GATHER(lane_ints_t, pixel_at, y * width + x);
    lane_ints_t covered = max(q, (lane_ints_t)0);   /* where q is -1 the loads read pixel 0, unused */
    float depth_p = depth[p];
    lane_ints_t rejected = (q < 0) | (q == p)
                         | (lanes_dot(vec3_load(normal, p), gather_lanes3(normal, covered)) < NORMAL_THRESHOLD)
                         | (fabs(GATHER(lanes_t, depth, covered) - depth_p) > DEPTH_THRESHOLD * depth_p);
    return select(q, (lane_ints_t)(-1), rejected);
}

/* The slots' inputs of the lanes' chains: the reservoirs r, their pixels, whether each is there
 * (`valid`), and the map's luminance and the visibility cell at each one's sample; returns the
 * neighbours found per lane. */
ALWAYS_INLINE lane_ints_t spatial_inputs(int p, int n, lane_ints_t chain, int at, int width, int height, int neighbours,
                                         float radius, uint seed, uint frame, __global const int *pixel_at,
                                         __global const float4 *normal, __global const float *depth,
                                         __global const float4 *env, int res, __global const float4 *in_sample,
                                         __global const float4 *in_info, lane_reservoirs_of_chains_t *r,
                                         lane_ints_t *pixels, lane_ints_t *valid, lanes_t *luminance, lane_ints_t *cell)
{
    lane_ints_t found = 0;
    for (int i = 0; i <= neighbours; ++i) {
        lane_ints_t q = i == 0 ? (lane_ints_t)p : lanes_spatial_neighbour(p, at, width, height, radius, seed, frame, chain,
                                                                    i - 1, pixel_at, normal, depth);
        valid[i] = q >= 0;
        pixels[i] = select(q, (lane_ints_t)p, q < 0);   /* an absent neighbour reads the pixel's own */
        if (i > 0) found -= valid[i];
        load_lane_reservoirs(in_sample, in_info, n, chain, pixels[i], &r[i]);
        lanes3_t w = make_lanes3(r[i].x, r[i].y, r[i].z);
        lane_ints_t face, row, col;
        lanes_texel_of(res, w, &face, &row, &col);
        luminance[i] = lanes_luminance(lanes_texel_radiance(env, (face * res + row) * res + col));
        cell[i] = lanes_visibility_cell(w);
    }
    return found;
}

/* combine_reservoirs of the slots' inputs, a chain a lane, with the targets p̂_j(ω_i) evaluated
 * as spatial reuse defines them (restir_target of domain j, with V where `unbiased` or j = 0; the
 * diagonal the inputs' own): the unbiased weights' denominators Σ_j c_j s_j p̂_j(ω_i) and the
 * biased Z's supports (bit j: p̂_j(ω_i) > 0) are summed domain by domain, as there. */
ALWAYS_INLINE void combine_lanes(const lane_reservoirs_of_chains_t *r, const lane_ints_t *pixels,
                                 const lane_ints_t *valid, const lanes_t *luminance, const lane_ints_t *cell,
                                 int slots, int unbiased, __global const float4 *normal, __global const float4 *view,
                                 __global const float4 *kd, __global const float4 *ks_m,
                                 __global const uint *visibility, __global const float *scales, lanes_t u,
                                 lane_reservoirs_of_chains_t *out)
{
    lanes_t denominator[MAX_NEIGHBOURS + 1], own_target[MAX_NEIGHBOURS + 1], scale[MAX_NEIGHBOURS + 1];
    lane_ints_t support[MAX_NEIGHBOURS + 1];
    lanes_t confidence = 0.0f;
    for (int i = 0; i < slots; ++i) {
        confidence += select((lanes_t)0.0f, r[i].confidence, valid[i]);
        denominator[i] = 0.0f;
        support[i] = 0;
    }
    for (int j = 0; j < slots; ++j) {
        lane_targets_t s;
        load_lane_targets(normal, view, kd, ks_m, pixels[j], &s);
        scale[j] = GATHER(lanes_t, scales, pixels[j]);
        for (int i = 0; i < slots; ++i) {
            lane_ints_t open = unbiased || j == 0 ? lanes_cells_open_of(visibility, pixels[j], cell[i]) : (lane_ints_t)(-1);
            lanes_t target = i == j ? r[i].target
                           : lanes_restir_target(&s, make_lanes3(r[i].x, r[i].y, r[i].z), luminance[i], open);
            if (j == 0) own_target[i] = target;   /* p̂_0(ω_i), domain 0 the pixel's own */
            if (unbiased)
                denominator[i] = select(denominator[i], denominator[i] + r[j].confidence * scale[j] * target, valid[j]);
            else
                support[i] |= select((lane_ints_t)0, (lane_ints_t)(1 << j), valid[j] & (target > 0.0f));
        }
    }
    lanes_t weights[MAX_NEIGHBOURS + 1], total = 0.0f;
    for (int i = 0; i < slots; ++i) {
        lanes_t w = own_target[i] * r[i].weight;
        if (unbiased) w *= r[i].confidence * scale[i] * r[i].target / denominator[i];
        else w *= r[i].confidence;
        weights[i] = select((lanes_t)0.0f, w, valid[i] & (w > 0.0f) & isfinite(w));
        total += weights[i];
    }
    /* pick_by_weight */
    lanes_t threshold = u * total, running = 0.0f;
    lane_ints_t chosen = -1, last = -1;
    for (int i = 0; i < slots; ++i) {
        running += weights[i];
        chosen = select(chosen, (lane_ints_t)i, (chosen < 0) & (weights[i] > 0.0f) & (threshold < running));
        last = select(last, (lane_ints_t)i, weights[i] > 0.0f);
    }
    chosen = select(chosen, last, chosen < 0);
    lane_ints_t kept = (chosen >= 0) & isfinite(total), chosen_support = 0;
    *out = r[0];
    out->weight = 0.0f;
    out->confidence = confidence;
    out->target = 0.0f;
    for (int i = 0; i < slots; ++i) {
        lane_ints_t pick = kept & (chosen == i);
        out->x = select(out->x, r[i].x, pick);
        out->y = select(out->y, r[i].y, pick);
        out->z = select(out->z, r[i].z, pick);
        out->target = select(out->target, own_target[i], pick);
        chosen_support = select(chosen_support, support[i], pick);
    }
    lanes_t normaliser = 1.0f;   /* Z(ω) of the biased combination */
    if (!unbiased) {
        normaliser = 0.0f;
        for (int j = 0; j < slots; ++j)
            normaliser += select((lanes_t)0.0f, r[j].confidence, (chosen_support & (1 << j)) != 0);
    }
    lanes_t weight = total / (out->target * normaliser);
    out->weight = select((lanes_t)0.0f, weight, kept & isfinite(weight));
}

/* Spatial reuse of the lanes' chains of pixel p: each one's reservoir of pass 1 combined with up
 * to `neighbours` neighbours' of the same chain (also of pass 1, so no pixel reads what another
 * writes), or kept as it is where no neighbour is found; returns the neighbours found. */
ALWAYS_INLINE lane_ints_t lanes_spatial_reuse(__global const float4 *normal, __global const float4 *view,
                                        __global const float4 *kd, __global const float4 *ks_m,
                                        __global const uint *visibility, __global const float4 *env, int res,
                                        int p, int n, lane_ints_t chain, int at, __global const int *pixel_at,
                                        __global const float *depth, int width, int height, int neighbours,
                                        float radius, int unbiased, uint seed, uint frame,
                                        __global const float4 *in_sample, __global const float4 *in_info,
                                        __global const float *scales, lane_reservoirs_of_chains_t *out)
{
    lane_reservoirs_of_chains_t inputs[MAX_NEIGHBOURS + 1];
    lane_ints_t pixels[MAX_NEIGHBOURS + 1], valid[MAX_NEIGHBOURS + 1], cell[MAX_NEIGHBOURS + 1];
    lanes_t luminance[MAX_NEIGHBOURS + 1];
    lane_ints_t found = spatial_inputs(p, n, chain, at, width, height, neighbours, radius, seed, frame, pixel_at,
                                       normal, depth, env, res, in_sample, in_info, inputs, pixels, valid,
                                       luminance, cell);
    lane_block_t u = rng_block_draws_lanes(seed, frame, STREAM_RESTIR_REUSE, (uint)p, 0u, convert_lane_uints(chain));
    combine_lanes(inputs, pixels, valid, luminance, cell, neighbours + 1, unbiased, normal, view, kd, ks_m,
                  visibility, scales, lanes_unit(u.v[3]), out);
    lane_ints_t alone = found == 0;   /* the reservoir itself, not combined */
    out->x = select(out->x, inputs[0].x, alone);
    out->y = select(out->y, inputs[0].y, alone);
    out->z = select(out->z, inputs[0].z, alone);
    out->weight = select(out->weight, inputs[0].weight, alone);
    out->confidence = select(out->confidence, inputs[0].confidence, alone);
    out->target = select(out->target, inputs[0].target, alone);
    return found;
}

/* The fewest chains left that run as a block of lanes; fewer run one at a time in scalars: a
 * block costs 1-2 scalar chains (sphere-sun at 128², PoCL on AVX2, 8 lanes: two chains 1.1× as
 * fast in lanes, three 1.7-2.0×, one 0.5-0.8×). */
#define LANE_CHAINS_FROM 2
/* 0 compiles pass 2 without lanes (restir.py's choice where a pixel has one chain): a kernel that
 * holds both paths runs a lone chain 10-20% slower than one with the scalar path alone. */
#ifndef CHAIN_LANES
#define CHAIN_LANES 1
#endif

/* Pass 2: each chain's spatial reuse (spatial_reuse, lanes_spatial_reuse) of pass 1's reservoirs,
 * which are also the next frame's history (restir.py: the spatially reused ones are shaded, not
 * kept); the pixel's estimate is the chains' mean of f(ω)·W, f = L·ρ·cos⁺·V (V = 1 where p̂ > 0),
 * summed in chain order whichever path runs a chain.  Outputs: radiance, counts (used = the chains,
 * effective = those whose kept sample has a positive cosine), stats (evaluations of every chain
 * with the shading, and per chain the neighbours reused and the confidence, then the shadow rays of
 * every chain). */
__kernel void restir_spatial_shade(__global const float4 *normal, __global const float4 *view,
                                   __global const float4 *kd, __global const float4 *ks_m,
                                   __global const uint *visibility, const int n, __global const float4 *env, const int res,
                                   __global const int *pixel_index, __global const int *pixel_at,
                                   __global const float *depth, const int width, const int height,
                                   const int neighbours, const float radius, const int chains,
                                   const int unbiased, const uint seed, const uint frame,
                                   __global const float4 *in_sample, __global const float4 *in_info,
                                   __global const float *scales, __global float4 *radiance, __global float2 *counts, __global float4 *stats)
{
    int p = get_global_id(0), at = pixel_index[p];
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    float4 first_pass = stats[p];
    float evaluations = first_pass.x, shadow_rays = first_pass.w, reused = 0.0f, confidence = 0.0f, effective = 0.0f;
    vec3_t sum = vec3(0.0f, 0.0f, 0.0f);
    for (int first = 0; first < chains; ) {
        if (!CHAIN_LANES || chains - first < LANE_CHAINS_FROM) {
            reservoir_t out = spatial_reuse(normal, view, kd, ks_m, visibility, env, res, p, n, first, at, pixel_at,
                                            depth, width, height, neighbours, radius, unbiased, seed, frame, in_sample,
                                            in_info, scales, &evaluations, &shadow_rays, &reused);
            confidence += out.confidence;
            float cosine = vec3_dot(s.n, out.w);
            if (out.weight > 0.0f && cosine > 0.0f) {
                vec3_t f = vec3_mul(env_radiance(env, res, out.w), phong_value(s.kd, s.ks, s.m, phong_lobe_power(s.r, out.w, s.m)));
                sum = vec3_add(sum, vec3_scale(f, out.weight * cosine));
                effective += 1.0f;
            }
            first += 1;
            continue;
        }
        lane_ints_t chain = min(first + LANE_NUMBERS, (lane_ints_t)(chains - 1));   /* lanes past the last: its copies */
        lane_reservoirs_of_chains_t out;
        lane_ints_t found = lanes_spatial_reuse(normal, view, kd, ks_m, visibility, env, res, p, n, chain, at,
                                                pixel_at, depth, width, height, neighbours, radius, unbiased, seed,
                                                frame, in_sample, in_info, scales, &out);
        /* f(ω)·W·cos⁺ of each lane's kept sample (phong_value's arithmetic, vec3_scale's product) */
        lanes3_t w = make_lanes3(out.x, out.y, out.z);
        lanes_t cosine = lanes_dot(s.n, w);
        lanes_t lobe = (s.m + 2.0f) / (2.0f * IBL_PI) * phong_power_lanes(max(lanes_dot(s.r, w), 0.0f), (lanes_t)s.m);
        lane_ints_t face, row, col;
        lanes_texel_of(res, w, &face, &row, &col);
        lanes3_t light = lanes_texel_radiance(env, (face * res + row) * res + col);
        lanes_t scale = out.weight * cosine;
        float red[POOL_LANES], green[POOL_LANES], blue[POOL_LANES], kept_confidence[POOL_LANES];
        int lit[POOL_LANES], neighbours_found[POOL_LANES];
        vstore_lanes(light.x * (s.kd.x / IBL_PI + s.ks.x * lobe) * scale, 0, red);
        vstore_lanes(light.y * (s.kd.y / IBL_PI + s.ks.y * lobe) * scale, 0, green);
        vstore_lanes(light.z * (s.kd.z / IBL_PI + s.ks.z * lobe) * scale, 0, blue);
        vstore_lanes(out.confidence, 0, kept_confidence);
        vstore_lanes((out.weight > 0.0f) & (cosine > 0.0f), 0, lit);
        vstore_lanes(found, 0, neighbours_found);
        /* The lanes' chains added in chain order, as the scalar path adds them. */
        for (int k = 0; k < min(POOL_LANES, chains - first); ++k) {
            reused += (float)neighbours_found[k];
            count_reuse(1 + neighbours_found[k], unbiased, &evaluations, &shadow_rays);
            confidence += kept_confidence[k];
            if (lit[k]) {
                sum = vec3_add(sum, vec3(red[k], green[k], blue[k]));
                effective += 1.0f;
            }
        }
        first += POOL_LANES;
    }
    float share = 1.0f / (float)chains;
    radiance[p] = (float4)(sum.x * share, sum.y * share, sum.z * share, 0.0f);
    counts[p] = (float2)((float)chains, effective);
    stats[p] = (float4)(evaluations + (float)chains, reused * share, confidence * share, shadow_rays);
}
