"""``iblbench perf`` (:mod:`iblbench.harness.studies.perf`, imported only when the command runs
or prints its help; the page: :mod:`iblbench.reports.perf`)."""
from __future__ import annotations

import argparse
import pathlib

from iblbench.commands.common import device_flags, env_res, launch_shape, positive_int, resolution


PERF_DESCRIPTION = """\
Measure the throughput of every estimator (or the chosen ones) on this device, side by side in
one run: per (scene, estimator), Msamples/s and M evaluations/s, the device ms of the build,
sample and shade stages (median, min and IQR of --repeats renders after one warm-up), the
device's measured FMA and copy roofline and the fraction of it each shading kernel reaches
(from analytic FLOP and byte counts per sample, estimates), the rates of probes of the other
limits (lobe powers, Philox blocks, divisions, random and dependent gathers, scalar sums,
LOCKSTEP search steps) and each kernel's speed over the time its declared uses of them take
(limit), and the speed-up over a single-threaded NumPy implementation of Lu 2013's shared-pool
shading on the same inputs (the floor every kernel must beat; it must also agree with the
uniform kernel on the same pool).
Where the mitsuba package is installed (pip install 'iblbench[peer]') and its llvm_ad_rgb variant
runs a kernel here, also a production peer, row mitsuba3-envmap: Mitsuba 3's own envmap emitter
sampling of the same map, Phong-shaded as envmap does, over the same pixels on every core, and
each row's speed-up over it (× mitsuba); otherwise one line says why it is absent.
Prints a table and writes perf.csv and perf.html into --out. The method is in
harness/studies/perf.py, the counts are each estimator's cost declaration. Exit 0, or 2 on bad input."""


def add_parser(subparsers) -> None:
    from iblbench.harness.protocol.run_config import flag_help

    perf = subparsers.add_parser("perf", help="throughput per estimator against the device's "
                                            "roofline and a NumPy floor (perf.csv, perf.html)",
                               description=PERF_DESCRIPTION, parents=[device_flags()],
                               formatter_class=argparse.RawDescriptionHelpFormatter)
    perf.add_argument("--scene", action="append", metavar="NAME|FILE",
                      help="built-in scene name or scene .toml; repeatable "
                           "(default: sphere-sun and blob-sun)")
    perf.add_argument("--estimator", action="append", metavar="NAME",
                      help="estimator name, optionally NAME{param=value,...}; repeatable "
                           "(default: every registered estimator)")
    perf.add_argument("--spp", type=positive_int, metavar="N",
                      help="samples per pixel of every estimator and the floor (default: 64, or an "
                           "estimator's own perf_budget: bis and smc 20, Kronander's N, with "
                           "M = 400 candidates)")
    perf.add_argument("--res", type=resolution, metavar="WxH",
                      help="image resolution (default: 256x256)")
    perf.add_argument("--env-res", type=env_res, metavar="R",
                      help="cube face resolution (default: 64)")
    perf.add_argument("--repeats", type=positive_int, metavar="N",
                      help="timed renders per estimator after one warm-up (default: 5, or an "
                           "estimator's own perf_budget: bis and smc 3)")
    perf.add_argument("--launch-shape", type=launch_shape, metavar="auto|pixel|sample-block",
                      help=flag_help("launch_shape"))
    perf.add_argument("--lanes", type=int, choices=(8, 16), metavar="{8,16}",
                      help="the estimators' explicit vector width (POOL_LANES) instead of the "
                           "device's (16 where its preferred float width is 16, else 8): to "
                           "measure the 8-lane kernels on an AVX-512 CPU")
    perf.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/perf"),
                      help="output directory for perf.csv and perf.html (default: results/perf)")

    def format_help() -> str:
        from iblbench.harness.studies.perf import columns_help

        perf.epilog = columns_help()
        return argparse.ArgumentParser.format_help(perf)

    perf.format_help = format_help


def run(args) -> None:
    """Measure, print the table, write perf.csv and perf.html into ``--out`` (nothing is
    written when the input is bad)."""
    from iblbench.harness.protocol.results import prepare_out
    from iblbench.harness.studies import perf
    from iblbench.reports.perf import write_outputs
    from iblbench.foundation.errors import InputError

    config = perf.PerfConfig(
        out=args.out, scenes=tuple(args.scene or perf.DEFAULT_SCENES),
        estimators=tuple(args.estimator or ()), spp=args.spp,
        resolution=args.res or perf.DEFAULT_RESOLUTION, env_res=args.env_res or perf.DEFAULT_ENV_RES,
        repeats=args.repeats, device=args.device, launch_shape=args.launch_shape,
        lanes=args.lanes)
    out = pathlib.Path(config.out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "--out exists and is not a directory")
    study = perf.run_study(config)
    prepare_out(out)
    paths = write_outputs(out, study.table, study.roofline, study.context())
    print(perf.format_table(study.table))
    print(f"timing floor (a fixed kernel launched back to back): {study.context()['timing_floor']}")
    print(f"wrote {', '.join(map(str, paths))}")
