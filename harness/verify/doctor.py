"""``iblbench doctor``: is every OpenCL device here right?  For each device it builds and runs the
portability set (harness/verify/portability.py; its quick set unless told the whole), the
device's cases one after another in a child process of its own (``portability.Worker``: a
Ctrl-C reaches this process alone, which ends the child and stops without a verdict), and
compares:

- the exact reference with its independent NumPy twin (harness/verify/twins/reference_twin.py), and the
  map's light pdf with the NumPy one of the smc twin (harness/verify/twins/ghosh2006.py, ``Map.pdf``),
  within :data:`TWIN_RTOL`;
- every array with the default device's, on the same fp64 path, within ``portability.FLOAT_RTOL``
  (the CDF words as numbers): the same inputs, seeds and Philox streams give the same image on
  any conforming device, up to float rounding;
- on a simulator (Oclgrind), its reports of invalid memory access, data races and API misuse.

The default device's estimators have no other device to agree with: the conformance suite
(`make test`) holds them to the reference statistically, and smc to its twin in distribution
(harness/verify/twins/crosscheck.py), which takes too many renders for a check per device.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from typing import Callable, Iterator

import numpy as np

from iblbench.harness.verify import portability

TWIN_RTOL = 1e-4        # the reference (tests/test_reference_twin.py) and light pdf against twins
SHOWN = 4               # problems named on a device's line


@dataclasses.dataclass
class DeviceReport:
    label: str
    kind: str
    problems: list[str]
    seconds: float
    cases: int
    build_logs: str = ""

    @property
    def ok(self) -> bool:
        return not self.problems

    def line(self) -> str:
        verdict = "OK  " if self.ok else "FAIL"
        more = f"; and {len(self.problems) - SHOWN} more" if len(self.problems) > SHOWN else ""
        tail = (f"{self.cases} cases in {self.seconds:.0f} s" if self.ok
                else "; ".join(self.problems[:SHOWN]) + more)
        return f"{verdict} [{self.kind}] {self.label}: {tail}"


@functools.lru_cache(maxsize=None)
def _twin(case: str) -> tuple[np.ndarray | None, np.ndarray]:
    """The NumPy twin of the reference (``case`` "reference", with or without ``MASKED``) or of
    the light pdf on the case's own inputs: (the covered pixels it holds, None for every value;
    its values), made once per process, however many devices run the case."""
    from iblbench.harness.verify.twins.ghosh2006 import Map
    from iblbench.harness.verify.twins.reference_twin import twin_image

    case, masked = portability.split_case(case)
    gbuffer, env, _ = portability.inputs(masked)
    if case == "reference":
        return gbuffer.mask, twin_image(gbuffer, env)[gbuffer.mask]
    return None, Map(env).pdf(portability.pdf_directions().astype(np.float64))


def _twin_problem(case: str, arrays: dict[str, np.ndarray]) -> str | None:
    """How far the reference or the light pdf is from its NumPy twin, if beyond tolerance."""
    name = portability.split_case(case)[0]
    covered, twin = _twin(case)
    got = arrays[name] if covered is None else arrays[name][covered]
    error = float(np.max(np.abs(got.astype(np.float64) - twin) / np.maximum(np.abs(twin), 1e-12)))
    return None if error <= TWIN_RTOL else f"{name} off its NumPy twin by {error:.2g} (relative)"


def _case_problems(outcome: portability.Outcome, baseline: dict | None) -> list[str]:
    problems = []
    if outcome.reports:
        first = outcome.reports[0].split(" | ")
        where = next((part for part in first if part.startswith("At line")), first[-1])
        problems.append(f"{outcome.case}: {len(outcome.reports)} Oclgrind reports, first "
                        f"'{first[0]}' {where}")
    if outcome.arrays is None:
        problems.append(f"{outcome.case}: cannot run ({outcome.error})")
        return problems
    if portability.split_case(outcome.case)[0] in ("reference", "light_pdf"):
        problems += filter(None, [_twin_problem(outcome.case, outcome.arrays)])
    if baseline is not None:
        off = portability.differences(outcome.arrays, baseline, exact_integers=False)
        if off:
            name, value = max(off.items(), key=lambda item: item[1])
            size = "not finite, or integers differ" if value == float("inf") else f"{value:.2g} relative"
            problems.append(f"{outcome.case}: {len(off)} arrays differ from the default device's, "
                            f"most {name} ({size})")
    return problems


def diagnose(spec: str | None = None, verbose: bool = False,
             progress: Callable[[str], None] = lambda text: None,
             cases: list[str] | None = None, fp64: bool = True) -> Iterator[DeviceReport]:
    """A report per OpenCL device, each as soon as its cases have run: the default device's
    first, then every other one (those matching ``spec``, if given), on ``cases`` (by default
    the quick set, ``portability.quick_cases()``), each device's in a
    :class:`~iblbench.harness.verify.portability.Worker` of its own.  The default device's
    arrays are the other devices' baseline, on the same fp64 path as theirs (a device without
    cl_khr_fp64 against the default device's float path); with no default device (none that
    builds, or only a simulator) the devices are held to the twins alone.

    ``fp64=False``: every device runs the float path, as one without cl_khr_fp64 does, and
    each, the default device too, is held to the default device's own path (its double path
    where it has fp64)."""
    from iblbench.estimators.runtime.device import (all_devices, build_failure, choose_device,
                                                     matching_devices)
    from iblbench.foundation.errors import InputError

    try:
        default = choose_device()
    except InputError:
        default = None
    cases = portability.quick_cases() if cases is None else cases
    others = [d for d in (matching_devices(spec) if spec else all_devices())
              if default is None or d.key != default.key]
    devices = ([] if default is None else [default]) + others
    baselines: dict[bool, dict] = {}

    def baseline(doubles: bool) -> dict:
        """The default device's arrays of every case on the fp64 or the float path."""
        if doubles not in baselines:
            baselines[doubles] = {}
            with portability.Worker(default.label, fp64=doubles) as worker:
                for case in cases:
                    progress(f"baseline on {default.device.name.strip()}: {case}")
                    outcome = worker.run(case)
                    if outcome.arrays is not None:
                        baselines[doubles][case] = outcome.arrays
        return baselines[doubles]

    def baseline_path(info) -> bool | None:
        """The fp64 path of the default device's arrays that ``info``'s are held to; None: none."""
        if default is None:
            return None
        if not fp64:
            return default.has_fp64
        if info.key == default.key or (info.has_fp64 and not default.has_fp64):
            return None
        return info.has_fp64

    for info in devices:
        start = time.perf_counter()
        failure = build_failure(info)
        if failure:
            yield DeviceReport(info.label, info.kind, [f"cannot build a kernel: {failure}"],
                               time.perf_counter() - start, 0)
            continue
        checks = portability.CHECKS if info.is_simulator else None
        held_to = baseline_path(info)
        problems, logs = [], []
        with portability.Worker(info.label, checks, verbose=verbose, fp64=fp64) as worker:
            for case in cases:
                progress(f"{info.kind} {info.device.name.strip()}: {case}")
                outcome = worker.run(case)
                logs.append(outcome.build_logs)
                if default is not None and info.key == default.key and outcome.arrays is not None:
                    own_path = baselines.setdefault(info.has_fp64 and fp64, {})
                    own_path[case] = outcome.arrays
                expected = None if held_to is None else baseline(held_to).get(case)
                problems += _case_problems(outcome, expected)
        label = info.label if fp64 else f"{info.label} (float path)"
        yield DeviceReport(label, info.kind, problems, time.perf_counter() - start,
                           len(cases), "\n".join(filter(None, logs)))
