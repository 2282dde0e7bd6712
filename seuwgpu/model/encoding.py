"""Stored number formats (fp32, fp16, bf16) and their raw-bit layouts.

A deployed model stores every parameter in one precision. The GPU buffer holds the raw bits as
u32 words; for 16-bit formats two values share a word: element 2j in the low half, 2j+1 in the
high half (the order `unpack2x16float` uses). Bit 0 is the least significant bit of the stored
value. fp32 -> bf16 rounds to nearest even; NaN stays NaN (quiet).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.errors import InputError
from seuwgpu.model import checks

PRECISIONS = ("fp32", "fp16", "bf16")

BITS = {"fp32": 32, "fp16": 16, "bf16": 16}
# (mantissa bits, exponent bits): sign is the top bit.
LAYOUT = {"fp32": (23, 8), "fp16": (10, 5), "bf16": (7, 8)}


def check_precision(precision: str, what: str | None = None) -> str:
    return checks.one_of(precision, "precision", PRECISIONS, what)


def bits_per_value(precision: str) -> int:
    return BITS[check_precision(precision)]


def check_bit(precision: str, bit: int, what: str | None = None) -> int:
    """A bit of a stored value at `precision` (0 = the least significant): the API's bit=, the
    command line's --bit and a spec's bits (`what` names the spec's list)."""
    checks.integer(bit, what or "bit")
    nb = bits_per_value(precision)
    if not 0 <= bit < nb:
        where = f"{what}: " if what else ""
        raise InputError(f"{where}bit {bit} is out of range for {precision} (valid bits are 0..{nb - 1})")
    return int(bit)


def bit_class(precision: str, bit: int) -> str:
    """'sign', 'exponent' or 'mantissa' for a bit of a stored value (IEEE-754 layout)."""
    check_bit(precision, bit)
    man, exp = LAYOUT[precision]
    if bit < man:
        return "mantissa"
    if bit < man + exp:
        return "exponent"
    return "sign"


def bits_of_class(precision: str, cls: str) -> list[int]:
    return [b for b in range(bits_per_value(precision)) if bit_class(precision, b) == cls]


def _f32_to_bf16_bits(x: np.ndarray) -> np.ndarray:
    u = np.ascontiguousarray(x, dtype=np.float32).view(np.uint32).astype(np.uint64)
    nan = np.isnan(np.asarray(x, dtype=np.float32))
    rounded = (u + 0x7FFF + ((u >> 16) & 1)) >> 16  # round to nearest, ties to even
    out = (rounded & 0xFFFF).astype(np.uint16)
    # NaN: keep sign, force a quiet NaN payload (rounding could carry a NaN into Inf).
    out[nan] = ((u[nan] >> 16) & 0x8000).astype(np.uint16) | np.uint16(0x7FC0)
    return out


def to_bits(values, precision: str) -> np.ndarray:
    """Raw stored bits of float values: uint32 for fp32, uint16 for fp16/bf16."""
    v = np.asarray(values, dtype=np.float32)
    check_precision(precision)
    if precision == "fp32":
        return np.ascontiguousarray(v).view(np.uint32).copy()
    if precision == "fp16":
        with np.errstate(over="ignore"):
            return v.astype(np.float16).view(np.uint16)
    return _f32_to_bf16_bits(v)


def from_bits(bits, precision: str) -> np.ndarray:
    """Stored bits -> float32 values (exact: every fp16/bf16 value is representable in fp32)."""
    check_precision(precision)
    b = np.asarray(bits)
    if precision == "fp32":
        return np.array(b, dtype=np.uint32, order="C").view(np.float32)  # one copy, never the input
    if precision == "fp16":
        return np.array(b, dtype=np.uint16, order="C").view(np.float16).astype(np.float32)
    return (b.astype(np.uint32) << 16).view(np.float32).copy()


def quantize(values, precision: str) -> np.ndarray:
    """Round float32 values to the stored precision and back (what the deployed model holds)."""
    return from_bits(to_bits(values, precision), precision)


def flip_bits(bits, bit: int | list[int], precision: str):
    """Flip one or several bits of stored values; returns the new bits with the same dtype."""
    b = np.asarray(bits)
    mask = 0
    for k in np.atleast_1d(bit):
        mask |= 1 << check_bit(precision, int(k))
    return (b ^ b.dtype.type(mask)).astype(b.dtype)


def pack_words(bits: np.ndarray, precision: str) -> np.ndarray:
    """1-D stored bits -> u32 words. 16-bit values: element 2j low half, 2j+1 high half; odd
    lengths are padded with a zero half."""
    b = np.asarray(bits).reshape(-1)
    if bits_per_value(precision) == 32:
        return b.astype(np.uint32)
    if b.size % 2:
        b = np.concatenate([b, np.zeros(1, dtype=b.dtype)])
    pairs = b.astype(np.uint32).reshape(-1, 2)
    return pairs[:, 0] | (pairs[:, 1] << 16)


def unpack_words(words: np.ndarray, precision: str, count: int) -> np.ndarray:
    """Inverse of pack_words: u32 words -> the first `count` stored bit patterns."""
    w = np.asarray(words, dtype=np.uint32).reshape(-1)
    if bits_per_value(precision) == 32:
        return w[:count].copy()
    halves = np.stack([w & 0xFFFF, w >> 16], axis=1).reshape(-1)
    return halves[:count].astype(np.uint16)


def is_finite_bits(bits, precision: str) -> np.ndarray:
    """Finite test on raw bits (exponent not all ones), as the shaders do it."""
    man, exp = LAYOUT[check_precision(precision)]
    b = np.asarray(bits).astype(np.uint64)
    return ((b >> man) & ((1 << exp) - 1)) != (1 << exp) - 1
