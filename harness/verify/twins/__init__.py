"""Independent NumPy twins of estimators, written from the papers and not from the kernels, and
the cross-check of an estimator against its twin in distribution (:mod:`.crosscheck`).

An estimator declares its twin with the class attribute ``twin``: the dotted name of a module
whose ``sampler(shading, params, spp, seed)`` returns an object with ``render(env)`` (the
estimates ``[C, 3]`` of the next frame of every chain of ``shading``, a
:class:`.ghosh2006.Shading`) and a ``reinits`` count.  The conformance suite then runs
``check_matches_twin`` on it (harness/verify/conformance.py).
"""
