"""Equal-time cells (``--time-budget-ms``): calibrate an estimator's frame time against spp.

For one (scene, estimator) the runner times renders on the scene's first frame to run (after a
warm-up; ``CALIBRATION_REPEATS`` per spp, on seeds no cell uses) at ``CALIBRATION_SPP``, then at
larger spp until the calibrated range brackets the choice.  The measure is the median device
time of the ``sample`` and ``shade`` stages (OpenCL profiling events: the estimator's per-frame
cost, without per-frame builds such as CDFs, host read-back or compilation), fitted as
``a + b·spp`` by least squares on relative error; the chosen spp is the largest whose predicted
time is within the budget.
"""
from __future__ import annotations

import math
import time

import numpy as np

CALIBRATION_SEED = 0xFFFFFF00   # + repeat index: seeds no benchmark cell uses
CALIBRATION_SPP = (1, 4, 16, 64)
CALIBRATION_REPEATS = 3
BUDGET_MAX_SPP = 32767     # the most spp an equal-time cell may choose (the pool estimators' limit)


def fit_linear(runs: dict[int, list[float]]) -> tuple[float, float]:
    """Least squares of median time ≈ a + b·spp on relative error; a ≥ 0, b > 0."""
    spp = np.array(sorted(runs), float)
    t = np.array([np.median(runs[int(s)]) for s in spp], float)
    t = np.maximum(t, 1e-6)
    (a, b), *_ = np.linalg.lstsq(np.stack([1 / t, spp / t], axis=1), np.ones_like(t), rcond=None)
    if a < 0:   # noise at low spp: a line through the origin instead
        a, b = 0.0, float(np.sum(spp / t) / np.sum((spp / t) ** 2))
    return float(a), float(max(b, 1e-12))


def choose_spp(a: float, b: float, budget_ms: float) -> int:
    """The largest spp in [1, BUDGET_MAX_SPP] whose predicted time a + b·spp is ≤ the budget
    (1 when even one sample is predicted over it)."""
    return int(max(1, min(BUDGET_MAX_SPP, math.floor((budget_ms - a) / b + 1e-9))))


class Calibration:
    """Timed renders of one (scene, estimator) on one frame, shared by every budget."""

    MEASURE = "device time of the sample and shade stages (OpenCL profiling events), ms"

    def __init__(self, estimator, gbuffer, cache):
        self.estimator, self.gbuffer, self.cache = estimator, gbuffer, cache
        self.runs: dict[int, list[float]] = {}
        self.host: dict[int, list[float]] = {}

    def measure(self, spp: int) -> None:
        device, host = [], []
        for repeat in range(CALIBRATION_REPEATS):
            start = time.perf_counter()
            estimate = self.estimator.render(self.gbuffer, self.cache, spp, CALIBRATION_SEED + repeat)
            host.append((time.perf_counter() - start) * 1e3)
            device.append(device_ms(estimate))
        self.runs[spp], self.host[spp] = device, host

    def choose(self, budget_ms: float) -> dict:
        for spp in CALIBRATION_SPP:
            if spp not in self.runs:
                self.measure(spp)
        a, b = fit_linear(self.runs)
        chosen = choose_spp(a, b, budget_ms)
        for _ in range(10):   # extend the calibrated range until it brackets the choice
            top = max(self.runs)
            if chosen <= 2 * top or top >= BUDGET_MAX_SPP:
                break
            self.measure(min(chosen, 4 * top, BUDGET_MAX_SPP))
            a, b = fit_linear(self.runs)
            chosen = choose_spp(a, b, budget_ms)
        return {"budget_ms": budget_ms, "a_ms": a, "b_ms_per_spp": b, "chosen_spp": chosen,
                "predicted_ms": a + b * chosen, "over_budget": a + b * chosen > budget_ms,
                "runs": [{"spp": s, "device_ms": self.runs[s], "host_frame_ms": self.host[s],
                          "median_device_ms": float(np.median(self.runs[s]))}
                         for s in sorted(self.runs)]}


def device_ms(estimate) -> float:
    """The estimator's device time of one frame: its sample and shade stages."""
    stages = [estimate.timings_ms.get(s, float("nan")) for s in ("sample", "shade")]
    return float(sum(v for v in stages if math.isfinite(v)))
