"""PNG previews and ΔE heat maps (reports/previews.py), against values worked out by hand."""
from __future__ import annotations

import math

import matplotlib
import numpy as np
from PIL import Image

from iblbench.reports.previews import (HEAT_MAX, HEAT_MIN, HEAT_SCALE, heat_scale,
                                       write_heat_map, write_preview)


def test_preview_is_the_reinhard_tone_mapped_srgb_of_the_protocol(tmp_path):
    radiance = np.zeros((2, 3, 3), np.float32)
    radiance[0, 0] = 1.0              # grey, Y = 1: k·Y/(1 + k·Y) = 0.5 at k = 1
    radiance[0, 1] = [3.0, 3.0, 3.0]  # Y = 3: 0.75
    radiance[1, 2] = np.nan           # non-finite: black
    write_preview(tmp_path / "p.png", radiance, 1.0)
    pixels = np.asarray(Image.open(tmp_path / "p.png"))
    srgb = lambda v: 1.055 * v ** (1 / 2.4) - 0.055
    assert pixels.shape == (2, 3, 3) and pixels.dtype == np.uint8
    assert (pixels[0, 0] == round(255 * srgb(0.5))).all()      # 188
    assert (pixels[0, 1] == round(255 * srgb(0.75))).all()     # 225
    assert (pixels[1] == 0).all() and [p.name for p in tmp_path.iterdir()] == ["p.png"]


def test_heat_map_is_inferno_on_a_log_scale_from_0_1_to_100(tmp_path):
    assert (HEAT_MIN, HEAT_MAX) == (0.1, 100.0)
    # Colormap fractions log10(ΔE / 0.1) / 3, worked by hand; 0 (an uncovered pixel) and ΔE
    # below 0.1 at the bottom, above 100 at the top.
    delta_e = np.array([[0.0, 0.05, 0.1, 1.0, math.sqrt(10.0), 100.0, 1e4]])
    fractions = np.array([0.0, 0.0, 0.0, 1 / 3, 0.5, 1.0, 1.0])
    write_heat_map(tmp_path / "h.png", delta_e)
    pixels = np.asarray(Image.open(tmp_path / "h.png")).astype(int)
    expected = matplotlib.colormaps["inferno"](fractions, bytes=True)[..., :3]
    assert pixels.shape == (1, 7, 3) and np.abs(pixels[0] - expected).max() <= 1
    # inferno's ends: #000004 and #fcffa4 (±1: matplotlib truncates to 8 bits).
    assert np.abs(pixels[0, [0, -1]] - [[0, 0, 4], [252, 255, 164]]).max() <= 1


def test_the_best_estimators_error_is_not_black(tmp_path):
    """Issue 11: balanced_mis at ΔE76 about 0.4 was solid black on the linear 0-20 scale.  On
    the log scale 0.4 and 0.8 are visibly apart, and both apart from black."""
    write_heat_map(tmp_path / "h.png", np.array([[0.0, 0.4, 0.8]]))
    black, low, high = np.asarray(Image.open(tmp_path / "h.png")).astype(int)[0]
    assert np.linalg.norm(low - black) >= 30 and np.linalg.norm(high - low) >= 30   # of 441


def test_heat_maps_carry_their_scale(tmp_path):
    write_heat_map(tmp_path / "h.png", np.zeros((2, 2)))
    assert heat_scale(tmp_path / "h.png") == HEAT_SCALE
    write_preview(tmp_path / "p.png", np.zeros((2, 2, 3)), 1.0)      # an untagged PNG
    assert heat_scale(tmp_path / "p.png") is None
    (tmp_path / "broken.png").write_bytes(b"not a PNG")
    assert heat_scale(tmp_path / "broken.png") is None
