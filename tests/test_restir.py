"""``restir`` (estimators/restir.py): unbiased on every frame of a switching sequence, its biased
mode biased where the docstring says, reuse that lowers the error, and the eye its depth test
measures from.  Its GRIS weights and M-cap are held by the conformance suite
(``check_unbiased_over_frames``, ``says_history_cap``), the mutation catalogue and, weight by
weight against NumPy twins, tests/test_restir_weights.py."""
import dataclasses

import numpy as np
import pytest

from iblbench.estimators.restir import ReSTIR, eye_depths
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.harness.verify.conformance import (SUN_FACE, bias_test, glossy_gbuffer, same_pixels,
                                                sequence_renders, sidak_z, smooth_map, sun_map)
from iblbench.scenes import visibility
from iblbench.scenes.gbuffer import trace_gbuffer
from iblbench.scenes.registry import load_scene
from iblbench.scenes.sequences import SWITCH_FRAMES

pytestmark = pytest.mark.slow


def test_unbiased_restir_passes_the_z_test_on_every_frame_of_sphere_switch(compute):
    """2000 seeds of the 30 frames of sphere-switch (12² pixels, 8² texels a face) at 1 spp, each
    sequence in order after reset(): every frame's mean, pixel by pixel and over the image, is
    its exact reference (Šidák over all frames' tests at α = 1e-3); the light comes on at
    frame 10 and goes off at frame 20."""
    scene = load_scene("sphere-switch", env_res=8)
    gbuffer = DeviceGBuffer(compute, trace_gbuffer(scene.mesh, scene.material, scene.camera, 12, 12))
    caches = [FrameCache(compute, scene.environment.frame(t), t) for t in range(SWITCH_FRAMES)]
    for cache in caches:
        cache.require(ReSTIR.requires)
    samples = sequence_renders(ReSTIR(), gbuffer, caches, 2000, 1)
    reference = Reference(compute, use_cache=False)
    worst = []
    for t, cache in enumerate(caches):
        test = bias_test(samples[:, t], reference.image(gbuffer, cache)[gbuffer.gbuffer.mask])
        worst.append((max(np.abs(test.pixel_z).max() / sidak_z(test.pixel_z.size * len(caches)),
                          np.abs(test.pooled_z).max() / sidak_z(3 * len(caches))), t))
    assert max(worst)[0] < 1.0, f"frame {max(worst)[1]}: |z| at {max(worst)[0]:.2f} of its bound"


def _half_shadowed(compute):
    """Eight columns of pixels of one normal and view, every other column's sun cell closed, and
    the frame of a sun in that cell."""
    gb = same_pixels((0.0, 0.0, 1.0), (0.0, 0.3, 1.0), rows=4, cols=8)
    env = sun_map(8, 1e3)
    vis_res = 2
    cells = np.ones(gb.shape + (6 * vis_res * vis_res,), bool)
    # The sun texel (SUN_FACE, 4, 4) of 8² lies in that face's visibility cell (1, 1) of 2².
    cells[:, 1::2, (SUN_FACE * vis_res + 1) * vis_res + 1] = False
    gb = dataclasses.replace(gb, visibility=visibility.pack_bits(cells), visibility_res=vis_res)
    gbuffer, cache = DeviceGBuffer(compute, gb), FrameCache(compute, env)
    cache.require(ReSTIR.requires)
    return gbuffer, cache, Reference(compute, use_cache=False).image(gbuffer, cache)


def test_biased_mode_darkens_beside_shadows_and_the_unbiased_one_does_not(compute):
    """The biased combination counts a shadowed neighbour in Z although it cannot produce the
    sun (its Z leaves V out, restir.cl): the lit columns come out dark, by many standard errors;
    the unbiased one's GRIS weights include V and hold the reference."""
    gbuffer, cache, reference = _half_shadowed(compute)
    for unbiased in (True, False):
        estimator = ReSTIR(unbiased=unbiased, radius=2.0, temporal=False)
        samples = np.array([estimator.render(gbuffer, cache, 2, seed).radiance.reshape(-1, 3)
                            for seed in range(300)])
        test = bias_test(samples, reference.reshape(-1, 3))
        if unbiased:
            assert np.abs(test.pixel_z).max() < sidak_z(test.pixel_z.size), test.pixel_z
        else:
            assert test.pooled_z.max() < -10, f"the biased mode is not dark: image z {test.pooled_z}"


def test_temporal_reuse_lowers_the_error_on_a_static_map(compute):
    """On a static map, each frame's reservoirs carry the last ones' candidates (up to RTXDI's M-cap of 20):
    by frame 5 the RMS error over 16 seeds is under 0.8 of frame 0's (measured 0.65; one shaded
    sample keeps the f/p̂ colour variance that no reuse removes); without reuse it stays (0.98)."""
    gbuffer, env = DeviceGBuffer(compute, glossy_gbuffer()), smooth_map()
    caches = [FrameCache(compute, env, frame) for frame in range(6)]   # one map, a new frame's numbers
    for cache in caches:
        cache.require(ReSTIR.requires)
    reference = Reference(compute, use_cache=False).image(gbuffer, caches[0])
    for temporal in (True, False):
        estimator = ReSTIR(temporal=temporal, neighbours=0, history_cap=20.0)
        errors = np.zeros((16, 6))
        for seed in range(16):
            estimator.reset()
            for frame, cache in enumerate(caches):
                image = estimator.render(gbuffer, cache, 1, seed).radiance
                errors[seed, frame] = np.sqrt(np.mean((image - reference) ** 2))
        ratio = errors[:, 5].mean() / errors[:, 0].mean()
        assert (ratio < 0.8) == temporal, f"temporal = {temporal}: error ratio frame 5 / frame 0 = {ratio:.2f}"


def test_eye_depths_are_distances_to_the_camera(compute):
    scene = load_scene("blob-sun", env_res=8)
    gb = trace_gbuffer(scene.mesh, scene.material, scene.camera, 24, 24)
    depths = eye_depths(DeviceGBuffer(compute, gb))
    expected = np.linalg.norm(gb.position[gb.mask] - np.asarray(scene.camera.eye), axis=1)
    np.testing.assert_allclose(depths, expected, rtol=1e-4)


def _masked(gb, open_share=0.7, seed=3):
    """``gb`` with random visibility masks of 2² cells a face."""
    cells = np.random.default_rng(seed).random(gb.shape + (24,)) < open_share
    return dataclasses.replace(gb, visibility=visibility.pack_bits(cells), visibility_res=2)


def test_evaluations_and_shadow_rays_count_what_the_docstring_says(compute):
    """Without neighbours: a first frame evaluates M candidates and the shading a chain, a
    continuing one two targets more; the shadow rays are the evaluations less the shading with
    masks, 0 without."""
    env = smooth_map()
    caches = [FrameCache(compute, env, t) for t in range(2)]
    for cache in caches:
        cache.require(ReSTIR.requires)
    spp, m = 3, ReSTIR().params.candidates
    for gb in (glossy_gbuffer(), _masked(glossy_gbuffer())):
        gbuffer, estimator = DeviceGBuffer(compute, gb), ReSTIR(neighbours=0)
        first, second = (estimator.render(gbuffer, cache, spp, 1) for cache in caches)
        assert (first.evaluations, second.evaluations) == (spp * (m + 1), spp * (m + 3))
        masked = gb.visibility is not None
        assert (first.shadow_rays, second.shadow_rays) == ((spp * m, spp * (m + 2)) if masked else (0, 0))


class _ScalarPass2(ReSTIR):
    """restir with pass 2 built without its lanes: every chain one at a time in scalars."""

    def defines(self, gbuffer=None):
        return {**super().defines(gbuffer), "CHAIN_LANES": 0}


@pytest.mark.parametrize("unbiased", [True, False])
def test_pass_2_in_lanes_gives_the_scalar_paths_images_bit_for_bit(compute, unbiased):
    """Pass 2's lanes (a chain a lane, restir.cl) against its scalar path on every chain: the same
    radiance, counts and extras bit for bit, on two frames (the second with history), with masks
    and all eight neighbours, at whole and part blocks of lanes with a lone chain left over."""
    env = smooth_map()
    caches = [FrameCache(compute, env, t) for t in range(2)]
    for cache in caches:
        cache.require(ReSTIR.requires)
    gbuffer = DeviceGBuffer(compute, _masked(glossy_gbuffer()))
    for spp in (compute.pool_lanes + 3, 2 * compute.pool_lanes + 1):
        lanes, scalar = (cls(neighbours=8, radius=3.0, unbiased=unbiased) for cls in (ReSTIR, _ScalarPass2))
        for cache in caches:
            a, b = (estimator.render(gbuffer, cache, spp, 5) for estimator in (lanes, scalar))
            assert np.array_equal(a.radiance, b.radiance) and np.array_equal(a.effective, b.effective)
            assert (a.evaluations, a.shadow_rays, a.extras) == (b.evaluations, b.shadow_rays, b.extras)
            assert a.extras["neighbours"] > 1.0   # neighbours were found and combined


def test_a_new_seed_spp_or_gbuffer_starts_without_history(compute):
    """Reuse carries over only within one (G-buffer, face size, seed, spp): after a frame of
    another, a render equals a fresh instance's."""
    env = smooth_map()
    caches = [FrameCache(compute, env, t) for t in range(2)]
    for cache in caches:
        cache.require(ReSTIR.requires)
    small, large = DeviceGBuffer(compute, glossy_gbuffer(4)), DeviceGBuffer(compute, glossy_gbuffer(8))
    for before, after in (((small, 2, 1), (small, 2, 2)), ((small, 2, 1), (small, 3, 1)),
                          ((small, 2, 1), (large, 2, 1))):
        estimator = ReSTIR()
        estimator.render(before[0], caches[0], before[1], before[2])
        carried = estimator.render(after[0], caches[1], after[1], after[2]).radiance
        fresh = ReSTIR().render(after[0], caches[1], after[1], after[2]).radiance
        assert np.array_equal(carried, fresh)
    estimator = ReSTIR()                                   # the same key does carry it
    estimator.render(small, caches[0], 2, 1)
    assert not np.array_equal(estimator.render(small, caches[1], 2, 1).radiance,
                              ReSTIR().render(small, caches[1], 2, 1).radiance)


def test_presample_tiles_smaller_than_a_block_of_lanes_are_refused():
    with pytest.raises(ValueError):
        ReSTIR(tile_size=8)
