"""``iblbench report``: the static HTML report of a run (tables, plots, images, sample picture).

One tiny real run (24×24 pixels, 8×8 cube faces, uniform and balanced at 4 and 16 spp) is made
in-process and reported once for the module; the browser test opens the page in Debian's
headless Chromium when it is installed.
"""
from __future__ import annotations

import html.parser
import io
import json
import math
import os
import pathlib
import re
import shutil

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from iblbench.estimators.light_pool import TICKS_PER_SAMPLE
from iblbench import cli
from iblbench.harness.protocol.metrics import delta_e_images, exposure
from iblbench.harness.protocol.runner import RunConfig, run
from iblbench.reports import plots
from iblbench.reports.plots import pareto_front
from iblbench.reports.previews import HEAT_SCALE, heat_scale, write_heat_map, write_preview
from iblbench.harness.protocol.report_inputs import read_pool_picture, read_surface
from iblbench.reports.images import default_pixel
from iblbench.reports.report import write_report
from iblbench.reports.tables import load_run, not_computed, summarize, summary_html
from iblbench.scenes import cubemap
from iblbench.foundation.errors import InputError
from iblbench.scenes.gbuffer import GBuffer
from iblbench.scenes.imageio import read_exr

SPP = (4, 16)
ESTIMATORS = ("uniform", "balanced")


class _Page(html.parser.HTMLParser):
    """Image sources, tags and the cells of every table of a page."""

    def __init__(self):
        super().__init__()
        self.images: list[str] = []
        self.options: list[str] = []
        self.scripts: list[dict] = []
        self.tags: list[str] = []
        self.tables: list[dict] = []
        self.h3: list[str] = []
        self._cell = None
        self._in_h3 = False

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.append(tag)
        if tag == "img":
            self.images.append(attrs.get("src"))
        elif tag == "option":
            self.options.append(attrs.get("value"))
        elif tag == "script":
            self.scripts.append(attrs)
        elif tag == "table":
            self.tables.append({"class": attrs.get("class", ""), "rows": []})
        elif tag == "tr" and self.tables:
            self.tables[-1]["rows"].append([])
        elif tag in ("td", "th"):
            self._cell = ""
        elif tag == "h3":
            self._in_h3 = True
            self.h3.append("")

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1]["rows"][-1].append(self._cell.strip())
            self._cell = None
        elif tag == "h3":
            self._in_h3 = False

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data
        if self._in_h3:
            self.h3[-1] += data


def _parse(path: pathlib.Path) -> _Page:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8"))
    return page


@pytest.fixture(scope="module")
def reported(tmp_path_factory):
    out = tmp_path_factory.mktemp("report-run")
    run(RunConfig(out=out, scenes=("sphere-sun",), estimators=ESTIMATORS, spp=SPP, seeds=1,
                  resolution=(24, 24), env_res=8, save_inputs=True, progress=False))
    return out, write_report(out)


def test_page_is_self_contained(reported):
    out, context = reported
    index = out / "report" / "index.html"
    assert context["path"] == index and index.is_file()
    page = _parse(index)
    assert "link" not in page.tags and page.scripts == [{}]        # one inline script, no src
    assert len(page.images) >= 10                                   # 3 plots + grid + bar + picture
    report = (out / "report").resolve()
    # The viewer's A and B each offer the reference and, per estimator and spp, the estimate and
    # its heat map.
    choices = [value for value in page.options if value.endswith(".png")]
    assert len(choices) == 2 * len(set(choices)) == 2 * (1 + 2 * len(ESTIMATORS) * len(SPP))
    for src in page.images + choices:
        assert src and "://" not in src and not src.startswith("/"), src
        target = (report / src).resolve()
        assert target.is_relative_to(report), src
        assert target.is_file() and target.stat().st_size > 0, src
    # The grid shows the reference, each estimator at the largest common spp and its heat map.
    for name in ["reference.png"] + [f"{e}_spp16_s0{suffix}.png" for e in ESTIMATORS
                                     for suffix in ("", "_de76")]:
        assert f"images/sphere-sun/f0/{name}" in page.images, name
    assert "colour_bar.png" in page.images


def test_summary_table_lists_every_cell(reported):
    out, _ = reported
    page = _parse(out / "report" / "index.html")
    # The summary's two tables (errors; samples and time), after the answer's where the run's
    # times reach a headline budget (how fast 24² renders are decides that).
    first = next(i for i, t in enumerate(page.tables) if "mean ΔE76" in t["rows"][0])
    errors, cost = page.tables[first:first + 2]
    assert len(errors["rows"]) == len(cost["rows"])
    header = errors["rows"][0] + cost["rows"][0]
    rows = [a + b for a, b in zip(errors["rows"][1:], cost["rows"][1:])]
    assert all(a[:2] == b[:2] for a, b in zip(errors["rows"], cost["rows"]))   # same cells
    for column in ("estimator", "spp", "mean ΔE76", "mean ΔE2000", "relMSE", "effective ratio",
                   "ms/frame (device)", "ms/frame (host wall)",
                   "efficiency 1/(relMSE·s)"):
        assert column in header, column
    cells = {(r[header.index("estimator")], int(r[header.index("spp")])) for r in rows}
    assert cells == {(e, s) for e in ESTIMATORS for s in SPP}
    # ms/frame is the cell's device time: the median of its timed renders, with an interval
    # even at one seed (the renders are its draws), which holds the median.
    table, _ = load_run(out)
    renders = table.set_index(["estimator", "spp"]).time_ms_renders
    for r in rows:
        cell = (r[header.index("estimator")], int(r[header.index("spp")]))
        median = float(np.median([float(v) for v in renders[cell].split()]))
        text = r[header.index("ms/frame (device)")]
        # Either "median ± half" (rounded at the half-width's second significant digit: within
        # half / 20), or, where a skewed time's interval would reach below zero, "median [low,
        # high]" (each at two significant digits: within 5% of the value).
        skewed = re.fullmatch(r"(\S+) \[(\S+), (\S+)\]", text)
        if skewed:
            shown, low, high = (float(part) for part in skewed.groups())
            assert abs(shown - median) <= 0.05 * median and low <= shown <= high and low < high, \
                (text, renders[cell])
        else:
            shown, half = (float(part) for part in text.split(" ± "))
            assert abs(shown - median) <= half / 10 and 0 < half, (text, renders[cell])
    # The efficiency column is 1/(relMSE·s) of the table's own relMSE and ms/frame.
    for r in summarize(table).itertuples():
        assert r.efficiency == pytest.approx(1e3 / (r.rel_mse * r.time_ms))   # one row per cell


def test_static_run_has_no_per_frame_section_and_shows_manifest(reported):
    out, _ = reported
    page = _parse(out / "report" / "index.html")
    text = (out / "report" / "index.html").read_text(encoding="utf-8")
    assert "Error per frame" not in page.h3
    assert "static (one frame)" in text
    for heading in ("Device", "Versions", "Stage timings", "Skipped stages", "Configuration"):
        assert heading in page.h3, heading
    assert "lab-reinhard-v1" in text


def test_sequences_get_an_error_per_frame_plot(reported, tmp_path):
    out, _ = reported
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    table = pd.read_parquet(copy / "results.parquet")
    second = table.assign(frame=1, mean_delta_e76=table.mean_delta_e76 * 1.5)
    pd.concat([table, second]).to_parquet(copy / "results.parquet", index=False)
    context = write_report(copy)
    page = _parse(context["path"])
    assert "Error per frame" in page.h3
    assert "per_frame_sphere-sun.png" in page.images
    assert (copy / "report" / "per_frame_sphere-sun.png").is_file()


def test_pareto_front_marks_only_non_dominated_points():
    time = [1.0, 2.0, 3.0, 4.0, 2.0, 5.0]
    error = [5.0, 3.0, 4.0, 1.0, 3.0, float("nan")]
    # (3, 4) is dominated by (2, 3); the two equal (2, 3) points do not dominate each other;
    # a NaN error is never on the front.
    assert pareto_front(time, error).tolist() == [True, True, False, True, True, False]
    assert pareto_front([1.0, 1.0], [2.0, 1.0]).tolist() == [False, True]   # tie in x, worse y


def test_summary_marks_a_dominated_cell():
    rows = []
    for estimator, spp, ms, rel in (("a", 4, 1.0, 0.5), ("a", 16, 4.0, 0.1),
                                    ("b", 4, 2.0, 0.6), ("b", 16, 3.0, 0.05)):
        for seed in (0, 1):
            rows.append({"scene": "s", "estimator": estimator, "spp": spp, "frame": 0,
                         "seed": seed, "mean_delta_e76": rel * 10, "mean_delta_e2000": rel * 8,
                         "rel_mse": rel, "used_samples": spp, "effective_samples": spp / 2,
                         "effective_ratio": 0.5, "nonfinite": 0, "time_ms": ms + seed * 0.01,
                         "time_ms_iqr": 0.0, "time_ms_host": 9.0})
    cells = summarize(pd.DataFrame(rows)).set_index(["estimator", "spp"])
    # b@4 (2.005 ms, 0.6) is slower and worse than a@4 (1.005 ms, 0.5); a@16 (4.005 ms, 0.1) is
    # slower and worse than b@16 (3.005 ms, 0.05); times ± 0.064 ms (t(0.975, 1) = 12.7 × 0.005)
    # and errors equal over seeds (point intervals): all separate.
    assert cells.pareto_rel_mse.to_dict() == {("a", 4): "◆", ("a", 16): "dominated",
                                             ("b", 4): "dominated", ("b", 16): "◆"}
    assert cells.loc[("a", 4), "time_ms"] == pytest.approx(1.005)   # mean over seeds


def _face_weights(normal: np.ndarray, env: np.ndarray) -> np.ndarray:
    """Lu 2013 Eq. 3 in numpy: F_f(n)·I_f, F_f the clamped cosines of the face's unit corners."""
    corners = cubemap.face_st_to_direction(np.repeat(np.arange(6), 4),
                                           np.tile([0.0, 1.0, 0.0, 1.0], 6),
                                           np.tile([0.0, 0.0, 1.0, 1.0], 6)).reshape(6, 4, 3)
    form = np.maximum(corners @ normal, 0.0).sum(axis=1)
    return form * cubemap.face_luminance_integrals(env)


def test_sample_picture_counts_match_the_split(reported):
    out, context = reported
    picture = context["scenes"][0]["picture"]
    assert [s.estimator for s in picture["data"]] == list(ESTIMATORS)
    assert picture["spp"] == max(SPP)
    gbuffer = GBuffer.load_npz(out / "inputs" / "sphere-sun" / "gbuffer.npz")
    env = np.load(out / "inputs" / "sphere-sun" / "env_f0.npy")
    x, y = picture["pixel"]
    assert (x, y) == default_pixel(gbuffer.mask) and gbuffer.mask[y, x]
    normal = gbuffer.normal[y, x].astype(np.float64)
    np.testing.assert_allclose(picture["normal"], normal)
    spp = picture["spp"]
    lit = cubemap.face_luminance_integrals(env) > 0
    expected = {"uniform": np.where(lit, spp / 6, 0.0)}
    weights = _face_weights(normal / np.linalg.norm(normal), env)
    expected["balanced"] = spp * weights / weights.sum()
    for sel in picture["data"]:
        per_face = len(sel.face) // 6
        assert per_face == spp + 1                                # the estimators' pool size
        # N_f(n) from the estimator's own split kernel agrees with Eq. 3 computed here.
        np.testing.assert_allclose(sel.n_f, expected[sel.estimator], atol=2e-3)
        assert sel.ticks[:6].sum() == spp * TICKS_PER_SAMPLE and sel.ticks[6] == 0
        # Selected per face = ⌈N_f(n)⌉, the prefix of the face's pool entries.
        counted = np.bincount(sel.face[sel.selected], minlength=6)
        ceil = np.array([math.ceil(v - 1e-9) for v in sel.n_f])
        np.testing.assert_array_equal(counted, ceil)
        np.testing.assert_array_equal(sel.selected_per_face, ceil)
        cos = sel.directions @ (normal / np.linalg.norm(normal))
        np.testing.assert_array_equal(sel.effective, sel.selected & (cos > 0))
        assert sel.counts["pool"] == 6 * per_face * lit.mean()
    # Balancing moves samples above the horizon: balanced has more effective samples here.
    effective = {s.estimator: s.counts["effective"] for s in picture["data"]}
    assert effective["balanced"] > effective["uniform"]
    for src in picture["panels"]:
        assert (out / "report" / src).is_file()


def test_the_run_saves_the_g_buffer_s_normals_and_mask_and_the_frame_s_map(reported):
    """Issue 33: the report reads the picture's inputs from the run folder; they are the
    G-buffer and environment ``run --save-inputs`` saves in full."""
    out, _ = reported
    gbuffer = GBuffer.load_npz(out / "inputs" / "sphere-sun" / "gbuffer.npz")
    normal, mask = read_surface(out, "sphere-sun")
    np.testing.assert_array_equal(mask, gbuffer.mask)
    np.testing.assert_array_equal(normal, gbuffer.normal)
    picture = read_pool_picture(out, "sphere-sun", 0)
    np.testing.assert_array_equal(picture.env, np.load(out / "inputs" / "sphere-sun" / "env_f0.npy"))
    assert picture.spp == max(SPP) and list(picture.ticks) == list(ESTIMATORS)
    assert picture.ticks["uniform"].shape == (*mask.shape, 7)


def _refuse_scenes_and_devices(monkeypatch) -> None:
    """Loading a scene, tracing a G-buffer or opening a device fails the test."""
    import iblbench.estimators.runtime.device
    import iblbench.scenes.gbuffer
    import iblbench.scenes.registry

    def refused(*args, **kwargs):
        raise AssertionError("the report loaded a scene, traced or opened a device")

    for module, name in ((iblbench.scenes.registry, "load_scene"),
                         (iblbench.scenes.gbuffer, "cached_trace"),
                         (iblbench.scenes.gbuffer, "trace_gbuffer"),
                         (iblbench.estimators.runtime.device, "get_compute")):
        monkeypatch.setattr(module, name, refused)


def test_the_report_reads_only_the_run_folder(reported, tmp_path, monkeypatch):
    """Issue 33: the sample picture comes from the run folder, with no scene, trace or device."""
    _refuse_scenes_and_devices(monkeypatch)
    out, first = reported
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    picture = write_report(copy)["scenes"][0]["picture"]
    assert "saved by the run" in picture["source"]
    assert picture["selections"] == first["scenes"][0]["picture"]["selections"]


def test_a_run_folder_without_saved_inputs_reports_without_its_sample_picture(reported, tmp_path,
                                                                              monkeypatch):
    """A run folder made before runs saved the report's inputs still gets its page: the sample
    picture left out with a note, the heat maps over the reference's non-black pixels."""
    _refuse_scenes_and_devices(monkeypatch)
    out, _ = reported
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report", "inputs"))
    context = write_report(copy)
    assert "the run folder holds no inputs for it" in context["scenes"][0]["picture"]["error"]
    page = (copy / "report" / "index.html").read_text(encoding="utf-8")
    assert page.count("No sample picture: the run folder holds no inputs") == 1
    assert (copy / "report" / "images" / "sphere-sun" / "f0" / "uniform_spp16_s0_de76.png").is_file()


def _cli_error(capsys, *argv) -> str:
    assert cli.main(["report", *map(str, argv)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("iblbench: error: ") and err.count("\n") == 1, err
    return err


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, reported):
    assert "no such run directory" in _cli_error(capsys, tmp_path / "missing")
    assert "no results table" in _cli_error(capsys, tmp_path)
    (tmp_path / "results.parquet").write_bytes(b"PAR1 this is not parquet")
    assert "cannot read the results table" in _cli_error(capsys, tmp_path)
    pd.DataFrame({"scene": ["s"]}).to_parquet(tmp_path / "results.parquet")
    assert "missing columns" in _cli_error(capsys, tmp_path)
    out, _ = reported
    assert "--spp 5 is not in the run" in _cli_error(capsys, out, "--spp", "5")
    assert "not a covered pixel" in _cli_error(capsys, out, "--pixel", "0,0")
    with pytest.raises(InputError):
        load_run(tmp_path / "missing")


def test_cli_writes_the_report(reported, capsys):
    out, _ = reported
    assert cli.main(["report", str(out), "--pixel", "12,12"]) == 0
    assert "report/index.html" in capsys.readouterr().out
    assert "x=12, y=12" in (out / "report" / "index.html").read_text(encoding="utf-8")


CHROMIUM = shutil.which("chromium")


def _plot_series(fig) -> list[dict]:
    """Per axis of a figure: the labels of its error-bar series, each with whether it has a
    y-interval drawn at every point (finite ends: none is drawn with one seed), and the labels
    of its plain lines."""
    from matplotlib.container import ErrorbarContainer

    axes = []
    for ax in fig.axes:
        bars = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
        in_bars = {id(line) for c in bars for line in c.get_children()}
        axes.append({
            "errorbars": {c.get_label(): c.has_yerr and np.isfinite(
                np.asarray(c.lines[2][-1].get_segments())).all() for c in bars},
            "lines": [line.get_label() for line in ax.lines if id(line) not in in_bars]})
    return axes


@pytest.fixture(scope="module")
def two_seeds(reported, tmp_path_factory):
    """The tiny run with a second seed (errors × 1.5, times × 1.2) and an equal-time copy of
    every row: a report whose every aggregated table has an interval to show.  Its plots'
    series are recorded as :func:`_plot_series` gives them, by file name."""
    out, _ = reported
    copy = tmp_path_factory.mktemp("two-seeds") / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    table = pd.read_parquet(copy / "results.parquet")
    errors = ["mean_delta_e76", "mean_delta_e2000", "rel_mse"]

    def scaled(texts, factor):   # the per-render columns scaled with their figure
        return [" ".join(f"{float(v) * factor:.7g}" for v in text.split()) for text in texts]

    second = table.assign(seed=1, **{c: table[c] * 1.5 for c in errors},
                          **{f"{c}_renders": scaled(table[f"{c}_renders"], 1.5) for c in errors},
                          time_ms=table.time_ms * 1.2,
                          time_ms_renders=scaled(table.time_ms_renders, 1.2))
    both = pd.concat([table, second])
    # Each estimator's budget its median row time: inside its error-time curve's span, where
    # its slowest row's time (the budget before) could land beyond the span's 10% tolerance on
    # a loaded machine and leave no estimator ranked.
    timed = both.assign(time_budget_ms=both.groupby("estimator").time_ms.transform("median"))
    pd.concat([both, timed]).to_parquet(copy / "results.parquet", index=False)
    series, save = {}, plots._save

    def recording_save(fig, path):
        series[pathlib.Path(path).name] = _plot_series(fig)
        save(fig, path)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(plots, "_save", recording_save)
        context = write_report(copy)
    return copy, context, series


@pytest.fixture(scope="module")
def browser(two_seeds):
    """Headless Chromium (Debian's) on the two-seed report: a function that opens the page
    fresh and returns it with the list its console errors and script errors go to."""
    sync_api = pytest.importorskip("playwright.sync_api")
    if CHROMIUM is None:
        pytest.skip("no Chromium installed (Debian package 'chromium')")
    out, _, _ = two_seeds
    with sync_api.sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        page = chromium.new_page(viewport={"width": 1280, "height": 900})
        errors: list[str] = []
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))

        def open_page():
            page.goto((out / "report" / "index.html").resolve().as_uri())
            page.wait_for_load_state("load")
            return page, errors

        yield open_page
        chromium.close()


# Headers of the aggregated tables that are not figures over seeds.
NOT_AGGREGATED = {"estimator", "spp", "seeds", "non-finite px", "Pareto (relMSE)", "Pareto (ΔE76)",
                  "budget (ms/frame)", "spp run", "within ±10%", "scene", "stage", "why",
                  "times", "times built", "total ms"}
# mean ± half-width, or mean [low, high] where a positive interval is wider than its figure
INTERVAL = r"\S+ ± \S+|\S+ \[\S+, \S+\]"
NUMBER = re.compile(r"[-+]?[\d.]+(e[-+]?\d+)?")


def test_report_renders_in_headless_chromium(browser):
    """Every image loads, no script error, and every table shows each figure aggregated over
    seeds (the summary's two tables and the equal-time table) as mean ± half-width (mean [low,
    high] where that would reach below zero); the stage timings as an interval over builds (one
    build: "n=1, no interval").  Exempt: the manifest's key/value tables and the sample
    picture's counts (one pixel of seed 0, nothing averaged)."""
    page, errors = browser()
    images = page.evaluate("Array.from(document.images).map(i => "
                           "[i.getAttribute('src'), i.complete, i.naturalWidth])")
    tables = page.evaluate("Array.from(document.querySelectorAll('table')).map(t => [t.className,"
                           " Array.from(t.rows).map(r => Array.from(r.cells).map("
                           "c => c.innerText.trim()))])")
    captions = page.evaluate("Array.from(document.querySelectorAll('figure.tile figcaption'))"
                             ".map(c => c.innerText)")
    assert len(images) >= 10
    broken = [src for src, complete, width in images if not complete or width == 0]
    assert not broken, broken
    assert not errors, errors
    # The answer's tables (checked below) give intervals as [low, high].
    checked = [(c, rows) for c, rows in tables
               if not {"kv", "counts", "ranking", "matrix"} & set(c.split())]
    # 2 of the summary, equal time, stage timings, skipped stages
    assert len(tables) - len(checked) >= 6 and len(checked) == 5
    # The cells' tables (the second summary table leaves its seeds to the first).
    over_seeds = [rows for _, rows in checked if "estimator" in rows[0]]
    assert len(over_seeds) == 3
    equal_time = next(rows[0] for rows in over_seeds if "spp run" in rows[0])
    for header in ("mean ΔE76", "relMSE", "effective spp", "achieved ms/frame (device)"):
        assert header in equal_time, header
    for header, *rows in [rows for _, rows in checked]:
        figures = [i for i, name in enumerate(header) if name not in NOT_AGGREGATED]
        assert len(figures) >= (3 if "estimator" in header else 0), header
        for row in rows:
            for i in figures:
                shown = (INTERVAL if "estimator" in header
                         else rf"{INTERVAL}|\S+ \(n=1, no interval\)")
                assert re.fullmatch(shown, row[i]), (header[i], row[i])
            # Every number outside those columns is one of the non-aggregated kinds.
            numbers = [header[i] for i, cell in enumerate(row) if NUMBER.fullmatch(cell)]
            assert set(numbers) <= NOT_AGGREGATED, numbers
    # The image grid's estimator captions give the cell's mean ΔE76 over the seeds too.
    estimates = [c for c in captions if "spp" in c]
    assert len(estimates) == len(ESTIMATORS) and all(" ± " in c for c in estimates), captions


def test_each_scene_opens_with_its_ranking_and_the_toggle_switches_the_plot(browser):
    """Issue 23: the page opens with the scene × budget matrix and the answer's plot; each scene
    section's first heading after its title is a ranking at a budget, with its verdict and a
    table whose every ranked row has an interval; the checkbox swaps the top-three plot for the
    every-estimator one and back, and both load."""
    page, errors = browser()
    first = page.evaluate("document.querySelector('h2').closest('section').id")
    assert first == "answer"
    assert page.locator("#answer table.matrix tr").count() == 1 + 1   # header + sphere-sun
    openings = page.evaluate("Array.from(document.querySelectorAll('section[id^=scene-]')).map("
                             "s => { const h = s.querySelector('h2').nextElementSibling;"
                             " return [h.tagName, h.className, h.innerText,"
                             " h.nextElementSibling.className]; })")
    assert openings and all(tag == "H3" and cls == "ranking" and text.startswith("Ranking at ")
                            and verdict == "verdict" for tag, cls, text, verdict in openings)
    rows = page.evaluate("Array.from(document.querySelectorAll('table.ranking tr')).slice(1).map("
                         "r => Array.from(r.cells).map(c => c.innerText.trim()))")
    ranked = [r for r in rows if r[0].isdigit()]
    assert ranked and all(re.fullmatch(r"\S+ \[\S+, \S+\]", r[2]) for r in ranked), rows
    plot = page.locator("#answer-plot")
    assert plot.get_attribute("src") == "answer_top3.png"
    page.locator("#answer-all").check()
    assert plot.get_attribute("src") == "answer_all.png"
    page.wait_for_function("document.getElementById('answer-plot').complete")
    assert page.evaluate("document.getElementById('answer-plot').naturalWidth") > 0
    page.locator("#answer-all").uncheck()
    assert plot.get_attribute("src") == "answer_top3.png"
    assert not errors, errors


def test_every_plot_draws_each_estimator_with_an_interval(two_seeds, browser):
    """Each plot the page shows: every estimator of the run is an error-bar series with its
    y-interval at every point (two seeds), and no plain line carries an estimator's name."""
    _, _, series = two_seeds
    page, _ = browser()
    shown = page.evaluate("Array.from(document.querySelectorAll('img.plot')).map("
                          "i => i.getAttribute('src'))")
    assert len(shown) >= 3
    for src in shown:
        axes = [ax for ax in series[src] if ax["errorbars"]]
        assert axes, src
        for ax in axes:
            labels = " ".join(ax["errorbars"])
            assert all(name in labels for name in ESTIMATORS), (src, ax)
            assert all(ax["errorbars"].values()), (src, ax)
            assert not [label for label in ax["lines"]
                        if label.split(":")[0] in ESTIMATORS], (src, ax)


def _pixels(locator) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(locator.screenshot())).convert("RGB")).astype(int)


def test_viewer_toggles_the_reference_slides_and_zooms(browser):
    page, errors = browser()
    viewer = page.locator("#viewer-sphere-sun")
    stage, split = viewer.locator('[data-role="stage"]'), viewer.locator('[data-role="split"]')
    image_a, image_b = viewer.locator('[data-role="img-a"]'), viewer.locator('[data-role="img-b"]')
    where = "images/sphere-sun/f0/"
    # It opens on the two estimators at the grid's spp, A left of the divider, B right.
    assert image_a.get_attribute("src") == f"{where}uniform_spp16_s0.png"
    assert image_b.get_attribute("src") == f"{where}balanced_spp16_s0.png"
    estimates = _pixels(stage)

    # The toggle shows the reference on both sides, and the estimates again.
    toggle = viewer.locator('[data-role="toggle"]')
    toggle.click()
    assert toggle.get_attribute("aria-pressed") == "true"
    assert image_a.get_attribute("src") == image_b.get_attribute("src") == f"{where}reference.png"
    assert viewer.locator('[data-role="tag-a"]').inner_text() == "reference"
    page.wait_for_function("Array.from(document.images).every(i => i.complete)")
    assert np.abs(_pixels(stage) - estimates).max() > 16          # another picture is shown
    toggle.click()
    assert image_a.get_attribute("src") == f"{where}uniform_spp16_s0.png"
    np.testing.assert_array_equal(_pixels(stage), estimates)

    # The slider moves the divider: at 100 all of the stage is A, at 0 all B; at 50 the left
    # half is A's and the right half B's (but for the divider's few columns).
    shots = {}
    for value in ("100", "0", "50"):
        split.fill(value)
        shots[value] = _pixels(stage)
    middle = shots["50"].shape[1] // 2
    left, right = slice(0, middle - 4), slice(middle + 4, None)
    np.testing.assert_array_equal(shots["50"][:, left], shots["100"][:, left])
    np.testing.assert_array_equal(shots["50"][:, right], shots["0"][:, right])
    assert np.abs(shots["100"] - shots["0"]).max() > 16          # A and B differ

    # A click zooms 4× on the crop around the clicked point: that point moves to the centre.
    stage.scroll_into_view_if_needed()
    box = viewer.locator(".viewer-layer").first.bounding_box()     # the unzoomed image
    # Whole pixels: Chromium reports a click's clientX/Y rounded.
    x, y = round(box["x"] + 0.3 * box["width"]), round(box["y"] + 0.35 * box["height"])
    page.mouse.click(x, y)
    assert viewer.locator('[data-role="zoom"]').input_value() == "4"
    shown = image_a.bounding_box()
    assert shown["width"] == pytest.approx(4 * box["width"], rel=1e-3)
    # The clicked point of the image, now:
    clicked_x = shown["x"] + (x - box["x"]) / box["width"] * shown["width"]
    clicked_y = shown["y"] + (y - box["y"]) / box["height"] * shown["height"]
    assert clicked_x == pytest.approx(box["x"] + box["width"] / 2, abs=1)
    assert clicked_y == pytest.approx(box["y"] + box["height"] / 2, abs=1)
    assert "4× crop" in viewer.locator('[data-role="caption"]').inner_text()
    assert not errors, errors


def test_no_table_is_wider_than_its_column_on_an_800_px_page(browser):
    """Issue 35: at 800 px the sample picture's counts and the summary's second table ran past
    the page (to 936 px), behind a scroll bar: their lists wrap, and a figure breaks from its
    interval (the whole figure above, the whole interval below)."""
    page, _ = browser()
    try:
        page.set_viewport_size({"width": 800, "height": 900})
        tables = page.evaluate("Array.from(document.querySelectorAll('table')).map(t => "
                               "[t.className, t.getBoundingClientRect().width, "
                               "t.parentElement.clientWidth])")
        cells = page.evaluate("Array.from(document.querySelectorAll('td.num')).map(c => "
                              "[c.innerText, Array.from(c.querySelectorAll('.spread')).map("
                              "s => s.getClientRects().length)])")
    finally:
        page.set_viewport_size({"width": 1280, "height": 900})
    assert any("counts" in name for name, _, _ in tables)
    assert [t for t in tables if t[1] > t[2] + 0.5] == []
    assert any(" ± " in text for text, _ in cells)
    # An interval is one span, on one line (its figure may be on the line above).
    assert all(spans == [1] for text, spans in cells if " ± " in text), cells


def test_clicking_a_grid_image_puts_it_into_the_viewer(browser):
    page, errors = browser()
    viewer = page.locator("#viewer-sphere-sun")
    heat = "images/sphere-sun/f0/uniform_spp16_s0_de76.png"
    page.locator(f'img[data-compare][src="{heat}"]').click()
    # The clicked image becomes B, the previous B becomes A.
    assert viewer.locator('[data-role="pick-b"]').input_value() == heat
    assert viewer.locator('[data-role="img-b"]').get_attribute("src") == heat
    assert viewer.locator('[data-role="img-a"]').get_attribute("src") == \
        "images/sphere-sun/f0/balanced_spp16_s0.png"
    assert "ΔE76 heat map" in viewer.locator('[data-role="caption"]').inner_text()
    assert not errors, errors


def test_the_report_draws_the_previews_from_the_run_s_exrs_once(reported, tmp_path):
    """The run writes EXRs only; the report draws each preview and heat map it shows, with the
    run's exposure and G-buffer mask, and a second report redraws only what is missing, older
    than its EXRs or on another heat scale."""
    out, _ = reported
    assert not list((out / "images").rglob("*.png"))
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    write_report(copy)
    run_images, drawn = copy / "images" / "sphere-sun" / "f0", copy / "report" / "images" / "sphere-sun" / "f0"
    reference = read_exr(run_images / "reference.exr")
    mask = GBuffer.load_npz(copy / "inputs" / "sphere-sun" / "gbuffer.npz").mask
    assert 0 < mask.sum() < mask.size and ((reference != 0).any(axis=-1) == mask).all()
    estimate = read_exr(run_images / "uniform_spp4_s0.exr")
    expected = tmp_path / "expected"
    expected.mkdir()
    write_preview(expected / "reference.png", reference, exposure(reference, mask))
    write_preview(expected / "estimate.png", estimate, exposure(reference, mask))
    write_heat_map(expected / "heat.png", delta_e_images(estimate, reference, mask)[0])
    for mine, theirs in (("reference.png", "reference.png"), ("uniform_spp4_s0.png", "estimate.png"),
                         ("uniform_spp4_s0_de76.png", "heat.png")):
        assert (np.asarray(Image.open(drawn / mine)) == np.asarray(Image.open(expected / theirs))).all()

    def stamps():
        return {path.name: path.stat().st_mtime_ns for path in drawn.iterdir()}

    first = stamps()
    assert len(first) == 1 + 2 * len(ESTIMATORS) * len(SPP)
    write_report(copy)
    assert stamps() == first                                        # nothing redrawn
    Image.new("RGB", (24, 24)).save(drawn / "uniform_spp16_s0_de76.png")   # untagged, as before
    newer = first["uniform_spp4_s0.png"] + 10**9
    os.utime(run_images / "uniform_spp4_s0.exr", ns=(newer, newer))
    write_report(copy)
    redrawn = {name for name, stamp in stamps().items() if stamp != first[name]}
    assert redrawn == {"uniform_spp16_s0_de76.png", "uniform_spp4_s0.png", "uniform_spp4_s0_de76.png"}
    assert heat_scale(drawn / "uniform_spp16_s0_de76.png") == HEAT_SCALE


def test_a_metric_the_run_left_out_is_said_not_computed(reported, tmp_path):
    """Issue 23: a run that leaves FLIP out (the default sweep does) showed no FLIP anywhere and
    said nothing of it; the page and the manifest now say it was not computed."""
    out, context = reported                       # every metric computed: nothing to say
    assert context["not_computed"] == []
    assert "Not computed" not in (out / "report" / "index.html").read_text(encoding="utf-8")
    left_out = tmp_path / "run"
    run(RunConfig(out=left_out, scenes=("sphere-sun",), estimators=("uniform",), spp=(4,), seeds=1,
                  resolution=(16, 16), env_res=8, repeats=1, metrics=("de76", "de2000", "relmse"),
                  progress=False))
    page = " ".join(write_report(left_out)["path"].read_text(encoding="utf-8").split())
    assert "Not computed in this run: FLIP. The sweep's metrics left it out" in page
    skipped = json.loads((left_out / "manifest.json").read_text())["skipped"]
    assert [entry["stage"] for entry in skipped if "scene" not in entry] == ["flip"]


def test_a_report_again_draws_only_the_figures_whose_data_changed(reported, tmp_path, monkeypatch):
    """Issue 23 (report speed): every report drew every figure again, most of its time; one
    that follows no change draws none, nor one with another spp (the run saved the sample
    picture's pool at one spp: issue 33), and a change to a scene's cells, or a figure gone,
    draws those again."""
    import iblbench.reports.sample_picture

    out, _ = reported
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    drawn = []
    for module, name in [(plots, name) for name in (
            "plot_error_vs_time", "plot_convergence", "plot_effective", "plot_extras",
            "write_colour_bar", "plot_answer")] + [(iblbench.reports.sample_picture,
                                                   "plot_sample_picture")]:
        def counted(*args, _plot=getattr(module, name), **kwargs):
            drawn.append(_plot.__name__)
            return _plot(*args, **kwargs)
        counted.__name__ = name
        monkeypatch.setattr(module, name, counted)
    scene_figures = ["plot_convergence", "plot_effective", "plot_error_vs_time", "plot_extras"]
    first = write_report(copy)
    # plot_answer only where the run's times reach a headline budget (how fast 24² renders are).
    assert sorted(d for d in drawn if d != "plot_answer") == sorted(
        scene_figures + ["write_colour_bar"] + ["plot_sample_picture"] * 2)   # uniform's and balanced's
    drawn.clear()
    again = write_report(copy, seed=0)
    assert drawn == [] and again["scenes"][0]["figures"] == first["scenes"][0]["figures"]
    assert again["scenes"][0]["extra_columns"] == first["scenes"][0]["extra_columns"] == ["FLIP"]
    (copy / "report" / first["scenes"][0]["figures"]["spp"]).unlink()
    write_report(copy)
    assert drawn == ["plot_convergence"]
    drawn.clear()
    table = pd.read_parquet(copy / "results.parquet")
    table.drop(index=0).to_parquet(copy / "results.parquet")   # a cell fewer
    write_report(copy)
    assert sorted(d for d in drawn if d != "plot_answer") == scene_figures
    drawn.clear()
    other = write_report(copy, spp=SPP[0])
    assert drawn == [] and "saved the pool at 16 spp only" in other["scenes"][0]["picture"]["error"]


# --- the report shows what the run has, from any working directory -------------------------------


def test_seed_or_frame_not_in_the_run_is_an_error_naming_the_run_s(reported, capsys):
    out, _ = reported
    assert "--seed 3 is not in the run (seed: 0)" in _cli_error(capsys, out, "--seed", "3")
    assert "--frame 2 is not in the run (frame: 0)" in _cli_error(capsys, out, "--frame", "2")


def test_a_sequence_scene_without_the_frame_is_an_error(reported, tmp_path, capsys):
    out, _ = reported
    copy = tmp_path / "run"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("report"))
    table = pd.read_parquet(copy / "results.parquet")
    frames = pd.concat([table.assign(frame=f) for f in (3, 6)])
    pd.concat([table.assign(scene="other"), frames]).to_parquet(copy / "results.parquet")
    # Frame 0 is in the run (scene "other") but not among sphere-sun's frames 3 and 6.
    assert "--frame 0 is not in scene sphere-sun (frame: 3, 6)" in _cli_error(
        capsys, copy, "--frame", "0")


def test_a_user_scene_run_reports_from_another_working_directory(tmp_path, monkeypatch):
    """A user scene's sample picture is read from the run folder, whatever the working directory
    of ``report`` (it reloads no scene file)."""
    import trimesh

    folder = tmp_path / "made-here" / "scene"
    folder.mkdir(parents=True)
    trimesh.creation.icosphere(subdivisions=1).export(folder / "ball.obj")
    np.save(folder / "sky.npy", np.full((6, 8, 8, 3), 0.5, np.float32))
    (folder / "ball.toml").write_text(
        '[mesh]\npath = "ball.obj"\n\n[environment]\npath = "sky.npy"\n\n'
        "[camera]\neye = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\n\n"
        "[render]\nwidth = 12\nheight = 12\n")
    out = tmp_path / "out"
    monkeypatch.chdir(tmp_path / "made-here")
    run(RunConfig(out=out, scenes=("scene/ball.toml",), estimators=("uniform",), spp=(4,),
                  seeds=1, progress=False))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    picture = write_report(out)["scenes"][0]["picture"]
    assert "saved by the run" in picture["source"] and len(picture["panels"]) == 1
    assert read_surface(out, "ball")[1].shape == (12, 12)


# --- intervals over seeds (issue 11) ---------------------------------------------------------------

T_975_2 = 4.302652729911275   # Student t, two-sided 95%, 2 degrees of freedom (printed tables)


def _seed_rows(estimator: str, spp: int, per_seed: list[tuple[float, float]], ms: float,
               **columns) -> list[dict]:
    """One cell of a synthetic results table: two frames per seed, whose values are given."""
    return [{"scene": "s", "estimator": estimator, "spp": spp, "frame": frame, "seed": seed,
             "time_budget_ms": math.nan, "mean_delta_e76": pair[frame],
             "mean_delta_e2000": pair[frame] / 2, "rel_mse": pair[frame] / 10,
             "used_samples": spp, "effective_samples": spp / 2, "effective_ratio": 0.5,
             "nonfinite": 0, "time_ms": ms * pair[frame], "time_ms_iqr": 0.0,
             "time_ms_host": 9.0, "evaluations": float(spp), **columns}
            for seed, pair in enumerate(per_seed) for frame in (0, 1)]


# Per-seed frame means 1, 2 and 6: mean 3, median 2, sd √7.
KNOWN = [(0.5, 1.5), (2.0, 2.0), (5.0, 7.0)]
KNOWN_HALF = T_975_2 * math.sqrt(7.0) / math.sqrt(3.0)


def test_report_table_shows_the_mean_over_seeds_and_its_t_interval(tmp_path):
    table = pd.DataFrame(_seed_rows("a", 16, KNOWN, ms=2.0))
    row = summarize(table).iloc[0]
    assert row.mean_delta_e76 == pytest.approx(3.0)          # the mean, not the median 2
    assert (row.mean_delta_e76_low, row.mean_delta_e76_high) == pytest.approx(
        (3.0 - KNOWN_HALF, 3.0 + KNOWN_HALF))
    assert (row.time_ms, row.time_ms_half) == pytest.approx((6.0, 2.0 * KNOWN_HALF))
    page = _Page()
    page.feed(str(summary_html(summarize(table))))
    header, cells = page.tables[0]["rows"]
    shown = dict(zip(header, cells))
    assert shown["seeds"] == "3"
    assert shown["mean ΔE76"] == "3.0 ± 6.6"                 # rounded at 6.57's second digit
    assert shown["relMSE"] == "0.30 ± 0.66"
    assert shown["ms/frame (device)"] == "6 ± 13"


def _captured_figures(monkeypatch) -> list:
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig))
    return figures


def test_plots_draw_each_cells_interval_as_an_error_bar(monkeypatch):
    from matplotlib.container import ErrorbarContainer

    table = pd.DataFrame(_seed_rows("a", 4, KNOWN, ms=1.0)
                         + _seed_rows("a", 16, [(v / 2, w / 2) for v, w in KNOWN], ms=3.0))
    cells = summarize(table)
    figures = _captured_figures(monkeypatch)
    plots.plot_convergence(pathlib.Path("unused.png"), cells, "s")
    plots.plot_error_vs_time(pathlib.Path("unused.png"), cells, "s")
    convergence, against_time = figures
    ax = convergence.axes[1]                                 # mean ΔE76 against spp
    bars = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
    assert len(bars) == 1 and bars[0].has_yerr
    segments = sorted(tuple(map(tuple, s)) for s in bars[0].lines[2][0].get_segments())
    expected = [((4.0, 3.0 - KNOWN_HALF), (4.0, 3.0 + KNOWN_HALF)),
                ((16.0, 1.5 - KNOWN_HALF / 2), (16.0, 1.5 + KNOWN_HALF / 2))]
    np.testing.assert_allclose(np.array(segments), np.array(expected))
    time_bars = [c for c in against_time.axes[0].containers if isinstance(c, ErrorbarContainer)]
    assert time_bars and time_bars[0].has_xerr and time_bars[0].has_yerr


def test_a_dozen_estimators_each_get_their_own_colour_and_marker_and_one_legend_entry(monkeypatch):
    """The default sweep puts every estimator (a dozen) on one error-time plane: no two may share
    a colour and a marker, and the figure lists each once in a legend under both panels."""
    names = [f"e{i}" for i in range(14)]
    styles = plots._styles(pd.DataFrame({"estimator": names}))
    assert len({s["color"] for s in styles.values()}) == 14
    assert len({s["marker"] for s in styles.values()}) == 14
    many = plots._styles(pd.DataFrame({"estimator": [f"e{i}" for i in range(60)]}))
    assert len({(s["color"], s["marker"]) for s in many.values()}) == 60
    table = pd.DataFrame([row for i, name in enumerate(names[:12])
                          for row in _seed_rows(name, 16, KNOWN, ms=1.0 + i)])
    figures = _captured_figures(monkeypatch)
    plots.plot_error_vs_time(pathlib.Path("unused.png"), summarize(table), "s")
    (figure,) = figures
    assert all(ax.get_legend() is None for ax in figure.axes) and len(figure.legends) == 1
    labels = [text.get_text() for text in figure.legends[0].get_texts()]
    assert [label for label in labels if label in names] == names[:12]
    drawn = {(c.lines[0].get_color(), c.lines[0].get_marker()) for c in figure.axes[0].containers}
    assert len(drawn) == 12


def test_a_pareto_ordering_is_called_only_where_intervals_separate():
    steady = [(3.0, 3.0)] * 3
    rows = (_seed_rows("a", 16, KNOWN, ms=1.0, time_ms=1.0)       # 1 ms, ΔE 3 ± 6.6
            + _seed_rows("b", 16, [(v + 1, w + 1) for v, w in KNOWN], ms=1.0, time_ms=2.0)
            + _seed_rows("c", 16, steady, ms=1.0, time_ms=0.5)      # 0.5 ms, ΔE exactly 3
            + _seed_rows("d", 16, [(4.0, 4.0)] * 3, ms=1.0, time_ms=3.0))
    cells = summarize(pd.DataFrame(rows)).set_index("estimator")
    # b (2 ms, 4 ± 6.6) and a (1 ms, 3 ± 6.6) are behind c (0.5 ms, 3) by the means (a ties c in
    # ΔE), but their ΔE intervals contain c's: not resolved.  d (3 ms, exactly 4) is behind c in
    # both, with separated intervals: dominated.
    assert cells.pareto_delta_e76.to_dict() == {
        "a": "not resolved at 3 seeds", "b": "not resolved at 3 seeds", "c": "◆",
        "d": "dominated"}


def test_one_seed_resolves_no_ordering():
    table = pd.DataFrame(_seed_rows("a", 16, [(1.0, 1.0)], ms=1.0)
                         + _seed_rows("b", 16, [(2.0, 2.0)], ms=1.0))
    assert summarize(table).pareto_delta_e76.tolist() == ["◆", "not resolved at 1 seeds"]


def test_a_run_with_de76_alone_reports(tmp_path):
    """`run --metrics de76` leaves relMSE out (NaN): the report failed on it (KeyError 'rel_mse',
    then log-scaling an all-NaN axis); now its plots have the ΔE76 panel alone and its tables
    show relMSE as not there."""
    out = tmp_path / "run"
    run(RunConfig(out=out, scenes=("sphere-sun",), estimators=("uniform", "envmap"), spp=(4, 16),
                  seeds=1, resolution=(16, 16), env_res=8, metrics=("de76",), progress=False))
    page = (write_report(out)["path"]).read_text(encoding="utf-8")
    assert "error_vs_time_sphere-sun.png" in page and "convergence_sphere-sun.png" in page


def test_a_metric_outside_the_default_sweep_shows_in_the_tables_from_its_descriptor(tmp_path):
    """PSNR, known only to the metric registry, gets its column (mean over seeds 30, 31, 32 →
    31) under its descriptor's label; a default metric the rows lack is said not computed."""
    rows = _seed_rows("a", 16, KNOWN, ms=2.0)
    for row in rows:
        row["psnr"] = 30.0 + row["seed"]
    table = pd.DataFrame(rows)
    page = _Page()
    page.feed(str(summary_html(summarize(table))))
    header, cells = page.tables[0]["rows"]
    assert dict(zip(header, cells))["PSNR"].startswith("31")
    assert not_computed(table) == ["FLIP"]


def test_the_bias_table_reads_the_instances_tags_not_the_classs():
    """restir is tagged unbiased, restir{unbiased=false} biased: the bias table must list the
    second (an instance's tags, as the conformance suite reads them)."""
    from iblbench.harness.protocol.sweep import estimator_tags

    assert estimator_tags("restir").unbiased and not estimator_tags("restir{unbiased=false}").unbiased
