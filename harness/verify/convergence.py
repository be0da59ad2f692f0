"""Convergence flatter than an estimator's tags allow (issue 11, "Statistics"), or not resolved
by the run's seeds (issue 34).

Between two consecutive spp levels a < b of a (scene, estimator) cell, an error E should fall
as a power of the budget: E_b / E_a ≈ (b/a)^slope.  The ideal Monte Carlo slope of an RMS-like
error is −½, and of a squared error −1.

**The error judged is relMSE** (``METRICS``): a fixed per-pixel weighting of squared errors in
linear HDR, so an unbiased estimator's expected relMSE is its variance over spp, exactly −1
whatever the budget.  Mean ΔE76 has no such law: it is taken after exposure, Reinhard's tone
map and Lab, which saturate a large error, so it falls slower at low spp (uniform on
sphere-switch, 48×48, env 16, 3 seeds: ΔE76 6.8 → 5.5 from 4 to 16 spp, slope −0.15, while
its relMSE fell 0.90 → 0.36, slope −0.65), and a warning there would speak of the tone map,
not of the estimator.  An estimator whose error is heavy-tailed (a sun that few samples find)
can fall slower than −1 before enough samples find the bright texels even in relMSE; that is
worth the warning too, since its numbers at those spp are not yet Monte Carlo's.

**The flattest slope the tags allow** follows the conformance suite
(:mod:`iblbench.harness.verify.conformance`): ``check_convergence`` (``Tags.unbiased``) and
``check_error_falls`` (not unbiased, on a static map, where the error must go to zero with the
budget) both accept an RMS error that falls at least ``MIN_ERROR_FALL_8_TO_128`` = 2.5× over 16×
the samples, a slope of −log 2.5 / log 16 ≈ −0.33 (ideal −½); relMSE, a squared error, gets twice
that, −0.66 (ideal −1).  This applies to

- an unbiased estimator (``tags.unbiased``), on any scene;
- an estimator that is not unbiased, on a static scene (one frame), or one that is not temporal
  on any scene (each frame is then a static problem of its own);

and a temporal estimator that is not unbiased, on a sequence, may level off at the bias its
state carries from frame to frame (havran's filter lag does not shrink with the budget), so its
flattest allowed slope is 0: it is flagged only when its error rises.  So may an estimator that
converges to a stated limit instead of the exact integral (``tags.has_limit``: fis's filtered
map, held to that limit by ``check_consistent_limit``), on any scene.

**The test.**  Each seed's error is its mean over the cell's frames (as in
:func:`iblbench.harness.protocol.stats.cell_intervals`); the ratio of the mean over seeds at b to that at
a gets a 95% interval on log(ratio) (:func:`step_interval`), the wider of two: the step's own
(:func:`iblbench.harness.protocol.stats.ratio_ci`, from the two levels' seeds alone) and one from
the cell's seed-to-seed spread pooled over all its spp levels (each seed's error relative to its
level's mean, Σ(n − 1) degrees of freedom).  Seed-to-seed variation is largely the cell's own (a
seed's shared light pool is good or bad at every spp), and two or three seeds that agree by
chance at one step give a narrow interval there that the other levels' seeds contradict: at 2
seeds balanced_mis was called flat where 8 seeds show it falling ×45 over 64×, each 4× step
±40–60% (issue 34).  Pooling widens such an interval, and leaves it narrow where every level's
seeds agree.

A step is reported only where its mean falls less than the allowed ratio (b/a)^slope:

- **not converging** where the whole interval lies above the allowed ratio (the intervals say
  the convergence is flatter than the tags allow);
- **not resolved at N seeds** where the interval reaches down to the allowed ratio, or there
  is none (one seed): the means look flat, and N seeds cannot tell.

``ratio_ci`` takes the two levels as independent samples; a run reuses its seeds at every spp,
and the two levels' errors of one seed are then positively correlated (they share random
streams), which makes the interval wider than needed: the test is conservative.  A cell whose
estimator is not registered here is not judged.  Equal-time cells (``time_budget_ms``) are
left out.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from iblbench.harness.protocol.metric import labels
from iblbench.harness.protocol.stats import RatioCI, ratio_ci, t_quantile
from iblbench.harness.protocol.sweep import estimator_tags

# The least fall of the RMS error over 16× the samples (8 → 128 spp) that the convergence checks
# accept (ideal 4 = √16): the conformance suite's and the benchmark cells' bound.  It lives here,
# not in the conformance suite, so that the report, which flags cells, loads no device.
MIN_ERROR_FALL_8_TO_128 = 2.5
# Error column → (name in messages, its power of an RMS-like error).
METRICS = {"rel_mse": (labels()["rel_mse"], 2)}
FLATTEST_RMS_SLOPE = -math.log(MIN_ERROR_FALL_8_TO_128) / math.log(16)


@dataclasses.dataclass(frozen=True)
class Allowance:
    """The flattest slope of an error against spp that an estimator's tags allow, and why."""
    slope: float
    ideal: float
    why: str


def allowance(tags, metric: str, sequence: bool) -> Allowance:
    """The flattest allowed slope of ``metric`` (a key of METRICS) for an estimator with
    ``tags`` on a static scene or a ``sequence`` (module docstring)."""
    power = METRICS[metric][1]
    ideal = -0.5 * power
    if sequence and tags.temporal and not tags.unbiased:
        return Allowance(0.0, ideal, "temporal and not unbiased, on a sequence: may level off "
                                     "at its bias, must not rise")
    if tags.has_limit and not tags.unbiased:
        return Allowance(0.0, ideal, "converges to a stated limit, not to the exact integral: "
                                     "may level off at its bias, must not rise")
    why = ("unbiased" if tags.unbiased else
           "not unbiased, on a static scene" if not sequence else "not unbiased, not temporal")
    return Allowance(power * FLATTEST_RMS_SLOPE, ideal, why)


def pooled_spread(per_seed: pd.Series) -> tuple[float, int]:
    """The cell's relative seed-to-seed variance, pooled over its spp levels: Σ (x/x̄_spp − 1)²
    / Σ (n_spp − 1) over the per-seed errors ``per_seed`` (indexed by spp and seed), and its
    degrees of freedom (0: no level has two seeds, NaN variance)."""
    levels = per_seed.groupby(level="spp")
    dof = int((levels.size() - 1).sum())
    relative = per_seed / levels.transform("mean") - 1
    return (float((relative ** 2).sum()) / dof if dof else math.nan), dof


def step_interval(before: np.ndarray, after: np.ndarray, spread: tuple[float, int]) -> RatioCI:
    """mean(after)/mean(before) with the wider of its own interval (``ratio_ci``) and the one
    the cell's pooled relative seed variance ``spread`` (:func:`pooled_spread`) gives."""
    own = ratio_ci(before, after)
    variance, dof = spread
    if not own.resolved or not dof:
        return own
    half = t_quantile(dof) * math.sqrt(variance * (1 / len(before) + 1 / len(after)))
    if half <= math.log(own.high / own.ratio):
        return own
    return RatioCI(own.ratio, own.ratio * math.exp(-half), own.ratio * math.exp(half), float(dof))


@dataclasses.dataclass(frozen=True)
class Flag:
    """One step between spp levels whose mean error fell less than the tags allow: not
    converging, or not resolved (module docstring)."""
    scene: str
    estimator: str
    metric: str
    spp_low: int
    spp_high: int
    low: float             # the mean error over seeds at spp_low …
    high: float            # … and at spp_high
    ratio: RatioCI         # high / low with its 95% interval (step_interval)
    allowed: Allowance
    seeds: int             # seeds at the level with fewer

    @property
    def allowed_ratio(self) -> float:
        return (self.spp_high / self.spp_low) ** self.allowed.slope

    @property
    def not_converging(self) -> bool:
        """The whole interval lies above the allowed ratio; otherwise the step is not resolved."""
        return self.ratio.resolved and self.ratio.low > self.allowed_ratio

    @property
    def verdict(self) -> str:
        if self.not_converging:
            return "not converging"
        return f"not resolved at {self.seeds} seed{'s' if self.seeds != 1 else ''}"

    def text(self) -> str:
        name = METRICS[self.metric][0]
        return (f"{self.estimator} on {self.scene}: {self.verdict}: {name} {self.low:.3g} → "
                f"{self.high:.3g} from {self.spp_low} to {self.spp_high} spp, "
                f"×{self.ratio.text()}; its tags ({self.allowed.why}) allow at most "
                f"×{self.allowed_ratio:.3g} (slope "
                f"{self.allowed.slope:+.2f}, ideal {self.allowed.ideal:+.2f})")


def flatter_than_tags(table: pd.DataFrame) -> list[Flag]:
    """Every (scene, estimator, consecutive spp levels, metric) of a results table whose mean
    error falls less than the estimator's tags allow, each not converging or not resolved by
    the interval test of the module docstring."""
    if "time_budget_ms" in table:
        table = table[table.time_budget_ms.isna()]
    metrics = [m for m in METRICS if m in table]
    flags = []
    for (scene, label), rows in table.groupby(["scene", "estimator"], sort=False):
        tags = estimator_tags(label)
        if tags is None:
            continue
        sequence = rows.frame.nunique() > 1
        per_seed = rows.groupby(["spp", "seed"])[metrics].mean()
        levels = sorted(per_seed.index.get_level_values("spp").unique())
        for metric in metrics:
            spread = pooled_spread(per_seed[metric])
            allowed = allowance(tags, metric, sequence)
            for a, b in zip(levels, levels[1:]):
                before = per_seed.loc[a, metric].to_numpy()
                after = per_seed.loc[b, metric].to_numpy()
                ratio = step_interval(before, after, spread)
                if ratio.ratio > (b / a) ** allowed.slope:
                    flags.append(Flag(scene, label, metric, int(a), int(b), float(np.mean(before)),
                                      float(np.mean(after)), ratio, allowed,
                                      min(len(before), len(after))))
    return flags


__all__ = ["METRICS", "Allowance", "Flag", "allowance", "flatter_than_tags", "pooled_spread",
           "step_interval"]
