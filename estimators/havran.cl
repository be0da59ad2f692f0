/* `havran` (Havran et al. 2005): the frame's map on the equal-area grid, and the shading of every
 * pixel by the frame's K directional lights.
 *
 * The lights are built on the host (estimators/havran.py): direction ω_k (float4, w unused) and
 * weight·radiance W_k = L(ω_k) / (p(ω_k) K) after the FIR filter (float4, w unused).  One work
 * item per covered pixel sums W_k ρ(ω_k) cos⁺(n, ω_k) over the lights above its horizon
 * (per-normal culling: lights with n·ω ≤ 0 are skipped, not evaluated).
 * used = K, effective = the lights above the horizon, evaluations = the lights shaded. */
#include "common.cl"

/* ---- the frame's map on the equal-area grid (havran.py, EqualAreaMap; NumPy twin there) ------
 * Cells are i·NPHI + j (row i of NZ, column j of NPHI); sums are in acc_t (double where the device
 * has it), as the twin's float64.  Work items: one per cell, per row, or one. */

/* The mean and the max of a cell's S² nearest-texel lookups (their texels precomputed per face
 * size: lookup is [NZ·S][NPHI·S]), the max also over the texels whose centres fall in the cell
 * (CSR: centre_texel[centre_offset[cell] …]). */
__kernel void cell_lookups(__global const float4 *env, __global const int *lookup, const int nphi,
                           const int supersample, __global const int *centre_offset,
                           __global const int *centre_texel, __global float *mean,
                           __global float *value)
{
    int cell = get_global_id(0), i = cell / nphi, j = cell % nphi, side = nphi * supersample;
    acc_t sum = 0;
    float largest = 0.0f;
    for (int a = 0; a < supersample; ++a)
        for (int b = 0; b < supersample; ++b) {
            float y = max(luminance(env[lookup[(i * supersample + a) * side + j * supersample + b]].xyz), 0.0f);
            sum += y;
            largest = max(largest, y);
        }
    for (int t = centre_offset[cell]; t < centre_offset[cell + 1]; ++t)
        largest = max(largest, max(luminance(env[centre_texel[t]].xyz), 0.0f));
    mean[cell] = (float)(sum / (acc_t)(supersample * supersample));
    value[cell] = largest;
}

/* mass = (1 − conservative)·mean + conservative·(max of value over the 3×3 cells around; φ wraps,
 * rows clamp at the poles). */
__kernel void cell_mass(__global const float *mean, __global const float *value, const int nz,
                        const int nphi, const float conservative, __global acc_t *mass)
{
    int cell = get_global_id(0), i = cell / nphi, j = cell % nphi;
    float bound = 0.0f;
    for (int a = -1; a <= 1; ++a)
        for (int b = -1; b <= 1; ++b)
            bound = max(bound, value[clamp(i + a, 0, nz - 1) * nphi + (j + b + nphi) % nphi]);
    mass[cell] = (1.0 - (acc_t)conservative) * (acc_t)mean[cell] + (acc_t)conservative * (acc_t)bound;
}

__kernel void row_mass(__global const acc_t *mass, const int nphi, __global acc_t *row_total)
{
    int i = get_global_id(0);
    acc_t sum = 0;
    for (int j = 0; j < nphi; ++j) sum += mass[i * nphi + j];
    row_total[i] = sum;
}

/* prob = factors[0]·mass + factors[1]: (1 − defensive)·mass/Σ mass + defensive/cells, or uniform
 * when Σ mass is 0 or not finite. */
__kernel void grid_factors(__global const acc_t *row_total, const int nz, const int nphi,
                           const float defensive, __global acc_t *factors)
{
    acc_t total = 0, cells = (acc_t)nz * (acc_t)nphi;
    for (int i = 0; i < nz; ++i) total += row_total[i];
    int usable = total > 0 && isfinite(total);
    factors[0] = usable ? (1.0 - (acc_t)defensive) / total : 0;
    factors[1] = usable ? (acc_t)defensive / cells : 1 / cells;
}

/* Row i's probability m_i = Σ_j prob, its column probabilities c_ij = prob/m_i and their CDF
 * (normalised by its last entry). */
__kernel void row_cdfs(__global const acc_t *mass, __global const acc_t *factors, const int nphi,
                       __global acc_t *row_prob, __global acc_t *col_prob, __global acc_t *col_cdf)
{
    int i = get_global_id(0);
    __global const acc_t *m = mass + i * nphi;
    acc_t sum = 0;
    for (int j = 0; j < nphi; ++j) sum += factors[0] * m[j] + factors[1];
    row_prob[i] = sum;
    acc_t running = 0;
    for (int j = 0; j < nphi; ++j) {
        acc_t c = (factors[0] * m[j] + factors[1]) / sum;
        col_prob[i * nphi + j] = c;
        running += c;
        col_cdf[i * nphi + j] = running;
    }
    for (int j = 0; j < nphi; ++j) col_cdf[i * nphi + j] /= running;
}

__kernel void marginal_cdf(__global const acc_t *row_prob, const int nz, __global acc_t *row_cdf)
{
    acc_t running = 0;
    for (int i = 0; i < nz; ++i) row_cdf[i] = running += row_prob[i];
    for (int i = 0; i < nz; ++i) row_cdf[i] /= running;
}

__kernel void render_havran(__global const float4 *normal, __global const float4 *view,
                            __global const float4 *kd, __global const float4 *ks_m,
                            __global const float4 *light_dir, __global const float4 *light_weight,
                            const int count, __global float4 *radiance, __global float2 *counts,
                            __global int *evaluations)
{
    int p = get_global_id(0);
    float3 n = normal[p].xyz;
    float3 r = reflect_view(n, view[p].xyz);
    float3 kdp = kd[p].xyz, ksp = ks_m[p].xyz;
    float m = ks_m[p].w;
    float3 sum = (float3)(0.0f);
    int above = 0;
    for (int k = 0; k < count; ++k) {
        float3 w = light_dir[k].xyz;
        float c = dot(n, w);
        if (c <= 0.0f)
            continue;
        ++above;
        sum += light_weight[k].xyz * phong_brdf(r, w, kdp, ksp, m) * c;
    }
    radiance[p] = (float4)(sum, 0.0f);
    counts[p] = (float2)((float)count, (float)above);
    evaluations[p] = above;
}
