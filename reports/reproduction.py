"""Markdown and HTML summaries of a paper reproduction (tables, plots, verdicts)."""
from __future__ import annotations

import pathlib

import jinja2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

from iblbench.scenes.atomic import atomic_path  # noqa: E402

_TEMPLATES = jinja2.Environment(
    loader=jinja2.PackageLoader("iblbench.reports", "templates"),
    autoescape=jinja2.select_autoescape(["html"]), trim_blocks=True, lstrip_blocks=True)


def _format(value) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{value:.3g}" if np.isfinite(value) else "–"
    return str(value)


def _rows(frame) -> list[list[str]]:
    return [[_format(v) for v in row] for row in frame.itertuples(index=False)]


def plot_error_vs_spp(path: pathlib.Path, table) -> None:
    """Mean ΔE76 against spp on log-log axes, one line per scene, with a −½ slope guide."""
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for scene, rows in table.groupby("scene"):
        rows = rows.sort_values("spp")
        ax.loglog(rows.spp, rows.mean_delta_e76, "o-", label=scene)
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
    ax.bar(x - 0.2, table.used, 0.4, label="used")
    ax.bar(x + 0.2, table.effective, 0.4, label="effective (cos > 0)")
    ax.set_xticks(x, labels, fontsize=7, rotation=45, ha="right")
    ax.set_ylabel("samples per pixel")
    ax.legend()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)


def write_summary(out: pathlib.Path, result) -> pathlib.Path:
    """Write ``summary.md`` and ``summary.html`` (plots beside them); returns the Markdown path."""
    plots = {"fig3": "fig3_error_vs_spp.png", "fig2": "fig2_samples.png"}
    plot_error_vs_spp(out / plots["fig3"], result.tables["fig3"])
    plot_effective_samples(out / plots["fig2"], result.tables["fig2"])
    context = {
        "title": result.title,
        "differences": result.setup_differences,
        "verdicts": result.verdicts,
        "tables": {name: {"columns": list(t.columns), "rows": _rows(t)}
                   for name, t in result.tables.items()},
        "plots": plots,
    }
    for name in ("summary.md", "summary.html"):
        text = _TEMPLATES.get_template(f"reproduction.{name.split('.')[1]}.j2").render(**context)
        with atomic_path(out / name) as tmp:
            tmp.write_text(text, encoding="utf-8")
    return out / "summary.md"
