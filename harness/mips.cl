/* The frame cache's mip products (harness/mips.py): one 2×2 reduction over the six faces of a
 * cube map, run level by level.  A level of face size n holds [6, n, n] texels of CHANNELS
 * floats (face-major, rows downward, as the map: DESIGN §3) at a float offset of one buffer that
 * holds every level.  Its parent level has size ⌈n/2⌉: parent (row, col) covers the children
 * (2·row + a, 2·col + b), a, b ∈ {0, 1}, that exist (an odd n leaves the last parents two or one
 * children).  Defines:
 *   CHANNELS  floats per texel (1: the sampling weights; 4: the float4 radiance, w unused)
 *   AVERAGE   0: a parent is the sum of its children; 1: their mean (the box filter) */
#ifndef CHANNELS
#define CHANNELS 1
#endif
#ifndef AVERAGE
#define AVERAGE 0
#endif

/* One work item per texel of the parent level (6·parent_res² of them): the children's sum or
 * mean, summed in the order (0, 0), (0, 1), (1, 0), (1, 1), channel by channel.  A missing child
 * is read at a clamped index and counts 0, so the loop has no branch. */
__kernel void reduce_2x2(__global float *levels, const int child_offset, const int child_res,
                         const int parent_offset, const int parent_res)
{
    int item = get_global_id(0), face_texels = parent_res * parent_res;
    int face = item / face_texels, row = item % face_texels / parent_res, col = item % parent_res;
    __global const float *children = levels + child_offset + (size_t)face * child_res * child_res * CHANNELS;
    float sum[CHANNELS];
    for (int c = 0; c < CHANNELS; ++c) sum[c] = 0.0f;
    float count = 0.0f;
    for (int a = 0; a < 2; ++a) {
        for (int b = 0; b < 2; ++b) {
            int child_row = 2 * row + a, child_col = 2 * col + b;
            int exists = child_row < child_res && child_col < child_res;
            int at = (min(child_row, child_res - 1) * child_res + min(child_col, child_res - 1)) * CHANNELS;
            for (int c = 0; c < CHANNELS; ++c) sum[c] += exists ? children[at + c] : 0.0f;
            count += exists ? 1.0f : 0.0f;
        }
    }
    __global float *parent = levels + parent_offset + (size_t)item * CHANNELS;
    for (int c = 0; c < CHANNELS; ++c) parent[c] = AVERAGE ? sum[c] / count : sum[c];
}
