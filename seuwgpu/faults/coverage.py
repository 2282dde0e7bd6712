"""Coverage of every defense under every fault model, by exhaustive sweep of the faults of a few
primitives (numpy, vectorised; the check defenses through their twins of shaders/check.wgsl, the
read-time codes through what they read).

A fault family is a list of faults of one primitive, each up to two (component, XOR mask) pairs
applied in order to its clean stored row (`family`): every single flip (`bit`); every burst of w
adjacent bits in one value, w = 2..8 (`burst2` .. `burst8`); the same bit in two values of one
primitive (`mcu_prim`, every pair of values and every bit); any two flipped cells of one primitive
(`pair`: every pair of (value, bit) cells, the same value included: 1,781,328 at fp32 degree 3);
the 28 pairs of the 8 dangerous cells (log-scale and opacity bits 30 and 31, `dangerous_pairs`);
a random value (`random`: RANDOM_DRAWS uniform patterns per value); and the same flip in the
neighbouring word of the device layout (`mcu_neighbour`: a single flip in each of two primitives,
caught when both are).

Per fault: `caught` (the check flags the primitive, or what the renderer reads is not the
corrupted row: corrected, culled, clamped) and `restored` (what is read is the clean row bit for
bit: a reload, an ECC correction, a vote). A support guard clamps in the pipeline and flags
nothing: not in the table (its campaigns measure it).
"""

from __future__ import annotations

import itertools

import numpy as np

from seuwgpu.faults import codes
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.sites import DANGEROUS_CELLS
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELD_OFFSET, field_components, n_components

RANDOM_DRAWS = 256
CHUNK = 1 << 17  # faults evaluated at once (rows of ncomp values)
FAMILIES = (
    "bit",
    *(f"burst{w}" for w in range(2, 9)),
    "random",
    "mcu_prim",
    "dangerous_pairs",
    "pair",
    "mcu_neighbour",
)


def covered_defenses() -> list[str]:
    """The defenses the table covers: all but the pipeline guards (they flag nothing)."""
    return [d.name for d in dfn.REGISTRY.values() if d.name != "none" and not isinstance(d, dfn.SupportGuard)]


def dangerous_cells() -> list[tuple[int, int]]:
    """(flat component, bit) of the 8 dangerous cells (sites.DANGEROUS_CELLS, each component of
    their fields), field by field, component by component, then bit."""
    bits = {}
    for field, bit in DANGEROUS_CELLS:
        bits.setdefault(field, []).append(bit)
    return [(FIELD_OFFSET[f] + i, b) for f, bs in bits.items() for i in range(field_components(f, 0)) for b in bs]


def family(name: str, ncomp: int, nb: int, clean_row=None, rng=None) -> tuple[np.ndarray, np.ndarray]:
    """(cols [F, 2], masks [F, 2] u64) of the faults of family `name` on one primitive (a second
    mask of 0 is no change). `random` needs the primitive's clean row and a generator."""
    one = np.uint64(1)
    if name == "bit":
        c, b = np.divmod(np.arange(ncomp * nb), nb)
        return np.stack([c, c], 1), np.stack([one << b.astype(np.uint64), np.zeros(c.size, np.uint64)], 1)
    if name.startswith("burst"):
        w = int(name[5:])
        c, lo = np.divmod(np.arange(ncomp * (nb - w + 1)), nb - w + 1)
        m = np.uint64((1 << w) - 1) << lo.astype(np.uint64)
        return np.stack([c, c], 1), np.stack([m, np.zeros(c.size, np.uint64)], 1)
    if name == "random":
        v = rng.integers(0, 1 << nb, size=(ncomp, RANDOM_DRAWS), dtype=np.uint64)
        m = v ^ np.asarray(clean_row, np.uint64)[:, None]
        c = np.repeat(np.arange(ncomp), RANDOM_DRAWS)
        m = m.ravel()
        keep = m != 0
        return np.stack([c, c], 1)[keep], np.stack([m, np.zeros(m.size, np.uint64)], 1)[keep]
    if name == "mcu_prim":
        pairs = np.array(list(itertools.combinations(range(ncomp), 2)))
        b = np.arange(nb, dtype=np.uint64)
        cols = np.repeat(pairs, nb, axis=0)
        m = np.tile(one << b, len(pairs))
        return cols, np.stack([m, m], 1)
    if name in ("pair", "dangerous_pairs"):
        if name == "pair":
            i, j = np.triu_indices(ncomp * nb, 1)
            c1, b1 = np.divmod(i, nb)
            c2, b2 = np.divmod(j, nb)
        else:
            cells = np.array(dangerous_cells())
            i, j = np.array(list(itertools.combinations(range(len(cells)), 2))).T
            (c1, b1), (c2, b2) = cells[i].T, cells[j].T
        return np.stack([c1, c2], 1), np.stack([one << b1.astype(np.uint64), one << b2.astype(np.uint64)], 1)
    raise ValueError(f"unknown fault family {name!r}; expected one of {', '.join(FAMILIES)}")


def outcomes(
    defense: str,
    clean: np.ndarray,
    prims: np.ndarray,
    cols: np.ndarray,
    masks: np.ndarray,
    precision: str,
    degree: int,
    box=None,
    state=None,
    index=None,
) -> tuple[np.ndarray, np.ndarray]:
    """(caught [F], restored [F]) of `defense` for faults (cols, masks) of primitives `prims` (rows
    of `clean`, the stored patterns of the swept primitives; `index`: their indices in the model,
    for cellbox's cells)."""
    d = dfn.get(defense)
    clean = np.asarray(clean)
    index = np.arange(clean.shape[0]) if index is None else np.asarray(index)
    side = d.side_data(clean, precision, degree, box) if d.checked else None
    caught = np.zeros(len(prims), bool)
    restored = np.zeros(len(prims), bool)
    for s in range(0, len(prims), CHUNK):
        sl = slice(s, s + CHUNK)
        p, c, m = prims[sl], cols[sl], masks[sl]
        rows = clean[p].copy()
        ar = np.arange(len(p))
        for k in range(c.shape[1]):
            rows[ar, c[:, k]] ^= m[:, k].astype(rows.dtype)
        base = clean[p]
        if d.frame_check:  # its code checked in the frame: dropped, then reloaded before the next frame
            # (each fault alone: with a per-word code its word pair, the partner clean, checked together)
            caught[sl] = restored[sl] = d.code.detect_changed(base, rows, 2 * ar, precision, degree)
            continue
        if d.checked:
            hit = d.detect(side[p], rows, precision, degree, box)
            caught[sl] = hit
            restored[sl] = hit if d.reloads else (d.repair(base, rows, hit, precision, box, side[p]) == base).all(1)
            continue
        if isinstance(d, (dfn.Ecc, dfn.Duplication)):  # value by value: only the values hit
            cv, rv = base[ar[:, None], c], rows[ar[:, None], c]
            out = d.read(cv, rv, precision, degree)
            caught[sl] = (out != rv).any(1)
            restored[sl] = (out == cv).all(1)
            continue
        out = d.read(base, rows, precision, degree, box, index[p], state)
        caught[sl] = (out != rows).any(1)
        restored[sl] = (out == base).all(1)
    return caught, restored


def coverage_table(
    clean: np.ndarray,
    precision: str,
    degree: int,
    box=None,
    state=None,
    index=None,
    families=FAMILIES,
    seed: int = 0,
    defenses=None,
) -> list[dict]:
    """[{family, defense, faults, caught, restored, faults_se, caught_se, restored_se}] over every
    fault of each family on every row of `clean` (`pair` on the first row only: 1.78M faults at
    fp32 degree 3; `mcu_neighbour` over consecutive rows as neighbours), and the same over the
    faults that touch a sign or exponent bit (the `_se` keys: the ones that can do harm).
    `defenses`: default covered_defenses() (scalebound needs `box`, cellbox `state`)."""
    defenses = covered_defenses() if defenses is None else list(defenses)
    clean = np.asarray(clean)
    nb = encoding.bits_per_value(precision)
    ncomp = n_components(degree)
    rng = np.random.default_rng(seed)
    se = np.uint64(sum(1 << b for b in codes.protected_bits(precision)))
    out = []

    def row(fam, d, n, caught, restored, harm):
        return {
            "family": fam,
            "defense": d,
            "faults": int(n),
            "caught": int(caught.sum()),
            "restored": int(restored.sum()),
            "faults_se": int(harm.sum()),
            "caught_se": int((caught & harm).sum()),
            "restored_se": int((restored & harm).sum()),
        }

    for fam in families:
        if fam == "mcu_neighbour":
            continue
        rows_of = [0] if fam == "pair" else range(clean.shape[0])
        parts = [family(fam, ncomp, nb, clean[p], rng) for p in rows_of]
        prims = np.concatenate([np.full(len(c), p) for p, (c, _) in zip(rows_of, parts)])
        cols = np.concatenate([c for c, _ in parts])
        masks = np.concatenate([m for _, m in parts])
        harm = ((masks & se) != 0).any(1)
        for d in defenses:
            caught, restored = outcomes(d, clean, prims, cols, masks, precision, degree, box, state, index)
            out.append(row(fam, d, len(prims), caught, restored, harm))
    if "mcu_neighbour" in families and clean.shape[0] >= 2:
        one_cols, one_masks = cols, masks = family("bit", ncomp, nb)
        m = clean.shape[0]
        harm = np.tile((masks & se) != 0, (m - 1, 1)).any(1)
        prims = np.repeat(np.arange(m), len(cols))
        cols, masks = np.tile(cols, (m, 1)), np.tile(masks, (m, 1))
        for d in defenses:
            caught, restored = (
                x.reshape(m, -1) for x in outcomes(d, clean, prims, cols, masks, precision, degree, box, state, index)
            )
            both_c, both_r = caught[:-1] & caught[1:], restored[:-1] & restored[1:]
            arm = dfn.get(d)
            if arm.frame_check and arm.code.pairs(precision):
                # a per-word code: rows 2i and 2i + 1 share a word and one code, checked together
                both_c[0::2] = both_r[0::2] = _same_word(arm, clean, one_cols, one_masks, precision, degree)
            out.append(row("mcu_neighbour", d, both_c.size, both_c.ravel(), both_r.ravel(), harm))
    return out


def _same_word(d, clean: np.ndarray, cols: np.ndarray, masks: np.ndarray, precision: str, degree: int):
    """[pairs, F] caught: fault f (cols[f], masks[f]) in both primitives of each stored word pair
    (rows 2i, 2i + 1) at once, under the per-word frame code of `d`."""
    m = clean.shape[0] - clean.shape[0] % 2
    out = np.zeros((m // 2, len(cols)), bool)
    ar = np.arange(len(cols))
    for i in range(m // 2):
        base = np.repeat(clean[2 * i : 2 * i + 2], len(cols), axis=0)  # [2F]: row 2i F times, then 2i + 1
        rows = base.copy()
        for half in range(2):
            r = half * len(cols) + ar
            for k in range(cols.shape[1]):
                rows[r, cols[:, k]] ^= masks[:, k].astype(rows.dtype)
        index = np.concatenate([2 * ar, 2 * ar + 1])  # fault f's two rows: a pair of their own
        out[i] = d.code.detect_changed(base, rows, index, precision, degree)[: len(cols)]
    return out


def markdown(rows: list[dict], harmful: bool = False) -> str:
    """The table: a row per fault family, a column per defense, `caught% (restored%)`; of the faults
    touching a sign or exponent bit with `harmful`."""
    sfx = "_se" if harmful else ""
    defenses = list(dict.fromkeys(r["defense"] for r in rows))
    fams = list(dict.fromkeys(r["family"] for r in rows))
    cell = {(r["family"], r["defense"]): r for r in rows}
    lines = ["| fault model (faults) | " + " | ".join(defenses) + " |", "|---|" + "---:|" * len(defenses)]
    for f in fams:
        n = next(cell[(f, d)]["faults" + sfx] for d in defenses if (f, d) in cell)
        vals = []
        for d in defenses:
            r = cell[(f, d)]
            if not n:
                vals.append("")
                continue
            c, rs = 100 * r["caught" + sfx] / n, 100 * r["restored" + sfx] / n
            vals.append(f"{c:.4g} ({rs:.4g})")
        lines.append(f"| {f} ({n:,}) | " + " | ".join(vals) + " |")
    return "\n".join(lines)
