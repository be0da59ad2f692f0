"""``iblbench stress``: the adversarial input battery (:mod:`iblbench.harness.verify.stress`);
its page comes from :func:`iblbench.reports.report.stress_html`."""
from __future__ import annotations

import argparse
import pathlib

from iblbench.commands.common import (LazyDescriptionFormatter, add_json, human_output, print_json,
                                      rendering_flags)
from iblbench.foundation.errors import InputError


def add_parser(subparsers) -> None:
    stress = subparsers.add_parser(
        "stress", help="run the adversarial input battery: exit 0 when every estimator passes it, "
                       "1 when any fails", description=_stress_description,
        formatter_class=LazyDescriptionFormatter, parents=[rendering_flags()])
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
    add_json(stress)


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


def run(args) -> int:
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
    paths = _write_outputs(args.out, table, scale, compute.device_name, seconds)
    shown = ["case", "estimator", "status", "nonfinite", "min", "max", "rel_rmse", "bias_pixels",
             "bias_z", "bias_p", "chi2_p", "recovery", "failures"]
    human = human_output(args)
    with pd.option_context("display.width", 250, "display.max_colwidth", 120):
        print(table[shown].to_string(index=False, float_format=lambda v: f"{v:.3g}"), file=human)
    print(f"{stress.verdict(table)} in {seconds:.0f} s; wrote {', '.join(map(str, paths))}",
          file=human)
    status = 1 if stress.failed(table) else 0
    if args.json:
        print_json(stress_summary(
            table, cases, estimators, status=status, verdict=stress.verdict(table), out=args.out,
            files=paths, device=compute.device_name, seconds=seconds,
            scale=dataclasses.asdict(scale)))
    return status


def _write_outputs(out: pathlib.Path, table, scale, device: str, seconds: float) -> list[pathlib.Path]:
    """``stress.parquet`` and ``stress.csv`` (:func:`stress.write_tables`) and ``stress.html``
    (:func:`iblbench.reports.report.stress_html`) in ``out``, each written atomically."""
    from iblbench.harness.verify import stress
    from iblbench.reports.report import stress_html
    from iblbench.foundation.atomic import atomic_path

    paths = stress.write_tables(out, table) + [out / "stress.html"]
    cases, context = stress.html_context(table, scale, device, seconds)
    with atomic_path(paths[2]) as tmp:
        tmp.write_text(stress_html(table, cases, context), encoding="utf-8")
    return paths
