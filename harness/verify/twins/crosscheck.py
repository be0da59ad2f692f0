"""An estimator against its NumPy twin, in distribution over independent chains, on
``rotating-sun`` (scenes/sequences.py): a map that turns 1° a frame with held frames and never
re-initialises (issue 13 §1).  Used by ``conformance.check_matches_twin`` (small) and
tests/test_smc_twin.py (large).

Each shading point is repeated over R pixels of a synthetic G-buffer: the estimator's pixels
draw independent random streams, so one render gives R independent runs of the same point's
sampler, and the twin runs R chains of each point.  Per frame, point and channel:

- :func:`mean_z`: the Welch z of the two mean estimates;
- :func:`log_variance_z`: log(s²_est/s²_twin) over its large-sample standard error
  √((κ_est − 1 + κ_twin − 1)/R), κ the sample kurtosis (the heavy tails of a glossy point under
  a sun widen it).

The caller compares the largest |z| with a Šidák-corrected bound.
"""
from __future__ import annotations

import importlib

import numpy as np

from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.harness.verify.twins.ghosh2006 import Shading
from iblbench.scenes import sequences, sky
from iblbench.scenes.gbuffer import GBuffer

ENV_RES = 16
SUN = sky.sun_direction(35.0, 63.0)   # the sun of rotating-sun at frame 3


def shading_points():
    """(normal, view, kd, ks, m) of five points: a rough one facing the sun, two glossy ones
    mirroring the sun's path (m = 200 and 60), and two lit by the sun at a grazing angle
    (n·sun = 0.15, so the warm sun and the blue sky share γ and a sampler that overweights
    either is seen in the colour)."""
    def mirrored(n):
        n = np.asarray(n, float) / np.linalg.norm(n)
        return n, 2 * np.dot(n, SUN) * n - SUN
    side = np.cross(SUN, [0.0, 1.0, 0.0])
    grazing = 0.15 * SUN + np.sqrt(1 - 0.15 ** 2) * np.cross(side / np.linalg.norm(side), SUN)
    points = [(SUN + [0.0, 0.3, 0.0], SUN, 0.5, 0.3, 20.0),
              (*mirrored([0, 1, 0]), 0.3, 0.6, 200.0),
              (*mirrored([0.6, 1.0, 0.4]), 0.2, 0.7, 60.0),
              (grazing, grazing, 0.8, 0.0, 1.0),
              (grazing, grazing, 0.5, 0.3, 20.0)]
    normal, view, kd, ks, m = (np.array(column, float) for column in zip(*points))
    unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)
    return unit(normal), unit(view), kd[:, None] * np.ones(3), ks[:, None] * np.ones(3), m


def replicated(chains):
    """The shading points repeated ``chains`` times each, as ``[points, chains, …]`` arrays."""
    return [np.repeat(a[:, None], chains, axis=1) for a in shading_points()]


def estimator_runs(compute, estimator, frames, chains, spp, seed):
    """The estimator's estimates ``[frames, points, chains, 3]`` on ``rotating-sun`` from
    ``reset()``, its re-inits (the ``reinits`` extra, 0 where it has none) and the G-buffer."""
    normal, view, kd, ks, m = replicated(chains)
    gbuffer = DeviceGBuffer(compute, GBuffer.from_pixels(normal, view, kd, ks, m))
    sequence = sequences.rotating_sun(ENV_RES)
    estimator.reset()
    estimates, reinits = [], 0
    for t in range(frames):
        cache = FrameCache(compute, sequence.frame(t), frame=t)
        cache.require(type(estimator).requires)
        estimate = estimator.render(gbuffer, cache, spp, seed)
        estimates.append(estimate.radiance.astype(np.float64))
        reinits += estimate.extras.get("reinits", 0)
    return np.array(estimates), reinits, gbuffer


def twin_runs(estimator, frames, chains, spp, seed):
    """The twin's estimates ``[frames, points, chains, 3]`` (``type(estimator).twin``) and its
    re-inits."""
    points = len(shading_points()[-1])
    flat = [a.reshape((points * chains,) + a.shape[2:]) for a in replicated(chains)]
    module = importlib.import_module(type(estimator).twin)
    twin = module.sampler(Shading(*flat), estimator.params, spp, seed)
    sequence = sequences.rotating_sun(ENV_RES)
    return np.array([twin.render(sequence.frame(t)).reshape(points, chains, 3)
                     for t in range(frames)]), twin.reinits


def mean_z(estimates, twin):
    """Welch z of the mean estimates ``[frames, points, channels]`` (chains on axis 2)."""
    chains = estimates.shape[2]
    spread = np.sqrt(estimates.var(2, ddof=1) / chains + twin.var(2, ddof=1) / twin.shape[2])
    return (estimates.mean(2) - twin.mean(2)) / spread


def log_variance_z(estimates, twin):
    """z of log(s²_est/s²_twin) ``[frames, points, channels]`` (module docstring)."""
    def log_var_and_excess(a):
        centred = a - a.mean(2, keepdims=True)
        m2, m4 = np.mean(centred ** 2, 2), np.mean(centred ** 4, 2)
        return np.log(m2), (m4 / m2 ** 2 - 1) / a.shape[2]

    (log_e, excess_e), (log_t, excess_t) = log_var_and_excess(estimates), log_var_and_excess(twin)
    return (log_e - log_t) / np.sqrt(excess_e + excess_t)
