"""Plots of the benchmark report (matplotlib, Agg): error against time with the Pareto front,
convergence against spp, effective samples, error per frame at every spp, FLIP, flicker and
smc's ess and reinits where a run has them, and the ΔE colour bar.

Every plot takes the per-cell summary of one scene (``summary`` from :mod:`.report`: one row per
(estimator, spp) with ``time_ms`` (the cell's device time per frame), ``rel_mse``, ``mean_delta_e76``, ``used_samples``,
``effective_samples``, ``effective_ratio``, each the mean over seeds with ``_low`` and ``_high``,
its 95% interval) and writes a PNG atomically.  Every plotted mean carries its interval as an
error bar (none with one seed); on a log axis a lower end at or below 0 runs off the axis.
"""
from __future__ import annotations

import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from iblbench.harness.protocol.stats import MeanCI, by_device, cell_intervals, separated  # noqa: E402
from iblbench.harness.protocol.timing import TIME  # noqa: E402
from iblbench.reports.previews import HEAT_CMAP, HEAT_MAX  # noqa: E402
from iblbench.foundation.atomic import atomic_path  # noqa: E402

DPI = 100
# Text that stays about 10 px or more where a page 800 px wide scales a figure 11 inches wide
# down to its column (issue 23: it was about 7 px).
matplotlib.rcParams.update({"font.size": 12, "legend.fontsize": 10})

# (column, axis label) of the two error measures the report plots.
ERRORS = (("rel_mse", "relMSE (linear HDR, dimensionless)"),
          ("mean_delta_e76", "mean ΔE76 (CIELAB units)"))


def _errors(summary) -> tuple:
    """The ERRORS ``summary`` has a value of (a run with ``--metrics de76`` has no relMSE)."""
    return tuple((column, label) for column, label in ERRORS
                 if column in summary and np.isfinite(np.asarray(summary[column], float)).any())


def pareto_front(x, y) -> np.ndarray:
    """Mask of the non-dominated points when both ``x`` and ``y`` are to be minimised.

    Point i is dominated when some point j has x_j ≤ x_i and y_j ≤ y_i with at least one strict
    inequality.  Points with a non-finite coordinate are never on the front (and dominate none).
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    finite = np.isfinite(x) & np.isfinite(y)
    front = finite.copy()
    for i in np.flatnonzero(finite):
        others = finite & (x <= x[i]) & (y <= y[i]) & ((x < x[i]) | (y < y[i]))
        front[i] = not others.any()
    return front


def pareto_calls(cells, column: str) -> list[str]:
    """Each cell's place on the (``time_ms``, ``column``) Pareto front, called only where the
    intervals say so: "◆" on the front of the means (:func:`pareto_front`), "dominated" when
    another cell is faster and more accurate with both intervals separated
    (:func:`~iblbench.harness.protocol.stats.separated`), else "not resolved at N seeds" (the means
    alone put it behind the front)."""
    def ci(row, name):
        return MeanCI(row[name], row[f"{name}_low"], row[f"{name}_high"], row["seeds"], np.nan)

    def beats(j, i):
        return all(separated(ci(j, name), ci(i, name)) and j[name] < i[name]
                   for name in ("time_ms", column))

    rows = [row for _, row in cells.iterrows()]
    error = _positive(cells[column])
    front = pareto_front(cells.time_ms, error)
    calls = []
    for i, row in enumerate(rows):
        if front[i] or not np.isfinite(error[i]):
            calls.append("◆" if front[i] else "–")
        elif any(beats(other, row) for other in rows):
            calls.append("dominated")
        else:
            calls.append(f"not resolved at {row['seeds']} seeds")
    return calls


def _errorbar(ax, summary, x: str, y: str, style: dict, label: str,
              x_interval: bool = False, log: bool = True, **line):
    """``y`` against ``x`` of ``summary`` with the 95% interval of ``y`` (and of ``x`` when
    ``x_interval``) as error bars, in the estimator's ``style`` (:func:`_styles`), joined by a
    solid line unless ``line`` says otherwise; ``log``: ``y`` is drawn on a log axis (values
    ≤ 0 left out)."""
    def bars(name):
        mean = np.asarray(summary[name], float)
        return np.vstack([mean - summary[f"{name}_low"], summary[f"{name}_high"] - mean])

    return ax.errorbar(summary[x], _positive(summary[y]) if log else summary[y], yerr=bars(y),
                       xerr=bars(x) if x_interval else None, label=label, capsize=2,
                       elinewidth=0.8, **{"linestyle": "-", **style, **line})


def _save(fig, path: pathlib.Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)


def _estimators(summary) -> list[str]:
    return list(dict.fromkeys(summary.estimator))


# A colour and a marker per estimator: the default sweep plots a dozen estimators on one plane,
# more than matplotlib's ten cycle colours.  Tableau 10, then four dark colours unlike them.
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf", "#000000", "#01665e", "#4b0082", "#b8860b")
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "h", "<", ">", "p", "d", "8")


def _styles(summary) -> dict[str, dict]:
    """Each estimator's colour and marker, in order of appearance: the first 14 differ in both,
    and no two of the first 14² share both."""
    return {name: {"color": PALETTE[i % len(PALETTE)],
                   "marker": MARKERS[(i + i // len(PALETTE)) % len(MARKERS)]}
            for i, name in enumerate(_estimators(summary))}


def _spp_ticks(ax, spp) -> None:
    spp = sorted({int(v) for v in spp})
    ax.set_xticks(spp, [str(v) for v in spp])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())


class _MinorLabels(matplotlib.ticker.Formatter):
    """Labels at 2, 3 and 5 × 10^k, only on an axis spanning less than two decades."""

    def __call__(self, value, pos=None) -> str:
        low, high = sorted(self.axis.get_view_interval())
        if low <= 0 or high / low >= 100.0:
            return ""
        return f"{value:.3g}" if f"{value:.1e}"[:3] in ("2.0", "3.0", "5.0") else ""


def _plain_log_axes(ax, which: str = "xy") -> None:
    """Log axes labelled with plain numbers (0.3, 6, 200), not 3×10⁻¹; minor ticks at 2, 3, 5
    labelled too, so a short axis still has a few numbers."""
    for name in which:
        axis = ax.xaxis if name == "x" else ax.yaxis
        axis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:.3g}"))
        axis.set_minor_formatter(_MinorLabels())


def _legend(ax) -> None:
    """The legend under the axes, where it can hide no data."""
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.17), ncol=2, frameon=False)


def _figure_legend(fig) -> None:
    """One legend under all the panels of a figure whose panels plot the same series: every
    label of any panel once, in order (a dozen estimators fit in four columns)."""
    entries = {}
    for ax in fig.axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    fig.legend(entries.values(), entries.keys(), loc="outside lower center", ncol=4,
               frameon=False)


def device_name(device: str) -> str:
    """A results row's ``device`` without its platform and driver (after " | "), for a title."""
    return device.split(" | ")[0]


def _positive(values) -> np.ndarray:
    values = np.asarray(values, float)
    return np.where(values > 0, values, np.nan)   # log axes: zero/negative cannot be drawn


def plot_error_vs_time(path: pathlib.Path, summary, scene: str,
                       xlabel: str = "device time per frame (ms: build + sample + shade)") -> None:
    """relMSE and mean ΔE76 against ms/frame, log-log, a curve per estimator (points labelled
    with their spp, error bars in time and error), the Pareto front of the means over all cells
    ringed and joined, cells behind it by their means only, not resolved, ringed in grey.
    ``xlabel`` names what ``time_ms`` holds (the report charges shadow rays into it)."""
    styles, errors = _styles(summary), _errors(summary)
    fig, axes = plt.subplots(1, len(errors), figsize=(11, 6.0), layout="constrained",
                             squeeze=False)
    for ax, (column, label) in zip(axes[0], errors):
        for name in _estimators(summary):
            rows = summary[summary.estimator == name].sort_values("spp")
            _errorbar(ax, rows, "time_ms", column, styles[name], name, x_interval=True)
            for r in rows.itertuples():
                ax.annotate(str(r.spp), (r.time_ms, getattr(r, column)), textcoords="offset points",
                            xytext=(4, 4), fontsize=9, color=styles[name]["color"])
        calls = np.array(pareto_calls(summary, column))
        cells = summary[calls == "◆"].sort_values("time_ms")
        ax.step(cells.time_ms, cells[column], where="post", color="black", lw=1, ls=":",
                zorder=1)
        ax.plot(cells.time_ms, cells[column], "o", ms=12, mfc="none", mec="black",
                label="Pareto front (non-dominated cells)")
        unresolved = summary[np.char.startswith(calls.astype(str), "not resolved")]
        if len(unresolved):
            ax.plot(unresolved.time_ms, unresolved[column], "o", ms=12, mfc="none", mec="grey",
                    ls="none", label="behind the front by the means only (not resolved)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        _plain_log_axes(ax, "xy")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    _figure_legend(fig)
    fig.suptitle(f"{scene}: error against time (labels: spp)")
    _save(fig, path)


def _guide(ax, spp, anchor: float, slope: float, label: str) -> None:
    spp = np.array(sorted(set(spp)), float)
    if len(spp) and np.isfinite(anchor) and anchor > 0:
        ax.plot(spp, anchor * (spp / spp[0]) ** slope, "k--", lw=1, label=label)


def plot_convergence(path: pathlib.Path, summary, scene: str) -> None:
    """Error against spp, log-log.  Mean ΔE76 (an absolute, RMSE-like error) with a slope −½
    guide; relMSE (a squared error) with a slope −1 guide, which is the −½ of √relMSE."""
    styles, errors = _styles(summary), _errors(summary)
    fig, axes = plt.subplots(1, len(errors), figsize=(11, 5.6), layout="constrained",
                             squeeze=False)
    guides = {"mean_delta_e76": (-0.5, r"slope −½ (ideal Monte Carlo: error $\propto$ spp$^{-1/2}$)"),
              "rel_mse": (-1.0, r"slope −1 (ideal: relMSE $\propto$ spp$^{-1}$, "
                                r"i.e. $\sqrt{\mathrm{relMSE}} \propto$ spp$^{-1/2}$)")}
    for ax, (column, label) in zip(axes[0], errors):
        for name in _estimators(summary):
            rows = summary[summary.estimator == name].sort_values("spp")
            _errorbar(ax, rows, "spp", column, styles[name], name)
        first = summary[summary.spp == summary.spp.min()]
        slope, text = guides[column]
        _guide(ax, summary.spp, np.nanmax(_positive(first[column])), slope, text)
        ax.set_xscale("log")
        ax.set_yscale("log")
        _plain_log_axes(ax, "y")
        _spp_ticks(ax, summary.spp)
        ax.set_xlabel("samples per pixel (spp)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    _figure_legend(fig)
    fig.suptitle(f"{scene}: convergence")
    _save(fig, path)


def plot_effective(path: pathlib.Path, summary, scene: str) -> None:
    """Used and effective (cos > 0) samples per pixel against spp (log-log, with the budget
    line used = spp), and the effective ratio against spp."""
    styles = _styles(summary)
    fig, (ax, ratio) = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    spp = np.array(sorted(set(summary.spp)), float)
    ax.plot(spp, spp, color="grey", lw=1, ls="--", label="budget (= spp)")
    for name in _estimators(summary):
        rows = summary[summary.estimator == name].sort_values("spp")
        _errorbar(ax, rows, "spp", "effective_samples", styles[name], f"{name}: effective")
        _errorbar(ax, rows, "spp", "used_samples", styles[name], f"{name}: used", marker="x",
                  linestyle=":")
        _errorbar(ratio, rows, "spp", "effective_ratio", styles[name], name, log=False)
    ax.set_xscale("log")
    ax.set_yscale("log")
    _plain_log_axes(ax, "y")
    _spp_ticks(ax, summary.spp)
    ax.set_xlabel("samples per pixel (spp)")
    ax.set_ylabel("samples per pixel (mean over covered pixels)")
    _legend(ax)
    ax.grid(True, which="both", alpha=0.3)
    ratio.set_xscale("log")
    _spp_ticks(ratio, summary.spp)
    ratio.set_ylim(0, 1.05)
    ratio.set_xlabel("samples per pixel (spp)")
    ratio.set_ylabel("effective ratio (effective / used, fraction)")
    _legend(ratio)
    ratio.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"{scene}: effective samples (cos > 0)")
    _save(fig, path)


def plot_per_frame(path: pathlib.Path, per_frame, scene: str, shown: int) -> None:
    """Mean ΔE76 and relMSE per frame of a sequence (mean over seeds, with its interval), a row
    of panels per spp (``per_frame``: one row per estimator, spp and frame), the frame ``shown``
    in the report's images marked."""
    levels = sorted({int(v) for v in per_frame.spp})
    styles, errors = _styles(per_frame), _errors(per_frame)
    fig, axes = plt.subplots(len(levels), len(errors), figsize=(11, 1.2 + 2.8 * len(levels)), sharex=True,
                             squeeze=False, layout="constrained")
    for spp, row in zip(levels, axes):
        cells = per_frame[per_frame.spp == spp]
        for ax, (column, label) in zip(row, errors):
            for name in _estimators(per_frame):
                rows = cells[cells.estimator == name].sort_values("frame")
                if len(rows):
                    _errorbar(ax, rows, "frame", column, styles[name], name, markersize=4)
            ax.axvline(shown, color="grey", lw=1, ls="--",
                       label=f"frame {shown}, shown in the images")
            ax.set_yscale("log")
            _plain_log_axes(ax, "y")
            ax.set_title(f"{spp} spp", fontsize=11, loc="left")
            ax.set_ylabel(label, fontsize=10)
            ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
            ax.grid(True, which="both", alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("frame (index in the sequence)")
    _figure_legend(fig)
    fig.suptitle(f"{scene}: error per frame at every spp")
    _save(fig, path)


# Per-frame scalars a run may hold beside the errors (column → name, axis label, log axis):
# each is plotted where any row has it, against spp, and FLIP, an error, against time too; after
# them the estimators' own extra columns, as the run's manifest describes them
# (``extra_columns``, from each estimator's declaration).
EXTRAS = {
    "flip": ("FLIP", "HDR-FLIP (mean over covered pixels, 0–1)", True),
    "flicker": ("flicker", "flicker: mean |change of ΔE76| between\nconsecutive frames "
                           "(CIELAB units)", True),
}


def extra_cells(rows, column: str, time: bool = True):
    """Per (estimator, spp) of one scene's ``rows`` the mean over seeds of ``column`` and, with
    ``time``, of ``time_ms`` with their intervals, each seed's value the mean over the frames
    where the column is defined (flicker is NaN on a first frame, smc's ess on an init frame);
    None when no row has it."""
    if column not in rows or rows[column].isna().all():
        return None
    defined = rows[rows[column].notna()]
    return cell_intervals(defined, ["estimator", "spp"], [column, TIME] if time else [column]) \
        .reset_index()


def plot_extras(path: pathlib.Path, rows, scene: str,
                estimator_extras: dict | None = None) -> list[str]:
    """FLIP, flicker (``EXTRAS``) and the estimators' extra columns (``estimator_extras``: the
    manifest's ``extra_columns``, column → its label, axis and log), those ``rows`` have, against
    spp with their intervals, FLIP also against device time (a panel per device where ``rows``
    have several: times are never pooled over devices); nothing is written when ``rows`` have
    none.  Returns the names of those plotted."""
    described = {**EXTRAS, **{column: (extra["label"], extra["axis"], extra["log"])
                              for column, extra in (estimator_extras or {}).items()}}
    devices = by_device(rows)
    cells = {column: extra_cells(rows, column, time=len(devices) == 1) for column in described}
    cells = {column: c for column, c in cells.items() if c is not None}
    panels = [(column, "spp", cells[column], None) for column in cells]
    if "flip" in cells:
        timed = [(device, cells["flip"] if device is None else extra_cells(on, "flip"))
                 for device, on in devices]
        panels[1:1] = [("flip", TIME, data, device) for device, data in timed if data is not None]
    if not panels:
        return []
    styles = _styles(rows)
    columns = min(len(panels), 2)
    count = -(-len(panels) // columns)
    fig, axes = plt.subplots(count, columns, figsize=(11, 0.4 + 4.2 * count), squeeze=False,
                             layout="constrained")
    for ax, (column, x, data, device) in zip(axes.flat, panels):
        _, label, log = described[column]
        if device is not None:
            ax.set_title(f"on {device_name(device)}", fontsize=11)
        for name in _estimators(data):
            shown = data[data.estimator == name].sort_values("spp")
            _errorbar(ax, shown, x, column, styles[name], name, x_interval=x == TIME, log=log)
        ax.set_xscale("log")
        if log:
            ax.set_yscale("log")
            _plain_log_axes(ax, "y")
        if x == TIME:
            _plain_log_axes(ax, "x")
            ax.set_xlabel("device time per frame (ms: build + sample + shade)")
        else:
            _spp_ticks(ax, data.spp)
            ax.set_xlabel("samples per pixel (spp)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        _legend(ax)
    for ax in axes.flat[len(panels):]:
        ax.remove()
    names = [described[column][0] for column in cells]
    fig.suptitle(f"{scene}: {', '.join(names)} (mean over seeds, 95% intervals)")
    _save(fig, path)
    return names


def write_colour_bar(path: pathlib.Path) -> None:
    """The one colour bar of every ΔE76 heat map: the heat maps' log scale and colormap
    (:mod:`.previews`), labelled in plain numbers, the just-noticeable difference marked."""
    from iblbench.reports import previews

    fig, ax = plt.subplots(figsize=(6, 1.0))
    bar = fig.colorbar(matplotlib.cm.ScalarMappable(norm=previews.heat_norm(), cmap=HEAT_CMAP),
                       cax=ax, orientation="horizontal")
    ticks = [t for t in (0.1, 0.3, 1, previews.JND_DE76, 10, 30, 100)
             if previews.HEAT_MIN <= t <= previews.HEAT_MAX]
    bar.set_ticks(ticks, labels=[f"{t:g}" + (" (JND)" if t == previews.JND_DE76 else "")
                                 for t in ticks])
    bar.ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.axvline(previews.JND_DE76, color="white", lw=1.5)
    low, high = previews.HEAT_MIN, previews.HEAT_MAX
    bar.set_label(f"ΔE76 per pixel (CIELAB units, log scale; ≤ {low:g} and uncovered pixels "
                  f"black, ≥ {high:g} shown as {high:g})")
    _save(fig, path)


def plot_answer(path: pathlib.Path, cells, rankings: dict, highlight: bool) -> None:
    """The equal-time answer at a glance: mean ΔE76 against ms/frame, log-log, one panel per
    scene on shared axes, each estimator's cells (error bars: their 95% intervals in time and
    error) joined in spp order, the scene's headline budgets dashed.  ``highlight``: the top
    three at the scene's middle headline budget (``rankings``: scene → its
    :class:`~iblbench.harness.protocol.ranking.Ranking` list) in colour and named in the panel,
    every other estimator grey; else every estimator in its colour, with one legend.  Cells of
    several devices (a ``device`` column) get a panel per scene and device, with that device's
    rankings (times are never compared across devices)."""
    panels = (list(dict.fromkeys(zip(cells.scene, cells.device))) if "device" in cells
              else [(scene, None) for scene in dict.fromkeys(cells.scene)])
    columns = min(3, len(panels))
    rows = -(-len(panels) // columns)
    styles = _styles(cells)
    with plt.rc_context({"font.size": 11}):   # three panels a row: a little smaller
        fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns + 0.6, 2.9 * rows + 0.9),
                                 sharex=True, sharey=True, layout="constrained", squeeze=False)
        for ax, (scene, device) in zip(axes.flat, panels):
            scene_rankings = [r for r in rankings.get(scene) or [] if r.device == device]
            chosen = scene_rankings[len(scene_rankings) // 2] if scene_rankings else None
            top = [s.estimator for s in chosen.ranked[:3]] if chosen is not None else []
            shown = cells[(cells.scene == scene) & ((cells.device == device) if device else True)]
            for name in _estimators(shown):
                summary = shown[shown.estimator == name].sort_values("spp")
                if not highlight:
                    style, extra = styles[name], {"label": name}
                elif name in top:   # a long label wraps at its parameters' commas
                    style = styles[name]
                    extra = {"label": f"{top.index(name) + 1}. {name}".replace(",", ",\n   "),
                             "lw": 2, "zorder": 3}
                else:   # "_": named, but in no legend
                    style = {"color": "0.75", "marker": "."}
                    extra = {"label": f"_{name}", "lw": 0.8, "zorder": 1}
                _errorbar(ax, summary, TIME, "mean_delta_e76", style, extra.pop("label", None),
                          x_interval=True, ms=4, **extra)
            for ranking in scene_rankings:
                ax.axvline(ranking.budget_ms, color="black", ls="--",
                           lw=1.4 if ranking is chosen else 0.6, alpha=0.7, zorder=0)
            title = scene if device is None else f"{scene}\non {device_name(device)}"
            title += "" if chosen is None else f" (top 3 at {chosen.budget_ms:g} ms)"
            ax.set_title(title, fontsize=11)
            if highlight and top:   # in rank order, in the empty fast-and-accurate corner
                handles, labels = ax.get_legend_handles_labels()
                order = sorted(range(len(labels)), key=lambda i: labels[i])
                ax.legend([handles[i] for i in order], [labels[i] for i in order], fontsize=8,
                          loc="lower left", frameon=True, framealpha=0.85, handlelength=1.5)
            ax.set_xscale("log")
            ax.set_yscale("log")
            _plain_log_axes(ax, "xy")
            ax.grid(True, which="both", alpha=0.3)
        for ax in axes.flat[len(panels):]:
            ax.set_visible(False)
        for ax in axes[-1]:
            ax.set_xlabel("device time per frame (ms)")
        for ax in axes[:, 0]:
            ax.set_ylabel("mean ΔE76 (CIELAB units)")
        if not highlight:
            _figure_legend(fig)
        _save(fig, path)


def plot_frames_at_budget(path: pathlib.Path, standings, scene: str, budget_ms: float,
                          estimators: list[str]) -> None:
    """A sequence's ΔE76 and flicker per frame at one time budget (``standings``: the table of
    :func:`iblbench.harness.protocol.sequence_answer.frame_standings`), each ranked estimator
    with its 95% intervals, in the colours of ``estimators`` (the scene's, in order)."""
    styles = _styles(pd.DataFrame({"estimator": estimators}))
    shown = standings[standings.frame.notna() & (standings.status == "ranked")].rename(
        columns={"mean": "value", "low": "value_low", "high": "value_high"})
    panels = (("mean_delta_e76", "mean ΔE76 at the budget"),
              ("flicker", "flicker at the budget (mean |change\nof ΔE76| from the previous frame)"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4), sharex=True, layout="constrained")
    for ax, (metric, label) in zip(axes, panels):
        for name in estimators:
            rows = shown[(shown.estimator == name) & (shown.metric == metric)].sort_values("frame")
            if len(rows):
                _errorbar(ax, rows, "frame", "value", styles[name], name, markersize=4)
        ax.set_yscale("log")
        _plain_log_axes(ax, "y")
        means = shown[(shown.metric == metric) & (shown.value > 0)].value
        if len(means):   # a seeds-only interval reaching 0 runs off the axis instead of squashing it
            ax.set_ylim(bottom=means.min() / 3)
        ax.set_ylabel(label, fontsize=10)
        ax.set_xlabel("frame (index in the sequence)")
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        ax.grid(True, which="both", alpha=0.3)
    _figure_legend(fig)
    fig.suptitle(f"{scene}: error and flicker per frame at {budget_ms:g} ms per frame")
    _save(fig, path)
