"""Which frame of a sequence the report's images show (issue 11, "Report").

A sequence's first frame is often unrepresentative (the `sun-day` sky starts at twilight, nearly
black), so, unless ``report --frame`` names one, the images show the **median-luminance frame**:
the frame whose reference has the median mean luminance over the run's frames (the lower median
of an even count; equal means in frame order).  The mean is over all pixels of the saved
reference (``images/<scene>/f<frame>/reference.exr``, Rec.709 Y): the geometry is static, so it is
the covered pixels' mean times one constant factor and ranks the frames alike.  Where a frame's
reference is missing or unreadable, the middle frame of the run's list is shown instead, and the
rule says so.
"""
from __future__ import annotations

import pathlib

import numpy as np

from iblbench.scenes.cubemap import luminance
from iblbench.foundation.errors import InputError
from iblbench.scenes.imageio import read_exr


def shown_frame(run_dir: pathlib.Path, scene: str, frames: list[int],
                chosen: int | None = None) -> tuple[int, str]:
    """(the frame the images of ``scene`` show, the rule that chose it, for the report)."""
    frames = sorted(frames)
    if len(frames) == 1:
        return frames[0], "the scene's only frame"
    if chosen is not None:
        return chosen, "chosen with report --frame"
    images = pathlib.Path(run_dir) / "images" / scene
    try:
        means = [float(luminance(read_exr(images / f"f{f}" / "reference.exr")).mean())
                 for f in frames]
    except InputError:
        middle = frames[(len(frames) - 1) // 2]
        return middle, (f"the middle of frames {frames[0]}–{frames[-1]} (a reference image is "
                        "missing, so the median-luminance frame cannot be found)")
    order = np.argsort(means, kind="stable")
    median = frames[order[(len(frames) - 1) // 2]]
    return median, (f"the frame whose reference has the median mean luminance of the run's "
                    f"{len(frames)} frames ({frames[0]}–{frames[-1]}); report --frame picks another")


__all__ = ["shown_frame"]
