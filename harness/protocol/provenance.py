"""Where a result came from: the installed packages' versions and the source checkout's git
revision.  Light on purpose (no OpenCL, NumPy or pandas): ``iblbench --version`` imports it."""
from __future__ import annotations

import pathlib
import subprocess
from importlib.metadata import PackageNotFoundError, version


def package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


def git_revision() -> str:
    """The source checkout's revision, "-dirty" with uncommitted changes; "unknown" when the
    package is not running from its own checkout (a site-packages install)."""
    package_root = pathlib.Path(__file__).resolve().parents[2]   # harness/protocol/ → the checkout
    try:
        top = subprocess.run(["git", "-C", str(package_root), "rev-parse", "--show-toplevel"],
                             capture_output=True, text=True, check=True, timeout=10).stdout.strip()
        if pathlib.Path(top).resolve() != package_root:
            return "unknown"
        return subprocess.run(["git", "-C", top, "describe", "--always", "--dirty", "--abbrev=40"],
                              capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
