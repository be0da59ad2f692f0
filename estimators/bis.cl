/* `bis`: Burke 2005 bidirectional importance sampling by SIR (Kronander §5, Eq. 3-4); the
 * algorithm is documented in sir.cl.  One work item per covered pixel, in padded groups. */
#include "sir.cl"

__kernel void render_bis(__global const float4 *normal, __global const float4 *view,
                         __global const float4 *kd, __global const float4 *ks_m,
                         __global const uint *visibility, __global const float4 *env, const int res, const int M, const int N,
                         const uint seed, const uint frame, const int offset, const int count,
                         __global int *chosen, __global acc_t *bounds, __global acc_t *sums,
                         __global float4 *radiance, __global float2 *counts)
{
    /* Pixels offset … offset + count − 1, in whole groups (LOCKSTEP): items past `count` redo
     * the last pixel in their own scratch slot and store nothing. */
    int item = get_global_id(0), p = offset + min(item, count - 1);
    vec3_t sum;
    float z = bis_pixel(normal, view, kd, ks_m, visibility, p, 0, 0, 0, 0.0f,   /* Burke: BRDF candidates */
                        env, res, M, N, seed, frame, (uint)p, GROUP_SCRATCH(chosen, N),
                        GROUP_SCRATCH(bounds, M), GROUP_SCRATCH(sums, 3), get_local_id(0),
                        get_local_size(0), &sum, 0, 0, 0, 0);
    if (item >= count) return;
    radiance[p] = (float4)(z / (float)N * sum.x, z / (float)N * sum.y, z / (float)N * sum.z, 0.0f);
    /* Every resampled sample has γ > 0, hence a positive cosine; none exist when Ẑ = 0. */
    float used = z > 0.0f ? (float)N : 0.0f;
    counts[p] = (float2)(used, used);
}

/* Debug twin for the tests: the M candidates (ω, w) of pixel 0 and the resampling uniform. */
__kernel void bis_candidates(__global const float4 *normal, __global const float4 *view,
                             __global const float4 *kd, __global const float4 *ks_m,
                             __global const uint *visibility, __global const float4 *env, const int res, const uint seed,
                             const uint frame, __global float4 *out, __global float *u)
{
    int i = get_global_id(0);
    shading_t s = load_shading(normal, view, kd, ks_m, 0);
    sir_proposal_t q = make_proposal(0, 0, 0, 0.0f);
    vec3_t w, radiance;
    float gamma, power;
    float weight = sir_candidate(&s, &q, env, res, seed, frame, 0u, i, (int)get_global_size(0), &w,
                                 &gamma, &radiance, &power, visibility, 0);
    out[i] = (float4)(w.x, w.y, w.z, weight);
    if (i == 0) u[0] = lane_uniform4(seed, frame, STREAM_SIR_RESAMPLE, 0u, 0u, 0u).x;
}

/* Systematic resampling of one weight vector (tests). */
__kernel void resample_systematic(__global const float *weights, const int n, const float u,
                                  __global int *out)
{
    if (get_global_id(0) == 0) systematic_indices(weights, n, u, out);
}
