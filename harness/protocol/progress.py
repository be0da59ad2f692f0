"""The run's progress bar: where the run is and what it is doing (scene, estimator, stage), and
the time left from what each estimator's cells have cost so far.

tqdm's own estimate divides the cells left by the cells per second so far, and a sweep's
estimators differ a hundredfold in cost (bis and smc weigh 21 candidates per sample): on the
default sweep it swung from 14 to 36 to 3.5 minutes as cheap and dear estimators took turns,
while the bar sat still for 20 s on a reference or a calibration that it did not name (issue 23).
Here each cell left is costed at its own estimator's seconds per cell at its spp
(:func:`cell_seconds`), so a cheap cell that finishes takes its own few seconds off the time
left, and the description names the stage the run is in.  The time left covers the cells; the
per-frame work around them (frame caches, references, warm-ups, calibrations) is not in it.
"""
from __future__ import annotations

import collections
from typing import Iterable, Mapping

import numpy as np

# tqdm's bar without its own time left and rate; the postfix carries ours.
BAR_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"


def cell_seconds(measured: list[tuple[int, float]], spp: int | None) -> float:
    """Seconds of one estimator's cell at ``spp`` from its finished cells, ``measured`` as
    (spp, seconds): the least-squares line a + b·spp through them once they span two spp (a
    fixed part, the scoring, and a part per sample), else their mean scaled by spp; for an
    equal-time cell whose spp is not chosen yet (None), their mean."""
    spps, seconds = np.array(measured, float).T
    if spp is None:
        return float(seconds.mean())
    if len(set(spps)) < 2:
        return float(seconds.mean() * spp / spps.mean())
    slope, intercept = np.polyfit(spps, seconds, 1)
    if slope < 0:   # noise over a narrow spp range: no trend to extrapolate
        return float(seconds.mean())
    return max(float(intercept + slope * spp), 0.0)


def time_left(remaining: Mapping[tuple[str, int | None], int],
              measured: Mapping[str, list[tuple[int, float]]]) -> tuple[float, list[str]]:
    """(seconds, estimators not timed yet): the cells ``remaining`` ((estimator, spp) → how
    many; spp None for an equal-time cell) costed by :func:`cell_seconds` over their estimator's
    ``measured`` cells, and the estimators of cells left that have none measured yet (their
    cells are not in the seconds)."""
    seconds, untimed = 0.0, []
    for (estimator, spp), count in remaining.items():
        if count <= 0:
            continue
        if measured.get(estimator):
            seconds += count * cell_seconds(measured[estimator], spp)
        elif estimator not in untimed:
            untimed.append(estimator)
    return seconds, untimed


def left_text(seconds: float, untimed: list[str]) -> str:
    """The postfix: ``~3.5 min left``, a lower bound while estimators are not timed yet."""
    if seconds <= 0 and untimed:
        return "time left: after the first cells"
    amount = (f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"
              if seconds < 5400 else f"{seconds / 3600:.1f} h")
    if untimed:
        return (f"≥{amount} left, {len(untimed)} estimator{'s' * (len(untimed) > 1)} not "
                "timed yet")
    return f"~{amount} left"


class Progress:
    """The description and postfix of the run's ``bar`` (a tqdm, disabled where no bar is
    shown) over ``todo``, the keys of the cells to run (scene, estimator, spp, frame, seed,
    budget)."""

    def __init__(self, bar, todo: Iterable[tuple]):
        self.bar = bar
        self.remaining = collections.Counter((key[1], key[2]) for key in todo)
        self.measured: dict[str, list[tuple[int, float]]] = collections.defaultdict(list)
        self.where: tuple[str, ...] = ()

    def stage(self, stage: str, *where: str) -> None:
        """The run is at ``stage`` (reference, warm-up, rendering, ...) in ``where`` (the scene
        and the estimator; none given: where it was)."""
        if where:
            self.where = where
        self.bar.set_description(" · ".join([*self.where, stage]))

    def finished(self, key: tuple, spp: int, seconds: float) -> None:
        """Cell ``key`` is done, run at ``spp``, having cost the run ``seconds`` (a cluster's:
        its worker's seconds over the number of workers)."""
        self.measured[key[1]].append((int(spp), seconds))
        self.remaining[(key[1], key[2])] -= 1
        self.bar.set_postfix_str(left_text(*time_left(self.remaining, self.measured)),
                                 refresh=False)
        self.bar.update()
