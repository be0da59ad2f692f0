"""``iblbench perf``: the throughput of every estimator, against the device's roofline and a
NumPy floor, measured side by side in one run.

Per (scene, estimator) it renders one frame ``repeats`` times after one untimed warm-up render,
interleaved in rounds (round r renders every estimator once, in an order of its own, seeded,
then the NumPy floor and the peer, so slow drifts of a shared machine hit them all alike), and
reports the median, min and IQR of each device stage (OpenCL profiling events, ARCHITECTURE.md
§Timing convention).  Each round starts once the host's threads are quiet
(``timing.wait_for_quiet_threads``): Dr.Jit's pool spins on after the peer's render, and with
one fixed order the round's first estimator ran 1.2-1.3× slower than when placed later
(hierarchical{mis="brdf"} 20.6 against 16.3 ms at sphere-sun, 256², issue 37):

- ``build``: the per-frame FrameCache products the estimator requires (the map's upload and,
  where required, the CDFs), from ``FrameCache.timings_ms``; every repeat builds a fresh cache,
  as a new frame would (reusing the dead cache's device buffers, as a renderer keeps them
  resident).  ``cdf_ms`` is the CDF build alone and ``cdf_bound_ms`` its copy-bandwidth bound:
  the bytes it must move (:func:`cdf_build_bytes`) over the copy bandwidth measured by a copy
  launch straight before each timed build (:class:`CopyProbe`), so that on a shared machine a
  build and its bound see the same load;
- ``sample`` and ``shade``: ``Estimate.timings_ms`` (the pool estimators' ``sample`` is the
  draw of the light-sample pool and its layout as planes, with ``balanced_mis``'s shared BRDF
  numbers; ``havran``'s is the device time of its map's CDFs, its K lights and their filter;
  ``smc``'s the build of its map proposal's alias tables, ``map_alias_pairs`` and
  ``map_alias_columns``);
- the rates divide by the render's device time, sample + shade (build does not scale with spp
  and is reported beside them).

Temporal estimators (``havran``, ``smc``) are ``reset()`` before every render, so each timed
render is the first frame of a sequence, what an ``iblbench run`` cell of a static scene
renders (``smc``: its alias tables' build, then its BIS initialisation, M + N evaluations per
pixel).

The roofline.  ``fma_throughput`` (``estimators/runtime/probes.cl``: independent FMA chains, two FLOPs each) gives
the device's FLOP rate and ``copy_bandwidth`` (one float4 read and one written per work item,
buffers much larger than the last-level cache) its bandwidth, counted as bytes read + bytes
written (STREAM's convention; a CPU's write-allocate reads are not counted).  Both run on the
estimators' own context and queue, as the median of ``repeats`` launches after a warm-up (the
FMA launch sized to take at least ``ROOF_MIN_MS``, the copy buffers ``copy_size``).  An estimator's shading kernel (its ``shade`` stage) then
reaches ``gflops`` = FLOPs/s and ``gbytes_per_s`` = bytes/s by the counts of its ``cost``,
and its roofline fraction is achieved / attainable with attainable = min(peak FLOP rate,
intensity × peak bandwidth), i.e. max(gflops / peak_gflops, gbytes_per_s / peak_gbps).

FLOP and byte counts (each estimator's ``cost``) are estimates, counted by reading the kernels as
they are as of this revision (``estimators/*.cl``, ``estimators/runtime/kernels/*.cl``), rounded, good to
perhaps ±30%; they must be re-derived whenever a shading kernel changes (nothing checks them
against the kernels).  FLOPs, counted per work item as the source reads after the compiler's exact
simplifications:
- an add, subtract, multiply, divide, sqrt, min, max, floor or ceil is one, a·b + c two (fused
  or not); compares, selects, sign flips, fabs, int ↔ float conversions and all integer work
  (Philox, CDF searches, indexing, tick arithmetic) are not counted;
- the polynomial steps count their real FLOPs (no library exp2, log2, sin or cos is left on a
  hot path): ``phong_power`` c^m = 35 (its log2 half, the atanh series, 16; its exp2 half, a
  Taylor polynomial to r⁷ over the float's bits, 19), ``sincos_turn`` 24, a direction about an
  axis 68 (its basis 13, sincos_turn, the rest 31), ``phong_mixture_pdf`` 5, a cube-map texel
  lookup 10, ``light_pdf_on_face`` 26, a map draw by the alias tables (``sir.cl``) 28 (two
  alias draws 6, the face-plane point 10, its unit direction 12);
- a factor that is the same for every sample of a pixel (kd/π, (m+2)/2π, 1/(m+1), Y(kd), the
  bases about n and r) counts once per pixel, as the compiler hoists it; a common subexpression
  once; products by constant ±1, 0 or 1 (a corner of Eq. 3, a proposal with env_pick = 0)
  nothing, as they fold.
Evaluations are Estimate.evaluations, the useful ones: the pool kernels run their draws in
blocks of 16 lanes and a strategy's last block is masked (uniform at spp 64: 6 × 16 lanes for 66
draws), and bis/smc pad their pixels to whole groups; the masked lanes are not counted, so a
fraction is one of useful work.
Bytes: the roofline's DRAM traffic, i.e. what each pixel must move (its four G-buffer float4s in,
64 B, its outputs out, and smc's particles), with the map, CDFs, face integrals, light pool,
shared BRDF numbers, light set and smc's alias tables and texels taken as cache-resident: they
are shared by every pixel, and at the default env 64 they fit in the last-level cache
(6·64²·(16 + 8) B ≈ 0.6 MB, the CDFs' words or the alias tables' beside the texels); so are
bis's and smc's per-group scratch blocks (64 pixels × (M cumulative bounds in acc_t, N chosen
candidate ints, 3 acc_t sums), 8M + 4N + 24 B a pixel: 169 KB at spp 16, 211 KB at spp 20),
written and read back within the group's run.  (Each group has a block of its own, so the
blocks' write-backs do reach DRAM on a CPU; not counted.)  At large faces the
random texel reads of balanced_mis, bis and smc, balanced_mis's CDF reads and smc's alias-table
reads also reach DRAM and the byte counts are lower bounds.  Per sample, at spp samples and E
evaluations per pixel: ``flops_per_sample`` = F_s + (F_e·E + F_p)/spp and ``bytes_per_sample``
= B_s + B_p/spp, with F_e per evaluation, F_s / B_s per sample and F_p / B_p per pixel the
fields of the estimator's ``cost`` (a ``KernelCost``, declared on its class beside its kernel,
with its derivation; perf.html lists those of the estimators measured).  An estimator that
declares none gets NaN FLOP, byte and roofline figures.

The other limits.  Most kernels are held by something other than FLOPs and DRAM bytes, so perf
also measures, beside the roofline and on the same queue, the rate of each operation that
holds one (``estimators/runtime/limit_probes.cl``, written in the estimators' explicit vectors
of POOL_LANES lanes but independent of their code; :func:`measure_limits`, ns per
lane-operation on the whole device, the median of ``repeats`` launches of ≥ 10 ms):
``phong_power`` (a lobe power, common.cl's polynomial), ``philox`` (a Philox4x32-10 block),
``divide`` (a correctly rounded division or square root: both run on the divider, at about 20
FMAs' time each here), ``gather`` (one lane's element of an independent random gather from a
table the size of the map), ``dependent_load`` (one step of a chain of such gathers, each
index the value loaded before: a CDF search, a descent, an alias table's second read),
``serial_add`` (one step of a scalar chain of acc_t additions: a vector's lanes leaving into a
running sum) and ``lockstep`` (a scalar search step ended by a LOCKSTEP barrier, as bis's and
smc's resampling searches are).  Each estimator's ``cost`` declares the operations its kernel
runs (``limits``, each with where in the kernel, counts a reviewer checks against it) per
evaluation slot, per sample and per pixel; an evaluation slot is a lane, masked or not, of the
blocks its loops run (``lane_loops``: uniform at spp 64 runs 96 slots a pixel for 66 useful
evaluations; restir a block of 16 for a chain's 8 candidates).  Per sample, each limit's time is its count × its probe's ns, and the FLOPs that
its probes' operations do not hold (the count's FLOPs less 35 a lobe power and 1 a division)
take their time at the FMA rate of POOL_LANES-wide vectors (``fma_ns``: at 8 lanes on an
AVX-512 CPU half the roofline's peak, which is measured at the preferred width).  ``limit_ms`` is the sum of those times × pixels × spp: the
bound if the operations do not overlap, which is the model here because on this kind of CPU
they share the same two vector ports (FMA, integer, shuffle and a gather's inserts; only the
divider is a unit apart, so where divisions dominate the sum may exceed the time); the largest
term alone (``limiting_probe``, ``limiting_fraction``) is the bound if they overlapped fully.
The true bound lies between.  ``limit_fraction`` = limit_ms / shade_ms: ≥ 0.5 is within 2× of
the limits.  Per-pixel work runs scalar (a pixel a work item), so each of its operations and
FLOPs counts POOL_LANES lane-operations, and so does all the work of a kernel that PoCL does not
vectorise (``scalar``: havran's and cosine's, whose one-pixel loops hold a branch).

The NumPy floor (``numpy_floor``).  Lu 2013's shared-pool shading, Algorithm 2 with Eq. 4 and
μ_f = 1/6 (``uniform``'s estimator, shared sequence): every covered pixel reads the same first
⌈N_f⌉ entries of each lit face's pool, N_f = N_s/6, with the fractional last weight β of
Eq. 5, shaded with ARCHITECTURE.md §Conventions's Phong BRDF.  It reads the same inputs as the kernels: the
G-buffer, and a light-sample pool drawn on the device by the FrameCache and read back
(directions, pdf_L and radiance).  It is the fastest NumPy formulation found, on one host thread
(BLAS capped to one by ``host_threads_capped``), in float32 as the kernels do, over blocks of
pixels that fit in cache: the dot products and the sums over the pool are matrix products, the
lobe's power NumPy's SIMD exp and log (sphere-sun and blob-sun, 256², spp 64, in one run
here: 308 and 304 Msamples/s, against 55 and 54 for the floor before issue 20, which used
element-wise products, exp2/log2 and ``einsum``).  Its time is host wall time.  Deviation from the kernels, not from the paper: N_f and β are
exact (N_s/6 and frac(N_f)) where the kernel rounds them to 2^-16 of a sample (ticks), a
relative difference under 1e-4 of a pixel.  ``FLOOR_RTOL``/``FLOOR_ATOL`` state how closely the
floor must match the ``uniform`` kernel on the same pool (``floor_max_rel_diff``); the
``speedup_vs_floor`` of a kernel is its msamples_per_s over the floor's.

The production peer (``mitsuba3-envmap``, :mod:`iblbench.harness.studies.mitsuba_peer`), where
the ``mitsuba`` package is installed and its ``llvm_ad_rgb`` variant runs a kernel here
(otherwise one line says why and its row and the ``× mitsuba`` column are absent; perf.csv keeps
the column, NaN): Mitsuba 3's own ``envmap`` emitter sampling (its ``Hierarchical2D`` warp over a
lat-long conversion of the same map), Phong-shaded as ``envmap`` is, over the same covered pixels
at the floor's spp, one Dr.Jit LLVM wavefront on every core.  It renders once untimed (Dr.Jit
compiles its kernel), then once per round after the floor; its shade_ms and render_ms are its
kernels' execution time (Dr.Jit's kernel history), its host_ms the wall time from the trace to
``dr.sync_thread()``, its build_ms the emitter's construction (host).
``speedup_vs_mitsuba`` of a row is its msamples_per_s over the peer's: ``envmap`` and
``hierarchical`` (light only) do the peer's work.
"""
from __future__ import annotations

import dataclasses
import math
import pathlib
import textwrap
import time

import numpy as np

from iblbench.estimators.runtime.probes import (FMA_ITEMS, LIMIT_ITEMS, LIMIT_MIN_MS, PROBE_FLOPS,
                                                CopyProbe, chase_table, copy_size, fma_iterations,
                                                gather_entries, run_copy, run_divide, run_fma,
                                                run_gathers, run_lockstep_steps, run_philox,
                                                run_phong_power, run_serial_adds, sized)
from iblbench.harness.studies import mitsuba_peer
from iblbench.harness.protocol.timing import (measure_timing_floor, required_build_ms, spread,
                                              round_orders, timing_floor_text, wait_for_quiet_threads)
from iblbench.foundation.errors import InputError

DEFAULT_SCENES = ("sphere-sun", "blob-sun")
DEFAULT_RESOLUTION = (256, 256)
DEFAULT_ENV_RES = 64
DEFAULT_SPP = 64
DEFAULT_REPEATS = 5
FLOOR = "numpy-floor"
FLOOR_SEED = 0xFFFFFF80        # a seed no benchmark cell uses
WARMUP_SEED = 0xFFFFFFFF
FLOOR_RTOL = 1e-4              # |floor − uniform| ≤ RTOL·|uniform| + ATOL·max|uniform| per channel
FLOOR_ATOL = 1e-6
FLOOR_BLOCK = 1 << 15          # pixels × pool entries per block of the floor (fits in L2)
ROOF_MIN_MS = 20.0             # each roofline launch is sized to take at least this


def cdf_build_bytes(res: int) -> int:
    """The bytes a frame's CDF build must move at faces of ``res`` texels: every float4 texel
    read once (16 B) and every 64-bit CDF word written once, R² conditional and R marginal words
    per face.  Not counted: the texel solid angles Ω (R² floats shared by the six faces, and
    geometry a kernel could compute), the row and face totals (R + 1 floats per face) and a
    CPU's write-allocate reads (the copy roofline does not count them either)."""
    return 6 * (res * res * (16 + 8) + res * 8)


# Every column of perf.csv, in order, with what it means (the --help epilog and perf.html).
COLUMNS = {
    "scene": "scene name",
    "estimator": f"estimator label; '{FLOOR}' is the NumPy shared-pool floor (one host thread), "
                 f"'{mitsuba_peer.PEER}' the Mitsuba 3 peer (where it runs)",
    "estimator_version": "hash of the estimator's Python and kernel sources (as in results rows)",
    "spp": "samples per pixel (havran: K lights; bis: N resampled; smc: N particles)",
    "repeats": "timed renders after one untimed warm-up; times are their median",
    "pixels": "covered pixels (work items)",
    "evaluations": "integrand evaluations per covered pixel (Estimate.evaluations)",
    "build_ms": "device ms of the FrameCache products required (upload, CDFs), median",
    "build_ms_min": "its minimum over repeats",
    "build_ms_iqr": "its interquartile range",
    "cdf_ms": "device ms of the CDF build alone (part of build_ms; NaN: not required), median",
    "cdf_bound_ms": "the CDF build's copy-bandwidth bound: 6·(R²·(16 + 8) + R·8) B (float4 "
                    "texels read once, conditional and marginal CDF words written once) / the "
                    "median copy bandwidth of a copy launched straight before each timed build",
    "sample_ms": "device ms of the sample stage (pool draw; havran: map build, light placement "
                 "and filter; 0: none), median",
    "sample_ms_min": "its minimum",
    "sample_ms_iqr": "its interquartile range",
    "shade_ms": "device ms of the shading kernel, median (the floor: host wall ms)",
    "shade_ms_min": "its minimum",
    "shade_ms_iqr": "its interquartile range",
    "frame_ms": "build + sample + shade per repeat, median",
    "frame_ms_min": "its minimum",
    "frame_ms_iqr": "its interquartile range",
    "render_ms": "sample + shade per repeat, median: the time the rates divide by",
    "host_ms": "host wall ms of the render call (read-back included), median",
    "msamples_per_s": "pixels × spp / render_ms, in millions per second",
    "mevals_per_s": "pixels × evaluations / render_ms, in millions per second",
    "flops_per_sample": "analytic FLOPs per sample of the shading kernel (an estimate)",
    "bytes_per_sample": "analytic DRAM bytes per sample (an estimate; shared tables cached)",
    "gflops": "FLOPs per sample × pixels × spp / shade_ms, GFLOP/s",
    "gbytes_per_s": "bytes per sample × pixels × spp / shade_ms, GB/s",
    "roofline_fraction": "max(gflops/peak_gflops, gbytes_per_s/peak_gbps): achieved over "
                         "attainable at the kernel's intensity",
    "bound": "the roof that binds at the kernel's intensity: compute or memory",
    "limit_ms": "the shading kernel's time bound by its limits: per sample, Σ over the probe "
                "operations its cost declares (masked lanes included) of count × the probe's ns, "
                "+ its other FLOPs at the FMA peak; × pixels × spp",
    "limit_fraction": "limit_ms / shade_ms: the kernel's speed over its limits' (≥ 0.5: within "
                      "2× of the bound)",
    "limiting_probe": "the largest term of limit_ms: a probe's name, or flops",
    "limiting_fraction": "that term's ms / shade_ms: the kernel's speed over its largest limit's "
                         "alone (the bound where the limits overlap fully)",
    "speedup_vs_floor": "msamples_per_s over the NumPy floor's (same scene)",
    "speedup_vs_mitsuba": "msamples_per_s over the Mitsuba 3 peer's (same scene; NaN where the "
                          "peer does not run)",
    "floor_max_rel_diff": "floor row: max over pixels and channels of |floor − uniform| / "
                          "(|uniform| + max|uniform|·ATOL/RTOL), on the same pool (≤ RTOL passes)",
    "peak_gflops": "the device's measured FMA throughput, GFLOP/s (median)",
    "peak_gbps": "the device's measured copy bandwidth, GB/s, read + written (median)",
    **{f"{probe}_ns": f"ns per lane-operation of the {probe} limit probe on the whole device "
                      "(median)" for probe in PROBE_FLOPS},
    "fma_ns": "ns per FLOP of FMA chains in vectors of POOL_LANES on the whole device (median): "
              "the rate of a limit's other FLOPs",
    "device": "OpenCL device | platform version | driver",
    "lanes": "the estimators' explicit vector width (POOL_LANES: the device's, or --lanes)",
}
SHOWN = {"scene": "scene", "estimator": "estimator", "spp": "spp", "pixels": "pixels",
         "msamples_per_s": "Msamples/s", "mevals_per_s": "Mevals/s", "build_ms": "build ms",
         "sample_ms": "sample ms", "shade_ms": "shade ms", "shade_iqr_pct": "IQR %",
         "gflops": "GFLOP/s", "gbytes_per_s": "GB/s", "roofline_fraction": "roof",
         "limit_fraction": "limit", "limiting_probe": "limited by", "speedup_vs_floor": "× floor",
         "speedup_vs_mitsuba": "× mitsuba"}


def columns_help() -> str:
    """The columns of perf.csv, one per line, and the printed table's headers (--help epilog)."""
    width = max(map(len, COLUMNS))
    printed = ", ".join(f"{header} = {name}" for name, header in SHOWN.items()
                        if header != name and name != "shade_iqr_pct")
    return ("columns of perf.csv:\n" + "\n".join(f"  {name:{width}s}  {text}"
                                                  for name, text in COLUMNS.items())
            + "\n\n" + textwrap.fill(f"the printed table shows {printed}, and IQR % = 100 × "
                                     "shade_ms_iqr / shade_ms.", 92))


# ---- the roofline --------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Roofline:
    gflops: float          # median FMA throughput
    gbps: float            # median copy bandwidth, bytes read + written
    fma_flops: int         # FLOPs per timed FMA launch
    copy_bytes: int        # bytes moved per timed copy launch
    limit_ns: dict = dataclasses.field(default_factory=dict)   # probe -> ns per lane-operation

    def fraction(self, gflops: float, gbps: float) -> float:
        """Achieved over attainable, min(peak, intensity × bandwidth), for a kernel that reaches
        ``gflops`` and ``gbps``."""
        return max(gflops / self.gflops, gbps / self.gbps)

    def bound(self, flops_per_byte: float) -> str:
        """The roof that binds at an arithmetic intensity (FLOPs per byte)."""
        return "compute" if flops_per_byte * self.gbps >= self.gflops else "memory"


def measure_roofline(compute, repeats: int, env_res: int = DEFAULT_ENV_RES) -> Roofline:
    """The device's FMA throughput and copy bandwidth: the median of ``repeats`` launches each,
    the FMA launch sized to take ≥ ROOF_MIN_MS; and its limit probes (:func:`measure_limits`)."""
    iterations = fma_iterations(compute, FMA_ITEMS, ROOF_MIN_MS)
    _, fma_ms, flops = run_fma(compute, FMA_ITEMS, iterations, repeats)
    _, copy_ms, moved = run_copy(compute, np.ones(copy_size(compute) // 4, np.float32), repeats)
    return Roofline(gflops=flops / spread(fma_ms)[0] / 1e6, gbps=moved / spread(copy_ms)[0] / 1e6,
                    fma_flops=flops, copy_bytes=moved,
                    limit_ns=measure_limits(compute, env_res, repeats))


def measure_limits(compute, env_res: int, repeats: int) -> dict[str, float]:
    """ns per lane-operation of each limit probe (``probes.PROBE_FLOPS``) on the whole device,
    and under ``"fma"`` ns per FLOP of FMA chains in vectors of POOL_LANES (the estimators'
    width: at 8 lanes on an AVX-512 CPU, half the roofline's rate): the median of ``repeats``
    launches of LIMIT_ITEMS work items, each sized to take ≥ LIMIT_MIN_MS; the gathers read a
    table of ``gather_entries(env_res)`` entries."""
    table = chase_table(gather_entries(env_res))
    runs = {   # (count, launches) -> (device ms of each launch, lane-operations per launch)
        "phong_power": lambda n, k: run_phong_power(compute, LIMIT_ITEMS, n, k)[1:],
        "philox": lambda n, k: run_philox(compute, LIMIT_ITEMS, n, k)[1:],
        "divide": lambda n, k: run_divide(compute, LIMIT_ITEMS, n, k)[1:],
        "gather": lambda n, k: run_gathers(compute, table, LIMIT_ITEMS, n, False, k)[2:],
        "dependent_load": lambda n, k: run_gathers(compute, table, LIMIT_ITEMS, n, True, k)[2:],
        "serial_add": lambda n, k: run_serial_adds(compute, LIMIT_ITEMS, n, k)[1:],
        "lockstep": lambda n, k: run_lockstep_steps(compute, table, LIMIT_ITEMS, n, k)[1:]}
    runs["fma"] = lambda n, k: run_fma(compute, LIMIT_ITEMS, n, k, width=compute.pool_lanes)[1:]
    rates = {}
    for probe, run in runs.items():
        count = sized(lambda n: run(n, 1)[0][0], LIMIT_MIN_MS)
        times, operations = run(count, repeats)
        rates[probe] = spread(times)[0] * 1e6 / operations
    return rates


def limit_terms(cost, spp: int, evaluations: float, lanes: int, roofline: Roofline) -> dict[str, float]:
    """ns per sample of each limit of an estimator's ``cost`` at ``spp`` and ``evaluations``
    per pixel in blocks of ``lanes``: each probe's operations × its ns, and under ``"flops"``
    the FLOPs its probes' operations do not hold at the FMA rate of ``lanes``-wide vectors.
    Their sum bounds the time (module docstring)."""
    counts = cost.executed_per_sample(spp, evaluations, lanes)
    flops = counts.pop("flops") - sum(count * PROBE_FLOPS[probe] for probe, count in counts.items())
    terms = {probe: count * roofline.limit_ns[probe] for probe, count in counts.items()}
    terms["flops"] = max(flops, 0.0) * roofline.limit_ns["fma"]
    return terms


# ---- the NumPy floor ---------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class HostPool:
    """A light-sample pool read back from the device: ``per_face`` entries per face, face-major;
    ``dirs`` ``[6·per_face, 3]``, ``pdf`` ``[6·per_face]`` (pdf_L(ω|f)), ``radiance``
    ``[6·per_face, 3]``; ``face_integrals`` I_f ``[6]``."""

    dirs: np.ndarray
    pdf: np.ndarray
    radiance: np.ndarray
    per_face: int
    face_integrals: np.ndarray

    @classmethod
    def read(cls, cache, per_face: int, seed: int) -> "HostPool":
        pool = cache.light_pool(per_face, seed)
        count = 6 * pool.per_face
        dir_pdf = cache.compute.to_host(pool.dir_pdf, (count, 4), np.float32)
        radiance = cache.compute.to_host(pool.radiance, (count, 4), np.float32)
        return cls(dir_pdf[:, :3].copy(), dir_pdf[:, 3].copy(), radiance[:, :3].copy(),
                   pool.per_face, np.asarray(cache.face_integrals, np.float32))


@dataclasses.dataclass(frozen=True)
class HostSurface:
    """The covered pixels' shading inputs, float32: ``normal``, ``view``, ``kd``, ``ks`` ``[N, 3]``
    and ``shininess`` ``[N]``."""

    normal: np.ndarray
    view: np.ndarray
    kd: np.ndarray
    ks: np.ndarray
    shininess: np.ndarray

    @classmethod
    def of(cls, gbuffer) -> "HostSurface":
        m = gbuffer.mask
        return cls(*(np.ascontiguousarray(getattr(gbuffer, name)[m], np.float32)
                     for name in ("normal", "view", "kd", "ks", "shininess")))


def floor_samples(pool: HostPool, spp: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pool entries every pixel reads (the first ⌈N_f⌉ of each lit face, N_f = spp/6) and
    their weights β_i/(N_f·pdf_i) of Eq. 4-5: (directions ``[S, 3]``, weights ``[S]``,
    radiance ``[S, 3]``)."""
    n_f = spp / 6.0
    draws = min(math.ceil(n_f), pool.per_face)
    beta = np.minimum(1.0, n_f - np.arange(draws))
    lit = np.flatnonzero(pool.face_integrals > 0)
    entries = (lit[:, None] * pool.per_face + np.arange(draws)).ravel()
    pdf = pool.pdf[entries].astype(np.float64)
    with np.errstate(divide="ignore"):
        weight = np.where(pdf > 0, np.tile(beta, len(lit)) / (n_f * pdf), 0.0)
    return pool.dirs[entries], weight.astype(np.float32), pool.radiance[entries]


def numpy_floor(surface: HostSurface, pool: HostPool, spp: int) -> np.ndarray:
    """Lu 2013's shared-pool shading with μ_f = 1/6 (module docstring), float32 ``[N, 3]``:
    Σ_f Σ_i β_i/(N_f pdf_i) · ρ(ω_i) cos⁺(n, ω_i) L_i, ρ = kd/π + ks (m+2)/(2π) cos⁺(r, ω)^m.
    Per block of pixels, as a NumPy user would write it: n·ω and r·ω of every (pixel, sample) as
    matrix products ``[pixels, 3] @ [3, samples]``, the lobe cos⁺(r, ω)^m as exp(m·log c) in
    NumPy's SIMD exp and log, and the sums over the samples as matrix products with the samples'
    weighted radiance ``[samples, 3]``; the per-pixel factors come after."""
    dirs, weight, radiance = floor_samples(pool, spp)
    count = len(surface.normal)
    out = np.zeros((count, 3), np.float32)
    if not len(dirs):
        return out
    weighted = (weight[:, None] * radiance).astype(np.float32)    # β_i L_i / (N_f pdf_i)
    n, v = surface.normal, surface.view
    r = 2.0 * np.sum(n * v, axis=1, keepdims=True, dtype=np.float32) * n - v
    columns = np.ascontiguousarray(dirs.T)                        # [3, samples]
    block = max(1, FLOOR_BLOCK // len(dirs))
    tiny = np.float32(np.finfo(np.float32).tiny)
    for start in range(0, count, block):
        rows = slice(start, start + block)
        m = surface.shininess[rows, None]
        cosine = n[rows] @ columns
        mirror = r[rows] @ columns
        np.maximum(cosine, 0.0, out=cosine)
        lobe = np.maximum(mirror, tiny)
        np.log(lobe, out=lobe)
        lobe *= m
        np.exp(lobe, out=lobe)
        lobe *= mirror > 0
        lobe *= cosine
        out[rows] = (surface.kd[rows] / np.float32(np.pi) * (cosine @ weighted)
                     + surface.ks[rows] * ((m + 2.0) / np.float32(2.0 * np.pi)) * (lobe @ weighted))
    return out


def floor_difference(floor: np.ndarray, kernel: np.ndarray) -> float:
    """max |floor − kernel| / (|kernel| + max|kernel|·ATOL/RTOL) over pixels and channels: ≤
    FLOOR_RTOL exactly when every value is within RTOL·|kernel| + ATOL·max|kernel|."""
    scale = np.abs(kernel) + float(np.max(np.abs(kernel), initial=0.0)) * FLOOR_ATOL / FLOOR_RTOL
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(scale > 0, np.abs(floor - kernel) / scale,
                         np.where(floor == kernel, 0.0, np.inf))
    return float(np.max(ratio, initial=0.0))


# ---- measuring -----------------------------------------------------------------------------------

@dataclasses.dataclass
class _Cell:
    """The repeated renders of one (scene, estimator)."""

    label: str
    estimator: object
    spp: int
    build: list = dataclasses.field(default_factory=list)
    cdf: list = dataclasses.field(default_factory=list)
    copy_gbps: list = dataclasses.field(default_factory=list)   # CopyProbe beside each CDF build
    sample: list = dataclasses.field(default_factory=list)
    shade: list = dataclasses.field(default_factory=list)
    host: list = dataclasses.field(default_factory=list)
    evaluations: float = math.nan

    def render(self, compute, gbuffer, env, seed: int, timed: bool = True):
        from iblbench.estimators.runtime.framecache import FrameCache

        cache = FrameCache(compute, env, 0)
        cache.require(type(self.estimator).requires)
        self.estimator.reset()
        start = time.perf_counter()
        try:
            estimate = self.estimator.render(gbuffer, cache, self.spp, seed)
        except ValueError as error:   # e.g. an spp beyond the estimator's limit
            raise InputError(None, f"estimator '{self.label}' at spp {self.spp}: {error}") from None
        host = (time.perf_counter() - start) * 1e3
        if timed:
            self.build.append(required_build_ms(cache.timings_ms, type(self.estimator).requires))
            self.cdf.append(cache.timings_ms.get("cdf", math.nan))
            self.sample.append(estimate.timings_ms.get("sample", 0.0))
            self.shade.append(estimate.timings_ms.get("shade", math.nan))
            self.host.append(host)
            self.evaluations = float(estimate.evaluations)
        return estimate


@dataclasses.dataclass
class PerfConfig:
    out: pathlib.Path
    scenes: tuple[str, ...] = DEFAULT_SCENES
    estimators: tuple[str, ...] = ()        # labels; () is every registered estimator
    spp: int | None = None                  # None: the estimator's perf_budget, else DEFAULT_SPP
    resolution: tuple[int, int] = DEFAULT_RESOLUTION
    env_res: int = DEFAULT_ENV_RES
    repeats: int | None = None              # None: its perf_budget, else DEFAULT_REPEATS
    device: str | None = None
    launch_shape: str | None = None         # None: the device's (Compute.launch_shape)
    lanes: int | None = None                # POOL_LANES override (8 or 16); None: the device's


def command_line(config: PerfConfig) -> str:
    """The ``iblbench perf`` command that measures ``config`` (for the page and the report)."""
    words = ["iblbench perf"] + [f"--scene {name}" for name in config.scenes]
    words += [f"--estimator '{label}'" for label in config.estimators]
    words += [f"--spp {config.spp}"] * bool(config.spp) + [f"--repeats {config.repeats}"] * bool(config.repeats)
    words += [f"--res {config.resolution[0]}x{config.resolution[1]}", f"--env-res {config.env_res}"]
    words += [f"--device '{config.device}'"] * bool(config.device) + [f"--lanes {config.lanes}"] * bool(config.lanes)
    words += [f"--launch-shape {config.launch_shape}"] * bool(config.launch_shape)
    return " ".join(words + [f"--out {config.out}"])


def _budget(config: PerfConfig, cls) -> tuple[int, int]:
    """(spp, repeats) of an estimator class: the flags, else its ``perf_budget``, else the
    defaults."""
    spp, repeats = cls.perf_budget or (DEFAULT_SPP, DEFAULT_REPEATS)
    return config.spp or spp, config.repeats or repeats


def _row(scene: str, cell: _Cell, pixels: int, env_res: int, roofline: Roofline,
         device: str, lanes: int) -> dict:
    build, sample, shade = spread(cell.build), spread(cell.sample), spread(cell.shade)
    frame = spread([b + s + h for b, s, h in zip(cell.build, cell.sample, cell.shade)])
    render_ms = spread([s + h for s, h in zip(cell.sample, cell.shade)])[0]
    samples = pixels * cell.spp
    cdf_ms = spread(cell.cdf)[0]
    cdf_bound_ms = (cdf_build_bytes(env_res) / (spread(cell.copy_gbps)[0] * 1e6)
                    if math.isfinite(cdf_ms) else math.nan)
    row = {"scene": scene, "estimator": cell.label,
           "estimator_version": type(cell.estimator).version(), "spp": cell.spp,
           "repeats": len(cell.shade),
           "pixels": pixels, "evaluations": cell.evaluations,
           **{f"{stage}_ms{suffix}": value for stage, values in
              (("build", build), ("sample", sample), ("shade", shade), ("frame", frame))
              for suffix, value in zip(("", "_min", "_iqr"), values)},
           "cdf_ms": cdf_ms, "cdf_bound_ms": cdf_bound_ms,
           "render_ms": render_ms, "host_ms": spread(cell.host)[0],
           "msamples_per_s": samples / (render_ms * 1e3),
           "mevals_per_s": pixels * cell.evaluations / (render_ms * 1e3)}
    cost = type(cell.estimator).cost
    flops = nbytes = gflops = gbps = math.nan
    if cost is not None:
        flops, nbytes = cost.per_sample(cell.spp, cell.evaluations)
        gflops, gbps = flops * samples / (shade[0] * 1e6), nbytes * samples / (shade[0] * 1e6)
    limit_ms, limiting, limiting_ms = math.nan, "", math.nan
    if cost is not None and cost.limits:
        terms = limit_terms(cost, cell.spp, cell.evaluations, lanes, roofline)
        limiting = max(terms, key=terms.get)
        limit_ms, limiting_ms = sum(terms.values()) * samples / 1e6, terms[limiting] * samples / 1e6
    row.update({"flops_per_sample": flops, "bytes_per_sample": nbytes, "gflops": gflops,
                "gbytes_per_s": gbps,
                "roofline_fraction": roofline.fraction(gflops, gbps) if cost else math.nan,
                "bound": roofline.bound(flops / nbytes) if cost else "",
                "limit_ms": limit_ms, "limit_fraction": limit_ms / shade[0], "limiting_probe": limiting,
                "limiting_fraction": limiting_ms / shade[0],
                "speedup_vs_floor": math.nan, "floor_max_rel_diff": math.nan,
                "peak_gflops": roofline.gflops, "peak_gbps": roofline.gbps, "device": device})
    return row


def _host_row(scene: str, label: str, spp: int, evaluations: int, pixels: int, times: list,
              roofline: Roofline, device: str) -> dict:
    """The row of a renderer timed outside OpenCL (the floor, the peer): ``evaluations`` per
    pixel, ms ``times``; the columns it has no figure for NaN."""
    median, low, iqr = spread(times)
    row = {column: math.nan for column in COLUMNS}
    row.update({"scene": scene, "estimator": label, "estimator_version": "", "spp": spp,
                "repeats": len(times),
                "pixels": pixels, "evaluations": float(evaluations), "shade_ms": median,
                "shade_ms_min": low, "shade_ms_iqr": iqr, "render_ms": median, "host_ms": median,
                "msamples_per_s": pixels * spp / (median * 1e3),
                "mevals_per_s": pixels * evaluations / (median * 1e3), "bound": "",
                "limiting_probe": "",
                "peak_gflops": roofline.gflops, "peak_gbps": roofline.gbps, "device": device})
    return row


def _floor_row(scene: str, spp: int, evaluations: int, pixels: int, times: list,
               difference: float, roofline: Roofline, device: str) -> dict:
    """The floor's row: ``evaluations`` pool entries read per pixel; host times ``times``."""
    from iblbench.estimators.uniform import Uniform

    flops, nbytes = Uniform.cost.per_sample(spp, evaluations)
    return dict(_host_row(scene, FLOOR, spp, evaluations, pixels, times, roofline, device),
                flops_per_sample=flops, bytes_per_sample=nbytes, speedup_vs_floor=1.0,
                floor_max_rel_diff=difference)


def _peer_row(scene: str, peer, spp: int, times: list, roofline: Roofline, device: str) -> dict:
    """The Mitsuba peer's row from its renders' (kernel ms, host ms) ``times``."""
    kernel_ms, host_ms = zip(*times)
    return dict(_host_row(scene, mitsuba_peer.PEER, spp, spp, peer.count, kernel_ms, roofline, device),
                build_ms=peer.build_ms, host_ms=spread(host_ms)[0])


def _with_speedups(rows: list, floor: dict) -> list:
    """``rows`` of one scene, each with its rate over the floor's (and over the peer's where its
    row is among them), then the floor's row."""
    peers = [row for row in rows if row["estimator"] == mitsuba_peer.PEER]
    for row in rows:
        row["speedup_vs_floor"] = row["msamples_per_s"] / floor["msamples_per_s"]
    for row in rows + [floor] if peers else []:
        row["speedup_vs_mitsuba"] = row["msamples_per_s"] / peers[0]["msamples_per_s"]
    return rows + [floor]


def _floor_pool(compute, specs, gbuffer, device_gbuffer, surface, env, spp: int) -> tuple:
    """(the floor's light-sample pool, drawn on the device, and :func:`floor_difference` of the
    floor from the uniform kernel on that pool, NaN where ``uniform`` is not measured); the
    floor's first render here is its warm-up."""
    from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
    from iblbench.estimators.runtime.framecache import FrameCache
    from iblbench.estimators.uniform import Uniform

    floor_cache = FrameCache(compute, env, 0)
    floor_cache.require(Uniform.requires)
    pool = HostPool.read(floor_cache, Uniform.pool_size(spp), FLOOR_SEED)
    floor_image = numpy_floor(surface, pool, spp)
    if Uniform.name not in {spec.cls.name for spec in specs}:
        return pool, math.nan
    # The floor has no V: the kernel it must agree with renders without the masks.
    unmasked = DeviceGBuffer(compute, dataclasses.replace(gbuffer, visibility=None)) \
        if gbuffer.visibility is not None else device_gbuffer
    kernel = Uniform().render(unmasked, floor_cache, spp, FLOOR_SEED)
    return pool, floor_difference(floor_image, kernel.radiance[gbuffer.mask])


def run_perf(config: PerfConfig, log=print):
    """Measure (module docstring); returns (the perf table, the roofline)."""
    import pandas as pd

    from iblbench.estimators.registry import estimator_names
    from iblbench.estimators.runtime.device import cache_dir, get_compute
    from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
    from iblbench.harness.protocol.shadows import attach_visibility
    from iblbench.harness.protocol.sweep import parse_estimator
    from iblbench.scenes.gbuffer import trace_gbuffer
    from iblbench.scenes.registry import load_scene

    specs = [parse_estimator(label) for label in (config.estimators or estimator_names())]
    labels = [spec.label for spec in specs]
    if len(set(labels)) != len(labels):
        raise InputError(None, f"an estimator is listed twice: {', '.join(labels)}")
    scenes = [load_scene(name, env_res=config.env_res) for name in dict.fromkeys(config.scenes)]
    compute = get_compute(config.device, config.launch_shape, config.lanes)
    floor_spp = config.spp or DEFAULT_SPP
    rows = []
    log(f"device: {compute.device_name}, {compute.pool_lanes} lanes")
    roofline = measure_roofline(compute, config.repeats or DEFAULT_REPEATS, config.env_res)
    log(f"roofline: {roofline.gflops:.4g} GFLOP/s (FMA), {roofline.gbps:.4g} GB/s (copy)")
    log("limit probes, ns per lane-operation: "
        + ", ".join(f"{probe} {ns:.3g}" for probe, ns in roofline.limit_ns.items()))
    probe_ns = {f"{probe}_ns": ns for probe, ns in roofline.limit_ns.items()}
    probe = CopyProbe(compute)
    peer_absent = mitsuba_peer.unavailable()
    log(f"{mitsuba_peer.PEER}: " + (f"absent, {peer_absent}" if peer_absent
                                   else f"Mitsuba 3 {mitsuba_peer.VARIANT}, at spp {floor_spp}"))
    for scene in scenes:
        gbuffer = trace_gbuffer(scene.mesh, scene.material, scene.camera, *config.resolution)
        if gbuffer.covered == 0:
            raise InputError(scene.source or scene.name, "the camera sees none of the mesh")
        env = np.asarray(scene.environment.frame(0), np.float32)
        gbuffer, _ = attach_visibility(scene, gbuffer, env.shape[1], cache_dir() / "visibility")
        device_gbuffer = DeviceGBuffer(compute, gbuffer)
        cells = []
        for spec in specs:
            spp, repeats = _budget(config, spec.cls)
            cells.append((_Cell(spec.label, spec.make(), spp), repeats))
        for cell, _ in cells:
            cell.render(compute, device_gbuffer, env, WARMUP_SEED, timed=False)
        surface = HostSurface.of(gbuffer)
        pool, difference = _floor_pool(compute, specs, gbuffer, device_gbuffer, surface, env, floor_spp)
        peer = None if peer_absent else mitsuba_peer.MitsubaPeer(surface, env)
        if peer:
            peer.render(floor_spp, WARMUP_SEED)   # Dr.Jit traces and compiles its kernel
        floor_times, peer_times, floor_repeats = [], [], config.repeats or DEFAULT_REPEATS
        shuffle = round_orders()
        for round_ in range(max([floor_repeats] + [repeats for _, repeats in cells])):
            wait_for_quiet_threads()   # the peer's and the warm-ups' host threads
            for cell, repeats in (cells[i] for i in shuffle(len(cells))):
                if round_ < repeats:
                    if {"cdf", "pool"} & set(type(cell.estimator).requires):   # builds CDFs
                        cell.copy_gbps.append(probe.gbps())
                    cell.render(compute, device_gbuffer, env, round_)
            if round_ < floor_repeats:
                start = time.perf_counter()
                numpy_floor(surface, pool, floor_spp)
                floor_times.append((time.perf_counter() - start) * 1e3)
                if peer:
                    peer_times.append(peer.render(floor_spp, round_)[1:])
        floor = _floor_row(scene.name, floor_spp, len(floor_samples(pool, floor_spp)[0]),
                           device_gbuffer.count, floor_times, difference, roofline,
                           compute.device_name)
        scene_rows = [_row(scene.name, cell, device_gbuffer.count, env.shape[1], roofline,
                           compute.device_name, compute.pool_lanes)
                      for cell, _ in cells]
        if peer:
            scene_rows.append(_peer_row(scene.name, peer, floor_spp, peer_times, roofline,
                                        compute.device_name))
        rows += [dict(row, lanes=compute.pool_lanes, **probe_ns)
                 for row in _with_speedups(scene_rows, floor)]
        log(f"{scene.name}: {len(cells)} estimators and the floor{' and the peer' * bool(peer)} measured")
    return pd.DataFrame(rows, columns=list(COLUMNS)), roofline


# ---- output -------------------------------------------------------------------------------------

def shown_table(table):
    """The printed subset of the table, with readable headers."""
    shown = table.assign(shade_iqr_pct=100.0 * table.shade_ms_iqr / table.shade_ms)
    names = [name for name in SHOWN if name != "speedup_vs_mitsuba"
             or table.speedup_vs_mitsuba.notna().any()]   # absent where the peer did not run
    return shown[names].rename(columns=SHOWN)


def format_table(table) -> str:
    import pandas as pd

    with pd.option_context("display.width", 250, "display.max_columns", 50):
        return shown_table(table).to_string(index=False, float_format=lambda v: f"{v:.4g}")


def run_study(config: PerfConfig) -> PerfStudy:
    """Measure (:func:`run_perf`) between two timing floors; nothing is written."""
    from iblbench.estimators.runtime.device import get_compute
    from iblbench.harness.protocol.timing import host_threads_capped

    start = time.perf_counter()
    with host_threads_capped():   # the NumPy floor runs between timed kernels: no spinning BLAS
        compute = get_compute(config.device, config.launch_shape, config.lanes)   # cached: as run_perf
        floors = [measure_timing_floor(compute)]
        table, roofline = run_perf(config)
        floors.append(measure_timing_floor(compute))
    return PerfStudy(table, roofline, floors, time.perf_counter() - start, command_line(config),
                     measured_costs(table))


def measured_costs(table) -> dict:
    """Label -> the ``cost`` declared by the estimator of each row of ``table`` that has one."""
    from iblbench.harness.protocol.sweep import parse_estimator

    labels = dict.fromkeys(label for label in table.estimator if label not in (FLOOR, mitsuba_peer.PEER))
    costs = {label: parse_estimator(label).cls.cost for label in labels}
    return {label: cost for label, cost in costs.items() if cost is not None}


@dataclasses.dataclass
class PerfStudy:
    """What ``iblbench perf`` measured: the table, the roofline, the timing floor at the start
    and the end, the seconds it took and the command that reproduces it."""

    table: object
    roofline: Roofline
    floors: list
    seconds: float
    command: str
    costs: dict    # label -> KernelCost of each estimator measured that declares one

    def context(self) -> dict:
        """The page's header and cost table (:func:`iblbench.reports.perf.write_outputs`)."""
        return {"device": self.table.device.iloc[0], "command": self.command,
                "seconds": f"{self.seconds:.0f}", "timing_floor": timing_floor_text(self.floors),
                "timing_floor_ms": f"{self.floors[0].median_ms:.2g}", "costs": self.costs}
