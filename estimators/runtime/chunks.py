"""Kernel launches split by measured device time, so that none runs much past ``CHUNK_MS``: a
display driver's watchdog (about 2 s on Windows) kills a longer one, and a Ctrl-C waits for the
launch in flight.  Every kernel whose one launch grows with spp or image size launches its work
items through :func:`run_in_chunks`: the exact reference, every pixel kernel
(``DeviceGBuffer.run``), bis's and smc's lockstep kernels and ``smc_advance``.

The split changes no result: each work item computes what it computes in one launch (its own
pixel's streams and sums), whatever launch it falls in, so images are bit-identical to one
launch (tests/test_chunks.py).  Its floor is one work group: a pixel's samples stay in one work
item, so one group's launch takes a pixel's whole sample loop (on a GPU, whose group runs its
pixels side by side, about one pixel's serial time); in the sample-block launch shape
(``DeviceGBuffer.run_sampled``) a work item is one block of a pixel's samples, and the chunks
split the pixels' blocks.
"""
from __future__ import annotations

from typing import Callable

import pyopencl as cl

from iblbench.estimators.runtime.device import event_ms

CHUNK_MS = 100.0           # the most device time a launch should take: 1/20 of a 2 s watchdog (read per call)
# Launches aim at this share of CHUNK_MS: the next launch's rate is not the last one's (on a 2-core
# CPU others' load made the same launch 2.5× slower from one to the next, and a launch 3× larger
# took 4-5× as long: its scratch left the cache), and at the whole target they passed it by 80%.
AIM = 0.5
# Work items of the first launch, before any rate is measured: rounded up, one group.  At bis's
# and smc's most spp one group of pixels already takes 0.3-1 s on a 2-core CPU.
FIRST_CHUNK_ITEMS = 1
# A launch takes at most this many times the last one's items: bis's launches of 4× the pixels
# took 7× as long (its scratch left the cache), so a larger step could pass CHUNK_MS.
MOST_GROWTH = 2
# Items a millisecond that the last launch of each kind ran at (a caller's key that holds what sets
# an item's work, e.g. a kernel and its scalar arguments, spp among them): the next run of that kind
# starts there, so a timed render after its warm-up runs in as few launches as the target allows
# (one where the whole fits), not from one group up with a wait between each (issue 34).
_RATES: dict = {}


def run_in_chunks(total: int, group: int, launch: Callable[[int, int], cl.Event],
                  most: int | None = None, kind=None) -> list[cl.Event]:
    """Work items 0 … ``total`` − 1 in order, by ``launch(first, count)``, which runs items
    first … first + count − 1 in one launch, waits for it and returns its profiled event; returns
    the events.

    The first launch takes what the last launch of ``kind`` ran at fills AIM × CHUNK_MS with, or
    FIRST_CHUNK_ITEMS where ``kind`` is None or new; each later one as many as the last one's measured
    rate fills AIM × CHUNK_MS with, but at most MOST_GROWTH times the last (one launch timed too short
    cannot make the next minutes long) and at most ``most`` (a caller's scratch bound); every
    count but the last is a whole number of ``group`` items, at least one group."""
    def whole_groups(items: int) -> int:
        items = max(group, items // group * group)
        return items if most is None else min(items, most)

    rate = _RATES.get(kind) if kind is not None else None
    events, first = [], 0
    count = whole_groups(int(rate * AIM * CHUNK_MS) if rate else FIRST_CHUNK_ITEMS)
    while first < total:
        count = min(count, total - first)
        events.append(launch(first, count))
        first += count
        ms = event_ms(events[-1])
        if kind is not None:
            _RATES[kind] = count / max(ms, 1e-3)
        count = whole_groups(min(MOST_GROWTH * count, int(count * AIM * CHUNK_MS / max(ms, 1e-3))))
    return events
