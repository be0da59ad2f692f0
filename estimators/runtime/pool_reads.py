"""What pixels read of a frame's shared light-sample pool, copied back to the host: the one
function through which a run saves what Lu 2013's sample picture draws
(:mod:`iblbench.harness.protocol.report_inputs`) without reaching into the frame cache."""
from __future__ import annotations

import dataclasses

import numpy as np

from iblbench.estimators.runtime.framecache import FrameCache


@dataclasses.dataclass(frozen=True)
class PoolRead:
    """One pool estimator's pool at (spp, seed), and its split for each of the normals."""

    directions: np.ndarray       # [6·per_face, 3] the pool, face-major (float64)
    per_face: int                # pool entries per face
    ticks: np.ndarray            # [n, 7] the split in ticks: six faces, then the BRDF
    face_integrals: np.ndarray   # [6] I_f of the frame (a face without light has no entries)


def pool_reads(cache: FrameCache, estimators: dict, normals: np.ndarray, spp: int,
               seed: int = 0) -> dict:
    """For each of ``estimators`` (name → a pool estimator: ``pool_size(spp)`` and
    ``strategy_ticks(cache, normals, spp)``), the pool a render at (``spp``, ``seed``) of the
    frame of ``cache`` reads and its split for each of the unit ``normals`` ``[n, 3]``, through
    the estimators' own pool and split kernels."""
    compute = cache.compute
    normals = np.asarray(normals, np.float32).reshape(-1, 3)
    reads = {}
    for name, estimator in estimators.items():
        pool = cache.light_pool(estimator.pool_size(spp), seed)
        dir_pdf = compute.to_host(pool.dir_pdf, (6 * pool.per_face, 4), np.float32)
        ticks = estimator.strategy_ticks(cache, normals, spp)
        reads[name] = PoolRead(dir_pdf[:, :3].astype(np.float64), pool.per_face, ticks,
                               cache.face_integrals)
    return reads
