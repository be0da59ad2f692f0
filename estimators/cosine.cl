/* `cosine`: cosine-weighted hemisphere sampling (Malley's method: a uniform point of the unit
 * disc lifted to the hemisphere about n, cos θ = √ξ₁, φ = 2π·ξ₂; Pharr, Jakob and Humphreys,
 * Physically Based Rendering, 4th ed., §A.5.3), density cos⁺(n,ω)/π.  One pixel per work item;
 * each sample adds π·ρ(ω)·L(ω)·V(ω), the integrand over the density (the map's nearest texel, as
 * the reference reads it), and the estimate is their mean.  used = spp, effective = the samples
 * with a positive cosine, evaluations = spp. */
#include "common.cl"

#define STREAM_COSINE 60u

__kernel void render_cosine(__global const float4 *normal, __global const float4 *view,
                            __global const float4 *kd, __global const float4 *ks_m,
                            __global const uint *visibility, __global const float4 *env,
                            const int res, const int spp, const uint seed, const uint frame,
                            __global float4 *radiance, __global float2 *counts)
{
    int p = get_global_id(0);
    surface_t s = make_surface(normal[p], view[p], kd[p], ks_m[p]);
    float3 sum = (float3)(0.0f);
    float effective = 0.0f;
    for (int i = 0; i < spp; ++i) {
        float4 xi = rng_uniform4(seed, frame, STREAM_COSINE, (uint)p, (uint)i, 0u);
        float3 w = direction_about(s.n, sqrt(xi.x), xi.y);
        if (!(dot(s.n, w) > 0.0f))
            continue;
        effective += 1.0f;
        float u, v;
        int face = dir_to_face_st(w, &u, &v);
        float3 light = env[texel_index(face, clamp_index(v, res), clamp_index(u, res), res)].xyz;
        float open = (float)visible(visibility, p, vec3_of(w));
        sum += open * IBL_PI * phong_brdf(s.r, w, s.kd, s.ks, s.m) * light;
    }
    radiance[p] = (float4)(sum / (float)spp, 0.0f);
    counts[p] = (float2)((float)spp, effective);
}
