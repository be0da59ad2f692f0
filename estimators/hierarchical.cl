/* `hierarchical`: envmap.cl's kernels (budget, MIS with BRDF samples, χ² hooks) with light samples
 * drawn by descent through each face's pyramid of sampling-weight sums (descent.cl), as Falcor's
 * EnvMapSampler and Mitsuba 3's Hierarchical2D descend their importance mips: every choice by
 * the pyramid's sums alone, the same for every pixel, so read from the frame cache's descent
 * tables. */
#include "descent.cl"

#define LIGHT_PARAMS __global const uint *descent_bounds, __global const float *texel_probability
#define LIGHT_ARGS descent_bounds, texel_probability

/* envmap.cl's light sampler: descent.cl's descent, the same for every pixel (no state). */
ALWAYS_INLINE lanes3_t lanes_sample_light(LIGHT_PARAMS, const light_state_t *state, int res, uint seed,
                                          uint frame, uint pixel, lane_ints_t draw, lane_ints_t *texel, lanes_t *pdf)
{
    return descent_sample(descent_bounds, texel_probability, res, seed, frame, pixel, draw, texel, pdf);
}

/* envmap.cl's light density: descent.cl's. */
ALWAYS_INLINE lanes_t lanes_light_density(LIGHT_PARAMS, const light_state_t *state, int res, lanes3_t w,
                                          lane_ints_t *texel)
{
    return descent_density(texel_probability, res, w, texel);
}

#include "envmap.cl"
