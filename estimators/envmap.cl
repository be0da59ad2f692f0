/* `envmap` (and, with LIGHT_SAMPLES = 0, `brdf`): the production samplers.  Light samples come from
 * one 2-D distribution over the whole cube map, a marginal over its 6·R rows (faces and rows,
 * face-major) and a conditional over columns, as pbrt-v4's ImageInfiniteLight samples its one
 * image, each drawn in O(1) from Walker's alias tables (FrameCache.map_alias: Walker 1977,
 * Vose 1991) where pbrt-v4 bisects its CDFs; BRDF samples are ARCHITECTURE.md §Conventions's
 * Phong sampling; the two combine by MIS.  Configured by the estimator's defines:
 *   LIGHT_SAMPLES  1: light samples (0: none, the `brdf` estimator)
 *   BRDF_SAMPLES   1: BRDF samples (half the budget when LIGHT_SAMPLES is 1)
 *   MIS_POWER      0: the balance heuristic; 1: the power heuristic with exponent 2
 * Budgets are light_pool.cl's fixed-point ticks: N_s samples are Q·N_s ticks, t_L = Q·N_s/2 for
 * light and t_B = Q·N_s − t_L for BRDF samples with MIS, and each strategy draws draws_for(t)
 * samples, the last weighted by β = frac(t/Q) (Lu 2013 Eq. 5), so every N_s ≥ 1 is unbiased.
 * `render_map` shades one pixel per work item (or, in the sample-block launch shape, one block of
 * a pixel's draws: light_pool.cl's launch shapes), its samples POOL_LANES at a time in explicit
 * vectors (light_pool.cl: lanes masked past a strategy's draws, no data-dependent trip count, the
 * polynomial Phong power, Philox per lane); `map_directions`/`map_direction_pdf` are the χ² hooks.
 *
 * The light sampler is a compile-time choice: a file that defines LIGHT_PARAMS (the kernels'
 * parameters that hold its distribution), LIGHT_ARGS (their names), lanes_sample_light and
 * lanes_light_density (their signatures below) before it includes this one replaces the map's
 * CDFs with its own sampler (estimators/hierarchical.cl, estimators/product.cl); the budget,
 * MIS and hooks stay these.  Both take the sampler's per-pixel state (lanes.cl's light_state_t),
 * made once a work item by light_state_of from the pixel's shading (written through a pointer:
 * an inlined struct return leaves an llvm.experimental.noalias.scope.decl that Oclgrind 21.10
 * cannot run), for a sampler whose
 * distribution depends on the pixel (product.cl, which defines its own light_state_of); the
 * others keep none. */
#include "lanes.cl"

#ifndef LIGHT_SAMPLES
#define LIGHT_SAMPLES 1
#endif
#ifndef BRDF_SAMPLES
#define BRDF_SAMPLES 1
#endif
#ifndef MIS_POWER
#define MIS_POWER 0
#endif

#define STREAM_MAP_LIGHT 8u

/* The denominator D of a sample in add_samples' β·s(ω)/D, from its own strategy's density
 * `own` = t_own·p_own(ω) and the other's `other` (ticks × solid-angle pdf).  Balance heuristic:
 * D = own + other, Veach's one-sample-per-strategy form with counts.  Power heuristic (β = 2):
 * the weight own²/(own² + other²) divided by own, D = own + other²/own (the ratio first: no
 * overflow of the squares; own = 0 never happens for a drawn sample, and add_samples drops
 * any D that is not positive). */
ALWAYS_INLINE lanes_t mis_denominator(lanes_t own, lanes_t other)
{
#if MIS_POWER
    return own + other * (other / own);
#else
    return own + other;
#endif
}

/* The map's alias tables, the light sampler unless the including file brought its own (header). */
#ifndef LIGHT_PARAMS
#define LIGHT_PARAMS __global const cdf_word_t *alias_words, __global const float *texel_probability
#define LIGHT_ARGS alias_words, texel_probability

/* x / d for 0 ≤ x, x/d < 2^24 and x + d < 2^31, in float lanes (CPUs have no vector integer
 * division): the float quotient's truncation is within one of x/d, and the two steps correct it. */
ALWAYS_INLINE lane_ints_t lanes_quotient(lane_ints_t x, int d)
{
    lane_ints_t q = convert_lane_ints(convert_lanes(x) / (float)d);
    q += q * d > x;            /* a true comparison is −1 */
    q -= (q + 1) * d <= x;
    return q;
}

/* The bins that the lanes' 64-bit words u draw from the alias tables of 2^bits bins at
 * words + first (framecache.cl's alias_tables): the bin from u's top bits, its threshold test by
 * the 63 − bits bits below them (bit 0 unused). */
ALWAYS_INLINE lane_ints_t lanes_alias_draw(__global const cdf_word_t *words, lane_ints_t first, int bits,
                                           lane_words_t u)
{
    lane_words_t low = u >> (lane_words_t)1;
    lane_ints_t bin = convert_lane_ints(low >> (lane_words_t)(63 - bits));
    lane_words_t word = GATHER(lane_words_t, words, first + bin);
    lane_words_t below = low & (lane_words_t)((CDF_ONE >> bits) - 1);
    lane_ints_t kept = convert_lane_ints(below < (word >> (lane_words_t)bits));
    return select(convert_lane_ints(word & (lane_words_t)(((cdf_word_t)1 << bits) - 1)), bin, kept);
}

/* The lanes' light directions from the blocks xi and at: the map row by the rows' alias table
 * (v0:v1 of xi), the column by that row's (v2:v3), the point uniform in the texel's face square
 * from at's v0 and v1 (24 bits each).  *texel gets the texel and *pdf the density in solid
 * angle, P(texel)·(1+x²+y²)^{3/2}/a_texel (ARCHITECTURE.md §Conventions), P(texel) = P(row)·P(col | row)
 * the tables' exact probabilities, as texel_probabilities rounds them. */
ALWAYS_INLINE lanes3_t lanes_sample_map(__global const cdf_word_t *alias_words,
                                        __global const float *texel_probability, int res,
                                        lane_block_t xi, lane_block_t at, lane_ints_t *texel, lanes_t *pdf)
{
    int row_bits = alias_bits(6 * res), col_bits = alias_bits(res);
    lane_ints_t map_row = lanes_alias_draw(alias_words, (lane_ints_t)0, row_bits, upsample(xi.v[0], xi.v[1]));
    lane_ints_t col = lanes_alias_draw(alias_words, (1 << row_bits) + (map_row << col_bits), col_bits,
                                       upsample(xi.v[2], xi.v[3]));
    lane_ints_t face = lanes_quotient(map_row, res);
    lanes_t x = -1.0f + 2.0f * (convert_lanes(col) + lanes_unit(at.v[0])) / (float)res;
    lanes_t y = -1.0f + 2.0f * (convert_lanes(map_row - face * res) + lanes_unit(at.v[1])) / (float)res;
    lanes_t q = 1.0f + x * x + y * y;   /* area_per_solid_angle */
    *texel = map_row * res + col;
    lanes_t p_texel = GATHER(lanes_t, texel_probability, *texel);
    *pdf = p_texel * q * sqrt(q) * (float)(res * res) / 4.0f;
    return lanes_face_direction(face, x, y);
}

/* The light directions of draws `draw` of pixel stream `pixel` (their random numbers keyed by
 * seed and frame: blocks 0 and 1 of each draw); *texel gets each one's texel and *pdf its
 * density in solid angle. */
ALWAYS_INLINE lanes3_t lanes_sample_light(LIGHT_PARAMS, const light_state_t *state, int res, uint seed,
                                          uint frame, uint pixel, lane_ints_t draw, lane_ints_t *texel, lanes_t *pdf)
{
    lane_uints_t index = convert_lane_uints(draw);
    lane_block_t xi = rng_block_lanes(seed, frame, STREAM_MAP_LIGHT, pixel, index, 0u);
    lane_block_t at = rng_block_lanes(seed, frame, STREAM_MAP_LIGHT, pixel, index, 1u);
    return lanes_sample_map(alias_words, texel_probability, res, xi, at, texel, pdf);
}

/* The light density at the lanes' directions w: their texels' probabilities
 * (texel_probabilities), with lanes_sample_map's Jacobian; *texel gets the texel of each. */
ALWAYS_INLINE lanes_t lanes_light_density(LIGHT_PARAMS, const light_state_t *state, int res, lanes3_t w,
                                          lane_ints_t *texel)
{
    lane_ints_t face, row, col;
    lanes_t area = lanes_texel_of(res, w, &face, &row, &col);
    *texel = (face * res + row) * res + col;
    return GATHER(lanes_t, texel_probability, *texel) * area * (float)(res * res) / 4.0f;
}
#endif

#ifndef PIXEL_LIGHT_STATE
/* A sampler whose distribution is the same for every pixel keeps no per-pixel state. */
ALWAYS_INLINE void light_state_of(LIGHT_PARAMS, const shading_t *s, int res, light_state_t *state)
{
    state->none = 0;
}
#endif

/* The lanes' BRDF directions of draws `draw` for pixel stream `stream_pixel` (draw_numbers). */
ALWAYS_INLINE lanes3_t lanes_brdf_draw(const shading_t *s, vec3_t t_n, vec3_t b_n, vec3_t t_r, vec3_t b_r,
                                       uint seed, uint frame, uint stream_pixel, lane_ints_t draw)
{
    lanes_t xi_cos, xi_lobe, azimuth_sin, azimuth_cos;
    draw_numbers(seed, frame, stream_pixel, draw, &xi_cos, &xi_lobe, &azimuth_sin, &azimuth_cos);
    return lanes_phong_direction(s, t_n, b_n, t_r, b_r, xi_cos, sqrt(xi_cos), phong_power_log2_lanes(xi_cos),
                                 xi_lobe, azimuth_sin, azimuth_cos);
}

/* The light density at the lanes' directions (0 without light samples); *texel gets the texel. */
ALWAYS_INLINE lanes_t lanes_map_pdf(LIGHT_PARAMS, const light_state_t *state, int res, lanes3_t w,
                                    lane_ints_t *texel)
{
#if LIGHT_SAMPLES
    return lanes_light_density(LIGHT_ARGS, state, res, w, texel);
#else
    lane_ints_t face, row, col;
    lanes_texel_of(res, w, &face, &row, &col);
    *texel = (face * res + row) * res + col;
    return (lanes_t)0.0f;
#endif
}

/* Ticks of the light and the BRDF samples of a budget of spp samples. */
ALWAYS_INLINE void strategy_split(int spp, int *light, int *brdf)
{
    *light = LIGHT_SAMPLES ? light_ticks(spp, BRDF_SAMPLES) : 0;
    *brdf = spp * TICKS_PER_SAMPLE - *light;
}

/* Outputs in planes of n floats (the G-buffer's launch_size: launches cover part of it,
 * chunks.py): radiance R, G, B; counts used, effective
 * (in samples); evaluations per pixel (store_sums; LAUNCH_PARAMS: the sample-block shape's).
 * The light sampler's buffers are unread without light samples. */
__kernel void render_map(__global const float4 *normal, __global const float4 *view,
                         __global const float4 *kd, __global const float4 *ks_m,
                         __global const uint *visibility, const int n, __global const float4 *env, LIGHT_PARAMS, const int res, const int spp,
                         const uint seed, const uint frame, __global float *radiance,
                         __global float *counts, __global int *evaluations LAUNCH_PARAMS)
{
    launch_item_t item = LAUNCH_ITEM(n);
    int p = item.pixel, from, to;
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    light_state_t state;
    light_state_of(LIGHT_ARGS, &s, res, &state);
    int light, brdf;
    strategy_split(spp, &light, &brdf);
    int light_draws = draws_for(light), brdf_draws = draws_for(brdf);
    lanes_sum_t acc = {(lanes_t)0.0f, (lanes_t)0.0f, (lanes_t)0.0f, (lane_ints_t)0};
#if LIGHT_SAMPLES
    strategy_window(&item, light_draws, &from, &to);
    for (int i = from; i < to; i += POOL_LANES) {
        lane_ints_t draw = i + LANE_NUMBERS, texel;
        lanes_t pdf_light;
        lanes3_t w = lanes_sample_light(LIGHT_ARGS, &state, res, seed, frame, (uint)p, draw, &texel, &pdf_light);
        lanes_t cosine = lanes_dot(s.n, w);
        lanes_t power = phong_power_lanes(max(lanes_dot(s.r, w), 0.0f), (lanes_t)s.m);
        lanes_t other = BRDF_SAMPLES ? (float)brdf * phong_mixture_pdf_lanes(s.p_spec, s.m, cosine, power) : 0.0f;
        add_samples(&acc, &s, draw < light_draws, lanes_beta(light, i), cosine, power,
                    lanes_texel_radiance(env, texel), mis_denominator((float)light * pdf_light, other),
                    lanes_visible(visibility, p, w));
    }
#endif
#if BRDF_SAMPLES
    vec3_t t_n, b_n, t_r, b_r;
    direction_about_axis_basis(s.n, &t_n, &b_n);
    direction_about_axis_basis(s.r, &t_r, &b_r);
    strategy_window(&item, brdf_draws, &from, &to);
    for (int i = from; i < to; i += POOL_LANES) {
        lane_ints_t draw = i + LANE_NUMBERS, texel;
        lanes3_t w = lanes_brdf_draw(&s, t_n, b_n, t_r, b_r, seed, frame, (uint)p, draw);
        lanes_t cosine = lanes_dot(s.n, w);
        lanes_t power = phong_power_lanes(max(lanes_dot(s.r, w), 0.0f), (lanes_t)s.m);
        lanes_t other = (float)light * lanes_map_pdf(LIGHT_ARGS, &state, res, w, &texel);
        lanes_t own = (float)brdf * phong_mixture_pdf_lanes(s.p_spec, s.m, cosine, power);
        add_samples(&acc, &s, draw < brdf_draws, lanes_beta(brdf, i), cosine, power,
                    lanes_texel_radiance(env, texel), mis_denominator(own, other),
                    lanes_visible(visibility, p, w));
    }
#endif
    store_sums(&acc, item, n, light + brdf, light_draws + brdf_draws, radiance, counts, evaluations, PARTIAL_SUMS);
}

/* The density of all of a pixel's samples pooled, (t_L·p_L + t_B·p_B)/(t_L + t_B), at the lanes'
 * directions w, given p_L there (what the χ² hooks check). */
ALWAYS_INLINE lanes_t pooled_map_density(const shading_t *s, int spp, lanes3_t w, lanes_t pdf_light)
{
    int light, brdf;
    strategy_split(spp, &light, &brdf);
    lanes_t power = phong_power_lanes(max(lanes_dot(s->r, w), 0.0f), (lanes_t)s->m);
    lanes_t pdf_brdf = BRDF_SAMPLES ? phong_mixture_pdf_lanes(s->p_spec, s->m, lanes_dot(s->n, w), power) : 0.0f;
    return ((float)light * pdf_light + (float)brdf * pdf_brdf) / (float)(light + brdf);
}

/* surface[0..3] = normal, view, kd, (ks, m) of one pixel; work item i draws the directions
 * i·POOL_LANES + k as the estimator draws them, a strategy with probability ∝ its ticks, and
 * writes them with their pooled density as planes x, y, z, density of n floats (n = global size
 * × POOL_LANES).  A light sample's p_L is the one lanes_sample_map returns (render's), not a
 * lookup: the χ² check compares it with map_direction_pdf's. */
__kernel void map_directions(__global const float4 *surface, LIGHT_PARAMS, const int res, const int spp,
                             const uint seed, __global float *out)
{
    int i = get_global_id(0), n = get_global_size(0) * POOL_LANES;
    shading_t s = load_shading(surface, surface + 1, surface + 2, surface + 3, 0);
    light_state_t state;
    light_state_of(LIGHT_ARGS, &s, res, &state);
    int light, brdf;
    strategy_split(spp, &light, &brdf);
    lane_ints_t draw = i * POOL_LANES + LANE_NUMBERS;
    vec3_t t_n, b_n, t_r, b_r;
    direction_about_axis_basis(s.n, &t_n, &b_n);
    direction_about_axis_basis(s.r, &t_r, &b_r);
    lanes3_t w = lanes_brdf_draw(&s, t_n, b_n, t_r, b_r, seed, 0u, 0u, draw);
    lane_ints_t texel;
    lanes_t pdf_light = lanes_map_pdf(LIGHT_ARGS, &state, res, w, &texel);
#if LIGHT_SAMPLES
    lane_block_t choice = rng_block_lanes(seed, 0u, STREAM_HOOK, 0u, convert_lane_uints(draw), 0u);
    lane_ints_t is_light = lanes_unit(choice.v[0]) * (float)(light + brdf) < (float)light;
    lanes_t pdf_sampled;
    lanes3_t w_light = lanes_sample_light(LIGHT_ARGS, &state, res, seed, 0u, 0u, draw, &texel, &pdf_sampled);
    w = select_lanes3(w, w_light, is_light);
    pdf_light = select(pdf_light, pdf_sampled, is_light);
#endif
    int at = i * POOL_LANES;
    vstore_lanes(w.x, 0, out + at);
    vstore_lanes(w.y, 0, out + n + at);
    vstore_lanes(w.z, 0, out + 2 * n + at);
    vstore_lanes(pooled_map_density(&s, spp, w, pdf_light), 0, out + 3 * n + at);
}

/* The pooled density of map_directions at directions given as planes x, y, z of n floats
 * (n = global size × POOL_LANES). */
__kernel void map_direction_pdf(__global const float4 *surface, LIGHT_PARAMS, const int res, const int spp,
                                __global const float *dirs, __global float *out)
{
    int i = get_global_id(0), n = get_global_size(0) * POOL_LANES, at = i * POOL_LANES;
    shading_t s = load_shading(surface, surface + 1, surface + 2, surface + 3, 0);
    lanes3_t w = make_lanes3(vload_lanes(0, dirs + at), vload_lanes(0, dirs + n + at), vload_lanes(0, dirs + 2 * n + at));
    lane_ints_t texel;
    light_state_t state;
    light_state_of(LIGHT_ARGS, &s, res, &state);
    vstore_lanes(pooled_map_density(&s, spp, w, lanes_map_pdf(LIGHT_ARGS, &state, res, w, &texel)), 0, out + at);
}
