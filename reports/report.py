"""``iblbench report DIR``: a self-contained static HTML report of one run → ``DIR/report/``.

``DIR/report/index.html`` opens from disk with no server: every image it shows (plots, the
colour bar, the sample pictures, the previews and heat maps it draws from the run's EXRs) lies
inside ``DIR/report`` and is referenced by a relative path; the page loads no script, stylesheet or font (its one
script, the compare viewer's, and its stylesheet are inline).

Contents, per scene: the summary (estimator × spp) in two tables, errors and samples/time, error
against time with the Pareto front, convergence against spp (with a warning where it is flatter
than the estimator's tags allow, and a note where it looks so but the seeds cannot tell,
:mod:`iblbench.harness.verify.convergence`), effective samples against spp, FLIP, flicker and
smc's ess/reinits where the run has them, error per frame at every spp (sequences only), an
image grid (reference, each estimator at one spp, ΔE76 heat maps on the shared log scale of
:mod:`.previews` with its colour bar), a compare viewer (any two of the frame's images, A left
and B right of a divider moved by a slider; a toggle that shows the reference on both sides; a
click zooms on the crop around the point) and Lu 2013 Fig. 1/2's sample picture
(:mod:`.sample_picture`); then the run's manifest.

The report reads only the run folder: its table, manifest and EXRs, and the inputs the run saved
for the sample picture (:mod:`iblbench.harness.protocol.report_inputs`); it loads no scene, traces
nothing and opens no device.  This module assembles the page (Jinja) from :mod:`.tables` (the
tables), :mod:`.images` (the image grid, the bias table, the sample picture) and
:mod:`.figures` (the figure cache), with a progress bar of its stages on stderr.

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

import pathlib
import re
import sys

import jinja2
import markupsafe
import pandas as pd
from tqdm import tqdm

from iblbench.harness.verify.convergence import flatter_than_tags
from iblbench.harness.protocol.control import control_calls
from iblbench.harness.protocol.ranking import scene_rankings
from iblbench.harness.protocol.report_inputs import read_surface
from iblbench.harness.protocol.stats import cell_intervals, devices
from iblbench.reports import plots
from iblbench.reports.answer import (answer_context, busy_sentence, ranking_table,
                                     sequence_context)
from iblbench.reports.figures import Figures, slugify
from iblbench.reports.frames import shown_frame
from iblbench.reports.images import bias_table, image_grid, picture_section
from iblbench.reports.previews import HEAT_SCALE
from iblbench.reports.tables import (device_cells, equal_time_html, load_run, manifest_tables,
                                     not_computed, number, on_device, ray_costs,
                                     split_equal_time, summarize, summary_tables, table_html,
                                     with_ray_cost)
from iblbench.foundation.atomic import atomic_path
from iblbench.foundation.errors import InputError, argument

_TEMPLATES = jinja2.Environment(
    loader=jinja2.PackageLoader("iblbench.reports", "templates"),
    autoescape=jinja2.select_autoescape(["html", "j2"]), trim_blocks=True, lstrip_blocks=True)


def write_report(run_dir, *, spp: int | None = None, seed: int | None = None,
                 frame: int | None = None, pixel: tuple[int, int] | None = None,
                 ray_cost_ns: float | None = None, progress: bool | None = None) -> dict:
    """Write ``run_dir/report/index.html`` and its images; returns the template context
    (``path`` is the page).  ``spp``/``seed``/``frame`` pick the images shown (default: the
    largest spp every estimator ran, the run's first seed, each sequence's median-luminance frame
    (:mod:`.frames`); one the run
    lacks is an InputError; the sample picture is the run's, at the spp it saved, and left out
    with a note for another) and ``pixel`` (x, y) the sample picture's pixel (default: the
    covered pixel nearest the centre); ``ray_cost_ns`` the cost of a shadow ray in the error against
    time-plus-rays plot of scenes with visibility (default: the Embree rate their trace measured);
    ``progress``: a bar of its stages on stderr (None: where stderr is a terminal)."""
    run_dir = pathlib.Path(run_dir)
    table, manifest = load_run(run_dir)
    bar = tqdm(total=table.scene.nunique() + 2, unit="step", file=sys.stderr, leave=False,
               disable=None if progress is None else not progress)
    with bar:
        return _write_page(run_dir, table, manifest, (spp, seed, frame, pixel, ray_cost_ns), bar)


def _write_page(run_dir: pathlib.Path, table, manifest, asked: tuple, bar) -> dict:
    """:func:`write_report` of the run's ``table`` and ``manifest``, ``asked``: its spp, seed,
    frame, pixel and ray cost; ``bar`` counts its stages: the rankings, each scene, the page."""
    spp, seed, frame, pixel, ray_cost_ns = asked
    bar.set_description("rankings")
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
    shown = {"spp": spp, "seed": seed, "frame": frame, "pixel": pixel,
             "ray_costs": ray_costs(manifest, ray_cost_ns),
             # the estimators' own labels of their extra columns, as the run declared them
             "extra_columns": (manifest or {}).get("extra_columns")}
    shown["figures"] = figures
    bar.update()
    scenes = []
    for scene in dict.fromkeys(table.scene):
        bar.set_description(f"scene {scene}")
        scenes.append(_scene_section(run_dir, report, table, (cells, views), equal_time,
                                     convergence, scene, shown, rankings.get(scene, [])))
        bar.update()
    bar.set_description("the answer and the page")
    context = _page_context(run_dir, manifest, table, scenes)
    answer_cells = cells if len(views) == 1 else pd.concat(
        [device_cells.assign(device=device) for device, device_cells in views])
    context["answer"] = answer_context(figures.draw, answer_cells, rankings, table_html)
    context["controls"] = controls
    text = _TEMPLATES.get_template("report.html.j2").render(**context)
    with atomic_path(report / "index.html") as tmp:
        tmp.write_text(text, encoding="utf-8")
    context["path"] = report / "index.html"
    bar.update()
    return context


def _scene_section(run_dir: pathlib.Path, report: pathlib.Path, table, cells,
                   equal_time, convergence, scene: str, shown: dict, rankings: list) -> dict:
    """One scene's part of the page: its ranking at its headline budgets (``rankings``) first,
    then its tables, figures, image grid, bias table and sample picture; ``cells``: the
    :func:`summarize` cells and :func:`device_cells`' views; ``shown``: the spp, seed, frame and
    pixel asked for (None: the defaults)."""
    cells, views = cells
    scene_cells = cells[cells.scene == scene]
    rows = table[table.scene == scene]
    slug = slugify(scene)
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
    surface = read_surface(run_dir, scene)   # None for a run made before runs saved it
    mask = None if surface is None else surface[1]
    grid = image_grid(run_dir, report, table, cells, scene, scene_frame, shown["seed"],
                      shown["spp"], mask)
    per_frame = (_per_frame_figure(shown["figures"], rows, scene, slug, scene_frame)
                 if len(frames) > 1 else None)
    extras = f"extras_{slug}.png"
    extra_columns = shown["figures"].draw(extras, plots.plot_extras, rows, scene,
                                          shown["extra_columns"])
    picture = _picture_section(run_dir, surface, scene, scene_frame, shown)
    timed = equal_time[equal_time.scene == scene]
    return {"name": scene, "slug": slug,
            "tables": summary_tables(scene_cells, [(device, c) for _, device, c in views]),
            "devices": [_device_part(shown, scene, slug, i, device, device_cells,
                                     on_device(rows, device), on_device(timed, device),
                                     [r for r in rankings if r.device == device])
                        for i, device, device_cells in views],
            "bias": bias_table(run_dir, table, cells, scene, scene_frame, mask),
            "figures": figures, "per_frame": per_frame, "frames": len(frames),
            "grid": grid, "picture": picture, "frame_rule": frame_rule,
            "extras": extras if extra_columns else None, "extra_columns": extra_columns,
            "convergence": [f.text() for f in convergence if f.scene == scene and f.not_converging],
            "convergence_unresolved": [f.text() for f in convergence
                                       if f.scene == scene and not f.not_converging],
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
                          "table": ranking_table(r, table_html)} for r in rankings],
            "equal_time": equal_time_html(timed) if len(timed) else None,
            "figures": _time_figures(shown["figures"], scene_cells, title, slug,
                                     shown["ray_costs"].get(scene)),
            "sequence": sequence_context(shown["figures"].draw, pd.concat([rows, timed]), title,
                                         slug, rankings, table_html)}


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


def _picture_section(run_dir, surface, scene: str, scene_frame: int, shown: dict) -> dict:
    """Lu 2013's sample picture, or why there is none (an error only for an asked pixel)."""
    try:
        return picture_section(shown["figures"].draw, run_dir, surface, scene, scene_frame,
                              shown["spp"], shown["pixel"])
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
        "manifest": manifest_tables(manifest),
        "busy": busy_sentence(manifest),
        "devices": devices(table) if len(devices(table)) > 1 else [],
        "rows": len(table),
        "not_computed": not_computed(table),
        "colour_bar": "colour_bar.png",
        "heat_scale": HEAT_SCALE,
    }


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
             "cells": [number(row[c]) for c in figures], "status": row["status"],
             **{c: row[c] if isinstance(row.get(c), str) else "" for c in STRESS_NOTES}}
            for _, row in table.iterrows()]
    return _TEMPLATES.get_template("stress.html.j2").render(
        estimators=estimators, matrix=matrix, header=figures, rows=rows,
        status_class=STRESS_STATUS_CLASSES, cases=cases, **context)


__all__ = ["write_report", "stress_html", "unbroken_words"]
