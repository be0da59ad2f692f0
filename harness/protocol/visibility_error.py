"""How close the cell visibility is to true geometric visibility (issues 22 and 34): measured, not
assumed, with an interval that holds the pixels it did not look at.

The masked reference is exact for the masks' V (every texel takes its cell's bit:
:mod:`iblbench.scenes.visibility`), so what the masks cost is ∫ L ρ cos⁺ (V_mask − V) dω per
pixel, V being real geometric visibility.  It is estimated per pixel with ``SAMPLES``
one-sample-MIS draws, half from the map's luminance distribution (``scenes.cubemap.MapSampler``)
and half uniform on the sphere (so every direction is covered, whatever the material), each
weighted by Y(f)/(½p_L + ½/(4π)), from the masks' offset origin:

- V is a real Embree shadow ray along the sample;
- V_mask is the mask's bit for the sample's cell at each resolution Rv (the answer of the ray
  through the cell's centre, :func:`iblbench.scenes.visibility.cell_answers`), and 1 for the row
  without visibility.

Both in the same sample (paired): only samples where they disagree add variance, so the
difference is resolved far better than two separate estimates would resolve it.  The image's
figure is Σ difference / Σ Y over the pixels, the denominator from the same samples with V.

Which pixels: every covered pixel where there are at most ``PIXELS``; otherwise a stratified
sample, the covered pixels in raster order cut into ``PIXELS`` strata of equal count and one
drawn from each.  The figure's standard error holds both the samples' error and the pixel
sample's (strata collapsed in pairs, with the finite-population factor 1 − n/N, so 0 when every
pixel is used).  Why (issue 34): at 48 random pixels the earlier figure moved 0.2–0.85 points
between draws, 5–20× the Monte Carlo error it stated.  The 90th percentile of per-pixel
differences is reported with the samples' own per-pixel noise at the same percentile, below
which it cannot fall.
"""
from __future__ import annotations

import statistics

import numpy as np

from iblbench.harness.protocol.stats import LEVEL

PIXELS = 4096           # strata: at 512 samples and four rows about 8 M Embree rays
SAMPLES = 512
PIXELS_PER_BATCH = 32
SEED = 22
LUMA = np.array([0.2126, 0.7152, 0.0722])


def sample_pixels(gbuffer, count: int = PIXELS, seed: int = SEED) -> np.ndarray:
    """A boolean ``[H, W]``: every covered pixel where there are at most ``count``, else one drawn
    from each of ``count`` strata of equal count over the covered pixels in raster order."""
    covered = np.flatnonzero(gbuffer.mask)
    if covered.size > count:
        edges = np.linspace(0, covered.size, count + 1).astype(np.int64)
        covered = covered[np.random.default_rng(seed).integers(edges[:-1], edges[1:])]
    only = np.zeros(gbuffer.mask.size, bool)
    only[covered] = True
    return only.reshape(gbuffer.mask.shape)


def pixel_sampling_error(difference: np.ndarray, y: np.ndarray, covered: int) -> float:
    """The standard error, from the choice of pixels, of Σ difference / Σ y as an estimate of the
    image's ratio: the residuals d − r·y of consecutive strata collapsed in pairs (raster-order
    neighbours are alike), times the finite-population factor 1 − n/N."""
    ratio = difference.sum() / y.sum()
    residual = difference - ratio * y
    pairs = residual[: residual.size // 2 * 2].reshape(-1, 2)
    variance = np.sum((pairs[:, 0] - pairs[:, 1]) ** 2) * (1.0 - residual.size / covered)
    return float(np.sqrt(max(variance, 0.0)) / y.sum())


def _integrand(gbuffer, light, pixels: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Y(L·ρ·cos⁺) at directions ``w`` ``[k, S, 3]`` of the flat pixel indices ``pixels``."""
    height, width = gbuffer.shape
    flat = lambda a: a.reshape(height * width, -1)[pixels][:, None]     # [k, 1, channels]
    normal, view, m = flat(gbuffer.normal), flat(gbuffer.view), flat(gbuffer.shininess)
    mirror = 2.0 * np.sum(normal * view, -1, keepdims=True) * normal - view
    lobe = np.maximum(np.sum(mirror * w, -1, keepdims=True), 0.0) ** m        # Phong, ARCHITECTURE.md §Conventions
    rho = flat(gbuffer.kd) / np.pi + flat(gbuffer.ks) * (m + 2.0) / (2.0 * np.pi) * lobe
    return (light.radiance(w) * rho * np.maximum(np.sum(normal * w, -1, keepdims=True), 0.0)) @ LUMA


def paired_differences(mesh, camera, gbuffer, env: np.ndarray, only: np.ndarray, resolutions,
                       samples: int = SAMPLES, seed: int = SEED) -> dict:
    """Per pixel of ``only`` (G-buffer order): ``y`` ``[k]``, the shadow-ray estimate of Y, and
    per resolution r of ``resolutions`` (None: no visibility) ``r`` → ``(mean, standard error)``
    ``[k]`` each of the paired difference (module docstring); ``"y_error"``, y's standard error."""
    from iblbench.scenes import visibility
    from iblbench.scenes.cubemap import MapSampler

    height, width = gbuffer.shape
    origins, covered = visibility.offset_points(mesh, camera, width, height)
    keep = only.reshape(-1)[covered]
    light, scene = MapSampler(env), visibility.occlusion_scene(mesh)
    rng = np.random.default_rng(seed)
    parts: dict = {"y": [], "y_error": [], **{r: [] for r in resolutions}}
    for first in range(0, int(keep.sum()), PIXELS_PER_BATCH):
        pixels = covered[keep][first:first + PIXELS_PER_BATCH]
        half = samples // 2
        uniform = rng.standard_normal((len(pixels), samples - half, 3))
        w = np.concatenate([light.sample((len(pixels), half), rng),
                            uniform / np.linalg.norm(uniform, axis=-1, keepdims=True)], 1)
        weight = _integrand(gbuffer, light, pixels, w) / (0.5 * light.pdf(w) + 0.5 / (4.0 * np.pi))
        ray_origins = np.repeat(origins[keep][first:first + PIXELS_PER_BATCH], samples, axis=0)
        rays = w.reshape(-1, 3)
        free = visibility.unoccluded(scene, ray_origins, rays).reshape(w.shape[:2]).astype(np.float64)
        values = {"y": weight * free}
        for r in resolutions:
            masked = 1.0 if r is None else visibility.cell_answers(scene, ray_origins, rays, r).reshape(w.shape[:2])
            values[r] = weight * (masked - free)
        for name, value in values.items():
            parts[name].append((value.mean(1), value.std(1, ddof=1) / np.sqrt(samples)))
    joined = {key: tuple(np.concatenate(column) for column in zip(*value)) for key, value in parts.items()}
    y, y_error = joined.pop("y")
    return dict(joined, y=y, y_error=y_error)


def resolutions(vis_res: int, env_res: int) -> list[int]:
    """Rv/2, Rv and 2·Rv where each is a power of two dividing the face size."""
    return [r for r in (vis_res // 2, vis_res, 2 * vis_res) if r >= 1 and env_res % r == 0]


def visibility_error(scene, gbuffer, env: np.ndarray, seed: int = SEED) -> list[dict]:
    """One row per visibility resolution (and one without visibility, ``visibility_res`` 0):
    the masked reference's luminance against real shadow rays', over the pixels of
    :func:`sample_pixels`: ``relative_difference`` (the image's Σ difference / Σ Y), its
    ``standard_error`` (of the samples and of the pixel sample, ``pixel_sampling_error`` the
    latter alone) and ``interval`` (the half-width of its interval at ``stats.LEVEL``, 95%),
    ``pixel_difference_p90`` (the 90th percentile of per-pixel differences relative to the
    pixels' mean Y) beside ``pixel_noise_p90`` (their own standard error at that percentile).
    ``seed`` draws the pixels and the samples."""
    only = sample_pixels(gbuffer, seed=seed)
    rows_of = [None, *resolutions(scene.visibility_res, env.shape[1])]
    measured = paired_differences(scene.mesh, scene.camera, gbuffer, env, only, rows_of, seed=seed)
    y, total, covered = measured["y"], measured["y"].sum(), int(gbuffer.mask.sum())
    z = statistics.NormalDist().inv_cdf(0.5 + LEVEL / 2)
    rows = []
    for vis_res in rows_of:
        difference, error = measured[vis_res]
        sampling = pixel_sampling_error(difference, y, covered)
        standard_error = float(np.hypot(sampling, np.sqrt((error ** 2).sum()) / total))
        rows.append({"visibility_res": vis_res or 0, "pixels": int(only.sum()), "covered": covered,
                     "samples": SAMPLES, "relative_difference": float(difference.sum() / total),
                     "standard_error": standard_error, "interval": z * standard_error,
                     "pixel_sampling_error": sampling,
                     "pixel_difference_p90": float(np.quantile(np.abs(difference), 0.9) / y.mean()),
                     "pixel_noise_p90": float(np.quantile(error, 0.9) / y.mean())})
    return rows
