"""Scores of one estimate against its reference: protocol ``lab-reinhard-v1`` of DESIGN §3.

1. Exposure k = 0.18 / log-average luminance of the reference over covered pixels, applied to both.
2. Reinhard L/(1+L) on luminance, colour scaled by the same ratio.
3. Linear sRGB → XYZ (D65) → L*a*b* with colour-science; mean ΔE76 and ΔE2000 over covered pixels.
Plus relMSE in linear HDR, mean((x−r)²/(r²+0.01)), flicker between consecutive frames (:func:`flicker`), HDR-FLIP (NVIDIA's flip-evaluator, where
installed; NaN otherwise) as a mean over covered pixels, and the sample counts.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

with warnings.catch_warnings():
    warnings.simplefilter("ignore")   # colour warns about optional packages at import
    import colour

from iblbench.scenes.cubemap import luminance

try:
    import flip_evaluator
except ImportError:   # optional: `pip install iblbench[flip]`
    flip_evaluator = None

PROTOCOL = "lab-reinhard-v1"
_D65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
_SRGB = colour.RGB_COLOURSPACES["sRGB"]
_LOG_EPSILON = 1e-6   # keeps black pixels out of log(0) in the log-average


def exposure(reference: np.ndarray, mask: np.ndarray) -> float:
    """k = 0.18 / exp(mean(log(ε + Y))) over covered pixels of the reference."""
    y = luminance(reference[mask])
    if y.size == 0:
        return 1.0
    return float(0.18 / np.exp(np.mean(np.log(_LOG_EPSILON + np.maximum(y, 0.0)))))


def tonemap(rgb: np.ndarray, k: float) -> np.ndarray:
    """Reinhard on luminance: c·k/(1 + k·Y), which maps k·Y to k·Y/(1 + k·Y)."""
    rgb = np.maximum(np.asarray(rgb, np.float64), 0.0)
    return rgb * (k / (1.0 + k * luminance(rgb)))[..., None]


def to_lab(display_rgb: np.ndarray) -> np.ndarray:
    xyz = colour.RGB_to_XYZ(display_rgb, _SRGB, apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, _D65)


def lab_differences(lab_a: np.ndarray, lab_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ΔE76 and ΔE2000 between L*a*b* arrays ``[..., 3]``."""
    return (colour.delta_E(lab_a, lab_b, method="CIE 1976"),
            colour.delta_E(lab_a, lab_b, method="CIE 2000"))


def delta_e_images(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray):
    """Per-pixel ΔE76 and ΔE2000 images (zero outside ``mask``)."""
    k = exposure(reference, mask)
    de76 = np.zeros(mask.shape)
    de2000 = np.zeros(mask.shape)
    de76[mask], de2000[mask] = lab_differences(to_lab(tonemap(estimate[mask], k)),
                                               to_lab(tonemap(reference[mask], k)))
    return de76, de2000


def flicker(delta_e: np.ndarray, previous_delta_e: np.ndarray | None, mask: np.ndarray) -> float:
    """Temporal flicker between consecutive frames of one (scene, estimator, spp, seed): the mean
    over covered pixels of |ΔE76(est_t, ref_t) − ΔE76(est_{t−1}, ref_{t−1})|, from the per-pixel
    ΔE76 maps of :func:`delta_e_images`; NaN without a previous map (the first frame)."""
    if previous_delta_e is None or not mask.any():
        return float("nan")
    return float(np.mean(np.abs(np.asarray(delta_e, np.float64)[mask]
                                - np.asarray(previous_delta_e, np.float64)[mask])))


def rel_mse(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    x = np.asarray(estimate[mask], np.float64)
    r = np.asarray(reference[mask], np.float64)
    return float(np.mean((x - r) ** 2 / (r * r + 0.01)))


def hdr_flip(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """Mean HDR-FLIP error over covered pixels; NaN without flip-evaluator or on a black reference.

    FLIP picks its exposure range from the reference's luminance; background pixels (zero) would
    stretch it, so the range is taken from the covered pixels alone.  A black or very dim
    reference makes that range degenerate, and FLIP then exits the whole process; the range
    follows any global scale, so both images are scaled to a peak reference luminance of 1, and
    a reference without a finite positive peak scores NaN.
    """
    if flip_evaluator is None or not mask.any():
        return float("nan")
    peak = float(luminance(reference[mask]).max())
    if not (math.isfinite(peak) and peak > 0.0):
        return float("nan")
    reference = np.ascontiguousarray(reference / peak, np.float32)
    estimate = estimate / peak
    covered = np.ascontiguousarray(reference[mask][None])
    exposures = flip_evaluator.evaluate(covered, covered, "HDR", applyMagma=False,
                                        computeMeanError=False)[2]
    parameters = {key: exposures[key] for key in ("startExposure", "stopExposure", "numExposures")}
    error_map = flip_evaluator.evaluate(reference, np.ascontiguousarray(estimate, np.float32), "HDR",
                                        applyMagma=False, parameters=parameters)[0]
    return float(error_map[..., 0][mask].mean())


def score(estimate, reference: np.ndarray, mask: np.ndarray) -> tuple[dict, np.ndarray]:
    """One results row's metrics for an :class:`Estimate`, and the ΔE76 image for a heat map.

    Non-finite estimate values are counted (``nonfinite``) and scored as black, so one NaN
    cannot hide the rest of the image's error.
    """
    radiance = np.where(np.isfinite(estimate.radiance), estimate.radiance, 0.0)
    de76, de2000 = delta_e_images(radiance, reference, mask)
    used = float(estimate.used[mask].mean()) if mask.any() else 0.0
    effective = float(estimate.effective[mask].mean()) if mask.any() else 0.0
    row = {
        "mean_delta_e76": float(de76[mask].mean()),
        "mean_delta_e2000": float(de2000[mask].mean()),
        "rel_mse": rel_mse(radiance, reference, mask),
        "flip": hdr_flip(radiance, reference, mask),
        "flicker": float("nan"),   # set by the runner, which knows the previous frame
        "used_samples": used,
        "effective_samples": effective,
        "effective_ratio": effective / used if used > 0 else float("nan"),
        "evaluations": estimate.evaluations,
        "nonfinite": estimate.nonfinite,
    }
    return row, de76
