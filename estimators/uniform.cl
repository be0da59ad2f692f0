/* `uniform`: Lu 2013's baseline, μ_f = 1/6 (Sec. 2.1), in the same pool framework as `balanced`:
 * the estimator of Eq. 4 with N_f = N_s/6 per face and β_i of Eq. 5, reading the light-sample
 * pool of Algorithm 1.  Faces with I_f = 0 are not drawn: their integrand is zero everywhere, so
 * skipping them changes nothing but the work done (and their sixth of the budget goes unused). */
#define LU_BALANCED_FACES 0
#define LU_BRDF_SAMPLES 0
#include "light_pool_kernels.cl"
