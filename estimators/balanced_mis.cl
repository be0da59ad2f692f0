/* `balanced_mis`: Lu 2013 Eq. 6.  Half the budget to light samples balanced per face
 * (N_f(n) = μ_f(n) N_s/2, Eq. 3), half to Phong BRDF samples (N_b = N_s/2), both with β of
 * Eq. 5, combined by the balance heuristic (see balanced_mis.py for the denominators).
 * SPECULAR_LOBE=0 (all-diffuse G-buffers) compiles the specular-lobe sampling branch out. */
#define LU_BALANCED_FACES 1
#define LU_BRDF_SAMPLES 1
#include "light_pool_kernels.cl"
