"""The checkers themselves (issue 36, class 7): a fault planted in what the portability
comparison and ``iblbench doctor`` are given must be flagged.

- ``portability.differences`` fails an array with any non-finite value (NaN, +Inf, -Inf), in
  either array (or both), anywhere in it, whatever the comparison of integers;
- ``doctor`` holds every case that has a NumPy twin (the reference, its masked variant, the
  light pdf) to that twin on the case's own inputs, and the rest to the default device's arrays;
- Oclgrind's reports, however they start, become a problem of the case."""
from __future__ import annotations

import functools
import types

import numpy as np
import pytest

from iblbench.harness.verify import doctor, portability
from iblbench.harness.verify.twins.ghosh2006 import Map
from iblbench.harness.verify.twins.reference_twin import twin_image

TWINNED = ("reference", "light_pdf")   # the cases with a NumPy twin (harness/verify/twins/)


def arrays():
    """A case's arrays as the portability set hands them over: an image, a 0-d count (an
    estimator's evaluations) and fixed-point CDF words."""
    return {"f0_radiance": np.arange(1.0, 13.0, dtype=np.float32).reshape(2, 2, 3),
            "f0_evaluations": np.float64(64.0),
            "cdf": np.array([0, 1 << 40, 1 << 41], np.uint64)}


def poisoned(values: dict, name: str, value: float, at: int) -> dict:
    out = {key: np.array(array, copy=True) for key, array in values.items()}
    out[name].reshape(-1)[at] = value   # a view: also for the 0-d array
    return out


@pytest.mark.parametrize("exact_integers", (True, False))
@pytest.mark.parametrize("side", ("ours", "baseline", "both"))
@pytest.mark.parametrize("value", (np.nan, np.inf, -np.inf))
def test_a_non_finite_value_fails_the_comparison_wherever_it_is(value, side, exact_integers):
    clean = arrays()
    assert portability.differences(arrays(), clean, exact_integers) == {}
    for name, at in (("f0_radiance", 0), ("f0_radiance", 5), ("f0_radiance", 11),
                     ("f0_evaluations", 0)):
        bad = poisoned(clean, name, value, at)
        ours, baseline = {"ours": (bad, clean), "baseline": (clean, bad), "both": (bad, bad)}[side]
        assert portability.differences(ours, baseline, exact_integers) == {name: np.inf}, (name, at)


def test_the_comparison_holds_floats_to_its_relative_tolerance_and_words_as_told():
    """Floats within FLOAT_RTOL pass and beyond it fail; a CDF word one off fails bit for bit and
    passes as a number (doctor's comparison, ARCHITECTURE.md §Devices and portability)."""
    clean = arrays()
    within, beyond = (poisoned(clean, "f0_radiance", 6.0 * (1 + k * portability.FLOAT_RTOL), 5)
                      for k in (0.9, 1.1))
    assert portability.differences(within, clean) == {}
    assert portability.differences(beyond, clean) == {"f0_radiance": pytest.approx(1.1e-4, rel=1e-2)}
    word = poisoned(clean, "cdf", (1 << 40) + 1, 1)
    assert portability.differences(word, clean) == {"cdf": np.inf}
    assert portability.differences(word, clean, exact_integers=False) == {}


@functools.lru_cache(maxsize=None)
def twin_arrays(case: str) -> dict[str, np.ndarray]:
    """What a device that computes exactly hands back for a twinned ``case``: the twin itself, on
    the case's own inputs (its visibility masks where it has them)."""
    name, masked = portability.split_case(case)
    gbuffer, env, _ = portability.inputs(masked)
    if name == "reference":
        return {"reference": twin_image(gbuffer, env).astype(np.float32)}
    return {"light_pdf": Map(env).pdf(portability.pdf_directions().astype(np.float64)).astype(np.float32)}


def twinned_cases() -> list[str]:
    cases = [case for case in portability.cases() if portability.split_case(case)[0] in TWINNED]
    assert {"reference", "reference" + portability.MASKED, "light_pdf"} <= set(cases), cases
    return cases


def test_doctor_holds_every_case_with_a_twin_to_it_masked_variants_included():
    """Each twinned case passes with its twin's arrays and fails with one value moved 2·TWIN_RTOL
    (at the first and the last pixel) or made NaN, with no default device's arrays to fall back
    on; one moved 0.5·TWIN_RTOL passes."""
    for case in twinned_cases():
        exact = twin_arrays(case)
        assert doctor._case_problems(portability.Outcome(case, exact, []), None) == [], case
        (name,) = exact
        for at, factor in ((0, 1 + 2 * doctor.TWIN_RTOL), (-1, 1 - 2 * doctor.TWIN_RTOL), (-1, np.nan)):
            flat = exact[name].reshape(-1)
            moved = poisoned(exact, name, flat[at] * factor, at % flat.size)
            problems = doctor._case_problems(portability.Outcome(case, moved, []), None)
            assert len(problems) == 1 and problems[0].startswith(
                f"{portability.split_case(case)[0]} off its NumPy twin by"), (case, at, problems)
        close = poisoned(exact, name, exact[name].reshape(-1)[0] * (1 + 0.5 * doctor.TWIN_RTOL), 0)
        assert doctor._case_problems(portability.Outcome(case, close, []), None) == [], case


def test_the_masked_reference_is_held_to_the_masked_twin_not_the_plain_one():
    """The masks darken the reference far beyond TWIN_RTOL, so the plain twin's image under the
    masked case's name (or the masked one under the plain name) must fail."""
    plain, masked = twin_arrays("reference"), twin_arrays("reference" + portability.MASKED)
    assert np.max(np.abs(plain["reference"] - masked["reference"]) / plain["reference"]) > 0.01
    for case, given in (("reference" + portability.MASKED, plain), ("reference", masked)):
        problems = doctor._case_problems(portability.Outcome(case, given, []), None)
        assert problems and problems[0].startswith("reference off its NumPy twin"), (case, problems)


def test_doctor_flags_a_non_finite_or_missing_array_against_the_default_devices():
    """A case without a twin is held to the default device's arrays: a NaN there (or in the
    baseline) is named, as not finite, and so is an array the case lacks."""
    clean = arrays()
    for ours, baseline in ((poisoned(clean, "f0_radiance", np.nan, 3), clean),
                           (clean, poisoned(clean, "f0_radiance", np.inf, 3))):
        problems = doctor._case_problems(portability.Outcome("cosine", ours, []), baseline)
        assert problems == ["cosine: 1 arrays differ from the default device's, most f0_radiance "
                            "(not finite, or integers differ)"], problems
    missing = {name: array for name, array in clean.items() if name != "cdf"}
    assert doctor._case_problems(portability.Outcome("cosine", missing, []), clean) == [
        "cosine: 1 arrays differ from the default device's, most cdf (not finite, or integers differ)"]


@pytest.mark.parametrize("first_line", [
    "Invalid read of size 4 at global memory address 0x1000000000010",
    "Invalid write of size 16 at local memory address 0x20",
    "Read-write data race at global memory address 0x8",
    "Work-group divergence detected (barrier):",
    "Uninitialized value read from private memory address 0x0",
    "Oclgrind - OpenCL runtime error detected",
    "OCLGRIND FATAL ERROR (unsupported intrinsic)",
    "Oclgrind: 2 errors generated.",
])
def test_every_kind_of_oclgrind_report_becomes_a_problem_of_its_case(first_line):
    """A report planted in a child's standard error, among ordinary lines, is found, and doctor
    names the case and its first line even though the arrays agree."""
    stderr = f"N warnings generated.\n{first_line}\n\tKernel: render_uniform\n\n1 done\n"
    reports = portability.oclgrind_reports(stderr)
    assert reports == [f"{first_line} | Kernel: render_uniform"]
    clean = arrays()
    problems = doctor._case_problems(portability.Outcome("uniform", clean, reports), clean)
    assert problems == [f"uniform: 1 Oclgrind reports, first '{first_line}' Kernel: render_uniform"]


class FakeWorker:
    """portability.Worker on stand-in devices: each case's arrays as ``ARRAYS[label]`` plants them."""
    arrays: dict[str, dict[str, dict]] = {}

    def __init__(self, label, checks=None, lanes=None, fp64=True, verbose=False, timeout=600.0):
        self.label = label

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def run(self, case):
        return portability.Outcome(case, self.arrays[self.label][case], [])


def fake_info(label: str):
    return types.SimpleNamespace(label=label, key=label, kind="CPU", is_simulator=False,
                                 has_fp64=True, device=types.SimpleNamespace(name=label))


def test_doctor_flags_each_device_whose_arrays_carry_a_planted_fault(monkeypatch):
    """Four stand-in devices run the twinned cases and one estimator: A (the default) and B give
    the twins' arrays; C a NaN in the estimator's image, D the plain reference for the masked
    one.  A and B pass; C fails against A's arrays, D against the masked twin (and A's)."""
    from iblbench.estimators.runtime import device

    cases = ["reference", "reference" + portability.MASKED, "light_pdf", "cosine"]
    clean = {case: twin_arrays(case) for case in cases[:3]} | {"cosine": arrays()}
    monkeypatch.setattr(FakeWorker, "arrays", {
        "A": clean, "B": clean,
        "C": {**clean, "cosine": poisoned(clean["cosine"], "f0_radiance", np.nan, 7)},
        "D": {**clean, "reference" + portability.MASKED: clean["reference"]}})
    monkeypatch.setattr(device, "all_devices", lambda: [fake_info(label) for label in FakeWorker.arrays])
    monkeypatch.setattr(device, "choose_device", lambda spec=None: fake_info("A"))
    monkeypatch.setattr(device, "build_failure", lambda info: None)
    monkeypatch.setattr(portability, "Worker", FakeWorker)
    reports = {report.label: report for report in doctor.diagnose(cases=cases)}
    assert reports["A"].ok and reports["B"].ok, (reports["A"].problems, reports["B"].problems)
    assert reports["C"].problems == ["cosine: 1 arrays differ from the default device's, most "
                                     "f0_radiance (not finite, or integers differ)"]
    (twin, baseline) = reports["D"].problems
    assert twin.startswith("reference off its NumPy twin by") and baseline.startswith(
        "reference+visibility: 1 arrays differ from the default device's, most reference")
    monkeypatch.setattr(FakeWorker, "arrays", {"A": FakeWorker.arrays["D"]})   # the default too
    (alone,) = doctor.diagnose(cases=cases)
    assert [p.split(" by ")[0] for p in alone.problems] == ["reference off its NumPy twin"]
