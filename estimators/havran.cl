/* `havran` (Havran et al. 2005): shade every pixel with the frame's K directional lights.
 *
 * The lights are built on the host (estimators/havran.py): direction ω_k (float4, w unused) and
 * weight·radiance W_k = L(ω_k) / (p(ω_k) K) after the FIR filter (float4, w unused).  One work
 * item per covered pixel sums W_k ρ(ω_k) cos⁺(n, ω_k) over the lights above its horizon
 * (per-normal culling: lights with n·ω ≤ 0 are skipped, not evaluated).
 * used = K, effective = the lights above the horizon, evaluations = the lights shaded. */
#include "common.cl"

__kernel void render_havran(__global const float4 *normal, __global const float4 *view,
                            __global const float4 *kd, __global const float4 *ks_m,
                            __global const float4 *light_dir, __global const float4 *light_weight,
                            const int count, __global float4 *radiance, __global float2 *counts,
                            __global int *evaluations)
{
    int p = get_global_id(0);
    float3 n = normal[p].xyz;
    float3 r = reflect_view(n, view[p].xyz);
    float3 kdp = kd[p].xyz, ksp = ks_m[p].xyz;
    float m = ks_m[p].w;
    float3 sum = (float3)(0.0f);
    int above = 0;
    for (int k = 0; k < count; ++k) {
        float3 w = light_dir[k].xyz;
        float c = dot(n, w);
        if (c <= 0.0f)
            continue;
        ++above;
        sum += light_weight[k].xyz * phong_brdf(r, w, kdp, ksp, m) * c;
    }
    radiance[p] = (float4)(sum, 0.0f);
    counts[p] = (float2)((float)count, (float)above);
    evaluations[p] = above;
}
