"""The side data of the check defenses as the device holds it (`pack_side`, `unpack_side`: what
shaders/check.wgsl reads) and what every defense holds beside the model: its encoding's bits
(`memory_overhead`) and the bytes this package uploads (`device_bytes`, `device_overhead`).
Time costs are measured in faults/costs.py."""

from __future__ import annotations

import numpy as np

from seuwgpu.faults.defenses import get
from seuwgpu.gpu.device import shader_source
from seuwgpu.gpu.kernel import wgsl_constants
from seuwgpu.model import encoding
from seuwgpu.model.fields import n_components


def pack_side(codes: np.ndarray, bits: int) -> np.ndarray:
    """[ceil(M * bits / 32)] u32 words holding M codes of `bits` bits (1, 2, 4, 8, 16 or 32), code
    i in word i // (32 / bits) at bit (i % (32 / bits)) * bits: what the GPU check reads."""
    if bits not in (1, 2, 4, 8, 16, 32):
        raise ValueError(f"side data packs 1, 2, 4, 8, 16 or 32 bits a code (got {bits})")
    codes = np.asarray(codes, dtype=np.uint64)
    if codes.size and int(codes.max()) >> bits:
        raise ValueError(f"a side code does not fit in {bits} bits")
    per = 32 // bits
    padded = np.zeros(-(-codes.size // per) * per, np.uint64)
    padded[: codes.size] = codes
    shifts = (np.arange(per, dtype=np.uint64) * np.uint64(bits))[None, :]
    return (padded.reshape(-1, per) << shifts).sum(axis=1).astype(np.uint32)


def unpack_side(words: np.ndarray, bits: int, m: int) -> np.ndarray:
    """[m] u32 codes of pack_side's words (the check shader's `side_code`, on the host)."""
    per = 32 // bits
    i = np.arange(m)
    w = np.asarray(words, dtype=np.uint64)[i // per]
    mask = np.uint64((1 << bits) - 1)
    return ((w >> ((i % per).astype(np.uint64) * np.uint64(bits))) & mask).astype(np.uint32)


# a check's output words as shaders/codes.wgsl lays them out (OUT_DETECTED, ..., OUT_FLAGS: the
# first flag word), read from it once; the header is the words before the flags
OUT_WORDS = {k: v for k, v in wgsl_constants(shader_source("codes")).items() if k.startswith("OUT_")}
CHECK_HEADER_BYTES = 4 * OUT_WORDS["OUT_FLAGS"]
BOUND_BYTES = 16  # faults/guard.py Box.rows(): lo, hi and their stored bits per component
GUARD_COUNT_BYTES = 32  # the renderer's clamp counts (8 u32)


def device_bytes(defense: str, precision: str, degree: int, n: int, chunks: int = 1) -> int:
    """Bytes the defense holds on the device beside the model, as this package uploads them.

    A support guard: the box the pipeline reads (one Bound record per stored component) and the
    clamp counts. A GPU check: its side data packed `side_bits` a primitive, its output (a count and
    one flag bit per primitive), its table (scalebound's class bounds) and one uniform slot per
    model chunk; scalebound adds the guard's. A check inside the frame: its packed codes (one a
    stored word pair for a per-word code at fp16/bf16: parity2f's 1 bit a primitive) and its
    output (the count, and the flag bits if it keeps them). The read-time codes without a GPU decoder (ECC,
    ecc_crit, TMR, cellbox): their encoding's bits, packed, rounded up to whole u32 words."""
    from seuwgpu.gpu.constants import UNIFORM_STRIDE
    from seuwgpu.model.budget import BUFFER_ALIGN

    def buffer(nbytes: int) -> int:  # gpu/device.py GPU.buffer's rounding
        return max(BUFFER_ALIGN, -(-int(nbytes) // BUFFER_ALIGN) * BUFFER_ALIGN)

    d = get(defense)
    total = 0
    if d.guard_fields:
        total += buffer(BOUND_BYTES * n_components(degree)) + buffer(GUARD_COUNT_BYTES)
    if d.frame_check:  # the check inside the frame: packed codes (a word pair's with a per-word code) and its output
        total += buffer(4 * -(-d.n_codes(n, precision) * d.side_bits // 32))
        total += buffer(CHECK_HEADER_BYTES + (4 * -(-n // 32) if d.flags else 0))  # flag bits if it keeps them
    elif d.checked:
        total += buffer(4 * -(-n * d.side_bits // 32))  # packed side data
        total += buffer(CHECK_HEADER_BYTES + 4 * -(-n // 32))  # count + flag bits
        total += buffer(4 * d.table_words)  # the check's table
        total += buffer(UNIFORM_STRIDE * chunks)
    elif not d.guard_fields:
        total += 4 * -(-(d.bits_per_primitive(precision, degree) * n + d.bits_per_model(precision, degree)) // 32)
    return int(total)


def device_overhead(defense: str, precision: str, degree: int, n: int, chunks: int = 1) -> float:
    """device_bytes over the model's stored bytes."""
    model_bytes = n * n_components(degree) * encoding.bits_per_value(precision) / 8
    return device_bytes(defense, precision, degree, n, chunks) / model_bytes


def memory_overhead(defense: str, precision: str, degree: int, n: int) -> float:
    """Extra stored bits per stored bit of the model (box bounds are fp32)."""
    d = get(defense)
    per_prim = n_components(degree) * encoding.bits_per_value(precision)
    return (d.bits_per_primitive(precision, degree) * n + d.bits_per_model(precision, degree)) / (per_prim * n)
