"""``restir``'s weights held to their definitions (estimators/restir.py, steps 3 and 4): a NumPy
twin of the target scales 1/Z̃ (the coarse cells' Σ Y·Ω·ρ_Y·cos⁺ at their centres, the map's power
where no lit centre is above the horizon, 0 for a black map), of the history's confidence
(M-capped, scaled by min(Z̃_t/Z̃_{t−1}, Z̃_{t−1}/Z̃_t)) and of GRIS's temporal resampling weights,
compared with what the kernels keep for the next frame (``ReSTIR.kept_state``).  An unbiased
estimator stays unbiased under wrong weights of this kind, so the z-tests of test_restir.py
cannot see them; these tests read the weights themselves.  And ``plane-grazing``, the scene
where every lit coarse cell's centre lies below the pixels' horizon while the light's texels lie
above it: restir still finds its light."""
import numpy as np
import pytest

from iblbench.estimators.restir import ReSTIR
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.harness.verify.conformance import (bias_test, glossy_gbuffer, sequence_renders, sidak_z,
                                                smooth_map, switch_frames)
from iblbench.scenes import cubemap
from iblbench.scenes.gbuffer import GBuffer, trace_gbuffer
from iblbench.scenes.registry import load_scene

M = ReSTIR.Params().candidates
SPP = 4
# A sequence whose maps change every way the history's confidence cares about: static, a sun
# that comes on (switch_frames: frames 0-3), goes off, a black frame (Z̃ = 0), the sky back, the
# sky dimmed 4× (every Z̃ scales, the ratio is exact) and a single lit face (+X; many normals'
# coarse centres see none of it: the fallback to the map's power).
SEQUENCE_RES = 8


def sequence_maps() -> list[np.ndarray]:
    sky = smooth_map(SEQUENCE_RES)
    one_face = np.zeros_like(sky)
    one_face[0] = sky[0]
    return [*switch_frames(SEQUENCE_RES), np.zeros_like(sky), sky.copy(), sky * np.float32(0.25), one_face]


def _shading(gb):
    """Covered pixels' normal, reflected view, Y(kd), Y(ks) and m (float64)."""
    n, v = (gb.normal[gb.mask].astype(np.float64), gb.view[gb.mask].astype(np.float64))
    r = 2.0 * np.sum(n * v, -1, keepdims=True) * n - v
    return n, r, cubemap.luminance(gb.kd[gb.mask]), cubemap.luminance(gb.ks[gb.mask]), gb.shininess[gb.mask]


def brdf_luminance(gb, w):
    """ρ_Y(ω) = Y(kd)/π + Y(ks)·(m+2)/(2π)·max(r·ω, 0)^m of each covered pixel at w [..., pixels, 3]."""
    _n, r, kd, ks, m = _shading(gb)
    lobe = np.maximum(np.sum(r * w, -1), 0.0) ** m
    return kd / np.pi + ks * (m + 2.0) / (2.0 * np.pi) * lobe


def targets(gb, env, w):
    """p̂(ω) = L_Y·ρ_Y·cos⁺ (no masks) of each covered pixel at w [..., pixels, 3], nearest texel."""
    w = np.asarray(w, np.float64)
    face, row, col = cubemap.direction_to_texel(w, env.shape[1])
    cosine = np.sum(_shading(gb)[0] * w, -1)
    value = cubemap.luminance(env[face, row, col]) * brdf_luminance(gb, w) * cosine
    return np.where(cosine > 0.0, value, 0.0)


def coarse_cells(env):
    """(Σ Y·Ω of each cell [6, n, n], its centre's direction [6, n, n, 3]) of the weight pyramid's
    level of at most 2 × 2 cells a face (a power-of-two face size)."""
    res = env.shape[1]
    n = min(res, 2)
    weights = cubemap.luminance(env) * cubemap.texel_solid_angles(res)
    cells = weights.reshape(6, n, res // n, n, res // n).sum(axis=(2, 4))
    centre = (np.arange(n) + 0.5) / n
    t, s = np.meshgrid(centre, centre, indexing="ij")
    return cells, cubemap.face_st_to_direction(np.arange(6)[:, None, None], s, t)


def target_scales(gb, env) -> np.ndarray:
    """1/Z̃ of each covered pixel: Z̃ = Σ over the coarse cells of Y·Ω × ρ_Y·cos⁺ at the cell's
    centre, the map's Σ Y·Ω where that is 0; 0 for a black map."""
    cells, centres = coarse_cells(env)
    w = centres.reshape(-1, 1, 3)
    cosine = np.maximum(np.sum(_shading(gb)[0] * w, -1), 0.0)
    z = np.sum(cells.reshape(-1, 1) * brdf_luminance(gb, w) * cosine, axis=0)
    z = np.where(z > 0.0, z, cells.sum())
    with np.errstate(divide="ignore"):
        return np.where(z > 0.0, 1.0 / z, 0.0)


def history_share(scale, previous_scale):
    """min(Z̃_t/Z̃_{t−1}, Z̃_{t−1}/Z̃_t); 0 where either map is black to the pixel."""
    both = (scale > 0) & (previous_scale > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(both, np.minimum(previous_scale / scale, scale / previous_scale), 0.0)


SEED = 5


def _render(compute, gbuffer, env, frame, estimator, spp=SPP, seed=SEED):
    """The state ``estimator`` keeps after rendering frame ``frame`` of map ``env``, with the
    covered pixels' radiance under ``radiance``."""
    cache = FrameCache(compute, env, frame)
    cache.require(ReSTIR.requires)
    radiance = estimator.render(gbuffer, cache, spp, seed).radiance[gbuffer.gbuffer.mask]
    return {**estimator.kept_state(compute, gbuffer, spp), "radiance": radiance}


def _frames(compute, gb, maps, estimator, spp=SPP, seed=SEED):
    """The kept state after each frame of ``maps`` rendered in order after reset()."""
    gbuffer = DeviceGBuffer(compute, gb)
    estimator.reset()
    return [_render(compute, gbuffer, env, t, estimator, spp, seed) for t, env in enumerate(maps)]


def test_target_scales_are_the_coarse_cells_sum_and_its_fallbacks(compute):
    """Every pixel's 1/Z̃ as restir.py defines it, on maps where the sum is positive everywhere,
    where many pixels see no lit cell centre (the map's power) and where the map is black (0)."""
    gb = glossy_gbuffer()
    maps = sequence_maps()
    states = _frames(compute, gb, maps, ReSTIR(neighbours=0))
    cells, centres = coarse_cells(maps[-1])
    lit_above = np.sum(((cells > 0)[..., None] * centres).reshape(-1, 3) @ gb.normal[gb.mask].T > 0, 0)
    assert np.sum(lit_above == 0) >= 8, "the one-face map should leave pixels with no lit centre above"
    for t, (env, state) in enumerate(zip(maps, states)):
        np.testing.assert_allclose(state["scales"], target_scales(gb, env), rtol=1e-4, atol=0,
                                   err_msg=f"frame {t}: 1/Z̃ off its definition")


@pytest.mark.parametrize("cap", [0.5, 1.0, 20.0])
def test_history_confidence_is_capped_and_scaled_by_the_change_of_the_map(compute, cap):
    """Each chain's confidence after frame t is M + min(c_{t−1}, cap·M)·min(Z̃_t/Z̃_{t−1},
    Z̃_{t−1}/Z̃_t) (M on the first frame), with Z̃ from the NumPy twin: the M-cap, and a map that
    gained or lost the pixel's light leaves the history little say."""
    gb = glossy_gbuffer()
    maps = sequence_maps()
    states = _frames(compute, gb, maps, ReSTIR(neighbours=0, history_cap=cap))
    scales = [target_scales(gb, env) for env in maps]
    expected = np.full((SPP, gb.covered), float(M))
    for t, state in enumerate(states):
        if t:
            expected = M + np.minimum(expected, cap * M) * history_share(scales[t], scales[t - 1])
        np.testing.assert_allclose(state["info"][..., 0], expected, rtol=1e-4,
                                   err_msg=f"history_cap {cap}, frame {t}: confidence off its definition")


def gris_weights(confidence, scale, target, contribution) -> list[np.ndarray]:
    """GRIS's resampling weights w_i = m_i(ω_i)·p̂_0(ω_i)·W_i of inputs i with the confidence-
    weighted, scaled balance heuristic m_i(ω) = c_i s_i p̂_i(ω) / Σ_j c_j s_j p̂_j(ω); target[j][i]
    is p̂_j(ω_i) (domain 0 the output's); 0 where not a positive number (the kernel's rule)."""
    n = len(contribution)
    with np.errstate(divide="ignore", invalid="ignore"):
        weights = []
        for i in range(n):
            share = [confidence[j] * scale[j] * target[j][i] for j in range(n)]
            w = share[i] / sum(share) * target[0][i] * contribution[i]
            weights.append(np.where(np.isfinite(w) & (w > 0), w, 0.0))
    return weights


def _temporal_gris(gb, maps, t, initial, history, cap):
    """(w_0, w_1) of frame t's initial reservoir and the history, and p̂_t at their samples:
    p̂_0 = p̂_t, p̂_1 = p̂_{t−1}, s_i = 1/Z̃ under its map, c_0 = M, c_1 the capped, scaled history."""
    omega = (initial["sample"][..., :3], history["sample"][..., :3])
    scale = target_scales(gb, maps[t]), target_scales(gb, maps[t - 1])
    confidence = (M, np.minimum(history["info"][..., 0], cap * M) * history_share(*scale))
    now = [targets(gb, maps[t], w) for w in omega]
    before = [targets(gb, maps[t - 1], w) for w in omega]
    contribution = (initial["sample"][..., 3], history["sample"][..., 3])
    return gris_weights(confidence, scale, (now, before), contribution), now


def test_temporal_resampling_weights_are_gris_with_confidence_and_scales(compute):
    """Frame t's kept reservoir against its inputs: the initial one (the same frame rendered
    without reuse, whose streams are the same) and the history (frame t−1's kept one).  Its
    sample is one of theirs; its W = (w_0 + w_1)/p̂_t(kept) with GRIS's weights from the NumPy
    twin (rtol 1e-3); its p̂ = p̂_t(kept); and the history is kept as often as w_1/(w_0 + w_1)
    says, summed over pixels, chains and frames (|z| < 4.5).  The history's target under the old
    map, its confidence and the scales all enter w, so a weight off its definition moves W."""
    gb = glossy_gbuffer()
    maps = sequence_maps()
    for cap in (1.0, 20.0):
        params = dict(neighbours=0, history_cap=cap)
        states = _frames(compute, gb, maps, ReSTIR(**params))
        fresh = ReSTIR(temporal=False, **params)
        kept_history, chance = 0.0, []
        for t in range(1, len(maps)):
            initial = _render(compute, DeviceGBuffer(compute, gb), maps[t], t, fresh)
            (w0, w1), now = _temporal_gris(gb, maps, t, initial, states[t - 1], cap)
            out = states[t]
            took = [np.all(out["sample"][..., :3] == source["sample"][..., :3], -1)
                    for source in (initial, states[t - 1])]
            total = w0 + w1
            assert np.all(took[0] | took[1] | (total == 0)), f"cap {cap}, frame {t}: a sample from nowhere"
            history = took[1] & ~took[0]
            kept_target = np.where(history, now[1], now[0])
            with np.errstate(divide="ignore", invalid="ignore"):
                expected = np.where(total > 0, total / kept_target, 0.0)
            where = f"cap {cap}, frame {t}"
            np.testing.assert_allclose(out["sample"][..., 3], expected, rtol=1e-3, atol=1e-30,
                                       err_msg=f"{where}: W off GRIS's")
            np.testing.assert_allclose(out["info"][..., 1], np.where(total > 0, kept_target, 0.0),
                                       rtol=1e-4, err_msg=f"{where}: p̂ of the kept sample")
            both = (w0 > 0) & (w1 > 0) & ~(took[0] & took[1])
            kept_history += history[both].sum()
            chance.append(w1[both] / total[both])
        q = np.concatenate(chance)
        z = (kept_history - q.sum()) / np.sqrt(np.sum(q * (1 - q)))
        assert q.size > 200 and abs(z) < 4.5, f"cap {cap}: the history kept {kept_history} of {q.size} " \
                                               f"times against {q.sum():.1f} expected (z = {z:.1f})"


def shade(gb, env, w, weight):
    """f(ω)·W = L(ω)·ρ(ω)·cos·W (RGB) of each covered pixel at w [pixels, 3]; 0 where W ≤ 0 or
    the cosine is not positive."""
    n, r, _kd, _ks, m = _shading(gb)
    cosine = np.sum(n * w, -1)
    face, row, col = cubemap.direction_to_texel(w, env.shape[1])
    lobe = (m + 2.0) / (2.0 * np.pi) * np.maximum(np.sum(r * w, -1), 0.0) ** m
    rho = gb.kd[gb.mask] / np.pi + gb.ks[gb.mask] * lobe[:, None]
    value = env[face, row, col] * rho * (cosine * weight)[:, None]
    return np.where(((weight > 0) & (cosine > 0))[:, None], value, 0.0)


def _spatial_outcomes(gb, env, state, unbiased):
    """Pixel p of a two-pixel image combined with the other, q (the only pixel its disc can
    reach): the radiance of each outcome, [no neighbour, kept ω_p, kept ω_q] × [pixels, 3], and
    (w_p, w_q).  Unbiased: GRIS over the two pixels' targets, each scaled by its 1/Z̃; biased:
    w_i = p̂_p(ω_i)·W_i·c_i and W = Σ w / (p̂_p(kept)·Z), Z = Σ c_j over the pixels j with
    p̂_j(kept) > 0."""
    omega, contribution = state["sample"][0, :, :3].astype(np.float64), state["sample"][0, :, 3]
    confidence, scale = state["info"][0, :, 0], target_scales(gb, env)
    own, across = targets(gb, env, omega), targets(gb, env, omega[::-1])   # p̂_p(ω_p), p̂_p(ω_q)
    swap = lambda a: a[::-1]
    if unbiased:
        w = gris_weights((confidence, swap(confidence)), (scale, swap(scale)), ((own, across), (swap(across), swap(own))),
                         (contribution, swap(contribution)))
        z = (1.0, 1.0)
    else:
        w = [own * contribution * confidence, across * swap(contribution * confidence)]
        z = (confidence * (own > 0) + swap(confidence * (across > 0)),
             confidence * (across > 0) + swap(confidence * (own > 0)))
    total = w[0] + w[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        kept = [shade(gb, env, at, np.where(total > 0, total / (target * norm), 0.0))
                for at, target, norm in ((omega, own, z[0]), (swap(omega), across, z[1]))]
    return [shade(gb, env, omega, contribution), *kept], w


@pytest.mark.parametrize("unbiased", [True, False])
def test_spatial_resampling_weights_are_gris_or_one_over_z(compute, unbiased):
    """Two pixels side by side (normals 30° apart, their own views), one neighbour at radius 2,
    1 chain, history cap 20, over the changing sequence and 40 seeds: each pixel's shaded radiance
    is one of its three outcomes (no neighbour found; the combination keeping its own sample or
    the other's) with the weights of restir.py's step 4 from the NumPy twin (rtol 1e-3), the
    combination happens (≥ 20% of the cases) and keeps the other's sample as often as
    w_q/(w_p + w_q) says (|z| < 4.5)."""
    normal = np.array([[[0.2, 0.5, 0.85], [-0.3, 0.6, 0.75]]])
    gb = GBuffer.from_pixels(normal, np.array([[[0.5, 0.3, 0.8], [-0.2, 0.1, 1.0]]]), 0.5, 0.3, 20.0)
    maps = sequence_maps()
    combined = kept_other = 0
    chance = []
    for seed in range(40):
        states = _frames(compute, gb, maps, ReSTIR(neighbours=1, radius=2.0, history_cap=20.0, unbiased=unbiased),
                         spp=1, seed=seed)
        for t, (env, state) in enumerate(zip(maps, states)):
            outcomes, (w_own, w_other) = _spatial_outcomes(gb, env, state, unbiased)
            match = [np.all(np.abs(state["radiance"] - o) <= 1e-3 * np.abs(o) + 1e-12, -1) for o in outcomes]
            odd = ~(match[0] | match[1] | match[2])
            assert not odd.any(), (f"seed {seed}, frame {t}: radiance {state['radiance'][odd]} is none of "
                                   f"{np.array(outcomes)[:, odd].tolist()} (no neighbour, own kept, other's kept)")
            clear = (w_own > 0) & (w_other > 0) & ~match[0] & (match[1] ^ match[2])
            combined += np.sum(~match[0] & (match[1] | match[2]))
            kept_other += np.sum(match[2][clear])
            chance.append(w_other[clear] / (w_own[clear] + w_other[clear]))
    q = np.concatenate(chance)
    cases = 40 * len(maps) * gb.covered
    assert combined >= 0.2 * cases, f"{combined} of {cases} cases combined: the test sees too little reuse"
    z = (kept_other - q.sum()) / np.sqrt(np.sum(q * (1 - q)))
    assert abs(z) < 4.5, f"the other's sample kept {kept_other} of {q.size} times, {q.sum():.1f} expected (z = {z:.1f})"


# ---- plane-grazing: all the light where the coarse model says it cannot reach ----------------

GRAZING_RES, GRAZING_PIXELS, GRAZING_FRAMES, GRAZING_SEEDS = 16, 8, 3, 150


def test_plane_grazing_has_its_light_above_the_horizon_and_its_cell_centres_below():
    """The scene's premise, at every face size the test and the default use: each texel that
    holds light has its centre above the plane's horizon, each coarse cell that holds light has
    its centre below it, so Σ over the cells is 0 and restir's Z̃ takes its fallback."""
    for res in (4, GRAZING_RES, 64):
        scene = load_scene("plane-grazing", env_res=res)
        env = scene.environment.frame(0)
        normal = np.unique(np.round(np.asarray(scene.mesh.vertex_normals), 6), axis=0)
        assert normal.shape == (1, 3), "one plane, one normal"
        lit = cubemap.luminance(env) > 0
        assert np.all(cubemap.texel_directions(res)[lit] @ normal[0] > 0), f"{res}²: a lit texel below"
        cells, centres = coarse_cells(env)
        assert np.all(centres[cells > 0] @ normal[0] < 0), f"{res}²: a lit cell's centre above"


def test_restir_finds_the_light_of_plane_grazing(compute):
    """Every pixel of plane-grazing (8², 16² faces), frames 0-2 of its one map in order (temporal
    and spatial reuse, the default settings), over 150 seeds at 2 spp: no pixel's mean is black,
    and every frame's mean is the reference, pixel by pixel and over the image (Šidák over all
    frames' tests at α = 1e-3); each pixel's scale is 1/the map's power (the fallback)."""
    scene = load_scene("plane-grazing", env_res=GRAZING_RES)
    gb = trace_gbuffer(scene.mesh, scene.material, scene.camera, GRAZING_PIXELS, GRAZING_PIXELS)
    env = scene.environment.frame(0)
    gbuffer = DeviceGBuffer(compute, gb)
    caches = [FrameCache(compute, env, t) for t in range(GRAZING_FRAMES)]
    for cache in caches:
        cache.require(ReSTIR.requires)
    estimator = ReSTIR()
    samples = sequence_renders(estimator, gbuffer, caches, GRAZING_SEEDS, 2)
    reference = Reference(compute, use_cache=False).image(gbuffer, caches[0])[gb.mask]
    assert np.all(reference.sum(-1) > 0), "every pixel sees the light"
    mean = samples.mean(axis=0).sum(-1)
    black = ~(mean > 0)
    assert not black.any(), f"{black.sum(1).tolist()} black pixels of {gb.covered} on frames 0-{GRAZING_FRAMES - 1}"
    for t in range(GRAZING_FRAMES):
        test = bias_test(samples[:, t], reference)
        assert np.abs(test.pixel_z).max() < sidak_z(test.pixel_z.size * GRAZING_FRAMES), \
            f"frame {t}: pixel |z| {np.abs(test.pixel_z).max():.1f}"
        assert np.abs(test.pooled_z).max() < sidak_z(3 * GRAZING_FRAMES), f"frame {t}: image z {test.pooled_z}"
    np.testing.assert_allclose(estimator.kept_state(compute, gbuffer, 2)["scales"], 1.0 / coarse_cells(env)[0].sum(),
                               rtol=1e-4, err_msg="1/Z̃ is not 1/the map's power where no lit cell centre is above")
