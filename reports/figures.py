"""The report's figure cache: each figure of :mod:`.plots` drawn only where the report does not
hold it drawn already from the same data and code (``report/figures.json``)."""
from __future__ import annotations

import functools
import hashlib
import json
import pathlib
import pickle

import pandas as pd

from iblbench.reports import plots
from iblbench.foundation.atomic import atomic_path

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


def slugify(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text)


__all__ = ["Figures", "slugify"]
