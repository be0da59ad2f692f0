"""PSNR: the peak signal-to-noise ratio of the image as it is displayed, in dB.

PSNR = 10·log10(MAX² / MSE) (Huynh-Thu & Ghanbari, "Scope of validity of PSNR in image/video
quality assessment", Electronics Letters 44(13), 2008), MSE the mean over covered pixels and the
three channels of the squared difference between estimate and reference.  Both are taken as the
protocol displays them (:mod:`iblbench.harness.protocol.metrics`): exposed by the reference's k,
Reinhard-tone-mapped, linear sRGB, clipped to the display's [0, 1], so MAX = 1.  Not in linear
HDR: radiance has no peak, and any MAX chosen there would shift every figure by a constant.
Higher is better; identical images score +inf.  Not in the default sweep: ``--metrics de76,psnr``.
"""
import math

import numpy as np

from iblbench.harness.protocol.metric import Metric
from iblbench.harness.protocol.metrics import tonemap

PEAK = 1.0   # the display's white


def displayed(radiance: np.ndarray, mask: np.ndarray, k: float) -> np.ndarray:
    """The covered pixels of ``radiance`` as the protocol displays them, in [0, PEAK]."""
    return np.clip(tonemap(radiance[mask], k), 0.0, PEAK)


def psnr(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray, k: float) -> float:
    """PSNR in dB of ``estimate`` against ``reference`` over ``mask``; NaN where nothing is
    covered, +inf where the displayed images are equal."""
    if not mask.any():
        return math.nan
    difference = displayed(estimate, mask, k) - displayed(reference, mask, k)
    mse = float(np.mean(difference * difference))
    return 10.0 * math.log10(PEAK * PEAK / mse) if mse > 0.0 else math.inf


def image_psnr(image) -> float:
    return psnr(image.radiance, image.reference, image.mask, image.scorer.k)


METRIC = Metric(name="psnr", column="psnr", label="PSNR", unit="dB", order=50, score=image_psnr,
                lower_is_better=False, default=False)
