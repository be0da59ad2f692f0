"""Exact precision audit of the device-built light CDFs (issue 6).

For a map, compare the probability the light sampler *actually* gives each texel with the exact
float64 probability Y·Ω / I_f (ARCHITECTURE.md §Conventions), and measure what a pure light sampler (``uniform``,
``balanced``) loses where the two disagree.  Everything is computed analytically from the CDFs the
device built (:meth:`FrameCache.host_cdfs`), no sampling:

- ``p_exact``  Y·Ω / I_f in float64 from the float32 map;
- ``p_eval``   the probability the kernels *evaluate* (``cdf_bin`` of the marginal times that of
  the conditional, in float32 as ``sample_face``/``light_pdf`` compute it);
- ``p_sampled`` the probability the sampler *draws* the texel with: the share of the variate grid
  that ``cdf_search`` sends to the bin (with the samplers' 63-bit variates, exactly the bin's
  width in the 2^63 fixed-point CDF; ``variate_bits = 24`` shows what a float32 variate, as the
  float32 CDFs before the fix used, would reach).

A light-sampling estimator that evaluates ``p_eval`` but draws with ``p_sampled`` has expectation
Σ_t (p_sampled/p_eval)·C_t (terms with p_eval = 0 add nothing), C_t = ∫_texel L cos⁺ dω.  So its
relative bias for a normal is Σ_t (p_sampled/p_eval − 1)·C_t / Σ_t C_t, and its *missed mass* is
Σ C_t over texels with p_sampled = 0 and L > 0, relative to ∫ L cos⁺ over the whole sphere.

Stress maps (``stress_map``): ``sun-1e6``/``sun-1e9`` (R = 64, smooth sky × 0.01 with the middle
texel of +Z set to 1e6/1e9 × the sky's maximum) and ``huge-faces`` (R = 1024, the smooth sky).
``DIM_NORMALS`` see part of the sun's face but have the sun below their horizon: they see only
texels *after* the sun in scan order (later columns of the sun's row, later rows of the marginal),
whose bins collapsed in the float32 CDFs (2942 lit texels never drawn on sun-1e9, 3.6% of a
dim-only normal's integral missed; none with the fixed-point CDFs).

Run it as ``python -m iblbench.harness.verify.cdf_precision`` for the table.
"""
from __future__ import annotations

import numpy as np

from iblbench.harness.verify.conformance import SUN_FACE, smooth_map, sun_map
from iblbench.scenes import cubemap

FIXED_POINT_ONE = 2 ** 63          # a fixed-point CDF's total (kernels/common.cl)

DIM_NORMALS = {
    "down": (0.0, -1.0, -0.3),        # rows below the sun's row (late in the marginal)
    "right": (1.0, 0.0, -0.3),        # columns right of the sun (late in its row), all rows
    "down-right": (1.0, -1.0, -0.6),
}


def stress_map(name: str) -> np.ndarray:
    """``sun-1e6``, ``sun-1e9`` (R = 64) or ``huge-faces`` (R = 1024), float32 ``[6, R, R, 3]``."""
    if name.startswith("sun-"):
        return sun_map(64, float(name[4:]))
    if name == "huge-faces":
        return smooth_map(1024)
    raise KeyError(f"unknown map '{name}'; valid: sun-1e6, sun-1e9, huge-faces")


def exact_texel_probabilities(env: np.ndarray) -> np.ndarray:
    """P(texel | face) = Y·Ω / I_f in float64 ``[6, R, R]`` (0 on a black face)."""
    weight = np.maximum(cubemap.luminance(env), 0.0) * cubemap.texel_solid_angles(env.shape[1])
    total = weight.sum(axis=(1, 2), keepdims=True)
    return np.divide(weight, total, out=np.zeros_like(weight), where=total > 0)


def _fixed_bins(cdf: np.ndarray, variate_bits: int = 63) -> tuple[np.ndarray, np.ndarray]:
    """(evaluated float32 widths, drawn probabilities) of fixed-point (uint64) CDFs searched with
    ``variate_bits``-bit variates (63: every sampler's, exact widths; 24: what a float32 variate
    would reach, the CDF on a grid of 2^39 units)."""
    cdf = np.asarray(cdf, np.uint64)
    width = np.diff(cdf, axis=-1, prepend=np.uint64(0))
    evaluated = width.astype(np.float32) * np.float32(2.0 ** -63)
    if variate_bits >= 63:
        return evaluated, width.astype(np.float64) / FIXED_POINT_ONE
    step = np.uint64(1 << (63 - variate_bits))
    cells = (cdf + step - np.uint64(1)) // step                     # ⌈c / step⌉, exact
    drawn = np.diff(cells, axis=-1, prepend=np.uint64(0)).astype(np.float64) / 2.0 ** variate_bits
    return evaluated, drawn


def sampler_probabilities(marginal: np.ndarray, conditional: np.ndarray, variate_bits: int = 63
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(p_eval float32, p_sampled float64), each ``[6, R, R]``, from the fixed-point device CDFs
    as :meth:`FrameCache.host_cdfs` returns them, searched with ``variate_bits``-bit variates."""
    row_eval, row_drawn = _fixed_bins(marginal, variate_bits)
    col_eval, col_drawn = _fixed_bins(conditional, variate_bits)
    return row_eval[..., None] * col_eval, row_drawn[..., None] * col_drawn


def texel_cosine_integrals(normal, res: int, sub: int = 4) -> np.ndarray:
    """∫_texel cos⁺(n, ω) dω per texel, float64 ``[6, R, R]``: midpoint rule on ``sub``² exact
    sub-texels (the sub-texel grid of a cube map of ``res·sub``)."""
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    fine = res * sub
    cosine = np.maximum(cubemap.texel_directions(fine) @ n, 0.0) * cubemap.texel_solid_angles(fine)
    return cosine.reshape(6, res, sub, res, sub).sum(axis=(2, 4))


def light_sampler_figures(env: np.ndarray, marginal: np.ndarray, conditional: np.ndarray,
                          normals: dict | None = None, sub: int = 4, variate_bits: int = 63) -> dict:
    """The audit of one map's device CDFs (``marginal``, ``conditional`` from host_cdfs):

    - ``max_rel_error_eval`` / ``max_rel_error_sampled``: max over texels with p_exact > 0 of
      |p − p_exact| / p_exact (1 where a bin collapsed to 0);
    - ``zero_bins``: texels with L > 0 whose drawn probability is 0 (never sampled);
    - per normal: ``missed`` = Σ_{p_sampled = 0} L_Y·∫cos⁺ / Σ_all L_Y·∫cos⁺ (luminance),
      ``missed_on_face`` the same relative to the sun face's own share (what that face's light
      samples should find), and ``bias`` = Σ (p_sampled/p_eval − 1)·C / Σ C, the exact relative
      bias of a light sampler that evaluates p_eval and draws with p_sampled.
    """
    normals = DIM_NORMALS if normals is None else normals
    exact = exact_texel_probabilities(env)
    p_eval, p_sampled = sampler_probabilities(marginal, conditional, variate_bits)
    lum = np.maximum(cubemap.luminance(env), 0.0)
    lit = exact > 0
    rel_eval = np.abs(p_eval.astype(np.float64)[lit] - exact[lit]) / exact[lit]
    rel_sampled = np.abs(p_sampled[lit] - exact[lit]) / exact[lit]
    never = (p_sampled == 0) & (lum > 0)
    ratio = np.divide(p_sampled, p_eval.astype(np.float64), out=np.zeros_like(p_sampled),
                      where=p_eval > 0)
    out = {"res": env.shape[1], "max_rel_error_eval": float(rel_eval.max()),
           "max_rel_error_sampled": float(rel_sampled.max()), "zero_bins": int(never.sum()),
           "normals": {}}
    for name, normal in normals.items():
        contribution = lum * texel_cosine_integrals(normal, env.shape[1], sub)
        total = contribution.sum()
        face_total = contribution[SUN_FACE].sum()
        out["normals"][name] = {
            "missed": float(contribution[never].sum() / total),
            "missed_on_face": float(contribution[SUN_FACE][never[SUN_FACE]].sum() / face_total)
            if face_total > 0 else 0.0,
            "bias": float(((ratio - 1.0) * contribution).sum() / total),
        }
    return out


def audit(name: str, compute=None, normals: dict | None = None, variate_bits: int = 63) -> dict:
    """:func:`light_sampler_figures` of stress map ``name`` on the device's CDFs."""
    from iblbench.estimators.runtime.device import get_compute
    from iblbench.estimators.runtime.framecache import FrameCache

    env = stress_map(name)
    cache = FrameCache(compute or get_compute(), env)
    marginal, conditional = cache.host_cdfs()
    return light_sampler_figures(env, marginal, conditional, normals,
                                 sub=1 if env.shape[1] > 256 else 4, variate_bits=variate_bits)


def main() -> None:
    import argparse
    parser = argparse.ArgumentParser(description="Exact audit of the device light CDFs.")
    parser.add_argument("--variate-bits", type=int, default=63,
                        help="bits of the search variate (63: the samplers' variates; 24: "
                             "what a float32 variate would reach)")
    bits = parser.parse_args().variate_bits
    for name in ("sun-1e6", "sun-1e9", "huge-faces"):
        r = audit(name, variate_bits=bits)
        print(f"{name} (R={r['res']}): max rel error eval {r['max_rel_error_eval']:.3g}, "
              f"sampled {r['max_rel_error_sampled']:.3g}; never-sampled lit texels {r['zero_bins']}")
        for normal, f in r["normals"].items():
            print(f"  {normal:>10}: missed {f['missed']:.4g} of ∫L cos⁺ "
                  f"({f['missed_on_face']:.4g} of the sun face's share); bias {f['bias']:+.4g}")


if __name__ == "__main__":
    main()
