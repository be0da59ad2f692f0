"""Scene description: mesh, material, camera and environment sequence."""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np


@dataclasses.dataclass(frozen=True)
class Material:
    """Energy-conserving (Lafortune) Phong of ARCHITECTURE.md §Conventions: ρ = kd/π + ks·(m+2)/(2π)·cos^m."""

    kd: tuple[float, float, float] = (0.5, 0.5, 0.5)
    ks: tuple[float, float, float] = (0.3, 0.3, 0.3)
    shininess: float = 150.0


@dataclasses.dataclass(frozen=True)
class Camera:
    """Pinhole camera; ``fov_y`` is the full vertical field of view in degrees."""

    eye: tuple[float, float, float] = (0.0, 0.0, 3.0)
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_y: float = 45.0


@dataclasses.dataclass
class EnvSequence:
    """Frames of ``[6, R, R, 3]`` float32 radiance; a static environment has one frame.

    Frames are made on demand by ``make_frame(index)`` so a long sequence is never held whole.
    """

    num_frames: int
    make_frame: Callable[[int], np.ndarray]
    source: str = ""
    texels_fixed: int = 0   # bad texels replaced by --sanitize while loading

    @property
    def is_static(self) -> bool:
        return self.num_frames == 1

    def frame(self, index: int) -> np.ndarray:
        return self.make_frame(index)

    @classmethod
    def static(cls, env: np.ndarray, source: str = "", texels_fixed: int = 0) -> "EnvSequence":
        return cls(1, lambda _index: env, source, texels_fixed)


@dataclasses.dataclass
class Scene:
    """Everything a benchmark cell needs except the estimator.

    ``mesh`` is a ``trimesh.Trimesh``; ``resolution`` is the default image size (W, H).
    ``visibility``: whether the integrand carries V(x, ω), traced by Embree into per-pixel masks
    of ``visibility_res``² cells per cube face (:mod:`iblbench.scenes.visibility`).
    """

    name: str
    mesh: object
    material: Material
    camera: Camera
    environment: EnvSequence
    resolution: tuple[int, int] = (128, 128)
    source: str = ""
    mesh_source: str = ""   # the mesh file of a user scene
    visibility: bool = False
    visibility_res: int = 16
