"""What pixels read of a frame's shared light-sample pool, copied back to the host: the one
function through which a report draws Lu 2013's sample picture (``iblbench.reports``) without
reaching into the frame cache."""
from __future__ import annotations

import dataclasses

import numpy as np

from iblbench.estimators.runtime.framecache import FrameCache


@dataclasses.dataclass(frozen=True)
class PoolRead:
    """One pool estimator's pool at (spp, seed), and its split for one normal."""

    directions: np.ndarray       # [6·per_face, 3] the pool, face-major (float64)
    per_face: int                # pool entries per face
    ticks: np.ndarray            # [7] the split in ticks: six faces, then the BRDF
    face_integrals: np.ndarray   # [6] I_f of the frame (a face without light has no entries)


def pool_reads(compute, env: np.ndarray, frame: int, estimators: dict, normal: np.ndarray,
               spp: int, seed: int = 0) -> dict:
    """For each of ``estimators`` (name → a pool estimator: ``pool_size(spp)`` and
    ``strategy_ticks(cache, normals, spp)``), the pool a render at (``spp``, ``seed``) of frame
    ``frame`` of the map ``env`` reads and its split for the unit ``normal``, through the
    estimators' own pool and split kernels on one frame cache."""
    cache = FrameCache(compute, env, frame)
    normals = np.asarray(normal, np.float64)[None].astype(np.float32)
    reads = {}
    for name, estimator in estimators.items():
        pool = cache.light_pool(estimator.pool_size(spp), seed)
        dir_pdf = compute.to_host(pool.dir_pdf, (6 * pool.per_face, 4), np.float32)
        ticks = estimator.strategy_ticks(cache, normals, spp)[0]
        reads[name] = PoolRead(dir_pdf[:, :3].astype(np.float64), pool.per_face, ticks,
                               cache.face_integrals)
    return reads
