"""``iblbench selftest``: the mutant catalogue (:mod:`iblbench.harness.verify.mutants`) through the checks."""
from __future__ import annotations

import argparse

from iblbench.commands.common import positive_int
from iblbench.foundation.errors import InputError


SELFTEST_DESCRIPTION = """\
Apply each mutant of the project's catalogue of realistic bugs (harness/verify/mutants.py,
and each registered estimator's own, a plugin's included) to a temporary copy of the sources
and run the check layers on it: the conformance suite
(check_estimator), the stress battery at its quick size (the cases that guard the broken
code), the error budgets of the quick sweep (budgets.toml) and the unit tests a mutant names
(for bugs no render shows: bookkeeping, ranking rules, the checkers; the last two layers only
in a source checkout, which has budgets.toml and tests/). A mutant that names unit tests runs
them first: they are the layer its entry says catches it, and the cheapest. By default each
mutant stops at the first layer that rejects it; --all-layers runs every layer,
to show which layers catch what. Prints one row per mutant and, per layer, the mutants it
caught. Exit 0 when every mutant is rejected (or survives as its catalogue entry expects, until
the check it waits for lands), 1 otherwise."""


def add_parser(subparsers) -> None:
    selftest = subparsers.add_parser("selftest", help="run the catalogue of known bugs through the "
                                                    "checks and show which layers catch each",
                                   description=SELFTEST_DESCRIPTION,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    selftest.add_argument("--mutant", action="append", metavar="NAME",
                          help="run only this mutant; repeatable (default: the whole catalogue)")
    selftest.add_argument("--all-layers", action="store_true",
                          help="run every layer on every mutant, not only up to the first that rejects it")
    selftest.add_argument("--jobs", type=positive_int, default=2, metavar="N",
                          help="mutants run at a time (default: 2)")
    selftest.add_argument("--list", action="store_true", help="list the catalogue and exit")


def run(args) -> int:
    from iblbench.harness.verify import mutants

    try:
        chosen = mutants.catalogue(args.mutant)
    except ValueError as error:
        raise InputError(None, str(error)) from None
    if args.list:
        for m in chosen:
            waits = f"  (expected to survive until: {m.expect_killed_after})" if m.expect_killed_after else ""
            print(f"{m.name:48s} {m.where}{waits}")
        return 0
    width = max(len(m.name) for m in chosen)

    def show(outcome):
        why = outcome.error or next((w for w in outcome.rejected_by.values() if w), "")
        verdict = outcome.killed_by or ("expected survivor" if outcome.mutant.expect_killed_after
                                        else "SURVIVED")
        print(f"{outcome.mutant.name:{width}s}  {verdict:17s} {outcome.seconds:5.1f} s  {why[:100]}",
              flush=True)

    outcomes = mutants.run_catalogue(chosen, all_layers=args.all_layers, jobs=args.jobs, progress=show)
    print()
    for layer in mutants.LAYERS:
        caught = [o.mutant.name for o in outcomes if o.rejected_by.get(layer)]
        print(f"{layer} caught {len(caught)}: {', '.join(caught) or '-'}")
    bad = [o.mutant.name for o in outcomes if not o.killed and not o.mutant.expect_killed_after]
    print(f"selftest: {len(outcomes) - len(bad)} of {len(outcomes)} mutants rejected or expected"
          + (f"; SURVIVED: {', '.join(bad)}" if bad else ""))
    return 1 if bad else 0
