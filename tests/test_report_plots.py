"""The report's plots of FLIP, flicker and smc's ess/reinits, the per-frame plot at every spp, the
frame a sequence's images show (reports/frames.py), and the convergence warning on the page."""
from __future__ import annotations

import math
import pathlib
import shutil

import numpy as np
import pandas as pd
import pytest
from matplotlib.container import ErrorbarContainer

from iblbench.harness.protocol.runner import RunConfig, run
from iblbench.reports import plots
from iblbench.reports.frames import shown_frame
from iblbench.reports.report import write_report
from iblbench.scenes.imageio import read_exr, write_exr

T_975_1 = 12.706204736174698   # Student-t critical value, 1 degree of freedom (two seeds)


def _captured(monkeypatch) -> list:
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig))
    return figures


def _rows(extras: dict, frames: int = 3) -> pd.DataFrame:
    """Two seeds × ``frames`` frames of estimator "a" at spp 4 and 16, time 1 + seed ms, and each
    column of ``extras`` as a function (spp, frame, seed) → value."""
    rows = []
    for spp in (4, 16):
        for seed in (0, 1):
            for frame in range(frames):
                rows.append({"estimator": "a", "spp": spp, "frame": frame, "seed": seed,
                             "time_ms": 1.0 + seed,
                             **{c: f(spp, frame, seed) for c, f in extras.items()}})
    return pd.DataFrame(rows)


def _bars(ax) -> list[ErrorbarContainer]:
    return [c for c in ax.containers if isinstance(c, ErrorbarContainer)]


def test_flicker_is_averaged_over_the_frames_where_it_is_defined_with_its_interval():
    # Flicker NaN on frame 0; seed s has 1 + s on frames 1 and 2: per-seed means 1 and 2, so the
    # cell is 1.5 ± t(0.975, 1)·sd/√2 with sd = 1/√2.
    table = _rows({"flicker": lambda spp, frame, seed: math.nan if frame == 0 else 1.0 + seed})
    cells = plots.extra_cells(table, "flicker").set_index("spp")
    assert cells.loc[4, "flicker"] == pytest.approx(1.5)
    assert cells.loc[4, "flicker_half"] == pytest.approx(T_975_1 * (1 / math.sqrt(2)) / math.sqrt(2))
    assert plots.extra_cells(table, "ess") is None


def test_extras_are_plotted_with_error_bars_only_where_present(monkeypatch, tmp_path):
    figures = _captured(monkeypatch)
    table = _rows({"flip": lambda spp, frame, seed: (0.2 + 0.1 * seed) / spp,
                   "flicker": lambda spp, frame, seed: math.nan,           # a static scene's
                   "ess": lambda spp, frame, seed: math.nan if frame == 0 else spp / 2 + seed})
    ess = {"ess": {"label": "smc's ESS", "axis": "ESS", "log": True}}   # as a manifest has it
    assert plots.plot_extras(tmp_path / "x.png", table, "s", ess) == ["FLIP", "smc's ESS"]
    (figure,) = figures
    axes = [ax for ax in figure.axes if ax.has_data()]
    assert len(axes) == 3                                  # FLIP/spp, FLIP/time, ESS/spp
    assert [ax.get_xlabel().split(" (")[0] for ax in axes] == [
        "samples per pixel", "device time per frame", "samples per pixel"]
    for ax in axes:
        (bars,) = _bars(ax)
        assert bars.has_yerr
    flip_bars = _bars(axes[0])[0].lines[2][0].get_segments()
    # FLIP at 4 spp: seeds 0.05 and 0.075, mean 0.0625, half-width t·sd/√2 with sd 0.025/√2.
    half = T_975_1 * 0.025 / 2
    np.testing.assert_allclose(flip_bars[0], [[4, 0.0625 - half], [4, 0.0625 + half]])
    assert _bars(axes[1])[0].has_xerr                       # time has its interval too
    assert plots.plot_extras(tmp_path / "y.png", table[["estimator", "spp", "frame", "seed",
                                                        "time_ms"]], "s", ess) == []
    assert len(figures) == 1 and not (tmp_path / "y.png").exists()   # no empty plot


def test_the_per_frame_plot_has_a_row_for_every_spp_and_marks_the_shown_frame(monkeypatch):
    figures = _captured(monkeypatch)
    per_frame = pd.DataFrame([
        {"estimator": e, "spp": spp, "frame": f, "seeds": 2,
         **{f"{c}{suffix}": v for c in ("mean_delta_e76", "rel_mse")
            for suffix, v in (("", 1.0 / spp), ("_low", 0.5 / spp), ("_high", 1.5 / spp))}}
        for e in ("a", "b") for spp in (4, 16, 64) for f in range(5)])
    plots.plot_per_frame(pathlib.Path("unused.png"), per_frame, "s", shown=3)
    (figure,) = figures
    assert len(figure.axes) == 6                           # 3 spp × (relMSE, ΔE76)
    for ax, spp in zip(figure.axes[::2], (4, 16, 64)):
        assert ax.get_title(loc="left") == f"{spp} spp"
        bars = _bars(ax)
        assert len(bars) == 2                              # one per estimator
        ys = bars[0].lines[0].get_ydata()
        np.testing.assert_allclose(ys, 1.0 / spp)
    for ax in figure.axes:
        marks = [line for line in ax.lines if list(line.get_xdata()) == [3, 3]]
        assert len(marks) == 1


def _write_references(run_dir: pathlib.Path, means: dict[int, float]) -> None:
    for frame, value in means.items():
        folder = run_dir / "images" / "s" / f"f{frame}"
        folder.mkdir(parents=True)
        write_exr(folder / "reference.exr", np.full((4, 4, 3), value, np.float32))


def test_a_sequence_shows_its_median_luminance_frame(tmp_path):
    # Frame 0 is dark (twilight), the others brighter: the median of 0.01, 3, 1, 2, 5 is 2.
    _write_references(tmp_path, {0: 0.01, 1: 3.0, 2: 1.0, 3: 2.0, 4: 5.0})
    frame, rule = shown_frame(tmp_path, "s", [0, 1, 2, 3, 4])
    assert frame == 3 and "median" in rule
    # An even count: the lower median of 0.01, 3, 1, 2 is 1 (frame 2).
    assert shown_frame(tmp_path, "s", [0, 1, 2, 3])[0] == 2
    assert shown_frame(tmp_path, "s", [0, 1, 2, 3, 4], chosen=4) == (4, "chosen with report --frame")
    frame, rule = shown_frame(tmp_path, "s", [0, 1, 2, 3, 4, 5, 6])       # f5, f6 have none
    assert frame == 3 and "missing" in rule


@pytest.fixture(scope="module")
def smc_sequence(tmp_path_factory):
    """A tiny smc and uniform run over frames 9-12 of sphere-switch (the light comes on at
    frame 10), with FLIP, reported."""
    out = tmp_path_factory.mktemp("smc-sequence")
    run(RunConfig(out=out, scenes=("sphere-switch",), estimators=("uniform", "smc"), spp=(4, 16),
                  seeds=2, frames=slice(9, 13), resolution=(16, 16), env_res=8, repeats=1,
                  metrics=("de76", "relmse", "flip"), progress=False))
    return out, write_report(out)


def test_the_report_of_a_sequence_plots_the_extras_and_every_spp_per_frame(smc_sequence):
    out, context = smc_sequence
    (scene,) = context["scenes"]
    assert scene["extra_columns"] == ["FLIP", "flicker", "smc's ESS", "smc's re-inits"]
    page = context["path"].read_text(encoding="utf-8")
    assert f'src="{scene["extras"]}"' in page and (out / "report" / scene["extras"]).is_file()
    assert "<h3>FLIP, flicker, smc&#39;s ESS, smc&#39;s re-inits</h3>" in page
    assert (out / "report" / scene["per_frame"]).is_file()
    # The images show the median-luminance frame of the run's references, read here directly.
    means = {f: float((read_exr(out / "images" / "sphere-switch" / f"f{f}" / "reference.exr")
                       @ np.array([0.2126, 0.7152, 0.0722])).mean()) for f in range(9, 13)}
    assert means[scene["grid"]["frame"]] == sorted(means.values())[1]
    assert scene["grid"]["frame"] != 9                     # the light is off in the first frame
    assert f"Frame {scene['grid']['frame']} (the frame whose reference has the median" in page


def test_the_report_warns_where_convergence_is_flatter_than_the_tags_allow(smc_sequence, tmp_path):
    # uniform (unbiased) with a relMSE that does not fall from 4 to 16 spp (seeds 0.1 and 0.1001
    # at both): not converging, a warning on the page under the convergence plot.  smc (which
    # may level off on a sequence, not rise) rising ×1.18 with seeds ×3 apart: not resolved at
    # 2 seeds, a note.
    out, _ = smc_sequence
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    table = pd.read_parquet(copy / "results.parquet")
    flat = table.estimator == "uniform"
    table.loc[flat, "rel_mse"] = 0.1 + 1e-4 * table.loc[flat, "seed"]
    rising = table.estimator == "smc"
    spread = {(4, 0): 0.1, (4, 1): 0.3, (16, 0): 0.35, (16, 1): 0.12}
    table.loc[rising, "rel_mse"] = [spread[spp, seed] for spp, seed in
                                    zip(table.loc[rising, "spp"], table.loc[rising, "seed"])]
    table.to_parquet(copy / "results.parquet", index=False)
    context = write_report(copy)
    (scene,) = context["scenes"]
    assert len(scene["convergence"]) == 1
    assert scene["convergence"][0].startswith("uniform on sphere-switch: not converging: relMSE "
                                              "0.1 → 0.1 from 4 to 16 spp")
    assert len(scene["convergence_unresolved"]) == 1
    assert scene["convergence_unresolved"][0].startswith("smc on sphere-switch: not resolved at 2 "
                                                         "seeds: relMSE 0.2 → 0.235 from 4 to 16")
    page = context["path"].read_text(encoding="utf-8")
    convergence = page.index("<h3>Convergence</h3>")
    warning = page.index("<p class=\"warn\">Convergence flatter than the estimator's tags allow: "
                         "uniform on sphere-switch: not converging")
    note = page.index("<p class=\"note\">Convergence looks flatter than the estimator's tags "
                      "allow, but its interval cannot tell: smc on sphere-switch: not resolved")
    assert convergence < warning < note < page.index("<h3>Effective samples</h3>")
