"""What several commands share: the parent parsers of the shared flags (``--device``, and
``--no-progress`` for the rendering commands), the argument types, ``--json`` and where a
command's human-readable output goes."""
from __future__ import annotations

import argparse
import functools
import pathlib
import sys


@functools.lru_cache(maxsize=None)
def device_flags() -> argparse.ArgumentParser:
    """``--device``: every command that opens a device."""
    device = argparse.ArgumentParser(add_help=False)
    device.add_argument("--device", metavar="SUBSTRING",
                        help="OpenCL platform/device substring (overrides IBLBENCH_DEVICE; default: "
                             "a GPU, else the fastest CPU platform)")
    return device


@functools.lru_cache(maxsize=None)
def rendering_flags() -> argparse.ArgumentParser:
    """``--device`` and ``--no-progress``: the commands that render."""
    rendering = argparse.ArgumentParser(add_help=False, parents=[device_flags()])
    rendering.add_argument("--no-progress", action="store_true", help="no progress bar")
    return rendering


def spp_list(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got '{text}'")
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"spp values must be positive integers, got '{text}'")
    return values


def resolution(text: str) -> tuple[int, int]:
    from iblbench.harness.protocol.sweep import parse_resolution

    try:
        return parse_resolution(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error))


def env_res(text: str) -> int:
    from iblbench.harness.protocol.sweep import check_env_res

    try:
        return check_env_res(positive_int(text))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error))


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got '{text}'")
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got '{text}'")
    return value


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got '{text}'") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive number, got '{text}'")
    return value


def non_negative_int(text: str) -> int:
    return 0 if text.strip() == "0" else positive_int(text)


def pixel(text: str) -> tuple[int, int]:
    try:
        x, y = (int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y such as 64,40, got '{text}'")
    return x, y


def add_run_dir(parser) -> None:
    """The positional DIR of the commands that read a run's results."""
    parser.add_argument("dir", type=pathlib.Path, metavar="DIR",
                        help="a run's output directory (holds results.parquet)")


def add_json(parser) -> None:
    parser.add_argument("--json", action="store_true",
                        help="print a machine-readable summary (one JSON document) on stdout; "
                             "the human-readable output goes to stderr (schema: README, "
                             "'Machine-readable output')")


def human_output(args):
    """Where a command's tables go: stderr when stdout carries its --json document."""
    return sys.stderr if getattr(args, "json", False) else sys.stdout


def print_json(document: dict) -> None:
    from iblbench.harness.protocol.results import json_text

    print(json_text(document))


class LazyDescriptionFormatter(argparse.RawDescriptionHelpFormatter):
    """Formats a description given as a function, called only when the help is shown (the
    stress battery's case list imports the battery)."""

    def add_text(self, text):
        super().add_text(text() if callable(text) else text)
