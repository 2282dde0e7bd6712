"""Every defense in one place: its name, what it costs in memory, and what the renderer reads
through it from a corrupted primitive (the numpy twin every evaluation uses).

This module is the single source of the defense list (`DEFENSES`, `DEFENSE_INFO`): the spec, the
CLI, the viewer and `seuwgpu defenses` take it from here.

A defense reads the stored primitive as it is now (`corrupt`, stored bit patterns [M, ncomp]) and
knows what it stored alongside the clean model (parity bits, checksums, scale classes, boxes: all
functions of the clean primitive, so the twins take the clean rows and recompute them). Every
defense is the identity on the clean model (tests/test_defenses.py).

- none, guard, selective: the support guard's box clamp (faults/guard.py; applied in the
  pipeline, so `read` returns the corrupted bits and `PIPELINE_GUARD` names the clamp);
- ecc: SEC-DED over every value's sign+exponent bits; dup: triple modular redundancy;
- parity / parity4: 1 (4 interleaved) parity bit(s) per primitive over the sign, exponent and top
  mantissa bits of its 14 geometry/opacity/colour values (not sh_rest); a mismatch culls the
  primitive (its mean is set to NaN: the one corrupted primitive the renderer draws nothing for).
  Four interleaved parities (bit position mod 4) catch every burst of up to 4 adjacent bits;
- ecc_crit: SEC-DED over the sign+exponent bits of log-scales and opacity only (the critical
  cells); a detected uncorrectable error culls the primitive;
- scalebound: the guard plus a 4-bit scale class per primitive bounding its log-scales from above
  (16 equal classes across the box);
- checksum: a 32-bit checksum per primitive over all its stored values, checked before the
  frame; a mismatch reloads the primitive from the golden copy (host memory or the model file,
  not charged to device memory). Each step, h = fmix32(h ^ value) (MurmurHash3's finaliser), is a
  bijection of the running hash, so any change
  confined to one stored value is detected with certainty;
- cellbox: the support guard with one box per cell of an 8x8x8 grid over the clean means (robust
  1-99% region, outer cells open), each primitive storing its 9-bit cell id; every value except
  sh_rest is clamped into its cell's box (NaN -> lower bound, as the guard);
- parity4r: parity4's check over every value (sh_rest too: a reload is harmless where a cull
  is not), a flagged primitive reloaded from the golden copy (as checksum does) instead of culled.
The golden copy that reloads read from lives off the device and is not charged as device memory.
"""

from __future__ import annotations

import functools

import numpy as np

from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS

# ---- defenses on stored bits -------------------------------------------------------------------
DEFENSE_INFO = {
    "none": "no protection",
    "guard": "support guard: clamp every value except sh_rest into the clean model's box",
    "selective": "support guard on log-scales and opacity only",
    "ecc": "SEC-DED Hamming code over every value's sign+exponent bits (corrects single errors)",
    "dup": "triple modular redundancy with bitwise majority voting",
    "parity": "1 parity bit per primitive over sign, exponent and top mantissa bits; mismatch culls",
    "parity4": "4 interleaved parity bits per primitive (bit mod 4): catch bursts of <= 4 bits; cull",
    "ecc_crit": "SEC-DED over sign+exponent of log-scales and opacity only; uncorrectable culls",
    "scalebound": "support guard plus a 4-bit scale class per primitive bounding its log-scales",
    "checksum": "32-bit checksum per primitive checked per frame; mismatch reloads it from the golden copy",
    "parity4r": "parity4's check over every value; a mismatch reloads the primitive from the golden copy",
    "cellbox": "support boxes per spatial cell (8x8x8 grid, 9-bit cell id per primitive): clamp into its cell's box",
}
DEFENSES = tuple(DEFENSE_INFO)
# the first study's defenses (guard variants, ECC, duplication); the others came with issue 16
FIRST_DEFENSES = ("none", "guard", "selective", "ecc", "dup")
# short names for figures and tables; a defense without one is shown by its name
DEFENSE_LABELS = {
    "none": "none",
    "guard": "support guard",
    "selective": "selective guard (log-scale + opacity)",
    "ecc": "ECC sign+exp (SEC-DED)",
    "dup": "full duplication (TMR vote)",
}
GUARDED_FIELDS = {
    "guard": ("means", "log_scales", "quats", "opacity", "sh_dc"),
    "guard_all": FIELDS,
    "selective": ("log_scales", "opacity"),
}
# the support-guard variant each defense clamps with in the pipeline
PIPELINE_GUARD = {"guard": "guard", "selective": "selective", "scalebound": "guard"}
PARITY_FIELDS = GUARDED_FIELDS["guard"]  # culling parities: a cull for an inert sh_rest hit would only harm
RELOAD_PARITY_FIELDS = FIELDS  # a reload is harmless, so parity4r covers every value
PARITY_MANTISSA = 4  # top mantissa bits covered by the parity defenses, besides sign+exponent
SCALE_CLASS_BITS = 4
CRITICAL_FIELDS = ("log_scales", "opacity")


def check_defense(name: str) -> str:
    if name not in DEFENSES:
        raise ValueError(f"unknown defense {name!r}; expected one of {', '.join(DEFENSES)}")
    return name


def _covered_components(fields, degree: int) -> np.ndarray:
    from seuwgpu.model.fields import FIELD_OFFSET, field_components

    return np.array([FIELD_OFFSET[f] + c for f in fields for c in range(field_components(f, degree))], np.int64)


def parity_fields(defense: str) -> tuple[str, ...]:
    return RELOAD_PARITY_FIELDS if defense == "parity4r" else PARITY_FIELDS


def parity_components(defense: str, degree: int) -> int:
    """A parity defense covers flat components 0 .. this - 1 (its fields lead the layout)."""
    cols = _covered_components(parity_fields(defense), degree)
    assert np.array_equal(cols, np.arange(cols.size))
    return int(cols.size)


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


def parity_bits(rows: np.ndarray, precision: str, degree: int, ways: int, fields=PARITY_FIELDS) -> np.ndarray:
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


# defenses whose check runs on the GPU (shaders/check.wgsl, faults/check.py): per-primitive side
# data stored with the model, and the check that flags a primitive
CHECKED = ("parity", "parity4", "parity4r", "checksum", "scalebound")
RELOADED = ("checksum", "parity4r")  # flagged primitives reloaded from the golden copy


def defense_label(name: str) -> str:
    """The defense's short name in figures and tables (its name where it has none)."""
    return DEFENSE_LABELS.get(name, name)


def scale_table(box, precision: str) -> np.ndarray:
    return scale_class_table(float(box.lo[3:6].min()), float(box.hi[3:6].max()), precision)


def side_data(defense: str, clean: np.ndarray, precision: str, degree: int, box=None) -> np.ndarray:
    """[M] u32 stored with each clean primitive: packed parity bits, the checksum, or the scale
    class (the table is shared by the model: `scale_table`)."""
    clean = np.asarray(clean)
    if defense in ("parity", "parity4", "parity4r"):
        ways = 1 if defense == "parity" else 4
        par = parity_bits(clean, precision, degree, ways, parity_fields(defense)).astype(np.uint32)
        return (par << np.arange(par.shape[1], dtype=np.uint32)).sum(axis=1).astype(np.uint32)
    if defense == "checksum":
        return checksum(clean)
    if defense == "scalebound":
        if box is None:
            raise ValueError("scalebound needs the clean model's box")
        return scale_classes(clean, scale_table(box, precision), precision).astype(np.uint32)
    raise ValueError(f"defense {defense!r} has no per-primitive check; checked ones: {', '.join(CHECKED)}")


def detect(defense: str, side: np.ndarray, rows: np.ndarray, precision: str, degree: int, box=None) -> np.ndarray:
    """[M] bool: the check of `defense` flags the primitive (stored `rows` against `side`).
    Twin of shaders/check.wgsl."""
    rows = np.asarray(rows)
    if defense == "scalebound":
        bound = scale_table(box, precision)[np.asarray(side, dtype=np.int64)]
        vals = encoding.from_bits(rows[:, 3:6], precision)
        with np.errstate(invalid="ignore"):
            return (vals > bound[:, None]).any(axis=1)
    return side_data(defense, rows, precision, degree, box) != np.asarray(side, dtype=np.uint32)


def repair(defense: str, clean: np.ndarray, corrupt: np.ndarray, hit: np.ndarray, precision: str, box=None, side=None):
    """What a flagged primitive becomes: culled (parity), reloaded (checksum) or its log-scales
    clamped to the class bound (scalebound; `side`: the clean rows' classes when already known);
    unflagged rows are returned as they are."""
    if defense in ("parity", "parity4"):
        return _cull(corrupt, hit, precision)
    if defense in RELOADED:
        return np.where(hit[:, None], clean, corrupt)
    side = side_data(defense, clean, precision, 0, box) if side is None else side
    bound = scale_table(box, precision)[np.asarray(side, dtype=np.int64)]
    vals = encoding.from_bits(corrupt[:, 3:6], precision)
    with np.errstate(invalid="ignore"):
        over = (vals > bound[:, None]) & hit[:, None]
    out = corrupt.copy()
    ls = out[:, 3:6]
    ls[over] = np.broadcast_to(encoding.to_bits(bound, precision)[:, None], ls.shape)[over]
    out[:, 3:6] = ls
    return out


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
        self.cols = _covered_components(GUARDED_FIELDS["guard"], degree)
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


def read(
    defense: str, clean: np.ndarray, corrupt: np.ndarray, precision: str, degree: int, box=None, prims=None, cells=None
) -> np.ndarray:
    """What `defense` reads from primitives whose stored patterns went from `clean` to `corrupt`
    ([M, ncomp] each). The support-guard clamp (PIPELINE_GUARD) is left to the pipeline; `box`
    (faults/guard.Box of the clean model) is needed by scalebound, the primitives' indices and
    the model's CellBoxes by cellbox."""
    check_defense(defense)
    clean, corrupt = np.asarray(clean), np.asarray(corrupt)
    if defense == "cellbox":
        if cells is None or prims is None:
            raise ValueError("cellbox needs the primitives' indices and the model's cell boxes")
        return cellbox_read(clean, corrupt, prims, cells)
    if defense == "ecc":
        return ecc_read(clean, corrupt, precision)
    if defense == "dup":
        return dup_read(clean, corrupt)
    if defense == "ecc_crit":
        return ecc_crit_read(clean, corrupt, precision, degree)
    if defense in CHECKED:
        side = side_data(defense, clean, precision, degree, box)
        hit = detect(defense, side, corrupt, precision, degree, box)
        return repair(defense, clean, corrupt, hit, precision, box, side)
    return corrupt


def memory_overhead(defense: str, precision: str, degree: int, n: int) -> float:
    """Extra stored bits on the device per stored bit of the model (box bounds are fp32)."""
    check_defense(defense)
    from seuwgpu.model.fields import n_components

    nb = encoding.bits_per_value(precision)
    per_prim = n_components(degree) * nb
    box = {g: 2 * 32 * _covered_components(GUARDED_FIELDS[v], degree).size for g, v in PIPELINE_GUARD.items()}
    extra_per_prim = {
        "ecc": ecc_check_bits(precision) * n_components(degree),
        "dup": 2 * per_prim,
        "parity": 1,
        "parity4": 4,
        "parity4r": 4,
        "ecc_crit": ecc_check_bits(precision) * _covered_components(CRITICAL_FIELDS, degree).size,
        "scalebound": SCALE_CLASS_BITS,
        "checksum": 32,
        "cellbox": 9,
    }.get(defense, 0)
    if defense == "cellbox":  # 2 fp32 bounds per guarded component per cell
        box = {"cellbox": 2 * 32 * _covered_components(GUARDED_FIELDS["guard"], degree).size * CELL_GRID**3}
    return (extra_per_prim * n + box.get(defense, 0)) / (per_prim * n)
