"""``iblbench reproduce NAME``: re-run a paper's experiments on our scenes and judge its claims.

Each reproduction is one or more sweeps through the ordinary runner into one ``--out`` (so its
results table, manifest and images are those of ``iblbench run``), then an analysis that turns the
table into the paper's tables and plots and one verdict line per claim: holds, partly holds or does
not hold, with our numbers beside the paper's.  Scenes are not tuned to make a claim hold.

Every number is a cell's mean over seeds with its 95% Student-t interval
(:func:`iblbench.harness.protocol.stats.cell_intervals`), and a comparison in a claim is called only where
the intervals separate (:func:`iblbench.harness.protocol.stats.separated`), or, for a ratio of two cells,
where the ratio's interval (:func:`iblbench.harness.protocol.stats.ratio_ci`) lies wholly on one side of
the claim's bound; a claim that hangs on an unresolved comparison is "not resolved at N seeds"
(N: the fewest seeds of a cell).

Equal time.  A reproduction that compares at equal time first runs its cells at a fixed spp, then
takes one budget from them (:func:`equal_time_budget`: the slowest estimator's mean frame time
over the scenes, so that every estimator gets about that spp or more, and the budget follows the
device rather than a number of milliseconds fixed for one machine), and runs every estimator at
that budget through ``--time-budget-ms``'s machinery (:mod:`iblbench.harness.protocol.equal_time`).
A cell can still land off its budget (the calibration is checked, not forced: on a loaded
machine by tens of percent), so each seed's error is scaled to the budget before two estimators
are compared (:func:`budget_scaled_values`): in the noise regime an unbiased estimator's MSE
falls as 1/time and its ΔE as 1/√time, so relMSE × t/T and ΔE76 × √(t/T) (t: the seed's frame
time, T: the budget) are what the cell would have reached in exactly T; the tables show the
measured errors and times beside them.  The ratio of two estimators is computed from their
per-seed values; the two use the same seeds, and the interval treats them as independent, which
for positively correlated errors makes it wider, not narrower.
"""
from __future__ import annotations

import dataclasses
import math
import pathlib

import numpy as np
import pandas as pd

from iblbench.harness.protocol.run_plan import RunConfig
from iblbench.harness.protocol.runner import run
from iblbench.harness.protocol.stats import MeanCI, RatioCI, cell_intervals, ratio_ci, separated
from iblbench.harness.protocol.sweep import parse_estimator
from iblbench.harness.protocol.timing import TIME
from iblbench.foundation.errors import InputError

HOLDS, PARTLY, FAILS = "holds", "partly holds", "does not hold"
TIMES = (TIME, "time_ms_build", "time_ms_sample", "time_ms_shade")
ERRORS = ("mean_delta_e76", "rel_mse")
METRICS = ("de76", "relmse")   # what the claims use; HDR-FLIP (slow) and ΔE2000 are left out
# results column → the reproduction's name for it
COUNTS = {"used_samples": "used", "effective_samples": "effective"}


@dataclasses.dataclass
class Verdict:
    claim: str
    verdict: str
    ours: str
    paper: str


@dataclasses.dataclass
class Plot:
    """A figure of a section: ``kind`` names its drawing in
    :data:`iblbench.reports.reproduction.PLOTS`, which reads ``data``; ``lines``: labelled
    reference values (a ratio plot's 1 and the paper's figure)."""

    kind: str
    file: str
    alt: str
    data: pd.DataFrame
    lines: dict[str, float] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class Section:
    """One table of a reproduction (see :func:`_shown`), with its plot if it has one."""

    title: str
    table: pd.DataFrame
    plot: Plot | None = None


@dataclasses.dataclass
class Reproduction:
    """What a reproduction produced: the sections, verdicts and notes a report renders."""

    title: str
    setup_differences: list[str]
    sections: list[Section]
    verdicts: list[Verdict]
    results: pd.DataFrame


# ---- Lu, Pacanowski & Granier 2013 ------------------------------------------------------------------

LU2013_SCENES = ("sphere-sun", "blob-sun", "sphere-backlit")
LU2013_SPP = (15, 30, 60, 120, 180, 240)
LU2013_MIS_SPP = (15, 30, 60, 120, 240)
LU2013_ESTIMATORS = ("uniform", "balanced", "balanced_mis")
# The production baselines (issue 12), at the paper's 60 spp and at equal time.
LU2013_BASELINES = ("brdf", "envmap", 'envmap{mis="brdf"}')
# (Lu's estimator, the global 2-D distribution it is set against at equal time)
LU2013_EQUAL_TIME_PAIRS = (("balanced", "envmap"), ("balanced_mis", 'envmap{mis="brdf"}'))
LU2013_N = 60   # the paper's spp of Fig. 2 and of the claims, and the equal-time budget's
LU2013_SETUP_DIFFERENCES = [
    "Scenes are procedural (a sphere and a >100k-triangle displaced blob) lit by an analytic "
    "Preetham sun+sky at 64² per face; the paper used a 169K-polygon model under a captured "
    "256² per face environment (Fig. 2) and the Stumpfel et al. day capture (Fig. 1).",
    "Direct lighting without visibility, as in the paper (V is omitted there too).",
    "Errors are mean ΔE76 under protocol lab-reinhard-v1 against an exact reference; the paper "
    "does not state its tone mapping or reference for ΔE.",
    "Timings are OpenCL device times per frame (build + sample + shade, the median of a cell's "
    "timed renders, then the mean over seeds) on the machine's chosen device (see manifest), not "
    "a GTX 680 with CUDA/DirectX; only ratios within one run are compared.",
    "Every figure is the mean over seeds ± the half-width of its 95% Student-t interval; a "
    "claim is judged only on comparisons whose intervals separate.",
    "A backlit scene (low sun behind the sphere) is included because per-normal balancing "
    "should matter most there; it is not in the paper.",
    "The production baselines are not in the paper: brdf (Phong BRDF sampling only), envmap "
    "(one luminance × solid-angle 2-D distribution over the whole map, as pbrt-v4's "
    "ImageInfiniteLight and Cycles) and envmap{mis=\"brdf\"} (the same with half the samples "
    "from the BRDF, power heuristic, where balanced_mis uses the balance heuristic). They run "
    "at 60 spp, and every estimator runs at one equal-time budget: the slowest estimator's "
    "mean frame time at 60 spp over the scenes, to two digits, so that each gets about 60 spp "
    "or more (the paper compares at equal spp only). A cell "
    "can land off the budget, so claim 5 scales each seed's ΔE76 to it by its own frame time "
    "t, ΔE76 × √(t/T) (ΔE ∝ 1/√time in the noise regime); the measured ratio is beside it.",
]


def _cell_means(table: pd.DataFrame) -> pd.DataFrame:
    """Per (scene, estimator, spp) of ``table`` (spp cells, or one budget's cells): the mean
    errors, sample counts (``used``, ``effective``), effective ratio and each time column over
    seeds, with their intervals (``_low``, ``_high``, ``_half``) and ``seeds``
    (:func:`iblbench.harness.protocol.stats.cell_intervals`)."""
    cells = cell_intervals(table, ["scene", "estimator", "spp"],
                           [*ERRORS, *COUNTS, "effective_ratio", *TIMES]).reset_index()
    return cells.rename(columns={f"{name}{suffix}": f"{short}{suffix}"
                                 for name, short in COUNTS.items()
                                 for suffix in ("", "_low", "_high", "_half")})


def _ci(cells: pd.DataFrame, scene: str, estimator: str, spp: int, column: str) -> MeanCI:
    """The cell's ``column`` with its interval (NaN when the cell is missing)."""
    row = cells[(cells.scene == scene) & (cells.estimator == estimator) & (cells.spp == spp)]
    if not len(row):
        return MeanCI(float("nan"), float("nan"), float("nan"), 0, float("nan"))
    row = row.iloc[0]
    return MeanCI(float(row[column]), float(row[f"{column}_low"]), float(row[f"{column}_high"]),
                  int(row.seeds), float("nan"))


def _below(a: MeanCI, b: MeanCI) -> bool | None:
    """Whether a < b, called only where the intervals separate (None: not resolved)."""
    return a.mean < b.mean if separated(a, b) else None


def _judge(flags: list, seeds: int) -> str:
    """The verdict on per-scene results of the claim's stated test, True, False or None (not
    resolved): holds where every scene holds, partly where some resolved scene holds and another
    not, does not hold where every scene is resolved and none holds, else not resolved."""
    if flags and all(f is True for f in flags):
        return HOLDS
    if True in flags and False in flags:
        return PARTLY
    if flags and all(f is False for f in flags):
        return FAILS
    return f"not resolved at {seeds} seed{'s' if seeds != 1 else ''}"


def _time_for_quality(cells, scene, target_de, column: str = TIME) -> float:
    """Frame time uniform needs to reach ``target_de``: log-log interpolation of its ΔE(time)
    (``column``: the time column or one end of its interval)."""
    rows = cells[(cells.scene == scene) & (cells.estimator == "uniform")].sort_values("spp")
    with np.errstate(invalid="ignore", divide="ignore"):   # a time interval reaching 0
        log_t, log_e = np.log(rows[column].to_numpy()), np.log(rows.mean_delta_e76.to_numpy())
    order = np.argsort(log_e)
    return float(np.exp(np.interp(np.log(target_de), log_e[order], log_t[order])))


def _uniform_time_for(cells, scene, de: MeanCI) -> MeanCI:
    """The time uniform needs for balanced's ΔE, with the range its interval spans: from the
    upper end of the ΔE interval on uniform's lower time ends to the lower end on the upper time
    ends (uniform's own ΔE interval is not propagated)."""
    return MeanCI(_time_for_quality(cells, scene, de.mean),
                  _time_for_quality(cells, scene, de.high, f"{TIME}_low"),
                  _time_for_quality(cells, scene, de.low, f"{TIME}_high"), de.n, float("nan"))


def _within(ratio_low: float, ratio_high: float, tolerance: float) -> bool | None:
    """Whether the ratio lies within 1 ± tolerance: True when its whole range does, False when
    none of it does, None (not resolved) otherwise."""
    if 1 - tolerance <= ratio_low and ratio_high <= 1 + tolerance:
        return True
    if ratio_high < 1 - tolerance or ratio_low > 1 + tolerance:
        return False
    return None


def _range_text(value: MeanCI) -> str:
    """An asymmetric range: ``mean [low, high]``, or ``mean (no interval)``."""
    if not value.resolved:
        return f"{value.mean:.3g} (no interval)"
    return f"{value.mean:.3g} [{value.low:.3g}, {value.high:.3g}]"


# ---- equal time and ratios of cells -----------------------------------------------------------


def spp_rows(table: pd.DataFrame) -> pd.DataFrame:
    """The rows of the spp cells (not of a time budget)."""
    return table[table.time_budget_ms.isna()]


def budget_rows(table: pd.DataFrame, budget_ms: float) -> pd.DataFrame:
    """The rows of the equal-time cells of ``budget_ms``."""
    return table[table.time_budget_ms == budget_ms]


def equal_time_budget(cells: pd.DataFrame, estimators, spp: int | None) -> float:
    """The equal-time budget: the largest of ``estimators``' mean frame times (``time_ms``) over
    the scenes at ``spp`` (``cells``: :func:`_cell_means` of the spp cells; None: the cells are
    each estimator's own), to two significant digits, so that the slowest estimator gets about
    ``spp`` and every other more."""
    rows = cells[cells.estimator.isin(estimators) & ((cells.spp == spp) if spp is not None else True)]
    slowest = rows.groupby("estimator")[TIME].mean().max() if len(rows) else math.nan
    if not slowest > 0:
        raise InputError(None, f"no time of {', '.join(estimators)} at {spp} spp to take an "
                               "equal-time budget from")
    return float(f"{slowest:.2g}")


def seed_values(rows: pd.DataFrame, column: str) -> dict[tuple[str, str], np.ndarray]:
    """Per (scene, estimator) of ``rows`` (one spp or one budget each): ``column`` per seed,
    the mean over its frames (a NaN frame makes it NaN, as in :func:`cell_intervals`)."""
    per_seed = rows.groupby(["scene", "estimator", "seed"])[column].mean(skipna=False)
    return {key: values.to_numpy()
            for key, values in per_seed.groupby(level=["scene", "estimator"])}


# error ∝ time^-power in the noise regime: an MSE falls as 1/t, ΔE (about an RMS error) as 1/√t
TIME_POWER = {"rel_mse": 1.0, "mean_delta_e76": 0.5}


def budget_scaled_values(rows: pd.DataFrame, column: str,
                         budget_ms: float) -> dict[tuple[str, str], np.ndarray]:
    """:func:`seed_values` of the error ``column`` of one budget's ``rows``, each row's error
    scaled to exactly the budget by its own frame time t: error × (t / budget)^p, with p of
    :data:`TIME_POWER` (module docstring, "Equal time").  The frame's build, a fixed cost, is
    scaled with the rest, so the correction is approximate where the build is a large share of t
    (a cell over its budget is then scaled slightly too little)."""
    scale = (rows[TIME] / budget_ms) ** TIME_POWER[column]
    return seed_values(rows.assign(**{column: rows[column] * scale}), column)


def cell_ratio(values: dict, scene: str, numerator: str, denominator: str) -> RatioCI:
    """numerator's mean over seeds / denominator's, with its 95% interval
    (:func:`iblbench.harness.protocol.stats.ratio_ci`); no ratio where a cell is missing."""
    if (scene, numerator) not in values or (scene, denominator) not in values:
        return RatioCI(math.nan, math.nan, math.nan, math.nan, "a cell is missing")
    return ratio_ci(values[scene, denominator], values[scene, numerator])


def _beyond(ratio: RatioCI, bound: float) -> bool | None:
    """Whether ``ratio`` exceeds ``bound``: True when its whole interval lies above it, False
    when below, None (not resolved) when the interval reaches it or there is none."""
    if not ratio.resolved:
        return None
    if ratio.low > bound:
        return True
    return False if ratio.high < bound else None


def _ratio_plot_data(ratios: dict[tuple[str, str], RatioCI]) -> pd.DataFrame:
    """A ratio plot's points: ``label`` (scene, then the compared estimator), ratio, low, high."""
    return pd.DataFrame([{"label": f"{scene}\n{estimator}", "ratio": r.ratio, "low": r.low,
                          "high": r.high} for (scene, estimator), r in ratios.items()])


def _landed(timed: pd.DataFrame, scene: str, estimators) -> dict[str, str]:
    """The spp and mean frame time each of ``estimators`` got at the budget in ``scene``
    (``timed``: :func:`_cell_means` of the budget's rows), comma-separated in their order."""
    cells = timed.set_index(["scene", "estimator"])
    got = [cells.loc[(scene, e)] if (scene, e) in cells.index else None for e in estimators]
    return {"spp": ", ".join("–" if c is None else str(int(c.spp)) for c in got),
            "time_ms": ", ".join("–" if c is None else f"{c[TIME]:.3g}" for c in got)}


def lu2013_verdicts(cells: pd.DataFrame, scenes) -> list[Verdict]:
    """The paper's four claims on ``cells`` (:func:`_cell_means`), each comparison called only
    where the intervals separate.  Claim 2's ratio balanced@N / uniform@3N has the range of the
    two intervals' ends (wider than the ratio's own 95% interval, so conservative)."""
    n = 60
    seeds = int(cells.seeds.min())
    fmt = lambda xs: "; ".join(xs)
    ratio_b = {s: _ci(cells, s, "balanced", n, "effective_ratio") for s in scenes}
    ratio_u = {s: _ci(cells, s, "uniform", n, "effective_ratio") for s in scenes}
    claim1 = Verdict(
        "1. balanced has a higher effective ratio than uniform (60 spp)",
        _judge([_below(ratio_u[s], ratio_b[s]) for s in scenes], seeds),
        fmt(f"{s}: {ratio_b[s].text(2)} vs {ratio_u[s].text(2)}" for s in scenes),
        "47/60 = 0.78 vs 116/180 = 0.64")

    de = {(s, e, k): _ci(cells, s, e, k, "mean_delta_e76") for s in scenes
          for e, k in (("balanced", n), ("uniform", n), ("uniform", 3 * n))}
    # The verdict is the stated test alone: beating uniform at equal spp is shown, not judged.
    close = []
    for s in scenes:
        balanced, uniform = de[s, "balanced", n], de[s, "uniform", 3 * n]
        low, high = (balanced.low / uniform.high, balanced.high / uniform.low) \
            if uniform.low > 0 else (float("nan"), float("nan"))
        close.append(_within(low, high, 0.10))
    claim2 = Verdict(
        "2. balanced at N spp ≈ uniform at 3N spp in ΔE (within 10%; N = 60)",
        _judge(close, seeds),
        fmt(f"{s}: {de[s, 'balanced', n].text(3)} vs {de[s, 'uniform', 3 * n].text(3)} "
            f"(uniform@{n}: {de[s, 'uniform', n].text(3)})" for s in scenes),
        "6.44 (balanced@60) vs 6.22 (uniform@180)")

    mis = {s: [_ci(cells, s, "balanced_mis", k, "mean_delta_e76") for k in LU2013_MIS_SPP]
           for s in scenes}
    # The stated test is every step: an error that falls from 15 to 240 spp but rises (resolved)
    # at some step in between is not monotone, so it does not make the claim partly hold.
    steps = {s: [_below(b, a) for a, b in zip(mis[s], mis[s][1:])] for s in scenes}
    monotone = [True if all(f is True for f in steps[s]) else False if False in steps[s] else None
                for s in scenes]
    claim3 = Verdict(
        "3. MIS error falls monotonically with spp (15 → 240)",
        _judge(monotone, seeds),
        fmt(f"{s}: " + " → ".join(v.text(3) for v in mis[s]) for s in scenes),
        "Fig. 3: error decreases from 15 to 240 spp")

    t_b = {s: _ci(cells, s, "balanced", n, TIME) for s in scenes}
    t_u = {s: _uniform_time_for(cells, s, de[s, "balanced", n]) for s in scenes}
    claim4 = Verdict(
        "4. balanced is faster than uniform at equal quality",
        _judge([_below(t_b[s], t_u[s]) for s in scenes], seeds),
        fmt(f"{s}: {t_b[s].text(3)} ms vs {_range_text(t_u[s])} ms" for s in scenes),
        "higher frame rate than uniform for the same quality (Sec. 3)")
    return [claim1, claim2, claim3, claim4]


def lu2013_equal_time_verdict(values: dict, scenes, seeds: int):
    """Claim 5, which the paper did not test: Lu's balanced sampling beats a global 2-D
    distribution at equal time.  Per scene and pair of :data:`LU2013_EQUAL_TIME_PAIRS`, the
    baseline's mean ΔE76 / Lu's at the budget (``values``: :func:`budget_scaled_values` of the
    budget's rows); it holds where every ratio's interval lies above 1.  Returns the verdict and
    the ratios by (scene, Lu's estimator)."""
    ratios = {(s, lu): cell_ratio(values, s, baseline, lu)
              for s in scenes for lu, baseline in LU2013_EQUAL_TIME_PAIRS}
    baseline_of = dict(LU2013_EQUAL_TIME_PAIRS)
    verdict = Verdict(
        "5. Lu's per-normal balancing beats a global 2-D distribution at equal time "
        "(ΔE76 of envmap / balanced and of envmap{mis=\"brdf\"} / balanced_mis, each scaled to "
        "the budget, above 1)",
        _judge([_beyond(r, 1.0) for r in ratios.values()], seeds),
        "; ".join(f"{s}: {baseline_of[lu]} / {lu} {r.text()}" for (s, lu), r in ratios.items()),
        "not compared: the paper's only baseline is uniform face selection at equal spp "
        "(Fig. 2); production renderers (pbrt-v4, Cycles, Mitsuba 3) use the global distribution")
    return verdict, ratios


def lu2013(out: pathlib.Path, seeds: int, device: str | None, progress: bool | None,
           scenes=LU2013_SCENES, resolution=None, env_res=None,
           time_budget_ms: float | None = None) -> Reproduction:
    """Fig. 2 and Fig. 3 analogues with the production baselines beside them, timings, an
    equal-time comparison, and the verdicts on the paper's four claims and on claim 5.

    Three sweeps into ``out``: Lu's estimators at :data:`LU2013_SPP`, the baselines at 60 spp,
    then all six at one budget, ``time_budget_ms`` or :func:`equal_time_budget` of all six at
    60 spp.  ``resolution`` and ``env_res`` shrink the sweeps (tests); the defaults are the
    scenes' own.
    """
    common = dict(out=out, scenes=tuple(scenes), seeds=seeds, device=device, progress=progress,
                  resolution=resolution, env_res=env_res, metrics=METRICS)
    estimators = (*LU2013_ESTIMATORS, *LU2013_BASELINES)
    run(RunConfig(estimators=LU2013_ESTIMATORS, spp=LU2013_SPP, **common))
    table = run(RunConfig(estimators=LU2013_BASELINES, spp=(LU2013_N,), **common))
    cells = _cell_means(_of_sweep(spp_rows(table), scenes, estimators))
    budget = time_budget_ms or equal_time_budget(cells, estimators, LU2013_N)
    table = _of_sweep(run(RunConfig(estimators=estimators, spp=(), time_budget_ms=(budget,),
                                    **common)), scenes, estimators)
    at_budget = budget_rows(table, budget)
    timed = _cell_means(at_budget)
    n = LU2013_N
    fig2 = cells[((cells.estimator == "balanced") & (cells.spp == n))
                 | ((cells.estimator == "uniform") & cells.spp.isin([n, 3 * n]))
                 | (cells.estimator.isin(LU2013_BASELINES) & (cells.spp == n))]
    fig3 = cells[(cells.estimator == "balanced_mis") & cells.spp.isin(LU2013_MIS_SPP)]
    timing = (_shown(cells[cells.spp == n], ["scene", "estimator"], TIMES)
              .rename(columns=lambda c: c.replace("time_ms_sample", "time_ms_pool")))
    claim5, ratios = lu2013_equal_time_verdict(
        budget_scaled_values(at_budget, "mean_delta_e76", budget), scenes, int(timed.seeds.min()))
    baseline_of = dict(LU2013_EQUAL_TIME_PAIRS)
    measured = seed_values(at_budget, "mean_delta_e76")
    ratio_table = pd.DataFrame([
        {"scene": s, "estimator": lu, "against": baseline_of[lu],
         **_landed(timed, s, (baseline_of[lu], lu)),
         "ΔE76 ratio, scaled to the budget": r.text(),
         "ΔE76 ratio, as measured": cell_ratio(measured, s, baseline_of[lu], lu).text()}
        for (s, lu), r in ratios.items()])
    sections = [
        Section("Fig. 2 analogue: balanced at 60 spp against uniform at 60 and 180 spp, and the "
                "production baselines at 60 spp",
                _shown(fig2, ["scene", "estimator", "spp"],
                       ["mean_delta_e76", "used", "effective", "effective_ratio"]),
                Plot("samples", "fig2_samples.png", "used and effective samples", fig2)),
        Section("Fig. 3 analogue: balanced_mis error against spp",
                _shown(fig3, ["scene", "spp"], ["mean_delta_e76", "used", "effective"]),
                Plot("error_vs_spp", "fig3_error_vs_spp.png", "mean ΔE76 against spp", fig3)),
        Section("Timing at 60 spp (device ms per frame, the median of each cell's timed renders, "
                "then the mean over seeds: time_ms = build + pool + shade, with build = upload + "
                "CDFs, pool = light-sample pool or, for the baselines, the sample stage)", timing),
        Section(f"Equal time: every estimator at {budget:g} ms per frame (the slowest "
                "estimator's mean time at 60 spp; spp: what each got within the budget)",
                _shown(timed, ["scene", "estimator", "spp"], [TIME, "mean_delta_e76"])),
        Section("Lu's balancing against a global 2-D distribution at equal time: the baseline's "
                "mean ΔE76 / Lu's (above 1: Lu's error is lower; spp and time_ms: baseline, "
                "Lu's)", ratio_table,
                Plot("ratios", "equal_time_ratios.png", "error ratios at equal time",
                     _ratio_plot_data(ratios), {"equal error": 1.0})),
    ]
    return Reproduction(
        title="Lu, Pacanowski & Granier 2013: Real-Time Importance Sampling of Dynamic "
              "Environment Maps",
        setup_differences=LU2013_SETUP_DIFFERENCES, sections=sections,
        verdicts=[*lu2013_verdicts(cells, scenes), claim5], results=table)


def _of_sweep(table: pd.DataFrame, scenes, estimators) -> pd.DataFrame:
    """The rows of ``scenes`` and ``estimators`` (an ``--out`` may hold other sweeps' too)."""
    labels = [parse_estimator(label).label for label in estimators]
    return table[table.scene.isin(list(scenes)) & table.estimator.isin(labels)]


# ---- Karlík, Šik, Vévoda, Skřivan & Křivánek 2019 -------------------------------------------

# The scenes of `reproduce mis-compensation`: the static built-ins (one line per scene added).
MISC_SCENES = ("sphere-sun", "blob-sun", "sphere-backlit", "torus-sun",
               "sphere-park")   # the shipped CC0 photograph: a captured map, as the paper's
# (uncompensated, compensated) MIS estimators: one line per estimator with ``mis_compensation``.
MISC_PAIRS = (
    ('envmap{mis="brdf"}', 'envmap{mis="brdf",mis_compensation=true}'),   # power heuristic
    ('envmap{heuristic="balance",mis="brdf"}',                             # the paper's heuristic
     'envmap{heuristic="balance",mis="brdf",mis_compensation=true}'),
    ("balanced_mis", "balanced_mis{mis_compensation=true}"),
    ('hierarchical{mis="brdf"}', 'hierarchical{mis="brdf",mis_compensation=true}'),
)
MISC_SPP = 64              # the equal-spp cells, and the equal-time budget's
MISC_PAPER_RATIO = 2.75    # Fig. 1: basic MIS's NMSE / compensated MIS's at equal time (5 s)
MISC_RATIO_TOLERANCE = 0.25
MISC_TIME_LIMIT = 1.10     # compensated / uncompensated frame time at equal spp: "no cost"
MISC_SETUP_DIFFERENCES = [
    "The paper's figure is its teaser, Fig. 1 (project page: "
    "https://cgg.mff.cuni.cz/~jaroslav/papers/2019-mis-compensation/): one scene under a "
    "captured HDR map, 5 s equal-time renders, basic MIS of BSDF and environment-map sampling "
    "under the balance heuristic against its normal-independent compensation, 2.75× lower NMSE. "
    "Ours: procedural scenes under an analytic Preetham sun+sky and one under the shipped CC0 "
    "Rooitou Park photograph (sphere-park), at 64² per face, Phong BRDF "
    "(kd 0.5, ks 0.3, m 150), direct lighting without visibility, and several estimators.",
    "Error measure: the claims use relMSE, the mean over covered pixels of (x−r)²/(r²+0.01) "
    "in linear HDR against an exact reference: a squared error, as the paper's NMSE is, but "
    "normalised per pixel with ε = 0.01 (so that dark pixels do not dominate), which the "
    "paper's NMSE need not be. ΔE76 ratios are shown beside them; ΔE is not squared, so its "
    "ratio is nearer the square root of a relMSE ratio.",
    "Compensation: pbrt-v4's max(Y − Ȳ, min(Ȳ/1000, Y))·Ω per texel (FrameCache.light_cdfs), "
    "where the paper's normal-independent form subtracts the mean and clamps at 0; the floor "
    "keeps every lit texel reachable by light samples.",
    "Estimators: envmap with BRDF MIS under the power heuristic (the production renderers' "
    "default) and under the balance heuristic (the paper's), hierarchical (mip descent) with "
    "BRDF MIS, and Lu 2013's balanced_mis, whose "
    "light distribution is balanced per normal (not in the paper). Each pixel's budget is "
    "split N/2 light + N/2 BRDF samples, where a path tracer takes one of each per vertex.",
    "Equal time: device time per frame (build + sample + shade, the median of a cell's timed "
    "renders) through --time-budget-ms's calibration, at one budget: the slowest estimator's "
    "mean frame time at 64 spp over the scenes, to two digits; the paper used 5 s of "
    "wall-clock render time.",
    "A cell can land off the budget (the calibration is checked, not forced; by tens of "
    "percent on a loaded machine), so each seed's relMSE is scaled to the budget by its own "
    "frame time t, relMSE × t/T (MSE ∝ 1/time in the noise regime), before the ratio is taken; "
    "the measured ratio is shown beside it. The interval covers the seeds' spread, not a "
    "machine whose speed drifts between cells: claim 2 (equal spp) needs no frame time.",
    "Every figure is the mean over seeds ± the half-width of its 95% Student-t interval, and a "
    "ratio carries its 95% interval (delta method on the log scale); a claim is called only "
    "where the intervals lie on one side of its bound.",
]


def _pair_text(ratios: dict) -> str:
    return "; ".join(f"{s} {estimator}: {r.text()}" for (s, estimator), r in ratios.items())


def mis_compensation_verdicts(errors: dict, per_sample: dict, times: dict, scenes, pairs,
                              seeds: int):
    """The paper's claims per scene and pair of ``pairs``, on ``errors``
    (:func:`budget_scaled_values` of relMSE at the budget), ``per_sample`` (:func:`seed_values`
    of relMSE at :data:`MISC_SPP`) and ``times`` (of ``time_ms`` there):

    1. compensation lowers the error at equal time: uncompensated / compensated relMSE above 1;
    2. it lowers the error per sample: the same ratio at equal spp above 1 (what claim 1 rests
       on without the frame times, which a loaded machine makes drift between cells);
    3. by about the paper's 2.75×: claim 1's ratio within 2.75 ± 25%
       (:data:`MISC_RATIO_TOLERANCE`);
    4. at no cost in time: compensated / uncompensated frame time at equal spp at most 1.10.

    Returns the verdicts and claim 1's ratios by (scene, uncompensated estimator)."""
    def by_pair(values, flip=False):
        return {(s, plain): cell_ratio(values, s, *((compensated, plain) if flip
                                                    else (plain, compensated)))
                for s in scenes for plain, compensated in pairs}

    ratios, sample_ratios, costs = by_pair(errors), by_pair(per_sample), by_pair(times, True)
    paper, tolerance = MISC_PAPER_RATIO, MISC_RATIO_TOLERANCE
    finite = [r.ratio for r in ratios.values() if math.isfinite(r.ratio)]
    spread = (f"the {len(finite)} ratios range {min(finite):.3g}–{max(finite):.3g} (claim 1)"
              if finite else "no ratio")
    slower = [_beyond(r, MISC_TIME_LIMIT) for r in costs.values()]
    return [
        Verdict("1. MIS compensation lowers MIS's error at equal time (uncompensated / "
                "compensated relMSE, each scaled to the budget, above 1)",
                _judge([_beyond(r, 1.0) for r in ratios.values()], seeds), _pair_text(ratios),
                "Fig. 1: 2.75× lower NMSE at equal time (5 s); abstract: a consistent noise "
                "reduction in all their tests"),
        Verdict(f"2. MIS compensation lowers MIS's error per sample (the same ratio at "
                f"{MISC_SPP} spp above 1)",
                _judge([_beyond(r, 1.0) for r in sample_ratios.values()], seeds),
                _pair_text(sample_ratios),
                "not stated apart from time: the paper's comparisons are at equal time"),
        Verdict(f"3. … by about the paper's {paper:g}× at equal time (claim 1's ratio within "
                f"{paper:g} ± {tolerance:.0%})",
                _judge([_within(r.low / paper, r.high / paper, tolerance)
                        for r in ratios.values()], seeds), spread,
                f"Fig. 1: {paper:g}× lower NMSE (one scene, one map)"),
        Verdict(f"4. MIS compensation costs no frame time (compensated / uncompensated time at "
                f"{MISC_SPP} spp at most {MISC_TIME_LIMIT:.2f})",
                _judge([None if f is None else not f for f in slower], seeds), _pair_text(costs),
                "abstract: no negative influence on run time (the distribution is built once, "
                "in preprocessing)"),
    ], ratios


def mis_compensation(out: pathlib.Path, seeds: int, device: str | None, progress: bool | None,
                     scenes=MISC_SCENES, pairs=MISC_PAIRS, resolution=None, env_res=None,
                     time_budget_ms: float | None = None) -> Reproduction:
    """Karlík et al. 2019's equal-time comparison of MIS with and without compensation.

    Two sweeps into ``out``: every estimator of ``pairs`` at :data:`MISC_SPP`, then all of them
    at one budget, ``time_budget_ms`` or :func:`equal_time_budget` of them all at that spp.
    ``resolution`` and ``env_res`` shrink the sweeps (tests).
    """
    pairs = tuple((parse_estimator(a).label, parse_estimator(b).label) for a, b in pairs)
    estimators = tuple(label for pair in pairs for label in pair)
    common = dict(out=out, scenes=tuple(scenes), estimators=estimators, seeds=seeds,
                  device=device, progress=progress, resolution=resolution, env_res=env_res,
                  metrics=METRICS)
    table = _of_sweep(run(RunConfig(spp=(MISC_SPP,), **common)), scenes, estimators)
    at_spp = spp_rows(table)[spp_rows(table).spp == MISC_SPP]
    spp_cells = _cell_means(at_spp)
    budget = time_budget_ms or equal_time_budget(spp_cells, estimators, MISC_SPP)
    table = _of_sweep(run(RunConfig(spp=(), time_budget_ms=(budget,), **common)), scenes,
                      estimators)
    at_budget = budget_rows(table, budget)
    timed = _cell_means(at_budget)
    per_sample = seed_values(at_spp, "rel_mse")
    verdicts, ratios = mis_compensation_verdicts(
        budget_scaled_values(at_budget, "rel_mse", budget), per_sample, seed_values(at_spp, TIME),
        scenes, pairs, int(min(timed.seeds.min(), spp_cells.seeds.min())))
    measured = seed_values(at_budget, "rel_mse")
    delta_e = budget_scaled_values(at_budget, "mean_delta_e76", budget)
    ratio_table = pd.DataFrame([
        {"scene": s, "estimator": plain, **_landed(timed, s, (plain, compensated)),
         "relMSE ratio, scaled to the budget": ratios[s, plain].text(),
         "relMSE ratio, as measured": cell_ratio(measured, s, plain, compensated).text(),
         "ΔE76 ratio, scaled": cell_ratio(delta_e, s, plain, compensated).text(),
         f"relMSE ratio at {MISC_SPP} spp": cell_ratio(per_sample, s, plain, compensated).text()}
        for s in scenes for plain, compensated in pairs])
    columns = [TIME, "rel_mse", "mean_delta_e76"]
    sections = [
        Section("Equal time: uncompensated / compensated error at the budget (above 1: "
                "compensation lowers the error; spp and time_ms: uncompensated, compensated)",
                ratio_table,
                Plot("ratios", "equal_time_ratios.png", "relMSE ratios at equal time",
                     _ratio_plot_data(ratios),
                     {"equal error": 1.0, f"paper, Fig. 1 (NMSE): {MISC_PAPER_RATIO:g}":
                      MISC_PAPER_RATIO})),
        Section(f"Equal time: every estimator at {budget:g} ms per frame (the slowest "
                f"estimator's mean time at {MISC_SPP} spp; spp: what each got within the budget)",
                _shown(timed, ["scene", "estimator", "spp"], columns)),
        Section(f"Equal spp ({MISC_SPP}): time and error per sample (time_ms = build + sample "
                "+ shade; a compensated estimator's own CDF build is in its sample stage)",
                _shown(spp_cells, ["scene", "estimator", "spp"],
                       [*columns, "time_ms_sample"])),
    ]
    return Reproduction(
        title="Karlík, Šik, Vévoda, Skřivan & Křivánek 2019: MIS Compensation: Optimizing "
              "Sampling Techniques in Multiple Importance Sampling",
        setup_differences=MISC_SETUP_DIFFERENCES, sections=sections, verdicts=verdicts,
        results=table)


# ---- Kronander, Dahlin, Jönsson, Kok, Schön & Unger: Real-time video based lighting using GPU raytracing ----

# Sequences of moving light: the moving-lights sequence made after Kronander's Fig. 3, the
# photographed key light that moves and the park photograph turning; their first frames.
KRONANDER_SCENES = ("torus-moving", "sphere-studio-moving", "park-turn")
KRONANDER_FRAMES = slice(0, 6)
# Fig. 3's configurations: MIS with N_ρ = N_L = 15 (Eq. 2, the balance heuristic), BIS with
# M = 400 and N = 20, SMC with N = 8 particles and 3 intermediate distributions; then the rows
# the paper does not have, restir (one reservoir chain) and product (MIS's 30 samples).
KRONANDER_MIS = 'envmap{heuristic="balance",mis="brdf"}'
KRONANDER_PAPER_SPP = ((KRONANDER_MIS, 30), ("bis", 20), ("smc", 8), ("restir", 1), ("product", 30))
KRONANDER_CLAIMED = (KRONANDER_MIS, "bis")     # the paper's: these beat SMC at equal time
KRONANDER_ADDED = ("restir", "product")         # ours: judged against SMC the same way
KRONANDER_SETUP_DIFFERENCES = [
    "The paper's sequences are HDR video light probes of real scenes (Fig. 3: several moving "
    "direct light sources, 90+ frames) rendered by OptiX on a GTX 770. Ours: torus-moving (four "
    "small lights on smooth paths, after Fig. 3), sphere-studio-moving (the shipped studio "
    "photograph's key light moving 2° a frame) and park-turn (the park photograph turning), "
    "their first 6 frames, direct lighting without visibility, Phong BRDF.",
    "Configurations as Fig. 3: MIS = envmap with half BRDF and half map samples under the balance "
    "heuristic (Eq. 2) at N_ρ = N_L = 15; BIS = bis at M = 400, N = 20 (Burke's BRDF candidates); "
    "SMC = smc at N = 8 with 3 intermediate distributions (its re-initialisation rules are the "
    "paper's plus the map-level tests its docstring states). restir and product are not in the "
    "paper: restir at one reservoir chain (M = 8 candidates, temporal and spatial reuse), "
    "product at 30 samples.",
    "Equal time: device time per frame (build + sample + shade) through --time-budget-ms's "
    "calibration at one budget, the slowest of MIS, BIS and SMC's mean frame times at their "
    "Fig. 3 configurations over the scenes, to two digits (the paper states equal rendering time "
    "without a figure). Each seed's ΔE76, the mean over the frames, is scaled to the budget by its "
    "own frame time t, ΔE76 × √(t/T). The calibration renders frame 0, where a temporal "
    "estimator carries nothing (restir evaluates 15 targets a chain there, 17 on later frames; "
    "smc's init is its BIS), so their later frames can run over the budget; the scaling by each "
    "cell's own median time over the frames corrects that only as far as ΔE ∝ 1/√time holds.",
    "The claim is the paper's result (Sec. 8, Results and comparisons): 'the MIS and BIS algorithms perform better for a "
    "fixed computational cost' than SMC. A ratio SMC / estimator above 1 with its 95% interval "
    "above 1 on a scene is a win there; the verdict holds where every scene is won.",
]


def _paper_spp_rows(table: pd.DataFrame) -> pd.DataFrame:
    """The spp cells of ``table`` at each estimator's Fig. 3 configuration."""
    rows = spp_rows(table)
    keep = np.zeros(len(rows), bool)
    for label, spp in KRONANDER_PAPER_SPP:
        keep |= (rows.estimator == parse_estimator(label).label).to_numpy() & (rows.spp == spp).to_numpy()
    return rows[keep]


def kronander_verdicts(errors: dict, scenes, seeds: int) -> tuple[list[Verdict], dict]:
    """Per scene, SMC's mean ΔE76 over each estimator's at the budget (``errors``:
    :func:`budget_scaled_values`), above 1 where the estimator beats SMC: the paper's claim for
    MIS and BIS, and the same test for restir and product.  Returns the verdicts and the ratios by
    (scene, estimator)."""
    labels = {label: parse_estimator(label).label for label, _ in KRONANDER_PAPER_SPP}
    ratios = {(s, labels[e]): cell_ratio(errors, s, "smc", labels[e]) for s in scenes
              for e in (*KRONANDER_CLAIMED, *KRONANDER_ADDED)}

    def verdict(claim: str, estimators, paper: str) -> Verdict:
        chosen = {k: r for k, r in ratios.items() if k[1] in {labels[e] for e in estimators}}
        return Verdict(claim, _judge([_beyond(r, 1.0) for r in chosen.values()], seeds),
                       _pair_text(chosen), paper)

    return [
        verdict("1. MIS beats SMC at equal time (SMC / MIS ΔE76, scaled to the budget, above 1)",
                (KRONANDER_MIS,), "Sec. 8 and Fig. 3: MIS performs better for a fixed computational cost"),
        verdict("2. BIS beats SMC at equal time (SMC / BIS ΔE76 above 1)", ("bis",),
                "Sec. 8 and Fig. 3: BIS performs better for a fixed computational cost"),
        verdict("3. restir beats SMC at equal time (not in the paper)", ("restir",),
                "— (ReSTIR, Bitterli et al. 2020, is later)"),
        verdict("4. product beats SMC at equal time (not in the paper)", ("product",),
                "— (product sampling, Clarberg et al. 2005, 2008; the paper's BIS is its resampled form)"),
    ], ratios


def kronander(out: pathlib.Path, seeds: int, device: str | None, progress: bool | None,
              scenes=KRONANDER_SCENES, resolution=None, env_res=None,
              time_budget_ms: float | None = None) -> Reproduction:
    """Kronander et al.'s equal-time comparison of MIS, BIS and SMC on moving light, with restir
    and product as rows.  Two sweeps into ``out``: each estimator at its Fig. 3 configuration
    (:data:`KRONANDER_PAPER_SPP`), then all of them at one budget, ``time_budget_ms`` or the
    slowest of MIS, BIS and SMC's mean frame times there.  ``resolution`` and ``env_res`` shrink
    the sweeps (tests)."""
    estimators = tuple(parse_estimator(label).label for label, _ in KRONANDER_PAPER_SPP)
    common = dict(out=out, scenes=tuple(scenes), estimators=estimators, seeds=seeds, device=device,
                  progress=progress, resolution=resolution, env_res=env_res, metrics=METRICS,
                  frames=KRONANDER_FRAMES)
    spp_for = tuple((parse_estimator(label).cls.name, (spp,)) for label, spp in KRONANDER_PAPER_SPP
                    if label != KRONANDER_MIS)
    mis_spp = dict(KRONANDER_PAPER_SPP)[KRONANDER_MIS]
    table = _of_sweep(run(RunConfig(spp=(mis_spp,), spp_for=spp_for, **common)), scenes, estimators)
    paper_cells = _cell_means(_paper_spp_rows(table))
    claimed = [parse_estimator(label).label for label in (*KRONANDER_CLAIMED, "smc")]
    budget = time_budget_ms or equal_time_budget(paper_cells, claimed, None)
    table = _of_sweep(run(RunConfig(spp=(), time_budget_ms=(budget,), **common)), scenes, estimators)
    at_budget = budget_rows(table, budget)
    timed = _cell_means(at_budget)
    errors = budget_scaled_values(at_budget, "mean_delta_e76", budget)
    verdicts, ratios = kronander_verdicts(errors, scenes, int(timed.seeds.min()) if len(timed) else 0)
    flicker = seed_values(at_budget.dropna(subset=["flicker"]), "flicker")
    ratio_table = pd.DataFrame([
        {"scene": s, "estimator": e, **_landed(timed, s, (e,)),
         "SMC / this ΔE76, scaled to the budget": r.text(),
         "flicker": "–" if (s, e) not in flicker else f"{flicker[s, e].mean():.3g}"}
        for (s, e), r in ratios.items()])
    columns = [TIME, "mean_delta_e76", "rel_mse"]
    sections = [
        Section("Equal time: SMC's error over each estimator's at the budget (above 1: it beats SMC)",
                ratio_table,
                Plot("ratios", "equal_time_ratios.png", "SMC / estimator ΔE76 at equal time",
                     _ratio_plot_data(ratios), {"equal error": 1.0})),
        Section(f"Equal time: every estimator at {budget:g} ms per frame (spp: what each got)",
                _shown(timed, ["scene", "estimator", "spp"], columns)),
        Section("Fig. 3's configurations: time and error per frame",
                _shown(paper_cells, ["scene", "estimator", "spp"], columns)),
    ]
    return Reproduction(
        title="Kronander, Dahlin, Jönsson, Kok, Schön & Unger: Real-time video based lighting "
              "using GPU raytracing (MIS and BIS against SMC), with restir and product",
        setup_differences=KRONANDER_SETUP_DIFFERENCES, sections=sections, verdicts=verdicts,
        results=table)


def _shown(cells: pd.DataFrame, keys: list[str], columns) -> pd.DataFrame:
    """A table of a reproduction: ``keys``, ``seeds`` and each column beside its ``_half``
    (:func:`iblbench.reports.reproduction.write_summary` shows them as mean ± half-width)."""
    return cells[[*keys, "seeds", *(name for c in columns for name in (c, f"{c}_half"))]]


REPRODUCTIONS = {"lu2013": lu2013, "mis-compensation": mis_compensation, "kronander": kronander}


def reproduce(name: str, out: pathlib.Path, seeds: int = 3, device: str | None = None,
              progress: bool | None = None, **options) -> Reproduction:
    """Run reproduction ``name`` into ``out``; returns its :class:`Reproduction` (the API writes
    its summary with :func:`iblbench.reports.reproduction.write_summary`)."""
    try:
        experiment = REPRODUCTIONS[name.lower()]
    except KeyError:
        raise InputError(None, f"unknown reproduction '{name}'; valid: "
                               f"{', '.join(sorted(REPRODUCTIONS))}") from None
    return experiment(pathlib.Path(out), seeds=seeds, device=device, progress=progress, **options)
