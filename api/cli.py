"""The ``iblbench`` command line: the parser shell and ``main``; each command is a module of
:mod:`iblbench.commands` with ``add_parser(subparsers)`` and ``run(args)``.

Building the parser imports nothing heavy (no colour-science, scipy, OpenCL or the stress
battery), so ``iblbench --help`` and ``iblbench list ...`` answer at once; each command imports
what it needs when it runs.
"""
from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys

from iblbench.foundation.errors import InputError

DESCRIPTION = """\
iblbench: comparative benchmarks of Monte Carlo estimators for image-based lighting.
Meshes lit by HDR cube maps are shaded by pluggable OpenCL estimators and scored against an
exact reference on Lab error (protocol lab-reinhard-v1), effective samples and device time."""

EPILOG = """\
examples:
  iblbench run                                   the default sweep: every declared estimator, 6 scenes, 1,188 cells (a cell: one image, of a scene, estimator, spp, frame and seed; minutes)
  iblbench run --scene sphere-sun --estimator uniform --spp 16,256 --seeds 2 --out runs/a
  iblbench run --scene my/scene.toml --sanitize  a user scene (the TOML format: docs/scenes.md)
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
  stdout (the tables then go to stderr); the schemas are in docs/results.md and in
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
  its finished cells first); 141 the reader of the output left (`| head`)
"""


EXIT_DISK_FULL = 3
EXIT_CLOSED_PIPE = 141   # 128 + SIGPIPE: the reader of the output left

# In the order `iblbench --help` lists them.
COMMANDS = ("run", "reproduce", "report", "list", "check", "budgets", "stress", "perf", "doctor",
            "compare", "selftest")


def command(name: str):
    """The module of command ``name``."""
    return importlib.import_module(f"iblbench.commands.{name}")


class _Parser(argparse.ArgumentParser):
    """Reports a bad argument in one line, as every other input error is, not under the usage."""

    def error(self, message):
        self.exit(2, f"iblbench: error: {message} (see '{self.prog} --help')\n")


class _Version(argparse.Action):
    """``--version``: the package version, and the source checkout's git revision where there is one
    (from the light ``provenance`` module: no OpenCL, NumPy or pandas is imported)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        from iblbench.harness.protocol.provenance import git_revision, package_version

        print(f"iblbench {package_version('iblbench')} (git {git_revision()})")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="iblbench", description=DESCRIPTION, epilog=EPILOG,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_Version,
                        help="print the version and the git revision of the source, and exit")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        command(name).add_parser(commands)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        status = command(args.command).run(args)
    except BrokenPipeError:
        return _closed_pipe()
    except (InputError, OSError) as error:
        if _disk_full(error):
            where = (getattr(error, "source", None) or getattr(error, "filename", None)
                     or getattr(args, "out", None) or getattr(args, "dir", None) or "the output")
            resumes = " (a run resumes from its saved cells)" if args.command == "run" else ""
            print(f"iblbench: error: {where}: no space left on device; free some and rerun{resumes}",
                  file=sys.stderr)
            return EXIT_DISK_FULL
        if not isinstance(error, InputError):
            raise
        print(f"iblbench: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as error:
        try:
            print(f"iblbench: interrupted{f': {error}' if str(error) else ''}", file=sys.stderr)
        except OSError:   # the Ctrl-C also ended the reader of stderr (`2>&1 | tee log`)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stderr.fileno())
        return 130
    try:
        sys.stdout.flush()   # what is still buffered meets a reader that left (`| head`) here
    except BrokenPipeError:
        return _closed_pipe()
    return status or 0


def _closed_pipe() -> int:
    """The reader of our output left (`iblbench list scenes | head`): end quietly, as a shell
    tool killed by SIGPIPE does (status 128 + 13), with stdout pointed at /dev/null so that
    Python's own flush at exit does not fail again."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return EXIT_CLOSED_PIPE


def _disk_full(error: Exception) -> bool:
    """ENOSPC or EDQUOT, also where only the message tells: pyarrow gives no errno, and the EXR
    writer wraps its failure in an InputError."""
    return (getattr(error, "errno", None) in (errno.ENOSPC, errno.EDQUOT)
            or os.strerror(errno.ENOSPC) in str(error) or os.strerror(errno.EDQUOT) in str(error))


if __name__ == "__main__":
    sys.exit(main())
