"""``uniform``: Lu 2013's baseline light sampling with μ_f = 1/6 of the samples per face."""
from __future__ import annotations

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
    kernel_files = ("uniform.cl",)
