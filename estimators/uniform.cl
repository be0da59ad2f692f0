/* `uniform`: Lu 2013's baseline, μ_f = 1/6 (Sec. 2.1), with the estimator of Eq. 4:
 *   L ≈ 1/N_s Σ_f Σ_{i < N_f + 1} β_i s(ω_i) / (μ_f pdf_L(ω_i|f)),  N_f = μ_f N_s,
 * and β_i of Eq. 5 (1, or frac(N_f) for the last sample).  Faces with I_f = 0 are skipped:
 * their integrand is zero everywhere, so skipping them changes nothing but the work done. */
#include "common.cl"

__kernel void render_uniform(__global const float4 *normal, __global const float4 *view,
                             __global const float4 *kd, __global const float4 *ks_m,
                             __global const float4 *env, __global const float *marginal,
                             __global const float *conditional, __global const float *face_integral,
                             const int res, const int spp, const uint seed, const uint frame,
                             __global float4 *radiance, __global float2 *counts)
{
    int p = get_global_id(0);
    float3 n = normal[p].xyz, v = view[p].xyz;
    float3 r = reflect_view(n, v);
    float3 rho_d = kd[p].xyz, rho_s = ks_m[p].xyz;
    float m = ks_m[p].w;
    const float mu = 1.0f / 6.0f;
    /* N_f = spp/6 = whole + sixths/6; β of the last sample is sixths/6 (Eq. 5).  Counts are kept
     * in sixths, as integers, so used and effective are exact and never exceed spp by rounding. */
    int whole = spp / 6, sixths = spp % 6;
    int n_draw = whole + (sixths > 0);
    float3 sum = 0.0f;
    int used6 = 0, effective6 = 0;
    for (int f = 0; f < 6; ++f) {
        if (!(face_integral[f] > 0.0f)) continue;
        for (int i = 0; i < n_draw; ++i) {
            int beta6 = (i < whole) ? 6 : sixths;
            float4 xi = rng_uniform4(seed, frame, 0u, (uint)p, (uint)(f * n_draw + i), 0u);
            float3 w;
            int texel;
            float pdf = sample_face(marginal, conditional, f, res, xi, &w, &texel);
            float cosine = dot(n, w);
            used6 += beta6;
            if (cosine > 0.0f && pdf > 0.0f) {
                effective6 += beta6;
                float3 s = phong_brdf(r, w, rho_d, rho_s, m) * cosine * env[texel].xyz;
                sum += (beta6 / 6.0f) * s / (mu * pdf);
            }
        }
    }
    radiance[p] = (float4)(sum / (float)spp, 0.0f);
    counts[p] = (float2)(used6 / 6.0f, effective6 / 6.0f);
}

/* χ² hooks.  The estimator draws N_s/6 samples from every lit face; pooled, its directions have
 * the density of a uniform choice among the lit faces: Σ_{f lit} pdf_L(ω|f) / n_lit. */
__kernel void sample_directions(__global const float *marginal, __global const float *conditional,
                                __global const int *lit_faces, const int n_lit, const int res,
                                const uint seed, __global float4 *out)
{
    int i = get_global_id(0);
    float3 w;
    int texel;
    float4 xi = rng_uniform4(seed, 0u, 1u, (uint)i, 0u, 0u);
    float pdf = sample_face(marginal, conditional, lit_faces[i % n_lit], res, xi, &w, &texel);
    out[i] = (float4)(w, pdf / n_lit);   /* the pdf render uses, checked against direction_pdf */
}

__kernel void direction_pdf(__global const float *marginal, __global const float *conditional,
                            __global const float *face_integral, const int n_lit, const int res,
                            __global const float4 *dirs, __global float *out)
{
    int i = get_global_id(0), face;
    float pdf = light_pdf(marginal, conditional, res, dirs[i].xyz, &face);
    out[i] = face_integral[face] > 0.0f ? pdf / n_lit : 0.0f;
}
