"""``iblbench compare`` (:mod:`iblbench.harness.protocol.compare`)."""
from __future__ import annotations

import pathlib

from iblbench.commands.common import add_json


DESCRIPTION = """\
Compare run folders A and B per cell (scene, estimator, spp or time budget, frame): for
{metrics}, effective_ratio and time_ms, the mean over
seeds on each side and the ratio B/A with its 95% interval (delta method on log, Welch df); a
change is significant when the interval excludes 1. Says when A and B differ in code, device,
protocol or configuration. An estimator label with parameters (balanced{{uniform_faces=true}}) is
paired with the other side's label of the same base name when no equal label exists. Exit 0, 1
when a cell has a significant change beyond a --fail-if threshold, 2 on bad input."""


def add_parser(subparsers) -> None:
    from iblbench.harness.protocol.metric import columns

    compare = subparsers.add_parser(
        "compare", help="compare two run folders cell by cell: ratios B/A with 95%% intervals "
                        "over seeds; exit 1 on a significant change beyond a --fail-if",
        description=DESCRIPTION.format(metrics=", ".join(columns())))
    compare.add_argument("a", type=pathlib.Path, metavar="A", help="the baseline run folder")
    compare.add_argument("b", type=pathlib.Path, metavar="B", help="the run folder compared with A")
    compare.add_argument("--fail-if", action="append", default=[], metavar="METRIC>P%%",
                         help="fail (exit 1) when a cell's METRIC changes significantly by "
                              "more than P%%: 'mean_delta_e76>5%%' (an increase), "
                              "'effective_ratio<-5%%' (a decrease); repeatable")
    add_json(compare)


def run(args) -> int:
    from iblbench.harness.protocol.compare import run_command

    return run_command(args.a, args.b, args.fail_if, as_json=args.json)
