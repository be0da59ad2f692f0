"""One definition of a cell's time (harness/protocol/timing.py) in the runner, equal-time calibration, the
terminal summary, ``check`` and the report.

Fake estimators report known stage times, so every time column can be checked against values
worked out by hand; the frame's build is made known by a FrameCache whose upload time is set.
"""
from __future__ import annotations

import dataclasses
import itertools
import json
import math

import numpy as np
import pandas as pd
import pytest
import threadpoolctl
import trimesh

from iblbench.estimators.base import Estimate, Estimator, Tags
from iblbench.estimators.registry import _registry, register
from iblbench.harness.protocol import budgets
from iblbench.commands import run as run_command
from iblbench.harness.protocol import executor, timing
from iblbench.harness.protocol.equal_time import CALIBRATION_SEED, TOLERANCE, Calibration
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.harness.protocol.executor import WARMUP_PIXELS, WARMUP_SEED
from iblbench.harness.protocol.run_plan import TIMING_SEED
from iblbench.harness.protocol.runner import RunConfig, run
from iblbench.harness.protocol.sweep import DEFAULT_REPEATS
from iblbench.harness.protocol.timing import FLOOR_POOR, TimedRender, TimingFloor, time_columns
from iblbench.reports.tables import equal_time_cells, summarize
from iblbench.scenes.imageio import read_exr

BUILD = 0.5                                               # upload ms of every frame's build
STAGES = [(2.0, 10.0), (1.0, 30.0), (4.0, 20.0), (3.0, 50.0), (5.0, 40.0)]   # (sample, shade)


def fake_estimate(gbuffer, spp, value, timings) -> Estimate:
    shape = gbuffer.shape
    return Estimate(np.full(shape + (3,), value, np.float32), np.full(shape, spp, np.float32),
                    np.full(shape, spp, np.float32), float(spp), 0, dict(timings))


class Scripted(Estimator):
    """Render k of an instance reports ``STAGES[k]`` (the warm-up runs on its own instance)."""

    name = "scripted_timing_test"
    tags = Tags(unbiased=False)
    log: list = []   # (seed, spp, pixels) of every render

    def __init__(self, params=None, **overrides):
        super().__init__(params, **overrides)
        self.renders = 0

    def render(self, gbuffer, cache, spp, seed):
        self.log.append((seed, spp, gbuffer.count))
        sample, shade = STAGES[self.renders % len(STAGES)]
        self.renders += 1
        return fake_estimate(gbuffer, spp, 0.5, {"sample": sample, "shade": shade})


class Linear(Estimator):
    """A device cost of 0.7 + 0.013·spp^POWER ms (shade), known exactly."""

    name = "linear_timing_test"
    tags = Tags(unbiased=False)
    POWER = 1.0

    def render(self, gbuffer, cache, spp, seed):
        return fake_estimate(gbuffer, spp, 0.5, {"shade": 0.7 + 0.013 * spp ** self.POWER})


class CellContext(Linear):
    """Linear's cost, ``SLOWDOWN`` times it on the seeds of cells and their timing renders (not
    on calibration seeds): cells rendered in another context than their calibration.  Temporal,
    and its image is the number of frames rendered since ``reset()``, so a scored image shows
    whether its instance rendered anything else first."""

    name = "cell_context_timing_test"
    tags = Tags(unbiased=False, temporal=True)
    SLOWDOWN = 1.3

    def __init__(self, params=None, **overrides):
        super().__init__(params, **overrides)
        self.frames = 0

    def reset(self):
        self.frames = 0

    def render(self, gbuffer, cache, spp, seed):
        self.frames += 1
        estimate = super().render(gbuffer, cache, spp, seed)
        estimate.radiance[:] = self.frames
        if seed < CALIBRATION_SEED:
            estimate.timings_ms["shade"] *= self.SLOWDOWN
        return estimate


class BlasProbe(Linear):
    """Linear, logging the BLAS threads NumPy may use during each render."""

    name = "blas_probe_timing_test"
    log: list = []

    def render(self, gbuffer, cache, spp, seed):
        self.log.append({pool["num_threads"] for pool in threadpoolctl.threadpool_info()
                         if pool["user_api"] == "blas"})
        return super().render(gbuffer, cache, spp, seed)


class Counting(Estimator):
    """Temporal: its image is the number of frames this instance has rendered, so a scored
    image shows whether anything else rendered on the scored instance."""

    name = "counting_timing_test"
    tags = Tags(unbiased=False, temporal=True)
    log: list = []
    made = itertools.count()   # serial numbers: id() is reused once an instance is freed

    def __init__(self, params=None, **overrides):
        super().__init__(params, **overrides)
        self.serial = next(self.made)
        self.frames = 0

    def reset(self):
        self.frames = 0

    def render(self, gbuffer, cache, spp, seed):
        self.frames += 1
        self.log.append((self.serial, cache.frame, seed))
        return fake_estimate(gbuffer, spp, float(self.frames), {"shade": 1.0})


@pytest.fixture
def fakes():
    for cls in (Scripted, Linear, CellContext, BlasProbe, Counting):
        register(cls)
    Counting.log.clear()
    Scripted.log.clear()
    BlasProbe.log.clear()
    yield
    for cls in (Scripted, Linear, CellContext, BlasProbe, Counting):
        _registry.pop(cls.name)


@pytest.fixture
def known_builds(monkeypatch):
    """Every frame's build reports BUILD as its upload time (and nothing else)."""
    class KnownBuild(FrameCache):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.timings_ms = {"upload": BUILD}

    monkeypatch.setattr(executor, "FrameCache", KnownBuild)


def tiny(out, estimators, **overrides) -> RunConfig:
    config = dict(out=out, scenes=("sphere-sun",), estimators=estimators, spp=(4,), seeds=1,
                  resolution=(16, 16), env_res=8, progress=False, metrics=("de76",))
    return RunConfig(**(config | overrides))


def test_time_columns_are_median_min_and_iqr_of_the_stage_events(tmp_path, fakes, known_builds,
                                                                  capsys):
    row = run(tiny(tmp_path, ("scripted_timing_test",))).iloc[0]
    # Render k: the frame's build (0.5) + sample + shade → 12.5, 31.5, 24.5, 53.5, 45.5 ms:
    # IQR/median 21/31.5 is above 15%, and the cell keeps its 5 renders (no more on a spread).
    assert row.time_repeats == 5 and row.time_ms_host > 0
    assert row.time_ms == pytest.approx(31.5)                  # the middle of five
    assert row.time_ms_min == pytest.approx(12.5)
    assert row.time_ms_iqr == pytest.approx(45.5 - 24.5)       # linear quartiles: 2nd, 4th
    assert row.time_ms_build == pytest.approx(BUILD)           # median of each stage on its own
    assert row.time_ms_sample == pytest.approx(3.0)
    assert row.time_ms_shade == pytest.approx(30.0)
    assert math.isnan(row.flip) and math.isnan(row.mean_delta_e2000) and row.metrics == "de76"
    # The warm-up rendered 1 spp on a few pixels, never the whole frame; then the full renders.
    warm_up = [entry for entry in Scripted.log if entry[0] == WARMUP_SEED]
    pixels = Scripted.log[-1][2]
    assert warm_up == [(WARMUP_SEED, 1, WARMUP_PIXELS)] and pixels > WARMUP_PIXELS
    assert [entry[1:] for entry in Scripted.log if entry[0] != WARMUP_SEED] == [(4, pixels)] * 5
    assert "1 of 1 cells' renders spread wider than 15%" in capsys.readouterr().err
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["timing"]["spread"] | {"rule": ""} == {"rule": "", "cells": 1,
                                                          "wide_cells": 1}


def test_a_frames_cells_render_in_interleaved_rounds(tmp_path, fakes, known_builds, capsys):
    """Issue 32: render r of every cell of a frame, then render r + 1 (render 0 on the cell's
    seed, render r on its timing seed r), so each cell's renders lie a round apart instead of
    back to back in one spell of the device; each round in an order of its own, so that no
    cell always takes the round's first place."""
    table = run(tiny(tmp_path, ("scripted_timing_test",), seeds=6, repeats=3))
    seeds = [entry[0] for entry in Scripted.log if entry[0] != WARMUP_SEED]
    rounds = [seeds[6 * r:6 * r + 6] for r in range(3)]
    assert sorted(rounds[0]) == list(range(6))
    for r in (1, 2):
        assert sorted(rounds[r]) == sorted(executor.timing_seed(s, r) for s in range(6))
    order = [[seed if r == 0 else (seed - TIMING_SEED) // 256 for seed in rounds[r]]
             for r in range(3)]
    assert len({tuple(o) for o in order}) > 1
    # One Scripted instance renders every cell of the frame: its stage times go round STAGES
    # in render order, and each row holds the ones its renders took.
    times = sorted(float(t) for row in table.itertuples() for t in row.time_ms_renders.split())
    assert times == sorted([12.5, 31.5, 24.5, 53.5, 45.5] * 3 + [12.5, 31.5, 24.5])
    err = capsys.readouterr().err
    # The device's own floor, measured at the run's start and end, is in the manifest; the
    # terminal says it only where it was poor (issue 23: two lines of jargon on every run).
    record = json.loads((tmp_path / "manifest.json").read_text())["timing"]
    poor = min(record["floor"]["groups_within"]) < FLOOR_POOR
    assert ("not repeatable" in err) == poor and err.count("groups of 5 within 15%") == 2 * poor
    assert len(record["floor"]["groups_within"]) == 2
    assert all(0 <= share <= 1 for share in record["floor"]["groups_within"])
    assert all(ratio >= 1 for ratio in record["floor"]["p90_over_p10"])


def test_groups_within_counts_consecutive_groups_of_five_by_iqr_over_median():
    steady = [10.0] * 5                  # IQR 0
    edge = [10.0, 10.0, 10.0, 11.5, 11.5]   # quartiles 10 and 11.5: IQR 1.5 = 15% of 10, within
    split = [10.0, 10.0, 20.0, 20.0, 20.0]  # quartiles 10 and 20 over the median 20: 50%
    assert timing.groups_within(steady + edge + split + [99.0]) == pytest.approx(2 / 3)
    assert timing.groups_within(split + steady, size=5) == pytest.approx(1 / 2)
    assert math.isnan(timing.groups_within([1.0, 2.0, 3.0]))


def test_the_timing_floor_times_fixed_launches_of_the_fma_kernel():
    from iblbench.estimators.runtime import probes
    from iblbench.estimators.runtime.device import get_compute

    floor = timing.measure_timing_floor(get_compute(), launches=10)
    iterations = probes._floor_iterations(get_compute())
    assert iterations >= 16 and iterations & (iterations - 1) == 0   # sized by doubling
    assert floor.launches == 10 and floor.median_ms > 0
    assert floor.groups_within in (0.0, 0.5, 1.0)   # two groups of five
    assert floor.p90_over_p10 >= 1.0


def test_stages_an_estimator_lacks_are_nan_and_count_zero():
    renders = [TimedRender({"build": 1.0, "shade": 2.0}, 5.0),
               TimedRender({"build": 1.0, "shade": 4.0, "other": 1.0}, 7.0)]
    columns = time_columns(renders)
    assert math.isnan(columns["time_ms_sample"])
    assert columns["time_ms"] == pytest.approx((3.0 + 6.0) / 2)   # "other" counts in the total
    assert columns["time_ms_host"] == pytest.approx(6.0) and columns["time_repeats"] == 2


def sequence_scene(tmp_path, frames=3) -> str:
    (tmp_path / "seq").mkdir()
    for index in range(frames):
        np.save(tmp_path / "seq" / f"f{index}.npy", np.full((6, 4, 4, 3), 0.5 + index, np.float32))
    trimesh.creation.icosphere(1).export(tmp_path / "ball.obj")
    scene = tmp_path / "seq.toml"
    scene.write_text('[mesh]\npath = "ball.obj"\n[environment]\npath = "seq/*.npy"\n'
                     '[camera]\neye = [0, 0, 3]\ntarget = [0, 0, 0]\n')
    return str(scene)


def test_timing_repeats_leave_a_temporal_estimators_scored_state_alone(tmp_path, fakes):
    out = tmp_path / "out"
    table = run(tiny(out, ("counting_timing_test",), scenes=(sequence_scene(tmp_path),),
                     seeds=2, resolution=(12, 12), env_res=None, repeats=3))
    assert len(table) == 3 * 2 and (table.time_repeats == 3).all()
    for row in table.itertuples():
        # The scored instance rendered frames 0..t once each: its state saw no timing render.
        image = read_exr(out / "images" / "seq" / f"f{row.frame}" / f"{row.estimator}_spp4_s{row.seed}.exr")
        assert image.max() == row.frame + 1
    by_instance = {}
    for instance, frame, seed in Counting.log:
        by_instance.setdefault(instance, []).append((frame, seed))
    sequences = [renders for renders in by_instance.values() if len(renders) > 1]
    # Per cell seed: the scored instance and two twins, each rendering every frame once, in order.
    assert len(sequences) == 2 * 3
    for renders in sequences:
        assert [frame for frame, _ in renders] == [0, 1, 2] and len({s for _, s in renders}) == 1
    seeds = sorted(renders[0][1] for renders in sequences)
    assert seeds[:2] == [0, 1] and all(TIMING_SEED <= s < 0xFFFFFF00 for s in seeds[2:])


@pytest.mark.parametrize("power", [1.0, 1.3])
def test_calibration_lands_within_tolerance_on_a_known_cost(power, monkeypatch):
    monkeypatch.setattr(Linear, "POWER", power)

    class Pixels:
        shape = (2, 2)

    calibration = Calibration(Linear(), Pixels(), None, build_ms=0.2)
    for budget in (5.0, 20.0, 80.0):
        fit = calibration.choose(budget)
        cost = 0.2 + 0.7 + 0.013 * fit["chosen_spp"] ** power
        assert abs(cost - budget) <= TOLERANCE * budget, (budget, fit)
        assert fit["measured_ms"] == pytest.approx(cost) and not fit["over_budget"]
    fit = calibration.choose(0.5)           # the build and one sample already take 0.913 ms
    assert fit["chosen_spp"] == 1 and fit["over_budget"]


def test_calibration_never_chooses_past_the_estimators_spp_bound(monkeypatch):
    """Issue 23: bis and smc got a bound (4096 spp); an equal-time cell whose budget affords
    more takes the bound, and measures nothing past it."""
    monkeypatch.setattr(Linear, "max_spp", 100, raising=False)

    class Pixels:
        shape = (2, 2)

    calibration = Calibration(Linear(), Pixels(), None, build_ms=0.2)
    fit = calibration.choose(80.0)          # 0.9 + 0.013·spp: about 6,000 spp fit
    assert fit["chosen_spp"] == 100 and max(run["spp"] for run in fit["runs"]) <= 100


def test_budget_cells_report_their_achieved_device_time(tmp_path, fakes, known_builds, capsys):
    out = tmp_path / "out"
    table = run(tiny(out, ("linear_timing_test",), spp=(), time_budget_ms=(0.5, 20.0)))
    err = capsys.readouterr().err
    achieved = {e["budget_ms"]: e for e in
                json.loads((out / "manifest.json").read_text())["time_budget"]["achieved"]}
    met = table[table.time_budget_ms == 20.0].iloc[0]
    assert abs(met.time_ms - 20.0) <= 2.0 and achieved[20.0]["within_tolerance"]
    assert achieved[0.5]["spp"] == 1 and not achieved[0.5]["within_tolerance"]
    assert "even 1 spp takes" in err and "outside ±10%" in err
    cells = equal_time_cells(table).set_index("time_budget_ms")
    assert cells.loc[0.5, "time_ms"] == pytest.approx(achieved[0.5]["time_ms"])
    assert not cells.loc[0.5, "within"] and cells.loc[20.0, "within"]


def test_a_budgets_first_cell_corrects_the_spp_on_its_own_time(tmp_path, fakes, known_builds):
    """Cells cost 1.3x their calibration renders at the same spp (another context): the
    calibrated spp lands 1.3x over the budget, so the first cell is rendered again at a
    corrected spp, from reset(), and every cell of the budget runs that spp."""
    out = tmp_path / "out"
    table = run(tiny(out, ("cell_context_timing_test",), scenes=(sequence_scene(tmp_path, 2),),
                     env_res=None, spp=(), seeds=2, time_budget_ms=(20.0,)))
    assert len(table) == 2 * 2 and table.spp.nunique() == 1
    for row in table.itertuples():
        assert abs(row.time_ms - 20.0) <= TOLERANCE * 20.0, table.time_ms.tolist()
        assert row.used_samples == row.spp   # the scored render is the corrected one
        image = read_exr(out / "images" / "seq" / f"f{row.frame}" /
                         f"{row.estimator}_t20ms_spp{row.spp}_s{row.seed}.exr")
        assert image.max() == row.frame + 1   # nothing rendered on it before, reset or not
    fit, = json.loads((out / "manifest.json").read_text())["time_budget"]["calibrations"]
    first, *corrected = fit["cell_runs"]
    assert first["spp"] == fit["calibrated_spp"] and first["median_device_ms"] > 1.2 * 20.0
    assert corrected and corrected[-1]["spp"] == fit["chosen_spp"] == table.spp.iloc[0]


def test_every_render_runs_with_host_blas_at_one_thread(tmp_path, fakes):
    """OpenBLAS's worker spins beside the device's threads after a NumPy product: a run keeps
    BLAS on the calling thread for the warm-up, calibration and cells, and gives it back."""
    before = [pool["num_threads"] for pool in threadpoolctl.threadpool_info()]
    run(tiny(tmp_path, ("blas_probe_timing_test",), time_budget_ms=(20.0,)))
    assert len(BlasProbe.log) > 10 and all(threads == {1} for threads in BlasProbe.log)
    assert [pool["num_threads"] for pool in threadpoolctl.threadpool_info()] == before


def test_terminal_check_and_report_show_one_time_per_cell(tmp_path):
    """A cell of 2 frames × 3 seeds whose mean over seeds differs from the median over its rows:
    the terminal, the report and ``check``'s time ratio all take the mean over seeds of the
    per-seed frame means (the median over rows would be 4.25 and 8.5 ms)."""
    times = {(0, 0): 1.0, (1, 0): 9.0, (0, 1): 4.0, (1, 1): 4.5, (0, 2): 3.0, (1, 2): 8.0}
    rows = []
    for estimator, scale in (("a", 1.0), ("b", 2.0)):
        for (frame, seed), ms in times.items():
            rows.append({"scene": "s", "estimator": estimator, "spp": 16, "frame": frame,
                         "seed": seed, "time_budget_ms": math.nan, "mean_delta_e76": 1.0,
                         "mean_delta_e2000": 1.0, "rel_mse": 0.1, "flip": 0.1,
                         "used_samples": 16.0, "effective_samples": 8.0, "effective_ratio": 0.5,
                         "evaluations": 16.0, "nonfinite": 0, "time_ms": ms * scale,
                         "time_ms_min": ms, "time_ms_iqr": 0.0, "time_ms_build": 0.0,
                         "time_ms_sample": 0.0, "time_ms_shade": ms, "time_ms_host": 99.0,
                         "time_repeats": 5})
    table = pd.DataFrame(rows)
    expected = {"a": 59 / 12, "b": 59 / 6}   # seeds' means (5, 4.25, 5.5) and twice those
    terminal = run_command.terminal_summaries(table)[0][1].time_ms
    report = summarize(table).set_index("estimator").time_ms
    rule = budgets.Rule("r", "s", "b", (16,), (), None, budgets.TimeRatio("a", "time_ms", 3.0))
    check = budgets.evaluate([rule], table).iloc[0]
    for estimator, ms in expected.items():
        assert terminal[("s", estimator, 16)].startswith(f"{ms:.1f} ± ")   # ± 1.6, ± 3.1
        assert report[estimator] == pytest.approx(ms)
    assert check.metric == "time_ms / a (9.833 / 4.917 ms)" and check.value == "2"


def test_a_slow_estimator_may_get_fewer_repeats_if_the_run_says_so(tmp_path, fakes, capsys):
    # Steady times (Linear's), so neither cell gets more renders than it is given.
    table = run(tiny(tmp_path, ("blas_probe_timing_test", "linear_timing_test"), repeats=4,
                     repeats_for=(("Blas_Probe_Timing_Test", 2),)))
    assert dict(zip(table.estimator, table.time_repeats)) == {"blas_probe_timing_test": 2,
                                                             "linear_timing_test": 4}
    # The manifest (and the report's manifest section) says so; the terminal no longer does
    # (issue 23: a line on every run of the default sweep).
    assert "fewer timed renders" not in capsys.readouterr().err
    timing = json.loads((tmp_path / "manifest.json").read_text())["timing"]
    assert timing["repeats"] == {"blas_probe_timing_test": 2, "linear_timing_test": 4}
    assert len(BlasProbe.log) == 1 + 2   # the warm-up and two timed renders
    probe = table.set_index("estimator").loc["blas_probe_timing_test"]
    assert probe.time_ms == pytest.approx(0.7 + 0.013 * 4 + probe.time_ms_build)


def test_the_warm_up_pixels_keep_a_specular_pixel_of_a_mostly_diffuse_scene():
    from iblbench.scenes.gbuffer import GBuffer

    size = 12
    ks = np.zeros((size, size, 3), np.float32)
    ks[-1, -1] = 0.3                           # the last covered pixel alone is specular
    gbuffer = GBuffer.from_pixels(np.tile([0.0, 0.0, 1.0], (size, size, 1)), [0.0, 0.0, 1.0],
                                  0.5, ks, 20.0)
    subset = executor.warm_up_gbuffer(gbuffer)
    assert subset.covered == WARMUP_PIXELS and not subset.is_diffuse and subset.mask[-1, -1]
    assert executor.warm_up_gbuffer(dataclasses.replace(gbuffer, ks=ks * 0)).is_diffuse


class Spells(Linear):
    """Linear's cost in calibration; on the seeds of cells the shade stage runs ``FACTORS[k]``
    times slower in the cell's k-th rendering (its repeats alike): a device that switches
    between slow and fast spells from one rendering of the cell to the next."""

    name = "spells_timing_test"
    FACTORS = (1.08, 0.8, 1.3, 1.0)
    cell_renders = 0

    def render(self, gbuffer, cache, spp, seed):
        estimate = super().render(gbuffer, cache, spp, seed)
        if seed < CALIBRATION_SEED:
            spell = self.FACTORS[type(self).cell_renders // DEFAULT_REPEATS]
            estimate.timings_ms["shade"] *= spell
            type(self).cell_renders += 1
        return estimate


def test_a_budgets_first_cell_ends_on_its_best_measured_spp(tmp_path, known_builds, monkeypatch):
    """Worked out by hand: calibration fits 1.2 + 0.013·spp exactly (build 0.5, shade 0.7 +
    0.013·spp) and chooses 1446 spp (20.0 ms).  The cell there runs 1.08x slow: 21.56 ms (+8%,
    outside half the tolerance), so a step through that point gives 1335 spp, which runs 0.8x:
    14.94 ms.  A step through that point alone would give 1826 spp (slope 0.01029); the median
    of both points' slopes (0.01408, 0.01029) gives 1542, which runs 1.3x: 27.47 ms.  The last
    step is no better than the first point, the only one within ±10%: the budget keeps
    1446 spp, and the cells (rendered after the corrections, the next spell: 1.0x) take
    20.0 ms.  The old rule kept 1826 spp at 32.3 ms."""
    register(Spells)
    monkeypatch.setattr(Spells, "cell_renders", 0)
    try:
        table = run(tiny(tmp_path, ("spells_timing_test",), spp=(), time_budget_ms=(20.0,)))
    finally:
        _registry.pop(Spells.name)
    fit, = json.loads((tmp_path / "manifest.json").read_text())["time_budget"]["calibrations"]
    assert fit["calibrated_spp"] == 1446
    assert [run["spp"] for run in fit["cell_runs"]] == [1446, 1335, 1542]
    assert [run["median_device_ms"] for run in fit["cell_runs"]] == pytest.approx(
        [21.558, 14.944, 27.470], abs=2e-3)
    row = table.iloc[0]
    assert row.spp == fit["chosen_spp"] == 1446 and row.used_samples == 1446
    assert abs(row.time_ms - 20.0) <= TOLERANCE * 20.0


@pytest.mark.parametrize("groups_within, said", [(1.0, False), (0.25, True)])
def test_the_terminal_speaks_of_the_timing_floor_only_when_it_was_poor(tmp_path, fakes, capsys,
                                                                        monkeypatch, groups_within, said):
    """Issue 23: every run printed the floor (two lines of p90/p10); now only a poor one, and
    the manifest keeps it either way."""
    from iblbench.harness.protocol import runner as runner_module

    floor = TimingFloor(launches=40, median_ms=3.0, groups_within=groups_within, p90_over_p10=1.5)
    monkeypatch.setattr(runner_module, "measure_timing_floor", lambda compute: floor)
    run(tiny(tmp_path, ("linear_timing_test",)))
    err = capsys.readouterr().err
    assert ("not repeatable" in err) == said and ("p90/p10" in err) == said, err
    record = json.loads((tmp_path / "manifest.json").read_text())["timing"]["floor"]
    assert record["groups_within"] == [groups_within, groups_within]


def test_a_cell_that_missed_its_budget_says_why():
    """Issue 32: the run names every equal-time cell off its budget by more than 10%, and why."""
    from iblbench.harness.protocol.runner import _missed_why

    calibration = {"limit": 100, "measured_ms": 5.0, "runs": [
        {"spp": 1, "median_device_ms": 3.0}, {"spp": 4, "median_device_ms": 5.0}]}
    assert _missed_why(calibration, 1, 3.0, 2.0) == "even 1 spp takes longer than the budget"
    assert _missed_why(calibration, 4, 5.0, 2.0) == (
        "no spp fitted: its fastest in calibration, 1 spp, took 3 ms (the frame's fixed work)")
    assert _missed_why(calibration, 100, 5.0, 10.0) == "100 spp is the most it may take"
    assert _missed_why(calibration, 4, 7.0, 5.0) == (
        "calibrated at 5 ms, its cells ran at 7 ms: the device's speed changed between the "
        "calibration and the cells")
    assert _missed_why(None, 4, 7.0, 5.0) == "its spp was chosen by an earlier run"
