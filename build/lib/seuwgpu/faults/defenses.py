"""The defenses' view of a corrupted stored word: which defenses exist, which fields the support
guard covers, and what ECC (SEC-DED over sign+exponent) and triple modular redundancy read back."""

from __future__ import annotations

import numpy as np

from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS

# ---- defenses on stored bits -------------------------------------------------------------------
DEFENSES = ("none", "guard", "selective", "ecc", "dup")
GUARDED_FIELDS = {
    "guard": ("means", "log_scales", "quats", "opacity", "sh_dc"),
    "guard_all": FIELDS,
    "selective": ("log_scales", "opacity"),
}


def check_defense(name: str) -> str:
    if name not in DEFENSES:
        raise ValueError(f"unknown defense {name!r}; expected one of {', '.join(DEFENSES)}")
    return name


def _protected_bits(precision: str) -> list[int]:
    return encoding.bits_of_class(precision, "exponent") + encoding.bits_of_class(precision, "sign")


def _hamming_positions(m: int) -> tuple[list[int], int]:
    """Codeword positions (1-based, non powers of two) for m data bits, and r check bits."""
    r = 0
    while (1 << r) < m + r + 1:
        r += 1
    pos = [p for p in range(1, m + r + 1) if p & (p - 1)][:m]
    return pos, r


def ecc_check_bits(precision: str) -> int:
    """SEC-DED Hamming check bits per stored value protecting its sign and exponent bits."""
    _, r = _hamming_positions(len(_protected_bits(precision)))
    return r + 1


def ecc_overhead(precision: str) -> float:
    return ecc_check_bits(precision) / encoding.bits_per_value(precision)


def ecc_read(clean_bits: np.ndarray, stored_bits: np.ndarray, precision: str) -> np.ndarray:
    """What an SEC-DED Hamming code over the sign+exponent bits returns on read.

    The check bits were computed from the clean value when it was written; the stored value may
    since have been corrupted (the check bits are assumed intact: they are a small fraction of the
    memory, and modelling their upsets would only add corrected cases). A single error among the
    protected bits is corrected; two are detected but cannot be corrected (the value passes);
    mantissa errors are not covered and pass.
    """
    prot = _protected_bits(precision)
    pos, r = _hamming_positions(len(prot))
    clean = np.asarray(clean_bits).astype(np.uint64)
    cur = np.asarray(stored_bits).astype(np.uint64)

    def syndrome_and_parity(v):
        syn = np.zeros(v.shape, dtype=np.uint64)
        par = np.zeros(v.shape, dtype=np.uint64)
        for p, b in zip(pos, prot):
            bit = (v >> np.uint64(b)) & np.uint64(1)
            syn ^= bit * np.uint64(p)
            par ^= bit
        return syn, par

    s_clean, p_clean = syndrome_and_parity(clean)
    s_cur, p_cur = syndrome_and_parity(cur)
    syn = s_clean ^ s_cur
    single = (syn != 0) & ((p_clean ^ p_cur) == 1)
    out = cur.copy()
    for p, b in zip(pos, prot):
        hit = single & (syn == np.uint64(p))
        out[hit] ^= np.uint64(1) << np.uint64(b)
    return out.astype(np.asarray(stored_bits).dtype)


def majority(a, b, c):
    """Bitwise majority vote of three copies (triple modular redundancy)."""
    return (a & b) | (a & c) | (b & c)


def dup_read(clean_bits: np.ndarray, stored_bits: np.ndarray) -> np.ndarray:
    """Full duplication with majority voting: the upset hit one of three copies (copy 0)."""
    return majority(np.asarray(stored_bits), np.asarray(clean_bits), np.asarray(clean_bits))
