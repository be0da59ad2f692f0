"""Philox4x32-10 (Salmon et al. 2011, random123's constants) and the kernels' ``rng_block`` and
``rng_unit`` (common.cl) in NumPy: a host twin of the numbers a kernel draws, for checks that
recompute what a render did with them (``ReSTIR.work_counts``: the neighbours its spatial pass
found).  Written from the paper's round function, not from the kernels; tests/test_work_counts.py
holds it to random123's known-answer vectors and to the device."""
from __future__ import annotations

import numpy as np

MULTIPLIERS = (0xD2511F53, 0xCD9E8D57)
KEY_STEPS = (0x9E3779B9, 0xBB67AE85)
ROUNDS = 10
WORD = np.uint64(0xFFFFFFFF)


def philox4x32(counter, key) -> tuple[np.ndarray, ...]:
    """The four words of Philox4x32-10 of ``counter`` (four arrays or ints) under ``key`` (two),
    broadcast together, as uint32 arrays."""
    c0, c1, c2, c3 = (np.asarray(word, np.uint64) & WORD for word in counter)
    k0, k1 = (np.asarray(word, np.uint64) & WORD for word in key)
    for round_ in range(ROUNDS):
        if round_:
            k0, k1 = (k0 + np.uint64(KEY_STEPS[0])) & WORD, (k1 + np.uint64(KEY_STEPS[1])) & WORD
        product0, product1 = c0 * np.uint64(MULTIPLIERS[0]), c2 * np.uint64(MULTIPLIERS[1])
        c0, c1, c2, c3 = ((product1 >> np.uint64(32)) ^ c1 ^ k0, product1 & WORD,
                          (product0 >> np.uint64(32)) ^ c3 ^ k1, product0 & WORD)
    return tuple(word.astype(np.uint32) for word in (c0, c1, c2, c3))


def rng_block(seed, frame, stream, pixel, sample, draw) -> tuple[np.ndarray, ...]:
    """common.cl's ``rng_block``: the block keyed by (seed, frame·2^8 + stream), countered by
    (pixel, sample, draw, 0)."""
    key = (seed, (np.asarray(frame, np.uint64) << np.uint64(8)) | (np.asarray(stream, np.uint64) & np.uint64(0xFF)))
    return philox4x32((pixel, sample, draw, 0), key)


def rng_unit(word) -> np.ndarray:
    """common.cl's ``rng_unit``: the word's top 24 bits over 2^24, a float32 in [0, 1)."""
    return (np.asarray(word, np.uint32) >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / 16777216.0)
