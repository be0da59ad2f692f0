"""The estimator contract of ARCHITECTURE.md §Estimator contract: parameters, capability tags, requirements, kernels.

A plugin subclasses :class:`Estimator`, sets ``name``, ``Params`` (a dataclass with documented
defaults), ``settings`` (a :class:`Setting` off the default for every parameter), ``tags``,
``requires`` and ``kernel_files``, and implements ``render``.  The optional
``sample_directions``/``pdf`` hooks feed the χ² test of ``check_estimator``.

What the harness keeps about an estimator it reads from the class too (each optional, with the
default below): ``cost`` (a :class:`KernelCost`, for ``iblbench perf``'s FLOP and roofline
figures), ``perf_budget`` (its (spp, repeats) there), ``extra_columns`` (the labels of its
``Estimate.extras``), ``portability_variants`` (configurations that ``iblbench doctor`` runs
besides the defaults), ``sweep`` (its part in the default sweep, a :class:`SweepPart`) and
``mutants`` (its own bugs for ``iblbench selftest``, in files of its own package).
``portability_variants``, ``sweep`` and ``mutants`` name the class's own configurations and
files, so a subclass does not inherit them (:func:`own`).
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import math
from typing import ClassVar

import numpy as np


@dataclasses.dataclass(frozen=True)
class Tags:
    """Capabilities that decide which conformance checks apply."""

    unbiased: bool = True          # mean over seeds equals the reference (z-test)
    temporal: bool = False         # keeps state across frames; reset() clears it
    has_pdf: bool = False          # sample_directions/pdf hooks exist (χ² test)
    deterministic: bool = True     # same seed, same device → same image
    has_limit: bool = False        # biased but consistent: limit_map hook, its exact integral


@dataclasses.dataclass(frozen=True)
class Setting:
    """One parameter off its default, which ``check_estimator`` holds to doing something, and
    what its docstring says it does (``conformance.check_settings_differ``,
    ``check_setting_properties``).

    ``parameter`` takes ``value``, with ``context`` the other parameters it needs or is meant
    under (``mis_compensation`` needs ``mis = "brdf"``).  Its *base* is the same context with
    ``parameter`` at its default: at one seed, the two render different images.  ``says`` names
    the property the parameter's docstring states, a key of ``conformance.SETTING_PROPERTIES``
    that checks it on the setting and its base; "" where the suite has no such check (the
    estimator's own tests hold it: ``uniform_faces``, ``lod_bias``, smc's re-init rules)."""

    parameter: str
    value: object
    context: dict = dataclasses.field(default_factory=dict)
    says: str = ""


@dataclasses.dataclass
class Estimate:
    """One rendered frame.

    ``radiance`` float32 ``[H, W, 3]``; ``used`` and ``effective`` float32 ``[H, W]``: the β-weighted
    counts of evaluated samples and of those with a strictly positive cosine (Lu 2013);
    ``evaluations``: integrand evaluations per covered pixel (mean); ``nonfinite``: count of
    non-finite output values; ``timings_ms``: device time per stage (``sample``, ``shade``);
    ``extras``: estimator-specific per-frame scalars (e.g. ``smc``'s ``ess`` and ``reinits``),
    which the runner writes as extra result columns after the fixed ones.  ``shadow_rays``: the
    visibility queries V(x, ω) per covered pixel (mean; 0 on a G-buffer without visibility): the
    integrand evaluations, but where an estimator's docstring counts otherwise (``bis``, whose
    target leaves V out: its N resampled samples; ``smc`` and ``restir``, which reuse a
    direction's V).  ``Estimator.work_counts`` states both counts, and ``conformance.check_work_counts``
    holds every path to them.
    """

    radiance: np.ndarray
    used: np.ndarray
    effective: np.ndarray
    evaluations: float
    nonfinite: int
    timings_ms: dict[str, float]
    extras: dict[str, float] = dataclasses.field(default_factory=dict)
    shadow_rays: float = 0.0


@dataclasses.dataclass(frozen=True)
class CountFrame:
    """One frame of a sequence that ``conformance.check_work_counts`` renders, in order, after
    ``reset()``: the frame's ``cache`` (a FrameCache: its map ``cache.env``), and the render's
    ``spp`` and ``seed``."""

    cache: object
    spp: int
    seed: int


@dataclasses.dataclass(frozen=True)
class WorkCounts:
    """The work a frame's render must report, as its docstring counts it (an estimator's
    ``work_counts``): ``evaluations`` and ``shadow_rays`` per covered pixel (arrays over the
    covered pixels, or one number for all), the shadow rays as on a G-buffer with visibility
    (without it the render must report 0); ``extras``: the ``Estimate.extras`` that count work
    (``smc``'s ``reinits``, ``restir``'s ``neighbours``), each the value the render must report."""

    evaluations: object
    shadow_rays: object
    extras: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Limit:
    """Lane-operations of one of ``iblbench perf``'s limit probes (a key of
    ``estimators.runtime.probes.PROBE_FLOPS``: ``phong_power``, ``philox``, ``divide``,
    ``gather``, ``dependent_load``) that an estimator's shading kernel runs per evaluation slot
    of its loop group ``group`` (:meth:`KernelCost.slots`), per sample and per pixel; ``why``
    says where in the kernel."""

    probe: str
    per_eval: float = 0.0
    per_sample: float = 0.0
    per_pixel: float = 0.0
    group: int = 0
    why: str = ""


@dataclasses.dataclass(frozen=True)
class KernelCost:
    """Analytic FLOPs and DRAM bytes of an estimator's shading kernel, per integrand evaluation,
    per sample and per pixel: an estimate, counted by reading the kernel by the rules of
    ``iblbench.harness.studies.perf``'s docstring; ``derivation`` says how (perf.html shows it).

    ``limits`` (:class:`Limit`) are the probe operations it runs; perf bounds the kernel's time
    by them (its ``limit_fraction``).  ``lane_loops`` groups a pixel's evaluations: (loops,
    share) where ``share`` of the evaluations run in ``loops`` loops (0: one a sample) of blocks
    of POOL_LANES lanes, split evenly, each loop's last block masked; () is one group of
    unpadded slots.
    ``scalar``: the kernel runs one evaluation at a time per work item in scalar code that PoCL
    does not vectorise across work items (``POCL_VECTORIZER_REMARKS=1`` reports no loop of the
    device's width), so each operation and FLOP holds a whole vector's time: POOL_LANES
    lane-operations.  Per-pixel work is scalar in every kernel that runs a pixel a work item
    and its samples in explicit lanes, so it counts POOL_LANES lane-operations too."""

    flops_per_eval: float
    flops_per_sample: float
    bytes_per_sample: float
    flops_per_pixel: float
    bytes_per_pixel: float
    derivation: str = ""
    limits: tuple[Limit, ...] = ()
    lane_loops: tuple[tuple[int, float], ...] = ()
    scalar: bool = False

    def per_sample(self, spp: int, evaluations: float) -> tuple[float, float]:
        """(FLOPs, bytes) per sample of a render at ``spp`` with ``evaluations`` per pixel."""
        flops = self.flops_per_sample + (self.flops_per_eval * evaluations + self.flops_per_pixel) / spp
        return flops, self.bytes_per_sample + self.bytes_per_pixel / spp

    def slots(self, evaluations: float, lanes: int, spp: int) -> list[float]:
        """Evaluation slots a pixel runs in each group of :attr:`lane_loops`, masked lanes
        included, for ``evaluations`` per pixel (a mean) in blocks of ``lanes`` at ``spp``."""
        if not self.lane_loops:
            return [evaluations]
        return [(loops or spp) * lanes * math.ceil(evaluations * share / (loops or spp) / lanes - 1e-9)
                for loops, share in self.lane_loops]

    def executed_per_sample(self, spp: int, evaluations: float, lanes: int) -> dict[str, float]:
        """Per sample at ``spp``: the FLOPs run (masked slots included) under ``"flops"``, and
        each limit probe's lane-operations under its name: per-pixel ones × ``lanes``, all of
        them where :attr:`scalar`."""
        slots, width = self.slots(evaluations, lanes, spp), lanes if self.scalar else 1
        counts = {"flops": width * (self.flops_per_sample + self.flops_per_eval * sum(slots) / spp)
                  + lanes * self.flops_per_pixel / spp}
        for limit in self.limits:
            counts[limit.probe] = (counts.get(limit.probe, 0.0) + lanes * limit.per_pixel / spp
                                   + width * (limit.per_sample + limit.per_eval * slots[limit.group] / spp))
        return counts


@dataclasses.dataclass(frozen=True)
class ExtraColumn:
    """How the report shows one ``Estimate.extras`` column: ``label`` names it in titles,
    ``axis`` labels its plot's axis, ``log`` draws that axis logarithmic."""

    label: str
    axis: str
    log: bool = True


@dataclasses.dataclass(frozen=True)
class SweepPart:
    """An estimator's part in the default sweep (``estimators = "declared"`` in a sweep file):
    its ``labels`` (``name`` or ``name{param=value,...}``) at its ``spp`` levels (None: the
    sweep's default levels); ``order`` places them in the sweep's list (lower first, ties by
    name), which orders the results table and the report's colours."""

    labels: tuple[str, ...]
    spp: tuple[int, ...] | None = None
    order: float = float("inf")


@dataclasses.dataclass(frozen=True)
class Mutant:
    """One realistic bug in the estimator's own files, for ``iblbench selftest``
    (:mod:`iblbench.harness.verify.mutants`): ``old`` → ``new`` (each occurring exactly once) in
    ``path``, relative to the folder of the package that holds the estimator's module (so a
    plugin names its own files).  ``estimators``: the configurations whose checks must reject
    it, as a sweep names them (default: the estimator itself); ``stress``: the stress cases that
    guard the broken code; ``budgets``: whether the quick sweep's error budgets apply;
    ``expect_killed_after``: the check still to land that will catch it (it may survive);
    ``tests``: unit tests (pytest node ids in the repository's ``tests/``) that must fail on it."""

    name: str
    path: str
    old: str | tuple[str, ...]   # a tuple: several places of one bug, replaced pairwise with new
    new: str | tuple[str, ...]
    estimators: tuple[str, ...] = ()
    stress: tuple[str, ...] = ()
    budgets: bool = False
    expect_killed_after: str = ""
    tests: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class NoParams:
    """This estimator has no parameters."""


class Estimator:
    name: ClassVar[str] = ""
    Params: ClassVar[type] = NoParams
    settings: ClassVar[tuple[Setting, ...]] = ()   # at least one per parameter of Params
    tags: ClassVar[Tags] = Tags()   # an instance may set its own where a parameter changes them (restir)
    requires: ClassVar[tuple[str, ...]] = ()
    kernel_files: ClassVar[tuple[str, ...]] = ()
    max_spp: ClassVar[int | None] = None   # the most spp render accepts; None: no bound
    cost: ClassVar[KernelCost | None] = None   # None: perf gives no FLOP or roofline figures
    perf_budget: ClassVar[tuple[int, int] | None] = None   # (spp, repeats) in perf; None: its defaults
    extra_columns: ClassVar[dict[str, ExtraColumn]] = {}   # Estimate.extras key -> how it is shown
    # Not inherited (:func:`own`): labels (``name{param=value}``) of the estimator's configurations
    # that run kernel paths its defaults do not, for the portability set (``iblbench doctor``);
    portability_variants: ClassVar[tuple[str, ...]] = ()
    # its part in the default sweep (None: it takes none);
    sweep: ClassVar[SweepPart | None] = None
    # and its own mutants (:class:`Mutant`).
    mutants: ClassVar[tuple[Mutant, ...]] = ()

    def __init__(self, params=None, **overrides):
        base = params if params is not None else self.Params()
        self.params = dataclasses.replace(base, **overrides)

    def render(self, gbuffer, cache, spp: int, seed: int) -> Estimate:
        raise NotImplementedError

    def reset(self) -> None:
        """Forget state carried across frames (temporal estimators)."""

    def work_counts(self, gbuffer, frames) -> list[WorkCounts] | None:
        """The counts of work (:class:`WorkCounts`) that renders of ``frames`` (:class:`CountFrame`,
        in order after ``reset()``) on the host G-buffer ``gbuffer`` must report, computed in
        Python from the docstring's formula and the inputs, never read from a render:
        ``conformance.check_work_counts`` holds every path to them.  None: not declared."""
        return None

    def limit_map(self, cache):
        """The map whose exact integral a ``has_limit`` estimator converges to (``fis``: its
        filtered map); the conformance suite's limit check needs it."""
        raise NotImplementedError(f"{self.name or type(self).__name__} is tagged has_limit but "
                                  f"defines no limit_map(cache) hook")

    @classmethod
    def version(cls) -> str:
        return estimator_version(cls)

    @classmethod
    def kernel_package(cls) -> str:
        """The package whose data holds ``kernel_files``: that of the class that declares them,
        so a subclass elsewhere (a plugin tweaking a built-in) that adds none keeps its base's."""
        owner = next(k for k in cls.__mro__ if "kernel_files" in vars(k))
        return owner.__module__.rpartition(".")[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params})"


@functools.lru_cache(maxsize=None)
def estimator_version(cls: type) -> str:
    """Hash of everything an estimator's output depends on: its Python source (and its bases'),
    its kernels, every shared kernel include, and the frame-cache code when it requires products."""
    import iblbench.estimators.runtime.framecache as framecache
    import iblbench.estimators.runtime.mips as mips
    from iblbench.estimators.runtime.device import kernel_path

    digest = hashlib.sha256()
    for klass in cls.__mro__:
        if klass is not object:
            digest.update(inspect.getsource(inspect.getmodule(klass)).encode())
    for filename in cls.kernel_files:
        digest.update(kernel_path(cls.kernel_package(), filename).read_bytes())
    for shared in sorted(kernel_path("iblbench.estimators.runtime", "kernels").glob("*.cl")):
        digest.update(shared.read_bytes())
    if cls.requires:
        digest.update(inspect.getsource(framecache).encode())
        digest.update(kernel_path("iblbench.estimators.runtime", "framecache.cl").read_bytes())
        digest.update(inspect.getsource(mips).encode())
        digest.update(kernel_path("iblbench.estimators.runtime", "mips.cl").read_bytes())
    return digest.hexdigest()[:12]


def own(cls: type, attribute: str):
    """``cls``'s own declaration of ``attribute`` (its class body's), or :class:`Estimator`'s
    default: for declarations a subclass must not inherit (``portability_variants``, ``sweep``,
    ``mutants``: they name its base's configurations and files)."""
    return vars(cls).get(attribute, getattr(Estimator, attribute))


def specular_lobe_defines(gbuffer) -> dict:
    """Kernel defines of an estimator that samples the Phong BRDF: an all-diffuse G-buffer
    compiles the specular-lobe sampling branch out (ARCHITECTURE.md §Data flow), and the G-buffer's own
    (:func:`visibility_defines`)."""
    lobe = {"SPECULAR_LOBE": 0} if gbuffer is not None and gbuffer.is_diffuse else {}
    return {**visibility_defines(gbuffer), **lobe}


def visibility_defines(gbuffer) -> dict:
    """The kernel defines every kernel that reads a DeviceGBuffer is built with: its visibility
    (``DeviceGBuffer.defines``; none without a G-buffer, for the χ² hooks)."""
    return dict(gbuffer.defines) if gbuffer is not None else {}


def read_estimate(compute, gbuffer, radiance, counts, evaluations: float,
                  timings_ms: dict[str, float], planar: bool = False,
                  shadow_rays: float | None = None) -> Estimate:
    """Copy a kernel's per-pixel outputs (float4 radiance, float2 used/effective) into an Estimate.

    ``shadow_rays``: the visibility queries per pixel where they are not the ``evaluations``;
    0 whatever it says on a G-buffer without visibility.

    ``planar``: the kernel wrote planes of ``gbuffer.launch_size`` floats instead (R, G, B; used,
    effective), of which the first ``gbuffer.count`` are the image's."""
    if planar:
        rgb = compute.to_host(radiance, (3, gbuffer.launch_size), np.float32)[:, :gbuffer.count].T
        used_effective = compute.to_host(counts, (2, gbuffer.launch_size), np.float32)[:, :gbuffer.count].T
    else:
        rgb = compute.to_host(radiance, (gbuffer.count, 4), np.float32)[:, :3]
        used_effective = compute.to_host(counts, (gbuffer.count, 2), np.float32)
    return Estimate(
        radiance=gbuffer.scatter(rgb),
        used=gbuffer.scatter(used_effective[:, 0]),
        effective=gbuffer.scatter(used_effective[:, 1]),
        evaluations=float(evaluations),
        nonfinite=int(np.count_nonzero(~np.isfinite(rgb))),
        timings_ms=timings_ms,
        shadow_rays=float(evaluations if shadow_rays is None else shadow_rays) if gbuffer.has_visibility else 0.0,
    )
