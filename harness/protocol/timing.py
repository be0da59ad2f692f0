"""The one definition of a cell's time (ARCHITECTURE.md §Timing convention), shared by the runner, equal-time
calibration, the terminal summary, ``iblbench check``, the report and ``reproduce``.

**A render's time** is the device time of the stages its estimator needs for one frame, from
OpenCL profiling events (:func:`device_ms`):

- ``build``: the frame-cache products the estimator requires (the map upload, the CDFs; built
  once per frame, so the one build's time counts in each render of the frame), 0 on a frame
  that reused an identical earlier frame's cache, plus a ``build`` stage the estimate reports
  itself, if any;
- ``sample``: the estimate's ``sample`` stage (e.g. a light pool's draw);
- ``shade``: the estimate's ``shade`` stage.

Any other stage an estimate reports counts in the total only.  A stage an estimator does not
have (``bis`` and ``smc`` report no ``sample``) is NaN in its column and 0 in the total.  Kernel
compilation is never in it: PoCL compiles a new work-group size between an event's *queued* and
*start* stamps (measured: 80-130 ms there, the start-to-end time unchanged), and a profiled
stage runs from start to end.

**A cell's time** (one results row) is over ``repeats`` timed renders after warm-up
(:func:`time_columns`): ``time_ms`` is the median of their device times, ``time_ms_min`` the
minimum, ``time_ms_iqr`` the interquartile range (NumPy's linear quantiles), ``time_ms_build``,
``time_ms_sample`` and ``time_ms_shade`` the medians of each stage (so they need not add up to
``time_ms``), ``time_ms_host`` the median host wall time of the render calls (read-back
included, builds excluded; never used to rank estimators) and ``time_repeats`` the number of
renders.  How the runner gets those renders without disturbing a temporal estimator's state is
in :mod:`iblbench.harness.protocol.runner`.

**Rounds** (issue 32).  A frame's cells render in interleaved rounds: round r renders render r
of every cell of the frame, in an order of its own (seeded), then round r + 1
(:meth:`iblbench.harness.protocol.executor.Executor._run_frame`).  So a cell's renders lie a
whole round apart, and fall in different spells of the device (below), not in one: its time
samples the machine's slow and fast spells as every other cell's does, and two cells that take
the same time get the same times, whichever spell either would have started in.  Measured on
the A/A simulation (:mod:`iblbench.harness.verify.timing_noise`: an estimator and its unchanged
copy, timed on the spells recorded on this machine, ranked by the real ranking): with each
cell's renders back to back, the copy was called apart in 5 of 120 verdicts idle and 35 of 120
beside two busy processes; in rounds, 2 and 4 of 120.  A round's renders run back to back and
are scored after it: with each render scored before the next one, 603 of the default sweep's
1,188 cells spread wider than 15% on an idle machine, with the scores after the round 247.
Each round's own order: with one fixed order (the control last in every round) a real A/A
run called the copy apart in 40 of 119 verdicts, shuffled in 1 of 120: a place in the round
(the first render after the scores, say) has a cost of its own.  The
rounds replace the earlier rule that gave a cell whose back-to-back renders spread wider than
15% more renders (``SPREAD_LIMIT`` now only counts such cells, ``timing.spread.wide_cells``):
it made a cell's renders agree within one spell, which is what the A/A check showed wrong.

**Which statistic** (:func:`robust_ms`).  A cell's time is the median of its renders.  On the
same simulation, 40 runs × 3 budgets each, idle and busy, each statistic both the cell's time
and its bootstrap's: the median called the copy apart in 2 and 4 of 120 verdicts, and resolved
an estimator with 12% less error at equal time in 94 and 72 of 120; the 25% quantile 1 and 3 of
120, with 45 and 66 resolved; the minimum (Chen and Revels 2016, BenchmarkTools.jl) 7 and 16 of
120, above the stated 5%: the bootstrap of an extreme value is not a valid interval, and one
lucky render moves it.  So the median: the A/A rate held and the best power here.

**Why a repeat is one render, not a batch.**  timeit's and asv's "autorange" (a repeat is a
batch of back-to-back renders lasting at least some 10-25 ms, its value the batch's time per
render) would average over the device's fast and slow spells if those were shorter than a batch.
On this VM they are not: in 400-600 renders back to back in one process (load 0.6-1.3) the
device time sits at one level for tens to hundreds of renders (sphere-sun ``balanced`` 256 spp,
128²: 5.7 ms for 40 renders, then 3.9-4.0 ms for 40, 4.6 ms for over 100, with 3.3 ms spells
between; the same with one seed over and over, so it is not the light pools' allocation), so
a batch only stretches the five repeats over more of them.  Groups of 5 consecutive repeats with
IQR/median ≤ 15%, by renders per repeat 1/2/4/8/16: sphere-sun ``uniform`` 16 spp (1.5 ms)
98/97/95/89/90%, ``balanced`` 256 spp 84/82/70/67/76%, blob-sun ``balanced_mis`` 64 spp
61/48/47/48/52%, sphere-backlit ``envmap`` 64 spp (18 ms) 89/87/82/76/67%.  In the runner
(``iblbench run --config default``, 108 cells, single renders against repeats of ≥ 20 ms
batches, alternated processes, 4 pairs at load 4-8): 87/57/59/54% of the cells had their first
5 repeats within 15% with single renders, 50/54/50/51% with batches; the batches took 1.8x the
device time in the least loaded pair (17.3 against 9.6 s), about as much as single renders with
their extension in the others.  So a repeat stays a single render (since issue 32 each in a
round of its own, "Rounds" above).

**Context.**  The device is the CPU (PoCL) shared with the host, so a render's device time
depends on what host threads do while it runs.  The host's own work (scoring, image writes)
runs on the calling thread between renders, never beside them (it waits on the events without
spinning: 1.5 ms of CPU for a 100 ms render); the one host thread that ran beside them was
OpenBLAS's worker, which spins ~0.1 s after a NumPy matrix product (host scoring) and takes a
core from PoCL's two workers.  So a run holds :func:`host_threads_capped` (BLAS and OpenMP
pools at one thread, threadpoolctl) around everything it renders, warm-up and calibration
included, and a round's renders (and a calibration's) run back to back in
:func:`timed_renders`, with no pause before them and their scores after them.  PoCL's worker
threads are not pinned
(the manifest records ``POCL_AFFINITY``): pinned one per core (``POCL_AFFINITY=1``), the median
render fell from 5.5-8.5 to 3.8-4.1 ms (sphere-sun, balanced, 256 spp) and from 4.3-5.3 to
2.9-3.4 ms (blob-sun, uniform, 256 spp) at load 6 (3 interleaved pairs of processes, 60
renders each), but at load 16-19 one warm default run pinned had 33% of its cells within 15%
against 65% for one unpinned: a pinned thread cannot leave a busy core.  Measured on 2 cores
shared with other jobs (load 8-12), interleaved in rounds, one process:

- the first render after a 200k×3 NumPy product (blob-sun, uniform, 256 spp, 20 rounds): 20.3 ms
  median with BLAS's two threads, 5.2 ms with one, 6.7 ms with no product before it;
- groups of 5 renders after a cell's scoring and image writes (25 rounds; blob-sun uniform 256
  spp, sphere-sun balanced_mis 64 spp): IQR/median ≤ 15% in 48% and 44% of the groups with
  BLAS at one thread and no pause, 52% and 24% with two threads and the 150 ms pause this
  replaces, 24% and 36% with neither; medians 5.44 / 6.94 ms, 5.64 / 7.49 ms, 6.73 / 7.55 ms.

The pause cost 0.15 s of wall time per cell: 8 s of a 12.7 s warm default run with 0.95 s of
device time (idle machine).  What remains is the platform's: on the idle machine, renders back
to back in one process with no host work between them are bimodal (balanced, 256 spp, 128²:
2.9 and 4.1 ms in runs of ~8 renders), and 57-80% of a warm default run's 54 cells have
IQR/median ≤ 15% (5 runs; an ``os.sync()`` before each group changed nothing: 63% against 65%).

**The device's own floor.**  How repeatable a cell's renders can be depends on how repeatable
the device is.  So a run measures the device at its start and end
(:func:`measure_timing_floor`; the manifest's ``timing.floor``, printed
at the end of the run): a fixed kernel of multiply-adds (no memory traffic, even work in many
groups) of about a render's length, launched back to back, and the share of its groups of 5
launches with IQR/median ≤ 15% (:func:`groups_within`).  It is a snapshot of a fraction of a
second at either end, so it tells a steady device from a disturbed one rather than bounding
each cell.  On this 2-vCPU VM (Firecracker, idle guest, 2026-12-02) it moved between 0% and
100% from one minute to the next (p90/p10 1.02-2.5), while warm default runs kept 75-87% of
their cells' first 5 renders within 15%.  The cause is the machine, not PoCL: two host threads
of fixed NumPy work, started and joined per repeat, gave 51-75% of groups within 15% (p90/p10
1.6-2.0); one thread doing the same gave 97-100%, pinned to either vCPU 100% (p90/p10
1.13-1.16).  Pinning PoCL's threads (``POCL_AFFINITY=1``) moved a warm default run within the
same range (75-87% against 80-83%), as did 20 ms of multiply-adds on both cores before each
cell.

**Over several rows** (frames × seeds of one (scene, estimator, spp) or equal-time cell), the
time is the median of every timed render of the cell (``time_ms_renders``, each render's device
time), with a distribution-free 95% interval from order statistics
(:func:`iblbench.harness.protocol.stats.median_ci`, through
:func:`~iblbench.harness.protocol.stats.cell_intervals`: :func:`cell_times`, :func:`one_cell_time`,
``check``'s time ratios too), not from the spread over seeds of per-seed medians: the renders
are the cell's own draws of its time (issue 23).
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import time

import numpy as np
import psutil
import threadpoolctl

from iblbench.harness.protocol.stats import RENDERS, TIME_COLUMN, cell_intervals, renders_text

STAGES = ("build", "sample", "shade")
TIME = TIME_COLUMN
SPREAD_LIMIT = 0.15   # IQR/median a cell's timed renders should stay within
MEASURE = ("device time per frame of the stages the estimator needs: build + sample + shade "
           "(OpenCL profiling events), ms")


@dataclasses.dataclass(frozen=True)
class TimedRender:
    """One render's stages (device ms, ``build`` included) and its host wall time."""

    stages: dict[str, float]
    host_ms: float


def render_stages(build_ms: float, timings_ms: dict[str, float]) -> dict[str, float]:
    """A render's stages: the estimate's ``timings_ms`` with the frame's build added to
    ``build``."""
    stages = dict(timings_ms)
    stages["build"] = build_ms + stages.get("build", 0.0)
    return stages


def host_threads_capped():
    """A context in which NumPy's BLAS and any OpenMP pool run on the calling thread alone, so
    no host thread spins beside a render (module docstring, "Context")."""
    return threadpoolctl.threadpool_limits(limits=1)


ROUND_ORDER_SEED = 0x5EED


def round_orders(*key: int):
    """The rounds' orders: each call of the returned function with n gives the next round's
    permutation of range(n), the same sequence in every run for the same ``key`` (``run``'s
    rounds per frame, ``perf``'s), so that a place in the round (the first after the previous
    round's host work, say) costs no cell more than another."""
    return np.random.default_rng([ROUND_ORDER_SEED, *key]).permutation


QUIET_WINDOW_S = 0.02   # wait_for_quiet_threads' window
QUIET_SHARE = 0.1       # of one core: below it over a window, the process's threads are quiet
QUIET_LONGEST_S = 1.0   # it waits no longer


def wait_for_quiet_threads() -> float:
    """Waits until this process's threads use under QUIET_SHARE of a core over a QUIET_WINDOW_S
    window, at most QUIET_LONGEST_S; returns the seconds waited.  A host library's worker pool
    spins on after its work: OpenBLAS's about 0.1 s after a matrix product, Dr.Jit's after the
    Mitsuba peer's render (``iblbench perf``), where the next render, on the same cores, ran
    1.2-1.3× slower (sphere-sun, 256², issue 37)."""
    start = time.perf_counter()
    while time.perf_counter() - start < QUIET_LONGEST_S:
        cpu, wall = time.process_time(), time.perf_counter()
        time.sleep(QUIET_WINDOW_S)
        if time.process_time() - cpu < QUIET_SHARE * (time.perf_counter() - wall):
            break
    return time.perf_counter() - start


def timed_renders(renderers, gbuffer, cache, spp: int, seeds, build_ms: float) -> list[tuple]:
    """(estimate, TimedRender) of one render per (renderer, seed), back to back (module
    docstring, "Context"; callers hold :func:`host_threads_capped`)."""
    out = []
    for renderer, seed in zip(renderers, seeds, strict=True):
        start = time.perf_counter()
        estimate = renderer.render(gbuffer, cache, spp, seed)
        host_ms = (time.perf_counter() - start) * 1e3
        out.append((estimate, TimedRender(render_stages(build_ms, estimate.timings_ms), host_ms)))
    return out


def required_build_ms(timings_ms: dict[str, float], requires) -> float:
    """Device ms of the per-frame FrameCache products an estimator requires (the map upload and
    its ``requires``), from the cache's ``timings_ms``; the light pool is not a build: it is drawn
    per render and timed as the render's ``sample`` stage."""
    return float(sum(timings_ms.get(p, 0.0) for p in ("upload", *requires) if p != "pool"))


def spread(values) -> tuple[float, float, float]:
    """(median, min, IQR) of repeated timings (NumPy's linear quantiles), over the finite ones;
    NaNs where none is finite."""
    values = np.asarray([v for v in values if math.isfinite(v)], np.float64)
    if not len(values):
        return math.nan, math.nan, math.nan
    q25, q75 = np.percentile(values, [25, 75])
    return float(np.median(values)), float(values.min()), float(q75 - q25)


def groups_within(values, size: int = 5) -> float:
    """The share of consecutive groups of ``size`` timings (a trailing part left out) whose
    IQR/median is within ``SPREAD_LIMIT``: how often ``size`` repeats in a row would pass it.
    NaN for fewer than ``size`` values."""
    values = list(values)
    groups = [values[i:i + size] for i in range(0, len(values) - size + 1, size)]
    return float(np.mean([not _spread_too_wide(g) for g in groups])) if groups else math.nan


def _spread_too_wide(values) -> bool:
    """Whether timings spread wider than ``SPREAD_LIMIT``: IQR/median (:func:`spread`)."""
    median, _, iqr = spread(values)
    return iqr > SPREAD_LIMIT * median


def too_wide(renders: list[TimedRender]) -> bool:
    """Whether the device times of ``renders`` spread wider than ``SPREAD_LIMIT``: IQR/median."""
    return _spread_too_wide(device_ms(r.stages) for r in renders)


def device_ms(stages: dict[str, float]) -> float:
    """A render's device time: the sum of its stages (missing or non-finite ones count 0)."""
    return float(sum(v for v in stages.values() if math.isfinite(v)))


def time_columns(renders: list[TimedRender]) -> dict:
    """The results row's time columns of one cell from its timed renders (module docstring)."""
    if not renders:
        raise ValueError("a cell needs at least one timed render")
    times = [device_ms(r.stages) for r in renders]
    median, low, iqr = spread(times)
    columns = {"time_ms": median, "time_ms_min": low, "time_ms_iqr": iqr}
    for stage in STAGES:
        values = [r.stages[stage] for r in renders if stage in r.stages]
        columns[f"time_ms_{stage}"] = float(np.median(values)) if values else math.nan
    columns["time_ms_host"] = float(np.median([r.host_ms for r in renders]))
    columns["time_repeats"] = len(renders)
    columns[TIME + RENDERS] = renders_text(times)
    return columns


def robust_ms(values, axis=None):
    """The robust time of timed renders spread over rounds: their median, along ``axis``
    (module docstring, "Which statistic")."""
    return np.median(np.asarray(values, np.float64), axis=axis)


def one_cell_time(rows, column: str = TIME) -> float:
    """The time of one cell from its rows (frames × seeds, a DataFrame with a ``seed`` column):
    as :func:`cell_times` aggregates (NaN if any row is NaN: fail closed)."""
    return float(cell_intervals(rows.assign(cell=0), ["cell"], [column])[column].iloc[0])


def cell_times(table, keys, column: str = TIME):
    """The time of each cell of ``table`` grouped by ``keys``: the mean over seeds of each
    seed's mean ``column`` over its frames (a pandas Series indexed by ``keys``; the interval is
    in :func:`iblbench.harness.protocol.stats.cell_intervals`)."""
    return cell_intervals(table, keys, [column])[column]


# ---- what else ran on the host ------------------------------------------------------------------

def cpu_snapshot() -> tuple[float, float, float]:
    """(wall s, CPU s the whole host has spent busy, CPU s this process and its children have
    spent: its threads, PoCL's, and a LocalCluster's worker processes), for
    :func:`others_cores`."""
    host, me = psutil.cpu_times(), psutil.Process()
    # guest time is in user time already (Linux); iowait is idle
    busy = (sum(host) - host.idle - getattr(host, "iowait", 0.0) - getattr(host, "guest", 0.0)
            - getattr(host, "guest_nice", 0.0))
    own = me.cpu_times()
    spent = own.user + own.system + own.children_user + own.children_system
    for child in me.children(recursive=True):
        with contextlib.suppress(psutil.Error):   # it may end while we look
            times = child.cpu_times()
            spent += times.user + times.system
    return time.perf_counter(), busy, spent


def others_cores(start: tuple, end: tuple) -> float:
    """The cores' worth of CPU that other programs (and, on a VM, other guests: steal time)
    used between two :func:`cpu_snapshot`: the host's busy CPU time less this process tree's,
    over the wall time.  A 1-minute load average lags a run of seconds by a minute; this does
    not."""
    wall = end[0] - start[0]
    if wall <= 0:
        return math.nan
    return max(0.0, ((end[1] - start[1]) - (end[2] - start[2])) / wall)


# ---- the device's own floor (the kernel: estimators/runtime/probes.py) ---------------------------

FLOOR_LAUNCHES = 40            # back to back: 8 groups of 5
FLOOR_POOR = 0.5               # a floor with fewer groups within SPREAD_LIMIT is said on stderr


@dataclasses.dataclass(frozen=True)
class TimingFloor:
    """How repeatable the device's own timings are now ("The device's own floor", above)."""

    launches: int           # timed launches, back to back
    median_ms: float        # their median device ms
    groups_within: float    # share of consecutive groups of 5 with IQR/median ≤ SPREAD_LIMIT
    p90_over_p10: float     # the spread of all launches

    def text(self) -> str:
        return (f"{self.groups_within:.0%} of groups of 5 within {SPREAD_LIMIT:.0%} "
                f"(p90/p10 {self.p90_over_p10:.2f})")

    @property
    def poor(self) -> bool:
        """Fewer than FLOOR_POOR of its groups of 5 within SPREAD_LIMIT: the terminal says so."""
        return self.groups_within < FLOOR_POOR


def timing_floor_text(floors: list[TimingFloor]) -> str:
    """The floor measured at a run's start and end, as the terminal and perf.html say it."""
    return " at the start, ".join(f.text() for f in floors) + " at the end"


def measure_timing_floor(compute, launches: int = FLOOR_LAUNCHES) -> TimingFloor:
    """``launches`` back-to-back launches of ``fma_throughput`` sized to take ≥ FLOOR_MS: a
    kernel with no memory traffic and even work in many groups, so their spread is the
    device's (and the machine's), not a kernel's."""
    from iblbench.estimators.runtime.probes import floor_launches

    times = floor_launches(compute, launches)
    p10, p90 = np.percentile(times, [10, 90])
    return TimingFloor(launches=launches, median_ms=float(np.median(times)),
                       groups_within=groups_within(times), p90_over_p10=float(p90 / p10))
