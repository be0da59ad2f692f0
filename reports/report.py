"""``iblbench report DIR``: a self-contained static HTML report of one run → ``DIR/report/``.

``DIR/report/index.html`` opens from disk with no server: every image it shows (plots, the
colour bar, the sample pictures, the previews and heat maps it draws from the run's EXRs) lies
inside ``DIR/report`` and is referenced by a relative path; the page loads no script, stylesheet or font (its one
script, the compare viewer's, and its stylesheet are inline).

Contents, per scene: the summary (estimator × spp) in two tables, errors and samples/time, error
against time with the Pareto front, convergence against spp (with a warning where it is flatter
than the estimator's tags allow, :mod:`iblbench.harness.verify.convergence`), effective samples against
spp, FLIP, flicker and smc's ess/reinits where the run has them, error per frame at every spp
(sequences only), an image grid (reference, each estimator at one spp, ΔE76 heat maps on the
shared log scale of :mod:`.previews` with its colour bar), a compare viewer (any two of the
frame's images, A left and B right of a divider moved by a slider; a toggle that shows the
reference on both sides; a click zooms on the crop around the point) and Lu 2013 Fig. 1/2's
sample picture (:mod:`.sample_picture`); then the run's manifest.

Aggregation: a cell is (scene, estimator, spp).  Each seed's metrics are first averaged over the
frames, then the cell's value is the mean over seeds with its 95% Student-t interval
(:func:`iblbench.harness.protocol.stats.cell_intervals`, the one aggregation ``iblbench run`` prints too),
shown as ``mean ± half-width`` in every table (and the image grid's captions) and as error bars
in the plots; the manifest's stage timings are the mean over builds with its interval.  ms/frame
is the cell's device time per frame (build + sample + shade, :mod:`iblbench.harness.protocol.timing`),
aggregated the same way; efficiency = 1 / (relMSE · s per frame) is computed per seed and then
aggregated.
The Pareto fronts call a cell dominated only where the intervals of time and of error both
separate (:func:`iblbench.reports.plots.pareto_calls`); otherwise it is "not resolved at N
seeds".  Host wall time is shown beside device time and never ranks anything.  Equal-time cells
are tabled with their budget, the time they achieved and whether it is within ±10% of the
budget.

Several devices: a table whose rows several devices ran (a sweep spread over machines) has
every figure of time per device (:func:`iblbench.harness.protocol.stats.by_device`), never two
devices' times in one figure: the rankings, the samples-and-time table, the equal-time table,
error against time (and shadow rays) and the sequences at equal time are shown once per device,
headed by its name, and the opening matrix and plot have a row and panels per scene and device;
the errors (the errors table, convergence, effective samples, the image captions) are pooled
over the devices as they are for one.  A one-device table's page names no device there.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import pathlib
import pickle
import re

import jinja2
import markupsafe
import numpy as np
import pandas as pd

from iblbench.harness.verify.convergence import flatter_than_tags
from iblbench.harness.protocol.control import control_calls
from iblbench.harness.protocol.equal_time import TOLERANCE
from iblbench.harness.protocol.metrics import Scorer
from iblbench.harness.protocol.ranking import scene_rankings
from iblbench.harness.protocol.results import load_table
from iblbench.harness.protocol.stats import (LEVEL, by_device, cell_intervals, devices,
                                             interval_text, mean_ci, t_quantile)
from iblbench.harness.protocol.timing import TIME
from iblbench.reports import plots
from iblbench.reports.answer import (answer_context, busy_sentence, ranking_table,
                                     sequence_context)
from iblbench.reports.frames import shown_frame
from iblbench.reports.previews import HEAT_SCALE, heat_scale, write_heat_map, write_preview
from iblbench.scenes import cubemap
from iblbench.scenes.atomic import atomic_path
from iblbench.scenes.errors import InputError, argument
from iblbench.scenes.imageio import read_exr

REQUIRED_COLUMNS = ("scene", "estimator", "spp", "frame", "seed", "mean_delta_e76",
                    "mean_delta_e2000", "rel_mse", "used_samples", "effective_samples",
                    "effective_ratio", "nonfinite", TIME, "time_ms_iqr", "time_ms_host")
MEAN_COLUMNS = ("mean_delta_e76", "mean_delta_e2000", "rel_mse", "used_samples",
                "effective_samples", "effective_ratio", "shadow_rays")
# Each is a cell's figure with its interval (module docstring).  The timed renders' IQR is not
# among them: the time's own interval says their spread (issue 23).
INTERVAL_COLUMNS = (*MEAN_COLUMNS, "flip", TIME, "time_ms_host")
SHOWN_INTERVALS = (*INTERVAL_COLUMNS, "efficiency")   # efficiency: summarize derives it

_TEMPLATES = jinja2.Environment(
    loader=jinja2.PackageLoader("iblbench.reports", "templates"),
    autoescape=jinja2.select_autoescape(["html", "j2"]), trim_blocks=True, lstrip_blocks=True)


# ---- input ------------------------------------------------------------------------------------

def load_run(run_dir: pathlib.Path) -> tuple[pd.DataFrame, dict | None]:
    """The results table and the manifest (None when the run has none) of ``run_dir``."""
    run_dir = pathlib.Path(run_dir)
    table = load_table(run_dir, REQUIRED_COLUMNS)
    if table.empty:
        raise InputError(run_dir / "results.parquet", "the results table has no rows")
    manifest = None
    manifest_path = run_dir / "manifest.json"
    if manifest_path.is_file():
        try:
            manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise InputError(manifest_path, f"cannot read the manifest ({error})") from None
        if not isinstance(manifest, dict):
            raise InputError(manifest_path, "the manifest is not a JSON object")
    return table, manifest


def summarize(table: pd.DataFrame) -> pd.DataFrame:
    """One row per (scene, estimator, spp): each column of INTERVAL_COLUMNS the table has (FLIP
    only where it was computed) as :func:`iblbench.harness.protocol.stats.cell_intervals` gives it
    (errors over the cell's replicates, the time as the median of its timed renders, each with
    ``_low``, ``_high``, ``_half``, ``_n``, ``_method``); ``seeds`` counts the seeds,
    ``nonfinite`` sums every row's; ``efficiency`` = 1/(relMSE·s) of the cell's figures, its
    interval from their bounds (low: both high; high: both low), so it is at least 95%;
    ``pareto_rel_mse``/``pareto_delta_e76`` are :func:`~.plots.pareto_calls` over the scene's
    cells (time, error).  A table of several devices gets no time, efficiency or Pareto call
    (pooled over devices: :func:`device_cells` has them per device)."""
    keys = ["scene", "estimator", "spp"]
    several = len(devices(table)) > 1
    # The errors the plots and Pareto calls read stay, NaN, where the run left them out
    # (--metrics de76 has no relMSE); any other figure left out is dropped.
    columns = [c for c in INTERVAL_COLUMNS if c in table
               and (table[c].notna().any() or c in ("mean_delta_e76", "rel_mse"))
               and not (several and c.startswith("time_"))]
    cells = cell_intervals(table, keys, columns)
    cells["nonfinite"] = table.groupby(keys, sort=False).nonfinite.sum()
    cells = cells.reset_index()
    if "rel_mse" in cells and TIME in cells:
        with np.errstate(divide="ignore", invalid="ignore"):
            cells["efficiency"] = 1e3 / (cells.rel_mse * cells[TIME])
            cells["efficiency_low"] = 1e3 / (cells.rel_mse_high * cells[f"{TIME}_high"])
            cells["efficiency_high"] = 1e3 / (cells.rel_mse_low * cells[f"{TIME}_low"])
        cells["efficiency_half"] = (cells.efficiency_high - cells.efficiency_low) / 2
    for column in ("rel_mse", "mean_delta_e76") if TIME in cells else ():
        name = f"pareto_{column.replace('mean_', '')}"
        cells[name] = ""
        for _, rows in cells.groupby("scene", sort=False):
            cells.loc[rows.index, name] = plots.pareto_calls(rows, column)
    order = {name: i for i, name in enumerate(dict.fromkeys(table.estimator))}
    cells["_order"] = cells.estimator.map(order)
    scene_order = {name: i for i, name in enumerate(dict.fromkeys(table.scene))}
    cells["_scene"] = cells.scene.map(scene_order)
    return cells.sort_values(["_scene", "_order", "spp"]).drop(columns=["_order", "_scene"]) \
        .reset_index(drop=True)


def device_cells(table: pd.DataFrame, cells: pd.DataFrame) -> list[tuple[str | None, pd.DataFrame]]:
    """The cells each device's figures of time are shown from: ``[(None, cells)]`` for a
    one-device table (``cells``: :func:`summarize`'s of it), else each device's name and
    :func:`summarize` of its rows."""
    views = by_device(table)
    return [(None, cells)] if len(views) == 1 else [(d, summarize(rows)) for d, rows in views]


def on_device(rows: pd.DataFrame, device: str | None) -> pd.DataFrame:
    """The rows of ``device``; all of them for None (a one-device table)."""
    return rows if device is None else rows[rows.device == device]


def split_equal_time(table: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(equal-spp rows, equal-time rows): rows with a ``time_budget_ms`` are the cells of an
    equal-time comparison (``run --time-budget-ms``), reported in their own table; a table of
    only such rows is reported as ordinary cells too."""
    if "time_budget_ms" not in table.columns:
        return table, table.iloc[:0]
    timed = table.time_budget_ms.notna()
    if timed.all():
        return table, table[timed]
    return table[~timed], table[timed]


def equal_time_cells(rows: pd.DataFrame) -> pd.DataFrame:
    """Error at equal time: per (budget, estimator) the spp run, errors and the achieved device
    time per frame (means over seeds of the means over frames, with their intervals, as in
    :func:`summarize`) and whether the achieved time is within ±TOLERANCE of the budget."""
    keys = ["time_budget_ms", "estimator", "spp"]
    columns = [c for c in ("mean_delta_e76", "mean_delta_e2000", "rel_mse", "flip",
                           "effective_samples", "effective_ratio", TIME)
               if c in rows and (c != "flip" or rows[c].notna().any())]   # FLIP where computed
    cells = cell_intervals(rows, keys, columns).reset_index()
    cells["within"] = (cells[TIME] - cells.time_budget_ms).abs() <= TOLERANCE * cells.time_budget_ms
    return cells.sort_values(["time_budget_ms", "rel_mse"])


def equal_time_html(rows: pd.DataFrame) -> markupsafe.Markup:
    cells = equal_time_cells(rows)
    shown = pd.DataFrame({
        "budget (ms/frame)": cells.time_budget_ms, "estimator": cells.estimator,
        "spp run": cells.spp, "seeds": cells.seeds,
        **{header: _intervals(cells, column) for column, header in (
            ("mean_delta_e76", "mean ΔE76"), ("mean_delta_e2000", "mean ΔE2000"),
            ("rel_mse", "relMSE"), ("flip", "FLIP"), ("effective_samples", "effective spp"),
            ("effective_ratio", "effective ratio"), (TIME, "achieved ms/frame (device)"))
           if column in cells},
        f"within ±{TOLERANCE:.0%}": cells.within.map({True: "yes", False: "NO"})})
    return _table_html(shown, "summary equal-time")


def _intervals(cells: pd.DataFrame, column: str) -> list[str]:
    """The column's cells as ``mean ± half-width`` (``stats.interval_text``)."""
    counts = cells[f"{column}_n"] if f"{column}_n" in cells else cells.seeds
    return [interval_text(mean, half, n) for mean, half, n in
            zip(cells[column], cells[f"{column}_half"], counts)]


_TABLE_COLUMNS = {   # summary column → header (with units)
    "estimator": "estimator", "spp": "spp", "seeds": "seeds",
    "mean_delta_e76": "mean ΔE76", "mean_delta_e2000": "mean ΔE2000", "rel_mse": "relMSE",
    "effective_ratio": "effective ratio", "effective_samples": "effective spp",
    "used_samples": "used spp", "flip": "FLIP", "time_ms": "ms/frame (device)",
    "time_ms_host": "ms/frame (host wall)",
    "efficiency": "efficiency 1/(relMSE·s)", "shadow_rays": "shadow rays/px",
    "nonfinite": "non-finite px", "pareto_rel_mse": "Pareto (relMSE)",
    "pareto_delta_e76": "Pareto (ΔE76)",
}


def _number(value) -> str:
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            return "–"
        return f"{value:.4g}"
    return str(value)


# The summary of a scene in two tables, so that neither runs off a page 1280 px wide: the
# errors, then samples and cost (where a column not named here goes too).
ERROR_COLUMNS = ("mean_delta_e76", "mean_delta_e2000", "rel_mse", "flip", "nonfinite",
                 "pareto_rel_mse", "pareto_delta_e76")
KEY_COLUMNS = ("estimator", "spp", "seeds")


def summary_html(cells: pd.DataFrame, columns=None) -> markupsafe.Markup:
    """The summary table of one scene's ``columns`` (default: every one of _TABLE_COLUMNS the
    cells have); every aggregated figure as ``mean ± half-width``."""
    columns = [c for c in (columns or _TABLE_COLUMNS) if c in cells]
    frame = pd.DataFrame({_TABLE_COLUMNS[c]: _intervals(cells, c) if c in SHOWN_INTERVALS
                          else cells[c] for c in columns})
    return _table_html(frame, "summary")


def summary_tables(cells: pd.DataFrame, views=None) -> dict[str, markupsafe.Markup]:
    """Title → table: the scene's errors, then its samples and cost (ERROR_COLUMNS); the seeds
    only in the first, so that the second fits a page 800 px wide.  ``views``
    (:func:`device_cells`' of the scene, default ``[(None, cells)]``): the samples and cost
    once per device, each named and with its Pareto calls, where there are several."""
    tables = {"Errors": summary_html(cells, KEY_COLUMNS + ERROR_COLUMNS)}
    for device, shown in views or [(None, cells)]:
        rest = [c for c in _TABLE_COLUMNS if c not in ERROR_COLUMNS and c not in KEY_COLUMNS
                and not (c == "shadow_rays" and c in shown and (shown[c] == 0).all())]   # no V
        pareto = [c for c in ERROR_COLUMNS if c.startswith("pareto_")] if device else []
        title = "Samples and time" + (f" on {device}" if device else "")
        tables[title] = summary_html(shown, ["estimator", "spp"] + rest + pareto)
    return tables


def _dict_table(mapping: dict) -> markupsafe.Markup:
    frame = pd.DataFrame({"key": list(mapping), "value": [
        json.dumps(v) if isinstance(v, (list, dict)) else ("–" if v is None else _number(v))
        for v in mapping.values()]})
    return _table_html(frame, "kv", header=False)


# A number, an interval (``stats.interval_text``) or "–": such a column is right-aligned.
_NUMERIC = re.compile(r"[-+]?[\d.]+(e[-+]?\d+)?( ± \S+| \(n=\d+, no interval\))?|–")


def _table_html(frame: pd.DataFrame, classes: str, header: bool = True) -> markupsafe.Markup:
    """``frame`` as an escaped HTML table, cells by :func:`_number`; a column of numbers or
    intervals gets class "num" (right-aligned), text stays left."""
    text = frame.apply(lambda column: column.map(_number))   # DataFrame.map needs pandas 2.1
    numeric = [text[c].map(lambda v: _NUMERIC.fullmatch(v) is not None).all() for c in text]
    cell = "<td{}>{}</td>".format
    rows = ["<tr>" + "".join(cell(' class="num"' if n else "", markupsafe.escape(v))
                             for v, n in zip(values, numeric)) + "</tr>"
            for values in text.itertuples(index=False)]
    head = ("<thead><tr>" + "".join(f"<th>{markupsafe.escape(c)}</th>" for c in frame.columns)
            + "</tr></thead>") if header else ""
    return markupsafe.Markup(f'<table class="{classes}">{head}<tbody>{"".join(rows)}'
                             "</tbody></table>")


def _frame_html(frame: pd.DataFrame) -> markupsafe.Markup:
    return _table_html(frame, "summary")


# ---- images -----------------------------------------------------------------------------------

def choose_spp(table: pd.DataFrame, scene: str, frame: int, seed: int, spp: int | None) -> dict:
    """The spp shown per estimator: ``spp`` when given, else the largest spp every estimator
    of the scene ran (at this frame and seed); an estimator without it shows its own largest."""
    rows = table[(table.scene == scene) & (table.frame == frame) & (table.seed == seed)]
    by_estimator = {name: set(g.spp) for name, g in rows.groupby("estimator", sort=False)}
    if not by_estimator:
        return {}
    if spp is None:
        common = set.intersection(*by_estimator.values())
        spp = max(common) if common else None
    return {name: (spp if spp in have else max(have)) for name, have in by_estimator.items()}


class FramePreviews:
    """The PNG previews and ΔE76 heat maps of one (scene, frame), drawn into the report from the
    run's EXRs (the run writes no PNG: they cost it ~5 ms of host time per cell, and a report
    shows one frame and seed).  A PNG no older than its EXRs (and, for a heat map, drawn on
    today's HEAT_SCALE) is kept, so a second report draws nothing.  The reference and the
    G-buffer's mask (``mask``, called at most once) are read only when something must be drawn:
    the exposure and the heat maps are the run's scorer's (:class:`~iblbench.harness.protocol.metrics.
    Scorer`), non-finite estimate values black as in its scoring.  Where the mask cannot be had
    (the scene left the registry, another resolution) the reference's non-black pixels stand in
    for it: the reference is black outside the mask, so only black covered pixels differ."""

    def __init__(self, run_images: pathlib.Path, report: pathlib.Path, where: str, mask):
        self.run_images, self.report, self.where, self._mask = run_images, report, where, mask
        self._scorer = None

    def _scorer_of_frame(self) -> Scorer:
        if self._scorer is None:
            reference = read_exr(self.run_images / "reference.exr")
            try:
                mask = self._mask()
            except InputError:
                mask = None
            if mask is None or mask.shape != reference.shape[:2]:
                mask = (reference != 0.0).any(axis=-1)
            self._scorer = Scorer(reference, mask, ("de76",))
        return self._scorer

    def _target(self, name: str, sources: list[pathlib.Path], scale: str | None = None):
        """(the PNG's path relative to the report or None when a source EXR is missing, whether
        it must be drawn)."""
        try:
            newest = max(source.stat().st_mtime_ns for source in sources)
        except FileNotFoundError:
            return None, False
        relative = f"{self.where}/{name}"
        target = self.report / relative
        try:
            stale = target.stat().st_mtime_ns < newest
        except FileNotFoundError:
            target.parent.mkdir(parents=True, exist_ok=True)
            return relative, True
        return relative, stale or (scale is not None and heat_scale(target) != scale)

    def reference(self) -> str | None:
        relative, draw = self._target("reference.png", [self.run_images / "reference.exr"])
        if draw:
            scorer = self._scorer_of_frame()
            write_preview(self.report / relative, scorer.reference, scorer.k)
        return relative

    def estimate(self, stem: str) -> tuple[str | None, str | None]:
        """The preview and the heat map of the estimate ``stem``; (None, None) when its EXR is
        missing or does not read whole (the page shows "no image" there instead of failing as a
        whole: issue 23; a resumed run renders such a cell again)."""
        sources = [self.run_images / f"{stem}.exr", self.run_images / "reference.exr"]
        preview, draw_preview = self._target(f"{stem}.png", sources[:1])
        heat, draw_heat = self._target(f"{stem}_de76.png", sources, HEAT_SCALE)
        if draw_preview or draw_heat:
            scorer = self._scorer_of_frame()
            try:
                radiance = read_exr(sources[0])
            except InputError:
                return None, None
            if draw_preview:
                write_preview(self.report / preview, radiance, scorer.k)
            if draw_heat:
                radiance = np.where(np.isfinite(radiance), radiance, 0.0)
                write_heat_map(self.report / heat, scorer.delta_e_images(radiance)[0])
        return preview, heat


def image_grid(run_dir, report, table, cells, scene, frame, seed, spp, mask) -> dict:
    """The images of one scene at (``frame``, ``seed``), drawn into the report by
    :class:`FramePreviews` (``mask``: a callable giving the scene's G-buffer mask): ``tiles``,
    the grid (the reference, each estimator at its :func:`choose_spp` spp and its ΔE76 heat map,
    captioned with the cell's mean ΔE76 over seeds and its interval), and ``viewer``, the
    compare viewer's ``choices`` (every estimate and heat map of the frame and seed, each spp)
    with the two estimators it opens on (``a``, ``b``) and the ``reference``."""
    previews = FramePreviews(pathlib.Path(run_dir) / "images" / scene / f"f{frame}",
                             pathlib.Path(report), f"images/{scene}/f{frame}", mask)
    chosen = choose_spp(table, scene, frame, seed, spp)
    rows = table[(table.scene == scene) & (table.frame == frame) & (table.seed == seed)]
    cell = cells[cells.scene == scene].set_index(["estimator", "spp"])
    reference = previews.reference()
    tiles = [{"title": "reference", "subtitle": ["exact quadrature"], "src": reference,
              "heat": None}]
    choices = [{"label": "reference (exact quadrature)", "src": reference}] if reference else []
    shown = {}
    for name, runs in rows.groupby("estimator", sort=False):
        for row in runs.sort_values("spp").to_dict("records"):
            n = int(row["spp"])
            src, heat = previews.estimate(_image_stem(row))
            choices += [{"label": label, "src": image} for label, image in (
                (f"{name} @ {n} spp", src), (f"{name} @ {n} spp: ΔE76 heat map", heat)) if image]
            if n != chosen[name]:
                continue
            over_seeds = cell.loc[(name, n)]
            tiles.append({"title": name, "src": src, "heat": heat, "subtitle": [
                f"{n} spp, mean ΔE76", f"seed {seed}: {row['mean_delta_e76']:.3g}",
                f"{over_seeds.seeds} seeds: " + interval_text(
                    over_seeds.mean_delta_e76, over_seeds.mean_delta_e76_half, over_seeds.seeds)]})
            if src:
                shown[name] = src
    pair = list(shown.values())[:2]
    pair = pair if len(pair) == 2 else [reference, *pair]   # one estimator: against the reference
    viewer = {"choices": choices, "reference": reference, "a": pair[0], "b": pair[-1]}
    return {"frame": frame, "seed": seed, "tiles": tiles, "viewer": viewer,
            "spp": sorted(set(chosen.values()))}


def bias_table(run_dir, table, cells, scene, frame, mask) -> markupsafe.Markup | None:
    """The bias left at the highest spp by each estimator of the scene tagged biased
    (``tags.unbiased = False``: fis, havran, smc), from the frame's estimate EXRs of every seed
    at that spp against the reference EXR, over covered pixels (``mask()``): the image-mean
    bias Σ Y(x)/Σ Y(r) − 1 in luminance, mean over seeds with its 95% interval, and the relMSE
    of the bias, mean(((m − r)² − s²/n)/(r² + 0.01)) with m and s a pixel's mean and standard
    deviation over the n seeds (the squared bias with the variance of the mean taken out, so
    it estimates the floor the cell's relMSE, shown beside it, levels off at), its 95% interval
    by the jackknife over seeds (n ≥ 3).  An estimator whose EXRs are gone or do not read whole
    is left out; None when none is left."""
    folder = pathlib.Path(run_dir) / "images" / scene / f"f{frame}"
    rows = table[(table.scene == scene) & (table.frame == frame)]
    shown = []
    for label, runs in rows.groupby("estimator", sort=False):
        spp = int(runs.spp.max())
        paths = [folder / f"{_image_stem(row)}.exr" for row in runs[runs.spp == spp].to_dict("records")]
        try:
            biased = not _estimator(label).tags.unbiased
        except InputError:      # an estimator this installation lacks
            biased = False
        if not biased or not all(p.exists() for p in [folder / "reference.exr", *paths]):
            continue
        covered, n = mask(), len(paths)
        try:
            reference = read_exr(folder / "reference.exr")[covered].astype(np.float64)
            estimates = np.array([read_exr(path)[covered] for path in paths], np.float64)
        except InputError:      # an EXR that no longer reads whole: left out, as one gone
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            image_mean = mean_ci(cubemap.luminance(estimates).sum(1) / cubemap.luminance(reference).sum() - 1)

        def bias_rel_mse(seeds):
            squared_bias = (seeds.mean(0) - reference) ** 2 - seeds.var(0, ddof=1) / len(seeds)
            return float(np.mean(squared_bias / (reference ** 2 + 0.01)))

        bias = bias_rel_mse(estimates) if n > 1 else np.nan
        left_out = np.array([bias_rel_mse(np.delete(estimates, i, 0)) for i in range(n)]) if n > 2 else np.nan
        bias_half = t_quantile(n - 1, LEVEL) * np.sqrt((n - 1) * np.mean((left_out - left_out.mean()) ** 2)) \
            if n > 2 else np.nan
        cell = cells[(cells.scene == scene) & (cells.estimator == label) & (cells.spp == spp)]
        shown.append({"estimator": label, "spp": spp, "seeds": n, "image-mean bias (%)": interval_text(
                          100 * image_mean.mean, 100 * (image_mean.high - image_mean.mean), n),
                      "relMSE of the bias": interval_text(bias, bias_half, n),
                      "relMSE": _intervals(cell, "rel_mse")[0]})
    return _table_html(pd.DataFrame(shown), "summary") if shown else None


# ---- the sample picture -----------------------------------------------------------------------

@dataclasses.dataclass
class SceneInputs:
    normal: np.ndarray      # [H, W, 3]
    mask: np.ndarray        # [H, W]
    env: np.ndarray         # [6, R, R, 3]
    source: str             # where they came from, for the report


def scene_inputs(run_dir: pathlib.Path, manifest: dict | None, scene: str, frame: int) -> SceneInputs:
    """The G-buffer and environment frame of ``scene``: the run's saved inputs
    (``inputs/<scene>/gbuffer.npz`` and ``env_f<frame>.npy``, from ``run --save-inputs``) when
    present, else rebuilt from the scene registry at the run's resolution and env resolution,
    the G-buffer read from the run's trace cache (``$IBLBENCH_CACHE/gbuffer``) where it is
    still there."""
    from iblbench.estimators.runtime.device import cache_dir
    from iblbench.scenes.gbuffer import GBuffer, cached_trace
    from iblbench.scenes.registry import load_scene

    inputs = pathlib.Path(run_dir) / "inputs" / scene
    gbuffer_path, env_path = inputs / "gbuffer.npz", inputs / f"env_f{frame}.npy"
    if gbuffer_path.is_file() and env_path.is_file():
        try:
            gbuffer = GBuffer.load_npz(gbuffer_path)
            env = np.load(env_path)
        except Exception as error:
            raise InputError(inputs, f"cannot read the saved inputs ({type(error).__name__})") from None
        return SceneInputs(gbuffer.normal, gbuffer.mask, env,
                           f"saved by the run ({gbuffer_path.parent.name}/gbuffer.npz, "
                           f"{env_path.name})")
    config = (manifest or {}).get("config", {})
    for entry in config.get("scenes", [scene]):
        if not str(entry).lower().endswith(".toml") and str(entry).lower() != scene.lower():
            continue   # another built-in scene: its name says so without loading it
        loaded = load_scene(entry, sanitize=bool(config.get("sanitize")), env_res=config.get("env_res"))
        if loaded.name == scene:
            break
    else:
        raise InputError(None, f"scene '{scene}' is not in the manifest's scene list")
    width, height = config.get("resolution") or loaded.resolution
    gbuffer, _ = cached_trace(loaded.mesh, loaded.material, loaded.camera, int(width), int(height),
                              cache_dir() / "gbuffer")
    env = np.asarray(loaded.environment.frame(frame), np.float32)
    return SceneInputs(gbuffer.normal, gbuffer.mask, env,
                       f"rebuilt from the scene registry ({loaded.source or scene}) at "
                       f"{width}×{height}, env faces {env.shape[1]}² (the run saved no inputs)")


def default_pixel(mask: np.ndarray) -> tuple[int, int]:
    """The covered pixel (x, y) nearest the image centre."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    i = np.argmin((xs + 0.5 - w / 2) ** 2 + (ys + 0.5 - h / 2) ** 2)
    return int(xs[i]), int(ys[i])


def sample_picture(draw, scene_frame_inputs, table, scene, frame, spp, pixel, compute) -> dict:
    """Compute and draw (by ``draw``, :meth:`Figures.draw`) the sample picture of ``scene``; a
    dict for the template (``error`` says why there is none); ``scene_frame_inputs`` gives the
    frame's :class:`SceneInputs`."""
    from iblbench.estimators.light_pool import PoolEstimator
    from iblbench.reports.sample_picture import (cross_frames, cross_image, plot_sample_picture,
                                                 pool_selections)

    estimators, notes = {}, []
    for name in dict.fromkeys(table[table.scene == scene].estimator):
        try:
            instance = _estimator(name)
        except Exception:
            notes.append(f"{name}: not a registered estimator here")
            continue
        if not isinstance(instance, PoolEstimator):
            continue
        if not instance.params.shared_sequence:
            notes.append(f"{name}: each pixel reads the pool from its own hashed offset "
                         "(interleaved), not shown")
            continue
        estimators[name] = instance
    if not estimators:
        return {"error": "no estimator of this scene reads Lu 2013's light-sample pool with the "
                         "shared sequence (uniform, balanced, balanced_mis)"
                         + (f" ({'; '.join(notes)})" if notes else "")}
    chosen = choose_spp(table, scene, frame, 0, spp)
    n = spp or max(chosen.get(name, 0) for name in estimators) or int(table.spp.max())
    inputs = scene_frame_inputs()
    if pixel is None:
        pixel = default_pixel(inputs.mask)
    x, y = pixel
    h, w = inputs.mask.shape
    if not (0 <= x < w and 0 <= y < h) or not inputs.mask[y, x]:
        raise InputError(None, f"{argument('pixel', (x, y))} is not a covered pixel of {scene} "
                               f"({w}×{h})")
    normal = inputs.normal[y, x].astype(np.float64)
    selections = pool_selections(compute(), inputs.env, frame, estimators, normal, n, seed=0)
    frames = cross_frames(normal)
    background = cross_image(inputs.env, normal / np.linalg.norm(normal), frames)
    panels = []
    for sel in selections:
        relative = f"sample_picture_{_slug(scene)}_{_slug(sel.estimator)}.png"
        draw(relative, plot_sample_picture, inputs.env, normal, sel, background)
        panels.append(relative)
    return {"panels": panels, "notes": notes, "pixel": (x, y), "normal": normal, "spp": n, "source": inputs.source,
            "selections": [{"estimator": s.estimator, **s.counts,
                            "n_f": ", ".join(f"{v:.2f}" for v in s.n_f),
                            "per_face": ", ".join(str(int(v)) for v in s.selected_per_face),
                            "brdf": s.ticks[6] / 65536.0} for s in selections],
            "data": selections}


def _estimator(label: str):
    """An estimator instance for a results label: ``name`` or ``name{param=value,...}``."""
    try:
        from iblbench.harness.protocol.sweep import parse_estimator
    except ImportError:   # no parameter syntax in this version
        from iblbench.estimators.registry import get_estimator_class
        return get_estimator_class(label)()
    return parse_estimator(label).make()


def _image_stem(row: dict) -> str:
    """The file stem the runner gave a cell's images."""
    try:
        from iblbench.harness.protocol.results import image_stem
    except ImportError:
        return f"{row['estimator']}_spp{int(row['spp'])}_s{int(row['seed'])}"
    return image_stem(row)


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text)


# ---- the page ---------------------------------------------------------------------------------

class Figures:
    """The report's figures (:mod:`.plots`), each drawn only where the report does not hold it
    drawn already by today's plotting code from the same data: ``figures.json`` keeps each PNG's
    key (a hash of that code, matplotlib's version, the plot and its arguments), the PNG's
    modification time then (None where the plot drew nothing; a PNG drawn since, by a report
    that stopped before recording it, is drawn again) and the plot's return value.  Figures
    were most of a report's time (issue 23); a report that picks other images (``spp``,
    ``seed``, ``frame``, ``pixel``), or follows a run that left a scene's cells as they were,
    draws none of its figures again."""

    def __init__(self, report: pathlib.Path):
        self.report, self.path = report, report / "figures.json"
        try:
            kept = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            kept = {}
        self.kept = kept if isinstance(kept, dict) else {}

    def draw(self, name: str, plot, *args, **kwargs):
        """``plot(report / name, *args, **kwargs)``'s return value, from the figure kept or
        drawn now."""
        key = _figure_key(plot, args, kwargs)
        entry, target = self.kept.get(name), self.report / name
        if (isinstance(entry, dict) and entry.get("key") == key
                and entry.get("mtime_ns", False) == _mtime_ns(target)):
            return entry.get("result")
        result = plot(target, *args, **kwargs)
        self.kept[name] = {"key": key, "mtime_ns": _mtime_ns(target), "result": result}
        with atomic_path(self.path) as tmp:
            tmp.write_text(json.dumps(self.kept), encoding="utf-8")
        return result


def _mtime_ns(path: pathlib.Path) -> int | None:
    """None where there is no file (a plot with nothing to draw, as plot_extras without extras)."""
    try:
        return path.stat().st_mtime_ns
    except FileNotFoundError:
        return None


@functools.cache
def _plotting_code() -> bytes:
    """What draws a figure besides its data: the sources of the plots and of what they compute
    with (the heat scale, the intervals), and matplotlib's version."""
    import matplotlib

    from iblbench.harness.protocol import stats
    from iblbench.reports import previews, sample_picture
    return b"".join(pathlib.Path(module.__file__).read_bytes()
                    for module in (plots, previews, stats, sample_picture)) \
        + matplotlib.__version__.encode()


def _figure_key(plot, args: tuple, kwargs: dict) -> str:
    def plain(value):   # a DataFrame as plain lists, whose pickle depends on its content only
        return value.to_dict("split") if isinstance(value, pd.DataFrame) else value

    arguments = ([plain(a) for a in args], sorted((k, plain(v)) for k, v in kwargs.items()))
    return hashlib.sha256(_plotting_code() + plot.__name__.encode()
                          + pickle.dumps(arguments, protocol=4)).hexdigest()


def ray_costs(manifest: dict | None, ray_cost_ns: float | None) -> dict[str, tuple[float, int]]:
    """Per scene with visibility: (ns per shadow ray, covered pixels), the cost being
    ``ray_cost_ns`` or, by default, the host Embree rate its trace measured (the manifest's
    visibility record)."""
    costs = {}
    for record in (manifest or {}).get("visibility") or []:
        rate = record.get("embree_rays_per_s")
        if "rays" in record and (ray_cost_ns is not None or rate):   # a trace skipped: no V, no rays
            costs[record["scene"]] = (ray_cost_ns if ray_cost_ns is not None else 1e9 / rate,
                                      int(record["covered_pixels"]))
    return costs


def with_ray_cost(cells: pd.DataFrame, ns_per_ray: float, pixels: int) -> pd.DataFrame:
    """``cells`` with ``time_ms`` (and its interval) plus each cell's shadow rays for the frame
    at ``ns_per_ray``: time + shadow_rays × pixels × cost, Kronander's trade-off of BIS."""
    charge = cells.shadow_rays * pixels * ns_per_ray * 1e-6
    return cells.assign(**{c: cells[c] + charge for c in (TIME, f"{TIME}_low", f"{TIME}_high") if c in cells})


def _visibility_table(manifest: dict) -> markupsafe.Markup | None:
    """The visibility records: one row per scene and Rv of the masked reference against real
    shadow rays (``harness/protocol/visibility_error.py``), with the trace's cost."""
    rows = []
    for record in manifest.get("visibility") or []:
        base = {"scene": record["scene"], "scene Rv": record["visibility_res"],
                "traced": "skipped: " + record["skipped"] if "skipped" in record
                else ("cached" if record.get("cached") else f"{record.get('trace_seconds', 0):.1f} s"),
                "Embree rays/s": record.get("embree_rays_per_s", "–")}
        for error in record.get("geometric_error") or [{}]:
            rows.append({**base, "Rv": error.get("visibility_res", "–") if error else "–",
                         "masked − shadow rays (Σ Y, relative)": error.get("relative_difference", "–"),
                         "per pixel p90": error.get("pixel_difference_p90", "–"),
                         "shadow rays' std. error": error.get("relative_standard_error", "–"),
                         "pixels × samples": f"{error['pixels']} × {error['samples']}" if error else "–"})
    return _table_html(pd.DataFrame(rows), "summary") if rows else None


def _manifest_context(manifest: dict | None) -> dict | None:
    if manifest is None:
        return None
    stages = pd.DataFrame(manifest.get("stages") or [], columns=["scene", "frame", "stage", "ms"])
    if len(stages):
        stages = stages.groupby(["scene", "stage"], sort=False).ms.agg(
            frames="count", total_ms="sum", mean_ms=lambda ms: mean_ci(ms).text()).reset_index()
        stages.columns = ["scene", "stage", "times built", "total ms", "mean ms per build"]
    skipped = pd.DataFrame(manifest.get("skipped") or [])
    if len(skipped):
        for column in ("scene", "stage", "why"):
            if column not in skipped:
                skipped[column] = ""
        skipped = skipped.groupby(["scene", "stage", "why"], sort=False).size() \
            .reset_index(name="times")
    keys = ("created", "status", "protocol", "git_revision", "resumed_cells")
    return {
        "run": _dict_table({k: manifest.get(k) for k in keys if k in manifest}),
        "device": _dict_table(manifest.get("device") or {}),
        "versions": _dict_table(manifest.get("versions") or {}),
        "estimator_versions": _dict_table(manifest.get("estimator_versions") or {}),
        "config": _dict_table(manifest.get("config") or {}),
        "timing": _dict_table(manifest["timing"]) if manifest.get("timing") else None,
        "stages": _table_html(stages, "summary") if len(stages) else None,
        "skipped": _table_html(skipped, "summary wraps") if len(skipped) else None,
        "visibility": _visibility_table(manifest),
        "status": manifest.get("status"),
        "protocol": manifest.get("protocol"),
        "git_revision": manifest.get("git_revision"),
        "device_name": (manifest.get("device") or {}).get("name"),
    }


def write_report(run_dir, *, spp: int | None = None, seed: int | None = None,
                 frame: int | None = None, pixel: tuple[int, int] | None = None,
                 device: str | None = None, ray_cost_ns: float | None = None) -> dict:
    """Write ``run_dir/report/index.html`` and its images; returns the template context
    (``path`` is the page).  ``spp``/``seed``/``frame`` pick the images shown (default: the
    largest spp every estimator ran, the run's first seed, each sequence's median-luminance frame
    (:mod:`.frames`); one the run
    lacks is an InputError) and ``pixel`` (x, y) the sample picture's pixel (default: the covered
    pixel nearest the centre); ``ray_cost_ns`` the cost of a shadow ray in the error against
    time-plus-rays plot of scenes with visibility (default: the Embree rate their trace measured)."""
    run_dir = pathlib.Path(run_dir)
    table, manifest = load_run(run_dir)
    rankings = scene_rankings(table)   # equal-time cells are points of the curves too
    controls = [calls.text() for calls in control_calls(rankings, table.estimator)]
    table, equal_time = split_equal_time(table)
    for value, column in ((spp, "spp"), (seed, "seed"), (frame, "frame")):
        _require_in_run(table, value, column)
    seed = int(table.seed.min()) if seed is None else seed
    report = run_dir / "report"
    try:
        report.mkdir(exist_ok=True)
    except OSError as error:
        raise InputError(report, f"cannot create the report directory ({error.strerror})") from None
    cells = summarize(table)
    views = device_cells(table, cells)
    convergence = flatter_than_tags(table)
    figures = Figures(report)
    figures.draw("colour_bar.png", plots.write_colour_bar)
    compute_holder: dict = {}

    def compute():
        if "c" not in compute_holder:
            from iblbench.estimators.runtime.device import get_compute
            compute_holder["c"] = get_compute(device)
        return compute_holder["c"]

    shown = {"spp": spp, "seed": seed, "frame": frame, "pixel": pixel,
             "ray_costs": ray_costs(manifest, ray_cost_ns)}
    shown["figures"] = figures
    scenes = [_scene_section(run_dir, report, manifest, table, (cells, views), equal_time,
                             convergence, scene, shown, compute, rankings.get(scene, []))
              for scene in dict.fromkeys(table.scene)]
    context = _page_context(run_dir, manifest, table, scenes)
    answer_cells = cells if len(views) == 1 else pd.concat(
        [device_cells.assign(device=device) for device, device_cells in views])
    context["answer"] = answer_context(figures.draw, answer_cells, rankings, _table_html)
    context["controls"] = controls
    text = _TEMPLATES.get_template("report.html.j2").render(**context)
    with atomic_path(report / "index.html") as tmp:
        tmp.write_text(text, encoding="utf-8")
    context["path"] = report / "index.html"
    return context


def _scene_section(run_dir: pathlib.Path, report: pathlib.Path, manifest: dict, table, cells,
                   equal_time, convergence, scene: str, shown: dict, compute,
                   rankings: list) -> dict:
    """One scene's part of the page: its ranking at its headline budgets (``rankings``) first,
    then its tables, figures, image grid, bias table and sample picture; ``cells``: the
    :func:`summarize` cells and :func:`device_cells`' views; ``shown``: the spp, seed, frame and
    pixel asked for (None: the defaults)."""
    cells, views = cells
    scene_cells = cells[cells.scene == scene]
    rows = table[table.scene == scene]
    slug = _slug(scene)
    figures = _scene_figures(shown["figures"], scene_cells, scene, slug)
    views = [(i, device, shown_cells[shown_cells.scene == scene])
             for i, (device, shown_cells) in enumerate(views)]
    views = [view for view in views if len(view[2])]
    frames = sorted(set(rows.frame))
    frame = shown["frame"]
    if frame is not None and len(frames) > 1:
        _require_in_run(rows, frame, "frame", f"scene {scene}")
    scene_frame, frame_rule = shown_frame(run_dir, scene, frames,
                                          frame if frame in frames else None)
    # the heat maps' mask and the sample picture share one read (or G-buffer trace)
    inputs = functools.cache(functools.partial(scene_inputs, run_dir, manifest, scene,
                                               scene_frame))
    grid = image_grid(run_dir, report, table, cells, scene, scene_frame, shown["seed"],
                      shown["spp"], lambda: inputs().mask)
    per_frame = (_per_frame_figure(shown["figures"], rows, scene, slug, scene_frame)
                 if len(frames) > 1 else None)
    extras = f"extras_{slug}.png"
    extra_columns = shown["figures"].draw(extras, plots.plot_extras, rows, scene,
                                          (manifest or {}).get("extra_columns"))
    picture = _picture_section(inputs, table, scene, scene_frame, shown, compute)
    timed = equal_time[equal_time.scene == scene]
    return {"name": scene, "slug": slug,
            "tables": summary_tables(scene_cells, [(device, c) for _, device, c in views]),
            "devices": [_device_part(shown, scene, slug, i, device, device_cells,
                                     on_device(rows, device), on_device(timed, device),
                                     [r for r in rankings if r.device == device])
                        for i, device, device_cells in views],
            "bias": bias_table(run_dir, table, cells, scene, scene_frame, lambda: inputs().mask),
            "figures": figures, "per_frame": per_frame, "frames": len(frames),
            "grid": grid, "picture": picture, "frame_rule": frame_rule,
            "extras": extras if extra_columns else None, "extra_columns": extra_columns,
            "convergence": [f.text() for f in convergence if f.scene == scene],
            "estimators": list(dict.fromkeys(rows.estimator)),
            "spp": sorted(set(int(v) for v in rows.spp))}


def _device_part(shown: dict, scene: str, slug: str, index: int, device: str | None,
                 scene_cells, rows, timed, rankings: list) -> dict:
    """What one scene shows of one device's times (of every row where the table has one
    device, ``device`` None): its rankings, equal-time table, error against time (and shadow
    rays) and sequence at equal time; ``on`` names the device in the headings, and its figures'
    files and titles name it (the ``index``-th device) too."""
    title = scene if device is None else f"{scene} on {plots.device_name(device)}"
    slug = slug if device is None else f"{slug}_device{index + 1}"
    return {"device": device, "on": f" on {device}" if device is not None else "",
            "rankings": [{"budget_ms": r.budget_ms, "verdict": r.verdict(),
                          "table": ranking_table(r, _table_html)} for r in rankings],
            "equal_time": equal_time_html(timed) if len(timed) else None,
            "figures": _time_figures(shown["figures"], scene_cells, title, slug,
                                     shown["ray_costs"].get(scene)),
            "sequence": sequence_context(shown["figures"].draw, pd.concat([rows, timed]), title,
                                         slug, rankings, _table_html)}


def _scene_figures(drawn: Figures, scene_cells, scene: str, slug: str) -> dict:
    """Convergence and effective samples of one scene (errors: every device's cells)."""
    figures = {"spp": f"convergence_{slug}.png", "effective": f"effective_{slug}.png"}
    drawn.draw(figures["spp"], plots.plot_convergence, scene_cells, scene)
    drawn.draw(figures["effective"], plots.plot_effective, scene_cells, scene)
    return figures


def _time_figures(drawn: Figures, scene_cells, scene: str, slug: str,
                  ray_cost: tuple[float, int] | None) -> dict:
    """Error against time (Pareto front) of one scene's cells of one device, and for a scene
    with visibility error against time plus shadow rays at ``ray_cost`` (ns per ray, covered
    pixels)."""
    figures = {"time": f"error_vs_time_{slug}.png"}
    drawn.draw(figures["time"], plots.plot_error_vs_time, scene_cells, scene)
    if ray_cost is not None and "shadow_rays" in scene_cells:
        ns_per_ray, pixels = ray_cost
        figures["ray_cost"] = f"error_vs_time_and_rays_{slug}.png"
        figures["ns_per_ray"] = ns_per_ray
        drawn.draw(figures["ray_cost"], plots.plot_error_vs_time,
                   with_ray_cost(scene_cells, ns_per_ray, pixels), scene,
                   xlabel=f"device time + shadow rays × {ns_per_ray:.3g} ns (ms per frame, "
                          f"{pixels} pixels)")
    return figures


def _per_frame_figure(drawn: Figures, rows, scene: str, slug: str, scene_frame: int) -> str:
    """A sequence's error per frame."""
    data = cell_intervals(rows, ["estimator", "spp", "frame"],
                          ["mean_delta_e76", "rel_mse"]).reset_index()
    per_frame = f"per_frame_{slug}.png"
    drawn.draw(per_frame, plots.plot_per_frame, data, scene, scene_frame)
    return per_frame


def _picture_section(inputs, table, scene: str, scene_frame: int, shown: dict, compute) -> dict:
    """Lu 2013's sample picture, or why there is none (an error only for an asked pixel)."""
    try:
        return sample_picture(shown["figures"].draw, inputs, table, scene, scene_frame,
                              shown["spp"], shown["pixel"], compute)
    except InputError as error:
        if shown["pixel"] is not None:
            raise
        return {"error": str(error)}


def _page_context(run_dir: pathlib.Path, manifest: dict, table, scenes: list[dict]) -> dict:
    """The template context of the whole page."""
    return {
        "title": f"iblbench report: {run_dir.resolve().name}",
        "run_dir": str(run_dir.resolve()),
        "scenes": scenes,
        "sequences": any(s["frames"] > 1 for s in scenes),
        "manifest": _manifest_context(manifest),
        "busy": busy_sentence(manifest),
        "devices": devices(table) if len(devices(table)) > 1 else [],
        "rows": len(table),
        "not_computed": not_computed(table),
        "colour_bar": "colour_bar.png",
        "heat_scale": HEAT_SCALE,
    }


def not_computed(table: pd.DataFrame) -> list[str]:
    """The metrics no row of ``table`` has a value of (the sweep's ``metrics`` left them out, as
    the default sweep does FLIP): the page says so, where their columns would only be missing."""
    return [name for column, name in (("mean_delta_e2000", "ΔE2000"), ("rel_mse", "relMSE"),
                                      ("flip", "FLIP"))
            if column not in table or table[column].isna().all()]


def _require_in_run(rows: pd.DataFrame, value: int | None, column: str,
                    where: str = "the run") -> None:
    """An InputError naming what ``rows`` hold when ``value`` (the argument ``column``) is given
    but not among them."""
    have = sorted(set(int(v) for v in rows[column]))
    if value is not None and value not in have:
        raise InputError(None, f"{argument(column, value)} is not in {where} ({column}: "
                               f"{', '.join(map(str, have))})")


# Where a browser may break a word: after a hyphen, a dash or a slash.
_BREAKS_INSIDE = re.compile(r"[-/\u2010-\u2014]")


def unbroken_words(text) -> markupsafe.Markup:
    """``text`` escaped, each word with a hyphen, dash or slash in a ``white-space: nowrap``
    span, so that lines break only between words (``view-89.94deg-specular-m2-R2`` stays
    whole); a Jinja filter of the stress page."""
    parts = re.split(r"(\s+)", "" if text is None else str(text))
    return markupsafe.Markup("".join(
        f'<span class="nowrap">{markupsafe.escape(part)}</span>'
        if _BREAKS_INSIDE.search(part) else str(markupsafe.escape(part)) for part in parts))


_TEMPLATES.filters["unbroken"] = unbroken_words
STRESS_STATUS_CLASSES = {"pass": "pass", "FAIL": "fail", "xfail": "xfail", "XPASS": "xpass",
                         "n/a": "na"}
STRESS_NOTES = ("failures", "notes")   # the text columns of a stress row, kept on screen


def stress_html(table: pd.DataFrame, cases: list[dict], context: dict) -> str:
    """The page of ``iblbench stress``: a case × estimator status matrix (each cell coloured by
    its status, "n/a" where the case does not apply to the estimator), every row (its failures
    and notes in a last column that stays on screen while the figures scroll), the cases
    (``cases``: dicts of name, guards, variants, z_pixels, notes) and ``context``'s text."""
    estimators = list(dict.fromkeys(table.estimator))
    status = dict(zip(zip(table.case, table.estimator), table.status))
    matrix = [(case, [status.get((case, name), "n/a") for name in estimators])
              for case in dict.fromkeys(table.case)]
    figures = [c for c in table.columns if c not in (*STRESS_NOTES, "case", "estimator")]
    rows = [{"name": f"{row['case']} · {row['estimator']}",
             "cells": [_number(row[c]) for c in figures], "status": row["status"],
             **{c: row[c] if isinstance(row.get(c), str) else "" for c in STRESS_NOTES}}
            for _, row in table.iterrows()]
    return _TEMPLATES.get_template("stress.html.j2").render(
        estimators=estimators, matrix=matrix, header=figures, rows=rows,
        status_class=STRESS_STATUS_CLASSES, cases=cases, **context)


__all__ = ["load_run", "summarize", "write_report", "choose_spp", "scene_inputs", "default_pixel",
           "stress_html"]
