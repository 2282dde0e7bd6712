"""Niantic SPZ (`.spz`): read versions 1-4, write versions 2 and 3.

Read from Niantic's reference library (github nianticlabs/spz, src/cc/load-spz.cc,
splat-utils.h, splat-types.h); the decoding below repeats its float32 arithmetic step by step,
so a file decodes to the same float32 values as `spz::loadSpz` with default options:

- Versions 1-3: one gzip stream holding a 16-byte header (magic 0x5053474e "NGSP", version,
  point count, SH degree, fractional bits, flags, reserved) and then planes: positions,
  alphas, colours, scales, rotations, SH. Version 4: a plain 32-byte header (numStreams and the
  byte offset of a table of contents), then per plane one zstd frame (read with zstandard).
- positions: 24-bit two's complement fixed point, `fractional bits` below the point (version
  1: float16). scales: log-scale = byte / 16 - 10. alphas: logit(byte / 255). colours: SH DC =
  (byte / 255 - 0.5) / 0.15. SH rest: (byte - 128) / 128, coefficient-major with the channel
  innermost (the same layout as Model.sh_rest).
- rotations: version <= 2 stores x, y, z as byte / 127.5 - 1 and w = sqrt(1 - |xyz|^2) >= 0;
  version >= 3 the "smallest three" of the quaternion in 32 bits (2 bits: the index of the
  largest component, 3 x (sign + 9-bit magnitude / 511 * sqrt(1/2))).
- Coordinates stay in SPZ's own frame, RUB (x right, y up, z back), as the reference library
  returns them by default (no conversion); the orbit framing of such a model uses +y as up.
- Differences, on purpose: saturated alpha bytes become +-20 instead of +-Inf (see quantized.py);
  SH degree 4 (version 3+) keeps its first three bands, with a warning (the renderer stops at 3);
  extensions (flag 0x2) are skipped with a warning, like a reference built without them.

Writing follows the reference packer (`packGaussians`, from = UNSPECIFIED: no axis change) with
8 bits for every SH band (the reference defaults of 5 and 4 bits throw away information that
the reader does not need), as version 3 by default (gzip; every SPZ reader since 2025 opens it)
or version 2 (`version=2`, first-three quaternions). Values outside what SPZ can hold (positions
beyond +-2048 at 12 fractional bits, non-finite values) raise ModelFileError.
"""

from __future__ import annotations

import gzip
import io
import os
import struct
import warnings
import zlib

import numpy as np
import zstandard

from seuwgpu.model.budget import check_model
from seuwgpu.model.fields import Model
from seuwgpu.model.formats.base import ANTIALIASED_NOTE, ModelFormat
from seuwgpu.model.formats.errors import ModelFileError
from seuwgpu.model.formats.quantized import finite_logit, largest_component, round_half_away, to_u8
from seuwgpu.model.sh import rotate_model, rotation_to_y

MAGIC = 0x5053474E  # "NGSP" little-endian
COLOR_SCALE = np.float32(0.15)
SQRT1_2 = np.float32(0.707106781186547524401)
FLAG_ANTIALIASED = 0x1
FLAG_EXTENSIONS = 0x2
SH_DIM = {0: 0, 1: 3, 2: 8, 3: 15, 4: 24}
F32 = np.float32


class SpzError(ModelFileError):
    """An SPZ file that cannot be read or written."""


def is_spz(head: bytes) -> bool:
    """SPZ by content: a gzip stream (checked further when read) or the version-4 NGSP header."""
    return head[:2] == b"\x1f\x8b" or (len(head) >= 4 and struct.unpack("<I", head[:4])[0] == MAGIC)


# ---------------------------------------------------------------------------------------- reading


def _tables():
    """Byte -> float32 lookup tables, each computed with the reference's float32 operations."""
    b = np.arange(256, dtype=F32)
    scale = b / F32(16.0) - F32(10.0)
    x = b / F32(255.0)
    with np.errstate(divide="ignore"):
        # std::log(x / (1 - x)) in float32; the float32 quotient's log is taken in float64 and
        # rounded once (matches glibc's logf on all 256 codes; checked against the reference)
        alpha = np.log((x / (F32(1.0) - x)).astype(np.float64)).astype(F32)
    color = ((b / F32(255.0)) - F32(0.5)) / COLOR_SCALE
    sh = (b - F32(128.0)) / F32(128.0)
    return scale, alpha, color, sh


SCALE_TABLE, ALPHA_TABLE, COLOR_TABLE, SH_TABLE = _tables()


def _quats_first_three(r: np.ndarray) -> np.ndarray:
    xyz = r.astype(F32) * (F32(1.0) / F32(127.5)) + F32(-1.0)
    sq = (xyz[:, 0] * xyz[:, 0] + xyz[:, 1] * xyz[:, 1]) + xyz[:, 2] * xyz[:, 2]
    w = np.sqrt(np.maximum(F32(0.0), F32(1.0) - sq))
    return np.concatenate([w[:, None], xyz], axis=1)  # (w, x, y, z)


def _quats_smallest_three(r: np.ndarray) -> np.ndarray:
    comp = r.astype(np.uint32) @ np.array([1, 1 << 8, 1 << 16, 1 << 24], dtype=np.uint32)
    largest = (comp >> 30).astype(np.int64)
    xyzw = np.empty((len(comp), 4), dtype=F32)
    sum_sq = np.zeros(len(comp), dtype=F32)
    rest = comp.copy()
    for i in (3, 2, 1, 0):  # the reference unpacks from the last component down
        skip = largest == i
        mag = (rest & 511).astype(F32)
        neg = ((rest >> 9) & 1).astype(bool)
        v = SQRT1_2 * mag / F32(511.0)
        v = np.where(neg, -v, v)
        xyzw[:, i] = np.where(skip, F32(0.0), v)
        sum_sq = np.where(skip, sum_sq, sum_sq + v * v)
        rest = np.where(skip, rest, rest >> 10)
    xyzw[np.arange(len(comp)), largest] = np.sqrt(F32(1.0) - sum_sq)
    return xyzw[:, [3, 0, 1, 2]]  # (w, x, y, z)


class SpzInfo:
    """What the header says: version, SH degree, fractional bits and flags."""

    def __init__(self, version: int, n: int, degree: int, fractional_bits: int, flags: int):
        self.version, self.n, self.degree, self.fractional_bits, self.flags = version, n, degree, fractional_bits, flags

    @property
    def antialiased(self) -> bool:
        return bool(self.flags & FLAG_ANTIALIASED)


TAIL_COUNTED = 1 << 20  # bytes after the planes a legacy stream is inflated for (to count them)


def _planes_legacy(path: str, data: bytes) -> tuple[SpzInfo, dict[str, bytes]]:
    """The header and planes of a gzip SPZ, inflated as far as they go and no further: the
    header first, the point count checked against host memory, then the planes it sizes (a small
    file can inflate to gigabytes; whole-stream decompression did that before any check)."""
    stream = gzip.GzipFile(fileobj=io.BytesIO(data))
    try:
        raw = stream.read(16)
        magic = struct.unpack("<I", raw[:4])[0] if len(raw) >= 4 else None  # the magic first: any gzip file gets here
        if magic != MAGIC:
            found = f"magic {magic:#010x}" if magic is not None else f"{len(raw)} bytes, no magic"
            raise SpzError(f"{path}: gzip file that is not SPZ ({found}, expected {MAGIC:#010x} 'NGSP')")
        if len(raw) < 16:
            raise SpzError(f"{path}: SPZ stream too short for its 16-byte header ({len(raw)} bytes)")
        _, version, n, degree, fbits, flags, _ = struct.unpack("<IIIBBBB", raw[:16])
        if not 1 <= version <= 3:
            raise SpzError(f"{path}: SPZ version {version} in a gzip stream is not supported (expected 1, 2 or 3)")
        info = _check_info(path, SpzInfo(version, n, degree, fbits, flags))
        check_model(n, degree, what=f"{path}: SPZ point count", use="read and render")
        sizes = _plane_sizes(info)
        need = 16 + sum(sizes.values())
        body = stream.read(need - 16)
        if 16 + len(body) < need:
            raise SpzError(
                f"{path}: truncated SPZ data: {n} Gaussians at SH degree {degree} need {need} bytes, "
                f"the stream has {16 + len(body)}"
            )
        tail = len(stream.read(TAIL_COUNTED))
        more = tail == TAIL_COUNTED and len(stream.read(1)) > 0
    except (OSError, EOFError, zlib.error) as e:
        raise SpzError(f"{path}: not a readable SPZ file: the gzip stream is corrupt or truncated ({e})") from None
    planes, off = {}, 0
    for name, size in sizes.items():
        planes[name] = body[off : off + size]
        off += size
    if info.flags & FLAG_EXTENSIONS:
        warnings.warn(f"{path}: SPZ extensions skipped (they may change how the data was packed)")
    elif tail:  # read as Niantic's reader reads it, but not without a word
        over = "over " if more else ""
        warnings.warn(f"{path}: {over}{tail} bytes after the SPZ data ignored (no extensions flagged)")
    return info, planes


def _planes_v4(path: str, data: bytes) -> tuple[SpzInfo, dict[str, bytes]]:
    if len(data) < 32:
        raise SpzError(f"{path}: SPZ file too short for its 32-byte header ({len(data)} bytes)")
    magic, version, n, degree, fbits, flags, nstreams, toc = struct.unpack("<IIIBBBBI", data[:20])
    if version < 4:
        raise SpzError(f"{path}: uncompressed SPZ header with version {version} (versions below 4 are gzip streams)")
    if version > 4:
        raise SpzError(f"{path}: SPZ version {version} is newer than this reader (1-4)")
    info = _check_info(path, SpzInfo(version, n, degree, fbits, flags))
    check_model(n, degree, what=f"{path}: SPZ point count", use="read and render")
    sizes = {k: v for k, v in _plane_sizes(info).items() if v}
    if nstreams != len(sizes) or toc < 32 or toc + 16 * nstreams > len(data):
        raise SpzError(f"{path}: corrupt SPZ v4 table of contents ({nstreams} streams at byte {toc})")
    planes, off = {}, toc + 16 * nstreams
    dctx = zstandard.ZstdDecompressor()
    for i, (name, size) in enumerate(sizes.items()):
        csize, usize = struct.unpack("<QQ", data[toc + 16 * i : toc + 16 * i + 16])
        if usize != size or off + csize > len(data):
            raise SpzError(f"{path}: corrupt SPZ v4 stream {i} ({name}): sizes do not match the header")
        frame = data[off : off + csize]
        try:
            # zstandard allocates what a frame declares, whatever max_output_size says
            declared = zstandard.get_frame_parameters(frame).content_size
            if declared not in (size, zstandard.CONTENTSIZE_UNKNOWN):
                raise SpzError(
                    f"{path}: corrupt SPZ v4 stream {i} ({name}): its frame declares {declared} bytes, expected {size}"
                )
            planes[name] = dctx.decompress(frame, max_output_size=size)
        except zstandard.ZstdError as e:
            raise SpzError(f"{path}: corrupt SPZ v4 stream {i} ({name}): {e}") from None
        if len(planes[name]) != size:
            raise SpzError(f"{path}: SPZ v4 stream {i} ({name}) holds {len(planes[name])} bytes, expected {size}")
        off += csize
    planes.setdefault("sh", b"")
    if info.flags & FLAG_EXTENSIONS:
        warnings.warn(f"{path}: SPZ extensions skipped (they may change how the data was packed)")
    return info, planes


def _check_info(path: str, info: SpzInfo) -> SpzInfo:
    if info.n == 0:
        raise SpzError(f"{path}: SPZ file holds zero Gaussians")
    if info.degree not in SH_DIM:
        raise SpzError(f"{path}: SPZ SH degree {info.degree} is not supported (0-4)")
    if info.version >= 2 and not 0 <= info.fractional_bits <= 23:
        raise SpzError(f"{path}: SPZ fractional bits {info.fractional_bits} out of range (0-23)")
    return info


def _plane_sizes(info: SpzInfo) -> dict[str, int]:
    n = info.n
    return {
        "positions": n * 3 * (2 if info.version == 1 else 3),
        "alphas": n,
        "colors": n * 3,
        "scales": n * 3,
        "rotations": n * (4 if info.version >= 3 else 3),
        "sh": n * SH_DIM[info.degree] * 3,
    }


def read_spz(path) -> tuple[Model, SpzInfo]:
    """Decode an SPZ file (versions 1-4) into a Model and its header info."""
    spath = os.fspath(path)
    with open(spath, "rb") as f:
        return decode_spz(f.read(), spath)


def decode_spz(data: bytes, spath: str = "<bytes>") -> tuple[Model, SpzInfo]:
    """Decode the bytes of an SPZ file (versions 1-4)."""
    if data[:2] == b"\x1f\x8b":
        info, planes = _planes_legacy(spath, data)
    elif len(data) >= 4 and struct.unpack("<I", data[:4])[0] == MAGIC:
        info, planes = _planes_v4(spath, data)
    else:
        raise SpzError(f"{spath}: not an SPZ file (neither a gzip stream nor an NGSP header)")
    n = info.n
    u8 = {k: np.frombuffer(v, dtype=np.uint8) for k, v in planes.items()}
    if info.version == 1:
        means = np.frombuffer(planes["positions"], dtype="<f2").astype(F32).reshape(n, 3)
    else:
        p = u8["positions"].reshape(n * 3, 3).astype(np.int32)
        fixed = p[:, 0] | (p[:, 1] << 8) | (p[:, 2] << 16)
        fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)  # sign extension
        means = (fixed.astype(F32) * F32(1.0 / (1 << info.fractional_bits))).reshape(n, 3)
    rot = u8["rotations"].reshape(n, -1)
    quats = _quats_smallest_three(rot) if info.version >= 3 else _quats_first_three(rot)
    dim = SH_DIM[info.degree]
    sh = SH_TABLE[u8["sh"]].reshape(n, dim, 3)
    if info.degree == 4:
        warnings.warn(f"{spath}: SH degree 4 reduced to degree 3 (the renderer evaluates degrees 0-3)")
        sh = sh[:, :15]
    model = Model(
        means=means,
        log_scales=SCALE_TABLE[u8["scales"]].reshape(n, 3),
        quats=quats,
        opacity=finite_logit(ALPHA_TABLE[u8["alphas"]]),
        sh_dc=COLOR_TABLE[u8["colors"]].reshape(n, 3),
        sh_rest=sh,
    )
    return model, info


# ---------------------------------------------------------------------------------------- writing


def pack_spz(model: Model, version: int = 3, fractional_bits: int = 12, antialiased: bool = False, path="") -> bytes:
    """The uncompressed SPZ stream (16-byte header + planes) of a model, as the reference packs it."""
    if version not in (2, 3):
        raise SpzError(f"{path}: SPZ version {version} cannot be written (2 or 3)")
    bad = [
        f
        for f in ("means", "log_scales", "quats", "opacity", "sh_dc", "sh_rest")
        if not np.isfinite(getattr(model, f)).all()
    ]
    if bad:
        raise SpzError(f"{path}: SPZ cannot store non-finite values (found in {', '.join(bad)})")
    n = model.n
    scale = F32(1 << fractional_bits)
    fixed = round_half_away(model.means.astype(F32) * scale)
    limit = 1 << 23
    if (np.abs(fixed) >= limit).any():
        raise SpzError(
            f"{path}: positions beyond +-{limit / float(scale):g} do not fit SPZ's 24-bit fixed point "
            f"at {fractional_bits} fractional bits"
        )
    fixed = fixed.astype(np.int64).reshape(-1) & 0xFFFFFF
    positions = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, fixed >> 16], axis=1).astype(np.uint8)
    with np.errstate(over="ignore"):
        # sigmoid in float32 (1 / (1 + expf(-x))); expf taken as the correctly rounded float64 exp
        e = np.exp(-model.opacity.astype(np.float64)).astype(F32)
        alphas = to_u8((F32(1.0) / (F32(1.0) + e)) * F32(255.0))
    colors = to_u8(model.sh_dc * (COLOR_SCALE * F32(255.0)) + (F32(0.5) * F32(255.0)))
    scales = to_u8((model.log_scales + F32(10.0)) * F32(16.0))
    q = model.quats[:, [1, 2, 3, 0]].astype(F32)  # the reference's x, y, z, w
    norm = np.sqrt(((q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1]) + q[:, 2] * q[:, 2]) + q[:, 3] * q[:, 3])
    with np.errstate(invalid="ignore", divide="ignore"):
        q = q / norm[:, None]
    rotations = _pack_smallest_three(q) if version >= 3 else _pack_first_three(q)
    sh = np.clip(round_half_away(model.sh_rest.astype(F32) * F32(128.0)) + 128.0, 0, 255).astype(np.uint8)
    flags = FLAG_ANTIALIASED if antialiased else 0
    header = struct.pack("<IIIBBBB", MAGIC, version, n, model.sh_degree, fractional_bits, flags, 0)
    return b"".join(
        [
            header,
            positions.tobytes(),
            alphas.tobytes(),
            colors.tobytes(),
            scales.tobytes(),
            rotations.tobytes(),
            sh.tobytes(),
        ]
    )


def _pack_first_three(q: np.ndarray) -> np.ndarray:
    s = np.where(q[:, 3] < 0, F32(-127.5), F32(127.5))[:, None]
    return to_u8(q[:, :3] * s + F32(127.5))


def _pack_smallest_three(q: np.ndarray) -> np.ndarray:
    a = np.abs(q)
    largest, negate = largest_component(q)
    comp = largest.astype(np.uint32)
    for i in range(4):
        keep = largest != i
        negbit = ((q[:, i] < 0) ^ negate).astype(np.uint32)
        # (uint32)(float(511) * (fabs(q) / sqrt1_2) + 0.5f): truncation of a non-negative float
        mag = (F32(511.0) * (a[:, i] / SQRT1_2) + F32(0.5)).astype(np.uint32)
        comp = np.where(keep, (comp << np.uint32(10)) | (negbit << np.uint32(9)) | mag, comp)
    return comp.astype("<u4").view(np.uint8).reshape(len(q), 4)


def spz_values(model: Model, version: int = 3) -> Model:
    """The values `model` holds once stored as SPZ and read back (quantised like a real export)."""
    return decode_spz(gzip.compress(pack_spz(model, version=version), mtime=0))[0]


def save_spz(model: Model, path, version: int = 3, antialiased: bool = False) -> None:
    """Write `model` as a gzip SPZ file (version 3 by default, or 2)."""
    spath = os.fspath(path)
    if not isinstance(model, Model):
        raise TypeError(f"save_spz expects a Model, got {type(model).__name__}")
    raw = pack_spz(model, version=version, antialiased=antialiased, path=spath)
    with open(spath, "wb") as f:
        f.write(gzip.compress(raw, compresslevel=6, mtime=0))


# ---------------------------------------------------------------------------------- the format


def _read(path: str) -> tuple[Model, list[str]]:
    model, info = read_spz(path)
    return model, [f"SPZ version {info.version}"] + ([ANTIALIASED_NOTE] if info.antialiased else [])


def _write(model: Model, path: str, up: str | None = None, version: int = 3, antialiased: bool = False) -> None:
    """SPZ has no up field and its frame is y-up (RUB): a model whose up is another axis is turned
    to +y first (positions, orientations and SH together), so that it stands upright in every viewer."""
    if up not in (None, "+y"):
        model = rotate_model(model, rotation_to_y(up))
    save_spz(model, path, version=version, antialiased=antialiased)


FORMAT = ModelFormat(
    name="spz",
    title="Niantic SPZ",
    suffixes=(".spz",),
    up="+y",
    sniff=lambda probe: is_spz(probe.head),
    read=_read,
    write=_write,
)
