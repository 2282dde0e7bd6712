"""The code mathematics of the defenses (faults/defenses.py registers the defenses built on it):
parity over the covered bits of each value (interleaved ways), SEC-DED Hamming over sign and
exponent, triple-modular majority, the per-primitive checksum (h = fmix32(h ^ value), each step
a bijection, so any change confined to one stored value is detected with certainty), scalebound's
scale classes and cellbox's per-cell boxes. Every function is a numpy twin over stored bit
patterns [M, ncomp]; shaders/check.wgsl computes parity, checksum and scale classes alike.
"""

from __future__ import annotations

import functools

import numpy as np

from seuwgpu.model import encoding

GUARD_FIELDS = ("means", "log_scales", "quats", "opacity", "sh_dc")  # every field but the inert sh_rest
CRITICAL_FIELDS = ("log_scales", "opacity")
PARITY_MANTISSA = 4  # top mantissa bits covered by the parity defenses, besides sign+exponent
SCALE_CLASS_BITS = 4
SCALE_CLASSES = 1 << SCALE_CLASS_BITS


def covered_components(fields, degree: int) -> np.ndarray:
    """Flat component indices of `fields` at SH degree `degree`, in layout order."""
    from seuwgpu.model.fields import FIELD_OFFSET, field_components

    return np.array([FIELD_OFFSET[f] + c for f in fields for c in range(field_components(f, degree))], np.int64)


def protected_bits(precision: str) -> list[int]:
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
    _, r = _hamming_positions(len(protected_bits(precision)))
    return r + 1


def ecc_read(clean_bits: np.ndarray, stored_bits: np.ndarray, precision: str) -> np.ndarray:
    """What an SEC-DED Hamming code over the sign+exponent bits returns on read.

    The check bits were computed from the clean value when it was written; the stored value may
    since have been corrupted (the check bits are assumed intact: they are a small fraction of the
    memory, and modelling their upsets would only add corrected cases). A single error among the
    protected bits is corrected; two are detected but cannot be corrected (the value passes);
    mantissa errors are not covered and pass. Three or more are what the decoder makes of them:
    an odd count looks like a single error and is "corrected" at the syndrome's position (a
    fourth wrong bit, or none changed where that is a check bit's).
    """
    return ecc_decode(clean_bits, stored_bits, precision)[0]


def ecc_decode(clean_bits: np.ndarray, stored_bits: np.ndarray, precision: str) -> tuple[np.ndarray, np.ndarray]:
    """SEC-DED decoding (ecc_read) and, per value, whether the decoder flags an uncorrectable
    error: an even number of errors with a non-zero syndrome, or an odd number whose syndrome
    names no position of the codeword."""
    prot = protected_bits(precision)
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
    n = len(prot) + r  # codeword positions 1..n: data at `pos`, check bits at the powers of two
    uncorrectable = (syn != 0) & (((p_clean ^ p_cur) == 0) | (syn > np.uint64(n)))
    return out.astype(np.asarray(stored_bits).dtype), uncorrectable


def majority(a, b, c):
    """Bitwise majority vote of three copies (triple modular redundancy)."""
    return (a & b) | (a & c) | (b & c)


def dup_read(clean_bits: np.ndarray, stored_bits: np.ndarray) -> np.ndarray:
    """Full duplication with majority voting: the upset hit one of three copies (copy 0)."""
    return majority(np.asarray(stored_bits), np.asarray(clean_bits), np.asarray(clean_bits))


def cull_bits(precision: str) -> int:
    """Stored pattern written into a culled primitive's means: a quiet NaN (the renderer culls a
    primitive whose camera-space depth is not finite, docs/renderer.md rule 2)."""
    return {"fp32": 0x7FC00000, "fp16": 0x7E00, "bf16": 0x7FC0}[encoding.check_precision(precision)]


def cull(rows: np.ndarray, hit: np.ndarray, precision: str) -> np.ndarray:
    """`rows` with the means of the `hit` primitives set to cull_bits (the renderer draws nothing)."""
    out = rows.copy()
    out[np.ix_(hit, np.arange(3))] = cull_bits(precision)  # means are components 0..2
    return out


def parity_cover_mask(precision: str) -> int:
    """Bits of each value the parity defenses cover: sign, exponent and the top PARITY_MANTISSA
    mantissa bits."""
    man, _ = encoding.LAYOUT[encoding.check_precision(precision)]
    return ((1 << encoding.bits_per_value(precision)) - 1) & ~((1 << (man - PARITY_MANTISSA)) - 1)


def parity_bits(
    rows: np.ndarray, precision: str, degree: int, ways: int, fields=GUARD_FIELDS, diagonal: int = 0
) -> np.ndarray:
    """[M, ways] parity of the covered bits of each primitive's `fields` values, bit b of flat
    component c in way (b + diagonal * c) % ways, counted bit by bit. diagonal 0 interleaves by bit
    position only: a burst of <= ways adjacent bits of one value flips at most one bit of each way.
    diagonal 1 also puts the same bit of neighbouring values in different ways."""
    cols = covered_components(fields, degree)
    v = np.asarray(rows)[:, cols].astype(np.uint64) & np.uint64(parity_cover_mask(precision))
    shift = (cols * diagonal) % ways  # the values whose bit b counts in way (b + shift) % ways
    out = np.zeros((v.shape[0], ways), dtype=np.uint8)
    for k in np.unique(shift):
        vk = v[:, shift == k]
        for b in range(encoding.bits_per_value(precision)):
            ones = ((vk >> np.uint64(b)) & np.uint64(1)).astype(np.uint8).sum(axis=1).astype(np.uint8)
            out[:, (b + int(k)) % ways] ^= ones & 1
    return out


def way_mask(way: int, ways: int) -> int:
    """The bit positions b of a u32 with b % ways == way (ways 1, 2, 4, 8 or 16; shaders/codes.wgsl)."""
    return (0xFFFFFFFF // ((1 << ways) - 1)) << way & 0xFFFFFFFF


def rotl32(x: np.ndarray, k: int) -> np.ndarray:
    """u32 words rotated left by k (0..31) bits."""
    x = np.asarray(x, np.uint32)
    return (x << np.uint32(k)) | (x >> np.uint32((32 - k) % 32)) if k else x


class ParityCode:
    """`ways` parity bits a primitive over the covered bits (parity_cover_mask) of the values of
    `fields` (they lead the layout), bit b of flat component c in way (b + diagonal * c) % ways
    (parity_bits). The check defenses (defenses.Parity) and the checks inside the frame
    (defenses.FrameParity) hold one; shaders/codes.wgsl computes it as `code` does.

    `per_word`: at 16-bit precisions (two primitives a stored word: primitives 2i and 2i + 1 share
    every word, fields.StoredLayout) one code covers a stored word pair, both halves folded whole
    (cover | cover << 16), so the side data holds `ways` bits a pair: ways / 2 a primitive. Parity is
    linear and a word's high half lands in the low half's ways (ways divide 16), so the pair's code
    is the XOR of its two primitive codes. At fp32 a word is a primitive: the code is per primitive."""

    def __init__(self, ways: int, fields, diagonal: int = 0, per_word: bool = False):
        if ways not in (1, 2, 4, 8, 16):
            raise ValueError(f"a parity code has 1, 2, 4, 8 or 16 ways (got {ways})")
        if per_word and ways < 2:  # ways / 2 bits a primitive
            raise ValueError("a per-word parity code has at least 2 ways")
        self.ways, self.fields, self.diagonal = int(ways), tuple(fields), int(diagonal)
        self.per_word = bool(per_word)

    def pairs(self, precision: str) -> bool:
        """One code a stored word pair of primitives (per_word at a 16-bit precision)."""
        return self.per_word and encoding.bits_per_value(precision) == 16

    def span(self, precision: str) -> int:
        """Primitives a code covers: 2 for a per-word code at 16 bits, else 1."""
        return 2 if self.pairs(precision) else 1

    def n_codes(self, n: int, precision: str) -> int:
        """Codes of n primitives (the side data's length)."""
        return -(-int(n) // self.span(precision))

    def bits_per_primitive(self, precision: str) -> int:
        return self.ways // self.span(precision)

    def cover(self, precision: str) -> int:
        """The bits of a folded stored pattern the code covers (both halves of a word per word)."""
        m = parity_cover_mask(precision)
        return m | m << 16 if self.pairs(precision) else m

    def components(self, degree: int) -> int:
        """The code covers flat components 0 .. this - 1 (its fields lead the layout)."""
        cols = covered_components(self.fields, degree)
        assert np.array_equal(cols, np.arange(cols.size))
        return int(cols.size)

    def side_data(self, clean, precision: str, degree: int) -> np.ndarray:
        """[n_codes] u32: the code of each clean primitive (of each word pair with `pairs`), as
        `code` computes it (the bit-by-bit count, parity_bits, is its test's oracle)."""
        return self.code(clean, precision, degree)

    def primitive_code(self, rows, precision: str, degree: int) -> np.ndarray:
        """[M] u32: each primitive's code, as the shaders compute it, parity being linear: value c's
        covered bits rotated left by (diagonal * c) % ways (so its bit b lands in way (b + diagonal
        * c) % ways), XORed over the values, then one parity per way (side_data's code at a
        fraction of its cost: the coverage sweep checks millions of rows)."""
        v = np.asarray(rows)[:, : self.components(degree)].astype(np.uint32) & np.uint32(parity_cover_mask(precision))
        shift = (np.arange(v.shape[1]) * self.diagonal) % self.ways
        x = np.zeros(v.shape[0], np.uint32)
        for k in np.unique(shift):
            x ^= rotl32(np.bitwise_xor.reduce(v[:, shift == k], axis=1), int(k))
        out = np.zeros(v.shape[0], np.uint32)
        for w in range(self.ways):
            out |= (np.bitwise_count(x & np.uint32(way_mask(w, self.ways))) & 1).astype(np.uint32) << np.uint32(w)
        return out

    def code(self, rows, precision: str, degree: int) -> np.ndarray:
        """[n_codes] u32: the stored code of the model `rows` (every primitive, in order): each
        primitive's, or with `pairs` each word pair's, the XOR of its primitives' (a missing last
        partner is the layout's zero padding)."""
        c = self.primitive_code(rows, precision, degree)
        if not self.pairs(precision):
            return c
        if c.size % 2:
            c = np.append(c, np.uint32(0))
        return c[0::2] ^ c[1::2]

    def detect(self, side, rows, precision: str, degree: int) -> np.ndarray:
        """[M] bool: the stored `rows` (every primitive, in order) fail their code `side`; with
        `pairs` both primitives of a failing pair."""
        fails = self.code(rows, precision, degree) != np.asarray(side, dtype=np.uint32)
        return np.repeat(fails, self.span(precision))[: np.asarray(rows).shape[0]]

    def detect_changed(self, clean, rows, prims, precision: str, degree: int) -> np.ndarray:
        """[M] bool: `detect` for primitives `prims` (indices in the model, each once) whose rows
        went from `clean` to `rows`, every other primitive clean: with `pairs` a pair fails when
        its members' code changes (linear: XORed over those in `prims`) do not cancel, and both of
        a failing pair's members among `prims` are True (a partner not among them is dropped too:
        `partners` adds it)."""
        delta = self.primitive_code(clean, precision, degree) ^ self.primitive_code(rows, precision, degree)
        if not self.pairs(precision):
            return delta != 0
        pair = np.asarray(prims, np.int64) >> 1
        u, inv = np.unique(pair, return_inverse=True)
        acc = np.zeros(u.size, np.uint32)
        np.bitwise_xor.at(acc, inv, delta)
        return acc[inv] != 0

    def partners(self, prims, n: int, precision: str) -> np.ndarray:
        """`prims` (sorted, unique) and, with `pairs`, their word partners (< n): what a frame of
        the per-word code drops with them."""
        prims = np.asarray(prims, np.int64)
        if not self.pairs(precision):
            return prims
        both = np.concatenate([prims, prims ^ 1])
        return np.unique(both[both < int(n)])


CHECKSUM_SEED = 0x811C9DC5


def fmix32(h: np.ndarray) -> np.ndarray:
    """MurmurHash3's 32-bit finaliser (a bijection that avalanches), on uint64 arrays of u32 values."""
    m = np.uint64(0xFFFFFFFF)
    h = h ^ (h >> np.uint64(16))
    h = (h * np.uint64(0x85EBCA6B)) & m
    h = h ^ (h >> np.uint64(13))
    h = (h * np.uint64(0xC2B2AE35)) & m
    return h ^ (h >> np.uint64(16))


def checksum(rows: np.ndarray) -> np.ndarray:
    """[M] 32-bit checksum of each primitive's stored patterns: h = fmix32(h ^ value) per value.
    (FNV-1a's multiply-only step was dropped: it moves a difference only upwards, so two sign-bit
    flips in one primitive cancel; a fault storm found such a pair.)"""
    h = np.full(np.asarray(rows).shape[0], CHECKSUM_SEED, dtype=np.uint64)
    for c in range(rows.shape[1]):
        h = fmix32(h ^ rows[:, c].astype(np.uint64))
    return h.astype(np.uint32)


@functools.cache
def scale_class_table(lo: float, hi: float, precision: str) -> np.ndarray:
    """The 2**SCALE_CLASS_BITS log-scale upper bounds a class stands for: the model's log-scale
    range [lo, hi] cut into equal classes, each top rounded up to a stored value; the last is hi.
    Cached per (range, precision), since every read of a scalebound primitive needs it; read-only."""
    k = 1 << SCALE_CLASS_BITS
    edges = (lo + (np.arange(1, k + 1) / k) * max(hi - lo, 0.0)).astype(np.float32)
    q = encoding.quantize(edges, precision)
    for _ in range(8):  # round up in the stored precision, one representable step at a time
        below = q < edges
        if not below.any():
            break
        b = encoding.to_bits(q[below], precision).astype(np.int64)
        nxt = np.where(q[below] == 0, 1, np.where(np.signbit(q[below]), b - 1, b + 1))
        q[below] = encoding.from_bits(nxt.astype(np.uint32), precision)
    q[-1] = hi
    table = np.maximum.accumulate(np.minimum(q, np.float32(hi)))
    table.flags.writeable = False
    return table


def scale_classes(clean: np.ndarray, table: np.ndarray, precision: str) -> np.ndarray:
    """[M] class of each primitive: the lowest whose bound holds its largest finite log-scale."""
    ls = encoding.from_bits(np.asarray(clean)[:, 3:6], precision)
    top = np.where(np.isfinite(ls), ls, -np.inf).max(axis=1)
    return np.minimum(np.searchsorted(table, top, side="left"), table.size - 1)


def scale_class_bounds(clean: np.ndarray, lo: float, hi: float, precision: str) -> np.ndarray:
    """[M] upper bound of each primitive's log-scales (scalebound's 4-bit class, looked up)."""
    table = scale_class_table(lo, hi, precision)
    return table[scale_classes(clean, table, precision)]


def ecc_crit_read(clean: np.ndarray, corrupt: np.ndarray, precision: str, degree: int) -> np.ndarray:
    cols = covered_components(CRITICAL_FIELDS, degree)
    out = corrupt.copy()
    out[:, cols], flagged = ecc_decode(clean[:, cols], corrupt[:, cols], precision)
    # SEC-DED flags what it cannot correct (two errors in the protected bits): cull. What it does
    # not flag (three errors read as one and "corrected", four with a zero syndrome) passes.
    return cull(out, flagged.any(axis=1), precision)


CELL_GRID = 8


class CellBoxes:
    """cellbox's stored state: the grid, each primitive's cell, and per-cell boxes [cells, 14]."""

    def __init__(self, rows: np.ndarray, precision: str, degree: int):
        rows = np.asarray(rows)
        vals = encoding.from_bits(rows, precision)
        means = vals[:, :3].astype(np.float64)
        fin = np.isfinite(means).all(axis=1)
        self.lo, self.hi = np.percentile(means[fin], 1, axis=0), np.percentile(means[fin], 99, axis=0)
        self.cell = self.cell_of(means)
        self.cols = covered_components(GUARD_FIELDS, degree)
        v = vals[:, self.cols].astype(np.float32)
        ncell = CELL_GRID**3
        self.box_lo = np.zeros((ncell, self.cols.size), np.float32)
        self.box_hi = np.zeros((ncell, self.cols.size), np.float32)
        for c in np.unique(self.cell):
            x = v[self.cell == c]
            f = np.isfinite(x)
            lo, hi = np.where(f, x, np.inf).min(0), np.where(f, x, -np.inf).max(0)
            empty = ~np.isfinite(lo)
            lo[empty], hi[empty] = 0, 0
            self.box_lo[c], self.box_hi[c] = lo, hi
        self.precision = precision

    def cell_of(self, means: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            q = np.floor((means - self.lo) / np.maximum(self.hi - self.lo, 1e-30) * CELL_GRID)
        q = np.clip(np.nan_to_num(q, nan=0), 0, CELL_GRID - 1).astype(np.int64)
        return (q[:, 0] * CELL_GRID + q[:, 1]) * CELL_GRID + q[:, 2]


def cellbox_read(clean: np.ndarray, corrupt: np.ndarray, prims: np.ndarray, cells: CellBoxes) -> np.ndarray:
    """Clamp the guarded values of `corrupt` (primitives `prims`) into their stored cell's box."""
    out = corrupt.copy()
    p = cells.precision
    cid = cells.cell[np.asarray(prims, dtype=np.int64)]
    lo, hi = cells.box_lo[cid], cells.box_hi[cid]
    v = encoding.from_bits(out[:, cells.cols], p)
    with np.errstate(invalid="ignore"):
        low = np.isnan(v) | (v < lo)
        high = v > hi
    sub = out[:, cells.cols]
    sub[low] = encoding.to_bits(lo[low], p)
    sub[high] = encoding.to_bits(hi[high], p)
    out[:, cells.cols] = sub
    return out


def scale_table(box, precision: str) -> np.ndarray:
    """scalebound's class bounds for a model: its log-scale box cut into 2**SCALE_CLASS_BITS."""
    return scale_class_table(float(box.lo[3:6].min()), float(box.hi[3:6].max()), precision)
