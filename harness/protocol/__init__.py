"""The benchmark protocol: the sweep, the runner, timing, equal time, metrics, the results store
and the statistics that aggregate every figure.  It stands on ``estimators`` (and their runtime)
and ``scenes``; it never imports ``verify``, ``studies``, ``reports`` or the API."""
