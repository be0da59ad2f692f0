"""harness/verify/convergence.py on synthetic results tables: a flat error is not converging, a
1/spp one is not reported, a noisy one whose interval reaches the allowance is not resolved (also
at 2 seeds that agree by chance at one step, issue 34), and the estimator's tags set the
allowance."""
from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from iblbench.estimators.base import Tags
from iblbench.harness.protocol.stats import ratio_ci
from iblbench.harness.verify.convergence import allowance, flatter_than_tags

SPP = (16, 64, 256)


def _table(estimator: str, error, seeds: int, noise: float, frames: int = 1,
           rng_seed: int = 1) -> pd.DataFrame:
    """Rows of one (scene, estimator): relMSE = error(spp), each seed and frame times a lognormal
    factor of log-sd ``noise`` (mean 1), and a flat ΔE76 (not judged: harness/verify/convergence.py)."""
    rng = np.random.default_rng(rng_seed)
    rows = []
    for spp in SPP:
        for seed in range(seeds):
            for frame in range(frames):
                factor = rng.lognormal(-noise ** 2 / 2, noise)
                rows.append({"scene": "s", "estimator": estimator, "spp": spp, "frame": frame,
                             "seed": seed, "time_budget_ms": np.nan,
                             "rel_mse": error(spp) * factor, "mean_delta_e76": 5.0})
    return pd.DataFrame(rows)


def flat(spp):
    return 0.12


def one_over_spp(spp):
    return 2.0 / spp


def _rows(estimator: str, errors: dict[int, list[float]]) -> pd.DataFrame:
    """Rows of one (scene, estimator) with the given relMSE per spp, one value per seed."""
    return pd.DataFrame([{"scene": "s", "estimator": estimator, "spp": spp, "frame": 0,
                          "seed": seed, "time_budget_ms": np.nan, "rel_mse": value}
                         for spp, values in errors.items() for seed, value in enumerate(values)])


def test_a_flat_error_of_an_unbiased_estimator_is_not_converging_at_every_step():
    flags = flatter_than_tags(_table("uniform", flat, seeds=8, noise=0.05))
    assert [(f.metric, f.spp_low, f.spp_high) for f in flags] == [("rel_mse", 16, 64),
                                                                  ("rel_mse", 64, 256)]
    assert all(f.not_converging and f.ratio.low > f.allowed_ratio for f in flags)
    assert re.match(r"uniform on s: not converging: relMSE 0\.12\d* → 0\.12\d* from 16 to 64 "
                    r"spp, ×",
                    flags[0].text())


def test_an_error_whose_interval_reaches_the_allowance_is_not_resolved():
    # 8 seeds spread ×9 (a coefficient of variation of 0.6), the same spread halved at 64 spp:
    # the means fall ×0.5, less than the ×0.40 allowed over 4×, but the interval (about ×2 either
    # way) reaches well below ×0.40.
    spread = [0.3, 0.5, 0.8, 1.0, 1.2, 1.5, 2.0, 2.7]
    (flag,) = flatter_than_tags(_rows("uniform", {16: spread, 64: [v / 2 for v in spread[::-1]]}))
    assert flag.ratio.ratio == pytest.approx(0.5)
    assert flag.ratio.low < flag.allowed_ratio < flag.ratio.ratio < flag.ratio.high
    assert not flag.not_converging
    assert flag.text().startswith("uniform on s: not resolved at 8 seeds: relMSE")


def test_two_seeds_that_agree_by_chance_at_one_step_do_not_resolve_it():
    # Issue 34: balanced_mis's two seeds, ×3 apart at most spp (its shared light pool), agree
    # at 64 and 256 spp; that step's own interval alone is narrow and would call the fall of
    # ×0.54 flatter than the ×0.40 allowed, but the seed spread of the other levels says 2
    # seeds cannot tell.  Where the seeds agree at every level, a flat error still is not
    # converging at 2 seeds.
    errors = {16: [0.125, 0.375], 64: [0.0625, 0.063], 256: [0.034, 0.0342], 1024: [0.004, 0.012]}
    flags = flatter_than_tags(_rows("balanced_mis", errors))
    (step,) = [f for f in flags if f.spp_low == 64]
    assert ratio_ci(errors[64], errors[256]).low > step.allowed_ratio   # the step alone
    assert step.ratio.low < step.allowed_ratio < step.ratio.high
    assert step.text().startswith("balanced_mis on s: not resolved at 2 seeds: relMSE")
    agreeing = flatter_than_tags(_rows("balanced_mis", {spp: [0.1, 0.1001] for spp in errors}))
    assert len(agreeing) == 3 and all(f.not_converging for f in agreeing)


def test_an_error_falling_as_one_over_spp_is_not_flagged():
    assert flatter_than_tags(_table("uniform", one_over_spp, seeds=8, noise=0.1)) == []


def test_a_noisy_error_whose_mean_falls_as_one_over_spp_is_rarely_not_converging():
    # Seeds scattered by a lognormal factor of log-sd 0.6 (a coefficient of variation of 0.66,
    # more than the 0.37 of balanced_mis's ΔE over 16 seeds in issue 11), 4 seeds: the sample
    # means often fall less than the allowance (those steps are reported, as not resolved), but
    # the intervals rarely say the convergence is flatter.  Each table holds 2 one-sided tests
    # at 2.5%; tolerance 5% of tables not converging.
    tables = [_table("uniform", one_over_spp, seeds=4, noise=0.6, rng_seed=1000 + i)
              for i in range(200)]
    allowed = 4 ** allowance(Tags(), "rel_mse", sequence=False).slope
    means = [t.groupby("spp").rel_mse.mean() for t in tables]
    slow = [m.loc[64] / m.loc[16] > allowed or m.loc[256] / m.loc[64] > allowed for m in means]
    assert sum(slow) >= 20                 # the means alone would flag these
    flags = [flatter_than_tags(t) for t in tables]
    assert [bool(f) for f in flags] == slow
    assert sum(any(f.not_converging for f in table_flags) for table_flags in flags) <= 10


def test_one_seed_resolves_nothing():
    flags = flatter_than_tags(_table("uniform", flat, seeds=1, noise=0.05))
    assert len(flags) == 2 and not any(f.not_converging for f in flags)
    assert flags[0].text().startswith("uniform on s: not resolved at 1 seed: relMSE")


def test_the_allowance_is_conformance_s_least_fall_of_2_5_over_16_times_the_samples():
    # relMSE is a squared error: 2.5² less over 16× the samples.
    for tags in (Tags(unbiased=True), Tags(unbiased=False, temporal=False)):
        for sequence in (False, True):
            assert 16 ** allowance(tags, "rel_mse", sequence).slope == pytest.approx(1 / 2.5 ** 2)
    biased_temporal = Tags(unbiased=False, temporal=True)
    assert allowance(biased_temporal, "rel_mse", sequence=False).slope < 0     # static: must fall
    assert allowance(biased_temporal, "rel_mse", sequence=True).slope == 0     # may level off


def test_smc_levelling_off_is_flagged_on_a_static_scene_but_not_on_a_sequence():
    # smc's relMSE 0.131 → 0.120 from 16 to 64 spp (issue 11): smc is temporal and not unbiased,
    # so on a static scene it must fall like any estimator, on a sequence it may level off.
    def smc(spp):
        return {16: 0.131, 64: 0.120, 256: 0.115}[spp]

    static = flatter_than_tags(_table("smc", smc, seeds=8, noise=0.05))
    assert [(f.metric, f.spp_low) for f in static] == [("rel_mse", 16), ("rel_mse", 64)]
    assert re.search(r"relMSE 0\.13\d* → 0\.1[12]\d* from 16 to 64 spp, .* allow at most ×0\.4 ",
                     static[0].text())
    assert flatter_than_tags(_table("smc", smc, seeds=8, noise=0.05, frames=3)) == []


def test_a_rising_error_of_a_biased_temporal_estimator_on_a_sequence_is_flagged():
    flags = flatter_than_tags(_table("havran", lambda spp: 0.01 * spp, seeds=8, noise=0.05,
                                     frames=3))
    assert [(f.spp_low, f.allowed.slope) for f in flags] == [(16, 0), (64, 0)]


def test_equal_time_cells_and_unregistered_estimators_are_not_judged():
    table = _table("uniform", flat, seeds=8, noise=0.05)
    assert flatter_than_tags(table.assign(time_budget_ms=5.0)) == []
    assert flatter_than_tags(table.assign(estimator="not_an_estimator")) == []


def test_run_prints_a_warning_for_each_flag(monkeypatch, tmp_path, capsys):
    from iblbench import cli
    from iblbench.commands import run as run_command
    from iblbench.harness.protocol import runner

    class FlatRunner:   # the sweep's table, without rendering it
        def __init__(self, config):
            pass

        def run(self):
            return _table("uniform", flat, seeds=8, noise=0.05)

        def sweep_rows(self, table):
            return table

    monkeypatch.setattr(runner, "Runner", FlatRunner)
    monkeypatch.setattr(run_command, "terminal_summaries", lambda table: [])
    assert cli.main(["run", "--scene", "sphere-sun", "--out", str(tmp_path)]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines()
                if line.startswith("warning: convergence: uniform on s: not converging: relMSE")]
    assert len(warnings) == 2
