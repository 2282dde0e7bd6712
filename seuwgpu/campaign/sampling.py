"""The deterministic enumeration of a campaign's injections and their counter-based random draws.

Every injection has an id (its index in the deterministic enumeration) and a seed derived from the
master seed and that id alone, so any injection can be replayed by itself, and batching, order or
sharding never change a record. All defense arms of an injection see the same site (paired).
"""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np

from seuwgpu.campaign.spec_types import SceneSpec, Spec, as_spec
from seuwgpu.faults.sites import VALUE_MODELS, Site, model_bits, site_from_flat
from seuwgpu.model import encoding
from seuwgpu.model.fields import field_components, stored_fields


@dataclass
class Context:
    """One engine set-up: a scene at a primitive count and precision, and its injections."""

    kind: str  # "single" | "dose" | "size"
    scene_index: int
    n: int | None  # primitive count (None: as loaded)
    precision: str
    defenses: list
    first_id: int
    count: int
    cells: list = dc_field(default_factory=list)  # single/size: [(field, bit)]; dose: [k]
    per_cell: int = 0  # samples (single/size) or repeats (dose)
    sampling: str = "stratified"
    regions: tuple = ()  # sort-first partition sizes measured for single upsets
    fault: str = "bit"  # fault model (faults/sites.py FAULT_MODELS)

    def cell_of(self, local: int):
        return self.cells[local // self.per_cell], local % self.per_cell


def _cells(fields, bits, precision, fault="bit"):
    """(field, bit) strata; a fault model replacing whole values has one cell per field (bit -1)."""
    if fault in VALUE_MODELS:
        return [(f, -1) for f in fields]
    nb = encoding.bits_per_value(precision)
    use = range(nb) if bits == "all" else [b for b in bits if b < nb]
    return [(f, b) for f in fields for b in use]


def scene_fields(fields, scene: SceneSpec) -> list:
    """The fields of a section that a scene's model holds: sh_rest has no component at SH degree
    0 (spec.py refuses it named for such a model; "all" stands for the fields each model holds)."""
    return stored_fields(scene.sh_degree, fields)


def enumerate_contexts(spec: Spec | dict) -> list[Context]:
    """The campaign's contexts in id order: [single] per scene and precision, then [dose], then
    [sizes] per swept scene, primitive count and precision. `spec`: a Spec or its stored form."""
    spec = as_spec(spec)
    ctxs, nid = [], 0
    if spec.single is not None:
        t = spec.single
        for si, sc in enumerate(spec.scenes):
            for p in t.precisions:
                cells = _cells(scene_fields(t.fields, sc), t.bits, p, t.fault)
                c = Context(
                    "single",
                    si,
                    sc.n,
                    p,
                    list(t.defenses),
                    nid,
                    len(cells) * t.samples,
                    cells,
                    t.samples,
                    t.sampling,
                    tuple(t.regions),
                    t.fault,
                )
                ctxs.append(c)
                nid += c.count
    if spec.dose is not None:
        t = spec.dose
        for si, sc in enumerate(spec.scenes):
            for p in t.precisions:
                c = Context(
                    "dose",
                    si,
                    sc.n,
                    p,
                    list(t.defenses),
                    nid,
                    len(t.k) * t.repeats,
                    list(t.k),
                    t.repeats,
                )
                ctxs.append(c)
                nid += c.count
    if spec.sizes is not None:
        t = spec.sizes
        for si, n in [(si, n) for si in t.scene_indices for n in t.n]:
            for p in t.precisions:
                cells = _cells(scene_fields(t.fields, spec.scenes[si]), t.bits, p, t.fault)
                c = Context(
                    "size",
                    si,
                    n,
                    p,
                    list(t.defenses),
                    nid,
                    len(cells) * t.samples,
                    cells,
                    t.samples,
                    t.sampling,
                    tuple(t.regions),
                    t.fault,
                )
                ctxs.append(c)
                nid += c.count
    return ctxs


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser on uint64 arrays (wrapping arithmetic): a counter-based hash, so any
    injection's random numbers follow from (master seed, id) alone, vectorised over a block."""
    x = np.asarray(x, dtype=np.uint64) + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def injection_seeds(master: int, ids) -> np.ndarray:
    """Per-injection 63-bit seeds (the records' `seed` column) of a block of injection ids."""
    key = _splitmix64(np.array([master], dtype=np.uint64))[0]
    return (_splitmix64(np.asarray(ids, dtype=np.uint64) ^ key) >> np.uint64(1)).astype(np.int64)


def _stream(seeds: np.ndarray, k: int) -> np.ndarray:
    """The k-th 64-bit random number of each injection's stream."""
    return _splitmix64(seeds.astype(np.uint64) * np.uint64(0x100000001B3) + np.uint64(k))


def draw_sites(ctx: Context, local: np.ndarray, seeds: np.ndarray, n: int, degree: int):
    """Sites of a block of single-upset injections and their weights (stored bits each stands
    for). Stratified: cell local // samples, primitive and component uniform within it; uniform:
    one stored bit uniform over the whole budget. The fault model (ctx.fault) turns the drawn bit
    into the site's bits and operation (sites.model_bits, from the stream's third number).
    Returns (sites, weights)."""
    nb = encoding.bits_per_value(ctx.precision)
    local = np.asarray(local, dtype=np.int64)
    if ctx.sampling == "uniform":
        ncomp = 14 + 3 * ((degree + 1) ** 2 - 1)
        total = n * ncomp * nb
        flat = (_stream(seeds, 0) % np.uint64(total)).astype(np.int64)
        prim, rest = np.divmod(flat, ncomp * nb)
        comp, bit = np.divmod(rest, nb)
        sites = [site_from_flat(int(p), int(c), (int(b),), degree) for p, c, b in zip(prim, comp, bit)]
        if ctx.fault != "bit":
            r3 = _stream(seeds, 3)
            sites = [_with_model(s, ctx.fault, s.bits[0], ctx.precision, r) for s, r in zip(sites, r3)]
        return sites, np.full(local.size, total / (len(ctx.cells) * ctx.per_cell))
    cell = local // ctx.per_cell
    prim = (_stream(seeds, 1) % np.uint64(n)).astype(np.int64)
    r2 = _stream(seeds, 2)
    r3 = _stream(seeds, 3)
    sites, weights = [], np.empty(local.size)
    for j, c in enumerate(cell):
        field, bit = ctx.cells[c]
        nc = field_components(field, degree)
        site = Site(field, int(prim[j]), int(r2[j] % np.uint64(nc)), (int(bit),))
        sites.append(site if ctx.fault == "bit" else _with_model(site, ctx.fault, bit, ctx.precision, r3[j]))
        weights[j] = n * nc / ctx.per_cell
    return sites, weights


def _with_model(site: Site, fault: str, bit: int, precision: str, r) -> Site:
    bits, op, value = model_bits(fault, bit, precision, int(r))
    return Site(site.field, site.primitive, site.component, bits, op, value)
