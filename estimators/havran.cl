/* `havran` (Havran et al. 2005): the frame's map on the equal-area grid, the K directional lights
 * placed by its inversion and FIR-filtered, and the shading of every pixel by them, all on the
 * device (estimators/havran.py; its NumPy twins are the tests' oracles).
 *
 * The renderer reads direction ω_k (float4, w unused) and weight·radiance
 * W_k = L(ω_k) / (p(ω_k) K) after the FIR filter (float4, w unused).  One work item per covered
 * pixel sums W_k ρ(ω_k) cos⁺(n, ω_k) over the lights above its horizon
 * (per-normal culling: lights with n·ω ≤ 0 are skipped, not evaluated).
 * used = K, effective = the lights above the horizon, evaluations = the lights shaded. */
#include "common.cl"

/* No multiply-add contraction: the lights and the filter round as their float64 NumPy twins. */
#pragma OPENCL FP_CONTRACT OFF

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

/* The max of value over columns j − 1, j, j + 1 of a row (φ wraps). */
ALWAYS_INLINE float row_max3(__global const float *row, int j, int nphi)
{
    int left = j > 0 ? j - 1 : nphi - 1, right = j < nphi - 1 ? j + 1 : 0;
    return max(max(row[left], row[j]), row[right]);
}

/* mass = (1 − conservative)·mean + conservative·(max of value over the 3×3 cells around; φ wraps,
 * rows clamp at the poles).  Straight-line code (no loops, no modulo), so it vectorises. */
__kernel void cell_mass(__global const float *mean, __global const float *value, const int nz,
                        const int nphi, const float conservative, __global acc_t *mass)
{
    int cell = get_global_id(0), i = cell / nphi, j = cell - i * nphi;
    float bound = max(max(row_max3(value + max(i - 1, 0) * nphi, j, nphi),
                          row_max3(value + i * nphi, j, nphi)),
                      row_max3(value + min(i + 1, nz - 1) * nphi, j, nphi));
    mass[cell] = (1 - (acc_t)conservative) * (acc_t)mean[cell] + (acc_t)conservative * (acc_t)bound;
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
    factors[0] = usable ? (1 - (acc_t)defensive) / total : 0;
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

/* ---- the lights (havran.py: EqualAreaMap.sample, Havran.raw_lights, fir_filter) ------------- */

/* The cube-map texel of direction (x, y, z) in acc_t, as cubemap.direction_to_texel (the float
 * cube_face_st of common.cl would round a direction near a texel edge to either side). */
ALWAYS_INLINE int acc_direction_texel(acc_t x, acc_t y, acc_t z, int res)
{
    acc_t ax = fabs(x), ay = fabs(y), az = fabs(z);
    int x_major = ax >= ay && ax >= az, y_major = !x_major && ay >= az;
    acc_t major = x_major ? x : y_major ? y : z;
    int positive = major >= 0;
    int face = (x_major ? 0 : y_major ? 2 : 4) + (positive ? 0 : 1);
    acc_t sc = x_major ? (positive ? -z : z) : y_major ? x : (positive ? x : -x);
    acc_t tc = y_major ? (positive ? z : -z) : -y;
    acc_t s = (sc / fabs(major) + 1) * ACC_LITERAL(0.5), t = (tc / fabs(major) + 1) * ACC_LITERAL(0.5);
    int row = clamp((int)floor(t * res), 0, res - 1), col = clamp((int)floor(s * res), 0, res - 1);
    return texel_index(face, row, col, res);
}

/* Entries of the nondecreasing cdf[0 … n) that are ≤ u (NumPy's searchsorted side="right"). */
ALWAYS_INLINE int count_at_most(__global const acc_t *cdf, int n, acc_t u)
{
    int base = 0;
    while (n > 0) {
        int step = n >> 1;
        if (cdf[base + step] <= u) { base += step + 1; n -= step + 1; } else n = step;
    }
    return base;
}

/* Light k of K = count from the point points[k] (the rotated relaxed set) by the map's
 * continuous inversion: ω, p(ω) and W = L(ω) / (p(ω)·K), written as acc_t (x, y, z, 0) and
 * (r, g, b, 0) at light k of slot `slot` of dir_out and weight_out ([slots][count][4]). */
__kernel void place_lights(__global const float4 *env, const int res, __global const acc_t *row_prob,
                           __global const acc_t *row_cdf, __global const acc_t *col_prob,
                           __global const acc_t *col_cdf, const int nz, const int nphi,
                           __global const acc_t *points, const int count, const int slot,
                           __global acc_t *dir_out, __global acc_t *weight_out)
{
    int k = get_global_id(0);
    acc_t u1 = points[2 * k], u2 = points[2 * k + 1];
    int i = min(count_at_most(row_cdf, nz, u1), nz - 1);   /* the row: searchsorted(side="right") */
    acc_t below = i > 0 ? row_cdf[i - 1] : 0;
    acc_t y = (i + clamp((u1 - below) / row_prob[i], (acc_t)0, (acc_t)1)) / nz;
    /* x from the blend of the CDFs of the rows whose centres bracket y, linear in y. */
    acc_t centre = y * nz - ACC_LITERAL(0.5), i0 = floor(centre), t = centre - i0;
    __global const acc_t *cdf0 = col_cdf + clamp((int)i0, 0, nz - 1) * nphi;
    __global const acc_t *cdf1 = col_cdf + clamp((int)i0 + 1, 0, nz - 1) * nphi;
    int base = 0, n = nphi;   /* count_at_most over the blend, nondecreasing as its rows are */
    while (n > 0) {
        int step = n >> 1;
        if ((1 - t) * cdf0[base + step] + t * cdf1[base + step] <= u2) { base += step + 1; n -= step + 1; }
        else n = step;
    }
    int j = min(base, nphi - 1);
    acc_t left = j > 0 ? (1 - t) * cdf0[j - 1] + t * cdf1[j - 1] : 0;
    acc_t width = (1 - t) * col_prob[(cdf0 - col_cdf) + j] + t * col_prob[(cdf1 - col_cdf) + j];
    acc_t x = (j + clamp((u2 - left) / width, (acc_t)0, (acc_t)1)) / nphi;
    acc_t pdf = row_prob[i] * nz * width * nphi / (4 * ACC_PI);
    /* Lambert's cylindrical equal-area map, +Y the pole (equal_area_to_direction). */
    acc_t cos_t = 1 - 2 * y, sin_t = sqrt(max(1 - cos_t * cos_t, (acc_t)0)), phi = 2 * ACC_PI * x;
    acc_t dx = sin_t * cos(phi), dz = sin_t * sin(phi);
    float4 radiance = env[acc_direction_texel(dx, cos_t, dz, res)];
    acc_t scale = pdf * count;
    __global acc_t *d = dir_out + ((size_t)slot * count + k) * 4;
    __global acc_t *w = weight_out + ((size_t)slot * count + k) * 4;
    d[0] = dx; d[1] = cos_t; d[2] = dz; d[3] = 0;
    w[0] = radiance.x / scale; w[1] = radiance.y / scale; w[2] = radiance.z / scale; w[3] = 0;
}

/* The FIR filter of light k over the history (fir_filter): the entries' lights are at slots
 * slot[0 … used) of the rings (newest first, acc_t [slots][count][4]) with renormalised taps
 * tap[…]; direction normalize(Σ a ω) (the newest where the sum vanishes), weight Σ a W.  One
 * entry is the identity, bit for bit.  Written in acc_t (dir_out, weight_out) and as the float4
 * lights that render_havran reads. */
__kernel void filter_lights(__global const acc_t *dir_ring, __global const acc_t *weight_ring,
                            const int count, __global const int *slot, __global const acc_t *tap,
                            const int used, __global acc_t *dir_out, __global acc_t *weight_out,
                            __global float4 *light_dir, __global float4 *light_weight)
{
    int k = get_global_id(0);
    __global const acc_t *newest = dir_ring + ((size_t)slot[0] * count + k) * 4;
    acc_t d[3] = {0, 0, 0}, w[3] = {0, 0, 0};
    for (int e = 0; e < used; ++e) {
        size_t at = ((size_t)slot[e] * count + k) * 4;
        for (int c = 0; c < 3; ++c) {
            d[c] += used == 1 ? dir_ring[at + c] : tap[e] * dir_ring[at + c];
            w[c] += used == 1 ? weight_ring[at + c] : tap[e] * weight_ring[at + c];
        }
    }
    if (used > 1) {
        acc_t norm = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        /* The twin's maximum(norm, 1e-300) guards np.where's other branch; here only the one taken runs. */
        for (int c = 0; c < 3; ++c) d[c] = norm > ACC_LITERAL(1e-9) ? d[c] / norm : newest[c];
    }
    for (int c = 0; c < 3; ++c) {
        dir_out[4 * k + c] = d[c];
        weight_out[4 * k + c] = w[c];
    }
    light_dir[k] = (float4)((float)d[0], (float)d[1], (float)d[2], 0.0f);
    light_weight[k] = (float4)((float)w[0], (float)w[1], (float)w[2], 0.0f);
}

/* The visibility cell of each light's direction, once per frame for every pixel (VISIBILITY). */
__kernel void light_cells(__global const float4 *light_dir, __global int *cells)
{
    int k = get_global_id(0);
    cells[k] = visibility_cell(vec3_load(light_dir, k));
}

__kernel void render_havran(__global const float4 *normal, __global const float4 *view,
                            __global const float4 *kd, __global const float4 *ks_m,
                            __global const uint *visibility, __global const int *light_cell,
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
        /* Havran's directional lights cast shadows: V at the light's direction. */
#if VISIBILITY
        if (!cell_open(visibility, p, light_cell[k]))   /* light_cell has K entries only with V */
            continue;
#endif
        sum += light_weight[k].xyz * phong_brdf(r, w, kdp, ksp, m) * c;
    }
    radiance[p] = (float4)(sum, 0.0f);
    counts[p] = (float2)((float)count, (float)above);
    evaluations[p] = above;
}
