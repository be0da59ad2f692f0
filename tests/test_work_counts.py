"""Counts of work (issue 36, class 1): ``check_work_counts`` (harness/verify/conformance.py) holds
every built-in's counts on every path to its ``work_counts`` formula (tests/test_estimators.py
runs it on each); here it rejects plugins whose counts are off on one path only, the NumPy
Philox twin that restir's formula draws its neighbours with is held to random123's known
answers and to the kernels, and smc's formula refuses a sequence whose counts it cannot know."""
import types

import numpy as np
import pyopencl as cl
import pytest

from iblbench.estimators.base import CountFrame, Estimator
from iblbench.estimators.bis import BIS
from iblbench.estimators.cosine import Cosine
from iblbench.estimators.runtime import philox
from iblbench.estimators.runtime.device import include_dirs
from iblbench.estimators.smc import SMC
from iblbench.harness.verify.conformance import Harness, check_work_counts, skipped_checks
from iblbench.harness.verify.fixtures import count_gbuffer, face_pattern_map


def test_philox_twin_gives_random123s_known_answers():
    """Random123's kat_vectors for philox4x32 with 10 rounds."""
    cases = [((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
             ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
             ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
              (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1))]
    for counter, key, expected in cases:
        assert tuple(int(word) for word in philox.philox4x32(counter, key)) == expected


RNG_KERNEL = """
#include "common.cl"
__kernel void blocks(__global const uint *args, __global uint *words, __global float *units)
{
    int i = get_global_id(0);
    __global const uint *a = args + 6 * i;
    philox4x32_ctr_t r = rng_block(a[0], a[1], a[2], a[3], a[4], a[5]);
    for (int j = 0; j < 4; ++j) {
        words[4 * i + j] = r.v[j];
        units[4 * i + j] = rng_unit(r.v[j]);
    }
}
"""


def test_philox_twin_is_the_kernels_rng_block(compute):
    """rng_block and rng_unit of common.cl, bit for bit, over random keys and counters (frames past
    2^24 included: the frame is shifted into the key's high bits)."""
    n = 512
    args = np.random.default_rng(36).integers(0, 2 ** 32, (n, 6), dtype=np.uint64).astype(np.uint32)
    args[:, 2] &= 0xFF
    program = cl.Program(compute.context, RNG_KERNEL).build(options=[f"-I{d}" for d in include_dirs()])
    words, units = compute.empty(16 * n), compute.empty(16 * n)
    program.blocks(compute.queue, (n,), None, compute.to_device(args), words, units)
    expected = np.stack(philox.rng_block(*args.T), axis=1)
    np.testing.assert_array_equal(compute.to_host(words, (n, 4), np.uint32), expected)
    np.testing.assert_array_equal(compute.to_host(units, (n, 4), np.float32), philox.rng_unit(expected))


class _OffOnAMaskedJump(Cosine):
    """``cosine`` with one shadow ray too many on one path: a masked G-buffer's last frame."""

    name = "test-off-on-a-masked-jump"

    def render(self, gbuffer, cache, spp, seed):
        estimate = super().render(gbuffer, cache, spp, seed)
        if cache.frame == 3 and gbuffer.has_visibility:
            estimate.shadow_rays += 1.0
        return estimate


class _OffInASetting(BIS):
    """``bis`` that counts one evaluation too many, only off its default N (a declared setting)."""

    name = "test-off-in-a-setting"

    def render(self, gbuffer, cache, spp, seed):
        estimate = super().render(gbuffer, cache, spp, seed)
        estimate.evaluations += float(self.params.N != type(self).Params().N)
        return estimate


def test_check_work_counts_finds_a_count_off_on_one_path_only(compute):
    with pytest.raises(AssertionError, match=r"test-off-on-a-masked-jump frame 3 masked: shadow_rays 4\.0 "
                                             r"where the docstring counts 3"):
        check_work_counts(_OffOnAMaskedJump(), Harness(compute))
    with pytest.raises(AssertionError, match=r"^8 counts off: test-off-in-a-setting\{N=5\} frame 0: evaluations"):
        check_work_counts(_OffInASetting(), Harness(compute))


def test_an_estimator_without_a_count_formula_skips_the_check():
    class Plain(Cosine):
        name = "test-plain"
        work_counts = Estimator.work_counts   # the contract's default: none declared

    assert "check_work_counts" in skipped_checks(Plain())
    assert "check_work_counts" not in skipped_checks(Cosine())


def test_smc_counts_refuse_a_change_whose_reinits_only_the_particles_know():
    """With the shape rule off (reinit_map_ess = 0), a map whose +Z face brightens 6× (its power
    1.83×, inside the threshold of 4; 1 + χ² = 2.03) leaves each pixel's own Z rule to decide:
    the formula says it cannot count that.  With the rule on (2/3 · 2.03 > 1) every pixel
    re-initialises."""
    still = face_pattern_map()
    moved = still.copy()
    moved[4] *= 6
    frames = [CountFrame(types.SimpleNamespace(env=env, frame=t), 3, 1) for t, env in enumerate((still, moved))]
    with pytest.raises(ValueError, match="scaled maps"):
        SMC(reinit_map_ess=0.0).work_counts(count_gbuffer(False), frames)
    counts = SMC().work_counts(count_gbuffer(False), frames)   # the shape rule fires: every pixel
    assert np.all(counts[1].evaluations == 60 + 3) and np.all(counts[1].shadow_rays == 60)
    assert counts[1].extras["reinits"] == 16
