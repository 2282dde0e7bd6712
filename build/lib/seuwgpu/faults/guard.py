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
from dataclasses import dataclass

import numpy as np

from seuwgpu.faults.defenses import GUARDED_FIELDS
from seuwgpu.gpu.device import STORAGE, UNIFORM, dispatch_dims
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELD_OFFSET, FIELDS, Model, field_components

_FIELD_INDEX = {f: i for i, f in enumerate(FIELDS)}


@dataclass
class Box:
    precision: str
    lo: np.ndarray  # [ncomp] float32 (stored values)
    hi: np.ndarray

    def rows(self) -> np.ndarray:
        """u32 [ncomp, 4]: lo, hi as f32 bits, then their stored bits (what the scrub writes)."""
        out = np.zeros((self.lo.size, 4), dtype=np.uint32)
        out[:, 0] = self.lo.view(np.uint32)
        out[:, 1] = self.hi.view(np.uint32)
        out[:, 2] = encoding.to_bits(self.lo, self.precision).astype(np.uint32)
        out[:, 3] = encoding.to_bits(self.hi, self.precision).astype(np.uint32)
        return out


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


def support_box(stored: Model, precision: str) -> Box:
    """Per-component [min, max] over the finite stored values of the clean model."""
    flat = stored.flat()
    fin = np.isfinite(flat)
    lo = np.where(fin, flat, np.inf).min(axis=0)
    hi = np.where(fin, flat, -np.inf).max(axis=0)
    empty = ~np.isfinite(lo)  # a component with no finite value: box collapses to 0
    lo[empty], hi[empty] = 0.0, 0.0
    # exact stored values already; quantize anyway so bounds are representable at `precision`
    return Box(precision, encoding.quantize(lo, precision), encoding.quantize(hi, precision))


def guard_fields(variant: str = "guard") -> tuple[str, ...]:
    if variant not in GUARDED_FIELDS:
        raise ValueError(f"unknown guard variant {variant!r}; expected one of {', '.join(GUARDED_FIELDS)}")
    return GUARDED_FIELDS[variant]


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
    out[low] = np.broadcast_to(rows[:, 2].astype(bits.dtype), bits.shape)[low]
    out[high] = np.broadcast_to(rows[:, 3].astype(bits.dtype), bits.shape)[high]
    return out, low | high


def scrub(renderer, box: Box, fields, per_primitive: bool = False):
    """Rewrite the renderer's stored buffers with every guarded value clamped into the box.

    Returns clamps per field (dict), and per primitive when asked (one readback)."""
    gpu, L = renderer.gpu, renderer.layout
    mask = component_mask(fields, L.degree)
    cache = renderer.scrub_cache
    if not cache:  # buffers and bind groups made once per renderer
        cache["box"] = gpu.buffer(16 * L.ncomp, STORAGE, "scrub_box")
        cache["counts"] = gpu.buffer(4 * (8 + L.n), STORAGE, "scrub_counts")
        cache["params"] = gpu.buffer(256 * L.n_chunks, UNIFORM, "scrub_params")
        pipe = gpu.pipeline("guard")
        cache["bgs"] = [
            gpu.bind(
                pipe, {0: (cache["params"], 256 * k, 32), 1: cache["box"], 2: renderer.chunks[k], 3: cache["counts"]}
            )
            for k in range(L.n_chunks)
        ]
    counts = cache["counts"]
    gpu.write(cache["box"], box.rows())
    gpu.write(counts, np.zeros(counts.size // 4, np.uint32))
    fmt = {"fp32": 0, "fp16": 1, "bf16": 2}[L.precision]
    params = np.zeros((L.n_chunks, 64), np.uint32)
    for k in range(L.n_chunks):
        a, b = L.chunk_range(k)
        params[k, :8] = [L.plane_words, L.ncomp, b - a, fmt, mask & 0xFFFFFFFF, mask >> 32, a, 0]
    gpu.write(cache["params"], params)
    pipe = gpu.pipeline("guard")
    enc = gpu.device.create_command_encoder()
    for k in range(L.n_chunks):
        p = enc.begin_compute_pass()
        p.set_pipeline(pipe)
        p.set_bind_group(0, cache["bgs"][k])
        p.dispatch_workgroups(*dispatch_dims(-(-L.chunk_words // 256)))
        p.end()
    gpu.submit(enc)
    raw = gpu.read(counts, np.uint32, 0, 4 * (8 + (L.n if per_primitive else 0)))
    per_field = {f: int(raw[i]) for i, f in enumerate(FIELDS)}
    if per_primitive:
        return per_field, raw[8 : 8 + L.n].copy()
    return per_field
