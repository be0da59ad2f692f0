"""``balanced_mis``: Lu 2013's balanced light sampling combined with BRDF sampling (Eq. 6)."""
from __future__ import annotations

import dataclasses

from iblbench.estimators.base import KernelCost, Limit, Setting, SweepPart, specular_lobe_defines
from iblbench.estimators.light_pool import PoolEstimator, PoolParams


@dataclasses.dataclass(frozen=True)
class BalancedMISParams(PoolParams):
    """``shared_sequence``: see :class:`~iblbench.estimators.light_pool.PoolParams`.

    ``mis_compensation`` (default False, the paper's estimator): MIS compensation (Karlík et al.
    2019, "MIS compensation: optimizing sampling techniques in multiple importance sampling",
    SIGGRAPH Asia 2019).  The light side, per-face CDFs and the face integrals I_f of Eq. 3 alike,
    is built from the weights max(Y − Ȳ, min(Ȳ/1000, Y))·Ω instead of Y·Ω (pbrt-v4's
    ``ImageInfiniteLight`` form; ``FrameCache.light_cdfs`` says why not Mitsuba 3's
    max(Y − Ȳ, 0)), so μ_f(n) follows the compensated integrals and the pool is drawn from the
    compensated CDFs; the denominators of Eq. 6 use the same compensated pdf_L, so the estimator
    is the balance heuristic over the compensated strategies and stays unbiased (every lit texel
    keeps a positive light pdf, and BRDF samples cover every direction the BRDF reaches).
    """

    mis_compensation: bool = False


class BalancedMIS(PoolEstimator):
    """Balanced light samples and Phong BRDF samples under the balance heuristic (Lu 2013 Eq. 6).

    Budget: N_f(n) = μ_f(n) N_s/2 light samples of face f (μ_f of Eq. 3) and N_b = N_s/2 BRDF
    samples, each strategy's last sample weighted by β = frac(N) (Eq. 5).  BRDF sampling is the
    energy-conserving Phong of ARCHITECTURE.md §Conventions: lobe by luminance weight, cosine-weighted diffuse lobe,
    cos^m lobe about r; its pdf p_B is the mixture pdf, counting the specular lobe's mass below
    the surface (those samples get a zero integrand).

    Denominators.  With strategies k (six faces, BRDF) of N_k samples and densities p_k, the
    balance heuristic estimates L = Σ_k Σ_i β_i s(ω_i) / Σ_j N_j p_j(ω_i).  pdf_L(ω|f) vanishes
    off face f, so for the face f(ω) holding ω,
        Σ_j N_j p_j(ω) = N_s [½ μ_f(ω)(n) pdf_L(ω|f(ω)) + ½ p_B(ω)]
                       = N_s [½ Σ_f μ_f(n) pdf_L(ω|f) + ½ p_B(ω)].
    Light samples of face f use the first form (Eq. 6's g_{f,i}), BRDF samples the second (Eq.
    6's f_i): it is one function of ω, so Eq. 6 is exactly the balance heuristic.  It is unbiased
    because the weights N_k p_k / Σ_j N_j p_j sum to 1 wherever s ≠ 0 (p_B > 0 wherever the BRDF
    is, and a face with μ_f = 0 has s = 0 on it), and because E[Σ_i β_i h(ω_i)] = N_k E_k[h]
    with the same fractional N_k in the denominator.  Deviations from the paper: none in the
    estimator; the counts N_k are rounded to 1/65536 of a sample (light_pool.cl) and the
    denominators use the rounded counts, which keeps the balance exact; the pool holds N_s + 1
    samples per face where the paper's Algorithm 1 draws N_s/2 (shared with the other pool
    estimators, see ``PoolEstimator.pool_size``).

    All-diffuse G-buffers build the kernel with the specular-lobe sampling branch compiled out.
    With ``mis_compensation`` (see :class:`BalancedMISParams`) the light CDFs, integrals and
    pool are the compensated ones; their build counts in the ``sample`` stage.
    """

    name = "balanced_mis"
    sweep = SweepPart(("balanced_mis",), spp=(16, 64, 256, 1024), order=3)
    portability_variants = ("balanced_mis{shared_sequence=false}",)
    cost = KernelCost(110, 0, 0, 246, 88, derivation="""\
        the mean of a light sample, 72 (+ t_6·phong_mixture_pdf 7 in D), and a BRDF sample of
        the shared sequence, 148 (cos θ from the shared log2 ξ: exp2 half 19; direction 31 in
        the per-pixel bases; lobe power 41; n·ω 5; mixture pdf 5; light_pdf 26; D 3; add_samples
        18); per pixel balanced's 214 + the bases about n and r 26 + pdf factors 6""",
        lane_loops=((6, 0.5), (1, 0.5)), limits=(   # light_pool.cl: a loop a face, then the BRDF's
            Limit("phong_power", per_eval=1, group=0, why="a light sample's lobe power"),
            Limit("divide", per_eval=2, group=0, why="add_samples' β / D, the mixture pdf's /π"),
            Limit("phong_power", per_eval=1, group=1, why="a BRDF sample's lobe power"),
            Limit("divide", per_eval=8, group=1,
                  why="shade_brdf: the direction's sin θ and 1/|ω| 3, the mixture pdf 1, "
                      "lanes_texel_of's s/ma, t/ma and √q 3, add_samples 1"),
            Limit("gather", per_eval=7, group=1,
                  why="lanes_cdf_bin's upper and lower words of the marginal and the "
                      "conditional 4, the texel's R, G, B 3"),
            Limit("divide", per_pixel=8, why="split_ticks 6, the bases about n and r 2")))
    Params = BalancedMISParams
    settings = PoolEstimator.settings + (Setting("mis_compensation", True, says="mis_compensation"),)
    kernel_files = ("balanced_mis.cl",)
    brdf_samples = True

    @property
    def mis_compensated(self) -> bool:
        return self.params.mis_compensation

    def defines(self, gbuffer=None) -> dict:
        return specular_lobe_defines(gbuffer)
