"""What ``uniform``, ``balanced`` and ``balanced_mis`` share: Lu 2013's light-sample pool
(Algorithm 1) read by a per-pixel estimator (Algorithm 2, Eq. 4-6) in ``kernels/light_pool.cl``.

The pool is a FrameCache product: per frame and render seed, ``pool_size(spp)`` samples of each
lit face, drawn on the device from the face's CDFs.  Its 2-D points are a fixed random sequence
(Lu's "precomputed random sequence") rotated modulo 1 per (seed, frame, face), so every pool
entry is an unbiased sample of pdf_L(ω|f).  A random fixed sequence, not Hammersley: the
estimator reads a *prefix* of N_f(n) ≤ pool size points, and a Hammersley set's prefix covers
only the first N_f/size of the unit square, while any prefix of a random sequence is random.

A render's sample stage is the pool's build plus two small launches: ``pool_planes`` lays the
pool out as planes for the kernel's vector loads, and ``brdf_numbers`` (``balanced_mis``, shared
sequence) computes the BRDF draws' random numbers once for all pixels.  They change no sample: the
same pool entries and the same Philox numbers reach the same arithmetic (``tests/test_lane_forms``).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from iblbench.estimators.base import Estimator, Setting, Tags, WorkCounts, read_estimate, visibility_defines
from iblbench.estimators.runtime.device import event_ms

TICKS_PER_SAMPLE = 65536   # fixed point of the sample counts (light_pool.cl)
MAX_SPP = 2 ** 31 // TICKS_PER_SAMPLE - 1
HOOK_SPP = 64              # budget whose split the χ² hooks sample


def light_ticks(spp: int, brdf_samples: bool) -> int:
    """The light samples' ticks of a budget of ``spp``: all, or half with BRDF samples
    (light_pool.cl's ``light_ticks``, which envmap.cl's split shares)."""
    total = spp * TICKS_PER_SAMPLE
    return total // 2 if brdf_samples else total


def draws_for(ticks: int) -> int:
    """Draws of a strategy of ``ticks`` ticks (light_pool.cl's ``draws_for``, Lu 2013 Eq. 5)."""
    return -(-ticks // TICKS_PER_SAMPLE)


def lane_chunks(draws, lanes: int) -> int:
    """The chunks of ``lanes`` draws (POOL_LANES) that each of ``draws`` draws (one a strategy)
    takes, together: what a kernel's window counts (light_pool.cl's ``strategy_window``)."""
    return sum(-(-int(d) // lanes) for d in draws)


def hook_surface(cache, normal, view, kd=0.5, ks=0.3, shininess=20.0):
    """The χ² hooks' one pixel on the device: rows normal, view, kd, (ks, m) of float4, the
    material the conformance suite's glossy one."""
    surface = np.zeros((4, 4), np.float32)
    surface[0, :3] = normal / np.linalg.norm(normal)
    surface[1, :3] = view / np.linalg.norm(view)
    surface[2, :3], surface[3, :3], surface[3, 3] = kd, ks, shininess
    return cache.compute.to_device(surface)


@dataclasses.dataclass(frozen=True)
class PoolParams:
    """Parameters of the pool estimators.

    ``shared_sequence`` (default True): every pixel reads the same first N_f(n) pool samples of
    each face, as in Lu 2013 Sec. 2.2; the per-(seed, frame) rotation of the pool keeps each
    pixel's estimate unbiased over seeds.  The default is the paper's set-up, which this
    benchmark reproduces; it is also the coherent, cache-friendly read the paper chose for
    speed.  Its noise is correlated across pixels (smooth, structured error instead of grain).
    False: pixel p reads pool samples from a hashed per-pixel offset (mod the pool size) and
    draws its own BRDF numbers, the interleaved sampling Lu suggest to decorrelate neighbours.
    """

    shared_sequence: bool = True


class PoolEstimator(Estimator):
    """A Lu 2013 estimator over the light-sample pool; subclasses set the kernel file, which
    configures the shared kernels of ``kernels/light_pool_kernels.cl``."""

    Params = PoolParams
    settings = (Setting("shared_sequence", False, says="shared_sequence"),)
    tags = Tags(unbiased=True, has_pdf=True)
    requires = ("cdf", "pool")
    max_spp = MAX_SPP
    brdf_samples = False   # True where the kernel file sets LU_BRDF_SAMPLES (Eq. 6)

    @staticmethod
    def pool_size(spp: int) -> int:
        """Pool samples per face: N_s + 1, the same for every pool estimator.

        Enough for the most draws ⌈N_f⌉ any split gives one face (N_s for ``balanced``, whose one
        face may hold all the light above the horizon; the integer split never exceeds it), where
        Lu 2013 draw N_s/2, which suffices only for Eq. 6's half budget.  The extra room also
        serves the interleaved reads: a pixel's window of ⌈N_f⌉ ≤ N_s/6 (uniform) entries starts
        anywhere in N_s + 1, so neighbours share few samples.  Shared-sequence reads use a prefix,
        so they do not depend on the size.
        """
        return spp + 1

    def defines(self, gbuffer=None) -> dict:
        """Compile-time options of the kernels (for this G-buffer, when one is given)."""
        return visibility_defines(gbuffer)

    def _kernel(self, compute, name: str, gbuffer=None):
        return compute.kernel(self.kernel_package(), self.kernel_files[0], name, self.defines(gbuffer))

    mis_compensated = False   # True where the light CDFs are MIS-compensated (balanced_mis)

    def light_cdfs(self, cache):
        """The light CDFs the kernels read (FrameCache.light_cdfs)."""
        return cache.light_cdfs(self.mis_compensated)

    def work_counts(self, gbuffer, frames) -> list[WorkCounts]:
        """Each strategy's N_k = ticks/``TICKS_PER_SAMPLE`` samples (the split of
        :meth:`strategy_ticks`, Eq. 3) in ⌈N_k⌉ draws, the last weighted by β (Eq. 5), a draw
        one evaluation of the integrand and its V."""
        normals = gbuffer.normal[gbuffer.mask]
        counts = []
        for frame in frames:
            frame.cache.require(self.requires)
            ticks = self.strategy_ticks(frame.cache, normals, frame.spp).astype(np.int64)
            draws = (-(-ticks // TICKS_PER_SAMPLE)).sum(1)
            counts.append(WorkCounts(draws, draws))
        return counts

    def most_lane_chunks(self, spp: int, lanes: int) -> int:
        """The most chunks of ``lanes`` draws a pixel's strategies take together at ``spp``
        (DeviceGBuffer.run_sampled): the six faces' ⌈d_f/L⌉ of Σ d_f ≤ D + 6 draws (D the light
        samples, a face's ⌈N_f⌉ at most one over its N_f) sum to at most ⌊D/L⌋ + 6, and the BRDF
        draws take theirs."""
        light = light_ticks(spp, self.brdf_samples)
        brdf_draws = draws_for(spp * TICKS_PER_SAMPLE - light)
        return light // TICKS_PER_SAMPLE // lanes + 6 + lane_chunks([brdf_draws], lanes)

    def render(self, gbuffer, cache, spp, seed):
        if not 1 <= spp <= MAX_SPP:
            raise ValueError(f"spp must be in [1, {MAX_SPP}], got {spp}")
        compute = cache.compute
        cdfs = self.light_cdfs(cache)
        pool = cache.light_pool(self.pool_size(spp), seed, self.mis_compensated)
        plane = 12 * pool.per_face + 16   # POOL_PLANE_STRIDE (light_pool.cl)
        planes = compute.empty(8 * plane * 4)   # POOL_PLANES (light_pool.cl)
        events = [compute.run(self._kernel(compute, "pool_planes", gbuffer), plane, pool.dir_pdf, pool.radiance,
                              np.int32(pool.per_face), planes)]
        shared_brdf = self.brdf_samples and self.params.shared_sequence
        numbers_stride = 16 * (spp // 16 + 1)   # BRDF_NUMBERS_STRIDE (light_pool.cl)
        numbers = compute.empty(6 * 4 * numbers_stride if shared_brdf else 4)   # 6 planes (brdf_numbers)
        if shared_brdf:
            events.append(compute.run(self._kernel(compute, "brdf_numbers"), numbers_stride, np.uint32(seed),
                                      np.uint32(cache.frame), np.int32(spp), numbers))
        radiance = compute.empty(gbuffer.launch_size * 12)   # planes R, G, B (light_pool_kernels.cl)
        counts = compute.empty(gbuffer.launch_size * 8)      # planes used, effective
        evaluations = compute.empty(gbuffer.launch_size * 4)
        event = gbuffer.run_sampled(
            compute, lambda name: self._kernel(compute, name, gbuffer), "render_light_pool",
            self.most_lane_chunks(spp, compute.pool_lanes), gbuffer.normal, gbuffer.view, gbuffer.kd,
            gbuffer.ks, gbuffer.visibility, np.int32(gbuffer.launch_size), cache.env_buffer, cdfs.marginal, cdfs.conditional,
            cdfs.face_integral,
            planes, np.int32(cache.res), np.int32(pool.per_face),
            np.int32(spp), np.int32(self.params.shared_sequence), np.uint32(seed),
            np.uint32(cache.frame), numbers, radiance, counts, evaluations)
        mean_evaluations = compute.to_host(evaluations, (gbuffer.count,), np.int32).mean()
        return read_estimate(compute, gbuffer, radiance, counts, mean_evaluations,
                             {"sample": cdfs.build_ms + pool.build_ms + sum(map(event_ms, events)), "shade": event_ms(event)}, planar=True)

    # ---- χ² hooks and the per-normal split ---------------------------------------------------

    def sample_directions(self, cache, normal, view, n, seed):
        """``n`` directions ``[n, 3]`` distributed as all the samples the estimator draws for
        one pixel pooled (Σ_k N_k p_k / Σ_k N_k over its strategies), and that density.

        The material is the conformance suite's glossy one (kd 0.5, ks 0.3, m 20).
        """
        compute, cdfs = cache.compute, self.light_cdfs(cache)
        if not np.any(cache.face_integrals > 0):   # an all-black map has nothing to sample
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        out = compute.empty(n * 16)
        compute.run(self._kernel(compute, "pooled_directions"), n, hook_surface(cache, normal, view),
                    cdfs.marginal, cdfs.conditional, cdfs.face_integral, np.int32(cache.res),
                    np.int32(HOOK_SPP), np.uint32(seed), out)
        samples = compute.to_host(out, (n, 4), np.float32)
        return samples[:, :3], samples[:, 3]

    def pdf(self, cache, normal, view, dirs):
        """Density of :meth:`sample_directions` at ``dirs`` ``[n, 3]``."""
        compute, n = cache.compute, len(dirs)
        padded = np.zeros((n, 4), np.float32)
        padded[:, :3] = dirs
        out = compute.empty(n * 4)
        cdfs = self.light_cdfs(cache)
        compute.run(self._kernel(compute, "pooled_direction_pdf"), n, hook_surface(cache, normal, view),
                    cdfs.marginal, cdfs.conditional, cdfs.face_integral, np.int32(cache.res),
                    np.int32(HOOK_SPP), compute.to_device(padded), out)
        return compute.to_host(out, (n,), np.float32)

    def strategy_ticks(self, cache, normals, spp) -> np.ndarray:
        """Per normal ``[n, 3]``, the ticks of the six faces and the BRDF, int ``[n, 7]``:
        N_k = ticks / TICKS_PER_SAMPLE samples of strategy k (for tests and inspection)."""
        compute, n = cache.compute, len(normals)
        padded = np.zeros((n, 4), np.float32)
        padded[:, :3] = normals
        out = compute.empty(n * 7 * 4)
        compute.run(self._kernel(compute, "split_strategies"), n, compute.to_device(padded),
                    self.light_cdfs(cache).face_integral, np.int32(spp), out)
        return compute.to_host(out, (n, 7), np.int32)
