"""Decode stage (render/decode.py): the shaders' decode of stored words against the numpy twin
(model/encoding.py from_bits), bit for bit, special values included."""

import numpy as np
import pytest

from seuwgpu.model import encoding
from seuwgpu.render.decode import gpu_decode


@pytest.mark.parametrize("precision", ["fp16", "bf16", "fp32"])
def test_gpu_decode_matches_numpy_bit_for_bit(precision):
    rng = np.random.default_rng(8)
    nb = encoding.bits_per_value(precision)
    raw = rng.integers(0, 2**nb, 4096, dtype=np.uint64).astype(np.uint32 if nb == 32 else np.uint16)
    special = {
        16: [0x0000, 0x8000, 0x0001, 0x03FF, 0x0400, 0x7BFF, 0x7C00, 0xFC00, 0x7E00, 0x7C01, 0x3C00],
        32: [0, 0x80000000, 1, 0x7F800000, 0xFF800000, 0x7FC00000, 0x7F800001, 0x3F800000],
    }[nb]
    raw[: len(special)] = special
    words = encoding.pack_words(raw, precision)
    got = gpu_decode(words, precision)[: raw.size]
    want = encoding.from_bits(raw, precision)
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
