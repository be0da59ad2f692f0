"""The ``iblbench`` console entry point, run as a real subprocess.

Every run uses a private ``IBLBENCH_CACHE`` and tiny sizes (16x16 pixels, 8x8 cube faces) so the
whole file stays well under a minute on a 2-core CPU with PoCL.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from iblbench.scenes.imageio import read_exr, write_exr, write_hdr

TINY = ["--res", "16x16", "--env-res", "8", "--no-progress"]
RUN_FLAGS = ("--scene", "--estimator", "--spp", "--seeds", "--res", "--env-res", "--out",
             "--device", "--save-inputs", "--sanitize", "--no-progress", "--repeats", "--metrics",
             "--no-flip", "--json", "--control")
RESULT_COLUMNS = {
    "scene", "estimator", "estimator_version", "spp", "frame", "seed", "mean_delta_e76",
    "mean_delta_e2000", "rel_mse", "flip", "flicker", "used_samples", "effective_samples", "effective_ratio",
    "evaluations", "shadow_rays", "nonfinite", "time_ms", "time_ms_min", "time_ms_iqr", "time_ms_build",
    "time_ms_sample", "time_ms_shade", "time_ms_host", "time_repeats", "device", "host", "protocol",
    "schema_version", "time_budget_ms", "width", "height", "env_res", "estimator_params", "metrics",
    "mean_delta_e76_renders", "mean_delta_e2000_renders", "rel_mse_renders", "time_ms_renders",
}


def registered_metric_columns() -> set[str]:
    """Each registered metric's column and replicate column: a metric registered after the four
    of RESULT_COLUMNS brings its own (and RESULT_COLUMNS still names the four's)."""
    from iblbench.harness.protocol.metric import registered

    return {column for metric in registered() for column in (metric.column, metric.renders_column)
            if column}


# --- helpers -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    """One private cache for the module: device measurements and references are shared."""
    return tmp_path_factory.mktemp("cli-cache")


@pytest.fixture(scope="module")
def cli(cache):
    def run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
        env = dict(os.environ, IBLBENCH_CACHE=str(cache), PYTHONWARNINGS="ignore")
        env.pop("IBLBENCH_DEVICE", None)
        return subprocess.run([sys.executable, "-m", "iblbench.cli", *map(str, args)],
                              capture_output=True, text=True, env=env, timeout=timeout)
    return run


def assert_input_error(result: subprocess.CompletedProcess, out: Path | None, *needles: str) -> str:
    """Exit 2, exactly one 'iblbench: error:' line on stderr with every needle, nothing in --out."""
    context = f"stdout:\n{result.stdout}\nstderr:\n{result.stderr}"
    assert result.returncode == 2, context
    assert "Traceback" not in result.stderr, context
    assert result.stderr.startswith("iblbench: error: "), context
    assert result.stderr.endswith("\n") and result.stderr.count("\n") == 1, context
    for needle in needles:
        assert needle in result.stderr, f"{needle!r} missing from stderr:\n{result.stderr}"
    if out is not None:
        assert not (out / "results.parquet").exists()
        written = [p for p in out.rglob("*") if p.is_file()] if out.exists() else []
        assert written == [], f"files left in --out after an input error: {written}"
    return result.stderr


def write_scene(folder: Path, env_name: str, *, layout: str | None = None) -> Path:
    """A scene TOML in ``folder``: a small icosphere seen from (0, 0, 3), lit by ``env_name``."""
    trimesh.creation.icosphere(subdivisions=1).export(folder / "ball.obj")
    layout_line = f'layout = "{layout}"\n' if layout else ""
    toml = folder / "scene.toml"
    toml.write_text(
        '[mesh]\npath = "ball.obj"\n\n'
        f'[environment]\npath = "{env_name}"\n{layout_line}\n'
        "[camera]\neye = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\n\n"
        "[render]\nwidth = 16\nheight = 16\n"
    )
    return toml


def latlong(height: int = 8) -> np.ndarray:
    """A smooth, positive 2:1 lat-long image."""
    rows = np.linspace(0.2, 2.0, height, dtype=np.float32)[:, None, None]
    cols = np.linspace(0.5, 1.0, 2 * height, dtype=np.float32)[None, :, None]
    return (rows * cols * np.array([1.0, 0.8, 0.6], np.float32)).astype(np.float32)


def run_scene(cli, toml: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    return cli("run", "--scene", toml, "--estimator", "uniform", "--spp", "4", "--seeds", "1",
               "--out", out, *TINY, *extra)


# --- help ----------------------------------------------------------------------------------------


def test_top_level_help_lists_every_subcommand(cli):
    result = cli("--help")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: iblbench")
    assert "import iblbench" in result.stdout and "iblbench.run(" in result.stdout   # the API
    assert "--json" in result.stdout and "--junit" in result.stdout
    for command in ("run", "list"):
        assert re.search(rf"^\s+{command}\s", result.stdout, re.M), result.stdout


def test_run_help_lists_every_flag(cli):
    result = cli("run", "--help")
    assert result.returncode == 0, result.stderr
    for flag in RUN_FLAGS:
        assert flag in result.stdout, f"{flag} missing from 'run --help':\n{result.stdout}"


def test_config_help_names_every_shipped_config(cli):
    """The shipped configs are the folder's files, frontier included (issue 35)."""
    shipped = sorted(path.stem for path in
                     (Path(__file__).parents[1] / "harness" / "configs").glob("*.toml"))
    assert "frontier" in shipped
    stated = " ".join(cli("run", "--help").stdout.split())
    assert f"a shipped one ({', '.join(shipped)})" in stated, stated


def test_help_counts_the_default_sweeps_cells_as_its_progress_bar_does(cli, tmp_path):
    """``iblbench --help`` said 792 cells while the bar of a bare ``iblbench run`` counted 1,188
    (issue 35): the help's count is the runner's, and both are each estimator's spp levels ×
    every scene's frames × the seeds."""
    import iblbench
    from iblbench.harness.protocol.runner import Runner

    runner = Runner(iblbench.run_config(tmp_path / "out"))
    runner._read_state()
    plan, config = runner.plan, runner.config
    levels = sum(len(spp) + len(config.time_budget_ms) for spp in plan.spp_levels.values())
    assert runner.total == levels * sum(len(p.frames) for p in plan.plans) * config.seeds
    stated = re.search(r"the default sweep: .*? ([\d,]+) cells", cli("--help").stdout)
    assert stated and int(stated.group(1).replace(",", "")) == runner.total


def modules_imported_by(argv: list[str], heavy: tuple[str, ...]) -> list[str]:
    """The modules of ``heavy`` (a package or module name each) that ``main(argv)`` imports, in
    a fresh interpreter."""
    code = ("import contextlib, io, sys\n"
            "from iblbench.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
            f"    main({argv!r})\n"
            f"heavy = {heavy!r}\n"
            "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] in heavy\n"
            "                      or m in heavy)))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    return [name for name in result.stdout.strip().split(",") if name]


def test_help_imports_no_heavy_module():
    """``iblbench --help`` builds every subparser without importing colour-science, scipy,
    trimesh, OpenCL or the stress battery (they cost seconds at start-up)."""
    assert modules_imported_by(["--help"], ("colour", "scipy", "trimesh", "pyopencl", "matplotlib",
                                            "flip_evaluator", "iblbench.harness.verify.stress")) == []


def test_stress_help_still_lists_the_cases(cli):
    result = cli("stress", "--help")
    assert result.returncode == 0, result.stderr
    assert "sun-1e9" in result.stdout and "cases:" in result.stdout, result.stdout
    result = cli("stress", "--case", "no-such-case")
    assert result.returncode == 2 and "invalid choice: 'no-such-case'" in result.stderr
    assert "sun-1e9" in result.stderr


def test_list_help_lists_every_choice(cli):
    result = cli("list", "--help")
    assert result.returncode == 0, result.stderr
    for word in ("devices", "estimators", "scenes", "--device"):
        assert word in result.stdout, result.stdout


# --- bad input: one clean line, exit 2, nothing written ------------------------------------------


def test_missing_environment_file(cli, tmp_path):
    toml = write_scene(tmp_path, "nowhere.exr")
    out = tmp_path / "out"
    stderr = assert_input_error(run_scene(cli, toml, out), out, "nowhere.exr", "not found")
    assert str(tmp_path / "nowhere.exr") in stderr


def test_garbage_exr_environment(cli, tmp_path):
    # The EXR magic number and version, then junk: the OpenEXR library itself must fail cleanly.
    (tmp_path / "sky.exr").write_bytes(b"\x76\x2f\x31\x01\x02\x00\x00\x00" + b"\xff\x13junk" * 200)
    toml = write_scene(tmp_path, "sky.exr")
    out = tmp_path / "out"
    assert_input_error(run_scene(cli, toml, out), out, str(tmp_path / "sky.exr"), "OpenEXR")


def test_truncated_hdr_environment(cli, tmp_path):
    path = tmp_path / "sky.hdr"
    write_hdr(path, latlong(16))
    data = path.read_bytes()
    header_end = data.index(b"+X 32\n") + len(b"+X 32\n")
    path.write_bytes(data[:header_end + (len(data) - header_end) // 2])  # cut mid-scanlines
    toml = write_scene(tmp_path, "sky.hdr")
    out = tmp_path / "out"
    assert_input_error(run_scene(cli, toml, out), out, str(path), "truncated")


@pytest.mark.parametrize("layout, needles", [
    (None, ("24x8", "aspect")),
    ("latlong", ("latlong", "2:1", "24x8")),
])
def test_wrong_aspect_environment(cli, tmp_path, layout, needles):
    path = tmp_path / "wide.exr"
    write_exr(path, np.ones((8, 24, 3), np.float32))  # 3:1
    toml = write_scene(tmp_path, "wide.exr", layout=layout)
    out = tmp_path / "out"
    assert_input_error(run_scene(cli, toml, out), out, str(path), *needles)


def bad_texel_environment(folder: Path) -> Path:
    """A lat-long map with 2 NaN, 3 Inf and 1 negative texel (6 bad texels)."""
    image = latlong(8)
    image[0, 0, 0] = np.nan
    image[1, 3, :] = np.nan          # one texel, even with three bad channels
    image[2, 2, 1] = np.inf
    image[3, 5, 2] = -np.inf
    image[4, 7, 0] = np.inf
    image[5, 9, 2] = -0.25
    path = folder / "bad.exr"
    write_exr(path, image)
    return path


def test_nonfinite_and_negative_texels_are_refused(cli, tmp_path):
    path = bad_texel_environment(tmp_path)
    toml = write_scene(tmp_path, "bad.exr")
    out = tmp_path / "out"
    stderr = assert_input_error(run_scene(cli, toml, out), out, str(path), "--sanitize")
    assert re.search(r"\b2 NaN\b", stderr), stderr
    assert re.search(r"\b3 Inf\b", stderr), stderr
    assert re.search(r"\b1 negative\b", stderr), stderr


def test_sanitize_runs_and_reports_the_fixed_texel_count(cli, tmp_path):
    path = bad_texel_environment(tmp_path)
    toml = write_scene(tmp_path, "bad.exr")
    out = tmp_path / "out"
    result = run_scene(cli, toml, out, "--sanitize")
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    # The count reaches the user: a line on stderr naming --sanitize/sanitized and the number 6.
    lines = [line for line in result.stderr.splitlines() if "sanitiz" in line.lower()]
    assert any(re.search(r"\b6\b", line) for line in lines), result.stderr
    assert any(str(path) in line for line in lines), result.stderr
    table = pd.read_parquet(out / "results.parquet")
    assert len(table) == 1 and table["nonfinite"].eq(0).all()
    assert np.isfinite(table["mean_delta_e76"]).all()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["sanitize"] is True
    assert manifest.get("sanitized") == {"scene": 6}, manifest.get("sanitized")
    reference = read_exr(out / "images" / "scene" / "f0" / "reference.exr")
    assert reference.shape == (16, 16, 3) and np.isfinite(reference).all()


def test_unknown_estimator_lists_the_valid_ones(cli, tmp_path):
    out = tmp_path / "out"
    result = cli("run", "--scene", "sphere-sun", "--estimator", "no-such-estimator", "--out", out,
                 *TINY)
    assert_input_error(result, out, "no-such-estimator", "uniform")


def test_unknown_scene_lists_the_valid_ones(cli, tmp_path):
    out = tmp_path / "out"
    result = cli("run", "--scene", "no-such-scene", "--estimator", "uniform", "--out", out, *TINY)
    assert_input_error(result, out, "no-such-scene", "sphere-sun")


@pytest.mark.parametrize("flag, value", [("--spp", "0"), ("--res", "12"),
                                         ("--res", "100000x100000"), ("--env-res", "100000")])
def test_malformed_flags_exit_2(cli, tmp_path, flag, value):
    out = tmp_path / "out"
    result = cli("run", "--scene", "sphere-sun", "--out", out, "--no-progress", flag, value)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert f"argument {flag}" in result.stderr, result.stderr
    assert not out.exists()


# --- a tiny end-to-end run -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_run(cli, tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny-run") / "out"
    result = cli("run", "--scene", "sphere-sun", "--estimator", "uniform", "--spp", "4,16",
                 "--seeds", "2", "--out", out, "--save-inputs", *TINY)
    return result, out


def test_tiny_run_succeeds(tiny_run):
    result, out = tiny_run
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert f"wrote 4 rows to {out}" in result.stdout, result.stdout


def test_tiny_run_results_table(tiny_run):
    result, out = tiny_run
    assert result.returncode == 0, result.stderr
    table = pd.read_parquet(out / "results.parquet")
    csv = pd.read_csv(out / "results.csv")
    for column in (c for c in csv.columns if c.endswith("_renders")):   # a metric left out: ""
        csv[column] = csv[column].astype(object).fillna("")             # in CSV, read as NaN
    assert set(table.columns) == RESULT_COLUMNS | registered_metric_columns()
    assert list(csv.columns) == list(table.columns)
    assert len(table) == 4 and len(csv) == 4
    pd.testing.assert_frame_equal(csv, table, check_dtype=False)
    assert sorted(zip(table["spp"], table["seed"])) == [(4, 0), (4, 1), (16, 0), (16, 1)]
    assert (table["scene"] == "sphere-sun").all() and (table["estimator"] == "uniform").all()
    assert (table["frame"] == 0).all()
    assert (table["protocol"] == "lab-reinhard-v1").all()
    assert table["device"].str.len().gt(0).all()
    assert (table["nonfinite"] == 0).all()
    # Strict: a row claiming more samples than spp is wrong however small the excess.
    assert (table["used_samples"] <= table["spp"]).all(), table[["spp", "used_samples"]]
    assert (table["effective_samples"] <= table["used_samples"]).all(), table
    assert (table["used_samples"] > 0).all()
    assert (table["effective_samples"] >= 0).all()
    for column in ("mean_delta_e76", "mean_delta_e2000", "rel_mse", "time_ms", "time_ms_host"):
        assert np.isfinite(table[column]).all() and (table[column] >= 0).all(), column
    assert (table["time_repeats"] == 10).all()   # the default sweep's repeats, no more
    # Every planned render is scored (10 repeats), the scored one first; every one is timed.
    for row in table.itertuples():
        for metric in ("mean_delta_e76", "mean_delta_e2000", "rel_mse"):
            values = [float(v) for v in getattr(row, f"{metric}_renders").split()]
            assert len(values) == 10 and values[0] == pytest.approx(getattr(row, metric), rel=1e-6)
            assert len(set(values)) == 10, metric   # ten renders, ten draws
        times = [float(v) for v in row.time_ms_renders.split()]
        assert len(times) == row.time_repeats
        assert np.median(times) == pytest.approx(row.time_ms, rel=1e-6)


def _hall_interval(values):
    """Hall (1992): the interval of the mean from g(T) = T + aT² + a²T³/3 + b = ±t(0.975, n−1),
    a = γ/(3√n), b = γ/(6√n), γ the sample skewness; g is increasing, so bisect."""
    from scipy import optimize, stats

    n, mean, sd = values.size, values.mean(), values.std(ddof=1)
    gamma = np.mean((values - mean) ** 3) / np.mean((values - mean) ** 2) ** 1.5
    a, b = gamma / (3 * np.sqrt(n)), gamma / (6 * np.sqrt(n))
    q = stats.t.ppf(0.975, n - 1)
    root = [optimize.brentq(lambda t: t + a * t * t + a * a * t ** 3 / 3 + b - y, -50, 50)
            for y in (q, -q)]
    return mean - sd * root[0] / np.sqrt(n), mean - sd * root[1] / np.sqrt(n)


def test_tiny_run_json_summary(tiny_run, cli):
    """A rerun with --json (all cells resumed): stdout is one JSON document whose cells agree
    with results.parquet (mean over seeds, t interval written out here); the table is on
    stderr."""
    from scipy import stats

    _, out = tiny_run
    result = cli("run", "--scene", "sphere-sun", "--estimator", "uniform", "--spp", "4,16",
                 "--seeds", "2", "--out", out, "--json", *TINY)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert "wrote 4 rows" in result.stderr and "mean_delta_e76" in result.stderr
    assert (summary["command"], summary["exit"], summary["status"]) == ("run", 0, "complete")
    assert summary["out"] == str(out) and summary["rows"] == 4
    assert (summary["resumed_cells"], summary["cells_run"]) == (4, 0)
    table = pd.read_parquet(out / "results.parquet")
    assert [(c["scene"], c["estimator"], c["spp"], c["seeds"]) for c in summary["cells"]] == [
        ("sphere-sun", "uniform", 4, 2), ("sphere-sun", "uniform", 16, 2)]
    for cell in summary["cells"]:
        rows = table[table.spp == cell["spp"]].sort_values("seed")
        # Errors: every scored render of both seeds (2 × 10 replicates), a t interval over them
        # with Hall's skewness correction: T = √n(x̄ − μ)/s in [−q, q] after g(T) = T + aT² +
        # a²T³/3 + b, solved here by bisection.
        for metric in ("mean_delta_e76", "rel_mse"):
            values = np.concatenate([[float(v) for v in text.split()]
                                     for text in rows[f"{metric}_renders"]])
            assert values.size == 20
            figure = cell["metrics"][metric]
            assert figure["mean"] == pytest.approx(values.mean()), metric
            assert (figure["low"], figure["high"]) == pytest.approx(_hall_interval(values)), metric
            assert figure["n"] == 20
        # Samples: one value per seed.
        values = rows["effective_samples"].to_numpy()
        figure = cell["metrics"]["effective_samples"]
        assert figure["mean"] == pytest.approx(values.mean())
        assert figure["half_width"] == pytest.approx(stats.t.ppf(0.975, 1) * values.std(ddof=1)
                                                     / np.sqrt(2))
        # Time: the median of every timed render, inside its interval.
        times = np.concatenate([[float(v) for v in text.split()] for text in rows.time_ms_renders])
        figure = cell["metrics"]["time_ms"]
        assert figure["mean"] == pytest.approx(np.median(times))
        assert figure["low"] <= figure["mean"] <= figure["high"] and figure["n"] == times.size


def test_tiny_run_manifest(tiny_run):
    result, out = tiny_run
    assert result.returncode == 0, result.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["protocol"] == "lab-reinhard-v1" and manifest["status"] == "complete"
    assert manifest["git_revision"] and manifest["versions"]["pyopencl"]
    device = manifest["device"]
    assert isinstance(device, dict) and device.get("name") and device.get("platform")
    # How the kernels ran sets a cell's time as much as the device: recorded with it.
    assert device.get("launch_shape") in ("pixel", "sample_block") and device.get("lanes") in (1, 2, 4, 8, 16)
    assert "uniform" in manifest["estimator_versions"]
    table = pd.read_parquet(out / "results.parquet")
    assert (table["estimator_version"].astype(str)
            == str(manifest["estimator_versions"]["uniform"])).all()
    assert manifest["config"]["spp"] == [4, 16] and manifest["config"]["seeds"] == 2


def test_tiny_run_images(tiny_run):
    result, out = tiny_run
    assert result.returncode == 0, result.stderr
    images = out / "images" / "sphere-sun" / "f0"
    for name in ("reference.exr", "uniform_spp4_s0.exr", "uniform_spp16_s1.exr"):
        assert (images / name).is_file(), name
    assert not list(out.rglob("*.png")), "the run drew previews (iblbench report draws them)"
    for name in ("reference.exr", "uniform_spp4_s0.exr"):
        image = read_exr(images / name)
        assert image.shape == (16, 16, 3) and np.isfinite(image).all() and image.max() > 0, name
    assert not list(out.rglob("*.tmp*")), "temporary files left behind"


def test_tiny_run_saved_inputs(tiny_run):
    result, out = tiny_run
    assert result.returncode == 0, result.stderr
    inputs = out / "inputs" / "sphere-sun"
    with np.load(inputs / "gbuffer.npz") as data:
        arrays = {name: data[name] for name in data.files}
    assert set(arrays) == {"mask", "position", "normal", "view", "kd", "ks", "shininess"}
    mask = arrays["mask"]
    assert mask.dtype == bool and mask.shape == (16, 16)
    for name in ("position", "normal", "view", "kd", "ks"):
        assert arrays[name].shape == (16, 16, 3), name
    assert arrays["shininess"].shape == (16, 16)
    assert 0 < mask.sum() < mask.size  # the sphere covers part of the frame
    for name in ("normal", "view"):
        lengths = np.linalg.norm(arrays[name][mask], axis=-1)
        np.testing.assert_allclose(lengths, 1.0, atol=1e-4, err_msg=name)
    assert (np.sum(arrays["normal"][mask] * arrays["view"][mask], axis=-1) > 0).all()
    env = np.load(inputs / "env_f0.npy")
    assert env.dtype == np.float32 and env.shape == (6, 8, 8, 3)
    assert np.isfinite(env).all() and (env >= 0).all() and env.max() > 0


# --- list ----------------------------------------------------------------------------------------


def test_list_devices_marks_exactly_one(cli):
    result = cli("list", "devices")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    device_lines = [line for line in lines if line[:1] in ("*", " ") and "[" in line]
    assert device_lines, result.stdout
    assert sum(line.startswith("*") for line in lines) == 1, result.stdout


def test_list_devices_gives_every_device_a_measured_speed(cli):
    """Issue 35: each device that builds a kernel shows its measured FLOP rate, the simulator and
    GPUs included (before, only CPUs had one); a simulator, which interprets every work item,
    measures slower than the CPU chosen beside it."""
    lines = [line for line in cli("list", "devices").stdout.splitlines() if line[2:3] == "["]
    rates = {}
    for line in lines:
        if "cannot build a kernel" in line:
            continue
        found = re.search(r"  ([0-9.]+) (G|M)FLOP/s \(measured\)$", line)
        assert found, line
        rates[line[3:line.index("]")]] = float(found[1]) * (1e3 if found[2] == "G" else 1)
    assert rates and all(rate > 0 for rate in rates.values()), lines
    if "simulator" in rates and "CPU" in rates:
        assert rates["simulator"] < rates["CPU"] / 10, rates


def listing(command: str, columns: int) -> dict[str, str]:
    """``iblbench list COMMAND`` at a terminal width: name -> its text, continuation lines joined;
    every line fits the width."""
    env = dict(os.environ, COLUMNS=str(columns), PYTHONWARNINGS="ignore")
    result = subprocess.run([sys.executable, "-m", "iblbench.cli", "list", command],
                            capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 0, result.stderr
    entries: dict[str, str] = {}
    for line in result.stdout.splitlines():
        assert len(line) <= columns, f"line wider than {columns}:\n{result.stdout}"
        if line.startswith(" "):
            entries[name] += " " + line.strip()
        else:
            name, _, text = line.partition(" ")
            entries[name] = text.strip()
    return entries


def test_list_estimators_one_plain_sentence_each():
    """Each estimator's first docstring sentence, whole, without reST, wrapped to the terminal."""
    entries = listing("estimators", columns=60)
    assert {"uniform", "balanced", "balanced_mis", "havran", "bis", "smc"} <= set(entries), entries
    for name, text in entries.items():
        assert not re.search(r"``|:[a-z]+:`", text), f"reST left in {name}: {text}"
        assert text.endswith("."), f"{name}'s sentence is cut: {text}"
    assert entries["bis"] == ("Burke et al. 2005 bidirectional importance sampling, as Kronander "
                              "et al. §5 use it.")
    assert entries["havran"].endswith("per-normal culling; K = spp lights."), entries["havran"]
    assert entries["uniform"].endswith("(Lu 2013 Sec. 2.1, Eq. 4 with μ_f = 1/6)."), entries


def test_list_scenes_gives_frames_and_description():
    from iblbench.scenes import sequences

    entries = listing("scenes", columns=70)
    frames = {"sphere-sun": 1, "blob-sun": 1, "blob-day": sequences.DAY_FRAMES,
              "torus-moving": sequences.MOVING_FRAMES, "sphere-switch": sequences.SWITCH_FRAMES}
    for name, count in frames.items():
        assert entries[name].startswith(f"{count} frame"), entries
    assert "moving-lights" in entries["torus-moving"] and "``" not in entries["blob-day"], entries
    assert "smooth sphere" in entries["sphere-sun"], entries


def test_list_estimators_imports_no_estimator_nor_opencl():
    """Listing reads the estimators' docstrings from their source, the built-ins' and any
    installed plugin's: no estimator module nor OpenCL is loaded (they were most of the time of
    a ``list``)."""
    from importlib.metadata import entry_points

    from iblbench.estimators.registry import ENTRY_POINT_GROUP

    modules = tuple(entry.module for entry in entry_points(group=ENTRY_POINT_GROUP))
    assert "iblbench.estimators.uniform" in modules
    assert modules_imported_by(["list", "estimators"], ("pyopencl", *modules)) == []


def test_docstrings_read_from_source_are_the_classes_own():
    from iblbench.estimators import registry

    read = registry.estimator_docstrings()
    assert list(read) == registry.estimator_names()
    for name, docstring in read.items():
        assert docstring == (registry.get_estimator_class(name).__doc__ or ""), name


def test_version(cli):
    result = cli("--version")
    assert result.returncode == 0, result.stderr
    assert re.fullmatch(r"iblbench \d+\.\d+\S* \(git ([0-9a-f]{7,}(-dirty)?|unknown)\)\n",
                        result.stdout), result.stdout


def test_version_imports_no_heavy_module():
    """Issue 23: --version took 1.6-2.2 s (it imported the runner, OpenCL and pandas) against
    0.3 s for --help; it reads the version and the revision from harness/protocol/provenance.py."""
    assert modules_imported_by(["--version"], ("pyopencl", "pandas", "scipy", "colour", "trimesh",
                                                "iblbench.harness.protocol.runner")) == []


def test_a_closed_pipe_ends_the_output_without_a_traceback():
    """Issue 23: `iblbench list scenes | head` ended in a BrokenPipeError traceback."""
    listing = subprocess.Popen([sys.executable, "-m", "iblbench.cli", "list", "scenes"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    listing.stdout.close()           # as `head` does once it has its lines: every write fails
    stderr = listing.stderr.read().decode()
    assert listing.wait(timeout=60) == 141, stderr   # 128 + SIGPIPE, as a shell tool ends
    assert "Traceback" not in stderr and "BrokenPipeError" not in stderr, stderr


@pytest.mark.parametrize("args, needle", [(("run", "--spp", "x"), "argument --spp"),
                                          (("no-such-command",), "invalid choice"),
                                          ((), "required")])
def test_argument_errors_are_one_line_with_a_help_hint(cli, args, needle):
    result = cli(*args)
    assert_input_error(result, None, needle, "--help")


# --- the printed tables --------------------------------------------------------------------------


def summary_rows(estimator: str, spp: int, evaluations: float, time_ms: float,
                 time_budget_ms: float = float("nan")) -> list[dict]:
    return [{"scene": "s", "estimator": estimator, "spp": spp, "frame": 0, "seed": seed,
             "time_budget_ms": time_budget_ms, "mean_delta_e76": 1.0 + seed, "rel_mse": 0.1,
             "effective_samples": spp / 2, "used_samples": spp, "evaluations": evaluations,
             "nonfinite": 0, "time_ms": time_ms + seed} for seed in (0, 1, 2)]


def test_terminal_tables_show_evaluations_and_time_beside_spp():
    """One bis sample is 21 integrand evaluations: spp alone would compare unequal work."""
    from iblbench.commands.run import terminal_summaries

    table = pd.DataFrame(summary_rows("uniform", 16, 16.0, 2.0) + summary_rows("bis", 16, 336.0, 30.0)
                         + summary_rows("uniform", 64, 64.0, 10.0, time_budget_ms=10.0)
                         + summary_rows("bis", 4, 84.0, 9.0, time_budget_ms=10.0))
    (spp_title, by_spp), (time_title, by_time) = terminal_summaries(table)
    assert list(by_spp.columns[:3]) == ["evaluations", "time_ms", "mean_delta_e76"]
    assert by_spp.loc[("s", "bis", 16), "evaluations"] == 336.0
    # The seeds' 30, 31, 32: mean 31 ± t(0.975, 2) · 1 / √3 = 2.48.
    assert by_spp.loc[("s", "bis", 16), "time_ms"] == "31.0 ± 2.5"
    assert "equal time" in spp_title and "equal time" in time_title
    assert list(by_time.columns[:4]) == ["spp", "evaluations", "time_ms", "mean_delta_e76"]
    assert by_time.loc[("s", 10.0, "bis"), "evaluations"] == 84.0


def test_terminal_table_shows_the_mean_over_seeds_and_its_t_interval():
    """Per-seed frame means 1, 2 and 6 (mean 3, median 2, sd √7): the printed cell is the mean
    ± t(0.975, 2)·√7/√3 = 6.57 (t = 4.3027 from the t table), both rounded at the half-width's
    second significant digit; one seed prints no interval."""
    from iblbench.commands.run import terminal_summaries

    rows = [{"scene": "s", "estimator": "a", "spp": 16, "frame": frame, "seed": seed,
             "time_budget_ms": float("nan"), "mean_delta_e76": value, "rel_mse": value / 10,
             "flip": value / 100, "effective_samples": 8.0, "used_samples": 16.0,
             "evaluations": 16.0, "nonfinite": 0, "time_ms": 2 * value}
            for seed, pair in enumerate([(0.5, 1.5), (2.0, 2.0), (5.0, 7.0)])
            for frame, value in enumerate(pair)]
    table = pd.DataFrame(rows)
    (_, summary), = terminal_summaries(table)
    cell = summary.loc[("s", "a", 16)]
    assert cell.mean_delta_e76 == "3.0 ± 6.6"
    assert cell.rel_mse == "0.30 ± 0.66"
    assert cell.flip == "0.030 ± 0.066"
    assert cell.time_ms == "6 ± 13"
    assert cell.effective == "8 ± 0" and cell.seeds == 3
    (_, single), = terminal_summaries(table[table.seed == 1])
    assert single.loc[("s", "a", 16)].mean_delta_e76 == "2 (n=1, no interval)"


def test_run_help_says_what_the_default_sweep_and_metrics_are(cli):
    """Issue 23: `iblbench --help` called the 720-cell default sweep a "small default suite", and
    `run --help` gave the metrics' default as "all" while the default sweep leaves FLIP out."""
    from iblbench.harness.protocol.sweep import load_sweep

    default = load_sweep("default")
    assert "flip" not in default.metrics and "flip" in load_sweep("full").metrics
    top = cli("--help").stdout
    assert "small default suite" not in top and "the default sweep" in top
    text = " ".join(cli("run", "--help").stdout.split())
    metrics_help = text[text.index("--metrics M[,M...] metrics"):text.index("--no-flip leave")]
    assert "(default: all;" not in metrics_help
    assert f"{','.join(default.metrics)} for the shipped default" in metrics_help


def test_run_help_and_the_run_agree_on_who_draws_the_previews(cli, tmp_path):
    """Issue 23: `run --help` said the run writes PNG previews and ΔE heat maps, the README that
    `iblbench report` draws them; the run writes EXRs only."""
    text = " ".join(cli("run", "--help").stdout.split())
    assert "EXR + PNG" not in text and "`iblbench report` draws the PNG previews" in text
    out = tmp_path / "out"
    result = cli("run", "--scene", "sphere-sun", "--estimator", "uniform", "--spp", "2", "--seeds", "1",
                 "--res", "8x8", "--env-res", "8", "--repeats", "1", "--out", str(out))
    assert result.returncode == 0, result.stderr
    images = list((out / "images").rglob("*.*"))
    assert images and all(path.suffix == ".exr" for path in images), images
