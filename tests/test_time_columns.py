"""Each time column of a real run equals the sum of the profiled OpenCL events of the stages it
names (harness/protocol/timing.py), counted here from the events themselves.

Every kernel launch and copy of a small run is logged as it is enqueued (pyopencl's
``enqueue_nd_range_kernel`` and ``enqueue_copy`` wrapped), with the phase it ran in: the frame
cache's build, or one estimator render.  The stage of each event follows from its kernel name
(``STAGE_OF_KERNEL``; an unknown kernel fails the test, so a new kernel must be given a stage),
and each row's columns are then worked out from the events alone:

- ``time_ms_build``: the frame's map upload plus the build kernels of the products the
  estimator requires (the CDF kernels for ``requires`` with ``cdf``), plus build events of the
  render itself;
- ``time_ms_sample`` / ``time_ms_shade``: the render's events of that stage (NaN when it has
  none), median over the cell's timed renders; a light pool's draw counts in the ``sample`` of
  every render that uses the pool, wherever it was drawn (a pool is drawn once per size and
  seed: ``balanced_mis`` reuses ``uniform``'s);
- ``time_ms``: median over the timed renders of build + every stage event of the render.

Read-backs (device → host) and host-side work are no stage.  ``havran`` is left out: its
``sample`` stage holds host time (its lights are placed on the host), not device events.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.registry import get_estimator_class
from iblbench.harness.protocol import executor
from iblbench.harness.protocol.runner import RunConfig, run

ESTIMATORS = ("uniform", "balanced_mis", "bis", "smc")
# Build kernels of each frame-cache product (the upload is the host → device copy of the map).
BUILD_KERNELS = {"cdf": {"row_cdfs", "weight_cdfs"}}
POOL_KERNEL = "build_light_pool"      # counted per use of its pool (module docstring)
STAGE_OF_KERNEL = {
    "pool_planes": "sample", "brdf_numbers": "sample", "map_alias_pairs": "sample",
    "map_alias_columns": "sample", "map_change": "sample",
    "render_light_pool": "shade", "render_bis": "shade", "smc_advance": "shade",
    "smc_init": "shade",
}
NOT_A_STAGE = {"copy:device-to-host", "copy:host-to-device"}


@dataclasses.dataclass
class Logged:
    phase: object     # "build", or the index of the render in EventLog.renders
    name: str         # kernel name or copy direction
    event: cl.Event

    @property
    def ms(self) -> float:
        return (self.event.profile.end - self.event.profile.start) * 1e-6


class EventLog:
    """The events of a run, by phase; ``timed``: per timed group of renders (a cell), the
    estimator's name and the indices of its renders."""

    def __init__(self):
        self.phase = None
        self.events: list[Logged] = []
        self.renders: list[str] = []
        self.timed: list[tuple[str, list[int]]] = []
        self.in_timed_group = False
        self.pool_uses: list[tuple[object, float]] = []   # (phase, its pool's draw ms)
        self.pool_draws: dict[tuple, float] = {}          # pool key → its draw's device ms

    def enqueued(self, name: str, event):
        if event is not None:
            self.events.append(Logged(self.phase, name, event))
        return event

    def of(self, phase) -> list[Logged]:
        return [logged for logged in self.events if logged.phase == phase]


def _is_buffer(x) -> bool:
    return isinstance(x, cl.MemoryObjectHolder)


@pytest.fixture
def event_log(monkeypatch):
    log = EventLog()
    launch, copy = cl.enqueue_nd_range_kernel, cl.enqueue_copy

    def logged_launch(queue, kernel, *args, **kwargs):
        return log.enqueued(kernel.function_name, launch(queue, kernel, *args, **kwargs))

    def logged_copy(queue, dest, src, **kwargs):
        direction = ("device-to-device" if _is_buffer(dest) and _is_buffer(src) else
                     "host-to-device" if _is_buffer(dest) else "device-to-host")
        return log.enqueued(f"copy:{direction}", copy(queue, dest, src, **kwargs))

    monkeypatch.setattr(cl, "enqueue_nd_range_kernel", logged_launch)
    monkeypatch.setattr(cl, "enqueue_copy", logged_copy)

    class LoggedCache(executor.FrameCache):
        def __init__(self, *args, **kwargs):
            log.phase, previous = "build", log.phase
            super().__init__(*args, **kwargs)
            log.phase = previous

        def require(self, products):
            log.phase, previous = "build", log.phase
            super().require(products)
            log.phase = previous

        def light_pool(self, per_face, seed, compensated=False):
            key, first = (id(self), per_face, seed, compensated), len(log.events)
            pool = super().light_pool(per_face, seed, compensated)
            drawn = [logged.ms for logged in log.events[first:] if logged.name == POOL_KERNEL]
            if drawn:
                log.pool_draws[key] = sum(drawn)
            # The draw this use reads: a pool evicted (POOLS_KEPT) and drawn again is another.
            log.pool_uses.append((log.phase, log.pool_draws[key]))
            return pool

    monkeypatch.setattr(executor, "FrameCache", LoggedCache)
    for name in ESTIMATORS:
        cls = get_estimator_class(name)

        def render(self, gbuffer, cache, spp, seed, _render=cls.render, _name=name):
            index, previous = len(log.renders), log.phase
            log.renders.append(_name)
            if log.in_timed_group:
                log.timed[-1][1].append(index)
            log.phase = index
            try:
                return _render(self, gbuffer, cache, spp, seed)
            finally:
                log.phase = previous

        monkeypatch.setattr(cls, "render", render)
    timed_renders = executor.timed_renders

    def logged_timed_renders(renderers, *args, **kwargs):
        log.timed.append((type(renderers[0]).name, []))
        log.in_timed_group = True
        try:
            return timed_renders(renderers, *args, **kwargs)
        finally:
            log.in_timed_group = False

    monkeypatch.setattr(executor, "timed_renders", logged_timed_renders)
    return log


def _stage_sums(log: EventLog, render: int) -> dict[str, float]:
    sums: dict[str, float] = {}
    for _, draw_ms in filter(lambda use: use[0] == render, log.pool_uses):
        sums["sample"] = sums.get("sample", 0.0) + draw_ms
    for logged in log.of(render):
        if logged.name in NOT_A_STAGE or logged.name == POOL_KERNEL:
            continue
        assert logged.name in STAGE_OF_KERNEL, f"kernel {logged.name} has no stage in this test"
        stage = STAGE_OF_KERNEL[logged.name]
        sums[stage] = sums.get(stage, 0.0) + logged.ms
    return sums


def _build_ms(log: EventLog, requires) -> float:
    kernels = set().union(*(BUILD_KERNELS.get(product, set()) for product in requires))
    known = set().union(*BUILD_KERNELS.values()) | {"copy:host-to-device", "copy:device-to-host"}
    total = 0.0
    for logged in log.of("build"):
        assert logged.name in known, f"build kernel {logged.name} belongs to no product here"
        if logged.name == "copy:host-to-device" or logged.name in kernels:
            total += logged.ms
    return total


def test_time_columns_are_the_sums_of_their_stages_events(tmp_path, event_log):
    config = RunConfig(out=tmp_path, scenes=("sphere-sun",), estimators=ESTIMATORS, spp=(8,),
                       seeds=1, resolution=(16, 16), env_res=8, progress=False,
                       metrics=("de76",), repeats=3)
    table = run(config)
    cells = {}   # a cell's timed renders, one a round (one cell per estimator here)
    for name, renders in event_log.timed:
        cells.setdefault(name, []).extend(renders)
    assert sorted(cells) == sorted(ESTIMATORS)
    assert any(logged.name in BUILD_KERNELS["cdf"] for logged in event_log.of("build"))
    for name, renders in cells.items():
        row = table[table.estimator == name].iloc[0]
        assert row.time_repeats == len(renders) >= 3
        build = _build_ms(event_log, get_estimator_class(name).requires)
        stages = [_stage_sums(event_log, render) for render in renders]
        expected = {
            "time_ms_build": np.median([build + s.get("build", 0.0) for s in stages]),
            "time_ms": np.median([build + sum(s.values()) for s in stages]),
        }
        for stage in ("sample", "shade"):
            values = [s[stage] for s in stages if stage in s]
            expected[f"time_ms_{stage}"] = np.median(values) if values else math.nan
        for column, value in expected.items():
            if math.isnan(value):
                assert math.isnan(row[column]), f"{name}: {column} = {row[column]}, has no events"
            else:
                assert row[column] == pytest.approx(value, rel=1e-6, abs=1e-9), \
                    f"{name}: {column} = {row[column]:.6g} ms, its events sum to {value:.6g} ms"
