"""Procedural meshes and mesh files (OBJ/PLY/GLB through trimesh)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from .errors import InputError

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


def sphere(subdivisions: int = 4, radius: float = 1.0) -> trimesh.Trimesh:
    """Icosphere centred at the origin whose vertex normals are the exact sphere normals."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    normals = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_normals=normals, process=False)


def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """One triangle mesh from a file; a multi-object file is concatenated into a single mesh."""
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(path, f"unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_SUFFIXES)}")
    if not path.is_file():
        raise InputError(path, "mesh file not found")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as error:  # trimesh raises many types for unreadable files
        raise InputError(path, f"cannot read mesh: {error}") from error
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(path, "mesh has no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputError(path, "mesh has non-finite vertex coordinates")
    return mesh
