"""Equal-time cells (``--time-budget-ms``): calibrate an estimator's frame time against spp.

The measure is the cell time of :mod:`iblbench.harness.protocol.timing`: device time per frame of build
+ sample + shade.  The frame's build does not depend on spp, so it enters the fit's intercept:
the calibration adds the frame's build time (``build_ms``) to every timed render.  A
budget below the build alone cannot be met by any spp.

For one (scene, estimator) the runner times renders on the scene's first frame to run, just before
its first equal-time cell (``CALIBRATION_REPEATS`` per spp, on seeds no cell uses, through the
same :func:`~iblbench.harness.protocol.timing.timed_renders` as a cell's repeats) at ``CALIBRATION_SPP``,
then at larger spp until the calibrated range brackets the choice; the ``CALIBRATION_SPP`` are
timed in interleaved rounds (one render of each a round), so that their line is not drawn
through one slow spell and one fast one.  Each spp's robust time (the median,
:func:`~iblbench.harness.protocol.timing.robust_ms`) is fitted as ``a + b·spp`` by least squares on
relative error, and the first choice is the largest spp whose predicted time is within the budget.
A line fitted from 1 to hundreds of spp misses by more than 10% where the cost is not quite
linear, so the choice is then refined on measurements: the spp chosen is timed, the per-spp slope
is re-estimated as the median slope through the points the refinement has timed (keeping the
intercept), and the largest spp predicted to fit is timed again, up to ``REFINE_STEPS`` times,
until the measured time lies within half of ``TOLERANCE`` of the budget (so that the cells' own
noise keeps them within it) (:func:`corrected_spp`). The spp run is then chosen among the
measured ones (:func:`best_measured`). The runner takes up to ``CELL_CORRECTIONS`` more such
steps on the time of the budget's first cell (its renders back to back on its own seeds, before
the frame's rounds), and again ends on the best of the cell's measured spp
(:mod:`iblbench.harness.protocol.runner`, "Equal time"). Whether the
cells then landed within ``TOLERANCE`` is checked on the cells themselves (the runner's
``time_budget.achieved``).

Why the median slope and the best measured point, not the last step: the device switches
between slow and fast spells lasting tens to hundreds of renders (:mod:`iblbench.harness.protocol.timing`,
up to 1.5x apart under load), so a step through one point measured in a slow spell undershoots
in the next fast one.  Seen in a warm idle run (budget 5 ms): blob-sun ``balanced`` measured
7.6 ms at 479 spp (4.7 ms in calibration), stepped to 281 spp (5.8 ms, still slow), then to 231
spp, which ran at 2.6 ms (-48%); sphere-backlit ``uniform`` went from 4.7 ms at 460 spp (-6%,
within the tolerance but not half of it) through 5.6 ms at 502 to 6.6 ms at 431 (+32%), and the
last step was the cell.
"""
from __future__ import annotations

import math

import numpy as np

from iblbench.harness.protocol.timing import device_ms, robust_ms, timed_renders

CALIBRATION_SEED = 0xFFFFFF00   # + repeat index: seeds no benchmark cell uses
CALIBRATION_SPP = (1, 4, 16, 64)
CALIBRATION_REPEATS = 3
BUDGET_MAX_SPP = 32767     # the most spp an equal-time cell may choose (the pool estimators' limit)
TOLERANCE = 0.10           # a cell's time should land within ±10% of its budget
REFINE_STEPS = 4
CELL_CORRECTIONS = 2      # steps of corrected_spp on the first cell of a budget (the runner)


def fit_linear(runs: dict[int, list[float]]) -> tuple[float, float]:
    """Least squares of median time ≈ a + b·spp on relative error; a ≥ 0, b > 0."""
    spp = np.array(sorted(runs), float)
    t = np.array([robust_ms(runs[int(s)]) for s in spp], float)
    t = np.maximum(t, 1e-6)
    (a, b), *_ = np.linalg.lstsq(np.stack([1 / t, spp / t], axis=1), np.ones_like(t), rcond=None)
    if a < 0:   # noise at low spp: a line through the origin instead
        a, b = 0.0, float(np.sum(spp / t) / np.sum((spp / t) ** 2))
    return float(a), float(max(b, 1e-12))


def choose_spp(a: float, b: float, budget_ms: float, limit: int = BUDGET_MAX_SPP) -> int:
    """The largest spp in [1, ``limit``] whose predicted time a + b·spp is ≤ the budget (1 when
    even one sample is predicted over it)."""
    return int(max(1, min(limit, math.floor((budget_ms - a) / b + 1e-9))))


def spp_limit(cls) -> int:
    """The most spp an equal-time cell of estimator class ``cls`` may choose: BUDGET_MAX_SPP, or
    the estimator's own ``max_spp`` where that is lower (bis, smc)."""
    return min(BUDGET_MAX_SPP, cls.max_spp or BUDGET_MAX_SPP)


class Calibration:
    """Timed renders of one (scene, estimator) on one frame, shared by every budget.

    ``build_ms``: the frame's build time for this estimator (added to each render); ``limit``:
    the most spp it may choose, BUDGET_MAX_SPP or the estimator's own ``max_spp``."""

    def __init__(self, estimator, gbuffer, cache, build_ms: float = 0.0):
        self.estimator, self.gbuffer, self.cache = estimator, gbuffer, cache
        self.build_ms = build_ms
        self.limit = spp_limit(type(estimator))
        self.runs: dict[int, list[float]] = {}
        self.host: dict[int, list[float]] = {}
        self.renders = []   # every TimedRender, for the run's device-time total

    def measure(self, *spps: int) -> float:
        """Time ``CALIBRATION_REPEATS`` renders at each of ``spps`` not timed yet, in
        interleaved rounds (one render per spp a round, so each spp's renders fall in different
        spells of the device, as a cell's do); the robust time of the last spp's renders."""
        todo = [spp for spp in dict.fromkeys(spps) if spp not in self.runs]
        for repeat in range(CALIBRATION_REPEATS):
            for spp in todo:
                [(_, render)] = timed_renders([self.estimator], self.gbuffer, self.cache, spp,
                                              [CALIBRATION_SEED + repeat], self.build_ms)
                self.renders.append(render)
                self.runs.setdefault(spp, []).append(device_ms(render.stages))
                self.host.setdefault(spp, []).append(render.host_ms)
        return float(robust_ms(self.runs[spps[-1]]))

    def choose(self, budget_ms: float) -> dict:
        self.measure(*CALIBRATION_SPP)
        a, b = fit_linear(self.runs)
        chosen = choose_spp(a, b, budget_ms, self.limit)
        for _ in range(10):   # extend the calibrated range until it brackets the choice
            top = max(self.runs)
            if chosen <= 2 * top or top >= self.limit:
                break
            self.measure(min(chosen, 4 * top, self.limit))
            a, b = fit_linear(self.runs)
            chosen = choose_spp(a, b, budget_ms, self.limit)
        fitted, refined = chosen, {}
        for _ in range(REFINE_STEPS):
            refined[chosen] = self.measure(chosen)
            step = corrected_spp(a, refined, chosen, budget_ms, self.limit)
            if step is None or step in self.runs:
                break
            chosen = step
        medians = {s: float(robust_ms(v)) for s, v in self.runs.items()}
        chosen = best_measured(medians, budget_ms)
        return {"budget_ms": budget_ms, "build_ms": self.build_ms, "limit": self.limit,
                "a_ms": a, "b_ms_per_spp": b,
                "fitted_spp": fitted, "chosen_spp": chosen, "predicted_ms": a + b * chosen,
                "measured_ms": medians[chosen], "over_budget": medians[chosen] > budget_ms,
                "runs": [{"spp": s, "device_ms": self.runs[s], "host_frame_ms": self.host[s],
                          "median_device_ms": medians[s]} for s in sorted(self.runs)]}


def corrected_spp(a: float, measured: dict[int, float], spp: int, budget_ms: float,
                  limit: int = BUDGET_MAX_SPP) -> int | None:
    """One refinement step after the median time ``measured[spp]``: None when it is already
    within half of ``TOLERANCE`` of the budget (so that noise keeps the cells within it) or at
    most the intercept ``a``; else the largest spp predicted within the budget by ``a`` and a
    per-spp slope that is the median of (time − a)/spp over every point of this refinement
    (``measured``: spp → median ms), so that one measurement in a slow or fast spell of the
    device (module docstring) is not chased on its own."""
    if abs(measured[spp] - budget_ms) <= TOLERANCE / 2 * budget_ms or measured[spp] <= a:
        return None
    slopes = [(ms - a) / s for s, ms in measured.items() if ms > a]
    return choose_spp(a, float(np.median(slopes)), budget_ms, limit)


def best_measured(medians: dict[int, float], budget_ms: float) -> int:
    """The spp to run, from measured median times per spp: among those within ``TOLERANCE`` of
    the budget the largest within it, else the one nearest it; with none within tolerance, the
    largest spp within the budget, else the cheapest spp (even that is over the budget)."""
    near = [s for s, t in medians.items() if abs(t - budget_ms) <= TOLERANCE * budget_ms]
    under = [s for s in near if medians[s] <= budget_ms]
    if under:
        return max(under)
    if near:
        return min(near, key=medians.get)
    under = [s for s, t in medians.items() if t <= budget_ms]
    return max(under) if under else min(medians, key=medians.get)
