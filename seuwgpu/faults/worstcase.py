"""Worst-case search: the single-bit flip with the largest footprint, for a model and a defense,
without rendering every flip.

A flip changes one primitive, so the pixels it can change lie in that primitive's clean tile
rectangle or its corrupted one (the incremental compositor's dirty tiles; everything else is the
clean frame bit for bit). The pixel count of those tiles, averaged over the views and divided by
the frame, bounds the flip's footprint from above. The search
1. bounds every site: a flip that leaves the primitive's geometry (means, log-scales, quats) as
   the defense reads it unchanged keeps its clean rectangle; the others are projected on the GPU
   in batches (the renderer's own projection shader); a flip the defense reads back as the
   clean primitive (corrected, reloaded) is bounded by 0;
2. evaluates sites in decreasing order of bound (incremental re-compositing, exact) and stops when
   the next bound cannot beat the best footprint found.
The result carries the observed maximum and the certified bound: the largest footprint any
unevaluated site could have (equal to the maximum when the search ran to the end, larger when
`max_evaluations` cut it short).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.sites import Site, check_field_stored, site_from_flat
from seuwgpu.gpu.constants import TILE
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELD_OFFSET, field_components, stored_fields

GEOMETRY = 10  # flat components 0..9: means, log_scales, quats decide the tile rectangle


@dataclass
class WorstCase:
    site: Site | None
    footprint: float  # observed maximum
    certified: float  # no site of the search space has a larger footprint
    evaluated: int  # flips rendered (incrementally)
    sites: int  # flips in the search space
    record: dict | None


def site_space(engine, fields=None, bits=None, primitives=None):
    """(primitives, flat components, bits) arrays of every single-bit site of the space. `fields`:
    None for every field the model stores (no sh_rest at SH degree 0); a named field the model
    does not store is refused (it would search nothing and report a worst flip of none)."""
    if fields is None:
        fields = stored_fields(engine.degree)
    for f in fields:
        check_field_stored(f, engine.degree)
    nb = encoding.bits_per_value(engine.precision)
    bits = np.arange(nb) if bits is None else np.asarray(bits, dtype=np.int64).reshape(-1)
    for b in dict.fromkeys(bits.tolist()):  # the first bit outside the value refused, as everywhere
        encoding.check_bit(engine.precision, b)
    prims = np.arange(engine.n) if primitives is None else np.asarray(primitives, dtype=np.int64)
    comps = np.array([FIELD_OFFSET[f] + c for f in fields for c in range(field_components(f, engine.degree))])
    p, c, b = np.meshgrid(prims, comps, bits, indexing="ij")
    return p.reshape(-1), c.reshape(-1), b.reshape(-1)


def _effective(engine, prims, comps, bits, defense, clamped: bool):
    """(clean, effective bits, guard masks) of the flips as `defense` reads them. `clamped`: with
    the in-pipeline guard's clamp applied (for the bounds); unclamped for the evaluator, which
    clamps in the pipeline itself and counts the clamps."""
    clean = engine.primitive_bits(prims)
    rows = np.arange(prims.size)
    flipped = clean[rows, comps] ^ (np.uint64(1) << bits.astype(np.uint64)).astype(clean.dtype)
    eff, gm = engine.variant_rows(prims, clean, comps, flipped, defense)
    if clamped and gm.size:
        eff = engine.drawn_rows(eff, gm[0])
    return clean, eff, gm


def _tile_pixels(r) -> np.ndarray:
    t = np.arange(r.n_tiles)
    w = np.minimum(TILE, r.width - (t % r.tiles_x) * TILE)
    h = np.minimum(TILE, r.height - (t // r.tiles_x) * TILE)
    return (w * h).astype(np.float64)


def footprint_bounds(engine, prims, comps, bits, defense: str = "none", chunk: int = 8192) -> np.ndarray:
    """[M] upper bound of each flip's footprint (dirty-tile pixels over the frame, mean over views)."""
    ev = engine.evaluator
    comp, r = ev.compositor, engine.renderer
    comp.ensure_current()
    tp = _tile_pixels(r)
    frame = float(r.width * r.height)
    out = np.empty(prims.size)
    for a in range(0, prims.size, chunk):
        sl = slice(a, a + chunk)
        p = prims[sl]
        clean, eff, _ = _effective(engine, p, comps[sl], bits[sl], defense, clamped=True)
        moved = (eff[:, :GEOMETRY] != clean[:, :GEOMETRY]).any(axis=1)
        rects = comp.clean_rects_of(p)  # [K, m, 4], a new array
        idx = np.flatnonzero(moved)
        for b in range(0, idx.size, ev.B):
            j = idx[b : b + ev.B]
            rects[:, j] = comp.project(eff[j])
        dirty = comp.dirty_tiles(p, rects)  # [m, K, T]
        same = (eff == clean).all(axis=1)  # the defense read the clean primitive back: footprint 0
        out[sl] = np.where(same, 0.0, (dirty * tp).sum(axis=2).mean(axis=1) / frame)
    return out


def worst_case(
    engine, defense: str = "none", fields=None, bits=None, primitives=None, max_evaluations: int | None = None
) -> WorstCase:
    """The single-bit flip of the space with the largest footprint under `defense` (see module);
    `fields` None: every field the model stores."""
    refusal = dfn.partner_drop_refusal("worstcase", defense, engine.precision)
    if refusal:
        raise ValueError(refusal)
    prims, comps, bts = site_space(engine, fields, bits, primitives)
    bound = footprint_bounds(engine, prims, comps, bts, defense)
    order = np.argsort(-bound, kind="stable")
    B = engine.evaluator.B
    best, best_i, best_rec, done, evaluated = -1.0, -1, None, 0, 0
    limit = prims.size if max_evaluations is None else min(prims.size, int(max_evaluations))
    while done < limit and bound[order[done]] > best:
        take = order[done : min(done + B, limit)]
        take = take[bound[take] > best]
        _, eff, gm = _effective(engine, prims[take], comps[take], bts[take], defense, clamped=False)
        m = engine.evaluator.evaluate(prims[take], eff, gm)
        evaluated += take.size
        j = int(np.argmax(m["footprint"]))
        if m["footprint"][j] > best:
            best, best_i = float(m["footprint"][j]), int(take[j])
            best_rec = {k: (v[j].item() if hasattr(v[j], "item") else v[j]) for k, v in m.items()}
        done += len(order[done : min(done + B, limit)])
    rest = bound[order[done:]]
    certified = max(best, float(rest.max()) if rest.size else best)
    site = None
    if best_i >= 0:
        site = site_from_flat(int(prims[best_i]), int(comps[best_i]), (int(bts[best_i]),), engine.degree)
    return WorstCase(site, max(best, 0.0), certified, evaluated, int(prims.size), best_rec)
