"""The A/A control (issue 32): ``--control NAME`` and a sweep's ``control`` run an unchanged copy
of an estimator as ``NAME@control``, and the answer counts the verdicts that call the two apart;
and the report's first sentence where the machine was busy during the run."""
from __future__ import annotations

import html
import json
import os
import shutil

import numpy as np
import pandas as pd
import pytest

from iblbench import run_config
from iblbench.harness.protocol.control import ControlCalls, control_calls
from iblbench.harness.protocol.ranking import scene_rankings
from iblbench.harness.protocol.run_plan import plan_run
from iblbench.harness.protocol.sweep import load_sweep
from iblbench.reports.answer import busy_sentence
from iblbench.reports.report import write_report
from iblbench.foundation.errors import InputError
from iblbench.scenes.imageio import read_exr
from test_cli import TINY, assert_input_error, cache, cli  # noqa: F401 (fixtures)
from test_ranking import cell

BRDF = 'envmap{mis="brdf"}'


def sweep_file(folder, **lines) -> os.PathLike:
    """A sweep config on sphere-sun with ``envmap{mis="brdf"}`` and uniform, plus ``lines``
    (TOML values by key)."""
    body = {"protocol": '"lab-reinhard-v1"', "scenes": '["sphere-sun"]', "seeds": "2",
            "estimators": """['envmap{ mis = "brdf" }', "uniform"]""", "spp": "[4]", **lines}
    path = folder / "sweep.toml"
    path.write_text("".join(f"{key} = {value}\n" for key, value in body.items()))
    return path


# --- asking for a control ------------------------------------------------------------------------


def test_a_control_outside_the_run_is_a_one_line_error_naming_it_and_the_estimators(cli, tmp_path):
    out = tmp_path / "out"
    result = cli("run", "--scene", "sphere-sun", "--estimator", "uniform", "--estimator", "envmap",
                 "--control", "bis", "--out", out, *TINY)
    assert_input_error(result, out, "control 'bis'", "(uniform, envmap)")


def test_a_control_label_among_the_estimators_is_refused(cli, tmp_path):
    out = tmp_path / "out"
    result = cli("run", "--scene", "sphere-sun", "--estimator", "uniform@control", "--out", out,
                 *TINY)
    assert_input_error(result, out, "uniform@control", "--control uniform")


def test_a_config_control_is_the_same_estimator_under_its_own_label(tmp_path):
    """Written in another spelling, the control is canonicalised; its spec makes the very same
    estimator (class, every parameter, version) under the label ending @control."""
    path = sweep_file(tmp_path, control="""['envmap{mis = "brdf"}']""")
    assert load_sweep(path).control == (BRDF,)
    plan = plan_run(run_config(tmp_path / "out", config=path))
    specs = {spec.label: spec for spec in plan.specs}
    assert list(specs) == [BRDF, "uniform", BRDF + "@control"]
    original, control = specs[BRDF], specs[BRDF + "@control"]
    assert control.cls is original.cls and control.make().params == original.make().params
    assert plan.params[BRDF + "@control"] == plan.params[BRDF]


def test_a_config_control_outside_its_estimators_names_the_file_and_the_control(tmp_path):
    path = sweep_file(tmp_path, control='["bis"]')
    with pytest.raises(InputError) as error:
        load_sweep(path)
    assert str(path) in str(error.value) and "control 'bis'" in str(error.value)
    assert "\n" not in str(error.value)


def test_estimators_given_drop_the_configs_control_unless_it_is_given_too(tmp_path):
    path = sweep_file(tmp_path, control=f"['{BRDF}']")
    assert run_config(tmp_path, config=path, estimators=["uniform"]).control == ()
    assert run_config(tmp_path, config=path, estimators=["uniform"],
                      control=["uniform"]).control == ("uniform",)


# --- a tiny run ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def control_run(cli, tmp_path_factory):
    """sphere-sun at 32², envmap{mis="brdf"} and uniform, a control of the first from the
    config, which gives it spp levels of its own (the others 4)."""
    folder = tmp_path_factory.mktemp("control-run")
    path = sweep_file(folder, control=f"['{BRDF}']", spp='{ default = [4], envmap = [4, 16] }',
                      resolution='"32x32"', env_res="8", metrics='["de76"]')
    out = folder / "out"
    result = cli("run", "--config", path, "--out", out, "--no-progress", "--json")
    assert result.returncode == 0, result.stderr
    return out, json.loads(result.stdout), path


def test_the_control_renders_the_same_images_under_another_label(control_run):
    out, _, _ = control_run
    table = pd.read_parquet(out / "results.parquet")
    keys = ["spp", "seed", "frame"]
    original = table[table.estimator == BRDF].set_index(keys).sort_index()
    control = table[table.estimator == BRDF + "@control"].set_index(keys).sort_index()
    # the spp levels the config gives envmap by name are the control's too
    assert sorted(set(control.index.get_level_values("spp"))) == [4, 16]
    assert list(control.index) == list(original.index) and len(control) == 4
    for column in ("mean_delta_e76", "mean_delta_e76_renders", "estimator_version",
                   "estimator_params"):
        assert (control[column] == original[column]).all(), column
    images = out / "images" / "sphere-sun" / "f0"
    for spp, seed, _ in original.index:
        stem = f"_spp{spp}_s{seed}.exr"
        np.testing.assert_array_equal(read_exr(images / f"envmap-mis=brdf@control{stem}"),
                                      read_exr(images / f"envmap-mis=brdf{stem}"))


def test_the_manifest_records_the_control_and_the_load(control_run):
    out, _, _ = control_run
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["control"] == [BRDF]
    assert manifest["estimator_versions"][BRDF + "@control"] == manifest["estimator_versions"][BRDF]
    load = manifest["timing"]["load"]
    assert load["cores"] == os.cpu_count() and len(load["load_1min"]) == 2
    assert all(value >= 0 for value in load["load_1min"])
    assert 0 <= load["others_cores"] <= os.cpu_count()


def test_run_json_carries_the_control_and_a_rerun_resumes_it(control_run, cli, tmp_path):
    out, summary, path = control_run
    (calls,) = summary["equal_time_answer"]["control"]
    assert (calls["original"], calls["control"]) == (BRDF, BRDF + "@control")
    assert calls["text"].startswith(f"A/A control: {BRDF}@control")
    copy = shutil.copytree(out, tmp_path / "out")   # the rerun rewrites the manifest
    result = cli("run", "--config", path, "--control", BRDF, "--out", copy, "--no-progress",
                 "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["cells_run"] == 0
    assert "A/A control: " in result.stderr   # the human output, beside the JSON


def test_the_report_shows_the_control_and_a_busy_machine(control_run, tmp_path):
    """The run's manifest made idle, then busy (the machine's own load is whatever it was)."""
    out = shutil.copytree(control_run[0], tmp_path / "out")

    def page(others):
        manifest = json.loads((out / "manifest.json").read_text())
        manifest["timing"].update(load={"cores": 2, "load_1min": [1.0, 1.0],
                                        "others_cores": others})
        (out / "manifest.json").write_text(json.dumps(manifest))
        return write_report(out)["path"].read_text(encoding="utf-8")

    idle = html.unescape(page(0.1))
    assert f"<p>A/A control: {BRDF}@control" in idle and "This machine" not in idle
    busy = page(1.3)
    assert busy.index("This machine was busy during the run (other programs used 1.3 of its 2 "
                      "cores)") < busy.index(
        "<h2>")


# --- counting the calls -----------------------------------------------------------------------------


def curve_rows(label, scene, factor, noise):
    """Rows of ``label`` on ``scene``: 16 spp at 1 ms, 64 spp at 4 ms, errors ``factor`` × a
    fixed pattern (× ``noise`` per render)."""
    base = np.array([[1.0, 1.2, 0.9, 1.1], [1.05, 0.95, 1.15, 0.85]])
    return sum((cell(label, spp, [t] * 4, scale * factor * base * noise, scene=scene)
                for spp, t, scale in ((16, 1.0, 2.0), (64, 4.0, 1.0))), [])


def test_control_calls_count_the_verdicts_that_call_a_control_apart():
    """On scene "same" the control's rows equal the original's: not called apart (the paired
    ratio is exactly 1).  On "apart" its errors are twice the original's: called apart.  At
    100 ms neither is ranked (no cell that slow): no verdict.  b has no control."""
    noise = np.array([[1.0, 1.02, 0.98, 1.01], [0.99, 1.03, 1.0, 0.97]])
    rows = []
    for scene, factor, own in (("same", 1.0, 1.0), ("apart", 2.0, noise)):
        rows += (curve_rows("a", scene, 1.0, 1.0) + curve_rows("a@control", scene, factor, own)
                 + curve_rows("b", scene, 3.0, 1.0))
    table = pd.DataFrame(rows)
    rankings = scene_rankings(table, budgets=[2.0, 100.0])
    assert control_calls(rankings, table.estimator) == [ControlCalls("a", "a@control", 1, 2)]
    assert control_calls(rankings, ["a", "b"]) == []
    text = ControlCalls("a", "a@control", 1, 2).text()
    assert "a@control was called apart from a in 1 of 2 equal-time verdicts" in text
    assert "the stated level is 5%" in text


def test_a_control_never_ranked_says_it_could_not_be_checked():
    table = pd.DataFrame(curve_rows("a", "s", 1.0, 1.0) + curve_rows("a@control", "s", 1.0, 1.0))
    (calls,) = control_calls(scene_rankings(table, budgets=[100.0]), table.estimator)
    assert (calls.called_apart, calls.verdicts) == (0, 0) and "could not be checked" in calls.text()


# --- a busy machine --------------------------------------------------------------------------------


def manifest(others=None, cores=2):
    timing = {"floor": {"groups_within": [0.9, 0.2]}}
    if others is not None:
        timing["load"] = {"cores": cores, "load_1min": [0.5, 0.5], "others_cores": others}
    return {"timing": timing}


def test_a_busy_machine_opens_the_report_with_one_plain_sentence():
    sentence = busy_sentence(manifest(others=1.2))
    assert sentence == ("This machine was busy during the run (other programs used 1.2 of its 2 "
                        "cores), so times are less certain than on an idle machine; the "
                        "intervals include that.")
    assert "used 1.3 of its 4 cores" in busy_sentence(manifest(others=1.3, cores=4))


@pytest.mark.parametrize("others, cores", [
    (0.1, 2),      # idle: the run alone (a poor timing floor does not count)
    (0.5, 2),      # at the bound, not above it
    (0.9, 4),      # under a quarter of 4 cores
    (None, 2),     # an older manifest without the load
])
def test_an_idle_machine_gets_no_sentence(others, cores):
    assert busy_sentence(manifest(others=others, cores=cores)) is None


def test_no_manifest_or_no_timing_gets_no_sentence():
    assert busy_sentence(None) is None and busy_sentence({}) is None
