/* The descent through each face's pyramid of sampling-weight sums (FrameCache.weight_pyramid,
 * estimators/runtime/mips.py's layout: level 0 the texels' weights, level l of face size
 * ⌈R/2^l⌉ from float offset 6·Σ_{k<l} n_k², the 1×1 level each face's total) that
 * `hierarchical` (Falcor's EnvMapSampler, Mitsuba 3's Hierarchical2D) and `product` sample by.
 *
 * A sample picks a face by the faces' weights, then at each level one of the (up to) four
 * children of the texel picked so far by their weights, down to a texel, and a point uniform in
 * the texel's face square.  A weight is the pyramid's sum (times, for `product`'s coarse
 * choices, the pixel's BRDF·cos factor).  Each choice
 * among n children (6 faces, or 4 children) is exact in fixed point (descent_widths##N): child k
 * gets an integer width q_k out of 2^31,
 *     q_k = max(1, ⌊2^31 · w_k / Σ w⌋) for w_k > 0,  q_k = 0 for w_k = 0,
 * the remainder 2^31 − Σ q going to the largest child (the first of equal ones), and the top 31
 * bits u of a fresh 32-bit Philox word pick the child whose bin [Σ_{j<k} q_j, Σ_{j≤k} q_j) holds
 * u: the child's probability is exactly q_k/2^31 (the density reports it in float: to float
 * rounding, ~1e-6 relative over a descent's factors).  So every child of positive weight has a
 * probability of at least 2^-31 ≈ 4.7e-10 at each level, whatever its siblings weigh (a 1e6:1
 * sun leaves every lit texel reachable), and a texel's probability P is the product of its
 * choices' q/2^31 in the order they are made, which the density looks up (descent_density).
 * The density in solid angle is P·(1+x²+y²)^{3/2}/a_texel,
 * a_texel = (2/R)² (ARCHITECTURE.md §Conventions).  Children of zero total (an all-black map, or past an odd size's
 * edge) fall back to widths 2^31/N for each child that exists, the remainder to the first of
 * them (so 1/2, 1/4, 1/4 for three of four: not equal, but the density has the same widths), so a black map still samples a valid texel with the density it is drawn from.
 *
 * The choices come from tables (made with descent_choice.cl's arithmetic, so bit for bit a
 * descent's from the same sums): the frame cache's (FrameCache.descent_tables, framecache.cl's
 * descent_bounds), whose weights are the sums alone, the same for every pixel, so each choice's
 * widths are computed once per frame; a sample reads three bounds a level (three gathers, no
 * division: 1.6× the speed of the widths computed per sample, issue 37), and its density is its
 * texel's P, read.  `product` makes its coarse choices' table once a pixel in the same layout
 * (product.cl's light_state_t) and continues below them with descend_by_tables.
 *
 * The tables (uint words; record r is the four words from 4r):
 *   - records 0 and 1: the faces' widths as prefix sums Σ_{j≤f} q_j, f = 0 … 4, then 2^31 in
 *     words 5 … 7;
 *   - record 2·4^k + Q, k = 0 … L − 2 (L the pyramid's levels), Q = f·4^k + Z(row, col): the
 *     choice among the children of the node (row, col) of face f at level L − 1 − k (the faces'
 *     nodes at k = 0, the texels' parents at k = L − 2), Z the Morton index (bits of row and col
 *     interleaved, row's higher: child k = 2a + b is Z's last two bits); its words are the
 *     children's prefix sums q_0, q_0 + q_1, q_0 + q_1 + q_2 and 2^31.  So the record of child c
 *     of record r is 4r + c: a descent's index chain is one shift and add a level, and the
 *     records of a face size that is not a power of two are those of the next power of two, the
 *     nodes past the edge never reached (their widths are 0);
 *   - the texels' probabilities P, float [6·R²], each the product of its descent's q/2^31 in
 *     float, formed in the order the descent makes them (the faces' first): bit for bit the
 *     product a descent forms;
 *   - the nodes' probabilities above the texels, likewise, in heap order: depth k's 6·4^k from
 *     2·(4^k − 1), so the node of record r (k ≥ 0) at r − 2. */
#ifndef IBLBENCH_DESCENT_CL
#define IBLBENCH_DESCENT_CL
#include "lanes.cl"
#include "descent_choice.cl"

#define STREAM_DESCENT 9u

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

/* The direction of the point in texel (row, col) of each lane's face from the word `point`, 16 bits
 * per coordinate: the centre of a cell of a 2^16 × 2^16 grid over the texel, not a continuous
 * point (the radiance is constant over the texel and the density is evaluated at the point
 * drawn; one Philox block fewer in three at the default face size of 64, though the render
 * time did not change measurably); *pdf gets its density in solid angle for a texel drawn with
 * probability P, P·(1+x²+y²)^{3/2}/a_texel, a_texel = (2/R)² (ARCHITECTURE.md §Conventions). */
ALWAYS_INLINE lanes3_t descent_point(int res, lane_ints_t face, lane_ints_t row, lane_ints_t col, lane_uints_t point,
                                     lanes_t probability, lanes_t *pdf)
{
    lanes_t x = -1.0f + 2.0f * (convert_lanes(col) + (convert_lanes(point & 0xffffu) + 0.5f) * 0x1p-16f) / (float)res;
    lanes_t y = -1.0f + 2.0f * (convert_lanes(row) + (convert_lanes(point >> 16) + 0.5f) * 0x1p-16f) / (float)res;
    lanes_t area = 1.0f + x * x + y * y;   /* area_per_solid_angle */
    *pdf = probability * area * sqrt(area) * (float)(res * res) / 4.0f;
    return lanes_face_direction(face, x, y);
}

/* The lanes' records, rows and columns one level down, at their children `child`. */
ALWAYS_INLINE void descend_to(lane_ints_t child, lane_ints_t *record, lane_ints_t *row, lane_ints_t *col)
{
    *record = 4 * *record + child;
    *row = 2 * *row + (child >> 1);
    *col = 2 * *col + (child & 1);
}

/* The lanes' descents by the tables (header) from their nodes' records *record, at (*row, *col) of
 * pyramid level l + 1, down to the texels: one choice a level l … 0, each by the draw's next
 * word (*word). */
ALWAYS_INLINE void descend_by_tables(__global const uint *bounds, int l, uint seed, uint frame, uint pixel,
                                     lane_ints_t draw, int *word, lane_block_t *block, lane_ints_t *record,
                                     lane_ints_t *row, lane_ints_t *col)
{
    for (; l >= 0; --l) {
        lane_uints_t u = descent_word(seed, frame, pixel, draw, (*word)++, block) >> (32 - DESCENT_BITS);
        lane_ints_t at = 4 * *record;
        lane_uints_t b[3] = {GATHER(lane_uints_t, bounds, at), GATHER(lane_uints_t, bounds, at + 1),
                             GATHER(lane_uints_t, bounds, at + 2)};
        descend_to(record_pick(b, u), record, row, col);
    }
}

/* A descent by the tables (header) with words 0 (the face) and 1 … L − 1 (the levels from the
 * coarsest) of the draw's stream, and the point in the texel from word L (descent_point).
 * *texel gets each lane's texel and *pdf its density in solid angle. */
ALWAYS_INLINE lanes3_t descent_sample(__global const uint *bounds, __global const float *texel_probability,
                                      int res, uint seed, uint frame, uint pixel, lane_ints_t draw,
                                      lane_ints_t *texel, lanes_t *pdf)
{
    int top, word = 0;
    int levels = descent_levels(res, &top);
    lane_block_t block;
    lane_uints_t u = descent_word(seed, frame, pixel, draw, word++, &block) >> (32 - DESCENT_BITS);
    lane_ints_t face = 0;
    UNROLL
    for (int f = 0; f < 5; ++f) face -= convert_lane_ints((lane_uints_t)bounds[f] <= u);
    lane_ints_t record = 2 + face, row = 0, col = 0;
    descend_by_tables(bounds, levels - 2, seed, frame, pixel, draw, &word, &block, &record, &row, &col);
    *texel = (face * res + row) * res + col;
    return descent_point(res, face, row, col, descent_word(seed, frame, pixel, draw, word, &block),
                         GATHER(lanes_t, texel_probability, *texel), pdf);
}

/* The density of descent_sample at the lanes' directions w: their texels' P (header) with
 * descent_point's Jacobian; *texel gets the texel. */
ALWAYS_INLINE lanes_t descent_density(__global const float *texel_probability, int res, lanes3_t w,
                                      lane_ints_t *texel)
{
    lane_ints_t face, row, col;
    lanes_t area = lanes_texel_of(res, w, &face, &row, &col);
    *texel = (face * res + row) * res + col;
    return GATHER(lanes_t, texel_probability, *texel) * area * (float)(res * res) / 4.0f;
}

#endif
