/* The frame cache's mip products (harness/mips.py): one 2×2 reduction over the six faces of a
 * cube map, run level by level.  A level of face size n holds [6, n, n] texels of CHANNELS
 * floats (face-major, rows downward, as the map: ARCHITECTURE.md §Conventions) at a float offset of one buffer that
 * holds every level.  Its parent level has size ⌈n/2⌉: parent (row, col) covers the children
 * (2·row + a, 2·col + b), a, b ∈ {0, 1}, that exist (an odd n leaves the last parents two or one
 * children).  Defines:
 *   CHANNELS  floats per texel: 1 (the sampling weights, float) or 4 (the radiance, float4; w is
 *             averaged as the rest, and the map's w is 0)
 *   AVERAGE   0: a parent is the sum of its children; 1: their mean (the box filter) */
#ifndef CHANNELS
#define CHANNELS 1
#endif
#ifndef AVERAGE
#define AVERAGE 0
#endif

#if CHANNELS == 1
typedef float texel_t;
#define load_texel(i, p) ((p)[i])
#define store_texel(v, i, p) ((p)[i] = (v))
#elif CHANNELS == 4
typedef float4 texel_t;
#define load_texel vload4
#define store_texel vstore4
#else
#error "CHANNELS must be 1 or 4"
#endif

/* One work item per texel of the parent level (6·parent_res² of them): the sum or mean of its
 * children, summed in the order (0, 0), (0, 1), (1, 0), (1, 1).  A missing child (past an odd
 * size's edge) counts 0.  No loop and no private array: a loop over children and channels
 * with an array of sums did not vectorise across work items and took 1.1–1.6× (weights) and
 * 1.2–1.35× (radiance) this kernel's time at 1024² faces, medians of 11 alternated launches on
 * a loaded CPU; one work item per float instead took 2.4× for the float4 radiance. */
__kernel void reduce_2x2(__global float *levels, const int child_offset, const int child_res,
                         const int parent_offset, const int parent_res)
{
    int item = get_global_id(0), face_texels = parent_res * parent_res;
    int face = item / face_texels, row = item % face_texels / parent_res, col = item % parent_res;
    int row0 = 2 * row, col0 = 2 * col;
    int second_row = row0 + 1 < child_res, second_col = col0 + 1 < child_res;
    int row1 = row0 + second_row, col1 = col0 + second_col;
    __global const float *children = levels + child_offset + (size_t)face * child_res * child_res * CHANNELS;
    texel_t zero = 0.0f;
    texel_t sum = load_texel(row0 * child_res + col0, children)
                + (second_col ? load_texel(row0 * child_res + col1, children) : zero)
                + (second_row ? load_texel(row1 * child_res + col0, children) : zero)
                + (second_row && second_col ? load_texel(row1 * child_res + col1, children) : zero);
    store_texel(AVERAGE ? sum / (float)((1 + second_row) * (1 + second_col)) : sum, item,
                levels + parent_offset);
}
