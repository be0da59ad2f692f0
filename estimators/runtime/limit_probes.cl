/* The limits other than the roofline that hold an estimator's kernel (`iblbench perf`,
 * harness/studies/perf.py; launchers in probes.py).  Each runs one operation of the estimators'
 * explicit vectors (POOL_LANES lanes, light_pool.cl) many times, independently of the
 * estimators' code but in its form, and perf divides its time by the lane-operations it ran:
 *   - phong_power_throughput: phong_power_lanes (common.cl) on fresh arguments, the lobe power
 *     of every sample;
 *   - philox_throughput: rng_block_lanes (common.cl), a Philox4x32-10 block a lane, the random
 *     numbers of a sample drawn per pixel;
 *   - divide_throughput: a float division a lane (correctly rounded: no -cl-fast-relaxed-math);
 *   - lane_gathers: GATHER (light_pool.cl), one element a lane from a table, as a texel, CDF
 *     word or pool lookup is made; with DEPENDENT = 1 each lane's next index is the value just
 *     loaded (a chain of dependent loads: a CDF search, a descent, an alias table's second
 *     read), with DEPENDENT = 0 an index the loads do not feed (independent random gathers);
 *   - serial_adds: a scalar chain of dependent acc_t additions, as a vector's lanes leave one by
 *     one into a pixel's running sum (bis's and smc's candidates' total);
 *   - lockstep_steps: a step of a scalar search, one dependent load a work item, ended by a
 *     LOCKSTEP barrier (lanes.cl), as bis's and smc's binary searches of their bounds are. */
#include "light_pool.cl"

#if POOL_LANES == 16
#define as_lane_uints as_uint16
#else
#define as_lane_uints as_uint8
#endif

/* A work item's lanes' global numbers g = POOL_LANES·id + k: every probe's arguments depend on g
 * alone, so its outputs, read as one array, are the same at either lane width. */
#define GLOBAL_LANES(id) (convert_lane_uints((int)((id) * POOL_LANES) + LANE_NUMBERS))

/* `iterations` lobe powers a lane: acc += c^m, then c *= shrink (shrink < 1 keeps c in (0, 1];
 * one multiply and one add of overhead a power), from c = 0.25 + (g mod 64)/128.  out[id]
 * holds each lane's sum. */
__kernel void phong_power_throughput(const int iterations, const float m, const float shrink,
                                     __global lanes_t *out)
{
    size_t id = get_global_id(0);
    lanes_t c = 0.25f + convert_lanes(GLOBAL_LANES(id) & 63u) * (1.0f / 128.0f), acc = (lanes_t)0.0f;
    for (int i = 0; i < iterations; ++i) {
        acc += phong_power_lanes(c, (lanes_t)m);
        c *= shrink;
    }
    out[id] = acc;
}

/* `iterations` Philox blocks a lane, rng_block_lanes(seed, 0, 0, 0, g·iterations + i, 0) in
 * iteration i; out[id] holds the XOR of every word each lane drew. */
__kernel void philox_throughput(const int iterations, const uint seed, __global lane_uints_t *out)
{
    size_t id = get_global_id(0);
    lane_uints_t first = GLOBAL_LANES(id) * (uint)iterations, seen = (lane_uints_t)0u;
    for (int i = 0; i < iterations; ++i) {
        lane_block_t block = rng_block_lanes(seed, 0u, 0u, 0u, first + (uint)i, 0u);
        seen ^= block.v[0] ^ block.v[1] ^ block.v[2] ^ block.v[3];
    }
    out[id] = seen;
}

/* `iterations` rounds of four independent divisions a lane, acc_k += (x + k) / d, then
 * d += step (one add each of overhead, and one a round): four chains, so the divider's
 * throughput binds, not an add's latency.  x = 1 + (g mod 16), d starts at 1 + (g mod 16)/2.
 * out[id] holds each lane's acc_0 + acc_1 + acc_2 + acc_3. */
__kernel void divide_throughput(const int iterations, const float step, __global lanes_t *out)
{
    size_t id = get_global_id(0);
    lanes_t lane = convert_lanes(GLOBAL_LANES(id) & 15u);
    lanes_t x = 1.0f + lane, d = 1.0f + 0.5f * lane, acc0 = (lanes_t)0.0f, acc1 = acc0, acc2 = acc0,
            acc3 = acc0;
    for (int i = 0; i < iterations; ++i) {
        acc0 += x / d;
        acc1 += (x + 1.0f) / d;
        acc2 += (x + 2.0f) / d;
        acc3 += (x + 3.0f) / d;
        d += step;
    }
    out[id] = (acc0 + acc1) + (acc2 + acc3);
}

/* `steps` gathers a lane from `table` (`mask` + 1 entries, a power of two), starting at lane
 * k's index start[POOL_LANES·id + k]; out[id] holds the XOR of every value each lane loaded. */
__kernel void lane_gathers(__global const uint *table, const uint mask, const int steps,
                           __global const uint *start, __global lane_uints_t *out)
{
    size_t id = get_global_id(0);
    lane_uints_t index = vload_lanes(id, start) & mask, seen = (lane_uints_t)0u;
    for (int s = 0; s < steps; ++s) {
        lane_uints_t value = GATHER(lane_uints_t, table, index);
        seen ^= value;
#if DEPENDENT
        index = value & mask;
#else
        index = (index * 1664525u + 1013904223u) & mask;   /* Numerical Recipes' LCG */
#endif
    }
    out[id] = seen;
}

/* `iterations` dependent additions total += (acc_t)x, then x *= shrink (a float multiply off the
 * chain).  out[id] holds the total. */
__kernel void serial_adds(const int iterations, const float shrink, __global acc_t *out)
{
    size_t id = get_global_id(0);
    float x = 1.0f + (float)(id & 1023) * 1e-3f;
    acc_t total = 0;
    for (int i = 0; i < iterations; ++i) {
        total += (acc_t)x;
        x *= shrink;
    }
    out[id] = total;
}

/* `steps` rounds of index = table[index] (work item id starts at id & mask), each ended by a
 * barrier: launched in groups of LOCKSTEP_GROUP (estimators/runtime/device_gbuffer.py), as a LOCKSTEP loop is.
 * out[id] holds the last index. */
__kernel void lockstep_steps(__global const uint *table, const uint mask, const int steps,
                             __global uint *out)
{
    size_t id = get_global_id(0);
    uint index = (uint)id & mask;
    for (int s = 0; s < steps; ++s) {
        index = table[index];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    out[id] = index;
}
