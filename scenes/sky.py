"""Analytic static sun + sky: Preetham, Shirley & Smits 1999, "A practical analytic model for daylight".

Sky (upper hemisphere)
    Each of Y, x, y follows the Perez distribution F(θ, γ) = (1 + A e^{B/cos θ})(1 + C e^{Dγ} + E cos²γ),
    with θ the view zenith angle and γ the angle to the sun, normalised at the zenith:
    value(θ, γ) = value_zenith · F(θ, γ) / F(0, θ_s).  The A..E are the paper's turbidity-linear fits
    (Appendix A.2); the zenith luminance is Y_z = (4.0453 T − 4.9710) tan χ − 0.2155 T + 2.4192 with
    χ = (4/9 − T/120)(π − 2θ_s), and the zenith chromaticities are the paper's cubics in θ_s and T.
    xyY → XYZ → linear Rec.709 (D65); out-of-gamut negatives are clamped to zero.

Ground (lower hemisphere)
    A constant grey-ish ground: GROUND_FRACTION × the azimuth-averaged sky radiance at the horizon
    (per channel).  It is constant so that it adds no structure of its own to the map.

Sun
    A disc of angular radius 0.2666° and luminance SUN_LUMINANCE (1.6e9 cd/m², the clear-sky sun
    near zenith), coloured with D50 chromaticity (warmer than the D65 white point).  The disc is
    splatted with a deterministic Fibonacci set of points uniform in solid angle over the cap, each
    carrying an equal share of the sun's power L_sun·Ω_sun, so a texel receives L_sun × (covered
    fraction) and Σ L·Ω of the sun is the same at every cube resolution.  The sky behind the disc is
    kept (it is ~1e-6 of the sun).

Units
    1.0 = 1 kcd/m² of luminance (the paper's unit for Y_z), so sky texels are O(1..10).

Coordinates
    Y is up.  ``sun_direction(elevation, azimuth)`` = (cos e·sin a, sin e, cos e·cos a): azimuth 0
    points to +Z (towards the default camera at +Z), azimuth 90° to +X.
"""
from __future__ import annotations

import numpy as np

from . import cubemap

SUN_ANGULAR_RADIUS_DEG = 0.2666
SUN_LUMINANCE = 1.6e6  # kcd/m² (1.6e9 cd/m²)
SUN_CHROMATICITY = (0.3457, 0.3585)  # CIE xy of D50: a warm white next to the D65 sky
GROUND_FRACTION = 0.3
SUN_SPLAT_POINTS = 4096

DEFAULT_SUN_ELEVATION_DEG = 35.0
DEFAULT_SUN_AZIMUTH_DEG = 60.0  # front-right of the default camera: the lit side is partly visible

# Perez coefficients (A..E) as (slope, intercept) in turbidity T: paper Appendix A.2.
_PEREZ_Y = np.array([[0.1787, -1.4630], [-0.3554, 0.4275], [-0.0227, 5.3251], [0.1206, -2.5771], [-0.0670, 0.3703]])
_PEREZ_X = np.array([[-0.0193, -0.2592], [-0.0665, 0.0008], [-0.0004, 0.2125], [-0.0641, -0.8989], [-0.0033, 0.0452]])
_PEREZ_SMALL_Y = np.array([[-0.0167, -0.2608], [-0.0950, 0.0092], [-0.0079, 0.2102], [-0.0441, -1.6537], [-0.0109, 0.0529]])

# Zenith chromaticity: [T², T, 1] · M · [θ_s³, θ_s², θ_s, 1]ᵀ (paper Appendix A.2).
_ZENITH_X = np.array([
    [0.00166, -0.00375, 0.00209, 0.0],
    [-0.02903, 0.06377, -0.03202, 0.00394],
    [0.11693, -0.21196, 0.06052, 0.25886],
])
_ZENITH_Y = np.array([
    [0.00275, -0.00610, 0.00317, 0.0],
    [-0.04214, 0.08970, -0.04153, 0.00516],
    [0.15346, -0.26756, 0.06670, 0.26688],
])

_XYZ_TO_REC709 = np.array([
    [3.2404542, -1.5371385, -0.4985314],
    [-0.9692660, 1.8760108, 0.0415560],
    [0.0556434, -0.2040259, 1.0572252],
])


def sun_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit direction towards the sun; Y up, azimuth 0 → +Z, azimuth 90° → +X."""
    e, a = np.radians(elevation_deg), np.radians(azimuth_deg)
    return np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])


def zenith_luminance(turbidity: float, sun_zenith: float) -> float:
    """Preetham's Y_z in kcd/m² for turbidity T and sun zenith angle θ_s (radians)."""
    chi = (4.0 / 9.0 - turbidity / 120.0) * (np.pi - 2.0 * sun_zenith)
    return (4.0453 * turbidity - 4.9710) * np.tan(chi) - 0.2155 * turbidity + 2.4192


def zenith_chromaticity(turbidity: float, sun_zenith: float) -> tuple[float, float]:
    """Preetham's zenith (x_z, y_z)."""
    t = np.array([turbidity**2, turbidity, 1.0])
    th = np.array([sun_zenith**3, sun_zenith**2, sun_zenith, 1.0])
    return float(t @ _ZENITH_X @ th), float(t @ _ZENITH_Y @ th)


def perez(coefficients: np.ndarray, cos_theta: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """F(θ, γ) for coefficients (A..E); cos θ is clipped above 0 so the horizon stays finite."""
    a, b, c, d, e = coefficients
    cos_theta = np.maximum(cos_theta, 1e-4)
    return (1.0 + a * np.exp(b / cos_theta)) * (1.0 + c * np.exp(d * gamma) + e * np.cos(gamma) ** 2)


def xyY_to_rec709(x, y, big_y) -> np.ndarray:
    """CIE xyY → linear Rec.709 RGB ``[..., 3]``, negatives (out of gamut) clamped to 0."""
    x, y, big_y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(big_y, float))
    xyz = np.stack([x / y * big_y, big_y, (1.0 - x - y) / y * big_y], axis=-1)
    return np.maximum(xyz @ _XYZ_TO_REC709.T, 0.0)


def sky_radiance(directions: np.ndarray, sun: np.ndarray, turbidity: float) -> np.ndarray:
    """Preetham sky RGB (kcd/m²) for unit directions ``[..., 3]`` in the upper hemisphere."""
    sun_zenith = np.arccos(np.clip(sun[1], -1.0, 1.0))
    gamma = np.arccos(np.clip(directions @ sun, -1.0, 1.0))
    cos_theta = directions[..., 1]
    values = []
    for table, zenith_value in zip(
        (_PEREZ_X, _PEREZ_SMALL_Y, _PEREZ_Y),
        (*zenith_chromaticity(turbidity, sun_zenith), zenith_luminance(turbidity, sun_zenith)),
    ):
        coefficients = table @ np.array([turbidity, 1.0])
        at_zenith = perez(coefficients, np.array(1.0), np.array(sun_zenith))
        values.append(zenith_value * perez(coefficients, cos_theta, gamma) / at_zenith)
    return xyY_to_rec709(*values)


def ground_radiance(sun: np.ndarray, turbidity: float) -> np.ndarray:
    """Constant ground RGB: GROUND_FRACTION × the azimuth-mean sky radiance at the horizon."""
    azimuths = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    horizon = np.stack([np.sin(azimuths), np.zeros_like(azimuths), np.cos(azimuths)], axis=-1)
    return GROUND_FRACTION * sky_radiance(horizon, sun, turbidity).mean(axis=0)


def sun_rgb(luminance: float) -> np.ndarray:
    """RGB of the sun disc with Rec.709 luminance ``luminance`` and SUN_CHROMATICITY."""
    return xyY_to_rec709(*SUN_CHROMATICITY, luminance)


def cap_points(axis: np.ndarray, half_angle: float, count: int) -> np.ndarray:
    """``count`` unit directions uniform in solid angle over a cap (Fibonacci spiral, deterministic)."""
    i = np.arange(count) + 0.5
    cos_alpha = 1.0 - (1.0 - np.cos(half_angle)) * i / count
    sin_alpha = np.sqrt(1.0 - cos_alpha**2)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    return (sin_alpha * np.cos(phi))[:, None] * u + (sin_alpha * np.sin(phi))[:, None] * v + cos_alpha[:, None] * axis


def sun_disc(res: int, sun: np.ndarray, radiance_rgb: np.ndarray) -> np.ndarray:
    """Coverage-weighted sun disc ``[6, R, R, 3]``: Σ L·Ω equals radiance × Ω_sun at any ``res``."""
    half_angle = np.radians(SUN_ANGULAR_RADIUS_DEG)
    sun_solid_angle = 2.0 * np.pi * (1.0 - np.cos(half_angle))
    face, row, col = cubemap.direction_to_texel(cap_points(sun, half_angle, SUN_SPLAT_POINTS), res)
    solid_angle_share = np.zeros((6, res, res))
    np.add.at(solid_angle_share, (face, row, col), sun_solid_angle / SUN_SPLAT_POINTS)
    coverage = solid_angle_share / cubemap.texel_solid_angles(res)
    return coverage[..., None] * radiance_rgb


def sun_sky(
    res: int = 64,
    sun_elevation_deg: float = DEFAULT_SUN_ELEVATION_DEG,
    sun_azimuth_deg: float = DEFAULT_SUN_AZIMUTH_DEG,
    turbidity: float = 3.0,
    sun_luminance: float = SUN_LUMINANCE,
) -> np.ndarray:
    """Preetham sky + ground + sun disc as a float32 cube map ``[6, res, res, 3]`` in kcd/m².

    ``sun_luminance=0`` gives the sky and ground alone.  The sun must be above the horizon.
    """
    if not 0.0 < sun_elevation_deg <= 90.0:
        raise ValueError(f"sun elevation {sun_elevation_deg}° must be in (0, 90]")
    sun = sun_direction(sun_elevation_deg, sun_azimuth_deg)
    directions = cubemap.texel_directions(res)
    above = directions[..., 1] > 0.0
    env = np.where(above[..., None], sky_radiance(directions, sun, turbidity), ground_radiance(sun, turbidity))
    env += sun_disc(res, sun, sun_rgb(sun_luminance))
    return env.astype(np.float32)
