"""ΔE76: the mean CIE 1976 colour difference over covered pixels, of the protocol's tone-mapped
L*a*b* images (:mod:`iblbench.harness.protocol.metrics`).  Always computed: heat maps, flicker and
the budgets read it."""
from iblbench.harness.protocol.metric import Metric


def mean_delta_e76(image) -> float:
    return image.delta_e[0][image.mask].mean()


METRIC = Metric(name="de76", column="mean_delta_e76", label="ΔE76", unit="ΔE", order=10,
                score=mean_delta_e76, always=True)
