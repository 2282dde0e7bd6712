"""The support guard: clamp stored parameters into the clean model's per-component box.

The box is the min and max of each component over the clean model's stored (decoded) values,
computed once after loading. Rule for non-finite values (shared by the WGSL guard, the in-pipeline
clamp and the numpy twin here): NaN -> lower bound (the smallest, least visible value for log-scale
and opacity), -Inf -> lower bound, +Inf -> upper bound. Values inside the box are untouched, bit
for bit, so the guard is the identity on the clean model.

Modes: `scrub` rewrites the stored GPU buffers (the memory is repaired); the in-pipeline clamp
(`Renderer.set_guard`) clamps while projecting and leaves memory untouched. Variants: "guard"
covers every field except sh_rest (45 of 59 components, inert); "guard_all" adds sh_rest;
"selective" covers log_scales and opacity only.

Clamp counts reach the host per field; `GuardMonitor` turns them into a health signal: a clean
model never clamps, so a count above the threshold raises a visible alert instead of silently
absorbing a degrading device.
"""

from __future__ import annotations

import warnings
import weakref
from dataclasses import dataclass

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.gpu.constants import PRECISION_CODE
from seuwgpu.gpu.device import STORAGE
from seuwgpu.gpu.kernel import Kernel, Struct, Uniforms
from seuwgpu.model import checks, encoding
from seuwgpu.model.fields import FIELD_OFFSET, FIELDS, Model, field_components

_FIELD_INDEX = {f: i for i, f in enumerate(FIELDS)}


@dataclass
class Box:
    precision: str
    lo: np.ndarray  # [ncomp] float32 (stored values)
    hi: np.ndarray

    def rows(self) -> np.ndarray:
        """The shaders' `Bound` records, one per component: lo, hi (f32), then their stored bits
        (what the scrub writes)."""
        bound = Struct.from_shader("guard", "Bound")
        return bound.fill(
            bound.zeros(self.lo.size),
            lo=self.lo,
            hi=self.hi,
            lo_bits=encoding.to_bits(self.lo, self.precision),
            hi_bits=encoding.to_bits(self.hi, self.precision),
        )


class GuardAlert(UserWarning):
    """The guard clamped more values than a healthy device should produce."""


class GuardMonitor:
    """Health signal from clamp counts: a clean model never clamps, so any count above
    `threshold` (default 0) per check is an alert, raised as a GuardAlert warning (visible in
    logs) and kept in `.alert`/`.message` for dashboards such as the viewer."""

    def __init__(self, threshold: int = 0):
        self.threshold = int(threshold)
        self.alert = False
        self.message = ""
        self.total = 0

    def update(self, counts: dict) -> bool:
        n = int(sum(counts.values()))
        self.total += n
        self.alert = n > self.threshold
        if self.alert:
            fields = ", ".join(f"{f}: {c}" for f, c in counts.items() if c)
            self.message = (
                f"support guard clamped {n} stored values (threshold {self.threshold}): {fields}; "
                "the model in memory is being corrupted - scrub it or reload it"
            )
            warnings.warn(self.message, GuardAlert, stacklevel=2)
        else:
            self.message = ""
        return self.alert


# rows reduced at a time by component_ranges (a cache-sized tile)
RANGE_ROWS = 65536


def model_tiles(model: Model, rows: int | None = None):
    """The model's flat values as [rows, components] tiles (each a small copy of its rows;
    RANGE_ROWS rows by default)."""
    rows = rows or RANGE_ROWS
    for s in range(0, model.n, rows):
        yield np.concatenate([model.field(f)[s : s + rows] for f in FIELDS], axis=1)


def component_ranges(tiles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(min and max over the finite values, number of non-finite values) of each flat component
    over `tiles` ([rows, components] arrays: model_tiles, or StoredLayout.value_tiles of the words
    a GPU holds); min +inf and max -inf where a component has no finite value. Tile by tile: the
    decoded flat copy and its whole-model masks were seconds of a 1M-primitive engine's set-up."""
    lo = hi = bad = None
    for tile in tiles:
        fin = np.isfinite(tile)
        t_lo = np.where(fin, tile, np.inf).min(axis=0)
        t_hi = np.where(fin, tile, -np.inf).max(axis=0)
        t_bad = tile.shape[0] - fin.sum(axis=0)
        if lo is None:
            lo, hi, bad = t_lo.astype(np.float32), t_hi.astype(np.float32), t_bad.astype(np.int64)
        else:
            np.minimum(lo, t_lo, out=lo)
            np.maximum(hi, t_hi, out=hi)
            bad += t_bad
    if lo is None:
        raise ValueError("component_ranges of no values (a model needs at least one primitive)")
    return lo, hi, bad


def stored_ranges(layout, words) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """component_ranges of the values a GPU holds (`words`: a StoredLayout's chunk words), read
    tile by tile from the words (StoredLayout.value_tiles), with no decoded copy of the model."""
    return component_ranges(layout.value_tiles(words, RANGE_ROWS))


def stored_box(layout, words, precision: str) -> Box:
    """support_box of the values a GPU holds (stored_ranges), e.g. a renderer's clean_words."""
    return support_box(None, precision, stored_ranges(layout, words))


def support_box(stored: Model | None, precision: str, ranges=None) -> Box:
    """Per-component [min, max] over the finite stored values of the clean model (`ranges`: its
    component_ranges, when the caller has them; then `stored` may be None)."""
    lo, hi, _ = component_ranges(model_tiles(stored)) if ranges is None else ranges
    lo, hi = lo.astype(np.float32), hi.astype(np.float32)  # copies: the caller's ranges stay as they were
    empty = ~np.isfinite(lo)  # a component with no finite value: box collapses to 0
    lo[empty], hi[empty] = 0.0, 0.0
    # exact stored values already; quantize anyway so bounds are representable at `precision`
    return Box(precision, encoding.quantize(lo, precision), encoding.quantize(hi, precision))


def guard_fields(variant: str = "guard") -> tuple[str, ...]:
    """The fields a guard variant (a registered defense with `guard_fields`) clamps."""
    variants = dfn.pipeline_guards()
    return variants[checks.one_of(variant, "guard variant", variants)]


def component_mask(fields, degree: int) -> int:
    """Bit mask over flat components (bit c set = component c guarded)."""
    m = 0
    for f in fields:
        off = FIELD_OFFSET[f]
        for c in range(field_components(f, degree)):
            m |= 1 << (off + c)
    return m


def clamp_values(flat: np.ndarray, box: Box, mask: int) -> tuple[np.ndarray, np.ndarray]:
    """Numpy twin of the guard: clamp [N, ncomp] values; returns (clamped, clamps per field [6])."""
    flat = np.asarray(flat, dtype=np.float32)
    out = flat.copy()
    counts = np.zeros(len(FIELDS), dtype=np.int64)
    cols = [c for c in range(flat.shape[1]) if (mask >> c) & 1]
    for c in cols:
        v = flat[:, c]
        low = np.isnan(v) | (v < box.lo[c])
        high = v > box.hi[c]
        out[low, c] = box.lo[c]
        out[high, c] = box.hi[c]
        f = max(i for i, name in enumerate(FIELDS) if c >= FIELD_OFFSET[name])
        counts[f] += int(low.sum() + high.sum())
    return out, counts


def clamp_bits(bits: np.ndarray, box: Box, mask: int) -> tuple[np.ndarray, np.ndarray]:
    """Numpy twin of the scrub shader on stored bits [N, ncomp]: every guarded value outside the
    box (or NaN) is replaced by the stored bits of the bound; everything else, NaN payloads of
    unguarded components included, is left bit for bit. Returns (new bits, clamped mask)."""
    bits = np.asarray(bits)
    vals = encoding.from_bits(bits, box.precision)
    guarded = np.array([(mask >> c) & 1 for c in range(bits.shape[1])], dtype=bool)
    with np.errstate(invalid="ignore"):
        low = guarded & (np.isnan(vals) | (vals < box.lo))
        high = guarded & (vals > box.hi)
    rows = box.rows()
    out = bits.copy()
    out[low] = np.broadcast_to(rows["lo_bits"].astype(bits.dtype), bits.shape)[low]
    out[high] = np.broadcast_to(rows["hi_bits"].astype(bits.dtype), bits.shape)[high]
    return out, low | high


def fill_chunk_params(params: Uniforms, layout, **extra):
    """One uniform slot per stored chunk with its layout (plane_words, ncomp, chunk_count, fmt,
    prim_base): the parameters every pass over the stored model shares, plus `extra` fields."""
    first, end = np.array([layout.chunk_range(k) for k in range(layout.n_chunks)]).T
    params.struct.fill(
        params.rows,
        plane_words=layout.plane_words,
        ncomp=layout.ncomp,
        chunk_count=end - first,
        fmt=PRECISION_CODE[layout.precision],
        prim_base=first,
        **extra,
    )


class Scrub:
    """guard.wgsl over one renderer's stored chunks: its box, its clamp counters (`ClampCounts`:
    per field, then per primitive) and one `GuardParams` slot per chunk. The pipeline is the
    one specialised for the stored precision; a run dispatches only the planes from the first to
    the last guarded component."""

    def __init__(self, renderer, words_per_thread: int | None = None):
        gpu, L = renderer.gpu, renderer.layout
        self.gpu, self.layout, self.chunks = gpu, L, renderer.chunks
        # CPU Vulkan pays per invocation and workgroup: long runs per thread (docs/renderer.md
        # "Measurements"); GPUs want many threads.
        self.wpt = int(words_per_thread or (128 if gpu.is_cpu else 4))
        self.kernel = Kernel(gpu, "guard", constants={"FMT": PRECISION_CODE[L.precision], "WPT": self.wpt})
        self.box = gpu.buffer(self.kernel.struct("Bound").size * L.ncomp, STORAGE, "scrub.box")
        self.layout_counts = self.kernel.struct("ClampCounts")
        self.per_prim_at = self.layout_counts.offset("per_primitive")
        self.counts = gpu.buffer(self.per_prim_at + 4 * L.n, STORAGE, "scrub.counts")
        self.params = Uniforms(gpu, self.kernel.struct("GuardParams"), L.n_chunks, "scrub.params")
        fill_chunk_params(self.params, L)

    def run(self, box: Box, mask: int, per_primitive: bool = False):
        g, L = self.gpu, self.layout
        g.write(self.box, box.rows())
        mask = int(mask)
        first, end = (mask & -mask).bit_length() - 1, mask.bit_length()  # guarded components [first, end)
        self.params.rows["mask_lo"] = mask & 0xFFFFFFFF
        self.params.rows["mask_hi"] = mask >> 32
        self.params.rows["comp_first"] = max(first, 0)
        self.params.write()
        enc = g.device.create_command_encoder()
        enc.clear_buffer(self.counts)
        threads = (end - first) * -(-L.plane_words // self.wpt) if mask else 0
        for k in range(L.n_chunks if threads else 0):
            self.kernel.dispatch(
                enc,
                params=self.params.binding(k),
                box=self.box,
                words=self.chunks[k],
                counts=self.counts,
                threads=threads,
            )
        g.submit(enc)
        raw = g.read(self.counts, np.uint8, 0, self.per_prim_at + (4 * L.n if per_primitive else 0))
        fields = raw[: self.layout_counts.size].view(self.layout_counts.dtype)["per_field"][0]
        per_field = {f: int(fields[i]) for i, f in enumerate(FIELDS)}
        if per_primitive:
            return per_field, raw[self.per_prim_at :].view(np.uint32).copy()
        return per_field


_SCRUBS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # renderer -> its Scrub


def scrub(renderer, box: Box, fields, per_primitive: bool = False):
    """Rewrite the renderer's stored buffers with every guarded value clamped into the box.

    Returns clamps per field (dict), and per primitive when asked (one readback)."""
    if renderer not in _SCRUBS:  # buffers made once per renderer
        _SCRUBS[renderer] = Scrub(renderer)
    return _SCRUBS[renderer].run(box, component_mask(fields, renderer.layout.degree), per_primitive)
