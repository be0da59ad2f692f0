/* `hierarchical`: envmap.cl's kernels (budget, MIS with BRDF samples, χ² hooks) with light samples
 * drawn by descent through each face's pyramid of sampling-weight sums (descent.cl), as Falcor's
 * EnvMapSampler and Mitsuba 3's Hierarchical2D descend their importance mips: every choice by
 * the pyramid's sums alone, the same for every pixel. */
#include "lanes.cl"

/* descent.cl's weigher: the light weights alone, a factor 1 everywhere. */
typedef struct { int unused; } descent_weigher_t;

#include "descent.cl"

ALWAYS_INLINE void weigher_at_face(descent_weigher_t *g, lane_ints_t face) {}
ALWAYS_INLINE void weigh_faces(const descent_weigher_t *g, int l, lanes_t w[6]) {}
ALWAYS_INLINE void weigh_children(const descent_weigher_t *g, int res, int l, lane_ints_t row, lane_ints_t col,
                                  lanes_t w[4]) {}

#define LIGHT_PARAMS __global const float *pyramid
#define LIGHT_ARGS pyramid

/* envmap.cl's light sampler: descent.cl's descent; the pixel's shading `s` is not used. */
ALWAYS_INLINE lanes3_t lanes_sample_light(LIGHT_PARAMS, const shading_t *s, int res, uint seed, uint frame,
                                          uint pixel, lane_ints_t draw, lane_ints_t *texel, lanes_t *pdf)
{
    descent_weigher_t light_only;
    return descent_sample(pyramid, &light_only, res, seed, frame, pixel, draw, texel, pdf);
}

/* envmap.cl's light density: descent.cl's. */
ALWAYS_INLINE lanes_t lanes_light_density(LIGHT_PARAMS, const shading_t *s, int res, lanes3_t w, lane_ints_t *texel)
{
    descent_weigher_t light_only;
    return descent_density(pyramid, &light_only, res, w, texel);
}

#include "envmap.cl"
