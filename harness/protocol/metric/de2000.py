"""ΔE2000: the mean CIEDE2000 colour difference over covered pixels, of the protocol's tone-mapped
L*a*b* images (:func:`iblbench.harness.protocol.metrics.delta_e2000`)."""
from iblbench.harness.protocol.metric import Metric


def mean_delta_e2000(image) -> float:
    return image.delta_e[1][image.mask].mean()


METRIC = Metric(name="de2000", column="mean_delta_e2000", label="ΔE2000", unit="ΔE", order=20,
                score=mean_delta_e2000, in_run_summary=False)
