"""``perf.html`` (and ``perf.csv``) of ``iblbench perf``: the tables and roofline that
:mod:`iblbench.harness.studies.perf` measured, on the page of ``templates/perf.html.j2``."""
from __future__ import annotations

import pathlib

from iblbench.harness.studies import perf
from iblbench.harness.studies.perf import Roofline


def write_outputs(out: pathlib.Path, table, roofline: Roofline, context: dict) -> list[pathlib.Path]:
    """``perf.csv`` and ``perf.html`` in ``out`` (an existing folder), each written atomically."""
    import jinja2
    import markupsafe

    from iblbench.harness.protocol.results import write_table
    from iblbench.foundation.atomic import atomic_path

    csv, html = out / "perf.csv", out / "perf.html"
    write_table(table, csv)

    def as_html(frame):
        return markupsafe.Markup(frame.to_html(index=False, border=0, classes="summary", na_rep="–",
                                               float_format=lambda v: f"{v:.4g}"))

    templates = jinja2.Environment(
        loader=jinja2.PackageLoader("iblbench.reports", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"]), trim_blocks=True, lstrip_blocks=True)
    page = templates.get_template("perf.html.j2").render(
        title="iblbench perf", summary=as_html(perf.shown_table(table)), table=as_html(table),
        columns=perf.COLUMNS, roofline=roofline, method=perf.__doc__,
        floor_rtol=perf.FLOOR_RTOL, floor_atol=perf.FLOOR_ATOL, **context)
    with atomic_path(html) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return [csv, html]
