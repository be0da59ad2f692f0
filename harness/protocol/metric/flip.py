"""HDR-FLIP: NVIDIA's flip-evaluator, its mean error over covered pixels (NaN where it is not
installed or the reference is black: :meth:`iblbench.harness.protocol.metrics.Scorer.flip`).  At
about 0.5 s an image it is scored on a cell's scored render only, so it has no replicates."""
from iblbench.harness.protocol.metric import Metric


def image_flip(image) -> float:
    return image.scorer.flip(image.radiance)


METRIC = Metric(name="flip", column="flip", label="FLIP", unit="", order=40, score=image_flip,
                replicated=False)
