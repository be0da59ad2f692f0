/* `fis`: filtered importance sampling (Colbert and Křivánek, GPU Gems 3 ch. 20; the choices and
 * deviations are in estimators/fis.py).  N = spp Phong BRDF samples per pixel from a Hammersley
 * set (Eq. 10) with a per-pixel Cranley–Patterson rotation, mapped by ARCHITECTURE.md §Conventions's mixture
 * sampling (Eq. 7-9 for the specular lobe); each sample reads the radiance mip chain at the
 * level of Eq. 11-13 plus the chapter's bias, linearly between the two nearest levels and at the
 * nearest texel within each, and is weighted by ρ·cos/(N·p) (Eq. 2).  envmap.cl without light
 * samples supplies the Phong draws' helpers, the sums and the pdf hook (map_direction_pdf). */
#define LIGHT_SAMPLES 0
#define BRDF_SAMPLES 1
#include "envmap.cl"

#define STREAM_FIS_ROTATION 40u

/* 2^32·Φ2(i) of Eq. 10: the radical inverse in base 2 as a 32-bit word, i's bits reversed.  The
 * halves swap by rotate(), not shifts: Oclgrind's compiler turns the all-shift form into
 * llvm.bitreverse, which its interpreter cannot run.  (PoCL then keeps the shifts, not its
 * bitreverse lowering; the render is no slower.) */
ALWAYS_INLINE lane_uints_t radical_inverse_words(lane_uints_t i)
{
    i = rotate(i, (lane_uints_t)16);
    i = ((i & 0x00ff00ffu) << 8) | ((i >> 8) & 0x00ff00ffu);
    i = ((i & 0x0f0f0f0fu) << 4) | ((i >> 4) & 0x0f0f0f0fu);
    i = ((i & 0x33333333u) << 2) | ((i >> 2) & 0x33333333u);
    return ((i & 0x55555555u) << 1) | ((i >> 1) & 0x55555555u);
}

/* A pixel's Hammersley set of n points: 2^32·i/n as i·step with step = ⌊2^32/n⌋ (off i/n by less
 * than n·2^-32), and the Cranley–Patterson shifts of both coordinates, added to the 32-bit words
 * modulo 2^32: a point's words are then uniform on all 2^32 values whatever i is, so every
 * rotated point, taken alone, is a uniform variate (its top 24 bits are rng_unit's). */
typedef struct { uint step, shift_polar, shift_azimuth; } hammersley_t;

ALWAYS_INLINE hammersley_t hammersley_set(uint seed, uint frame, uint pixel, int n)
{
    philox4x32_ctr_t r = rng_block(seed, frame, STREAM_FIS_ROTATION, pixel, 0u, 0u);
    hammersley_t h = {(uint)(0x100000000ul / (ulong)n), r.v[0], r.v[1]};
    return h;
}

/* The lanes' directions of points `draw` of the set: ξ1 = i/N ⊕ shift picks the lobe by where it
 * falls (specular below p_s) and, rescaled to [0, 1) within that lobe's share, is the polar
 * variate (Eq. 7: cos θ = ξ^{1/(m+1)} about r; the diffuse lobe's cos θ = √ξ about n); ξ2 =
 * Φ2(i) ⊕ shift is the azimuth (Eq. 8).  One uniform for the lobe and the angle keeps the set's
 * stratification in ξ1 (ARCHITECTURE.md §Conventions's mixture, exactly: given the lobe, the rescaled ξ1 is uniform). */
ALWAYS_INLINE lanes3_t lanes_hammersley_direction(const shading_t *s, vec3_t t_n, vec3_t b_n, vec3_t t_r,
                                                  vec3_t b_r, hammersley_t h, lane_ints_t draw)
{
    lane_uints_t i = convert_lane_uints(draw);
    lanes_t xi_polar = lanes_unit(i * h.step + h.shift_polar);
    lanes_t azimuth_sin, azimuth_cos;
    sincos_turn_lanes(lanes_unit(radical_inverse_words(i) + h.shift_azimuth), &azimuth_sin, &azimuth_cos);
    lanes_t xi_cos = select((xi_polar - s->p_spec) / (1.0f - s->p_spec), xi_polar / s->p_spec,
                            xi_polar < s->p_spec);
    xi_cos = clamp(xi_cos, 0.0f, 0x1.fffffep-1f);
    return lanes_phong_direction(s, t_n, b_n, t_r, b_r, xi_cos, sqrt(xi_cos), phong_power_log2_lanes(xi_cos),
                                 xi_polar, azimuth_sin, azimuth_cos);
}

/* The radiance of mip level `level` (nearest texel) at the level-0 texel (face, row, col): level l
 * of face size ⌈R/2^l⌉ starts at texel level_offsets.s[l] of `mips` (harness/mips.py's layout;
 * a kernel argument, so no buffer per render), and its texel (row >> l, col >> l) averages the
 * level-0 texels below it. */
ALWAYS_INLINE lanes3_t lanes_level_radiance(__global const float4 *mips, int16 level_offsets, int res,
                                            lane_ints_t level, lane_ints_t face, lane_ints_t row,
                                            lane_ints_t col)
{
    lane_ints_t level_res = (((lane_ints_t)(res - 1)) >> level) + 1;
    lane_ints_t texel = shuffle(level_offsets, convert_lane_uints(level))
                      + (face * level_res + (row >> level)) * level_res + (col >> level);
    return lanes_texel_radiance(mips, texel);
}

/* The filtered radiance a sample of density `pdf` in direction w reads (Sec. 20.4):
 *   lod = max(½·log2(Ω_s/Ω_p), 0) + lod_bias                                     (Eq. 13, + 1)
 *   Ω_s = 1/(N·p)                                                                    (Eq. 11)
 *   Ω_p = d(u)/(w·h), w·h = R², d(u) = 4/(1+u²+v²)^{3/2}                             (Eq. 12)
 * so ½·log2(Ω_s/Ω_p) = ½·log2((1+u²+v²)^{3/2}/p) + lod_shift, lod_shift = ½·log2(R²/(4N)); the
 * lod is clamped to the coarsest level `top`, and the level-lod radiance is the linear blend of
 * levels ⌊lod⌋ and ⌊lod⌋ + 1 (each at its nearest texel).  A density of 0 (a sample that adds
 * nothing) reads the coarsest level. */
ALWAYS_INLINE lanes3_t lanes_filtered_radiance(__global const float4 *mips, int16 level_offsets,
                                               int res, int top, float lod_shift, float lod_bias,
                                               lanes3_t w, lanes_t pdf)
{
    lane_ints_t face, row, col;
    lanes_t jacobian = lanes_texel_of(res, w, &face, &row, &col);   /* (1+u²+v²)^{3/2} */
    lanes_t lod = max(0.5f * phong_power_log2_lanes(max(jacobian / pdf, 0x1p-126f)) + lod_shift, 0.0f);
    lod = min(lod + lod_bias, (float)top);
    lanes_t level = floor(lod), fine_share = 1.0f - (lod - level);
    lane_ints_t fine = convert_lane_ints(level), coarse = min(fine + 1, (lane_ints_t)top);   /* vector bound: see POOL_LANES */
    lanes3_t a = lanes_level_radiance(mips, level_offsets, res, fine, face, row, col);
    lanes3_t b = lanes_level_radiance(mips, level_offsets, res, coarse, face, row, col);
    return make_lanes3(b.x + fine_share * (a.x - b.x), b.y + fine_share * (a.y - b.y),
                       b.z + fine_share * (a.z - b.z));
}

/* ½·log2(R²/(4N)): Eq. 13's log2(w·h/N) with the cube face's d(u) factor 4 taken out. */
static inline float lod_shift_of(int res, int spp)
{
    return 0.5f * log2((float)res * (float)res / (4.0f * (float)spp));
}

/* Outputs as envmap.cl's render_map: planes of n floats (launch_size), radiance R, G, B;
 * counts used, effective (in samples); evaluations per pixel; either launch shape (light_pool.cl).
 * `levels` (≤ 16) mip levels, the last 1×1. */
__kernel void render_fis(__global const float4 *normal, __global const float4 *view,
                         __global const float4 *kd, __global const float4 *ks_m,
                         __global const uint *visibility, const int n, __global const float4 *mips, const int16 level_offsets,
                         const int levels, const int res, const int spp, const float lod_bias,
                         const uint seed, const uint frame, __global float *radiance,
                         __global float *counts, __global int *evaluations LAUNCH_PARAMS)
{
    launch_item_t item = LAUNCH_ITEM(n);
    int p = item.pixel, from, to;
    shading_t s = load_shading(normal, view, kd, ks_m, p);
    vec3_t t_n, b_n, t_r, b_r;
    direction_about_axis_basis(s.n, &t_n, &b_n);
    direction_about_axis_basis(s.r, &t_r, &b_r);
    hammersley_t h = hammersley_set(seed, frame, (uint)p, spp);
    float lod_shift = lod_shift_of(res, spp);
    int ticks = spp * TICKS_PER_SAMPLE;
    lanes_sum_t acc = {(lanes_t)0.0f, (lanes_t)0.0f, (lanes_t)0.0f, (lane_ints_t)0};
    strategy_window(&item, spp, &from, &to);
    for (int i = from; i < to; i += POOL_LANES) {
        lane_ints_t draw = i + LANE_NUMBERS;
        lanes3_t w = lanes_hammersley_direction(&s, t_n, b_n, t_r, b_r, h, draw);
        lanes_t cosine = lanes_dot(s.n, w);
        lanes_t power = phong_power_lanes(max(lanes_dot(s.r, w), 0.0f), (lanes_t)s.m);
        lanes_t pdf = phong_mixture_pdf_lanes(s.p_spec, s.m, cosine, power);
        lanes3_t filtered = lanes_filtered_radiance(mips, level_offsets, res, levels - 1, lod_shift,
                                                    lod_bias, w, pdf);
        add_samples(&acc, &s, draw < spp, lanes_beta(ticks, i), cosine, power, filtered, (float)ticks * pdf,
                    lanes_visible(visibility, p, w));
    }
    store_sums(&acc, item, n, ticks, spp, radiance, counts, evaluations, PARTIAL_SUMS);
}

/* The χ² hook: surface[0..3] = normal, view, kd, (ks, m) of one pixel; the set of `points`
 * points that render_fis draws for pixel 0 of frame 0 at spp = points.  Work item i writes points
 * i·POOL_LANES + k as planes x, y, z, mixture density of n = global size × POOL_LANES floats
 * (those past `points` are padding). */
__kernel void fis_directions(__global const float4 *surface, const int points, const uint seed,
                             __global float *out)
{
    int i = get_global_id(0), n = get_global_size(0) * POOL_LANES, at = i * POOL_LANES;
    shading_t s = load_shading(surface, surface + 1, surface + 2, surface + 3, 0);
    vec3_t t_n, b_n, t_r, b_r;
    direction_about_axis_basis(s.n, &t_n, &b_n);
    direction_about_axis_basis(s.r, &t_r, &b_r);
    lanes3_t w = lanes_hammersley_direction(&s, t_n, b_n, t_r, b_r, hammersley_set(seed, 0u, 0u, points),
                                            at + LANE_NUMBERS);
    lanes_t power = phong_power_lanes(max(lanes_dot(s.r, w), 0.0f), (lanes_t)s.m);
    vstore_lanes(w.x, 0, out + at);
    vstore_lanes(w.y, 0, out + n + at);
    vstore_lanes(w.z, 0, out + 2 * n + at);
    vstore_lanes(phong_mixture_pdf_lanes(s.p_spec, s.m, lanes_dot(s.n, w), power), 0, out + 3 * n + at);
}
