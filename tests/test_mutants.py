"""The mutation suite (harness/verify/mutants.py, issue 13): every realistic bug of the catalogue is
rejected by the conformance suite, the stress battery or the budgets, not only by a unit test.

The catalogue runs once per module, two mutants at a time, each stopping at the first layer
that rejects it.  A mutant whose catalogue entry waits for a check still to land
(``expect_killed_after``) may survive (xfail, not strict).
"""
import dataclasses
import pathlib
import tempfile

import pytest

from iblbench.harness.verify import mutants
from iblbench.cli import main

pytestmark = pytest.mark.slow
BUILTIN = mutants.catalogue(plugins=False)   # an installed plugin's own mutants are its tests'
TESTS = pathlib.Path(__file__).parent
AREAS = ("uniform", "balanced", "balanced_mis", "havran", "bis", "smc", "restir")


def test_catalogue_covers_every_estimator_and_harness_part_and_applies_cleanly():
    names = [m.name for m in BUILTIN]
    assert len(names) >= 30 and len(set(names)) == len(names)
    covered = {e.partition("{")[0] for m in BUILTIN for e in m.estimators}
    assert set(AREAS) <= covered
    paths = {m.path for m in BUILTIN}
    for part in ("estimators/runtime/framecache", "estimators/runtime/reference", "harness/protocol/metrics"):
        assert any(p.startswith(part) for p in paths), part
    with tempfile.TemporaryDirectory() as tmp:
        root = mutants.copy_sources(pathlib.Path(tmp))
        for mutant in BUILTIN:       # each replaces text that occurs exactly once
            mutant.apply(root)
    for mutant in BUILTIN:          # every layer a mutant names has something to run
        assert mutant.estimators or mutant.stress or mutant.budgets or mutant.tests, mutant.name
    for mutant in BUILTIN:          # every test a mutant names exists
        for node in mutant.tests:
            file, _, name = node.partition("::")
            assert f"def {name.partition('[')[0]}(" in (TESTS / file).read_text(encoding="utf-8"), node


def test_a_null_mutation_survives_every_layer():
    """The layers do not reject correct code: a mutation that changes nothing passes them."""
    null = mutants.Mutant("null", "estimators/runtime/kernels/common.cl", "#define IBL_PI", "#define IBL_PI",
                          ("uniform",), ("constant",))
    outcome = mutants.run_mutant(null, all_layers=True)
    assert not outcome.error, outcome.error
    assert outcome.rejected_by == {"conformance": "", "stress": ""}


def test_the_tests_layer_runs_the_named_tests_on_the_mutated_copy():
    """A bug that only a unit test can see (the scheduler's usual port named wrongly in the
    dashboard hint) is rejected by the test the mutant names, which fails only on the copy; the
    same test passes a null mutation."""
    node = "test_scheduler_address.py::test_a_web_scheme_names_the_schedulers_form"
    path = "harness/protocol/scheduler_address.py"
    wrong = mutants.Mutant("scheduler-port-wrong", path, "SCHEDULER_PORT, DASHBOARD_PORT = 8786, 8787",
                           "SCHEDULER_PORT, DASHBOARD_PORT = 8788, 8787", (), tests=(node,))
    outcome = mutants.run_mutant(wrong)
    assert not outcome.error, outcome.error
    assert outcome.killed_by == "tests" and "test_a_web_scheme" in outcome.rejected_by["tests"]
    null = dataclasses.replace(wrong, new=wrong.old)
    assert mutants.run_mutant(null).rejected_by == {"tests": ""}


@pytest.fixture(scope="module")
def outcomes():
    return {o.mutant.name: o for o in mutants.run_catalogue(BUILTIN, jobs=2)}


@pytest.mark.parametrize("name", [m.name for m in BUILTIN])
def test_mutant_is_rejected(outcomes, name):
    outcome = outcomes[name]
    assert not outcome.error, outcome.error
    if not outcome.killed and outcome.mutant.expect_killed_after:
        pytest.xfail(f"survives until: {outcome.mutant.expect_killed_after}")
    assert outcome.killed, f"{name} survived conformance, stress and budgets: {outcome.rejected_by}"


def test_selftest_lists_the_catalogue(capsys):
    assert main(["selftest", "--list"]) == 0
    listed = capsys.readouterr().out
    assert all(m.name in listed for m in BUILTIN)
    assert main(["selftest", "--mutant", "no-such-bug"]) == 2
