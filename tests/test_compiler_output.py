"""No compiler output unless asked for (issue 35, row 9): a driver's compiler that writes to
stderr itself (PoCL's clang: "1 warning generated.") is kept in the build log, which
`iblbench doctor --verbose` prints, and shows nothing on the terminal."""
import uuid

from iblbench.estimators.runtime.device import quietly_built

# An implicit double-to-int conversion: a warning clang gives by default, an error nowhere.
WARNING_KERNEL = "__kernel void k(__global float *out) {{ int x = 1.5; out[0] = x; }} /* {} */"


def _warning_package(tmp_path, monkeypatch) -> str:
    name = f"warnpkg_{uuid.uuid4().hex}"
    (tmp_path / name).mkdir()
    (tmp_path / name / "__init__.py").write_text("")
    # A fresh comment each time, so that no kernel cache answers without compiling.
    (tmp_path / name / "warn.cl").write_text(WARNING_KERNEL.format(uuid.uuid4()))
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def test_a_kernel_that_warns_prints_nothing_and_keeps_the_warning(compute, tmp_path, monkeypatch, capfd):
    package = _warning_package(tmp_path, monkeypatch)
    compute.program(package, "warn.cl")
    printed = capfd.readouterr()
    assert printed.err == "" and printed.out == ""
    assert "warning" in compute.build_logs[f"{package}/warn.cl"].lower()


def test_what_the_compiler_writes_to_stderr_itself_is_returned(compute, capfd):
    _, printed = quietly_built(compute.context, WARNING_KERNEL.format(uuid.uuid4()))
    assert capfd.readouterr().err == ""
    if compute.info.platform.name.startswith("Portable"):   # PoCL's clang counts its warnings
        assert "1 warning generated." in printed
