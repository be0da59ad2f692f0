"""The G-buffer's covered pixels, compacted and resident on the device for every frame."""
from __future__ import annotations

import numpy as np

from iblbench.harness.device import Compute
from iblbench.scenes.gbuffer import GBuffer


def _float4(xyz: np.ndarray, w: np.ndarray | float = 0.0) -> np.ndarray:
    out = np.empty(xyz.shape[:-1] + (4,), np.float32)
    out[..., :3] = xyz
    out[..., 3] = w
    return out


class DeviceGBuffer:
    """Covered pixels only, as float4 buffers: ``normal``, ``view``, ``kd`` and ``ks`` (w = shininess).

    Uploaded once per scene (geometry and camera are static).  ``scatter`` puts per-pixel
    kernel outputs back into the image.
    """

    def __init__(self, compute: Compute, gbuffer: GBuffer):
        self.gbuffer = gbuffer
        self.shape = gbuffer.shape
        self.pixel_index = np.flatnonzero(gbuffer.mask)
        self.count = len(self.pixel_index)
        self.is_diffuse = gbuffer.is_diffuse
        m = gbuffer.mask
        self.normal = compute.to_device(_float4(gbuffer.normal[m]))
        self.view = compute.to_device(_float4(gbuffer.view[m]))
        self.kd = compute.to_device(_float4(gbuffer.kd[m]))
        self.ks = compute.to_device(_float4(gbuffer.ks[m], gbuffer.shininess[m]))

    def scatter(self, values: np.ndarray) -> np.ndarray:
        """Per-covered-pixel ``[N, ...]`` → image ``[H, W, ...]`` with zeros elsewhere."""
        out = np.zeros((self.shape[0] * self.shape[1],) + values.shape[1:], values.dtype)
        out[self.pixel_index] = values
        return out.reshape(self.shape + values.shape[1:])
