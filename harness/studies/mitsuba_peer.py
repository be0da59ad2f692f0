"""The production peer of ``iblbench perf``: Mitsuba 3's own environment-map light sampling on the
same G-buffer, Phong-shaded as ``envmap`` shades, so that the light-only production samplers
(``envmap``, ``hierarchical``) can be timed against a production renderer doing the same work.

The work.  For each covered pixel and each of its spp samples: a 2-D uniform point from a PCG32
stream (Mitsuba's ``independent`` sampler's seeding: ``sample_tea_32`` of the seed and the lane),
a direction from Mitsuba's ``envmap`` emitter plugin (``Emitter.sample_direction``: its
``Hierarchical2D`` warp over luminance × sin θ, the bilinear radiance lookup, the density in
solid angle; it returns L/pdf), then ``envmap.cl``'s shading of that sample (``add_samples``):
(kd/π + ks·(m + 2)/(2π)·max(r·ω, 0)^m)·(n·ω)·L/pdf where n·ω > 0, r the mirror direction of the
view about n; the per-pixel sum over its samples (``dr.block_sum``) divided by spp is the pixel's
estimate, as ``envmap``'s light-only estimate is.  All pixels × samples are one Dr.Jit wavefront,
traced and compiled into one LLVM kernel (cached by Dr.Jit after the first render) that runs on
Dr.Jit's thread pool, one thread per core, and writes each sample's value (12 B); three small
kernels then sum each pixel's block (``block_sum`` needs its input evaluated; a
``scatter_reduce`` into the pixels instead, fused into the one kernel, measured 1.3× slower).  A render's time is its kernels' execution time by
Dr.Jit's kernel history (what the estimators' OpenCL profiling events are to them), and beside it
the host wall time from the trace to ``dr.sync_thread()`` (the Python tracing included); the
emitter's construction (the warp's build) is timed apart, as the estimators' CDF builds are.

Deviations from the iblbench kernels' work: the peer reads no visibility mask (on a scene with
one, iblbench's kernels do one more load per sample, so the ratio there favours the peer), and its
lobe power is Dr.Jit's exp2(m·log2 x) where the kernels evaluate a polynomial.

The environment.  Mitsuba's ``envmap`` takes a latitude-longitude bitmap of H rows and W = 2H
columns; its row y is the polar angle θ = π·y/(H − 1) (the first and last rows at the poles),
its column x the azimuth φ = 2π·(x + ½)/W, and the direction is (sin θ sin φ, cos θ,
−sin θ cos φ), Y up as in iblbench's cube maps (ARCHITECTURE.md §Conventions), so no rotation is
needed.  Between those points it interpolates bilinearly.  :func:`latlong_from_cube` converts a
cube map [6, R, R, 3] at H = 2R by default (the equator keeps the cube's 4R texels, so the
peer's tables are the cube's size, not larger): every cube texel is split into SUPERSAMPLE²
squares, each square's power L·Ω (Ω its exact solid angle, ``cubemap.texel_solid_angles``) goes
to the lat-long cell its centre falls in (the cell of row y: θ within Δθ/2 = π/(2(H − 1)) of
the row's, clipped to [0, π]; of column x: φ in [2πx/W, 2π(x + 1)/W)), and each cell's radiance
is its power over its solid angle.  So Σ L·Ω is the cube map's exactly and a sun keeps its power,
placed within a cell of where it is; Mitsuba's bilinear lookup then blurs it by about a cell.
The peer therefore estimates a slightly blurred version of the cube map's integrand; its image
agrees with ``envmap``'s within the statistical tolerance tests/test_mitsuba_peer.py states (at
H = 4R within the noise alone).

Availability.  The peer needs the ``mitsuba`` package (``pip install 'iblbench[peer]'``) and its
``llvm_ad_rgb`` variant, which needs a libLLVM that Dr.Jit can load and compile with: Dr.Jit ≥ 1.0
(Mitsuba ≥ 3.6) aborts the process in LLVM 15's code generator (Debian 12's; ``Cannot select
fmaximum``), Mitsuba 3.5.2 (Dr.Jit 0.4.6) runs there.  :func:`unavailable` therefore compiles and runs a tiny
kernel in a child process first, and ``perf`` says in one line why the peer is absent.
"""
from __future__ import annotations

import importlib.util
import math
import subprocess
import sys
import time

import numpy as np

from iblbench.scenes.cubemap import texel_directions, texel_solid_angles

PEER = "mitsuba3-envmap"
VARIANT = "llvm_ad_rgb"
SUPERSAMPLE = 8         # squares per cube texel and axis of the conversion
PROBE = ("import drjit as dr, mitsuba as mi; mi.set_variant('llvm_ad_rgb'); "
         "x = dr.arange(mi.Float, 64) - 32.0; dr.eval(dr.maximum(x, 0.0)); "
         "print(mi.__version__)")
PROBE_TIMEOUT_S = 300


def unavailable() -> str | None:
    """None where the peer can run here, else why not, in one line (see the module docstring)."""
    if importlib.util.find_spec("mitsuba") is None:
        return "mitsuba is not installed (pip install 'iblbench[peer]')"
    try:
        probe = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                               timeout=PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return f"mitsuba's {VARIANT} variant did not run a test kernel in {PROBE_TIMEOUT_S} s"
    if probe.returncode == 0:
        return None
    lines = [line.strip() for line in probe.stderr.splitlines() if line.strip()]
    # LLVM's code generator aborts with its error first and a dump after; Python's error is last
    why = [line for line in lines if line.startswith("LLVM ERROR")] or lines[-1:] or [f"exit {probe.returncode}"]
    return f"mitsuba's {VARIANT} variant cannot run a kernel here: {why[0][:160]}"


def latlong_grid(height: int) -> tuple[np.ndarray, np.ndarray]:
    """(θ of each row, φ of each column) of Mitsuba's lat-long bitmap of ``height`` rows."""
    return (np.pi * np.arange(height) / (height - 1),
            2.0 * np.pi * (np.arange(2 * height) + 0.5) / (2 * height))


def latlong_cell_solid_angles(height: int) -> np.ndarray:
    """The solid angle of the cell of each row of the lat-long bitmap ``[H]``: the band
    [θ − Δθ/2, θ + Δθ/2] ∩ [0, π] of its row's θ by one column's Δφ."""
    theta, _ = latlong_grid(height)
    half = 0.5 * math.pi / (height - 1)
    low, high = np.maximum(theta - half, 0.0), np.minimum(theta + half, math.pi)
    return (np.cos(low) - np.cos(high)) * (2.0 * math.pi / (2 * height))


def latlong_from_cube(env: np.ndarray, height: int | None = None) -> np.ndarray:
    """The lat-long bitmap ``[H, 2H, 3]`` (float32) of cube map ``env`` ``[6, R, R, 3]`` for
    Mitsuba's ``envmap``, H = 2R unless given: every cube texel split into SUPERSAMPLE² squares,
    each square's power L·Ω (Ω its exact solid angle) added to the lat-long cell its centre falls
    in, each cell's power divided by its solid angle (module docstring)."""
    res = env.shape[1]
    height = height or 2 * res
    fine = res * SUPERSAMPLE
    directions = texel_directions(fine)                                       # [6, F, F, 3]
    theta = np.arccos(np.clip(directions[..., 1], -1.0, 1.0))
    phi = np.mod(np.arctan2(directions[..., 0], -directions[..., 2]), 2.0 * math.pi)
    row = np.clip(np.rint(theta * (height - 1) / math.pi).astype(np.int64), 0, height - 1)
    col = np.clip(np.floor(phi * height / math.pi).astype(np.int64), 0, 2 * height - 1)
    cell = (row * 2 * height + col).ravel()
    radiance = np.repeat(np.repeat(np.asarray(env, np.float64), SUPERSAMPLE, 1), SUPERSAMPLE, 2)
    power = radiance * texel_solid_angles(fine)[None, :, :, None]
    sums = np.stack([np.bincount(cell, power[..., k].ravel(), minlength=2 * height * height)
                     for k in range(3)], axis=-1).reshape(height, 2 * height, 3)
    return (sums / latlong_cell_solid_angles(height)[:, None, None]).astype(np.float32)


class MitsubaPeer:
    """Mitsuba's ``envmap`` emitter over ``env`` shading the pixels of ``surface`` (a
    perf.HostSurface: ``normal``, ``view``, ``kd``, ``ks`` [N, 3], ``shininess`` [N]) as the
    module docstring says, the map converted at ``height`` rows (:func:`latlong_from_cube`'s
    default unless given).  Construct only where :func:`unavailable` is None."""

    def __init__(self, surface, env: np.ndarray, height: int | None = None):
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(VARIANT)
        self.dr, self.mi = dr, mi
        bitmap = mi.Bitmap(latlong_from_cube(env, height))
        start = time.perf_counter()
        self.emitter = mi.load_dict({"type": "envmap", "bitmap": bitmap})
        self.build_ms = (time.perf_counter() - start) * 1e3
        normal = np.asarray(surface.normal, np.float32)
        view = np.asarray(surface.view, np.float32)
        mirror = 2.0 * np.sum(normal * view, axis=1, keepdims=True) * normal - view
        self.count = len(normal)
        self.normal, self.mirror = mi.Vector3f(normal), mi.Vector3f(mirror.astype(np.float32))
        self.kd_over_pi = mi.Color3f(np.asarray(surface.kd, np.float32) / np.float32(np.pi))
        shininess = np.asarray(surface.shininess, np.float32)
        lobe_norm = np.asarray(surface.ks, np.float32) * ((shininess + 2.0) / np.float32(2.0 * np.pi))[:, None]
        self.lobe_norm, self.shininess = mi.Color3f(lobe_norm), mi.Float(shininess)

    def render(self, spp: int, seed: int) -> tuple[np.ndarray, float, float]:
        """(the covered pixels' estimates [N, 3], the ms its kernels executed by Dr.Jit's kernel
        history, the host ms from trace to sync; the copy to NumPy after it is not timed)."""
        dr = self.dr
        dr.kernel_history()   # empties it
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            start = time.perf_counter()
            estimate = self._estimate(spp, seed)
            dr.eval(estimate)
            dr.sync_thread()
            host_ms = (time.perf_counter() - start) * 1e3
        kernel_ms = sum(kernel["execution_time"] for kernel in dr.kernel_history())
        return np.asarray(estimate, np.float32).reshape(self.count, 3), kernel_ms, host_ms

    def _estimate(self, spp: int, seed: int):
        """The traced (not yet evaluated) per-pixel estimates, a Color3f of N entries."""
        dr, mi = self.dr, self.mi
        lane = dr.arange(mi.UInt32, self.count * spp)
        pixel = lane // spp
        seed_lo, seed_hi = mi.sample_tea_32(dr.opaque(mi.UInt32, seed), lane)
        rng = mi.PCG32(size=self.count * spp, initstate=mi.UInt64(seed_lo), initseq=mi.UInt64(seed_hi))
        sample = mi.Point2f(rng.next_float32(), rng.next_float32())
        direction, weight = self.emitter.sample_direction(dr.zeros(mi.Interaction3f), sample, True)
        w = direction.d
        cosine = dr.dot(dr.gather(mi.Vector3f, self.normal, pixel), w)
        mirror = dr.maximum(dr.dot(dr.gather(mi.Vector3f, self.mirror, pixel), w), 0.0)
        power = dr.power(mirror, dr.gather(mi.Float, self.shininess, pixel))
        brdf = (dr.gather(mi.Color3f, self.kd_over_pi, pixel)
                + dr.gather(mi.Color3f, self.lobe_norm, pixel) * power)
        value = dr.select(cosine > 0.0, brdf * weight * cosine, 0.0)
        # One kernel for the three channels, then the block sums (block_sum evaluates its input:
        # left lazy, each channel would recompute the samples; a scatter_reduce into the pixels
        # measured 1.3× slower here).
        dr.eval(value)
        return mi.Color3f([dr.block_sum(value[k], spp) for k in range(3)]) / spp
