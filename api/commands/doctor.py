"""``iblbench doctor``: every OpenCL device checked (the engine: :mod:`iblbench.harness.verify.doctor`)."""
from __future__ import annotations

import argparse
import sys


DOCTOR_DESCRIPTION = """\
For each OpenCL device found, build the kernels and run the portability set on 16 pixels and a
4x4 map with a sun (a temporal estimator on two frames), each device's cases one after another
in a process of its own. By default the quick set: the exact reference, the frame cache's CDFs,
pool and mip pyramids, the light pdf, the perf probes and every estimator with its defaults on a
G-buffer with visibility masks; --thorough adds every estimator without masks, each one's
variants and the reference with masks. It compares the reference and the light pdf with their
independent NumPy twins (within 1e-4), and every result with the default device's on the same
fp64 path (within 1e-4 relative). On Oclgrind, the OpenCL specification's simulator, its memory,
data-race and API checks are on and any report fails the device. Prints a line per device as
each finishes, the default device's first (it is the baseline, so it runs under --device too):
OK, or which part is wrong and by how much. Exit 0 when every device is OK, 1 otherwise; 130 on
Ctrl-C, at once, with no verdict on the device it was checking. Time on a busy 2-core machine:
the first run, which compiles every kernel, about 45 s for a CPU device (PoCL) and 25 s on
Oclgrind (--thorough: 65 s and 30 s); later runs, the kernels cached, a few seconds each.

A new GPU: run this first; then choose a device with --device or IBLBENCH_DEVICE."""


def add_parser(subparsers) -> None:
    doctor = subparsers.add_parser(
        "doctor", help="check every OpenCL device: build and run each kernel, compare results",
        description=DOCTOR_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    doctor.add_argument("--device", metavar="SUBSTRING",
                        help="only the devices whose 'platform / version / device' contains this "
                             "(the default device still runs: it is the baseline)")
    doctor.add_argument("--thorough", action="store_true",
                        help="run the whole portability set (every estimator with and without "
                             "visibility masks, and each one's variants), not the quick set")
    doctor.add_argument("--verbose", action="store_true",
                        help="also print the compilers' output (warnings), which is silent otherwise")
    doctor.add_argument("--no-fp64", dest="fp64", action="store_false",
                        help="run every device on the float path, as a device without cl_khr_fp64 "
                             "does (single-precision sums where the kernels otherwise accumulate in "
                             "double), and hold each, the default device too, to the default "
                             "device's double path")


def run(args) -> int:
    from iblbench.harness.verify import portability
    from iblbench.harness.verify.doctor import diagnose

    def progress(text: str) -> None:   # one status line on a terminal, nothing in a log
        if sys.stderr.isatty():
            print(f"\r\033[K{text}", end="", file=sys.stderr, flush=True)

    cases = portability.cases() if args.thorough else portability.quick_cases()
    everyone_ok = True
    try:
        for report in diagnose(args.device, args.verbose, progress, cases, args.fp64):
            progress("")
            if args.verbose and report.build_logs:
                print(report.build_logs)
            print(report.line(), flush=True)   # as each device finishes, on a terminal or not
            everyone_ok &= report.ok
    finally:
        progress("")
    return 0 if everyone_ok else 1
