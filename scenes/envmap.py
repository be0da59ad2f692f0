"""Load an environment image (lat-long, cross or six faces) as a cube map ``[6, R, R, 3]``.

The cube map follows :mod:`iblbench.scenes.cubemap` (faces +X, −X, +Y, −Y, +Z, −Z; OpenGL
face table; rows grow downward).

Lat-long (equirectangular, aspect 2:1)
    Pixel (0, 0) is the top-left corner; u, v ∈ [0, 1] run across columns and down rows.
    Polar angle θ = π·v from +Y (up) at the top row; azimuth φ = 2π·(u − 0.5);
    direction = (sin θ sin φ, cos θ, −sin θ cos φ). The image centre looks toward −Z,
    u = 0.75 toward +X and u = 0.25 toward −X: the inside view of a right-handed, Y-up frame
    with forward = −Z at the centre, as in Debevec's light probes (https://www.debevec.org/probes/).
    Mitsuba 3's ``envmap`` (src/emitters/envmap.cpp: u = atan2(x, −z)/2π, v = acos(y)/π) has
    the same handedness and v but puts u = 0 at −Z: its image is this one rolled by half its
    width (a 180° turn about +Y).

Crosses (unfolded cube, seen from inside; HDRShop's and Debevec's light-probe layout)
    ``vcross`` (3 faces wide × 4 tall) and ``hcross`` (4 wide × 3 tall), in face-sized cells
    (column, row): +Y at (1, 0); −X, −Z, +X at (0, 1), (1, 1), (2, 1); −Y at (1, 2); +Z at
    (1, 3) in the vertical cross, or at (3, 1) in the horizontal one.  Each cell is what a
    viewer at the centre sees through that face of the cube, in the same right-handed frame
    as the lat-long: the middle row reads left, front, right (−X, −Z, +X; +X to the right of
    the front), the top cell's bottom edge and the bottom cell's top edge meet the front, and
    the vertical cross's +Z cell hangs upside down below −Y (its top edge meets −Y's bottom
    edge).  So a lat-long and a cross of one panorama give the same cube map, and the cross is
    the lat-long's picture unmirrored.  Source: the vertical-cross image-to-direction mapping of
    Reinhard, Ward, Pattanaik and Debevec, *High Dynamic Range Imaging* (2005), §9.4.4 (quoted
    by G. Ward on radiance-general, 13 June 2010), which is HDRShop's "Cubic Environment
    (Vertical Cross)" and the layout of the crosses in Debevec's Light Probe Image Gallery
    (https://www.debevec.org/probes/): forward = −Z at the centre, x growing to the right on
    the front, up and down cells, and y growing downward on the +Z cell.  (The OpenGL
    cube-map layout, +Z at the centre with the faces as stored, is the mirror image in z.)
    With ``layout = "auto"`` a 3:4 or 4:3 image is taken as a cross only when its six unused
    cells are black (every channel ≤ :data:`BLACK_LEVEL` × the mean of the used cells), since
    a 3:4 crop of a lat-long has the same aspect; otherwise the layout must be given.  Unused
    cells must hold valid texels either way.

Face files (``faces``, and ``.npy`` cube maps)
    Read as stored: the cube map itself (:mod:`~iblbench.scenes.cubemap`, the OpenGL face
    table, as GPU cube maps and ``iblbench run --save-inputs`` keep them): face +X's columns
    run toward −Z and its rows toward −Y, and so on.  Shown as pictures they are inside views
    of a left-handed frame, each the mirror image of its cross cell.

Resampling (lat-long, or a cube at another resolution)
    Each cube texel is the solid-angle-weighted mean of an n×n grid of sub-texel samples
    (the box filter over the texel, by quadrature): weights are the exact sub-cell solid
    angles, so a constant map stays exactly constant. Lat-long samples are bilinear
    (wrapping in φ, clamped at the poles); cube samples are nearest (the map is piecewise
    constant), which makes integer-factor cube downsampling exactly energy-preserving.
    n is chosen so samples are at most a quarter of a source pixel apart at face centres.
    The default lat-long R is H/2 rounded to a power of two, at most 512: texels then match
    the lat-long pixels at the equator.

Validation
    NaN, ±Inf, negative texels and texels above :data:`MAX_RADIANCE` are refused unless
    ``sanitize=True``, which replaces NaN, −Inf and negatives by 0, and +Inf and values above
    :data:`MAX_RADIANCE` by the largest valid value of the map.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Callable, Sequence, Union

import numpy as np

from . import cubemap
from iblbench.foundation.errors import InputError, argument
from .imageio import read_image

LAYOUTS = ("auto", "latlong", "vcross", "hcross", "faces")
FACE_FILE_NAMES = ("px", "nx", "py", "ny", "pz", "nz")
MAX_DEFAULT_RES = 512
MAX_RES = 4096   # a 4096² cube map is 1.2 GB of float32; larger ones exhaust memory
# Brighter texels make float32 sums and weights on the device overflow (near 1e35 in a 4² map);
# real maps stay below about 1e10.
MAX_RADIANCE = 1e20
MAX_SUBSAMPLES = 16
_SAMPLES_PER_SOURCE_PIXEL = 4  # sub-texel samples per source pixel width (per axis)
_SAMPLES_PER_BATCH = 1 << 20  # bounds temporary memory

# With layout "auto", a 3:4 or 4:3 image is a cross only if no unused cell's channel exceeds
# BLACK_LEVEL × the mean of the used cells (real crosses hold exact zeros there).
BLACK_LEVEL = 1e-3

# Cell (column, row) of each face, in face order (module docstring; HDR Imaging §9.4.4).
_CROSS_CELLS = {
    "hcross": ((2, 1), (0, 1), (1, 0), (1, 2), (3, 1), (1, 1)),
    "vcross": ((2, 1), (0, 1), (1, 0), (1, 2), (1, 3), (1, 1)),
}
_X, _Y, _Z = np.eye(3, dtype=np.int64)
# The directions in which each face's cell grows (to the right, downward), in face order.
_CELL_AXES = {
    "vcross": ((_Z, -_Y), (-_Z, -_Y), (_X, -_Z), (_X, _Z), (_X, _Y), (_X, -_Y)),
    "hcross": ((_Z, -_Y), (-_Z, -_Y), (_X, -_Z), (_X, _Z), (-_X, -_Y), (_X, -_Y)),
}
_CROSS_SHAPE = {"hcross": (3, 4), "vcross": (4, 3)}  # (rows, columns) of face cells
_ASPECT_NAMES = {"hcross": "horizontal cross", "vcross": "vertical cross"}

PathLike = Union[str, os.PathLike]
Source = Union[PathLike, Sequence[PathLike]]


@dataclass(frozen=True)
class EnvironmentReport:
    """What :func:`load_environment` did."""

    layout: str  # "latlong", "vcross", "hcross" or "faces"
    paths: tuple[str, ...]  # the file(s) read
    source_size: tuple[int, int]  # (width, height) of the image (of one face for "faces")
    resolution: int  # R of the cube map returned
    texels_fixed: int  # source texels replaced by sanitize


def load_environment(
    source: Source, layout: str = "auto", res: int | None = None, sanitize: bool = False
) -> tuple[np.ndarray, EnvironmentReport]:
    """Load ``source`` as a float32 cube map ``[6, R, R, 3]`` and a report.

    ``source`` is one image path, six face paths (+X, −X, +Y, −Y, +Z, −Z), or a path with
    ``{face}`` standing for px, nx, py, ny, pz, nz, or a ``.npy`` cube map ``[6, R, R, 3]`` (as
``iblbench run --save-inputs`` writes).  ``layout`` is one of :data:`LAYOUTS`.
    ``res`` sets R (default: the faces' own size, or the lat-long rule in the module doc).
    """
    if layout not in LAYOUTS:
        raise InputError(None, f"unknown layout '{layout}' (choose from {', '.join(LAYOUTS)})")
    if res is not None and (not isinstance(res, (int, np.integer)) or not 1 <= res <= MAX_RES):
        raise InputError(None, f"cube-map resolution must be an integer in 1..{MAX_RES}, got {res!r}")
    paths, requested = _source_paths(source), layout
    if len(paths) == 1 and os.fspath(paths[0]).lower().endswith(".npy"):
        images, paths = _read_cube_npy(paths[0]), paths * 6
    else:
        images = [read_image(path) for path in paths]
    if len(paths) == 6:
        layout = _check_faces(paths, images, layout)
    else:
        layout = _check_single_layout(paths[0], images[0], layout)
    fixed = _validate_texels(paths, images, sanitize)
    if requested == "auto" and layout in _CROSS_CELLS:
        _require_black_unused_cells(paths[0], images[0], layout)
    env = _to_cube(images, layout, res)
    height, width = images[0].shape[:2]
    report = EnvironmentReport(layout, tuple(map(str, paths)), (width, height), env.shape[1], fixed)
    return env, report


def resample_latlong(image: np.ndarray, res: int) -> np.ndarray:
    """Resample a lat-long image ``[H, 2H, 3]`` to a float32 cube map ``[6, res, res, 3]``."""
    image = np.asarray(image, dtype=np.float32)
    height = image.shape[0]

    def lookup(face, s, t):
        return _bilinear_latlong(image, cubemap.face_st_to_direction(face, s, t))

    return _resample_to_cube(lookup, res, _subsamples(height / 2, res))


def default_latlong_res(height: int) -> int:
    """H/2 rounded to the nearest power of two, capped at :data:`MAX_DEFAULT_RES`."""
    return min(MAX_DEFAULT_RES, 2 ** max(0, round(math.log2(max(height / 2, 1)))))


# --- source paths and layout checks ---------------------------------------------------

def _source_paths(source: Source) -> list[PathLike]:
    if isinstance(source, (str, os.PathLike)):
        text = os.fspath(source)
        if "{face}" in text:
            return [text.replace("{face}", name) for name in FACE_FILE_NAMES]
        return [source]
    paths = list(source)
    if len(paths) != 6:
        raise InputError(None, f"expected one image or six face files (+X,-X,+Y,-Y,+Z,-Z), got {len(paths)}")
    return paths


def _read_cube_npy(path: PathLike) -> list[np.ndarray]:
    """The six faces of a cube map saved with numpy as ``[6, R, R, 3]`` floats."""
    try:
        cube = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except (OSError, ValueError) as error:
        raise InputError(path, f"cannot read .npy cube map ({error})") from None
    if cube.ndim != 4 or cube.shape[0] != 6 or cube.shape[3] != 3:
        raise InputError(path, f"a .npy cube map must have shape [6, R, R, 3], got {list(cube.shape)}")
    if not np.issubdtype(cube.dtype, np.floating):
        raise InputError(path, f"a .npy cube map must hold floats, got {cube.dtype}")
    return [face.astype(np.float32) for face in cube]


def _check_faces(paths, images, layout: str) -> str:
    if layout not in ("auto", "faces"):
        raise InputError(paths[0], f"layout '{layout}' takes one image, not six face files")
    size = images[0].shape[:2]
    for path, image in zip(paths, images):
        height, width = image.shape[:2]
        if height != width:
            raise InputError(path, f"cube face is not square ({width}x{height})")
        if image.shape[:2] != size:
            raise InputError(path, f"face is {width}x{height} but {paths[0]} is {size[1]}x{size[0]}")
    return "faces"


def _check_single_layout(path, image: np.ndarray, layout: str) -> str:
    height, width = image.shape[:2]
    by_aspect = {(2, 1): "latlong", (3, 4): "vcross", (4, 3): "hcross"}
    aspect = next((a for a in by_aspect if width * a[1] == height * a[0]), None)
    if layout == "faces":
        raise InputError(path, "layout 'faces' needs six face files (a list or a path with {face})")
    if layout == "auto":
        if aspect is None:
            raise InputError(
                path,
                f"aspect ratio {width}x{height} matches no cube-map layout (lat-long 2:1, "
                "vertical cross 3:4, horizontal cross 4:3, or six face files)",
            )
        return by_aspect[aspect]
    if by_aspect.get(aspect) != layout:
        wanted = next(f"{a[0]}:{a[1]}" for a, name in by_aspect.items() if name == layout)
        raise InputError(path, f"layout '{layout}' needs aspect {wanted}, but the image is {width}x{height}")
    return layout


# --- texel validation -------------------------------------------------------------------

def _validate_texels(paths, images: list[np.ndarray], sanitize: bool) -> int:
    """Refuse (or, with ``sanitize``, fix in place) NaN, Inf, too bright and negative texels.

    Each bad texel is counted once, in the first matching class: NaN, Inf, above
    :data:`MAX_RADIANCE`, negative.  Returns the number of texels fixed.
    """
    masks = [_bad_texel_masks(image) for image in images]
    if not sanitize:
        for path, (nan, inf, bright, negative) in zip(paths, masks):
            if nan.any() or inf.any() or bright.any() or negative.any():
                too_bright = f", {bright.sum()} above {MAX_RADIANCE:g}" if bright.any() else ""
                raise InputError(
                    path,
                    f"{nan.sum()} NaN, {inf.sum()} Inf{too_bright} and {negative.sum()} negative "
                    f"texels; pass {argument('sanitize', True)} to replace them",
                )
        return 0
    valid_max = max(float(image[np.isfinite(image) & (image <= MAX_RADIANCE)].max(initial=0.0))
                    for image in images)
    for image in images:
        np.nan_to_num(image, copy=False, nan=0.0, neginf=0.0)   # +Inf becomes the float32 max
        image[image > MAX_RADIANCE] = valid_max
        np.maximum(image, 0.0, out=image)
    return sum(int(mask.sum()) for texel_masks in masks for mask in texel_masks)


def _bad_texel_masks(image: np.ndarray) -> tuple[np.ndarray, ...]:
    """Masks of NaN, Inf, too bright and negative texels, each texel in the first it matches."""
    nan = np.isnan(image).any(axis=-1)
    inf = np.isinf(image).any(axis=-1) & ~nan
    bright = (image > MAX_RADIANCE).any(axis=-1) & ~nan & ~inf
    negative = (image < 0).any(axis=-1) & ~nan & ~inf & ~bright
    return nan, inf, bright, negative


# --- conversion to a cube map -----------------------------------------------------------

def _to_cube(images: list[np.ndarray], layout: str, res: int | None) -> np.ndarray:
    if layout == "latlong":
        image = images[0]
        return resample_latlong(image, res or default_latlong_res(image.shape[0]))
    faces = np.stack(images) if layout == "faces" else _extract_cross_faces(images[0], layout)
    if res is None or res == faces.shape[1]:
        return faces
    return _resample_cube(faces, res)


def _cross_cells(cross: np.ndarray, layout: str) -> list[np.ndarray]:
    """The 12 face-sized cells of a cross, row by row; the used ones at :data:`_CROSS_CELLS`."""
    rows, columns = _CROSS_SHAPE[layout]
    size = cross.shape[0] // rows
    return [cross[row * size:(row + 1) * size, column * size:(column + 1) * size]
            for row in range(rows) for column in range(columns)]


def _extract_cross_faces(cross: np.ndarray, layout: str) -> np.ndarray:
    """The cube map of a cross: each face's texels, fetched from its cell (exact, no resampling).

    Face texel (row i, column j) looks along u·U + v·V + W (the cube-map basis); its cell pixel
    is found by projecting that direction on the cell's rightward and downward axes.  The axes
    are ± U or ± V, so each face is its cell transposed and/or flipped.
    """
    cells = _cross_cells(cross, layout)
    columns = _CROSS_SHAPE[layout][1]
    size = cells[0].shape[0]
    rows_of_face, columns_of_face = np.indices((size, size))
    faces = np.empty((6, size, size, 3), dtype=np.float32)
    for face, ((column, row), axes) in enumerate(zip(_CROSS_CELLS[layout], _CELL_AXES[layout])):
        face_u, face_v, _ = cubemap.face_basis(face).astype(np.int64)

        def cell_index(axis):
            grid, sign = ((columns_of_face, axis @ face_u) if axis @ face_u
                          else (rows_of_face, axis @ face_v))
            return grid if sign > 0 else size - 1 - grid

        right, down = axes
        faces[face] = cells[row * columns + column][cell_index(down), cell_index(right)]
    return faces


def _require_black_unused_cells(path, cross: np.ndarray, layout: str) -> None:
    """Refuse an auto-detected cross whose unused cells are not black (a cropped lat-long?)."""
    columns = _CROSS_SHAPE[layout][1]
    used = {row * columns + column for column, row in _CROSS_CELLS[layout]}
    cells = _cross_cells(cross, layout)
    used_mean = float(np.mean([cells[k].mean(dtype=np.float64) for k in sorted(used)]))
    unused_max = max(float(cells[k].max()) for k in range(len(cells)) if k not in used)
    if unused_max > BLACK_LEVEL * used_mean:
        height, width = cross.shape[:2]
        raise InputError(
            path,
            f"a {width}x{height} image has a {_ASPECT_NAMES[layout]}'s aspect, but its six unused "
            f"cells are not black (up to {unused_max:.3g}, against a mean of {used_mean:.3g} in "
            f"the used ones; black means at most {BLACK_LEVEL:g}× that); set the environment's "
            f"layout explicitly (layout = \"{layout}\" to read it as a cross anyway)",
        )


def _resample_cube(faces: np.ndarray, res: int) -> np.ndarray:
    source_res = faces.shape[1]

    def lookup(face, s, t):
        col = np.minimum((s * source_res).astype(np.int64), source_res - 1)
        row = np.minimum((t * source_res).astype(np.int64), source_res - 1)
        return faces[face, row, col]

    return _resample_to_cube(lookup, res, _subsamples(source_res, res))


def _subsamples(source_pixels_per_face: float, res: int) -> int:
    """Sub-texel grid size n: samples ≤ 1/_SAMPLES_PER_SOURCE_PIXEL source pixel apart."""
    wanted = math.ceil(_SAMPLES_PER_SOURCE_PIXEL * source_pixels_per_face / res)
    return int(min(MAX_SUBSAMPLES, max(2, wanted)))


def _resample_to_cube(
    lookup: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray], res: int, n: int
) -> np.ndarray:
    """Box-filter ``lookup(face, s, t) -> rgb`` over each texel with n×n weighted samples."""
    fine = res * n
    weights = cubemap.texel_solid_angles(fine)  # exact solid angle of each sub-cell
    texel_weights = weights.reshape(res, n, res, n).sum(axis=(1, 3))
    centres = (np.arange(fine) + 0.5) / fine
    texel_rows_per_batch = max(1, _SAMPLES_PER_BATCH // (fine * n))
    env = np.empty((6, res, res, 3), dtype=np.float32)
    for face in range(6):
        for first in range(0, res, texel_rows_per_batch):
            texel_rows = slice(first, min(res, first + texel_rows_per_batch))
            rows = slice(texel_rows.start * n, texel_rows.stop * n)
            t, s = np.meshgrid(centres[rows], centres, indexing="ij")
            weighted = lookup(np.full(s.shape, face), s, t) * weights[rows, :, None]
            texel_sums = weighted.reshape(-1, n, res, n, 3).sum(axis=(1, 3))
            env[face, texel_rows] = texel_sums / texel_weights[texel_rows, :, None]
    return env


def _bilinear_latlong(image: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a lat-long image at unit ``directions`` (wraps in φ, clamps at poles)."""
    height, width = image.shape[:2]
    x, y, z = directions[..., 0], directions[..., 1], directions[..., 2]
    u = np.arctan2(x, -z) / (2 * np.pi) + 0.5
    v = np.arccos(np.clip(y, -1.0, 1.0)) / np.pi
    column = u * width - 0.5  # pixel centres sit at half-integers
    row = np.clip(v * height - 0.5, 0.0, height - 1.0)
    c0 = np.floor(column).astype(np.int64)
    r0 = np.minimum(np.floor(row).astype(np.int64), max(height - 2, 0))
    fc = (column - c0)[..., None]
    fr = (row - r0)[..., None]
    c0 %= width
    c1 = (c0 + 1) % width
    r1 = np.minimum(r0 + 1, height - 1)
    top = image[r0, c0] * (1 - fc) + image[r0, c1] * fc
    bottom = image[r1, c0] * (1 - fc) + image[r1, c1] * fc
    return top * (1 - fr) + bottom * fr
