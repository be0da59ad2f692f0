"""PNG previews and ΔE heat maps (reports/previews.py), against values worked out by hand."""
from __future__ import annotations

import numpy as np
from PIL import Image

from iblbench.reports.previews import HEAT_MAX, write_heat_map, write_preview


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


def test_heat_map_runs_from_inferno_black_to_its_pale_yellow_at_heat_max(tmp_path):
    delta_e = np.array([[0.0, HEAT_MAX, 3 * HEAT_MAX]])
    write_heat_map(tmp_path / "h.png", delta_e)
    pixels = np.asarray(Image.open(tmp_path / "h.png"))
    # inferno's ends: #000004 and #fcffa4 (±1: matplotlib truncates to 8 bits); ΔE above
    # HEAT_MAX is shown as HEAT_MAX.
    expected = [[[0, 0, 4], [252, 255, 164], [252, 255, 164]]]
    assert pixels.shape == (1, 3, 3) and np.abs(pixels - np.array(expected)).max() <= 1
