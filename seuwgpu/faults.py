"""Fault sites in the stored model, and the defenses' view of a corrupted word.

A site is (field, primitive, component, bits) in the stored precision: one bit is a single-event
upset, several bits of one value a multi-bit upset. Flips are XOR masks on stored words, so
applying the same mask again restores the value exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import formats
from .model import FIELD_OFFSET, FIELDS, canonical_field, field_components, Model


@dataclass(frozen=True)
class Site:
    field: str
    primitive: int
    component: int
    bits: tuple[int, ...]

    @property
    def bit(self) -> int:
        return self.bits[0] if len(self.bits) == 1 else -1

    def flat_component(self) -> int:
        return FIELD_OFFSET[self.field] + self.component


def make_site(model_or_n, field: str, primitive: int, component: int, bits, precision: str,
              degree: int | None = None) -> Site:
    """Validated site; raises ValueError naming what is out of range."""
    if isinstance(model_or_n, Model):
        n, degree = model_or_n.n, model_or_n.sh_degree
    else:
        n = int(model_or_n)
    field = canonical_field(field)
    bits = tuple(int(b) for b in np.atleast_1d(bits))
    if not bits:
        raise ValueError("a site needs at least one bit")
    for b in bits:
        formats.check_bit(precision, b)
    if len(set(bits)) != len(bits):
        raise ValueError(f"bits {bits} repeat a bit")
    if not 0 <= int(primitive) < n:
        raise ValueError(f"primitive {primitive} is out of range (model has {n} primitives, valid 0..{n - 1})")
    nc = field_components(field, degree)
    if not 0 <= int(component) < nc:
        raise ValueError(f"component {component} is out of range for field {field} (valid 0..{nc - 1})")
    return Site(field, int(primitive), int(component), bits)


def site_bit_class(site: Site, precision: str) -> str:
    classes = {formats.bit_class(precision, b) for b in site.bits}
    return classes.pop() if len(classes) == 1 else "mixed"


def mask_of(bits) -> int:
    m = 0
    for b in bits:
        m |= 1 << int(b)
    return m


def uniform_upsets(model: Model, precision: str, k: int, rng: np.random.Generator) -> list[Site]:
    """k distinct single-bit upsets drawn uniformly over the whole stored bit budget (all six
    fields), without replacement."""
    return draw_uniform_sites(model.n, model.sh_degree, precision, k, rng)


def draw_uniform_sites(n: int, degree: int, precision: str, k: int, rng: np.random.Generator) -> list[Site]:
    """k distinct stored bits of an n-primitive model, uniform over its bit budget (the dose
    campaign's draw: a function of the generator's state alone)."""
    nb = formats.bits_per_value(precision)
    ncomp = 14 + 3 * ((degree + 1) ** 2 - 1)
    total = n * ncomp * nb
    if k > total:
        raise ValueError(f"k={k} exceeds the model's {total} stored bits")
    flat = np.unique(rng.integers(0, total, size=k))
    while flat.size < k:
        flat = np.unique(np.concatenate([flat, rng.integers(0, total, size=k - flat.size)]))
    prim, rest = np.divmod(flat, ncomp * nb)
    comp, bit = np.divmod(rest, nb)
    return [site_from_flat(int(p), int(c), (int(b),), degree) for p, c, b in zip(prim, comp, bit)]


def site_from_flat(prim: int, flat_comp: int, bits: tuple[int, ...], degree: int) -> Site:
    for f in reversed(FIELDS):
        if flat_comp >= FIELD_OFFSET[f]:
            return Site(f, prim, flat_comp - FIELD_OFFSET[f], bits)
    raise AssertionError


# ---- defenses on stored bits -------------------------------------------------------------------
DEFENSES = ("none", "guard", "selective", "ecc", "dup")
GUARDED_FIELDS = {"guard": ("means", "log_scales", "quats", "opacity", "sh_dc"),
                  "guard_all": FIELDS,
                  "selective": ("log_scales", "opacity")}


def check_defense(name: str) -> str:
    if name not in DEFENSES:
        raise ValueError(f"unknown defense {name!r}; expected one of {', '.join(DEFENSES)}")
    return name


def _protected_bits(precision: str) -> list[int]:
    return formats.bits_of_class(precision, "exponent") + formats.bits_of_class(precision, "sign")


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
    return ecc_check_bits(precision) / formats.bits_per_value(precision)


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
