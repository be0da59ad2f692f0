"""Documented import path of the conformance suite (docs/writing-an-estimator.md): ``check_estimator`` and the rest
live in :mod:`iblbench.harness.verify.conformance`."""
from iblbench.harness.verify.conformance import *  # noqa: F401,F403
from iblbench.harness.verify.conformance import check_estimator, parametrize_with_checks  # noqa: F401
