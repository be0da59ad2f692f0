"""The ``iblbench`` command line.

Building the parser imports nothing heavy (no colour-science, scipy, OpenCL or the stress
battery), so ``iblbench --help`` and ``iblbench list ...`` answer at once; each command imports
what it needs when it runs.
"""
from __future__ import annotations

import argparse
import errno
import os
import pathlib
import re
import sys

from iblbench.scenes.errors import InputError

DESCRIPTION = """\
iblbench: comparative benchmarks of Monte Carlo estimators for image-based lighting.
Meshes lit by HDR cube maps are shaded by pluggable OpenCL estimators and scored against an
exact reference on Lab error (protocol lab-reinhard-v1), effective samples and device time."""

EPILOG = """\
examples:
  iblbench run                                   small default suite on built-in scenes
  iblbench run --scene sphere-sun --estimator uniform --spp 16,256 --seeds 2 --out runs/a
  iblbench run --scene my/scene.toml --sanitize  a user scene (see README for the TOML format)
  iblbench reproduce lu2013 --out runs/lu2013    Lu 2013's figures and claims, with verdicts
  iblbench reproduce mis-compensation            Karlík et al. 2019's equal-time claim
  iblbench report runs/a                         runs/a/report/index.html (open it from disk)
  iblbench list devices                          OpenCL platforms/devices and which is chosen
  iblbench doctor                                is every OpenCL device here right? (run it first)
  iblbench check runs/a --budgets budgets.toml   CI gate: exit 1 if any error budget fails
  iblbench budgets runs/q8 --margin 0.1          budgets.toml from a run of >= 8 seeds
  iblbench stress --out runs/stress              adversarial inputs; exit 1 if an estimator fails
  iblbench perf --out runs/perf                  throughput against the roofline and a NumPy floor
  iblbench compare runs/a runs/b --fail-if 'mean_delta_e76>5%'   B against A, intervals over seeds
  iblbench selftest                              which checks catch the catalogue of known bugs
  iblbench check runs/a --json --junit check.xml JSON summary on stdout, JUnit XML for CI

machine-readable output: --json on run, check, compare and stress prints one JSON document on
  stdout (the tables then go to stderr); the schemas are in the README and in
  iblbench.harness.machine_readable

Python API (a notebook; returns the results table as a pandas DataFrame):
  import iblbench
  table = iblbench.run(scenes=["sphere-sun", {"name": "ball", "mesh": {"path": "ball.obj"},
                               "environment": {"path": "sky.exr"},
                               "camera": {"eye": [0, 0, 3], "target": [0, 0, 0]}}],
                       estimators=["uniform", "balanced"], spp=[16, 64], seeds=2, out="runs/nb")
  help(iblbench) for the arguments; iblbench.check and iblbench.report as the commands

exit codes: 0 done; 1 a check or stress gate failed; 2 bad input (one line naming it);
  3 the disk is full (free space and rerun: a run resumes); 130 interrupted (Ctrl-C; a run saves
  its finished cells first)
"""


EXIT_DISK_FULL = 3


def _spp_list(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got '{text}'")
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"spp values must be positive integers, got '{text}'")
    return values


def _resolution(text: str) -> tuple[int, int]:
    from iblbench.harness.protocol.sweep import parse_resolution

    try:
        return parse_resolution(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error))


def _env_res(text: str) -> int:
    from iblbench.harness.protocol.sweep import check_env_res

    try:
        return check_env_res(_positive_int(text))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error))


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got '{text}'")
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got '{text}'")
    return value


def _non_negative_int(text: str) -> int:
    return 0 if text.strip() == "0" else _positive_int(text)


def _pixel(text: str) -> tuple[int, int]:
    try:
        x, y = (int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y such as 64,40, got '{text}'")
    return x, y


def _add_json(parser) -> None:
    parser.add_argument("--json", action="store_true",
                        help="print a machine-readable summary (one JSON document) on stdout; "
                             "the human-readable output goes to stderr (schema: README, "
                             "'Machine-readable output')")


def _human_output(args):
    """Where a command's tables go: stderr when stdout carries its --json document."""
    return sys.stderr if getattr(args, "json", False) else sys.stdout


def _print_json(document: dict) -> None:
    from iblbench.harness.protocol.results import json_text

    print(json_text(document))


class _Parser(argparse.ArgumentParser):
    """Reports a bad argument in one line, as every other input error is, not under the usage."""

    def error(self, message):
        self.exit(2, f"iblbench: error: {message} (see '{self.prog} --help')\n")


class _Version(argparse.Action):
    """``--version``: the package version, and the source checkout's git revision where there is one
    (imported only when asked: the runner that records it in every manifest is heavy)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from importlib.metadata import version

        from iblbench.harness.protocol.runner import _git_revision

        print(f"iblbench {version('iblbench')} (git {_git_revision()})")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    from iblbench.harness.protocol import sweep

    parser = _Parser(prog="iblbench", description=DESCRIPTION, epilog=EPILOG,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_Version,
                        help="print the version and the git revision of the source, and exit")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    # Flags every rendering command shares.
    device = argparse.ArgumentParser(add_help=False)
    device.add_argument("--device", metavar="SUBSTRING",
                        help="OpenCL platform/device substring (overrides IBLBENCH_DEVICE; default: "
                             "a GPU, else the fastest CPU platform)")
    rendering = argparse.ArgumentParser(add_help=False, parents=[device])
    rendering.add_argument("--no-progress", action="store_true", help="no progress bar")

    run = commands.add_parser(
        "run", help="benchmark estimators on scenes and write results, manifest and images",
        description="Render every (scene, estimator, spp, frame, seed) cell of a sweep, score it "
                    "against the exact reference and write results.parquet/.csv, manifest.json "
                    "and images/<scene>/f<frame>/ (EXR + PNG previews + ΔE heat maps) into --out. "
                    "The sweep comes from --config (default: the shipped 'default'); each flag "
                    "given replaces that field of the config. Re-running resumes: cells already "
                    "in --out with the same configuration, code version and device are skipped.",
        parents=[rendering])
    run.add_argument("--config", metavar="NAME|FILE",
                     help="sweep config: a shipped one (quick, default, full, temporal) or a .toml file "
                          "(default: default; format: the docstring of iblbench.harness.sweep)")
    run.add_argument("--scene", action="append", metavar="NAME|FILE",
                     help="built-in scene name or a scene .toml file; repeatable")
    run.add_argument("--estimator", action="append", metavar="NAME",
                     help="estimator name, optionally with parameters as NAME{param=value,...}; "
                          "repeatable (see 'iblbench list estimators')")
    run.add_argument("--spp", type=_spp_list, metavar="N,N,...",
                     help="samples per pixel, comma-separated")
    run.add_argument("--seeds", type=_positive_int, help="seeds per cell, 0..N-1")
    run.add_argument("--first-seed", type=_non_negative_int, metavar="S",
                     help="the first seed instead of 0: seeds S..S+N-1 (a seeds-only rerun)")
    run.add_argument("--frames", metavar="START:STOP[:STEP]",
                     help="frames of environment sequences, a Python slice of each sequence's "
                          "frames such as 0:67:6 or ::4 (default: all; also all, A..B inclusive "
                          "or N,N,...; write --frames=-5: for a negative start); static scenes "
                          "run frame 0")
    run.add_argument("--res", type=_resolution, metavar="WxH",
                     help="image resolution (default: the scene's own)")
    run.add_argument("--env-res", type=_env_res, metavar="R",
                     help="cube face resolution for built-in skies and resampled maps")
    run.add_argument("--time-budget-ms", type=sweep.budgets_arg, metavar="T[,T...]",
                     help="equal-time cells besides the spp list: per (scene, estimator), the spp "
                          "whose calibrated device time per frame (build+sample+shade) lands "
                          "within 10%% of T ms; the run says where it cannot")
    run.add_argument("--repeats", type=sweep.repeats_arg, metavar="N[,NAME=M...]",
                     help=f"timed renders per cell after warm-up (default "
                          f"{sweep.DEFAULT_REPEATS}); a cell's time is the median of their "
                          "device times (build+sample+shade), with min and IQR beside it; "
                          "NAME=M gives estimator NAME M of its own (e.g. 5,smc=3)")
    metrics = run.add_mutually_exclusive_group()
    metrics.add_argument("--metrics", type=sweep.metrics_arg, metavar="M[,M...]",
                         help=f"metrics to compute, of {','.join(sweep.METRICS)} (default: all; "
                              "de76 always: heat maps and flicker use it); one left out is NaN")
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
    _add_json(run)

    repro = commands.add_parser(
        "reproduce", help="re-run a paper's experiments and judge its claims (lu2013, "
                          "mis-compensation)",
        description="Run a paper's experiments on built-in scenes through the ordinary runner, "
                    "then write summary.md and summary.html (tables, plots, and one verdict per "
                    "claim: holds / partly holds / does not hold / not resolved, with 95% "
                    "intervals) beside results.parquet. lu2013: Lu, Pacanowski & Granier 2013's "
                    "Fig. 2 and 3 and claims, with the production baselines (brdf, envmap) and "
                    "an equal-time comparison beside them. mis-compensation: Karlík et al. "
                    "2019's MIS compensation against plain MIS at equal time (envmap and "
                    "balanced_mis). Equal-time cells run at one budget taken from the "
                    "reproduction's own spp cells (see the summary).",
        parents=[rendering])
    repro.add_argument("paper", metavar="PAPER",
                       help="which reproduction: lu2013 or mis-compensation")
    repro.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/reproduce"),
                       help="output directory (default: results/reproduce)")
    repro.add_argument("--seeds", type=_positive_int, default=3,
                       help="seeds per cell (default: 3)")

    report = commands.add_parser(
        "report", help="write a self-contained HTML report of a run (DIR/report/index.html)",
        description="Summarise a run directory in DIR/report/index.html: tables per scene, error "
                    "against time with the Pareto front, convergence, effective samples, image "
                    "grids with ΔE heat maps, Lu 2013's sample picture, and the manifest. The "
                    "page opens from disk (no server, no external files).",
        parents=[device])
    report.add_argument("dir", type=pathlib.Path, metavar="DIR", help="an 'iblbench run' --out")
    report.add_argument("--spp", type=_positive_int, metavar="N",
                        help="spp of the image grid and sample picture (default: the largest "
                             "spp every estimator of the scene ran)")
    report.add_argument("--seed", type=int, help="seed of the images shown (default: the run's "
                                                 "first; one the run lacks is an error)")
    report.add_argument("--frame", type=int, help="frame of the images shown (default: each "
                                                  "scene's first; one the run lacks is an error)")
    report.add_argument("--pixel", type=_pixel, metavar="X,Y",
                        help="pixel of the sample picture (default: the covered pixel nearest "
                             "the image centre)")

    listing = commands.add_parser("list", help="list devices, estimators or scenes",
                                  description="List OpenCL devices (and the one chosen), "
                                              "registered estimators, or built-in scenes.",
                                  parents=[device])
    listing.add_argument("what", choices=("devices", "estimators", "scenes"))

    check = commands.add_parser(
        "check", help="gate on error budgets: exit 0 when every budget holds, 1 when any fails",
        description="Check DIR/results.parquet against the rules of a budgets file (per scene glob, "
                    "estimator glob and spp: max mean ΔE76, max relMSE, min effective ratio, "
                    "nonfinite == 0, max time ratio to a baseline estimator of the same run; "
                    "format in harness/budgets.py). Prints every rule x cell with value, budget "
                    "and PASS/FAIL, then a verdict. A missing cell fails. Exit 0 all pass, 1 any "
                    "fails, 2 bad input.")
    check.add_argument("dir", type=pathlib.Path, metavar="DIR",
                       help="a run's output directory (holds results.parquet)")
    check.add_argument("--budgets", type=pathlib.Path, default=pathlib.Path("budgets.toml"),
                       metavar="FILE", help="budgets TOML file (default: budgets.toml)")
    _add_json(check)
    check.add_argument("--junit", type=pathlib.Path, metavar="FILE",
                       help="also write JUnit XML to FILE for CI systems: one testcase per rule, "
                            "a failure (with the failed checks) where any of its checks fails")

    make_budgets = commands.add_parser(
        "budgets", help="write a budgets file from a multi-seed run (>= 8 seeds)",
        description="Write a fresh budgets file for `check` from DIR's equal-spp cells: each "
                    "bound is the measured mean over seeds ± K standard errors ± MARGIN × the "
                    "mean, on both sides, with the run's configuration and the measured values "
                    "in it (format and bound shapes in harness/budgets.py). Exit 2 on fewer than "
                    "8 seeds per cell.")
    make_budgets.add_argument("dir", type=pathlib.Path, metavar="DIR",
                              help="a run's output directory (holds results.parquet)")
    make_budgets.add_argument("--margin", type=float, required=True, metavar="M",
                              help="relative margin beyond the standard errors, e.g. 0.1 for 10%%")
    make_budgets.add_argument("--se-multiple", type=float, metavar="K",
                              help="standard errors of the mean on each side (default: 3)")
    make_budgets.add_argument("--output", type=pathlib.Path, default=pathlib.Path("budgets.toml"),
                              metavar="FILE", help="file to write (default: budgets.toml)")
    make_budgets.add_argument("--why", default="", metavar="TEXT",
                              help="why the budgets are made anew, written into the file")

    stress = commands.add_parser(
        "stress", help="run the adversarial input battery: exit 0 when every estimator passes it, "
                       "1 when any fails", description=_stress_description,
        formatter_class=_LazyDescriptionFormatter, parents=[rendering])
    stress.add_argument("--estimator", action="append", metavar="NAME",
                        help="estimator name, optionally NAME{param=value,...}; repeatable "
                             "(default: every registered estimator)")
    stress.add_argument("--case", action="append", metavar="CASE", type=_stress_case,
                        help="run only this case; repeatable (default: all)")
    stress.add_argument("--quick", action="store_true",
                        help="the small size the tests use (fewer normals and seeds, R = 8)")
    stress.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/stress"),
                        help="output directory for stress.csv/.parquet/.html "
                             "(default: results/stress)")
    _add_json(stress)
    _add_perf(commands, device)
    doctor = commands.add_parser(
        "doctor", help="check every OpenCL device: build and run each kernel, compare results",
        description=DOCTOR_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    doctor.add_argument("--device", metavar="SUBSTRING",
                        help="only the devices whose 'platform / version / device' contains this "
                             "(the default device still runs: it is the baseline)")
    doctor.add_argument("--verbose", action="store_true",
                        help="also print the compilers' output (warnings), which is silent otherwise")
    _add_compare(commands)
    _add_selftest(commands)
    return parser


# ---- iblbench compare (harness/compare.py) ------------------------------------------------------

def _add_compare(commands) -> None:
    compare = commands.add_parser(
        "compare", help="compare two run folders cell by cell: ratios B/A with 95%% intervals "
                        "over seeds; exit 1 on a significant change beyond a --fail-if",
        description="Compare run folders A and B per cell (scene, estimator, spp or time "
                    "budget, frame): for mean_delta_e76, mean_delta_e2000, rel_mse, flip, "
                    "effective_ratio and time_ms, the mean over seeds on each side and the "
                    "ratio B/A with its 95%% interval (delta method on log, Welch df); a change "
                    "is significant when the interval excludes 1. Says when A and B differ in "
                    "code, device, protocol or configuration. An estimator label with "
                    "parameters (balanced{uniform_faces=true}) is paired with the other side's "
                    "label of the same base name when no equal label exists. Exit 0, 1 when a "
                    "cell has a significant change beyond a --fail-if threshold, 2 on bad input.")
    compare.add_argument("a", type=pathlib.Path, metavar="A", help="the baseline run folder")
    compare.add_argument("b", type=pathlib.Path, metavar="B", help="the run folder compared with A")
    compare.add_argument("--fail-if", action="append", default=[], metavar="METRIC>P%%",
                         help="fail (exit 1) when a cell's METRIC changes significantly by "
                              "more than P%%: 'mean_delta_e76>5%%' (an increase), "
                              "'effective_ratio<-5%%' (a decrease); repeatable")
    _add_json(compare)


def _compare(args) -> int:
    from iblbench.harness.verify.compare import run_command

    return run_command(args.a, args.b, args.fail_if, as_json=args.json)


# ---- iblbench perf (harness/perf.py, imported only when the command runs or prints its help) --

PERF_DESCRIPTION = """\
Measure the throughput of every estimator (or the chosen ones) on this device, side by side in
one run: per (scene, estimator), Msamples/s and M evaluations/s, the device ms of the build,
sample and shade stages (median, min and IQR of --repeats renders after one warm-up), the
device's measured FMA and copy roofline and the fraction of it each shading kernel reaches
(from analytic FLOP and byte counts per sample, estimates), and the speed-up over a
single-threaded NumPy implementation of Lu 2013's shared-pool shading on the same inputs (the
floor every kernel must beat; it must also agree with the uniform kernel on the same pool).
Prints a table and writes perf.csv and perf.html into --out. The method and the counts are in
harness/perf.py. Exit 0, or 2 on bad input."""


DOCTOR_DESCRIPTION = """\
For each OpenCL device found, build every kernel and run the portability set (the exact reference,
the frame cache's CDFs, pool and mip pyramids, and every estimator, on 16 pixels and a 4x4 map with
a sun; a temporal estimator on two frames), each part in its own process, and compare: the
reference with its independent NumPy twin (within 1e-4), and every result with the default
device's (integers bit for bit, floats within 1e-4 relative). On Oclgrind, the OpenCL
specification's simulator, its memory, data-race and API checks are on and any report fails the
device. Prints one line per device: OK, or which part is wrong and by how much. Exit 0 when every
device is OK, 1 otherwise. A few seconds per device; about a minute on Oclgrind.

A new GPU: run this first; then choose a device with --device or IBLBENCH_DEVICE."""


def _doctor(args) -> int:
    from iblbench.harness.verify.doctor import diagnose

    def progress(text: str) -> None:   # one status line on a terminal, nothing in a log
        if sys.stderr.isatty():
            print(f"\r\033[K{text}", end="", file=sys.stderr, flush=True)

    reports = diagnose(args.device, args.verbose, progress)
    progress("")
    for report in reports:
        if args.verbose and report.build_logs:
            print(report.build_logs)
        print(report.line())
    return 0 if all(report.ok for report in reports) else 1


def _add_perf(commands, device) -> None:
    perf = commands.add_parser("perf", help="throughput per estimator against the device's "
                                            "roofline and a NumPy floor (perf.csv, perf.html)",
                               description=PERF_DESCRIPTION, parents=[device],
                               formatter_class=argparse.RawDescriptionHelpFormatter)
    perf.add_argument("--scene", action="append", metavar="NAME|FILE",
                      help="built-in scene name or scene .toml; repeatable "
                           "(default: sphere-sun and blob-sun)")
    perf.add_argument("--estimator", action="append", metavar="NAME",
                      help="estimator name, optionally NAME{param=value,...}; repeatable "
                           "(default: every registered estimator)")
    perf.add_argument("--spp", type=_positive_int, metavar="N",
                      help="samples per pixel of every estimator and the floor (default: 64; "
                           "bis and smc 20, Kronander's N, with M = 400 candidates)")
    perf.add_argument("--res", type=_resolution, metavar="WxH",
                      help="image resolution (default: 256x256)")
    perf.add_argument("--env-res", type=_env_res, metavar="R",
                      help="cube face resolution (default: 64)")
    perf.add_argument("--repeats", type=_positive_int, metavar="N",
                      help="timed renders per estimator after one warm-up (default: 5; bis "
                           "and smc 3)")
    perf.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/perf"),
                      help="output directory for perf.csv and perf.html (default: results/perf)")

    def format_help() -> str:
        from iblbench.harness.studies.perf import columns_help

        perf.epilog = columns_help()
        return argparse.ArgumentParser.format_help(perf)

    perf.format_help = format_help


def _perf(args) -> None:
    from iblbench.harness.studies import perf

    perf.run_command(perf.PerfConfig(
        out=args.out, scenes=tuple(args.scene or perf.DEFAULT_SCENES),
        estimators=tuple(args.estimator or ()), spp=args.spp,
        resolution=args.res or perf.DEFAULT_RESOLUTION, env_res=args.env_res or perf.DEFAULT_ENV_RES,
        repeats=args.repeats, device=args.device))


# ---- iblbench selftest (harness/mutants.py) ------------------------------------------------------

SELFTEST_DESCRIPTION = """\
Apply each mutant of the project's catalogue of realistic bugs (harness/mutants.py) to a
temporary copy of the sources and run the check layers on it: the conformance suite
(check_estimator), the stress battery at its quick size (the cases that guard the broken
code) and the error budgets of the quick sweep (budgets.toml, in a source checkout). By
default each mutant stops at the first layer that rejects it; --all-layers runs every layer,
to show which layers catch what. Prints one row per mutant and, per layer, the mutants it
caught. Exit 0 when every mutant is rejected (or survives as its catalogue entry expects, until
the check it waits for lands), 1 otherwise."""


def _add_selftest(commands) -> None:
    selftest = commands.add_parser("selftest", help="run the catalogue of known bugs through the "
                                                    "checks and show which layers catch each",
                                   description=SELFTEST_DESCRIPTION,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    selftest.add_argument("--mutant", action="append", metavar="NAME",
                          help="run only this mutant; repeatable (default: the whole catalogue)")
    selftest.add_argument("--all-layers", action="store_true",
                          help="run every layer on every mutant, not only up to the first that rejects it")
    selftest.add_argument("--jobs", type=_positive_int, default=2, metavar="N",
                          help="mutants run at a time (default: 2)")
    selftest.add_argument("--list", action="store_true", help="list the catalogue and exit")


def _selftest(args) -> int:
    from iblbench.harness.verify import mutants

    try:
        chosen = mutants.catalogue(args.mutant)
    except ValueError as error:
        raise InputError(None, str(error)) from None
    if args.list:
        for m in chosen:
            waits = f"  (expected to survive until: {m.expect_killed_after})" if m.expect_killed_after else ""
            print(f"{m.name:48s} {m.path}{waits}")
        return 0
    width = max(len(m.name) for m in chosen)

    def show(outcome):
        why = outcome.error or next((w for w in outcome.rejected_by.values() if w), "")
        verdict = outcome.killed_by or ("expected survivor" if outcome.mutant.expect_killed_after
                                        else "SURVIVED")
        print(f"{outcome.mutant.name:{width}s}  {verdict:17s} {outcome.seconds:5.1f} s  {why[:100]}",
              flush=True)

    outcomes = mutants.run_catalogue(chosen, all_layers=args.all_layers, jobs=args.jobs, progress=show)
    print()
    for layer in mutants.LAYERS:
        caught = [o.mutant.name for o in outcomes if o.rejected_by.get(layer)]
        print(f"{layer} caught {len(caught)}: {', '.join(caught) or '-'}")
    bad = [o.mutant.name for o in outcomes if not o.killed and not o.mutant.expect_killed_after]
    print(f"selftest: {len(outcomes) - len(bad)} of {len(outcomes)} mutants rejected or expected"
          + (f"; SURVIVED: {', '.join(bad)}" if bad else ""))
    return 1 if bad else 0


class _LazyDescriptionFormatter(argparse.RawDescriptionHelpFormatter):
    """Formats a description given as a function, called only when the help is shown (the
    stress battery's case list imports the battery)."""

    def add_text(self, text):
        super().add_text(text() if callable(text) else text)


def _stress_case(text: str) -> str:
    cases = stress_cases()
    if text not in cases:
        raise argparse.ArgumentTypeError(f"invalid choice: '{text}' (choose from "
                                         f"{', '.join(cases)})")
    return text


def stress_cases() -> dict[str, str]:
    """Case name → the failure it guards against."""
    from iblbench.harness.verify.stress import CASES

    return {name: case.guards for name, case in CASES.items()}


def _stress_description() -> str:
    import textwrap

    column = max(18, 1 + max(map(len, stress_cases())))   # the longest name, then a space
    cases = "\n".join(textwrap.fill(guards, 88, initial_indent=f"  {name:{column}s}",
                                     subsequent_indent=" " * (column + 2))
                      for name, guards in stress_cases().items())
    return textwrap.fill("Run every estimator (or the chosen ones) over a battery of adversarial inputs, one "
            "row per (case, estimator): non-finite and negative values, range, error against "
            "the exact reference, exactness where the reference is 0, a bias z-test over seeds "
            "(unbiased estimators), a χ² test of the sampler (estimators with a pdf) and "
            "recovery after a drop-out (temporal estimators). Prints the table and writes "
            "stress.csv, stress.parquet and stress.html into --out. Exit 0 when no cell "
            "fails, 1 when any does (non-finite or negative values, a non-zero value where "
            "the reference is 0, a failed bias or χ² test; known failures are reported as "
            "xfail), 2 on bad arguments. The full battery takes a few minutes on a 2-core "
            "CPU; --quick about one.", 88) + "\n\ncases:\n" + cases


def _list(args) -> None:
    if args.what == "devices":
        from iblbench.estimators.runtime.device import (all_devices, build_failure, choose_device,
                                             measured_gflops)

        chosen = choose_device(args.device)
        for info in all_devices():
            mark = "*" if info.key == chosen.key else " "
            failure = build_failure(info)
            note = (f"  cannot build a kernel: {failure}" if failure
                    else "" if info.is_gpu else f"  {measured_gflops(info):.1f} GFLOP/s")
            print(f"{mark} [{info.kind}] {info.label}{note}")
        print("(* = chosen; override with --device or IBLBENCH_DEVICE; a simulator only by name)")
    elif args.what == "estimators":
        from iblbench.estimators.registry import estimator_docstrings

        for name, docstring in estimator_docstrings().items():
            print(_listing_line(name, summary(docstring, name)))
    else:
        from iblbench.scenes.registry import BUILTIN_SCENES, builtin_frames, scene_names

        for name in scene_names():
            frames = builtin_frames(name)
            print(_listing_line(name, f"{frames} frame{'s' * (frames > 1)}. "
                                      f"{summary(BUILTIN_SCENES[name].__doc__, name)}"))


_NAME_WIDTH = 15
# Roles (:class:`~a.b.C` -> C), literals and emphasis (``x``, *x* -> x).
_REST_ROLE = re.compile(r":[a-z]+:`~?(?:[\w.]*\.)?([^`]+)`")
_REST_MARKUP = re.compile(r"``([^`]+)``|\*\*([^*]+)\*\*|\*([^*\s][^*]*)\*")
# A full stop ends a sentence before a capital, or at the end, but not after an abbreviation.
_SENTENCE_END = re.compile(r"(?<!\bal)(?<!\bEq)(?<!\bSec)(?<!\bFig)(?<!\bet)(?<!e\.g)(?<!i\.e)"
                           r"\.(?=\s+[A-Z]|\s*$)")


def summary(docstring: str | None, name: str) -> str:
    """The first sentence of a docstring as plain text: reST markup stripped, the lines of its
    first paragraph joined, and a leading "name:" dropped (the listing shows the name)."""
    paragraph = " ".join((docstring or "").strip().split("\n\n")[0].split())
    text = _REST_MARKUP.sub(lambda m: next(g for g in m.groups() if g), _REST_ROLE.sub(r"\1", paragraph))
    end = _SENTENCE_END.search(text)
    text = text[:end.end()] if end else text
    return text.removeprefix(f"{name}: ")


def _listing_line(name: str, text: str) -> str:
    """``name`` then ``text`` wrapped to the terminal, continuation lines under the text."""
    import shutil
    import textwrap

    width = max(shutil.get_terminal_size().columns, _NAME_WIDTH + 30)
    return textwrap.fill(text, width, initial_indent=f"{name:{_NAME_WIDTH - 1}s} ", break_on_hyphens=False,
                         subsequent_indent=" " * _NAME_WIDTH)


def _run(args) -> None:
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
        ("--no-flip", args.no_flip)) if value]
    runner = Runner(run_config(
        args.out, config=args.config, scenes=args.scene, estimators=args.estimator,
        spp=args.spp, seeds=args.seeds, first_seed=args.first_seed, frames=frames,
        resolution=args.res,
        env_res=args.env_res, time_budget_ms=args.time_budget_ms,
        sanitize=True if args.sanitize else None, repeats=args.repeats and args.repeats[0],
        repeats_for=args.repeats and args.repeats[1], metrics=metrics, device=args.device,
        save_inputs=args.save_inputs, force=args.force,
        progress=False if args.no_progress else None, note={"overridden_by_flags": flags}))
    table = runner.run()
    human = _human_output(args)
    rows = runner.sweep_rows(table)   # --out may also hold other sweeps' cells
    for title, summary in terminal_summaries(rows):
        if title:
            print(title, file=human)
        print(summary.to_string(float_format=lambda v: f"{v:.4g}"), file=human)
    print(f"wrote {len(rows)} rows to {args.out}/results.parquet"
          + (f" ({len(table)} in all)" if len(table) != len(rows) else ""), file=human)
    from iblbench.harness.verify.convergence import flatter_than_tags
    for flag in flatter_than_tags(rows):   # issue 11: convergence flatter than the tags allow
        print(f"warning: convergence: {flag.text()}", file=sys.stderr)
    if args.json:
        _print_json(run_summary(rows, args.out, read_manifest(args.out)))


def terminal_summaries(table):
    """The tables ``iblbench run`` prints: per (scene, estimator, spp) cell, then per equal-time
    cell. Beside spp each shows what a sample costs, as the estimators' spp are not comparable
    (one bis or smc sample costs 21 integrand evaluations): ``evaluations`` (integrand evaluations per
    covered pixel) and the cell's time of :mod:`iblbench.harness.timing` (``time_ms``: device ms
    per frame, build + sample + shade) as the report and ``check`` show it.  Time, errors and
    samples are the mean over seeds with its 95% Student-t interval, ``mean ± half-width``
    (:func:`iblbench.harness.stats.cell_intervals`); ``seeds`` says how many."""
    from iblbench.harness.protocol.stats import cell_intervals, interval_text
    from iblbench.harness.protocol.timing import TIME

    shown = {TIME: TIME, "mean_delta_e76": "mean_delta_e76", "rel_mse": "rel_mse", "flip": "flip",
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
            columns = [c for c in shown if c in rows and rows[c].notna().any()]
            cells = cell_intervals(rows, keys, columns)
            spp = {} if "spp" in keys else {"spp": ("spp", "first")}
            summary = rows.groupby(keys).agg(**spp, evaluations=("evaluations", "mean"))
            for column in columns:
                summary[shown[column]] = [interval_text(*cells.loc[key, [column, f"{column}_half"]],
                                                        cells.seeds[key]) for key in summary.index]
            summary["seeds"] = cells.seeds
            summary["nonfinite"] = rows.groupby(keys).nonfinite.sum()
            summaries.append((title, summary))
    return summaries


def _reproduce(args) -> None:
    from iblbench.harness.studies.reproduce import reproduce
    from iblbench.reports.reproduction import summary_head

    summary = reproduce(args.paper, args.out, seeds=args.seeds, device=args.device,
                        progress=False if args.no_progress else None)
    print(summary_head(summary.read_text(encoding="utf-8")))
    print(f"wrote {summary} and {summary.with_suffix('.html')}")


def _check(args) -> int:
    import pandas as pd

    from iblbench.harness.verify.budgets import check
    from iblbench.harness.protocol.machine_readable import check_summary, junit_xml
    from iblbench.scenes.atomic import atomic_path

    checks, verdict, status = check(args.dir, args.budgets)
    human = _human_output(args)
    with pd.option_context("display.width", 250, "display.max_colwidth", 60):
        print(checks.to_string(index=False), file=human)
    print(verdict, file=human)
    if args.junit:
        try:
            with atomic_path(args.junit) as tmp:
                tmp.write_text(junit_xml(checks, args.budgets), encoding="utf-8")
        except OSError as error:   # (a full disk is still told apart by its message)
            raise InputError(args.junit, f"--junit: cannot write it ({error.strerror})") from None
        print(f"wrote {args.junit}", file=human)
    if args.json:
        _print_json(check_summary(checks, verdict, status, args.dir, args.budgets))
    return status


def _budgets(args) -> None:
    from iblbench.harness.verify.budgets import write_budgets

    extra = {} if args.se_multiple is None else {"se_multiple": args.se_multiple}
    rules = write_budgets(args.dir, args.output, args.margin, why=args.why, **extra)
    print(f"wrote {rules} rules to {args.output}")


def _report(args) -> None:
    from iblbench.reports.report import write_report

    context = write_report(args.dir, spp=args.spp, seed=args.seed, frame=args.frame,
                           pixel=args.pixel, device=args.device)
    print(f"wrote {context['path']}")


def _stress(args) -> int:
    import dataclasses
    import time

    import pandas as pd

    from iblbench.estimators.registry import estimator_names
    from iblbench.harness.verify import stress
    from iblbench.estimators.runtime.device import get_compute
    from iblbench.harness.protocol.machine_readable import stress_summary
    from iblbench.harness.protocol.results import prepare_out
    from iblbench.harness.protocol.sweep import parse_estimator

    estimators = {spec.label: spec.make()
                  for spec in map(parse_estimator, args.estimator or estimator_names())}
    cases = tuple(dict.fromkeys(args.case or stress.CASE_NAMES))
    if not any(stress.CASES[case].applies(e) for case in cases for e in estimators.values()):
        raise InputError(None, f"no case of {', '.join(cases)} applies to {', '.join(estimators)} "
                               "(temporal-dropout runs temporal estimators only)")
    prepare_out(args.out)
    compute = get_compute(args.device)
    scale = stress.SMALL if args.quick else stress.LARGE
    start = time.perf_counter()
    table = stress.run_stress(estimators, cases, scale, compute,
                              progress=False if args.no_progress else None)
    seconds = time.perf_counter() - start
    paths = stress.write_outputs(args.out, table, scale, compute.device_name, seconds)
    shown = ["case", "estimator", "status", "nonfinite", "min", "max", "rel_rmse", "bias_pixels",
             "bias_z", "bias_p", "chi2_p", "recovery", "failures"]
    human = _human_output(args)
    with pd.option_context("display.width", 250, "display.max_colwidth", 120):
        print(table[shown].to_string(index=False, float_format=lambda v: f"{v:.3g}"), file=human)
    print(f"{stress.verdict(table)} in {seconds:.0f} s; wrote {', '.join(map(str, paths))}",
          file=human)
    status = 1 if stress.failed(table) else 0
    if args.json:
        _print_json(stress_summary(
            table, cases, estimators, status=status, verdict=stress.verdict(table), out=args.out,
            files=paths, device=compute.device_name, seconds=seconds,
            scale=dataclasses.asdict(scale)))
    return status


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        status = {"run": _run, "reproduce": _reproduce, "list": _list,
                  "check": _check, "budgets": _budgets, "report": _report, "stress": _stress,
                  "perf": _perf, "compare": _compare,
                  "selftest": _selftest, "doctor": _doctor}[args.command](args)
    except (InputError, OSError) as error:
        if _disk_full(error):
            where = (getattr(error, "source", None) or getattr(error, "filename", None)
                     or getattr(args, "out", None) or "the output")
            print(f"iblbench: error: {where}: no space left on device; free some and rerun "
                  "(a run resumes from its saved cells)", file=sys.stderr)
            return EXIT_DISK_FULL
        if not isinstance(error, InputError):
            raise
        print(f"iblbench: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as error:
        print(f"iblbench: interrupted{f': {error}' if str(error) else ''}", file=sys.stderr)
        return 130
    return status or 0


def _disk_full(error: Exception) -> bool:
    """ENOSPC or EDQUOT, also where only the message tells: pyarrow gives no errno, and the EXR
    writer wraps its failure in an InputError."""
    return (getattr(error, "errno", None) in (errno.ENOSPC, errno.EDQUOT)
            or os.strerror(errno.ENOSPC) in str(error) or os.strerror(errno.EDQUOT) in str(error))


if __name__ == "__main__":
    sys.exit(main())
