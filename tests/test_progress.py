"""The run's progress bar (issue 23): it names the scene, estimator and stage, and its time left
comes from each estimator's own cost per cell, so it does not swing as cheap and dear
estimators take turns."""
from __future__ import annotations

import collections

import pytest

from iblbench.harness.protocol.progress import cell_seconds, left_text, time_left
from iblbench.harness.protocol.runner import RunConfig, run

SPP = (16, 64)


def cost(estimator: str, spp: int) -> float:
    """Seconds per cell: 0.1 s of scoring and 10 ms a sample; ``slow`` 100 times that."""
    return (100.0 if estimator == "slow" else 1.0) * (0.1 + 0.01 * spp)


def sweep() -> list[tuple[str, int]]:
    """(estimator, spp) of each cell in the runner's order: scene, estimator, spp, seed."""
    return [(estimator, spp) for _scene in range(3) for estimator in ("cheap", "slow")
            for spp in SPP for _seed in range(2)]


def test_cell_seconds_scales_with_spp():
    # one spp measured: proportional to spp
    assert cell_seconds([(16, 1.0), (16, 1.2)], 64) == pytest.approx(4.4)
    # two: the line through them (0.5 s + 1/32 s a sample)
    assert cell_seconds([(16, 1.0), (64, 2.5)], 256) == pytest.approx(8.5)
    assert cell_seconds([(16, 1.0), (64, 2.5)], None) == pytest.approx(1.75)   # spp not chosen


def test_time_left_does_not_swing_when_one_estimator_is_100x_slower():
    cells = sweep()
    remaining = collections.Counter(cells)
    measured = collections.defaultdict(list)
    rate, estimates, rates = None, [], []   # rates: tqdm's estimate / the truth
    for done, (estimator, spp) in enumerate(cells, 1):
        measured[estimator].append((spp, cost(estimator, spp)))
        remaining[(estimator, spp)] -= 1
        # tqdm's cells per second: an exponential moving average, smoothing 0.3
        rate = 1 / cost(estimator, spp) if rate is None else 0.3 / cost(estimator, spp) + 0.7 * rate
        seconds, untimed = time_left(remaining, measured)
        truth = sum(cost(*cell) for cell in cells[done:])
        if done >= 8:   # both estimators measured at both spp (the first scene)
            assert not untimed and seconds == pytest.approx(truth, rel=1e-9, abs=1e-9)
            if estimator == "cheap" and estimates:
                assert estimates[-1] - seconds == pytest.approx(cost(estimator, spp))
            estimates.append(seconds)
            rates.append((len(cells) - done) / rate / truth if truth else 1.0)
        elif done < 4:
            assert untimed == ["slow"]   # its cells are not in the seconds, and the text says so
    # the sweep tells them apart: tqdm's estimate is 10x off here, ours exact and only falling
    assert min(rates) < 0.1
    assert all(b <= a for a, b in zip(estimates, estimates[1:]))


def test_left_text_says_when_estimators_are_not_timed_yet():
    assert left_text(210.0, []) == "~3.5 min left"
    assert left_text(30.0, ["bis"]) == "≥30 s left, 1 estimator not timed yet"
    assert left_text(0.0, ["bis", "smc"]) == "time left: after the first cells"


def test_the_bar_names_scene_estimator_and_stage(tmp_path, capsys):
    run(RunConfig(out=tmp_path / "out", scenes=("sphere-sun",), estimators=("uniform",), spp=(2,),
                  seeds=1, resolution=(16, 16), env_res=8, repeats=1, metrics=("de76",),
                  time_budget_ms=(1.0,), progress=True))
    bar = capsys.readouterr().err
    for description in ("timing floor", "sphere-sun · frame cache", "sphere-sun · reference",
                        "sphere-sun · uniform · warm-up", "sphere-sun · uniform · calibrating",
                        "sphere-sun · rendering, round 1 of 1"):
        assert f"{description}" in bar, description
    assert "s left" in bar and "it/s" not in bar and "cell/s" not in bar
