"""A photograph's light taken out of the photograph, and put back where a sequence wants it
(issue 24: photographed sequences whose light moves or switches).

Separation (:func:`separate`), on the lat-long image as read (Debevec's convention,
:mod:`iblbench.scenes.envmap`):

- **The light** is every pixel whose Rec.709 luminance is at least ``threshold`` and whose centre
  lies within ``cap_deg`` of the brightest pixel's: the lamp or sun that carries the map's power,
  and not another bright thing elsewhere in the picture.
- **The remainder** is the photograph with the light's pixels filled by the *harmonic*
  interpolation of the pixels around them: per channel, the solution of Laplace's equation on the
  hole (4-neighbour, wrapping in azimuth) whose boundary values are the unmasked neighbours.  It
  is the smoothest continuation of the surrounding sky or wall into the hole, and by the maximum
  principle it never exceeds its boundary, so no remainder pixel of the hole reaches
  ``threshold`` (every boundary pixel lies below it).
- **The light layer** is what the fill took away: per light pixel, max(image − fill, 0) times
  the pixel's solid angle (2π/W · (cos θ_top − cos θ_bottom)), its power in Σ L·Ω.  The clamp
  at 0 drops only channels where the fill is brighter than the photograph, which no light pixel
  of the shipped maps is (the light is ≥ ``threshold``, its boundary below).

Placement (:func:`light_cube`): each light pixel is split into ``SPLAT_SUBPIXELS``² points on
its (u, v) grid, each carrying an equal share of the pixel's power; the points are turned about
+Y by the frame's azimuth (sky azimuth grows: 0 → +Z, 90° → +X, as in :mod:`.sky`) and splatted
into the cube texel each falls in, divided by that texel's solid angle.  So Σ L·Ω of the placed
light is the light layer's power at every azimuth and cube resolution, to float rounding, and
the light moves continuously (by any angle, not whole columns).  A frame is the remainder
resampled to the cube (:func:`envmap.resample_latlong`, once) plus the placed light, so its
Σ Y·Ω is the same in every frame: the light adds to the wall or sky it passes over instead of
hiding it, a liberty worth at most the background under it (a 0.2 luminance under the studio
light's 10³, the park's 10 under its 10⁴).
"""
from __future__ import annotations

import dataclasses
import functools

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from . import cubemap
from .imageio import read_image

SPLAT_SUBPIXELS = 4   # points per light pixel side: the light's footprint is smooth at 64² faces


@dataclasses.dataclass(frozen=True)
class SeparatedLight:
    """A photograph split into its light and the rest (module docstring)."""
    remainder: np.ndarray    # [H, W, 3] float64: the photograph with the light filled
    mask: np.ndarray         # [H, W] bool: the light's pixels
    points: np.ndarray       # [n·k², 3] unit directions of the light's splat points (azimuth 0)
    point_power: np.ndarray  # [n·k², 3] Σ L·Ω each point carries

    @property
    def power(self) -> float:
        """The light layer's Σ Y·Ω."""
        return float(cubemap.luminance(self.point_power).sum())


def latlong_directions(rows: np.ndarray, cols: np.ndarray, height: int, width: int) -> np.ndarray:
    """Unit directions ``[..., 3]`` of (fractional) pixel coordinates of a lat-long image, pixel
    (r, c) covering [r, r + 1) × [c, c + 1): θ = π·v from +Y, φ = 2π·(u − ½), direction
    (sin θ sin φ, cos θ, −sin θ cos φ) (:mod:`.envmap`)."""
    theta = np.pi * np.asarray(rows, np.float64) / height
    phi = 2.0 * np.pi * (np.asarray(cols, np.float64) / width - 0.5)
    return np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)],
                    axis=-1)


def latlong_solid_angles(height: int, width: int) -> np.ndarray:
    """The solid angle of one pixel of each row ``[H]`` of a lat-long image."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (2.0 * np.pi / width) * (edges[:-1] - edges[1:])


def light_mask(image: np.ndarray, threshold: float, cap_deg: float) -> np.ndarray:
    """The light's pixels: luminance ≥ ``threshold`` within ``cap_deg`` of the brightest pixel."""
    height, width = image.shape[:2]
    luminance = cubemap.luminance(np.asarray(image, np.float64))
    rows, cols = np.mgrid[0:height, 0:width] + 0.5
    centres = latlong_directions(rows, cols, height, width)
    brightest = centres[np.unravel_index(np.argmax(luminance), luminance.shape)]
    return (luminance >= threshold) & (centres @ brightest >= np.cos(np.radians(cap_deg)))


def harmonic_fill(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``image`` with the pixels of ``mask`` replaced by the harmonic interpolation of their
    unmasked neighbours (module docstring): for every masked pixel p, per channel,
    4·x_p − Σ_{masked q ~ p} x_q = Σ_{unmasked q ~ p} image_q, neighbours wrapping in azimuth and
    clamped at the poles (a pole row's missing neighbour is the pixel itself)."""
    height, width = mask.shape
    filled = np.array(image, np.float64)
    hole = np.flatnonzero(mask)
    if hole.size == 0:
        return filled
    unknown = np.full(mask.size, -1)
    unknown[hole] = np.arange(hole.size)
    row, col = np.divmod(hole, width)
    rhs = np.zeros((hole.size, filled.shape[2]))
    entries = [(np.arange(hole.size), np.arange(hole.size), np.full(hole.size, 4.0))]
    flat = filled.reshape(-1, filled.shape[2])
    for d_row, d_col in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        neighbour = np.clip(row + d_row, 0, height - 1) * width + (col + d_col) % width
        inside = unknown[neighbour] >= 0
        entries.append((np.flatnonzero(inside), unknown[neighbour[inside]],
                        np.full(int(inside.sum()), -1.0)))
        rhs[~inside] += flat[neighbour[~inside]]
    rows_, cols_, values = (np.concatenate(part) for part in zip(*entries))
    system = scipy.sparse.csc_matrix((values, (rows_, cols_)), shape=(hole.size, hole.size))
    flat[hole] = scipy.sparse.linalg.splu(system).solve(rhs)
    return filled


@functools.lru_cache(maxsize=4)
def separate(path: str, threshold: float, cap_deg: float) -> SeparatedLight:
    """The photograph at ``path`` (lat-long) split into its light and the rest."""
    image = np.asarray(read_image(path), np.float64)
    height, width = image.shape[:2]
    mask = light_mask(image, threshold, cap_deg)
    remainder = harmonic_fill(image, mask)
    row, col = np.nonzero(mask)
    power = (np.maximum(image[row, col] - remainder[row, col], 0.0)
             * latlong_solid_angles(height, width)[row, None])
    offsets = (np.arange(SPLAT_SUBPIXELS) + 0.5) / SPLAT_SUBPIXELS
    sub_row = row[:, None, None] + offsets[None, :, None]
    sub_col = col[:, None, None] + offsets[None, None, :]
    points = latlong_directions(*np.broadcast_arrays(sub_row, sub_col), height, width)
    share = np.repeat(power / SPLAT_SUBPIXELS ** 2, SPLAT_SUBPIXELS ** 2, axis=0)
    for array in (remainder, mask):
        array.flags.writeable = False
    return SeparatedLight(remainder, mask, points.reshape(-1, 3), share)


def turned(directions: np.ndarray, azimuth_deg: float) -> np.ndarray:
    """``directions`` turned about +Y so that each one's sky azimuth (atan2(x, z)) grows by
    ``azimuth_deg``."""
    a = np.radians(azimuth_deg)
    x, y, z = np.moveaxis(directions, -1, 0)
    return np.stack([x * np.cos(a) + z * np.sin(a), y, z * np.cos(a) - x * np.sin(a)], axis=-1)


def light_cube(light: SeparatedLight, res: int, azimuth_deg: float) -> np.ndarray:
    """The light layer turned by ``azimuth_deg`` and splatted into a float64 cube map
    ``[6, res, res, 3]`` (module docstring): its Σ L·Ω is the layer's at every azimuth."""
    face, row, col = cubemap.direction_to_texel(turned(light.points, azimuth_deg), res)
    power = np.zeros((6, res, res, 3))
    np.add.at(power, (face, row, col), light.point_power)
    return power / cubemap.texel_solid_angles(res)[None, :, :, None]
