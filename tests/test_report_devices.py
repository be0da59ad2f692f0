"""A table of several devices (a sweep spread over machines): every figure of time is per device.

One tiny real run (sphere-sun, uniform and balanced at 4, 16 and 64 spp, two seeds, and an
equal-time cell each) is the fast device; the slow device is the same rows with ``device``
renamed and every time ×10 (its budget too: the slow machine's sweep asked for 10× the time), the
errors unchanged.  Each device's figures of time in the two-device table must be that device's
own single-device figures, the report must name both devices and head each one's times with its
name, and a one-device table's report must show no per-device split.
"""
from __future__ import annotations

import html
import re
import shutil

import pandas as pd
import pytest

from iblbench.commands.run import terminal_summaries
from iblbench.harness.protocol.machine_readable import run_summary
from iblbench.harness.protocol.ranking import scene_rankings
from iblbench.harness.protocol.runner import RunConfig, run
from iblbench.harness.protocol.stats import cell_intervals, column_interval, time_keys
from iblbench.reports.report import write_report
from iblbench.reports.tables import device_cells, summarize

SLOW = "Slow CPU"
FACTOR = 10.0


def _slower(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` as the slow device ran it: every time (and budget) × FACTOR."""
    def scaled(texts):
        return [" ".join(f"{float(v) * FACTOR:.7g}" for v in text.split()) for text in texts]

    times = {c: table[c] * FACTOR for c in table.columns
             if c.startswith("time_ms") and c != "time_ms_renders"}
    return table.assign(device=SLOW, time_ms_renders=scaled(table.time_ms_renders),
                        time_budget_ms=table.time_budget_ms * FACTOR, **times)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """{"one": the fast run, "slow": its rows on the slow device, "two": both} (folders)."""
    root = tmp_path_factory.mktemp("devices")
    one = root / "one"
    common = dict(out=one, scenes=("sphere-sun",), estimators=("uniform", "balanced"), seeds=2,
                  resolution=(24, 24), env_res=8, progress=False)
    run(RunConfig(spp=(4, 16, 64), **common))
    run(RunConfig(spp=(4,), time_budget_ms=(0.2,), **common))
    table = pd.read_parquet(one / "results.parquet")
    folders = {"one": one}
    for name, rows in (("slow", _slower(table)), ("two", pd.concat([table, _slower(table)]))):
        folders[name] = root / name
        shutil.copytree(one, folders[name], ignore=shutil.ignore_patterns("report"))
        rows.to_parquet(folders[name] / "results.parquet", index=False)
    return folders


def _table(folder) -> pd.DataFrame:
    return pd.read_parquet(folder / "results.parquet")


def _fast(runs) -> str:
    return _table(runs["one"]).device.iloc[0]


def test_a_time_is_never_aggregated_over_two_devices(runs):
    two = _table(runs["two"])
    with pytest.raises(ValueError, match="several devices"):
        column_interval(two, "time_ms")
    assert column_interval(two, "mean_delta_e76")[0].mean == pytest.approx(
        column_interval(_table(runs["one"]), "mean_delta_e76")[0].mean)
    assert time_keys(two, ["scene"]) == ["scene", "device"]
    assert time_keys(_table(runs["one"]), ["scene"]) == ["scene"]


def test_each_device_s_time_figures_are_its_single_device_figures(runs):
    two = _table(runs["two"])
    views = dict(device_cells(two, summarize(two)))
    assert list(views) == [_fast(runs), SLOW]
    timed = ["time_ms", "time_ms_low", "time_ms_high", "efficiency", "pareto_rel_mse",
             "pareto_delta_e76", "time_ms_host"]
    for device, folder in ((_fast(runs), "one"), (SLOW, "slow")):
        alone = summarize(_table(runs[folder]))
        pd.testing.assert_frame_equal(views[device][timed].reset_index(drop=True),
                                      alone[timed].reset_index(drop=True))
    # errors are pooled over the devices (the same errors: the same figures), times left out
    pooled = summarize(two)
    assert not any(c.startswith("time_") or c.startswith("pareto") for c in pooled)
    assert pooled.mean_delta_e76.tolist() == pytest.approx(
        summarize(_table(runs["one"])).mean_delta_e76.tolist())


def test_each_device_is_ranked_on_its_own_at_its_own_budgets(runs):
    two = scene_rankings(_table(runs["two"]))["sphere-sun"]
    for device, folder in ((_fast(runs), "one"), (SLOW, "slow")):
        alone = scene_rankings(_table(runs[folder]))["sphere-sun"]
        mine = [r for r in two if r.device == device]
        assert [r.budget_ms for r in mine] == [r.budget_ms for r in alone]
        assert [r.verdict().replace(f" ({device})", "") for r in mine] == \
            [r.verdict() for r in alone]
        assert all(f"sphere-sun ({device}):" in r.verdict() for r in mine)
    assert all(r.device is None for r in scene_rankings(_table(runs["one"]))["sphere-sun"])


def test_run_s_summaries_and_json_key_times_by_device(runs):
    two, one = _table(runs["two"]), _table(runs["one"])
    for (_, both), (_, alone) in zip(terminal_summaries(two), terminal_summaries(one)):
        assert both.index.names[-1] == "device"
        fast = both.xs(_fast(runs), level="device")
        assert fast.time_ms.tolist() == alone.time_ms.tolist()
        assert set(both.index.get_level_values("device")) == {_fast(runs), SLOW}
    cells = run_summary(two, runs["two"], {})["cells"]
    assert {c["device"] for c in cells} == {_fast(runs), SLOW}
    assert all("device" not in c for c in run_summary(one, runs["one"], {})["cells"])
    intervals = cell_intervals(two, time_keys(two, ["scene", "estimator", "spp"]), ["time_ms"])
    assert len(intervals) == 2 * len(cell_intervals(one, ["scene", "estimator", "spp"], ["time_ms"]))


def _h3(page: str) -> list[str]:
    return [html.unescape(re.sub("<[^>]+>", "", h)) for h in re.findall(r"<h3[^>]*>.*?</h3>", page)]


def _tables(page: str) -> dict[str, str]:
    """Each h3's title → the first table after it, as text."""
    found = {}
    for part in re.split(r"(?=<h3)", page):
        title = re.match(r"<h3[^>]*>(.*?)</h3>", part)
        table = re.search(r"<table.*?</table>", part, re.S)
        if title and table:
            found.setdefault(html.unescape(title.group(1)), table.group(0))
    return found


def _rows(table: str) -> list[list[str]]:
    return [[html.unescape(re.sub("<[^>]+>", "", c)) for c in re.findall(r"<t[hd][^>]*>.*?</t[hd]>", row)]
            for row in re.findall(r"<tr>.*?</tr>", table)]


def test_the_report_names_both_devices_and_shows_each_one_s_times_under_it(runs):
    context = write_report(runs["two"])
    page = context["path"].read_text(encoding="utf-8")
    fast = _fast(runs)
    headings = _h3(page)
    assert html.escape(fast) in page.split("<section")[0] and SLOW in page.split("<section")[0]
    assert "Times are per device" in page
    for device in (fast, SLOW):
        for title in ("Samples and time", "Equal time", "Error against time"):
            assert f"{title} on {device}" in headings
        assert any(h.startswith("Ranking at") and h.endswith(f" on {device}") for h in headings)
    assert "Samples and time" not in headings and "Errors" in headings
    # the fast device's tables are the one-device report's, cell by cell
    alone = _tables(write_report(runs["one"])["path"].read_text(encoding="utf-8"))
    both = _tables(page)
    assert both[f"Equal time on {html.escape(fast)}"] == alone["Equal time"]
    mine, theirs = (_rows(t) for t in (both[f"Samples and time on {html.escape(fast)}"],
                                       alone["Samples and time"]))
    assert len(mine) == len(theirs) and all(m[:len(t)] == t for m, t in zip(mine, theirs))
    assert mine[0][len(theirs[0]):] == ["Pareto (relMSE)", "Pareto (ΔE76)"]
    assert _rows(both["Errors"]) == [row[:len(_rows(both["Errors"])[0])]
                                     for row in _rows(alone["Errors"])]
    # the opening matrix: a row per scene and device
    matrix = re.search(r'<table class="summary matrix">.*?</table>', page, re.S).group(0)
    assert "<th>device</th>" in matrix and html.escape(fast) in matrix and SLOW in matrix
    devices = context["scenes"][0]["devices"]
    assert [d["device"] for d in devices] == [fast, SLOW]
    assert devices[0]["figures"]["time"] != devices[1]["figures"]["time"]


def test_a_one_device_report_has_no_per_device_split(runs):
    context = write_report(runs["one"])
    page = context["path"].read_text(encoding="utf-8")
    assert "Times are per device" not in page and "<th>device</th>" not in page
    assert not any(" on " in h for h in _h3(page) if not h.startswith("Sample picture"))
    assert [d["device"] for d in context["scenes"][0]["devices"]] == [None]
    assert context["scenes"][0]["devices"][0]["figures"]["time"] == "error_vs_time_sphere-sun.png"
