"""The machine's timing noise, recorded, and the equal-time answer's A/A check simulated on it
(issue 32).

**Recording** (:func:`record`, ``python -m iblbench.harness.verify.timing_noise OUT.txt``):
the timing floor's kernel (``fma_throughput``, sized to at least 3 ms: 10 ms idle here)
launched one at a time, each after a little host work (a NumPy product); the device ms of each
launch in order.  Its slow and fast spells, tens to hundreds of launches long, are the
machine's, not a kernel's (:mod:`iblbench.harness.protocol.timing`, "The device's own
floor").  Two recordings of this 2-vCPU machine ship in ``tests/data/``: one idle and one
beside two busy processes.

**The simulated A/A check** (:func:`simulate`): a sweep of three estimators, ``a``, its
unchanged copy ``a copy`` (the same error replicates, bit for bit, as a renamed plugin renders)
and ``b`` (half ``a``'s error at equal time), each at four spp levels over 2 seeds × 5 renders,
whose renders take their true time times the recorded series' relative speed at the moment
they run, in the run's order: interleaved rounds (one render of every cell a round, as the
executor renders a frame) or each cell's renders back to back.  It models no cost of a place
in the round, so its rounds keep one order; real runs showed one, and the executor orders each
round anew (:mod:`iblbench.harness.protocol.timing`, "Rounds").  The table goes through the real
ranking (:func:`iblbench.harness.protocol.ranking.scene_rankings`), and the simulation counts how
often the copy was called apart from ``a`` (the A/A rate, which should be the stated 5%) and
how often ``b`` was resolved ahead of ``a`` (power).
"""
from __future__ import annotations

import argparse
import pathlib

import numpy as np
import pandas as pd

from iblbench.harness.protocol.ranking import scene_rankings
from iblbench.harness.protocol.stats import renders_text

SPP = (16, 64, 256, 1024)
SEEDS, RENDERS = 2, 5
BUDGETS = (2.0, 5.0, 10.0)
COPY = "a copy"


def record(compute, launches: int = 1500) -> np.ndarray:
    """Device ms of ``launches`` launches of the timing floor's kernel, one at a time with a
    NumPy product of host work between them (module docstring)."""
    from iblbench.estimators.runtime.probes import floor_launches

    host = np.random.default_rng(0).random((200, 200))
    times = []
    for _ in range(launches):
        times += floor_launches(compute, 1)
        host = host @ host / 200.0   # the host's scoring between two renders, roughly
    return np.asarray(times)


def read_series(path) -> np.ndarray:
    """A recorded series (one ms value per line) as relative speeds: each over the median."""
    values = np.loadtxt(path, dtype=np.float64, ndmin=1)
    return values / np.median(values)


def _true_ms(spp: int) -> float:
    """A cell's noiseless time: 0.2 ms of fixed work and 0.02 ms per spp (0.5 to 21 ms)."""
    return 0.2 + 0.02 * spp


def simulated_table(series: np.ndarray, rng, rounds: bool) -> pd.DataFrame:
    """One simulated run's results table (module docstring)."""
    cells = [(label, spp, seed) for label in ("a", COPY, "b") for spp in SPP
             for seed in range(SEEDS)]
    errors = {}
    for spp in SPP:
        for seed in range(SEEDS):
            # ΔE76 ∝ 1/√(time): b at equal time has half a's error; a and its copy share theirs
            noise = rng.lognormal(0.0, 0.05, size=(2, RENDERS))
            errors[("a", spp, seed)] = errors[(COPY, spp, seed)] = 10 / np.sqrt(spp) * noise[0]
            errors[("b", spp, seed)] = 5 / np.sqrt(spp) * noise[1]
    order = ([(cell, r) for r in range(RENDERS) for cell in cells] if rounds
             else [(cell, r) for cell in cells for r in range(RENDERS)])
    start = int(rng.integers(len(series)))
    speed = np.resize(np.roll(series, -start), len(order))
    times = {cell: [] for cell in cells}
    for (cell, _), factor in zip(order, speed):
        times[cell].append(_true_ms(cell[1]) * factor)
    return pd.DataFrame([{"scene": "simulated", "estimator": label, "spp": spp, "frame": 0,
                          "seed": seed, "time_budget_ms": np.nan,
                          "mean_delta_e76": errors[(label, spp, seed)][0],
                          "mean_delta_e76_renders": renders_text(errors[(label, spp, seed)]),
                          "time_ms": float(np.median(times[(label, spp, seed)])),
                          "time_ms_renders": renders_text(times[(label, spp, seed)])}
                         for label, spp, seed in cells])


def simulate(series: np.ndarray, runs: int, rounds: bool = True, seed: int = 0) -> dict:
    """The A/A rate and the power over ``runs`` simulated runs at ``BUDGETS`` (module
    docstring): {"verdicts", "aa_called_apart", "b_ahead"}."""
    rng = np.random.default_rng(seed)
    verdicts = apart = ahead = 0
    for _ in range(runs):
        for ranking in scene_rankings(simulated_table(series, rng, rounds),
                                      budgets=BUDGETS)["simulated"]:
            aa, ab = ranking.pair("a", COPY), ranking.pair("a", "b")
            if aa is None or ab is None:
                continue
            verdicts += 1
            apart += aa.significant
            ahead += ab.significant and ab.ratio < 1
    return {"verdicts": verdicts, "aa_called_apart": apart, "b_ahead": ahead}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m iblbench.harness.verify.timing_noise",
        description="Record this machine's timing noise: the timing floor's kernel launched one "
                    "at a time, device ms per line (the A/A simulation's input).")
    parser.add_argument("out", type=pathlib.Path, help="the text file to write")
    parser.add_argument("--launches", type=int, default=1500)
    args = parser.parse_args(argv)
    from iblbench.estimators.runtime.device import get_compute

    times = record(get_compute(), args.launches)
    args.out.write_text("".join(f"{t:.4g}\n" for t in times))
    print(f"wrote {len(times)} launches to {args.out}: median {np.median(times):.3g} ms, "
          f"p90/p10 {np.percentile(times, 90) / np.percentile(times, 10):.2f}")


if __name__ == "__main__":
    main()
