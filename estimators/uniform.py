"""``uniform``: Lu 2013's baseline light sampling with μ_f = 1/6 of the samples per face."""
from __future__ import annotations

import numpy as np

from iblbench.estimators.base import Estimator, Tags, read_estimate
from iblbench.harness.device import event_ms


class Uniform(Estimator):
    """Light importance sampling with a uniform face split (Lu 2013 Sec. 2.1, Eq. 4 with μ_f = 1/6).

    Each face gets N_f = N_s/6 samples, drawn from its luminance CDF (weights Y·Ω, binary
    search) and a uniform point in the texel's face square; N_f is fractional and the last
    sample is weighted by β = frac(N_f) (Eq. 5), so any spp is unbiased.  Choices where the
    paper is silent: faces with zero luminance integral get no samples (their contribution is
    exactly zero); each pixel draws its own Philox stream (no shared sequence).
    Sampling and shading run fused in one kernel, so only ``shade`` time is reported.
    """

    name = "uniform"
    tags = Tags(unbiased=True, has_pdf=True)
    requires = ("cdf",)
    kernel_files = ("uniform.cl",)

    def sample_directions(self, cache, normal, view, n, seed):
        """``n`` light-sample directions ``[n, 3]`` and their pooled pdf (normal-independent)."""
        compute, lit = cache.compute, np.flatnonzero(cache.face_integrals > 0).astype(np.int32)
        if len(lit) == 0:   # an all-black map has nothing to sample
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        out = compute.empty(n * 16)
        compute.run(compute.kernel(self.kernel_package(), "uniform.cl", "sample_directions"), n,
                    cache.marginal, cache.conditional, compute.to_device(lit), np.int32(len(lit)),
                    np.int32(cache.res), np.uint32(seed), out)
        samples = compute.to_host(out, (n, 4), np.float32)
        return samples[:, :3], samples[:, 3]

    def pdf(self, cache, normal, view, dirs):
        """Density of :meth:`sample_directions` at ``dirs`` ``[n, 3]``."""
        compute, n = cache.compute, len(dirs)
        padded = np.zeros((n, 4), np.float32)
        padded[:, :3] = dirs
        out = compute.empty(n * 4)
        compute.run(compute.kernel(self.kernel_package(), "uniform.cl", "direction_pdf"), n,
                    cache.marginal, cache.conditional, cache.face_integral_buffer,
                    np.int32(np.count_nonzero(cache.face_integrals > 0)), np.int32(cache.res),
                    compute.to_device(padded), out)
        return compute.to_host(out, (n,), np.float32)

    def render(self, gbuffer, cache, spp, seed):
        compute = cache.compute
        kernel = compute.kernel(self.kernel_package(), "uniform.cl", "render_uniform")
        radiance = compute.empty(gbuffer.count * 16)
        counts = compute.empty(gbuffer.count * 8)
        event = compute.run(
            kernel, gbuffer.count, gbuffer.normal, gbuffer.view, gbuffer.kd, gbuffer.ks,
            cache.env_buffer, cache.marginal, cache.conditional, cache.face_integral_buffer,
            np.int32(cache.res), np.int32(spp), np.uint32(seed), np.uint32(cache.frame),
            radiance, counts)
        lit_faces = int(np.count_nonzero(cache.face_integrals > 0))
        evaluations = lit_faces * np.ceil(spp / 6.0)
        return read_estimate(compute, gbuffer, radiance, counts, evaluations,
                             {"shade": event_ms(event)})
