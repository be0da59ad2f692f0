"""The tables of ``iblbench report``'s page: the run read back (:func:`load_run`), its cells
aggregated (:func:`summarize`; the aggregation is :mod:`.report`'s docstring's), and each table
the page shows as escaped HTML (summary, equal time, the manifest's)."""
from __future__ import annotations

import json
import pathlib
import re

import markupsafe
import numpy as np
import pandas as pd

from iblbench.harness.protocol.equal_time import TOLERANCE
from iblbench.harness.protocol.metric import registered
from iblbench.harness.protocol.results import load_table
from iblbench.harness.protocol.stats import (by_device, cell_intervals, devices, interval_text,
                                             is_time_column, mean_ci)
from iblbench.harness.protocol.timing import TIME
from iblbench.reports import plots
from iblbench.foundation.errors import InputError

REQUIRED_COLUMNS = ("scene", "estimator", "spp", "frame", "seed", "mean_delta_e76",
                    "mean_delta_e2000", "rel_mse", "used_samples", "effective_samples",
                    "effective_ratio", "nonfinite", TIME, "time_ms_iqr", "time_ms_host")


def metric_header(metric) -> str:
    """A metric's column header: a ``mean_`` column is a mean of per-pixel differences."""
    return f"mean {metric.label}" if metric.column.startswith("mean_") else metric.label


METRICS = {metric.column: metric_header(metric) for metric in registered()}   # column → header
SAMPLE_COLUMNS = ("used_samples", "effective_samples", "effective_ratio", "shadow_rays")


# Each is a cell's figure with its interval (module docstring).  The timed renders' IQR is not
# among them: the time's own interval says their spread.
INTERVAL_COLUMNS = (*METRICS, *SAMPLE_COLUMNS, TIME, "time_ms_host")


SHOWN_INTERVALS = (*INTERVAL_COLUMNS, "efficiency")   # efficiency: summarize derives it


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
               and not (several and is_time_column(c))]
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
    columns = [c for c in (*METRICS, "effective_samples", "effective_ratio", TIME)
               if c in rows and (c not in METRICS or rows[c].notna().any()
                                 or c in ("mean_delta_e76", "rel_mse"))]   # a metric where computed
    cells = cell_intervals(rows, keys, columns).reset_index()
    cells["within"] = (cells[TIME] - cells.time_budget_ms).abs() <= TOLERANCE * cells.time_budget_ms
    return cells.sort_values(["time_budget_ms", "rel_mse"])


def equal_time_html(rows: pd.DataFrame) -> markupsafe.Markup:
    cells = equal_time_cells(rows)
    shown = pd.DataFrame({
        "budget (ms/frame)": cells.time_budget_ms, "estimator": cells.estimator,
        "spp run": cells.spp, "seeds": cells.seeds,
        **{header: intervals(cells, column) for column, header in (
            *METRICS.items(), ("effective_samples", "effective spp"),
            ("effective_ratio", "effective ratio"), (TIME, "achieved ms/frame (device)"))
           if column in cells},
        f"within ±{TOLERANCE:.0%}": cells.within.map({True: "yes", False: "NO"})})
    return table_html(shown, "summary equal-time")


def intervals(cells: pd.DataFrame, column: str) -> list[str]:
    """The column's cells as ``mean ± half-width`` or ``mean [low, high]``
    (``stats.interval_text``; ``mean ± half-width`` where the cells carry no bounds)."""
    counts = cells[f"{column}_n"] if f"{column}_n" in cells else cells.seeds
    bound = lambda side: cells[f"{column}_{side}"] if f"{column}_{side}" in cells else [np.nan] * len(cells)
    return [interval_text(mean, half, n, low=low, high=high) for mean, half, n, low, high in
            zip(cells[column], cells[f"{column}_half"], counts, bound("low"), bound("high"))]


_TABLE_COLUMNS = {   # summary column → header (with units)
    "estimator": "estimator", "spp": "spp", "seeds": "seeds", **METRICS,
    "effective_ratio": "effective ratio", "effective_samples": "effective spp",
    "used_samples": "used spp", "time_ms": "ms/frame (device)",
    "time_ms_host": "ms/frame (host wall)",
    "efficiency": "efficiency 1/(relMSE·s)", "shadow_rays": "shadow rays/px",
    "nonfinite": "non-finite px", "pareto_rel_mse": "Pareto (relMSE)",
    "pareto_delta_e76": "Pareto (ΔE76)",
}


def number(value) -> str:
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            return "–"
        return f"{value:.4g}"
    return str(value)


# The summary of a scene in two tables, so that neither runs off a page 1280 px wide: the
# errors, then samples and cost (where a column not named here goes too).
ERROR_COLUMNS = (*METRICS, "nonfinite", "pareto_rel_mse", "pareto_delta_e76")


KEY_COLUMNS = ("estimator", "spp", "seeds")


def summary_html(cells: pd.DataFrame, columns=None) -> markupsafe.Markup:
    """The summary table of one scene's ``columns`` (default: every one of _TABLE_COLUMNS the
    cells have); every aggregated figure as ``mean ± half-width``."""
    columns = [c for c in (columns or _TABLE_COLUMNS) if c in cells]
    frame = pd.DataFrame({_TABLE_COLUMNS[c]: intervals(cells, c) if c in SHOWN_INTERVALS
                          else cells[c] for c in columns})
    return table_html(frame, "summary")


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
        json.dumps(v) if isinstance(v, (list, dict)) else ("–" if v is None else number(v))
        for v in mapping.values()]})
    return table_html(frame, "kv", header=False)


# A number, an interval (``stats.interval_text``) or "–": such a column is right-aligned.
_NUMERIC = re.compile(r"[-+]?[\d.]+(e[-+]?\d+)?"
                      r"( ± \S+| \[[\d.]+, [\d.]+\]| \(n=\d+, no interval\))?|–")
_SLASH_BREAK = markupsafe.Markup("/<wbr>")


def table_html(frame: pd.DataFrame, classes: str, header: bool = True) -> markupsafe.Markup:
    """``frame`` as an escaped HTML table, cells by :func:`number`; a column of numbers or
    intervals gets class "num" (right-aligned), text stays left."""
    text = frame.apply(lambda column: column.map(number))   # DataFrame.map needs pandas 2.1
    numeric = [text[c].map(lambda v: _NUMERIC.fullmatch(v) is not None).all() for c in text]
    rows = ["<tr>" + "".join(_figure_cell(v) if n else f"<td>{markupsafe.escape(v)}</td>"
                             for v, n in zip(values, numeric)) + "</tr>"
            for values in text.itertuples(index=False)]
    # A header may break after a slash ("ms/frame"), so that a unit does not widen its column.
    head = ("<thead><tr>" + "".join(f"<th>{markupsafe.escape(c).replace('/', _SLASH_BREAK)}</th>"
                                    for c in frame.columns) + "</tr></thead>") if header else ""
    return markupsafe.Markup(f'<table class="{classes}">{head}<tbody>{"".join(rows)}'
                             "</tbody></table>")


def _figure_cell(text: str) -> str:
    """A right-aligned cell of a number or an interval, the interval (``± 0.31``, ``[6.6, 31]``)
    in a span.spread, so that a narrow page breaks a figure from its interval, never inside
    either (report.css.j2); "(n=1, no interval)" wraps as words do."""
    figure, _, spread = text.partition(" ")
    if spread.startswith(("±", "[")):
        return markupsafe.Markup('<td class="num">{} <span class="spread">{}</span></td>').format(
            figure, spread)
    return f'<td class="num">{markupsafe.escape(text)}</td>'


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


def _pixels_and_samples(error: dict) -> str:
    """"n of N × samples"; a run before issue 34 recorded no ``covered``."""
    if not error:
        return "–"
    of = f" of {error['covered']}" if "covered" in error else ""
    return f"{error['pixels']}{of} × {error['samples']}"


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
                         "± (95%)": error.get("interval", "–"),
                         "per pixel p90": error.get("pixel_difference_p90", "–"),
                         "its noise floor": error.get("pixel_noise_p90", "–"),
                         "pixels × samples": _pixels_and_samples(error)})
    return table_html(pd.DataFrame(rows), "summary") if rows else None


def manifest_tables(manifest: dict | None) -> dict | None:
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
        "stages": table_html(stages, "summary") if len(stages) else None,
        "skipped": table_html(skipped, "summary wraps") if len(skipped) else None,
        "visibility": _visibility_table(manifest),
        "status": manifest.get("status"),
        "protocol": manifest.get("protocol"),
        "git_revision": manifest.get("git_revision"),
        "device_name": (manifest.get("device") or {}).get("name"),
    }


def not_computed(table: pd.DataFrame) -> list[str]:
    """The metrics no row of ``table`` has a value of (the sweep's ``metrics`` left them out, as
    the default sweep does FLIP): the page says so, where their columns would only be missing."""
    return [metric.label for metric in registered() if metric.default and not metric.always
            and (metric.column not in table or table[metric.column].isna().all())]


__all__ = ["load_run", "summarize", "device_cells", "on_device", "split_equal_time",
           "equal_time_cells", "equal_time_html", "intervals", "number", "summary_html",
           "summary_tables", "table_html", "ray_costs", "with_ray_cost", "manifest_tables",
           "not_computed"]
