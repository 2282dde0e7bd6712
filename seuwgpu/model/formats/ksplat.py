"""mkkellogg GaussianSplats3D `.ksplat` (its SplatBuffer, version 0.1): read.

Layout (github mkkellogg/GaussianSplats3D 0.4.7, src/loaders/SplatBuffer.js), little-endian:

- a 4096-byte main header: uint8 version major (0), minor (>= 1); uint32 [1] max section count,
  [2] section count, [3] max splat count, [4] splat count; uint16 [10] compression level (0, 1,
  2); float32 [6..8] scene centre, [9] and [10] the range of 8-bit SH (0 or NaN means -1.5 and 1.5);
- one 1024-byte header per section (max section count of them): uint32 [0] splat count, [1] max
  splat count, [2] bucket size, [3] bucket count, float32 [4] bucket block size, uint16 [10]
  bucket storage bytes, uint32 [6] position quantisation range (0: the level's default,
  32767), [8] full buckets, [9] partially filled buckets, uint16 [20] SH degree (0-2);
- then per section: the partially filled buckets' lengths (uint32 each), the bucket centres
  (float32 x 3 each), and max-splat-count records: centre, scale (linear), rotation (w, x, y,
  z), colour RGBA uint8, SH. Level 0 stores float32 throughout; levels 1 and 2 store the
  centre as uint16 offsets from its bucket's centre, (u - range) * block / 2 / range, and
  scales, rotations and (level 1) SH as float16; level 2 stores SH as uint8 over the header's
  range, min + b / 255 * (max - min). Records follow their buckets: full buckets of `bucket
  size` splats first, then the partially filled ones, so the file's order is not the source's.
- SH: degree 1's 9 values are channel-major (r of coefficients 1-3, then g, then b), and
  degree 2's 15 follow, channel-major too (5 a channel), as the library's PLY parser writes
  them from f_rest.

Decoded as the library's own reader and PlayCanvas splat-transform (read-ksplat.ts) decode it,
in float64 and rounded once to float32: log_scales = log(scale) (a scale of 0, what float16
holds for scales below 2^-25, becomes the log of the smallest positive value of the stored type
instead of -Inf), sh_dc = (byte / 255 - 0.5) / C0, opacity = logit(byte / 255) (saturated bytes
become -+20, see quantized.py; splat-transform clamps to 1e-6 instead), quats as stored (the
renderer normalises). The writer quantises colour and opacity with floor(), not round(), so a
decoded colour or alpha lies up to 1/255 below the source's. Coordinates are those of the PLY
the file was made from (COLMAP-style, y down).

Written (write_ksplat) at compression level 0, the one exact level, laid out as create-ksplat.js
writes level 0 (tests/data/formats/level0_sh2.ksplat): version 0.1, one section, no buckets,
scene centre 0, the header's SH range the min and max of the stored SH; records in the model's
order (splat i is primitive i). Positions, rotations (as given: the library normalises when it
writes, the renderers when they draw; an infinite or zero one as quantized.unit_quats) and SH
(degrees 1-2, float32) are exact; scale = exp(log-scale) rounded once to float32, clamped
to the positive finite float32s as .splat's (a log-scale above 88.72 stores 3.4e38, below -103.28
the smallest subnormal); colour and alpha bytes rounded to nearest (the library floors: a file
read and written again keeps its bytes), saturating at 0 and 255. SH band 3, which the format
lacks, is dropped (an upset there shows in the PLY only). NaN is refused, +-Inf positions and SH
stored as +-3.4e38 (quantized.py, "writing").
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from seuwgpu.model.fields import Model, sh_rest_count
from seuwgpu.model.formats.base import ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError
from seuwgpu.model.formats.quantized import (
    alpha_bytes,
    byte_opacity,
    byte_sh_dc,
    colour_bytes,
    linear_scales,
    storable,
)

SUFFIXES = (".ksplat",)
HEADER_BYTES = 4096
SECTION_HEADER_BYTES = 1024
MAX_DEGREE = 2  # SH degrees 0-2: 0, 9 or 24 values a splat
# bytes of centre, scale, rotation, colour and one SH value, per compression level
LEVELS = {0: (12, 12, 16, 4, 4), 1: (6, 6, 8, 4, 2), 2: (6, 6, 8, 4, 1)}
DEFAULT_RANGE = {0: 1, 1: 32767, 2: 32767}
# the smallest positive scale each level's stored type holds: float32 and float16 subnormals
SMALLEST_SCALE = {0: 2.0**-149, 1: 2.0**-24, 2: 2.0**-24}
BUCKET_BYTES = 12
LEVEL_NOTES = {
    0: "float32, 8-bit colour and opacity",
    1: "16-bit positions in buckets, float16 scales, rotations and SH, 8-bit colour and opacity",
    2: "16-bit positions in buckets, float16 scales and rotations, 8-bit colour, opacity and SH",
}

_MAIN = np.dtype(
    [
        ("major", "u1"),
        ("minor", "u1"),
        ("unused", "u1", 2),
        ("max_sections", "<u4"),
        ("sections", "<u4"),
        ("max_splats", "<u4"),
        ("splats", "<u4"),
        ("level", "<u2"),
        ("pad", "u1", 2),
        ("centre", "<f4", 3),
        ("sh_min", "<f4"),
        ("sh_max", "<f4"),
    ]
)
_SECTION = np.dtype(
    {
        "names": ["splats", "max_splats", "bucket_size", "buckets", "block", "bucket_bytes", "range", "storage",
                  "full", "partial", "sh_degree"],
        "formats": ["<u4", "<u4", "<u4", "<u4", "<f4", "<u2", "<u4", "<u4", "<u4", "<u4", "<u2"],
        "offsets": [0, 4, 8, 12, 16, 20, 24, 28, 32, 36, 40],
        "itemsize": SECTION_HEADER_BYTES,
    }
)  # fmt: skip


class KsplatError(ModelFileError):
    """A .ksplat file that cannot be read."""


@dataclass
class KsplatInfo:
    version: str
    level: int


def _or_default(value: float, default: float) -> float:
    """JavaScript's `value || default`, how the library reads the header's SH range: 0 and NaN
    are unset (a NaN range would make every SH value NaN)."""
    return value if value and not math.isnan(value) else default


def _record(level: int, degree: int) -> np.dtype:
    centre, scale, value = ("<f4", "<f4", "<f4") if level == 0 else ("<u2", "<f2", "<f2" if level == 1 else "u1")
    fields = [("centre", centre, 3), ("scale", scale, 3), ("rot", scale, 4), ("rgba", "u1", 4)]
    if degree:
        fields.append(("sh", value, 3 * sh_rest_count(degree)))
    return np.dtype(fields)


def _layout(size: int, head: bytes):
    """(main header, section headers, the byte offset of each section) of a file of `size`
    bytes starting with `head`, or the reason why it is no .ksplat the reader can take."""
    if size < HEADER_BYTES:
        return f"{size} bytes, shorter than the 4096-byte header (truncated or not a .ksplat)"
    h = np.frombuffer(head[: _MAIN.itemsize], dtype=_MAIN)[0]
    major, minor = int(h["major"]), int(h["minor"])
    if major != 0 or minor < 1:
        return f"version {major}.{minor} (this reader takes 0.1 and later 0.x, what GaussianSplats3D writes)"
    level = int(h["level"])
    if level not in LEVELS:
        return f"compression level {level} (0, 1 or 2 expected)"
    nsec = int(h["max_sections"])
    if nsec == 0:
        return "zero sections"
    end = HEADER_BYTES + nsec * SECTION_HEADER_BYTES
    if end > size:
        return f"{nsec} section headers do not fit in its {size} bytes (truncated or not a .ksplat)"
    return h, nsec, level


def _sections(spath: str, size: int, h, nsec: int, level: int, f) -> tuple[np.ndarray, list[int]]:
    f.seek(HEADER_BYTES)
    sec = np.frombuffer(f.read(nsec * SECTION_HEADER_BYTES), dtype=_SECTION)
    bases, base = [], HEADER_BYTES + nsec * SECTION_HEADER_BYTES
    for i, s in enumerate(sec):
        deg = int(s["sh_degree"])
        if deg > MAX_DEGREE:
            raise KsplatError(f"{spath}: .ksplat section {i} has SH degree {deg} (the format holds degrees 0-2)")
        if s["splats"] > s["max_splats"]:
            raise KsplatError(
                f"{spath}: .ksplat section {i} counts {s['splats']} splats, more than its capacity {s['max_splats']}"
            )
        bases.append(base)
        base += (
            _record(level, deg).itemsize * int(s["max_splats"])
            + int(s["bucket_bytes"]) * int(s["buckets"])
            + 4 * int(s["partial"])
        )
    if base > size:
        raise KsplatError(f"{spath}: .ksplat truncated: its headers describe {base} bytes, the file has {size}")
    if base < size:
        raise KsplatError(f"{spath}: .ksplat has {size - base} bytes past the sections its headers describe")
    total = int(sec["splats"].sum(dtype=np.int64))
    if total != int(h["splats"]):
        raise KsplatError(f"{spath}: .ksplat header counts {int(h['splats'])} splats, its sections {total}")
    return sec, bases


def ksplat_problem(path) -> str | None:
    """Why a file is no .ksplat this reader takes (its header and sizes checked), or None."""
    spath = os.fspath(path)
    size = os.path.getsize(spath)
    with open(spath, "rb") as f:
        lay = _layout(size, f.read(_MAIN.itemsize))
        if isinstance(lay, str):
            return lay
        try:
            _sections(spath, size, *lay, f)
        except KsplatError as e:
            return str(e).removeprefix(f"{spath}: .ksplat ")
    return None


def looks_like_ksplat(path, head: bytes) -> bool:
    """A headerless-magic .ksplat by content: version 0.1+, a known compression level, unused
    header bytes zero, section headers whose sizes add up to the file's size exactly."""
    return len(head) >= 16 and head[0] == 0 and head[1] >= 1 and head[2:4] == b"\0\0" and ksplat_problem(path) is None


def read_ksplat(path) -> tuple[Model, KsplatInfo]:
    spath = os.fspath(path)
    size = os.path.getsize(spath)
    with open(spath, "rb") as f:
        lay = _layout(size, f.read(_MAIN.itemsize))
        if isinstance(lay, str):
            raise KsplatError(f"{spath}: not a .ksplat this reader takes: {lay}")
        h, nsec, level = lay
        sec, bases = _sections(spath, size, h, nsec, level, f)
        degree = int(sec["sh_degree"][sec["splats"] > 0].max(initial=0))
        n = int(h["splats"])
        if n == 0:
            raise KsplatError(f"{spath}: .ksplat holds zero splats")
        sh_lo = _or_default(float(h["sh_min"]), -1.5)  # the library's defaults when the header holds 0 or NaN
        sh_hi = _or_default(float(h["sh_max"]), 1.5)
        parts = []
        for i, s in enumerate(sec):
            count = int(s["splats"])
            if count == 0:
                continue
            f.seek(bases[i])
            parts.append(_decode_section(spath, i, s, level, degree, sh_lo, sh_hi, f, count))
    cat = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    scale = cat["scale"]
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.log(np.where(scale == 0, SMALLEST_SCALE[level], scale))
    model = Model(
        means=cat["means"],
        log_scales=log_scales,
        quats=cat["quats"],
        opacity=byte_opacity(cat["rgba"][:, 3]),
        sh_dc=byte_sh_dc(cat["rgba"][:, :3]),
        sh_rest=cat["sh_rest"],
    )
    return model, KsplatInfo(f"{int(h['major'])}.{int(h['minor'])}", level)


def _decode_section(spath, i, s, level, degree, sh_lo, sh_hi, f, count) -> dict[str, np.ndarray]:
    partial, nbuckets = int(s["partial"]), int(s["buckets"])
    lengths = np.frombuffer(f.read(4 * partial), dtype="<u4").astype(np.int64)
    centres = np.frombuffer(f.read(int(s["bucket_bytes"]) * nbuckets), dtype="<f4")
    deg = int(s["sh_degree"])
    record = _record(level, deg)
    rec = np.frombuffer(f.read(record.itemsize * int(s["max_splats"])), dtype=record)
    rec = rec[:count]
    if level == 0:
        means = rec["centre"].astype(np.float64)
    else:
        if int(s["bucket_bytes"]) != BUCKET_BYTES:
            raise KsplatError(
                f"{spath}: .ksplat section {i} stores {int(s['bucket_bytes'])}-byte buckets (12 expected)"
            )
        size, full = int(s["bucket_size"]), int(s["full"])
        # the bucket of each of the section's `count` splats, checked before anything is allocated:
        # the header's counts (up to 2^32 each) may describe far more splats than the file holds
        in_full = min(count, full * size)
        ends = np.cumsum(lengths)  # where each partially filled bucket's splats end, after the full ones
        if full + partial != nbuckets or in_full + (int(ends[-1]) if partial else 0) < count:
            raise KsplatError(
                f"{spath}: .ksplat section {i}'s buckets ({full} full of {size}, {partial} partial holding "
                f"{int(lengths.sum())}, {nbuckets} in all) do not hold its {count} splats"
            )
        bucket = np.concatenate(
            [
                np.arange(in_full, dtype=np.int64) // max(size, 1),
                full + np.searchsorted(ends, np.arange(count - in_full), side="right"),
            ]
        )
        rng = int(s["range"]) or DEFAULT_RANGE[level]
        step = float(s["block"]) / 2.0 / rng
        centre = centres.reshape(nbuckets, 3).astype(np.float64)[bucket]
        means = (rec["centre"].astype(np.float64) - rng) * step + centre
    sh_rest = np.zeros((count, sh_rest_count(degree), 3))
    if deg:
        v = rec["sh"].astype(np.float64)
        if level == 2:
            v = sh_lo + v / 255.0 * (sh_hi - sh_lo)
        sh_rest[:, 0:3, :] = v[:, :9].reshape(count, 3, 3).transpose(0, 2, 1)  # channel-major -> [N, k, c]
        if deg == 2:
            sh_rest[:, 3:8, :] = v[:, 9:24].reshape(count, 3, 5).transpose(0, 2, 1)
    return {
        "means": means,
        "scale": rec["scale"].astype(np.float64),
        "quats": rec["rot"].astype(np.float64),
        "rgba": rec["rgba"],
        "sh_rest": sh_rest,
    }


def ksplat_bytes(model: Model, path: str = "<model>") -> bytes:
    """The level-0 .ksplat of a model (module docstring, "Written")."""
    v = storable(model, path, "GaussianSplats3D .ksplat")
    n, degree = model.n, min(model.sh_degree, MAX_DEGREE)
    rec = np.zeros(n, dtype=_record(0, degree))
    rec["centre"] = v["means"]
    rec["scale"] = linear_scales(v["log_scales"])  # at least SMALLEST_SCALE[0]
    q = model.quats.astype(np.float64)
    odd = ~np.isfinite(q).all(axis=1) | ~q.any(axis=1)  # Inf or zero: quantized.unit_quats's rule
    rec["rot"] = np.where(odd[:, None], v["quats"], q)
    rec["rgba"][:, :3] = colour_bytes(v["sh_dc"])
    rec["rgba"][:, 3] = alpha_bytes(v["opacity"])
    if degree:  # channel-major per band: degree 1's 9 values, then degree 2's 15
        rest = v["sh_rest"]
        bands = [rest[:, 0:3, :]] + ([rest[:, 3:8, :]] if degree == 2 else [])
        rec["sh"] = np.concatenate([b.transpose(0, 2, 1).reshape(n, -1) for b in bands], axis=1)
    sh = rec["sh"] if degree else np.zeros(1, np.float32)
    main = np.zeros(1, dtype=_MAIN)
    main[0] = (0, 1, 0, 1, 1, n, n, 0, 0, 0, float(sh.min()), float(sh.max()))
    section = np.zeros(1, dtype=_SECTION)
    section[0] = (n, n, 0, 0, 0.0, 0, 0, rec.itemsize * n, 0, 0, degree)
    head = main.tobytes().ljust(HEADER_BYTES, b"\0")
    return head + section.tobytes() + rec.tobytes()


def write_ksplat(model: Model, path, up: str | None = None, **_options) -> None:
    """Write `model` as a level-0 .ksplat (turned to -y up first when `up` says otherwise)."""
    from seuwgpu.model.formats.quantized import turned_to_minus_y

    spath = os.fspath(path)
    data = ksplat_bytes(turned_to_minus_y(model, up), spath)
    with open(spath, "wb") as f:
        f.write(data)


def _sniff(probe: Probe) -> bool:
    """No magic number: a file named .ksplat must be one (or hear why not); any other file is one
    when its header's sizes add up to the file's exactly."""
    if probe.named(SUFFIXES):
        why = ksplat_problem(probe.path)
        if why:
            raise KsplatError(f"{probe.path}: not a .ksplat this reader takes: {why}")
        return True
    return looks_like_ksplat(probe.path, probe.head)


def _read(path: str) -> tuple[Model, list[str]]:
    model, info = read_ksplat(path)
    return model, [f"ksplat v{info.version}, compression level {info.level} ({LEVEL_NOTES[info.level]})"]


FORMAT = ModelFormat(
    name="ksplat",
    title="GaussianSplats3D .ksplat",
    suffixes=SUFFIXES,
    up="-y",
    sniff=_sniff,
    read=_read,
    write=write_ksplat,
)
