"""The G-buffer: per-pixel surface data from Embree primary rays, traced once per scene.

Camera: a pinhole at ``eye`` looking at ``target``; one ray per pixel through the pixel centre,
rows top to bottom, ``fov_y`` the full vertical field of view, aspect = width / height.

Shading normal: Embree's barycentrics (u, v) weight the vertex normals as
(1 − u − v)·n0 + u·n1 + v·n2.  Surfaces are two-sided: the normal is first turned to the side
of the triangle's geometric normal (so inverted vertex normals do not matter), then flipped with
it when the camera sees the triangle's back.

Degenerate and back-facing shading normals are handled this one way (the stress cases
``grazing`` and ``degenerate-mesh`` check it): an interpolated normal of (near) zero length
(zero-length vertex normals, or normals that cancel) is replaced by the geometric normal; an
interpolated normal that still faces away from the viewer (n·view < MIN_COS_VIEW: near
silhouettes, or vertex normals that lean away from the surface) is bent towards ``view``, in
the plane of n and view, just enough that n·view = MIN_COS_VIEW.  That is the smallest change
that keeps the mirror direction r = 2(n·view)n − view on the lit side, and the pixel stays
covered, shaded continuously with its neighbours, instead of being masked.  So every covered
pixel of a traced G-buffer has a finite unit normal with n·view ≥ MIN_COS_VIEW.
(:meth:`GBuffer.from_pixels` takes its normals as given.)

Cache.  :func:`cached_trace` keeps traced G-buffers on disk (``<folder>/<key>.npz``, written
atomically), keyed by a hash of what the trace reads: this module's source, the mesh's
vertices, faces and vertex normals, the material, the camera and the image size.  The
geometric normals are not hashed: trimesh derives them from the vertices and faces (no loader
here supplies its own).  A file that cannot be read back whole, or holds another image size, is
traced again and replaced.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import pathlib
import zipfile

import numpy as np

from iblbench.foundation.atomic import atomic_path

GBUFFER_ARRAYS = ("mask", "position", "normal", "view", "kd", "ks", "shininess")
MIN_COS_VIEW = 1e-3


@dataclasses.dataclass
class GBuffer:
    """Per-pixel arrays, rows top to bottom.

    ``mask`` bool ``[H, W]``; ``position``, ``normal`` (unit shading normal), ``view`` (unit,
    surface → camera), ``kd``, ``ks`` float32 ``[H, W, 3]``; ``shininess`` float32 ``[H, W]``.
    Uncovered pixels hold zeros.  ``visibility``: None (no V in the integrand), or the per-pixel
    bit masks ``[H, W, words]`` uint32 over ``visibility_res``² cells a cube face
    (:mod:`iblbench.scenes.visibility`).
    """

    mask: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    view: np.ndarray
    kd: np.ndarray
    ks: np.ndarray
    shininess: np.ndarray
    visibility: np.ndarray | None = None
    visibility_res: int = 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape

    @property
    def covered(self) -> int:
        return int(self.mask.sum())

    @property
    def is_diffuse(self) -> bool:
        """True when no covered pixel has a specular lobe (no BRDF-lobe branch is needed)."""
        return not np.any(self.ks[self.mask] > 0)

    def arrays(self) -> dict[str, np.ndarray]:
        arrays = {name: getattr(self, name) for name in GBUFFER_ARRAYS}
        if self.visibility is not None:
            arrays.update(visibility=self.visibility, visibility_res=np.int32(self.visibility_res))
        return arrays

    @classmethod
    def from_pixels(cls, normal, view, kd, ks, shininess, mask=None) -> "GBuffer":
        """A G-buffer made directly from per-pixel arrays (tests, synthetic inputs).

        ``normal`` is ``[H, W, 3]``; the others broadcast to it.  Vectors are normalised.
        """
        normal = np.asarray(normal, dtype=np.float32)
        shape = normal.shape[:-1]
        unit = lambda a: (a / np.linalg.norm(a, axis=-1, keepdims=True)).astype(np.float32)
        vec = lambda a: np.broadcast_to(np.asarray(a, np.float32), shape + (3,)).copy()
        return cls(
            mask=np.ones(shape, bool) if mask is None else np.asarray(mask, bool),
            position=np.zeros(shape + (3,), np.float32),
            normal=unit(normal),
            view=unit(vec(view)),
            kd=vec(kd),
            ks=vec(ks),
            shininess=np.broadcast_to(np.asarray(shininess, np.float32), shape).copy(),
        )

    def save_npz(self, path: str | os.PathLike) -> None:
        """Write the arrays to ``path`` atomically."""
        with atomic_path(path) as tmp:
            np.savez(tmp, **self.arrays())

    @classmethod
    def load_npz(cls, path: str | os.PathLike) -> "GBuffer":
        with np.load(path) as data:
            visibility = {"visibility": data["visibility"], "visibility_res": int(data["visibility_res"])} \
                if "visibility" in data else {}
            return cls(**{name: data[name] for name in GBUFFER_ARRAYS}, **visibility)


def camera_rays(camera, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions ``[H*W, 3]`` (float64) of the pixel-centre primary rays."""
    eye = np.asarray(camera.eye, np.float64)
    forward = np.asarray(camera.target, np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half_height = np.tan(np.radians(camera.fov_y) / 2.0)
    x = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * half_height * width / height
    y = (1.0 - (np.arange(height) + 0.5) / height * 2.0) * half_height
    dirs = forward + x[None, :, None] * right + y[:, None, None] * up
    dirs = dirs.reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return np.broadcast_to(eye, dirs.shape), dirs


def intersect(mesh, origins: np.ndarray, dirs: np.ndarray) -> dict[str, np.ndarray]:
    """Embree closest hits: ``primID`` (-1 for a miss), barycentrics ``u``, ``v`` and ``tfar``."""
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    scene = rtcs.EmbreeScene()
    TriangleMesh(scene, np.ascontiguousarray(mesh.vertices, np.float32), np.ascontiguousarray(mesh.faces, np.int32))
    return scene.run(np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(dirs, np.float32), output=1)


def shading_normals(mesh, prim: np.ndarray, u: np.ndarray, v: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Unit two-sided shading normals facing the camera (see the module docstring)."""
    corners = np.asarray(mesh.vertex_normals)[np.asarray(mesh.faces)[prim]]
    normal = (1.0 - u - v)[:, None] * corners[:, 0] + u[:, None] * corners[:, 1] + v[:, None] * corners[:, 2]
    geometric = np.asarray(mesh.face_normals)[prim]
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(length > 1e-12, normal / np.maximum(length, 1e-300), geometric)
    facing = np.sign(np.einsum("ij,ij->i", normal, geometric)) * np.sign(np.einsum("ij,ij->i", geometric, view))
    normal *= np.where(facing == 0.0, 1.0, facing)[:, None]
    cos_view = np.einsum("ij,ij->i", normal, view)
    normal += np.maximum(MIN_COS_VIEW - cos_view, 0.0)[:, None] * view
    return normal / np.linalg.norm(normal, axis=1, keepdims=True)


def trace_gbuffer(mesh, material, camera, width: int, height: int) -> GBuffer:
    """Trace one primary ray per pixel with Embree and fill the G-buffer (float32, zeros off-mesh)."""
    origins, dirs = camera_rays(camera, width, height)
    hits = intersect(mesh, origins, dirs)
    mask = hits["primID"] >= 0
    prim = hits["primID"][mask]
    u, v = hits["u"][mask].astype(np.float64), hits["v"][mask].astype(np.float64)
    view = -dirs[mask]

    def per_pixel(values: np.ndarray, channels: tuple[int, ...] = (3,)) -> np.ndarray:
        image = np.zeros((height * width, *channels), np.float32)
        image[mask] = values
        return image.reshape(height, width, *channels)

    return GBuffer(
        mask=mask.reshape(height, width),
        position=per_pixel(origins[mask] + hits["tfar"][mask, None] * dirs[mask]),
        normal=per_pixel(shading_normals(mesh, prim, u, v, view)),
        view=per_pixel(view),
        kd=per_pixel(np.asarray(material.kd, np.float32)),
        ks=per_pixel(np.asarray(material.ks, np.float32)),
        shininess=per_pixel(np.float32(material.shininess), ()),
    )


def gbuffer_key(mesh, material, camera, width: int, height: int) -> str:
    """The content hash of a trace's inputs (module docstring, "Cache")."""
    digest = hashlib.sha256(pathlib.Path(__file__).read_bytes())
    for array in (mesh.vertices, mesh.faces, mesh.vertex_normals):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    digest.update(repr((dataclasses.astuple(material), dataclasses.astuple(camera),
                        int(width), int(height))).encode())
    return digest.hexdigest()[:24]


def cached_trace(mesh, material, camera, width: int, height: int,
                 folder: str | os.PathLike) -> tuple[GBuffer, bool]:
    """:func:`trace_gbuffer`'s G-buffer from the cache in ``folder`` (module docstring, "Cache"),
    traced and stored there on a miss; and whether it was a hit."""
    path = pathlib.Path(folder) / f"{gbuffer_key(mesh, material, camera, width, height)}.npz"
    try:
        gbuffer = GBuffer.load_npz(path)
        if gbuffer.shape == (height, width):
            return gbuffer, True
    except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile):
        pass   # absent or damaged: traced again and replaced
    gbuffer = trace_gbuffer(mesh, material, camera, width, height)
    gbuffer.save_npz(path)
    return gbuffer, False
