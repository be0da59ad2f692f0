"""harness/convergence.py on synthetic results tables: a flat error is flagged, a 1/spp one and a
noisy one whose mean follows 1/spp are not, and the estimator's tags set the allowance."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from iblbench.estimators.base import Tags
from iblbench.harness.convergence import allowance, flatter_than_tags

SPP = (16, 64, 256)


def _table(estimator: str, error, seeds: int, noise: float, frames: int = 1,
           rng_seed: int = 1) -> pd.DataFrame:
    """Rows of one (scene, estimator): relMSE = error(spp) and ΔE76 = √error(spp) × 30, each seed
    and frame times a lognormal factor of log-sd ``noise`` (mean 1)."""
    rng = np.random.default_rng(rng_seed)
    rows = []
    for spp in SPP:
        for seed in range(seeds):
            for frame in range(frames):
                factor = rng.lognormal(-noise ** 2 / 2, noise, 2)
                rows.append({"scene": "s", "estimator": estimator, "spp": spp, "frame": frame,
                             "seed": seed, "time_budget_ms": np.nan,
                             "rel_mse": error(spp) * factor[0],
                             "mean_delta_e76": 30 * np.sqrt(error(spp)) * factor[1]})
    return pd.DataFrame(rows)


def flat(spp):
    return 0.12


def one_over_spp(spp):
    return 2.0 / spp


def test_a_flat_error_of_an_unbiased_estimator_is_flagged_at_every_step_and_metric():
    flags = flatter_than_tags(_table("uniform", flat, seeds=8, noise=0.05))
    assert {(f.metric, f.spp_low, f.spp_high) for f in flags} == {
        (m, a, b) for m in ("rel_mse", "mean_delta_e76") for a, b in ((16, 64), (64, 256))}
    assert all(f.ratio.low > f.allowed_ratio for f in flags)


def test_an_error_falling_as_one_over_spp_is_not_flagged():
    assert flatter_than_tags(_table("uniform", one_over_spp, seeds=8, noise=0.1)) == []


def test_a_noisy_error_whose_mean_falls_as_one_over_spp_is_rarely_flagged():
    # Seeds scattered by a lognormal factor of log-sd 0.6 (a coefficient of variation of 0.66,
    # more than the 0.37 of balanced_mis's ΔE over 16 seeds in issue 11), 4 seeds: the sample
    # means often fall less than the allowance, but the intervals rarely say the convergence is
    # flatter.  Each table holds 4 one-sided tests at 2.5%; measured 1.7% of tables flagged,
    # tolerance 5% (P(more than 10 of 200 | 1.7%) < 1e-3).
    tables = [_table("uniform", one_over_spp, seeds=4, noise=0.6, rng_seed=1000 + i)
              for i in range(200)]
    allowed = 4 ** allowance(Tags(), "rel_mse", sequence=False).slope
    means = [t.groupby("spp").rel_mse.mean() for t in tables]
    slow = sum(m.loc[64] / m.loc[16] > allowed or m.loc[256] / m.loc[64] > allowed for m in means)
    assert slow >= 20                 # the means alone would flag these
    assert sum(bool(flatter_than_tags(t)) for t in tables) <= 10


def test_one_seed_flags_nothing():
    assert flatter_than_tags(_table("uniform", flat, seeds=1, noise=0.05)) == []


def test_the_allowance_is_conformance_s_least_fall_of_2_5_over_16_times_the_samples():
    for tags in (Tags(unbiased=True), Tags(unbiased=False, temporal=False)):
        assert 16 ** allowance(tags, "mean_delta_e76", sequence=False).slope == pytest.approx(1 / 2.5)
        assert 16 ** allowance(tags, "rel_mse", sequence=True).slope == pytest.approx(1 / 2.5 ** 2)
    biased_temporal = Tags(unbiased=False, temporal=True)
    assert allowance(biased_temporal, "rel_mse", sequence=False).slope < 0     # static: must fall
    assert allowance(biased_temporal, "rel_mse", sequence=True).slope == 0     # may level off


def test_smc_levelling_off_is_flagged_on_a_static_scene_but_not_on_a_sequence():
    # smc's relMSE 0.131 → 0.120 from 16 to 64 spp (issue 11): smc is temporal and not unbiased,
    # so on a static scene it must fall like any estimator, on a sequence it may level off.
    def smc(spp):
        return {16: 0.131, 64: 0.120, 256: 0.115}[spp]

    static = flatter_than_tags(_table("smc", smc, seeds=8, noise=0.05))
    assert [(f.metric, f.spp_low) for f in static if f.metric == "rel_mse"] == [("rel_mse", 16),
                                                                                ("rel_mse", 64)]
    assert "0.131 → 0.12 from 16 to 64 spp" in static[0].text()
    assert flatter_than_tags(_table("smc", smc, seeds=8, noise=0.05, frames=3)) == []


def test_a_rising_error_of_a_biased_temporal_estimator_on_a_sequence_is_flagged():
    flags = flatter_than_tags(_table("havran", lambda spp: 0.01 * spp, seeds=8, noise=0.05,
                                     frames=3))
    assert {f.metric for f in flags} == {"rel_mse", "mean_delta_e76"}
    assert all(f.allowed.slope == 0 for f in flags)


def test_equal_time_cells_and_unregistered_estimators_are_not_judged():
    table = _table("uniform", flat, seeds=8, noise=0.05)
    assert flatter_than_tags(table.assign(time_budget_ms=5.0)) == []
    assert flatter_than_tags(table.assign(estimator="not_an_estimator")) == []
