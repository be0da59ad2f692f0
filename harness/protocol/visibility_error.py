"""How close the cell visibility is to true geometric visibility (issue 22): measured, not assumed.

At ``PIXELS`` covered pixels drawn at random (seeded), two values of the same integral
∫ L ρ cos⁺ V dω:

- the exact reference under the masks at each visibility resolution Rv (every texel takes its
  cell's bit: :mod:`iblbench.scenes.visibility`), traced for those pixels alone;
- a converged Monte Carlo estimate whose V is a real Embree shadow ray per sample, from the same
  offset origin as the masks: ``SAMPLES`` one-sample-MIS draws per pixel, half from the map's
  luminance distribution (``scenes.cubemap.MapSampler``) and half uniform on the sphere, each
  weighted by f·V/(½p_L + ½/(4π)), with its standard error (the uniform half covers every
  direction, so the estimate is unbiased whatever the material).

The difference (Y, relative to the pixels' summed Monte Carlo luminance; and per pixel) is
reported against Rv.  What it measures: a cell's one bit (the majority of four rays) against the
exact fraction of its directions that leave the scene, which matters where a shadow's edge or a
bright light lies within a cell.
"""
from __future__ import annotations

import dataclasses

import numpy as np

PIXELS = 48
SAMPLES = 1 << 16
PIXELS_PER_BATCH = 8
SEED = 22
LUMA = np.array([0.2126, 0.7152, 0.0722])


def sample_pixels(gbuffer, count: int = PIXELS, seed: int = SEED) -> np.ndarray:
    """A boolean ``[H, W]`` of ``count`` covered pixels drawn without replacement."""
    covered = np.flatnonzero(gbuffer.mask)
    chosen = np.random.default_rng(seed).choice(covered, size=min(count, covered.size), replace=False)
    only = np.zeros(gbuffer.mask.size, bool)
    only[chosen] = True
    return only.reshape(gbuffer.mask.shape)


def shadow_ray_estimate(mesh, camera, gbuffer, env: np.ndarray, only: np.ndarray,
                        samples: int = SAMPLES, seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """The Monte Carlo radiance ``[k, 3]`` of the pixels ``only`` (in G-buffer order) with a real
    Embree shadow ray per sample, and its standard error ``[k, 3]``; ``PIXELS_PER_BATCH`` pixels
    at a time."""
    from iblbench.scenes import visibility
    from iblbench.scenes.cubemap import MapSampler

    height, width = gbuffer.shape
    origins, covered = visibility.offset_points(mesh, camera, width, height)
    keep = only.reshape(-1)[covered]
    light, scene = MapSampler(env), visibility.occlusion_scene(mesh)
    rng = np.random.default_rng(seed)
    means, errors = [], []
    for first in range(0, int(keep.sum()), PIXELS_PER_BATCH):
        pixels = covered[keep][first:first + PIXELS_PER_BATCH]
        flat = lambda a: a.reshape(height * width, -1)[pixels][:, None]     # [k, 1, channels]
        half = samples // 2
        uniform = rng.standard_normal((len(pixels), samples - half, 3))
        w = np.concatenate([light.sample((len(pixels), half), rng),
                            uniform / np.linalg.norm(uniform, axis=-1, keepdims=True)], 1)
        pdf = 0.5 * light.pdf(w) + 0.5 / (4.0 * np.pi)
        normal, view, m = flat(gbuffer.normal), flat(gbuffer.view), flat(gbuffer.shininess)
        mirror = 2.0 * np.sum(normal * view, -1, keepdims=True) * normal - view
        lobe = np.maximum(np.sum(mirror * w, -1, keepdims=True), 0.0) ** m        # Phong, ARCHITECTURE.md §Conventions
        rho = flat(gbuffer.kd) / np.pi + flat(gbuffer.ks) * (m + 2.0) / (2.0 * np.pi) * lobe
        f = light.radiance(w) * rho * np.maximum(np.sum(normal * w, -1, keepdims=True), 0.0)
        free = visibility.unoccluded(scene, np.repeat(origins[keep][first:first + PIXELS_PER_BATCH],
                                                      samples, axis=0), w.reshape(-1, 3))
        values = f * free.reshape(w.shape[:2])[..., None] / pdf[..., None]
        means.append(values.mean(1))
        errors.append(values.std(1, ddof=1) / np.sqrt(samples))
    return np.concatenate(means), np.concatenate(errors)


def masked_reference(compute, mesh, camera, gbuffer, env: np.ndarray, only: np.ndarray,
                     vis_res: int | None) -> np.ndarray:
    """The exact reference ``[k, 3]`` of the pixels ``only`` under masks of ``vis_res`` (traced
    for them), or with no visibility (None)."""
    from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
    from iblbench.estimators.runtime.framecache import FrameCache
    from iblbench.estimators.runtime.reference import Reference
    from iblbench.scenes import visibility

    sub = dataclasses.replace(gbuffer, mask=gbuffer.mask & only, visibility=None, visibility_res=0)
    if vis_res is not None:
        masks, _ = visibility.trace_visibility(mesh, camera, gbuffer.normal, *gbuffer.shape[::-1],
                                               vis_res, only=sub.mask)
        sub = dataclasses.replace(sub, visibility=masks, visibility_res=vis_res)
    image = Reference(compute, use_cache=False).image(DeviceGBuffer(compute, sub), FrameCache(compute, env))
    return image[sub.mask].astype(np.float64)


def resolutions(vis_res: int, env_res: int) -> list[int]:
    """Rv/2, Rv and 2·Rv where each is a power of two dividing the face size."""
    return [r for r in (vis_res // 2, vis_res, 2 * vis_res) if r >= 1 and env_res % r == 0]


def visibility_error(compute, scene, gbuffer, env: np.ndarray) -> list[dict]:
    """One row per visibility resolution (and one without visibility, ``visibility_res`` 0):
    the masked reference's luminance against the shadow-ray estimate's at the sampled pixels,
    ``relative_difference`` (summed over the pixels, relative to the estimate's sum),
    ``pixel_difference_p90`` (the 90th percentile of per-pixel differences relative to the
    image's mean) and the estimate's own ``relative_standard_error``."""
    only = sample_pixels(gbuffer)
    estimate, error = shadow_ray_estimate(scene.mesh, scene.camera, gbuffer, env, only)
    y, y_error = estimate @ LUMA, np.sqrt((error ** 2) @ LUMA ** 2)
    total = y.sum()
    rows = []
    for vis_res in [None, *resolutions(scene.visibility_res, env.shape[1])]:
        reference = masked_reference(compute, scene.mesh, scene.camera, gbuffer, env, only, vis_res) @ LUMA
        difference = reference - y
        rows.append({"visibility_res": vis_res or 0, "pixels": int(only.sum()), "samples": SAMPLES,
                     "relative_difference": float(difference.sum() / total),
                     "pixel_difference_p90": float(np.quantile(np.abs(difference), 0.9) / y.mean()),
                     "relative_standard_error": float(np.sqrt((y_error ** 2).sum()) / total)})
    return rows
