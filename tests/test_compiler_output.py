"""No compiler output unless asked for (issue 35, row 9): a driver's compiler that writes to
stderr itself (PoCL's clang: "1 warning generated.") is kept in the build log, which
`iblbench doctor --verbose` prints, and shows nothing on the terminal."""
import os
import pathlib
import subprocess
import sys
import uuid

from iblbench.estimators.runtime.device import quietly_built

# An implicit double-to-int conversion: a warning clang gives by default, an error nowhere.
# Each test's kernel adds its own number: PoCL's cache, keyed by the preprocessed source (no
# comments), would answer a kernel it has built before without compiling it.
WARNING_KERNEL = "__kernel void k(__global float *out) {{ int x = 1.5; out[0] = x + {}; }}"


def fresh_kernel() -> str:
    return WARNING_KERNEL.format(uuid.uuid4().int % 1_000_000_007)


def _warning_package(tmp_path, monkeypatch) -> str:
    name = f"warnpkg_{uuid.uuid4().hex}"
    (tmp_path / name).mkdir()
    (tmp_path / name / "__init__.py").write_text("")
    (tmp_path / name / "warn.cl").write_text(fresh_kernel())
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def test_a_kernel_that_warns_prints_nothing_and_keeps_the_warning(compute, tmp_path, monkeypatch, capfd):
    package = _warning_package(tmp_path, monkeypatch)
    compute.program(package, "warn.cl")
    printed = capfd.readouterr()
    assert printed.err == "" and printed.out == ""
    assert "warning" in compute.build_logs[f"{package}/warn.cl"].lower()


def test_what_the_compiler_writes_to_stderr_itself_is_returned(compute, capfd):
    _, printed = quietly_built(compute.context, fresh_kernel())
    assert capfd.readouterr().err == ""
    if compute.info.platform.name.startswith("Portable"):   # PoCL's clang counts its warnings
        assert "1 warning generated." in printed


def test_a_build_with_stderr_closed_still_builds():
    """``iblbench run 2>&-``: no descriptor 2 to redirect, and the build goes on."""
    code = ("from iblbench.estimators.runtime.device import get_compute, quietly_built\n"
            "from tests.test_compiler_output import fresh_kernel\n"
            "quietly_built(get_compute().context, fresh_kernel())\n"
            "print('built')\n")
    result = subprocess.run([sys.executable, "-c", code], text=True, stdout=subprocess.PIPE, preexec_fn=lambda: os.close(2), timeout=120,
                            cwd=pathlib.Path(__file__).parents[1])
    assert result.returncode == 0 and result.stdout.strip() == "built", result.stdout
