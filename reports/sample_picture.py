"""Lu 2013 Fig. 1/2's sample picture: for one pixel, the unfolded cube map with the shared
light-sample pool drawn as not selected (red), selected (yellow) and effective (green).

Nothing here re-implements sampling, and nothing here opens a device: the run saved, per frame,
the pool the estimators read, ``FrameCache.light_pool(pool_size(spp), seed)``, and every pixel's
per-face split N_f(n) from the estimator's own ``split_strategies`` kernel
(:mod:`iblbench.harness.protocol.report_inputs`).  With the shared sequence (the pool estimators' default) a
pixel reads the first ⌈N_f(n)⌉ pool entries of face f, so those are "selected"; the rest of the
pool is "not selected"; a selected sample is "effective" when cos = n·ω > 0 (ARCHITECTURE.md §Conventions).
For ``balanced_mis`` the picture shows its light half (N_s/2 light samples split by Eq. 3); its
N_s/2 BRDF samples are drawn per pixel, not from the pool, and are not shown.
"""
from __future__ import annotations

import dataclasses
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import patheffects  # noqa: E402

from iblbench.harness.protocol.report_inputs import PoolPicture  # noqa: E402
from iblbench.reports.previews import srgb_encode  # noqa: E402
from iblbench.scenes import cubemap  # noqa: E402
from iblbench.foundation.atomic import atomic_path  # noqa: E402

COLOURS = {"not selected": "#e02020", "selected": "#ffd400", "effective": "#20c020"}
NORMAL_COLOUR = "#00e5ff"
CELL_PX = 96   # drawn pixels per cube face in the cross
_OUTLINE = [patheffects.withStroke(linewidth=2.2, foreground="black")]


@dataclasses.dataclass
class PoolSelection:
    """One estimator's view of the pool for one normal."""

    estimator: str
    spp: int
    ticks: np.ndarray            # [7] the split in ticks: six faces, then the BRDF
    selected_per_face: np.ndarray  # [6] pool entries read per face, ⌈N_f(n)⌉
    directions: np.ndarray       # [6·per_face, 3] the pool, face-major
    face: np.ndarray             # [6·per_face] face of each entry
    selected: np.ndarray         # [6·per_face] bool
    effective: np.ndarray        # [6·per_face] bool: selected and n·ω > 0
    valid: np.ndarray            # [6·per_face] bool: entry of a face with light (others unused)
    ticks_per_sample: int        # the split's fixed point

    @property
    def n_f(self) -> np.ndarray:
        """N_f(n) per face, fractional (the last sample's β is its fraction, Eq. 5)."""
        return self.ticks[:6] / self.ticks_per_sample

    @property
    def counts(self) -> dict[str, int]:
        return {"pool": int(self.valid.sum()), "selected": int(self.selected.sum()),
                "effective": int(self.effective.sum())}


def pool_selections(picture: PoolPicture, pixel: tuple[int, int],
                    normal: np.ndarray) -> list[PoolSelection]:
    """Which entries of the frame's saved pool (``picture``) the pixel ``(x, y)`` with the unit
    ``normal`` selects, for each estimator the run saved its split of."""
    x, y = pixel
    return [_selection(label, picture, ticks[y, x], normal)
            for label, ticks in picture.ticks.items()]


def _selection(label: str, picture: PoolPicture, ticks: np.ndarray,
               normal: np.ndarray) -> PoolSelection:
    per_face, unit = picture.per_face, picture.ticks_per_sample
    draws = np.minimum(-(-ticks[:6] // unit), per_face)
    face = np.repeat(np.arange(6), per_face)
    index = np.tile(np.arange(per_face), 6)
    valid = np.repeat(picture.face_integrals > 0, per_face)
    selected = valid & (index < draws[face])
    effective = selected & (picture.directions @ normal > 0)
    return PoolSelection(label, picture.spp, ticks, draws, picture.directions, face, selected,
                         effective, valid, unit)


# ---- the unfolded cube (a cross seen from the centre of the cube) -----------------------------

# Cross slots (column, row) of the centre face F and of its neighbours, with the frame
# (front, up) of each slot expressed in F, U (up) and R = F × U.
_SLOTS = {"centre": (1, 1), "left": (0, 1), "right": (2, 1), "back": (3, 1), "top": (1, 0),
          "bottom": (1, 2)}


def cross_frames(normal: np.ndarray) -> list[tuple[tuple[int, int], np.ndarray, np.ndarray, np.ndarray]]:
    """(slot, front, up, right) of the six faces in a cross centred on the normal's major-axis
    face, seen from inside the cube (as the pixel sees its sky); adjacent slots share edges."""
    axis = int(np.argmax(np.abs(normal)))
    front = np.zeros(3)
    front[axis] = np.sign(normal[axis]) or 1.0
    up = np.array([0.0, 1.0, 0.0]) if axis != 1 else np.array([0.0, 0.0, -front[1]])
    right = np.cross(front, up)
    frames = {"centre": (front, up), "left": (-right, up), "right": (right, up),
              "back": (-front, up), "top": (up, -front), "bottom": (-up, front)}
    return [(_SLOTS[k], f, u, np.cross(f, u)) for k, (f, u) in frames.items()]


def to_cross(directions: np.ndarray, frames) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cross coordinates (x right, y down; one unit per face) and slot index of directions."""
    d = np.atleast_2d(np.asarray(directions, np.float64))
    fronts = np.stack([f for _, f, _, _ in frames])
    slot = np.argmax(d @ fronts.T, axis=1)
    x, y = np.empty(len(d)), np.empty(len(d))
    for k, ((col, row), front, up, right) in enumerate(frames):
        m = slot == k
        depth = d[m] @ front
        x[m] = col + (d[m] @ right / depth + 1.0) / 2.0
        y[m] = row + (1.0 - d[m] @ up / depth) / 2.0
    return x, y, slot


def cross_image(env: np.ndarray, normal: np.ndarray, frames, cell: int = CELL_PX) -> np.ndarray:
    """RGBA cross of the tone-mapped environment (Reinhard, exposure 0.18 / solid-angle weighted
    log-average luminance), the half-space below the normal's horizon darkened."""
    env = np.asarray(env, np.float64)
    res = env.shape[1]
    omega = cubemap.texel_solid_angles(res)[None]
    lum = np.maximum(cubemap.luminance(env), 0.0)
    log_average = np.exp(np.sum(np.log(lum + 1e-6) * omega) / (6 * omega.sum()))
    k = 0.18 / log_average
    image = np.zeros((3 * cell, 4 * cell, 4))
    centres = (np.arange(cell) + 0.5) / cell * 2.0 - 1.0
    a, b = np.meshgrid(centres, -centres)        # a right, b up, rows top to bottom
    for (col, row), front, up, right in frames:
        d = front + a[..., None] * right + b[..., None] * up
        f, r, c = cubemap.direction_to_texel(d, res)
        rgb = k * env[f, r, c]
        y = rgb @ cubemap.LUMINANCE_WEIGHTS
        rgb = rgb * (1.0 / (1.0 + np.maximum(y, 0.0)))[..., None]
        rgb = srgb_encode(rgb)
        below = (d @ normal) <= 0
        rgb[below] *= 0.45
        image[row * cell:(row + 1) * cell, col * cell:(col + 1) * cell, :3] = rgb
        image[row * cell:(row + 1) * cell, col * cell:(col + 1) * cell, 3] = 1.0
    return image


def _horizon(ax, normal, frames) -> None:
    """The great circle n·ω = 0, drawn slot by slot."""
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    t = np.linspace(0.0, 2 * np.pi, 1441)
    x, y, slot = to_cross(np.cos(t)[:, None] * u + np.sin(t)[:, None] * v, frames)
    breaks = np.flatnonzero(np.diff(slot)) + 1
    for part in np.split(np.arange(len(t)), breaks):
        ax.plot(x[part], y[part], color="white", lw=1.0, path_effects=_OUTLINE)


def plot_sample_picture(path: pathlib.Path, env: np.ndarray, normal: np.ndarray,
                        selection: PoolSelection, background: np.ndarray | None = None) -> None:
    """One estimator's panel: the cross, the pool in three colours, the normal in cyan and its
    horizon.  ``background`` (from :func:`cross_image`) may be shared between panels."""
    normal = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    frames = cross_frames(normal)
    if background is None:
        background = cross_image(env, normal, frames)
    names = {tuple(f): cubemap.FACE_NAMES[i] for i, f in enumerate(
        [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])}
    fig, ax = plt.subplots(figsize=(6.4, 5.3))
    ax.imshow(background, extent=(0, 4, 3, 0), interpolation="nearest")
    for (col, row), front, _, _ in frames:
        ax.text(col + 0.04, row + 0.04, names[tuple(int(v) for v in front)], color="white",
                fontsize=9, va="top", path_effects=_OUTLINE)
    _horizon(ax, normal, frames)
    x, y, _ = to_cross(selection.directions, frames)
    groups = (("not selected", "not selected (beyond N_f(n))", selection.valid & ~selection.selected),
              ("selected", "selected, cos ≤ 0", selection.selected & ~selection.effective),
              ("effective", "selected, cos > 0 (effective)", selection.effective))
    for colour, label, mask in groups:
        ax.plot(x[mask], y[mask], "o", ms=3.6, mfc=COLOURS[colour], mec="black", mew=0.3,
                label=f"{label}: {int(mask.sum())}")
    nx, ny, _ = to_cross(normal, frames)
    ax.plot(nx, ny, "o", ms=9, mfc=NORMAL_COLOUR, mec="black", label="pixel normal n")
    ax.plot([], [], color="white", lw=1.0, path_effects=_OUTLINE,
            label="horizon of n (below: darkened)")
    c = selection.counts
    ax.set_title(f"{selection.estimator} @ {selection.spp} spp: {c['selected']} of {c['pool']} "
                 f"pool samples selected, {c['effective']} effective"
                 + ("\n(light half only; its BRDF samples are not from the pool)"
                    if selection.ticks[6] > 0 else ""), fontsize=10)
    ax.set_xlim(0, 4)
    ax.set_ylim(3, 0)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel("unfolded cube map seen from its centre (faces labelled; unitless)", fontsize=9)
    ax.legend(loc="lower right", fontsize=8, framealpha=0.95, borderaxespad=0.2)
    for side in ax.spines.values():
        side.set_visible(False)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)


__all__ = ["PoolSelection", "pool_selections", "plot_sample_picture", "cross_frames", "to_cross"]
