"""An independent NumPy twin of Ghosh, Doucet & Heidrich 2006's sequential sampler for a batch of
independent shading points, the oracle that ``smc`` (estimators/smc.cl) is checked against
(``SMC.twin`` names this module: :func:`sampler` builds the twin of an ``smc`` instance).

Written from the papers, not from the kernel: Kronander et al. §5-6 (their Eq. 3-8, the form
in which ``smc`` implements Ghosh's sampler; equation numbers below are Kronander's) and the
SMC-sampler construction Ghosh et al. take from Del Moral, Doucet & Jasra 2006.  Ghosh's paper
itself is not among the project's papers (ARCHITECTURE.md §Papers lists only Kronander's account of it).
Where ``smc`` deliberately deviates from the papers (its docstring, estimators/smc.py), the twin
follows the documented deviation, from the docstring's words, and says so below.

One chain per shading point c (``Shading``, arrays over c), N particles each, float64.
Per frame t with target γ_t(ω) = L_Y,t(ω) ρ_Y(ω) cos⁺(n, ω) (Eq. 3):

* init (Kronander §6.1: "any product sampling", they use BIS, §5): M candidates from the
  proposal q, weights γ/q, Ẑ = (1/M) Σ γ/q, N particles by systematic resampling, W = 1/N.
  smc's documented deviations, followed here: q = ½ p_map + ½ p_B with the strategy stratified
  (the first M/2 candidates from the map), and the frame's estimate (1/M) Σ f/q over the
  candidates instead of Eq. 4 over the resampled points.
* a changed frame, S = intermediates + 1 tempered steps π_k = γ_{t−1}^{1−k/S} γ_t^{k/S}
  (Ghosh's intermediate distributions; S = 1 is plain Eq. 5).  Step k:
  - reweight, Eq. 5 with π_k/π_{k−1} in place of γ_t/γ_{t−1}: w_i = W_i (γ_t/γ_{t−1})(ω_i)^{1/S},
    γ_{t−1} at the particle's current position (after last frame's MH moves);
  - Eq. 8, one factor per step: Z ← Z Σ_i w_i, then W = w/Σw;
  - resample (systematic) when ESS = 1/Σ W² < 2N/3 (§6.1);
  - one MH move per particle with a π_k-invariant kernel (Eq. 6, corrected below).
  Then the re-init test (Z_t/Z_{t−1} outside [1/4, 4]: re-init by BIS, smc's two-sided form of
  Kronander's rule) and Eq. 7, L̂ = Z_t Σ W_i f(ω_i)/γ_t(ω_i).  Not modelled: smc's map-level
  tests (a jump of the map's power, and its shape test 1 + χ² of the texel densities above
  1/reinit_map_ess), which re-initialise every pixel; the twin's sequences stay below both
  (rotating-sun: 1 + χ² ≤ 1.008 against 1.5).
* a static frame (the map equals the previous one), smc's documented deviation: S MH moves at
  γ_t, no reweighting; the n_map + n_brdf independent proposals give fresh balance-heuristic
  estimates Σ γ/(n_map p_map + n_brdf p_B) of Z and Σ f/(…) of the integral, averaged with the
  carried ones by sample counts (M behind an init, N behind a changed frame's Eq. 7).

MH kernels (Ghosh's mixture, Kronander §6.2): a local move, ω' uniform in the cone of half-angle
δ about ω (symmetric), or an independent move from the map or the BRDF.  smc fixes the kind of
move j = (k−1)N + i by a Beatty schedule (a ν share local, the independent ones alternating map,
BRDF, map first) instead of drawing it with probability ν (its documented deviation; the twin
does the same by default, ``random_kinds=True`` draws it as Ghosh do; a static frame's fresh
estimates need the fixed counts).  The map proposal is frame t's: face f with μ_f = I_f/Σ I,
texel ∝ Y·Ω on the face, a point uniform in the texel's face square, density
μ_f P(texel|f) (1+x²+y²)^{3/2}/a_texel (ARCHITECTURE.md §Conventions); the BRDF proposal is the Phong mixture.

Errata and ambiguities of the printed papers (Kronander et al.'s text of Ghosh's method):
1. Eq. 6 prints q(ω→ω') in both numerator and denominator, so the proposal cancels and an
   independent move is accepted by γ(ω')/γ(ω) alone: its invariant distribution is then not γ
   (for an independent proposal q it is ∝ γ·q).  Metropolis-Hastings needs the reverse density
   in the numerator: a = min(1, γ(ω') q(ω'→ω) / (γ(ω) q(ω→ω'))), i.e. γ(ω')q(ω)/(γ(ω)q(ω')) for
   an independent move and γ(ω')/γ(ω) for the symmetric local move.  With intermediate
   distributions γ is π_k there.
2. §6.1 writes the weighted set at t−1 as approximating "γ̂_t"; it approximates γ_{t−1}/Z_{t−1}.
3. §6.1 defines ESS as Σ (W^i)^{−2}; it is (Σ (W^i)²)^{−1} (≤ N; the printed form is ≥ N³).
4. Eq. 4 computes Ẑ = (1/N) Σ γ(ω^i) at the resampled points, with no division by the
   proposal density (not an estimate of Z at all) and Eq. 4's sum lacks its 1/N; BIS's Ẑ is
   (1/M) Σ γ/q over the M candidates (Burke 2005), and the estimate Ẑ (1/N) Σ f/γ.
5. Eq. 5/8 state the weight update for one step.  With S intermediate distributions each step
   multiplies by (γ_t/γ_{t−1})^{1/S} at the particle's position at that step (after the previous
   step's MH move), and Z_t is Z_{t−1} times the product of the S sums; Eq. 8's Σ_i w_t^i is
   over w = W_{t−1} × ratio with W normalised, never over unnormalised weights carried across
   frames.  γ_{t−1}(ω) is the previous map's target at the particle's current position (after
   last frame's moves), not where the particle was placed.
6. Kronander §6.3 re-initialises "when a large increase occurs"; a collapse of Z (a light
   leaving every particle) is as much a failure, so smc and the twin test both sides.
7. Kronander give no rule for a frame whose map did not change; Eq. 5/8 then do nothing and Z
   stays frozen at the init's.  The static-stretch update above is smc's own (estimators/
   smc.py step 6); its sample counts are: n_map and n_brdf, the independent proposals of the
   frame's S·N moves whose particle has W > 0 (the balance heuristic's n_k must be the actual
   counts of the techniques, or the fresh estimate is biased by Σ_k n_k p_k/Σ_k n'_k p_k); and n,
   the samples behind the carried values: M after an init (the candidates), N after a changed
   frame (Eq. 7's particles), n + n_map + n_brdf after a static frame.
Not modelled: the map-level power-jump re-init of smc (a smooth sequence never triggers it).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from iblbench.scenes.cubemap import MapSampler as Map

LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclasses.dataclass
class Shading:
    """Shading points: ``normal``, ``view`` ``[C, 3]`` (unit), ``kd``, ``ks`` ``[C, 3]``,
    ``m`` ``[C]`` (Phong, ARCHITECTURE.md §Conventions)."""

    normal: np.ndarray
    view: np.ndarray
    kd: np.ndarray
    ks: np.ndarray
    m: np.ndarray

    def __post_init__(self):
        unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)
        self.normal, self.view = unit(np.asarray(self.normal, float)), unit(np.asarray(self.view, float))
        self.kd, self.ks = np.asarray(self.kd, float), np.asarray(self.ks, float)
        self.m = np.asarray(self.m, float)
        self.mirror = 2 * np.sum(self.normal * self.view, -1, keepdims=True) * self.normal - self.view
        self.p_spec = (self.ks @ LUMA) / (self.kd @ LUMA + self.ks @ LUMA)

    def lobe(self, w):
        """max(0, r·ω)^m for directions ``[C, K, 3]``."""
        c = np.maximum(np.einsum("ck,cjk->cj", self.mirror, w), 0.0)
        return c ** self.m[:, None]

    def brdf(self, w):
        """ρ(ω) ``[C, K, 3]``."""
        spec = (self.m[:, None] + 2) / (2 * np.pi) * self.lobe(w)
        return self.kd[:, None] / np.pi + self.ks[:, None] * spec[..., None]

    def cosine(self, w):
        return np.einsum("ck,cjk->cj", self.normal, w)

    def brdf_pdf(self, w):
        """p_B(ω): the lobe picked by luminance, cosine-weighted diffuse, cos^m specular."""
        p = self.p_spec[:, None]
        return (1 - p) * np.maximum(self.cosine(w), 0) / np.pi \
            + p * (self.m[:, None] + 1) / (2 * np.pi) * self.lobe(w)

    def sample_brdf(self, k, rng):
        specular = rng.random((len(self.m), k)) < self.p_spec[:, None]
        u = rng.random((len(self.m), k))
        cos_theta = np.where(specular, u ** (1 / (self.m[:, None] + 1)), np.sqrt(u))
        axis = np.where(specular[..., None], self.mirror[:, None], self.normal[:, None])
        return about_axis(axis, cos_theta, rng.random(cos_theta.shape))


def about_axis(axis, cos_theta, u):
    """Directions at polar cosine ``cos_theta`` and azimuth 2πu about unit ``axis`` ``[..., 3]``."""
    helper = np.where(np.abs(axis[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    a = np.cross(axis, helper)
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.cross(axis, a)
    sin_theta = np.sqrt(np.maximum(1 - cos_theta ** 2, 0))[..., None]
    phi = 2 * np.pi * u[..., None]
    return cos_theta[..., None] * axis + sin_theta * (np.cos(phi) * a + np.sin(phi) * b)


def systematic_indices(weights, n, rng):
    """Systematic resampling of each row of ``weights`` ``[C, K]`` to ``n`` indices: one uniform
    u per row, positions (k + u)/n of the row's total, k < n."""
    cumulative = np.cumsum(weights, -1)
    positions = (np.arange(n) + rng.random((len(weights), 1))) / n * cumulative[:, -1:]
    index = np.array([np.searchsorted(c, p, side="right") for c, p in zip(cumulative, positions)])
    return np.minimum(index, weights.shape[1] - 1)


def move_kinds(steps, n, nu, rng=None):
    """Kinds ``[steps, n]`` of the MH moves (0 local, 1 map, 2 BRDF): smc's Beatty schedule, or
    Ghosh's random mixture (local with probability ν, else map or BRDF alike) given ``rng``."""
    if rng is not None:
        local = rng.random((steps, n)) < nu
        return np.where(local, 0, 1 + (rng.random((steps, n)) < 0.5))
    j = np.arange(steps * n)
    local_before = np.floor(j * nu).astype(int)
    local = np.floor((j + 1) * nu).astype(int) > local_before
    return np.where(local, 0, np.where((j - local_before) % 2 == 0, 1, 2)).reshape(steps, n)


@dataclasses.dataclass
class GhoshSampler:
    """The sampler for every chain of ``shading`` (parameters as estimators/smc.py's)."""

    shading: Shading
    N: int = 8
    nu: float = 0.5
    local_degrees: float = 3.0
    intermediates: int = 3
    reinit_threshold: float = 4.0
    init_candidates: int = 20
    init_env_pick: float = 0.5
    random_kinds: bool = False
    seed: int = 0

    def __post_init__(self):
        self.rng = np.random.default_rng(self.seed)
        self.previous = None
        self.reinits = 0

    # -- target --------------------------------------------------------------------------------
    def target(self, environment: Map, w):
        """(γ(ω) ``[C, K]``, f(ω) ``[C, K, 3]``) of Eq. 3 and the integrand."""
        f = environment.radiance(w) * self.shading.brdf(w) * np.maximum(self.shading.cosine(w), 0)[..., None]
        return f @ LUMA, f

    # -- init: BIS (Kronander §5, with smc's documented q and estimate) -------------------------
    def _bis(self, environment: Map):
        C, N = len(self.shading.m), self.N
        M = self.init_candidates * N
        from_map = (np.arange(M) + 0.5) / M < self.init_env_pick
        w = np.where(from_map[None, :, None], environment.sample((C, M), self.rng),
                     self.shading.sample_brdf(M, self.rng))
        q = self.init_env_pick * environment.pdf(w) + (1 - self.init_env_pick) * self.shading.brdf_pdf(w)
        gamma, f = self.target(environment, w)
        ok = (q > 0) & (gamma > 0)
        weight = np.where(ok, gamma / np.where(ok, q, 1), 0)
        estimate = np.where(ok[..., None], f / np.where(ok, q, 1)[..., None], 0).mean(1)
        index = systematic_indices(weight, N, self.rng)
        take = lambda a: np.take_along_axis(a, index[..., None] if a.ndim == 3 else index, 1)
        return dict(w=take(w), W=np.full((C, N), 1 / N), gamma=take(gamma), Z=weight.mean(1),
                    count=np.full(C, float(M)), estimate=estimate)

    # -- MH ------------------------------------------------------------------------------------
    def _move(self, s, kind, alpha, now: Map, before: Map, static: bool, fresh=None):
        """One MH move of every particle with W > 0 targeting π_α (Eq. 6 with the reverse
        density in the numerator, erratum 1); ``kind`` ``[N]``."""
        C, N = s["W"].shape
        cone = 1 - self.rng.random((C, N)) * (1 - np.cos(np.radians(self.local_degrees)))
        local = about_axis(s["w"], cone, self.rng.random((C, N)))
        from_map, from_brdf = now.sample((C, N), self.rng), self.shading.sample_brdf(N, self.rng)
        w_new = np.where((kind == 0)[None, :, None], local,
                         np.where((kind == 1)[None, :, None], from_map, from_brdf))
        g1_new, f_new = self.target(now, w_new)
        g0_new = self.target(before, w_new)[0] if alpha < 1 else g1_new
        pi_new, pi_old = tempered(g0_new, g1_new, alpha), tempered(s["g0"], s["gamma"], alpha)
        q = lambda w: np.where(kind == 1, now.pdf(w), self.shading.brdf_pdf(w))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(kind == 0, pi_new / pi_old, pi_new * q(s["w"]) / (pi_old * q(w_new)))
            accept = (s["W"] > 0) & (pi_new > 0) & ((pi_old <= 0) | (self.rng.random((C, N)) < ratio))
        if fresh is not None:
            independent = (kind > 0) & (s["W"] > 0) & (g1_new > 0)
            mixture = fresh["n_map"][:, None] * now.pdf(w_new) \
                + fresh["n_brdf"][:, None] * self.shading.brdf_pdf(w_new)
            share = np.where(independent, 1 / np.where(independent, mixture, 1), 0)
            fresh["Z"] += np.sum(g1_new * share, 1)
            fresh["L"] += np.sum(f_new * share[..., None], 1)
        s["w"] = np.where(accept[..., None], w_new, s["w"])
        s["g0"] = np.where(accept, g0_new, s["g0"])
        s["gamma"] = np.where(accept, g1_new, s["gamma"])

    def _resample(self, s, where):
        C, N = s["W"].shape
        index = systematic_indices(s["W"], N, self.rng)
        index = np.where(where[:, None], index, np.arange(N))
        for key in ("w", "g0", "gamma"):
            s[key] = np.take_along_axis(s[key], index[..., None] if key == "w" else index, 1)
        s["W"] = np.where(where[:, None], 1 / N, s["W"])

    # -- one frame -----------------------------------------------------------------------------
    def render(self, env) -> np.ndarray:
        """The estimates ``[C, 3]`` of the next frame, lit by ``env`` ``[6, R, R, 3]``."""
        now = Map(env)
        if self.previous is None:
            state = self._bis(now)
        else:
            before = self.previous
            static = np.array_equal(before.env, now.env)
            state = self._static(now) if static else self._changed(now, before)
        self.state, self.previous = state, now
        return np.where((state["Z"] > 0)[:, None], state["estimate"], 0)

    def _kinds(self, steps):
        return move_kinds(steps, self.N, self.nu, self.rng if self.random_kinds else None)

    def _changed(self, now: Map, before: Map):
        s, S = dict(self.state), self.intermediates + 1
        s["g0"] = s["gamma"]                       # γ_{t−1} at the particles
        s["gamma"] = self.target(now, s["w"])[0]   # γ_t
        z_before = s["Z"]
        reinit = np.any((s["W"] > 0) & ~(s["g0"] > 0), 1) | ~(z_before > 0)
        kinds = self._kinds(S)
        for k in range(1, S + 1):
            with np.errstate(divide="ignore", invalid="ignore"):
                increment = np.where((s["W"] > 0) & (s["g0"] > 0), (s["gamma"] / s["g0"]) ** (1 / S), 0)
            w = s["W"] * increment                                        # Eq. 5
            total = w.sum(1)
            s["Z"] = s["Z"] * total                                       # Eq. 8
            reinit |= ~(total > 0)
            s["W"] = w / np.where(total > 0, total, 1)[:, None]
            self._resample(s, (total > 0) & (np.sum(s["W"] ** 2, 1) * 2 * self.N > 3))   # ESS < 2N/3
            self._move(s, kinds[k - 1], k / S, now, before, static=False)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = s["Z"] / z_before
        reinit |= ~((ratio <= self.reinit_threshold) & (ratio >= 1 / self.reinit_threshold))
        gamma, f = self.target(now, s["w"])
        ok = (s["W"] > 0) & (gamma > 0)
        over = np.where(ok[..., None], f / np.where(ok, gamma, 1)[..., None], 0)
        s["estimate"] = s["Z"][:, None] * np.sum(s["W"][..., None] * over, 1)   # Eq. 7
        s["count"] = np.full_like(s["Z"], float(self.N))
        return self._reinit(s, reinit, now)

    def _static(self, now: Map):
        s, S = dict(self.state), self.intermediates + 1
        s["g0"] = s["gamma"]
        reinit = np.any((s["W"] > 0) & ~(s["g0"] > 0), 1) | ~(s["Z"] > 0)
        kinds = self._kinds(S)
        weighted = s["W"] > 0
        fresh = dict(n_map=np.einsum("kn,cn->c", (kinds == 1).astype(float), weighted),
                     n_brdf=np.einsum("kn,cn->c", (kinds == 2).astype(float), weighted),
                     Z=np.zeros_like(s["Z"]), L=np.zeros_like(s["estimate"]))
        for k in range(S):
            self._move(s, kinds[k], 1.0, now, now, static=True, fresh=fresh)
        n_fresh = fresh["n_map"] + fresh["n_brdf"]
        total = s["count"] + n_fresh
        share = np.where(n_fresh > 0, n_fresh / total, 0)
        s["Z"] = (1 - share) * s["Z"] + share * fresh["Z"]
        s["estimate"] = (1 - share)[:, None] * s["estimate"] + share[:, None] * fresh["L"]
        s["count"] = total
        return self._reinit(s, reinit, now)

    def _reinit(self, s, reinit, now: Map):
        if reinit.any():
            self.reinits += int(reinit.sum())
            fresh = self._bis(now)
            for key, value in fresh.items():
                mask = reinit.reshape((-1,) + (1,) * (value.ndim - 1))
                s[key] = np.where(mask, value, s[key])
        s.pop("g0", None)
        return s


def sampler(shading: Shading, params, spp: int, seed: int) -> GhoshSampler:
    """The twin of ``smc`` with ``params`` (``SMCParams``) at ``spp`` for the chains of ``shading``."""
    return GhoshSampler(shading, N=params.N or int(spp), nu=params.nu,
                        local_degrees=params.local_degrees, intermediates=params.intermediates,
                        reinit_threshold=params.reinit_threshold,
                        init_candidates=params.init_candidates, init_env_pick=params.init_env_pick,
                        seed=seed)


def tempered(g0, g1, alpha):
    """π_α = γ_{t−1}^{1−α} γ_t^α (α = 1: γ_t)."""
    if alpha >= 1:
        return g1
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((g0 > 0) & (g1 > 0), g0 ** (1 - alpha) * g1 ** alpha, 0)
