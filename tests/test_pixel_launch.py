"""Pixel kernels run over a G-buffer padded to whole work groups (DeviceGBuffer): the padding
must neither reach the image nor change a real pixel's value."""
import dataclasses

import numpy as np
import pytest

from iblbench.harness.verify import conformance
from iblbench.estimators.runtime.device_gbuffer import PIXEL_GROUP, DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.harness.protocol.sweep import parse_estimator


def test_buffers_hold_whole_groups_padded_with_the_last_pixel(compute):
    gbuffer = conformance.glossy_gbuffer(9)   # 81 pixels
    device = DeviceGBuffer(compute, gbuffer)
    assert device.count == 81 and device.launch_size == 2 * PIXEL_GROUP
    normals = compute.to_host(device.normal, (device.launch_size, 4), np.float32)
    np.testing.assert_array_equal(normals[:81, :3], gbuffer.normal.reshape(-1, 3))
    np.testing.assert_array_equal(normals[81:], np.repeat(normals[80:81], device.launch_size - 81, 0))


@pytest.mark.parametrize("label", ["uniform", "balanced_mis{shared_sequence=false}",
                                   'envmap{mis="brdf"}', "fis", "havran"])
def test_a_pixel_does_not_depend_on_the_launch(compute, label):
    """The first 64 pixels rendered alone (one whole group, no padding) and within 169 pixels
    (three groups, the last padded): the same values, bit for bit, and nothing outside the mask."""
    gbuffer = conformance.glossy_gbuffer(13)
    alone = dataclasses.replace(gbuffer, mask=np.arange(169).reshape(13, 13) < PIXEL_GROUP)
    estimator = parse_estimator(label).make()
    cache = FrameCache(compute, conformance.sun_map(16, 50.0))
    cache.require(type(estimator).requires)
    whole = estimator.render(DeviceGBuffer(compute, gbuffer), cache, 8, 3)
    part = estimator.render(DeviceGBuffer(compute, alone), cache, 8, 3)
    for field in ("radiance", "used", "effective"):
        first = getattr(part, field)[alone.mask]
        np.testing.assert_array_equal(getattr(whole, field)[alone.mask], first)
        assert np.all(getattr(part, field)[~alone.mask] == 0)
    assert np.all(whole.radiance[gbuffer.mask] > 0)


@pytest.mark.parametrize("label", ["uniform", "envmap"])   # bis sizes its own groups (bis.py)
def test_a_device_that_allows_fewer_work_items_per_group_gets_a_divisor(compute, label):
    """Where a kernel may have fewer than PIXEL_GROUP work items per group (a GPU's limit for a
    kernel that holds many registers), launches use the largest divisor of the group within it,
    and the image is the same, bit for bit."""
    from iblbench.estimators.runtime.device import Compute

    gbuffer = conformance.glossy_gbuffer(9)
    estimator = parse_estimator(label).make()
    images, groups = [], []
    for limit in (None, 24):
        device = Compute(compute.info)
        if limit:
            fitting = device.fitting_group

            def limited(kernel, group):
                device._group_limits[kernel.int_ptr] = limit
                groups.append((group, fitting(kernel, group)))
                return groups[-1][1]

            device.fitting_group = limited
        cache = FrameCache(device, conformance.sun_map(8, 50.0))
        cache.require(type(estimator).requires)
        images.append(estimator.render(DeviceGBuffer(device, gbuffer), cache, 8, 1).radiance)
    assert (PIXEL_GROUP, 16) in groups and all(used <= 24 and wanted % used == 0
                                               for wanted, used in groups)
    np.testing.assert_array_equal(images[0], images[1])
