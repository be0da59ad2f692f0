"""The one aggregation of iblbench: the mean over seeds with its 95% interval, and the ratio of
two such means with its interval (issue 11, "Statistics a researcher can rely on").

**A cell's value** (one scene, estimator, spp or time budget, and frame) is the mean of its
rows over seeds, with a two-sided Student-t interval, :func:`mean_ci`::

    mean ± t(0.975, n − 1) · s / √n          s: the sample standard deviation (ddof = 1)

It assumes the seeds' values are independent draws (they are: each seed keys its own Philox
stream) and that their mean is close to normal, which holds for the means over pixels that the
metrics are.  With one seed there is no interval: ``low`` and ``high`` are NaN and
:attr:`MeanCI.resolved` is False ("not resolved at 1 seed").

**The ratio of two cells** B/A, from independent seeds, :func:`ratio_ci`, is the delta method
on the log scale with Welch–Satterthwaite degrees of freedom::

    r = m_B / m_A,   v_X = s_X² / (n_X · m_X²)   (the relative variance of the mean)
    se = √(v_A + v_B),   df = (v_A + v_B)² / (v_A² / (n_A − 1) + v_B² / (n_B − 1))
    interval = r · exp(± t(0.975, df) · se)

It is not Fieller's interval: Fieller's is exact for normal means but is unbounded when the
denominator's interval contains 0; the log-scale interval is always positive and finite, and
for the relative errors of a benchmark (a few percent to about 30%) the two agree closely
(tests/test_stats.py simulates its coverage).  It needs both means positive; otherwise the
ratio is undefined (NaN, with the reason).  When both samples are constant (``se`` = 0: the
same seeds of unchanged code give the same quality figures) the interval is the point r.

**Significance** is one decision everywhere: a ratio is significant when its 95% interval
excludes 1 (:attr:`RatioCI.significant`), and two cells are ordered only when their intervals
do not overlap (:func:`separated`; a conservative test: non-overlapping 95% intervals imply a
difference at well under 5%).  Anything else is "not resolved at N seeds".
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import stats as _scipy_stats

LEVEL = 0.95
MEAN_METHOD = "mean over seeds, 95% Student-t interval"
RATIO_METHOD = ("ratio of means B/A, 95% interval by the delta method on log(ratio) with "
                "Welch-Satterthwaite degrees of freedom")


def t_quantile(df: float, level: float = LEVEL) -> float:
    """The two-sided Student-t critical value: P(|T_df| ≤ t) = level."""
    return float(_scipy_stats.t.ppf(0.5 + level / 2, df))


@dataclasses.dataclass(frozen=True)
class MeanCI:
    """The mean of ``n`` values and its interval (``low``, ``high``; NaN when n < 2)."""
    mean: float
    low: float
    high: float
    n: int
    sd: float

    @property
    def resolved(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)

    @property
    def half_width(self) -> float:
        return (self.high - self.low) / 2

    def text(self, digits: int = 4) -> str:
        """``mean ± half-width``, or ``mean (n=1, no interval)``."""
        return interval_text(self.mean, self.half_width, self.n, digits)

    def to_dict(self) -> dict:
        return {"mean": _finite(self.mean), "low": _finite(self.low), "high": _finite(self.high),
                "n": self.n, "sd": _finite(self.sd)}


def mean_ci(values, level: float = LEVEL) -> MeanCI:
    """Mean over seeds with its Student-t interval; a NaN value makes every figure NaN."""
    values = np.asarray(values, dtype=np.float64).ravel()
    n = values.size
    if n == 0:
        raise ValueError("mean_ci of no values")
    mean = float(values.mean())
    if n < 2:
        return MeanCI(mean, math.nan, math.nan, n, math.nan)
    sd = float(values.std(ddof=1))
    half = t_quantile(n - 1, level) * sd / math.sqrt(n)
    return MeanCI(mean, mean - half, mean + half, n, sd)


@dataclasses.dataclass(frozen=True)
class RatioCI:
    """B/A with its interval; ``low``/``high`` NaN, and ``reason`` saying why, when there is none."""
    ratio: float
    low: float
    high: float
    df: float
    reason: str = ""

    @property
    def resolved(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)

    @property
    def significant(self) -> bool:
        """The interval excludes 1."""
        return self.resolved and (self.low > 1 or self.high < 1)

    def text(self) -> str:
        if not math.isfinite(self.ratio):
            return f"- ({self.reason})"
        if not self.resolved:
            return f"{self.ratio:.3f} ({self.reason})"
        return f"{self.ratio:.3f} [{self.low:.3f}, {self.high:.3f}]"

    def to_dict(self) -> dict:
        return {"ratio": _finite(self.ratio), "low": _finite(self.low),
                "high": _finite(self.high), "df": _finite(self.df),
                "significant": self.significant, "reason": self.reason or None}


def ratio_ci(a, b, level: float = LEVEL) -> RatioCI:
    """mean(b) / mean(a) of two independent samples with its interval (module docstring)."""
    a, b = (np.asarray(x, dtype=np.float64).ravel() for x in (a, b))
    mean_a, mean_b = float(a.mean()), float(b.mean())
    if not (math.isfinite(mean_a) and math.isfinite(mean_b)):
        return RatioCI(math.nan, math.nan, math.nan, math.nan, "NaN values")
    if mean_a <= 0 or mean_b <= 0:
        return RatioCI(math.nan, math.nan, math.nan, math.nan, "a mean is not positive")
    ratio = mean_b / mean_a
    if min(a.size, b.size) < 2:
        return RatioCI(ratio, math.nan, math.nan, math.nan, "n=1: no interval")
    var_a = a.var(ddof=1) / (a.size * mean_a ** 2)
    var_b = b.var(ddof=1) / (b.size * mean_b ** 2)
    total = var_a + var_b
    if total == 0:
        return RatioCI(ratio, ratio, ratio, math.inf)
    df = total ** 2 / (var_a ** 2 / (a.size - 1) + var_b ** 2 / (b.size - 1))
    spread = math.exp(t_quantile(df, level) * math.sqrt(total))
    return RatioCI(ratio, ratio / spread, ratio * spread, float(df))


def interval_text(mean: float, half_width: float, n: int, digits: int = 4) -> str:
    """How every table shows a cell: ``mean ± half-width`` of its 95% interval, both rounded at
    the half-width's second significant digit (``3.0 ± 6.6``, ``5800 ± 4000``); ``mean (n=1, no
    interval)`` without one and ``–`` for a NaN mean.  A half-width below the mean's ``digits``-th
    significant digit is shown as 0 (equal values give a rounding-error spread, 1e-17)."""
    if not math.isfinite(mean):
        return "–"
    if not math.isfinite(half_width):
        return f"{mean:.{digits}g} (n={n}, no interval)"
    if half_width <= abs(mean) * 10.0 ** -digits:
        return f"{mean:.{digits}g} ± 0"
    place = math.floor(math.log10(half_width)) - 1
    decimals = max(-place, 0)
    mean = round(mean, -place) + 0.0            # + 0.0: no "-0.0"
    return f"{mean:.{decimals}f} ± {round(half_width, -place):.{decimals}f}"


def cell_intervals(table, keys, columns):
    """The cells of a results table with :func:`mean_ci` of each column: per seed the mean of
    its rows (its frames; a NaN row makes it NaN: fail closed), then the mean over seeds and
    its interval.  A pandas DataFrame indexed by ``keys`` with, per column ``c``, ``c`` (the
    mean), ``c_low``, ``c_high`` and ``c_half`` (NaN with one seed), and ``seeds`` (how many)."""
    import pandas as pd

    keys, columns = list(keys), list(columns)
    per_seed = table.groupby(keys + ["seed"], sort=False)[columns].mean(skipna=False)
    cells = {}
    for key, seeds in per_seed.groupby(level=keys, sort=False):
        cell = {"seeds": len(seeds)}
        for column in columns:
            ci = mean_ci(seeds[column])
            cell.update({column: ci.mean, f"{column}_low": ci.low, f"{column}_high": ci.high,
                         f"{column}_half": ci.half_width})
        cells[key] = cell
    frame = pd.DataFrame.from_dict(cells, orient="index")
    index = pd.MultiIndex.from_tuples(list(cells), names=keys)
    frame.index = index if len(keys) > 1 else index.get_level_values(0)
    return frame


def separated(a: MeanCI, b: MeanCI) -> bool:
    """Whether the two intervals do not overlap (both resolved): the only case in which an
    ordering of the two cells is called."""
    return a.resolved and b.resolved and (a.high < b.low or b.high < a.low)


def _finite(value: float):
    """``value`` for JSON: None where it is not finite."""
    return float(value) if math.isfinite(value) else None
