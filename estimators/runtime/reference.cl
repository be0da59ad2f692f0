/* Exact reference of ARCHITECTURE.md §Conventions: Σ_texels L_t ∫_texel ρ cos⁺ dω for the piecewise-constant map.
 *
 * Diffuse part: exact.  ∫_texel cos⁺ dω = n · Φ_t for a texel wholly above the horizon, with
 * Φ_t = ∫_texel ω dω its vector irradiance (Lambert/Arvo polygon formula, precomputed in float64
 * on the host); a texel cut by the horizon is clipped to n·x ≥ 0 and the same formula applied.
 * Specular part: a composite 2 × 2 Gauss–Legendre rule on sub-cells of the texel's face square
 * cut down to the box that holds the lobe (specular_integral), REF_DENSITY points per lobe width
 * 1/√m and none sparser than 1/CELL_RADIANS a radian (the cosines curve on a scale of 1 rad
 * however wide the lobe), with the horizon integrated exactly (each row of points spans only its
 * part above the horizon, and rows wholly below it are left out of the cells) and sin²(r, ω)
 * formed as a sum of squares (1 − cos² would lose ~m·1e-7 of the lobe to float cancellation at
 * m = 1e4).  Where the lobe's own plane r·ω = 0 cuts the
 * texel for m < 2 the lobe's slope jumps: sub-cells there are no wider than KINK_CELL_RADIANS
 * (up to MAX_CELLS a side).  Measured against tests/test_reference_twin.py's independent
 * quadratures, at reference.py's density of 8: ≤ 3e-6 relative for m from 1 to 1e4 at R = 2, 8,
 * 16, grazing views; a texel lit alone: 2e-5 on the lobe's flank at m = 3000 (2e-4 at density 4),
 * 6e-5 cut by the horizon at grazing views at m = 20 (4e-3 with the rows below it in the cells,
 * 4e-4 without HORIZON_DENSITY).  At m = 0
 * the lobe is the half-space r·ω > 0: exact, by clipping the texel to both planes.
 * Texels whose bounding cap keeps the lobe below LOBE_CUTOFF of its peak are skipped: their
 * whole contribution is below LOBE_CUTOFF·(m+2)/(2π)·Ω·L, far under any Monte Carlo error.
 *
 * Speed (issue 10): one work item per pixel, in work groups that spread over every core;
 * faces wholly below the pixel's horizon are skipped (exact: cos⁺ = 0 there, face_below), and
 * a face's texels go LANES at a time through explicit vectors (SoA tables): the horizon and
 * lobe tests, and the exact n·Φ_t of texels wholly above the horizon.  Black texels contribute nothing and are skipped.  The texels the horizon cuts or
 * the lobe reaches (a few hundred of 6R²) go one by one, each vectorised inside: the clipped
 * polygon's edges, and the lobe's sub-cells, are vector lanes; lobe texels of one sub-cell (most
 * of them on fine maps) go four to a vector step (flush_single_cells).  The lobe's power is exact exp2
 * of an accurate table-free log2 (log2_lanes), not a fast polynomial power.  Sums are plain, in
 * double lanes where the device has it (float otherwise): a few thousand positive terms each. */
#include "common.cl"

#ifndef REF_DENSITY
#define REF_DENSITY 16
#endif
#define LOBE_CUTOFF 1e-9f
#define CELL_RADIANS 0.05f
#define KINK_CELL_RADIANS 1e-3f
#define MAX_CELLS 128
#define HORIZON_DENSITY 2.0f   /* times the points per radian in a lobe texel the horizon cuts */
#define LANES 8
#define SUBCELL_LANES 16   /* sub-cells per step of specular_integral (~15% faster than 8 on PoCL) */

#ifdef HAVE_FP64
typedef double3 real3;
#define REAL3(x) convert_double3(x)
typedef long8 acc_index8_t;          /* shuffle masks and select conditions of acc8_t */
#define convert_uindex8 convert_ulong8
#else
typedef float3 real3;
#define REAL3(x) (x)
typedef int8 acc_index8_t;
#define convert_uindex8 convert_uint8
#endif

/* Sutherland–Hodgman: clip the convex polygon p[0..k) on the planar face quad (whose edges are
 * great-circle arcs) to a·x ≥ 0, into out[0..k+1); returns the clipped vertex count. */
static inline int clip_to_halfspace(const real3 *p, int k, real3 a, real3 *out)
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

static inline void texel_quad(int face, int row, int col, int res, real3 *quad)
{
    float u0 = -1.0f + 2.0f * col / res, u1 = -1.0f + 2.0f * (col + 1) / res;
    float v0 = -1.0f + 2.0f * row / res, v1 = -1.0f + 2.0f * (row + 1) / res;
    quad[0] = REAL3(face_uv_to_dir(face, u0, v0));
    quad[1] = REAL3(face_uv_to_dir(face, u1, v0));
    quad[2] = REAL3(face_uv_to_dir(face, u1, v1));
    quad[3] = REAL3(face_uv_to_dir(face, u0, v1));
}

/* n · ∫ ω dω over the spherical polygon through p[0..k) (k ≤ LANES, any positive scale): ∫ cos dω
 * when it lies above the horizon.  ∫ ω dω = (1/2) Σ θ_i γ_i over the edges, θ_i the edge's arc
 * and γ_i its unit plane normal (Arvo 1995); the edges go through vector lanes, one each.  The
 * orientation of the polygon fixes the sign of the whole sum; the integral is ≥ 0. */
static inline acc_t polygon_cosine(float3 n, const real3 *p, int k)
{
    if (k < 3) return 0;
    acc_t x[LANES], y[LANES], z[LANES];
    for (int i = 0; i < LANES; ++i) {
        real3 v = i < k ? normalize(p[i]) : (real3)(0, 0, 0);
        x[i] = v.x;
        y[i] = v.y;
        z[i] = v.z;
    }
    acc8_t ax = vload8(0, x), ay = vload8(0, y), az = vload8(0, z);
    /* Edge i runs from vertex i to vertex i + 1 (mod k). */
    acc_index8_t next = (acc_index8_t)(1, 2, 3, 4, 5, 6, 7, 8);
    next = select(next, (acc_index8_t)0, next >= (acc_index8_t)k);
    acc8_t bx = shuffle(ax, convert_uindex8(next)), by = shuffle(ay, convert_uindex8(next)),
           bz = shuffle(az, convert_uindex8(next));
    acc8_t cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
    acc8_t s = sqrt(cx * cx + cy * cy + cz * cz);
    acc8_t term = atan2(s, ax * bx + ay * by + az * bz) / s * (n.x * cx + n.y * cy + n.z * cz);
    return fabs(ACC_LITERAL(0.5) * sum_acc8(select((acc8_t)0, term, s > 0)));
}

/* ∫ cos⁺ dω over a texel the horizon cuts: the texel clipped to n·x ≥ 0. */
static inline acc_t clipped_cosine(float3 n, int face, int row, int col, int res)
{
    real3 quad[4], clipped[5];
    texel_quad(face, row, col, res, quad);
    return polygon_cosine(n, clipped, clip_to_halfspace(quad, 4, REAL3(n), clipped));
}

/* ∫_texel [r·ω > 0] cos⁺(n·ω) dω, the lobe integral at m = 0: the texel clipped to both planes. */
static inline acc_t half_space_cosine(float3 n, float3 r, int face, int row, int col, int res)
{
    real3 quad[4], by_r[5], both[6];
    texel_quad(face, row, col, res, quad);
    int k = clip_to_halfspace(quad, 4, REAL3(r), by_r);
    return polygon_cosine(n, both, clip_to_halfspace(by_r, k, REAL3(n), both));
}

/* log2 x = (2/ln 2)·atanh t for t = (x − 1)/(x + 1), |t| ≤ 0.172, by its series to t^9 (the
 * next term is below 2^-28 relative, under float rounding). */
static inline float16 log2_of_ratio(float16 t)
{
    float16 t2 = t * t;
    float16 series = 1.0f + t2 * (1.0f / 3.0f + t2 * (1.0f / 5.0f + t2 * (1.0f / 7.0f + t2 * (1.0f / 9.0f))));
    return (2.0f * 1.44269504088896341f) * t * series;
}

/* log2 x for positive normal x, without table lookups (PoCL's log2 gathers its table lane by
 * lane): x = 2^e·a with a in [√½, √2), ln a = 2 atanh(t), t = (a − 1)/(a + 1), |t| ≤ 0.172, by
 * its series to t^9 (the next term is below 2^-28 relative, under float rounding).  Relative
 * error a few ulps, also near x = 1 where log2 x → 0. */
static inline float16 log2_lanes(float16 x)
{
    int16 bits = as_int16(x);
    float16 a = as_float16((bits & 0x007fffff) | 0x3f800000);   /* [1, 2) */
    int16 upper = a > 1.41421356f;                              /* −1 where a ≥ √2 */
    a = select(a, 0.5f * a, upper);
    /* upper only through select: Oclgrind turns `− upper` into + 255, not + 1 (see CLASSIFY). */
    float16 exponent = convert_float16(((bits >> 23) & 0xff) - 127) + select((float16)0.0f, (float16)1.0f, upper);
    return exponent + log2_of_ratio((a - 1.0f) / (a + 1.0f));
}

/* log2(1 − s) for s in [0, 1), accurate relative to s where s is small: 2 atanh(t)/ln 2 with
 * t = −s/(2 − s) by log2_lanes's series up to s = 1/4 (|t| ≤ 1/7), log2_lanes(1 − s) above
 * (skipped when no lane needs it: in narrow lobes, none does). */
static inline float16 log2_one_minus(float16 s)
{
    float16 near_one = log2_of_ratio(-s / (2.0f - s));
    return all(s < 0.25f) ? near_one : select(log2_lanes(1.0f - s), near_one, s < 0.25f);
}

/* The lobe falls below LOBE_CUTOFF beyond angle θ_cut from r: (cos θ_cut, sin θ_cut). */
static inline float2 lobe_cut(float m)
{
    float cos_cut = exp(log(LOBE_CUTOFF) / m);
    return (float2)(cos_cut, sqrt(1.0f - cos_cut * cos_cut));
}

/* Quadrature points per radian for shininess m: REF_DENSITY per lobe width 1/√m, and at
 * least 1/CELL_RADIANS (the cosines curve on a scale of 1 rad however wide the lobe). */
static inline float points_per_radian(float m) { return max(REF_DENSITY * sqrt(m), 1.0f / CELL_RADIANS); }

/* r·ω and n·ω over face f as linear forms of the face point (u, v), times √q: the point's
 * direction N + uU + vV (face_uv_to_dir is linear) has orthonormal N, U, V and squared length
 * q = 1 + u² + v².  Each form holds (x·N, x·U, x·V).  With them, the lobe's box: its centre g =
 * r_N⁻¹(r_U, r_V) on the face plane, 1/(1 + |g|²) = r_N²/|r|², and the half side of a square
 * around g that holds every direction within θ_cut of r (none beyond it is above LOBE_CUTOFF),
 * or INFINITY where the cap reaches within 3° of the face's plane: a great-circle path of angle
 * θ from r stays within the angle β + θ of N (cos β = r_N), where the face plane stretches
 * lengths by at most 1/cos²(β + θ). */
typedef struct {
    float3 r, n;
    float centre_u, centre_v, inverse_centre_q, half_box, inverse_r2;
    int centred;   /* is g near enough (|r_N| > |r|/10) for sin² from the offset to g? */
} face_forms_t;

static inline face_forms_t face_forms(float3 n, float3 r, float2 cut, int face)
{
    float3 origin = face_uv_to_dir(face, 0.0f, 0.0f);
    float3 along_u = face_uv_to_dir(face, 1.0f, 0.0f) - origin;
    float3 along_v = face_uv_to_dir(face, 0.0f, 1.0f) - origin;
    float3 form_r = (float3)(dot(r, origin), dot(r, along_u), dot(r, along_v));
    float cos_beta = form_r.x * rsqrt(dot(r, r)), sin_beta = sqrt(max(0.0f, 1.0f - cos_beta * cos_beta));
    float cos_far = cos_beta * cut.x - sin_beta * cut.y;
    face_forms_t forms = {form_r, (float3)(dot(n, origin), dot(n, along_u), dot(n, along_v)),
                          form_r.y / form_r.x, form_r.z / form_r.x, cos_beta * cos_beta,
                          cos_far > 0.05f ? atan2(cut.y, cut.x) / (cos_far * cos_far) : INFINITY,
                          1.0f / dot(r, r), fabs(cos_beta) > 0.1f};
    return forms;
}

/* A texel's square on its face, cut down to the lobe's box (face_forms) and to the rows that
 * reach above the horizon, in the coordinates of the rule: s inner, t outer, (u, v) or (v, u), s
 * the face axis along which n·ω changes faster.
 * Sub-cells per side follow points_per_radian over the side's angular length (face-plane
 * length / √q at its point nearest the face centre bounds it), and none wider than
 * KINK_CELL_RADIANS where the lobe's own plane r·ω = 0 cuts the texel for m < 2 (the lobe's
 * slope jumps there; up to MAX_CELLS sub-cells a side). */
typedef struct {
    float s_lo, s_hi, t_lo, step_t;
    int cells_s, cells_t;
} lobe_cells_t;

static inline int s_is_v(face_forms_t forms) { return fabs(forms.n.z) > fabs(forms.n.y); }

/* The texel's cells; 0 where its square misses the lobe's box. */
static inline int lobe_cells(face_forms_t forms, float density, int row, int col, int res, int cut_by_lobe_plane,
                             lobe_cells_t *cells)
{
    float side = 2.0f / res, half_box = forms.half_box, centre_u = forms.centre_u, centre_v = forms.centre_v;
    float u_lo = -1.0f + side * col, v_lo = -1.0f + side * row, u_hi = u_lo + side, v_hi = v_lo + side;
    if (half_box < INFINITY) {
        u_lo = max(u_lo, centre_u - half_box);
        u_hi = min(u_hi, centre_u + half_box);
        v_lo = max(v_lo, centre_v - half_box);
        v_hi = min(v_hi, centre_v + half_box);
    }
    /* Rows wholly below the horizon n·ω = 0 are cut off: the integral over a row falls to 0
     * where the horizon leaves the row and stays 0 beyond, a kink inside a cell that the 2-point
     * rule misses by up to 4e-3 of a grazing texel's lobe (issue 34). */
    if (s_is_v(forms)) {
        float above = forms.n.x + max(forms.n.z * v_lo, forms.n.z * v_hi);   /* row's top, less n.y·u */
        if (forms.n.y > 0.0f) u_lo = max(u_lo, -above / forms.n.y);
        if (forms.n.y < 0.0f) u_hi = min(u_hi, -above / forms.n.y);
    } else {
        float above = forms.n.x + max(forms.n.y * u_lo, forms.n.y * u_hi);
        if (forms.n.z > 0.0f) v_lo = max(v_lo, -above / forms.n.z);
        if (forms.n.z < 0.0f) v_hi = min(v_hi, -above / forms.n.z);
    }
    if (u_lo >= u_hi || v_lo >= v_hi) return 0;
    float nearest_u = max(0.0f, max(u_lo, -u_hi)), nearest_v = max(0.0f, max(v_lo, -v_hi));
    float per_length = density / sqrt(1.0f + nearest_u * nearest_u + nearest_v * nearest_v);
    /* Where the horizon cuts the cells, the row integral keeps a kink where the horizon enters
     * the row (its second derivative jumps): twice the points there (4e-4 → 6e-5 of a grazing
     * texel's lobe at m = 20). */
    float lowest = forms.n.x + min(forms.n.y * u_lo, forms.n.y * u_hi)
                 + min(forms.n.z * v_lo, forms.n.z * v_hi);   /* n·ω√q at the lowest corner */
    if (lowest < 0.0f) per_length *= HORIZON_DENSITY;
    if (cut_by_lobe_plane) per_length = max(per_length, 1.0f / KINK_CELL_RADIANS);
    int cells_u = clamp((int)ceil((u_hi - u_lo) * per_length / 2.0f), 1, MAX_CELLS);
    int cells_v = clamp((int)ceil((v_hi - v_lo) * per_length / 2.0f), 1, MAX_CELLS);
    int swap = s_is_v(forms);
    cells->s_lo = swap ? v_lo : u_lo;
    cells->s_hi = swap ? v_hi : u_hi;
    cells->t_lo = swap ? u_lo : v_lo;
    cells->cells_s = swap ? cells_v : cells_u;
    cells->cells_t = swap ? cells_u : cells_v;
    cells->step_t = ((swap ? u_hi : v_hi) - cells->t_lo) / cells->cells_t;
    return 1;
}

#define GAUSS_OFFSET 0.577350269189625765f   /* Gauss–Legendre nodes 1/2 ± 1/(2√3) of a cell */

/* The rule's terms at SUBCELL_LANES points, each on row t of its texel (rows span [s_lo, s_hi]
 * in `cells_s` sub-cells), at the fraction `position` of its sub-cell along the row, weighed
 * for 2 × 2 nodes per sub-cell (times the row step, which the caller applies).  The horizon is
 * integrated exactly, not as a kink inside cells: each row has its sub-cells over only its part
 * above the horizon (the row integral stays C¹ in t: the integrand vanishes where the horizon
 * leaves the row).  With the face forms, cos_r^m = exp2(m/2 · log2((r·d)²/q)) (exact exp2 and
 * log2_lanes, not a fast power: the reference needs ~1e-6) and dω = dA/q^{3/2}. */
static inline float16 lobe_terms(face_forms_t forms, float m, float16 t, float16 s_lo, float16 s_hi, float16 position,
                                 float per_cell_s)
{
    int swap = s_is_v(forms);
    float b_s = swap ? forms.n.z : forms.n.y, b_t = swap ? forms.n.y : forms.n.z, inverse_b_s = 1.0f / b_s;
    /* The row's part above the horizon: s ≥ or ≤ −(a + b_t·t)/b_s, with n·ω·√q = a + b_s·s + b_t·t. */
    float16 edge = -(forms.n.x + b_t * t) * inverse_b_s;
    float16 row_lo = b_s > 0.0f ? clamp(edge, s_lo, s_hi) : s_lo;
    float16 row_hi = b_s < 0.0f ? clamp(edge, s_lo, s_hi) : s_hi;
    float16 step_s = (row_hi - row_lo) * per_cell_s;
    float16 s = row_lo + position * step_s;
    float16 weight = 0.25f * step_s;   /* both nodes weigh 1/2 */
    float16 u = swap ? t : s, v = swap ? s : t;
    float16 inverse_q = 1.0f / (1.0f + u * u + v * v);
    float16 c_r = forms.r.x + u * forms.r.y + v * forms.r.z;   /* times √q */
    float16 c_n = forms.n.x + u * forms.n.y + v * forms.n.z;
    /* sin²(r, ω) from the offset δ to the lobe's centre g: (|δ|² + (g × δ)²)/(|g|² + 1)/q,
     * a sum of squares, where 1 − cos² would cancel to ~1/m of its float precision; 1 − cos²
     * where g is far off, on faces that only lobes with m ≲ 150 reach from beyond 84°. */
    float16 sin2;
    if (forms.centred) {
        float16 du = u - forms.centre_u, dv = v - forms.centre_v, twist = forms.centre_u * dv - forms.centre_v * du;
        sin2 = (du * du + dv * dv + twist * twist) * inverse_q * forms.inverse_centre_q;
    } else {
        sin2 = max(0.0f, 1.0f - c_r * c_r * inverse_q * forms.inverse_r2);
    }
    float16 term = exp2(0.5f * m * log2_one_minus(sin2)) * max(c_n, 0.0f)
                 * inverse_q * inverse_q * weight;
    return select((float16)0.0f, term, c_r > 0.0f && step_s > 0.0f);
}

/* ∫_texel max(0, r·ω)^m cos⁺(n·ω) dω by a composite Gauss–Legendre rule (2 × 2 points per
 * sub-cell) on the texel's cells (lobe_cells), SUBCELL_LANES points per step (lobe_terms). */
static inline acc_t specular_integral(face_forms_t forms, float m, lobe_cells_t cells)
{
    int points_s = 2 * cells.cells_s, count = points_s * 2 * cells.cells_t;
    float per_point_s = 1.0f / points_s, per_cell_s = 1.0f / cells.cells_s;
    const float16 lane = (float16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    acc8_t sum = 0;      /* positive terms */
    for (int k = 0; k < count; k += SUBCELL_LANES) {
        float16 index = (float)k + lane;
        /* Point (i, j), in sub-cell (i / 2, j / 2) at node (i % 2, j % 2): truncation is floor. */
        float16 i = convert_float16(convert_int16((index + 0.5f) * per_point_s)), j = index - i * points_s;
        float16 cell_i = convert_float16(convert_int16((i + 0.5f) * 0.5f)), node_i = i - 2.0f * cell_i;
        float16 cell_j = convert_float16(convert_int16((j + 0.5f) * 0.5f)), node_j = j - 2.0f * cell_j;
        float16 t = cells.t_lo + (cell_i + 0.5f + (node_i - 0.5f) * GAUSS_OFFSET) * cells.step_t;
        float16 term = lobe_terms(forms, m, t, (float16)cells.s_lo, (float16)cells.s_hi,
                                  cell_j + 0.5f + (node_j - 0.5f) * GAUSS_OFFSET, per_cell_s);
        term = select((float16)0.0f, term, index < count);
        sum += convert_acc8(term.lo) + convert_acc8(term.hi);
    }
    return sum_acc8(sum) * cells.step_t;
}

/* Texels of one sub-cell (4 points each, most lobe texels of fine maps) wait in a batch of
 * SINGLE_CELL_BATCH, so that a step of SUBCELL_LANES lanes evaluates the points of four texels,
 * not one texel's four points in sixteen lanes: lane l is node (l/2 % 2, l % 2) of texel l/4. */
#define SINGLE_CELL_BATCH (SUBCELL_LANES / 4)
typedef struct {
    float s_lo[SINGLE_CELL_BATCH], s_hi[SINGLE_CELL_BATCH], t_lo[SINGLE_CELL_BATCH],
          step_t[SINGLE_CELL_BATCH], red[SINGLE_CELL_BATCH], green[SINGLE_CELL_BATCH], blue[SINGLE_CELL_BATCH];
    int count;
} single_cells_t;

/* Each texel's lane value: its ∫ lobe·cos⁺ from its four points, in float16 lanes. */
static inline float16 per_texel(const float *batch_values)
{
    return shuffle(vload4(0, batch_values), (uint16)(0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3));
}

/* Adds Σ L_t ∫_t lobe·cos⁺ dω of the batch's texels to `glossy` (red, green, blue) and empties it. */
static inline void flush_single_cells(face_forms_t forms, float m, single_cells_t *batch, acc8_t *glossy)
{
    if (!batch->count) return;
    const float16 lane = (float16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    float16 node_i = (float16)(0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1), node_j = (float16)(0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1);
    float16 step_t = per_texel(batch->step_t);
    float16 t = per_texel(batch->t_lo) + (0.5f + (node_i - 0.5f) * GAUSS_OFFSET) * step_t;
    float16 term = lobe_terms(forms, m, t, per_texel(batch->s_lo), per_texel(batch->s_hi),
                              0.5f + (node_j - 0.5f) * GAUSS_OFFSET, 1.0f) * step_t;
    term = select((float16)0.0f, term, lane < 4.0f * batch->count);
    acc8_t term_lo = convert_acc8(term.lo), term_hi = convert_acc8(term.hi);
    float16 red = per_texel(batch->red), green = per_texel(batch->green), blue = per_texel(batch->blue);
    glossy[0] += term_lo * convert_acc8(red.lo) + term_hi * convert_acc8(red.hi);
    glossy[1] += term_lo * convert_acc8(green.lo) + term_hi * convert_acc8(green.hi);
    glossy[2] += term_lo * convert_acc8(blue.lo) + term_hi * convert_acc8(blue.hi);
    batch->count = 0;
}

/* Texel tables as structures of arrays: plane k of `table` holds, for every texel t (stride
 * `texels`, the 6R² texels plus LANES of padding), k = 0-2 its centre, 3 sin α, 4-6 Φ_t
 * (reference.py's texel_tables); `env_planes` holds the map's red, green and blue. */
#define PLANE(table, k, t, texels) ((table)[(k) * (texels) + (t)])
#define PLANE_LANES(table, k, t, texels) vload8(0, (table) + (k) * (texels) + (t))

/* Where texel t stands for normal n and mirror direction r: its bounding cap against the
 * horizon, and whether any point of the cap is within θ_cut of r (the cos(θ_cut + α) test).
 * Scalar and vector alike (gentype float or float8), so that both kernels classify alike.
 * Vector comparisons go on only through select, &&, || and vector operands: Oclgrind (21.10)
 * holds a comparison's true lanes as all ones but a constant true as 1, so `!` of a vector
 * comparison gives −2 and 1, its zero extension (`x − (a > b)`) 255, and scalar && vector 1,
 * which select and any() read as false. */
#define CLASSIFY(n, r, cx, cy, cz, sin_a, cut, cn, cr, above, cut_by_horizon, in_lobe) \
    cn = n.x * (cx) + n.y * (cy) + n.z * (cz); \
    cr = r.x * (cx) + r.y * (cy) + r.z * (cz); \
    above = cn >= (sin_a); \
    cut_by_horizon = cn > -(sin_a) && cn < (sin_a); \
    in_lobe = cr > (cut).x * sqrt(1.0f - (sin_a) * (sin_a)) - (cut).y * (sin_a);

/* ∫_texel max(0, r·ω)^m cos⁺(n·ω) dω of texel t, whose cap reaches the lobe and the upper
 * hemisphere (cr = r·centre); `forms` are those of its face.  With a `batch` (the reference
 * kernel), a texel of one sub-cell joins it with its radiance instead, and counts 0 here. */
static inline acc_t texel_lobe(float3 n, float3 r, float m, face_forms_t forms, int t, int res, float sin_a,
                               float cr, single_cells_t *batch, float3 radiance)
{
    int face = t / (res * res), row = (t / res) % res, col = t % res;
    if (m == 0.0f) return half_space_cosine(n, r, face, row, col, res);
    lobe_cells_t cells;
    if (!lobe_cells(forms, points_per_radian(m), row, col, res, m < 2.0f && fabs(cr) < sin_a, &cells))
        return 0;
    if (!batch || cells.cells_s > 1 || cells.cells_t > 1) return specular_integral(forms, m, cells);
    int k = batch->count++;
    batch->s_lo[k] = cells.s_lo;
    batch->s_hi[k] = cells.s_hi;
    batch->t_lo[k] = cells.t_lo;
    batch->step_t[k] = cells.step_t;
    batch->red[k] = radiance.x;
    batch->green[k] = radiance.y;
    batch->blue[k] = radiance.z;
    return 0;
}

/* ∫_texel cos⁺(n·ω) dω (x) and ∫_texel max(0, r·ω)^m cos⁺(n·ω) dω (y, 0 without a lobe or where
 * the texel's cap is beyond the lobe's cut) of texel t; 0 for a texel wholly below the horizon. */
static inline void texel_integrals(float3 n, float3 r, float m, int specular, float2 cut,
                                   __global const float *table, int texels, int t, int res,
                                   acc_t *cosine, acc_t *lobe)
{
    float sin_a = PLANE(table, 3, t, texels), cn, cr;
    int above, cut_by_horizon, in_lobe;
    CLASSIFY(n, r, PLANE(table, 0, t, texels), PLANE(table, 1, t, texels), PLANE(table, 2, t, texels),
             sin_a, cut, cn, cr, above, cut_by_horizon, in_lobe)
    *cosine = 0;
    *lobe = 0;
    if (above)
        *cosine = n.x * PLANE(table, 4, t, texels) + n.y * PLANE(table, 5, t, texels)
                + n.z * PLANE(table, 6, t, texels);
    if (cut_by_horizon)
        *cosine = clipped_cosine(n, t / (res * res), (t / res) % res, t % res, res);
    if (specular && in_lobe && (above || cut_by_horizon))
        *lobe = texel_lobe(n, r, m, face_forms(n, r, cut, t / (res * res)), t, res, sin_a, cr, 0, 0.0f);
}

static inline int has_lobe(float3 ks) { return ks.x > 0.0f || ks.y > 0.0f || ks.z > 0.0f; }

/* Is the whole face in the closed lower hemisphere of n?  Yes when its four corners are: every
 * direction on the face is a positive multiple of a convex combination of them. */
static inline int face_below(float3 n, int face)
{
    int below = 1;
    for (int j = 0; j < 4; ++j)
        below &= dot(n, face_uv_to_dir(face, (j & 1) ? 1.0f : -1.0f, (j & 2) ? 1.0f : -1.0f)) <= 0.0f;
    return below;
}

/* V of the texels `in_face` (indices within face `face`, past the face clamped to its last) for
 * pixel p: the bit of the visibility cell that holds each (VIS_RES divides res, so a texel lies
 * in one cell: the reference Σ_t V_cell(t)·L_t·∫_t ρ cos⁺ stays exact under this V), as a mask. */
static inline int8 texels_open(__global const uint *visibility, int p, int face, int8 in_face, int res)
{
    in_face = min(in_face, (int8)(res * res - 1));
    int8 row = in_face / res, col = in_face - row * (int8)res;
    int texels_per_cell = res / VIS_RES;
    int8 cell = (face * VIS_RES + row / texels_per_cell) * VIS_RES + col / texels_per_cell;
    __global const uint *mask = visibility + (size_t)p * VIS_WORDS;
    int8 word_index = cell >> 5;
    uint8 word = (uint8)(mask[word_index.s0], mask[word_index.s1], mask[word_index.s2], mask[word_index.s3],
                         mask[word_index.s4], mask[word_index.s5], mask[word_index.s6], mask[word_index.s7]);
    /* −1 where open (a mask); not `… != 0u`, which inlined into `lit && …` Oclgrind 21.10 reads wrong. */
    return -convert_int8((word >> convert_uint8(cell & 31)) & 1u);
}

/* The reference of pixels first … first + count − 1 (one enqueue of a chunk), one work item
 * each.  Faces wholly below the horizon are skipped (exact: cos⁺ = 0 on them).  A face's
 * texels go LANES at a time: the diffuse term n·Φ_t of lit texels wholly above the horizon in
 * vector lanes; lit texels that the horizon cuts or the lobe reaches (a few hundred per pixel)
 * one by one, as texel_integrals does them.  With VISIBILITY, texels of shadowed cells are not lit:
 * V multiplies each texel's term (texels_open). */
__kernel void reference(__global const float4 *normal, __global const float4 *view,
                        __global const float4 *kd, __global const float4 *ks_m,
                        __global const uint *visibility, __global const float *env_planes, __global const float *table,
                        const int res, const int texels, const int first, const int count,
                        __global float4 *out)
{
    if (get_global_id(0) >= count) return;
    int p = first + get_global_id(0);
    float3 n = normal[p].xyz, r = reflect_view(n, view[p].xyz);
    float3 rho_s = ks_m[p].xyz;
    float m = ks_m[p].w;
    int specular = has_lobe(rho_s);
    float2 cut = lobe_cut(m);
    const int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    acc8_t whole_red = 0, whole_green = 0, whole_blue = 0;   /* Σ L·n·Φ_t, whole visible texels */
    acc_t diffuse[3] = {0, 0, 0}, glossy[3] = {0, 0, 0};   /* the texels taken one by one */
    acc8_t batched_glossy[3] = {0, 0, 0};                    /* the texels of one sub-cell */
    single_cells_t batch = {.count = 0};
    for (int face = 0; face < 6; ++face) {
        if (face_below(n, face)) continue;
        face_forms_t forms = face_forms(n, r, cut, face);
        int end = (face + 1) * res * res;
        for (int t = face * res * res; t < end; t += LANES) {
            float8 red = PLANE_LANES(env_planes, 0, t, texels), green = PLANE_LANES(env_planes, 1, t, texels),
                   blue = PLANE_LANES(env_planes, 2, t, texels), sin_a = PLANE_LANES(table, 3, t, texels);
            float8 cn, cr;
            int8 above, cut_by_horizon, in_lobe;
            CLASSIFY(n, r, PLANE_LANES(table, 0, t, texels), PLANE_LANES(table, 1, t, texels),
                     PLANE_LANES(table, 2, t, texels), sin_a, cut, cn, cr, above, cut_by_horizon, in_lobe)
            int8 lit = red + green + blue > 0.0f && t + lane < end;
#if VISIBILITY
            lit = lit && texels_open(visibility, p, face, t - face * res * res + lane, res);
#endif
            float8 cosine = n.x * PLANE_LANES(table, 4, t, texels) + n.y * PLANE_LANES(table, 5, t, texels)
                          + n.z * PLANE_LANES(table, 6, t, texels);
            cosine = select((float8)0.0f, cosine, lit && above);
            whole_red += convert_acc8(cosine * red);
            whole_green += convert_acc8(cosine * green);
            whole_blue += convert_acc8(cosine * blue);
            /* specular picks a whole vector, not lanes by scalar && vector (see CLASSIFY). */
            int8 one_by_one = lit && (specular ? cut_by_horizon || (in_lobe && above) : cut_by_horizon);
            if (!any(one_by_one)) continue;
            for (int k = 0; k < LANES; ++k) {
                if (!((int *)&one_by_one)[k]) continue;
                int texel = t + k, cut_k = ((int *)&cut_by_horizon)[k];
                float3 radiance = (float3)(((float *)&red)[k], ((float *)&green)[k], ((float *)&blue)[k]);
                if (cut_k) {
                    acc_t clipped = clipped_cosine(n, face, (texel / res) % res, texel % res, res);
                    diffuse[0] += clipped * radiance.x;
                    diffuse[1] += clipped * radiance.y;
                    diffuse[2] += clipped * radiance.z;
                }
                if (specular && ((int *)&in_lobe)[k]) {
                    acc_t lobe = texel_lobe(n, r, m, forms, texel, res, ((float *)&sin_a)[k],
                                            ((float *)&cr)[k], &batch, radiance);
                    glossy[0] += lobe * radiance.x;
                    glossy[1] += lobe * radiance.y;
                    glossy[2] += lobe * radiance.z;
                    if (batch.count == SINGLE_CELL_BATCH) flush_single_cells(forms, m, &batch, batched_glossy);
                }
            }
        }
        flush_single_cells(forms, m, &batch, batched_glossy);   /* the next face has other forms */
    }
    for (int c = 0; c < 3; ++c) glossy[c] += sum_acc8(batched_glossy[c]);
    float3 d = (float3)((float)(sum_acc8(whole_red) + diffuse[0]), (float)(sum_acc8(whole_green) + diffuse[1]),
                        (float)(sum_acc8(whole_blue) + diffuse[2]));
    float3 s = (float3)((float)glossy[0], (float)glossy[1], (float)glossy[2]);
    float3 result = kd[p].xyz / IBL_PI * d;
    if (specular) result += rho_s * (m + 2.0f) / (2.0f * IBL_PI) * s;
    out[p] = (float4)(result, 0.0f);
}

/* One work item per texel t of pixel p: out[t] = (∫_t cos⁺, ∫_t lobe·cos⁺) of the reference's
 * quadrature, from which a pixel's integral splits into per-texel shares (the stress battery). */
__kernel void texel_integral_table(__global const float4 *normal, __global const float4 *view,
                                   __global const float4 *ks_m, __global const float *table,
                                   const int res, const int texels, const int p, __global float2 *out)
{
    int t = get_global_id(0);
    float3 n = normal[p].xyz, r = reflect_view(n, view[p].xyz);
    float m = ks_m[p].w;
    acc_t cosine, lobe;
    texel_integrals(n, r, m, has_lobe(ks_m[p].xyz), lobe_cut(m), table, texels, t, res, &cosine, &lobe);
    out[t] = (float2)((float)cosine, (float)lobe);
}
