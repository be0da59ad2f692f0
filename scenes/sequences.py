"""Built-in environment sequences (ARCHITECTURE.md §Scenes and bad input): ``day``, ``minutes``, ``moving-lights``,
``switch`` and ``rotating-sun``, and of a lat-long image given by its path ``turntable``,
``light-moving`` and ``light-switch`` (the built-in scenes ``park-turn``, ``sphere-studio-moving``
and ``sphere-park-switch`` use the shipped photographs; scenes/registry.py names every sequence a
scene uses).

Every sequence is an :class:`EnvSequence` whose frames are made on demand by ``make_frame(index)``
and cached per (parameters, index), so a long sequence is never held whole and a frame asked for
twice is made once.  A frame that repeats an earlier one is returned as the *same* array object,
which lets the runner reuse that frame's FrameCache (ARCHITECTURE.md §Data flow: a static environment builds its
FrameCache once).  Units and coordinates are those of :mod:`iblbench.scenes.sky` (1.0 = 1 kcd/m²,
Y up, azimuth 0 → +Z, 90° → +X).

``day`` — 67 frames, like the 67 captures of a day in Lu et al. 2013, Fig. 1
    The sun follows the real solar path of latitude ``DAY_LATITUDE_DEG`` = 45° N on the June
    solstice (solar declination δ = +23.44°), in local apparent solar time from
    ``DAY_START_HOUR`` = 3:00 to ``DAY_END_HOUR`` = 21:00 in 67 equal steps (16.4 min apart).
    Hour angle H = 15°·(t − 12); elevation h from sin h = sin φ sin δ + cos φ cos δ cos H;
    compass azimuth A (from north, clockwise) from cos A = (sin δ − sin h sin φ)/(cos h cos φ),
    A > 180° in the afternoon.  The map's compass: +Z is south (the default camera at +Z looks
    north, so the midday sun lights the side it sees), +X east, −Z north, −X west, i.e.
    sky azimuth = 180° − A.  Sunrise is at 4:17 and sunset at 19:43 solar time; the first and
    last frames have the sun 10.2° below the horizon (nautical twilight).

    Sun above the horizon (h > 0): the Preetham sky of :func:`sky.sun_sky` (turbidity 3) plus the
    sun disc, whose luminance is SUN_LUMINANCE attenuated by the extra air mass relative to the
    zenith, exp(−DAY_OPTICAL_DEPTH·(m(h) − 1)) with Kasten & Young's (1989) air mass m(h), so the
    sun reddens-out and dims continuously towards the horizon instead of popping in at full power.
    Preetham is fitted for the sun above the horizon only, so the sky part always uses the sun at
    ``max(h, DAY_MIN_SKY_ELEVATION_DEG)`` (1°).

    Sun below the horizon (h ≤ 0), a documented twilight/night model, not Preetham: the sky of
    the sun at 1° (the same sky as at sunrise, so the map is continuous through h = 0), without
    the disc, scaled by ``10^(h / DAY_TWILIGHT_DECADE_DEG)`` (one decade of luminance per 2.5° of
    solar depression, roughly the fall of twilight illuminance from sunset to −12°) plus a
    floor ``DAY_NIGHT_FLOOR`` (1e-6: an airglow/starlight night sky, ~1 mcd/m²).  The night
    frames are therefore dim (~1e-4 of the sunset sky) but finite, non-negative and never all
    zero.  Total power Σ Y·Ω spans about six orders of magnitude over the day.

``minutes`` — ``day``'s sun one frame a minute: the smooth case for temporal reuse (issue 24)
    ``MINUTES_FRAMES`` = 24 frames of ``day``'s model (:func:`solar_frame`, the same sky, sun,
    air mass and twilight) at solar times ``MINUTES_START_HOUR`` = 9:00, 9:01, …, 9:23, June 21
    at 45° N: the sun climbs from 47.7° to 51.6° up at sky azimuth 74.7° to 69.1° (front right
    of the default camera), 15°·cos δ / 60 = 0.229° a frame, which at 64² faces (on +Y, near
    its edge) is 0.19–0.21 of a texel a frame, 4.6 texels over the sequence; Σ Y·Ω grows by
    0.05% a frame (179.8 to 181.7).  Frame 0 is ``day``'s frame 22 (3:00 + 22 · 18 h / 66).

``moving-lights`` — after Kronander et al.'s sequence of moving light sources
    ``MOVING_LIGHTS`` = 4 small bright discs (angular radius 4°, each of power 1.5 in Σ Y·Ω,
    about 10× the dim background's) in four colours, over a dim background (a vertical gradient,
    0.02 at the nadir to 0.05 at the zenith).  Light i moves on a smooth closed path with period
    ``MOVING_FRAMES`` = 48 frames: azimuth a_i + 360°·k_i·t/48 (k = 1, −1, 2, −1) and elevation
    e_i + 20°·sin(2π t/48 + φ_i), so consecutive frames move a light by at most ~16°.  The
    discs are splatted like the sun (:func:`sky.sun_disc`), so their power is the same at every
    cube resolution.

``switch`` — the hard case for temporal reuse
    ``SWITCH_FRAMES`` = 30 frames of a static dim sky (the default Preetham sky without its
    sun, × 0.05).  A strong light (a 2° disc at elevation 40°, azimuth 30°, power
    ``SWITCH_POWER_RATIO`` = 100× the background's) is on in frames
    ``SWITCH_ON`` = 10 … ``SWITCH_OFF`` − 1 = 19 and off otherwise.  Frames 0–9 and 20–29 are the
    same array object, and so are frames 10–19.

``rotating-sun`` — a map that changes smoothly, with no jump that would force a re-init
    A blue, asymmetric sky (its three channels vary differently with x, y and z, so no face is
    uniform) and a warm, soft sun (``ROTATING_SUN`` = elevation 35°, azimuth 60° at frame 0; a
    glow exp((cos θ − 1)/σ²) of width σ = 8° about it, power ``ROTATING_SUN_POWER`` = 4× the sky's
    Σ Y·Ω, peak ~400× the sky) turn together about the vertical axis by ``ROTATING_STEP_DEG`` = 1°
    per moving frame.  Every texel's radiance changes by at most ~30% a frame (the glow's flank at
    2σ), so a pixel's γ_t/γ_{t−1} stays bounded everywhere, far inside smc's ×4 re-init
    threshold.  (A hard disc would not be smooth: a texel that its edge reaches jumps from sky to
    sun, ×1000, in one frame.)
    Frames listed in ``ROTATING_HOLDS`` repeat the previous frame (the same array object), so one
    run passes both smc's continuing-frame path (Kronander Eq. 5/7/8) and its static-stretch
    path, right after the init (frame 1) and in mid-run.  ``ROTATING_FRAMES`` = 24.

``turntable`` — a real photograph turning: a lat-long HDR image about the vertical axis
    ``TURNTABLE_FRAMES`` = 6 frames; frame t is the image rolled by t·``TURNTABLE_STEP_COLUMNS``
    = 4 columns toward larger u, then resampled to the cube (:func:`envmap.resample_latlong`).
    A whole-column roll turns the panorama about +Y by exactly 360°·4/W (1.41° for the
    1024-wide shipped maps, 7° over the sequence; a light's sky azimuth falls by that much a
    frame) with no resampling of the source, so every frame holds the same pixels, only
    turned.  A small sun moves by about half a 32² cube texel a frame: the map changes
    smoothly, as under a camera panning beneath a fixed sky.

``light-moving`` — a photograph whose light moves (issue 24)
    The photograph's light is taken out (:mod:`.photo_lights`: the pixels at or above a
    luminance threshold within ``PHOTO_LIGHT_CAP_DEG`` = 15° of the brightest one, filled by
    harmonic interpolation of their surroundings) and splatted back turned by
    ``LIGHT_MOVING_STEP_DEG`` = 2° of sky azimuth a frame, ``LIGHT_MOVING_FRAMES`` = 16 frames
    (30° in all), over the remainder resampled once.  Σ Y·Ω is the same in every frame (the
    splat keeps the light's power exactly; the light adds to what it passes over).  On the
    studio photograph at threshold 0.2 (``sphere-studio-moving``): the key softbox and its glow,
    2,404 pixels carrying 20.1 of the map's 27.9 (72%), peak texel ~2,800 at 32² over a room of
    0.01–0.1; at 32² faces its power-weighted centre moves about 0.6 of a texel a frame, along
    the top edge of face −X and over onto +Y near the end.

``light-switch`` — a photograph whose light switches off and on (issue 24)
    The same separation; ``LIGHT_SWITCH_FRAMES`` = 12 frames, the light on in spells of
    ``LIGHT_SWITCH_SPELL`` = 4 (on in 0–3 and 8–11, off in 4–7).  Off frames are the remainder
    alone, in which no texel reaches the threshold (the harmonic fill never exceeds its
    boundary).  On frames are one array object, off frames another.  On the park photograph at
    threshold 10 (``sphere-park-switch``): the sun, 315 pixels carrying 6.37 of the map's 9.50
    (67%, peak texel 3,100 at 32²); off, the sky's 3.12 is left, brightest texel 9.5.
"""
from __future__ import annotations

import functools

import numpy as np

from . import cubemap, photo_lights, sky
from .envmap import resample_latlong
from .imageio import read_image
from .scene import EnvSequence

# ---- day --------------------------------------------------------------------------------------

DAY_FRAMES = 67
DAY_LATITUDE_DEG = 45.0
DAY_DATE = "June 21 (summer solstice)"
DAY_DECLINATION_DEG = 23.44
DAY_START_HOUR = 3.0     # local apparent solar time
DAY_END_HOUR = 21.0
DAY_TURBIDITY = 3.0
DAY_OPTICAL_DEPTH = 0.2            # broadband visible extinction per air mass
DAY_MIN_SKY_ELEVATION_DEG = 1.0    # the Preetham sky is evaluated with the sun at least this high
DAY_TWILIGHT_DECADE_DEG = 2.5      # one decade of sky luminance per 2.5° of solar depression
DAY_NIGHT_FLOOR = 1e-6             # kcd/m²: the night sky (airglow, stars)


def day_hours(frames: int = DAY_FRAMES) -> np.ndarray:
    """Local apparent solar time (hours) of each frame of ``day``."""
    return np.linspace(DAY_START_HOUR, DAY_END_HOUR, frames)


def solar_position(hour: float, latitude_deg: float = DAY_LATITUDE_DEG,
                   declination_deg: float = DAY_DECLINATION_DEG) -> tuple[float, float]:
    """(elevation, compass azimuth from north clockwise) in degrees at solar time ``hour``."""
    phi, delta = np.radians(latitude_deg), np.radians(declination_deg)
    hour_angle = np.radians(15.0 * (hour - 12.0))
    sin_h = np.sin(phi) * np.sin(delta) + np.cos(phi) * np.cos(delta) * np.cos(hour_angle)
    h = np.arcsin(np.clip(sin_h, -1.0, 1.0))
    cos_a = (np.sin(delta) - np.sin(h) * np.sin(phi)) / (np.cos(h) * np.cos(phi))
    azimuth = np.degrees(np.arccos(np.clip(cos_a, -1.0, 1.0)))
    if hour_angle > 0:
        azimuth = 360.0 - azimuth
    return float(np.degrees(h)), float(azimuth)


def day_sun(index: int) -> tuple[float, float]:
    """(elevation, sky azimuth) in degrees of the sun in frame ``index`` of ``day`` (sky.py's
    azimuth convention: 0 → +Z = south, 90° → +X = east)."""
    return sun_at(float(day_hours()[index]))


def sun_at(hour: float) -> tuple[float, float]:
    """(elevation, sky azimuth) in degrees of ``day``'s sun at solar time ``hour``: the map's
    compass puts south at +Z, so sky azimuth = 180° − compass azimuth."""
    elevation, compass = solar_position(hour)
    return elevation, (180.0 - compass) % 360.0


def air_mass(elevation_deg: float) -> float:
    """Kasten & Young (1989) relative optical air mass for the sun at ``elevation_deg`` ≥ 0."""
    h = max(float(elevation_deg), 0.0)
    return 1.0 / (np.sin(np.radians(h)) + 0.50572 * (h + 6.07995) ** -1.6364)


def twilight_scale(elevation_deg: float) -> float:
    """The sky's scale factor: 1 with the sun up, 10^(h/2.5°) below the horizon."""
    return 1.0 if elevation_deg > 0 else float(10.0 ** (elevation_deg / DAY_TWILIGHT_DECADE_DEG))


def day_frame(index: int, res: int) -> np.ndarray:
    """Frame ``index`` of ``day`` as ``[6, res, res, 3]`` float32 (see the module docstring)."""
    if not 0 <= index < DAY_FRAMES:
        raise IndexError(f"day has {DAY_FRAMES} frames, asked for {index}")
    return solar_frame(float(day_hours()[index]), res)


@functools.lru_cache(maxsize=256)
def solar_frame(hour: float, res: int) -> np.ndarray:
    """The sky and sun of ``day``'s solar model at solar time ``hour`` (the module docstring's
    ``day``), read-only float32 ``[6, res, res, 3]``."""
    elevation, azimuth = sun_at(hour)
    env = sky.sun_sky(res=res, sun_elevation_deg=max(elevation, DAY_MIN_SKY_ELEVATION_DEG),
                      sun_azimuth_deg=azimuth, turbidity=DAY_TURBIDITY, sun_luminance=0.0)
    env = env.astype(np.float64) * twilight_scale(elevation) + DAY_NIGHT_FLOOR
    if elevation > 0:
        luminance = sky.SUN_LUMINANCE * np.exp(-DAY_OPTICAL_DEPTH * (air_mass(elevation) - 1.0))
        env += sky.sun_disc(res, sky.sun_direction(elevation, azimuth), sky.sun_rgb(luminance))
    env = env.astype(np.float32)
    env.flags.writeable = False
    return env


def day(res: int = 64) -> EnvSequence:
    return EnvSequence(DAY_FRAMES, lambda index: day_frame(int(index), int(res)),
                       source=f"builtin:day ({DAY_LATITUDE_DEG:g}°N, {DAY_DATE}, "
                              f"{DAY_START_HOUR:g}h-{DAY_END_HOUR:g}h solar time)")


# ---- minutes ------------------------------------------------------------------------------------

MINUTES_FRAMES = 24
MINUTES_START_HOUR = 9.0   # local apparent solar time of frame 0
MINUTES_STEP_HOURS = 1.0 / 60.0


def minutes_hour(index: int) -> float:
    """Solar time (hours) of frame ``index`` of ``minutes``."""
    return MINUTES_START_HOUR + index * MINUTES_STEP_HOURS


def minutes_frame(index: int, res: int) -> np.ndarray:
    """Frame ``index`` of ``minutes``: ``day``'s sky and sun one minute after the last."""
    if not 0 <= index < MINUTES_FRAMES:
        raise IndexError(f"minutes has {MINUTES_FRAMES} frames, asked for {index}")
    return solar_frame(minutes_hour(index), res)


def minutes(res: int = 64) -> EnvSequence:
    return EnvSequence(MINUTES_FRAMES, lambda index: minutes_frame(int(index), int(res)),
                       source=f"builtin:minutes ({DAY_LATITUDE_DEG:g}°N, {DAY_DATE}, "
                              f"{MINUTES_FRAMES} frames a minute apart from "
                              f"{MINUTES_START_HOUR:g}h solar time)")


# ---- moving lights ----------------------------------------------------------------------------

MOVING_FRAMES = 48
MOVING_LIGHTS = 4
MOVING_RADIUS_DEG = 4.0
MOVING_POWER = 1.5            # Σ Y·Ω of each light
MOVING_AMPLITUDE_DEG = 20.0   # elevation swing
_MOVING_BASE = (  # (azimuth°, elevation°, azimuth turns per period, elevation phase, chromaticity)
    (0.0, 30.0, 1, 0.0, (0.64, 0.33)),
    (90.0, 50.0, -1, 1.3, (0.30, 0.60)),
    (200.0, 15.0, 2, 2.9, (0.15, 0.06)),
    (300.0, 60.0, -1, 4.4, (0.3127, 0.3290)),
)
MOVING_BACKGROUND = (0.02, 0.05)   # radiance at the nadir and the zenith (grey)


def moving_light_positions(t: float) -> list[tuple[float, float]]:
    """(elevation°, azimuth°) of each light at (possibly fractional) frame ``t``."""
    phase = 2.0 * np.pi * t / MOVING_FRAMES
    return [(e + MOVING_AMPLITUDE_DEG * np.sin(phase + p), (a + 360.0 * k * t / MOVING_FRAMES) % 360.0)
            for a, e, k, p, _ in _MOVING_BASE]


def _disc(res: int, direction: np.ndarray, radius_deg: float, power: float, xy) -> np.ndarray:
    """A coverage-splatted disc whose Σ Y·Ω is ``power``."""
    solid_angle = 2.0 * np.pi * (1.0 - np.cos(np.radians(radius_deg)))
    half = np.radians(radius_deg)
    face, row, col = cubemap.direction_to_texel(sky.cap_points(direction, half, 8192), res)
    share = np.zeros((6, res, res))
    np.add.at(share, (face, row, col), solid_angle / 8192)
    coverage = share / cubemap.texel_solid_angles(res)
    return coverage[..., None] * sky.xyY_to_rec709(*xy, power / solid_angle)


@functools.lru_cache(maxsize=16)
def _gradient_background(res: int, low: float, high: float) -> np.ndarray:
    up = cubemap.texel_directions(res)[..., 1]
    value = low + (high - low) * 0.5 * (1.0 + up)
    return np.repeat(value[..., None], 3, axis=-1)


@functools.lru_cache(maxsize=128)
def moving_lights_frame(index: int, res: int) -> np.ndarray:
    if not 0 <= index < MOVING_FRAMES:
        raise IndexError(f"moving-lights has {MOVING_FRAMES} frames, asked for {index}")
    env = _gradient_background(res, *MOVING_BACKGROUND).copy()
    for (elevation, azimuth), base in zip(moving_light_positions(index), _MOVING_BASE):
        env += _disc(res, sky.sun_direction(elevation, azimuth), MOVING_RADIUS_DEG, MOVING_POWER,
                     base[4])
    env = env.astype(np.float32)
    env.flags.writeable = False
    return env


def moving_lights(res: int = 64) -> EnvSequence:
    return EnvSequence(MOVING_FRAMES, lambda index: moving_lights_frame(int(index), int(res)),
                       source=f"builtin:moving-lights ({MOVING_LIGHTS} lights, {MOVING_FRAMES} frames)")


# ---- switch -----------------------------------------------------------------------------------

SWITCH_FRAMES = 30
SWITCH_ON = 10        # first frame with the light on
SWITCH_OFF = 20       # first frame with the light off again
SWITCH_BACKGROUND_SCALE = 0.05
SWITCH_POWER_RATIO = 100.0
SWITCH_LIGHT = (40.0, 30.0, 2.0)   # elevation°, azimuth°, angular radius°


def total_power(env: np.ndarray) -> float:
    """Σ Y·Ω over the cube map (luminance times texel solid angle)."""
    res = env.shape[1]
    return float(np.sum(cubemap.luminance(np.asarray(env, np.float64)) * cubemap.texel_solid_angles(res)))


@functools.lru_cache(maxsize=16)
def _switch_frames(res: int) -> tuple[np.ndarray, np.ndarray]:
    off = (sky.sun_sky(res=res, sun_luminance=0.0).astype(np.float64) * SWITCH_BACKGROUND_SCALE)
    elevation, azimuth, radius = SWITCH_LIGHT
    on = off + _disc(res, sky.sun_direction(elevation, azimuth), radius,
                     SWITCH_POWER_RATIO * total_power(off), sky.SUN_CHROMATICITY)
    frames = []
    for env in (off, on):
        env = env.astype(np.float32)
        env.flags.writeable = False
        frames.append(env)
    return frames[0], frames[1]


def switch_is_on(index: int) -> bool:
    return SWITCH_ON <= index < SWITCH_OFF


def switch_frame(index: int, res: int) -> np.ndarray:
    if not 0 <= index < SWITCH_FRAMES:
        raise IndexError(f"switch has {SWITCH_FRAMES} frames, asked for {index}")
    off, on = _switch_frames(res)
    return on if switch_is_on(index) else off


def switch(res: int = 64) -> EnvSequence:
    return EnvSequence(SWITCH_FRAMES, lambda index: switch_frame(int(index), int(res)),
                       source=f"builtin:switch (on {SWITCH_ON}..{SWITCH_OFF - 1} of {SWITCH_FRAMES})")


# ---- rotating sun -------------------------------------------------------------------------------

ROTATING_FRAMES = 24
ROTATING_STEP_DEG = 1.0
ROTATING_HOLDS = frozenset({1, 7, 8, 15})
ROTATING_SUN = (35.0, 60.0, 8.0)   # elevation°, azimuth° at frame 0, the glow's width σ°
ROTATING_SUN_POWER = 4.0           # × the sky's Σ Y·Ω


def rotating_angle(index: int) -> float:
    """The rotation (degrees of azimuth) of frame ``index``: one step per frame not held."""
    return ROTATING_STEP_DEG * sum(1 for t in range(1, index + 1) if t not in ROTATING_HOLDS)


def rotating_sky(directions: np.ndarray) -> np.ndarray:
    """The unrotated sky's radiance at unit ``directions`` ``[..., 3]``: blue, brighter up and
    towards +X, different in every channel and on every face."""
    x, y, z = np.moveaxis(np.asarray(directions, np.float64), -1, 0)
    return 0.1 * np.stack([0.35 + 0.15 * x + 0.1 * y * z, 0.55 + 0.25 * y + 0.1 * x * y,
                           1.0 + 0.4 * y - 0.2 * z + 0.15 * x * x], axis=-1)


@functools.lru_cache(maxsize=64)
def _rotating_frame_at(angle_deg: float, res: int) -> np.ndarray:
    theta = np.radians(angle_deg)
    x, y, z = np.moveaxis(cubemap.texel_directions(res), -1, 0)
    # The sky turned by θ in azimuth (azimuth = atan2(x, z)): look it up at the direction turned back.
    env = rotating_sky(np.stack([x * np.cos(theta) - z * np.sin(theta), y,
                                 z * np.cos(theta) + x * np.sin(theta)], axis=-1))
    elevation, azimuth, width = ROTATING_SUN
    cosine = np.stack([x, y, z], axis=-1) @ sky.sun_direction(elevation, azimuth + angle_deg)
    glow = np.exp((cosine - 1.0) / np.radians(width) ** 2)[..., None] * sky.xyY_to_rec709(*sky.SUN_CHROMATICITY, 1.0)
    env += glow * (ROTATING_SUN_POWER * total_power(env) / total_power(glow))
    env = env.astype(np.float32)
    env.flags.writeable = False
    return env


def rotating_sun_frame(index: int, res: int) -> np.ndarray:
    if not 0 <= index < ROTATING_FRAMES:
        raise IndexError(f"rotating-sun has {ROTATING_FRAMES} frames, asked for {index}")
    return _rotating_frame_at(rotating_angle(index), res)


def rotating_sun(res: int = 64) -> EnvSequence:
    return EnvSequence(ROTATING_FRAMES, lambda index: rotating_sun_frame(int(index), int(res)),
                       source=f"builtin:rotating-sun ({ROTATING_STEP_DEG:g}° a frame, "
                              f"held at {sorted(ROTATING_HOLDS)})")


# ---- turntable ---------------------------------------------------------------------------------

TURNTABLE_FRAMES = 6
TURNTABLE_STEP_COLUMNS = 4


@functools.lru_cache(maxsize=2)
def _latlong_image(path: str) -> np.ndarray:
    return read_image(path)


@functools.lru_cache(maxsize=64)
def turntable_frame(path: str, index: int, res: int) -> np.ndarray:
    """Frame ``index`` of the turntable of the lat-long image at ``path`` (module docstring)."""
    if not 0 <= index < TURNTABLE_FRAMES:
        raise IndexError(f"turntable has {TURNTABLE_FRAMES} frames, asked for {index}")
    image = np.roll(_latlong_image(path), index * TURNTABLE_STEP_COLUMNS, axis=1)
    env = resample_latlong(image, res)
    env.flags.writeable = False
    return env


def turntable(path: str, res: int = 32) -> EnvSequence:
    """The image is read on the first frame asked for, so a frame count costs nothing."""
    return EnvSequence(TURNTABLE_FRAMES, lambda index: turntable_frame(str(path), int(index), int(res)),
                       source=f"turntable of {path} ({TURNTABLE_STEP_COLUMNS} columns a frame)")



# ---- photographed lights: moving and switching --------------------------------------------------

PHOTO_LIGHT_CAP_DEG = 15.0
LIGHT_MOVING_FRAMES = 16
LIGHT_MOVING_STEP_DEG = 2.0
LIGHT_SWITCH_FRAMES = 12
LIGHT_SWITCH_SPELL = 4         # frames on, then as many off, and so on (on first)


def separated_light(path: str, threshold: float) -> photo_lights.SeparatedLight:
    """The photograph at ``path`` split at luminance ``threshold`` within PHOTO_LIGHT_CAP_DEG of
    its brightest pixel (:mod:`.photo_lights`)."""
    return photo_lights.separate(str(path), float(threshold), PHOTO_LIGHT_CAP_DEG)


@functools.lru_cache(maxsize=8)
def remainder_cube(path: str, threshold: float, res: int) -> np.ndarray:
    """The photograph without its light, as a float64 cube map."""
    return resample_latlong(separated_light(path, threshold).remainder, res).astype(np.float64)


def _read_only(env: np.ndarray) -> np.ndarray:
    env = env.astype(np.float32)
    env.flags.writeable = False
    return env


@functools.lru_cache(maxsize=64)
def _light_at(path: str, threshold: float, azimuth_deg: float, res: int) -> np.ndarray:
    light = separated_light(path, threshold)
    return _read_only(remainder_cube(path, threshold, res)
                      + photo_lights.light_cube(light, res, azimuth_deg))


def light_moving_frame(path: str, threshold: float, index: int, res: int) -> np.ndarray:
    """Frame ``index`` of ``light-moving``: the light turned by index · step over the remainder."""
    if not 0 <= index < LIGHT_MOVING_FRAMES:
        raise IndexError(f"light-moving has {LIGHT_MOVING_FRAMES} frames, asked for {index}")
    return _light_at(str(path), float(threshold), index * LIGHT_MOVING_STEP_DEG, int(res))


def light_moving(path: str, threshold: float, res: int = 32) -> EnvSequence:
    return EnvSequence(LIGHT_MOVING_FRAMES,
                       lambda index: light_moving_frame(path, threshold, int(index), res),
                       source=f"light-moving of {path} (light: luminance >= {threshold:g}; "
                              f"{LIGHT_MOVING_STEP_DEG:g}° a frame)")


def light_switch_is_on(index: int) -> bool:
    return (index // LIGHT_SWITCH_SPELL) % 2 == 0


@functools.lru_cache(maxsize=8)
def _light_off(path: str, threshold: float, res: int) -> np.ndarray:
    return _read_only(remainder_cube(path, threshold, res))


def light_switch_frame(path: str, threshold: float, index: int, res: int) -> np.ndarray:
    """Frame ``index`` of ``light-switch``: the photograph's light in place, or only the
    remainder; every on frame is one array object, and so is every off frame."""
    if not 0 <= index < LIGHT_SWITCH_FRAMES:
        raise IndexError(f"light-switch has {LIGHT_SWITCH_FRAMES} frames, asked for {index}")
    key = (str(path), float(threshold))
    return (_light_at(*key, 0.0, int(res)) if light_switch_is_on(index)
            else _light_off(*key, int(res)))


def light_switch(path: str, threshold: float, res: int = 32) -> EnvSequence:
    return EnvSequence(LIGHT_SWITCH_FRAMES,
                       lambda index: light_switch_frame(path, threshold, int(index), res),
                       source=f"light-switch of {path} (light: luminance >= {threshold:g}; "
                              f"{LIGHT_SWITCH_SPELL} frames on, {LIGHT_SWITCH_SPELL} off)")
