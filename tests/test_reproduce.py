"""Verdict logic and summary writing of `iblbench reproduce`, on synthetic results."""
import numpy as np
import pandas as pd
import pytest

from iblbench.harness import reproduce
from iblbench.reports.reproduction import write_summary
from iblbench.scenes.errors import InputError


def with_intervals(cells: pd.DataFrame, half: float = 0.0, seeds: int = 8) -> pd.DataFrame:
    """``cells`` with every figure's interval ± ``half`` × the figure over ``seeds`` seeds."""
    intervals = {}
    for c in (c for c in cells.columns if c not in ("scene", "estimator", "spp")):
        intervals.update({f"{c}_low": cells[c] * (1 - half), f"{c}_high": cells[c] * (1 + half),
                          f"{c}_half": cells[c] * half})
    return cells.assign(seeds=seeds, **intervals)


def synthetic_cells(balanced_de=6.4, mis_de=(9.0, 7.0, 5.0, 3.5, 2.5), balanced_ms=10.0, half=0.0):
    """Cells shaped like _cell_means: uniform error ∝ spp^-½ and time ∝ spp; each figure's
    interval is ± ``half`` × the figure (0: exact)."""
    rows = []
    for spp in reproduce.LU2013_SPP:
        rows.append(dict(scene="s", estimator="uniform", spp=spp, mean_delta_e76=11.0 * (60 / spp) ** 0.5,
                         used=spp, effective=0.6 * spp, effective_ratio=0.6, time_ms=spp / 6.0))
        rows.append(dict(scene="s", estimator="balanced", spp=spp, mean_delta_e76=balanced_de * (60 / spp) ** 0.5,
                         used=spp, effective=0.8 * spp, effective_ratio=0.8,
                         time_ms=balanced_ms * spp / 60))
    for spp, de in zip(reproduce.LU2013_MIS_SPP, mis_de):
        rows.append(dict(scene="s", estimator="balanced_mis", spp=spp, mean_delta_e76=de, used=spp,
                         effective=0.7 * spp, effective_ratio=0.7, time_ms=spp / 5.0))
    return with_intervals(pd.DataFrame(rows), half)


def test_verdicts_follow_the_numbers():
    # uniform@180 has ΔE 11/√3 = 6.35: balanced@60 = 6.4 is within 10% → claim 2 holds.
    # uniform needs 30 ms (180 spp) for ΔE 6.35; balanced takes 10 ms → claim 4 holds.
    verdicts = reproduce.lu2013_verdicts(synthetic_cells(), ["s"])
    assert [v.verdict for v in verdicts] == [reproduce.HOLDS] * 4
    assert "0.8 ± 0 vs 0.6 ± 0" in verdicts[0].ours        # exact cells: point intervals


def test_verdicts_can_fail():
    cells = synthetic_cells(balanced_de=9.0, mis_de=(9.0, 7.0, 7.5, 3.5, 2.5), balanced_ms=40.0)
    verdicts = reproduce.lu2013_verdicts(cells, ["s"])
    # 9.0 is not within 10% of 6.35: the stated test fails, though 9.0 beats uniform@60's 11.
    assert verdicts[1].verdict == reproduce.FAILS
    assert verdicts[2].verdict == reproduce.FAILS       # rises 7.0 → 7.5: not monotone
    assert verdicts[3].verdict == reproduce.FAILS       # 40 ms vs uniform's ~18 ms for ΔE 9.0


@pytest.mark.parametrize("with_monotone_scene, verdict", [(False, reproduce.FAILS),
                                                          (True, reproduce.PARTLY)])
def test_claim3_verdict_is_monotone_in_every_scene(with_monotone_scene, verdict):
    """Claim 3 states a monotone fall over 15 → 240 spp: a scene whose error falls overall (2.5
    at 240 below 9.0 at 15) but rises at one step (9.0 → 9.5) fails it; the claim partly holds
    only beside a scene where it holds (issue 11)."""
    rising = synthetic_cells(mis_de=(9.0, 9.5, 5.0, 3.5, 2.5)).assign(scene="t")
    cells, scenes = rising, ["t"]
    if with_monotone_scene:
        cells, scenes = pd.concat([synthetic_cells(), rising]), ["s", "t"]
    claim3 = reproduce.lu2013_verdicts(cells, scenes)[2]
    assert claim3.claim.startswith("3.") and "monotonically" in claim3.claim
    assert claim3.verdict == verdict, claim3


def test_time_for_quality_interpolates_log_log():
    cells = synthetic_cells()
    # uniform: ΔE = 11·√(60/spp), time = spp/6 → ΔE 11 at 10 ms, 11/√2 at 20 ms.
    assert reproduce._time_for_quality(cells, "s", 11 / np.sqrt(2)) == pytest.approx(20.0, rel=1e-6)


def test_unknown_reproduction_lists_valid_names(tmp_path):
    with pytest.raises(InputError, match="unknown reproduction 'nope'; valid: lu2013"):
        reproduce.reproduce("nope", tmp_path)
    assert not any(tmp_path.iterdir())


def test_summary_has_verdict_table_and_plots(tmp_path):
    cells, noisy = synthetic_cells(), synthetic_cells(half=0.05)
    fig2 = noisy[noisy.spp.isin([60, 180]) & (noisy.estimator != "balanced_mis")]
    fig3 = noisy[noisy.estimator == "balanced_mis"]
    result = reproduce.Reproduction(
        title="test", setup_differences=["a difference"],
        tables={"fig2": reproduce._shown(fig2, ["scene", "estimator", "spp"],
                                         ["mean_delta_e76", "used", "effective"]),
                "fig3": reproduce._shown(fig3, ["scene", "spp"], ["mean_delta_e76"]),
                "timing": reproduce._shown(fig2, ["scene", "estimator"], ["time_ms"])},
        verdicts=reproduce.lu2013_verdicts(cells, ["s"]), results=cells)
    md = write_summary(tmp_path, result).read_text()
    html = (tmp_path / "summary.html").read_text()
    assert md.count("| **holds** |") == 4 and "a difference" in md
    # balanced@60: ΔE 6.4 ± 5%, 60 ± 5% spp used, 10 ± 5% ms; every table shows intervals.
    assert "| s | balanced | 60 | 8 | 6.40 ± 0.32 | 60.0 ± 3.0 | 48.0 ± 2.4 |" in md
    assert "| s | 15 | 8 | 9.00 ± 0.45 |" in md and "| s | balanced | 8 | 10.00 ± 0.50 |" in md
    assert html.count('class="holds"') == 4 and "<table>" in html
    for plot in ("fig3_error_vs_spp.png", "fig2_samples.png"):
        assert (tmp_path / plot).stat().st_size > 1000 and plot in md and plot in html


def test_lu2013_end_to_end_on_tiny_images(tmp_path):
    summary = reproduce.reproduce("lu2013", tmp_path, seeds=1, progress=False,
                                  resolution=(10, 10), env_res=8)
    text = summary.read_text()
    verdicts = [line for line in text.splitlines() if line.startswith("| ") and "**" in line]
    assert len(verdicts) == 4
    # One seed gives no interval: no claim is called.
    assert all("**not resolved at 1 seed**" in line for line in verdicts)
    assert "(n=1, no interval)" in text
    table = pd.read_parquet(tmp_path / "results.parquet")
    assert set(table.estimator) == {"uniform", "balanced", "balanced_mis"}
    assert set(table.scene) == set(reproduce.LU2013_SCENES)
    assert (table.nonfinite == 0).all() and (tmp_path / "summary.html").exists()


def test_verdicts_are_not_called_where_intervals_overlap():
    """±20% intervals: the effective ratios 0.8 ± 0.16 and 0.6 ± 0.12 overlap, as do MIS's
    neighbouring errors and the times; claim 2's ratio range 6.4·0.8/(6.35·1.2) … 6.4·1.2/(6.35·0.8)
    = 0.67 … 1.51 straddles the ±10% band: claims 1-3 are not called.  Claim 4 still is: balanced
    takes 10 ± 2 ms; uniform needs at least 0.8 × 60·(11/7.68)²/6 = 16.4 ms for ΔE 6.4 × 1.2."""
    verdicts = reproduce.lu2013_verdicts(synthetic_cells(half=0.2), ["s"])
    assert [v.verdict for v in verdicts] == ["not resolved at 8 seeds"] * 3 + [reproduce.HOLDS]
    assert "16.4" in verdicts[3].ours
    assert "0.80 ± 0.16 vs 0.60 ± 0.12" in verdicts[0].ours


def test_one_resolved_scene_against_one_unresolved_is_not_resolved():
    steady, noisy = synthetic_cells(), synthetic_cells(half=0.2).assign(scene="t")
    verdicts = reproduce.lu2013_verdicts(pd.concat([steady, noisy]), ["s", "t"])
    assert verdicts[0].verdict == "not resolved at 8 seeds"
    # A resolved failure beside a resolved success is called whatever else is unresolved.
    failing = synthetic_cells(balanced_de=9.0).assign(scene="u")
    assert reproduce.lu2013_verdicts(pd.concat([steady, noisy, failing]),
                                     ["s", "t", "u"])[1].verdict == reproduce.PARTLY


def test_cells_are_means_over_seeds_with_t_intervals():
    """Seeds' values 1, 2, 6 (two frames each): 3 ± t(0.975, 2)·√7/√3 = 3 ± 6.57."""
    rows = [{"scene": "s", "estimator": "uniform", "spp": 60, "frame": frame, "seed": seed,
             "mean_delta_e76": value, "used_samples": 60.0, "effective_samples": 30.0,
             "effective_ratio": 0.5, **{t: 2 * value for t in reproduce.TIMES}}
            for seed, pair in enumerate([(0.5, 1.5), (2.0, 2.0), (5.0, 7.0)])
            for frame, value in enumerate(pair)]
    cell = reproduce._cell_means(pd.DataFrame(rows)).iloc[0]
    half = 4.302652729911275 * 7 ** 0.5 / 3 ** 0.5
    assert (cell.mean_delta_e76, cell.mean_delta_e76_half, cell.seeds) == pytest.approx((3, half, 3))
    assert (cell.time_ms, cell.time_ms_low) == pytest.approx((6, 6 - 2 * half))
    assert (cell.effective, cell.effective_half) == (30.0, 0.0)
