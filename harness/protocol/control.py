"""The A/A control (issue 32): how often the equal-time answer calls an estimator apart from an
unchanged copy of itself.

``iblbench run --control NAME`` runs estimator NAME a second time as ``NAME@control``
(:data:`~iblbench.harness.protocol.sweep.CONTROL_SUFFIX`): the same class, parameters and seeds,
so the same images at equal spp, but its own timed renders, equal-time calibration and place in
the run.  The two differ only by what the machine did to their times, so every verdict that calls
them apart (the ratio of their errors at a budget excludes 1, :meth:`Ranking.pair`) is a false
call.  A sound answer makes about the stated share of them (5% at the 95% level); many more say
that the times moved enough to move the answer, a busy machine for one.
"""
from __future__ import annotations

import dataclasses

from iblbench.harness.protocol.ranking import Ranking
from iblbench.harness.protocol.stats import LEVEL
from iblbench.harness.protocol.sweep import CONTROL_SUFFIX


@dataclasses.dataclass(frozen=True)
class ControlCalls:
    """One control over a run's rankings: in how many of the ``verdicts`` (scenes × budgets,
    and devices, where both were ranked) it was ``called_apart`` from its ``original``."""
    original: str
    control: str
    called_apart: int
    verdicts: int

    def text(self) -> str:
        stated = f"the stated level is {1 - LEVEL:.0%}"
        if not self.verdicts:
            return (f"A/A control: {self.control} and {self.original} were never both ranked at "
                    f"a budget, so the control could not be checked; {stated}.")
        return (f"A/A control: {self.control} was called apart from {self.original} in "
                f"{self.called_apart} of {self.verdicts} equal-time verdicts (scenes × budgets "
                f"where both were ranked); {stated}.")

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "level": round(1 - LEVEL, 6), "text": self.text()}


def controls(labels) -> list[str]:
    """The controls among estimator ``labels`` (a results table's ``estimator`` column), once
    each, in order."""
    return [label for label in dict.fromkeys(labels) if str(label).endswith(CONTROL_SUFFIX)]


def control_calls(rankings: dict[str, list[Ranking]], labels) -> list[ControlCalls]:
    """Per control among ``labels`` (:func:`controls`), its calls over ``rankings``
    (:func:`~iblbench.harness.protocol.ranking.scene_rankings`)."""
    calls = []
    for control in controls(labels):
        original = control[:-len(CONTROL_SUFFIX)]
        pairs = [ranking.pair(original, control)
                 for scene in rankings.values() for ranking in scene]
        pairs = [pair for pair in pairs if pair is not None]
        calls.append(ControlCalls(original, control, sum(p.significant for p in pairs),
                                  len(pairs)))
    return calls
