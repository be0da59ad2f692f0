"""The cube-map conventions of ARCHITECTURE.md §Conventions, in Python and in OpenCL's common.cl."""
import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.runtime.device import include_dirs
from iblbench.scenes import cubemap

MAPPING_KERNEL = """
#include "common.cl"
__kernel void map_dirs(__global const float4 *dirs, const int res, __global int4 *texel,
                       __global float4 *back)
{
    int i = get_global_id(0);
    float s, t;
    int face = dir_to_face_st(dirs[i].xyz, &s, &t);
    texel[i] = (int4)(face, clamp_index(t, res), clamp_index(s, res), 0);
    back[i] = (float4)(normalize(face_uv_to_dir(face, 2.0f * s - 1.0f, 2.0f * t - 1.0f)), 0.0f);
}
"""


@pytest.mark.parametrize("res", [1, 3, 64, 1024])
def test_solid_angles_sum_to_four_pi(res):
    assert abs(6 * cubemap.texel_solid_angles(res).sum() - 4 * np.pi) < 1e-5


def test_solid_angle_matches_area_over_cubed_distance():
    # A small texel at the face centre subtends ≈ its area (distance 1, facing the origin).
    res = 1001
    omega = cubemap.texel_solid_angles(res)[res // 2, res // 2]
    assert omega == pytest.approx((2 / res) ** 2, rel=1e-5)


def test_opengl_face_table():
    # Spot checks of the OpenGL table: the major axis picks the face, (sc, tc) the position.
    cases = {(1, 0, 0): (0, 0.5, 0.5), (-1, 0, 0): (1, 0.5, 0.5), (0, 1, 0): (2, 0.5, 0.5),
             (0, -1, 0): (3, 0.5, 0.5), (0, 0, 1): (4, 0.5, 0.5), (0, 0, -1): (5, 0.5, 0.5),
             (1, -0.5, -0.5): (0, 0.75, 0.75),   # +X: sc = -z, tc = -y
             (0.5, 1, 0.5): (2, 0.75, 0.75),     # +Y: sc = +x, tc = +z
             (0.5, -0.5, 1): (4, 0.75, 0.75)}    # +Z: sc = +x, tc = -y
    for direction, expected in cases.items():
        face, s, t = cubemap.direction_to_face_st(np.array(direction, float))
        assert (int(face), float(s), float(t)) == pytest.approx(expected)


def _hard_directions(rng, n):
    """Random directions plus face edges, cube corners and exact axis ties."""
    random = rng.normal(size=(n, 3))
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    edges = []
    for axis in range(3):
        e = rng.uniform(-1, 1, size=(n // 10, 3))
        e[:, axis] = np.sign(e[:, axis]) * 1.0
        e[:, (axis + 1) % 3] = np.sign(e[:, (axis + 1) % 3]) * 1.0   # |a| == |b|: a tie on an edge
        edges.append(e)
    near_edges = np.concatenate(edges) * (1 + rng.uniform(-1e-4, 1e-4, size=(3 * (n // 10), 3)))
    return np.concatenate([random, signs, np.eye(3), -np.eye(3), np.concatenate(edges), near_edges])


def test_python_and_opencl_mappings_agree(compute):
    rng = np.random.default_rng(7)
    res = 64
    dirs = _hard_directions(rng, 20000).astype(np.float32)
    padded = np.zeros((len(dirs), 4), np.float32)
    padded[:, :3] = dirs
    prg = cl.Program(compute.context, MAPPING_KERNEL).build(
        options=[f"-I{d}" for d in include_dirs()])
    texel = cl.Buffer(compute.context, cl.mem_flags.WRITE_ONLY, 16 * len(dirs))
    back = cl.Buffer(compute.context, cl.mem_flags.WRITE_ONLY, 16 * len(dirs))
    prg.map_dirs(compute.queue, (len(dirs),), None, compute.to_device(padded), np.int32(res),
                 texel, back)
    cl_texel = compute.to_host(texel, (len(dirs), 4), np.int32)[:, :3]
    cl_back = compute.to_host(back, (len(dirs), 4), np.float32)[:, :3]

    face, row, col = cubemap.direction_to_texel(dirs.astype(np.float64), res)
    py_texel = np.stack([face, row, col], axis=1)
    # float32 vs float64 may round a direction within 1e-6 of a texel border differently;
    # such cases must land in an adjacent texel of the same face, never elsewhere.
    differ = np.any(cl_texel != py_texel, axis=1)
    assert differ.mean() < 1e-3
    assert np.all(cl_texel[differ, 0] == py_texel[differ, 0])
    assert np.abs(cl_texel[differ, 1:] - py_texel[differ, 1:]).max(initial=0) <= 1
    # Exact ties (|x| == |y| etc.) are decided identically: first of x, y, z wins.
    ties = np.all(np.abs(np.abs(dirs[:, :, None]) - np.abs(dirs[:, None, :])).reshape(-1, 9)[:, [1, 2, 5]]
                  .min(axis=1, keepdims=True) == 0, axis=1)
    assert ties.sum() > 100 and np.all(cl_texel[ties, 0] == py_texel[ties, 0])
    # (face, s, t) -> direction inverts the mapping in both implementations.
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    assert np.abs(cl_back - unit).max() < 1e-5
    _, s, t = cubemap.direction_to_face_st(dirs.astype(np.float64))
    assert np.abs(cubemap.face_st_to_direction(face, s, t) - unit).max() < 1e-6


def test_texel_directions_map_back_to_their_texel():
    res = 16
    face, row, col = cubemap.direction_to_texel(cubemap.texel_directions(res), res)
    f, r, c = np.meshgrid(np.arange(6), np.arange(res), np.arange(res), indexing="ij")
    assert np.array_equal(face, f) and np.array_equal(row, r) and np.array_equal(col, c)
