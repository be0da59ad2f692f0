/* Shared conventions of ARCHITECTURE.md §Conventions: cube map, light pdf, Phong BRDF, Philox RNG, CDF search.
 * The Python twin of the cube-map functions is iblbench.scenes.cubemap; tests pin that they agree. */
#ifndef IBLBENCH_COMMON_CL
#define IBLBENCH_COMMON_CL

/* Random123 declares its helpers with this: static, so that none is left as an undefined symbol where
 * a compiler does not inline it (a plain `inline` function has no definition of its own, C99 6.7.4). */
#define R123_STATIC_INLINE static inline
#include <pyopencl-random123/philox.cl>

#define IBL_PI 3.14159265358979323846f

/* Helpers that per-sample loops call are forced inline: PoCL's inliner leaves large ones out
 * ("too costly"), and a call inside the work-item loop stops its vectorisation.  Every helper is
 * static: a plain `inline` function has no definition of its own (C99 6.7.4), so a compiler that
 * does not inline a call to it (any, at -O0) leaves an undefined symbol. */
#define ALWAYS_INLINE static inline __attribute__((always_inline))

/* Before a loop whose trip count is a constant: unroll it (so that its private arrays stay in
 * registers).  OpenCL C 2.0's opencl_unroll_hint is not OpenCL C 1.2; clang's pragma (PoCL's
 * compiler and most others) gives the same loop metadata, and elsewhere the loop is left as is. */
#ifdef __clang__
#define UNROLL _Pragma("unroll")
#else
#define UNROLL
#endif

/* ---- accumulation ---------------------------------------------------------------------------- */

/* Long sums (CDF scans, the reference) use double where the device has it (-DHAVE_FP64, set by
 * the harness) and are Kahan-compensated either way. */
#ifdef HAVE_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double acc_t;
typedef double8 acc8_t;   /* eight lanes of acc_t, for sums in explicit vectors */
#define convert_acc8 convert_double8
#define ACC_LITERAL(x) x   /* a floating constant in acc_t */
#else
typedef float acc_t;
typedef float8 acc8_t;
#define convert_acc8 convert_float8
/* A double constant needs cl_khr_fp64 (a device without it warns and rounds it to float). */
#define ACC_LITERAL(x) x##f
#endif
#define ACC_PI ACC_LITERAL(3.14159265358979323846)   /* π in acc_t (M_PI needs cl_khr_fp64) */

static inline acc_t sum_acc8(acc8_t v)
{
    return ((v.s0 + v.s1) + (v.s2 + v.s3)) + ((v.s4 + v.s5) + (v.s6 + v.s7));
}

typedef struct { acc_t sum, carry; } kahan_t;

static inline void kahan_add(kahan_t *k, acc_t x)
{
    acc_t y = x - k->carry;
    acc_t t = k->sum + y;
    k->carry = (t - k->sum) - y;
    k->sum = t;
}

/* ---- scalar 3-vectors ------------------------------------------------------------------------ */

/* Three floats in a struct, not a float3: LLVM's loop vectoriser, which PoCL runs across the work
 * items, rejects every instruction of vector type ("instruction return type cannot be
 * vectorized"), so code meant to run SIMD across work items keeps 3-vectors as scalars (a struct
 * of scalars lives in registers).  The padding makes the struct 20 bytes: the x86-64 ABI then
 * returns it in memory, which inlining removes, instead of as a <2 x float> and a float, which
 * stays a 2-vector in the IR.  The float3 forms of the helpers below wrap the vec3_t ones. */
typedef struct { float x, y, z, padding[2]; } vec3_t;

ALWAYS_INLINE vec3_t vec3(float x, float y, float z)
{
    vec3_t v = {x, y, z, {0.0f, 0.0f}};
    return v;
}

ALWAYS_INLINE vec3_t vec3_of(float3 a) { return vec3(a.x, a.y, a.z); }
ALWAYS_INLINE float3 float3_of(vec3_t a) { return (float3)(a.x, a.y, a.z); }

/* .xyz of element i of a float4 buffer, as three scalar loads.  The component stride is
 * get_work_dim(), which is 1 for the 1-D kernels here but unknown to the compiler: PoCL runs
 * LLVM's SLP vectoriser on the kernel before it builds the work-item loops, and that pass fuses
 * loads it can prove adjacent, and the x and y arithmetic that follows them, into 2-vectors,
 * which then keep the work-item loop scalar.  (balanced_mis on PoCL 3.1: with literal offsets
 * 6 of the 41 work-item loops in its three compiled copies vectorise, with this stride and
 * vec3_t's padding 21, its sample loops among them.) */
ALWAYS_INLINE vec3_t vec3_load(__global const float4 *buffer, int i)
{
    __global const float *f = (__global const float *)(buffer + i);
    int stride = (int)get_work_dim();
    return vec3(f[0], f[stride], f[2 * stride]);
}

/* .w of element i of a float4 buffer. */
ALWAYS_INLINE float load_w(__global const float4 *buffer, int i)
{
    return ((__global const float *)(buffer + i))[3];
}

ALWAYS_INLINE float vec3_dot(vec3_t a, vec3_t b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
ALWAYS_INLINE vec3_t vec3_scale(vec3_t a, float k) { return vec3(a.x * k, a.y * k, a.z * k); }
ALWAYS_INLINE vec3_t vec3_mul(vec3_t a, vec3_t b) { return vec3(a.x * b.x, a.y * b.y, a.z * b.z); }
ALWAYS_INLINE vec3_t vec3_add(vec3_t a, vec3_t b) { return vec3(a.x + b.x, a.y + b.y, a.z + b.z); }
ALWAYS_INLINE vec3_t vec3_normalize(vec3_t a) { return vec3_scale(a, 1.0f / sqrt(vec3_dot(a, a))); }

/* 3-vectors of 8 and 16 lanes, for code in explicit vectors (one direction per lane). */
typedef struct { float8 x, y, z; } vec3x8_t;
typedef struct { float16 x, y, z; } vec3x16_t;

ALWAYS_INLINE vec3x8_t vec3x8(float8 x, float8 y, float8 z)
{
    vec3x8_t v = {x, y, z};
    return v;
}

ALWAYS_INLINE vec3x16_t vec3x16(float16 x, float16 y, float16 z)
{
    vec3x16_t v = {x, y, z};
    return v;
}

ALWAYS_INLINE float vec3_luminance(vec3_t c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }
static inline float luminance(float3 c) { return vec3_luminance(vec3_of(c)); }

/* ---- cube map ------------------------------------------------------------------------------ */

/* Direction -> face and (s, t) in [0, 1] by the OpenGL table; ties go to x, then y.  Selects,
 * no branches, so it vectorises.  y_major by a select, not !x_major & …: Oclgrind 21.10 gets
 * vectors' ! of a mask wrong (1 and -2 for -1 and 0). */
#define DEFINE_CUBE_FACE_ST(name, floatn, intn, vecn)                                              \
ALWAYS_INLINE intn name(vecn d, floatn *s, floatn *t)                                              \
{                                                                                                  \
    floatn ax = fabs(d.x), ay = fabs(d.y), az = fabs(d.z);                                         \
    intn x_major = (ax >= ay) & (ax >= az), y_major = select(ay >= az, (intn)0, x_major);          \
    intn positive = select(select(d.z, d.y, y_major), d.x, x_major) >= 0.0f;                       \
    intn face = select(select((intn)4, (intn)2, y_major), (intn)0, x_major)                        \
              + select((intn)1, (intn)0, positive);                                                \
    floatn ma = select(select(az, ay, y_major), ax, x_major);                                      \
    floatn sc = select(select(select(-d.x, d.x, positive), d.x, y_major),                          \
                       select(d.z, -d.z, positive), x_major);                                      \
    floatn tc = select(-d.y, select(-d.z, d.z, positive), y_major);                                \
    *s = (sc / ma + 1.0f) * 0.5f;                                                                  \
    *t = (tc / ma + 1.0f) * 0.5f;                                                                  \
    return face;                                                                                   \
}

DEFINE_CUBE_FACE_ST(cube_face_st, float, int, vec3_t)
DEFINE_CUBE_FACE_ST(cube_face_st8, float8, int8, vec3x8_t)
DEFINE_CUBE_FACE_ST(cube_face_st16, float16, int16, vec3x16_t)

static inline int dir_to_face_st(float3 d, float *s, float *t) { return cube_face_st(vec3_of(d), s, t); }

/* Face-plane point (u, v) = (2s-1, 2t-1) -> (unnormalised) direction on the cube. */
static inline float3 face_uv_to_dir(int face, float u, float v)
{
    switch (face) {
    case 0:  return (float3)( 1.0f, -v, -u);
    case 1:  return (float3)(-1.0f, -v,  u);
    case 2:  return (float3)( u,  1.0f,  v);
    case 3:  return (float3)( u, -1.0f, -v);
    case 4:  return (float3)( u, -v,  1.0f);
    default: return (float3)(-u, -v, -1.0f);
    }
}

static inline int clamp_index(float x, int res) { return clamp((int)floor(x * res), 0, res - 1); }

static inline int texel_index(int face, int row, int col, int res) { return (face * res + row) * res + col; }

/* dA/dω at face-plane point (u, v): solid angle → face area Jacobian (1+u²+v²)^{3/2}. */
static inline float area_per_solid_angle(float u, float v)
{
    float q = 1.0f + u * u + v * v;
    return q * sqrt(q);
}

/* ---- visibility ------------------------------------------------------------------------------ */

/* V(x, ω) from the G-buffer's per-pixel bit masks (iblbench.scenes.visibility, whose docstring
 * is the layout): VIS_RES² cells a cube face, cell (face, ⌊t·VIS_RES⌋, ⌊s·VIS_RES⌋) of ω, bit
 * b = (face·VIS_RES + row)·VIS_RES + col of the pixel's VIS_WORDS words.  Set by the harness
 * from the G-buffer (VISIBILITY=1 and VIS_RES): without it V is 1 and compiles away, so a scene
 * without visibility runs the very code it ran before. */
#ifndef VISIBILITY
#define VISIBILITY 0
#endif
#ifndef VIS_RES
#define VIS_RES 1
#endif
#define VIS_WORDS ((6 * VIS_RES * VIS_RES + 31) / 32)

/* The visibility cell (its bit's index) that holds direction w. */
ALWAYS_INLINE int visibility_cell(vec3_t w)
{
    float s, t;
    int face = cube_face_st(w, &s, &t);
    return (face * VIS_RES + clamp((int)floor(t * VIS_RES), 0, VIS_RES - 1)) * VIS_RES
         + clamp((int)floor(s * VIS_RES), 0, VIS_RES - 1);
}

/* The pixel's mask bit of visibility cell `cell`: 1 where open, 0 where shadowed (1 without
 * VISIBILITY). */
ALWAYS_INLINE int cell_open(__global const uint *visibility, int pixel, int cell)
{
#if VISIBILITY
    return (int)((visibility[(size_t)pixel * VIS_WORDS + (cell >> 5)] >> (cell & 31)) & 1u);
#else
    return 1;
#endif
}

/* V(x_pixel, w) (the one visibility function of every kernel; light_pool.cl's lanes_visible is
 * its lanes form): 1 where the pixel's mask says the cell of w is open, else 0.  Where many
 * pixels share a direction (a light pool's entry, a directional light) its cell is found once
 * and read with cell_open. */
ALWAYS_INLINE int visible(__global const uint *visibility, int pixel, vec3_t w)
{
    return VISIBILITY ? cell_open(visibility, pixel, visibility_cell(w)) : 1;
}

/* ---- CDF search and light sampling --------------------------------------------------------- */

/* The light CDFs are fixed point (built by harness/framecache.cl): entry i is the inclusive prefix
 * sum of integer bin widths q_j in units of 2^-63, the last entry exactly CDF_ONE = 2^63; bin i
 * has probability q_i / 2^63.  Why (issue 6, stress case sun-1e9): a float32 CDF collapses bins
 * under its spacing near 1 (6e-8), e.g. the sky after a sun in its row or face: never drawn,
 * pdf 0, a silent bias of pure light sampling.  Wider storage alone does not help, nor does a
 * two-sided or hierarchical float CDF: a float32 variate has 24 bits and cannot reach a bin
 * under 2^-24 (the sky next to a sun in the same block has such bins).  So: widths rounded
 * relatively and ≥ 1 for every positive weight, searched with 63-bit variates (pool_point),
 * draw bin i with probability exactly q_i / 2^63, on any device (sampling needs no fp64).
 * Samplers draw their points as 63-bit words (rng_words2 >> 1). */
typedef ulong cdf_word_t;
#define CDF_ONE ((cdf_word_t)1 << 63)

/* Bits of the bin index of an alias table over n ≥ 2 bins (framecache.cl's alias_table): its
 * 2^bits bins are the n padded to a power of two, so a bin is the top bits of a random word. */
static inline int alias_bits(int n) { return 32 - clz(n - 1); }

/* First i with cdf[i] > u; cdf is inclusive and ends at exactly CDF_ONE, so zero-width bins are
 * never chosen and the result is < n for u in [0, CDF_ONE).  The trip count depends on n only,
 * so the search is branch-free across work items and vectorises. */
static inline int cdf_search(__global const cdf_word_t *cdf, int n, cdf_word_t u)
{
    int base = 0;
    while (n > 1) {
        int step = n >> 1;
        base = (cdf[base + step - 1] <= u) ? base + step : base;
        n -= step;
    }
    return base;
}

static inline cdf_word_t cdf_lower(__global const cdf_word_t *cdf, int i) { return i > 0 ? cdf[i - 1] : 0; }

/* Probability of bin i: its width q_i·2^-63, exact to float rounding (relative 2^-24). */
static inline float cdf_bin(__global const cdf_word_t *cdf, int i)
{
    return convert_float(cdf[i] - cdf_lower(cdf, i)) * 0x1p-63f;
}

/* Position of u within bin i of `cdf`, in [0, 1): the continuous inversion that lets one uniform
 * pick both the bin and the point inside it, so a 2-D point set maps to directions. */
static inline float cdf_bin_position(__global const cdf_word_t *cdf, int i, cdf_word_t u)
{
    cdf_word_t lo = cdf_lower(cdf, i);
    return clamp(convert_float(u - lo) / convert_float(cdf[i] - lo), 0.0f, 0x1.fffffep-1f);
}

/* Sample face `face` from the 2-D fixed-point point u (63-bit coordinates in [0, CDF_ONE)) by its
 * marginal (rows) and conditional (columns | row) CDFs; the position of u inside the chosen bins
 * is the point in the texel's face square.  Returns pdf_L(ω|f) in solid angle (ARCHITECTURE.md §Conventions):
 * P(texel|f) · (1+u²+v²)^{3/2} / a_texel with a_texel = (2/R)².  *texel gets the texel index. */
/* sample_face once its texel (row, col) is chosen from the face's marginal `rows` and conditional
 * `cols` by the point (ux, uy): the face-plane point (*x, *y) and pdf_L(ω|f).  Shared with the
 * scalar-lane form in estimators/lanes.cl, which searches the CDFs its own way. */
ALWAYS_INLINE float face_point_pdf(__global const cdf_word_t *rows, __global const cdf_word_t *cols,
                                   int row, int col, int res, cdf_word_t ux, cdf_word_t uy,
                                   float *x, float *y)
{
    *x = -1.0f + 2.0f * ((float)col + cdf_bin_position(cols, col, uy)) / res;
    *y = -1.0f + 2.0f * ((float)row + cdf_bin_position(rows, row, ux)) / res;
    float texel_area = 4.0f / ((float)res * (float)res);
    return cdf_bin(rows, row) * cdf_bin(cols, col) * area_per_solid_angle(*x, *y) / texel_area;
}

static inline float sample_face(__global const cdf_word_t *marginal,
                                      __global const cdf_word_t *conditional,
                                      int face, int res, ulong2 u, float3 *dir, int *texel)
{
    __global const cdf_word_t *rows = marginal + face * res;
    int row = cdf_search(rows, res, u.x);
    __global const cdf_word_t *cols = conditional + (face * res + row) * res;
    int col = cdf_search(cols, res, u.y);
    float x, y;
    float pdf = face_point_pdf(rows, cols, row, col, res, u.x, u.y, &x, &y);
    *dir = normalize(face_uv_to_dir(face, x, y));
    *texel = texel_index(face, row, col, res);
    return pdf;
}

/* pdf_L(ω|f) of sample_face for the face f that holds ω (it is zero on every other face);
 * *face and *texel get the face and the texel that hold ω. */
ALWAYS_INLINE float light_pdf_on_face(__global const cdf_word_t *marginal,
                                      __global const cdf_word_t *conditional, int res, vec3_t w,
                                      int *face, int *texel)
{
    float s, t;
    int f = cube_face_st(w, &s, &t);
    int row = clamp_index(t, res), col = clamp_index(s, res);
    float p_texel = cdf_bin(marginal + f * res, row)
                  * cdf_bin(conditional + (f * res + row) * res, col);
    *face = f;
    *texel = texel_index(f, row, col, res);
    return p_texel * area_per_solid_angle(2.0f * s - 1.0f, 2.0f * t - 1.0f) * (float)(res * res) / 4.0f;
}

/* light_pdf_on_face for a float3, without the face (it is texel / R²). */
static inline float light_pdf(__global const cdf_word_t *marginal, __global const cdf_word_t *conditional,
                              int res, float3 w, int *texel)
{
    int face;
    return light_pdf_on_face(marginal, conditional, res, vec3_of(w), &face, texel);
}

/* ---- Phong BRDF (energy-conserving, Lafortune) --------------------------------------------- */

/* Mirror of the view direction about n: r = 2(n·v)n − v. */
ALWAYS_INLINE vec3_t vec3_reflect_view(vec3_t n, vec3_t v)
{
    float k = 2.0f * vec3_dot(n, v);
    return vec3(k * n.x - v.x, k * n.y - v.y, k * n.z - v.z);
}

static inline float3 reflect_view(float3 n, float3 v) { return float3_of(vec3_reflect_view(vec3_of(n), vec3_of(v))); }

/* c^m for c in [0, 1] and m ≥ 0, as 2^(m·log2 c) with both halves polynomials over the float's
 * bits: straight-line code that inlines and vectorises (the library exp2/log2 are table-driven
 * scalar calls on PoCL, about 35 cycles, most of a pool sample's time).
 *   log2 c = e + log2 f, c = 2^e·f with f in [√½, √2) (denormal c scaled by 2^24 first);
 *   log2 f = (2/ln 2)·atanh s, s = (f−1)/(f+1), |s| ≤ 0.172, by its series to s⁹ (remainder
 *   below 2e-9 relative: exact near c = 1, where m·log2 c needs it);
 *   2^y = 2^n·2^r, n = round(y), |r| ≤ ½, 2^r by its Taylor series to r⁷ (remainder 5e-9), 2^n
 *   from the exponent bits.
 * c ≤ 0 gives 0 (the lobe max(0, r·ω)^m vanishes below its horizon, also for m = 0), c = 1 and
 * m = 0 give exactly 1, results under 2^-126 flush to 0; no NaN or Inf for any m ≥ 0 (y is
 * clamped at −127).  Error against float64 pow on a dense grid of float c in [0, 1], m in
 * [0, 1e4] and up to 1e6 (tests/test_phong_power.py): relative ≤ 2e-5 wherever c^m ≥ 2^-120
 * (measured 1.5e-5; float exp2(m·log2 c) with libm's functions: 1.1e-5), absolute ≤ 2^-120 below.
 * The relative error grows as ln 2·|y|·ε with the float rounding ε of y = m·log2 c (1e-6 where
 * c^m ≥ 1e-3), as it does for exp2(m·log2 c) in float. */
#define DEFINE_PHONG_POWER(name, floatn, intn)                                                    \
/* log2 c for c > 0 (the first half; a base shared by many exponents takes it once). */            \
ALWAYS_INLINE floatn name##_log2(floatn c)                                                         \
{                                                                                                  \
    intn denormal = c < (floatn)0x1p-126f;                                                         \
    intn bits = as_##intn(select(c, c * 0x1p24f, denormal));                                       \
    floatn f = as_##floatn((bits & 0x007fffff) | 0x3f800000);        /* mantissa in [1, 2) */      \
    intn above = f > (floatn)1.41421356f;                                                          \
    f = select(f, 0.5f * f, above);                                                                \
    intn e = (bits >> 23) - 127 + select((intn)0, (intn)1, above)                                  \
           - select((intn)0, (intn)24, denormal);                                                  \
    floatn s = (f - 1.0f) / (f + 1.0f), z = s * s;                                                 \
    floatn log2_f = s * (2.8853900817779268f + z * (0.9617966939259756f + z * (0.5770780163555853f \
                  + z * (0.4121985831111324f + z * 0.3205988979753252f))));                        \
    return convert_##floatn(e) + log2_f;                                                           \
}                                                                                                  \
                                                                                                   \
/* c^m given log2_c = name##_log2(c) (the second half). */                                         \
ALWAYS_INLINE floatn name##_of_log2(floatn c, floatn log2_c, floatn m)                             \
{                                                                                                  \
    floatn y = max(m * log2_c, (floatn)-127.0f);                                                   \
    floatn n = -convert_##floatn(convert_##intn(0.5f - y)), r = y - n; /* round(y), halves down */ \
    floatn exp2_r = 1.0f + r * (0.6931471805599453f + r * (0.2402265069591007f                     \
                  + r * (0.055504108664821576f + r * (0.009618129107628477f                        \
                  + r * (0.0013333558146428441f + r * (0.00015403530393381606f                     \
                  + r * 1.5252733804059838e-05f))))));                                             \
    floatn scale = as_##floatn((convert_##intn(n) + 127) << 23);       /* 2^n; 0 at n = −127 */    \
    return select((floatn)0.0f, exp2_r * scale, c > 0.0f);                                         \
}                                                                                                  \
                                                                                                   \
ALWAYS_INLINE floatn name(floatn c, floatn m) { return name##_of_log2(c, name##_log2(c), m); }

/* The scalar form, and 8 and 16 lanes of it for code in explicit vectors (all selects, so the
 * one body serves every width; the lanes' results are bit-identical to the scalar one's). */
DEFINE_PHONG_POWER(phong_power, float, int)
DEFINE_PHONG_POWER(phong_power8, float8, int8)
DEFINE_PHONG_POWER(phong_power16, float16, int16)

/* The specular lobe's power cos⁺(r, ω)^m.  phong_value and phong_mixture_pdf take it, so a
 * sample that needs the BRDF and the pdf at one direction computes it once. */
ALWAYS_INLINE float phong_lobe_power(vec3_t r, vec3_t w, float m)
{
    return phong_power(max(vec3_dot(r, w), 0.0f), m);
}

/* ρ = kd/π + ks·(m+2)/(2π)·max(0, r·ω)^m (no cosine), given the lobe power. */
ALWAYS_INLINE vec3_t phong_value(vec3_t kd, vec3_t ks, float m, float power)
{
    float lobe = (m + 2.0f) / (2.0f * IBL_PI) * power;
    return vec3(kd.x / IBL_PI + ks.x * lobe, kd.y / IBL_PI + ks.y * lobe, kd.z / IBL_PI + ks.z * lobe);
}

static inline float3 phong_brdf(float3 r, float3 w, float3 kd, float3 ks, float m)
{
    return float3_of(phong_value(vec3_of(kd), vec3_of(ks), m, phong_lobe_power(vec3_of(r), vec3_of(w), m)));
}

/* BRDF sampling compiles its specular-lobe branch only with SPECULAR_LOBE=1 (the default); a
 * G-buffer without any ks > 0 builds with SPECULAR_LOBE=0, so all-diffuse scenes never run it. */
#ifndef SPECULAR_LOBE
#define SPECULAR_LOBE 1
#endif

/* Probability of sampling the specular lobe: its luminance weight Y(ks) / (Y(kd) + Y(ks)). */
ALWAYS_INLINE float lobe_probability(float yd, float ys) { return ys > 0.0f ? ys / (yd + ys) : 0.0f; }

static inline float specular_lobe_probability(float3 kd, float3 ks)
{
    return lobe_probability(luminance(kd), luminance(ks));
}

/* One pixel's shading inputs, unpacked from the G-buffer's float4 buffers (ks_m.w = shininess). */
typedef struct {
    float3 n, r, kd, ks;
    float m, p_spec, rho_y_kd, rho_y_ks;   /* lobe choice probability, luminances of kd, ks */
} surface_t;

/* surface_t in scalars (vec3_t), for code that vectorises across work items. */
typedef struct {
    vec3_t n, r, kd, ks;
    float m, p_spec;
} shading_t;

ALWAYS_INLINE shading_t make_shading(vec3_t n, vec3_t view, vec3_t kd, vec3_t ks, float m)
{
    shading_t s = {n, vec3_reflect_view(n, view), kd, ks, m,
                   lobe_probability(vec3_luminance(kd), vec3_luminance(ks))};
    return s;
}

/* Pixel p's shading_t, read from the G-buffer component by component. */
ALWAYS_INLINE shading_t load_shading(__global const float4 *normal, __global const float4 *view,
                                     __global const float4 *kd, __global const float4 *ks_m, int p)
{
    return make_shading(vec3_load(normal, p), vec3_load(view, p), vec3_load(kd, p),
                        vec3_load(ks_m, p), load_w(ks_m, p));
}

static inline surface_t make_surface(float4 normal, float4 view, float4 kd, float4 ks_m)
{
    shading_t h = make_shading(vec3_of(normal.xyz), vec3_of(view.xyz), vec3_of(kd.xyz),
                               vec3_of(ks_m.xyz), ks_m.w);
    surface_t s;
    s.n = normal.xyz;
    s.r = float3_of(h.r);
    s.kd = kd.xyz;
    s.ks = ks_m.xyz;
    s.m = h.m;
    s.p_spec = h.p_spec;
    s.rho_y_kd = luminance(s.kd);
    s.rho_y_ks = luminance(s.ks);
    return s;
}

/* cos and sin of 2π·u for u in [0, 1]: u's nearest quarter turn q/4 and the rest a = 2π(u − q/4)
 * in [−π/4, π/4], whose sine and cosine are their Taylor series to a⁹ and a¹⁰ (remainders under
 * 2e-9); the quarter turns rotate them.  Polynomials and selects, so it vectorises (the library
 * sin and cos are calls on PoCL). */
#define DEFINE_SINCOS_TURN(name, floatn, intn)                                                     \
ALWAYS_INLINE void name(floatn u, floatn *sine, floatn *cosine)                                    \
{                                                                                                  \
    intn q = convert_##intn(4.0f * u + 0.5f);                                                      \
    floatn a = (4.0f * u - convert_##floatn(q)) * (0.5f * IBL_PI), a2 = a * a;                     \
    floatn sin_a = a * (1.0f + a2 * (-1.0f / 6.0f + a2 * (1.0f / 120.0f + a2 * (-1.0f / 5040.0f    \
                 + a2 * (1.0f / 362880.0f)))));                                                    \
    floatn cos_a = 1.0f + a2 * (-0.5f + a2 * (1.0f / 24.0f + a2 * (-1.0f / 720.0f                  \
                 + a2 * (1.0f / 40320.0f + a2 * (-1.0f / 3628800.0f)))));                          \
    intn quadrant = q & 3, odd = (quadrant & 1) != 0;                                              \
    floatn c = select(cos_a, sin_a, odd), s = select(sin_a, cos_a, odd);                           \
    *cosine = select(c, -c, (quadrant == 1) | (quadrant == 2));                                    \
    *sine = select(s, -s, quadrant >= 2);                                                          \
}

DEFINE_SINCOS_TURN(sincos_turn, float, int)
DEFINE_SINCOS_TURN(sincos_turn8, float8, int8)
DEFINE_SINCOS_TURN(sincos_turn16, float16, int16)

/* Unit direction at polar cosine cos_theta and azimuth 2π·u about the unit axis z
 * (branchless orthonormal basis of Duff et al. 2017). */
#define DEFINE_DIRECTION_ABOUT_AXIS(name, floatn, vecn, make_vec, sincos)                         \
/* The basis t, b ⟂ z. */                                                                          \
ALWAYS_INLINE void name##_basis(vecn z, vecn *t, vecn *b)                                          \
{                                                                                                  \
    floatn sign = copysign((floatn)1.0f, z.z);                                                     \
    floatn a = -1.0f / (sign + z.z);                                                               \
    floatn c = z.x * z.y * a;                                                                      \
    *t = make_vec(1.0f + sign * z.x * z.x * a, sign * c, -sign * z.x);                             \
    *b = make_vec(c, sign + z.y * z.y * a, -z.y);                                                  \
}                                                                                                  \
                                                                                                   \
/* The direction in z's basis t, b, given the azimuth's sine and cosine. */                        \
ALWAYS_INLINE vecn name##_in(vecn z, vecn t, vecn b, floatn cos_theta, floatn sine, floatn cosine) \
{                                                                                                  \
    floatn sin_theta = sqrt(max(0.0f, 1.0f - cos_theta * cos_theta));                              \
    floatn along_t = sin_theta * cosine, along_b = sin_theta * sine;                               \
    /* Products and sums in separate statements: not contracted into FMAs (as in vec3_add of   \
     * vec3_scale), so the rounding is the float3 form's. */                                      \
    vecn on_t = make_vec(t.x * along_t, t.y * along_t, t.z * along_t);                             \
    vecn on_b = make_vec(b.x * along_b, b.y * along_b, b.z * along_b);                             \
    vecn on_z = make_vec(z.x * cos_theta, z.y * cos_theta, z.z * cos_theta);                       \
    floatn x = on_t.x + on_b.x, y = on_t.y + on_b.y, w = on_t.z + on_b.z;                          \
    x = x + on_z.x;                                                                                \
    y = y + on_z.y;                                                                                \
    w = w + on_z.z;                                                                                \
    floatn length_sq = x * x + y * y + w * w, k = 1.0f / sqrt(length_sq);                          \
    return make_vec(x * k, y * k, w * k);                                                          \
}                                                                                                  \
                                                                                                   \
ALWAYS_INLINE vecn name(vecn z, floatn cos_theta, floatn u)                                        \
{                                                                                                  \
    vecn t, b;                                                                                     \
    floatn sine, cosine;                                                                           \
    name##_basis(z, &t, &b);                                                                       \
    sincos(u, &sine, &cosine);                                                                     \
    return name##_in(z, t, b, cos_theta, sine, cosine);                                            \
}

DEFINE_DIRECTION_ABOUT_AXIS(direction_about_axis, float, vec3_t, vec3, sincos_turn)
DEFINE_DIRECTION_ABOUT_AXIS(direction_about_axis8, float8, vec3x8_t, vec3x8, sincos_turn8)
DEFINE_DIRECTION_ABOUT_AXIS(direction_about_axis16, float16, vec3x16_t, vec3x16, sincos_turn16)

static inline float3 direction_about(float3 z, float cos_theta, float u)
{
    return float3_of(direction_about_axis(vec3_of(z), cos_theta, u));
}

/* Mixture pdf of sample_phong in solid angle, given cos(n, ω) and the lobe power cos⁺(r,ω)^m:
 * (1 − p_s)·cos⁺(n,ω)/π + p_s·(m+1)/(2π)·cos⁺(r,ω)^m.  The specular lobe's mass below the surface
 * counts: those directions are sampled (and get a zero integrand). */
#define DEFINE_PHONG_MIXTURE_PDF(name, floatn)                                                     \
ALWAYS_INLINE floatn name(float p_spec, float m, floatn cos_n, floatn power)                       \
{                                                                                                  \
    floatn pdf = (1.0f - p_spec) * max(cos_n, 0.0f) / IBL_PI;                                      \
    return SPECULAR_LOBE ? pdf + p_spec * (m + 1.0f) / (2.0f * IBL_PI) * power : pdf;              \
}

/* The scalar form and 8 and 16 lanes of it (phong_power's widths). */
DEFINE_PHONG_MIXTURE_PDF(phong_mixture_pdf, float)
DEFINE_PHONG_MIXTURE_PDF(phong_mixture_pdf8, float8)
DEFINE_PHONG_MIXTURE_PDF(phong_mixture_pdf16, float16)

static inline float phong_pdf(float3 n, float3 r, float p_spec, float m, float3 w)
{
#if SPECULAR_LOBE
    float power = phong_lobe_power(vec3_of(r), vec3_of(w), m);
#else
    float power = 0.0f;
#endif
    return phong_mixture_pdf(p_spec, m, dot(n, w), power);
}

/* A direction drawn from the Phong BRDF (ARCHITECTURE.md §Conventions): the lobe by luminance weight (xi_lobe), the
 * diffuse lobe cosine-weighted (cos θ = √ξ), the specular lobe ∝ cos^m about r
 * (cos θ = ξ^{1/(m+1)}).  Both cosines are computed and one selected (no branch). */
ALWAYS_INLINE vec3_t sample_phong_direction(vec3_t n, vec3_t r, float p_spec, float m, float xi_cos,
                                            float xi_azimuth, float xi_lobe)
{
#if SPECULAR_LOBE
    int specular = xi_lobe < p_spec;
    vec3_t axis = specular ? r : n;
    float cos_theta = specular ? phong_power(xi_cos, 1.0f / (m + 1.0f)) : sqrt(xi_cos);
#else
    vec3_t axis = n;
    float cos_theta = sqrt(xi_cos);
#endif
    return direction_about_axis(axis, cos_theta, xi_azimuth);
}

/* sample_phong_direction for float3s and ξ = (cos, azimuth, lobe); returns the mixture pdf of the
 * direction. */
static inline float sample_phong(float3 n, float3 r, float p_spec, float m, float3 xi, float3 *w)
{
    *w = float3_of(sample_phong_direction(vec3_of(n), vec3_of(r), p_spec, m, xi.x, xi.y, xi.z));
    return phong_pdf(n, r, p_spec, m, *w);
}

/* ---- Random numbers -------------------------------------------------------------------------- */

/* The Philox4x32 block keyed by (seed, frame·2^8 + stream) and countered by (pixel, sample, draw). */
ALWAYS_INLINE philox4x32_ctr_t rng_block(uint seed, uint frame, uint stream, uint pixel, uint sample,
                                         uint draw)
{
    philox4x32_key_t key = {{seed, (frame << 8) | (stream & 0xffu)}};
    philox4x32_ctr_t ctr = {{pixel, sample, draw, 0u}};
    return philox4x32(ctr, key);
}

/* A uniform in [0, 1) from one word; 24-bit mantissas keep u < 1 exactly. */
ALWAYS_INLINE float rng_unit(uint word) { return (float)(word >> 8) * (1.0f / 16777216.0f); }

/* rng_block for lanes of sample numbers (lane k is rng_block(seed, frame, stream, pixel,
 * sample.sk, draw)) or of draw numbers (the `_draws` forms: rng_block(…, sample, draw.sk)),
 * Philox4x32 with random123's constants and ten rounds, in explicit vectors. */
typedef struct { uint8 v[4]; } rng_block8_t;
typedef struct { uint16 v[4]; } rng_block16_t;
#define DEFINE_RNG_BLOCK_LANES(name, uintn, ulongn, blockn, samplen, drawn)                         \
ALWAYS_INLINE blockn name(uint seed, uint frame, uint stream, uint pixel, samplen sample, drawn draw) \
{                                                                                                  \
    uint key0 = seed, key1 = (frame << 8) | (stream & 0xffu);                                      \
    uintn c0 = pixel, c1 = sample, c2 = draw, c3 = 0u;                                             \
    _Pragma("unroll")                                                                              \
    for (int round = 0; round < 10; ++round) {                                                     \
        /* 32×32 → 64-bit products (one native multiply per lane pair; mul_hi is not). */          \
        ulongn product0 = convert_##ulongn(c0) * 0xD2511F53ul;                                      \
        ulongn product1 = convert_##ulongn(c2) * 0xCD9E8D57ul;                                      \
        c0 = convert_##uintn(product1 >> 32) ^ c1 ^ key0;                                          \
        c1 = convert_##uintn(product1);                                                            \
        c2 = convert_##uintn(product0 >> 32) ^ c3 ^ key1;                                          \
        c3 = convert_##uintn(product0);                                                            \
        key0 += 0x9E3779B9u;                                                                       \
        key1 += 0xBB67AE85u;                                                                       \
    }                                                                                              \
    blockn block = {{c0, c1, c2, c3}};                                                             \
    return block;                                                                                  \
}

DEFINE_RNG_BLOCK_LANES(rng_block8, uint8, ulong8, rng_block8_t, uint8, uint)
DEFINE_RNG_BLOCK_LANES(rng_block16, uint16, ulong16, rng_block16_t, uint16, uint)
DEFINE_RNG_BLOCK_LANES(rng_block8_draws, uint8, ulong8, rng_block8_t, uint, uint8)
DEFINE_RNG_BLOCK_LANES(rng_block16_draws, uint16, ulong16, rng_block16_t, uint, uint16)

/* The block's four uniforms. */
static inline float4 rng_uniform4(uint seed, uint frame, uint stream, uint pixel, uint sample, uint draw)
{
    philox4x32_ctr_t r = rng_block(seed, frame, stream, pixel, sample, draw);
    return (float4)(rng_unit(r.v[0]), rng_unit(r.v[1]), rng_unit(r.v[2]), rng_unit(r.v[3]));
}

/* The same block as two 64-bit words (v0:v1, v2:v3): fixed-point CDF variates are their top 63
 * bits (word >> 1). */
static inline ulong2 rng_words2(uint seed, uint frame, uint stream, uint pixel, uint sample, uint draw)
{
    philox4x32_ctr_t r = rng_block(seed, frame, stream, pixel, sample, draw);
    return (ulong2)(upsample(r.v[0], r.v[1]), upsample(r.v[2], r.v[3]));
}

#endif
