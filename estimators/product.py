"""``product``: per-pixel hierarchical product importance sampling of map × BRDF × cos by descent
through the weight pyramid (after Clarberg et al. 2005 and Clarberg & Akenine-Möller 2008), with
Phong BRDF samples under MIS."""
from __future__ import annotations

import dataclasses

from iblbench.estimators.base import Setting
from iblbench.estimators.envmap import HEURISTICS, MIS_MODES
from iblbench.estimators.hierarchical import Hierarchical

CHILD_WEIGHTS = ("bound", "centre")


@dataclasses.dataclass(frozen=True)
class ProductParams:
    """``mis`` (default ``"brdf"``): half the budget to Phong BRDF samples, combined with the
    product samples by MIS, so that a lobe sharper than the levels the product resolves is still
    covered; ``"none"``: product samples only.

    ``heuristic`` (default ``"power"``): the MIS weights, ``"balance"`` or ``"power"``, as
    ``envmap``'s; unused without MIS.

    ``child_weight`` (default ``"bound"``): a child's BRDF·cos factor, ``"bound"`` (an upper
    bound over the child's directions) or ``"centre"`` (its value at the child's centre
    direction, floored at 1/16 of the bound).

    ``light_levels`` (default 0): the choices among the children of the ``light_levels`` finest
    pyramid levels (1: the texels; 0: none) are made by the light weights alone, as
    ``hierarchical``'s; the coarser ones (and the faces, unless ``light_levels`` passes the
    pyramid's top) by the product.  At or beyond the pyramid's levels (log2 R + 1) every choice
    is ``hierarchical``'s.
    """

    mis: str = "brdf"
    heuristic: str = "power"
    child_weight: str = "bound"
    light_levels: int = 0

    def __post_init__(self):
        if self.mis not in MIS_MODES:
            raise ValueError(f"mis must be one of {', '.join(MIS_MODES)}, got {self.mis!r}")
        if self.heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, got {self.heuristic!r}")
        if self.child_weight not in CHILD_WEIGHTS:
            raise ValueError(f"child_weight must be one of {', '.join(CHILD_WEIGHTS)}, "
                             f"got {self.child_weight!r}")
        if not 0 <= self.light_levels <= 32:
            raise ValueError(f"light_levels must be in [0, 32], got {self.light_levels}")


class Product(Hierarchical):
    """DOCSTRING"""

    name = "product"
    Params = ProductParams
    settings = (Setting("mis", "none"), Setting("heuristic", "balance"),
                Setting("child_weight", "centre"), Setting("light_levels", 2))
    kernel_files = ("product.cl", "descent.cl", "envmap.cl", "lanes.cl")

    @property
    def compensated(self) -> bool:
        return False

    def defines(self, gbuffer=None) -> dict:
        """envmap.cl's options and product.cl's: the child-weight rule and the light-only levels."""
        return {**super().defines(gbuffer), "CHILD_WEIGHT": CHILD_WEIGHTS.index(self.params.child_weight),
                "LIGHT_LEVELS": self.params.light_levels}
