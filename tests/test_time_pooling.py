"""Times are per device (issue 36, class 5): every time column of the results schema, not only
``time_ms``, is refused when an aggregation would pool rows of two devices, and kept when the
rows are one device's or keyed by device.

The columns come from the schema (``results.TIME_COLUMNS``), so a time column added to it is a
case here without a new test; :func:`test_a_time_column_added_to_the_schema_is_refused_too`
adds one that does not even start with ``time_``.  The tables are made here: two seeds of one
cell on a fast device and the same rows on a slow one, every time ten times longer.
"""
from __future__ import annotations

import math

import pandas as pd
import pytest

from iblbench.cli import main
from iblbench.harness.protocol import stats
from iblbench.harness.protocol.budgets import TIME_METRICS
from iblbench.harness.protocol.results import COLUMNS, TIME_COLUMNS, write_results
from iblbench.harness.protocol.stats import (RENDERS, cell_intervals, column_interval,
                                             is_time_column, time_keys)
from iblbench.harness.protocol.timing import TimedRender, time_columns
from iblbench.reports.tables import summarize

KEYS = ["scene", "estimator", "spp"]


def _rows(device: str, scale: float, extra: tuple = (), estimator: str = "uniform",
          seeds: int = 2) -> list[dict]:
    """``seeds`` seeds of one cell on ``device``; seed s's renders take ``scale`` × (1, 2, 3) ms
    + s; ``extra``: more time columns, with the same values as ``time_ms``."""
    rows = []
    for seed in range(seeds):
        renders = [TimedRender({"build": 0.1 * scale, "sample": 0.2 * scale,
                                "shade": (0.7 + render + seed) * scale}, 2.0 * scale)
                   for render in range(3)]
        times = time_columns(renders)
        rows.append({"scene": "s", "estimator": estimator, "spp": 4, "frame": 0, "seed": seed,
                     "width": 8, "height": 8, "env_res": 8, "protocol": "p", "metrics": "de76",
                     "time_budget_ms": math.nan, "mean_delta_e76": 1.0 + seed,
                     "mean_delta_e2000": 1.0, "rel_mse": 0.1, "used_samples": 4.0,
                     "effective_samples": 4.0, "effective_ratio": 1.0, "shadow_rays": 0.0,
                     "nonfinite": 0, "device": device, **times,
                     **{column: times["time_ms"] for column in extra}})
    return rows


def _tables(extra: tuple = ()) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the fast device's table, both devices' table)."""
    fast = _rows("Fast GPU", 1.0, extra)
    return pd.DataFrame(fast), pd.DataFrame(fast + _rows("Slow CPU", 10.0, extra))


def test_a_row_s_time_columns_are_the_schema_s():
    """What the timing module writes into a row is what the schema lists as its time columns
    (a time column the row gains is then in the schema, and refused below)."""
    row = time_columns([TimedRender({"build": 1.0, "shade": 2.0}, 3.0)])
    assert sorted(row) == sorted(TIME_COLUMNS) and set(TIME_COLUMNS) <= set(COLUMNS)


@pytest.mark.parametrize("column", TIME_COLUMNS)
def test_every_time_column_is_refused_over_two_devices(column):
    one, two = _tables()
    if column.endswith(RENDERS):   # per-render text: what time_ms's interval is made of
        column = column[:-len(RENDERS)]
    with pytest.raises(ValueError, match=f"{column} of rows from several devices"):
        column_interval(two, column)
    with pytest.raises(ValueError, match="several devices"):
        cell_intervals(two, KEYS, [column])
    # One device's rows, or both keyed by device, are aggregated: each device's own figure.
    alone = cell_intervals(one, KEYS, [column])[column].iloc[0]
    per_device = cell_intervals(two, time_keys(two, KEYS), [column])[column]
    assert per_device.xs("Fast GPU", level="device").iloc[0] == pytest.approx(alone)
    assert math.isfinite(alone) and alone > 0


def test_the_report_s_summary_of_two_devices_shows_no_time_column():
    """summarize pools errors over devices and leaves every time column to the per-device
    tables (reports.tables.device_cells)."""
    one, two = _tables()
    shown = [column for column in summarize(two) if is_time_column(column)
             or any(column.startswith(time + "_") for time in TIME_COLUMNS)]
    assert shown == []
    assert "time_ms" in summarize(one) and "time_ms_host" in summarize(one)   # one device: shown


def test_a_time_column_added_to_the_schema_is_refused_too(monkeypatch):
    """A time column the schema gains is refused by construction, whatever its name."""
    added = "gpu_wall_ms"
    one, two = _tables(extra=(added,))
    column_interval(two, added)                      # not yet a time column: pooled
    monkeypatch.setattr(stats, "TIME_COLUMNS", (*stats.TIME_COLUMNS, added))
    assert is_time_column(added)
    with pytest.raises(ValueError, match=f"{added} of rows from several devices"):
        column_interval(two, added)
    assert column_interval(one, added)[0].mean > 0


def test_the_time_ratios_a_budget_may_bound_are_the_schema_s_times_in_ms():
    """Every time column a row holds as a number of ms (not a count, not text) is a metric of
    ``max_time_ratio``, and only those."""
    row = time_columns([TimedRender({"build": 1.0, "shade": 2.0}, 3.0)])
    assert TIME_METRICS == tuple(c for c in TIME_COLUMNS if isinstance(row[c], float))


@pytest.mark.parametrize("metric", TIME_METRICS)
def test_check_refuses_a_time_ratio_over_two_devices(tmp_path, capsys, metric):
    """``iblbench check`` of a time ratio: on one device's rows the ratio; on two devices' rows
    one line, exit 2, naming both (no traceback); the errors alone are still checked."""
    budgets = tmp_path / "budgets.toml"
    ratio = ("[[rule]]\nscene = 's'\nestimator = 'balanced'\nspp = 4\n"
             f"max_time_ratio = {{ baseline = 'uniform', metric = '{metric}', max = 100 }}\n")
    errors = "[[rule]]\nscene = 's'\nestimator = '*'\nspp = 4\nmax_mean_delta_e76 = 9\n"
    fast, slow = (_rows(device, scale, estimator=label) for device, scale, label in
                  (("Fast GPU", 1.0, "balanced"), ("Slow CPU", 10.0, "uniform")))
    outcomes = []
    for name, rows, rules in (("one", _rows("Fast GPU", 1.0) + fast, ratio),
                              ("two", _rows("Fast GPU", 1.0) + fast + slow, ratio),
                              ("errors", _rows("Fast GPU", 1.0) + fast + slow, errors)):
        (tmp_path / name).mkdir()
        write_results(tmp_path / name, rows)
        budgets.write_text("[configuration]\nwidth = 8\nheight = 8\nenv_res = 8\nseeds = 2\n"
                           "protocol = 'p'\n" + rules)
        outcomes.append((main(["check", str(tmp_path / name), "--budgets", str(budgets)]),
                         capsys.readouterr().err))
    assert [status for status, _ in outcomes] == [0, 2, 0], outcomes
    assert outcomes[1][1].count("\n") == 1 and "2 devices (Fast GPU, Slow CPU)" in outcomes[1][1]


def test_budgets_are_not_made_from_two_devices_times(tmp_path, capsys):
    """``iblbench budgets`` derives a time ratio against uniform: from one device's rows, not
    from two devices' (one line, exit 2)."""
    rows = {device: _rows(device, scale, seeds=8) + _rows(device, scale, estimator="balanced",
                                                          seeds=8)
            for device, scale in (("Fast GPU", 1.0), ("Slow CPU", 10.0))}
    statuses = []
    for name, table in (("one", rows["Fast GPU"]), ("two", rows["Fast GPU"] + rows["Slow CPU"])):
        (tmp_path / name).mkdir()
        write_results(tmp_path / name, table)
        statuses.append(main(["budgets", str(tmp_path / name), "--margin", "0.1", "--output",
                              str(tmp_path / f"{name}.toml")]))
    err = capsys.readouterr().err
    assert statuses == [0, 2] and "2 devices (Fast GPU, Slow CPU)" in err, (statuses, err)
    assert "max_time_ratio" in (tmp_path / "one.toml").read_text()
