/* Scalar-form helpers for kernels that PoCL vectorises across work items (issue 10).
 *
 * PoCL 3.1 (LLVM 15) runs the work items of a group as SIMD lanes only over a region of code that
 *   - holds no inner loop: a kernel's own loop (over samples, candidates) must end each iteration
 *     at LOCKSTEP, a barrier, which makes the loop body a region of its own (PoCL then vectorises
 *     the work-item loop inside it);
 *   - holds no value of an OpenCL vector type: float3/float4 arithmetic, loads and returns stop
 *     it ("instruction return type cannot be vectorized");
 *   - holds no call: helpers just above the inliner's threshold stay calls, and so do the library
 *     sin/cos (their argument reduction never inlines);
 *   - carries only scalars across a barrier: a struct or float3 live there becomes a context array
 *     of aggregates, which stops it too;
 *   - selects no whole struct (`c ? a : b` on vec3_t): the optimiser turns that into a
 *     <2 x float> vector, which stops it as any vector type does.
 * Measured on small kernels: 10× per work item and iteration for the barrier, 8× for scalar
 * instead of float3 code.  So the hot paths use vec3_t, three floats in a struct that inlining
 * dissolves into scalars, rebuild per-pixel structs inside each iteration (from the G-buffer),
 * and call only forced-inline helpers.  The helpers here are the float3 helpers of common.cl
 * (DESIGN §3) in that form, operation for operation, so they sample the same directions with the
 * same densities; a GPU runs either form, one work item per lane. */
#ifndef IBLBENCH_LANES_CL
#define IBLBENCH_LANES_CL

#define LANE inline __attribute__((always_inline))

/* common.cl helpers on the hot paths, forced inline by a declaration before their definition. */
LANE float phong_power(float c, float m);
LANE int cdf_search(__global const ulong *cdf, int n, ulong u);
LANE float cdf_bin(__global const ulong *cdf, int i);
LANE float cdf_bin_position(__global const ulong *cdf, int i, ulong u);

#include "common.cl"

/* Ends one iteration of a loop whose trip count is the same in every work item of the group (see
 * the header).  Every work item must reach it: no early exit before or inside such a loop, and
 * the host launches whole, padded groups (estimators/bis.py, run_lockstep). */
#define LOCKSTEP() barrier(CLK_LOCAL_MEM_FENCE)

/* ---- three floats ---------------------------------------------------------------------------- */

typedef struct { float x, y, z; } vec3_t;

LANE vec3_t vec3(float x, float y, float z) { vec3_t v = {x, y, z}; return v; }
LANE vec3_t vec3_add(vec3_t a, vec3_t b) { return vec3(a.x + b.x, a.y + b.y, a.z + b.z); }
LANE vec3_t vec3_scale(vec3_t a, float k) { return vec3(a.x * k, a.y * k, a.z * k); }
LANE vec3_t vec3_mul(vec3_t a, vec3_t b) { return vec3(a.x * b.x, a.y * b.y, a.z * b.z); }
LANE float vec3_dot(vec3_t a, vec3_t b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
LANE float vec3_luminance(vec3_t c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }
LANE int vec3_isfinite(vec3_t a) { return isfinite(a.x) && isfinite(a.y) && isfinite(a.z); }

LANE vec3_t vec3_normalize(vec3_t a) { return vec3_scale(a, 1.0f / sqrt(vec3_dot(a, a))); }

/* Element i of a float4 buffer as scalar loads (.xyz, and .w). */
LANE vec3_t vec3_load(__global const float4 *buffer, int i)
{
    __global const float *f = (__global const float *)(buffer + i);
    return vec3(f[0], f[1], f[2]);
}

LANE float load_w(__global const float4 *buffer, int i) { return ((__global const float *)(buffer + i))[3]; }

/* Compensated sum (common.cl's kahan_add) on two scalars, which may be carried across LOCKSTEP. */
LANE void kahan_add_to(acc_t *sum, acc_t *carry, acc_t x)
{
    acc_t y = x - *carry;
    acc_t t = *sum + y;
    *carry = (t - *sum) - y;
    *sum = t;
}

/* ---- random numbers: common.cl's rng_uniform4 / rng_words2 without vector types --------------- */

typedef struct { float x, y, z, w; } uniform4_t;
typedef struct { ulong x, y; } words2_t;

LANE philox4x32_ctr_t philox_block(uint seed, uint frame, uint stream, uint pixel, uint sample, uint draw)
{
    philox4x32_key_t key = {{seed, (frame << 8) | (stream & 0xffu)}};
    philox4x32_ctr_t ctr = {{pixel, sample, draw, 0u}};
    return philox4x32(ctr, key);
}

LANE uniform4_t lane_uniform4(uint seed, uint frame, uint stream, uint pixel, uint sample, uint draw)
{
    philox4x32_ctr_t r = philox_block(seed, frame, stream, pixel, sample, draw);
    const float scale = 1.0f / 16777216.0f;
    uniform4_t u = {(float)(r.v[0] >> 8) * scale, (float)(r.v[1] >> 8) * scale,
                    (float)(r.v[2] >> 8) * scale, (float)(r.v[3] >> 8) * scale};
    return u;
}

LANE words2_t lane_words2(uint seed, uint frame, uint stream, uint pixel, uint sample, uint draw)
{
    philox4x32_ctr_t r = philox_block(seed, frame, stream, pixel, sample, draw);
    words2_t u = {upsample(r.v[0], r.v[1]), upsample(r.v[2], r.v[3])};
    return u;
}

/* ---- cube map ------------------------------------------------------------------------------- */

/* dir_to_face_st: face and (s, t) by the OpenGL table; ties go to x, then y. */
LANE int lane_face_st(vec3_t d, float *s, float *t)
{
    float ax = fabs(d.x), ay = fabs(d.y), az = fabs(d.z);
    int x_major = ax >= ay && ax >= az, y_major = !x_major && ay >= az;
    float ma = x_major ? ax : y_major ? ay : az;
    float sc = x_major ? (d.x >= 0.0f ? -d.z : d.z) : y_major ? d.x : (d.z >= 0.0f ? d.x : -d.x);
    float tc = x_major ? -d.y : y_major ? (d.y >= 0.0f ? d.z : -d.z) : -d.y;
    *s = (sc / ma + 1.0f) * 0.5f;
    *t = (tc / ma + 1.0f) * 0.5f;
    return x_major ? (d.x >= 0.0f ? 0 : 1) : y_major ? (d.y >= 0.0f ? 2 : 3) : (d.z >= 0.0f ? 4 : 5);
}

/* face_uv_to_dir: face-plane point (u, v) -> (unnormalised) direction on the cube. */
LANE vec3_t lane_face_dir(int face, float u, float v)
{
    float sign = (face & 1) ? -1.0f : 1.0f;
    int x_major = face < 2, y_major = face == 2 || face == 3;   /* selects per component: a */
    return vec3(x_major ? sign : y_major ? u : sign * u,       /* select of structs would */
                y_major ? sign : -v,                           /* become a vector type    */
                x_major ? -sign * u : y_major ? sign * v : sign);
}

/* The texel that holds direction w (nearest lookup, DESIGN §3). */
LANE int lane_texel(vec3_t w, int res)
{
    float s, t;
    int face = lane_face_st(w, &s, &t);
    return texel_index(face, clamp_index(t, res), clamp_index(s, res), res);
}

/* ---- light sampling: common.cl's sample_face / light_pdf ------------------------------------- */

/* common.cl's cdf_search (first i with cdf[i] > u) with a fixed trip count: CDF_STEPS =
 * ⌈log2 R⌉ halvings (the host defines it with ENV_RES), each a no-op once n = 1, so the loop
 * unrolls and a loop body that samples the map stays one region (lanes.cl header).  Without
 * CDF_STEPS it is common.cl's search. */
LANE int lane_cdf_search(__global const cdf_word_t *cdf, int n, cdf_word_t u)
{
#ifdef CDF_STEPS
    int base = 0;
    __attribute__((opencl_unroll_hint))
    for (int i = 0; i < CDF_STEPS; ++i) {
        int step = n >> 1;
        base = (step > 0 && cdf[base + step - 1] <= u) ? base + step : base;
        n -= step;
    }
    return base;
#else
    return cdf_search(cdf, n, u);
#endif
}

LANE float lane_sample_face(__global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                            int face, int res, words2_t u, vec3_t *dir, int *texel)
{
    __global const cdf_word_t *rows = marginal + face * res;
    int row = lane_cdf_search(rows, res, u.x);
    __global const cdf_word_t *cols = conditional + (face * res + row) * res;
    int col = lane_cdf_search(cols, res, u.y);
    float x = -1.0f + 2.0f * ((float)col + cdf_bin_position(cols, col, u.y)) / res;
    float y = -1.0f + 2.0f * ((float)row + cdf_bin_position(rows, row, u.x)) / res;
    *dir = vec3_normalize(lane_face_dir(face, x, y));
    *texel = texel_index(face, row, col, res);
    float texel_area = 4.0f / ((float)res * (float)res);
    return cdf_bin(rows, row) * cdf_bin(cols, col) * area_per_solid_angle(x, y) / texel_area;
}

LANE float lane_light_pdf(__global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                          int res, vec3_t w, int *texel)
{
    float s, t;
    int f = lane_face_st(w, &s, &t);
    int row = clamp_index(t, res), col = clamp_index(s, res);
    float p_texel = cdf_bin(marginal + f * res, row)
                  * cdf_bin(conditional + (f * res + row) * res, col);
    *texel = texel_index(f, row, col, res);
    return p_texel * area_per_solid_angle(2.0f * s - 1.0f, 2.0f * t - 1.0f) * (float)(res * res) / 4.0f;
}

/* ---- Phong BRDF ----------------------------------------------------------------------------- */

/* common.cl's surface_t, from the G-buffer's float4 buffers at pixel p. */
typedef struct {
    vec3_t n, r, kd, ks;
    float m, p_spec, rho_y_kd, rho_y_ks;
} lane_surface_t;

LANE lane_surface_t lane_surface(__global const float4 *normal, __global const float4 *view,
                                 __global const float4 *kd, __global const float4 *ks_m, int p)
{
    lane_surface_t s;
    s.n = vec3_load(normal, p);
    vec3_t v = vec3_load(view, p);
    float nv = 2.0f * vec3_dot(s.n, v);
    s.r = vec3(nv * s.n.x - v.x, nv * s.n.y - v.y, nv * s.n.z - v.z);
    s.kd = vec3_load(kd, p);
    s.ks = vec3_load(ks_m, p);
    s.m = load_w(ks_m, p);
    s.rho_y_kd = vec3_luminance(s.kd);
    s.rho_y_ks = vec3_luminance(s.ks);
    s.p_spec = s.rho_y_ks > 0.0f ? s.rho_y_ks / (s.rho_y_kd + s.rho_y_ks) : 0.0f;
    return s;
}

/* cos⁺(r, ω)^m, computed once per direction and passed to the functions below. */
LANE float lane_lobe_power(const lane_surface_t *s, vec3_t w)
{
    return phong_power(max(vec3_dot(s->r, w), 0.0f), s->m);
}

/* phong_brdf_at: ρ = kd/π + ks·(m+2)/(2π)·power. */
LANE vec3_t lane_brdf(const lane_surface_t *s, float power)
{
    float lobe = (s->m + 2.0f) / (2.0f * IBL_PI) * power;
    return vec3(s->kd.x / IBL_PI + s->ks.x * lobe, s->kd.y / IBL_PI + s->ks.y * lobe,
                s->kd.z / IBL_PI + s->ks.z * lobe);
}

/* ρ_Y = Y(ρ) (Y is linear). */
LANE float lane_brdf_luminance(const lane_surface_t *s, float power)
{
    return s->rho_y_kd / IBL_PI + s->rho_y_ks * ((s->m + 2.0f) / (2.0f * IBL_PI) * power);
}

/* phong_pdf_at: the mixture pdf of lane_sample_phong. */
LANE float lane_phong_pdf(const lane_surface_t *s, vec3_t w, float power)
{
    float pdf = (1.0f - s->p_spec) * max(vec3_dot(s->n, w), 0.0f) / IBL_PI;
#if SPECULAR_LOBE
    pdf += s->p_spec * (s->m + 1.0f) / (2.0f * IBL_PI) * power;
#endif
    return pdf;
}

/* sin and cos of 2πu for u in [0, 1): u's distance to its nearest quarter turn, |a| ≤ π/4, by
 * Taylor polynomials to a⁹ and a¹⁰ (remainders below 2e-9 and 2e-10, under float rounding), then
 * rotated by that quarter.  The library sin/cos call an argument reduction that never inlines. */
LANE void sincos_turn(float u, float *sine, float *cosine)
{
    float x = u - rint(u);                       /* in [−½, ½]: the same angle */
    float quarter = rint(4.0f * x);
    float a = 2.0f * IBL_PI * (x - 0.25f * quarter), a2 = a * a;
    float s = a * (1.0f + a2 * (-1.0f / 6.0f + a2 * (1.0f / 120.0f + a2 * (-1.0f / 5040.0f
            + a2 * (1.0f / 362880.0f)))));
    float c = 1.0f + a2 * (-0.5f + a2 * (1.0f / 24.0f + a2 * (-1.0f / 720.0f
            + a2 * (1.0f / 40320.0f + a2 * (-1.0f / 3628800.0f)))));
    int q = (int)quarter & 3;   /* sin, cos of a + q·π/2, by arithmetic (a select chain became a switch) */
    *sine = ((q & 1) ? c : s) * ((q & 2) ? -1.0f : 1.0f);
    *cosine = ((q & 1) ? s : c) * (((q + 1) & 2) ? -1.0f : 1.0f);
}

/* direction_about: unit direction at polar cosine cos_theta and azimuth 2π·u about the unit axis
 * z (branchless orthonormal basis of Duff et al. 2017). */
LANE vec3_t lane_direction_about(vec3_t z, float cos_theta, float u)
{
    float sign = copysign(1.0f, z.z);
    float a = -1.0f / (sign + z.z);
    float c = z.x * z.y * a;
    vec3_t t = vec3(1.0f + sign * z.x * z.x * a, sign * c, -sign * z.x);
    vec3_t b = vec3(c, sign + z.y * z.y * a, -z.y);
    float sin_theta = sqrt(max(0.0f, 1.0f - cos_theta * cos_theta));
    float sin_phi, cos_phi;
    sincos_turn(u, &sin_phi, &cos_phi);
    return vec3_normalize(vec3(sin_theta * (cos_phi * t.x + sin_phi * b.x) + cos_theta * z.x,
                               sin_theta * (cos_phi * t.y + sin_phi * b.y) + cos_theta * z.y,
                               sin_theta * (cos_phi * t.z + sin_phi * b.z) + cos_theta * z.z));
}

/* sample_phong's direction: the lobe by luminance weight (xi_z), the diffuse lobe cosine-weighted
 * (cos θ = √ξ), the specular lobe ∝ cos^m about r (cos θ = ξ^{1/(m+1)}).  Its pdf is
 * lane_phong_pdf. */
LANE vec3_t lane_sample_phong(const lane_surface_t *s, float xi_x, float xi_y, float xi_z)
{
#if SPECULAR_LOBE
    int specular = xi_z < s->p_spec;
    vec3_t axis = vec3(specular ? s->r.x : s->n.x, specular ? s->r.y : s->n.y, specular ? s->r.z : s->n.z);
    float cos_theta = specular ? phong_power(xi_x, 1.0f / (s->m + 1.0f)) : sqrt(xi_x);
    return lane_direction_about(axis, cos_theta, xi_y);
#else
    return lane_direction_about(s->n, sqrt(xi_x), xi_y);
#endif
}

#endif
