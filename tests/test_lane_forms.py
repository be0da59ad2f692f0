"""common.cl's 16-lane forms (the pool estimators' explicit-vector sample loops) against its scalar
forms on the same inputs: Philox blocks bit-identical to random123's philox4x32 (rng_block), and
phong_power, the Phong sampling direction (direction_about_axis) and the cube-map face lookup
(cube_face_st) identical to float rounding (the same operations, lane by lane)."""
import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.runtime.device import include_dirs

LANES_KERNEL = """
#include "common.cl"
/* Work item g: lanes 16g … 16g+15 through the 16-lane forms (out_lanes) and the scalar ones
 * (out_scalar); 8 outputs per lane: Philox words 0..3 (as float bits), power, direction x, y, z;
 * then face, s, t in out_face. */
__kernel void lanes(__global const float *c, __global const float *m, __global const float4 *axis,
                    __global const float *cos_theta, __global const float *u, __global uint *words_lanes,
                    __global uint *words_scalar, __global float *out_lanes, __global float *out_scalar)
{
    int g = get_global_id(0), k0 = 16 * g;
    uint16 sample = (uint16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15) + (uint)k0;
    rng_block16_t block = rng_block16(0x1234u, 7u, 5u, (uint)g, sample, 3u);
    float16 power = phong_power16(vload16(g, c), vload16(g, m));
    float16 ax, ay, az;
    for (int k = 0; k < 16; ++k) {
        ax[k] = axis[k0 + k].x;
        ay[k] = axis[k0 + k].y;
        az[k] = axis[k0 + k].z;
    }
    vec3x16_t w = direction_about_axis16(vec3x16(ax, ay, az), vload16(g, cos_theta), vload16(g, u));
    float16 s, t;
    int16 face = cube_face_st16(w, &s, &t);
    for (int k = 0; k < 16; ++k) {
        int i = k0 + k;
        philox4x32_ctr_t r = rng_block(0x1234u, 7u, 5u, (uint)g, (uint)i, 3u);
        for (int j = 0; j < 4; ++j) {
            words_lanes[4 * i + j] = block.v[j][k];
            words_scalar[4 * i + j] = r.v[j];
        }
        vec3_t ws = direction_about_axis(vec3(ax[k], ay[k], az[k]), cos_theta[i], u[i]);
        float ss, ts;
        int fs = cube_face_st(ws, &ss, &ts);
        float lane[7] = {power[k], w.x[k], w.y[k], w.z[k], (float)face[k], s[k], t[k]};
        float scalar[7] = {phong_power(c[i], m[i]), ws.x, ws.y, ws.z, (float)fs, ss, ts};
        for (int j = 0; j < 7; ++j) {
            out_lanes[7 * i + j] = lane[j];
            out_scalar[7 * i + j] = scalar[j];
        }
    }
}
"""


@pytest.fixture(scope="module")
def results(compute):
    rng = np.random.default_rng(10)
    n = 16 * 256
    c = rng.random(n).astype(np.float32)
    m = np.where(rng.random(n) < 0.5, rng.random(n) * 200, 1 / (1 + rng.random(n) * 1e4)).astype(np.float32)
    axis = rng.normal(size=(n, 4)).astype(np.float32)
    axis[:, :3] /= np.linalg.norm(axis[:, :3], axis=1, keepdims=True)
    axis[:8, :3] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0], [0, -1, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1]]
    cos_theta, u = rng.random(n).astype(np.float32), rng.random(n).astype(np.float32)
    u[:4] = [0.0, 0.125, 0.25, 0.999]
    program = cl.Program(compute.context, LANES_KERNEL).build(options=[f"-I{d}" for d in include_dirs()])
    buffers = [compute.empty(16 * n) for _ in range(2)] + [compute.empty(28 * n) for _ in range(2)]
    program.lanes(compute.queue, (n // 16,), None, *(compute.to_device(a) for a in (c, m, axis, cos_theta, u)),
                  *buffers)
    words = [compute.to_host(b, (n, 4), np.uint32) for b in buffers[:2]]
    values = [compute.to_host(b, (n, 7), np.float32) for b in buffers[2:]]
    return words, values


def test_philox_lanes_are_random123_blocks(results):
    (lanes, scalar), _ = results
    np.testing.assert_array_equal(lanes, scalar)
    assert len(np.unique(lanes)) > 0.99 * lanes.size   # not a constant stream


def test_power_direction_and_face_lanes_match_scalar(results):
    _, (lanes, scalar) = results
    np.testing.assert_array_equal(lanes[:, 0], scalar[:, 0])        # phong_power: the same body
    np.testing.assert_allclose(lanes[:, 1:4], scalar[:, 1:4], rtol=0, atol=2e-7)
    np.testing.assert_allclose(np.linalg.norm(lanes[:, 1:4], axis=1), 1, atol=1e-6)
    same_face = lanes[:, 4] == scalar[:, 4]
    assert same_face.mean() > 0.999                                 # ties only where w differs by rounding
    np.testing.assert_allclose(lanes[same_face, 5:], scalar[same_face, 5:], rtol=0, atol=1e-6)
