"""What several commands share: the parent parsers of the shared flags (``--device``, and
``--no-progress`` for the rendering commands), the argument types (the command line's
spellings of values, parsed by the harness's sweep parsers: :mod:`iblbench.harness.protocol.sweep`),
``--json`` and where a command's human-readable output goes."""
from __future__ import annotations

import argparse
import functools
import math
import pathlib
import re
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


def launch_shape(text: str) -> str:
    """``--launch-shape``'s value as the API spells it (sample-block: sample_block)."""
    return text.replace("-", "_")


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


def frames_arg(text: str) -> tuple[int, ...] | slice | None:
    """``--frames``: ``START:STOP[:STEP]`` (a Python slice), ``all``, ``A..B`` (inclusive) or
    ``N,N,...``; a bad spec is an InputError (the CLI prints it on one line and exits 2)."""
    from iblbench.harness.protocol.sweep import parse_frames
    from iblbench.foundation.errors import InputError

    value = text.strip()
    if re.fullmatch(r"\d+(\s*,\s*\d+)*", value):
        value = [int(part) for part in value.split(",")]
    try:
        return parse_frames(value)
    except ValueError as error:
        raise InputError(None, f"--frames: {error}") from None


def repeats_arg(text: str) -> tuple[int, tuple[tuple[str, int], ...]]:
    """``--repeats``: ``N`` or ``N,NAME=M,...`` (``parse_repeats``)."""
    from iblbench.harness.protocol.sweep import parse_repeats

    table = {}
    for part in text.split(","):
        key, _, number = part.rpartition("=")
        try:
            table[key.strip() or "default"] = int(number)
        except ValueError:
            table[key.strip() or "default"] = number.strip()
    try:
        return parse_repeats(table)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"{error} (write N or N,NAME=M,...)")


def labels_arg(text: str) -> tuple[str, ...]:
    """``--control``: ``NAME[,NAME...]``, each an estimator label; a comma inside a label's
    braces (``balanced{a=1,b=2}``) is the label's own."""
    labels = tuple(part.strip() for part in re.split(r",(?![^{]*\})", text))   # not in {}
    if not all(labels):
        raise argparse.ArgumentTypeError(f"expected estimator labels separated by commas, "
                                         f"got '{text}'")
    return labels


def metrics_arg(text: str) -> tuple[str, ...]:
    """``--metrics``: comma-separated metric names (harness.protocol.metric)."""
    from iblbench.harness.protocol.metric import parse_metrics

    try:
        return parse_metrics(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error))


def budgets_arg(text: str) -> tuple[float, ...]:
    """``--time-budget-ms``: ``T`` or ``T,T,...`` milliseconds, each positive."""
    try:
        values = tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        values = ()
    if not values or not all(math.isfinite(v) and v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected positive milliseconds such as 20 or 5,20, "
                                         f"got '{text}'")
    return values


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
                             "the human-readable output goes to stderr (schema: "
                             "docs/results.md)")


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
