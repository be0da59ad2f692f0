"""``iblbench reproduce``: a paper's experiments (:mod:`iblbench.harness.studies.reproduce`) and
their summary (:mod:`iblbench.reports.reproduction`)."""
from __future__ import annotations

import pathlib

from iblbench.commands.common import positive_int, rendering_flags


DESCRIPTION = """\
Run a paper's experiments on built-in scenes through the ordinary runner, then write summary.md
and summary.html (tables, plots, and one verdict per claim: holds / partly holds / does not hold
/ not resolved, with 95% intervals) beside results.parquet. lu2013: Lu, Pacanowski & Granier
2013's Fig. 2 and 3 and claims, with the production baselines (brdf, envmap) and an equal-time
comparison beside them. mis-compensation: Karlík et al. 2019's MIS compensation against plain
MIS at equal time (envmap and balanced_mis). kronander: Kronander et al.'s claim that MIS and
BIS beat SMC at equal time on moving light, with restir and product as rows. Equal-time cells
run at one budget taken from the reproduction's own spp cells (see the summary)."""


def add_parser(subparsers) -> None:
    repro = subparsers.add_parser(
        "reproduce", help="re-run a paper's experiments and judge its claims (lu2013, "
                          "mis-compensation, kronander)",
        description=DESCRIPTION,
        parents=[rendering_flags()])
    repro.add_argument("paper", metavar="PAPER",
                       help="which reproduction: lu2013, mis-compensation or kronander")
    repro.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/reproduce"),
                       help="output directory (default: results/reproduce)")
    repro.add_argument("--seeds", type=positive_int, default=3,
                       help="seeds per cell (default: 3)")


def run(args) -> None:
    from iblbench.harness.studies.reproduce import reproduce
    from iblbench.reports.reproduction import summary_head, write_summary

    result = reproduce(args.paper, args.out, seeds=args.seeds, device=args.device,
                       progress=False if args.no_progress else None)
    summary = write_summary(pathlib.Path(args.out), result)
    print(summary_head(summary.read_text(encoding="utf-8")))
    print(f"wrote {summary} and {summary.with_suffix('.html')}")
