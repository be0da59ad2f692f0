"""``havran`` (Havran et al. 2005): point set, bicontinuous map, FIR filter, progressivity,
culling, convergence on a static map."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from iblbench.estimators import havran as hv
from iblbench.estimators.havran import EqualAreaMap, Havran, fir_filter
from iblbench.harness.protocol import metrics
from iblbench.harness.verify.conformance import (Harness, constant_map, smooth_map, stress_maps,
                                                 white_lambertian, yield_checks)
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import trace_gbuffer
from iblbench.scenes.registry import builtin_scene

TAPS = (0.5, 0.3, 0.2)


@pytest.fixture(scope="module")
def h(compute):
    return Harness(compute)


def angle(a, b):
    return np.arccos(np.clip(np.sum(a * b, -1), -1.0, 1.0))


# ---- FIR filter ------------------------------------------------------------------------------

def test_fir_step_in_power_gives_the_tap_cumulative_sums(h):
    """A constant map whose value doubles at a frame: the pdf (so every direction) is unchanged
    and each light's raw weight steps w → 2w; the filtered weight and the rendered image follow
    1 + (cumulative sum of the taps), frame by frame, including the renormalised taps of the
    first frames after reset()."""
    gbuffer = DeviceGBuffer(h.compute, white_lambertian())
    for step in (3, 1):          # full history before the step; the step on frame 1 after reset
        est = Havran()
        est.reset()
        k, seed = 32, 5
        ratios, images = [], []
        for frame in range(step + 4):
            value = 0.7 if frame < step else 1.4
            cache = FrameCache(h.compute, constant_map(value), frame=frame)
            dirs, weights = est.lights(cache, k, seed)
            base_dirs, base_weights = est.raw_lights(FrameCache(h.compute, constant_map(0.7)), k, seed)
            np.testing.assert_allclose(dirs, base_dirs, atol=1e-12)
            ratios.append(weights / base_weights)
            images.append(est.render(gbuffer, cache, k, seed).radiance)
        expected = []
        for frame in range(step + 4):
            n = min(frame + 1, len(TAPS))
            taps = np.array(TAPS[:n]) / sum(TAPS[:n])
            # the tap j looks back to frame − j, which has the doubled value if frame − j ≥ step
            expected.append(1.0 + sum(taps[j] for j in range(n) if frame - j >= step))
        np.testing.assert_allclose([r.mean() for r in ratios], expected, rtol=1e-12)
        np.testing.assert_allclose([r.std() for r in ratios], 0.0, atol=1e-12)
        if step == 3:
            np.testing.assert_allclose(expected[step:step + 3], 1.0 + np.cumsum(TAPS))
        else:
            np.testing.assert_allclose(expected[1:3], [1.0 + 0.5 / 0.8, 1.8])
        for frame in range(step + 4):
            np.testing.assert_allclose(images[frame], expected[frame] * images[0], rtol=2e-5, atol=1e-7)


def test_fir_step_in_direction():
    """A light jumping from d0 to d1 (90° apart) moves along the great circle between them as the
    renormalised weighted sum of the taps' cumulative sums."""
    d0, d1 = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]])
    w = np.ones((1, 3))
    trajectory = [d0, d0, d0, d1, d1, d1, d1]
    history, out = [], []
    for d in trajectory:
        history.insert(0, d)
        out.append(fir_filter(history[:3], [w] * min(3, len(history)), TAPS)[0][0])
    for frame, c in zip(range(3, 7), (0.5, 0.8, 1.0, 1.0)):
        expected = c * d1[0] + (1 - c) * d0[0]
        np.testing.assert_allclose(out[frame], expected / np.linalg.norm(expected), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)
    np.testing.assert_allclose(out[:3], np.repeat(d0, 3, 0))


def test_estimator_filters_light_trajectories_and_reset_clears_them(h):
    """A moving bright region moves the lights; the estimator's lights are the FIR of the raw
    lights of its last frames, and reset() forgets them."""
    maps = []
    for frame in range(4):
        env = smooth_map(16) * 0.05
        face, row, col = cubemap.direction_to_texel(np.array([0.3, 0.8 - 0.3 * frame, 0.2 + 0.1 * frame]), 16)
        env[face, row, col] = 500.0
        maps.append(env)
    est, k, seed = Havran(), 48, 2
    raw = []
    for frame, env in enumerate(maps):
        cache = FrameCache(h.compute, env, frame=frame)
        raw.insert(0, est.raw_lights(cache, k, seed))
        dirs, weights = est.lights(cache, k, seed)
        want_dirs, want_weights = fir_filter([r[0] for r in raw[:3]], [r[1] for r in raw[:3]], TAPS)
        np.testing.assert_allclose(dirs, want_dirs, atol=1e-12)
        np.testing.assert_allclose(weights, want_weights, rtol=1e-12)
    assert angle(raw[0][0], raw[1][0]).max() > 1e-3, "the moving light must move the lights"
    assert angle(dirs, raw[0][0]).max() > 1e-3, "the filter must lag the raw lights"
    est.reset()
    dirs, weights = est.lights(FrameCache(h.compute, maps[-1], frame=3), k, seed)
    np.testing.assert_array_equal(dirs, raw[0][0])
    np.testing.assert_array_equal(weights, raw[0][1])


# ---- point set and progressivity -------------------------------------------------------------

def nearest_neighbour_stats(points):
    d, _ = cKDTree(points % 1.0, boxsize=1.0).query(points % 1.0, k=2)
    d = d[:, 1]
    return d.min() * np.sqrt(len(points)), d.std() / d.mean()


@pytest.mark.parametrize("k", [64, 256, 1024])
def test_lloyd_relaxation_spreads_the_halton_points(k):
    """Relaxed points: larger minimum toroidal nearest-neighbour distance (× √K) and a smaller
    coefficient of variation of the nearest-neighbour distances than raw Halton (2, 3)."""
    raw_min, raw_cv = nearest_neighbour_stats(hv.halton(k))
    relaxed_min, relaxed_cv = nearest_neighbour_stats(hv.relaxed_points(k))
    assert relaxed_min > 1.25 * raw_min, (relaxed_min, raw_min)
    assert relaxed_cv < 0.8 * raw_cv, (relaxed_cv, raw_cv)


def test_progressive_k_adds_lights_without_moving_existing_ones(h):
    np.testing.assert_array_equal(hv.relaxed_points(100), hv.relaxed_points(1000)[:100])
    np.testing.assert_array_equal(hv.relaxed_points(37), hv.relaxed_points(64)[:37])
    cache = FrameCache(h.compute, stress_maps()["sun-1e6"])
    big_dirs, big_weights = Havran().raw_lights(cache, 256, 3)
    for k in (16, 64, 100):
        dirs, weights = Havran().raw_lights(cache, k, 3)
        np.testing.assert_array_equal(dirs, big_dirs[:k])
        np.testing.assert_allclose(weights * k, big_weights[:k] * 256, rtol=1e-12)


# ---- the map: bicontinuity and pdf ------------------------------------------------------------

def faces(dirs):
    return cubemap.direction_to_face_st(dirs)[0]


def max_jump(sample, delta, n=160):
    """Largest angular move of the direction when a point on a grid over the unit square moves
    by ``delta`` along either axis."""
    g = (np.arange(n) + 0.5) / n * (1 - 2 * delta) + delta
    u = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    a = sample(u)
    worst = 0.0
    for axis in (0, 1):
        v = u.copy()
        v[:, axis] += delta
        worst = max(worst, angle(a, sample(v)).max())
    return worst


def face_crossing_jumps(sample, n=64, steps=36):
    """Where the map crosses a cube face: grid neighbours (spacing 1/n) on different faces are
    bisected down to points (1/n)·2^-steps apart on either side of the face edge; returns the
    angles between the two sides' directions."""
    g = (np.arange(n) + 0.5) / n
    u = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    gaps = []
    for axis in (0, 1):
        lo = u[u[:, axis] + 1 / n < 1]
        hi = lo.copy()
        hi[:, axis] += 1 / n
        cross = faces(sample(lo)) != faces(sample(hi))
        lo, hi = lo[cross], hi[cross]
        for _ in range(steps):
            mid = 0.5 * (lo + hi)
            same = faces(sample(mid)) == faces(sample(lo))
            lo = np.where(same[:, None], mid, lo)
            hi = np.where(same[:, None], hi, mid)
        gaps.append(angle(sample(lo), sample(hi)))
    return np.concatenate(gaps)


def facewise(u):
    """A face-wise inverse transform (face from u1, then the point in that face): not continuous."""
    face = np.minimum((u[:, 0] * 6).astype(int), 5)
    return cubemap.face_st_to_direction(face, u[:, 0] * 6 - face, u[:, 1]).reshape(-1, 3)


@pytest.mark.parametrize("name", ["sun-1e6", "single-hot-texel", "black-faces"])
def test_the_map_is_bicontinuous(name):
    """Small moves of a 2-D point give small angular moves everywhere (shrinking with the move),
    including across cube faces, where a face-wise inversion jumps."""
    envmap = EqualAreaMap(stress_maps()[name])
    sample = lambda u: envmap.sample(u)[0]
    jumps = {delta: max_jump(sample, delta) for delta in (1e-5, 1e-7)}
    assert jumps[1e-7] < 2e-3, jumps
    assert jumps[1e-7] < 0.05 * jumps[1e-5] + 1e-6, f"moves must shrink with the step: {jumps}"
    crossings = face_crossing_jumps(sample)
    assert len(crossings) > 50, "the probe must find the map's face crossings"
    assert crossings.max() < 1e-6, f"a jump of {crossings.max():.3g} rad across a cube face"
    facewise_jumps = face_crossing_jumps(facewise, n=24)
    assert facewise_jumps.max() > 0.5, "the probe must catch a face-wise map's jumps"


def test_the_map_pdf_is_its_density():
    """E[Y(ω)/p(ω)] over uniform points is ∫Y dω (the pdf is the map's density), and samples
    concentrate where the map is bright."""
    env = smooth_map(16)
    env[4, 5:8, 5:8] *= 40.0
    envmap = EqualAreaMap(env)
    u = np.random.default_rng(1).random((200_000, 2))
    dirs, pdf = envmap.sample(u)
    luminance = cubemap.luminance(envmap.radiance(dirs))
    truth = cubemap.luminance(cubemap.integrate(env.astype(np.float64)))
    estimate = luminance / pdf
    assert abs(estimate.mean() - truth) < 4 * estimate.std() / np.sqrt(len(u)) + 1e-3 * truth
    face, row, col = cubemap.direction_to_texel(dirs, 16)
    bright = (face == 4) & (row >= 5) & (row < 8) & (col >= 5) & (col < 8)
    share = cubemap.texel_solid_angles(16)[5:8, 5:8].sum() / (4 * np.pi)
    assert bright.mean() > 10 * share


@pytest.mark.parametrize("name", ["sun-1e6", "single-hot-texel", "all-black", "black-faces", "sphere-sun"])
def test_the_device_map_is_the_numpy_map(compute, name):
    """havran.cl builds the map's probabilities and CDFs as the NumPy build does: equal up to
    the float32 luminance on the device (relative 1e-6; the CDF searches and the blend need no
    more), and the marginal and every row's CDF end at exactly 1."""
    env = (builtin_scene("sphere-sun", env_res=32).environment.frame(0) if name == "sphere-sun"
           else stress_maps()[name])
    device, host = EqualAreaMap.on_device(FrameCache(compute, env)), EqualAreaMap(env)
    for array in ("row_prob", "row_cdf", "col_prob", "col_cdf"):
        np.testing.assert_allclose(getattr(device, array), getattr(host, array), rtol=1e-6, atol=0,
                                   err_msg=array)
    assert device.row_cdf[-1] == 1.0 and np.all(device.col_cdf[:, -1] == 1.0)
    assert device.build_ms > 0


@pytest.mark.parametrize("name", ["sun-1e6", "black-faces", "sphere-sun"])
def test_the_device_lights_are_the_numpy_inversion(compute, name):
    """place_lights inverts the device map as EqualAreaMap.sample does (the NumPy twin, run on
    the device map's own arrays), and weights its lights L/(p·K) with the texel of ω: equal up
    to libm's cos and sin."""
    env = (builtin_scene("sphere-sun", env_res=32).environment.frame(0) if name == "sphere-sun"
           else stress_maps()[name])
    cache = FrameCache(compute, env)
    twin = EqualAreaMap.of_device_map(hv.frame_map(cache), env)
    k, seed = 500, 7
    want_dirs, pdf = twin.sample((hv.relaxed_points(k) + hv.seed_shift(seed)) % 1.0)
    want_weights = twin.radiance(want_dirs) / (pdf[:, None] * k)
    dirs, weights = Havran().raw_lights(cache, k, seed)
    np.testing.assert_allclose(dirs, want_dirs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(weights, want_weights, rtol=1e-12, atol=0)


# ---- rendering --------------------------------------------------------------------------------

def test_per_normal_culling_counts_the_lights_above_the_horizon(h):
    gb = white_lambertian(6)
    gbuffer, cache = h.inputs(gb, smooth_map())
    est = Havran()
    estimate = h.render(est, gbuffer, cache, 40, 1)
    dirs, _ = est.lights(cache, 40, 1)
    above = (gb.normal.reshape(-1, 3) @ dirs.T.astype(np.float32) > 0).sum(1)
    np.testing.assert_array_equal(estimate.effective.reshape(-1), above)
    np.testing.assert_array_equal(estimate.used, 40)
    assert estimate.evaluations == pytest.approx(above.mean())


def test_white_furnace_within_tolerance(h):
    """Constant map 0.7 on a white Lambertian: with K = 256 relaxed lights every pixel is within
    3% of 0.7 and the image mean within 0.5%; over 100 seeds the mean is unbiased (the
    rotation makes every light uniform, and on a static map the FIR filter is the identity)."""
    gbuffer, cache = h.inputs(white_lambertian(), constant_map(0.7))
    image = h.render(Havran(), gbuffer, cache, 256, 0).radiance
    assert np.abs(image / 0.7 - 1).max() < 0.03
    assert abs(image.mean() / 0.7 - 1) < 0.005
    means = np.array([h.render(Havran(), gbuffer, cache, 16, s).radiance.mean() for s in range(100)])
    assert abs(means.mean() - 0.7) < 3 * means.std(ddof=1) / 10 + 1e-6


def test_delta_e_falls_with_k_on_a_static_map(h):
    """The acceptance: on sphere-sun (static), ΔE76 falls from K = 16 to 64 to 256."""
    scene = builtin_scene("sphere-sun", env_res=32)
    gb = trace_gbuffer(scene.mesh, scene.material, scene.camera, 40, 40)
    gbuffer = DeviceGBuffer(h.compute, gb)
    cache = FrameCache(h.compute, scene.environment.frame(0))
    reference = Reference(h.compute, use_cache=False).image(gbuffer, cache)
    est = Havran()
    delta_e = []
    for k in (16, 64, 256):
        rows = []
        for seed in range(3):
            est.reset()
            row, _ = metrics.score(est.render(gbuffer, cache, k, seed), reference, gb.mask)
            rows.append(row["mean_delta_e76"])
        delta_e.append(np.mean(rows))
    assert delta_e[0] > delta_e[1] > delta_e[2], delta_e
    assert delta_e[2] < 0.5 * delta_e[0], delta_e


def test_conformance_applies_error_falls_not_the_z_test():
    names = [check.__name__ for check in yield_checks(Havran())]
    assert "check_error_falls" in names and "check_white_furnace" in names
    assert "check_unbiased" not in names and "check_convergence" not in names
    assert "check_chi2_sampling" not in names


def test_bad_taps_are_rejected():
    with pytest.raises(ValueError, match="fir_taps"):
        Havran(fir_taps=(0.5, -0.1))
    with pytest.raises(ValueError, match="fir_taps"):
        Havran(fir_taps=())


def test_light_weights_stay_bounded_on_a_sun():
    """The conservative cell bound: on sphere-sun (R = 64) no direction's Y/p exceeds 50× the
    map's ∫Y (a mean-only grid gave 5000×: a sun texel missed by a cell's lookups)."""
    env = builtin_scene("sphere-sun", env_res=64).environment.frame(0)
    envmap = EqualAreaMap(env)
    dirs, pdf = envmap.sample(np.random.default_rng(0).random((100_000, 2)))
    ratio = cubemap.luminance(envmap.radiance(dirs)) / pdf
    assert ratio.max() < 50 * cubemap.luminance(cubemap.integrate(env.astype(np.float64)))


def test_fir_taps_are_per_sequence_frame_not_per_render(h):
    """Frames rendered with gaps: a tap belongs to frame t − j of the sequence, so frames 0, 1, 3
    filter frame 3 with taps 0.5 (frame 3) and 0.2 (frame 1, two back), renormalised, and a
    step of 3 or more (frames 0, 6) leaves every frame unfiltered."""
    est, k, seed = Havran(), 16, 4
    values = {0: 0.7, 1: 1.4, 3: 2.8, 6: 5.6}
    raw = {f: est.raw_lights(FrameCache(h.compute, constant_map(v)), k, seed)[1] for f, v in values.items()}
    for frame in (0, 1, 3):
        _, weights = est.lights(FrameCache(h.compute, constant_map(values[frame]), frame=frame), k, seed)
    np.testing.assert_allclose(weights, (0.5 * raw[3] + 0.2 * raw[1]) / 0.7, rtol=1e-12)
    _, weights = est.lights(FrameCache(h.compute, constant_map(values[6]), frame=6), k, seed)
    np.testing.assert_array_equal(weights, raw[6])


def test_same_frame_with_a_new_seed_or_k_starts_a_new_history(h):
    """A new seed (or K) on the frame just rendered resets the history: the lights are that
    seed's raw lights, not an error and not a mix with the other seed's."""
    est = Havran()
    cache = FrameCache(h.compute, smooth_map(8), frame=0)
    est.lights(cache, 16, 0)
    for k, seed in ((16, 1), (24, 1)):
        dirs, weights = est.lights(cache, k, seed)
        raw_dirs, raw_weights = est.raw_lights(cache, k, seed)
        np.testing.assert_array_equal(dirs, raw_dirs)
        np.testing.assert_array_equal(weights, raw_weights)


# Render sequences (frame, seed, K) whose last render's history each of havran's history rules
# decides alone (``Havran._filtered``): a new (seed, K) or a frame that goes back starts a new
# history, the same frame again replaces its entry, a later frame adds one.  Expected: the
# (frame, tap) pairs of that history, taps renormalised over it.
HISTORY_CASES = {
    "new-seed-on-a-later-frame": ([(0, 0, 16), (1, 0, 16), (2, 1, 16)], [(2, 0.5)]),
    "new-k-on-a-later-frame": ([(0, 0, 16), (1, 0, 16), (2, 0, 24)], [(2, 0.5)]),
    "frame-goes-back": ([(0, 0, 16), (1, 0, 16), (2, 0, 16), (1, 0, 16)], [(1, 0.5)]),
    "frame-goes-back-then-on": ([(0, 0, 16), (1, 0, 16), (2, 0, 16), (1, 0, 16), (2, 0, 16)],
                                     [(2, 0.5), (1, 0.3)]),
    "same-frame-again": ([(0, 0, 16), (1, 0, 16), (1, 0, 16)], [(1, 0.5), (0, 0.3)]),
}


@pytest.mark.parametrize("case", HISTORY_CASES)
def test_each_history_rule_decides_alone(h, case):
    """Each rule where no other applies: the earlier test of a new seed or K renders it on the
    frame just rendered, where replacing the frame's entry alone also gives that seed's raw
    lights, so a dead (seed, K) rule passes it.  Frame t's map is smooth_map × (1 + t): the
    lights' directions are those of every frame (one density), their weights scale with the
    frame, and a frame or seed kept where the rule drops it changes the filtered lights."""
    renders, history = HISTORY_CASES[case]
    est = Havran()
    caches = [FrameCache(h.compute, smooth_map(8) * np.float32(1 + t), frame=t) for t in range(3)]
    for frame, seed, k in renders:
        dirs, weights = est.lights(caches[frame], k, seed)
    raw = {f: est.raw_lights(caches[f], k, seed) for f, _ in history}
    taps = sum(tap for _, tap in history)
    np.testing.assert_allclose(dirs, raw[history[0][0]][0], atol=1e-12)
    np.testing.assert_allclose(weights, sum(tap * raw[f][1] for f, tap in history) / taps, rtol=1e-12)
