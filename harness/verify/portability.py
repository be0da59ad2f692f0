"""The portability set: every kernel on tiny inputs, run on any OpenCL device and compared across
devices (``iblbench doctor``, tests/test_portability.py).

One *case* renders one thing on 16 pixels (a glossy G-buffer over the whole sphere) lit by a
4×4-texel-per-face map with a sun: ``reference`` (the exact reference), ``products`` (the frame
cache's CDFs, face integrals, light pool and both mip pyramids, plain and compensated, and the
weight pyramids' descent tables),
``light_pdf`` (the map's light pdf, ARCHITECTURE.md §Conventions, at :data:`PDF_DIRECTIONS` directions, by
``envmap``'s pdf hook), ``probes`` (``iblbench perf``'s FMA and copy kernels), or an estimator
label such as ``envmap{mis="brdf"}`` at 4 spp; a name ending in ``+visibility`` (the reference and
each estimator's defaults) renders the G-buffer with visibility masks of 2² cells a face, three
in four open (issue 22), so both paths of every kernel that reads V run; a temporal estimator renders a first
frame and then the same map with each face's texel columns shifted by one, so its carried state
is exercised.  Sizes are this small because Oclgrind interprets every work item.

The cases run in a child process (:class:`Worker`), one device's one after another so that
each program builds once: Oclgrind's checks are switched on by environment variables read when
its platform loads, and a driver that crashes takes only the child with it.  The child writes
each case's arrays to an ``.npz`` file and the parent reads Oclgrind's reports from its
standard error (:func:`oclgrind_reports`).
"""
from __future__ import annotations

import dataclasses
import functools
import os
import pathlib
import re
import select
import signal
import subprocess
import sys
import tempfile

import numpy as np

SIZE = 4          # pixels per side
ENV_RES = 4       # texels per face side
SPP = 4
SUN_RATIO = 50.0  # the sun texel's luminance over the sky's
PDF_DIRECTIONS = 64
VIS_RES, OPEN_SHARE, VIS_SEED = 2, 0.75, 22   # the G-buffer's visibility masks (inputs)
# Oclgrind's checks: memory (always on), data races and API misuse.
CHECKS = {"OCLGRIND_DATA_RACES": "1", "OCLGRIND_CHECK_API": "1"}
# Its uninitialised-value check, where it runs: Oclgrind 21.10's checker marks any vector
# shuffle lane that picks element 11 as uninitialised (it compares the mask with an LLVM value
# kind, 11, not with undef), so row_cdfs's shuffles are reported, falsely (built without
# optimisation and without the shuffles only a .hi half is left, as false); it crashes on a
# shuffle with an undef lane (the reference, brdf) and stops at LLVM's `freeze` (the mips,
# havran).  Every case but the probes builds the CDFs, so the probes alone are checked.
UNINITIALIZED = {"OCLGRIND_UNINITIALIZED": "1"}
UNINITIALIZED_CASES = ("probes",)
# First lines of Oclgrind's reports: memory, races, barriers, uninitialised values, API misuse,
# and its own fatal errors (such as an LLVM intrinsic it cannot run).
_REPORT = re.compile(r"^(Invalid (read|write)|.*data race|Work-(group|item) divergence|"
                     r"Uninitiali[sz]ed|Oclgrind - OpenCL runtime error|OCLGRIND FATAL ERROR|"
                     r"Oclgrind: \d+ errors generated)")


MASKED = "+visibility"
OWN_CASES = ("reference", "products", "light_pdf", "probes")   # the cases that are no estimator


def variants() -> list[str]:
    """The configurations beyond each registered estimator's defaults that run other kernel
    paths: each class's own ``portability_variants``."""
    from iblbench.estimators.base import own
    from iblbench.estimators.registry import estimator_names, get_estimator_class

    return [label for name in estimator_names()
            for label in own(get_estimator_class(name), "portability_variants")]


def cases() -> list[str]:
    """Every case of the set: the reference, the frame-cache products, the light pdf, the perf
    probes, each registered estimator with its defaults, its :func:`variants`, and the reference
    and each estimator again with visibility masks (``MASKED``)."""
    from iblbench.estimators.registry import estimator_names

    return [*OWN_CASES, *estimator_names(), *variants(),
            *(name + MASKED for name in ("reference", *estimator_names()))]


def quick_cases() -> list[str]:
    """``iblbench doctor``'s default set, every estimator once: the cases that are no estimator
    and each registered estimator with its defaults on the G-buffer with visibility masks (its
    longest path: the masks read, both lit and shadowed directions).  :func:`cases` adds each
    estimator on the plain G-buffer, its variants and the reference with masks."""
    from iblbench.estimators.registry import estimator_names

    return [*OWN_CASES, *(name + MASKED for name in estimator_names())]


def split_case(case: str) -> tuple[str, bool]:
    """(the case's name without ``MASKED``, whether its G-buffer has visibility masks)."""
    return case.removesuffix(MASKED), case.endswith(MASKED)


def inputs(masked: bool = False):
    """(G-buffer, first map, turned map) of every case; ``masked``: the G-buffer carries
    visibility masks of VIS_RES² cells a face, OPEN_SHARE of them open (random, seeded)."""
    from iblbench.harness.verify import fixtures
    from iblbench.scenes import visibility

    env = fixtures.sun_map(ENV_RES, SUN_RATIO)
    gbuffer = fixtures.glossy_gbuffer(SIZE)
    if masked:
        cells = np.random.default_rng(VIS_SEED).random(gbuffer.shape + (6 * VIS_RES * VIS_RES,)) < OPEN_SHARE
        gbuffer = dataclasses.replace(gbuffer, visibility=visibility.pack_bits(cells), visibility_res=VIS_RES)
    return gbuffer, env, np.ascontiguousarray(np.roll(env, 1, axis=2))


def pdf_directions() -> np.ndarray:
    """The ``light_pdf`` case's directions, spread over the sphere, float32 ``[n, 3]``."""
    from iblbench.harness.verify.fixtures import fibonacci_directions

    return fibonacci_directions(PDF_DIRECTIONS).astype(np.float32)


def render(compute, case: str) -> dict[str, np.ndarray]:
    """The arrays of one case on ``compute``, by name."""
    from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
    from iblbench.estimators.runtime.framecache import FrameCache
    from iblbench.estimators.runtime.reference import Reference
    from iblbench.harness.protocol.sweep import parse_estimator

    case, masked = split_case(case)
    if case not in OWN_CASES:
        return render_estimator(compute, parse_estimator(case).make(), masked)
    gbuffer, env, _ = inputs(masked)
    pixels = DeviceGBuffer(compute, gbuffer)
    cache = FrameCache(compute, env)
    if case == "reference":
        return {"reference": Reference(compute, use_cache=False).image(pixels, cache)}
    if case == "products":
        return _products(compute, cache)
    if case == "probes":
        from iblbench.estimators.runtime import probes

        copied = probes.run_copy(compute, np.arange(64, dtype=np.float32))[0]
        lanes = probes.run_fma(compute, 16, 5, b=1.0)[0]   # [items, chains, the device's width]
        return {"fma": lanes[..., 0], "copy": copied, **probes.limit_outputs(compute)}
    light_only = parse_estimator("envmap").make()   # the light_pdf case
    cache.require(type(light_only).requires)
    return {"light_pdf": light_only.pdf(cache, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.6, 0.8]),
                                        pdf_directions())}


def render_estimator(compute, estimator, masked: bool = False) -> dict[str, np.ndarray]:
    """An estimator's arrays on the set's inputs (``masked``: with visibility masks), frame by
    frame: its radiance, used and effective counts and evaluations; a temporal one's on two
    frames (the map turned on the second)."""
    from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
    from iblbench.estimators.runtime.framecache import FrameCache

    gbuffer, env, turned = inputs(masked)
    pixels = DeviceGBuffer(compute, gbuffer)
    frames = [FrameCache(compute, env)]
    if type(estimator).tags.temporal:
        frames.append(FrameCache(compute, turned, frame=1))
    out = {}
    for frame, frame_cache in enumerate(frames):
        frame_cache.require(type(estimator).requires)
        estimate = estimator.render(pixels, frame_cache, SPP, 0)
        out.update({f"f{frame}_radiance": estimate.radiance, f"f{frame}_used": estimate.used,
                    f"f{frame}_effective": estimate.effective,
                    f"f{frame}_evaluations": np.float64(estimate.evaluations)})
    return out


@functools.lru_cache(maxsize=None)
def float_path(compute):
    """The float path (``fp64=False``), which a device without cl_khr_fp64 runs, on
    ``compute``'s device and lane width: one per ``compute``, so its programs build once."""
    from iblbench.estimators.runtime.device import Compute

    return Compute(compute.info, fp64=False, lanes=compute.pool_lanes)


def _products(compute, cache) -> dict[str, np.ndarray]:
    out = {}
    marginal, conditional = cache.host_cdfs()
    out.update(cdf_marginal=marginal, cdf_conditional=conditional,
               face_integrals=cache.face_integrals)
    for compensated in (False, True):
        tag = "compensated" if compensated else "plain"
        cdfs = cache.light_cdfs(compensated)
        out[f"light_marginal_{tag}"] = compute.to_host(cdfs.marginal, (6, cache.res), np.uint64)
        pool = cache.light_pool(8, 0, compensated)
        out[f"pool_{tag}"] = compute.to_host(pool.dir_pdf, (6 * 8, 4), np.float32)
        levels = cache.weight_pyramid(compensated).host_levels(compute)
        out.update({f"weights_{tag}_{i}": level for i, level in enumerate(levels)})
        tables = cache.descent_tables(compensated)
        out[f"descent_bounds_{tag}"] = compute.to_host(tables.bounds, (2 * 4 ** (len(levels) - 1), 4), np.uint32)
        out[f"descent_probability_{tag}"] = compute.to_host(tables.probability, (6 * cache.res ** 2,), np.float32)
    levels = cache.radiance_mips().host_levels(compute)
    out.update({f"radiance_mips_{i}": level for i, level in enumerate(levels)})
    return out


# Integer arrays (the fixed-point CDF words) agree bit for bit between PoCL and Oclgrind (the
# portability test holds them to it); float arithmetic may differ in rounding and in the order of
# sums (vector widths, fused multiply-add).  The CDF words are sums of float weights, so on another
# device (a GPU's divide and FMA contraction may round differently; a device without fp64 sums
# them in float) `iblbench doctor` compares them as numbers, within FLOAT_RTOL.
FLOAT_RTOL = 1e-4


def differences(ours: dict[str, np.ndarray], baseline: dict[str, np.ndarray],
                exact_integers: bool = True) -> dict[str, float]:
    """Per array of ``baseline``: 0 where ``ours`` matches it (bit for bit for integer arrays if
    ``exact_integers``, else like float ones; within :data:`FLOAT_RTOL` for float ones), else how
    far off: the largest relative difference (inf for a missing array, a shape change, an
    integer mismatch or a NaN or infinity in either array, even where both have it: no render
    of the set's inputs has one)."""
    out = {}
    for name, expected in baseline.items():
        got = ours.get(name)
        if got is None or np.shape(got) != np.shape(expected):
            out[name] = float("inf")
        elif exact_integers and np.issubdtype(np.asarray(expected).dtype, np.integer):
            out[name] = 0.0 if np.array_equal(got, expected) else float("inf")
        elif not (np.isfinite(got).all() and np.isfinite(expected).all()):
            out[name] = float("inf")
        else:
            expected = np.asarray(expected, np.float64)
            scale = np.maximum(np.abs(expected), 1e-3 * max(float(np.max(np.abs(expected))), 1e-30))
            relative = float(np.max(np.abs(np.asarray(got, np.float64) - expected) / scale, initial=0.0))
            out[name] = relative if relative > FLOAT_RTOL else 0.0
    return {name: value for name, value in out.items() if value}


@dataclasses.dataclass
class Outcome:
    """One case on one device: its arrays (None when the child failed), Oclgrind's reports, and
    the child's last line of error when it failed."""

    case: str
    arrays: dict[str, np.ndarray] | None
    reports: list[str]
    error: str = ""
    build_logs: str = ""


# pyopencl's own queries: under OCLGRIND_CHECK_API, each Program.build and each kernel it creates
# asks Oclgrind (OpenCL 1.2) for a device property 1.2 does not define; iblbench's own device
# queries are all OpenCL 1.2 names (tests/test_portability.py checks them alone).
PYOPENCL_QUERY = "Oclgrind - OpenCL runtime error detected | Function: clGetDeviceInfo | " \
                 "Error: CL_INVALID_VALUE | For argument 'param_name'"


def oclgrind_reports(stderr: str) -> list[str]:
    """Each report Oclgrind wrote to ``stderr``, its lines joined by " | " (whitespace folded),
    less :data:`PYOPENCL_QUERY`."""
    lines = stderr.splitlines()
    reports = []
    for at, line in enumerate(lines):
        if _REPORT.match(line):
            block = [line]
            for detail in lines[at + 1:]:
                if not detail.strip() or _REPORT.match(detail):
                    break
                block.append(" ".join(detail.split()))
            reports.append(" | ".join(block))
    return [report for report in reports if report != PYOPENCL_QUERY]


class Worker:
    """A child process that runs cases on one device, one after another (:func:`serve`), so
    that each program builds once per device: with ``checks`` (Oclgrind's) in its environment,
    ``lanes`` for ``Compute.pool_lanes`` if given, and the float path with ``fp64=False``.

    The child runs in a session of its own: a Ctrl-C reaches the parent alone, which ends the
    child (:meth:`close`) and stops, so no case is cut short into a false failure.  A case that
    fails, crashes the driver or draws Oclgrind reports ends its child, and the next case starts
    a fresh one: Oclgrind stops listing errors at 1000 per process, and a crash takes only that
    case with it.  The child's standard error goes to a file, each case's part read back for
    Oclgrind's reports (:func:`oclgrind_reports`); a child whose parent died ends at its next
    case (its standard input closed)."""

    def __init__(self, device: str, checks: dict[str, str] | None = None, lanes: int | None = None,
                 fp64: bool = True, verbose: bool = False, timeout: float = 600.0):
        self.command = [sys.executable, "-m", "iblbench.harness.verify.portability", device,
                        str(lanes or 0), str(int(fp64))]
        self.env = {**os.environ, **(checks or {})}
        self.fp64, self.verbose, self.timeout = fp64, verbose, timeout
        self.folder = tempfile.TemporaryDirectory()
        self.child: subprocess.Popen | None = None
        self.cases = 0

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
        self.folder.cleanup()

    def _path(self, suffix: str) -> pathlib.Path:
        return pathlib.Path(self.folder.name) / f"{self.cases}{suffix}"

    def close(self) -> None:
        """End the child, and any process it started (a linker), at once."""
        if self.child is not None:
            try:
                os.killpg(self.child.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.child.wait()
            self.child.stdin.close()
            self.child.stdout.close()
            self.child = None

    def run(self, case: str) -> Outcome:
        """``case``'s arrays and reports (and with ``verbose`` the compiler's output)."""
        try:
            return self._run(case)
        except BaseException:   # a Ctrl-C (KeyboardInterrupt) above all: the child goes too
            self.close()
            raise

    def _run(self, case: str) -> Outcome:
        self.cases += 1
        stderr_path = pathlib.Path(self.folder.name) / "stderr"
        if self.child is None:
            with open(stderr_path, "wb") as stderr:   # the child holds its own descriptor
                self.child = subprocess.Popen(self.command + [self.folder.name], env=self.env,
                                              stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                              stderr=stderr, bufsize=0, start_new_session=True)
        start = stderr_path.stat().st_size
        try:
            self.child.stdin.write(f"{self.cases} {case}\n".encode())
        except BrokenPipeError:   # the child ended before this case (its standard error says why)
            answered, done = True, False
        else:
            answered = bool(select.select([self.child.stdout], [], [], self.timeout)[0])
            done = answered and self.child.stdout.readline() == b"done\n"
        with open(stderr_path, "rb") as stderr:
            stderr.seek(start)
            errors = stderr.read().decode(errors="replace")
        reports = oclgrind_reports(errors)
        logs = self._path(".log")
        build_logs = logs.read_text() if self.verbose and logs.exists() else ""
        if not done:
            self.close()
            lines = [line for line in errors.splitlines() if line.strip()]
            why = (f"no result within {self.timeout:.0f} s" if not answered
                   else lines[-1] if lines else "the child ended without a word")
            return Outcome(case, None, reports, why, build_logs)
        if reports:
            self.close()
        with np.load(self._path(".npz")) as data:
            return Outcome(case, {name: data[name] for name in data.files}, reports, "", build_logs)


def run_case(device: str, case: str, checks: dict[str, str] | None = None,
             timeout: float = 600.0, verbose: bool = False, lanes: int | None = None,
             fp64: bool = True) -> Outcome:
    """``case`` alone in a :class:`Worker` of its own."""
    with Worker(device, checks, lanes, fp64, verbose, timeout) as worker:
        return worker.run(case)


def serve(argv: list[str]) -> None:
    """The child of :class:`Worker`: ``DEVICE LANES FP64 FOLDER`` (LANES 0: the device's; FP64 0:
    the float path).  For each line ``N CASE`` on standard input it writes the case's arrays to
    ``FOLDER/N.npz``, the compiler's output of the programs it built to ``FOLDER/N.log``, and
    ``done`` on standard output (whatever else writes there goes to standard error); it ends
    when its input does."""
    from iblbench.estimators.runtime.device import Compute, choose_device

    device, lanes, fp64, folder = argv
    answers = os.fdopen(os.dup(sys.stdout.fileno()), "w")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    compute = Compute(choose_device(device), fp64=fp64 == "1", lanes=int(lanes) or None)
    for line in sys.stdin:
        number, case = line.strip().split(" ", 1)
        built = set(compute.build_logs)
        out = pathlib.Path(folder) / number
        try:
            np.savez(out.with_suffix(".npz"), **render(compute, case))
        finally:
            out.with_suffix(".log").write_text("".join(
                f"== {program}\n{log}\n" for program, log in compute.build_logs.items()
                if log and program not in built))
        sys.stdout.flush()
        sys.stderr.flush()
        print("done", file=answers, flush=True)


if __name__ == "__main__":
    serve(sys.argv[1:])
