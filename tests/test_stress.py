"""The stress battery (harness/verify/stress.py): every case at the small size over every built-in
estimator, the statistics it rests on, and ``iblbench stress`` with broken estimators."""
import numpy as np
import pandas as pd
import pytest

from iblbench.estimators import registry
from iblbench.estimators.base import Estimator, Tags
from iblbench.estimators.uniform import Uniform
from iblbench import cli
from iblbench.harness.verify import conformance, stress, stress_cases
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import GBuffer

pytestmark = pytest.mark.slow   # about 2 minutes: conftest schedules it first
BUILTINS = {name: registry.make_estimator(name) for name in registry.builtin_names()}


@pytest.fixture(scope="module")
def battery(compute):
    """Every case's rows, run once per case (the parametrized tests read their case's)."""
    cache = {}

    def rows(case):
        if case not in cache:
            cache[case] = stress.run_stress(BUILTINS, (case,), stress.SMALL, compute, progress=False)
        return cache[case]
    return rows


@pytest.mark.parametrize("case", stress.CASE_NAMES)
def test_case_passes_on_every_builtin(battery, case):
    rows = battery(case)
    expected = {name for name, e in BUILTINS.items() if stress.CASES[case].applies(e)}
    assert set(rows.estimator) == expected
    failed = rows[rows.status == "FAIL"]
    assert failed.empty, failed[["estimator", "failures"]].to_string()
    assert (rows.nonfinite == 0).all() and (rows.negative == 0).all() and (rows.dark_nonzero == 0).all()
    unbiased = rows[[BUILTINS[e].tags.unbiased and (case, e) not in stress.NO_Z_PIXELS
                     for e in rows.estimator]]
    sampled = rows[[BUILTINS[e].tags.has_pdf for e in rows.estimator]]
    if case == "black-map":
        assert (rows["min"] == 0).all() and (rows["max"] == 0).all() and (rows.reference_error == 0).all()
        assert (sampled.chi2_tests == 0).all()     # nothing to sample on a black map
    else:                                          # the tests are not vacuous
        assert (unbiased.bias_pixels > 0).all(), unbiased[["estimator", "bias_pixels"]]
        assert (sampled.chi2_tests > 0).all()
    if case == "constant":
        assert (rows.reference_error <= stress.EXACT_RTOL).all()
    if case == "temporal-dropout":
        assert (rows.recovery <= stress_cases.RECOVERY_LIMIT).all()


# ---- the statistics ------------------------------------------------------------------------------

def test_bias_test_floor_passes_an_exact_estimate_and_fails_a_wrong_constant():
    reference = np.array([[0.5, 0.25, 0.0]] * 4)
    exact = conformance.bias_test(np.broadcast_to(reference, (50, 4, 3)), reference)
    assert exact.max_abs_z == 0.0
    off = conformance.bias_test(np.broadcast_to(reference * 1.01, (50, 4, 3)), reference)
    assert off.max_abs_z > conformance.sidak_z(10 ** 6)   # 1% off: z = 100 from the floor alone
    nan = conformance.bias_test(np.full((50, 4, 3), np.nan), reference)
    assert nan.max_abs_z == np.inf


def test_sidak_helpers_agree():
    alpha, tests = 1e-3, 40
    per_test = conformance.sidak_alpha(alpha, tests)
    assert conformance.sidak_p(per_test, tests) == pytest.approx(alpha)
    assert conformance.two_sided_p(conformance.sidak_z(tests, alpha)) == pytest.approx(per_test)


def test_reach_model_keeps_only_pixels_whose_integrand_is_sampled(compute):
    """On a 1e9 sun, a normal that sees the sun's face but not the sun sees only dim sky a light
    sampler reaches ~1e-6 times per render: not z-tested for uniform, tested for bis (BRDF
    sampling reaches that sky); a normal facing the sun is tested for uniform."""
    sees_sun, dim_only = (0.0, 0.0, 1.0), (0.0, -1.0, -0.3)
    normals = np.array([[sees_sun, dim_only]], np.float64)
    variant = stress.Variant("sun", GBuffer.from_pixels(normals, normals, 0.5, 0.3, 20.0),
                             [conformance.sun_map(8, 1e9)])
    prepared = stress.Prepared.of(variant, compute)
    prepared.caches[0].require(("cdf",))
    assert stress.tested_pixels(BUILTINS["uniform"], prepared, 0, 8, 200).tolist() == [[True] * 3, [False] * 3]
    assert stress.tested_pixels(BUILTINS["bis"], prepared, 0, 8, 200)[1].all()


def test_reach_model_skips_a_channel_that_few_resampled_draws_carry(compute):
    """bis at one sample per pixel carries only its resampled draw's colour, and that draw
    follows the target γ = L_Y·ρ_Y·cos⁺.  On one-sample's colour-split map (red only where
    x > 0) a diffuse normal 8° off −x sees the red as a sliver holding ~1% of γ (a NumPy
    quadrature here): a handful of red draws over 500 seeds, so its red is not z-tested
    (a mean of 0 over 500 seeds failed the full-size stress at |z| = 1e4), its blue is."""
    seeds, tilt = stress.LARGE.seeds, np.radians(8.0)
    normal = np.array([[[-np.cos(tilt), 0.0, np.sin(tilt)]]])
    env = stress.CASES["one-sample"].build(stress.LARGE)[0].frames[0]
    directions = cubemap.texel_directions(env.shape[1])
    gamma = cubemap.luminance(env) * cubemap.texel_solid_angles(env.shape[1]) \
        * np.maximum(directions @ normal[0, 0], 0.0)
    red_draws = seeds * gamma[directions[..., 0] > 0].sum() / gamma.sum()
    assert 1 < red_draws < stress.REACH_HITS
    variant = stress.Variant("sliver", GBuffer.from_pixels(normal, normal, 0.8, 0.0, 20.0), [env])
    tested = stress.tested_pixels(BUILTINS["bis"], stress.Prepared.of(variant, compute), 0, 1, seeds)
    assert not tested[0, 0] and tested[0, 2]


def test_horizon_shares_match_a_fine_grid():
    """The exact share of each texel's face square above a plane (horizon_shares) against the
    fraction of a 256² grid of its directions above it, for random axes and the degenerate
    ones (a face's axis, a face's plane, an edge's)."""
    rng = np.random.default_rng(5)
    axes = rng.normal(size=(6, 3))
    axes = np.vstack([axes / np.linalg.norm(axes, axis=1, keepdims=True),
                      [[0, 0, 1], [1, 0, 0], [0, -np.sqrt(0.5), np.sqrt(0.5)]]])
    res, fine = 4, 256
    directions = cubemap.texel_directions(res * fine).reshape(-1, 3)
    grid = (axes @ directions.T > 0).reshape(len(axes), 6, res, fine, res, fine).mean(axis=(3, 5))
    assert np.abs(stress.horizon_shares(res, axes) - grid).max() < 2.0 / fine


def test_reach_model_counts_light_hits_above_the_horizon_only(compute):
    """hot-texel's face-corner texel (R = 8) holds all the light, and pixel 6 of the quick
    battery's G-buffer sees it through a sliver of ~0.1% of its square (its reference 2.4e-6):
    8 spp × 200 seeds of product (4 light draws a render, uniform in the texel's square) land ~1
    sample there, so its mean is 0 in most seed sets.  The pixel is not z-tested (the battery
    failed product at |z| = 1e4 when every light hit on the texel counted); a normal facing the
    texel is."""
    case = next(v for v in stress.CASES["hot-texel"].build(stress.SMALL) if v.name == "face-corner")
    normal, view = case.gbuffer.normal.reshape(-1, 3)[6], case.gbuffer.view.reshape(-1, 3)[6]
    facing = cubemap.face_st_to_direction(4, 15 / 16, 1 / 16)
    u = (np.arange(64) + 0.5) / 64            # a grid over the texel's square: s in [7/8, 1], t in [0, 1/8]
    directions = cubemap.face_st_to_direction(4, (7 + u) / 8, u[:, None] / 8)
    assert 0 < np.mean(directions @ normal > 0) < 0.005
    normals = np.array([[normal, facing]])
    views = np.array([[view, facing]])
    variant = stress.Variant("face-corner", GBuffer.from_pixels(normals, views, 0.5, 0.3, 20.0), case.frames)
    tested = stress.tested_pixels(BUILTINS["product"], stress.Prepared.of(variant, compute), 0, 8, 200)
    assert tested.tolist() == [[False] * 3, [True] * 3]


# ---- broken estimators must fail ------------------------------------------------------------------

class _NaNEstimator(Uniform):
    """uniform with one NaN pixel."""

    name = "test-nan"

    def render(self, gbuffer, cache, spp, seed):
        estimate = super().render(gbuffer, cache, spp, seed)
        estimate.radiance[0, 0, 0] = np.nan
        return estimate


class _Scaled(Uniform):
    """uniform × 1.05: biased."""

    name = "test-scaled"

    def render(self, gbuffer, cache, spp, seed):
        estimate = super().render(gbuffer, cache, spp, seed)
        estimate.radiance *= np.float32(1.05)
        return estimate


class _Glow(Estimator):
    """A tiny positive value everywhere: wrong where the reference is exactly 0."""

    name = "test-glow"
    tags = Tags(unbiased=False)
    requires = Uniform.requires

    def render(self, gbuffer, cache, spp, seed):
        estimate = Uniform().render(gbuffer, cache, spp, seed)
        estimate.radiance += np.float32(1e-6)
        return estimate


class _MirroredPdf(Uniform):
    """uniform's sampler with the pdf hook of the mirrored direction: χ² must reject it."""

    name = "test-mirrored-pdf"

    def pdf(self, cache, normal, view, dirs):
        return super().pdf(cache, normal, view, -dirs)


@pytest.mark.parametrize("estimator, case, failure", [
    (_NaNEstimator(), "constant", "non-finite"),
    (_Scaled(), "constant", "biased"),
    (_Glow(), "black-map", "≠ 0 where the reference is 0"),
    (_MirroredPdf(), "sun-1e6", "sampler"),
])
def test_a_broken_estimator_fails(compute, estimator, case, failure):
    row = stress.run_stress({estimator.name: estimator}, (case,), stress.SMALL, compute,
                            progress=False).iloc[0]
    assert row.status == "FAIL" and failure in row.failures, row.failures


def test_known_failures_are_reported_not_failed(compute, monkeypatch):
    monkeypatch.setitem(stress.KNOWN_FAILURES, ("constant", "test-nan"), "NaN on purpose")
    table = stress.run_stress({"test-nan": _NaNEstimator()}, ("constant",), stress.SMALL, compute,
                              progress=False)
    assert table.status.tolist() == ["xfail"] and "NaN on purpose" in table.notes[0]
    assert not stress.failed(table)


def test_degenerate_mesh_traces_a_valid_gbuffer():
    gbuffer = stress_cases._trace(stress_cases.degenerate_sphere(), stress.SMALL)
    assert gbuffer.covered > 50 and stress.gbuffer_invalid(gbuffer) == 0


# ---- the command --------------------------------------------------------------------------------

QUICK = ["stress", "--quick", "--no-progress", "--case", "constant", "--case", "black-map"]


def test_command_passes_and_writes_the_table_and_html(tmp_path, capsys):
    assert cli.main(QUICK + ["--estimator", "uniform", "--estimator", "havran",
                             "--out", str(tmp_path)]) == 0
    table = pd.read_csv(tmp_path / "stress.csv")
    assert len(table) == 4 and set(table.status) == {"pass"}
    assert list(pd.read_parquet(tmp_path / "stress.parquet").columns) == list(table.columns)
    html = (tmp_path / "stress.html").read_text(encoding="utf-8")
    assert "white furnace" in html and "havran" in html and "Statistical design" in html
    assert "stress: passed" in capsys.readouterr().out


def test_command_exits_1_with_a_broken_estimator(tmp_path, monkeypatch):
    registry.estimator_names()                    # load the built-ins before adding one
    monkeypatch.setitem(registry._registry, "test-nan", _NaNEstimator)
    assert cli.main(QUICK + ["--estimator", "uniform", "--estimator", "test-nan",
                             "--out", str(tmp_path)]) == 1
    table = pd.read_csv(tmp_path / "stress.csv")
    assert table.set_index(["case", "estimator"]).status[("constant", "test-nan")] == "FAIL"


def test_command_exits_2_on_bad_arguments(tmp_path, capsys):
    assert cli.main(["stress", "--estimator", "nope", "--out", str(tmp_path)]) == 2
    assert "valid estimators" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        cli.main(["stress", "--case", "nope"])
    assert exit_.value.code == 2
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    assert cli.main(QUICK + ["--out", str(a_file)]) == 2     # refused before the battery runs
    assert "cannot create the output directory" in capsys.readouterr().err
    out = tmp_path / "none-applies"                            # temporal-dropout: temporal only
    assert cli.main(["stress", "--case", "temporal-dropout", "--estimator", "uniform",
                     "--out", str(out)]) == 2
    assert "no case" in capsys.readouterr().err and not out.exists()
