"""The one aggregation of iblbench: a cell's error as a mean with its 95% interval, its time as a
median with its 95% interval, and the ratio or difference of two cells with its interval and
p-value (issue 11, "Statistics a researcher can rely on"; issue 23, "Intervals that resolve with
few seeds").

**Replicates: every timed render is scored.**  A cell (one scene, estimator, spp or time budget,
and frame) renders each seed R times for its timing (``repeats``; render 0 with the cell's seed,
renders 1..R−1 with timing seeds no cell uses, each drawing its own samples), and every one of
those R renders is scored: a results row carries, beside the scored render's metrics, the ΔE76,
ΔE2000 and relMSE of each of its R planned renders (``<metric>_renders``, :func:`renders_text`;
renders added only because the timing spread was wide are timed, not scored, so the count never
depends on the machine).  A *replicate* is one (seed, render) pair: its value is the render's
metric, averaged over the cell's frames when there are several (render r of a seed follows the
same seeds through every frame, and a temporal estimator's twin r carries its own state), so
replicates are independent draws of the cell's error at its spp, and S seeds give S·R of them.

**A cell's error** is the mean over its replicates with a two-sided Student-t interval,
:func:`mean_ci`::

    mean ± t(0.975, n − 1) · s / √n          s: the sample standard deviation (ddof = 1)

corrected for the replicates' skewness as Hall (1992) does (:func:`skew_corrected_ci`: a
relMSE over renders is skewed to the right, and the plain interval missed it on the high side).
One seed gives R replicates and an interval; seeds add replicates.  It assumes the replicates
are independent draws (each render keys its own Philox stream) and that their mean is close to
normal, which holds for the means over pixels that the metrics are (``tests/test_coverage.py``
simulates the coverage).  This is batch means with a whole render at the cell's spp as the
batch, not a split of the cell's spp into smaller batches: a metric of a render at spp/B is not
a draw of the metric at spp (the error at spp/B is larger), and the metrics are not linear in
the image, so batches of one render would need a model of how each metric scales with spp.
Rows without replicates (older schemas, a metric left out) fall back to one value per seed.
With one value there is no interval: ``low`` and ``high`` are NaN and :attr:`MeanCI.resolved`
is False ("not resolved").

**A cell's time** is the median of every timed render of the cell (all seeds and frames, the
renders added for a wide spread included; ``time_ms_renders``) with a distribution-free 95%
interval for the median from order statistics, interpolated as Hettmansperger & Sheather (1986)
do, :func:`median_ci`.  It assumes only that the renders' times are independent draws of one
distribution (a steady device: the manifest's timing floor says how steady it was).  Below 6
renders no pair of order statistics reaches 95%: the interval is then the range, and its level
(50% at 2, 75% at 3, 87.5% at 4, 93.75% at 5) is carried in :attr:`MeanCI.level`.  The host
wall time (:data:`LOG_SCALE_COLUMNS`), one median per seed, is their geometric mean with the
t interval of their logarithms, :func:`geometric_mean_ci`: a positive, skewed duration, whose
plain t interval over two seeds reached below zero.

**Times are per device.**  A table may hold rows that several devices ran (the ``device``
column: a sweep spread over machines).  A time (``time_ms`` and every other time column of the
schema, :func:`is_time_column`) is never aggregated over rows of two devices (:func:`column_interval` refuses to), so every
figure of time is aggregated per device: :func:`by_device` splits a table by device, and
:func:`time_keys` adds ``device`` to an aggregation's keys, each only where the table holds
several devices, so a one-device table is aggregated as before.  Errors do not depend on the
device: the report pools them over devices (``run``'s tables and ``--json``, keyed by device
where several ran, give each device's).

**Two cells with the same replicates** (the same seeds and repeats: two runs of one sweep, or
two estimators of one run) are compared *paired*: the replicates are matched by (seed, render)
and the test is on their differences, :func:`ratio_ci` with ``paired=True``
(:func:`compare_values`); otherwise unpaired (Welch), which keeps every value of each side.

**The ratio of two cells** B/A, :func:`ratio_ci`, is the delta method on the log scale.
Unpaired, with Welch–Satterthwaite degrees of freedom::

    r = m_B / m_A,   v_X = s_X² / (n_X · m_X²)   (the relative variance of the mean)
    se = √(v_A + v_B),   df = (v_A + v_B)² / (v_A² / (n_A − 1) + v_B² / (n_B − 1))
    interval = r · exp(± t(0.975, df) · se)

Paired (n matched replicates), the same on the per-pair relative differences, so what the two
cells share (the same light pool, the same sun hit) cancels::

    z_i = b_i / m_B − a_i / m_A,   se = s_z / √n,   df = n − 1

and its p-value is the two-sided t-test of log r = 0 (``RatioCI.p``).  It is not Fieller's
interval: Fieller's is exact for normal means but is unbounded when the denominator's interval
contains 0; the log-scale interval is always positive and finite, and for the relative errors
of a benchmark (a few percent to about 30%) the two agree closely (tests/test_stats.py simulates
its coverage).  It needs both means positive; otherwise the ratio is undefined (NaN, with the
reason).  When both samples are constant (``se`` = 0: the same seeds of unchanged code give the
same quality figures) the interval is the point r.

**Significance** is one decision everywhere: a ratio is significant when its 95% interval
excludes 1 (:attr:`RatioCI.significant`, the same as p < 0.05), and two cells are ordered only
then.  :func:`separated` (intervals that do not overlap) remains for cells that share nothing.
Anything else is "not resolved".
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from scipy import stats as _scipy_stats

from iblbench.harness.protocol.metric import RENDERS

LEVEL = 0.95
MEAN_METHOD = ("mean over the cell's scored renders (every timed render of every seed), 95% "
               "Student-t interval with Hall's (1992) skewness correction")
SEED_METHOD = "mean over seeds, 95% Student-t interval"
MEDIAN_METHOD = ("median of the cell's timed renders (every seed and frame), 95% order-statistic "
                 "interval (Hettmansperger-Sheather)")
GEOMETRIC_METHOD = ("geometric mean of the cell's values, 95% Student-t interval of their "
                    "logarithms (a positive, right-skewed time: the interval stays positive)")
# Columns of positive, right-skewed durations: their intervals are taken on a log scale, where a
# t interval over two seeds gave a host wall time of 600 ± 1300 ms (issue 35).
LOG_SCALE_COLUMNS = ("time_ms_host",)
RATIO_METHOD = ("ratio of means B/A, 95% interval by the delta method on log(ratio): paired where "
                "both cells have the same (seed, render) replicates, else Welch-Satterthwaite")
TIME_COLUMN = "time_ms"       # the one column aggregated as a median (timing.TIME)
DEVICE_COLUMN = "device"      # the device that ran a row: times are aggregated per device
# A results row's time columns, in the schema's order (timing.time_columns writes them, the
# results schema lists them): each a figure of the device that ran the row.
TIME_COLUMNS = (TIME_COLUMN, "time_ms_min", "time_ms_iqr", "time_ms_build", "time_ms_sample",
                "time_ms_shade", "time_ms_host", "time_repeats", TIME_COLUMN + RENDERS)


def t_quantile(df: float, level: float = LEVEL) -> float:
    """The two-sided Student-t critical value: P(|T_df| ≤ t) = level."""
    return float(_scipy_stats.t.ppf(0.5 + level / 2, df))


@dataclasses.dataclass(frozen=True)
class MeanCI:
    """A cell's figure (a mean; for a time, the median) of ``n`` values and its interval (``low``,
    ``high``; NaN when n < 2) at ``level`` (below LEVEL only for a median of under 6 values)."""
    mean: float
    low: float
    high: float
    n: int
    sd: float
    level: float = LEVEL

    @property
    def resolved(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)

    @property
    def half_width(self) -> float:
        return (self.high - self.low) / 2

    def text(self, digits: int = 4) -> str:
        """``mean ± half-width``, ``mean [low, high]`` or ``mean (n=1, no interval)``
        (:func:`interval_text`)."""
        return interval_text(self.mean, self.half_width, self.n, digits, self.low, self.high)

    def to_dict(self) -> dict:
        return {"mean": _finite(self.mean), "low": _finite(self.low), "high": _finite(self.high),
                "n": self.n, "sd": _finite(self.sd), "level": self.level}


def mean_ci(values, level: float = LEVEL) -> MeanCI:
    """Mean of independent values with its Student-t interval; a NaN value makes every figure
    NaN."""
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


def geometric_mean_ci(values, level: float = LEVEL) -> MeanCI:
    """Geometric mean of independent positive values with the Student-t interval of their
    logarithms, exponentiated: positive, and asymmetric about its figure as a duration's
    spread is."""
    values = np.asarray(values, dtype=np.float64).ravel()
    logs = mean_ci(np.log(values), level)
    sd = float(values.std(ddof=1)) if values.size > 1 else math.nan
    return MeanCI(math.exp(logs.mean), math.exp(logs.low), math.exp(logs.high), logs.n, sd, level)


def skew_corrected_ci(values, level: float = LEVEL) -> MeanCI:
    """Mean of independent values with Hall's (1992) skewness-corrected Student-t interval.

    A relMSE over renders is skewed to the right (a render that hits a sun-lit texel in few
    pixels has a large error), and the plain t interval then misses the mean on its high side:
    in 2000 simulated runs of 10 replicates it held the true relMSE of uniform at 16 spp in 85-87%
    of runs.  Hall's transformation of the Studentised mean T = √n(x̄ − μ)/s, with γ the
    replicates' skewness, a = γ/(3√n) and b = γ/(6√n),

        g(T) = ((1 + a·T)³ − 1)/(3a) + b,   monotone, with g⁻¹(y) = (∛(1 + 3a(y − b)) − 1)/a,

    is close to symmetric, so μ ∈ [x̄ − s·g⁻¹(q)/√n, x̄ − s·g⁻¹(−q)/√n], q = t(0.975, n − 1).
    γ = 0 gives the plain t interval.  ``tests/test_coverage.py`` has the coverage."""
    values = np.asarray(values, dtype=np.float64).ravel()
    plain = mean_ci(values, level)
    if not plain.resolved or plain.sd == 0:
        return plain
    n, mean = values.size, plain.mean
    centred = values - mean
    gamma = float(np.mean(centred ** 3) / np.mean(centred ** 2) ** 1.5)
    a, b = gamma / (3 * math.sqrt(n)), gamma / (6 * math.sqrt(n))
    q = t_quantile(n - 1, level)

    def inverse(y: float) -> float:
        return y - b if abs(a) < 1e-12 else (float(np.cbrt(1 + 3 * a * (y - b))) - 1) / a

    scale = plain.sd / math.sqrt(n)
    return MeanCI(mean, mean - scale * inverse(q), mean - scale * inverse(-q), n, plain.sd)


def median_ci(values, level: float = LEVEL) -> MeanCI:
    """The median of independent values (in ``MeanCI.mean``) with a distribution-free interval
    from order statistics (module docstring).  [X(k), X(n+1−k)] covers the median with
    probability γ_k = 1 − 2·P(Bin(n, ½) ≤ k − 1); with k the largest index where γ_k ≥ level,
    Hettmansperger & Sheather (1986) interpolate towards [X(k+1), X(n−k)] by
    λ = (n − k)·I / (k + (n − 2k)·I), I = (γ_k − level) / (γ_k − γ_{k+1}).  Where even the
    range (k = 1) is below ``level``, the range is the interval and γ_1 its level."""
    values = np.sort(np.asarray(values, dtype=np.float64).ravel())
    n = values.size
    if n == 0:
        raise ValueError("median_ci of no values")
    median = float(np.median(values))
    if n < 2 or not np.isfinite(values).all():
        return MeanCI(median, math.nan, math.nan, n, math.nan)
    coverage = _order_coverage(n)
    if coverage[0] < level:
        return MeanCI(median, float(values[0]), float(values[-1]), n, math.nan, coverage[0])
    k = max(i + 1 for i, gamma in enumerate(coverage) if gamma >= level)
    if 2 * k >= n:   # X(k+1) would pass X(n−k): nothing to interpolate towards
        return MeanCI(median, float(values[k - 1]), float(values[n - k]), n, math.nan, level)
    share = (coverage[k - 1] - level) / (coverage[k - 1] - coverage[k])
    weight = (n - k) * share / (k + (n - 2 * k) * share)
    low = (1 - weight) * values[k - 1] + weight * values[k]
    high = (1 - weight) * values[n - k] + weight * values[n - k - 1]
    return MeanCI(median, float(low), float(high), n, math.nan, level)


@functools.lru_cache(maxsize=None)
def _order_coverage(n: int) -> tuple[float, ...]:
    """γ_1, γ_2, …: the probability that [X(k), X(n+1−k)] holds the median of n values."""
    binomial = _scipy_stats.binom(n, 0.5)
    return tuple(1.0 - 2.0 * float(binomial.cdf(k - 1)) for k in range(1, n // 2 + 2))


@dataclasses.dataclass(frozen=True)
class RatioCI:
    """B/A with its interval and p-value; ``low``/``high`` NaN, and ``reason`` saying why, when
    there is none.  ``paired``: whether matched replicates made it."""
    ratio: float
    low: float
    high: float
    df: float
    reason: str = ""
    p: float = math.nan
    paired: bool = False

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
                "significant": self.significant, "p": _finite(self.p), "paired": self.paired,
                "reason": self.reason or None}


def ratio_ci(a, b, level: float = LEVEL, paired: bool = False) -> RatioCI:
    """mean(b) / mean(a) with its interval (module docstring); ``paired``: ``a`` and ``b`` are
    matched replicates (equal lengths, the i-th of each from the same seed and render)."""
    a, b = (np.asarray(x, dtype=np.float64).ravel() for x in (a, b))
    if paired and a.size != b.size:
        raise ValueError("paired samples of different sizes")
    mean_a, mean_b = float(a.mean()), float(b.mean())
    if not (math.isfinite(mean_a) and math.isfinite(mean_b)):
        return RatioCI(math.nan, math.nan, math.nan, math.nan, "NaN values")
    if mean_a <= 0 or mean_b <= 0:
        return RatioCI(math.nan, math.nan, math.nan, math.nan, "a mean is not positive")
    ratio = mean_b / mean_a
    if min(a.size, b.size) < 2:
        return RatioCI(ratio, math.nan, math.nan, math.nan, "n=1: no interval")
    if paired:
        total = float(np.var(b / mean_b - a / mean_a, ddof=1)) / a.size
        df = a.size - 1.0
    else:
        var_a = a.var(ddof=1) / (a.size * mean_a ** 2)
        var_b = b.var(ddof=1) / (b.size * mean_b ** 2)
        total = var_a + var_b
        df = (total ** 2 / (var_a ** 2 / (a.size - 1) + var_b ** 2 / (b.size - 1))
              if total > 0 else math.inf)
    if total == 0:
        return RatioCI(ratio, ratio, ratio, math.inf, p=0.0 if ratio != 1 else 1.0, paired=paired)
    se = math.sqrt(total)
    spread = math.exp(t_quantile(df, level) * se)
    p = float(2 * _scipy_stats.t.sf(abs(math.log(ratio)) / se, df))
    return RatioCI(ratio, ratio / spread, ratio * spread, float(df), p=p, paired=paired)


def renders_text(values) -> str:
    """A row's per-render values of one metric as stored (``"0.5123 0.4987 …"``, 7 digits)."""
    return " ".join(f"{float(value):.7g}" for value in values)


def renders_values(text) -> np.ndarray:
    """The values :func:`renders_text` stored; empty for a missing or empty entry."""
    if not isinstance(text, str) or not text.strip():
        return np.empty(0)
    return np.array(text.split(), dtype=np.float64)


def replicates(rows, column: str):
    """The cell's replicates of ``column`` (module docstring): a pandas Series indexed by
    (seed, render), each the mean over the cell's frames of that render's value; renders a seed
    lacks in some frame are left out.  None where a row has no per-render values (then the cell
    has one value per seed, :func:`seed_values`)."""
    import pandas as pd

    name = column + RENDERS
    if name not in rows.columns:
        return None
    values = [renders_values(text) for text in rows[name]]
    if any(v.size == 0 for v in values):
        return None
    chains = {}
    for seed, group in pd.Series(values, index=rows["seed"].to_numpy()).groupby(level=0, sort=True):
        depth = min(v.size for v in group)
        chains.update({(int(seed), r): value for r, value in
                       enumerate(np.mean([v[:depth] for v in group], axis=0))})
    return pd.Series(chains, dtype=np.float64)


def seed_values(rows, column: str):
    """Per seed, the mean of its rows' ``column`` (its frames; a NaN row makes it NaN: fail
    closed), as a Series indexed by (seed, 0)."""
    import pandas as pd

    per_seed = rows.groupby("seed", sort=True)[column].mean(skipna=False)
    return pd.Series(per_seed.to_numpy(), index=pd.MultiIndex.from_arrays(
        [per_seed.index.astype(int), np.zeros(len(per_seed), int)]), dtype=np.float64)


def cell_values(rows, column: str):
    """(values, method): the cell's replicates where its rows carry them, else its per-seed
    values (:func:`replicates`, :func:`seed_values`)."""
    chains = replicates(rows, column)
    return (chains, MEAN_METHOD) if chains is not None else (seed_values(rows, column), SEED_METHOD)


def column_interval(rows, column: str) -> tuple[MeanCI, str]:
    """One cell's figure of ``column`` with its interval, and the method that made it: the time
    (``TIME_COLUMN``) as :func:`median_ci` of every timed render where the rows carry them, any
    other figure over :func:`cell_values`: :func:`geometric_mean_ci` for
    :data:`LOG_SCALE_COLUMNS`, :func:`skew_corrected_ci` of replicates, :func:`mean_ci` of
    per-seed values.  A time of rows from several devices is a ValueError
    (module docstring: times are per device)."""
    if is_time_column(column) and len(devices(rows)) > 1:
        raise ValueError(f"{column} of rows from several devices ({', '.join(devices(rows))}): "
                         "times are aggregated per device")
    if column == TIME_COLUMN:
        times = render_times(rows)
        if times.size:
            return median_ci(times), MEDIAN_METHOD
    values, method = cell_values(rows, column)
    if column in LOG_SCALE_COLUMNS and (values > 0).all():
        return geometric_mean_ci(values.to_numpy()), GEOMETRIC_METHOD
    interval = skew_corrected_ci if method == MEAN_METHOD else mean_ci
    return interval(values.to_numpy()), method


def render_times(rows) -> np.ndarray:
    """Every timed render's device ms of a cell's rows (``time_ms_renders``); empty where a row
    lacks them (older schemas)."""
    times = [renders_values(text) for text in rows.get(TIME_COLUMN + RENDERS, ())]
    return np.concatenate(times) if times and all(t.size for t in times) else np.empty(0)


def compare_values(a, b) -> RatioCI:
    """B/A of two cells' values (Series indexed by replicate, :func:`cell_values`):
    :func:`ratio_ci` paired when both hold the same replicates (at least two), unpaired
    otherwise, where pairing a part would drop the rest's information."""
    if len(a) >= 2 and a.index.sort_values().equals(b.index.sort_values()):
        return ratio_ci(a.to_numpy(), b[a.index].to_numpy(), paired=True)
    return ratio_ci(a.to_numpy(), b.to_numpy())



def interval_text(mean: float, half_width: float, n: int, digits: int = 4,
                  low: float = math.nan, high: float = math.nan) -> str:
    """How every table shows a cell: ``mean ± half-width`` of its 95% interval, both rounded at
    the half-width's second significant digit (``3.0 ± 6.6``, ``5800 ± 4000``); ``mean (n=1, no
    interval)`` without one and ``–`` for a NaN mean.  A half-width below the mean's ``digits``-th
    significant digit is shown as 0 (equal values give a rounding-error spread, 1e-17).  An
    interval [``low``, ``high``] that stays positive while its half-width passes the mean (a
    time's, skewed) is shown as ``mean [low, high]``, each to two significant digits: ``± `` would
    reach below zero."""
    if not math.isfinite(mean):
        return "–"
    if not math.isfinite(half_width):
        return f"{mean:.{digits}g} (n={n}, no interval)"
    if half_width <= abs(mean) * 10.0 ** -digits:
        return f"{mean:.{digits}g} ± 0"
    if half_width > abs(mean) and low >= 0:
        return f"{_two_digits(mean)} [{_two_digits(low)}, {_two_digits(high)}]"
    place = math.floor(math.log10(half_width)) - 1
    decimals = max(-place, 0)
    mean = round(mean, -place) + 0.0            # + 0.0: no "-0.0"
    return f"{mean:.{decimals}f} ± {round(half_width, -place):.{decimals}f}"


def _two_digits(value: float) -> str:
    """``value`` at two significant digits, without an exponent (``7000``, ``0.48``)."""
    if value == 0:
        return "0"
    place = math.floor(math.log10(abs(value))) - 1
    return f"{round(value, -place) + 0.0:.{max(-place, 0)}f}"


def cell_intervals(table, keys, columns):
    """The cells of a results table with each column's figure and interval
    (:func:`column_interval`: errors over the cell's replicates, the time as a median of its
    timed renders).  A pandas DataFrame indexed by ``keys`` with, per column ``c``, ``c`` (the
    figure), ``c_low``, ``c_high``, ``c_half`` (NaN without an interval), ``c_n`` (how many
    values) and ``c_method``; and ``seeds`` (how many)."""
    import pandas as pd

    keys, columns = list(keys), list(columns)
    cells = {}
    for key, rows in table.groupby(keys, sort=False):
        cell = {"seeds": int(rows["seed"].nunique())}
        for column in columns:
            ci, method = column_interval(rows, column)
            cell.update({column: ci.mean, f"{column}_low": ci.low, f"{column}_high": ci.high,
                         f"{column}_half": ci.half_width, f"{column}_n": ci.n,
                         f"{column}_method": method})
        cells[key if len(keys) > 1 else (key[0] if isinstance(key, tuple) else key)] = cell
    frame = pd.DataFrame.from_dict(cells, orient="index")
    index = (pd.MultiIndex.from_tuples(list(cells), names=keys) if len(keys) > 1
             else pd.Index(list(cells), name=keys[0]))
    frame.index = index
    return frame


def is_time_column(column: str) -> bool:
    """Whether ``column`` is one of the results schema's time columns (:data:`TIME_COLUMNS`): a
    figure of the device that ran the row, never aggregated over devices (module docstring).
    Read from the schema, not the name, so that a time column added to it is one here too."""
    return column in TIME_COLUMNS


def devices(table) -> list[str]:
    """The devices that ran ``table``'s rows, in the order they first appear ([] without a
    ``device`` column)."""
    if DEVICE_COLUMN not in table:
        return []
    return list(dict.fromkeys(table[DEVICE_COLUMN].dropna()))


def by_device(table) -> list[tuple[str | None, object]]:
    """``table`` split by device for a figure of time: ``[(None, table)]`` where at most one
    device ran its rows (a one-device table is shown as a whole, unnamed, as before), else
    ``(device, its rows)`` per device in the order they first appear."""
    names = devices(table)
    if len(names) < 2:
        return [(None, table)]
    return [(name, table[table[DEVICE_COLUMN] == name]) for name in names]


def time_keys(table, keys) -> list[str]:
    """``keys`` with ``device`` added where several devices ran ``table``'s rows: an aggregation
    of times by these keys never pools two devices."""
    return [*keys, DEVICE_COLUMN] if len(devices(table)) > 1 else list(keys)


def separated(a: MeanCI, b: MeanCI) -> bool:
    """Whether the two intervals do not overlap (both resolved): the only case in which an
    ordering of the two cells is called."""
    return a.resolved and b.resolved and (a.high < b.low or b.high < a.low)


def _finite(value: float):
    """``value`` for JSON: None where it is not finite."""
    return float(value) if math.isfinite(value) else None
