"""Warnings about a camera that frames its mesh badly (issue 11): it sees too few mesh pixels to
score, or it sits inside the mesh.  The run goes on; each warning is one line on stderr.

- Too few pixels: fewer than :data:`MIN_MESH_PIXELS` covered pixels.  Every metric is a mean over
  covered pixels, and a mean over a handful of them says little about an estimator.
- Inside the mesh: more than :data:`INSIDE_BACK_FACE_FRACTION` of the primary rays that hit the
  mesh hit the back of a triangle (geometric normal, i.e. the winding, facing away from the
  camera).  From outside a closed, consistently wound mesh no ray does; from inside every ray
  does.  The test is made only when the eye lies inside the mesh's bounding box (elsewhere it
  cannot be inside the mesh), on a grid of at most :data:`PROBE_SIDE`² rays over the image.  A
  mesh whose winding points inwards (a room) also trips it, which is worth a look as well.
"""
from __future__ import annotations

import sys

import numpy as np

from .gbuffer import camera_rays, intersect

MIN_MESH_PIXELS = 64
INSIDE_BACK_FACE_FRACTION = 0.5
PROBE_SIDE = 64   # probe rays along the longer image side


def back_face_fraction(mesh, camera, width: int, height: int) -> float:
    """The fraction of mesh-hitting primary rays that hit a triangle's back (0 with no hit or
    with the eye outside the mesh's bounding box), over a probe grid of the image's aspect."""
    low, high = np.asarray(mesh.bounds, np.float64)
    if np.any(np.asarray(camera.eye) < low) or np.any(np.asarray(camera.eye) > high):
        return 0.0
    scale = min(1.0, PROBE_SIDE / max(width, height))
    origins, dirs = camera_rays(camera, max(1, round(width * scale)), max(1, round(height * scale)))
    prim = intersect(mesh, origins, dirs)["primID"]
    hit = prim >= 0
    if not hit.any():
        return 0.0
    facing_away = np.einsum("ij,ij->i", np.asarray(mesh.face_normals)[prim[hit]], dirs[hit]) > 0
    return float(facing_away.mean())


def framing_warnings(scene, gbuffer) -> list[str]:
    """One-line warnings about how ``scene``'s camera frames its mesh in ``gbuffer`` (its trace)."""
    warnings = []
    height, width = gbuffer.shape
    if 0 < gbuffer.covered < MIN_MESH_PIXELS:
        warnings.append(
            f"scene {scene.name}: the camera sees only {gbuffer.covered} of {width * height} pixels "
            f"of the mesh (fewer than {MIN_MESH_PIXELS}), too few for its metrics to mean much; "
            "check the camera's eye, target and fov_y, and the mesh's size and position")
    back = back_face_fraction(scene.mesh, scene.camera, width, height)
    if back > INSIDE_BACK_FACE_FRACTION:
        warnings.append(
            f"scene {scene.name}: the camera at {tuple(map(float, scene.camera.eye))} seems to be "
            f"inside the mesh ({back:.0%} of the rays that hit it hit the back of a triangle); "
            "check camera.eye, the mesh's size and position, or its face winding")
    return warnings


def warn_about_framing(scene, gbuffer) -> None:
    """Print :func:`framing_warnings` to stderr, one line each."""
    for warning in framing_warnings(scene, gbuffer):
        print(f"iblbench: warning: {warning}", file=sys.stderr)
