"""Procedural meshes and mesh files (OBJ/PLY/GLB through trimesh).

trimesh (which imports scipy) is imported by the functions that use it, so that importing the
scene registry (``iblbench list scenes``, the CLI) stays fast."""
from __future__ import annotations

import functools
import os
import re
from pathlib import Path

import numpy as np

from iblbench.foundation.errors import InputError

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")
# Larger coordinates overflow trimesh's vertex merging (it rounds x·1e8 to int64) and lose
# Embree's float32 precision; cameras are held to the same bound.
MAX_COORDINATE = 1e9
# OBJ vertex indices count from 1 (negative ones from the end); trimesh reads a 0 as the last vertex.
_OBJ_ZERO_INDEX = re.compile(rb"^f[ \t](?:[^\n]*[ \t])?0(?=[/\s]|$)", re.MULTILINE)


def sphere(subdivisions: int = 4, radius: float = 1.0) -> trimesh.Trimesh:
    """Icosphere centred at the origin whose vertex normals are the exact sphere normals."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    normals = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_normals=normals, process=False)


BLOB_SUBDIVISIONS = 7     # 20·4^7 = 327,680 triangles
BLOB_AMPLITUDE = 0.15     # radial displacement scale: the radius stays within 1 ± amplitude (0.885..1.119)


def blob_displacement(directions: np.ndarray) -> np.ndarray:
    """Smooth radial displacement in [-1, 1] for unit ``directions [N, 3]``: a few low-frequency sines.

    Its second derivatives (~16 × the amplitude) exceed the sphere's curvature, so the displaced
    surface has both convex bumps and concave dents.  Deterministic: no random numbers.
    """
    x, y, z = directions[:, 0], directions[:, 1], directions[:, 2]
    value = (
        np.sin(4.0 * x + 0.3) * np.cos(3.0 * y - 0.7)
        + 0.7 * np.sin(5.0 * z + 1.1) * np.cos(2.0 * x)
        + 0.5 * np.sin(3.0 * (x + y + z))
    )
    return value / 2.2  # |value| <= 1 + 0.7 + 0.5


@functools.lru_cache(maxsize=4)
def _blob_arrays(subdivisions: int, amplitude: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, faces and smooth vertex normals of the blob (read-only; cached by parameters)."""
    import trimesh

    base = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    directions = base.vertices / np.linalg.norm(base.vertices, axis=1, keepdims=True)
    vertices = directions * (1.0 + amplitude * blob_displacement(directions))[:, None]
    faces = np.asarray(base.faces, np.int64)
    # Smooth normals of the displaced surface: the area-weighted sum of the adjacent face normals
    # (the cross product of two edges is twice the area times the unit face normal).
    corners = vertices[faces]
    weighted = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], weighted)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for array in (vertices, faces, normals):
        array.flags.writeable = False
    return vertices, faces, normals


def blob(subdivisions: int = BLOB_SUBDIVISIONS, amplitude: float = BLOB_AMPLITUDE) -> trimesh.Trimesh:
    """A unit icosphere displaced radially by ``amplitude × blob_displacement`` (outward winding).

    The default has 327,680 triangles.  The geometry is cached per (subdivisions, amplitude); each
    call returns a fresh ``Trimesh`` over copies of it, so callers may modify their mesh.
    """
    import trimesh

    vertices, faces, normals = _blob_arrays(int(subdivisions), float(amplitude))
    return trimesh.Trimesh(vertices.copy(), faces.copy(), vertex_normals=normals.copy(), process=False)


def torus(major_radius: float = 1.0, minor_radius: float = 0.4, major_sections: int = 96, minor_sections: int = 48) -> trimesh.Trimesh:
    """Torus around the +Y axis (the ring lies in the XZ plane) with exact analytic vertex normals."""
    import trimesh

    mesh = trimesh.creation.torus(major_radius, minor_radius, major_sections, minor_sections)
    # trimesh builds the ring around +Z; rotate +Z onto +Y.
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1.0, 0.0, 0.0]))
    vertices = np.asarray(mesh.vertices)
    ring = vertices * [1.0, 0.0, 1.0]
    ring *= major_radius / np.linalg.norm(ring, axis=1, keepdims=True)
    normals = (vertices - ring) / minor_radius
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return trimesh.Trimesh(vertices, mesh.faces, vertex_normals=normals, process=False)


def ground(half_size: float = 6.0, height: float = -1.0) -> trimesh.Trimesh:
    """A square ground plane at y = ``height``, normal +Y, of side 2·``half_size`` (two triangles)."""
    import trimesh

    h = half_size
    vertices = np.array([[-h, height, -h], [h, height, -h], [h, height, h], [-h, height, h]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    normals = np.tile([0.0, 1.0, 0.0], (4, 1))
    return trimesh.Trimesh(vertices, faces, vertex_normals=normals, process=False)


def on_ground(mesh: trimesh.Trimesh, half_size: float = 6.0) -> trimesh.Trimesh:
    """``mesh`` resting on a :func:`ground` plane that touches its lowest point; one mesh, each
    part keeping its own vertex normals."""
    import trimesh

    floor = ground(half_size, float(np.asarray(mesh.vertices)[:, 1].min()))
    vertices = np.concatenate([mesh.vertices, floor.vertices])
    faces = np.concatenate([mesh.faces, floor.faces + len(mesh.vertices)])
    normals = np.concatenate([mesh.vertex_normals, floor.vertex_normals])
    return trimesh.Trimesh(vertices, faces, vertex_normals=normals, process=False)


def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """One triangle mesh from a file; a multi-object file is concatenated into a single mesh."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(path, f"unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_SUFFIXES)}")
    if not path.is_file():
        raise InputError(path, "mesh file not found")
    if path.suffix.lower() == ".obj":
        _check_obj_indices(path)
    try:
        # Unprocessed: processing would drop non-finite vertices and their faces without a word.
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as error:  # trimesh raises many types for unreadable files
        raise InputError(path, f"cannot read mesh: {_reason(error)}") from error
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(path, "mesh has no triangles")
    _check_geometry(path, np.asarray(mesh.vertices), np.asarray(mesh.faces))
    return mesh.process()


# The rotation that stands a Z-up mesh (as Blender, 3ds Max and most scans store it) up in this
# Y-up frame: (x, y, z) -> (x, z, -y), a -90° turn about X (what Blender's glTF export applies).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def rotation_xyz(degrees) -> np.ndarray:
    """The 3×3 rotation by ``degrees`` = (rx, ry, rz) about the fixed X, then Y, then Z axes.

    Right-handed: a positive angle turns counter-clockwise seen from the axis's positive end
    (rotating +X by 90° about Y gives −Z).
    """
    rx, ry, rz = np.radians(np.asarray(degrees, np.float64))

    def about(angle, i, j):   # rotation in the (i, j) coordinate plane, i toward j
        turn = np.eye(3)
        turn[[i, j, i, j], [i, j, j, i]] = np.cos(angle), np.cos(angle), -np.sin(angle), np.sin(angle)
        return turn

    return about(rz, 0, 1) @ about(ry, 2, 0) @ about(rx, 1, 2)


def transform_mesh(mesh: trimesh.Trimesh, linear: np.ndarray, translate) -> trimesh.Trimesh:
    """A copy of ``mesh`` with vertices ``linear @ v + translate``.

    ``linear`` must have a positive determinant (no mirroring, so the winding keeps its sense).
    Vertex normals follow the inverse transpose of ``linear`` (right under non-uniform scale).
    """
    import trimesh

    linear = np.asarray(linear, np.float64)
    vertices = np.asarray(mesh.vertices, np.float64) @ linear.T + np.asarray(translate, np.float64)
    normals = np.asarray(mesh.vertex_normals, np.float64) @ np.linalg.inv(linear)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)   # 0 stays 0
    return trimesh.Trimesh(vertices, np.asarray(mesh.faces), vertex_normals=normals, process=False)


def _reason(error: Exception) -> str:
    """What a trimesh exception says about the file."""
    if isinstance(error, ImportError) and error.name == "charset_normalizer":
        return "not UTF-8 text"   # trimesh guesses other encodings only with that package
    if isinstance(error, KeyError) or not str(error):
        return f"{type(error).__name__} {error}".strip()   # a KeyError's text is only the key
    return str(error)


def _check_obj_indices(path: Path) -> None:
    try:
        zero = _OBJ_ZERO_INDEX.search(path.read_bytes())
    except OSError as error:
        raise InputError(path, f"cannot read mesh: {error.strerror}") from None
    if zero:
        line = zero.string.count(b"\n", 0, zero.start()) + 1
        raise InputError(path, f"line {line}: face vertex index 0 (OBJ indices start at 1)")


def _check_geometry(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Refuse what trimesh reads from a corrupt file without complaint."""
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(path, f"cannot read mesh: got vertices of shape {list(vertices.shape)} and "
                               f"faces of shape {list(faces.shape)}, not 3D points and triangles")
    if not np.all(np.isfinite(vertices)):
        raise InputError(path, "mesh has non-finite vertex coordinates")
    peak = float(np.abs(vertices).max())
    if peak > MAX_COORDINATE:
        raise InputError(path, f"vertex coordinates reach {peak:g}; at most ±{MAX_COORDINATE:g} is supported")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(path, f"a face refers to vertex {faces.max() + 1} or {faces.min() + 1}, "
                               f"but the mesh has vertices 1..{len(vertices)}")
