"""PNG previews of HDR images and ΔE heat maps (written atomically).

Heat maps draw ΔE76 per pixel on one logarithmic scale, HEAT_MIN (black) to HEAT_MAX (pale
yellow) in inferno, shared by every estimator and every run.  Shared, so that two estimators'
maps compare by colour alone (a per-estimator scale would paint an error of 0.4 and one of 7
alike); logarithmic, because the estimators' errors span decades: at equal spp on sphere-sun
balanced_mis's pixels lie at ΔE76 0.1-2 and uniform's at 1-36, and the linear 0-20 scale used
before showed balanced_mis as solid black.  HEAT_MIN lies far below a visible difference (the
just-noticeable ΔE76 is about 2.3: Mahy, Van Eycken and Oosterlinck 1994; JND_DE76) and
HEAT_MAX above any pixel we have measured.  Uncovered pixels (ΔE 0) are black like errors at or
below HEAT_MIN.  Each heat map carries its scale (HEAT_SCALE) in a PNG text chunk (HEAT_TAG), so
a report redraws maps drawn on another scale by an older version.  ``iblbench report`` draws
these PNGs from the run's EXRs (:class:`iblbench.reports.images.FramePreviews`); the run writes
none.
"""
from __future__ import annotations

import matplotlib
import numpy as np
from PIL import Image, PngImagePlugin

from iblbench.harness.protocol.metrics import tonemap
from iblbench.foundation.atomic import atomic_path

HEAT_MIN = 0.1     # ΔE76 at the bottom (black) of the heat maps' log scale; less is shown as it
HEAT_MAX = 100.0   # ΔE76 at the top (pale yellow); more is shown as it
HEAT_CMAP = "inferno"
HEAT_SCALE = f"log ΔE76 {HEAT_MIN:g}..{HEAT_MAX:g} {HEAT_CMAP}"
HEAT_TAG = "iblbench-heat-scale"
JND_DE76 = 2.3     # just-noticeable ΔE76 (Mahy et al. 1994), marked on the colour bar
# zlib level 1 writes a 128² preview 3-5x faster than the default (6), about as small (measured:
# 47 kB against 45 kB; a heat map 40 kB against 48 kB).
PNG_COMPRESS_LEVEL = 1


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def _write_png(path, pixels: np.ndarray, text: dict[str, str] | None = None) -> None:
    """8-bit RGB ``[H, W, 3]`` values in [0, 1] or uint8 as a PNG, atomically, with ``text``
    as tEXt chunks."""
    if pixels.dtype != np.uint8:
        pixels = (np.clip(pixels, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    info = PngImagePlugin.PngInfo()
    for key, value in (text or {}).items():
        info.add_text(key, value)
    with atomic_path(path) as tmp:
        Image.fromarray(pixels).save(tmp, format="png", compress_level=PNG_COMPRESS_LEVEL,
                                     pnginfo=info)


def write_preview(path, radiance: np.ndarray, k: float) -> None:
    """Tone-mapped (protocol exposure ``k``, Reinhard) sRGB preview of a linear HDR image."""
    _write_png(path, srgb_encode(tonemap(np.where(np.isfinite(radiance), radiance, 0.0), k)))


def heat_norm() -> matplotlib.colors.LogNorm:
    """ΔE76 → [0, 1] of the heat maps' colormap: log scale from HEAT_MIN to HEAT_MAX, clipped."""
    return matplotlib.colors.LogNorm(vmin=HEAT_MIN, vmax=HEAT_MAX, clip=True)


def write_heat_map(path, delta_e: np.ndarray) -> None:
    """ΔE76 per pixel on the shared log scale (module docstring), tagged with HEAT_SCALE."""
    colormap = matplotlib.colormaps[HEAT_CMAP]
    _write_png(path, colormap(heat_norm()(delta_e), bytes=True)[..., :3],
               text={HEAT_TAG: HEAT_SCALE})


def heat_scale(path) -> str | None:
    """The scale a heat map PNG was drawn on (HEAT_SCALE today); None for an untagged or an
    unreadable one."""
    try:
        with Image.open(path) as image:
            return image.text.get(HEAT_TAG)
    except OSError:   # PIL's UnidentifiedImageError too
        return None
