"""common.cl's phong_power (the Phong lobe's c^m, a polynomial 2^(m·log2 c)) against NumPy float64
pow on a dense grid, with the error bound its comment states: relative 2e-5 wherever c^m ≥ 2^-120,
absolute 2^-120 below; exact at m = 0 and c = 1, zero at c = 0, finite for m up to 1e6."""
import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.runtime.device import include_dirs

POWER_KERNEL = """
#include "common.cl"
__kernel void power(__global const float *c, __global const float *m, __global float *out)
{
    int i = get_global_id(0);
    out[i] = phong_power(c[i], m[i]);
}
"""
RELATIVE_BOUND = 2e-5
FLOOR = 2.0 ** -120


def _bases():
    """Float32 c in [0, 1]: a dense uniform grid, the floats just under 1 (where m·log2 c is
    tiny), and tiny and denormal values down to the smallest float."""
    uniform = np.linspace(0, 1, 4001)
    near_one = 1 - np.arange(1, 200) * 2.0 ** -24
    tiny = np.geomspace(1e-45, 1e-3, 400)
    return np.unique(np.concatenate([uniform, near_one, tiny, [0.0, 1.0]]).astype(np.float32))


def _exponents():
    """Float32 m: 0, the Phong range [0, 1e4] (linear and logarithmic), the sampling exponents
    1/(m+1) in (0, 1], and the stress battery's cap 1e6."""
    return np.unique(np.concatenate([
        [0.0, 0.5, 1.0, 2.0, 1e6, 3e5], np.linspace(0, 1e4, 101), np.geomspace(1e-4, 1e4, 120),
        1 / (np.geomspace(1, 1e6, 30) + 1)]).astype(np.float32))


@pytest.fixture(scope="module")
def powers(compute):
    c, m = (a.ravel() for a in np.meshgrid(_bases(), _exponents(), indexing="ij"))
    program = cl.Program(compute.context, POWER_KERNEL).build(options=[f"-I{d}" for d in include_dirs()])
    out = compute.empty(4 * len(c))
    program.power(compute.queue, (len(c),), None, compute.to_device(c), compute.to_device(m), out)
    return c, m, compute.to_host(out, (len(c),), np.float32).astype(np.float64)


def test_phong_power_within_stated_bound(powers):
    c, m, got = powers
    expected = np.where(c > 0, np.power(c.astype(np.float64), m.astype(np.float64)), 0.0)
    assert np.all(np.isfinite(got))
    large = expected >= FLOOR
    relative = np.abs(got[large] - expected[large]) / expected[large]
    assert relative.max() <= RELATIVE_BOUND, (c[large][relative.argmax()], m[large][relative.argmax()])
    assert np.abs(got[~large] - expected[~large]).max() <= FLOOR


def test_phong_power_exact_cases(powers):
    c, m, got = powers
    assert np.all(got[(m == 0) & (c > 0)] == 1.0)     # c^0 = 1 above the lobe's horizon
    assert np.all(got[c == 1] == 1.0)
    assert np.all(got[c == 0] == 0.0)                  # the lobe is zero at and below it
    assert np.all((got >= 0) & (got <= 1))
