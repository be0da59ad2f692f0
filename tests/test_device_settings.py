"""Device settings from the device's own info (issue 36, class 6): the estimators' lane width
(``-DPOOL_LANES``) and the FMA probe's width from every preferred float vector width the OpenCL
specification allows (1, 2, 4, 8, 16), and an explicit ``lanes`` that wins over the device's.

The devices here are stand-ins (a namespace with ``preferred_vector_width_float``), so every
width is checked whatever this machine's device prefers; the one real device only runs the FMA
kernel each width builds."""
from __future__ import annotations

import types

import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.runtime import device, probes
from iblbench.harness.verify import portability

SPEC_WIDTHS = (1, 2, 4, 8, 16)   # CL_DEVICE_PREFERRED_VECTOR_WIDTH_FLOAT's values (OpenCL 1.2 §4.2)


def fake_device(width: int):
    return types.SimpleNamespace(preferred_vector_width_float=width, name="fake", extensions="",
                                 type=cl.device_type.CPU)


def fake_info(width: int) -> device.DeviceInfo:
    return device.DeviceInfo(types.SimpleNamespace(name="fake", version="fake"), fake_device(width))


class FakeProgram:
    def get_build_info(self, *args):
        return ""


@pytest.fixture
def no_driver(monkeypatch):
    """Compute on a stand-in device: a context and queue that are never made, and program builds
    that record their options instead of compiling."""
    built = []
    monkeypatch.setattr(cl, "Context", lambda devices: ("context", devices))
    monkeypatch.setattr(cl, "CommandQueue", lambda context, properties=None: "queue")
    monkeypatch.setattr(device, "quietly_built",
                        lambda context, source, options: built.append(options) or (FakeProgram(), ""))
    return built


@pytest.mark.parametrize("width", SPEC_WIDTHS)
def test_the_lane_width_is_16_where_the_device_prefers_16_floats_else_8(no_driver, width):
    """ARCHITECTURE.md §Devices and portability: 16 where the preferred float width is 16, else 8;
    and that width is what every program is built with."""
    expected = 16 if width == 16 else 8
    assert device.pool_lanes_for(fake_device(width)) == expected
    compute = device.Compute(fake_info(width))
    assert compute.pool_lanes == expected
    compute.program("iblbench.estimators.runtime.kernels", "light_pool.cl")
    (options,) = no_driver
    assert [o for o in options if o.startswith("-DPOOL_LANES=")] == [f"-DPOOL_LANES={expected}"]


@pytest.mark.parametrize("width", SPEC_WIDTHS)
@pytest.mark.parametrize("lanes", (8, 16))
def test_an_explicit_lane_width_wins_over_the_devices(no_driver, width, lanes):
    """``lanes`` overrides the device's width, whichever it prefers, in the programs built and in
    the float path the portability set and ``doctor`` derive from that Compute."""
    compute = device.Compute(fake_info(width), lanes=lanes)
    assert compute.pool_lanes == lanes == device.pool_lanes_for(fake_device(width), lanes)
    compute.program("iblbench.estimators.runtime.kernels", "light_pool.cl")
    assert f"-DPOOL_LANES={lanes}" in no_driver[-1]
    single = portability.float_path(compute)
    assert (single.pool_lanes, single.fp64, single.info) == (lanes, False, compute.info)


@pytest.mark.parametrize("lanes", (0, 1, 4, 12, 32))
def test_a_lane_width_that_no_kernel_has_is_refused_before_any_device_work(no_driver, lanes):
    """light_pool.cl has 8- and 16-wide forms only; 0 is refused too, not read as "the device's"."""
    with pytest.raises(ValueError, match="lanes must be 8 or 16"):
        device.Compute(fake_info(16), lanes=lanes)


def test_a_portability_worker_hands_its_lane_width_to_its_child():
    """The child's third argument is the width (0: the device's own)."""
    assert portability.Worker("dev", lanes=16).command[-3:] == ["dev", "16", "1"]
    assert portability.Worker("dev", lanes=None, fp64=False).command[-3:] == ["dev", "0", "0"]


class AtWidth:
    """The real device's compute, seen through a stand-in device info of another width."""

    def __init__(self, compute, width: int):
        self._compute, self.info = compute, types.SimpleNamespace(device=fake_device(width))

    def __getattr__(self, name):
        return getattr(self._compute, name)


@pytest.mark.parametrize("width", SPEC_WIDTHS)
def test_the_fma_probe_runs_chains_of_the_devices_preferred_width(compute, width):
    """probes.fma_width is the preferred width itself, at each width the specification allows,
    and probes.cl builds and runs every FMA at it: with b = 1 each step is an exact float add
    (the NumPy replay of tests/test_perf.py), and the FLOPs count that width's lanes."""
    items, iterations, c = 4, 3, np.float32(0.25)
    stand_in = AtWidth(compute, width)
    assert probes.fma_width(stand_in) == width
    out, _, flops = probes.run_fma(stand_in, items, iterations, b=1.0, c=float(c))
    assert out.shape == (items, probes.FMA_CHAINS, width)
    expected = (np.arange(items, dtype=np.float32) * np.float32(1e-9))[:, None] \
        + np.arange(probes.FMA_CHAINS, dtype=np.float32)[None, :]
    for _ in range(iterations):
        expected = expected + c
    np.testing.assert_array_equal(out, np.broadcast_to(expected[:, :, None], out.shape))
    assert flops == 2 * width * probes.FMA_CHAINS * iterations * items
