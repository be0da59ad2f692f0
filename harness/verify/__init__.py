"""Verification: the conformance suite and its fixtures, convergence, the stress battery, the
mutant catalogue, CDF precision, error budgets, run comparison, the NumPy twins, the portability
set and the doctor's engine.  It stands on ``protocol``, ``estimators`` and ``scenes``; it never
imports ``studies``, ``reports`` or the API."""
