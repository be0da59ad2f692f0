"""``cosine`` (estimators/cosine.py): Malley's method draws directions with density cos⁺/π, which
is a Lambertian's integrand up to a constant, so under a constant map every single sample of a
Lambertian returns kd·L: the estimate is exact at any spp and seed (the conformance suite and the
stress battery hold it to the reference on glossy surfaces)."""
import numpy as np

from iblbench.estimators.registry import make_estimator
from iblbench.harness.verify.conformance import Harness
from iblbench.harness.verify.fixtures import fibonacci_directions
from iblbench.scenes.gbuffer import GBuffer


def test_a_lambertian_under_a_constant_map_has_no_variance(compute):
    normal = fibonacci_directions(64).reshape(8, 8, 3)   # every pixel covered, seen head-on
    kd, light = 0.6, np.array([0.7, 0.3, 0.1], np.float32)
    gbuffer, cache = Harness(compute).inputs(GBuffer.from_pixels(normal, normal, kd, 0.0, 1.0),
                                             np.broadcast_to(light, (6, 8, 8, 3)).copy())
    estimator = make_estimator("cosine")
    for spp, seed in [(1, 0), (1, 7), (5, 3)]:
        estimate = estimator.render(gbuffer, cache, spp, seed)
        np.testing.assert_allclose(estimate.radiance, np.broadcast_to(kd * light, (8, 8, 3)),
                                   rtol=1e-5)
        assert estimate.evaluations == spp and np.all(estimate.used == spp)
