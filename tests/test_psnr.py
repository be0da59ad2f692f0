"""PSNR (harness/protocol/metric/psnr.py) against its definition, 10·log10(MAX²/MSE) on the
protocol's displayed image (Reinhard with the reference's exposure, clipped to [0, 1]), and
through run, its table, compare and check."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from iblbench.harness.protocol import metric, metrics
from iblbench.harness.protocol.metric.psnr import psnr

EPSILON = 1e-6   # the protocol's log-average offset (metrics module docstring)


def grey(value, shape=(4, 4)) -> np.ndarray:
    return np.full(shape + (3,), value, np.float64)


def displayed_grey(x: float, g: float) -> float:
    """A grey x as displayed against a uniform grey reference g: k = 0.18 / (ε + g), the
    log-average of a uniform image being ε + g, and Reinhard x·k / (1 + k·x) (luminance of a
    grey = the grey)."""
    k = 0.18 / (EPSILON + g)
    return x * k / (1.0 + k * x)


def scored_psnr(estimate, reference, mask) -> float:
    return metrics.Scorer(reference, mask, ("de76", "psnr")).errors(estimate)[0]["psnr"]


def test_a_uniform_error_gives_the_psnr_of_its_formula_and_uncovered_pixels_do_not_count():
    g, h = 0.5, 0.7
    mask = np.zeros((4, 4), bool)
    mask[:2] = True
    estimate = grey(h)
    estimate[2:] = 100.0                      # uncovered: not scored
    error = displayed_grey(h, g) - displayed_grey(g, g)
    assert scored_psnr(estimate, grey(g), mask) == pytest.approx(-20.0 * math.log10(abs(error)),
                                                                 rel=1e-9)


def test_displayed_values_are_clipped_to_the_peak_of_one():
    """A huge pure blue displays as blue = 1 (its luminance is a small fraction of blue, so the
    tone-mapped channel would exceed 1): MSE = (2·v² + (1 − v)²)/3, v the reference's grey."""
    g = 0.5
    mask = np.ones((4, 4), bool)
    estimate = np.zeros((4, 4, 3))
    estimate[..., 2] = 1e6
    v = displayed_grey(g, g)
    expected = 10.0 * math.log10(1.0 / ((2.0 * v * v + (1.0 - v) ** 2) / 3.0))
    assert scored_psnr(estimate, grey(g), mask) == pytest.approx(expected, rel=1e-9)


def test_identical_images_score_infinity_and_an_empty_mask_nan():
    assert scored_psnr(grey(0.3), grey(0.3), np.ones((4, 4), bool)) == math.inf
    assert math.isnan(psnr(grey(0.3), grey(0.5), np.zeros((4, 4), bool), 1.0))


def test_psnr_is_registered_outside_the_default_sweep_higher_being_better():
    descriptor = {m.name: m for m in metric.registered()}["psnr"]
    assert descriptor.column == "psnr" and not descriptor.default and not descriptor.lower_is_better
    assert "psnr" not in metric.default_names()
    assert metric.parse_metrics("psnr") == ("de76", "psnr")


def test_psnr_runs_end_to_end_through_run_compare_and_check(tmp_path):
    env = dict(os.environ, IBLBENCH_CACHE=str(tmp_path / "cache"), PYTHONWARNINGS="ignore")
    env.pop("IBLBENCH_DEVICE", None)

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "iblbench.cli", *map(str, args)],
                              capture_output=True, text=True, env=env, timeout=300)

    out = tmp_path / "run"
    result = cli("run", "--scene", "sphere-sun", "--estimator", "uniform", "--spp", "4",
                 "--seeds", "2", "--res", "16x16", "--env-res", "8", "--repeats", "2",
                 "--no-progress", "--metrics", "de76,psnr", "--out", out)
    assert result.returncode == 0, result.stderr
    table = pd.read_parquet(out / "results.parquet")
    assert np.isfinite(table.psnr).all() and (table.psnr > 0).all()
    assert (table.psnr_renders.str.split().str.len() == 2).all()   # one value per render
    assert table.rel_mse.isna().all() and (table.metrics == "de76,psnr").all()
    assert "psnr" in result.stdout.splitlines()[1]          # a column of run's table

    compared = cli("compare", out, out, "--json", "--fail-if", "psnr<-5%")
    assert compared.returncode == 0, compared.stderr
    cell = json.loads(compared.stdout)["cells"][0]
    assert cell["metrics"]["psnr"]["ratio"] == pytest.approx(1.0)

    budgets = tmp_path / "budgets.toml"
    configuration = ('[configuration]\nwidth = 16\nheight = 16\nenv_res = 8\nseeds = 2\n'
                     'protocol = "lab-reinhard-v1"\n\n[[rule]]\nscene = "sphere-sun"\n'
                     'estimator = "uniform"\nspp = 4\n')
    budgets.write_text(configuration + "min_psnr = 1.0\n")
    assert cli("check", out, "--budgets", budgets).returncode == 0
    budgets.write_text(configuration + "min_psnr = 1000.0\n")
    failed = cli("check", out, "--budgets", budgets)
    assert failed.returncode == 1 and "psnr" in failed.stdout
