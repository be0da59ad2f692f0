"""The project's own mutation suite (issue 13): realistic one-line bugs, each applied to a
temporary copy of the sources, and the check layers that must reject them.

A :class:`Mutant` replaces one exact piece of text (it must occur exactly once, so a catalogue
entry that no longer matches the code fails loudly instead of testing nothing) in one file of
the installed ``iblbench`` packages or of a plugin's package: a kernel (``.cl``) or a Python
module.  The catalogue is this module's mutants of the shared kernels and the harness and each
registered estimator's own (``Estimator.mutants``, declared beside it, in files of its own
package).  :func:`run_mutant` copies the four packages (and the plugin's, for its mutants) into
a temporary folder, applies the mutation there and runs the layers in a fresh interpreter whose
``PYTHONPATH`` puts the copy first, with its own reference cache, so that neither the imports
nor the kernel and reference caches of this process see the bug.

Layers, in order (``run_mutant`` stops at the first that rejects unless asked for all; the
``tests`` layer comes first for a mutant that names tests, being the one its entry says catches
it, and the cheapest):

- ``conformance``: ``check_estimator``'s checks (``conformance.yield_checks``) on each of the
  mutant's estimators, stopping at the first failed check;
- ``stress``: the stress battery at its quick size (``stress.SMALL``), on the mutant's cases
  only (the ones that guard the code it breaks) and its estimators;
- ``budgets``: the ``quick`` sweep (``iblbench run --config quick --repeats 1 --no-flip``) checked
  against the repository's ``budgets.toml`` (only where that file exists: a source checkout);
- ``tests``: the unit tests the mutant names (pytest node ids in the repository's ``tests/``,
  again only in a source checkout), run on the mutated copy: the layer for bugs that no render
  can show, such as the bookkeeping of a distributed run, the ranking's rules or a checker
  that passes what it should fail.

A mutant that only a check still to land can catch says so in ``expect_killed_after``: the
test suite expects it to survive until then (``xfail``, not strict).

``iblbench selftest`` runs the catalogue and prints which layer rejected each mutant.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import importlib.util
import json
import os
import pathlib
import queue
import shutil
import subprocess
import sys
import tempfile
import time

PACKAGES = ("foundation", "scenes", "estimators", "harness", "reports")
LAYERS = ("conformance", "stress", "budgets", "tests")
RESULT_TAG = "MUTANT-RESULT "


@dataclasses.dataclass(frozen=True)
class Mutant:
    """One realistic bug: ``old`` → ``new`` in ``path``, relative to the folder of the top-level
    package ``package`` (``estimators/...``, ``harness/...`` in ``iblbench``; a plugin's own
    files in its package).  ``estimators``: the estimators whose conformance and stress rows
    run, as a sweep names them (``name`` or ``name{param=value,...}``: a configuration where the
    bug shows, such as bis with M = 2 candidates per sample); ``stress``: the stress cases that
    guard the broken code; ``budgets``: whether the budgets layer applies (the quick sweep runs
    uniform, balanced and balanced_mis); ``tests``: pytest node ids, relative to the repository's
    ``tests/`` folder, that must fail on the bug (each should take seconds)."""

    name: str
    path: str
    old: str | tuple[str, ...]   # a tuple: several places of one bug, replaced pairwise with new
    new: str | tuple[str, ...]
    estimators: tuple[str, ...]
    stress: tuple[str, ...] = ()
    budgets: bool = False
    expect_killed_after: str = ""
    package: str = "iblbench"
    tests: tuple[str, ...] = ()

    @classmethod
    def declared(cls, estimator: type, mutant) -> "Mutant":
        """The catalogue's entry for an estimator class's own ``mutant``
        (:class:`iblbench.estimators.base.Mutant`): its path from the package that holds the
        class's module, its estimators the class itself unless it names others."""
        package = estimator.__module__.rpartition(".")[0]
        top, _, below = package.partition(".")
        return cls(mutant.name, "/".join(filter(None, [*below.split("."), mutant.path])),
                   mutant.old, mutant.new, tuple(mutant.estimators) or (estimator.name,),
                   tuple(mutant.stress), mutant.budgets, mutant.expect_killed_after, top,
                   tuple(mutant.tests))

    @property
    def where(self) -> str:
        """``path``, with its package where that is not iblbench (``selftest --list``)."""
        return self.path if self.package == "iblbench" else f"{self.package}/{self.path}"

    def apply(self, root: pathlib.Path) -> None:
        target = root / self.package / self.path
        text = target.read_text(encoding="utf-8")
        olds, news = ((self.old,), (self.new,)) if isinstance(self.old, str) else (self.old, self.new)
        for old, new in zip(olds, news, strict=True):
            count = text.count(old)
            if count != 1:
                raise ValueError(f"mutant {self.name}: the text to replace occurs {count} times "
                                 f"in {self.where} (must be once): {old!r}")
            text = text.replace(old, new)
        target.write_text(text, encoding="utf-8")


def _m(name, path, old, new, estimators, stress=(), budgets=False, expect_killed_after="", tests=()):
    return Mutant(name, path, old, new, tuple(estimators), tuple(stress), budgets, expect_killed_after,
                  tests=tuple(tests))


COMMON, POOL = "estimators/runtime/kernels/common.cl", "estimators/runtime/kernels/light_pool.cl"

# The shared kernels' and the harness's mutants; each estimator's own are declared beside it
# (``Estimator.mutants``) and :func:`catalogue` collects them.
HARNESS_MUTANTS: tuple[Mutant, ...] = (
    # ---- the light pool: uniform, balanced, balanced_mis ----------------------------------------
    _m("pool-effective-counts-every-sample", POOL,
       "acc->effective += select((lane_ints_t)0, beta, counts);",
       "acc->effective += select((lane_ints_t)0, beta, active);", ["uniform"], ["hot-texel"]),
    _m("pool-beta-always-one", POOL,
       "return min(TICKS_PER_SAMPLE, ticks - i * TICKS_PER_SAMPLE - LANE_NUMBERS * TICKS_PER_SAMPLE);",
       "return (lane_ints_t)TICKS_PER_SAMPLE;", ["balanced"], ["sun-1e6"]),
    _m("pool-specular-normalisation-m+1", POOL,
       "lanes_t lobe = (s->m + 2.0f) / (2.0f * IBL_PI) * power;",
       "lanes_t lobe = (s->m + 1.0f) / (2.0f * IBL_PI) * power;", ["uniform"], ["shininess"]),
    _m("balanced-form-factor-unclamped", POOL,
       "sum += max(0.0f, vec3_dot(n, corner));", "sum += vec3_dot(n, corner);",
       ["balanced"], ["black-faces"]),
    _m("balanced-mu-without-face-integral", POOL,
       "weight[f] = balanced_faces ? face_form_factor(n, f) * face_integral[f] : 1.0f;",
       "weight[f] = balanced_faces ? face_form_factor(n, f) : 1.0f;", ["balanced"], budgets=True),
    _m("mis-denominator-without-brdf", POOL,
       "            if (brdf_samples)\n                denominator +=",
       "            if (0)\n                denominator +=", ["balanced_mis"], ["shininess"]),
    _m("mis-brdf-lobe-axis-normal", POOL,
       "lanes3_pick(specular, b_r, b_n)", "lanes3_pick(specular, b_n, b_n)",
       ["balanced_mis"], ["shininess"]),
    _m("pool-shared-sequence-ignored", "estimators/light_pool.py",
       "np.int32(self.params.shared_sequence)", "np.int32(True)", ["uniform"]),
    # ---- shared conventions (common.cl) -----------------------------------------------------------
    _m("light-pdf-jacobian-inverted", COMMON,
       "cdf_bin(rows, row) * cdf_bin(cols, col) * area_per_solid_angle(*x, *y) / texel_area",
       "cdf_bin(rows, row) * cdf_bin(cols, col) / area_per_solid_angle(*x, *y) / texel_area",
       ["uniform"], ["sun-1e6"]),
    _m("light-pdf-hook-texel-area", COMMON,
       "* (float)(res * res) / 4.0f;", "* (float)(res * res) / 2.0f;",
       ["balanced_mis"], ["shininess"]),
    _m("phong-pdf-normalisation-m+2", COMMON,
       "p_spec * (m + 1.0f) / (2.0f * IBL_PI) * power", "p_spec * (m + 2.0f) / (2.0f * IBL_PI) * power",
       ["balanced_mis"], ["shininess"]),
    _m("face-orientation-minus-y", COMMON,
       "case 3:  return (float3)( u, -1.0f, -v);", "case 3:  return (float3)( u, -1.0f,  v);",
       ["uniform"], ["black-faces"]),
    _m("diffuse-sampling-uniform-cosine", COMMON,
       "float cos_theta = specular ? phong_power(xi_cos, 1.0f / (m + 1.0f)) : sqrt(xi_cos);",
       "float cos_theta = specular ? phong_power(xi_cos, 1.0f / (m + 1.0f)) : xi_cos;",
       ["balanced_mis"], ["shininess"]),
    # ---- the frame cache --------------------------------------------------------------------
    _m("framecache-luminance-weights-swapped", "estimators/runtime/framecache.cl",
       "return 0.2126f * x + 0.7152f * y + 0.0722f * z;",
       "return 0.7152f * x + 0.2126f * y + 0.0722f * z;",
       ["uniform"], ["sun-1e6"]),
    _m("framecache-cdf-without-solid-angle", "estimators/runtime/framecache.cl",
       "return luminance_of_sixteen(a, b, c, d) * omega;",
       "return luminance_of_sixteen(a, b, c, d);",
       ["uniform"], ["tiny-faces"]),
    _m("framecache-zero-bins-kept", "estimators/runtime/framecache.cl",
       "(cdf_word8_t)0, convert_long8(w > 0.0f) == 0);", "(cdf_word8_t)0, convert_long8(w >= 0.0f) == 0);",
       ["uniform"], ["hot-texel"]),
    # ---- the frame cache's alias table (FrameCache.map_alias, envmap's light sampler) -------------
    # The over-full bin keeps its whole width after lending to an under-full one: the tables draw
    # other probabilities than the CDFs' widths, which the table test reads off their words.
    _m("framecache-alias-lend-not-deducted", "estimators/runtime/framecache.cl",
       "cdf_word_t rest = table[g] - (unit - table[l]);", "cdf_word_t rest = table[g];",
       ["envmap"], ["sun-1e6"],
       tests=("test_brdf_envmap.py::test_map_distribution_is_proportional_to_its_weights",)),
    # ---- the reference ---------------------------------------------------------------------------
    _m("reference-chord-for-arc", "estimators/runtime/reference.py",
       "theta = np.arctan2(s, np.sum(a * b, axis=-1, keepdims=True))",
       "theta = 2.0 * np.sin(np.arctan2(s, np.sum(a * b, axis=-1, keepdims=True)) / 2.0)",
       ["uniform"], ["constant", "tiny-faces"]),
    # The specular integral clips each row of points at the horizon and clamps c_n (reference.cl);
    # without both it integrates the lobe's part below the horizon with negative cosines.
    _m("reference-specular-without-cos-clamp", "estimators/runtime/reference.cl",
       ("    float16 row_lo = b_s > 0.0f ? clamp(edge, s_lo, s_hi) : s_lo;\n"
        "    float16 row_hi = b_s < 0.0f ? clamp(edge, s_lo, s_hi) : s_hi;\n",
        "* max(c_n, 0.0f)\n"),
       ("    float16 row_lo = s_lo + 0.0f * edge, row_hi = s_hi;\n", "* c_n\n"),
       ["bis"], ["grazing"]),
    _m("reference-cache-key-without-material", "estimators/runtime/reference.py",
       "for array in (g.mask, g.normal[g.mask], g.view[g.mask], g.kd[g.mask], g.ks[g.mask],\n"
       "                      g.shininess[g.mask], np.ascontiguousarray(env, np.float32), *masks):",
       "for array in (g.mask, g.normal[g.mask], g.view[g.mask], np.ascontiguousarray(env, np.float32)):",
       [], ["shininess"]),
    _m("reference-specular-normalisation-m+1", "estimators/runtime/reference.cl",
       "if (specular) result += rho_s * (m + 2.0f) / (2.0f * IBL_PI) * s;",
       "if (specular) result += rho_s * (m + 1.0f) / (2.0f * IBL_PI) * s;", ["uniform"], ["shininess"]),
    # ---- visibility (issue 22) -------------------------------------------------------------------
    # A cell index that slips by one column (the pool's and the scalar kernels', then the lanes'):
    # the estimators read the neighbouring cell's bit, the reference (which finds the cell from
    # the texel) the right one.
    _m("visibility-cell-index-off-by-one", COMMON,
       "         + clamp((int)floor(s * VIS_RES), 0, VIS_RES - 1);",
       "         + clamp((int)floor(s * VIS_RES) + 1, 0, VIS_RES - 1);",
       ["uniform"], ["occlusion"]),
    _m("visibility-lanes-cell-index-off-by-one", POOL,
       "return (face * VIS_RES + lanes_clamp_index(t, VIS_RES)) * VIS_RES + lanes_clamp_index(s, VIS_RES);",
       "return (face * VIS_RES + lanes_clamp_index(t, VIS_RES)) * VIS_RES\n"
       "           + min(lanes_clamp_index(s, VIS_RES) + 1, (lane_ints_t)(VIS_RES - 1));",
       ["envmap"], ["occlusion"]),
    # Shadow rays from the hit point itself: they hit the triangle they start on.
    _m("visibility-without-normal-offset", "scenes/visibility.py",
       "return point + OFFSET_SCALE * diagonal * geometric, covered",
       "return point, covered", ["uniform"], ["occlusion"]),
    # V on the estimators' side only: the exact reference integrates the unshadowed map.
    _m("visibility-missing-from-reference", "estimators/runtime/reference.cl",
       "lit = lit && texels_open(visibility, p, face, t - face * res * res + lane, res);",
       "lit = lit;", ["envmap"], ["occlusion"]),
    # ---- restir's temporal reuse in its edge cases (issue 36, class 2) ---------------------------
    # Weights that keep restir unbiased, so no z-test sees them: its unit tests read the weights.
    # The history's confidence scaled only where the map lost the pixel's light (restir.py's
    # rejected variant): where light came on, the history claims light it never sampled.
    _m("restir-history-share-one-sided", "estimators/restir.cl",
       "min(domain_scales[1] / domain_scales[0], domain_scales[0] / domain_scales[1])",
       "min(domain_scales[1] / domain_scales[0], 1.0f)", [],
       tests=["test_restir_weights.py::test_history_confidence_is_capped_and_scaled_by_the_change_of_the_map[1.0]"]),
    # No fallback where every lit coarse cell's centre is below the horizon: scale 0, and every
    # reservoir that reuse combines there is black.
    _m("restir-target-scale-without-fallback", "estimators/restir.cl",
       "float normaliser = total > 0.0f ? total : map_power(pyramid, res);",
       "float normaliser = total;", [],
       tests=["test_restir_weights.py::test_restir_finds_the_light_of_plane_grazing"]),
    # Each domain's MIS scale given to the other's target.
    _m("restir-gris-scales-swapped", "estimators/restir.cl",
       "float domain_scales[2] = {scales[p], temporal ? prev_scales[p] : 0.0f};",
       "float domain_scales[2] = {temporal ? prev_scales[p] : 0.0f, scales[p]};", [],
       tests=["test_restir_weights.py::test_temporal_resampling_weights_are_gris_with_confidence_and_scales"]),
    # ---- counts of work (issue 36, class 1): conformance's check_work_counts ----------------------
    # The "0 without visibility" rule of Estimate.shadow_rays: bis reports its N rays unmasked.
    _m("counts-shadow-rays-without-visibility", "estimators/base.py",
       "shadow_rays=float(evaluations if shadow_rays is None else shadow_rays) if gbuffer.has_visibility else 0.0,",
       "shadow_rays=float(evaluations if shadow_rays is None else shadow_rays),", ["bis"]),
    # An MIS variant's BRDF draws left out of the pool's count.
    _m("counts-pool-brdf-draws-uncounted", POOL,
       "*draws = draws_for(ticks[6]);", "*draws = 0;", ["balanced_mis"]),
    # The biased mode's spatial pass: row 0's neighbour targets (with V) counted as without.
    _m("counts-restir-biased-neighbour-rays-uncounted", "estimators/restir.cl",
       "*shadow_rays += i != j && visible_too ? 1.0f : 0.0f;",
       "*shadow_rays += i != j && unbiased ? 1.0f : 0.0f;", ["restir{unbiased=false}"]),
    # A re-initialised pixel's candidates' rays counted twice.
    _m("counts-smc-reinit-rays-counted-twice", "estimators/smc.cl",
       "rays[p] = (have_state ? rays[p] : 0.0f) + (float)M;",
       "rays[p] = (have_state ? rays[p] + (float)M : 0.0f) + (float)M;", ["smc"]),
    # ---- the metrics -----------------------------------------------------------------------------
    _m("metrics-exposure-from-estimate", "harness/protocol/metrics.py",
       "lab = to_lab(tonemap(estimate[mask], self.k))",
       "lab = to_lab(tonemap(estimate[mask], exposure(estimate, mask)))", [], ["constant"], budgets=True),
    _m("metrics-tonemap-without-exposure-in-denominator", "harness/protocol/metrics.py",
       "return rgb * (k / (1.0 + k * luminance(rgb)))[..., None]",
       "return rgb * (k / (1.0 + luminance(rgb)))[..., None]", [], ["constant"], budgets=True),
    _m("metrics-relmse-without-square", "harness/protocol/metrics.py",
       "return float(np.mean((x - r) ** 2 / (r * r + 0.01)))",
       "return float(np.mean((x - r) ** 2 / (r + 0.01)))", [], ["constant"], budgets=True),
    # ---- issue 36, class 3: distributed bookkeeping (tests/test_lost_units.py) --------------------
    _m("cluster-lost-chain-spares-the-killed-unit", "harness/protocol/distributed.py",
       "lost += [k for unit in units[index:] for k in unit]",
       "lost += [k for unit in units[index + 1:] for k in unit]", [],
       tests=["test_lost_units.py::test_a_run_that_lost_cells_never_ends_complete[before-0-in-order]"]),
    _m("cluster-lost-calibrator-strands-its-budget", "harness/protocol/distributed.py",
       "submit(waiting[budget].pop(0), 0, {})", "waiting[budget].pop(0)", [],
       tests=["test_lost_units.py::test_a_run_that_lost_cells_never_ends_complete[mid-0-newest-first]"]),
    _m("runner-trusts-the-cluster-s-lost-count", "harness/protocol/runner.py",
       "missing = set(lost) | (self.todo - self.journalled)", "missing = set(lost)", [],
       tests=["test_lost_units.py::test_a_unit_that_returns_without_a_cell_s_row_leaves_the_run_incomplete"]),
    # ---- issue 36, class 4: the ranking's edges (tests/test_ranking_edges.py) ---------------------
    _m("ranking-end-tolerance-exclusive", "harness/protocol/ranking.py",
       "and abs(t - budget_ms) <= TOLERANCE * budget_ms and t in span]",
       "and abs(t - budget_ms) < TOLERANCE * budget_ms and t in span]", [],
       tests=["test_ranking_edges.py::test_an_equal_time_cell_at_the_fast_end_is_read_within_its_tolerance"]),
    _m("ranking-headlines-more-than-twice-apart", "harness/protocol/ranking.py",
       ">= BUDGET_SPACING for c in chosen)", "> BUDGET_SPACING for c in chosen)", [],
       tests=["test_ranking_edges.py::test_budgets_exactly_twice_apart_and_reaching_exactly_half_are_both_headlines"]),
    _m("ranking-budget-at-fastest-cell-not-reached", "harness/protocol/ranking.py",
       "if budget_ms < span[0] and not at_end:", "if budget_ms <= span[0] and not at_end:", [],
       tests=["test_ranking_edges.py::test_a_budget_equal_to_a_cells_time_reads_that_cell"]),
    # ---- issue 36, class 5: per-device times (tests/test_time_pooling.py) -------------------------
    _m("time-refused-over-devices-only-for-time-ms", "harness/protocol/stats.py",
       "if is_time_column(column) and len(devices(rows)) > 1:",
       "if column == TIME_COLUMN and len(devices(rows)) > 1:", [],
       tests=["test_time_pooling.py::test_every_time_column_is_refused_over_two_devices[time_ms_host]"]),
    _m("check-time-ratio-pools-devices", "harness/protocol/budgets.py",
       'if any(rule.time_ratio for rule in rules):', "if False:", [],
       tests=["test_time_pooling.py::test_check_refuses_a_time_ratio_over_two_devices[time_ms_shade]"]),
    # ---- issue 36, class 6: device settings (tests/test_device_settings.py) ------------------------
    _m("pool-lanes-16-from-preferred-8", "estimators/runtime/device.py",
       "(16 if device.preferred_vector_width_float >= 16 else 8)",
       "(16 if device.preferred_vector_width_float >= 8 else 8)", [],
       tests=["test_device_settings.py::test_the_lane_width_is_16_where_the_device_prefers_16_floats_else_8"]),
    _m("float-path-forgets-lane-override", "harness/verify/portability.py",
       "return Compute(compute.info, fp64=False, lanes=compute.pool_lanes)",
       "return Compute(compute.info, fp64=False)", [],
       tests=["test_device_settings.py::test_an_explicit_lane_width_wins_over_the_devices"]),
    # ---- issue 36, class 7: the checkers themselves (tests/test_checkers.py) -----------------------
    _m("portability-nonfinite-baseline-passes", "harness/verify/portability.py",
       "elif not (np.isfinite(got).all() and np.isfinite(expected).all()):",
       "elif not np.isfinite(got).all():", [],
       tests=["test_checkers.py::test_a_non_finite_value_fails_the_comparison_wherever_it_is"]),
    _m("doctor-masked-reference-skips-twin", "harness/verify/doctor.py",
       "if portability.split_case(outcome.case)[0] in (\"reference\", \"light_pdf\"):",
       "if outcome.case in (\"reference\", \"light_pdf\"):", [],
       tests=["test_checkers.py::test_doctor_holds_every_case_with_a_twin_to_it_masked_variants_included"]),
    _m("doctor-devices-not-held-to-default", "harness/verify/doctor.py",
       "expected = None if held_to is None else baseline(held_to).get(case)", "expected = None", [],
       tests=["test_checkers.py::test_doctor_flags_each_device_whose_arrays_carry_a_planted_fault"]),
)


def catalogue(names=None, plugins: bool = True) -> list[Mutant]:
    """The catalogue: :data:`HARNESS_MUTANTS` and every registered estimator's own mutants (only
    the built-ins' without ``plugins``), or the named mutants of it (ValueError naming an unknown
    one)."""
    from iblbench.estimators.base import own
    from iblbench.estimators.registry import builtin_names, estimator_classes

    chosen = [cls for cls in estimator_classes() if plugins or cls.name in builtin_names()]
    every = [*HARNESS_MUTANTS, *(Mutant.declared(cls, mutant) for cls in chosen
                                 for mutant in own(cls, "mutants"))]
    by_name = {m.name: m for m in every}
    if not names:
        return every
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise ValueError(f"unknown mutant(s) {', '.join(unknown)}; known: {', '.join(by_name)}")
    return [by_name[n] for n in names]


@dataclasses.dataclass
class Outcome:
    """What the layers said about one mutant: ``rejected_by`` maps each layer that ran to the
    first failure it reported ("" where it passed); ``killed_by`` is the first rejecting layer."""

    mutant: Mutant
    rejected_by: dict[str, str]
    seconds: float
    error: str = ""

    @property
    def killed_by(self) -> str | None:
        return next((layer for layer, why in self.rejected_by.items() if why), None)

    @property
    def killed(self) -> bool:
        return self.killed_by is not None


def in_checkout(name: str) -> pathlib.Path | None:
    """The repository's ``name`` beside the packages (budgets.toml, tests/) where this is a
    source checkout that has it, else None."""
    path = _package_folder("iblbench.harness").resolve().parent / name
    return path if path.exists() else None


def copy_sources(folder: pathlib.Path, packages=()) -> pathlib.Path:
    """Copy the installed ``iblbench`` packages into ``folder/iblbench``, and each other
    top-level package of ``packages`` (a plugin's) into ``folder``; returns ``folder``.
    The top-level package (the Python API) comes too: on ``PYTHONPATH`` first, the copy must
    be a regular package, or an installed one would shadow it."""
    (folder / "iblbench").mkdir(parents=True)
    api = _package_folder("iblbench")
    for entry in api.iterdir():          # the API: __init__, cli and commands/
        if entry.name in PACKAGES or entry.name == "__pycache__":
            continue
        if entry.is_dir():
            shutil.copytree(entry, folder / "iblbench" / entry.name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        elif entry.suffix == ".py":
            shutil.copy(entry, folder / "iblbench")
    for package in PACKAGES:
        shutil.copytree(_package_folder(f"iblbench.{package}"), folder / "iblbench" / package,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for package in set(packages) - {"iblbench"}:
        shutil.copytree(_package_folder(package), folder / package,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return folder


def _package_folder(package: str) -> pathlib.Path:
    """The folder of an installed package, found without importing it: the mutants copy files,
    so the API above the harness is located, never imported."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise ValueError(f"{package!r} is not an installed package (a mutant's files must be "
                         f"in a package, with its estimator's module)")
    return pathlib.Path(next(iter(spec.submodule_search_locations)))


def run_mutant(mutant: Mutant, layers=LAYERS, all_layers: bool = False, timeout: float = 600.0,
               cache: pathlib.Path | None = None, workspace: pathlib.Path | None = None) -> Outcome:
    """Apply ``mutant`` to a temporary copy and run ``layers`` on it in a fresh interpreter.

    ``cache``: the reference cache it uses (default: its own, fresh).  Mutants may share one:
    a reference's key hashes its kernel, its host code and its inputs, so a mutant of those
    never reads a clean entry (and the cache-key mutant only mixes up its own entries).

    ``workspace``: the folder the copy goes into, emptied first (default: a fresh temporary
    one).  PoCL keys its kernel cache by the preprocessed source, whose line markers name each
    file's path, so mutants that run one after another in one workspace rebuild only the
    programs that their bug changes instead of every kernel they use."""
    start = time.perf_counter()
    with contextlib.ExitStack() as stack:
        if workspace is None:
            tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix=f"iblbench-mutant-{mutant.name}-"))
        else:
            if workspace.exists():   # last mutant's copy: a failure to remove it must show
                shutil.rmtree(workspace)
            workspace.mkdir(parents=True)
            tmp = str(workspace)
        root = copy_sources(pathlib.Path(tmp), [mutant.package])
        mutant.apply(root)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root)] + [p for p in [os.environ.get("PYTHONPATH")] if p]),
                   IBLBENCH_CACHE=str(cache or root / "cache"), IBLBENCH_CHI2_PLOTS=str(root / "chi2"))
        budgets, tests = in_checkout("budgets.toml"), in_checkout("tests")
        command = [sys.executable, "-m", "iblbench.harness.verify.mutants", json.dumps(dataclasses.asdict(mutant)),
                   ",".join(layers), "all" if all_layers else "first", str(budgets) if budgets else "-",
                   str(tests) if tests else "-"]
        try:
            done = subprocess.run(command, env=env, cwd=tmp, capture_output=True, text=True,
                                  timeout=timeout)
        except subprocess.TimeoutExpired:
            return Outcome(mutant, {}, time.perf_counter() - start, f"timed out after {timeout:.0f} s")
    lines = [line for line in done.stdout.splitlines() if line.startswith(RESULT_TAG)]
    if not lines:
        tail = (done.stdout + done.stderr)[-2000:]
        return Outcome(mutant, {}, time.perf_counter() - start, f"no result (exit {done.returncode}): {tail}")
    return Outcome(mutant, json.loads(lines[-1][len(RESULT_TAG):]), time.perf_counter() - start)


def run_catalogue(mutants, layers=LAYERS, all_layers: bool = False, jobs: int = 2,
                  progress=None) -> list[Outcome]:
    """:func:`run_mutant` over ``mutants``, ``jobs`` at a time (kernel builds and imports are
    single-threaded; two overlap well on two cores); ``progress(outcome)`` after each.  Each of
    the ``jobs`` workers keeps one workspace, so the kernel cache serves its unmutated programs."""
    with tempfile.TemporaryDirectory(prefix="iblbench-mutants-cache-") as cache, \
            concurrent.futures.ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        workspaces = queue.SimpleQueue()
        for slot in range(max(1, jobs)):
            workspaces.put(pathlib.Path(cache) / f"workspace-{slot}")

        def run_in_a_free_workspace(mutant):
            workspace = workspaces.get()
            try:
                return run_mutant(mutant, layers, all_layers, cache=pathlib.Path(cache) / "references",
                                  workspace=workspace)
            finally:
                workspaces.put(workspace)

        futures = [pool.submit(run_in_a_free_workspace, m) for m in mutants]
        outcomes = []
        for future in futures:
            outcomes.append(future.result())
            if progress:
                progress(outcomes[-1])
    return outcomes


# ---- the layers, run inside the mutated copy ---------------------------------------------------

def _first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0] if text else ''}"[:300]


def _conformance(mutant: Mutant, compute) -> str:
    from iblbench.harness.verify import conformance
    from iblbench.harness.protocol.sweep import parse_estimator

    h = conformance.Harness(compute)
    for name in mutant.estimators:
        estimator = parse_estimator(name).make()
        for check in conformance.yield_checks(estimator):
            try:
                check(estimator, h)
            except Exception as error:   # an exception is a rejection too (check_estimator raises)
                return f"{name} {check.__name__}: {_first_line(error)}"
    return ""


def _stress(mutant: Mutant, compute) -> str:
    from iblbench.harness.verify import stress
    from iblbench.harness.protocol.sweep import parse_estimator

    names = mutant.estimators or ("uniform",)
    estimators = {name: parse_estimator(name).make() for name in names}
    try:
        table = stress.run_stress(estimators, mutant.stress, stress.SMALL, compute, progress=False)
    except Exception as error:
        return f"stress: {_first_line(error)}"
    failed = table[table.status == "FAIL"]
    return "; ".join(f"{r.case}/{r.estimator}: {r.failures}"[:300] for r in failed.itertuples())


def _budgets(budgets: str) -> str:
    from iblbench.harness.protocol import budgets as budget_check

    if budgets == "-":
        return ""
    with tempfile.TemporaryDirectory() as out:
        done = subprocess.run([sys.executable, "-m", "iblbench.cli", "run", "--config", "quick",
                               "--out", out, "--repeats", "1", "--no-flip"], capture_output=True, text=True)
        if done.returncode != 0:
            return f"quick sweep failed (exit {done.returncode}): {(done.stdout + done.stderr)[-300:]}"
        checks, verdict, status = budget_check.check(out, budgets)
    return "" if status == 0 else verdict[:300]


def _tests(mutant: Mutant, tests: str) -> str:
    """The mutant's named tests, run by pytest in a fresh interpreter on the mutated copy (first
    on ``PYTHONPATH``); the first failing test's summary line when any fails."""
    if tests == "-":
        return ""
    nodes = [str(pathlib.Path(tests) / node) for node in mutant.tests]
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-n", "0", "-p", "no:randomly",
                           "-p", "no:cacheprovider", "--rootdir", str(pathlib.Path(tests).parent),
                           "--tb=line", *nodes], capture_output=True, text=True)
    if done.returncode == 0:
        return ""
    failed = [line for line in done.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
    return (failed[0] if failed else f"pytest exit {done.returncode}: {done.stdout[-200:]}")[:300]


def _child(fields: str, layers: str, mode: str, budgets: str, tests: str) -> None:
    from iblbench.estimators.runtime.device import get_compute

    mutant = Mutant(**{key: tuple(value) if isinstance(value, list) else value
                       for key, value in json.loads(fields).items()})
    compute = get_compute()
    results: dict[str, str] = {}
    # The tests a mutant names are the layer its entry says catches it, and the cheapest (seconds,
    # where conformance builds and renders every variant of its estimators): they run first.
    ordered = sorted(layers.split(","), key=lambda layer: not (layer == "tests" and mutant.tests))
    for layer in ordered:
        if layer == "conformance" and mutant.estimators:
            results[layer] = _conformance(mutant, compute)
        elif layer == "stress" and mutant.stress:
            results[layer] = _stress(mutant, compute)
        elif layer == "budgets" and mutant.budgets:
            results[layer] = _budgets(budgets)
        elif layer == "tests" and mutant.tests:
            results[layer] = _tests(mutant, tests)
        if mode == "first" and any(results.values()):
            break
    print(RESULT_TAG + json.dumps(results), flush=True)


if __name__ == "__main__":
    _child(*sys.argv[1:6])
