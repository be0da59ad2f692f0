"""The device probes: the FMA-throughput and copy-bandwidth kernels of ``probes.cl`` and their
launchers.  ``iblbench perf`` builds the device's roofline from them
(:mod:`iblbench.harness.studies.perf`), the timing floor launches the FMA kernel back to back
(:func:`iblbench.harness.protocol.timing.measure_timing_floor`), and :class:`CopyProbe` measures
the copy bandwidth beside each timed CDF build.

``fma_throughput`` runs ``FMA_CHAINS`` independent FMA chains per work item, each a vector of
:func:`fma_width` lanes (the device's preferred float width, ``-DFMA_WIDTH``), two FLOPs per
step; ``copy_bandwidth`` reads one float4 and writes one per work item."""
from __future__ import annotations

import functools
import math

import numpy as np

from iblbench.estimators.runtime.device import event_ms
from iblbench.estimators.runtime.device_gbuffer import LOCKSTEP_GROUP

FMA_CHAINS = 8                 # probes.cl's fma_throughput: chains of fma_width(compute) lanes
FMA_ITEMS = 1 << 17
COPY_MIN_BYTES = 64 << 20      # each copy buffer: at least this, and 8× the device's cache
FLOOR_MS = 3.0                 # the timing floor's launches: about a render's device time


def fma_width(compute) -> int:
    """Lanes of each FMA chain: the device's preferred float vector width (1, 2, 4, 8 or 16)."""
    width = int(compute.info.device.preferred_vector_width_float)
    return max(w for w in (1, 2, 4, 8, 16) if w <= max(width, 1))


def _probe_kernel(compute, name: str, width: int | None = None):
    return compute.kernel("iblbench.estimators.runtime", "probes.cl", name,
                          {"FMA_WIDTH": width or fma_width(compute)})


def _launches(compute, kernel, items: int, args, launches: int, group: int | None = None) -> list[float]:
    """Device ms of ``launches`` launches (in groups of ``group``; None: the device's choice)
    after an untimed one (first touch of the buffers' pages, kernel compilation)."""
    compute.run(kernel, items, *args, group=group)
    return [event_ms(compute.run(kernel, items, *args, group=group)) for _ in range(launches)]


def run_fma(compute, items: int, iterations: int, launches: int = 1, b: float = 0.999,
            c: float = 1e-3, width: int | None = None):
    """``launches`` timed launches of ``fma_throughput`` with chains of ``width`` lanes (None:
    :func:`fma_width`): (the outputs ``[items, FMA_CHAINS, width]``, device ms of each launch,
    FLOPs per launch)."""
    lanes = width or fma_width(compute)
    shape = (items, FMA_CHAINS, lanes)
    out = compute.empty(4 * math.prod(shape))
    args = (np.int32(iterations), np.float32(b), np.float32(c), out)
    times = _launches(compute, _probe_kernel(compute, "fma_throughput", lanes), items, args, launches)
    flops = 2 * lanes * FMA_CHAINS * iterations * items
    return compute.to_host(out, shape, np.float32), times, flops


def run_copy(compute, source: np.ndarray, launches: int = 1):
    """``launches`` timed launches of ``copy_bandwidth`` on ``source`` (float32, a multiple of 4
    values): (the copy read back, device ms of each launch, bytes moved = read + written)."""
    source = np.ascontiguousarray(source, np.float32)
    if source.size % 4:
        raise ValueError("the copy kernel moves float4s: give a multiple of 4 values")
    args = (compute.to_device(source), compute.empty(source.nbytes))
    times = _launches(compute, _probe_kernel(compute, "copy_bandwidth"), source.size // 4, args,
                      launches)
    return compute.to_host(args[1], source.shape, np.float32), times, 2 * source.nbytes


def copy_size(compute) -> int:
    """Bytes per copy buffer: ≥ COPY_MIN_BYTES and 8× the device's global-memory cache, within
    its largest allocation."""
    device = compute.info.device
    wanted = max(COPY_MIN_BYTES, 8 * int(device.global_mem_cache_size))
    return int(min(wanted, device.max_mem_alloc_size // 2, 1 << 30)) // 16 * 16


def fma_iterations(compute, items: int, min_ms: float) -> int:
    """Iterations (a power of two) for an ``fma_throughput`` launch of ``items`` to take ≥
    ``min_ms``."""
    iterations = 16
    while True:
        ms = run_fma(compute, items, iterations)[1][0]
        if ms >= min_ms or iterations >= 1 << 16:
            return iterations
        iterations *= 2 if ms > 0 else 16


@functools.lru_cache(maxsize=None)
def _floor_iterations(compute) -> int:
    """The floor kernel's size on ``compute``, found once per process (a run measures twice)."""
    return fma_iterations(compute, FMA_ITEMS // 8, FLOOR_MS)


def floor_launches(compute, launches: int) -> list[float]:
    """Device ms of ``launches`` back-to-back launches of ``fma_throughput`` sized to take ≥
    FLOOR_MS (the timing floor's kernel)."""
    return run_fma(compute, FMA_ITEMS // 8, _floor_iterations(compute), launches)[1]


class CopyProbe:
    """One timed ``copy_bandwidth`` launch on resident buffers of ``copy_size`` bytes each: the
    copy bandwidth now (GB/s, read + written), measured beside each timed CDF build."""

    def __init__(self, compute):
        self.compute = compute
        self.items = copy_size(compute) // 16
        self.buffers = (compute.empty(16 * self.items), compute.empty(16 * self.items))
        self.kernel = _probe_kernel(compute, "copy_bandwidth")
        compute.run(self.kernel, self.items, *self.buffers)   # first touch of the pages

    def gbps(self) -> float:
        ms = event_ms(self.compute.run(self.kernel, self.items, *self.buffers))
        return 32 * self.items / (ms * 1e6)


# ---- the other limits (limit_probes.cl): per lane-operation rates -------------------------------

# Each limit probe's operation and its FLOPs by perf's counting rules (its docstring), which a
# bound that times the operation by its probe must not count again at the FMA rate.
PROBE_FLOPS = {
    "phong_power": 35,      # phong_power_lanes: log2 half 16, exp2 half 19
    "philox": 0,            # rng_block_lanes: integer work
    "divide": 1,            # a division or a square root (both on the divider)
    "gather": 0,            # one GATHER element, independent
    "dependent_load": 0,    # one GATHER element whose index the previous load gave
    "serial_add": 1,        # one acc_t addition of a scalar chain
    "lockstep": 0,          # one work item's step of a search between LOCKSTEP barriers
}
LIMIT_MIN_MS = 10.0            # each limit probe's launch is sized to take at least this
LIMIT_ITEMS = 1 << 12          # work items of a limit probe's launch (POOL_LANES lanes each)
PHONG_M = 37.0                 # the lobe power's exponent (its cost does not depend on it)
PHONG_SHRINK = 0.9999


def _limit_kernel(compute, name: str, dependent: bool = False):
    return compute.kernel("iblbench.estimators.runtime", "limit_probes.cl", name,
                          {"DEPENDENT": int(dependent)})


def _run_lanes(compute, name: str, items: int, args: tuple, launches: int, dtype=np.float32,
               dependent: bool = False):
    """``launches`` timed launches of the limit probe ``name``, which writes one value a lane
    after ``args``: (the outputs ``[items, pool_lanes]`` of ``dtype``, device ms of each launch)."""
    out = compute.empty(4 * items * compute.pool_lanes)
    times = _launches(compute, _limit_kernel(compute, name, dependent), items, (*args, out), launches)
    return compute.to_host(out, (items, compute.pool_lanes), dtype), times


def run_phong_power(compute, items: int, iterations: int, launches: int = 1):
    """``launches`` timed launches of ``phong_power_throughput``: (each lane's sum of its
    ``iterations`` powers ``[items, pool_lanes]``, device ms of each launch, lane-powers per
    launch)."""
    out, times = _run_lanes(compute, "phong_power_throughput", items,
                            (np.int32(iterations), np.float32(PHONG_M), np.float32(PHONG_SHRINK)), launches)
    return out, times, items * compute.pool_lanes * iterations


def run_philox(compute, items: int, iterations: int, launches: int = 1, seed: int = 0x1234):
    """``launches`` timed launches of ``philox_throughput``: (the XOR of each lane's words
    ``[items, pool_lanes]``, device ms of each launch, lane-blocks per launch).  Lane g =
    pool_lanes·item + k draws rng_block(seed, 0, 0, 0, g·iterations + i, 0), i < iterations."""
    out, times = _run_lanes(compute, "philox_throughput", items, (np.int32(iterations), np.uint32(seed)),
                            launches, np.uint32)
    return out, times, items * compute.pool_lanes * iterations


DIVIDE_STEP = 0.25


def run_divide(compute, items: int, iterations: int, launches: int = 1):
    """``launches`` timed launches of ``divide_throughput``: (each lane's sum of its four
    chains ``[items, pool_lanes]``, device ms of each launch, lane-divisions per launch)."""
    out, times = _run_lanes(compute, "divide_throughput", items, (np.int32(iterations), np.float32(DIVIDE_STEP)),
                            launches)
    return out, times, 4 * items * compute.pool_lanes * iterations


def run_serial_adds(compute, items: int, iterations: int, launches: int = 1):
    """``launches`` timed launches of ``serial_adds``: (each item's total ``[items]``, in the
    kernels' acc_t, device ms of each launch, additions per launch)."""
    dtype = np.float64 if compute.doubles else np.float32
    out = compute.empty(np.dtype(dtype).itemsize * items)
    args = (np.int32(iterations), np.float32(PHONG_SHRINK), out)
    times = _launches(compute, _limit_kernel(compute, "serial_adds"), items, args, launches)
    return compute.to_host(out, (items,), dtype), times, items * iterations


def run_lockstep_steps(compute, table: np.ndarray, items: int, steps: int, launches: int = 1):
    """``launches`` timed launches of ``lockstep_steps`` on ``table`` in groups of
    LOCKSTEP_GROUP (``items`` a multiple of it): (each item's last index ``[items]``, device ms
    of each launch, work-item steps per launch)."""
    out = compute.empty(4 * items)
    args = (compute.to_device(np.ascontiguousarray(table, np.uint32)), np.uint32(len(table) - 1),
            np.int32(steps), out)
    times = _launches(compute, _limit_kernel(compute, "lockstep_steps"), items, args, launches,
                      LOCKSTEP_GROUP)
    return compute.to_host(out, (items,), np.uint32), times, items * steps


def chase_table(entries: int, seed: int = 0) -> np.ndarray:
    """``entries`` (a power of two) uint32: a random cyclic permutation, so that index →
    table[index] visits every entry once in a random order (the dependent chain's table)."""
    if entries & (entries - 1):
        raise ValueError(f"a gather table's entries must be a power of two, got {entries}")
    order = np.random.default_rng(seed).permutation(entries).astype(np.uint32)
    table = np.empty(entries, np.uint32)
    table[order] = np.roll(order, -1)
    return table


def run_gathers(compute, table: np.ndarray, items: int, steps: int, dependent: bool,
                launches: int = 1, seed: int = 1):
    """``launches`` timed launches of ``lane_gathers`` on ``table`` (uint32, a power-of-two
    size): (the XOR of each lane's loaded values ``[items, pool_lanes]``, the start indices,
    device ms of each launch, lane-gathers per launch)."""
    lanes = compute.pool_lanes
    start = np.random.default_rng(seed).integers(0, len(table), items * lanes, dtype=np.uint32)
    args = (compute.to_device(np.ascontiguousarray(table, np.uint32)), np.uint32(len(table) - 1),
            np.int32(steps), compute.to_device(start))
    out, times = _run_lanes(compute, "lane_gathers", items, args, launches, np.uint32, dependent)
    return out, start.reshape(items, lanes), times, items * lanes * steps


def gather_entries(env_res: int) -> int:
    """The gather probes' table size: the power of two ≥ the cube map's floats, 6·R²·4 (the
    texels the estimators gather from; their CDF words, pyramid and alias tables are as large)."""
    return 1 << max(10, (6 * env_res * env_res * 4 - 1).bit_length())


def sized(run, min_ms: float) -> int:
    """The power-of-two count (of iterations or steps) for which ``run(count)`` (device ms)
    takes ≥ ``min_ms``."""
    count = 16
    while True:
        ms = run(count)
        if ms >= min_ms or count >= 1 << 20:
            return count
        count *= 2 if ms > min_ms / 64 else 16


def limit_outputs(compute, lanes_total: int = 32) -> dict[str, np.ndarray]:
    """Small runs of every limit probe over ``lanes_total`` lanes (a multiple of 16), their
    outputs by probe, flat: the same at either lane width (the portability set's ``probes``
    case runs them on Oclgrind and compares them across devices)."""
    table, items = chase_table(1 << 8), lanes_total // compute.pool_lanes
    return {name: np.ravel(out) for name, out in {
        "phong_power": run_phong_power(compute, items, 3)[0],
        "philox": run_philox(compute, items, 2)[0],
        "divide": run_divide(compute, items, 3)[0],
        "gather": run_gathers(compute, table, items, 3, False)[0],
        "dependent_load": run_gathers(compute, table, items, 3, True)[0],
        "serial_add": run_serial_adds(compute, 2, 3)[0],
        "lockstep": run_lockstep_steps(compute, table, LOCKSTEP_GROUP, 2)[0]}.items()}
