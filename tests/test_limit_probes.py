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


def test_phong_power_probe_sums_every_power_it_counts(lanes_compute):
    """Lane k of item i sums c^m over c = c₀·shrink^j, j < iterations, c₀ = 0.5 + k/(2L) −
    (i mod 1024)·1e-6: one power left out would move the sum by ≥ 1/iterations of it."""
    items, iterations, lanes = 24, 40, lanes_compute.pool_lanes
    out, times, powers = probes.run_phong_power(lanes_compute, items, iterations)
    assert powers == items * lanes * iterations and len(times) == 1
    start = (np.float32(0.5) + np.arange(lanes, dtype=np.float32) * np.float32(0.5 / lanes))[None, :] \
        - (np.arange(items) % 1024).astype(np.float32)[:, None] * np.float32(1e-6)
    c = start.astype(np.float64)[:, :, None] * probes.PHONG_SHRINK ** np.arange(iterations)
    np.testing.assert_allclose(out, (c ** probes.PHONG_M).sum(axis=2), rtol=2e-4)


def test_philox_probe_draws_every_block_it_counts(lanes_compute):
    """The XOR of every word drawn equals philox.py's (the paper's round function), block by
    block: rng_block(seed, 0, 0, item, i·L + k, 0) in lane k of iteration i."""
    items, iterations, lanes, seed = 6, 5, lanes_compute.pool_lanes, 0x1234
    out, _, blocks = probes.run_philox(lanes_compute, items, iterations, seed=seed)
    assert blocks == items * lanes * iterations
    item = np.arange(items)[:, None, None]
    sample = (np.arange(iterations)[None, :, None] * lanes + np.arange(lanes)[None, None, :])
    words = philox.rng_block(seed, 0, 0, item, sample, 0)
    expected = np.bitwise_xor.reduce(np.bitwise_xor.reduce(np.stack(words), axis=0), axis=1)
    np.testing.assert_array_equal(out, expected)


def test_divide_probe_sums_every_quotient_it_counts(lanes_compute):
    """acc_k += (x + k)/d for k < 4, d += step, replayed in float32 in the kernel's order (each
    quotient correctly rounded): equal within a few roundings; 4 divisions a lane a round."""
    items, iterations, lanes = 3, 50, lanes_compute.pool_lanes
    out, _, divisions = probes.run_divide(lanes_compute, items, iterations)
    assert divisions == 4 * items * lanes * iterations
    x = np.float32(1) + np.arange(lanes, dtype=np.float32)
    d = np.float32(1) + np.float32(0.5) * np.arange(lanes, dtype=np.float32)
    acc = np.zeros((4, lanes), np.float32)
    for _ in range(iterations):
        for k in range(4):
            acc[k] += (x + np.float32(k)) / d
        d += np.float32(probes.DIVIDE_STEP)
    expected = (acc[0] + acc[1]) + (acc[2] + acc[3])
    np.testing.assert_allclose(out, np.broadcast_to(expected, out.shape), rtol=1e-6)


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
