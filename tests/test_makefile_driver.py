"""Issue 35, row 11: the driver the Makefile installs on a machine with no system OpenCL driver.
The venv recipe runs against stand-ins (python, pip, iblbench, id, apt-get on PATH) that log
their calls, in a copy of the Makefile, so no package is installed."""
import os
import pathlib
import shutil
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
LOGGED = '#!/bin/sh\necho "$(basename "$0") $*" >> "$CALLS"\n'
FAKE_PYTHON = LOGGED + 'if [ "$1 $2" = "-m venv" ]; then mkdir -p "$3/bin"; ' \
    'cp "$0" "$3/bin/python"; cp "$(dirname "$0")/iblbench" "$3/bin/iblbench"; fi\n'
FAKE_IBLBENCH = LOGGED + 'echo "* [CPU] stand-in device"\n'
TOOLS = ("sh", "ls", "sed", "grep", "cut", "tail", "touch", "mkdir", "cp", "basename", "dirname",
         "cat", "echo")


def make_venv(tmp_path, uid: str, apt: bool, *args: str) -> tuple[str, str]:
    """``make venv`` in a copy of the Makefile with stand-ins; (its output, the calls logged)."""
    if shutil.which("make") is None:
        pytest.skip("no make")
    work, bin_ = tmp_path / "repo", tmp_path / "bin"
    work.mkdir()
    bin_.mkdir()
    shutil.copy(ROOT / "Makefile", work)
    (work / "pyproject.toml").write_text("")
    stand_ins = {"python": FAKE_PYTHON, "iblbench": FAKE_IBLBENCH, "id": f'#!/bin/sh\necho {uid}\n',
                 "clang-15": LOGGED}
    if apt:
        stand_ins["apt-get"] = LOGGED
    for name, text in stand_ins.items():
        (bin_ / name).write_text(text)
        (bin_ / name).chmod(0o755)
    for tool in TOOLS:   # only these on PATH, so no real apt-get is ever found
        (bin_ / tool).symlink_to(shutil.which(tool))
    calls = tmp_path / "calls"
    env = dict(os.environ, PATH=str(bin_), CALLS=str(calls))
    env.pop("OCL_ICD_VENDORS", None)
    done = subprocess.run([shutil.which("make"), "venv", f"PYTHON={bin_ / 'python'}",
                           f"OPENCL_VENDORS={tmp_path / 'no-vendors'}", *args],
                          cwd=work, env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout, calls.read_text()


def test_as_root_with_apt_it_installs_debians_pocl_not_the_pip_one(tmp_path):
    out, calls = make_venv(tmp_path, "0", apt=True)
    assert "apt-get install -y -q pocl-opencl-icd" in calls, calls
    assert "[pocl]" not in calls and "pocl]" not in calls, calls
    assert "installing Debian's pocl-opencl-icd" in out and "builds for this CPU" in out, out


def test_without_root_it_installs_the_pip_pocl_and_says_what_is_faster(tmp_path):
    out, calls = make_venv(tmp_path, "1000", apt=True)
    assert "apt-get" not in calls and ".[test,pocl]" in calls, calls
    assert "not root with apt-get" in out and "apt-get install -y pocl-opencl-icd" in out, out


def test_without_apt_it_installs_the_pip_pocl(tmp_path):
    out, calls = make_venv(tmp_path, "0", apt=False)
    assert ".[test,pocl]" in calls, calls


def test_opencl_pip_forces_the_pip_pocl_even_as_root(tmp_path):
    out, calls = make_venv(tmp_path, "0", True, "OPENCL=pip")
    assert "apt-get install -y -q pocl-opencl-icd" not in calls and ".[test,pocl]" in calls, calls
    assert "OPENCL=pip" in out, out
