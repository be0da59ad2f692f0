/* `brdf`: Phong BRDF sampling only (ARCHITECTURE.md §Conventions: lobe by luminance weight, cosine-weighted diffuse
 * lobe, cos^m lobe about r), estimator Σ β_i s(ω_i) / (N p_B(ω_i)): envmap.cl's kernels without
 * light samples.  SPECULAR_LOBE=0 (all-diffuse G-buffers) compiles the specular-lobe sampling
 * branch out. */
#define LIGHT_SAMPLES 0
#define BRDF_SAMPLES 1
#include "envmap.cl"
