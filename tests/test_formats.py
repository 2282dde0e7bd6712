"""Stored formats: hand-computed IEEE-754 bit patterns, bf16 rounding, bit classes, flips, packing."""

from __future__ import annotations

import numpy as np
import pytest

from seuwgpu.model import encoding

F32 = np.float32


def f32_from_bits(u: int) -> np.float32:
    return np.array([u], dtype=np.uint32).view(np.float32)[0]


def bits_list(values, precision):
    return [int(b) for b in encoding.to_bits(np.asarray(values, dtype=np.float32), precision)]


# ------------------------------------------------------------------------------- bit patterns


@pytest.mark.parametrize(
    "value,expect",
    [
        (1.0, 0x3F800000),
        (-2.0, 0xC0000000),
        (0.5, 0x3F000000),
        (3.0, 0x40400000),
        (0.0, 0x00000000),
        (-0.0, 0x80000000),
        (np.inf, 0x7F800000),
        (-np.inf, 0xFF800000),
        (2.0**-149, 0x00000001),  # smallest subnormal
        (2.0**-126, 0x00800000),  # smallest normal
        (float(np.finfo(np.float32).max), 0x7F7FFFFF),
        (65504.0, 0x477FE000),
    ],
)
def test_fp32_bits(value, expect):
    assert bits_list([value], "fp32") == [expect]
    assert encoding.to_bits(np.float32(value), "fp32").dtype == np.uint32
    back = encoding.from_bits(np.array([expect], np.uint32), "fp32")
    assert back.dtype == np.float32
    assert back.view(np.uint32)[0] == expect


@pytest.mark.parametrize(
    "value,expect",
    [
        (1.0, 0x3C00),
        (-2.0, 0xC000),
        (0.5, 0x3800),
        (3.0, 0x4200),
        (65504.0, 0x7BFF),  # fp16 max
        (2.0**-14, 0x0400),  # smallest normal
        (2.0**-24, 0x0001),  # smallest subnormal
        (1023 * 2.0**-24, 0x03FF),  # largest subnormal
        (-0.0, 0x8000),
        (np.inf, 0x7C00),
        (-np.inf, 0xFC00),
        (65520.0, 0x7C00),  # tie between 65504 and 65536 -> even -> overflows to Inf
        (65519.0, 0x7BFF),  # below the tie -> max
        (1e6, 0x7C00),
        (2.0**-25, 0x0000),  # tie between 0 and 2^-24 -> even (0)
        (3 * 2.0**-25, 0x0002),  # tie between 1 and 2 ulps -> even (2)
        (1 + 2.0**-11, 0x3C00),  # tie above 1.0 -> even mantissa (1.0)
        (1 + 3 * 2.0**-11, 0x3C02),  # tie -> even (0x3C02)
    ],
)
def test_fp16_bits(value, expect):
    out = encoding.to_bits(np.array([value], np.float32), "fp16")
    assert out.dtype == np.uint16
    assert int(out[0]) == expect, hex(int(out[0]))


def test_fp16_decode_hand_values():
    got = encoding.from_bits(
        np.array([0x3C00, 0xC000, 0x3800, 0x7BFF, 0x0001, 0x0400, 0x7C00, 0x8000], np.uint16), "fp16"
    )
    np.testing.assert_array_equal(got, np.array([1, -2, 0.5, 65504, 2.0**-24, 2.0**-14, np.inf, -0.0], np.float32))
    assert np.signbit(got[-1])
    nan = encoding.from_bits(np.array([0x7C01, 0x7E00, 0xFFFF], np.uint16), "fp16")
    assert np.isnan(nan).all()


@pytest.mark.parametrize(
    "value,expect",
    [
        (1.0, 0x3F80),
        (-2.0, 0xC000),
        (0.5, 0x3F00),
        (3.0, 0x4040),
        (-0.0, 0x8000),
        (np.inf, 0x7F80),
        (-np.inf, 0xFF80),
        (65504.0, 0x4780),  # 65504 rounds to 65536 in bf16
        (2.0**-133, 0x0001),  # smallest bf16 subnormal
    ],
)
def test_bf16_bits(value, expect):
    out = encoding.to_bits(np.array([value], np.float32), "bf16")
    assert out.dtype == np.uint16
    assert int(out[0]) == expect, hex(int(out[0]))


def test_bf16_decode_is_shift():
    b = np.array([0x3F80, 0xC000, 0x7F7F, 0x0001, 0x7F80, 0x8000], np.uint16)
    got = encoding.from_bits(b, "bf16")
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got.view(np.uint32), b.astype(np.uint32) << 16)
    assert got[0] == 1.0 and got[1] == -2.0 and got[4] == np.inf
    assert got[2] == F32(3.3895313892515355e38)  # bf16 max


@pytest.mark.parametrize(
    "u32,expect",
    [
        (0x3F808000, 0x3F80),  # exact tie, even (0x3F80) below -> round down
        (0x3F818000, 0x3F82),  # exact tie, odd below -> round up to even
        (0x3F808001, 0x3F81),  # just above the tie -> up
        (0x3F807FFF, 0x3F80),  # just below the tie -> down
        (0xBF808000, 0xBF80),  # negative tie, even
        (0xBF818000, 0xBF82),  # negative tie, odd
        (0x3FFF8000, 0x4000),  # tie carrying into the exponent
        (0x7F7F8000, 0x7F80),  # tie at the top: rounds to even = Inf
        (0x7F7FFFFF, 0x7F80),  # fp32 max -> Inf
        (0x7F7F7FFF, 0x7F7F),  # below the tie stays bf16 max
        (0x00008000, 0x0000),  # subnormal tie -> even (0)
        (0x00018000, 0x0002),  # subnormal tie, odd below -> 2
    ],
)
def test_bf16_round_to_nearest_even(u32, expect):
    got = encoding.to_bits(np.array([u32], np.uint32).view(np.float32), "bf16")
    assert int(got[0]) == expect, hex(int(got[0]))


@pytest.mark.parametrize("u32", [0x7F800001, 0x7FFFFFFF, 0x7FC00000, 0xFF800001, 0xFFC12345, 0x7F80FFFF])
def test_nan_stays_nan(u32):
    x = np.array([u32], np.uint32).view(np.float32)
    for p in encoding.PRECISIONS:
        b = encoding.to_bits(x, p)
        assert not encoding.is_finite_bits(b, p)[0]
        assert np.isnan(encoding.from_bits(b, p)[0]), (p, hex(int(b[0])))
    bf = int(encoding.to_bits(x, "bf16")[0])
    assert bf & 0x8000 == (u32 >> 16) & 0x8000  # sign kept
    assert bf & 0x7F80 == 0x7F80 and bf & 0x7F != 0
    assert int(encoding.to_bits(x, "fp32")[0]) == u32  # fp32 keeps the payload


def test_nan_bits_decode_to_nan():
    assert np.isnan(encoding.from_bits(np.array([0x7F800001], np.uint32), "fp32")[0])
    assert np.isnan(encoding.from_bits(np.array([0x7F81, 0xFFC0], np.uint16), "bf16")).all()


def test_quantize_round_trip_exact_values():
    v = np.array([1.0, -2.0, 0.5, 0.0, -0.0, 1.5, 2.0**-10], np.float32)
    for p in encoding.PRECISIONS:
        q = encoding.quantize(v, p)
        assert q.dtype == np.float32
        np.testing.assert_array_equal(q.view(np.uint32), v.view(np.uint32))
    # not representable: 0.1 -> nearest
    assert encoding.quantize([0.1], "fp16")[0] == F32(np.float16(0.1))
    assert encoding.quantize([0.1], "bf16")[0] == f32_from_bits(0x3DCD0000)  # 0x3DCCCCCD -> up


def test_is_finite_bits():
    np.testing.assert_array_equal(
        encoding.is_finite_bits(
            np.array([0x3F800000, 0x7F800000, 0x7F7FFFFF, 0xFFC00000, 0x00000001], np.uint32), "fp32"
        ),
        [True, False, True, False, True],
    )
    np.testing.assert_array_equal(
        encoding.is_finite_bits(np.array([0x7BFF, 0x7C00, 0xFE00, 0x0001], np.uint16), "fp16"),
        [True, False, False, True],
    )
    np.testing.assert_array_equal(
        encoding.is_finite_bits(np.array([0x7F7F, 0x7F80, 0xFFC0, 0x8000], np.uint16), "bf16"),
        [True, False, False, True],
    )


# ------------------------------------------------------------------------------- bit classes

IEEE = {  # precision: (width, sign bit, exponent bit range)
    "fp32": (32, 31, range(23, 31)),
    "fp16": (16, 15, range(10, 15)),
    "bf16": (16, 15, range(7, 15)),
}


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_bit_class_every_bit(precision):
    width, sign, exp = IEEE[precision]
    assert encoding.bits_per_value(precision) == width
    for b in range(width):
        expect = "sign" if b == sign else "exponent" if b in exp else "mantissa"
        assert encoding.bit_class(precision, b) == expect, (precision, b)
    assert encoding.bits_of_class(precision, "sign") == [sign]
    assert encoding.bits_of_class(precision, "exponent") == list(exp)
    assert encoding.bits_of_class(precision, "mantissa") == list(range(exp.start))


def test_bit_class_matches_value_semantics():
    """Flipping the sign bit negates; the top exponent bit of 1.0 makes Inf in all encoding."""
    for p in encoding.PRECISIONS:
        one = encoding.to_bits(np.array([1.0], np.float32), p)
        (sign,) = encoding.bits_of_class(p, "sign")
        assert encoding.from_bits(encoding.flip_bits(one, sign, p), p)[0] == -1.0
        top_exp = encoding.bits_of_class(p, "exponent")[-1]
        assert encoding.from_bits(encoding.flip_bits(one, top_exp, p), p)[0] == np.inf
        # lowest mantissa bit: one ulp above 1.0
        ulp = {"fp32": 2.0**-23, "fp16": 2.0**-10, "bf16": 2.0**-7}[p]
        assert encoding.from_bits(encoding.flip_bits(one, 0, p), p)[0] == F32(1 + ulp)


def test_hand_flips():
    assert int(encoding.flip_bits(np.uint32(0x3F800000), 30, "fp32")) == 0x7F800000
    assert int(encoding.flip_bits(np.uint16(0x3C00), 14, "fp16")) == 0x7C00
    assert int(encoding.flip_bits(np.uint16(0x3F80), 14, "bf16")) == 0x7F80
    assert int(encoding.flip_bits(np.uint32(0), [0, 31], "fp32")) == 0x80000001


# ----------------------------------------------------------------------------------- flips


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_flip_changes_exactly_one_bit_and_is_an_involution(precision):
    rng = np.random.default_rng(1)
    vals = rng.standard_normal(64).astype(np.float32)
    bits = encoding.to_bits(vals, precision)
    width = encoding.bits_per_value(precision)
    for b in range(width):
        flipped = encoding.flip_bits(bits, b, precision)
        assert flipped.dtype == bits.dtype and flipped.shape == bits.shape
        diff = flipped.astype(np.uint64) ^ bits.astype(np.uint64)
        assert (diff == (1 << b)).all(), (precision, b)
        np.testing.assert_array_equal(encoding.flip_bits(flipped, b, precision), bits)
    assert np.array_equal(encoding.to_bits(vals, precision), bits)  # input not modified in place


@pytest.mark.parametrize(
    "precision,bad", [("fp32", 32), ("fp32", -1), ("fp16", 16), ("bf16", 16), ("bf16", 100), ("fp16", -3)]
)
def test_out_of_range_bit_rejected(precision, bad):
    bits = encoding.to_bits(np.ones(2, np.float32), precision)
    width = encoding.bits_per_value(precision)
    for call in (
        lambda: encoding.flip_bits(bits, bad, precision),
        lambda: encoding.flip_bits(bits, [0, bad], precision),
        lambda: encoding.bit_class(precision, bad),
        lambda: encoding.check_bit(precision, bad),
    ):
        with pytest.raises(ValueError) as e:
            call()
        msg = str(e.value)
        assert str(bad) in msg and precision in msg and f"0..{width - 1}" in msg, msg


def test_unknown_precision_rejected():
    with pytest.raises(ValueError, match=r"fp8.*fp32, fp16, bf16"):
        encoding.to_bits([1.0], "fp8")
    with pytest.raises(ValueError, match="unknown precision"):
        encoding.bit_class("float", 0)


# --------------------------------------------------------------------------------- packing


def test_pack_16bit_pairs_low_half_first():
    b = np.array([0x1111, 0x2222, 0x3333, 0xABCD, 0xFFFF], np.uint16)
    for p in ("fp16", "bf16"):
        w = encoding.pack_words(b, p)
        assert w.dtype == np.uint32
        assert [int(x) for x in w] == [0x22221111, 0xABCD3333, 0x0000FFFF]
        back = encoding.unpack_words(w, p, 5)
        assert back.dtype == np.uint16
        np.testing.assert_array_equal(back, b)
        np.testing.assert_array_equal(encoding.unpack_words(w, p, 6), list(b) + [0])


def test_pack_matches_unpack2x16float_order():
    """WGSL unpack2x16float(w).x is the low half: element 2j must decode from there."""
    vals = np.array([1.0, -2.0, 0.5, 65504.0], np.float32)
    w = encoding.pack_words(encoding.to_bits(vals, "fp16"), "fp16")
    lo = (w & 0xFFFF).astype(np.uint16).view(np.float16).astype(np.float32)
    hi = (w >> 16).astype(np.uint16).view(np.float16).astype(np.float32)
    np.testing.assert_array_equal(lo, vals[0::2])
    np.testing.assert_array_equal(hi, vals[1::2])


def test_pack_fp32_is_identity():
    b = np.array([0x3F800000, 0xFFFFFFFF, 0], np.uint32)
    w = encoding.pack_words(b, "fp32")
    np.testing.assert_array_equal(w, b)
    np.testing.assert_array_equal(encoding.unpack_words(w, "fp32", 2), b[:2])


def test_pack_unpack_random_round_trip():
    rng = np.random.default_rng(2)
    for n in (1, 2, 7, 64, 1001):
        b = rng.integers(0, 1 << 16, n, dtype=np.uint16)
        w = encoding.pack_words(b, "bf16")
        assert w.size == (n + 1) // 2
        np.testing.assert_array_equal(encoding.unpack_words(w, "bf16", n), b)
