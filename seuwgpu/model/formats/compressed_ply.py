"""The compressed PLY of SuperSplat / PlayCanvas (`.compressed.ply`): chunks of 256 splats.

Read as PlayCanvas's splat-transform reads it (src/lib/readers/decompress-ply.ts): a `chunk`
element of float32 bounds (min/max of x y z, of the log-scales and, when 18 properties, of the
colours), a `vertex` element of four uint32 (packed_position 11-10-11 bits, packed_rotation
2 + 3 x 10 bits "smallest three", packed_scale 11-10-11 bits, packed_color 8-8-8-8 bits) and an
optional `sh` element of uint8 f_rest_0..K-1 (channel-major as in the INRIA PLY). Each value is
lerp(min, max, code / (2^bits - 1)) computed in float64 like the JavaScript reference and rounded
once to float32; colour -> SH DC = (c - 0.5) / C0; alpha byte -> logit (saturated bytes give
+-20 instead of +-Inf, below); SH byte b -> ((b + 0.5) / 256 - 0.5) * 8, with 0 and
255 mapping to the ends (-4, +4). rot_0..3 keep the INRIA order (w, x, y, z).

Saturated alphas (decided here, docs/models.md "Saturated opacities"): the reference decoder's
logit -log(1 / a - 1) is +Inf for a packed alpha of 1.0 (byte 255; 667 rows of PlayCanvas's
guitar.compressed.ply, 198 of biker's) and -Inf for 0.0. They are read as +-20 (quantized.py's
rule for every quantised format), which draws the same: the renderer's float32 sigmoid of 20 is
1.0 exactly, as of +Inf (a reference viewer's alpha 1, capped at 0.99 by the compositor), and a
splat at sigmoid(-20) = 2e-9 is skipped as one at 0. Keeping +Inf would instead make the model's
stored words the decoder's accident: 23 of a +Inf's 32 bit flips give NaN, where a trained
model's large logit (which 20 stands for) turns into another large or small finite value. The
rows are counted in the loader's notes ("opacity +inf in 198 rows, ..."), which a campaign's
manifest keeps (its `models`).

Written (write_compressed_ply) as splat-transform's write-compressed-ply.ts / compressed-chunk.ts
pack it, in float64: the same header (18 chunk bounds, four uint32, uchar SH), bounds = each
chunk's float32 min/max (colours: f_dc * C0 + 0.5 rounded to float32 first), code =
clamp(floor(normalised * (2^bits - 1) + 0.5)), alpha byte of sigmoid(opacity), rotation normalised
with its largest component made positive, SH byte trunc(clamp((v / 8 + 0.5) * 256, 0, 255)); the
last chunk is padded with its last splat. Two deliberate differences: the splats keep the model's
order (no Morton sort: splat i is primitive i, and a chunk is 256 consecutive primitives), and the
log-scale bounds are not clamped to +-20, so a damaged log-scale is not silently clipped.

A damaged model (quantized.py, "writing"): positions, log-scales and colours are exact at their
chunk's min and max (float32 bounds), so an upset that widens its chunk's range survives bit for
bit; the price is paid by the other 255 splats of its chunk, whose codes now span the widened range
(a position upset to 1e30 puts every neighbour at the chunk's minimum). The chunks of the rest of
the model are untouched. +-Inf becomes +-3.4e38 (a bound of Inf would decode its chunk's other
codes as NaN), NaN is refused. Opacity saturates at bytes 0/255 (read as -+20); SH rest saturates
at -+4, the format's fixed range; rotations as quantized.unit_quats.
"""

from __future__ import annotations

import os

import numpy as np

from seuwgpu.model.fields import Model
from seuwgpu.model.formats import ply
from seuwgpu.model.formats.base import ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError
from seuwgpu.model.formats.ply import PlyHeader, read_element
from seuwgpu.model.formats.quantized import (
    SATURATED_LOGIT,
    SH_C0,
    alpha_bytes,
    finite_logit,
    largest_component,
    storable,
    unorm_codes,
)

CHUNK = 256
_BOUNDS = [f"{m}_{a}" for m in ("min", "max") for a in "xyz"] + [
    f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"
]
_COLOURS = [f"{m}_{c}" for m in ("min", "max") for c in "rgb"]
_PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")


class CompressedPlyError(ModelFileError):
    """A compressed PLY that cannot be read."""


def is_compressed_ply(header: PlyHeader) -> bool:
    vertex, chunk = header.element("vertex"), header.element("chunk")
    return chunk is not None and vertex is not None and "packed_position" in vertex.names()


def _unorm(v: np.ndarray, bits: int) -> np.ndarray:
    t = (1 << bits) - 1
    return (v & t).astype(np.float64) / t


def _lerp(a, b, t):
    return a * (1.0 - t) + b * t


def saturation_notes(full: int, empty: int) -> list[str]:
    """What the loader says of packed alphas of 1.0 and 0.0 (+-Inf by the reference decoder)."""
    notes = []
    if full:
        notes.append(
            f"opacity +inf in {full} rows, from packed alpha 1.0, as the reference decoder gives: read as "
            f"+{SATURATED_LOGIT:g}, drawn the same (alpha 1, capped at 0.99)"
        )
    if empty:
        notes.append(
            f"opacity -inf in {empty} rows, from packed alpha 0.0, as the reference decoder gives: read as "
            f"-{SATURATED_LOGIT:g}, drawn the same (skipped)"
        )
    return notes


def read_with_notes(header: PlyHeader) -> tuple[Model, list[str]]:
    path = header.path
    chunk_el, vertex_el = header.element("chunk"), header.element("vertex")
    names = chunk_el.names()
    missing = [p for p in _BOUNDS if p not in names] + [p for p in _PACKED if p not in vertex_el.names()]
    if missing:
        raise CompressedPlyError(f"{path}: compressed PLY lacks required properties: {', '.join(missing)}")
    types = dict(vertex_el.props)  # numpy type strings, or "list" for a list property
    words = ("<u4", "<i4")  # bit fields of 32-bit words (int32 holds the same bits)
    wrong = [
        f"{name} ({'list' if types[name] == 'list' else np.dtype(types[name]).name})"
        for name in _PACKED
        if types[name] not in words
    ]
    if wrong:  # read as floats, shorter integers or lists they would decode to garbage
        raise CompressedPlyError(f"{path}: compressed PLY packed properties must be uint32, got {', '.join(wrong)}")
    n = vertex_el.count
    if n == 0:
        raise CompressedPlyError(f"{path}: compressed PLY holds zero splats")
    if chunk_el.count != -(-n // CHUNK):
        raise CompressedPlyError(
            f"{path}: compressed PLY has {chunk_el.count} chunks for {n} splats (expected {-(-n // CHUNK)})"
        )
    chunks = read_element(header, "chunk")
    vert = read_element(header, "vertex")
    ci = np.arange(n) // CHUNK

    def bound(name):
        return chunks[name].astype(np.float32).astype(np.float64)[ci]

    pos = vert["packed_position"].astype(np.uint32)
    means = np.stack(
        [
            _lerp(bound("min_x"), bound("max_x"), _unorm(pos >> 21, 11)),
            _lerp(bound("min_y"), bound("max_y"), _unorm(pos >> 11, 10)),
            _lerp(bound("min_z"), bound("max_z"), _unorm(pos, 11)),
        ],
        axis=1,
    )
    sc = vert["packed_scale"].astype(np.uint32)
    log_scales = np.stack(
        [
            _lerp(bound("min_scale_x"), bound("max_scale_x"), _unorm(sc >> 21, 11)),
            _lerp(bound("min_scale_y"), bound("max_scale_y"), _unorm(sc >> 11, 10)),
            _lerp(bound("min_scale_z"), bound("max_scale_z"), _unorm(sc, 11)),
        ],
        axis=1,
    )
    rot = vert["packed_rotation"].astype(np.uint32)
    norm = 1.0 / (np.sqrt(2.0) * 0.5)
    abc = np.stack([(_unorm(rot >> s, 10) - 0.5) * norm for s in (20, 10, 0)], axis=1)
    m = np.sqrt(np.maximum(0.0, 1.0 - (abc[:, 0] * abc[:, 0] + abc[:, 1] * abc[:, 1] + abc[:, 2] * abc[:, 2])))
    which = (rot >> 30).astype(np.int64)
    quats = np.empty((n, 4))
    for w in range(4):  # the largest component sits at `which`, the other three keep their order
        sel = which == w
        others = [i for i in range(4) if i != w]
        quats[np.ix_(sel, others)] = abc[sel]
        quats[sel, w] = m[sel]
    col = vert["packed_color"].astype(np.uint32)
    c = np.stack([_unorm(col >> s, 8) for s in (24, 16, 8, 0)], axis=1)
    if all(p in names for p in _COLOURS):
        for j, ch in enumerate("rgb"):
            c[:, j] = _lerp(bound(f"min_{ch}"), bound(f"max_{ch}"), c[:, j])
    with np.errstate(divide="ignore"):
        opacity = finite_logit(-np.log(1.0 / c[:, 3] - 1.0))
    saturated = (int(np.count_nonzero(c[:, 3] == 1.0)), int(np.count_nonzero(c[:, 3] == 0.0)))
    sh_rest = np.zeros((n, 0, 3))
    sh_el = header.element("sh")
    if sh_el is not None:
        k = len(sh_el.names())
        if k not in (9, 24, 45) or sh_el.count != n:
            raise CompressedPlyError(
                f"{path}: compressed PLY sh element has {k} properties x {sh_el.count} rows "
                f"(expected 9, 24 or 45 x {n})"
            )
        sh = read_element(header, "sh")
        try:
            cols = [sh[f"f_rest_{i}"] for i in range(k)]
        except ValueError:
            raise CompressedPlyError(f"{path}: compressed PLY sh element must hold f_rest_0..f_rest_{k - 1}") from None
        b = np.stack(cols, axis=1).astype(np.float64)
        v = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256.0))
        r = k // 3
        sh_rest = ((v - 0.5) * 8.0).reshape(n, 3, r).transpose(0, 2, 1)  # channel-major -> [N, R, 3]
    model = Model(
        means=means,
        log_scales=log_scales,
        quats=quats,
        opacity=opacity,
        sh_dc=(c[:, :3] - 0.5) / SH_C0,
        sh_rest=sh_rest,
    )
    return model, saturation_notes(*saturated)


def _normalise(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """compressed-chunk.ts's normalize: 0 at or below lo, 1 at or above hi, 0 for a range under 1e-5."""
    span = hi - lo
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        t = np.where(span < 1e-5, 0.0, (x - lo) / np.where(span > 0, span, 1.0))
    return np.where(x <= lo, 0.0, np.where(x >= hi, 1.0, t))


def _pack_rotation(q: np.ndarray) -> np.ndarray:
    """2 bits: the largest component (the first of equal magnitudes); 3 x 10 bits: the others, of
    the unit quaternion whose largest component is positive, times sqrt(2)/2 plus 0.5."""
    largest, negative = largest_component(q)
    q = np.where(negative[:, None], -q, q)
    out = largest.astype(np.uint32)
    for i in range(4):
        keep = largest != i
        code = unorm_codes(q[:, i] * (np.sqrt(2.0) * 0.5) + 0.5, 10)
        out = np.where(keep, (out << np.uint32(10)) | code, out)
    return out


def compressed_ply_bytes(model: Model, path: str = "<model>", comments=()) -> bytes:
    """The compressed PLY of a model (module docstring, "Written")."""
    v = storable(model, path, "compressed PLY")
    n, r = model.n, model.sh_rest.shape[1]
    chunks = -(-n // CHUNK)
    pad = np.concatenate([np.arange(n), np.full(chunks * CHUNK - n, n - 1)])  # the last splat repeated

    def bounds(x: np.ndarray):  # [n, 3] -> float32-exact min, max per chunk: [chunks, 3] each
        c = x[pad].reshape(chunks, CHUNK, 3)
        return c.min(axis=1), c.max(axis=1)

    colour = (v["sh_dc"] * SH_C0 + 0.5).astype(np.float32).astype(np.float64)
    parts = [bounds(v["means"]), bounds(v["log_scales"]), bounds(colour)]
    table = np.concatenate([np.concatenate(p, axis=1) for p in parts], axis=1).astype("<f4")  # [chunks, 18]
    ci = np.arange(n) // CHUNK

    def codes(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, bits=(11, 10, 11)):
        t = _normalise(x, lo.astype(np.float64)[ci], hi.astype(np.float64)[ci])
        return [unorm_codes(t[:, j], b) for j, b in enumerate(bits)]

    (px, py, pz), (sx, sy, sz) = codes(v["means"], *parts[0]), codes(v["log_scales"], *parts[1])
    cr, cg, cb = codes(colour, *parts[2], bits=(8, 8, 8))
    vert = np.empty((n, 4), dtype="<u4")
    vert[:, 0] = (px << 21) | (py << 11) | pz
    vert[:, 1] = _pack_rotation(v["quats"])
    vert[:, 2] = (sx << 21) | (sy << 11) | sz
    vert[:, 3] = (cr << 24) | (cg << 16) | (cb << 8) | alpha_bytes(v["opacity"])
    header = ["ply", "format binary_little_endian 1.0", "comment Generated by seuwgpu"]
    header += [f"comment {c}" for c in comments] + [f"element chunk {chunks}"]
    header += [f"property float {p}" for p in _BOUNDS + _COLOURS] + [f"element vertex {n}"]
    header += [f"property uint {p}" for p in _PACKED]
    sh = b""
    if r:
        header += [f"element sh {n}"] + [f"property uchar f_rest_{i}" for i in range(3 * r)]
        rest = v["sh_rest"].transpose(0, 2, 1).reshape(n, 3 * r)  # [N, R, 3] -> channel-major
        sh = np.clip(np.trunc((rest / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8).tobytes()
    head = ("\n".join([*header, "end_header"]) + "\n").encode("utf-8")
    return head + table.tobytes() + vert.tobytes() + sh


def write_compressed_ply(model: Model, path, up: str | None = None, **_options) -> None:
    """Write `model` as a SuperSplat/PlayCanvas compressed PLY; `up` is recorded as PLY's `comment up`."""
    spath = os.fspath(path)
    data = compressed_ply_bytes(model, spath, comments=[f"up {up}"] if up else ())
    with open(spath, "wb") as f:
        f.write(data)


def _sniff(probe: Probe) -> bool:
    """A PLY whose vertices are packed (sniffed before the plain PLY, which takes any PLY)."""
    return ply.is_ply(probe) and is_compressed_ply(ply.read_header(probe.path))


FORMAT = ModelFormat(
    name="compressed-ply",
    title="SuperSplat/PlayCanvas compressed PLY",
    suffixes=(".compressed.ply",),
    up="-y",
    sniff=_sniff,
    read=lambda path: read_with_notes(ply.read_header(path)),
    write=write_compressed_ply,
    recorded_up=ply.recorded_up,
)
