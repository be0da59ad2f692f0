"""``iblbench compare``: flags a deliberately worse estimator, not a seeds-only rerun
(``run --first-seed``); pairing, thresholds, differences and bad input on hand-made tables."""
import json

import numpy as np
import pandas as pd
import pytest

from iblbench.cli import main
from iblbench.harness.protocol.compare import pair_estimators, parse_threshold
from iblbench.harness.protocol.results import TABLE, read_manifest, write_manifest
from iblbench.harness.protocol.run_plan import MAX_SEED, MAX_SEEDS
from iblbench.harness.protocol.runner import RunConfig, run
from iblbench.foundation.errors import InputError

MUTANT = "balanced{uniform_faces=true}"
SCENES = ("sphere-backlit",)
SEEDS = 8   # per side; at 32x32 the mutant's +17% in ΔE76 needs about 8 seeds to resolve
SPP = (64, 256)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """balanced on seeds 0..SEEDS-1 (a), its seeds-only rerun on the next SEEDS seeds through
    ``iblbench run --first-seed`` (b), and the uniform_faces mutant on a's seeds."""
    root = tmp_path_factory.mktemp("compare")
    common = dict(scenes=SCENES, spp=SPP, resolution=(32, 32), env_res=16, repeats=1,
                  metrics=("de76", "relmse"), progress=False, seeds=SEEDS)
    run(RunConfig(out=root / "a", estimators=("balanced",), **common))
    run(RunConfig(out=root / "mutant", estimators=(MUTANT,), **common))
    assert main(["run", "--scene", *SCENES, "--estimator", "balanced",
                 "--spp", ",".join(map(str, SPP)), "--seeds", str(SEEDS),
                 "--first-seed", str(SEEDS), "--res", "32x32", "--env-res", "16", "--repeats", "1",
                 "--metrics", "de76,relmse", "--no-progress", "--out", str(root / "b")]) == 0
    return {"a": root / "a", "b": root / "b", "mutant": root / "mutant"}


def test_first_seed_offsets_the_seeds_and_is_recorded(runs):
    seeds = {side: sorted(pd.read_parquet(runs[side] / TABLE).seed.unique()) for side in "ab"}
    assert seeds == {"a": list(range(SEEDS)), "b": list(range(SEEDS, 2 * SEEDS))}
    manifest = read_manifest(runs["b"])
    assert manifest["config"]["first_seed"] == manifest["sweep"]["first_seed"] == SEEDS
    assert "--first-seed" in manifest["sweep"]["overridden_by_flags"]


@pytest.mark.parametrize("first_seed, seeds", [(-1, 1), (MAX_SEED, 2)])
def test_seeds_beyond_the_cell_seed_range_are_refused(tmp_path, first_seed, seeds):
    """Cell seeds stay below the timing and calibration seeds (executor.timing_seed)."""
    with pytest.raises(InputError, match=f"the seeds must lie in 0..{MAX_SEED}"):
        run(RunConfig(out=tmp_path / "run", seeds=seeds, first_seed=first_seed))
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("seeds", [MAX_SEEDS + 1, 8388607, 1_000_000_000])
def test_too_many_seeds_are_refused_at_once_naming_seeds_only(tmp_path, seeds):
    """Issue 23: --seeds 8388607 was accepted (2.7 GB and no cell after 50 s); --seeds 1e9 was
    refused naming --first-seed, which was not given."""
    with pytest.raises(InputError, match=f"--seeds must be in 1..{MAX_SEEDS}") as error:
        run(RunConfig(out=tmp_path / "run", seeds=seeds))
    assert "--first-seed" not in str(error.value)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("estimator", ["bis", "smc"])
def test_an_spp_past_bis_and_smcs_bound_is_refused_before_anything_is_written(tmp_path, estimator):
    """Issue 23: bis had no spp bound (a 40,000-spp cell ran past 25 s)."""
    from iblbench.estimators.bis import MAX_SPP
    with pytest.raises(InputError, match=f"--spp 40000 is above {estimator}'s limit of {MAX_SPP}"):
        run(RunConfig(out=tmp_path / "run", estimators=[estimator], spp=[16, 40000]))
    assert not (tmp_path / "run").exists()


def _compare(capsys, *args):
    status = main(["compare", *map(str, args)])
    return status, capsys.readouterr()


def test_flags_the_uniform_faces_mutant(runs, capsys):
    status, out = _compare(capsys, runs["a"], runs["mutant"], "--fail-if", "mean_delta_e76>5%")
    assert status == 1, out.out
    for scene in SCENES:
        for spp in SPP:
            assert f"{scene} balanced → {MUTANT} spp={spp} frame 0: mean_delta_e76" in out.out
    assert f"balanced (A) paired with {MUTANT} (B) by base name" in out.out


@pytest.fixture(scope="module")
def two_seed_runs(tmp_path_factory):
    """The default sweep's shape: 2 seeds × 5 timed renders, every render scored (issue 23):
    balanced (a), the uniform_faces mutant on a's seeds, and a's seeds-only rerun (b)."""
    root = tmp_path_factory.mktemp("compare-replicates")
    common = dict(scenes=SCENES, spp=SPP, resolution=(32, 32), env_res=16, repeats=5,
                  metrics=("de76", "relmse"), progress=False, seeds=2)
    run(RunConfig(out=root / "a", estimators=("balanced",), **common))
    run(RunConfig(out=root / "mutant", estimators=(MUTANT,), **common))
    run(RunConfig(out=root / "b", estimators=("balanced",), first_seed=2, **common))
    return {"a": root / "a", "b": root / "b", "mutant": root / "mutant"}


def test_two_seeds_flag_the_mutant_with_a_paired_test_more_powerful_than_welch(two_seed_runs,
                                                                              capsys):
    """Issue 23: with 2 seeds the per-seed interval (t(0.975, 1) = 12.7) resolved nothing;
    paired over the 10 replicates the runs share (same seeds and timing seeds), compare flags
    the mutant's ΔE76 at every spp, and its p-value is below Welch's on the same values (both
    shown).  The seeds-only rerun shares no replicate: Welch, and nothing beyond the threshold."""
    status, out = _compare(capsys, two_seed_runs["a"], two_seed_runs["mutant"],
                           "--fail-if", "mean_delta_e76>5%", "--json")
    assert status == 1, out.err
    summary = json.loads(out.out)
    assert {f["cell"].split(": ")[0] for f in summary["failures"]} == {
        f"{scene} balanced → {MUTANT} spp={spp} frame 0" for scene in SCENES for spp in SPP}
    for cell in summary["cells"]:
        entry = cell["metrics"]["mean_delta_e76"]
        assert entry["paired"] and entry["a"]["n"] == entry["b"]["n"] == 10
        assert entry["p"] < 0.05 and entry["p"] <= entry["p_unpaired"], entry
    assert "paired (Welch " in out.err
    status, out = _compare(capsys, two_seed_runs["a"], two_seed_runs["b"],
                           "--fail-if", "mean_delta_e76>5%", "--json")
    assert status == 0, out.err
    for cell in json.loads(out.out)["cells"]:
        assert not cell["metrics"]["mean_delta_e76"]["paired"]


def test_seed_only_rerun_is_not_flagged(runs, capsys):
    status, out = _compare(capsys, runs["a"], runs["b"], "--fail-if", "mean_delta_e76>5%",
                           "--fail-if", "rel_mse>10%", "--json")
    assert status == 0, out.out
    summary = json.loads(out.out)
    assert summary["failures"] == [] and summary["differences"] == []
    assert len(summary["cells"]) == len(SCENES) * len(SPP)
    for cell in summary["cells"]:
        delta_e = cell["metrics"]["mean_delta_e76"]
        assert delta_e["a"]["n"] == delta_e["b"]["n"] == SEEDS
        assert delta_e["low"] <= 1 <= delta_e["high"]
        assert "flip" not in cell["metrics"]   # not computed by either run


def _table(path, estimator, values, seeds=None, spp=64, time_budget_ms=np.nan, **columns):
    """A hand-made run folder: one cell (sphere-sun, estimator, spp 64, frame 0); a list in
    ``columns`` gives a column's value per seed."""
    path.mkdir()
    seeds = range(len(values)) if seeds is None else seeds
    rows = [{"scene": "sphere-sun", "estimator": estimator, "spp": spp, "frame": 0, "seed": s,
             "time_budget_ms": time_budget_ms, "estimator_version": "v1", "device": "dev",
             "protocol": "lab-reinhard-v1", "mean_delta_e76": v, "time_ms": 1.0 + 0.1 * s,
             **{name: value[i] if isinstance(value, list) else value
                for name, value in columns.items()}}
            for i, (s, v) in enumerate(zip(seeds, values))]
    pd.DataFrame(rows).to_parquet(path / TABLE, index=False)
    return path


def test_threshold_needs_significance_and_size(tmp_path, capsys):
    a = _table(tmp_path / "a", "uniform", [1.0, 1.1, 0.9, 1.0])
    noisy = _table(tmp_path / "noisy", "uniform", [0.5, 2.0, 1.0, 1.3])    # +20%, not significant
    small = _table(tmp_path / "small", "uniform", [1.03, 1.13, 0.93, 1.03])   # +3%, within 5%
    large = _table(tmp_path / "large", "uniform", [1.3, 1.4, 1.2, 1.3])      # +30%, significant
    for folder, expected in ((noisy, 0), (small, 0), (large, 1)):
        status, out = _compare(capsys, a, folder, "--fail-if", "mean_delta_e76>5%")
        assert status == expected, out.out
    # A decrease fails only a '<' threshold.
    status, _ = _compare(capsys, large, a, "--fail-if", "mean_delta_e76>5%")
    assert status == 0
    status, out = _compare(capsys, large, a, "--fail-if", "mean_delta_e76<-5%")
    assert status == 1 and "sphere-sun uniform spp=64 frame 0: mean_delta_e76" in out.out


# Four seeds whose values spread by 2^-10 (relative SD 8e-4): B = r·A then has a 95% interval of
# about r·e^(±1.4e-3) (Welch, ~6 df), so every ratio below, 2% or more from 1, is significant,
# and the point ratio is r to rounding (exactly r for r = 1.5 and 0.5: every value is binary).
SEED_VALUES = (1.0, 1.0 + 2 ** -10, 1.0 - 2 ** -10, 1.0)


@pytest.mark.parametrize("threshold, ratio, fails", [
    # an increase threshold, written with and without '+': just beyond, just within, and
    # changes the other way (a lower ΔE: an improvement), one of them beyond the threshold's size
    ("mean_delta_e76>5%", 1.051, True), ("mean_delta_e76>+5%", 1.051, True),
    ("mean_delta_e76>5%", 1.049, False), ("mean_delta_e76>5%", 0.949, False),
    ("mean_delta_e76>5%", 0.98, False),
    # a decrease threshold: the same, mirrored
    ("mean_delta_e76<-5%", 0.949, True), ("mean_delta_e76<-5%", 0.951, False),
    ("mean_delta_e76<-5%", 1.051, False), ("mean_delta_e76<-5%", 1.02, False),
    # exactly at the threshold is not "more than" it
    ("mean_delta_e76>50%", 1.5, False), ("mean_delta_e76<-50%", 0.5, False),
    # a higher-is-better metric: the threshold is on the change, whatever its direction means
    ("effective_ratio<-5%", 0.949, True), ("effective_ratio<-5%", 1.051, False),
    ("effective_ratio>5%", 1.051, True), ("effective_ratio>5%", 0.949, False)])
def test_thresholds_on_small_significant_changes_in_both_directions(tmp_path, capsys, threshold,
                                                                    ratio, fails):
    """A cell fails a threshold exactly when its change lies beyond it on the threshold's side:
    B = ratio·A over four seeds of tiny spread (SEED_VALUES), so every change is significant
    and only its size and side decide; ``change`` says worse or better by the metric's direction."""
    metric = threshold.split("<")[0].split(">")[0]
    sides = {side: _table(tmp_path / side, "uniform", [1.0] * 4,
                          **{metric: [scale * v for v in SEED_VALUES]})
             for side, scale in (("a", 1.0), ("b", ratio))}
    status, out = _compare(capsys, sides["a"], sides["b"], "--fail-if", threshold, "--json")
    summary = json.loads(out.out)
    entry = summary["cells"][0]["metrics"][metric]
    assert entry["significant"] and entry["ratio"] == pytest.approx(ratio, rel=1e-12)
    assert status == int(fails) and len(summary["failures"]) == int(fails), out.err
    worse = (ratio > 1) != (metric == "effective_ratio")
    assert entry["change"] == ("worse" if worse else "better")


def test_one_seed_is_never_significant(tmp_path, capsys):
    a = _table(tmp_path / "a", "uniform", [1.0])
    b = _table(tmp_path / "b", "uniform", [3.0])
    status, out = _compare(capsys, a, b, "--fail-if", "mean_delta_e76>5%")
    assert status == 0 and "n=1" in out.out


def test_equal_time_cells_match_by_budget(tmp_path, capsys):
    """The spp an equal-time cell chose may differ between runs: its budget identifies it."""
    a = _table(tmp_path / "a", "uniform", [1.0, 1.1, 0.9], spp=40, time_budget_ms=5.0)
    b = _table(tmp_path / "b", "uniform", [2.0, 2.2, 1.8], spp=52, time_budget_ms=5.0)
    status, out = _compare(capsys, a, b, "--fail-if", "mean_delta_e76>5%")
    assert status == 1 and "sphere-sun uniform 5 ms frame 0: mean_delta_e76 ratio 2.000" in out.out


def test_says_what_differs(tmp_path, capsys):
    a = _table(tmp_path / "a", "uniform", [1.0, 1.1])
    b = _table(tmp_path / "b", "uniform", [1.0, 1.1], estimator_version="v2", device="other",
               protocol="lab-other")
    write_manifest(a, {"git_revision": "aaa", "timing": {"repeats": {"uniform": 5, "havran": 3}}})
    write_manifest(b, {"git_revision": "bbb", "timing": {"repeats": {"uniform": 3}}})
    _, out = _compare(capsys, a, b)
    for text in ("code: git revision aaa (A) vs bbb (B)", "estimator_version v1 (A) vs v2 (B)",
                 "device: device dev (A) vs other (B)", "protocol: protocol lab-reinhard-v1",
                 "protocol: uniform timing repeats 5 (A) vs 3 (B)"):
        assert text in out.out


def test_pairing():
    assert pair_estimators(["balanced", "uniform"], ["uniform", MUTANT]) == (
        [("uniform", "uniform"), ("balanced", MUTANT)], [], [])
    # An equal label wins; two candidates of one base name are ambiguous and stay unpaired.
    assert pair_estimators(["balanced"], ["balanced", MUTANT]) == ([("balanced", "balanced")],
                                                                   [], [MUTANT])
    assert pair_estimators(["balanced"], [MUTANT, "balanced{shared_sequence=false}"]) == (
        [], ["balanced"], ["balanced{shared_sequence=false}", MUTANT])


@pytest.mark.parametrize("text, problem", [("mean_delta_e76>5", "write METRIC>P%"),
                                           ("mean_delta_e67>5%", "did you mean 'mean_delta_e76'"),
                                           ("rel_mse>-5%", "use '>' with an increase")])
def test_bad_thresholds(text, problem):
    with pytest.raises(InputError, match=problem):
        parse_threshold(text)


def test_bad_input_exits_2_with_one_line(tmp_path, capsys):
    a = _table(tmp_path / "a", "uniform", [1.0, 1.1])
    b = _table(tmp_path / "b", "bis", [1.0, 1.1])
    for args, problem in (((a, tmp_path / "missing"), "no such run directory"),
                          ((a, b), "no cell in common"),
                          ((a, a, "--fail-if", "flip>5%"), "no common cell has it"),
                          ((a, a, "--fail-if", "x>5%"), "unknown metric")):
        status, out = _compare(capsys, *args)
        assert status == 2 and problem in out.err and len(out.err.strip().splitlines()) == 1
