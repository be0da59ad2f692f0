"""Verdict logic and summary writing of `iblbench reproduce`, on synthetic results."""
import numpy as np
import pandas as pd
import pytest

from iblbench.harness import reproduce
from iblbench.reports.reproduction import write_summary
from iblbench.scenes.errors import InputError


def synthetic_cells(balanced_de=6.4, mis_de=(9.0, 7.0, 5.0, 3.5, 2.5), balanced_ms=10.0):
    """Cells shaped like _cell_means: uniform error ∝ spp^-½ and time ∝ spp."""
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
    return pd.DataFrame(rows)


def test_verdicts_follow_the_numbers():
    # uniform@180 has ΔE 11/√3 = 6.35: balanced@60 = 6.4 is within 10% → claim 2 holds.
    # uniform needs 30 ms (180 spp) for ΔE 6.35; balanced takes 10 ms → claim 4 holds.
    verdicts = reproduce.lu2013_verdicts(synthetic_cells(), ["s"])
    assert [v.verdict for v in verdicts] == [reproduce.HOLDS] * 4
    assert "0.80 vs 0.60" in verdicts[0].ours


def test_verdicts_can_fail():
    cells = synthetic_cells(balanced_de=9.0, mis_de=(9.0, 7.0, 7.5, 3.5, 2.5), balanced_ms=40.0)
    verdicts = reproduce.lu2013_verdicts(cells, ["s"])
    # 9.0 is not within 10% of 6.35: the stated test fails, though 9.0 beats uniform@60's 11.
    assert verdicts[1].verdict == reproduce.FAILS
    assert verdicts[2].verdict == reproduce.PARTLY      # not monotone, but 240 < 15
    assert verdicts[3].verdict == reproduce.FAILS       # 40 ms vs uniform's ~18 ms for ΔE 9.0


def test_time_for_quality_interpolates_log_log():
    cells = synthetic_cells()
    # uniform: ΔE = 11·√(60/spp), time = spp/6 → ΔE 11 at 10 ms, 11/√2 at 20 ms.
    assert reproduce._time_for_quality(cells, "s", 11 / np.sqrt(2)) == pytest.approx(20.0, rel=1e-6)


def test_unknown_reproduction_lists_valid_names(tmp_path):
    with pytest.raises(InputError, match="unknown reproduction 'nope'; valid: lu2013"):
        reproduce.reproduce("nope", tmp_path)
    assert not any(tmp_path.iterdir())


def test_summary_has_verdict_table_and_plots(tmp_path):
    cells = synthetic_cells()
    fig2 = cells[cells.spp.isin([60, 180]) & (cells.estimator != "balanced_mis")]
    fig3 = cells[cells.estimator == "balanced_mis"]
    result = reproduce.Reproduction(
        title="test", setup_differences=["a difference"],
        tables={"fig2": fig2[["scene", "estimator", "spp", "mean_delta_e76", "used", "effective"]],
                "fig3": fig3[["scene", "spp", "mean_delta_e76"]],
                "timing": fig2[["scene", "estimator", "time_ms"]]},
        verdicts=reproduce.lu2013_verdicts(cells, ["s"]), results=cells)
    md = write_summary(tmp_path, result).read_text()
    html = (tmp_path / "summary.html").read_text()
    assert md.count("| **holds** |") == 4 and "a difference" in md
    assert html.count('class="holds"') == 4 and "<table>" in html
    for plot in ("fig3_error_vs_spp.png", "fig2_samples.png"):
        assert (tmp_path / plot).stat().st_size > 1000 and plot in md and plot in html


def test_lu2013_end_to_end_on_tiny_images(tmp_path):
    summary = reproduce.reproduce("lu2013", tmp_path, seeds=1, progress=False,
                                  resolution=(10, 10), env_res=8)
    text = summary.read_text()
    verdicts = [line for line in text.splitlines() if line.startswith("| ") and "**" in line]
    assert len(verdicts) == 4
    assert all(any(v in line for v in ("**holds**", "**partly holds**", "**does not hold**"))
               for line in verdicts)
    table = pd.read_parquet(tmp_path / "results.parquet")
    assert set(table.estimator) == {"uniform", "balanced", "balanced_mis"}
    assert set(table.scene) == set(reproduce.LU2013_SCENES)
    assert (table.nonfinite == 0).all() and (tmp_path / "summary.html").exists()
