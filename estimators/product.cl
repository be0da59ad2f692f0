/* `product`: envmap.cl's kernels (budget, MIS with BRDF samples, χ² hooks) with light samples
 * drawn by weighed_descent.cl's descent through the weight pyramid, each choice weighted by the
 * pyramid's sums times the pixel's BRDF·cos factor over the child (hierarchical product
 * sampling of L·ρ·cos⁺, after Clarberg et al. 2005 and Clarberg & Akenine-Möller 2008).
 * Configured by the estimator's defines:
 *   CHILD_WEIGHT  0: the factor's bound over the child's cone of directions; 1: its value at the
 *                 child's centre direction, floored at CENTRE_FLOOR of that bound; 2: the bound
 *                 with the lobe's term capped at its integral over the child's least solid angle
 *                 (a bound of the child's mean factor)
 *   LIGHT_LEVELS  L: the choices among children of pyramid level l < L (0 = texels) weigh by the
 *                 sums alone, as hierarchical's (0: every choice, the faces' included, by the
 *                 product)
 *
 * The factor F(ω) = cos⁺(n, ω)·(Y(kd)/π + Y(ks)·(m+2)/(2π)·cos⁺(r, ω)^m) is the Phong BRDF·cos
 * of add_samples in luminance (no V: the target is map × BRDF × cos), divided by its largest
 * value Y(kd)/π + Y(ks)·(m+2)/(2π) so that it lies in [0, 1] and a weight never exceeds the
 * pyramid's sum (no overflow beside a 1e30 texel).  Over a child, the two cosines are bounded
 * over a cone that holds its directions (cone_cos_bound), each separately. */
#include "lanes.cl"

#ifndef CHILD_WEIGHT
#define CHILD_WEIGHT 0
#endif
#ifndef LIGHT_LEVELS
#define LIGHT_LEVELS 0
#endif

#define CENTRE_FLOOR (1.0f / 16.0f)   /* measured: 1/64 and 1/4 gave more error (the estimator's docstring) */
#define BOUND_MARGIN 0x1p-12f      /* above the bound's float rounding (~1e-6): no child cut by it */
#define FACE_COS 0.577350269f      /* a face's cone about its axis: its corners are 1/√3 off it */
#define FACE_SIN 0.816496581f

/* weighed_descent.cl's weigher: the pixel's normal n, mirror direction r and normalised factor
 * F = cos_n·(diffuse + specular·cos_r^m) (diffuse + specular = 1), and n and r in the frames of
 * the lanes' faces (n·U, n·V, n·W of the face's direction x·U + y·V + W at face point (x, y)). */
typedef struct {
    vec3_t n, r;
    float diffuse, specular, m, lobe_integral;   /* lobe_integral: ∫ cos⁺_r^m dω = 2π/(m + 1) */
    lanes_t n_u, n_v, n_w, r_u, r_v, r_w;
} descent_weigher_t;

#include "weighed_descent.cl"

ALWAYS_INLINE descent_weigher_t product_weigher(const shading_t *s)
{
    float diffuse = vec3_luminance(s->kd) / IBL_PI;
    float specular = vec3_luminance(s->ks) * (s->m + 2.0f) / (2.0f * IBL_PI);
    float largest = diffuse + specular;
    int scaled = largest > 0.0f && isfinite(largest);   /* else the integrand is 0: cos_n alone */
    descent_weigher_t g;
    g.n = s->n;
    g.r = s->r;
    g.m = s->m;
    g.lobe_integral = 2.0f * IBL_PI / (s->m + 1.0f);
    g.diffuse = scaled ? diffuse / largest : 1.0f;
    g.specular = scaled ? specular / largest : 0.0f;
    return g;
}

/* a·U, a·V, a·W of the lanes' faces (lanes_face_direction's table). */
ALWAYS_INLINE void lanes_face_frame(lane_ints_t face, vec3_t a, lanes_t *u, lanes_t *v, lanes_t *w)
{
    lanes_t sign = select((lanes_t)1.0f, (lanes_t)-1.0f, (face & 1) != 0);
    lane_ints_t x_major = face < 2, y_major = (face == 2) | (face == 3);
    *u = select(select(sign * a.x, (lanes_t)a.x, y_major), -sign * a.z, x_major);
    *v = select((lanes_t)-a.y, sign * a.z, y_major);
    *w = sign * select(select((lanes_t)a.z, (lanes_t)a.y, y_major), (lanes_t)a.x, x_major);
}

ALWAYS_INLINE void weigher_at_face(descent_weigher_t *g, lane_ints_t face)
{
    lanes_face_frame(face, g->n, &g->n_u, &g->n_v, &g->n_w);
    lanes_face_frame(face, g->r, &g->r_u, &g->r_v, &g->r_w);
}

/* An upper bound of cos⁺ of the angle between a unit vector and any direction of a cone of half
 * angle θ about an axis, from cos_a = cos α (α the vector's angle to the axis) and cos_lo ≤ cos θ
 * ≤ cos_hi, sin θ ≤ sin_hi: 1 where the vector may lie in the cone (cos_a ≥ cos_lo), else
 * cos(α − θ) = cos α cos θ + sin α sin θ bounded term by term (sin α ≥ 0), plus BOUND_MARGIN,
 * in [0, 1]. */
ALWAYS_INLINE lanes_t cone_cos_bound(lanes_t cos_a, lanes_t cos_lo, lanes_t cos_hi, lanes_t sin_hi)
{
    lanes_t sin_a = sqrt(max(1.0f - cos_a * cos_a, 0.0f));
    lanes_t bound = cos_a * select(cos_lo, cos_hi, cos_a >= 0.0f) + sin_a * sin_hi + BOUND_MARGIN;
    return select(min(max(bound, 0.0f), 1.0f), (lanes_t)1.0f, cos_a >= cos_lo);
}

/* The normalised factor of cos_n (≥ 0) and the lobe's value `lobe` (cos_r^m, or a stand-in). */
ALWAYS_INLINE lanes_t factor_with_lobe(const descent_weigher_t *g, lanes_t cos_n, lanes_t lobe)
{
#if SPECULAR_LOBE
    return cos_n * (g->diffuse + g->specular * lobe);
#else
    return cos_n * g->diffuse;
#endif
}

/* The normalised factor of cosines cos_n, cos_r (≥ 0). */
ALWAYS_INLINE lanes_t factor_of(const descent_weigher_t *g, lanes_t cos_n, lanes_t cos_r)
{
    return factor_with_lobe(g, cos_n, phong_power_lanes(cos_r, (lanes_t)g->m));
}

/* A child's (or a face's) cone of directions: cos_n and cos_r the cosines of its centre direction
 * with n and r, its half angle θ with cos_lo ≤ cos θ ≤ cos_hi and sin θ ≤ sin_hi, and a lower
 * bound of its solid angle. */
typedef struct {
    lanes_t cos_n, cos_r, cos_lo, cos_hi, sin_hi, least_omega;
} cone_t;

/* The bound of cos⁺_r over the cone; its lobe_bound bounds the lobe cos⁺_r^m. */
ALWAYS_INLINE lanes_t cone_r_bound(const cone_t *c)
{
    return cone_cos_bound(c->cos_r, c->cos_lo, c->cos_hi, c->sin_hi);
}

/* An upper bound of c^m for 0 ≤ c ≤ 1: c^m = e^{m ln c} ≤ e^{-m(1 − c)} ≤ (1 + m(1 − c)/32)^{-32}
 * (e^t ≥ (1 + t/32)^32 for t ≥ 0): a reciprocal and five squarings where the power took two
 * polynomials (issue 37: the lobe's power was about a quarter of product's time).  It is
 * tight where the lobe is large (c near 1) and looser in its tail, where the lobe is small. */
ALWAYS_INLINE lanes_t lobe_bound(lanes_t c, float m)
{
    lanes_t b = 1.0f / (1.0f + (m * (1.0f / 32.0f)) * (1.0f - c));
    b *= b;
    b *= b;
    b *= b;
    b *= b;
    return b * b;
}

/* The factor of the cone's child by the CHILD_WEIGHT rule, given the lobe's bound (computed apart,
 * so that weigh_children runs the four children's powers side by side). */
ALWAYS_INLINE lanes_t cone_factor(const descent_weigher_t *g, const cone_t *c, lanes_t bound_lobe)
{
    lanes_t bound_n = cone_cos_bound(c->cos_n, c->cos_lo, c->cos_hi, c->sin_hi);
#if CHILD_WEIGHT == 1
    return max(factor_of(g, max(c->cos_n, 0.0f), max(c->cos_r, 0.0f)),
               CENTRE_FLOOR * factor_with_lobe(g, bound_n, bound_lobe));
#elif CHILD_WEIGHT == 2
    /* the lobe's mean over the child is at most its integral over the child's least solid angle */
    return factor_with_lobe(g, bound_n, min(bound_lobe, g->lobe_integral / c->least_omega));
#else
    return factor_with_lobe(g, bound_n, bound_lobe);
#endif
}

/* Faces: each face's cone is exact, half angle acos(1/√3) about its axis ±e_{f/2}; its solid
 * angle 2π/3. */
ALWAYS_INLINE void weigh_faces(const descent_weigher_t *g, int l, lanes_t w[6])
{
    if (l < LIGHT_LEVELS)
        return;
    float n_axis[3] = {g->n.x, g->n.y, g->n.z}, r_axis[3] = {g->r.x, g->r.y, g->r.z};
    UNROLL
    for (int f = 0; f < 6; ++f) {
        float sign = (f & 1) ? -1.0f : 1.0f;
        cone_t face = {(lanes_t)(sign * n_axis[f >> 1]), (lanes_t)(sign * r_axis[f >> 1]), (lanes_t)FACE_COS,
                       (lanes_t)FACE_COS, (lanes_t)FACE_SIN, (lanes_t)(2.0f * IBL_PI / 3.0f)};
        w[f] *= cone_factor(g, &face, lobe_bound(cone_r_bound(&face), g->m));
    }
}

/* A child at level l spans the texels [x0, x1) of its face (x1 = x0 + 2^l but for an odd size's
 * last), the face square [−1 + 2·x0/R, −1 + 2·x1/R]: its centre (x, y) and half extents (hx, hy).
 * The cone about the centre direction that holds it has half angle θ ≤ √(hx² + hy²)/√(1 + d²),
 * d the child's least distance from the face's centre: the gnomonic map's metric is at most
 * |dp|/√(1 + |p|²), so a straight path from the centre to a corner is no longer on the sphere.
 * cos θ and sin θ are bounded by cos's Taylor terms (1 − t²/2 ≤ cos t ≤ 1 − t²/2 + t⁴/24) and
 * sin t ≤ min(t, 1): no trigonometry.  Its solid angle is at least its face area 4·hx·hy times the
 * gnomonic Jacobian (1 + x² + y²)^{-3/2} at its farthest corner.  Child k of the lanes' parents
 * (row, col), texels 2^l = span wide, scale = 1/R. */
ALWAYS_INLINE cone_t child_cone(const descent_weigher_t *g, int res, int span, float scale, lane_ints_t row,
                                lane_ints_t col, int k)
{
    lane_ints_t x0 = (2 * col + (k & 1)) * span, y0 = (2 * row + (k >> 1)) * span;
    lane_ints_t x1 = min(x0 + span, (lane_ints_t)res), y1 = min(y0 + span, (lane_ints_t)res);
    lanes_t x = convert_lanes(x0 + x1) * scale - 1.0f, y = convert_lanes(y0 + y1) * scale - 1.0f;
    lanes_t hx = convert_lanes(x1 - x0) * scale, hy = convert_lanes(y1 - y0) * scale;
    lanes_t k_centre = rsqrt(1.0f + x * x + y * y);
    lanes_t dx = max(fabs(x) - hx, 0.0f), dy = max(fabs(y) - hy, 0.0f);
    lanes_t t = sqrt(hx * hx + hy * hy) * rsqrt(1.0f + dx * dx + dy * dy);
    lanes_t cos_lo = 1.0f - 0.5f * t * t;
    lanes_t fx = fabs(x) + hx, fy = fabs(y) + hy, k_far = rsqrt(1.0f + fx * fx + fy * fy);
    cone_t c = {(g->n_u * x + g->n_v * y + g->n_w) * k_centre, (g->r_u * x + g->r_v * y + g->r_w) * k_centre,
                cos_lo, cos_lo + t * t * t * t * (1.0f / 24.0f), min(t, 1.0f), 4.0f * hx * hy * k_far * k_far * k_far};
    return c;
}

/* The four children's factors stage by stage (their cones, the lobes' bounds, the factors), not
 * child after child: the same operations on the same values, so the same bits, but four
 * independent chains side by side for the core to overlap (10% less CPU time a sample than
 * child after child, measured with the lobe's exact power, whose division and polynomials are
 * long chains). */
ALWAYS_INLINE void weigh_children(const descent_weigher_t *g, int res, int l, lane_ints_t row, lane_ints_t col,
                                  lanes_t w[4])
{
    if (l < LIGHT_LEVELS)
        return;
    cone_t cone[4];
    lanes_t lobe[4];
    UNROLL
    for (int k = 0; k < 4; ++k) cone[k] = child_cone(g, res, 1 << l, 1.0f / (float)res, row, col, k);
    UNROLL
    for (int k = 0; k < 4; ++k) lobe[k] = lobe_bound(cone_r_bound(&cone[k]), g->m);
    UNROLL
    for (int k = 0; k < 4; ++k) w[k] *= cone_factor(g, &cone[k], lobe[k]);
}

#define LIGHT_PARAMS __global const float *pyramid
#define LIGHT_ARGS pyramid

/* envmap.cl's light sampler: weighed_descent.cl's descent weighted for the pixel of shading s. */
ALWAYS_INLINE lanes3_t lanes_sample_light(LIGHT_PARAMS, const shading_t *s, int res, uint seed, uint frame,
                                          uint pixel, lane_ints_t draw, lane_ints_t *texel, lanes_t *pdf)
{
    descent_weigher_t g = product_weigher(s);
    return weighed_descent_sample(pyramid, &g, res, seed, frame, pixel, draw, texel, pdf);
}

/* envmap.cl's light density: weighed_descent.cl's, with the same weights. */
ALWAYS_INLINE lanes_t lanes_light_density(LIGHT_PARAMS, const shading_t *s, int res, lanes3_t w, lane_ints_t *texel)
{
    descent_weigher_t g = product_weigher(s);
    return weighed_descent_density(pyramid, &g, res, w, texel);
}

#include "envmap.cl"
