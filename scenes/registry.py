"""Built-in scenes by name, and user scenes from TOML files.

``load_scene(name_or_path)`` takes a built-in name (case-insensitive) or a path ending in ``.toml``.

Built-in scenes (static Preetham sun + sky, kd = 0.5, ks = 0.3, shininess = 150, 128 × 128):

- ``sphere-sun``: the baseline; a smooth sphere, sun at 35° front-right.
- ``sphere-backlit``: the same sphere with the sun at 5° behind it, below the horizon of every
  visible normal: where per-normal balancing of environment sampling (Lu 2013) should matter most.
- ``blob-sun``: a displaced icosphere of 327,680 triangles (bumps and dents, varied normals) for
  scale and normal variety.
- ``torus-sun``: a torus seen from above; inner faces point down and back at the tube.
- ``plane-grazing``: a plane tilted 20°, lit only by a small light 11° above its horizon (no sky)
  whose coarse cube-map cell (a quarter face) has its centre 6° below that horizon: the light is
  where a coarse model of the map says it cannot reach.

Built-in scenes with occlusion (visibility on, 32² cells a face: :mod:`iblbench.scenes.visibility`):

- ``sphere-ground``: the sphere resting on a ground plane under the sun and sky: a contact
  shadow, and the ground hiding the lower hemisphere.
- ``park-ground``: the same under the park photograph (below), its low sun casting a long shadow.
- ``torus-day``: the torus seen from above under ``day`` (below): the tube shadows the ring's
  inner side.

Built-in scenes lit by real HDR photographs (CC0, shipped in ``scenes/data/``, whose README gives
their origin and terms), same material and 128 × 128:

- ``sphere-park``: the sphere under Poly Haven's *Rooitou Park* (a low sun, 10° up, carrying
  most of the map's power, over a sky, trees and grass), seen from where the sun stands as
  sphere-sun's does: 60° to the right of the view.
- ``sphere-studio``: the sphere under *Studio Small 03* (small bright softboxes over a dark
  room), the brightest softbox placed the same way.

Built-in scenes lit by environment sequences (:mod:`iblbench.scenes.sequences`):

- ``blob-day``: the blob-sun blob (327,680 triangles, Phong m = 150) under ``day``, 67 frames of
  a solar day at 45° N on June 21 from nautical twilight to nautical twilight: the analogue of
  Lu et al. 2013, Fig. 1.
- ``torus-moving``: the torus-sun torus and camera under ``moving-lights`` (4 lights, 48 frames).
- ``sphere-switch``: the sphere-sun sphere and camera under ``switch`` (30 frames, a strong light
  on in frames 10..19).
- ``park-turn``: the sphere-park sphere and camera under a ``turntable`` of the park map (6
  frames, 1.41° of turn a frame), at 48 × 48 pixels with 32² cube faces by default: the short
  real-photograph sequence of the default sweep, where bis, smc and havran carry state across
  frames.
- ``blob-minutes``: the blob-day blob under ``minutes``, ``day``'s sun one frame a minute (24
  frames from 9:00 solar time): the smooth case for temporal reuse.
- ``sphere-studio-moving``: sphere-studio's sphere and camera under ``light-moving`` of the
  studio photograph (its key softbox turned 2° a frame over the room, 16 frames), 48 × 48, 32².
- ``sphere-park-switch``: sphere-park's sphere and camera under ``light-switch`` of the park
  photograph (its sun off in frames 4..7 of 12), 48 × 48, 32².

User scene format (paths are relative to the TOML file's folder)::

    [mesh]
    path = "bunny.obj"              # required: OBJ, PLY or GLB (multi-object files are merged)
    up = "z"                        # optional: "y" (default) or "z"; "z" stands a Z-up mesh up
                                    # by turning it -90° about X: (x, y, z) -> (x, z, -y)
    scale = 0.01                    # optional: a positive number or three (x, y, z)
    rotate = [0.0, 90.0, 0.0]       # optional: degrees about X, then Y, then Z (fixed axes,
                                    # right-handed: 90° about Y takes +X to -Z)
    translate = [0.0, -0.5, 0.0]    # optional
                                    # applied in this order: up, scale, rotate, translate

    [environment]
    path = "sky.exr"                # required: EXR/HDR lat-long or cross, "sky_{face}.exr" for six
                                    # faces (px, nx, py, ny, pz, nz), a .npy [6,R,R,3], or a glob
                                    # ("day/*.exr") for a sequence, frames in sorted name order
    layout = "auto"                 # optional: auto, latlong, vcross, hcross or faces
    res = 64                        # optional cube face resolution, at most 4096 (default: the
                                    # source's own)

    [material]                      # optional; defaults kd = 0.5, ks = 0.3, shininess = 150
    kd = [0.6, 0.5, 0.4]            # a number or an RGB triple; kd + ks <= 1 per channel
    ks = 0.2
    shininess = 80                  # at most 1e6

    [camera]
    eye = [0.0, 0.5, 3.0]           # required; camera (and mesh) coordinates within ±1e9
    target = [0.0, 0.0, 0.0]        # required
    up = [0.0, 1.0, 0.0]            # optional
    fov_y = 45.0                    # optional, full vertical field of view in degrees

    [render]                        # optional
    width = 128                     # each side at most 16384
    height = 128
    visibility = true               # optional (default false): shadows, V(x, ω) traced by Embree
    visibility_res = 32             # optional (default 32, or the largest power of two below
                                    # it dividing the face size): cells per cube-face side of
                                    # the visibility masks, a power of two dividing the face size

Unknown sections or keys are errors (they are usually typos).  Every problem is an ``InputError``
naming the TOML file, or the referenced file when that file is the problem.
"""
from __future__ import annotations

import dataclasses
import functools
import glob
import math
import os
from importlib.resources import files
from pathlib import Path
from typing import Any, Callable

import numpy as np

from . import meshes, sequences, sky
from .envmap import LAYOUTS, MAX_RES, load_environment
from iblbench.foundation.errors import InputError
from .scene import Camera, EnvSequence, Material, Scene
from iblbench.foundation.tomlfile import read_toml
from .visibility import check_resolution, default_resolution

DEFAULT_ENV_RES = 64
# Bounds that only a corrupt or mistyped scene file exceeds; past them a run would exhaust memory
# or overflow float32 on the device.
MAX_IMAGE_SIDE = 16384
MAX_SHININESS = 1e6


_MATERIAL = Material(kd=(0.5, 0.5, 0.5), ks=(0.3, 0.3, 0.3), shininess=150.0)

# Sun low behind the sphere-backlit sphere: elevation 5°, azimuth 180° (towards −Z, away from the
# camera at +Z).
BACKLIT_SUN_ELEVATION_DEG = 5.0
BACKLIT_SUN_AZIMUTH_DEG = 180.0


def _sun_sky_scene(name: str, mesh, camera: Camera, env_res: int | None, **sun) -> Scene:
    """A static Preetham sun + sky scene with the default material at 128 × 128."""
    env = sky.sun_sky(res=env_res or DEFAULT_ENV_RES, **sun)
    return Scene(
        name=name,
        mesh=mesh,
        material=_MATERIAL,
        camera=camera,
        environment=EnvSequence.static(env, source="preetham-sun-sky"),
        resolution=(128, 128),
        source=f"builtin:{name}",
    )


def _camera_facing_light(light_azimuth_deg: float) -> Camera:
    """sphere-sun's camera (3 from the origin, level, 45° fov) turned about +Y so that a light at
    ``light_azimuth_deg`` (sky azimuth: 0° → +Z, 90° → +X) stands where sphere-sun's sun does,
    ``sky.DEFAULT_SUN_AZIMUTH_DEG`` to the right of the view."""
    azimuth = math.radians(light_azimuth_deg - sky.DEFAULT_SUN_AZIMUTH_DEG)
    return Camera(eye=(3.0 * math.sin(azimuth), 0.0, 3.0 * math.cos(azimuth)),
                  target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)


def _sphere_sun(env_res: int | None) -> Scene:
    """The baseline: a smooth sphere, the sun at 35° elevation front-right (its lit side is partly visible)."""
    # The unit sphere spans 87% of the frame height from (0, 0, 3) with a 45° vertical fov.
    camera = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sun_sky_scene("sphere-sun", meshes.sphere(), camera, env_res)


def _sphere_backlit(env_res: int | None) -> Scene:
    """The sphere-sun sphere and camera with the sun low (5°) and behind the sphere.

    From 3 radii away only normals with n_z > 1/3 are visible, and for all of them the sun is below
    the horizon (n·sun <= 0.087·0.943 − 0.996/3 ≈ −0.25, i.e. at least 14° below).  All the light
    reaching the camera comes from the dim sky and ground while nearly all the environment's power
    is in the sun: the case where balancing environment sampling per normal (Lu et al. 2013) should
    matter most, and where plain environment-importance sampling wastes most of its samples.
    """
    camera = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sun_sky_scene(
        "sphere-backlit", meshes.sphere(), camera, env_res,
        sun_elevation_deg=BACKLIT_SUN_ELEVATION_DEG, sun_azimuth_deg=BACKLIT_SUN_AZIMUTH_DEG,
    )


def _blob_sun(env_res: int | None) -> Scene:
    """A displaced icosphere of 327,680 triangles under the sphere-sun sky.

    Tests scale (a G-buffer and BVH over > 100k triangles) and normal variety: its bumps and dents
    give concave regions and rapidly varying normals, so neighbouring pixels see the sun at very
    different angles, unlike the smooth sphere.
    """
    # The blob's radius is within 0.885..1.119; from 3 away its silhouette is at most 21.9° off
    # axis, inside the 22.5° half fov: it covers 57% of the frame and is nowhere cut.
    camera = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sun_sky_scene("blob-sun", meshes.blob(), camera, env_res)


def _builtin_visibility_res(env_res: int | None) -> int:
    """A built-in scene's Rv: :func:`.visibility.default_resolution` of its faces (32 at the
    default face size; under ``--env-res`` R at most R)."""
    return default_resolution(env_res or DEFAULT_ENV_RES)


def _sphere_ground(env_res: int | None) -> Scene:
    """The sphere resting on a ground plane under the default sun-and-sky, seen from above the
    front: the sphere's contact shadow on the ground (sharp from the sun, soft from the sky), and
    the ground occluding the sphere's lower hemisphere.  Visibility on (32² cells a face)."""
    camera = Camera(eye=(0.0, 2.0, 4.2), target=(0.0, -0.6, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    scene = _sun_sky_scene("sphere-ground", meshes.on_ground(meshes.sphere()), camera, env_res)
    return dataclasses.replace(scene, visibility=True, visibility_res=_builtin_visibility_res(env_res))


def _torus_sun(env_res: int | None) -> Scene:
    """A torus (ring radius 1, tube 0.4) lying in the XZ plane, seen from 34° above, default sky.

    A genus-1 shape: the inner side of the ring faces away from the sun and back towards the tube,
    giving normals that point down and inwards as well as the sphere's outward ones.
    """
    camera = Camera(eye=(0.0, 2.2, 3.3), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sun_sky_scene("torus-sun", meshes.torus(), camera, env_res)


# plane-grazing: a plane tilted 20° about Z (its normal n = (sin 20°, cos 20°, 0)) lit only by a
# sun-sized light on the +X face at face point (u, v) = (−0.15, 0.15): 11.3° above the plane's
# horizon, while the centre (−0.5, 0.5) of its quarter of the face, the cell of the coarsest
# level of at most 2 × 2 cells a face (restir's target scales), lies 6.0° below it; the light's
# texels stay above it at every face size from 4².
GRAZING_TILT_DEG = 20.0
GRAZING_LIGHT = (1.0, -0.15, 0.15)   # unnormalised: the +X face's point (u, v) = (−0.15, 0.15)
GRAZING_LIGHT_POWER = 3.0            # Σ Y·Ω of the light


def _plane_grazing(env_res: int | None) -> Scene:
    """A plane tilted 20°, lit only by a small light 11° above its horizon whose coarse cube-map
    cell (a quarter face) has its centre 6° below it: where a model of the map by coarse cells
    (restir's target scales) sees no light that reaches the plane."""
    res = env_res or DEFAULT_ENV_RES
    light = np.asarray(GRAZING_LIGHT) / np.linalg.norm(GRAZING_LIGHT)
    solid_angle = 2.0 * math.pi * (1.0 - math.cos(math.radians(sky.SUN_ANGULAR_RADIUS_DEG)))
    env = sky.sun_disc(res, light, sky.sun_rgb(GRAZING_LIGHT_POWER / solid_angle)).astype(np.float32)
    env.flags.writeable = False
    plane = meshes.transform_mesh(meshes.ground(height=0.0), meshes.rotation_xyz((0.0, 0.0, -GRAZING_TILT_DEG)),
                                  (0.0, 0.0, 0.0))
    # Seen from 30° off its normal, towards +Z: the plane fills the frame.
    camera = Camera(eye=(1.03, 2.82, 1.5), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return Scene(name="plane-grazing", mesh=plane, material=_MATERIAL, camera=camera,
                 environment=EnvSequence.static(env, source="builtin:grazing-light"),
                 resolution=(128, 128), source="builtin:plane-grazing")


# --- real photographs ---------------------------------------------------------------------------

PARK_MAP = "rooitou_park_1k.hdr"
STUDIO_MAP = "studio_small_03_1k.hdr"
# Sky azimuths (0° → +Z, 90° → +X) of each map's brightest pixel, read off the files: the park's
# sun at row 226, column 614 of 512 × 1024 (10.4° up); the studio's softbox at row 133, column
# 235 (43° up).  tests/test_photo_scenes.py checks them against the loaded cube maps.
PARK_SUN_AZIMUTH_DEG = 144.0
STUDIO_LIGHT_AZIMUTH_DEG = -82.8
# The luminance at which sphere-park-switch and sphere-studio-moving take a photograph's light out
# (scenes/photo_lights.py): the park's sun (315 pixels, 67% of Σ Y·Ω; the sky around it stays,
# below 10), the studio's key softbox with its glow down to where the dark room begins (2,404
# pixels, 72%; at 10 the fill kept a grey disc of luminance 7 where the box was).
PARK_SUN_THRESHOLD = 10.0
STUDIO_LIGHT_THRESHOLD = 0.2
# park-turn: few frames at low resolution keep the default sweep's temporal cells cheap (bis and
# smc at 256 spp cost seconds a frame at 128²); 32² faces also cut each frame's host resample to
# a quarter of a 64² one (0.7 against 2.6 s: the sub-sample count per texel is capped, so 64²
# costs 4× the samples).
PARK_TURN_RESOLUTION = (48, 48)
# park-ground: the ground fills most of the frame (twice sphere-park's covered pixels at 128²).
PARK_GROUND_RESOLUTION = (96, 96)
PARK_TURN_ENV_RES = 32


def shipped_map(file_name: str) -> str:
    """The path of a map shipped in ``scenes/data`` (package data, see its README)."""
    return os.fspath(files("iblbench.scenes") / "data" / file_name)


@functools.lru_cache(maxsize=8)
def _shipped_environment(file_name: str, res: int) -> np.ndarray:
    """A shipped lat-long map as a read-only cube map, resampled once per process (seconds at 64²)."""
    env, _report = load_environment(shipped_map(file_name), layout="latlong", res=res)
    env.flags.writeable = False
    return env


def _photo_scene(name: str, file_name: str, light_azimuth_deg: float, env_res: int | None) -> Scene:
    # 64² faces by default, as the sky scenes: the park's sun (0.5° across) stays within about one
    # 1.4° texel, 14,700× the map's mean luminance (4,100× at 32², where it would be easier to
    # find), while the reference (4 s at 128², loaded) and the per-frame builds stay small.
    env = _shipped_environment(file_name, env_res or DEFAULT_ENV_RES)
    return Scene(name=name, mesh=meshes.sphere(), material=_MATERIAL,
                 camera=_camera_facing_light(light_azimuth_deg),
                 environment=EnvSequence.static(env, source=f"shipped:{file_name}"),
                 resolution=(128, 128), source=f"builtin:{name}")


def _sphere_park(env_res: int | None) -> Scene:
    """The sphere under Poly Haven's Rooitou Park (CC0), the low sun 60° right of the view.

    A real outdoor map: the sun's few texels carry most of the power (the brightest 0.1% of the
    lat-long's pixels, 69% of Σ Y·Ω), the rest is a bright sky over trees and grass, so both light
    and BRDF sampling have something to find.
    """
    return _photo_scene("sphere-park", PARK_MAP, PARK_SUN_AZIMUTH_DEG, env_res)


def _park_ground(env_res: int | None) -> Scene:
    """sphere-park's sphere resting on a ground plane, camera raised to see its shadow: the park's
    low sun casts a long shadow, the ground hides the photographed grass below the horizon.
    Visibility on (32² cells a face)."""
    camera = _camera_facing_light(PARK_SUN_AZIMUTH_DEG)
    eye = np.array(camera.eye) * 1.4 + (0.0, 2.0, 0.0)
    camera = dataclasses.replace(camera, eye=tuple(eye), target=(0.0, -0.6, 0.0))
    env = _shipped_environment(PARK_MAP, env_res or DEFAULT_ENV_RES)
    return Scene(name="park-ground", mesh=meshes.on_ground(meshes.sphere()), material=_MATERIAL,
                 camera=camera, environment=EnvSequence.static(env, source=f"shipped:{PARK_MAP}"),
                 resolution=PARK_GROUND_RESOLUTION, source="builtin:park-ground", visibility=True,
                 visibility_res=_builtin_visibility_res(env_res))


def _sphere_studio(env_res: int | None) -> Scene:
    """The sphere under Poly Haven's Studio Small 03 (CC0): small bright softboxes, dark room.

    The brightest 1% of the lat-long's pixels carry 89% of Σ Y·Ω, spread over several boxes.
    """
    return _photo_scene("sphere-studio", STUDIO_MAP, STUDIO_LIGHT_AZIMUTH_DEG, env_res)


# The environment sequence of each built-in sequence scene, and its default cube face size; every
# other built-in scene is static.
_SEQUENCES: dict[str, tuple[Callable[[int], EnvSequence], int]] = {
    "blob-day": (sequences.day, DEFAULT_ENV_RES),
    "torus-moving": (sequences.moving_lights, DEFAULT_ENV_RES),
    "sphere-switch": (sequences.switch, DEFAULT_ENV_RES),
    "torus-day": (sequences.day, DEFAULT_ENV_RES),
    "park-turn": (lambda res: sequences.turntable(shipped_map(PARK_MAP), res), PARK_TURN_ENV_RES),
    "blob-minutes": (sequences.minutes, DEFAULT_ENV_RES),
    "sphere-studio-moving": (lambda res: sequences.light_moving(
        shipped_map(STUDIO_MAP), STUDIO_LIGHT_THRESHOLD, res), PARK_TURN_ENV_RES),
    "sphere-park-switch": (lambda res: sequences.light_switch(
        shipped_map(PARK_MAP), PARK_SUN_THRESHOLD, res), PARK_TURN_ENV_RES)}


def _sequence_scene(name: str, mesh, camera: Camera, env_res: int | None,
                    resolution: tuple[int, int] = (128, 128)) -> Scene:
    sequence, default_res = _SEQUENCES[name]
    return Scene(name=name, mesh=mesh, material=_MATERIAL, camera=camera,
                 environment=sequence(env_res or default_res),
                 resolution=resolution, source=f"builtin:{name}")


def _blob_day(env_res: int | None) -> Scene:
    """The blob-sun blob and camera under the 67-frame ``day`` sequence (Lu 2013, Fig. 1)."""
    camera = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sequence_scene("blob-day", meshes.blob(), camera, env_res)


def _torus_day(env_res: int | None) -> Scene:
    """The torus seen from above under ``day``: the ring's inner side is shadowed by the tube
    across it as the sun moves.  Visibility on (32² cells a face)."""
    camera = Camera(eye=(0.0, 3.2, 1.8), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return dataclasses.replace(_sequence_scene("torus-day", meshes.torus(), camera, env_res),
                               visibility=True, visibility_res=_builtin_visibility_res(env_res))


def _torus_moving(env_res: int | None) -> Scene:
    """The torus-sun torus and camera under ``moving-lights``."""
    camera = Camera(eye=(0.0, 2.2, 3.3), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sequence_scene("torus-moving", meshes.torus(), camera, env_res)


def _sphere_switch(env_res: int | None) -> Scene:
    """The sphere-sun sphere and camera under ``switch`` (light on in frames 10..19)."""
    camera = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sequence_scene("sphere-switch", meshes.sphere(), camera, env_res)


def _park_turn(env_res: int | None) -> Scene:
    """The sphere-park sphere and camera under a 6-frame turntable of the park map, 48 × 48."""
    return _sequence_scene("park-turn", meshes.sphere(), _camera_facing_light(PARK_SUN_AZIMUTH_DEG),
                           env_res, PARK_TURN_RESOLUTION)


def _blob_minutes(env_res: int | None) -> Scene:
    """The blob-day blob and camera under ``minutes``: day's sun one frame a minute from 9:00
    solar time (47.7° up, 75° to the right), moving 0.23° a frame (0.19-0.21 texels at 64²)."""
    camera = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=45.0)
    return _sequence_scene("blob-minutes", meshes.blob(), camera, env_res)


def _sphere_studio_moving(env_res: int | None) -> Scene:
    """sphere-studio's sphere and camera under ``light-moving`` of the studio photograph: its key
    softbox and its glow taken out (20.1 of the map's 27.9 in Σ Y·Ω, 72%) and turned 2° a frame over the
    filled room, from 60° to 90° right of the view over 16 frames; 48 × 48, 32² faces."""
    return _sequence_scene("sphere-studio-moving", meshes.sphere(),
                           _camera_facing_light(STUDIO_LIGHT_AZIMUTH_DEG), env_res,
                           PARK_TURN_RESOLUTION)


def _sphere_park_switch(env_res: int | None) -> Scene:
    """sphere-park's sphere and camera under ``light-switch`` of the park photograph: the sun
    (6.37 of the map's 9.50 in Σ Y·Ω, 67%) on in frames 0-3 and 8-11, off (a sky of 3.12)
    in frames 4-7; 48 × 48, 32² faces."""
    return _sequence_scene("sphere-park-switch", meshes.sphere(),
                           _camera_facing_light(PARK_SUN_AZIMUTH_DEG), env_res,
                           PARK_TURN_RESOLUTION)


# Every built-in scene: kd = 0.5, ks = 0.3, shininess = 150; 128 × 128 but park-turn and the
# photographed sequences (48 × 48); the *-sun ones static Preetham sun + sky, the *-park and
# *-studio ones shipped photographs, plane-grazing one small light; cube faces DEFAULT_ENV_RES² (park-turn, sphere-studio-moving
# and sphere-park-switch: PARK_TURN_ENV_RES²) unless env_res says otherwise.
BUILTIN_SCENES: dict[str, Callable[[int | None], Scene]] = {
    "sphere-sun": _sphere_sun,
    "sphere-backlit": _sphere_backlit,
    "blob-sun": _blob_sun,
    "torus-sun": _torus_sun,
    "plane-grazing": _plane_grazing,
    "blob-day": _blob_day,
    "torus-moving": _torus_moving,
    "sphere-switch": _sphere_switch,
    "sphere-park": _sphere_park,
    "sphere-ground": _sphere_ground,
    "park-ground": _park_ground,
    "torus-day": _torus_day,
    "sphere-studio": _sphere_studio,
    "park-turn": _park_turn,
    "blob-minutes": _blob_minutes,
    "sphere-studio-moving": _sphere_studio_moving,
    "sphere-park-switch": _sphere_park_switch,
}


def scene_names() -> list[str]:
    return sorted(BUILTIN_SCENES)


def builtin_frames(name: str) -> int:
    """A built-in scene's frame count, without building its mesh or environment."""
    entry = _SEQUENCES.get(name.lower())
    return entry[0](entry[1]).num_frames if entry else 1


def builtin_scene(name: str, env_res: int | None = None) -> Scene:
    """A built-in scene by case-insensitive name; an unknown name lists the valid ones."""
    factory = BUILTIN_SCENES.get(name.lower())
    if factory is None:
        raise InputError(None, f"unknown scene {name!r}; valid scenes: {', '.join(scene_names())}")
    return factory(env_res)


def load_scene(name_or_path: str | os.PathLike, sanitize: bool = False, env_res: int | None = None) -> Scene:
    """A built-in scene by name, or a user scene from a ``.toml`` file.

    ``env_res`` overrides the environment's cube face resolution; ``sanitize`` lets the environment
    loader repair NaN, Inf and negative texels instead of refusing them.
    """
    text = os.fspath(name_or_path)
    if _is_toml(text):
        return _toml_scene(Path(text), sanitize, env_res)
    return builtin_scene(text, env_res)


def scene_entry(name_or_path: str | os.PathLike) -> str:
    """A scene as a run records it: a TOML path made absolute, so that the record names the same
    file from any working directory; a built-in name as given."""
    text = os.fspath(name_or_path)
    return os.path.abspath(text) if _is_toml(text) else text


def _is_toml(text: str) -> bool:
    return text.lower().endswith(".toml")


# --- TOML scenes -------------------------------------------------------------------------------

_SECTIONS = {
    "mesh": ({"path"}, {"up", "scale", "rotate", "translate"}),
    "environment": ({"path"}, {"layout", "res"}),
    "material": (set(), {"kd", "ks", "shininess"}),
    "camera": ({"eye", "target"}, {"up", "fov_y"}),
    "render": (set(), {"width", "height", "visibility", "visibility_res"}),
}


def _section_problem(section: str, table: Any) -> str | None:
    """What is wrong with the keys of one scene table, or None."""
    if not isinstance(table, dict):
        return f"[{section}] must be a table"
    required, optional = _SECTIONS[section]
    unknown = set(table) - required - optional
    if unknown:
        return (f"unknown key {sorted(unknown)[0]!r} in [{section}]; valid keys: "
                f"{', '.join(sorted(required | optional))}")
    missing = required - set(table)
    return f"missing required key {sorted(missing)[0]!r} in [{section}]" if missing else None


def scene_key_problem(document: dict) -> str | None:
    """The first problem with a scene document's sections and keys (unknown or missing), or
    None: what a scene file or a Python API scene dict is checked against before anything else."""
    unknown = set(document) - set(_SECTIONS)
    if unknown:
        return f"unknown section [{sorted(unknown)[0]}]; valid sections: {', '.join(_SECTIONS)}"
    for section in ("mesh", "environment", "camera"):
        if section not in document:
            return f"missing required section [{section}]"
    return next(filter(None, (_section_problem(section, table) for section, table in document.items())), None)


class _Fields:
    """Typed access to one TOML table whose keys scene_key_problem has checked; every problem is
    an InputError naming the TOML file."""

    def __init__(self, toml_path: Path, section: str, table: dict):
        self.toml_path, self.section, self.table = toml_path, section, table

    def fail(self, problem: str):
        raise InputError(self.toml_path, problem)

    def has(self, key: str) -> bool:
        return key in self.table

    def _where(self, key: str) -> str:
        return f"{self.section}.{key}"

    def number(self, key: str, minimum: float | None = None, maximum: float | None = None) -> float:
        value = self.table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            self.fail(f"{self._where(key)} must be a finite number, got {value!r}")
        if minimum is not None and value < minimum:
            self.fail(f"{self._where(key)} must be >= {minimum}, got {value!r}")
        if maximum is not None and value > maximum:
            self.fail(f"{self._where(key)} must be <= {maximum:g}, got {value!r}")
        return float(value)

    def positive_int(self, key: str, maximum: int) -> int:
        value = self.table[key]
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            self.fail(f"{self._where(key)} must be a positive integer, got {value!r}")
        if value > maximum:
            self.fail(f"{self._where(key)} must be at most {maximum}, got {value!r}")
        return value

    def boolean(self, key: str) -> bool:
        value = self.table[key]
        if not isinstance(value, bool):
            self.fail(f"{self._where(key)} must be true or false, got {value!r}")
        return value

    def string(self, key: str) -> str:
        value = self.table[key]
        if not isinstance(value, str) or not value:
            self.fail(f"{self._where(key)} must be a non-empty string, got {value!r}")
        return value

    def vector(self, key: str, limit: float | None = None) -> tuple[float, float, float]:
        value = self.table[key]
        if not (isinstance(value, list) and len(value) == 3) or not all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in value
        ):
            self.fail(f"{self._where(key)} must be a list of 3 finite numbers, got {value!r}")
        if limit is not None and max(abs(c) for c in value) > limit:
            self.fail(f"{self._where(key)} must lie within ±{limit:g}, got {value!r}")
        return tuple(float(c) for c in value)

    def rgb(self, key: str) -> tuple[float, float, float]:
        """A number (grey) or an RGB triple, each channel >= 0."""
        value = self.table[key]
        rgb = (self.number(key),) * 3 if not isinstance(value, list) else self.vector(key)
        if min(rgb) < 0:
            self.fail(f"{self._where(key)} must be non-negative, got {value!r}")
        return rgb


def _toml_scene(path: Path, sanitize: bool, env_res: int | None) -> Scene:
    document = read_toml(path, "scene file")
    problem = scene_key_problem(document)
    if problem:
        raise InputError(path, problem)
    fields = {section: _Fields(path, section, document.get(section, {})) for section in _SECTIONS}
    folder = path.parent
    material = _material(fields["material"])
    camera = _camera(fields["camera"])
    environment = _environment(fields["environment"], folder, sanitize, env_res)
    mesh_path = folder / fields["mesh"].string("path")
    mesh = _placed_mesh(fields["mesh"], meshes.load_mesh(mesh_path))
    render = fields["render"]
    resolution = tuple(render.positive_int(k, MAX_IMAGE_SIDE) if render.has(k) else 128
                       for k in ("width", "height"))
    visibility = render.boolean("visibility") if render.has("visibility") else False
    face = environment.frame(0).shape[1]
    visibility_res = (render.positive_int("visibility_res", MAX_RES) if render.has("visibility_res")
                      else default_resolution(face))
    if visibility:
        try:
            check_resolution(visibility_res, face, "render.visibility_res")
        except ValueError as error:
            render.fail(str(error))
    return Scene(path.stem, mesh, material, camera, environment, resolution, source=os.fspath(path),
                 mesh_source=os.fspath(mesh_path), visibility=visibility, visibility_res=visibility_res)


def _placed_mesh(fields: _Fields, mesh):
    """``mesh`` after the optional [mesh] up, scale, rotate and translate, in that order."""
    if not any(fields.has(key) for key in ("up", "scale", "rotate", "translate")):
        return mesh
    up = fields.string("up") if fields.has("up") else "y"
    if up not in ("y", "z"):
        fields.fail(f'mesh.up must be "y" or "z", got {up!r}')
    scale = np.ones(3)
    if fields.has("scale"):
        scale = (np.full(3, fields.number("scale")) if not isinstance(fields.table["scale"], list)
                 else np.array(fields.vector("scale")))
        if scale.min() <= 0.0:
            fields.fail(f"mesh.scale must be positive (a mirror would turn the mesh inside out), "
                        f"got {fields.table['scale']!r}")
    rotate = fields.vector("rotate") if fields.has("rotate") else (0.0, 0.0, 0.0)
    translate = fields.vector("translate", meshes.MAX_COORDINATE) if fields.has("translate") else (0.0, 0.0, 0.0)
    linear = meshes.rotation_xyz(rotate) @ np.diag(scale)
    if up == "z":
        linear = linear @ meshes.Z_UP_TO_Y_UP
    with np.errstate(over="ignore", invalid="ignore"):   # reported just below
        placed = meshes.transform_mesh(mesh, linear, translate)
    peak = float(np.abs(placed.vertices).max())
    if not peak <= meshes.MAX_COORDINATE:
        fields.fail(f"the placed mesh reaches {peak:g}; coordinates must stay within "
                    f"±{meshes.MAX_COORDINATE:g} (check mesh.scale and mesh.translate)")
    return placed


def _material(fields: _Fields) -> Material:
    default = Material()
    kd = fields.rgb("kd") if fields.has("kd") else default.kd
    ks = fields.rgb("ks") if fields.has("ks") else default.ks
    if max(d + s for d, s in zip(kd, ks)) > 1.0 + 1e-9:
        fields.fail(f"material kd + ks must be <= 1 per channel (energy conservation), got kd={kd}, ks={ks}")
    shininess = (fields.number("shininess", minimum=0.0, maximum=MAX_SHININESS)
                 if fields.has("shininess") else default.shininess)
    return Material(kd=kd, ks=ks, shininess=shininess)


def _camera(fields: _Fields) -> Camera:
    default = Camera()
    eye, target = (fields.vector(key, meshes.MAX_COORDINATE) for key in ("eye", "target"))
    up = fields.vector("up", meshes.MAX_COORDINATE) if fields.has("up") else default.up
    fov_y = fields.number("fov_y") if fields.has("fov_y") else default.fov_y
    if not 0.0 < fov_y < 180.0:
        fields.fail(f"camera.fov_y must be in (0, 180) degrees, got {fov_y}")
    forward = np.subtract(target, eye)
    if np.linalg.norm(forward) == 0.0:
        fields.fail("camera.eye and camera.target must differ")
    if np.linalg.norm(np.cross(forward, up)) == 0.0:
        fields.fail("camera.up must not be parallel to the viewing direction")
    return Camera(eye=eye, target=target, up=up, fov_y=fov_y)


def _environment(fields: _Fields, folder: Path, sanitize: bool, env_res: int | None) -> EnvSequence:
    """One environment, or a sequence when the path is a glob (frames in sorted name order).

    Frames are all loaded and validated here, so a bad frame is reported before any work starts.
    """
    pattern = os.fspath(folder / fields.string("path"))
    layout = fields.string("layout") if fields.has("layout") else "auto"
    if layout not in LAYOUTS:
        fields.fail(f"environment.layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    res = env_res or (fields.positive_int("res", MAX_RES) if fields.has("res") else None)
    paths = sorted(glob.glob(pattern)) if any(c in pattern for c in "*?") else [pattern]
    if not paths:
        fields.fail(f"environment.path {pattern!r} matches no files")
    frames, texels_fixed = [], 0
    for path in paths:
        env, report = load_environment(path, layout=layout, res=res, sanitize=sanitize)
        if frames and env.shape != frames[0].shape:
            raise InputError(
                path, f"frame faces are {env.shape[1]}² but {paths[0]} has {frames[0].shape[1]}²; set res to resample"
            )
        frames.append(env)
        texels_fixed += report.texels_fixed
    return EnvSequence(len(frames), frames.__getitem__, source=pattern, texels_fixed=texels_fixed)
