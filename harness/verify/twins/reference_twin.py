"""An independent NumPy twin of the exact reference (estimators/runtime/reference.cl), at the 1e-4 level.

tests/test_reference_twin.py holds it to closed forms and to the kernel; `iblbench doctor`
compares each device's reference with it.

The twin integrates ARCHITECTURE.md §Conventions's reference, Σ_texels L_t ∫_texel ρ cos⁺ dω with Lafortune Phong
ρ = kd/π + ks·(m+2)/(2π)·max(0, r·ω)^m, its own way and shares no code with reference.cl or
reference.py (no Lambert/Arvo polygon formula, no sub-cell midpoint rule, no lobe cutoff of
theirs, its own cube-face table written from the OpenGL convention):

- On a face, the direction of face-plane point (u, v) is W + uU + vV (unnormalised), so
  n·ω = (a + bu + cv)/√q and r·ω likewise, with q = 1 + u² + v², and dω = du dv / q^{3/2}.
  The horizon n·ω = 0 and the lobe's plane r·ω = 0 are straight lines on the face plane.
- Each texel (or sub-square of it) is clipped to the half-planes where the integrand is
  non-zero (n·ω ≥ 0, and r·ω ≥ 0 for the lobe), which leaves a convex polygon on which the
  integrand is smooth, and the polygon is integrated by a collapsed Gauss–Legendre rule
  (Duffy) on the triangles of a fan: exponential convergence, no kink inside a cell.
- For the lobe, texels are split into sub-squares no wider than ``LOBE_WIDTHS_PER_CELL`` lobe
  widths 1/√m, so the rule resolves the peak; texels whose nearest point is where
  cos^m < ``LOBE_NEGLIGIBLE`` are left out (their share is below 1e-16 of the pixel's lobe).

The twin's own accuracy is checked against closed forms (the white furnace, and the lobe's
hemisphere integral 2π/(m+2) on a constant map seen head-on), its rule against a rule of
twice the order, and one texel on the flank of a lobe of m = 3000 against a nested Gauss rule
with exact limits (within 1e-9; measured 5e-14).
"""
from __future__ import annotations

import numpy as np

from iblbench.scenes.gbuffer import GBuffer

# Face f: (W, U, V) with direction(u, v) = W + u·U + v·V, from the OpenGL cube-map table
# (s = (sc/|ma| + 1)/2 with (sc, tc) per major axis; rows grow with t).
OPENGL_FACES = {
    0: ((1, 0, 0), (0, 0, -1), (0, -1, 0)),    # +X: sc = −z, tc = −y
    1: ((-1, 0, 0), (0, 0, 1), (0, -1, 0)),    # −X: sc = +z, tc = −y
    2: ((0, 1, 0), (1, 0, 0), (0, 0, 1)),      # +Y: sc = +x, tc = +z
    3: ((0, -1, 0), (1, 0, 0), (0, 0, -1)),    # −Y: sc = +x, tc = −z
    4: ((0, 0, 1), (1, 0, 0), (0, -1, 0)),     # +Z: sc = +x, tc = −y
    5: ((0, 0, -1), (-1, 0, 0), (0, -1, 0)),   # −Z: sc = −x, tc = −y
}
GAUSS_ORDER = 8              # Gauss–Legendre points per axis of the collapsed triangle rule
MAX_CELL = 0.25              # largest sub-square side on the face plane (diffuse and lobe)
LOBE_WIDTHS_PER_CELL = 2.0   # sub-square side ≤ this many lobe widths 1/√m (face-plane units)
LOBE_NEGLIGIBLE = 1e-16      # texels where cos(r, ω)^m stays below this are left out


def _clip(polygons: np.ndarray, counts: np.ndarray, line: np.ndarray):
    """Sutherland–Hodgman on a batch: convex ``polygons`` [N, K, 2] with ``counts`` [N] vertices,
    each kept where a + b·u + c·v ≥ 0, ``line`` [N, 3] = (a, b, c)."""
    n, k = polygons.shape[:2]
    index = np.arange(k)
    valid = index[None] < counts[:, None]
    following = np.where(index[None] + 1 < counts[:, None], index[None] + 1, 0)
    nxt = np.take_along_axis(polygons, following[..., None], axis=1)
    side = line[:, :1] + line[:, 1:2] * polygons[..., 0] + line[:, 2:] * polygons[..., 1]
    side_next = np.take_along_axis(side, following, axis=1)
    inside, inside_next = side >= 0, side_next >= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(inside != inside_next, side / (side - side_next), 0.0)
    crossing = polygons + share[..., None] * (nxt - polygons)
    candidates = np.stack([polygons, crossing], axis=2).reshape(n, 2 * k, 2)
    keep = np.stack([valid & inside, valid & (inside != inside_next)], axis=2).reshape(n, 2 * k)
    order = np.argsort(~keep, axis=1, kind="stable")
    out_counts = keep.sum(axis=1)
    width = max(int(out_counts.max(initial=0)), 1)
    return np.take_along_axis(candidates, order[:, :width, None], axis=1), out_counts


def _triangle_rule(order: int):
    """Collapsed Gauss–Legendre rule on the triangle A + ξ(B − A) + ξη(C − B), (ξ, η) ∈ [0, 1]²:
    (ξ, η, weight including the Jacobian factor ξ), each [order²]; the area factor is |det|."""
    x, w = np.polynomial.legendre.leggauss(order)
    x, w = (x + 1) / 2, w / 2
    xi, eta = np.meshgrid(x, x, indexing="ij")
    return xi.ravel(), eta.ravel(), (np.outer(w, w) * xi).ravel()


def _integrate(polygons, counts, integrand, order: int) -> np.ndarray:
    """∫ integrand(u, v, item) du dv over each convex polygon [N], by fans of triangles."""
    xi, eta, weight = _triangle_rule(order)
    total = np.zeros(len(polygons))
    for j in range(1, polygons.shape[1] - 1):
        live = np.flatnonzero(counts > j + 1)
        if not len(live):
            break
        a, b, c = polygons[live, 0], polygons[live, j], polygons[live, j + 1]
        area = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - b[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - b[:, 0]))
        points = (a[:, None] + xi[None, :, None] * (b - a)[:, None]
                  + (xi * eta)[None, :, None] * (c - b)[:, None])
        values = integrand(points[..., 0], points[..., 1], live)
        total[live] += area * (values @ weight)
    return total


def _squares(res: int, split: np.ndarray):
    """Sub-squares of every texel of one face: texel t split into split[t]² squares.
    Returns corners [N, 4, 2] (counter-clockwise) and the texel of each [N]."""
    texels = np.repeat(np.arange(res * res), split.ravel() ** 2)
    first = np.concatenate([[0], np.cumsum(split.ravel() ** 2)[:-1]])
    local = np.arange(len(texels)) - np.repeat(first, split.ravel() ** 2)
    k = split.ravel()[texels]
    row, col = texels // res, texels % res
    size = 2.0 / res / k
    u0 = -1 + 2.0 * col / res + (local % k) * size
    v0 = -1 + 2.0 * row / res + (local // k) * size
    corners = np.stack([np.stack([u0, v0], -1), np.stack([u0 + size, v0], -1),
                        np.stack([u0 + size, v0 + size], -1), np.stack([u0, v0 + size], -1)], 1)
    return corners, texels


def texel_integrals(normal, view, m: float, res: int, order: int = GAUSS_ORDER):
    """Per texel [6, R, R]: (∫ cos⁺(n·ω) dω, ∫ max(0, r·ω)^m cos⁺(n·ω) dω) for one pixel."""
    normal, view = np.asarray(normal, np.float64), np.asarray(view, np.float64)
    r = 2 * np.dot(normal, view) * normal - view
    r /= np.linalg.norm(r)
    cosine = np.zeros((6, res * res))
    lobe = np.zeros((6, res * res))
    base = max(1, int(np.ceil(2.0 / res / MAX_CELL)))
    for face, (w_axis, u_axis, v_axis) in OPENGL_FACES.items():
        w_axis, u_axis, v_axis = (np.array(a, np.float64) for a in (w_axis, u_axis, v_axis))
        horizon = np.array([normal @ w_axis, normal @ u_axis, normal @ v_axis])
        mirror = np.array([r @ w_axis, r @ u_axis, r @ v_axis])

        def linear(form, u, v):
            return form[0] + form[1] * u + form[2] * v

        def diffuse(u, v, item):
            return linear(horizon, u, v) / (1 + u * u + v * v) ** 2

        def specular(u, v, item):
            q = 1 + u * u + v * v
            cos_r = np.maximum(linear(mirror, u, v), 0.0) / np.sqrt(q)
            power = np.ones_like(cos_r) if m == 0 else np.exp(m * np.log(np.maximum(cos_r, 1e-300)))
            return power * linear(horizon, u, v) / q ** 2

        split = np.full((res, res), base)
        corners, texels = _squares(res, split)
        lines = np.broadcast_to(horizon, (len(corners), 3))
        polygons, counts = _clip(corners, np.full(len(corners), 4), lines)
        np.add.at(cosine[face], texels, _integrate(polygons, counts, diffuse, order))

        # The lobe: texels whose nearest direction to r is within the lobe, split finely.
        side = 2.0 / res
        centre = (np.arange(res) + 0.5) * side - 1
        v, u = np.meshgrid(centre, centre, indexing="ij")
        direction = w_axis + u[..., None] * u_axis + v[..., None] * v_axis
        length = np.linalg.norm(direction, axis=-1)
        radius = np.arcsin(np.minimum(1.0, side / np.sqrt(2) / length))   # bounds the texel's cap
        angle = np.arccos(np.clip(direction @ r / length, -1, 1))
        nearest = np.cos(np.minimum(np.maximum(angle - radius, 0.0), np.pi / 2))
        reached = (nearest > 0) if m == 0 else (m * np.log(np.maximum(nearest, 1e-300))
                                                > np.log(LOBE_NEGLIGIBLE))
        cells = np.ceil(side * np.sqrt(max(m, 1.0)) / LOBE_WIDTHS_PER_CELL).astype(int)
        split = np.where(reached, max(base, cells), 0)
        corners, texels = _squares(res, split)
        if len(corners):
            polygons, counts = _clip(corners, np.full(len(corners), 4),
                                     np.broadcast_to(horizon, (len(corners), 3)))
            polygons, counts = _clip(polygons, counts, np.broadcast_to(mirror, (len(corners), 3)))
            np.add.at(lobe[face], texels, _integrate(polygons, counts, specular, order))
    return cosine.reshape(6, res, res), lobe.reshape(6, res, res)


def texel_visibility(words: np.ndarray, vis_res: int, res: int) -> np.ndarray:
    """V per texel [6, R, R] (0 or 1) of one pixel's visibility mask ``words`` (uint32): texel
    (f, row, col) lies in cell (f, row·Rv/R, col·Rv/R), whose bit is bit b % 32 of word b // 32,
    b = (f·Rv + cell row)·Rv + cell column (the layout of iblbench.scenes.visibility)."""
    face, row, col = np.meshgrid(np.arange(6), np.arange(res), np.arange(res), indexing="ij")
    bit = (face * vis_res + row * vis_res // res) * vis_res + col * vis_res // res
    return (np.asarray(words, np.uint64)[bit // 32] >> (bit % 32).astype(np.uint64)) & 1


def twin_image(gbuffer: GBuffer, env: np.ndarray, order: int = GAUSS_ORDER) -> np.ndarray:
    """The reference radiance of every covered pixel [H, W, 3], float64 (0 where uncovered, as
    the reference's); with the G-buffer's visibility masks, each texel's integrals times its
    cell's V."""
    env = np.asarray(env, np.float64)
    out = np.zeros(gbuffer.shape + (3,))
    for index in zip(*np.nonzero(gbuffer.mask)):   # uncovered pixels (zero vectors) stay 0
        m = float(gbuffer.shininess[index])
        cosine, lobe = texel_integrals(gbuffer.normal[index], gbuffer.view[index], m, env.shape[1], order)
        if gbuffer.visibility is not None:
            open_texels = texel_visibility(gbuffer.visibility[index], gbuffer.visibility_res, env.shape[1])
            cosine, lobe = cosine * open_texels, lobe * open_texels
        diffuse = np.einsum("frc,frck->k", cosine, env)
        specular = np.einsum("frc,frck->k", lobe, env)
        # float64 kd and ks: a float32 array times a Python float stays float32 (3e-8 off)
        kd, ks = gbuffer.kd[index].astype(np.float64), gbuffer.ks[index].astype(np.float64)
        out[index] = kd / np.pi * diffuse + ks * (m + 2) / (2 * np.pi) * specular
    return out
