"""What a run saves for its report besides the images, so that ``iblbench report`` reads only the
run folder (no scene, tracer, device or estimator):

- ``inputs/<scene>/surface.npz``: the G-buffer's ``normal`` (float32 ``[H, W, 3]``) and
  ``mask`` (bool ``[H, W]``): the heat maps' and the bias table's covered pixels, and the
  sample picture's normal.  Written once per scene rendered.
- ``inputs/<scene>/pool_f<frame>.npz``: Lu 2013's sample picture of the frame (issue 33): the
  environment frame ``env`` (float32 ``[6, R, R, 3]``), the pool the shared-sequence pool
  estimators read at ``spp`` (:func:`picture_spp`) and seed 0 (``directions`` float32
  ``[6·per_face, 3]``, face-major, ``per_face``, ``face_integrals`` ``[6]``), and each
  estimator's split of every pixel (``ticks`` int32 ``[estimators, H, W, 7]``: six faces, then
  the BRDF, in ``ticks_per_sample``), the estimators named in ``labels`` (``interleaved``: the
  pool estimators left out, whose pixels read the pool at hashed offsets).  Written once per
  frame, after its renders and before its rows (its pool, built then, moves no cell's time).

The executor writes them (:mod:`.executor`); a run folder made before has none, and its report
leaves the sample pictures out.  The ΔE76 maps are not saved: the report scores the run's EXRs
with the run's own :class:`~.metrics.Scorer` (a few ms an image), which keeps the folder as it
was (a map per cell would add about half the images' size).  Both files are written atomically,
compressed; this module reads and writes them with NumPy only."""
from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from iblbench.foundation.atomic import atomic_path
from iblbench.foundation.errors import InputError

SEED = 0   # the sample picture's pool is seed 0's, whatever seeds the run has


def surface_path(run_dir: pathlib.Path, scene: str) -> pathlib.Path:
    return pathlib.Path(run_dir) / "inputs" / scene / "surface.npz"


def pool_path(run_dir: pathlib.Path, scene: str, frame: int) -> pathlib.Path:
    return pathlib.Path(run_dir) / "inputs" / scene / f"pool_f{frame}.npz"


def picture_spp(levels: dict[str, set[int]], pool_labels) -> int | None:
    """The spp of the sample picture: the largest spp every estimator ran (``levels``: label →
    its spp), or, where they share none, the largest of the pool estimators' own (the spp the
    image grid shows each: :func:`shown_spp`); None without a pool estimator among them."""
    shown = shown_spp(levels)
    return max((shown[label] for label in pool_labels if label in shown), default=None)


def shown_spp(levels: dict[str, set[int]], spp: int | None = None) -> dict[str, int]:
    """The spp shown per estimator (``levels``: label → the spp it ran): ``spp`` when given,
    else the largest spp every estimator ran; an estimator without it shows its own largest."""
    if not levels:
        return {}
    if spp is None:
        common = set.intersection(*map(set, levels.values()))
        spp = max(common) if common else None
    return {name: (spp if spp in have else max(have)) for name, have in levels.items()}


def write_surface(run_dir: pathlib.Path, scene: str, normal: np.ndarray, mask: np.ndarray) -> None:
    path = surface_path(run_dir, scene)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as file:
            np.savez_compressed(file, normal=np.asarray(normal, np.float32),
                                mask=np.asarray(mask, bool))


@dataclasses.dataclass(frozen=True)
class PoolPicture:
    """One frame's saved sample-picture inputs (module docstring)."""

    env: np.ndarray
    spp: int
    directions: np.ndarray      # float64, as the picture computes with
    per_face: int
    face_integrals: np.ndarray
    ticks_per_sample: int
    ticks: dict[str, np.ndarray]   # label → [H, W, 7]
    interleaved: tuple[str, ...]   # the pool estimators whose pixels read hashed offsets: not shown


def write_pool_picture(run_dir: pathlib.Path, scene: str, frame: int, picture: PoolPicture) -> None:
    path = pool_path(run_dir, scene, frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as file:
            np.savez_compressed(
                file, env=np.asarray(picture.env, np.float32), spp=np.int64(picture.spp),
                directions=np.asarray(picture.directions, np.float32),
                per_face=np.int64(picture.per_face),
                face_integrals=np.asarray(picture.face_integrals, np.float64),
                ticks_per_sample=np.int64(picture.ticks_per_sample),
                labels=np.array(list(picture.ticks), dtype=str),
                interleaved=np.array(list(picture.interleaved), dtype=str),
                ticks=np.stack([np.asarray(t, np.int32) for t in picture.ticks.values()]))


def _read(path: pathlib.Path, what: str):
    """The arrays of ``path`` (None where there is none: a run from before these files)."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            return {name: data[name] for name in data.files}
    except Exception as error:   # zipfile, OSError, ValueError: a damaged file
        raise InputError(path, f"cannot read the run's saved {what} ({type(error).__name__})") \
            from None


def read_surface(run_dir: pathlib.Path, scene: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(normal ``[H, W, 3]``, mask ``[H, W]``) of ``scene``; None where the run saved none."""
    arrays = _read(surface_path(run_dir, scene), "G-buffer normals and mask")
    return None if arrays is None else (arrays["normal"], arrays["mask"])


def read_pool_picture(run_dir: pathlib.Path, scene: str, frame: int) -> PoolPicture | None:
    """The saved sample-picture inputs of (``scene``, ``frame``); None where the run saved none."""
    arrays = _read(pool_path(run_dir, scene, frame), "sample-picture pool")
    if arrays is None:
        return None
    return PoolPicture(arrays["env"], int(arrays["spp"]), arrays["directions"].astype(np.float64),
                       int(arrays["per_face"]), arrays["face_integrals"],
                       int(arrays["ticks_per_sample"]),
                       dict(zip((str(label) for label in arrays["labels"]), arrays["ticks"])),
                       tuple(str(label) for label in arrays["interleaved"]))


__all__ = ["PoolPicture", "picture_spp", "shown_spp", "write_surface", "write_pool_picture",
           "read_surface", "read_pool_picture", "surface_path", "pool_path", "SEED"]
