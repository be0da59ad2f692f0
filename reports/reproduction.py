"""Markdown and HTML summaries of a paper reproduction (tables, plots, verdicts)."""
from __future__ import annotations

import pathlib

import jinja2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

from iblbench.harness.protocol.stats import interval_text  # noqa: E402
from iblbench.foundation.atomic import atomic_path  # noqa: E402

_TEMPLATES = jinja2.Environment(
    loader=jinja2.PackageLoader("iblbench.reports", "templates"),
    # HTML templates escape what they interpolate (their names end in .html.j2, which
    # select_autoescape(["html"]) does not match: issue 23); the Markdown one must not.
    autoescape=lambda name: name is not None and name.endswith((".html", ".html.j2")),
    trim_blocks=True, lstrip_blocks=True)


def _format(value) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{value:.3g}" if np.isfinite(value) else "–"
    return str(value)


def _shown(frame) -> tuple[list[str], list[list[str]]]:
    """(columns, rows) of a table: a column with a ``_half`` beside it (its 95% interval's
    half-width) as ``mean ± half-width`` (:func:`iblbench.harness.protocol.stats.interval_text`)."""
    columns = [c for c in frame.columns if not c.endswith("_half")]
    rows = []
    for _, row in frame.iterrows():
        rows.append([interval_text(row[c], row[f"{c}_half"], row["seeds"])
                     if f"{c}_half" in frame else _format(row[c]) for c in columns])
    return columns, rows


def _half(table, column: str):
    """The half-widths of ``column``'s intervals, for error bars (None where the table has none)."""
    return table[f"{column}_half"] if f"{column}_half" in table else None


def plot_error_vs_spp(path: pathlib.Path, table) -> None:
    """Mean ΔE76 against spp on log-log axes, one line per scene (with its 95% intervals as error
    bars where the table has them), with a −½ slope guide."""
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for scene, rows in table.groupby("scene"):
        rows = rows.sort_values("spp")
        ax.errorbar(rows.spp, rows.mean_delta_e76, yerr=_half(rows, "mean_delta_e76"), fmt="o-",
                    capsize=2, label=scene)
    ax.set_xscale("log")
    ax.set_yscale("log")
    spp = np.array(sorted(table.spp.unique()), float)
    start = table[table.spp == spp[0]].mean_delta_e76.max()
    ax.loglog(spp, start * (spp / spp[0]) ** -0.5, "k--", label="slope −½")
    ax.set_xticks(spp, [str(int(v)) for v in spp])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("samples per pixel")
    ax.set_ylabel("mean ΔE76")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)


def plot_effective_samples(path: pathlib.Path, table) -> None:
    """Used and effective samples per pixel of each (scene, estimator@spp) cell."""
    labels = [f"{r.scene}\n{r.estimator}@{r.spp}" for r in table.itertuples()]
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(max(6, 0.9 * len(labels)), 4.5))
    ax.bar(x - 0.2, table.used, 0.4, yerr=_half(table, "used"), capsize=2, label="used")
    ax.bar(x + 0.2, table.effective, 0.4, yerr=_half(table, "effective"), capsize=2,
           label="effective (cos > 0)")
    ax.set_xticks(x, labels, fontsize=7, rotation=45, ha="right")
    ax.set_ylabel("samples per pixel")
    ax.legend()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)


def plot_ratios(path: pathlib.Path, table, lines: dict[str, float]) -> None:
    """One point per compared pair (``label``) at its ratio, with its 95% interval (``low``,
    ``high``; none where the ratio has no interval) as an asymmetric error bar, on a log axis,
    and a line at each of ``lines`` (labelled values)."""
    fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(table)), 4.5))
    x = np.arange(len(table))
    ratio = table.ratio.to_numpy(float)
    below, above = ratio - table.low.to_numpy(float), table.high.to_numpy(float) - ratio
    ax.errorbar(x, ratio, yerr=np.nan_to_num([below, above]), fmt="o", color="#1f5fa8",
                capsize=3, label="ratio, 95% interval")
    for (label, value), style in zip(lines.items(), ("k--", "r:", "g-.")):
        ax.axhline(value, color=style[0], linestyle=style[1:], label=label)
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set_xticks(x, table.label, fontsize=7, rotation=45, ha="right")
    ax.set_ylabel("error ratio (95% interval)")
    ax.legend()
    ax.grid(True, axis="y", which="both", alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)


# Plot.kind → its drawing: (path, the plot) → None
PLOTS = {"error_vs_spp": lambda path, plot: plot_error_vs_spp(path, plot.data),
         "samples": lambda path, plot: plot_effective_samples(path, plot.data),
         "ratios": lambda path, plot: plot_ratios(path, plot.data, plot.lines)}


def summary_head(markdown: str) -> str:
    """A summary's title and verdicts, the part `iblbench reproduce` prints: everything before
    its second ``## `` heading (the first is the verdicts')."""
    return "\n## ".join(markdown.split("\n## ")[:2]).strip()


def write_summary(out: pathlib.Path, result) -> pathlib.Path:
    """Write ``summary.md`` and ``summary.html`` (plots beside them); returns the Markdown path."""
    sections = []
    for section in result.sections:
        if section.plot is not None:
            PLOTS[section.plot.kind](out / section.plot.file, section.plot)
        columns, rows = _shown(section.table)
        sections.append({"title": section.title, "columns": columns, "rows": rows,
                         "plot": section.plot})
    context = {"title": result.title, "differences": result.setup_differences,
               "verdicts": result.verdicts, "sections": sections}
    for name in ("summary.md", "summary.html"):
        text = _TEMPLATES.get_template(f"reproduction.{name.split('.')[1]}.j2").render(**context)
        with atomic_path(out / name) as tmp:
            tmp.write_text(text, encoding="utf-8")
    return out / "summary.md"
