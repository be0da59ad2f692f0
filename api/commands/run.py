"""``iblbench run``: a sweep through the runner, its tables on the terminal and its --json document."""
from __future__ import annotations

import pathlib
import sys

from iblbench.commands.common import (add_json, env_res, human_output, non_negative_int,
                                      positive_int, print_json, rendering_flags, resolution,
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
    from iblbench.harness.protocol import sweep
    from iblbench.harness.protocol.metric import names as metric_names

    run = subparsers.add_parser(
        "run", help="benchmark estimators on scenes and write results, manifest and images",
        description=DESCRIPTION,
        parents=[rendering_flags()])
    run.add_argument("--config", metavar="NAME|FILE",
                     help="sweep config: a shipped one (quick, default, full, temporal) or a .toml file "
                          "(default: default; format: the docstring of iblbench.harness.sweep)")
    run.add_argument("--scene", action="append", metavar="NAME|FILE",
                     help="built-in scene name or a scene .toml file; repeatable")
    run.add_argument("--estimator", action="append", metavar="NAME",
                     help="estimator name, optionally with parameters as NAME{param=value,...}; "
                          "repeatable (see 'iblbench list estimators')")
    run.add_argument("--control", type=sweep.labels_arg, action="append", metavar="NAME[,NAME...]",
                     help="the A/A control: run estimator NAME (one of the run's, spelt as for "
                          "--estimator) a second time, unchanged, as NAME@control (the same "
                          "images at equal spp and seed, its own timings), and count the "
                          "equal-time verdicts that call the two apart: each is a false call, "
                          "and the stated 95%% level allows about 5%%; repeatable or "
                          "comma-separated; --estimator without --control drops the config's "
                          "control")
    run.add_argument("--spp", type=spp_list, metavar="N,N,...",
                     help="samples per pixel, comma-separated, the same for every estimator "
                          "(a sweep config may give estimators levels of their own, as the "
                          "default sweep does: spp = {default = [...], NAME = [...]})")
    run.add_argument("--seeds", type=positive_int,
                     help="seeds per cell, 0..N-1; each seed's timed renders (--repeats) are "
                          "all scored, so one seed already gives a cell an interval")
    run.add_argument("--first-seed", type=non_negative_int, metavar="S",
                     help="the first seed instead of 0: seeds S..S+N-1 (a seeds-only rerun)")
    run.add_argument("--frames", metavar="START:STOP[:STEP]",
                     help="frames of environment sequences, a Python slice of each sequence's "
                          "frames such as 0:67:6 or ::4 (default: all; also all, A..B inclusive "
                          "or N,N,...; write --frames=-5: for a negative start); static scenes "
                          "run frame 0")
    run.add_argument("--res", type=resolution, metavar="WxH",
                     help="image resolution (default: the scene's own)")
    run.add_argument("--env-res", type=env_res, metavar="R",
                     help="cube face resolution for built-in skies and resampled maps")
    run.add_argument("--time-budget-ms", type=sweep.budgets_arg, metavar="T[,T...]",
                     help="equal-time cells besides the spp list: per (scene, estimator), the spp "
                          "whose calibrated device time per frame (build+sample+shade) lands "
                          "within 10%% of T ms; the run says where it cannot")
    run.add_argument("--repeats", type=sweep.repeats_arg, metavar="N[,NAME=M...]",
                     help=f"timed renders per cell after warm-up (default: the sweep's; "
                          f"{sweep.DEFAULT_REPEATS} where it gives none, 10 in the shipped "
                          "default sweep), each in a round of the frame's cells; a cell's "
                          "time is the median of their device times (build+sample+shade), "
                          "with min and IQR beside it; "
                          "NAME=M gives estimator NAME M of its own (e.g. 5,smc=3)")
    metrics = run.add_mutually_exclusive_group()
    metrics.add_argument("--metrics", type=sweep.metrics_arg, metavar="M[,M...]",
                         help=f"metrics to compute, of {','.join(metric_names())} (default: the "
                              "sweep's own: de76,de2000,relmse for the shipped default, which leaves "
                              "the slow FLIP out, all four for full; de76 always: heat maps and "
                              "flicker use it); one left out is NaN")
    metrics.add_argument("--no-flip", action="store_true",
                         help="leave HDR-FLIP out (the slowest metric)")
    run.add_argument("--force", action="store_true",
                     help="recompute the selected cells even where --out already has them, and "
                          "replace the results of another --res or --env-res there (without it, "
                          "a run refuses an --out made with another of those)")
    run.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/latest"),
                     help="output directory (default: results/latest)")
    run.add_argument("--save-inputs", action="store_true",
                     help="also write inputs/<scene>/gbuffer.npz and env_f<frame>.npy")
    run.add_argument("--sanitize", action="store_true",
                     help="replace NaN/Inf/negative texels in environment maps instead of refusing")
    where = run.add_mutually_exclusive_group()
    where.add_argument("--workers", type=positive_int, metavar="N",
                       help="run the cells on a Dask LocalCluster of N worker processes on this "
                            "machine (spawned; one OpenCL context each); this process alone "
                            "writes --out's table; default: in this process")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run the cells on the Dask cluster whose dask-scheduler is at "
                            "ADDRESS (e.g. tcp://node1:8786); its workers need this iblbench, "
                            "and --out and the cache (IBLBENCH_CACHE) on a filesystem they share "
                            "(README, 'Running on a cluster')")
    add_json(run)


def run(args) -> None:
    from iblbench import run_config
    from iblbench.harness.protocol.machine_readable import run_summary
    from iblbench.harness.protocol.results import read_manifest
    from iblbench.harness.protocol.runner import Runner
    from iblbench.harness.protocol.sweep import frames_arg, load_sweep

    # "all" parses to None, which Sweep.replace would ignore: spell it as the full slice.
    frames = None if args.frames is None else (frames_arg(args.frames) or slice(None))
    metrics = args.metrics
    if args.no_flip:
        metrics = tuple(m for m in load_sweep(args.config or "default").metrics if m != "flip")
    flags = [flag for flag, value in (
        ("--scene", args.scene), ("--estimator", args.estimator), ("--spp", args.spp),
        ("--seeds", args.seeds), ("--first-seed", args.first_seed is not None),
        ("--frames", args.frames), ("--res", args.res),
        ("--env-res", args.env_res), ("--time-budget-ms", args.time_budget_ms),
        ("--sanitize", args.sanitize), ("--repeats", args.repeats), ("--metrics", args.metrics),
        ("--no-flip", args.no_flip), ("--control", args.control)) if value]
    runner = Runner(run_config(
        args.out, config=args.config, scenes=args.scene, estimators=args.estimator,
        spp=args.spp, seeds=args.seeds, first_seed=args.first_seed, frames=frames,
        resolution=args.res,
        env_res=args.env_res, time_budget_ms=args.time_budget_ms,
        sanitize=True if args.sanitize else None, repeats=args.repeats and args.repeats[0],
        repeats_for=args.repeats and args.repeats[1], metrics=metrics, device=args.device,
        save_inputs=args.save_inputs, force=args.force, workers=args.workers,
        scheduler=args.scheduler, progress=False if args.no_progress else None,
        control=args.control and [label for labels in args.control for label in labels],
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
    for flag in flatter_than_tags(rows):   # issue 11: convergence flatter than the tags allow
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
                    int(cells.loc[key, f"{column}_n"])) for key in summary.index]
            summary["seeds"] = cells.seeds
            summary["nonfinite"] = rows.groupby(keys).nonfinite.sum()
            summaries.append((title, summary))
    return summaries
