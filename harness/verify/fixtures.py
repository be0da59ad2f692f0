"""The conformance suite's fixtures: synthetic inputs (directions, cube maps, G-buffers) that
``check_estimator``, the stress battery, the portability set and the tests build their cases
from.  Each is a pure NumPy function of its size; nothing here touches a device."""
from __future__ import annotations

import dataclasses

import numpy as np

from iblbench.scenes import cubemap, visibility
from iblbench.scenes.gbuffer import GBuffer


def fibonacci_directions(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def smooth_map(res: int = 8) -> np.ndarray:
    """A smooth, strictly positive map whose channels vary differently (χ² and z-tests need no
    hard edges, and a bias in one channel must not hide behind the others)."""
    x, y, z = np.moveaxis(cubemap.texel_directions(res), -1, 0)
    return np.stack([1.0 + 0.6 * y + 0.4 * x * x, 0.8 + 0.5 * x * z, 0.6 - 0.4 * y + 0.3 * z],
                    axis=-1).astype(np.float32)


# One blob per face: its centre (u, v) on the face plane and its RGB tint.  Every centre is at
# least 0.15 off both axes and its two diagonals lie ≥ 0.25/√2 away, so each of the 7 flips and
# turns of a face square moves its blob by ≥ 0.3 (1.2 texels at R = 8); tints and places differ
# between faces, so swapping two faces changes the map too.
FACE_BLOBS = (((0.55, -0.2), (3.0, 0.9, 0.4)), ((-0.25, 0.6), (0.4, 2.5, 0.8)),
              ((0.6, 0.25), (0.8, 0.5, 3.0)), ((-0.5, -0.2), (2.5, 2.0, 0.3)),
              ((0.2, -0.55), (0.3, 1.5, 2.0)), ((-0.6, 0.3), (2.0, 0.4, 2.5)))
FACE_BLOB_WIDTH = 0.3


def face_pattern_map(res: int = 8) -> np.ndarray:
    """``smooth_map`` plus a bright, tinted Gaussian blob on every face, placed so that no flip
    or turn of a face and no swap of two faces leaves the map (and its luminance) unchanged
    (``FACE_BLOBS``): a sign or orientation error on any face then moves light, which the z-tests
    and the χ² test see (issue 13: ``smooth_map`` on ±Y changed by 3% under a half turn)."""
    centre = (np.arange(res) + 0.5) * (2.0 / res) - 1.0
    v, u = np.meshgrid(centre, centre, indexing="ij")          # rows are v (t), columns u (s)
    env = smooth_map(res).astype(np.float64)
    for face, ((u0, v0), tint) in enumerate(FACE_BLOBS):
        blob = np.exp(-((u - u0) ** 2 + (v - v0) ** 2) / (2 * FACE_BLOB_WIDTH ** 2))
        env[face] += blob[..., None] * np.asarray(tint)
    return env.astype(np.float32)


def constant_map(value: float = 0.7, res: int = 8) -> np.ndarray:
    return np.full((6, res, res, 3), value, np.float32)


SUN_FACE = 4   # +Z


def sun_map(res: int, ratio: float) -> np.ndarray:
    """A smooth sky (``smooth_map`` × 0.01) with a one-texel sun of ``ratio`` × the sky's
    brightest texel in the middle of the +Z face."""
    env = smooth_map(res) * np.float32(0.01)
    env[SUN_FACE, res // 2, res // 2] = ratio * env.max()
    return env


def stress_maps(res: int = 16) -> dict[str, np.ndarray]:
    """The robustness cases of the guide (small resolution; the full battery is ``stress``)."""
    hot = np.zeros((6, res, res, 3), np.float32)
    hot[4, res // 2, res // 3] = 1e4
    black_faces = smooth_map(res)
    black_faces[[1, 3, 5]] = 0.0
    return {"sun-1e6": sun_map(res, 1e6), "single-hot-texel": hot,
            "all-black": np.zeros((6, res, res, 3), np.float32), "black-faces": black_faces}


def glossy_gbuffer(size: int = 8, shininess: float = 20.0, ks: float = 0.3, kd: float = 0.5) -> GBuffer:
    """Normals over the whole sphere, views tilted off each normal, a Phong material."""
    n = fibonacci_directions(size * size).reshape(size, size, 3)
    tilt = np.roll(n, 1, axis=-1)
    view = n + 0.6 * (tilt - np.sum(tilt * n, -1, keepdims=True) * n)
    return GBuffer.from_pixels(n, view, kd, ks, shininess)


def grazing_gbuffer(size: int = 8) -> GBuffer:
    """Views at grazing angles (n·v ≈ 1e-3) and shininess 1e4."""
    n = fibonacci_directions(size * size).reshape(size, size, 3)
    side = np.cross(n, np.array([0.3, 0.5, 0.81]))
    side /= np.linalg.norm(side, axis=-1, keepdims=True)
    return GBuffer.from_pixels(n, side + 1e-3 * n, 0.5, 0.5, 1e4)


def white_lambertian(size: int = 8) -> GBuffer:
    """Normals over the whole sphere, each seen head-on (a Lambertian ignores the view, but the
    G-buffer contract wants n·view > 0)."""
    normal = fibonacci_directions(size * size).reshape(size, size, 3)
    return GBuffer.from_pixels(normal, normal, 1.0, 0.0, 1.0)


def settings_frames(res: int = 8) -> list[np.ndarray]:
    """Four frames on which a temporal estimator's settings show (``check_settings_differ``):
    ``face_pattern_map``, the same again (a static frame), its +Y face 1.3× (a small change that
    carries state) and 8× (one that re-initialises it)."""
    still = face_pattern_map(res)
    frames = [still, still.copy()]
    for gain in (1.3, 8.0):
        changed = still.copy()
        changed[2] *= np.float32(gain)
        frames.append(changed)
    return frames


def same_pixels(normal, view, rows: int = 5, cols: int = 7, kd=0.5, ks=0.3, shininess=20.0) -> GBuffer:
    """``rows`` × ``cols`` pixels of one normal, view and material: an estimator whose pixels
    read the same samples renders them identically."""
    shape = (rows, cols, 3)
    return GBuffer.from_pixels(np.broadcast_to(normal, shape), np.broadcast_to(view, shape), kd, ks,
                               shininess)


def count_gbuffer(masked: bool, size: int = 4) -> GBuffer:
    """``size``² glossy pixels whose normals lie within 35° of +Y, views tilted off them, so that
    many pixels pass restir's neighbour tests and some do not; ``masked``: visibility masks of
    2² cells a face with the −Y face closed and, at every other pixel, a cell of +Y, so every
    pixel sees light on a map that is lit everywhere, but pixel (1, 2), whose every cell is
    closed (a black pixel: ``smc`` re-initialises it every frame) (``check_work_counts``)."""
    side = np.linspace(-0.5, 0.5, size)
    x, z = np.meshgrid(side, side, indexing="ij")
    normal = np.stack([x, np.ones_like(x), z], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    tilt = np.roll(normal, 1, axis=-1)
    view = normal + 0.6 * (tilt - np.sum(tilt * normal, -1, keepdims=True) * normal)
    gb = GBuffer.from_pixels(normal, view, 0.5, 0.3, 20.0)
    if not masked:
        return gb
    res = 2
    cells = np.ones(gb.shape + (6 * res * res,), bool)
    cells[..., 3 * res * res:4 * res * res] = False            # −Y
    cells.reshape(-1, 6 * res * res)[1::2, 2 * res * res] = False   # a cell of +Y
    cells[1, 2] = False                                         # one pixel sees nothing
    return dataclasses.replace(gb, visibility=visibility.pack_bits(cells), visibility_res=res)


def count_frames(res: int = 8) -> list[np.ndarray]:
    """The maps of ``check_work_counts``'s sequence, one per path of a temporal estimator:
    ``face_pattern_map`` (a first frame), the same again (static), ×1.25 (a change that carries
    state) and ×8 (one whose power jump re-initialises it)."""
    still = face_pattern_map(res)
    return [still, still.copy(), still * np.float32(1.25), still * np.float32(8.0)]
