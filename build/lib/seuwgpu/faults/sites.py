"""Fault sites in the stored model, and the defenses' view of a corrupted word.

A site is (field, primitive, component, bits) in the stored precision: one bit is a single-event
upset, several bits of one value a multi-bit upset. Flips are XOR masks on stored words, so
applying the same mask again restores the value exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELD_OFFSET, FIELDS, Model, canonical_field, field_components


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


def make_site(
    model_or_n, field: str, primitive: int, component: int, bits, precision: str, degree: int | None = None
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
    nc = field_components(field, degree)
    if not 0 <= int(component) < nc:
        raise ValueError(f"component {component} is out of range for field {field} (valid 0..{nc - 1})")
    return Site(field, int(primitive), int(component), bits)


def site_bit_class(site: Site, precision: str) -> str:
    classes = {encoding.bit_class(precision, b) for b in site.bits}
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
