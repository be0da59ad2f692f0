"""``iblbench run``: a sweep through the runner, its tables on the terminal and its --json document."""
from __future__ import annotations

import pathlib
import sys

from iblbench.commands.common import (add_json, budgets_arg, env_res, frames_arg, human_output,
                                      labels_arg, launch_shape, metrics_arg, non_negative_int, positive_int,
                                      print_json, rendering_flags, repeats_arg, resolution,
                                      spp_list)


DESCRIPTION = """\
Render every (scene, estimator, spp, frame, seed) cell of a sweep, score it against the exact
reference and write results.parquet/.csv, manifest.json and images/<scene>/f<frame>/ (the EXR of
every image; `iblbench report` draws the PNG previews and ΔE heat maps) into --out. The sweep comes from --config (default: the shipped
'default'); each flag given replaces that field of the config. Re-running resumes: cells already
in --out with the same configuration, code version and device are skipped. The cells run in this
process, or on a Dask cluster (--workers, --scheduler) whose rows this process alone writes; every
row names the host and device that ran it."""


def add_parser(subparsers) -> None:
    from iblbench.harness.protocol.run_config import flag_help, flag_of
    from iblbench.harness.protocol.sweep import SHIPPED

    run = subparsers.add_parser(
        "run", help="benchmark estimators on scenes and write results, manifest and images",
        description=DESCRIPTION,
        parents=[rendering_flags()])

    def setting(group, name, **options):
        """The flag of RunConfig field ``name``, with its help text."""
        group.add_argument(flag_of(name), help=flag_help(name), **options)

    run.add_argument("--config", metavar="NAME|FILE",
                     help=f"sweep config: a shipped one ({', '.join(SHIPPED)}) or a .toml file "
                          "(default: default; format: the docstring of iblbench.harness.sweep)")
    setting(run, "scenes", action="append", metavar="NAME|FILE")
    setting(run, "estimators", action="append", metavar="NAME")
    setting(run, "control", type=labels_arg, action="append", metavar="NAME[,NAME...]")
    setting(run, "spp", type=spp_list, metavar="N,N,...")
    setting(run, "seeds", type=positive_int)
    setting(run, "first_seed", type=non_negative_int, metavar="S")
    setting(run, "frames", metavar="START:STOP[:STEP]")
    setting(run, "resolution", type=resolution, metavar="WxH")
    setting(run, "env_res", type=env_res, metavar="R")
    setting(run, "time_budget_ms", type=budgets_arg, metavar="T[,T...]")
    setting(run, "repeats", type=repeats_arg, metavar="N[,NAME=M...]")
    metrics = run.add_mutually_exclusive_group()
    setting(metrics, "metrics", type=metrics_arg, metavar="M[,M...]")
    metrics.add_argument("--no-flip", action="store_true",
                         help="leave HDR-FLIP out (the slowest metric)")
    setting(run, "force", action="store_true")
    setting(run, "out", type=pathlib.Path, default=pathlib.Path("results/latest"))
    setting(run, "save_inputs", action="store_true")
    setting(run, "launch_shape", type=launch_shape, metavar="auto|pixel|sample-block")
    setting(run, "sanitize", action="store_true")
    where = run.add_mutually_exclusive_group()
    setting(where, "workers", type=positive_int, metavar="N")
    setting(where, "scheduler", metavar="ADDRESS")
    add_json(run)


def _flag_value(args, name: str):
    """The value of RunConfig field ``name``'s flag in ``args``."""
    from iblbench.harness.protocol.run_config import flag_of

    return getattr(args, flag_of(name).lstrip("-").replace("-", "_"))


def run_settings(args) -> tuple[dict, list[str]]:
    """:func:`iblbench.run_config`'s keywords from the flags, and the sweep's flags given (the
    manifest's ``overridden_by_flags``)."""
    from iblbench.harness.protocol.run_config import SWEEP_FIELDS, config_keywords, flag_of
    from iblbench.harness.protocol.sweep import load_sweep

    settings = {name: _flag_value(args, name) for name in config_keywords() if flag_of(name)}
    if args.no_flip:   # --metrics excludes it
        settings["metrics"] = tuple(m for m in load_sweep(args.config or "default").metrics
                                    if m != "flip")
    flags = [("--no-flip" if name == "metrics" and args.no_flip else flag_of(name))
             for name in SWEEP_FIELDS
             if name in settings and settings[name] is not None and settings[name] is not False]
    # "all" parses to None, which Sweep.replace would ignore: spell it as the full slice.
    settings["frames"] = None if args.frames is None else (frames_arg(args.frames) or slice(None))
    settings["sanitize"] = True if args.sanitize else None   # not given: the sweep's
    settings["repeats"], settings["repeats_for"] = args.repeats or (None, None)
    settings["control"] = args.control and [label for labels in args.control for label in labels]
    settings["progress"] = False if args.no_progress else None
    return settings, flags


def run(args) -> None:
    if args.scheduler is not None:   # before the runner's imports, seconds on a busy machine
        from iblbench.harness.protocol.scheduler_address import check_scheduler

        check_scheduler(args.scheduler)
    from iblbench import run_config
    from iblbench.harness.protocol.machine_readable import run_summary
    from iblbench.harness.protocol.results import read_manifest
    from iblbench.harness.protocol.runner import Runner

    settings, flags = run_settings(args)
    runner = Runner(run_config(args.out, config=args.config, **settings,
                               note={"overridden_by_flags": flags}))
    table = runner.run()
    human = human_output(args)
    rows = runner.sweep_rows(table)   # --out may also hold other sweeps' cells
    for title, summary in terminal_summaries(rows):
        if title:
            print(title, file=human)
        print(summary.to_string(float_format=lambda v: f"{v:.4g}"), file=human)
    print(f"wrote {len(rows)} rows to {args.out}/results.parquet"
          + (f" ({len(table)} in all)" if len(table) != len(rows) else "")
          + (f", run on {', '.join(sorted(set(rows['device'])))}" if len(rows) and "device" in rows
             else ""),
          file=human)
    from iblbench.harness.protocol.control import control_calls
    from iblbench.harness.protocol.ranking import rankings_text, scene_rankings
    rankings = scene_rankings(rows) if len(rows) else {}
    if any(rankings.values()):
        print(rankings_text(rankings), file=human)
    for calls in control_calls(rankings, rows.get("estimator", ())):
        print(calls.text(), file=human)
    from iblbench.harness.verify.convergence import flatter_than_tags
    for flag in flatter_than_tags(rows):   # issues 11, 34: not converging, or not resolved
        print(f"warning: convergence: {flag.text()}", file=sys.stderr)
    if args.json:
        print_json(run_summary(rows, args.out, read_manifest(args.out), rankings))


def terminal_summaries(table):
    """The tables ``iblbench run`` prints: per (scene, estimator, spp) cell, then per equal-time
    cell. Beside spp each shows what a sample costs, as the estimators' spp are not comparable
    (one bis or smc sample costs 21 integrand evaluations): ``evaluations`` (integrand evaluations per
    covered pixel) and the cell's time of :mod:`iblbench.harness.protocol.timing` (``time_ms``: device ms
    per frame, build + sample + shade) as the report and ``check`` show it.  Errors are the mean
    over the cell's scored renders, the time the median of its timed renders, each with its 95%
    interval, ``mean ± half-width`` (:func:`iblbench.harness.protocol.stats.cell_intervals`);
    ``seeds`` says how many seeds.  Where several devices ran the rows, each cell is keyed by its
    device too (:func:`iblbench.harness.protocol.stats.time_keys`): times are per device."""
    from iblbench.harness.protocol.metric import registered
    from iblbench.harness.protocol.stats import cell_intervals, interval_text, time_keys
    from iblbench.harness.protocol.timing import TIME

    shown = {TIME: TIME, **{metric.column: metric.column for metric in registered()
                            if metric.in_run_summary},
             "effective_samples": "effective", "used_samples": "used"}
    summaries = []
    for keys, rows, title in (
            (["scene", "estimator", "spp"], table[table.time_budget_ms.isna()],
             "error at equal spp (an spp costs each estimator different evaluations and time: "
             "compare estimators at equal time_ms, as --time-budget-ms does):"),
            (["scene", "time_budget_ms", "estimator"], table[table.time_budget_ms.notna()],
             "error at equal time (the spp chosen so that the device time per frame, build + "
             "sample + shade, lands within 10% of time_budget_ms):")):
        if len(rows):
            keys = time_keys(table, keys)
            columns = [c for c in shown if c in rows and rows[c].notna().any()]
            cells = cell_intervals(rows, keys, columns)
            spp = {} if "spp" in keys else {"spp": ("spp", "first")}
            summary = rows.groupby(keys).agg(**spp, evaluations=("evaluations", "mean"))
            for column in columns:
                summary[shown[column]] = [interval_text(
                    cells.loc[key, column], cells.loc[key, f"{column}_half"],
                    int(cells.loc[key, f"{column}_n"]), low=cells.loc[key, f"{column}_low"],
                    high=cells.loc[key, f"{column}_high"]) for key in summary.index]
            summary["seeds"] = cells.seeds
            summary["nonfinite"] = rows.groupby(keys).nonfinite.sum()
            summaries.append((title, summary))
    return summaries
