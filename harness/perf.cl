/* The device's measured roofline for `iblbench perf` (harness/perf.py): FMA throughput and copy
 * bandwidth, on the same context and queue as the estimator kernels. */

/* Eight independent chains of float8 multiply-adds per work item, `iterations` rounds:
 * 2·8·8·iterations FLOPs per work item (an FMA is two).  Explicit float8 vectors in named
 * registers fill the SIMD lanes and hide the FMA latency (PoCL's vectorisation across work
 * items reached a third of this rate with scalar chains, and a private array of chains a
 * quarter); a GPU splits them into scalar chains.  b and c are arguments, so the compiler
 * cannot fold the chains; with b = 1 every step is an exactly rounded float add, which the
 * tests replay in NumPy to check that every FMA ran.  perf.py's FMA_CHAINS and FMA_LANES
 * state the shape. */
__kernel void fma_throughput(const int iterations, const float b, const float c,
                             __global float8 *out)
{
    size_t id = get_global_id(0);
    float8 a0 = (float8)((float)id * 1e-9f), a1 = a0 + 1.0f, a2 = a0 + 2.0f, a3 = a0 + 3.0f,
           a4 = a0 + 4.0f, a5 = a0 + 5.0f, a6 = a0 + 6.0f, a7 = a0 + 7.0f;
    float8 bv = (float8)(b), cv = (float8)(c);
    for (int i = 0; i < iterations; ++i) {
        a0 = fma(a0, bv, cv); a1 = fma(a1, bv, cv); a2 = fma(a2, bv, cv); a3 = fma(a3, bv, cv);
        a4 = fma(a4, bv, cv); a5 = fma(a5, bv, cv); a6 = fma(a6, bv, cv); a7 = fma(a7, bv, cv);
    }
    __global float8 *o = out + 8 * id;
    o[0] = a0; o[1] = a1; o[2] = a2; o[3] = a3; o[4] = a4; o[5] = a5; o[6] = a6; o[7] = a7;
}

/* One float4 read and one float4 written per work item: 32 bytes moved per item. */
__kernel void copy_bandwidth(__global const float4 *in, __global float4 *out)
{
    size_t i = get_global_id(0);
    out[i] = in[i];
}
