"""Fault sites in the stored model and the fault models that corrupt them.

A site is (field, primitive, component, bits) in the stored precision plus an operation on those
bits of the stored value:
- "flip": XOR (one bit: a single-event upset; 2-8 neighbouring bits: an adjacent multi-bit
  upset in one word, as in SRAM; any other set: a multi-bit upset);
- "stuck0" / "stuck1": the named bits read 0 / 1 (a stuck-at fault; a bit already at that value is
  masked);
- "set": the named bits take `value`'s bits ("zero": every bit 0; "random": every bit uniform).
Whatever the operation, the engine writes the difference from the clean value as an XOR mask on the
stored word, so applying the same mask again restores the value exactly.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from seuwgpu.errors import InputError
from seuwgpu.model import checks, encoding
from seuwgpu.model.fields import FIELD_OFFSET, FIELDS, Model, canonical_field, field_components, n_components

# Fault models a campaign spec or the CLI names (`fault = ...`), and what each does to the bits a
# site names (the cell's bit): see `model_bits` for the draw. The multi-cell models hit several
# stored values at once (`multi_cell_sites`): a storm draws them (an upset is then a few sites);
# a single-upset campaign, whose injection is one site, refuses them.
SITE_MODELS = ("bit", "adjacent", "burst", "stuck0", "stuck1", "random", "zero")
MULTI_CELL_MODELS = ("mcu_prim", "mcu_neighbour")
FAULT_MODELS = SITE_MODELS + MULTI_CELL_MODELS
VALUE_MODELS = ("random", "zero")  # replace the whole value: cells are per field, bit = -1
OPS = ("flip", "stuck0", "stuck1", "set")
ADJACENT_WIDTHS = (2, 3, 4)
BURST_WIDTHS = (2, 3, 4, 5, 6, 7, 8)  # "burst": an adjacent multi-bit upset in one word, 2-8 bits
# (field, bit) of the dangerous cells at fp32, where nearly every catastrophe of a single flip
# lives: the log-scales' and opacity's sign and top exponent bit (the visible-damage upsets, the
# coverage sweep's dangerous pairs)
DANGEROUS_CELLS = (("log_scales", 30), ("log_scales", 31), ("opacity", 30), ("opacity", 31))
# primitives `inject` (command line and seuwgpu.inject) tries when no primitive is named: the
# most harmful of this many, drawn with the seed
INJECT_SAMPLE = 64


def check_fault_model(name: str, what: str | None = None) -> str:
    return checks.one_of(name, "fault model", FAULT_MODELS, what)


def check_site_model(name: str, what: str | None = None) -> str:
    """A fault model one site carries (a single-upset injection); the multi-cell ones are refused
    with a line saying where they can be drawn."""
    check_fault_model(name, what)
    if name in MULTI_CELL_MODELS:
        raise InputError(
            f"{checks.prefix(what)}fault model {name!r} hits several stored values at once: a storm draws "
            f"it (seuwgpu storm --fault), a single-upset injection carries one of {', '.join(SITE_MODELS)}"
        )
    return name


@dataclass(frozen=True)
class Site:
    field: str
    primitive: int
    component: int
    bits: tuple[int, ...]
    op: str = "flip"  # see OPS
    value: int = 0  # the stored pattern written by op "set" (only its `bits` are used)

    @property
    def bit(self) -> int:
        return self.bits[0] if len(self.bits) == 1 else -1

    @property
    def record_bit(self) -> int:
        """The `bit` column of records: the bit, or an adjacent burst's top bit (its stratum; up to
        max(BURST_WIDTHS) bits); -1 for other multi-bit and whole-value faults."""
        if len(self.bits) == 1:
            return self.bits[0]
        b = sorted(self.bits)
        return b[-1] if self.op == "flip" and b[-1] - b[0] == len(b) - 1 and len(b) <= BURST_WIDTHS[-1] else -1

    def flat_component(self) -> int:
        return FIELD_OFFSET[self.field] + self.component


def check_field_stored(field: str, degree: int) -> int:
    """The components of `field` in a model of SH degree `degree`; a field the model does not
    store (sh_rest at degree 0) is refused with a ValueError saying so."""
    nc = field_components(field, degree)
    if nc == 0:
        raise ValueError(
            f"field {field} is not stored in this model: it has no higher-order SH (SH degree {degree}); "
            "its fields are means, log_scales, quats, opacity and sh_dc"
        )
    return nc


def make_site(
    model_or_n,
    field: str,
    primitive: int,
    component: int,
    bits,
    precision: str,
    degree: int | None = None,
    op: str = "flip",
    value: int = 0,
) -> Site:
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
        encoding.check_bit(precision, b)
    if len(set(bits)) != len(bits):
        raise ValueError(f"bits {bits} repeat a bit")
    if not 0 <= int(primitive) < n:
        raise ValueError(f"primitive {primitive} is out of range (model has {n} primitives, valid 0..{n - 1})")
    nc = check_field_stored(field, degree)
    if not 0 <= int(component) < nc:
        raise ValueError(f"component {component} is out of range for field {field} (valid 0..{nc - 1})")
    if op not in OPS:
        raise ValueError(f"unknown fault operation {op!r}; expected one of {', '.join(OPS)}")
    return Site(field, int(primitive), int(component), bits, op, int(value))


def fault_name(site: Site, precision: str) -> str:
    """The fault model of a site, as records name it (FAULT_MODELS, or "multi" for several
    non-neighbouring flipped bits): neighbouring bits are "adjacent" up to max(ADJACENT_WIDTHS)
    bits, "burst" above (a burst campaign's 2-4-bit draws are adjacent ones)."""
    if site.op == "set":
        return "zero" if (site.value & mask_of(site.bits)) == 0 else "random"
    if site.op != "flip":
        return site.op
    if len(site.bits) == 1:
        return "bit"
    if site.record_bit < 0:
        return "multi"
    return "adjacent" if len(site.bits) <= ADJACENT_WIDTHS[-1] else "burst"


def site_bit_class(site: Site, precision: str) -> str:
    return _bit_class(site.op, tuple(site.bits), precision)


@functools.lru_cache(maxsize=4096)
def _bit_class(op: str, bits: tuple, precision: str) -> str:
    """Memoised: a campaign's records name the class of a few dozen (op, bits), once per site."""
    if op == "set" and len(bits) == encoding.bits_per_value(precision):
        return "value"
    classes = {encoding.bit_class(precision, b) for b in bits}
    return classes.pop() if len(classes) == 1 else "mixed"


def mask_of(bits) -> int:
    m = 0
    for b in bits:
        m |= 1 << int(b)
    return m


def corrupt_bits(clean, ops, masks, values) -> np.ndarray:
    """Stored patterns `clean` after per-element operations (OPS names) on the bits of `masks`;
    same dtype as `clean`. The twin of every fault model (the engine XORs the difference)."""
    c = np.asarray(clean)
    dt = c.dtype
    c = c.astype(np.uint64)
    ops = np.broadcast_to(np.asarray(ops), c.shape)
    m = np.broadcast_to(np.asarray(masks, dtype=np.uint64), c.shape)
    v = np.broadcast_to(np.asarray(values, dtype=np.uint64), c.shape)
    unknown = set(np.unique(ops)) - set(OPS)
    if unknown:
        raise ValueError(f"unknown fault operation(s) {sorted(unknown)}; expected one of {', '.join(OPS)}")
    out = np.select(
        [ops == "flip", ops == "stuck0", ops == "stuck1"],
        [c ^ m, c & ~m, c | m],
        (c & ~m) | (v & m),
    )
    return out.astype(dt)


def apply_sites(clean: np.ndarray, sites: list[Site]) -> np.ndarray:
    """`clean` (stored patterns, one per site) after each site's fault; sites hitting one value
    are composed by the caller in order (engine: per value)."""
    return corrupt_bits(
        clean,
        np.array([s.op for s in sites]),
        np.array([mask_of(s.bits) for s in sites], dtype=np.uint64),
        np.array([s.value for s in sites], dtype=np.uint64),
    )


def model_bits(model: str, bit: int, precision: str, r: int) -> tuple[tuple[int, ...], str, int]:
    """(bits, op, value) of one fault of `model` anchored at the cell's `bit`, from one 64-bit
    random number `r` (adjacent: width ADJACENT_WIDTHS[r % 3], burst: BURST_WIDTHS[r % 7], the
    burst's top bit is `bit`, moved up to fit in the value at the lowest bits; random: the value's
    bits are r's low bits). A multi-cell model's bits in each value it hits are the cell's bit."""
    nb = encoding.bits_per_value(precision)
    if model in VALUE_MODELS:
        allbits = tuple(range(nb))
        return allbits, "set", (int(r) & ((1 << nb) - 1)) if model == "random" else 0
    if model in ("adjacent", "burst"):
        widths = ADJACENT_WIDTHS if model == "adjacent" else BURST_WIDTHS
        w = widths[int(r) % len(widths)]
        start = max(0, int(bit) - w + 1)
        return tuple(range(start, start + w)), "flip", 0
    if model in ("stuck0", "stuck1"):
        return (int(bit),), model, 0
    check_fault_model(model)
    return (int(bit),), "flip", 0


def neighbour_primitive(primitive: int, n: int, precision: str) -> int:
    """The primitive whose value of the same component sits in the next u32 word of the device's
    planar layout (model/layout.py: component c of primitive j at word c * plane + j, two 16-bit
    values a word): j + 1 at fp32, j + 2 at fp16/bf16; the previous word's at the end."""
    step = 32 // encoding.bits_per_value(precision)
    q = int(primitive) + step
    return q if q < n else max(int(primitive) - step, 0)


def multi_cell_sites(site: Site, model: str, n: int, degree: int, precision: str, r: int) -> list[Site]:
    """The sites of one multi-cell upset anchored at `site` (its bits flip in every value hit):
    mcu_prim also flips them in another value of the same primitive (component drawn from `r`,
    uniform over the others: a layout that keeps a primitive's values together); mcu_neighbour in
    the same component of the primitive in the neighbouring word (`neighbour_primitive`). Other
    models: [site]."""
    if model == "mcu_prim":
        ncomp = n_components(degree)
        other = (site.flat_component() + 1 + int(r) % (ncomp - 1)) % ncomp
        partner = site_from_flat(site.primitive, other, site.bits, degree)
        return [site, Site(partner.field, partner.primitive, partner.component, site.bits, site.op, site.value)]
    if model == "mcu_neighbour":
        q = neighbour_primitive(site.primitive, n, precision)
        return [site] if q == site.primitive else [site, Site(site.field, q, site.component, site.bits, site.op)]
    check_fault_model(model)
    return [site]


def uniform_upsets(model: Model, precision: str, k: int, rng: np.random.Generator) -> list[Site]:
    """k distinct single-bit upsets drawn uniformly over the whole stored bit budget (all six
    fields), without replacement."""
    return draw_uniform_sites(model.n, model.sh_degree, precision, k, rng)


def draw_uniform_sites(n: int, degree: int, precision: str, k: int, rng: np.random.Generator) -> list[Site]:
    """k distinct stored bits of an n-primitive model, uniform over its bit budget (the dose
    campaign's draw: a function of the generator's state alone)."""
    nb = encoding.bits_per_value(precision)
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
