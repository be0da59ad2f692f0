"""A scene's visibility for the runner: traced (or read from the cache) when the scene asks for
it and needs it, and what the manifest records of it."""
from __future__ import annotations

import dataclasses
import time

from iblbench.harness.protocol.visibility_error import visibility_error
from iblbench.scenes import visibility
from iblbench.foundation.errors import InputError


def attach_visibility(scene, gbuffer, env_res: int, folder, progress=None) -> tuple[object, dict | None]:
    """``gbuffer`` with the scene's visibility masks (:mod:`iblbench.scenes.visibility`), and the
    manifest's record of them (None for a scene that asks for no visibility): its resolution,
    whether the cache held it, the rays traced and the Embree ray rate of that trace; or why it
    was skipped.  (The runner adds the masks' ``geometric_error``: :func:`measured_record`.)
    ``progress``: called with the pixels traced since its last call (a trace only).

    A scene that asks for visibility but has one convex mesh and nothing else gets none
    (V = 1 wherever the surface faces ω: nothing to trace), and the record says so."""
    if not scene.visibility:
        return gbuffer, None
    record = {"scene": scene.name, "visibility_res": scene.visibility_res, "covered_pixels": gbuffer.covered}
    if not traces_visibility(scene):
        return gbuffer, dict(record, skipped="one convex mesh and nothing else: V = 1 wherever its "
                                             "surface faces ω, so nothing is traced")
    try:
        visibility.check_resolution(scene.visibility_res, env_res)
    except ValueError as error:
        raise InputError(scene.source or scene.name, str(error)) from None
    start = time.perf_counter()
    masks, stats, cached = visibility.cached_visibility(scene.mesh, scene.camera, gbuffer.normal,
                                                        scene.visibility_res, folder, progress)
    record.update(cached=cached, seconds=round(time.perf_counter() - start, 3),
                  rays=stats.rays, trace_seconds=round(stats.seconds, 3),
                  embree_rays_per_s=round(stats.rays_per_second),
                  bytes_per_pixel=4 * visibility.words(scene.visibility_res))
    return dataclasses.replace(gbuffer, visibility=masks, visibility_res=scene.visibility_res), record


def traces_visibility(scene) -> bool:
    """Whether :func:`attach_visibility` traces the scene's masks (or reads them from the
    cache): it asks for visibility, and its geometry can shadow itself."""
    return bool(scene.visibility) and visibility.needs_visibility(scene.mesh)


def measured_record(scene, gbuffer, env, record: dict) -> dict:
    """``record`` with ``geometric_error`` where the scene's masks were traced or read: the
    masked reference against real shadow rays under ``env`` (a frame of the scene) at Rv/2, Rv
    and 2·Rv (:mod:`.visibility_error`)."""
    if gbuffer.visibility is None:
        return record
    return dict(record, geometric_error=visibility_error(scene, gbuffer, env))
