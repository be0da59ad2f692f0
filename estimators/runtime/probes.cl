/* The device's measured roofline for `iblbench perf` (harness/studies/perf.py): FMA throughput
 * and copy bandwidth, on the same context and queue as the estimator kernels. */

/* Eight independent chains of fma_t multiply-adds per work item, `iterations` rounds:
 * 2·8·FMA_WIDTH·iterations FLOPs per work item (an FMA is two).  FMA_WIDTH is the device's
 * preferred float vector width (probes.py's fma_width): explicit vectors of that width in named
 * registers fill the SIMD lanes and hide the FMA latency (on this AVX-512 CPU float16 ran 1.8-2.7×
 * float8's rate, which used half of each register; PoCL's vectorisation across work items
 * reached a third of float8's rate with scalar chains, and a private array of chains a quarter);
 * a GPU, whose preferred width is 1, runs scalar chains per work item.  b and c are arguments, so
 * the compiler cannot fold the chains; with b = 1 every step is an exactly rounded float add,
 * which the tests replay in NumPy to check that every FMA ran.  probes.py's FMA_CHAINS states the
 * shape. */
#if FMA_WIDTH == 16
typedef float16 fma_t;
#elif FMA_WIDTH == 8
typedef float8 fma_t;
#elif FMA_WIDTH == 4
typedef float4 fma_t;
#elif FMA_WIDTH == 2
typedef float2 fma_t;
#else
typedef float fma_t;
#endif

__kernel void fma_throughput(const int iterations, const float b, const float c,
                             __global fma_t *out)
{
    size_t id = get_global_id(0);
    fma_t a0 = (fma_t)((float)id * 1e-9f), a1 = a0 + 1.0f, a2 = a0 + 2.0f, a3 = a0 + 3.0f,
          a4 = a0 + 4.0f, a5 = a0 + 5.0f, a6 = a0 + 6.0f, a7 = a0 + 7.0f;
    fma_t bv = (fma_t)(b), cv = (fma_t)(c);
    for (int i = 0; i < iterations; ++i) {
        a0 = fma(a0, bv, cv); a1 = fma(a1, bv, cv); a2 = fma(a2, bv, cv); a3 = fma(a3, bv, cv);
        a4 = fma(a4, bv, cv); a5 = fma(a5, bv, cv); a6 = fma(a6, bv, cv); a7 = fma(a7, bv, cv);
    }
    __global fma_t *o = out + 8 * id;
    o[0] = a0; o[1] = a1; o[2] = a2; o[3] = a3; o[4] = a4; o[5] = a5; o[6] = a6; o[7] = a7;
}

/* One float4 read and one float4 written per work item: 32 bytes moved per item. */
__kernel void copy_bandwidth(__global const float4 *in, __global float4 *out)
{
    size_t i = get_global_id(0);
    out[i] = in[i];
}
