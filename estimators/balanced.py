"""``balanced``: Lu 2013's dynamic per-normal face balancing (Eq. 3-5)."""
from __future__ import annotations

import dataclasses

from iblbench.estimators.base import KernelCost, Limit, Setting, SweepPart
from iblbench.estimators.light_pool import PoolEstimator, PoolParams


@dataclasses.dataclass(frozen=True)
class BalancedParams(PoolParams):
    """``shared_sequence``: see :class:`~iblbench.estimators.light_pool.PoolParams`.

    ``uniform_faces`` (debug switch, default False): force μ_f = 1/6 instead of Eq. 3, which must
    reproduce ``uniform`` exactly on the same seed.
    """

    uniform_faces: bool = False


class Balanced(PoolEstimator):
    """Light importance sampling with the face split balanced per normal (Lu 2013 Eq. 3-5).

    μ_f(n) = F_f(n) I_f / Σ_f F_f(n) I_f (Eq. 3), F_f(n) the clamped cosines of the face's four
    normalised corners and I_f its luminance integral; N_f(n) = μ_f(n) N_s samples of face f read
    from the shared pool, the last weighted by β = frac(N_f) (Eq. 5), in the estimator of Eq. 4.
    Faces with F_f = 0 lie wholly below the horizon and get no samples (proof in light_pool.cl);
    all-black faces (I_f = 0) get none either.

    Pool size: N_s + 1 per face, not the paper's N_s/2 (Sec. 2.2): without BRDF samples one face
    can take the whole budget (μ_f → 1 when it holds all the light above the horizon), and a
    smaller pool would have to reuse samples (see ``PoolEstimator.pool_size``).
    """

    name = "balanced"
    sweep = SweepPart(("balanced",), spp=(64, 256, 1024, 4096), order=2)
    cost = KernelCost(65, 0, 0, 214, 88, derivation="""\
        uniform's samples; per pixel + F_f(n)·I_f of Eq. 3, 6 faces × 18 (4 corners × 4: n·c
        with c = (±1, ±1, ±1) folds to 2 adds), and the split of split_ticks over weights 30""",
        lane_loops=((6, 1.0),), limits=(   # uniform's loops (light_pool.cl), the split per pixel
            Limit("phong_power", per_eval=1, why="the lobe power of each lane"),
            Limit("divide", per_eval=1, per_pixel=6,
                  why="add_samples' β / D; split_ticks' running / divisor of each face")))
    Params = BalancedParams
    settings = PoolEstimator.settings + (Setting("uniform_faces", True),)   # tests/test_lu2013.py
    kernel_files = ("balanced.cl",)

    def defines(self, gbuffer=None) -> dict:
        return {**super().defines(gbuffer), **({"LU_BALANCED_FACES": 0} if self.params.uniform_faces else {})}
