"""Launches split by measured device time (estimators/runtime/chunks.py): with a chunk target far
below one group's time, bis's and smc's kernels, every registered estimator's pixel kernels and
the reference run one group per launch, and their images are bit-identical to those of one
launch; at a target of a few groups' time each launch takes what the last one's measured rate
fills the target with."""
import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.bis import BIS
from iblbench.estimators.registry import estimator_classes, get_estimator_class
from iblbench.estimators.runtime import chunks
from iblbench.estimators.runtime.device import event_ms
from iblbench.estimators.runtime.device_gbuffer import DeviceGBuffer
from iblbench.estimators.runtime.framecache import FrameCache
from iblbench.estimators.runtime.reference import Reference
from iblbench.estimators.smc import ADVANCE_GROUP, SMC
from iblbench.harness.verify.fixtures import glossy_gbuffer, smooth_map

SIZE = 24   # 576 pixels: 9 groups of 64
# Work items per group of each kernel's launches: PIXEL_GROUP, bis's LOCKSTEP_GROUP, the
# reference's WORK_GROUP (64 each on a CPU), smc_advance's own.
GROUP = {"smc_advance": ADVANCE_GROUP}


@pytest.fixture
def launches(monkeypatch):
    """Every kernel launch from here on, as (kernel name, global size, event)."""
    seen = []
    enqueue = cl.enqueue_nd_range_kernel

    def recorded(queue, kernel, global_size, *args, **kwargs):
        event = enqueue(queue, kernel, global_size, *args, **kwargs)
        seen.append((kernel.function_name, global_size[0], event))
        return event

    monkeypatch.setattr(cl, "enqueue_nd_range_kernel", recorded)
    return seen


def _render(compute, monkeypatch, launches, estimator, envs, spp, chunk_ms, first_items, size=SIZE):
    """The frames' (radiance, used, effective, extras) and the launch sizes per kernel name."""
    monkeypatch.setattr(chunks, "CHUNK_MS", chunk_ms)
    monkeypatch.setattr(chunks, "FIRST_CHUNK_ITEMS", first_items)
    gbuffer = DeviceGBuffer(compute, glossy_gbuffer(size))
    launches.clear()
    frames = []
    for t, env in enumerate(envs):
        cache = FrameCache(compute, env, frame=t)
        cache.require(type(estimator).requires)
        e = estimator.render(gbuffer, cache, spp, 5)
        frames.append((e.radiance, e.used, e.effective, e.extras))
    sizes = {}
    for name, size, _ in launches:
        sizes.setdefault(name, []).append(size)
    return frames, sizes


def _assert_identical(chunked, whole):
    for (*images, extras), (*whole_images, whole_extras) in zip(chunked, whole):
        for image, whole_image in zip(images, whole_images):
            np.testing.assert_array_equal(image, whole_image)
        assert extras.keys() == whole_extras.keys()
        np.testing.assert_array_equal(list(extras.values()), list(whole_extras.values()))


def _smc_frames():
    """An init frame; the map turned (smc_advance moves every pixel's particles, none re-inits);
    one face 10× brighter (a fifth of the pixels re-initialised: smc_init's list shorter than its
    launches); everything ×1e3 (every pixel re-initialised).  Without the map-level test, which
    would re-initialise every pixel at the turn."""
    env = smooth_map(8)
    lit = env.copy()
    lit[4] *= 10
    return [env, np.roll(env, 3, axis=2), lit, 1e3 * lit]


SEQUENCES = {"bis": (BIS, [smooth_map(8)], ("render_bis",)),
             "smc": (lambda: SMC(reinit_map_ess=0.0), _smc_frames(), ("smc_advance", "smc_init"))}


@pytest.mark.parametrize("name", SEQUENCES)
def test_a_tiny_chunk_target_launches_one_group_at_a_time_and_changes_no_value(
        compute, monkeypatch, launches, name):
    make, envs, kernels = SEQUENCES[name]
    whole, whole_sizes = _render(compute, monkeypatch, launches, make(), envs, 8, chunks.CHUNK_MS, 10 ** 9)
    chunked, sizes = _render(compute, monkeypatch, launches, make(), envs, 8, 1e-6, 1)
    _assert_identical(chunked, whole)
    if name == "smc":   # the frames do what _smc_frames says
        reinits = [extras["reinits"] for *_, extras in whole]
        assert reinits[:2] == [0, 0] and 0 < reinits[2] < SIZE * SIZE and reinits[3] == SIZE * SIZE
    for kernel in kernels:
        frames = len(whole_sizes[kernel])   # the frames that launch it, once for the whole image
        assert frames >= 1 and set(whole_sizes[kernel]) == {SIZE * SIZE}
        # 576 pixels = 9 groups of 64 (36 of smc_advance's 16), each its own launch, every frame.
        group = GROUP.get(kernel, 64)
        assert sizes[kernel] == [group] * (SIZE * SIZE // group) * frames


def _runs(launches, kernels):
    """The launches of ``kernels`` as runs of one kernel each (one run_in_chunks call): (its
    name, [(work items, device ms) of each launch])."""
    runs, previous = [], None
    for name, size, event in launches:
        if name in kernels:
            if name != previous:
                runs.append((name, []))
            runs[-1][1].append((size, event_ms(event)))
        previous = name
    return runs


@pytest.mark.parametrize("name", SEQUENCES)
def test_each_launch_takes_what_the_last_ones_rate_fills_the_target_with(compute, monkeypatch,
                                                                         launches, name):
    """With a 16 ms target (a group of 64 pixels takes about 3 ms here at 128 spp), each launch
    after a run's first takes at most the items that the last launch's measured rate fills AIM
    of the target with, at most MOST_GROWTH× the last's, and a whole group at least: the rule
    that bounds every launch's time while the rate holds.  (Not the times themselves: other processes on a
    2-core CI machine made the same launch 2.5× slower from one to the next.)"""
    make, envs, kernels = SEQUENCES[name]
    target = 16.0
    _render(compute, monkeypatch, launches, make(), envs, 128, target, 1)
    runs = _runs(launches, kernels)
    assert len(runs) >= len(kernels)
    last = {}   # a kernel's later runs (frames) start from the rate of its last launch before
    for kernel, run in runs:
        group = GROUP.get(kernel, 64)
        assert sum(size for size, _ in run) == SIZE * SIZE
        if kernel in last:
            size, ms = last[kernel]
            assert run[0][0] <= max(group, size * chunks.AIM * target / ms), (last[kernel], run)
        else:
            assert len(run) > 1 and run[0][0] == group, run
        for (size, ms), (next_size, _) in zip(run, run[1:]):
            assert next_size <= max(group, min(chunks.MOST_GROWTH * size, size * chunks.AIM * target / ms)), run
        last[kernel] = run[-1]


@pytest.mark.parametrize("name", [cls.name for cls in estimator_classes()])
def test_every_estimator_renders_the_same_image_one_group_a_launch(compute, monkeypatch, launches,
                                                                  name):
    """Every registered estimator's pixel kernels (DeviceGBuffer.run, bis's and smc's own
    launches) split to one group a launch: more launches, the same two frames bit for bit."""
    cls = get_estimator_class(name)
    envs = [smooth_map(8), np.roll(smooth_map(8), 3, axis=2)]
    whole, whole_sizes = _render(compute, monkeypatch, launches, cls(), envs, 8, chunks.CHUNK_MS, 10 ** 9)
    chunked, sizes = _render(compute, monkeypatch, launches, cls(), envs, 8, 1e-6, 1)
    _assert_identical(chunked, whole)
    split = [kernel for kernel, size in whole_sizes.items() if size != sizes[kernel]]
    assert split and all(set(sizes[kernel]) == {GROUP.get(kernel, 64)} for kernel in split), sizes


def test_the_reference_is_the_same_one_group_a_launch(compute, monkeypatch, launches):
    gbuffer = DeviceGBuffer(compute, glossy_gbuffer(SIZE))
    cache = FrameCache(compute, smooth_map(8))
    images, sizes = [], []
    for chunk_ms, first_items in ((chunks.CHUNK_MS, 10 ** 9), (1e-6, 1)):
        monkeypatch.setattr(chunks, "CHUNK_MS", chunk_ms)
        monkeypatch.setattr(chunks, "FIRST_CHUNK_ITEMS", first_items)
        launches.clear()
        images.append(Reference(compute, use_cache=False).image(gbuffer, cache))
        sizes.append([size for name, size, _ in launches if name == "reference"])
    assert sizes == [[SIZE * SIZE], [64] * 9]
    np.testing.assert_array_equal(images[1], images[0])


def test_a_second_render_of_a_kind_starts_at_the_last_ones_rate(compute, monkeypatch, launches):
    """At the 100 ms target a first render's pixel kernel starts at one group and grows; a render
    of the same kernel, size and spp after it (another seed: the Philox keys set no item's work)
    starts at what the first one's last launch ran at, so its 576 pixels of 4 spp fit one launch."""
    monkeypatch.setattr(chunks, "_RATES", {})
    estimator, gbuffer = get_estimator_class("uniform")(), DeviceGBuffer(compute, glossy_gbuffer(SIZE))
    cache = FrameCache(compute, smooth_map(8))
    cache.require(type(estimator).requires)
    counts = []
    for seed in (1, 2):
        launches.clear()
        estimator.render(gbuffer, cache, 4, seed)
        counts.append(sum(name == "render_light_pool" for name, _, _ in launches))
    assert counts[0] > 1 and counts[1] == 1, counts
