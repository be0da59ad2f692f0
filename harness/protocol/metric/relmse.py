"""relMSE: mean((x − r)² / (r² + 0.01)) over covered pixels and channels, in linear HDR
(:func:`iblbench.harness.protocol.metrics.rel_mse`)."""
from iblbench.harness.protocol.metric import Metric
from iblbench.harness.protocol.metrics import rel_mse


def image_rel_mse(image) -> float:
    return rel_mse(image.radiance, image.reference, image.mask)


METRIC = Metric(name="relmse", column="rel_mse", label="relMSE", unit="", order=30,
                score=image_rel_mse)
