/* Kernels of the pool estimators (Lu 2013 Algorithm 2), configured by the estimator file that
 * includes this one:
 *   LU_BALANCED_FACES  0: μ_f = 1/6 (Sec. 2.1);  1: μ_f(n) of Eq. 3
 *   LU_BRDF_SAMPLES    0: light samples only (Eq. 4);  1: half the budget to BRDF samples (Eq. 6)
 * `render_light_pool` shades one pixel per work item (or, in the sample-block launch shape, one
 * block of a pixel's draws: light_pool.cl's launch shapes), its samples in explicit vectors of
 * POOL_LANES (light_pool.cl), from the pool laid out by `pool_planes` and, for BRDF samples of the
 * shared sequence, the numbers of `brdf_numbers`; `pooled_directions`/`pooled_direction_pdf` are
 * the χ² hooks; `split_strategies` exposes the per-normal split for tests. */
#include "light_pool.cl"

/* The pool as planes for shade_light_faces: work item k writes entry k of the planes x, y, z,
 * pdf, R, G, B and the direction's visibility cell (POOL_PLANE_STRIDE(size) floats each): face
 * f's entry i at k = 2·size·f + i and 2·size·f + size + i, zeros past the six faces. */
__kernel void pool_planes(__global const float4 *dir_pdf, __global const float4 *radiance,
                          const int pool_size, __global float *planes)
{
    int k = get_global_id(0), stride = POOL_PLANE_STRIDE(pool_size);
    int f = k / (2 * pool_size), i = k - 2 * pool_size * f;
    int valid = f < 6;
    int entry = valid ? f * pool_size + (i >= pool_size ? i - pool_size : i) : 0;
    float4 d = valid ? dir_pdf[entry] : (float4)(0.0f), c = valid ? radiance[entry] : (float4)(0.0f);
    planes[k] = d.x;
    planes[stride + k] = d.y;
    planes[2 * stride + k] = d.z;
    planes[3 * stride + k] = d.w;
    planes[4 * stride + k] = c.x;
    planes[5 * stride + k] = c.y;
    planes[6 * stride + k] = c.z;
    planes[7 * stride + k] = VISIBILITY && valid ? (float)visibility_cell(vec3(d.x, d.y, d.z)) : 0.0f;
}

/* The shared BRDF numbers of draw i = get_global_id(0) (see BRDF_NUMBERS_STRIDE), the scalar
 * forms of what shade_brdf computes in lanes for the interleaved sequence. */
__kernel void brdf_numbers(const uint seed, const uint frame, const int spp, __global float *out)
{
    int i = get_global_id(0), stride = BRDF_NUMBERS_STRIDE(spp);
    philox4x32_ctr_t xi = rng_block(seed, frame, STREAM_BRDF, 0u, (uint)i, 0u);
    float xi_cos = rng_unit(xi.v[0]), sine, cosine;
    sincos_turn(rng_unit(xi.v[1]), &sine, &cosine);
    out[i] = xi_cos;
    out[stride + i] = rng_unit(xi.v[2]);
    out[2 * stride + i] = sine;
    out[3 * stride + i] = cosine;
    out[4 * stride + i] = sqrt(xi_cos);
    out[5 * stride + i] = phong_power_log2(xi_cos);
}

/* Outputs in planes of n floats (the G-buffer's launch_size: launches cover part of it,
 * chunks.py): radiance R, G, B; counts used, effective (in samples); evaluations per pixel
 * (store_sums; LAUNCH_PARAMS: the sample-block shape's). */
__kernel void render_light_pool(__global const float4 *normal, __global const float4 *view,
                                __global const float4 *kd, __global const float4 *ks_m,
                                __global const uint *visibility, const int n, __global const float4 *env, __global const cdf_word_t *marginal,
                                __global const cdf_word_t *conditional, __global const float *face_integral,
                                __global const float *pool, const int res, const int pool_size, const int spp,
                                const int shared_sequence, const uint seed, const uint frame,
                                __global const float *shared_numbers, __global float *radiance, __global float *counts,
                                __global int *evaluations LAUNCH_PARAMS)
{
    launch_item_t item = LAUNCH_ITEM(n);
    int p = item.pixel;
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    int ticks[7];
    strategy_ticks(s.n, face_integral, spp, LU_BALANCED_FACES, LU_BRDF_SAMPLES, ticks);
    /* Shared: every pixel reads the same pool entries and BRDF numbers (Lu Sec. 2.2).
     * Interleaved: a per-pixel offset into the pool and per-pixel BRDF streams. */
    int offset = shared_sequence ? 0
               : (int)(rng_unit(rng_block(seed, frame, STREAM_POOL_OFFSET, (uint)p, 0u, 0u).v[0]) * pool_size);
    lanes_sum_t acc = {(lanes_t)0.0f, (lanes_t)0.0f, (lanes_t)0.0f, (lane_ints_t)0};
    shade_light_faces(&acc, &item, &s, ticks, LU_BRDF_SAMPLES, pool, pool_size, offset, visibility, p);
#if LU_BRDF_SAMPLES
    shade_brdf(&acc, &item, &s, ticks, env, marginal, conditional, res, seed, frame, shared_sequence, (uint)p,
               shared_numbers, BRDF_NUMBERS_STRIDE(spp), visibility, p);
#endif
    int used, draws;
    drawn_counts(ticks, pool_size, &used, &draws);
    store_sums(&acc, item, n, used, draws, radiance, counts, evaluations, PARTIAL_SUMS);
}

/* surface[0..3] = normal, view, kd, (ks, m) of one pixel; n directions drawn as the estimator
 * draws them (a strategy with probability ∝ its ticks; light samples through pool_point), each
 * with pooled_pdf. */
__kernel void pooled_directions(__global const float4 *surface, __global const cdf_word_t *marginal,
                                __global const cdf_word_t *conditional, __global const float *face_integral,
                                const int res, const int spp, const uint seed, __global float4 *out)
{
    int i = get_global_id(0);
    shading_t s = load_shading(surface, surface + 1, surface + 2, surface + 3, 0);
    int ticks[7], total = 0;
    strategy_ticks(s.n, face_integral, spp, LU_BALANCED_FACES, LU_BRDF_SAMPLES, ticks);
    for (int k = 0; k < 7; ++k) total += ticks[k];
    float4 xi = rng_uniform4(seed, 0u, STREAM_HOOK, (uint)i, 0u, 0u);
    int pick = min((int)(xi.x * (float)total), total - 1), strategy = 0;
    while (pick >= ticks[strategy]) pick -= ticks[strategy++];
    vec3_t w;
    float pdf;
    if (strategy < 6) {
        /* The pdf sample_face returns (the one render uses), not a lookup: the χ² check then
         * compares it with pooled_direction_pdf's texel lookup. */
        int texel;
        float3 light_w;
        float pdf_light = sample_face(marginal, conditional, strategy, res,
                                      pool_point(strategy, i, seed, 0u), &light_w, &texel);
        w = vec3_of(light_w);
        pdf = pooled_density(&s, ticks, strategy, pdf_light, w);
    } else {
        w = sample_phong_direction(s.n, s.r, s.p_spec, s.m, xi.y, xi.z, xi.w);
        pdf = pooled_pdf(&s, ticks, marginal, conditional, res, w);
    }
    out[i] = (float4)(float3_of(w), pdf);
}

__kernel void pooled_direction_pdf(__global const float4 *surface, __global const cdf_word_t *marginal,
                                   __global const cdf_word_t *conditional, __global const float *face_integral,
                                   const int res, const int spp, __global const float4 *dirs,
                                   __global float *out)
{
    int i = get_global_id(0);
    shading_t s = load_shading(surface, surface + 1, surface + 2, surface + 3, 0);
    int ticks[7];
    strategy_ticks(s.n, face_integral, spp, LU_BALANCED_FACES, LU_BRDF_SAMPLES, ticks);
    out[i] = pooled_pdf(&s, ticks, marginal, conditional, res, vec3_load(dirs, i));
}

/* Ticks of the seven strategies (six faces, BRDF) for each normal. */
__kernel void split_strategies(__global const float4 *normal, __global const float *face_integral,
                               const int spp, __global int *out)
{
    int p = get_global_id(0), ticks[7];
    strategy_ticks(vec3_load(normal, p), face_integral, spp, LU_BALANCED_FACES, LU_BRDF_SAMPLES, ticks);
    for (int k = 0; k < 7; ++k) out[7 * p + k] = ticks[k];
}
