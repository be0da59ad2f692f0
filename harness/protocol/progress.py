"""The run's progress bar: where the run is and what it is doing (scene, estimator, stage), and
the time left from what the cells done so far cost.

tqdm's own estimate divides the cells left by the cells per second so far, and a sweep's
estimators differ a hundredfold in cost (bis and smc weigh 21 candidates per sample): on the
default sweep it swung from 14 to 36 to 3.5 minutes as cheap and dear estimators took turns,
while the bar sat still for 20 s on a reference or a calibration that it did not name (issue 23).
Costing each estimator's cells by a line in spp fitted on its cells so far then ignored the
scenes' sizes: fitted on the first scene's 128² pixels, it priced the 48² frames of a sequence
as 128² ones (``~31.3 min left`` for 17 minutes of cells, issue 35).

So each cell left is costed by its *work* times a *rate* (:func:`time_left`).  An equal-spp
cell's work is its scene's covered pixels × its spp (a frame is a cell of its own, so a
sequence's frames add up); an equal-time cell's is its budget in ms (its spp is chosen to fit
the budget, whatever its size).  The rate is the median seconds per unit of work over its
estimator's finished cells of that kind, or, for an estimator none of whose cells of that kind
is done, over every estimator's: a median, not a fit, so one slow cell (a busy moment) does not
swing it.  Replayed on a recorded default sweep (tests/test_progress.py) it stays within 0.73
and 1.06 times the time the cells left took, from 10% of the cells on; a line in spp per pixel
came to 0.58-0.80 there, the later scenes (shadows, a back-lit sky, 48² frames) costing 1.5-2
times the first ones per pixel and sample.  The median prices a cell's work that does not grow
with spp (the scoring of every render, the launches) per sample too, so it runs high where that
work dominates: by up to 2.6 times near the end of a small mixed-size sweep scored with FLIP.
The time left covers the cells; the per-frame work around them (frame caches, references,
warm-ups, calibrations) is not in it.
"""
from __future__ import annotations

import collections
from typing import Iterable, Mapping

import numpy as np

# tqdm's bar without its own time left and rate; the postfix carries ours.
BAR_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"


def cell_work(key: tuple, pixels: Mapping[str, int]) -> tuple[bool, float]:
    """(equal time, work) of the cell ``key`` (scene, estimator, spp, frame, seed, budget):
    for an equal-spp cell its scene's ``pixels`` × spp, for an equal-time cell its budget in
    ms."""
    if key[5] is not None:
        return True, float(key[5])
    return False, float(pixels[key[0]] * key[2])


def time_left(remaining: Mapping[tuple[str, bool, float], int],
              rates: Mapping[tuple[str, bool], list[float]]) -> tuple[float, list[str]]:
    """(seconds, estimators not timed yet): the cells ``remaining`` ((estimator, equal time,
    work) → how many, :func:`cell_work`) costed at their work times the median of ``rates``
    (seconds per unit of work of the finished cells, by (estimator, equal time)) of their
    estimator, or of every estimator where it has none of that kind; the estimators of cells
    left that no finished cell of their kind can cost (they are not in the seconds)."""
    own = {key: float(np.median(values)) for key, values in rates.items() if values}
    pooled = {}
    for timed in (False, True):
        values = [rate for (_, kind), measured in rates.items() if kind == timed
                  for rate in measured]
        if values:
            pooled[timed] = float(np.median(values))
    seconds, untimed = 0.0, []
    for (estimator, timed, work), count in remaining.items():
        if count <= 0:
            continue
        rate = own.get((estimator, timed), pooled.get(timed))
        if rate is not None:
            seconds += count * work * rate
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
    budget); ``pixels``: the covered pixels of each scene's G-buffer."""

    def __init__(self, bar, todo: Iterable[tuple], pixels: Mapping[str, int]):
        self.bar = bar
        self.pixels = dict(pixels)
        self.remaining = collections.Counter((key[1], *cell_work(key, self.pixels))
                                             for key in todo)
        self.rates: dict[tuple[str, bool], list[float]] = collections.defaultdict(list)
        self.where: tuple[str, ...] = ()

    def stage(self, stage: str, *where: str) -> None:
        """The run is at ``stage`` (reference, warm-up, rendering, ...) in ``where`` (the scene
        and the estimator; none given: where it was)."""
        if where:
            self.where = where
        self.bar.set_description(" · ".join([*self.where, stage]))

    def finished(self, key: tuple, seconds: float) -> None:
        """Cell ``key`` is done, having cost the run ``seconds`` (a cluster's:
        its worker's seconds over the number of workers)."""
        timed, work = cell_work(key, self.pixels)
        self.remaining[(key[1], timed, work)] -= 1
        self.rates[(key[1], timed)].append(seconds / work)
        self.bar.set_postfix_str(left_text(*self.left()), refresh=False)
        self.bar.update()

    def left(self) -> tuple[float, list[str]]:
        """The seconds the cells left should take, and the estimators not timed yet
        (:func:`time_left`)."""
        return time_left(self.remaining, self.rates)
