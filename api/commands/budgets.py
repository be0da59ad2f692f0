"""``iblbench budgets``: a budgets file from a multi-seed run."""
from __future__ import annotations

import pathlib

from iblbench.commands.common import add_run_dir


DESCRIPTION = """\
Write a fresh budgets file for `check` from DIR's equal-spp cells: each bound is the measured
mean over seeds ± K standard errors ± MARGIN × the mean, on both sides, with the run's
configuration and the measured values in it (format and bound shapes in harness/protocol/budgets.py).
Exit 2 on fewer than 8 seeds per cell."""


def add_parser(subparsers) -> None:
    make_budgets = subparsers.add_parser(
        "budgets", help="write a budgets file from a multi-seed run (>= 8 seeds)",
        description=DESCRIPTION)
    add_run_dir(make_budgets)
    make_budgets.add_argument("--margin", type=float, required=True, metavar="M",
                              help="relative margin beyond the standard errors, e.g. 0.1 for 10%%")
    make_budgets.add_argument("--se-multiple", type=float, metavar="K",
                              help="standard errors of the mean on each side (default: 3)")
    make_budgets.add_argument("--output", type=pathlib.Path, metavar="FILE",
                              help="file to write (default: budgets.toml, only where none exists: "
                                   "an existing file is replaced only when named here)")
    make_budgets.add_argument("--why", default="", metavar="TEXT",
                              help="why the budgets are made anew, written into the file")


DEFAULT_OUTPUT = pathlib.Path("budgets.toml")


def run(args) -> None:
    from iblbench.harness.protocol.budgets import write_budgets
    from iblbench.foundation.errors import InputError

    output = args.output or DEFAULT_OUTPUT
    if args.output is None and output.exists():   # from the repository root: the committed file
        raise InputError(output, "exists and --output was not given; name the file to write "
                                 "(--output budgets.toml replaces this one)")
    extra = {} if args.se_multiple is None else {"se_multiple": args.se_multiple}
    rules = write_budgets(args.dir, output, args.margin, why=args.why, **extra)
    print(f"wrote {rules} rules to {output}")
