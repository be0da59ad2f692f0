"""Every kernel program is OpenCL C 1.2 that any compiler takes, not only the device's: clang 15's
OpenCL front end compiles each program the portability set builds (harness/verify/portability.py),
with the source and build options Compute gives it (device.program_options), at both lane widths,
for ``spir64`` without fp64 (the float path: no cl_khr_fp64, no HAVE_FP64) and for
``nvptx64-nvidia-nvcl`` with it and in the launch shape a GPU builds (SAMPLE_BLOCKS), at ``-cl-std=CL1.2 -Werror``; and at ``-O0`` every function a
program calls is defined in it or is a built-in (a helper declared ``inline`` without ``static``
has no definition of its own there, by C99's inline rule, and a compiler that does not inline it
leaves an undefined symbol).  clang-15 is optional (the Makefile and .ci/run try to install it):
without it these tests skip."""
import concurrent.futures
import os
import re
import shlex
import shutil
import subprocess

import pytest

from iblbench.estimators.registry import estimator_names, get_estimator_class
from iblbench.estimators.runtime.device import kernel_path, program_options
from iblbench.harness.verify import portability

CLANG = shutil.which("clang-15")
pytestmark = pytest.mark.skipif(CLANG is None, reason="clang-15 is not installed (Debian: "
                                                      "apt-get install clang-15; the Makefile tries)")

# (clang's target options, whether the program is built with HAVE_FP64, whether in the GPU's
# sample-block launch shape, device.launch_shape_for)
TARGETS = {"spir64": (["-target", "spir64", "-Xclang", "-cl-ext=-cl_khr_fp64"], False, False),
           "nvptx64": (["-target", "nvptx64-nvidia-nvcl"], True, True)}
FLAGS = ["-x", "cl", "-cl-std=CL1.2", "-Werror", "-Xclang", "-finclude-default-header",
         # clang 15 takes OpenCL C 2.0's loop attribute at CL1.2 without a word; under another
         # name it is an unknown attribute, which -Werror rejects.
         "-Dopencl_unroll_hint=opencl_unroll_hint_needs_opencl_c_2_0",
         "-O0", "-emit-llvm", "-S", "-o", "-"]
# A function the LLVM IR declares but does not define, less OpenCL's built-ins (mangled, _Z…)
# and LLVM's intrinsics.
UNDEFINED = re.compile(r"^declare .*?@\"?(?!_Z|llvm\.)([\w.$]+)\"?\(", re.MULTILINE)


def command(program: tuple, lanes: int, target: str) -> list[str]:
    """The clang command line that compiles ``program`` (package, file, defines) for ``target``
    at ``lanes``, its source read from standard input."""
    package, filename, defines = program
    _, doubles, sample_blocks = TARGETS[target]
    options = program_options(package, filename, dict(defines), lanes, doubles, sample_blocks)
    return [CLANG, *FLAGS, *TARGETS[target][0], *options, "-"]


def compile_errors(program: tuple, lanes: int, target: str, source: str | None = None) -> str:
    """clang's complaints about ``program`` (package, file, defines), its source or ``source``
    instead, built for ``target`` at ``lanes``: its error output, or the functions it calls and
    does not define; "" when it compiles clean."""
    text = kernel_path(*program[:2]).read_text() if source is None else source
    done = subprocess.run(command(program, lanes, target), input=text, capture_output=True, text=True)
    if done.returncode or done.stderr:
        return done.stderr.strip() or f"exit status {done.returncode}"
    undefined = sorted(set(UNDEFINED.findall(done.stdout)))
    return f"calls undefined {', '.join(undefined)}" if undefined else ""


@pytest.fixture(scope="module")
def programs(compute) -> list[tuple]:
    """Each program (package, file, defines) that rendering the portability set asks for."""
    seen = {}
    kernel = compute.kernel

    def recording(package, filename, name, defines=None):
        seen[(package, filename, tuple(sorted((defines or {}).items())))] = None
        return kernel(package, filename, name, defines)

    compute.kernel = recording
    try:
        for case in portability.cases():
            portability.render(compute, case)
    finally:
        del compute.kernel
    return list(seen)


def all_errors(jobs: list[tuple]) -> list[str]:
    """compile_errors of each (program, lanes, target[, source]), compiled side by side."""
    with concurrent.futures.ThreadPoolExecutor(os.cpu_count()) as pool:
        return list(pool.map(lambda job: compile_errors(*job), jobs))


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("lanes", [8, 16])
def test_every_program_compiles_clean(programs, lanes, target):
    errors = dict(zip(programs, all_errors([(program, lanes, target) for program in programs])))
    failed = {program: error for program, error in errors.items() if error}
    first = next(iter(failed), None)
    assert not failed, f"{len(failed)} of {len(programs)} programs fail:\n" + "\n".join(
        f"{filename} {dict(defines)}:\n{error[:1500]}" for (_, filename, defines), error in failed.items()) + (
        f"\nthe first's command: {shlex.join(command(first, lanes, target))} < {kernel_path(*first[:2])}")


def test_the_recording_saw_every_estimators_program(programs):
    """Each registered estimator's main kernel file (the first of its kernel_files) is among
    the programs compiled, with and without visibility."""
    files = [(filename, "VISIBILITY" in dict(defines)) for _, filename, defines in programs]
    for name in estimator_names():
        main = get_estimator_class(name).kernel_files[0]
        assert (main, False) in files and (main, True) in files, name


# Constructs that an OpenCL 1.2 compiler may reject, each planted in a kernel appended to a
# program's source: (the construct, its portable form, the targets where the test must fail on
# it, what it says there).
PLANTS = {
    "unroll": ("__attribute__((opencl_unroll_hint))", "UNROLL", tuple(TARGETS), "opencl_unroll_hint"),
    "pi": ("M_PI", "M_PI_F", ("spir64",), "double precision constant requires cl_khr_fp64"),
    "inline": ("inline", "static inline", tuple(TARGETS), "calls undefined planted_twice"),
}
PLANTED = """
{inline} float planted_twice(float x) {{ return 2.0f * x; }}
__kernel void planted(__global float *out)
{{
    {unroll}
    for (int i = 0; i < 4; ++i) out[i] = planted_twice(out[i]) * {pi};
}}
"""


@pytest.mark.parametrize("plant", PLANTS)
def test_a_planted_construct_fails_where_it_is_not_opencl_1_2(programs, plant):
    """The same kernel in its portable form compiles clean on both targets."""
    construct, _, failing, message = PLANTS[plant]
    portable = {name: form for name, (_, form, _, _) in PLANTS.items()}
    source = kernel_path(*programs[0][:2]).read_text()
    jobs = [(programs[0], 8, target, source + PLANTED.format(**forms))
            for target in TARGETS for forms in ({**portable, plant: construct}, portable)]
    errors = iter(all_errors(jobs))
    for target in TARGETS:
        planted, clean = next(errors), next(errors)
        assert clean == "", (target, clean[:1000])
        assert (message in planted) == (target in failing), (target, planted[:1000])
