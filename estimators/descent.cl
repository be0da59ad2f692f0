/* The descent through each face's pyramid of sampling-weight sums (FrameCache.weight_pyramid,
 * estimators/runtime/mips.py's layout: level 0 the texels' weights, level l of face size
 * ⌈R/2^l⌉ from float offset 6·Σ_{k<l} n_k², the 1×1 level each face's total) that
 * `hierarchical` (Falcor's EnvMapSampler, Mitsuba 3's Hierarchical2D) and `product` sample by.
 *
 * A sample picks a face by the faces' weights, then at each level one of the (up to) four
 * children of the texel picked so far by their weights, down to a texel, and a point uniform in
 * the texel's face square.  A weight is the pyramid's sum times a factor of the including file's
 * weigher (below): 1 for `hierarchical`, the pixel's BRDF·cos factor for `product`.  Each choice
 * among n children (6 faces, or 4 children) is exact in fixed point (descent_widths##N): child k
 * gets an integer width q_k out of 2^31,
 *     q_k = max(1, ⌊2^31 · w_k / Σ w⌋) for w_k > 0,  q_k = 0 for w_k = 0,
 * the remainder 2^31 − Σ q going to the largest child (the first of equal ones), and the top 31
 * bits u of a fresh 32-bit Philox word pick the child whose bin [Σ_{j<k} q_j, Σ_{j≤k} q_j) holds
 * u: the child's probability is exactly q_k/2^31 (the density reports it in float: to float
 * rounding, ~1e-6 relative over a descent's factors).  So every child of positive weight has a
 * probability of at least 2^-31 ≈ 4.7e-10 at each level, whatever its siblings weigh (a 1e6:1
 * sun leaves every lit texel reachable), and a texel's probability P is the product of its
 * choices' q/2^31, which the density (descent_density) recomputes from the same pyramid words
 * and factors in the same order.  The density in solid angle is P·(1+x²+y²)^{3/2}/a_texel,
 * a_texel = (2/R)² (ARCHITECTURE.md §Conventions).  Children of zero total (an all-black map, or past an odd size's
 * edge) fall back to widths 2^31/N for each child that exists, the remainder to the first of
 * them (so 1/2, 1/4, 1/4 for three of four: not equal, but the lookup recomputes the same
 * widths), so a black map still samples a valid texel with the density it is drawn from.
 *
 * The including file defines its weigher: the type descent_weigher_t before it includes this
 * one, and the three functions declared below (anywhere in the program).  A factor must be
 * finite and ≥ 0, and positive wherever the sample's integrand may be. */
#ifndef IBLBENCH_DESCENT_CL
#define IBLBENCH_DESCENT_CL
#include "lanes.cl"

/* The lanes' faces are chosen (a weigher may set up per face). */
ALWAYS_INLINE void weigher_at_face(descent_weigher_t *g, lane_ints_t face);
/* Multiplies the faces' totals w (pyramid level l) by the weigher's factors. */
ALWAYS_INLINE void weigh_faces(const descent_weigher_t *g, int l, lanes_t w[6]);
/* Multiplies the sums w of the four children at level l of the lanes' parents (row, col), of the
 * faces given to weigher_at_face, by the weigher's factors (child k = 2a + b at (2·row + a,
 * 2·col + b)). */
ALWAYS_INLINE void weigh_children(const descent_weigher_t *g, int res, int l, lane_ints_t row, lane_ints_t col,
                                  lanes_t w[4]);

#define STREAM_DESCENT 9u
#define DESCENT_BITS 31
#define DESCENT_ONE 0x1p31f   /* a choice's widths total 2^31: uint lanes, where 2^32 would need ulong */

/* A choice among N children (N = 6 faces or 4 children: one copy per N, so that the loops over
 * the children unroll and their arrays stay in registers):
 *   descent_widths##N: the integer widths q of children of weights w (≥ 0) as in the header;
 *     `exists` marks the children that exist (the fallback's support when Σ w is 0 or its
 *     inverse overflows: 2^31/N each, the remainder to the first); the widths' prefix sums never
 *     pass 2^31;
 *   descent_probability##N: q_child/2^31 of the lanes' children `child`;
 *   descent_pick##N: the child whose bin of widths q holds the top 31 bits of the words u, and
 *     its probability. */
#define DEFINE_DESCENT_CHOICE(N) \
ALWAYS_INLINE void descent_widths##N(const lanes_t w[N], const lane_ints_t exists[N], lane_uints_t q[N])        \
{                                                                                                               \
    lanes_t total = 0.0f;                                                                                       \
    UNROLL                                                                                                      \
    for (int k = 0; k < N; ++k) total += w[k];                                                                  \
    lanes_t scale = DESCENT_ONE / total;                                                                        \
    lane_ints_t fallback = !(total > 0.0f) | isinf(scale);                                                      \
    lanes_t largest_weight = -1.0f;                                                                             \
    lane_ints_t largest = 0;                                                                                    \
    lane_uints_t others = 0;                                                                                    \
    UNROLL                                                                                                      \
    for (int k = 0; k < N; ++k) {                                                                               \
        lanes_t weight = select(w[k], select((lanes_t)0.0f, (lanes_t)1.0f, exists[k]), fallback);               \
        lanes_t share = weight * select(scale, (lanes_t)(DESCENT_ONE / N), fallback);                           \
        q[k] = select((lane_uints_t)0, max((lane_uints_t)1, convert_lane_uints(min(share, DESCENT_ONE))),       \
                      weight > 0.0f);                                                                           \
        lane_ints_t larger = weight > largest_weight;                                                           \
        largest_weight = select(largest_weight, weight, larger);                                                \
        largest = select(largest, (lane_ints_t)k, larger);                                                      \
    }                                                                                                           \
    UNROLL                                                                                                      \
    for (int k = 0; k < N; ++k) others += select(q[k], (lane_uints_t)0, largest == k);                          \
    UNROLL                                                                                                      \
    for (int k = 0; k < N; ++k) q[k] = select(q[k], (lane_uints_t)(1u << DESCENT_BITS) - others, largest == k); \
}                                                                                                               \
                                                                                                                \
ALWAYS_INLINE lanes_t descent_probability##N(const lane_uints_t q[N], lane_ints_t child)                        \
{                                                                                                               \
    lane_uints_t width = 0;                                                                                     \
    UNROLL                                                                                                      \
    for (int k = 0; k < N; ++k) width = select(width, q[k], child == k);                                        \
    return convert_lanes(width) * (1.0f / DESCENT_ONE);                                                         \
}                                                                                                               \
                                                                                                                \
ALWAYS_INLINE lane_ints_t descent_pick##N(const lane_uints_t q[N], lane_uints_t u, lanes_t *probability)        \
{                                                                                                               \
    lane_uints_t bound = 0, word = u >> (32 - DESCENT_BITS);                                                    \
    lane_ints_t child = 0;                                                                                      \
    UNROLL                                                                                                      \
    for (int k = 0; k < N - 1; ++k) {                                                                           \
        bound += q[k];                                                                                          \
        child += convert_lane_ints(bound <= word) & 1;                                                          \
    }                                                                                                           \
    *probability = descent_probability##N(q, child);                                                            \
    return child;                                                                                               \
}

DEFINE_DESCENT_CHOICE(4)
DEFINE_DESCENT_CHOICE(6)

/* The widths of the faces by their totals (the pyramid's 1×1 level at `top`, the top of
 * `levels`) times the weigher's factors. */
ALWAYS_INLINE void face_widths(__global const float *pyramid, const descent_weigher_t *g, int top, int levels,
                               lane_uints_t q[6])
{
    lanes_t w[6];
    lane_ints_t exists[6];
    UNROLL
    for (int f = 0; f < 6; ++f) {
        w[f] = pyramid[top + f];
        exists[f] = -1;
    }
    weigh_faces(g, levels - 1, w);
    descent_widths6(w, exists, q);
}

/* The widths of the four children (2·row + a, 2·col + b) of each lane's parent (row, col) of
 * face `face` at pyramid level l, of size n from float offset `level` (a row-major quad:
 * k = 2a + b), by their sums times the weigher's factors. */
ALWAYS_INLINE void child_widths(__global const float *pyramid, const descent_weigher_t *g, int res, int l,
                                int level, int n, lane_ints_t face, lane_ints_t row, lane_ints_t col,
                                lane_uints_t q[4])
{
    lanes_t w[4];
    lane_ints_t exists[4];
    UNROLL
    for (int k = 0; k < 4; ++k) {
        lane_ints_t child_row = 2 * row + (k >> 1), child_col = 2 * col + (k & 1);
        exists[k] = (child_row < n) & (child_col < n);
        lane_ints_t last = n - 1;   /* a vector bound for min: see POOL_LANES in light_pool.cl */
        lane_ints_t at = level + (face * n + min(child_row, last)) * n + min(child_col, last);
        w[k] = select((lanes_t)0.0f, GATHER(lanes_t, pyramid, at), exists[k]);
    }
    weigh_children(g, res, l, row, col, w);
    descent_widths4(w, exists, q);
}

/* The pyramid over faces of `res` (estimators/runtime/mips.py): level l has size ⌈res/2^l⌉; returns the
 * number of levels and sets *top to the float offset of the last, 1×1 one.  A descent walks
 * down from there, level l's offset that of level l + 1 less 6·size(l)². */
ALWAYS_INLINE int descent_levels(int res, int *top)
{
    int levels = 1;
    *top = 0;
    for (int n = res; n > 1; n = (n + 1) / 2) {
        ++levels;
        *top += 6 * n * n;
    }
    return levels;
}

ALWAYS_INLINE int level_size(int res, int l) { return (res + (1 << l) - 1) >> l; }

/* Word k (0 …) of a lane's random stream, four to a Philox block: *block holds block k/4 once k
 * is a multiple of 4 (the caller draws words in order).  Indexed, not a chain of selects over
 * the four words: Oclgrind 21.10 ran that chain on the previous block after a refill. */
ALWAYS_INLINE lane_uints_t descent_word(uint seed, uint frame, uint pixel, lane_ints_t draw, int k,
                                        lane_block_t *block)
{
    if ((k & 3) == 0)
        *block = rng_block_lanes(seed, frame, STREAM_DESCENT, pixel, convert_lane_uints(draw), (uint)(k >> 2));
    return block->v[k & 3];
}

/* The descent of the header with words 0 (the face) and 1 … L − 1 (the levels from the
 * coarsest) of the draw's stream, and the point in the texel from word L, 16 bits per
 * coordinate: the centre of a cell of a 2^16 × 2^16 grid over the texel, not a continuous point
 * (the radiance is constant over the texel and the density is evaluated at the point drawn; one
 * Philox block fewer in three at the default face size of 64, though the render time did not
 * change measurably).  *texel gets each lane's texel and *pdf its density in solid angle. */
ALWAYS_INLINE lanes3_t descent_sample(__global const float *pyramid, descent_weigher_t *g, int res, uint seed,
                                      uint frame, uint pixel, lane_ints_t draw, lane_ints_t *texel, lanes_t *pdf)
{
    int offset, word = 0;
    int levels = descent_levels(res, &offset);
    lane_block_t block;
    lane_uints_t faces[6];
    face_widths(pyramid, g, offset, levels, faces);
    lanes_t probability, p;
    lane_ints_t face = descent_pick6(faces, descent_word(seed, frame, pixel, draw, word++, &block), &probability);
    weigher_at_face(g, face);
    lane_ints_t row = 0, col = 0;
    for (int l = levels - 2; l >= 0; --l) {
        int n = level_size(res, l);
        offset -= 6 * n * n;
        lane_uints_t q[4];
        child_widths(pyramid, g, res, l, offset, n, face, row, col, q);
        lane_ints_t child = descent_pick4(q, descent_word(seed, frame, pixel, draw, word++, &block), &p);
        probability *= p;
        row = 2 * row + (child >> 1);
        col = 2 * col + (child & 1);
    }
    lane_uints_t point = descent_word(seed, frame, pixel, draw, word, &block);
    lanes_t x = -1.0f + 2.0f * (convert_lanes(col) + (convert_lanes(point & 0xffffu) + 0.5f) * 0x1p-16f) / (float)res;
    lanes_t y = -1.0f + 2.0f * (convert_lanes(row) + (convert_lanes(point >> 16) + 0.5f) * 0x1p-16f) / (float)res;
    lanes_t area = 1.0f + x * x + y * y;   /* area_per_solid_angle */
    *texel = (face * res + row) * res + col;
    *pdf = probability * area * sqrt(area) * (float)(res * res) / 4.0f;
    return lanes_face_direction(face, x, y);
}

/* The density of descent_sample at the lanes' directions w: the product of the choices that
 * lead to the texel of each, recomputed as descent_sample makes them; *texel gets the texel. */
ALWAYS_INLINE lanes_t descent_density(__global const float *pyramid, descent_weigher_t *g, int res, lanes3_t w,
                                      lane_ints_t *texel)
{
    lane_ints_t face, row, col;
    lanes_t area = lanes_texel_of(res, w, &face, &row, &col);
    int offset;
    int levels = descent_levels(res, &offset);
    lane_uints_t faces[6];
    face_widths(pyramid, g, offset, levels, faces);
    lanes_t probability = descent_probability6(faces, face);
    weigher_at_face(g, face);
    for (int l = levels - 2; l >= 0; --l) {
        int n = level_size(res, l);
        offset -= 6 * n * n;
        lane_uints_t q[4];
        lane_ints_t child_row = row >> l, child_col = col >> l;
        child_widths(pyramid, g, res, l, offset, n, face, child_row >> 1, child_col >> 1, q);
        probability *= descent_probability4(q, 2 * (child_row & 1) + (child_col & 1));
    }
    *texel = (face * res + row) * res + col;
    return probability * area * (float)(res * res) / 4.0f;
}

#endif
