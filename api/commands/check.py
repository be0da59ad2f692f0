"""``iblbench check``: a run against error budgets, with --json and --junit."""
from __future__ import annotations

import pathlib

from iblbench.commands.common import add_json, add_run_dir, human_output, print_json
from iblbench.foundation.errors import InputError


DESCRIPTION = """\
Check DIR/results.parquet against the rules of a budgets file (per scene glob, estimator glob
and spp: max mean ΔE76, max relMSE, min effective ratio, nonfinite == 0, max time ratio to a
baseline estimator of the same run, on one device: a time ratio over rows of several devices is
refused; format in harness/protocol/budgets.py). Prints every rule x cell with
value, budget and PASS/FAIL, then a verdict. A missing cell fails. Exit 0 all pass, 1 any fails,
2 bad input."""


def add_parser(subparsers) -> None:
    check = subparsers.add_parser(
        "check", help="gate on error budgets: exit 0 when every budget holds, 1 when any fails",
        description=DESCRIPTION)
    add_run_dir(check)
    check.add_argument("--budgets", type=pathlib.Path, default=pathlib.Path("budgets.toml"),
                       metavar="FILE", help="budgets TOML file (default: budgets.toml)")
    add_json(check)
    check.add_argument("--junit", type=pathlib.Path, metavar="FILE",
                       help="also write JUnit XML to FILE for CI systems: one testcase per rule, "
                            "a failure (with the failed checks) where any of its checks fails")


def run(args) -> int:
    import pandas as pd

    from iblbench.harness.protocol.budgets import check, rule_name
    from iblbench.harness.protocol.machine_readable import check_summary, junit_xml
    from iblbench.foundation.atomic import atomic_path

    checks, verdict, status = check(args.dir, args.budgets)
    human = human_output(args)
    # A rule named "scene estimator spp=N" (as `iblbench budgets` names them) already says its
    # cell, which the scene, estimator and spp columns said again: the table was about 220
    # characters wide (issue 23).  They are left out where every rule is so named; --json and
    # --junit keep them.
    derived = [rule_name(*cell) for cell in zip(checks.scene, checks.estimator, checks.spp)]
    shown = checks.drop(columns=["scene", "estimator", "spp"]) if (checks.rule == derived).all() else checks
    with pd.option_context("display.width", 250, "display.max_colwidth", 60):
        print(shown.to_string(index=False), file=human)
    print(verdict, file=human)
    if args.junit:
        try:
            with atomic_path(args.junit) as tmp:
                tmp.write_text(junit_xml(checks, args.budgets), encoding="utf-8")
        except OSError as error:   # (a full disk is still told apart by its message)
            raise InputError(args.junit, f"--junit: cannot write it ({error.strerror})") from None
        print(f"wrote {args.junit}", file=human)
    if args.json:
        print_json(check_summary(checks, verdict, status, args.dir, args.budgets))
    return status
