/* `balanced`: Lu 2013 Eq. 3-5.  Per pixel, μ_f(n) = F_f(n) I_f / Σ_f F_f(n) I_f (Eq. 3), the
 * floating count N_f(n) = μ_f(n) N_s with β = frac(N_f) on the last sample (Eq. 5), and the
 * estimator of Eq. 4 over the light-sample pool.  Faces with F_f = 0 (wholly below the horizon,
 * see face_form_factor) or I_f = 0 get μ_f = 0 and no samples.
 * -DLU_BALANCED_FACES=0 is the `uniform_faces` debug switch (μ_f = 1/6). */
#ifndef LU_BALANCED_FACES
#define LU_BALANCED_FACES 1
#endif
#define LU_BRDF_SAMPLES 0
#include "light_pool_kernels.cl"
