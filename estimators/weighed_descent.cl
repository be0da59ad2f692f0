/* The descent of descent.cl with weights computed per sample: each choice's children weigh
 * their pyramid sums times a factor of the including file's weigher (below), the pixel's
 * BRDF·cos factor for `product`; the choices are descent_choice.cl's, the density the product
 * of the choices' q/2^31, recomputed by weighed_descent_density from the same pyramid words
 * and factors in the same order.
 *
 * The including file defines its weigher: the type descent_weigher_t before it includes this
 * one, and the three functions declared below (anywhere in the program).  A factor must be
 * finite and ≥ 0, and positive wherever the sample's integrand may be. */
#ifndef IBLBENCH_WEIGHED_DESCENT_CL
#define IBLBENCH_WEIGHED_DESCENT_CL
#include "descent.cl"

/* The lanes' faces are chosen (a weigher may set up per face). */
ALWAYS_INLINE void weigher_at_face(descent_weigher_t *g, lane_ints_t face);
/* Multiplies the faces' totals w (pyramid level l) by the weigher's factors. */
ALWAYS_INLINE void weigh_faces(const descent_weigher_t *g, int l, lanes_t w[6]);
/* Multiplies the sums w of the four children at level l of the lanes' parents (row, col), of the
 * faces given to weigher_at_face, by the weigher's factors (child k = 2a + b at (2·row + a,
 * 2·col + b)). */
ALWAYS_INLINE void weigh_children(const descent_weigher_t *g, int res, int l, lane_ints_t row, lane_ints_t col,
                                  lanes_t w[4]);

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
 * face `face` at pyramid level l, of size n from float offset `level`, by their sums
 * (child_sums) times the weigher's factors. */
ALWAYS_INLINE void child_widths(__global const float *pyramid, const descent_weigher_t *g, int res, int l,
                                int level, int n, lane_ints_t face, lane_ints_t row, lane_ints_t col,
                                lane_uints_t q[4])
{
    lanes_t w[4];
    lane_ints_t exists[4];
    child_sums(pyramid, level, n, face, row, col, w, exists);
    weigh_children(g, res, l, row, col, w);
    descent_widths4(w, exists, q);
}

/* The descent of the header with words 0 (the face) and 1 … L − 1 (the levels from the
 * coarsest) of the draw's stream, and the point in the texel from word L, 16 bits per
 * coordinate: the centre of a cell of a 2^16 × 2^16 grid over the texel, not a continuous point
 * (the radiance is constant over the texel and the density is evaluated at the point drawn; one
 * Philox block fewer in three at the default face size of 64, though the render time did not
 * change measurably).  *texel gets each lane's texel and *pdf its density in solid angle. */
ALWAYS_INLINE lanes3_t weighed_descent_sample(__global const float *pyramid, descent_weigher_t *g, int res, uint seed,
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
    *texel = (face * res + row) * res + col;
    return descent_point(res, face, row, col, descent_word(seed, frame, pixel, draw, word, &block), probability, pdf);
}

/* The density of weighed_descent_sample at the lanes' directions w: the product of the choices that
 * lead to the texel of each, recomputed as weighed_descent_sample makes them; *texel gets the texel. */
ALWAYS_INLINE lanes_t weighed_descent_density(__global const float *pyramid, descent_weigher_t *g, int res, lanes3_t w,
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
