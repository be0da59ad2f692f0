/* `product`: envmap.cl's kernels (budget, MIS with BRDF samples, χ² hooks) with light samples
 * drawn by descent through the weight pyramid whose PRODUCT_LEVELS coarsest choices (the faces',
 * then the children's of the coarsest nodes) are weighed by the pyramid's sums times the pixel's
 * BRDF·cos factor over the child, and whose finer choices are the frame's descent tables'
 * (`hierarchical`'s): hierarchical product sampling of L·ρ·cos⁺ over the coarse levels, after
 * Clarberg et al. 2005 and Clarberg & Akenine-Möller 2008.  The product choices are made once
 * a work item, in the pixel's table (light_state_t, light_state_of), from the node cones of
 * estimators/product.py's node_cone_table; a sample reads them as it reads the frame's tables.
 * Configured by the estimator's defines:
 *   CHILD_WEIGHT    0: the factor's bound over the child's cone of directions; 1: its value at the
 *                   child's centre direction, floored at CENTRE_FLOOR of that bound; 2: the bound
 *                   with the lobe's term capped at its integral over the child's least solid
 *                   angle (a bound of the child's mean factor)
 *   PRODUCT_LEVELS  T ≥ 1: the choices weighed by the product, the faces' and the T − 1 coarsest
 *                   levels' of children (all of them where the pyramid has fewer)
 *
 * The factor F(ω) = cos⁺(n, ω)·(Y(kd)/π + Y(ks)·(m+2)/(2π)·cos⁺(r, ω)^m) is the Phong BRDF·cos
 * of add_samples in luminance (no V: the target is map × BRDF × cos), divided by its largest
 * value Y(kd)/π + Y(ks)·(m+2)/(2π) so that it lies in [0, 1] and a weight never exceeds the
 * pyramid's sum (no overflow beside a 1e30 texel).  Over a child, the two cosines are bounded
 * over a cone that holds its directions (cone_cos_bound), each separately. */
#define PIXEL_LIGHT_STATE 1   /* the table below (lanes.cl, envmap.cl) */
#include "lanes.cl"
#include "descent.cl"

#ifndef CHILD_WEIGHT
#define CHILD_WEIGHT 0
#endif
#ifndef PRODUCT_LEVELS
#define PRODUCT_LEVELS 1
#endif

/* The pixel's product choices in descent.cl's record layout: records 0 and 1 the faces', record
 * 2·4^k + Q the choice among the children of node Q of depth k (k = 0 … T − 2), 2·4^{T−1}
 * records of four words; and each node's probability under them, in heap order (depth k's
 * 6·4^k from 2·(4^k − 1), so node Q of depth k, record r = 2·4^k + Q, at r − 2), those of the
 * last depth (T − 1) divided by the frame's own (light_state_of): 56 bytes at the default
 * T = 1, 1 KiB at T = 3. */
typedef struct {
    uint bounds[4 * (2 << (2 * (PRODUCT_LEVELS - 1)))];
    float probability[2 * ((1 << (2 * PRODUCT_LEVELS)) - 1)];
} light_state_t;

#define CENTRE_FLOOR (1.0f / 16.0f)   /* measured: 1/64 and 1/4 gave more error (the estimator's docstring) */
#define BOUND_MARGIN 0x1p-12f      /* above the bound's float rounding (~1e-6): no child cut by it */
#define FACE_COS 0.577350269f      /* a face's cone about its axis: its corners are 1/√3 off it */
#define FACE_SIN 0.816496581f

/* The pixel's weigher: its normal n, mirror direction r and normalised factor
 * F = cos_n·(diffuse + specular·cos_r^m) (diffuse + specular = 1). */
typedef struct {
    vec3_t n, r;
    float diffuse, specular, m, lobe_integral;   /* lobe_integral: ∫ cos⁺_r^m dω = 2π/(m + 1) */
} descent_weigher_t;

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
 * with n and r, its half angle θ with cos_lo ≤ cos θ ≤ cos_hi and sin θ ≤ sin_hi, and the
 * reciprocal of a lower bound of its solid angle. */
typedef struct {
    lanes_t cos_n, cos_r, cos_lo, cos_hi, sin_hi, inverse_omega;
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
 * so that weigh_children runs the four children's bounds side by side). */
ALWAYS_INLINE lanes_t cone_factor(const descent_weigher_t *g, const cone_t *c, lanes_t bound_lobe)
{
    lanes_t bound_n = cone_cos_bound(c->cos_n, c->cos_lo, c->cos_hi, c->sin_hi);
#if CHILD_WEIGHT == 1
    return max(factor_of(g, max(c->cos_n, 0.0f), max(c->cos_r, 0.0f)),
               CENTRE_FLOOR * factor_with_lobe(g, bound_n, bound_lobe));
#elif CHILD_WEIGHT == 2
    /* the lobe's mean over the child is at most its integral over the child's least solid angle */
    return factor_with_lobe(g, bound_n, min(bound_lobe, g->lobe_integral * c->inverse_omega));
#else
    return factor_with_lobe(g, bound_n, bound_lobe);
#endif
}

/* The faces' factors in lanes 0 … 5 (lane f: face f about ±e_{f/2}; the lanes past 5 repeat face
 * 5): each face's cone is exact, half angle acos(1/√3) about its axis, solid angle 2π/3. */
ALWAYS_INLINE lanes_t face_factors(const descent_weigher_t *g)
{
    lane_ints_t f = min(LANE_NUMBERS, (lane_ints_t)5);   /* vector bounds: light_pool.cl's POOL_LANES */
    lanes_t sign = select((lanes_t)1.0f, (lanes_t)-1.0f, (f & 1) != 0);
    lane_ints_t x_axis = f < 2, y_axis = (f == 2) | (f == 3);
    lanes_t cos_n = sign * select(select((lanes_t)g->n.z, (lanes_t)g->n.y, y_axis), (lanes_t)g->n.x, x_axis);
    lanes_t cos_r = sign * select(select((lanes_t)g->r.z, (lanes_t)g->r.y, y_axis), (lanes_t)g->r.x, x_axis);
    cone_t face = {cos_n, cos_r, (lanes_t)FACE_COS, (lanes_t)FACE_COS, (lanes_t)FACE_SIN,
                   (lanes_t)(3.0f / (2.0f * IBL_PI))};
    return cone_factor(g, &face, lobe_bound(cone_r_bound(&face), g->m));
}

/* Child c's cone of the lanes' parents from node cones (product.py's node_cone_table: the
 * depth's block from its first parent, planes of `stride` floats: component p of child c at
 * (4p + c)·stride): its centre direction, cos θ's bounds, sin θ's and 1/Ω_least. */
ALWAYS_INLINE cone_t child_cone(const descent_weigher_t *g, __global const float *cones, int stride, int c)
{
    __global const float *at = cones + c * stride;
    lanes_t x = vload_lanes(0, at), y = vload_lanes(0, at + 4 * stride), z = vload_lanes(0, at + 8 * stride);
    cone_t cone = {g->n.x * x + g->n.y * y + g->n.z * z, g->r.x * x + g->r.y * y + g->r.z * z,
                   vload_lanes(0, at + 12 * stride), vload_lanes(0, at + 16 * stride),
                   vload_lanes(0, at + 20 * stride), vload_lanes(0, at + 24 * stride)};
    return cone;
}

/* Multiplies the sums w of the four children of the lanes' parents by their factors, stage by
 * stage (their cones, the lobes' bounds, the factors): four independent chains side by side
 * for the core to overlap. */
ALWAYS_INLINE void weigh_children(const descent_weigher_t *g, __global const float *cones, int stride, lanes_t w[4])
{
    cone_t cone[4];
    lanes_t lobe[4];
    UNROLL
    for (int k = 0; k < 4; ++k) cone[k] = child_cone(g, cones, stride, k);
    UNROLL
    for (int k = 0; k < 4; ++k) lobe[k] = lobe_bound(cone_r_bound(&cone[k]), g->m);
    UNROLL
    for (int k = 0; k < 4; ++k) w[k] *= cone_factor(g, &cone[k], lobe[k]);
}

#define LIGHT_PARAMS __global const float *pyramid, __global const float *cones, __global const uint *descent_bounds, \
                     __global const float *node_probability, __global const float *texel_probability
#define LIGHT_ARGS pyramid, cones, descent_bounds, node_probability, texel_probability

/* The floats of a depth's block of node cones for `parents` parents: seven components of four
 * children, each a plane padded to whole vectors of 16 lanes (product.py's node_cone_table). */
ALWAYS_INLINE int cone_plane(int parents) { return (parents + 15) & ~15; }

/* The pixel of shading s's product choices (light_state_t, into *t): each choice's widths are
 * descent_choice.cl's of the pyramid's sums times the pixel's factors, the faces' in one vector,
 * then depth by depth the children of POOL_LANES parents at a time, each child's probability its
 * parent's times q/2^31; then the last depth's probabilities over the frame's (node_probability,
 * in the same heap order; the texels' P where the choices reach them, `below` 0), so that a
 * texel's P is that ratio times the frame's P(texel) (0 where the frame's node probability
 * underflowed). */
ALWAYS_INLINE void light_state_of(LIGHT_PARAMS, const shading_t *s, int res, light_state_t *t)
{
    descent_weigher_t g = product_weigher(s);
    int level, levels = descent_levels(res, &level), choices = min(PRODUCT_LEVELS, levels);
    lanes_t factors = face_factors(&g);
    const float *factor = (const float *)&factors;   /* lane i of a vector v at ((T *)&v)[i] */
    lanes_t w[6];
    lane_ints_t exists[6];
    lane_uints_t q[6];
    UNROLL
    for (int f = 0; f < 6; ++f) {
        w[f] = pyramid[level + f] * factor[f];
        exists[f] = -1;
    }
    descent_widths6(w, exists, q);
    face_record_words(q, t->bounds);
    UNROLL
    for (int f = 0; f < 6; ++f) t->probability[f] = (float)q[f].s0 * (1.0f / DESCENT_ONE);
    __global const float *block = cones;
    for (int k = 0; k + 1 < choices; ++k) {
        int n = level_size(res, levels - 2 - k), parents = 6 << (2 * k), stride = cone_plane(parents);
        int here = 2 * ((1 << (2 * k)) - 1), next = 2 * ((1 << (2 * k + 2)) - 1);
        level -= 6 * n * n;
        for (int first = 0; first < parents; first += POOL_LANES) {
            lane_ints_t node = min(first + LANE_NUMBERS, (lane_ints_t)(parents - 1)), morton = node & ((1 << (2 * k)) - 1);
            lane_ints_t face = node >> (2 * k), row = morton_half(morton >> 1), col = morton_half(morton);
            lanes_t sums[4];
            lane_ints_t present[4];
            lane_uints_t widths[4];
            child_sums(pyramid, level, n, face, row, col, sums, present);
            weigh_children(&g, block + first, stride, sums);
            descent_widths4(sums, present, widths);
            lanes_t parent = GATHER(lanes_t, t->probability, here + node), p[4];
            UNROLL
            for (int c = 0; c < 4; ++c) p[c] = parent * (convert_lanes(widths[c]) * (1.0f / DESCENT_ONE));
            lane_uints_t words[3] = {widths[0], widths[0] + widths[1], widths[0] + widths[1] + widths[2]};
            const uint *word = (const uint *)words;
            const float *child = (const float *)p;
            for (int i = 0; i < POOL_LANES && first + i < parents; ++i) {
                uint *record = t->bounds + 4 * ((2 << (2 * k)) + first + i);
                for (int c = 0; c < 3; ++c) record[c] = word[c * POOL_LANES + i];
                record[3] = 1u << DESCENT_BITS;
                for (int c = 0; c < 4; ++c) t->probability[next + 4 * (first + i) + c] = child[c * POOL_LANES + i];
            }
        }
        block += 28 * stride;
    }
    if (choices < levels) {
        int last = 2 * ((1 << (2 * (choices - 1))) - 1);
        for (int node = last; node < last + (6 << (2 * (choices - 1))); ++node) {
            float frame = node_probability[node];
            t->probability[node] = frame > 0.0f ? t->probability[node] / frame : 0.0f;
        }
    }
}

/* The probability P of the lanes' texels `texel`, reached through the table's nodes of record
 * `node` (depth T − 1): the table's ratio there (light_state_of) times the frame's P(texel), or
 * the table's probability where its choices reach the texels (`below` 0). */
ALWAYS_INLINE lanes_t texel_chance(const light_state_t *t, __global const float *texel_probability, int below,
                                   lane_ints_t node, lane_ints_t texel)
{
    lanes_t p = GATHER(lanes_t, t->probability, node - 2);
    return below ? p * GATHER(lanes_t, texel_probability, texel) : p;
}

/* envmap.cl's light sampler: the faces' and T − 1 levels' choices from the pixel's table t
 * (words 0 … T − 1 of the draw's stream), the finer ones from the frame's tables
 * (descend_by_tables), the point from the next word; P texel_chance's. */
ALWAYS_INLINE lanes3_t lanes_sample_light(LIGHT_PARAMS, const light_state_t *t, int res, uint seed, uint frame,
                                          uint pixel, lane_ints_t draw, lane_ints_t *texel, lanes_t *pdf)
{
    int top, word = 0;
    int levels = descent_levels(res, &top), choices = min(PRODUCT_LEVELS, levels);
    lane_block_t block;
    lane_uints_t u = descent_word(seed, frame, pixel, draw, word++, &block) >> (32 - DESCENT_BITS);
    lane_ints_t face = 0;
    UNROLL
    for (int f = 0; f < 5; ++f) face -= convert_lane_ints((lane_uints_t)t->bounds[f] <= u);
    lane_ints_t record = 2 + face, row = 0, col = 0;
    for (int k = 1; k < choices; ++k) {
        lane_ints_t at = 4 * record;
        lane_uints_t b[3] = {GATHER(lane_uints_t, t->bounds, at), GATHER(lane_uints_t, t->bounds, at + 1),
                             GATHER(lane_uints_t, t->bounds, at + 2)};
        u = descent_word(seed, frame, pixel, draw, word++, &block) >> (32 - DESCENT_BITS);
        descend_to(record_pick(b, u), &record, &row, &col);
    }
    lane_ints_t node = record;
    descend_by_tables(descent_bounds, levels - 1 - choices, seed, frame, pixel, draw, &word, &block, &record, &row, &col);
    *texel = (face * res + row) * res + col;
    return descent_point(res, face, row, col, descent_word(seed, frame, pixel, draw, word, &block),
                         texel_chance(t, texel_probability, choices < levels, node, *texel), pdf);
}

/* envmap.cl's light density: texel_chance's P of the texels of the lanes' directions w, their
 * nodes of depth T − 1 found from the texels' rows and columns, with descent_point's Jacobian;
 * *texel gets the texel. */
ALWAYS_INLINE lanes_t lanes_light_density(LIGHT_PARAMS, const light_state_t *t, int res, lanes3_t w, lane_ints_t *texel)
{
    lane_ints_t face, row, col;
    lanes_t area = lanes_texel_of(res, w, &face, &row, &col);
    int top, levels = descent_levels(res, &top), choices = min(PRODUCT_LEVELS, levels);
    lane_ints_t record = 2 + face;
    for (int k = 1; k < choices; ++k) {
        int l = levels - 1 - k;
        record = 4 * record + 2 * ((row >> l) & 1) + ((col >> l) & 1);
    }
    *texel = (face * res + row) * res + col;
    return texel_chance(t, texel_probability, choices < levels, record, *texel) * area * (float)(res * res) / 4.0f;
}

#include "envmap.cl"
