"""The G-buffer: per-pixel surface data from Embree primary rays, traced once per scene."""
from __future__ import annotations

import dataclasses

import numpy as np

GBUFFER_ARRAYS = ("mask", "position", "normal", "view", "kd", "ks", "shininess")


@dataclasses.dataclass
class GBuffer:
    """Per-pixel arrays, rows top to bottom.

    ``mask`` bool ``[H, W]``; ``position``, ``normal`` (unit shading normal), ``view`` (unit,
    surface → camera), ``kd``, ``ks`` float32 ``[H, W, 3]``; ``shininess`` float32 ``[H, W]``.
    Uncovered pixels hold zeros.
    """

    mask: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    view: np.ndarray
    kd: np.ndarray
    ks: np.ndarray
    shininess: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape

    @property
    def covered(self) -> int:
        return int(self.mask.sum())

    @property
    def is_diffuse(self) -> bool:
        """True when no covered pixel has a specular lobe (no BRDF-lobe branch is needed)."""
        return not np.any(self.ks[self.mask] > 0)

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in GBUFFER_ARRAYS}

    @classmethod
    def from_pixels(cls, normal, view, kd, ks, shininess, mask=None) -> "GBuffer":
        """A G-buffer made directly from per-pixel arrays (tests, synthetic inputs).

        ``normal`` is ``[H, W, 3]``; the others broadcast to it.  Vectors are normalised.
        """
        normal = np.asarray(normal, dtype=np.float32)
        shape = normal.shape[:-1]
        unit = lambda a: (a / np.linalg.norm(a, axis=-1, keepdims=True)).astype(np.float32)
        vec = lambda a: np.broadcast_to(np.asarray(a, np.float32), shape + (3,)).copy()
        return cls(
            mask=np.ones(shape, bool) if mask is None else np.asarray(mask, bool),
            position=np.zeros(shape + (3,), np.float32),
            normal=unit(normal),
            view=unit(vec(view)),
            kd=vec(kd),
            ks=vec(ks),
            shininess=np.broadcast_to(np.asarray(shininess, np.float32), shape).copy(),
        )
