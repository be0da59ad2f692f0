"""``uniform``: Lu 2013's baseline light sampling with μ_f = 1/6 of the samples per face."""
from __future__ import annotations

from iblbench.estimators.base import KernelCost, Limit, SweepPart
from iblbench.estimators.light_pool import PoolEstimator


class Uniform(PoolEstimator):
    """Light importance sampling with a uniform face split (Lu 2013 Sec. 2.1, Eq. 4 with μ_f = 1/6).

    Each face gets N_f = N_s/6 samples from the shared light-sample pool (Algorithm 1: drawn
    from the face's luminance CDF, weights Y·Ω, by binary search); N_f is fractional and the
    last sample is weighted by β = frac(N_f) (Eq. 5), so any spp is unbiased.  Faces with zero
    luminance integral get no samples (their contribution is exactly zero).  The pool is drawn in
    the ``sample`` stage, the estimator runs in ``shade``.
    """

    name = "uniform"
    sweep = SweepPart(("uniform",), spp=(64, 256, 1024, 4096), order=1)
    cost = KernelCost(65, 0, 0, 88, 88, derivation="""\
        a light sample: lobe power 41 (r·ω 5, max, phong_power 35), n·ω 5, D = t_f·pdf 1,
        add_samples 18 (β/D·cos 2, lobe 1, 3 × (kd/π + ks·lobe 2, ×L, ×weight, +=)); per pixel:
        shading 24 (reflection 12, Y(kd), Y(ks) 10, lobe choice 2), the face split 12 (μ_f = 1/6
        folds), hoisted factors 5, the 16-lane sums out 47; bytes: 64 in, 24 out (radiance,
        used, effective, evaluations)""",
        lane_loops=((6, 1.0),), limits=(   # light_pool.cl's shade_light_faces: a loop a face
            Limit("phong_power", per_eval=1, why="the lobe power of each lane"),
            Limit("divide", per_eval=1, why="add_samples' β / D")))
    kernel_files = ("uniform.cl",)
