"""The limit probes of ``iblbench perf`` (``estimators/runtime/limit_probes.cl``): each runs
exactly the lane-operations it counts, shown by replaying its output in NumPy (a skipped or
folded operation changes the output), at both lane widths.  Nothing here is timed."""
from __future__ import annotations

import numpy as np
import pytest

from iblbench.estimators.runtime import philox, probes
from iblbench.estimators.runtime.device import Compute


@pytest.fixture(scope="module", params=(8, 16))
def lanes_compute(compute, request):
    return Compute(compute.info, lanes=request.param)


def global_lanes(items: int, lanes: int) -> np.ndarray:
    """limit_probes.cl's GLOBAL_LANES: g = lanes·item + k, ``[items, lanes]``."""
    return np.arange(items * lanes).reshape(items, lanes)


def test_phong_power_probe_sums_every_power_it_counts(lanes_compute):
    """Lane g sums c^m over c = c₀·shrink^j, j < iterations, c₀ = 0.25 + (g mod 64)/128: one
    power left out would move the sum by ≥ 1/iterations of it."""
    items, iterations, lanes = 24, 40, lanes_compute.pool_lanes
    out, times, powers = probes.run_phong_power(lanes_compute, items, iterations)
    assert powers == items * lanes * iterations and len(times) == 1
    start = 0.25 + (global_lanes(items, lanes) % 64) / 128.0
    c = start[:, :, None] * probes.PHONG_SHRINK ** np.arange(iterations)
    np.testing.assert_allclose(out, (c ** probes.PHONG_M).sum(axis=2), rtol=2e-4)


def test_philox_probe_draws_every_block_it_counts(lanes_compute):
    """The XOR of every word drawn equals philox.py's (the paper's round function), block by
    block: rng_block(seed, 0, 0, 0, g·iterations + i, 0) in lane g at iteration i."""
    items, iterations, lanes, seed = 6, 5, lanes_compute.pool_lanes, 0x1234
    out, _, blocks = probes.run_philox(lanes_compute, items, iterations, seed=seed)
    assert blocks == items * lanes * iterations
    sample = global_lanes(items, lanes)[:, :, None] * iterations + np.arange(iterations)
    words = philox.rng_block(seed, 0, 0, 0, sample, 0)
    expected = np.bitwise_xor.reduce(np.bitwise_xor.reduce(np.stack(words), axis=0), axis=2)
    np.testing.assert_array_equal(out, expected)


def test_divide_probe_sums_every_quotient_it_counts(lanes_compute):
    """acc_k += (x + k)/d for k < 4, d += step, x = 1 + (g mod 16), replayed in float32 in the
    kernel's order (each quotient correctly rounded): equal within a few roundings; 4 divisions
    a lane a round."""
    items, iterations, lanes = 3, 50, lanes_compute.pool_lanes
    out, _, divisions = probes.run_divide(lanes_compute, items, iterations)
    assert divisions == 4 * items * lanes * iterations
    lane = (global_lanes(items, lanes) % 16).astype(np.float32)
    x, d = np.float32(1) + lane, np.float32(1) + np.float32(0.5) * lane
    acc = np.zeros((4, items, lanes), np.float32)
    for _ in range(iterations):
        for k in range(4):
            acc[k] += (x + np.float32(k)) / d
        d += np.float32(probes.DIVIDE_STEP)
    np.testing.assert_allclose(out, (acc[0] + acc[1]) + (acc[2] + acc[3]), rtol=1e-6)


def test_chase_table_is_one_cycle_through_every_entry():
    table = probes.chase_table(1 << 10)
    seen, index = set(), 0
    for _ in range(len(table)):
        seen.add(index)
        index = int(table[index])
    assert index == 0 and len(seen) == len(table)
    with pytest.raises(ValueError):
        probes.chase_table(1000)
    assert probes.gather_entries(64) == 1 << 17 >= 6 * 64 * 64 * 4


@pytest.mark.parametrize("dependent", (True, False))
def test_gather_probe_loads_every_element_it_counts(lanes_compute, dependent):
    """The XOR of the values each lane loaded, replayed in NumPy: the chain index → table[index]
    (dependent), or the LCG's indices (independent)."""
    table = probes.chase_table(1 << 12, seed=5)
    items, steps, lanes = 8, 33, lanes_compute.pool_lanes
    out, start, _, loads = probes.run_gathers(lanes_compute, table, items, steps, dependent)
    assert loads == items * lanes * steps
    index, seen = start.astype(np.uint64) & (len(table) - 1), np.zeros_like(start)
    for _ in range(steps):
        value = table[index]
        seen ^= value
        index = (value.astype(np.uint64) if dependent
                 else index * 1664525 + 1013904223) & (len(table) - 1)
    np.testing.assert_array_equal(out, seen)


def test_serial_add_probe_adds_every_term_it_counts(lanes_compute):
    """total = Σ_i x_i in acc_t, x_{i+1} = x_i·shrink in float32, replayed in NumPy."""
    items, iterations = 5, 70
    out, _, adds = probes.run_serial_adds(lanes_compute, items, iterations)
    assert adds == items * iterations
    x = np.float32(1) + (np.arange(items) % 1024).astype(np.float32) * np.float32(1e-3)
    total = np.zeros(items, out.dtype)
    for _ in range(iterations):
        total += x.astype(out.dtype)
        x = x * np.float32(probes.PHONG_SHRINK)
    np.testing.assert_allclose(out, total, rtol=1e-6)


def test_lockstep_probe_takes_every_step_it_counts(lanes_compute):
    """Each work item's index after `steps` rounds of index = table[index] from id & mask."""
    table = probes.chase_table(1 << 8, seed=2)
    items, steps = 2 * probes.LOCKSTEP_GROUP, 11
    out, _, taken = probes.run_lockstep_steps(lanes_compute, table, items, steps)
    assert taken == items * steps
    index = np.arange(items) & (len(table) - 1)
    for _ in range(steps):
        index = table[index]
    np.testing.assert_array_equal(out, index)


def test_limit_outputs_are_the_same_at_either_lane_width(compute):
    """What the portability set compares across devices does not depend on POOL_LANES."""
    narrow, wide = (probes.limit_outputs(Compute(compute.info, lanes=lanes)) for lanes in (8, 16))
    assert narrow.keys() == wide.keys() == set(probes.PROBE_FLOPS)
    for name in narrow:
        np.testing.assert_allclose(narrow[name], wide[name], rtol=1e-6, err_msg=name)
