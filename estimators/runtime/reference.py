"""Exact reference images, computed by ``reference.cl`` and cached on disk by content hash."""
from __future__ import annotations

import functools
import hashlib
import pathlib
import time
from typing import Iterator

import numpy as np
import pyopencl as cl

from iblbench.estimators.runtime.chunks import run_in_chunks
from iblbench.estimators.runtime.device import Compute, cache_dir, event_ms, kernel_path
from iblbench.scenes import cubemap
from iblbench.foundation.atomic import atomic_path

# Quadrature points per lobe width for the specular quadrature (see reference.cl); part of the cache key.
# The 2 × 2 Gauss rule's error in a texel on the lobe's flank (where cos^m falls by e^{√m·θ}
# per lobe width) shrinks as density⁻⁴: at 4 a lit texel alone was 2e-4 off (issue 34), at 8
# ≤ 2e-5 (tests/test_reference_twin.py), for 1.3–1.8× the device time (m = 150: park-ground,
# sphere-sun at 64² pixels and faces, PoCL).
DEFAULT_DENSITY = 8
LANES = 8              # texels per vector step of reference.cl: the tables' padding
WORK_GROUP = 64        # pixels per work group, at most: many groups, so every core gets some


def arc_vectors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """θ·γ of the great-circle arcs a → b ``[..., 3]`` (any positive scale): the arc's angle times
    the unit normal of its plane.  Half their sum around a spherical polygon is Arvo's vector
    irradiance Φ = ∫ ω dω, and n·Φ is Lambert's ∫ cos dω for a polygon above the horizon."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    c = np.cross(a, b)
    s = np.linalg.norm(c, axis=-1, keepdims=True)
    theta = np.arctan2(s, np.sum(a * b, axis=-1, keepdims=True))
    return theta / np.where(s > 0, s, 1.0) * c


def _face_tables(res: int) -> tuple[np.ndarray, ...]:
    """One face's texels in its own frame, where the face-plane point (u, v) is (u, v, 1): unit
    centres, sin α and Φ, each ``[R, R, ...]`` float64.

    Φ sums the arc vectors of the texel's four edges, each edge computed once for the two texels
    that share it (in opposite directions), so the cost is O(R²) arcs, not 4R²."""
    edges = np.linspace(-1.0, 1.0, res + 1)
    u, v = np.meshgrid(edges, edges)                          # [row edge, column edge]
    corner = np.stack([u, v, np.ones_like(u)], axis=-1)
    along_row = arc_vectors(corner[:, :-1], corner[:, 1:])    # (u_c, v_r) → (u_c+1, v_r)
    along_col = arc_vectors(corner[:-1], corner[1:])          # (u_c, v_r) → (u_c, v_r+1)
    phi = 0.5 * (along_row[:-1] + along_col[:, 1:] - along_row[1:] - along_col[:, :-1])
    middle = (edges[:-1] + edges[1:]) / 2
    mu, mv = np.meshgrid(middle, middle)
    centre = np.stack([mu, mv, np.ones_like(mu)], axis=-1)
    centre /= np.linalg.norm(centre, axis=-1, keepdims=True)
    phi *= np.sign(np.sum(phi * centre, axis=-1, keepdims=True))
    corner /= np.linalg.norm(corner, axis=-1, keepdims=True)
    nearest_corner = np.min([np.sum(centre * corner[i:res + i, j:res + j], axis=-1)
                             for i in (0, 1) for j in (0, 1)], axis=0)
    return centre, np.sin(np.arccos(np.clip(nearest_corner, -1.0, 1.0))), phi


def planes(values: np.ndarray) -> np.ndarray:
    """Per-texel values ``[6·R·R, k]`` as k planes ``[k, 6·R·R + LANES]`` (float32, zero padded,
    so reference.cl's vector loads of the last texels stay inside)."""
    out = np.zeros((values.shape[1], values.shape[0] + LANES), np.float32)
    out[:, :values.shape[0]] = values.T
    return out


@functools.lru_cache(maxsize=8)
def texel_table(res: int) -> np.ndarray:
    """``texel_tables`` as the planes of reference.cl: centre, sin α, Φ_t ``[7, 6·R·R + LANES]``."""
    return planes(np.concatenate(texel_tables(res), axis=1))


@functools.lru_cache(maxsize=8)
def texel_tables(res: int) -> tuple[np.ndarray, np.ndarray]:
    """Per texel: (centre direction, sin α) float32 ``[6·R·R, 4]`` and Φ_t ``[6·R·R, 3]``.

    α is the largest angle between the texel's centre and its corners (its bounding cap), Φ_t
    its vector irradiance (``arc_vectors``), oriented toward its centre.  Every face is one face
    turned by its basis (a signed permutation, which keeps angles and that orientation), so the
    float64 work and memory are one face's."""
    centre, sin_alpha, phi = _face_tables(res)
    centres = np.empty((6, res, res, 4), np.float32)
    vectors = np.empty((6, res, res, 3), np.float32)
    for face in range(6):
        basis = cubemap.face_basis(face)
        centres[face, ..., :3] = centre @ basis
        vectors[face] = phi @ basis
    centres[..., 3] = sin_alpha
    return centres.reshape(-1, 4), vectors.reshape(-1, 3)


def _wait(queue, event) -> None:
    """Wait for ``event`` in short sleeps: Python runs its SIGINT handler between them, while a
    blocking ``event.wait()`` would hold a Ctrl-C until the kernel ends."""
    queue.flush()
    while event.command_execution_status > cl.command_execution_status.COMPLETE:
        time.sleep(0.002)
    event.wait()   # raises if the command failed


class Reference:
    """Computes (or loads from the cache) the exact image for one G-buffer and one frame."""

    def __init__(self, compute: Compute, density: int = DEFAULT_DENSITY, use_cache: bool = True):
        self.compute = compute
        self.density = density
        self.use_cache = use_cache
        self.last_ms: float | None = None   # device time of the last computation (None: cached)

    def _key(self, gbuffer, env: np.ndarray) -> str:
        digest = hashlib.sha256()
        digest.update(kernel_path("iblbench.estimators.runtime", "reference.cl").read_bytes())
        digest.update(kernel_path("iblbench.estimators.runtime", "kernels/common.cl").read_bytes())
        digest.update(pathlib.Path(__file__).read_bytes())   # the host-side texel tables
        fp64 = self.compute.doubles   # the path Compute builds
        digest.update(f"density={self.density} fp64={fp64}".encode())
        g = gbuffer.gbuffer
        masks = () if g.visibility is None else (g.visibility[g.mask],)
        if masks:
            digest.update(f"visibility_res={g.visibility_res}".encode())
        for array in (g.mask, g.normal[g.mask], g.view[g.mask], g.kd[g.mask], g.ks[g.mask],
                      g.shininess[g.mask], np.ascontiguousarray(env, np.float32), *masks):
            digest.update(np.ascontiguousarray(array).tobytes())
            digest.update(str(array.shape).encode())
        return digest.hexdigest()[:24]

    def image(self, gbuffer, cache) -> np.ndarray:
        """The reference radiance ``[H, W, 3]`` float32 for a DeviceGBuffer and FrameCache.

        With visibility, Rv must divide the face size (each texel in one cell: reference.cl)."""
        if gbuffer.has_visibility and cache.res % gbuffer.visibility_res:
            raise ValueError(f"visibility_res {gbuffer.visibility_res} does not divide the "
                             f"environment's face size {cache.res}")
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
        table = texel_table(res)
        table_buffer = c.to_device(table)
        out = c.empty(6 * res * res * 8)
        kernel = c.kernel("iblbench.estimators.runtime", "reference.cl", "texel_integral_table",
                          {"REF_DENSITY": self.density})
        for pixel in range(gbuffer.count):
            c.run(kernel, 6 * res * res, gbuffer.normal, gbuffer.view, gbuffer.ks, table_buffer,
                  np.int32(res), np.int32(table.shape[1]), np.int32(pixel), out)
            yield c.to_host(out, (6, res, res, 2), np.float32)

    def _compute(self, gbuffer, cache) -> np.ndarray:
        """The image's covered pixels in launches of about ``chunks.CHUNK_MS`` device time each
        (:func:`~iblbench.estimators.runtime.chunks.run_in_chunks`), waited for in short sleeps
        (:func:`_wait`), so that a Ctrl-C stops it within about a launch; ``last_ms`` sums the
        launches' device times."""
        c = self.compute
        table = texel_table(cache.res)
        table_buffer = c.to_device(table)
        env_planes = c.to_device(planes(cache.env.reshape(-1, 3)))
        out = c.empty(gbuffer.count * 16)
        kernel = c.kernel("iblbench.estimators.runtime", "reference.cl", "reference",
                          {"REF_DENSITY": self.density, **gbuffer.defines})
        group = min(WORK_GROUP, c.group_limit(kernel))

        def launch(first: int, count: int) -> cl.Event:
            kernel.set_args(gbuffer.normal, gbuffer.view, gbuffer.kd, gbuffer.ks, gbuffer.visibility, env_planes,
                            table_buffer, np.int32(cache.res), np.int32(table.shape[1]),
                            np.int32(first), np.int32(count), out)
            size = -(-count // group) * group
            event = cl.enqueue_nd_range_kernel(c.queue, kernel, (size,), (group,))
            _wait(c.queue, event)
            return event

        self.last_ms = event_ms(run_in_chunks(gbuffer.count, group, launch))
        return c.to_host(out, (gbuffer.count, 4), np.float32)[:, :3]
