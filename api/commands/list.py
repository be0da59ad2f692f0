"""``iblbench list devices | estimators | metrics | scenes``."""
from __future__ import annotations

import re

from iblbench.commands.common import device_flags


DESCRIPTION = """\
List OpenCL devices (and the one chosen), registered estimators, registered metrics (each
with its results column, unit and direction, and whether a sweep that names none computes it),
or built-in scenes."""


def add_parser(subparsers) -> None:
    listing = subparsers.add_parser("list", help="list devices, estimators, metrics or scenes",
                                  description=DESCRIPTION,
                                  parents=[device_flags()])
    listing.add_argument("what", choices=("devices", "estimators", "metrics", "scenes"))


def run(args) -> None:
    if args.what == "devices":
        from iblbench.estimators.runtime.device import (all_devices, build_failure, choose_device,
                                                        measured_gflops)

        chosen = choose_device(args.device)
        for info in all_devices():
            mark = "*" if info.key == chosen.key else " "
            failure = build_failure(info)
            note = (f"  cannot build a kernel: {failure}" if failure
                    else f"  {_rate(measured_gflops(info))} (measured)")
            print(f"{mark} [{info.kind}] {info.label}{note}")
        print("(* = chosen; override with --device or IBLBENCH_DEVICE; a simulator only by name;\n"
              " speed: straight-line FMAs, measured once per device and driver, cached)")
    elif args.what == "estimators":
        from iblbench.estimators.registry import estimator_docstrings

        for name, docstring in estimator_docstrings().items():
            print(_listing_line(name, summary(docstring, name)))
    elif args.what == "metrics":
        from iblbench.harness.protocol.metric import registered

        for metric in registered():
            unit = f" in {metric.unit}" if metric.unit else ""
            better = "lower" if metric.lower_is_better else "higher"
            when = "always" if metric.always else "by default" if metric.default else "when named"
            print(_listing_line(metric.name, f"{metric.label}{unit}, {better} is better; column "
                                             f"{metric.column}; computed {when}. "
                                             f"{summary(metric.description, metric.label)}"))
    else:
        from iblbench.scenes.registry import BUILTIN_SCENES, builtin_frames, scene_names

        for name in scene_names():
            frames = builtin_frames(name)
            print(_listing_line(name, f"{frames} frame{'s' * (frames > 1)}. "
                                      f"{summary(BUILTIN_SCENES[name].__doc__, name)}"))


def _rate(gflops: float) -> str:
    """A FLOP rate with a unit that keeps it readable (a simulator's is MFLOP/s or less)."""
    return f"{gflops:.1f} GFLOP/s" if gflops >= 1 else f"{gflops * 1e3:.3g} MFLOP/s"


_NAME_WIDTH = 15
# Roles (:class:`~a.b.C` -> C), literals and emphasis (``x``, *x* -> x).
_REST_ROLE = re.compile(r":[a-z]+:`~?(?:[\w.]*\.)?([^`]+)`")
_REST_MARKUP = re.compile(r"``([^`]+)``|\*\*([^*]+)\*\*|\*([^*\s][^*]*)\*")
# A full stop ends a sentence before a capital, or at the end, but not after an abbreviation.
_SENTENCE_END = re.compile(r"(?<!\bal)(?<!\bEq)(?<!\bSec)(?<!\bFig)(?<!\bet)(?<!e\.g)(?<!i\.e)"
                           r"\.(?=\s+[A-Z]|\s*$)")


def summary(docstring: str | None, name: str) -> str:
    """The first sentence of a docstring as plain text: reST markup stripped, the lines of its
    first paragraph joined, and a leading "name:" dropped (the listing shows the name)."""
    paragraph = " ".join((docstring or "").strip().split("\n\n")[0].split())
    text = _REST_MARKUP.sub(lambda m: next(g for g in m.groups() if g), _REST_ROLE.sub(r"\1", paragraph))
    end = _SENTENCE_END.search(text)
    text = text[:end.end()] if end else text
    return text.removeprefix(f"{name}: ")


def _listing_line(name: str, text: str) -> str:
    """``name`` then ``text`` wrapped to the terminal, continuation lines under the text."""
    import shutil
    import textwrap

    width = max(shutil.get_terminal_size().columns, _NAME_WIDTH + 30)
    if not text:   # a plugin without a docstring is listed all the same
        return name
    return textwrap.fill(text, width, initial_indent=f"{name:{_NAME_WIDTH - 1}s} ", break_on_hyphens=False,
                         subsequent_indent=" " * _NAME_WIDTH)
