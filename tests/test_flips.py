"""Flips stage (faults/flips.py): batched XORs on the GPU against the numpy twin `xor_words`,
exactly, and the second application restores the words bit for bit."""

import numpy as np

from seuwgpu.faults.flips import Flips, xor_words


def test_flips_match_twin_and_undo_exactly(gpu):
    rng = np.random.default_rng(9)
    words = [rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32) for n in (5000, 700, 3)]
    chunks = [gpu.upload(w) for w in words]
    stage = Flips(gpu, chunks)
    xors = {
        0: np.stack([rng.choice(5000, 1500, replace=False), rng.integers(1, 2**32, 1500)], 1).astype(np.uint32),
        2: np.array([[2, 0x80000000], [0, 0x00000001]], np.uint32),
    }
    stage.apply(xors)
    for c, w in enumerate(words):
        want = xor_words(w, xors[c]) if c in xors else w
        np.testing.assert_array_equal(gpu.read(chunks[c])[: len(w)], want)
    assert gpu.read(chunks[2])[2] == words[2][2] ^ 0x80000000
    # a larger list grows the pair buffers; the same lists again undo everything
    big = {1: np.stack([np.arange(700), np.full(700, 0xFFFF0000)], 1).astype(np.uint32)}
    stage.apply(big)
    np.testing.assert_array_equal(gpu.read(chunks[1])[:700], words[1] ^ np.uint32(0xFFFF0000))
    stage.apply(xors)
    stage.apply(big)
    for c, w in enumerate(words):
        np.testing.assert_array_equal(gpu.read(chunks[c])[: len(w)], w)
    stage.apply({})  # nothing to do


def test_twin_composes_repeated_words():
    np.testing.assert_array_equal(xor_words([0, 0, 7], [[2, 1], [2, 2], [0, 4]]), [4, 0, 4])
