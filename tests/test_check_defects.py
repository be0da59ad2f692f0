"""Issue 11, defect 9: ``iblbench check`` on a typo in a rule, ``max_flicker`` on a static
scene, contradictory bounds, and results made in another configuration than the budgets.

In-process (``cli.main``) on small hand-made results tables; no render.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from iblbench import cli
from iblbench.harness.protocol.results import write_results
from test_budgets import row

CONFIGURATION = """
[configuration]
width = 48
height = 48
env_res = 32
seeds = 2
protocol = "lab-reinhard-v1"
"""


def rule(scene: str, estimator: str, *limits: str, name: str = "r") -> str:
    """One [[rule]] at spp 16 with the given limit lines."""
    return (f'\n[[rule]]\nname = "{name}"\nscene = "{scene}"\nestimator = "{estimator}"\n'
            f"spp = 16\n" + "\n".join(limits) + "\n")


def configured(**changes) -> dict:
    return {"width": 48, "height": 48, "env_res": 32} | changes


@pytest.fixture
def run_dir(tmp_path) -> Path:
    """sphere-sun (static) and twilight (3 frames) × uniform, balanced at spp 16, 2 seeds."""
    rows = []
    for estimator in ("uniform", "balanced"):
        for seed in (0, 1):
            rows.append(row("sphere-sun", estimator, 16, seed=seed, **configured()))
            for frame in range(3):
                rows.append(row("twilight", estimator, 16, seed=seed, frame=frame,
                                flicker=float("nan") if frame == 0 else 0.5 + 0.1 * seed,
                                **configured()))
    out = tmp_path / "run"
    out.mkdir()
    write_results(out, rows)
    return out


def check(run_dir: Path, text: str, capsys) -> tuple[int, str, str]:
    budgets = run_dir.parent / "budgets.toml"
    budgets.write_text(text, encoding="utf-8")
    status = cli.main(["check", str(run_dir), "--budgets", str(budgets)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.parametrize("key, typo, meant", [("estimator", "unifrom", "uniform"),
                                               ("scene", "sphere-snu", "sphere-sun")])
def test_a_typo_in_a_rule_exits_2_with_did_you_mean(run_dir, capsys, key, typo, meant):
    names = {"scene": "sphere-sun", "estimator": "uniform"} | {key: typo}
    status, out, err = check(run_dir, CONFIGURATION + rule(names["scene"], names["estimator"],
                                                           "max_rel_mse = 1.0", name="typo"),
                             capsys)
    assert status == 2, out + err
    assert f"did you mean '{meant}'?" in err and "typo" in err and typo in err, err
    assert out == ""


def test_max_flicker_on_a_static_scene_is_not_applicable(run_dir, capsys):
    status, out, err = check(run_dir, CONFIGURATION + rule("*", "uniform", "max_flicker = 1.0",
                                                           name="steady"), capsys)
    assert status == 0, out + err
    lines = {line.split()[1]: line for line in out.splitlines() if line.startswith("steady ")}
    assert "n/a: static scene (no flicker)" in lines["sphere-sun"], out
    assert "nan" not in lines["sphere-sun"].lower().replace("n/a", ""), out
    # The sequence's flicker is judged over its frames after the first (frame 0 has none):
    # per seed 0.5 and 0.6, mean 0.55.
    assert "0.55" in lines["twilight"] and lines["twilight"].rstrip().endswith("PASS"), out
    assert out.strip().splitlines()[-1].startswith("check: PASS"), out


@pytest.mark.parametrize("limits", [("max_rel_mse = 1.0", "min_rel_mse = 9.0"),
                                    ("max_time_ratio = { baseline = 'uniform', max = 2 }",
                                     "max_mean_delta_e76 = 1.0\nmin_mean_delta_e76 = 1.5")])
def test_a_minimum_above_the_maximum_exits_2_naming_the_rule(run_dir, capsys, limits):
    status, out, err = check(run_dir, CONFIGURATION + rule("sphere-sun", "balanced", *limits,
                                                           name="impossible"), capsys)
    assert status == 2, out + err
    assert "impossible" in err and "min" in err and "max" in err, err


@pytest.mark.parametrize("change, named", [
    (configured(width=128, height=128, env_res=64), ("width", "height", "env_res", "128", "64")),
    (configured(env_res=64), ("env_res", "64", "32")),
    ({"protocol": "lab-reinhard-v0"}, ("protocol", "lab-reinhard-v0")),
])
def test_results_of_another_configuration_are_refused(tmp_path, capsys, change, named):
    rows = [row("sphere-sun", "uniform", 16, seed=seed, **configured()) | change
            for seed in (0, 1)]
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    write_results(out_dir, rows)
    status, out, err = check(out_dir, CONFIGURATION
                             + rule("sphere-sun", "uniform", "max_rel_mse = 1.0"), capsys)
    assert status == 2, out + err
    assert "configuration" in err and all(word in err for word in named), err


def test_results_with_another_seed_count_are_refused(tmp_path, capsys):
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    write_results(out_dir, [row("sphere-sun", "uniform", 16, seed=seed, **configured())
                            for seed in range(5)])
    status, out, err = check(out_dir, CONFIGURATION
                             + rule("sphere-sun", "uniform", "max_rel_mse = 1.0"), capsys)
    assert status == 2 and "seeds" in err and "5" in err, out + err


def test_a_budgets_file_without_its_configuration_is_refused(run_dir, capsys):
    status, out, err = check(run_dir, rule("sphere-sun", "uniform", "max_rel_mse = 1.0"), capsys)
    assert status == 2 and "[configuration]" in err, out + err


def test_the_value_is_the_mean_over_seeds_with_its_interval(tmp_path, capsys):
    """Seeds 1, 2, 6: mean 3, sd √7, 95% Student-t half-width t(0.975, 2)·√7/√3 = 6.572
    (t = 4.3027, a table value)."""
    out_dir = tmp_path / "run"
    out_dir.mkdir()
    write_results(out_dir, [row("s", "a", 16, seed=seed, mean_delta_e76=value, **configured())
                            for seed, value in enumerate((1.0, 2.0, 6.0))])
    status, out, err = check(out_dir, CONFIGURATION.replace("seeds = 2", "seeds = 3")
                             + rule("s", "a", "max_mean_delta_e76 = 3.5"), capsys)
    assert status == 0, out + err
    line = next(line for line in out.splitlines() if "mean_delta_e76" in line)
    assert re.search(r"\b3\s+± 6.6\s", line), line
