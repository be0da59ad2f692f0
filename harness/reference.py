"""Exact reference images, computed by ``reference.cl`` and cached on disk by content hash."""
from __future__ import annotations

import functools
import hashlib
import pathlib
from typing import Iterator

import numpy as np

from iblbench.harness.device import Compute, cache_dir, event_ms, kernel_path
from iblbench.scenes import cubemap
from iblbench.scenes.atomic import atomic_path

# Sub-cells per lobe width for the specular quadrature (see reference.cl); part of the cache key.
DEFAULT_DENSITY = 16


def polygon_vector(vertices: np.ndarray) -> np.ndarray:
    """Φ = ∫ ω dω over spherical polygons ``[..., k, 3]`` (vertices in order, any scale).

    Arvo's formula Φ = ½ Σ_i θ_i γ_i, θ_i the arc between consecutive vertices and γ_i the unit
    normal of its great-circle plane; n·Φ is Lambert's ∫ cos dω for a polygon above the horizon.
    """
    a = vertices / np.linalg.norm(vertices, axis=-1, keepdims=True)
    b = np.roll(a, -1, axis=-2)
    c = np.cross(a, b)
    s = np.linalg.norm(c, axis=-1, keepdims=True)
    theta = np.arctan2(s, np.sum(a * b, axis=-1, keepdims=True))
    return 0.5 * np.sum(theta / np.where(s > 0, s, 1.0) * c, axis=-2)


def texel_corners(res: int) -> np.ndarray:
    """Unnormalised cube-surface corners of every texel, ``[6, R, R, 4, 3]`` in a fixed winding."""
    edges = np.linspace(0.0, 1.0, res + 1)
    col, row = np.meshgrid(np.arange(res), np.arange(res))
    s0, s1, t0, t1 = edges[col], edges[col + 1], edges[row], edges[row + 1]
    corners_st = [(s0, t0), (s1, t0), (s1, t1), (s0, t1)]
    faces = np.arange(6)[:, None, None]
    return np.stack([cubemap.face_st_to_direction(faces, s[None], t[None], normalize=False)
                     for s, t in corners_st], axis=-2)


@functools.lru_cache(maxsize=8)
def texel_tables(res: int) -> tuple[np.ndarray, np.ndarray]:
    """Per texel: (centre direction, sin α) and (Φ_t, α), float32 ``[6·R·R, 4]`` each.

    α is the largest angle between the texel's centre and its corners (its bounding cap).
    """
    centre = cubemap.texel_directions(res)
    corners = texel_corners(res)
    unit_corners = corners / np.linalg.norm(corners, axis=-1, keepdims=True)
    alpha = np.arccos(np.clip(np.einsum("...k,...jk->...j", centre, unit_corners), -1, 1)).max(-1)
    phi = polygon_vector(corners)
    phi *= np.sign(np.einsum("...k,...k->...", phi, centre))[..., None]
    return (np.concatenate([centre, np.sin(alpha)[..., None]], -1).reshape(-1, 4).astype(np.float32),
            np.concatenate([phi, alpha[..., None]], -1).reshape(-1, 4).astype(np.float32))


class Reference:
    """Computes (or loads from the cache) the exact image for one G-buffer and one frame."""

    def __init__(self, compute: Compute, density: int = DEFAULT_DENSITY, use_cache: bool = True):
        self.compute = compute
        self.density = density
        self.use_cache = use_cache
        self.last_ms: float | None = None   # device time of the last computation (None: cached)

    def _key(self, gbuffer, env: np.ndarray) -> str:
        digest = hashlib.sha256()
        digest.update(kernel_path("iblbench.harness", "reference.cl").read_bytes())
        digest.update(kernel_path("iblbench.estimators", "kernels/common.cl").read_bytes())
        digest.update(pathlib.Path(__file__).read_bytes())   # the host-side texel tables
        digest.update(f"density={self.density} fp64={self.compute.info.has_fp64}".encode())
        g = gbuffer.gbuffer
        for array in (g.mask, g.normal[g.mask], g.view[g.mask], g.kd[g.mask], g.ks[g.mask],
                      g.shininess[g.mask], np.ascontiguousarray(env, np.float32)):
            digest.update(np.ascontiguousarray(array).tobytes())
            digest.update(str(array.shape).encode())
        return digest.hexdigest()[:24]

    def image(self, gbuffer, cache) -> np.ndarray:
        """The reference radiance ``[H, W, 3]`` float32 for a DeviceGBuffer and FrameCache."""
        path = cache_dir() / "reference" / f"{self._key(gbuffer, cache.env)}.npy"
        if self.use_cache and path.exists():
            self.last_ms = None
            return gbuffer.scatter(np.load(path))
        values = self._compute(gbuffer, cache)
        if self.use_cache:
            with atomic_path(path) as tmp:
                np.save(tmp, values)
        return gbuffer.scatter(values)

    def texel_integrals(self, gbuffer, res: int) -> Iterator[np.ndarray]:
        """Per covered pixel of a DeviceGBuffer, in order, per texel of a map of face size
        ``res``: (∫_t cos⁺ dω, ∫_t max(0, r·ω)^m cos⁺ dω), float32 ``[6, R, R, 2]``, by the
        quadrature of :meth:`image` (which is Σ_t L_t (kd/π·first + ks·(m+2)/(2π)·second))."""
        c = self.compute
        centre, vector = (c.to_device(table) for table in texel_tables(res))
        out = c.empty(6 * res * res * 8)
        kernel = c.kernel("iblbench.harness", "reference.cl", "texel_integral_table",
                          {"REF_DENSITY": self.density})
        for pixel in range(gbuffer.count):
            c.run(kernel, 6 * res * res, gbuffer.normal, gbuffer.view, gbuffer.ks, centre, vector,
                  np.int32(res), np.int32(pixel), out)
            yield c.to_host(out, (6, res, res, 2), np.float32)

    def _compute(self, gbuffer, cache) -> np.ndarray:
        c = self.compute
        centre, vector = texel_tables(cache.res)
        out = c.empty(gbuffer.count * 16)
        kernel = c.kernel("iblbench.harness", "reference.cl", "reference",
                          {"REF_DENSITY": self.density})
        event = c.run(kernel, gbuffer.count, gbuffer.normal, gbuffer.view, gbuffer.kd,
                      gbuffer.ks, cache.env_buffer, c.to_device(centre), c.to_device(vector),
                      np.int32(cache.res), out)
        self.last_ms = event_ms(event)
        return c.to_host(out, (gbuffer.count, 4), np.float32)[:, :3]
