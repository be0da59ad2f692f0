"""OpenCL device selection and the per-context program cache.

Preference (ARCHITECTURE.md §Devices and portability): a GPU first, then the fastest CPU platform, among the devices that can
build a kernel, and never a simulator unless asked for by name.  Two CPU platforms are common
here — Debian's PoCL (LLVM host-CPU target) and the pip ``pocl-binary-distribution`` (generic
target) — and both report the same platform name, so CPU platforms are ranked by a short
measured FLOP rate, cached on disk per (platform version, device, driver).  A driver whose
compiler fails on this machine (the pip PoCL 3.0's LLVM 14 names CPUs newer than it "generic",
which it then cannot target) is passed over with its reason.  Oclgrind, the specification's
simulator, registers as a GPU but runs kernels thousands of times slower: it serves the
portability test and ``iblbench doctor``.
``IBLBENCH_DEVICE`` or ``--device`` picks by a case-insensitive substring of
"platform name / platform version / device name".
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib.resources
import json
import os
import pathlib
import signal
import time
import warnings

import numpy as np
import pyopencl as cl

from iblbench.foundation.atomic import atomic_path
from iblbench.foundation.captured_output import output_collected
from iblbench.foundation.errors import InputError, argument

ENV_DEVICE = "IBLBENCH_DEVICE"
SIMULATORS = ("oclgrind",)   # platform or device names of simulators, lower case


def cache_dir() -> pathlib.Path:
    """Where references and device measurements are cached (``IBLBENCH_CACHE`` overrides)."""
    root = os.environ.get("IBLBENCH_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "iblbench")
    path = pathlib.Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path


@dataclasses.dataclass(frozen=True)
class DeviceInfo:
    platform: cl.Platform
    device: cl.Device

    @property
    def is_gpu(self) -> bool:
        return bool(self.device.type & cl.device_type.GPU)

    @property
    def label(self) -> str:
        return f"{self.platform.name} / {self.platform.version} / {self.device.name}"

    @property
    def short_name(self) -> str:
        """Device name, platform version and driver: what every results row records."""
        return (f"{self.device.name.strip()} | {self.platform.version.strip()} | "
                f"driver {self.device.driver_version.strip()}")

    @property
    def key(self) -> str:
        return f"{self.platform.version}|{self.device.name}|{self.device.driver_version}"

    @property
    def has_fp64(self) -> bool:
        return "cl_khr_fp64" in self.device.extensions

    @property
    def is_simulator(self) -> bool:
        return any(name in self.label.lower() for name in SIMULATORS)

    @property
    def kind(self) -> str:
        return "simulator" if self.is_simulator else "GPU" if self.is_gpu else "CPU"


@contextlib.contextmanager
def sigint_deferred():
    """SIGINT blocked in the calling thread inside, and in the threads and processes started
    meanwhile: a Ctrl-C arriving then is delivered when the block ends (as KeyboardInterrupt in
    the main thread).  PoCL links each kernel by running ``ld`` from its worker threads, which
    inherit the signal mask of the thread that starts them; a linker killed by the terminal's
    SIGINT made PoCL abort the whole process (exit 134, the manifest left "running": issue 23)."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def all_devices() -> list[DeviceInfo]:
    try:
        with sigint_deferred():   # PoCL starts its worker threads here (sigint_deferred)
            platforms = cl.get_platforms()
    except cl.Error:
        return []
    devices = []
    for platform in platforms:
        try:
            devices += [DeviceInfo(platform, d) for d in platform.get_devices()]
        except cl.Error:   # a platform with no usable device (e.g. a GPU driver without a GPU)
            continue
    return devices


# Straight-line code (no loop in the kernel body) so that a vectorising CPU compiler can run
# work items in SIMD lanes, as it does for branch-light estimator kernels.
_FMA_BLOCK = "a = fma(a, b, c); c = fma(c, b, a); " * 32
_FLOP_KERNEL = f"""
__kernel void fma_block(__global float *out) {{
    float a = get_global_id(0) * 1e-6f, b = 0.999f, c = 1e-3f;
    {_FMA_BLOCK * 4}
    out[get_global_id(0)] = a + c;
}}
"""
_FLOPS_PER_ITEM = 2 * 2 * 32 * 4


def _measure_gflops(info: DeviceInfo) -> float:
    """FLOP rate of straight-line FMAs (compile and a warm-up run excluded), median of 3.  The
    launch doubles from 1,024 work items until one takes 50 ms (or reaches 2^20), so that a
    simulator, thousands of times slower, is measured in seconds too."""
    ctx = cl.Context([info.device])
    queue = cl.CommandQueue(ctx)
    kernel = cl.Kernel(quietly_built(ctx, _FLOP_KERNEL)[0], "fma_block")
    out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, 4 << 20)
    kernel.set_args(out)

    def seconds(items: int) -> float:
        start = time.perf_counter()
        cl.enqueue_nd_range_kernel(queue, kernel, (items,), None).wait()
        return time.perf_counter() - start

    items = 1 << 10
    while seconds(items) < 0.05 and items < 1 << 20:
        items *= 2
    times = [seconds(items) for _ in range(3)]
    return _FLOPS_PER_ITEM * items / float(np.median(times)) / 1e9


def measured_gflops(info: DeviceInfo) -> float:
    """Cached FLOP rate of a device (measured once per platform/device/driver)."""
    path = cache_dir() / "device_speed.json"
    try:
        table = json.loads(path.read_text())
    except (OSError, ValueError):
        table = {}
    if info.key not in table:
        table[info.key] = _measure_gflops(info)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(table, indent=1))
    return float(table[info.key])


def quietly_built(context: cl.Context, source: str, options: list[str] | None = None,
                  ) -> tuple[cl.Program, str]:
    """The program built, and what its compiler printed meanwhile.  The compiler's warnings
    (PoCL gives hundreds for vector-typed helpers) are kept, not shown: pyopencl's are
    silenced, and what a driver's compiler writes to stderr itself (clang's "125 warnings
    generated.") is collected; `iblbench doctor --verbose` prints both."""
    printed: list[str] = []
    with warnings.catch_warnings(), output_collected(printed, ("stderr",)):
        warnings.simplefilter("ignore", cl.CompilerWarning)
        program = cl.Program(context, source).build(options=options or [])
    return program, "".join(printed).strip()


_PROBE_KERNEL = "__kernel void probe(__global float *out) { out[get_global_id(0)] = 1.0f; }"


@functools.lru_cache(maxsize=None)
def build_failure(info: DeviceInfo) -> str | None:
    """None if the device builds a trivial kernel, else the first line of its compiler's error."""
    try:
        quietly_built(cl.Context([info.device]), _PROBE_KERNEL)
    except cl.Error as error:
        lines = [line.strip() for line in str(error).splitlines()]
        reasons = [line for line in lines if line.startswith("error")] or [lines[0]]
        return reasons[0]
    return None


def matching_devices(spec: str) -> list[DeviceInfo]:
    """The devices whose 'platform / version / device' contains ``spec`` (any case); an
    InputError naming every device when none does."""
    devices = [d for d in all_devices() if spec.lower() in d.label.lower()]
    if not devices:
        valid = "; ".join(d.label for d in all_devices())
        raise InputError(None, f"no OpenCL device matches '{spec}'; devices: {valid}")
    return devices


def choose_device(spec: str | None = None) -> DeviceInfo:
    """The device to run on: among those matching ``spec`` (or ``IBLBENCH_DEVICE``) as a substring,
    if given, else among those that are not simulators, the devices that can build a kernel; of
    them a GPU, else the fastest CPU."""
    devices = all_devices()
    if not devices:
        raise InputError(None, "no OpenCL platform found; install pocl-opencl-icd "
                               "(apt) or pocl-binary-distribution (pip)")
    spec = spec or os.environ.get(ENV_DEVICE)
    if spec:
        devices = matching_devices(spec)
    else:
        devices = [d for d in devices if not d.is_simulator]
        if not devices:
            raise InputError(None, "only a simulator (Oclgrind) is installed, which runs kernels "
                                   "thousands of times slower; install a driver (Debian: "
                                   "apt-get install pocl-opencl-icd) or choose it by name "
                                   f"({argument('device', 'oclgrind')})")
    failures = {d: build_failure(d) for d in devices}
    if all(failures.values()):
        reasons = "; ".join(f"{d.label}: {reason}" for d, reason in failures.items())
        raise InputError(None, f"no OpenCL device here can build a kernel ({reasons}); on Debian "
                               "'apt-get install pocl-opencl-icd' gives a PoCL for this CPU")
    devices = [d for d in devices if not failures[d]]
    gpus = [d for d in devices if d.is_gpu]
    if gpus:
        return gpus[0]
    if len(devices) == 1:
        return devices[0]
    return max(devices, key=measured_gflops)


POOL_WIDTHS = (8, 16)   # light_pool.cl's explicit vector widths (POOL_LANES)


def pool_lanes_for(device, lanes: int | None = None) -> int:
    """The estimators' explicit vector width (``-DPOOL_LANES``) on ``device`` (a pyopencl
    device, or anything with its ``preferred_vector_width_float``): ``lanes`` where given, else
    16 where the device's preferred float width is 16 (AVX-512), else 8.  A ValueError for a
    ``lanes`` that is not one of :data:`POOL_WIDTHS` (0 included: an override never falls back
    to the device's width unseen)."""
    width = (16 if device.preferred_vector_width_float >= 16 else 8) if lanes is None else lanes
    if width not in POOL_WIDTHS:
        raise ValueError(f"lanes must be 8 or 16 (light_pool.cl's widths), got {lanes}")
    return width


# How the kernels that sum a pixel's draws in lanes (light_pool.cl's LAUNCH_PARAMS) are launched:
# one work item a pixel, or one a (pixel, block of draws) with a reduction (SAMPLE_BLOCKS).
LAUNCH_SHAPES = ("pixel", "sample_block")


def check_launch_shape(shape: str | None) -> None:
    """An InputError unless ``shape`` is one of :data:`LAUNCH_SHAPES`, "auto" or None."""
    if shape not in (None, "auto", *LAUNCH_SHAPES):
        raise InputError(None, f"{argument('launch_shape', shape)}: the launch shape is one of "
                               f"auto, {', '.join(LAUNCH_SHAPES)}")


def launch_shape_for(device, shape: str | None = None) -> str:
    """The launch shape on ``device`` (a pyopencl device, or anything with its ``type``):
    ``shape`` where given ("auto" or None: the device's), else ``"sample_block"`` where the
    device's type is GPU (its pixels alone are too few work items to keep it busy: 16k at 128²),
    else ``"pixel"`` (a CPU runs the lanes of one work item as SIMD and needs only a few work
    items a core).  An InputError for any other ``shape`` (:func:`check_launch_shape`)."""
    check_launch_shape(shape)
    if shape in (None, "auto"):
        return "sample_block" if device.type & cl.device_type.GPU else "pixel"
    return shape


# Work items a sample-block launch aims at per compute unit: a GPU's unit holds 1-2k resident
# work items (an NVIDIA SM 2048, an AMD CU 2560, fewer where a kernel's registers limit it), so
# 1024 a unit, with pixels × blocks ≥ that, leaves each unit whole waves to switch between while
# gathers wait, and a block still shades at least POOL_LANES draws.
ITEMS_PER_UNIT = 1024


def sample_blocks(units: int, pixels: int, chunks: int) -> tuple[int, int]:
    """(lane chunks per block, blocks per pixel) of a sample-block launch over ``pixels`` on a
    device of ``units`` compute units, where a pixel has at most ``chunks`` chunks of POOL_LANES
    draws: ⌊chunks / wanted⌋ chunks per block (at least one), wanted = ⌈units ×
    :data:`ITEMS_PER_UNIT` / pixels⌉ blocks, so that pixels × blocks ≥ units × ITEMS_PER_UNIT
    work items (one chunk a block where even that is too few) and a work item's setup (its
    pixel's shading, the pool's split) is shared by many draws.  Not always the most chunks a
    block that fill the device (10 chunks, 3 wanted: 3 a block in 4 blocks, where 4 in 3 would
    do): a block or so more, for a simpler rule."""
    chunks = max(int(chunks), 1)
    wanted = -(-units * ITEMS_PER_UNIT // max(int(pixels), 1))
    per_block = max(1, chunks // wanted)
    return per_block, -(-chunks // per_block)


class Compute:
    """A context and a profiling queue on one device, with a program cache for ``.cl`` files.

    Programs are built once per (files, defines) from package data with ``-I`` include
    directories (``estimators/runtime/kernels`` and pyopencl's Random123 headers) and ``-D`` options.
    ``pool_lanes`` (``-DPOOL_LANES``), the width of the explicit vectors in which the estimators
    run a pixel's samples (light_pool.cl), comes from the device: 16 where its preferred float
    vector width is 16 (AVX-512), else 8 (a generic CPU target warned of an ABI change for every
    float16 argument).  Both widths give the same images within float rounding, and Oclgrind
    checks both (tests/test_portability.py).  ``launch_shape`` (:func:`launch_shape_for`) is how
    the kernels that sum a pixel's draws launch (``DeviceGBuffer.run_sampled``): ``"pixel"`` on a
    CPU, ``"sample_block"`` (``-DSAMPLE_BLOCKS=1``) on a GPU; both give the same images within
    float rounding (tests/test_launch_shape.py).
    """

    def __init__(self, info: DeviceInfo, fp64: bool = True, lanes: int | None = None,
                 launch_shape: str | None = None):
        """``fp64=False`` builds the float path of the kernels that accumulate in double where the
        device has it (the reference, the CDF scans), as on a device without cl_khr_fp64;
        ``lanes`` (8 or 16) overrides :attr:`pool_lanes`, ``launch_shape`` (pixel, sample_block;
        auto: the device's) :attr:`launch_shape`."""
        self.info = info
        self.fp64 = fp64
        self.pool_lanes = pool_lanes_for(info.device, lanes)
        self.launch_shape = launch_shape_for(info.device, launch_shape)
        self.build_logs: dict[str, str] = {}
        self.context = cl.Context([info.device])
        self.queue = cl.CommandQueue(
            self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
        self._programs: dict[tuple, cl.Program] = {}
        self._kernels: dict[tuple, cl.Kernel] = {}
        self._group_limits: dict[int, int] = {}

    @property
    def doubles(self) -> bool:
        """Whether the kernels this builds accumulate in double (``HAVE_FP64``): the device has
        cl_khr_fp64 and this is not the float path.  A host buffer a kernel accumulates into is
        sized by this, never by the device alone."""
        return self.info.has_fp64 and self.fp64

    @property
    def device_name(self) -> str:
        return self.info.short_name

    def program(self, package: str, filename: str, defines: dict | None = None) -> cl.Program:
        key = (package, filename, tuple(sorted((defines or {}).items())))
        if key not in self._programs:
            source = kernel_path(package, filename).read_text()
            options = program_options(package, filename, defines, self.pool_lanes, self.doubles,
                                      self.launch_shape == "sample_block")
            program, printed = quietly_built(self.context, source, options)
            self._programs[key] = program
            log = program.get_build_info(self.info.device, cl.program_build_info.LOG).strip()
            self.build_logs[f"{package}/{filename}"] = "\n".join(filter(None, (log, printed)))
        return self._programs[key]

    def kernel(self, package: str, filename: str, name: str, defines: dict | None = None) -> cl.Kernel:
        """A kernel of a cached program, itself cached (retrieving kernels is not free)."""
        key = (package, filename, name, tuple(sorted((defines or {}).items())))
        if key not in self._kernels:
            self._kernels[key] = cl.Kernel(self.program(package, filename, defines), name)
        return self._kernels[key]

    def run(self, kernel: cl.Kernel, size: int, *args, group: int | None = None,
            offset: int = 0) -> cl.Event:
        """Launch a 1-D kernel over ``size`` work items (in work groups of ``group``, a divisor
        of ``size``, or of it the largest divisor the device allows; default: the device's choice),
        their global ids starting at ``offset``, and wait; returns the profiled event."""
        kernel.set_args(*args)
        event = cl.enqueue_nd_range_kernel(self.queue, kernel, (int(size),),
                                           None if group is None else (self.fitting_group(kernel, group),),
                                           (int(offset),) if offset else None)
        event.wait()
        return event

    def group_limit(self, kernel: cl.Kernel) -> int:
        """The most work items per group the device allows for ``kernel`` (asked once): a GPU may
        allow a kernel that holds many registers fewer than it allows others."""
        if kernel.int_ptr not in self._group_limits:
            self._group_limits[kernel.int_ptr] = kernel.get_work_group_info(
                cl.kernel_work_group_info.WORK_GROUP_SIZE, self.info.device)
        return self._group_limits[kernel.int_ptr]

    def fitting_group(self, kernel: cl.Kernel, group: int) -> int:
        """The largest divisor of ``group`` within :meth:`group_limit`, for a launch whose size is a
        multiple of ``group``."""
        group, limit = int(group), self.group_limit(kernel)
        return group if group <= limit else max(d for d in range(1, limit + 1) if group % d == 0)

    def to_device(self, array: np.ndarray) -> cl.Buffer:
        array = np.ascontiguousarray(array)
        return cl.Buffer(self.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=array)

    def empty(self, nbytes: int) -> cl.Buffer:
        return cl.Buffer(self.context, cl.mem_flags.READ_WRITE, max(int(nbytes), 4))

    def to_host(self, buffer: cl.Buffer, shape, dtype) -> np.ndarray:
        out = np.empty(shape, dtype)
        cl.enqueue_copy(self.queue, out, buffer).wait()
        return out


def kernel_path(package: str, filename: str) -> pathlib.Path:
    return pathlib.Path(str(importlib.resources.files(package) / filename))


def program_options(package: str, filename: str, defines: dict | None, lanes: int, doubles: bool,
                    sample_blocks: bool = False) -> list[str]:
    """The build options of a program (what :meth:`Compute.program` passes the device's compiler,
    and tests/test_compile_clang.py passes clang): include directories, ``defines``,
    ``POOL_LANES=lanes``, where ``doubles`` ``HAVE_FP64`` and where ``sample_blocks`` (the
    sample-block launch shape) ``SAMPLE_BLOCKS``."""
    # The kernel's own folder first, so a plugin's .cl files can include their siblings.
    options = [f"-I{kernel_path(package, filename).parent}"] + [f"-I{d}" for d in include_dirs()]
    options += [f"-D{name}={value}" for name, value in sorted((defines or {}).items())]
    options.append(f"-DPOOL_LANES={lanes}")
    if doubles:
        options.append("-DHAVE_FP64=1")
    if sample_blocks:
        options.append("-DSAMPLE_BLOCKS=1")
    return options


@functools.lru_cache(maxsize=1)
def include_dirs() -> tuple[str, ...]:
    import pyopencl
    return (str(kernel_path("iblbench.estimators.runtime", "kernels")),
            os.path.join(os.path.dirname(pyopencl.__file__), "cl"))


def event_ms(event: cl.Event | list[cl.Event]) -> float:
    """Device time of a profiled event in milliseconds, or of a list of them (one launch split
    into several: chunks.py) summed."""
    if isinstance(event, list):
        return sum(map(event_ms, event))
    return (event.profile.end - event.profile.start) * 1e-6


@functools.lru_cache(maxsize=None)
def get_compute(spec: str | None = None, launch_shape: str | None = None,
                lanes: int | None = None) -> Compute:
    """One shared Compute per device choice, launch shape (None: the device's) and ``lanes``
    (:func:`pool_lanes_for`'s override), so programs are built once per context."""
    return Compute(choose_device(spec), lanes=lanes, launch_shape=launch_shape)


class KeptBuffers:
    """An estimator's device buffers by name, kept across its frames and resets: every kernel
    writes what it later reads of them, and fresh buffers (tens of MB of scratch on smc's init
    frame) cost the kernels about a sixth of their time in page faults.  A buffer is made anew
    only when a larger one is asked for or the context changed."""

    def __init__(self):
        self._kept = {}

    def get(self, compute: Compute, name: str, nbytes: int) -> cl.Buffer:
        """The buffer ``name`` of at least ``nbytes`` on ``compute``'s context."""
        kept = self._kept.get(name)
        if kept is None or kept.size < nbytes or kept.context != compute.context:
            kept = self._kept[name] = compute.empty(nbytes)
        return kept
