/* Exact reference of DESIGN §3: Σ_texels L_t ∫_texel ρ cos⁺ dω for the piecewise-constant map.
 *
 * Diffuse part: exact.  ∫_texel cos⁺ dω = n · Φ_t for a texel wholly above the horizon, with
 * Φ_t = ∫_texel ω dω its vector irradiance (Lambert/Arvo polygon formula, precomputed in float64
 * on the host); a texel cut by the horizon is clipped to n·x ≥ 0 and the same formula applied.
 * Specular part: sub-texel midpoint quadrature, with as many sub-cells as the lobe's width
 * asks for (REF_DENSITY sub-cells per lobe width 1/√m across the texel's angular radius, and
 * none wider than CELL_RADIANS: the cosines curve on a scale of 1 rad however wide the lobe),
 * at least 8 where the horizon cuts the texel, and none wider than KINK_CELL_RADIANS where the
 * lobe's own plane r·ω = 0 does for m < 2: the lobe's slope jumps there (from ~(m+2)/(2π) to
 * 0), and the midpoint rule's error per unit length of the kink goes as the sub-cell width
 * squared, so the width, not the count, sets it (up to MAX_CELLS² sub-cells per texel: on faces
 * of R ≤ 8 the cells are wider, 1.4e-3 rad at R = 8, 7.5e-3 at R = 1).  At m = 0 the lobe is the
 * half-space r·ω > 0: exact, by clipping the texel to both planes.
 * Texels whose bounding cap keeps the lobe below LOBE_CUTOFF of its peak are skipped: their
 * whole contribution is below LOBE_CUTOFF·(m+2)/(2π)·Ω·L, far under any Monte Carlo error.
 * Sums are compensated, in double where the device has it. */
#include "common.cl"

#ifndef REF_DENSITY
#define REF_DENSITY 16
#endif
#define LOBE_CUTOFF 1e-9f
#define CELL_RADIANS 0.02f
#define KINK_CELL_RADIANS 1e-3f
#define MAX_CELLS 128

#ifdef HAVE_FP64
typedef double3 real3;
#define REAL3(x) convert_double3(x)
#else
typedef float3 real3;
#define REAL3(x) (x)
#endif

/* ∫ ω dω over the spherical polygon through p[0..k) (any positive scale):
 * (1/2) Σ θ_i γ_i, with θ_i the edge's arc and γ_i its unit plane normal (Arvo 1995). */
inline real3 polygon_vector(const real3 *p, int k)
{
    real3 phi = (real3)(0, 0, 0);
    for (int i = 0; i < k; ++i) {
        real3 a = normalize(p[i]), b = normalize(p[(i + 1) % k]);
        real3 c = cross(a, b);
        acc_t s = length(c);
        if (s > 0) phi += atan2(s, dot(a, b)) / s * c;
    }
    return (acc_t)0.5 * phi;
}

/* Sutherland–Hodgman: clip the convex polygon p[0..k) on the planar face quad (whose edges are
 * great-circle arcs) to a·x ≥ 0, into out[0..k+1); returns the clipped vertex count. */
inline int clip_to_halfspace(const real3 *p, int k, real3 a, real3 *out)
{
    int count = 0;
    for (int i = 0; i < k; ++i) {
        real3 x = p[i], y = p[(i + 1) % k];
        acc_t dx = dot(a, x), dy = dot(a, y);
        if (dx >= 0) out[count++] = x;
        if ((dx >= 0) != (dy >= 0)) out[count++] = x + (y - x) * (dx / (dx - dy));
    }
    return count;
}

inline void texel_quad(int face, int row, int col, int res, real3 *quad)
{
    float u0 = -1.0f + 2.0f * col / res, u1 = -1.0f + 2.0f * (col + 1) / res;
    float v0 = -1.0f + 2.0f * row / res, v1 = -1.0f + 2.0f * (row + 1) / res;
    quad[0] = REAL3(face_uv_to_dir(face, u0, v0));
    quad[1] = REAL3(face_uv_to_dir(face, u1, v0));
    quad[2] = REAL3(face_uv_to_dir(face, u1, v1));
    quad[3] = REAL3(face_uv_to_dir(face, u0, v1));
}

/* n · ∫ ω dω over polygon p[0..k): ∫ cos dω when it lies above the horizon.  The orientation of
 * the polygon fixes the sign of the whole sum; the integral is ≥ 0. */
inline acc_t polygon_cosine(float3 n, const real3 *p, int k)
{
    return k < 3 ? 0 : fabs(dot(REAL3(n), polygon_vector(p, k)));
}

/* ∫ cos⁺ dω over a texel the horizon cuts: the texel clipped to n·x ≥ 0. */
inline acc_t clipped_cosine(float3 n, int face, int row, int col, int res)
{
    real3 quad[4], clipped[5];
    texel_quad(face, row, col, res, quad);
    return polygon_cosine(n, clipped, clip_to_halfspace(quad, 4, REAL3(n), clipped));
}

/* ∫_texel [r·ω > 0] cos⁺(n·ω) dω, the lobe integral at m = 0: the texel clipped to both planes. */
inline acc_t half_space_cosine(float3 n, float3 r, int face, int row, int col, int res)
{
    real3 quad[4], by_r[5], both[6];
    texel_quad(face, row, col, res, quad);
    int k = clip_to_halfspace(quad, 4, REAL3(r), by_r);
    return polygon_cosine(n, both, clip_to_halfspace(by_r, k, REAL3(n), both));
}

/* ∫_texel max(0, r·ω)^m cos⁺(n·ω) dω by midpoint quadrature on sub-cells of the face square;
 * cells per side follow the lobe width 1/√m across the texel's angular radius α and the
 * cut planes (see the top of this file). */
inline acc_t specular_integral(float3 n, float3 r, float m, int face, int row, int col, int res,
                               float alpha, int cut_by_horizon, int cut_by_lobe_plane)
{
    int cells = clamp((int)ceil(alpha * max(REF_DENSITY * sqrt(m), 1.0f / CELL_RADIANS)), 2, 64);
    if (cut_by_horizon) cells = max(cells, 8);
    if (cut_by_lobe_plane) cells = clamp((int)ceil(alpha / KINK_CELL_RADIANS), cells, MAX_CELLS);
    float step = 2.0f / (res * cells);
    acc_t sum = 0;      /* up to MAX_CELLS² positive terms */
    for (int i = 0; i < cells; ++i) {
        float v = -1.0f + 2.0f * row / res + (i + 0.5f) * step;
        for (int j = 0; j < cells; ++j) {
            float u = -1.0f + 2.0f * col / res + (j + 0.5f) * step;
            float3 w = normalize(face_uv_to_dir(face, u, v));
            float c_r = dot(r, w), c_n = dot(n, w);
            if (c_r > 0.0f && c_n > 0.0f)
                sum += exp2(m * log2(c_r)) * c_n / area_per_solid_angle(u, v);
        }
    }
    return sum * step * step;
}

/* The lobe falls below LOBE_CUTOFF beyond angle θ_cut from r: (cos θ_cut, sin θ_cut). */
inline float2 lobe_cut(float m)
{
    float cos_cut = exp(log(LOBE_CUTOFF) / m);
    return (float2)(cos_cut, sqrt(1.0f - cos_cut * cos_cut));
}

/* ∫_texel cos⁺(n·ω) dω (x) and ∫_texel max(0, r·ω)^m cos⁺(n·ω) dω (y, 0 without a lobe or where
 * the texel's cap is beyond the lobe's cut) of texel t; 0 for a texel wholly below the horizon. */
inline void texel_integrals(float3 n, float3 r, float m, int specular, float2 cut,
                            __global const float4 *texel_centre, __global const float4 *texel_vector,
                            int t, int res, acc_t *cosine, acc_t *lobe)
{
    float4 centre = texel_centre[t];
    float cn = dot(n, centre.xyz);
    *cosine = 0;
    *lobe = 0;
    if (cn <= -centre.w) return;                    /* the texel's cap is below the horizon */
    int face = t / (res * res), row = (t / res) % res, col = t % res;
    int cut_by_horizon = cn < centre.w;
    float4 phi = texel_vector[t];
    *cosine = cut_by_horizon ? clipped_cosine(n, face, row, col, res) : (acc_t)dot(n, phi.xyz);
    /* Is any point of the cap within θ_cut of r?  cos(θ_cut + α) test. */
    float sin_a = centre.w, cos_a = sqrt(1.0f - sin_a * sin_a);
    if (specular && dot(r, centre.xyz) > cut.x * cos_a - cut.y * sin_a) {
        int cut_by_lobe_plane = m < 2.0f && fabs(dot(r, centre.xyz)) < sin_a;
        *lobe = m == 0.0f ? half_space_cosine(n, r, face, row, col, res)
              : specular_integral(n, r, m, face, row, col, res, phi.w, cut_by_horizon,
                                  cut_by_lobe_plane);
    }
}

inline int has_lobe(float3 ks) { return ks.x > 0.0f || ks.y > 0.0f || ks.z > 0.0f; }

__kernel void reference(__global const float4 *normal, __global const float4 *view,
                        __global const float4 *kd, __global const float4 *ks_m,
                        __global const float4 *env, __global const float4 *texel_centre,
                        __global const float4 *texel_vector, const int res,
                        __global float4 *out)
{
    int p = get_global_id(0);
    float3 n = normal[p].xyz, r = reflect_view(n, view[p].xyz);
    float3 rho_s = ks_m[p].xyz;
    float m = ks_m[p].w;
    int specular = has_lobe(rho_s);
    float2 cut = lobe_cut(m);
    kahan_t diffuse[3] = {{0, 0}, {0, 0}, {0, 0}}, glossy[3] = {{0, 0}, {0, 0}, {0, 0}};
    int texels = 6 * res * res;
    for (int t = 0; t < texels; ++t) {
        float3 radiance = env[t].xyz;
        if (!(radiance.x + radiance.y + radiance.z > 0.0f)) continue;
        acc_t cosine, lobe;
        texel_integrals(n, r, m, specular, cut, texel_centre, texel_vector, t, res, &cosine, &lobe);
        kahan_add(&diffuse[0], cosine * radiance.x);
        kahan_add(&diffuse[1], cosine * radiance.y);
        kahan_add(&diffuse[2], cosine * radiance.z);
        kahan_add(&glossy[0], lobe * radiance.x);
        kahan_add(&glossy[1], lobe * radiance.y);
        kahan_add(&glossy[2], lobe * radiance.z);
    }
    float3 d = (float3)((float)diffuse[0].sum, (float)diffuse[1].sum, (float)diffuse[2].sum);
    float3 s = (float3)((float)glossy[0].sum, (float)glossy[1].sum, (float)glossy[2].sum);
    float3 result = kd[p].xyz / IBL_PI * d;
    if (specular) result += rho_s * (m + 2.0f) / (2.0f * IBL_PI) * s;
    out[p] = (float4)(result, 0.0f);
}

/* One work item per texel t of pixel p: out[t] = (∫_t cos⁺, ∫_t lobe·cos⁺) of the reference's
 * quadrature, from which a pixel's integral splits into per-texel shares (the stress battery). */
__kernel void texel_integral_table(__global const float4 *normal, __global const float4 *view,
                                   __global const float4 *ks_m, __global const float4 *texel_centre,
                                   __global const float4 *texel_vector, const int res, const int p,
                                   __global float2 *out)
{
    int t = get_global_id(0);
    float3 n = normal[p].xyz, r = reflect_view(n, view[p].xyz);
    float m = ks_m[p].w;
    acc_t cosine, lobe;
    texel_integrals(n, r, m, has_lobe(ks_m[p].xyz), lobe_cut(m), texel_centre, texel_vector, t, res,
                    &cosine, &lobe);
    out[t] = (float2)((float)cosine, (float)lobe);
}
