"""Every defense in one place: one object per defense, registered once here (`register`), that
says what it is (name, label, info), what it stores beside the model, what the renderer reads
through it from a corrupted primitive (the numpy twin every evaluation uses), and, for the
defenses with a GPU check, the check's side data, detection and repair.

The CLI, the spec, the engine, the GPU check, the cost report, the storm, the viewer and the
analyses ask these objects (`get(name)`, `DEFENSES`); none of them lists defense names.

A defense reads the stored primitive as it is now (`corrupt`, stored bit patterns [M, ncomp]) and
knows what it stored alongside the clean model (parity bits, checksums, scale classes, boxes: all
functions of the clean primitive, so the twins take the clean rows and recompute them). Every
defense is the identity on the clean model (tests/test_defenses.py).

The kinds (classes below): `Defense` (none: reads the corrupted bits), `SupportGuard` (the
guard's box clamp, applied in the pipeline: faults/guard.py; its `read` returns the corrupted
bits and `guard_fields` names what the pipeline clamps), `Ecc`, `EccCritical` and
`Duplication` (read-time codes, modelled by what they read), `CellBox` (per-cell boxes), and
`CheckedDefense` (a per-primitive check on the GPU, shaders/check.wgsl: `Parity`, `Checksum`,
`ScaleBound`), which flags a primitive and then culls it (its mean set to NaN: the one corrupted
primitive the renderer draws nothing for), reloads it from the golden copy (host memory or the
model file, not charged to device memory) or clamps it. The checksum's step, h = fmix32(h ^
value) (MurmurHash3's finaliser), is a bijection of the running hash, so any change confined to
one stored value is detected with certainty; four interleaved parities (bit position mod 4)
catch every burst of up to 4 adjacent bits.

Also here, so that every part computes them alike: the side data as the device holds it
(`pack_side`, `device_bytes`) and a check defense's schedule, a check every S frames
(`exposure`: the frames drawn from a corrupted model before the check; `amortised_time`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS, n_components

GUARD_FIELDS = ("means", "log_scales", "quats", "opacity", "sh_dc")  # every field but the inert sh_rest
CRITICAL_FIELDS = ("log_scales", "opacity")
PARITY_MANTISSA = 4  # top mantissa bits covered by the parity defenses, besides sign+exponent
SCALE_CLASS_BITS = 4
SCALE_CLASSES = 1 << SCALE_CLASS_BITS


def _covered_components(fields, degree: int) -> np.ndarray:
    from seuwgpu.model.fields import FIELD_OFFSET, field_components

    return np.array([FIELD_OFFSET[f] + c for f in fields for c in range(field_components(f, degree))], np.int64)


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
    return _ecc_decode(clean_bits, stored_bits, precision)[0]


def _ecc_decode(clean_bits: np.ndarray, stored_bits: np.ndarray, precision: str) -> tuple[np.ndarray, np.ndarray]:
    """SEC-DED decoding (ecc_read) and, per value, whether the decoder flags an uncorrectable
    error: an even number of errors with a non-zero syndrome, or an odd number whose syndrome
    names no position of the codeword."""
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
    n = len(prot) + r  # codeword positions 1..n: data at `pos`, check bits at the powers of two
    uncorrectable = (syn != 0) & (((p_clean ^ p_cur) == 0) | (syn > np.uint64(n)))
    return out.astype(np.asarray(stored_bits).dtype), uncorrectable


def majority(a, b, c):
    """Bitwise majority vote of three copies (triple modular redundancy)."""
    return (a & b) | (a & c) | (b & c)


def dup_read(clean_bits: np.ndarray, stored_bits: np.ndarray) -> np.ndarray:
    """Full duplication with majority voting: the upset hit one of three copies (copy 0)."""
    return majority(np.asarray(stored_bits), np.asarray(clean_bits), np.asarray(clean_bits))


# ---- new defenses: twins of what the renderer reads ---------------------------------------------
def cull_bits(precision: str) -> int:
    """Stored pattern written into a culled primitive's means: a quiet NaN (the renderer culls a
    primitive whose camera-space depth is not finite, docs/renderer.md rule 2)."""
    return {"fp32": 0x7FC00000, "fp16": 0x7E00, "bf16": 0x7FC0}[encoding.check_precision(precision)]


def _cull(rows: np.ndarray, hit: np.ndarray, precision: str) -> np.ndarray:
    out = rows.copy()
    out[np.ix_(hit, np.arange(3))] = cull_bits(precision)  # means are components 0..2
    return out


def parity_cover_mask(precision: str) -> int:
    """Bits of each value the parity defenses cover: sign, exponent and the top PARITY_MANTISSA
    mantissa bits."""
    man, _ = encoding.LAYOUT[encoding.check_precision(precision)]
    return ((1 << encoding.bits_per_value(precision)) - 1) & ~((1 << (man - PARITY_MANTISSA)) - 1)


def parity_bits(rows: np.ndarray, precision: str, degree: int, ways: int, fields=GUARD_FIELDS) -> np.ndarray:
    """[M, ways] parity of the covered bits of each primitive's `fields` values, way w over bit
    positions b with b % ways == w (interleaving: a burst of <= ways adjacent bits of one value
    flips at most one bit of each way)."""
    cols = _covered_components(fields, degree)
    v = np.asarray(rows)[:, cols].astype(np.uint64) & np.uint64(parity_cover_mask(precision))
    out = np.zeros((v.shape[0], ways), dtype=np.uint8)
    for b in range(encoding.bits_per_value(precision)):
        out[:, b % ways] ^= ((v >> np.uint64(b)) & np.uint64(1)).astype(np.uint8).sum(axis=1).astype(np.uint8) & 1
    return out


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
    cols = _covered_components(CRITICAL_FIELDS, degree)
    out = corrupt.copy()
    out[:, cols], flagged = _ecc_decode(clean[:, cols], corrupt[:, cols], precision)
    # SEC-DED flags what it cannot correct (two errors in the protected bits): cull. What it does
    # not flag (three errors read as one and "corrected", four with a zero syndrome) passes.
    return _cull(out, flagged.any(axis=1), precision)


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
        self.cols = _covered_components(GUARD_FIELDS, degree)
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


# ---- the defenses ------------------------------------------------------------------------------
class Defense:
    """One defense. This base is "none": it stores nothing and reads the corrupted bits.

    A subclass overrides what differs: `read` (the twin of what the renderer reads), the bits it
    stores (`bits_per_primitive`, `bits_per_model`), `guard_fields` (the fields the in-pipeline
    support guard clamps for it), `model_state` (state built once from the clean model, such as
    cellbox's boxes), and for a GPU check the members of `CheckedDefense`."""

    guard_fields: tuple[str, ...] = ()  # fields the pipeline's support guard clamps (faults/guard.py)
    reads_stored_bits = True  # `read` returns the stored bits as they are (none, the guards)
    has_model_state = False  # `model_state` builds something from the clean model
    check_mode: str | None = None  # its check's MODE_* const in shaders/check.wgsl, by name; None: no check
    writes_back = False  # its repair rewrites the stored model (a storm keeps the repair)

    def __init__(self, name: str, info: str, label: str = "", first_study: bool = False):
        self.name, self.info, self.label = name, info, label or name
        self.first_study = first_study  # one of the first study's defenses (guard variants, ECC, TMR)

    def __repr__(self) -> str:
        return f"<defense {self.name}>"

    @property
    def checked(self) -> bool:
        return self.check_mode is not None

    def upset_exposure(self, check_every: int) -> Exposure:
        """Frames drawn from a corrupted model before it acts: a check's schedule (`exposure`);
        none for one that changes what every read returns (a guard, a correction, a vote); for
        one that reads the stored bits as they are and guards nothing, until a reload."""
        if self.checked:
            return exposure(check_every)
        return exposure(0 if self.reads_stored_bits and not self.guard_fields else 1)

    def bits_per_primitive(self, precision: str, degree: int) -> int:
        """Stored bits it adds per primitive."""
        return 0

    def bits_per_model(self, precision: str, degree: int) -> int:
        """Stored bits it adds once per model (boxes, tables): a support guard's box, 2 fp32 bounds
        per guarded component."""
        return 2 * 32 * _covered_components(self.guard_fields, degree).size

    def model_state(self, clean_rows: np.ndarray, precision: str, degree: int):
        """What it builds once from the clean model beyond the box (None: nothing)."""
        return None

    def read(self, clean, corrupt, precision: str, degree: int, box=None, prims=None, state=None) -> np.ndarray:
        """What the renderer reads from primitives whose stored bits went from `clean` to
        `corrupt` ([M, ncomp] each); the in-pipeline guard clamp is applied later."""
        return corrupt


class SupportGuard(Defense):
    """The support guard: `fields` clamped into the clean model's box while projecting (the
    pipeline does it; memory is untouched). Stores the box: 2 fp32 bounds per guarded component."""

    def __init__(self, name, info, fields, label="", first_study=False):
        super().__init__(name, info, label, first_study)
        self.guard_fields = tuple(fields)


class Ecc(Defense):
    reads_stored_bits = False

    def bits_per_primitive(self, precision, degree):
        return ecc_check_bits(precision) * n_components(degree)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        return ecc_read(clean, corrupt, precision)


class Duplication(Defense):
    reads_stored_bits = False

    def bits_per_primitive(self, precision, degree):
        return 2 * n_components(degree) * encoding.bits_per_value(precision)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        return dup_read(clean, corrupt)


class EccCritical(Defense):
    reads_stored_bits = False

    def bits_per_primitive(self, precision, degree):
        return ecc_check_bits(precision) * _covered_components(CRITICAL_FIELDS, degree).size

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        return ecc_crit_read(clean, corrupt, precision, degree)


class CellBox(Defense):
    reads_stored_bits = False
    has_model_state = True

    def bits_per_primitive(self, precision, degree):
        return 9

    def bits_per_model(self, precision, degree):
        return 2 * 32 * _covered_components(GUARD_FIELDS, degree).size * CELL_GRID**3

    def model_state(self, clean_rows, precision, degree):
        return CellBoxes(clean_rows, precision, degree)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        if state is None or prims is None:
            raise ValueError("cellbox needs the primitives' indices and the model's cell boxes")
        return cellbox_read(clean, corrupt, prims, state)


class CheckedDefense(Defense):
    """A per-primitive check that runs on the GPU (shaders/check.wgsl, faults/check.py): side
    data computed from the clean model once, a check that flags primitives, and a repair."""

    reads_stored_bits = False

    side_bits = 32  # bits of side data per primitive
    table_words = 1  # f32 words of its check's table (`check_table`)
    reloads = False  # a flagged primitive is reloaded from the golden copy (off the device)
    writes_back = True

    def bits_per_primitive(self, precision, degree):
        return self.side_bits

    def check_parameters(self, precision: str, degree: int) -> dict:
        """The CheckParams fields of its check besides the chunk's (parity ways and cover)."""
        return {"ways": 4, "cover": 0, "comp_count": 0}

    def check_table(self, box, precision: str) -> np.ndarray:
        """The f32 table its check reads (scalebound's class bounds; one placeholder word otherwise)."""
        return np.zeros(self.table_words, np.float32)

    def side_data(self, clean, precision: str, degree: int, box=None) -> np.ndarray:
        """[M] u32: what it stores with each clean primitive."""
        raise NotImplementedError

    def detect(self, side, rows, precision: str, degree: int, box=None) -> np.ndarray:
        """[M] bool: the check flags the primitive (stored `rows` against `side`). Twin of
        shaders/check.wgsl."""
        return self.side_data(rows, precision, degree, box) != np.asarray(side, dtype=np.uint32)

    def repair(self, clean, corrupt, hit, precision: str, box=None, side=None) -> np.ndarray:
        """What a flagged primitive becomes; unflagged rows are returned as they are."""
        if self.reloads:
            return np.where(hit[:, None], clean, corrupt)
        return _cull(corrupt, hit, precision)

    def read(self, clean, corrupt, precision, degree, box=None, prims=None, state=None):
        side = self.side_data(clean, precision, degree, box)
        hit = self.detect(side, corrupt, precision, degree, box)
        return self.repair(clean, corrupt, hit, precision, box, side)


class Parity(CheckedDefense):
    """`ways` interleaved parity bits over the sign, exponent and top PARITY_MANTISSA mantissa
    bits of the values of `fields` (they lead the layout); a mismatch culls or reloads."""

    check_mode = "MODE_PARITY"

    def __init__(self, name, info, ways: int, fields, reloads: bool, label="", first_study=False):
        super().__init__(name, info, label, first_study)
        self.ways, self.fields, self.reloads = ways, tuple(fields), reloads
        self.side_bits = ways

    def components(self, degree: int) -> int:
        """The check covers flat components 0 .. this - 1 (its fields lead the layout)."""
        cols = _covered_components(self.fields, degree)
        assert np.array_equal(cols, np.arange(cols.size))
        return int(cols.size)

    def check_parameters(self, precision, degree):
        return {"ways": self.ways, "cover": parity_cover_mask(precision), "comp_count": self.components(degree)}

    def side_data(self, clean, precision, degree, box=None):
        par = parity_bits(np.asarray(clean), precision, degree, self.ways, self.fields).astype(np.uint32)
        return (par << np.arange(par.shape[1], dtype=np.uint32)).sum(axis=1).astype(np.uint32)


class Checksum(CheckedDefense):
    check_mode = "MODE_CHECKSUM"
    reloads = True

    def side_data(self, clean, precision, degree, box=None):
        return checksum(np.asarray(clean))


class ScaleBound(CheckedDefense):
    """The support guard plus a SCALE_CLASS_BITS-bit class per primitive bounding its log-scales
    from above; a flagged primitive's log-scales are clamped to the class bound."""

    check_mode = "MODE_SCALE"
    side_bits = SCALE_CLASS_BITS
    guard_fields = GUARD_FIELDS
    table_words = SCALE_CLASSES

    def check_table(self, box, precision):
        return scale_table(box, precision)

    def side_data(self, clean, precision, degree, box=None):
        if box is None:
            raise ValueError("scalebound needs the clean model's box")
        return scale_classes(np.asarray(clean), scale_table(box, precision), precision).astype(np.uint32)

    def detect(self, side, rows, precision, degree, box=None):
        bound = scale_table(box, precision)[np.asarray(side, dtype=np.int64)]
        vals = encoding.from_bits(np.asarray(rows)[:, 3:6], precision)
        with np.errstate(invalid="ignore"):
            return (vals > bound[:, None]).any(axis=1)

    def repair(self, clean, corrupt, hit, precision, box=None, side=None):
        side = self.side_data(clean, precision, 0, box) if side is None else side
        bound = scale_table(box, precision)[np.asarray(side, dtype=np.int64)]
        vals = encoding.from_bits(corrupt[:, 3:6], precision)
        with np.errstate(invalid="ignore"):
            over = (vals > bound[:, None]) & hit[:, None]
        out = corrupt.copy()
        ls = out[:, 3:6]
        ls[over] = np.broadcast_to(encoding.to_bits(bound, precision)[:, None], ls.shape)[over]
        out[:, 3:6] = ls
        return out


# ---- side data as the device holds it ------------------------------------------------------------
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


CHECK_HEADER_BYTES = 16  # shaders/check.wgsl CheckOut's count and padding
BOUND_BYTES = 16  # faults/guard.py Box.rows(): lo, hi and their stored bits per component
GUARD_COUNT_BYTES = 32  # the renderer's clamp counts (8 u32)


def device_bytes(defense: str, precision: str, degree: int, n: int, chunks: int = 1) -> int:
    """Bytes the defense holds on the device beside the model, as this package uploads them.

    A support guard: the box the pipeline reads (one Bound record per stored component) and the
    clamp counts. A GPU check: its side data packed `side_bits` a primitive, its output (a count and
    one flag bit per primitive), its table (scalebound's class bounds) and one uniform slot per
    model chunk; scalebound adds the guard's. The read-time codes without a GPU decoder (ECC,
    ecc_crit, TMR, cellbox): their encoding's bits, packed, rounded up to whole u32 words."""
    from seuwgpu.gpu.constants import UNIFORM_STRIDE
    from seuwgpu.model.budget import BUFFER_ALIGN

    def buffer(nbytes: int) -> int:  # gpu/device.py GPU.buffer's rounding
        return max(BUFFER_ALIGN, -(-int(nbytes) // BUFFER_ALIGN) * BUFFER_ALIGN)

    d = get(defense)
    total = 0
    if d.guard_fields:
        total += buffer(BOUND_BYTES * n_components(degree)) + buffer(GUARD_COUNT_BYTES)
    if d.checked:
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


# ---- the check schedule -------------------------------------------------------------------------
class Exposure(NamedTuple):
    per_upset: np.ndarray  # frames rendered from the corrupted model, per upset of the schedule
    expected: float  # over an upset landing in a uniformly drawn frame gap
    worst: float


def exposure(check_every: int, upset_frames=None) -> Exposure:
    """Frames rendered from a corrupted model between an upset and the check that repairs it,
    for a check before every `check_every`-th frame (before frames 0, S, 2S, ...; 0 = never).

    An upset "at frame f" lands after frame f - 1 was drawn and before frame f's check: frames
    f .. c - 1 are drawn corrupted, c the first check frame >= f, so (-f) mod S of them: none
    when f is a check frame, S - 1 when it lands just after one. `expected` and `worst` are over
    every phase (f = 0 .. S - 1, each equally likely); `per_upset` is for `upset_frames` (a
    hand-made schedule; every phase when None). Never checked: infinite exposure."""
    s = int(check_every)
    if s < 0:
        raise ValueError(f"a check schedule is every S >= 1 frames, or 0 for never (got {s})")
    frames = np.arange(max(s, 1)) if upset_frames is None else np.asarray(upset_frames, dtype=np.int64)
    if s == 0:
        per = np.full(frames.shape, np.inf)
        return Exposure(per, float("inf"), float("inf"))
    per = (-frames) % s
    phases = (-np.arange(s)) % s
    return Exposure(per.astype(np.float64), float(phases.mean()), float(phases.max()))


def amortised_time(defense: str, guard_fraction: float, check_fraction: float, check_every: int = 1) -> float:
    """Extra time per frame (fraction of a view): the in-pipeline clamp every frame, the check
    once every `check_every` frames (0: never). NaN stays NaN."""
    d = get(defense)
    total = guard_fraction if d.guard_fields else 0.0
    if d.checked and check_every:
        total += check_fraction / check_every
    return total


# ---- the registry ------------------------------------------------------------------------------
REGISTRY: dict[str, Defense] = {}


def register(defense: Defense) -> Defense:
    """Add a defense to the one list every part of the package reads (in this order)."""
    if defense.name in REGISTRY:
        raise ValueError(f"defense {defense.name!r} is registered twice")
    REGISTRY[defense.name] = defense
    return defense


register(Defense("none", "no protection", first_study=True))
register(
    SupportGuard(
        "guard",
        "support guard: clamp every value except sh_rest into the clean model's box",
        GUARD_FIELDS,
        label="support guard",
        first_study=True,
    )
)
register(
    SupportGuard(
        "selective",
        "support guard on log-scales and opacity only",
        CRITICAL_FIELDS,
        label="selective guard (log-scale + opacity)",
        first_study=True,
    )
)
register(
    Ecc(
        "ecc",
        "SEC-DED Hamming code over every value's sign+exponent bits (corrects single errors)",
        label="ECC sign+exp (SEC-DED)",
        first_study=True,
    )
)
register(
    Duplication(
        "dup",
        "triple modular redundancy with bitwise majority voting",
        label="full duplication (TMR vote)",
        first_study=True,
    )
)
register(
    Parity(
        "parity",
        "1 parity bit per primitive over sign, exponent and top mantissa bits; mismatch culls",
        ways=1,
        fields=GUARD_FIELDS,  # a cull for an inert sh_rest hit would only harm
        reloads=False,
    )
)
register(
    Parity(
        "parity4",
        "4 interleaved parity bits per primitive (bit mod 4): catch bursts of <= 4 bits; cull",
        ways=4,
        fields=GUARD_FIELDS,
        reloads=False,
    )
)
register(EccCritical("ecc_crit", "SEC-DED over sign+exponent of log-scales and opacity only; uncorrectable culls"))
register(ScaleBound("scalebound", "support guard plus a 4-bit scale class per primitive bounding its log-scales"))
register(Checksum("checksum", "32-bit checksum per primitive; a mismatch reloads it from the golden copy"))
register(
    Parity(
        "parity4r",
        "parity4's check over every value; a mismatch reloads the primitive from the golden copy",
        ways=4,
        fields=FIELDS,  # a reload is harmless, so it covers every value
        reloads=True,
    )
)
register(
    CellBox(
        "cellbox",
        "support boxes per spatial cell (8x8x8 grid, 9-bit cell id per primitive): clamp into its cell's box",
    )
)

register(
    SupportGuard(
        "guard_all",
        "the paper's Algorithm 1: clamp every value, sh_rest included, into the clean model's box",
        FIELDS,
        label="support guard, every field (paper)",
    )
)

DEFENSES = tuple(REGISTRY)
FIRST_DEFENSES = tuple(d.name for d in REGISTRY.values() if d.first_study)


def get(name: str) -> Defense:
    """The registered defense `name` (a clear error for any other name)."""
    d = REGISTRY.get(name)
    if d is None:
        raise ValueError(f"unknown defense {name!r}; expected one of {', '.join(REGISTRY)}")
    return d


def check_defense(name: str) -> str:
    return get(name).name


def defense_label(name: str) -> str:
    """The defense's short name in figures and tables (its name where it has none)."""
    d = REGISTRY.get(name)
    return d.label if d is not None else name


def pipeline_guards() -> dict[str, tuple[str, ...]]:
    """{name: fields} of the defenses whose fields the pipeline's support guard clamps."""
    return {d.name: d.guard_fields for d in REGISTRY.values() if d.guard_fields}


def checked(name: str) -> CheckedDefense:
    """The registered defense `name`, which must have a per-primitive check."""
    d = get(name)
    if not d.checked:
        ok = ", ".join(x.name for x in REGISTRY.values() if x.checked)
        raise ValueError(f"defense {name!r} has no per-primitive check; checked ones: {ok}")
    return d


# ---- the twins by name (what the engine, the check stage and the tests call) -------------------
def side_data(defense: str, clean: np.ndarray, precision: str, degree: int, box=None) -> np.ndarray:
    """[M] u32 stored with each clean primitive by a checked defense (CheckedDefense.side_data)."""
    return checked(defense).side_data(np.asarray(clean), precision, degree, box)


def detect(defense: str, side: np.ndarray, rows: np.ndarray, precision: str, degree: int, box=None) -> np.ndarray:
    """[M] bool: the check of `defense` flags the primitive. Twin of shaders/check.wgsl."""
    return checked(defense).detect(side, np.asarray(rows), precision, degree, box)


def repair(defense: str, clean: np.ndarray, corrupt: np.ndarray, hit: np.ndarray, precision: str, box=None, side=None):
    return checked(defense).repair(np.asarray(clean), np.asarray(corrupt), hit, precision, box, side)


def read(
    defense: str, clean: np.ndarray, corrupt: np.ndarray, precision: str, degree: int, box=None, prims=None, cells=None
) -> np.ndarray:
    """What `defense` reads from primitives whose stored patterns went from `clean` to `corrupt`
    ([M, ncomp] each); `box` (faults/guard.Box of the clean model) is needed by scalebound, the
    primitives' indices and the model state (`Defense.model_state`, cellbox's CellBoxes) by cellbox."""
    return get(defense).read(np.asarray(clean), np.asarray(corrupt), precision, degree, box, prims, cells)


def memory_overhead(defense: str, precision: str, degree: int, n: int) -> float:
    """Extra stored bits per stored bit of the model (box bounds are fp32)."""
    d = get(defense)
    per_prim = n_components(degree) * encoding.bits_per_value(precision)
    return (d.bits_per_primitive(precision, degree) * n + d.bits_per_model(precision, degree)) / (per_prim * n)
