"""Scores of one estimate against its reference: protocol ``lab-reinhard-v1`` of ARCHITECTURE.md §Conventions.

1. Exposure k = 0.18 / log-average luminance of the reference over covered pixels, applied to both.
2. Reinhard L/(1+L) on luminance, colour scaled by the same ratio.
3. Linear sRGB → XYZ (D65) → L*a*b*; mean ΔE76 and ΔE2000 over covered pixels.
Plus relMSE in linear HDR, mean((x−r)²/(r²+0.01)), flicker between consecutive frames (:func:`flicker`), HDR-FLIP (NVIDIA's flip-evaluator, where
installed; NaN otherwise) as a mean over covered pixels, and the sample counts.

Which metrics there are, and which a run computes where it names none, is the registry's
(:mod:`iblbench.harness.protocol.metric`, one descriptor per metric; ``iblbench run --metrics``
picks a subset); ΔE76 is always computed (heat maps, flicker and the budgets use it), and a metric
left out is NaN in its column.  Everything that depends on the reference alone (its exposure, its L*a*b*, FLIP's
exposure range) is computed once per reference by a :class:`Scorer`, which the runner keeps per
(scene, frame), and each estimate is then scored with one FLIP evaluation.

flip-evaluator is imported on first use, so importing this module (the CLI does, for
``PROTOCOL``) costs nothing.

Colour science in NumPy (:func:`to_lab`, :func:`lab_differences`; a deviation from ARCHITECTURE.md §Conventions,
which names colour-science): colour-science 0.4's ``RGB_to_XYZ``, ``XYZ_to_Lab`` and
``delta_E`` spent ~7.5 ms of host time per 128² estimate in input checks, domain scaling and
temporaries, about a third of a warm run's host time per cell (issue 10).  The same formulas
here take ~3 ms:

- sRGB → XYZ is IEC 61966-2-1's matrix as printed (4 decimals, the one colour-science uses), the
  white of L*a*b* D65's xy (0.3127, 0.3290) at Y = 1, and L*a*b* CIE 1976's (ε = 216/24389,
  κ = 24389/27);
- ΔE2000 is Sharma, Wu & Dalal (2005), rewritten without hue angles where they only enter
  through trigonometric functions: ΔH'² = Δa'² + Δb*² − ΔC'² (ΔH' = 2√(C'₁C'₂)·sin(Δh'/2)
  squared, by the law of cosines), its sign that of the hue vectors' cross product; the mean
  hue h̄' is the direction of the sum of the two unit hue vectors (the mean along the shorter
  arc, and the other hue where one chroma is 0, as the formula's cases say), T's cosines of
  multiples of h̄' come from the multiple-angle identities, and h̄' itself is needed only for
  Δθ.  At hues exactly opposite (|Δh'| = 180°, where the formula's h̄' jumps by 180°) the
  direction is undefined and h̄' = 0 is taken.

They agree with colour-science within 1e-5 ΔE on 10⁶ random pairs, near-opposite hues included
(``tests/test_metrics.py``).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from iblbench.harness.protocol import metric as registry
from iblbench.scenes.cubemap import luminance

PROTOCOL = "lab-reinhard-v1"
_LOG_EPSILON = 1e-6   # keeps black pixels out of log(0) in the log-average
_SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805],   # IEC 61966-2-1, as printed
                         [0.2126, 0.7152, 0.0722],
                         [0.0193, 0.1192, 0.9505]])
_D65_XYZ = np.array([0.3127 / 0.3290, 1.0, (1.0 - 0.3127 - 0.3290) / 0.3290])
_SRGB_TO_WHITE_RELATIVE_XYZ = (_SRGB_TO_XYZ / _D65_XYZ[:, None]).T   # rows: R, G, B
_LAB_EPSILON, _LAB_KAPPA = 216 / 24389, 24389 / 27
_25_POW_7 = 25.0 ** 7
_COS = {d: math.cos(math.radians(d)) for d in (6, 30, 63)}   # T's phase shifts
_SIN = {d: math.sin(math.radians(d)) for d in (6, 30, 63)}


@functools.lru_cache(maxsize=None)
def _flip():
    """NVIDIA's flip-evaluator module, or None where it is not installed (iblbench[flip])."""
    try:
        import flip_evaluator
    except ImportError:
        return None
    return flip_evaluator


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
    """CIE 1976 L*a*b* (D65 white) of display-referred linear sRGB ``[..., 3]``."""
    t = np.asarray(display_rgb, np.float64) @ _SRGB_TO_WHITE_RELATIVE_XYZ   # X/Xn, Y/Yn, Z/Zn
    f = np.where(t > _LAB_EPSILON, np.cbrt(t), (_LAB_KAPPA * t + 16.0) / 116.0)
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return np.stack([116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)], axis=-1)


def lab_differences(lab_a: np.ndarray, lab_b: np.ndarray,
                    de2000: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """ΔE76 and ΔE2000 (None when ``de2000`` is False) between L*a*b* arrays ``[..., 3]``."""
    lab_a, lab_b = np.asarray(lab_a, np.float64), np.asarray(lab_b, np.float64)
    difference = lab_b - lab_a
    de76 = np.sqrt(np.einsum("...i,...i->...", difference, difference))
    return de76, (delta_e2000(lab_a, lab_b) if de2000 else None)


def delta_e2000(lab_1: np.ndarray, lab_2: np.ndarray) -> np.ndarray:
    """CIEDE2000 (k_L = k_C = k_H = 1), Sharma, Wu & Dalal (2005), without hue angles where they
    only enter through trigonometric functions (module docstring)."""
    l1, a1, b1 = np.moveaxis(lab_1, -1, 0)
    l2, a2, b2 = np.moveaxis(lab_2, -1, 0)
    c7 = ((np.hypot(a1, b1) + np.hypot(a2, b2)) * 0.5) ** 7
    g = 1.5 - 0.5 * np.sqrt(c7 / (c7 + _25_POW_7))
    a1, a2 = g * a1, g * a2
    c1, c2 = np.hypot(a1, b1), np.hypot(a2, b2)
    delta_c = c2 - c1
    delta_h = np.copysign(np.sqrt(np.maximum((a2 - a1) ** 2 + (b2 - b1) ** 2 - delta_c ** 2,
                                             0.0)), a1 * b2 - a2 * b1)
    # The mean hue's unit vector: the sum of the unit hue vectors, normalised.
    inverse_1 = np.divide(1.0, c1, out=np.zeros_like(c1), where=c1 > 0)
    inverse_2 = np.divide(1.0, c2, out=np.zeros_like(c2), where=c2 > 0)
    x, y = a1 * inverse_1 + a2 * inverse_2, b1 * inverse_1 + b2 * inverse_2
    norm = np.hypot(x, y)
    zero = norm == 0   # both chromas 0 (h̄' = 0), or hues exactly opposite (undefined; 0)
    norm = np.where(zero, 1.0, norm)
    cos_1, sin_1 = np.where(zero, 1.0, x / norm), y / norm
    cos_2, sin_2 = 2.0 * cos_1 * cos_1 - 1.0, 2.0 * sin_1 * cos_1
    cos_3, sin_3 = cos_1 * (2.0 * cos_2 - 1.0), sin_1 * (2.0 * cos_2 + 1.0)
    cos_4, sin_4 = 2.0 * cos_2 * cos_2 - 1.0, 2.0 * sin_2 * cos_2
    t = (1.0 - 0.17 * (cos_1 * _COS[30] + sin_1 * _SIN[30]) + 0.24 * cos_2
         + 0.32 * (cos_3 * _COS[6] - sin_3 * _SIN[6])
         - 0.20 * (cos_4 * _COS[63] + sin_4 * _SIN[63]))
    mean_hue = np.degrees(np.arctan2(sin_1, cos_1)) % 360.0
    delta_theta = np.radians(30.0) * np.exp(-(((mean_hue - 275.0) / 25.0) ** 2))
    mean_c = (c1 + c2) * 0.5
    mean_c7 = mean_c ** 7
    r_t = -np.sin(2.0 * delta_theta) * 2.0 * np.sqrt(mean_c7 / (mean_c7 + _25_POW_7))
    lightness = ((l1 + l2) * 0.5 - 50.0) ** 2
    s_l = 1.0 + 0.015 * lightness / np.sqrt(20.0 + lightness)
    delta_l = (l2 - l1) / s_l
    delta_c = delta_c / (1.0 + 0.045 * mean_c)
    delta_h = delta_h / (1.0 + 0.015 * mean_c * t)
    return np.sqrt(delta_l ** 2 + delta_c ** 2 + delta_h ** 2 + r_t * delta_c * delta_h)


def delta_e_images(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray):
    """Per-pixel ΔE76 and ΔE2000 images (zero outside ``mask``)."""
    return Scorer(reference, mask).delta_e_images(estimate)


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
    """Mean HDR-FLIP error over covered pixels; NaN without flip-evaluator or on a black
    reference (see :meth:`Scorer.flip`)."""
    return Scorer(reference, mask, ("de76", "flip")).flip(estimate)


class Scorer:
    """Scores estimates against one reference (one scene and frame); what depends on the
    reference alone is computed once, here or on first use."""

    def __init__(self, reference: np.ndarray, mask: np.ndarray, metrics=None):
        self.reference, self.mask = reference, mask
        self.metrics = registry.default_names() if metrics is None else tuple(metrics)
        self.k = exposure(reference, mask)
        self._reference_lab = None
        self._flip_range = None

    @property
    def reference_lab(self) -> np.ndarray:
        if self._reference_lab is None:
            self._reference_lab = to_lab(tonemap(self.reference[self.mask], self.k))
        return self._reference_lab

    def delta_e_images(self, estimate: np.ndarray):
        """Per-pixel ΔE76 and ΔE2000 images (zero outside the mask; ΔE2000 None when left out)."""
        mask = self.mask
        de76 = np.zeros(mask.shape)
        de2000 = np.zeros(mask.shape) if "de2000" in self.metrics else None
        if mask.any():
            lab = to_lab(tonemap(estimate[mask], self.k))
            de76[mask], covered_2000 = lab_differences(lab, self.reference_lab, de2000 is not None)
            if de2000 is not None:
                de2000[mask] = covered_2000
        return de76, de2000

    def flip_range(self):
        """(peak reference luminance, FLIP's exposure parameters), from the covered pixels of
        the reference; None where FLIP cannot score (not installed, nothing covered, no finite
        positive peak)."""
        if self._flip_range is None:
            flip_evaluator = _flip()
            peak = float(luminance(self.reference[self.mask]).max()) if self.mask.any() else 0.0
            if flip_evaluator is None or not (math.isfinite(peak) and peak > 0.0):
                self._flip_range = (None,)
            else:
                covered = np.ascontiguousarray(self.reference[self.mask][None] / peak, np.float32)
                exposures = flip_evaluator.evaluate(covered, covered, "HDR", applyMagma=False,
                                                    computeMeanError=False)[2]
                self._flip_range = (peak, {key: exposures[key] for key in
                                           ("startExposure", "stopExposure", "numExposures")})
        return None if self._flip_range[0] is None else self._flip_range

    def flip(self, estimate: np.ndarray) -> float:
        """Mean HDR-FLIP error over covered pixels; NaN where :meth:`flip_range` is None.

        FLIP picks its exposure range from the reference's luminance; background pixels (zero)
        would stretch it, so the range is taken from the covered pixels alone.  A black or very
        dim reference makes that range degenerate, and FLIP then exits the whole process; the
        range follows any global scale, so both images are scaled to a peak reference luminance
        of 1, and a reference without a finite positive peak scores NaN.
        """
        flip_range = self.flip_range()
        if flip_range is None:
            return float("nan")
        peak, parameters = flip_range
        reference = np.ascontiguousarray(self.reference / peak, np.float32)
        error_map = _flip().evaluate(reference, np.ascontiguousarray(estimate / peak, np.float32),
                                     "HDR", applyMagma=False, parameters=parameters)[0]
        return float(error_map[..., 0][self.mask].mean())

    def _scores(self, image: "ScoredImage", replicated: bool) -> dict[str, float]:
        """Column → value of the registered metrics that are (or are not) ``replicated``; NaN for
        one this Scorer leaves out."""
        return {metric.column: float(metric.score(image)) if metric.name in self.metrics
                else float("nan") for metric in registry.registered()
                if metric.replicated == replicated}

    def errors(self, radiance: np.ndarray) -> tuple[dict[str, float], np.ndarray]:
        """The replicated metrics of one image (ΔE76, ΔE2000, relMSE, ...; NaN for a metric left
        out), and its ΔE76 image: what every timed render of a cell is scored on (its
        replicates; FLIP, at ~0.5 s an image, only on the scored render)."""
        image = ScoredImage(self, radiance)
        return self._scores(image, replicated=True), image.delta_e[0]

    def score(self, estimate) -> tuple[dict, np.ndarray]:
        """One results row's metrics for an :class:`Estimate` (every registered metric, the
        sample counts; non-finite values are counted in ``nonfinite``), and the ΔE76 image for a
        heat map."""
        mask = self.mask
        image = ScoredImage(self, estimate.radiance)
        used = float(estimate.used[mask].mean()) if mask.any() else 0.0
        effective = float(estimate.effective[mask].mean()) if mask.any() else 0.0
        row = {
            **self._scores(image, replicated=True),
            **self._scores(image, replicated=False),
            "flicker": float("nan"),   # set by the runner, which knows the previous frame
            "used_samples": used,
            "effective_samples": effective,
            "effective_ratio": effective / used if used > 0 else float("nan"),
            "evaluations": estimate.evaluations,
            "shadow_rays": estimate.shadow_rays,
            "nonfinite": estimate.nonfinite,
        }
        return row, image.delta_e[0]


class ScoredImage:
    """One estimate as a metric's ``score`` sees it: its radiance with non-finite values as black
    (so one NaN cannot hide the rest of the image's error), the :class:`Scorer` of its reference,
    and its ΔE76 and ΔE2000 images, computed once for every metric that reads them."""

    def __init__(self, scorer: Scorer, radiance: np.ndarray):
        self.scorer = scorer
        self.radiance = np.where(np.isfinite(radiance), radiance, 0.0)
        self.reference, self.mask = scorer.reference, scorer.mask
        self._delta_e = None

    @property
    def delta_e(self) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`Scorer.delta_e_images` of the image."""
        if self._delta_e is None:
            self._delta_e = self.scorer.delta_e_images(self.radiance)
        return self._delta_e


def score(estimate, reference: np.ndarray, mask: np.ndarray,
          metrics=None) -> tuple[dict, np.ndarray]:
    """:meth:`Scorer.score` against ``reference`` (a runner keeps one Scorer per frame;
    ``metrics``: the registry's default ones where None)."""
    return Scorer(reference, mask, metrics).score(estimate)
