/* The choices of a descent through each face's pyramid of sampling-weight sums (estimators/descent.cl
 * has the method, estimators/runtime/mips.py the pyramid's layout), shared by the tables that
 * descents read: the frame cache's (framecache.cl's descent_bounds) and `product`'s per pixel
 * (product.cl's light_state_of), so that a choice read from a table is the one a descent would
 * make from the same weights, bit for bit.
 *
 * A choice among N children (N = 6 faces or 4 children: one copy per N, so that the loops over
 * the children unroll and their arrays stay in registers):
 *   descent_widths##N: the integer widths q of children of weights w (≥ 0), out of 2^31:
 *     q_k = max(1, ⌊2^31 · w_k / Σ w⌋) for w_k > 0, q_k = 0 for w_k = 0, the remainder
 *     2^31 − Σ q to the largest child (the first of equal ones); `exists` marks the children that
 *     exist (the fallback's support when Σ w is 0 or its inverse overflows: 2^31/N each, the
 *     remainder to the first); the widths' prefix sums never pass 2^31. */
#ifndef IBLBENCH_DESCENT_CHOICE_CL
#define IBLBENCH_DESCENT_CHOICE_CL
#include "light_pool.cl"

#define DESCENT_BITS 31
#define DESCENT_ONE 0x1p31f   /* a choice's widths total 2^31: uint lanes, where 2^32 would need ulong */

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
}

DEFINE_DESCENT_CHOICE(4)
DEFINE_DESCENT_CHOICE(6)

/* The faces' record words (estimators/descent.cl's tables, records 0 and 1) of their widths q
 * (the same in every lane): the prefix sums Σ_{j≤f} q_j, f = 0 … 4, then 2^31 in words 5 … 7. */
ALWAYS_INLINE void face_record_words(const lane_uints_t q[6], uint words[8])
{
    uint sum = 0;
    UNROLL
    for (int f = 0; f < 8; ++f) {
        sum += f < 6 ? q[f].s0 : 0u;
        words[f] = f < 5 ? sum : 1u << DESCENT_BITS;
    }
}

/* A record's child picked by the lanes' top 31 bits u of a word: the child whose bin of the
 * record's prefix widths b[0] ≤ b[1] ≤ b[2] (the fourth 2^31) holds u. */
ALWAYS_INLINE lane_ints_t record_pick(const lane_uints_t b[3], lane_uints_t u)
{
    return -(convert_lane_ints(b[0] <= u) + convert_lane_ints(b[1] <= u) + convert_lane_ints(b[2] <= u));
}

/* The bits of m at even positions, packed: a Morton index's column (m) or row (m >> 1). */
ALWAYS_INLINE lane_ints_t morton_half(lane_ints_t m)
{
    m &= 0x55555555;
    m = (m | (m >> 1)) & 0x33333333;
    m = (m | (m >> 2)) & 0x0f0f0f0f;
    m = (m | (m >> 4)) & 0x00ff00ff;
    return (m | (m >> 8)) & 0x0000ffff;
}

/* The sums w of the four children (2·row + a, 2·col + b) of each lane's parent (row, col) of face
 * `face` at pyramid level l, of size n from float offset `level` (a row-major quad: k = 2a + b),
 * and which of them exist (0 past an odd size's edge). */
ALWAYS_INLINE void child_sums(__global const float *pyramid, int level, int n, lane_ints_t face, lane_ints_t row,
                              lane_ints_t col, lanes_t w[4], lane_ints_t exists[4])
{
    UNROLL
    for (int k = 0; k < 4; ++k) {
        lane_ints_t child_row = 2 * row + (k >> 1), child_col = 2 * col + (k & 1);
        exists[k] = (child_row < n) & (child_col < n);
        lane_ints_t last = n - 1;   /* a vector bound for min: see POOL_LANES in light_pool.cl */
        lane_ints_t at = level + (face * n + min(child_row, last)) * n + min(child_col, last);
        w[k] = select((lanes_t)0.0f, GATHER(lanes_t, pyramid, at), exists[k]);
    }
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

#endif
