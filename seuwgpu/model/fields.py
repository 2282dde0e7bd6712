"""The 3DGS model: six fields per primitive, and its stored (raw-bit, chunked) GPU layout.

Fields (DESIGN.md): means[3], log_scales[3] (renderer applies exp), quats[4] (w, x, y, z;
normalized at render time), opacity[1] (logit), sh_dc[3], sh_rest[R][3] with R = (deg+1)^2 - 1,
coefficient-major like gsplat (`sh_rest[i, k, c]`: coefficient k+1, channel c).

Stored layout: the model is split into chunks of `chunk_prims` primitives so that no storage
binding exceeds the device limit (a 4M-primitive degree-3 model is ~1 GB at fp32). A chunk is one
u32 buffer of component planes: plane p (the flat component index below) holds that component
for every primitive of the chunk, so neighbouring threads read neighbouring words. For 16-bit
precisions two primitives share a word (primitive 2j low half, 2j+1 high half).

Flat component order: means 0-2, log_scales 3-5, quats 6-9, opacity 10, sh_dc 11-13,
sh_rest 14 + 3*k + c.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from dataclasses import fields as dc_fields

import numpy as np

from seuwgpu.model import checks, encoding

FIELDS = ("means", "log_scales", "quats", "opacity", "sh_dc", "sh_rest")
FIELD_ALIASES = {
    "mean": "means",
    "means": "means",
    "xyz": "means",
    "log_scale": "log_scales",
    "log_scales": "log_scales",
    "scale": "log_scales",
    "scales": "log_scales",
    "quat": "quats",
    "quats": "quats",
    "rotation": "quats",
    "rot": "quats",
    "opacity": "opacity",
    "opacities": "opacity",
    "sh_dc": "sh_dc",
    "color": "sh_dc",
    "dc": "sh_dc",
    "sh_rest": "sh_rest",
    "sh": "sh_rest",
}
FIELD_OFFSET = {"means": 0, "log_scales": 3, "quats": 6, "opacity": 10, "sh_dc": 11, "sh_rest": 14}
BASE_COMPONENTS = 14


def canonical_field(name: str, what: str | None = None) -> str:
    """A field by its name or an alias (log_scale, mean, ...), as its canonical name."""
    key = str(name).strip().lower()
    if key not in FIELD_ALIASES:
        checks.one_of(name, "field", FIELDS, what)
    return FIELD_ALIASES[key]


def sh_rest_count(degree: int) -> int:
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return (degree + 1) ** 2 - 1


def field_components(field: str, degree: int) -> int:
    field = canonical_field(field)
    return {"means": 3, "log_scales": 3, "quats": 4, "opacity": 1, "sh_dc": 3, "sh_rest": 3 * sh_rest_count(degree)}[
        field
    ]


def stored_fields(degree: int, fields=FIELDS) -> list[str]:
    """The fields of `fields` a model of SH degree `degree` stores: sh_rest has no component at
    degree 0."""
    return [f for f in fields if field_components(f, degree) > 0]


def n_components(degree: int) -> int:
    return BASE_COMPONENTS + 3 * sh_rest_count(degree)


@dataclass
class Model:
    means: np.ndarray  # [N, 3]
    log_scales: np.ndarray  # [N, 3]
    quats: np.ndarray  # [N, 4] (w, x, y, z)
    opacity: np.ndarray  # [N]
    sh_dc: np.ndarray  # [N, 3]
    sh_rest: np.ndarray  # [N, R, 3]

    def __post_init__(self):
        for f in dc_fields(self):
            setattr(self, f.name, np.ascontiguousarray(getattr(self, f.name), dtype=np.float32))
        n = self.means.shape[0]
        if not (self.sh_rest.ndim == 3 and self.sh_rest.shape[0] == n and self.sh_rest.shape[2] == 3):
            self.sh_rest = self.sh_rest.reshape(n, -1, 3)  # (reshape(0, -1, 3) is ambiguous when n == 0)
        expect = {"means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity": (n,), "sh_dc": (n, 3)}
        for name, shape in expect.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"field {name} has shape {getattr(self, name).shape}, expected {shape}")
        r = self.sh_rest.shape[1]
        if r not in (0, 3, 8, 15):
            raise ValueError(f"sh_rest holds {r} coefficients per channel, which is no SH degree (0, 3, 8 or 15)")

    @property
    def n(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return {0: 0, 3: 1, 8: 2, 15: 3}[self.sh_rest.shape[1]]

    @property
    def n_components(self) -> int:
        return n_components(self.sh_degree)

    def field(self, name: str) -> np.ndarray:
        """Field as a 2-D [N, components] array (a view where possible)."""
        name = canonical_field(name)
        return getattr(self, name).reshape(self.n, -1)

    def flat(self) -> np.ndarray:
        """[N, n_components] in the flat component order."""
        return np.concatenate([self.field(f) for f in FIELDS], axis=1)

    @classmethod
    def from_flat(cls, flat: np.ndarray, degree: int) -> Model:
        flat = np.asarray(flat, dtype=np.float32)
        n = flat.shape[0]
        return cls(
            means=flat[:, 0:3],
            log_scales=flat[:, 3:6],
            quats=flat[:, 6:10],
            opacity=flat[:, 10],
            sh_dc=flat[:, 11:14],
            sh_rest=flat[:, 14:].reshape(n, sh_rest_count(degree), 3),
        )

    def copy(self) -> Model:
        return Model(**{f: getattr(self, f).copy() for f in FIELDS})

    def subset(self, index) -> Model:
        return Model(**{f: getattr(self, f)[index] for f in FIELDS})

    def sample(self, n: int, seed: int, name: str) -> Model:
        """A seeded random subset of `n` primitives, in stored order: how a trained model is cut to
        a smaller primitive count (the paper subsamples trained models for its primitive-count
        sweep). The same (n, seed, name) give the same subset; all of them when n >= self.n."""
        if n >= self.n:
            return self.copy()
        rng = np.random.default_rng([int(seed) % (1 << 63), zlib.crc32(name.encode())])
        return self.subset(np.sort(rng.choice(self.n, int(n), replace=False)))

    def quantized(self, precision: str) -> Model:
        """The values a model deployed at `precision` holds."""
        return Model(**{f: encoding.quantize(getattr(self, f), precision) for f in FIELDS})

    def bit_budget(self, precision: str) -> dict[str, int]:
        """Stored bits per field and in total (the space a uniform upset is drawn from)."""
        nb = encoding.bits_per_value(precision)
        out = {f: self.n * field_components(f, self.sh_degree) * nb for f in FIELDS}
        out["total"] = sum(out.values())
        return out


class StoredLayout:
    """Where each (primitive, component) of a model lives in the chunked u32 GPU buffers."""

    def __init__(self, n: int, degree: int, precision: str, chunk_prims: int):
        if n <= 0:
            raise ValueError("a model needs at least one primitive")
        self.n, self.degree = int(n), int(degree)
        self.precision = encoding.check_precision(precision)
        self.ncomp = n_components(degree)
        self.halves = encoding.bits_per_value(precision) == 16
        chunk_prims = int(min(chunk_prims, n + (n & 1)))
        self.chunk_prims = chunk_prims + (chunk_prims & 1)  # even, so a 16-bit pair never splits
        self.n_chunks = -(-self.n // self.chunk_prims)
        self.plane_words = self.chunk_prims // 2 if self.halves else self.chunk_prims
        self.chunk_words = self.ncomp * self.plane_words

    @staticmethod
    def max_chunk_prims(degree: int, precision: str, max_binding_bytes: int) -> int:
        per_prim = n_components(degree) * encoding.bits_per_value(precision) // 8
        c = max_binding_bytes // per_prim
        return max(2, c - (c & 1))

    def chunk_range(self, k: int) -> tuple[int, int]:
        return k * self.chunk_prims, min(self.n, (k + 1) * self.chunk_prims)

    def locate(self, prim, comp):
        """(chunk, word index in chunk, bit shift of the value within the word) - vectorised."""
        prim = np.asarray(prim, dtype=np.int64)
        comp = np.asarray(comp, dtype=np.int64)
        chunk = prim // self.chunk_prims
        j = prim % self.chunk_prims
        if self.halves:
            return chunk, comp * self.plane_words + (j >> 1), 16 * (j & 1)
        return chunk, comp * self.plane_words + j, np.zeros_like(j)

    @staticmethod
    def balanced_chunk_prims(n: int, max_chunk_prims: int) -> int:
        """The smallest even chunk size that splits n primitives into as few chunks as
        `max_chunk_prims` allows: every chunk is allocated whole, so 10M fp32 primitives at a 2 GiB
        binding take two chunks of 5M (2.4 GB), not two of 9.1M (4.3 GB)."""
        if int(n) <= 0:  # no model: StoredLayout says so
            return int(max_chunk_prims)
        n_chunks = -(-int(n) // int(max_chunk_prims))
        c = -(-int(n) // n_chunks)
        return c + (c & 1)

    # rows transposed at a time by encode: a cache-sized tile (a whole-field transpose was most of
    # the encode of a 1M-primitive model)
    ENCODE_ROWS = 16384

    def encode(self, model: Model) -> list[np.ndarray]:
        """Model -> list of u32 word arrays, one per chunk. Converted ENCODE_ROWS primitives of a
        field at a time, so the host holds the model, the words and one tile's temporaries (bf16's
        conversion peaks at 33 bytes a value: a whole-model pass would need 8x the model)."""
        if model.n != self.n or model.sh_degree != self.degree:
            raise ValueError("model does not match this layout")
        out = []
        for k in range(self.n_chunks):
            a, b = self.chunk_range(k)
            # bit planes [components, chunk_prims], packed into words by _words
            planes = np.zeros((self.ncomp, self.chunk_prims), dtype="<u2" if self.halves else "<u4")
            c = 0
            for f in FIELDS:
                values = model.field(f)
                width = values.shape[1]
                for s in range(a, b, self.ENCODE_ROWS):
                    e = min(b, s + self.ENCODE_ROWS)
                    planes[c : c + width, s - a : e - a] = encoding.to_bits(values[s:e], self.precision).T
                c += width
            out.append(self._words(planes))
        return out

    def encode_bits(self, bits: np.ndarray) -> list[np.ndarray]:
        """Stored bit patterns [N, ncomp] (uint32 or uint16) -> list of u32 chunk word arrays."""
        bits = np.asarray(bits)
        out = []
        for k in range(self.n_chunks):
            a, b = self.chunk_range(k)
            planes = np.zeros((self.ncomp, self.chunk_prims), dtype=bits.dtype)
            planes[:, : b - a] = bits[a:b].T
            out.append(self._words(planes))
        return out

    def _words(self, planes: np.ndarray) -> np.ndarray:
        """Bit planes [P, chunk_prims] (uint32 or uint16) -> their flat u32 words (P planes:
        the chunk's ncomp, or one). 16-bit values two to a word, the even primitive's in the low
        half: the little-endian u16 pairs read as u32 (no shifts, no copy of u16 planes)."""
        if self.halves:
            planes = np.ascontiguousarray(planes, dtype="<u2").view("<u4")
        return np.ascontiguousarray(planes.reshape(-1), dtype=np.uint32)

    def chunk_values(self, k: int, words: np.ndarray) -> np.ndarray:
        """Chunk k's stored values as float32 planes [components, the chunk's primitives] (at fp32
        a view of `words`)."""
        a, b = self.chunk_range(k)
        w = np.asarray(words, dtype="<u4").reshape(self.ncomp, self.plane_words)
        if not self.halves:
            return w[:, : b - a].view(np.float32)
        # a little-endian word's low half is the even primitive's value (see _words)
        return encoding.from_bits(w.view("<u2")[:, : b - a], self.precision)

    def value_tiles(self, chunks: list[np.ndarray], rows: int):
        """The stored values as [rows, components] tiles in primitive order (transposed views of
        chunk_values): a pass over the model without its decoded copy (guard.component_ranges)."""
        for k, words in enumerate(chunks):
            values = self.chunk_values(k, words)
            for s in range(0, values.shape[1], rows):
                yield values[:, s : s + rows].T

    def decode(self, chunks: list[np.ndarray]) -> Model:
        """Inverse of encode: u32 chunk words -> Model of the stored values (as float32). Works on
        the planes ([components, N], contiguous) and transposes once: decoding a 1M-primitive
        model row-major was a large share of a campaign's set-up."""
        values = np.concatenate([self.chunk_values(k, w) for k, w in enumerate(chunks)], axis=1)
        return Model.from_flat(values.T, self.degree)
