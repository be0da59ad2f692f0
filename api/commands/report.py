"""``iblbench report``: a run's HTML report (:mod:`iblbench.reports.report`)."""
from __future__ import annotations

import pathlib

from iblbench.commands.common import pixel, positive_float, positive_int


DESCRIPTION = """\
Summarise a run directory in DIR/report/index.html: tables per scene, error against time with
the Pareto front, convergence, effective samples, image grids with ΔE heat maps, Lu 2013's
sample picture, and the manifest. The page opens from disk (no server, no external files)."""


def add_parser(subparsers) -> None:
    report = subparsers.add_parser(
        "report", help="write a self-contained HTML report of a run (DIR/report/index.html)",
        description=DESCRIPTION)
    report.add_argument("dir", type=pathlib.Path, metavar="DIR", help="an 'iblbench run' --out")
    report.add_argument("--spp", type=positive_int, metavar="N",
                        help="spp of the image grid (default: the largest spp every estimator "
                             "of the scene ran; the sample picture is drawn at the spp the run "
                             "saved it at, that default)")
    report.add_argument("--seed", type=int, help="seed of the images shown (default: the run's "
                                                 "first; one the run lacks is an error)")
    report.add_argument("--frame", type=int, help="frame of the images shown (default: each "
                                                  "scene's median-luminance frame; one the run "
                                                  "lacks is an error)")
    report.add_argument("--pixel", type=pixel, metavar="X,Y",
                        help="pixel of the sample picture (default: the covered pixel nearest "
                             "the image centre)")
    report.add_argument("--ray-cost-ns", type=positive_float, metavar="NS",
                        help="cost of one shadow ray in the error against time-plus-rays plot "
                             "of scenes with visibility (default: the host Embree rate measured "
                             "when their masks were traced)")
    report.add_argument("--no-progress", action="store_true",
                        help="no progress bar (shown on stderr where it is a terminal)")


def run(args) -> None:
    from iblbench.reports.report import write_report

    context = write_report(args.dir, spp=args.spp, seed=args.seed, frame=args.frame,
                           pixel=args.pixel, ray_cost_ns=args.ray_cost_ns,
                           progress=False if args.no_progress else None)
    print(f"wrote {context['path']}")
