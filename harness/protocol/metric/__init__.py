"""What iblbench knows about each metric: one :class:`Metric` descriptor per metric, one module of
this package per metric.

A module of this package that defines ``METRIC`` (a :class:`Metric`) registers it; nothing else
names it.  Results (its columns, and its ``_renders`` replicate column), stats, ranking, the
budgets, ``compare``, the commands and ``--metrics`` read their lists from :func:`registered`, so a
new metric is one module here (``docs``: writing a metric) and a test.  A descriptor's ``score``
gets a :class:`~iblbench.harness.protocol.metrics.ScoredImage` (the estimate with non-finite values
as black, the reference's :class:`~iblbench.harness.protocol.metrics.Scorer`, and ΔE maps made
once for every metric that reads them) and returns one float.

The modules are imported on the first question asked of the registry, not with this package, so
that a metric's module may import the scoring module, which imports this one.
"""
from __future__ import annotations

import dataclasses
import functools
import importlib
import pkgutil
from typing import Callable

RENDERS = "_renders"      # a metric's per-render values: column f"{column}{RENDERS}"
LIMITS = ("max", "min")   # the bounds a budgets file may set: max_<column>, min_<column>


@dataclasses.dataclass(frozen=True)
class Metric:
    """One metric: how it is named, stored, shown, judged and computed."""
    name: str                 # on the command line and in a sweep's ``metrics`` (``de76``)
    column: str               # its results column (``mean_delta_e76``)
    label: str                # in tables, plots and rankings (``ΔE76``)
    unit: str                 # of its values ("" for a pure number)
    order: int                # its place in every list of metrics and in the table's columns
    score: Callable[..., float]   # ScoredImage → the metric over the covered pixels
    lower_is_better: bool = True
    replicated: bool = True   # scored on every timed render: ``column + "_renders"`` holds them
    default: bool = True      # computed where a sweep or call names no metrics
    always: bool = False      # computed whatever is asked for (ΔE76: heat maps and flicker)
    budget_limits: tuple[str, ...] = LIMITS   # of LIMITS: what a budgets file may gate on it
    derive_budget: bool = True   # ``iblbench budgets`` bounds it where the run computed it
    in_run_summary: bool = True  # a column of the table ``iblbench run`` prints

    @property
    def description(self) -> str:
        """Its module's docstring: what it measures and why (``iblbench list metrics``)."""
        return importlib.import_module(self.score.__module__).__doc__ or ""

    @property
    def renders_column(self) -> str | None:
        """The column of its per-render replicates; None for a metric scored once per cell."""
        return self.column + RENDERS if self.replicated else None


@functools.lru_cache(maxsize=None)
def registered() -> tuple[Metric, ...]:
    """Every metric of this package's modules, in ``order``."""
    found = []
    for module in pkgutil.iter_modules(__path__):
        descriptor = getattr(importlib.import_module(f"{__name__}.{module.name}"), "METRIC", None)
        if descriptor is not None:
            found.append(descriptor)
    found.sort(key=lambda metric: metric.order)
    for kind in ("name", "column", "order"):
        values = [getattr(metric, kind) for metric in found]
        if len(set(values)) != len(values):
            raise RuntimeError(f"two metrics share a {kind}: {values}")
    return tuple(found)


def names() -> tuple[str, ...]:
    """Every metric's name, in order."""
    return tuple(metric.name for metric in registered())


def default_names() -> tuple[str, ...]:
    """The metrics computed where none are named."""
    return tuple(metric.name for metric in registered() if metric.default)


def columns() -> list[str]:
    """Every metric's results column, in order."""
    return [metric.column for metric in registered()]


def replicated_columns() -> tuple[str, ...]:
    """The columns of the metrics scored on every timed render."""
    return tuple(metric.column for metric in registered() if metric.replicated)


def higher_is_better() -> frozenset[str]:
    """The columns of the metrics whose larger value is the better one (PSNR)."""
    return frozenset(metric.column for metric in registered() if not metric.lower_is_better)


def labels() -> dict[str, str]:
    """Column → label."""
    return {metric.column: metric.label for metric in registered()}


def parse_metrics(text: str) -> tuple[str, ...]:
    """``de76,de2000,relmse,flip`` (any subset, any order) → the metrics in registry order, those
    computed always included; ValueError naming the valid ones for an unknown name."""
    asked = {part.strip().lower() for part in text.split(",") if part.strip()}
    unknown = sorted(asked - set(names()))
    if unknown:
        raise ValueError(f"unknown metric {unknown[0]!r}; valid: {','.join(names())}")
    return tuple(metric.name for metric in registered() if metric.name in asked or metric.always)


__all__ = ["LIMITS", "RENDERS", "Metric", "columns", "default_names", "labels", "names", "parse_metrics",
           "registered", "replicated_columns"]
