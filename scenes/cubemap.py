"""Cube-map conventions of ARCHITECTURE.md §Conventions, shared with ``estimators/runtime/kernels/common.cl``.

- Face order +X, -X, +Y, -Y, +Z, -Z; Y is up.
- Face coordinates follow the OpenGL table: ``ma`` is the major axis and ``(sc, tc)``
  come from ``_SC_TC`` below; ``s = (sc/|ma| + 1)/2``, ``t = (tc/|ma| + 1)/2``.
- Column = s·R, row = t·R; rows grow downward (t grows downward on every face).
- Ties between major axes go to the first of x, y, z (the OpenCL code does the same).
- A texel's solid angle is exact: Ω = F(x1,y1) − F(x0,y1) − F(x1,y0) + F(x0,y0),
  F(x, y) = atan2(x·y, √(x²+y²+1)), with (x, y) the face-plane coordinates in [-1, 1].

An environment frame is a float32 array ``[6, R, R, 3]`` of linear Rec.709 radiance.
"""
from __future__ import annotations

import numpy as np

FACE_NAMES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")
LUMINANCE_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])

# For each face: (major axis index, sign of major axis); then how (u, v) = (2s-1, 2t-1)
# map back to a direction.  _FACE_BASIS[f] = (axis of u, axis of v, axis of ma) as signed
# unit vectors so that direction = u*U + v*V + W.
_FACE_BASIS = np.array(
    [
        # U             V              W (outward face normal)
        [[0, 0, -1], [0, -1, 0], [1, 0, 0]],    # +X: sc = -z, tc = -y
        [[0, 0, 1], [0, -1, 0], [-1, 0, 0]],    # -X: sc = +z, tc = -y
        [[1, 0, 0], [0, 0, 1], [0, 1, 0]],      # +Y: sc = +x, tc = +z
        [[1, 0, 0], [0, 0, -1], [0, -1, 0]],    # -Y: sc = +x, tc = -z
        [[1, 0, 0], [0, -1, 0], [0, 0, 1]],     # +Z: sc = +x, tc = -y
        [[-1, 0, 0], [0, -1, 0], [0, 0, -1]],   # -Z: sc = -x, tc = -y
    ],
    dtype=np.float64,
)


def face_basis(face) -> np.ndarray:
    """(U, V, W) of ``face`` as rows, ``[..., 3, 3]``: the direction at face-plane point (u, v) is
    u·U + v·V + W (W the outward face normal).  Each is a signed permutation matrix."""
    return _FACE_BASIS[np.asarray(face)]


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luminance Y of the last axis."""
    return np.asarray(rgb, dtype=np.float64) @ LUMINANCE_WEIGHTS


def direction_to_face_st(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map directions ``[..., 3]`` (any length > 0) to (face, s, t) with s, t in [0, 1]."""
    d = np.asarray(d, dtype=np.float64)
    ax = np.abs(d)
    x_major = (ax[..., 0] >= ax[..., 1]) & (ax[..., 0] >= ax[..., 2])
    y_major = ~x_major & (ax[..., 1] >= ax[..., 2])
    axis = np.where(x_major, 0, np.where(y_major, 1, 2))
    major = np.take_along_axis(d, axis[..., None], axis=-1)[..., 0]
    face = 2 * axis + (major < 0)
    basis = _FACE_BASIS[face]
    ma = np.abs(major)
    s = (np.einsum("...k,...k->...", d, basis[..., 0, :]) / ma + 1.0) * 0.5
    t = (np.einsum("...k,...k->...", d, basis[..., 1, :]) / ma + 1.0) * 0.5
    return face, s, t


def direction_to_texel(d: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map directions to (face, row, col) texel indices of a cube map with R = ``res``."""
    face, s, t = direction_to_face_st(d)
    col = np.clip(np.floor(s * res).astype(np.int64), 0, res - 1)
    row = np.clip(np.floor(t * res).astype(np.int64), 0, res - 1)
    return face, row, col


def face_st_to_direction(face, s, t, normalize: bool = True) -> np.ndarray:
    """Inverse of :func:`direction_to_face_st`: a direction ``[..., 3]`` on the cube."""
    face = np.asarray(face)
    basis = _FACE_BASIS[face]
    u = (2.0 * np.asarray(s, dtype=np.float64) - 1.0)[..., None]
    v = (2.0 * np.asarray(t, dtype=np.float64) - 1.0)[..., None]
    d = u * basis[..., 0, :] + v * basis[..., 1, :] + basis[..., 2, :]
    if normalize:
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return d


def _area_integral(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """F(x, y) = atan2(xy, sqrt(x²+y²+1)): solid angle of the face rectangle [0,x]×[0,y]."""
    return np.arctan2(x * y, np.sqrt(x * x + y * y + 1.0))


def texel_solid_angles(res: int) -> np.ndarray:
    """Exact solid angle of every texel of one face, float64 ``[R, R]`` (same on all faces)."""
    edges = np.linspace(-1.0, 1.0, res + 1)
    f = _area_integral(edges[None, :], edges[:, None])  # f[row_edge, col_edge]
    return f[1:, 1:] - f[:-1, 1:] - f[1:, :-1] + f[:-1, :-1]


def texel_directions(res: int) -> np.ndarray:
    """Unit directions of all texel centres, float64 ``[6, R, R, 3]``."""
    centres = (np.arange(res) + 0.5) / res
    t, s = np.meshgrid(centres, centres, indexing="ij")
    faces = np.arange(6)[:, None, None]
    return face_st_to_direction(faces, s[None], t[None])


def integrate(env: np.ndarray) -> np.ndarray:
    """Σ L·Ω over the whole sphere, per channel (float64)."""
    env = np.asarray(env, dtype=np.float64)
    omega = texel_solid_angles(env.shape[1])
    return np.einsum("frcx,rc->x", env, omega)


def face_luminance_integrals(env: np.ndarray) -> np.ndarray:
    """I_f = Σ_texels Y·Ω per face, float64 ``[6]`` (Lu 2013 Eq. 3's face intensity)."""
    return np.einsum("frc,rc->f", luminance(env), texel_solid_angles(env.shape[1]))


class MapSampler:
    """A cube map's radiance lookup (nearest texel) and its luminance sampler (ARCHITECTURE.md §Conventions)."""

    def __init__(self, env):
        self.env = np.asarray(env, np.float64)
        self.res = res = self.env.shape[1]
        weight = luminance(self.env) * texel_solid_angles(res)   # Y·Ω
        self.prob = (weight / weight.sum()).reshape(-1)   # μ_f P(texel|f) = Y·Ω/Σ I
        self.cumulative = np.cumsum(self.prob)

    def radiance(self, w):
        face, row, col = direction_to_texel(w, self.res)
        return self.env[face, row, col]

    def pdf(self, w):
        face, s, t = direction_to_face_st(w)
        res = self.res
        row, col = (np.clip(np.floor(a * res).astype(int), 0, res - 1) for a in (t, s))
        x, y = 2 * s - 1, 2 * t - 1
        return self.prob[(face * res + row) * res + col] * (1 + x * x + y * y) ** 1.5 * res * res / 4

    def sample(self, shape, rng):
        texel = np.minimum(np.searchsorted(self.cumulative, rng.random(shape) * self.cumulative[-1],
                                           side="right"), self.prob.size - 1)
        face, rest = np.divmod(texel, self.res * self.res)
        row, col = np.divmod(rest, self.res)
        s = (col + rng.random(shape)) / self.res
        t = (row + rng.random(shape)) / self.res
        return face_st_to_direction(face, s, t)
