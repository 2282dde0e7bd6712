"""PlayCanvas SOG (`.sog`, or an unbundled `meta.json` next to its WebP images): read version 2.

Layout (github playcanvas/splat-transform 3.7.0: src/lib/writers/write-sog.ts writes it,
src/lib/readers/read-sog.ts reads it): a zip (`.sog`) or a folder holding `meta.json` and
lossless WebP images of W x H texels, texel i (row-major) holding splat i:

- `meta.json`: {"version": 2, "count": N, "model"?: "antialiased" | "2dgs", "means": {"mins",
  "maxs", "files": [low, high]}, "scales": {"codebook", "files"}, "quats": {"files"}, "sh0":
  {"codebook", "files"}, "shN"?: {"count", "bands", "codebook", "files": [centroids, labels]}}.
- means: 16 bits per axis (low byte in the first image, high in the second) over [min, max] of
  the log-transformed position, v = min + (max - min) * u / 65535, x = sign(v) (exp|v| - 1).
- quats: "smallest three" in 8 bits: RGB = the three other components in (w, x, y, z) order,
  (b / 255 * 2 - 1) / sqrt(2); A = 252 + the index of the largest, which is sqrt(1 - sum of
  the others' squares) >= 0 (any other A: the identity, as the reference decodes it).
- scales (log-scales) and sh0 (SH DC): an index into a 256-entry codebook per component; sh0's
  A is the opacity, sigmoid(opacity) * 255 (truncated by the writer).
- shN: a 16-bit palette label per splat (R low, G high); the centroids image holds 64 palette
  entries a row, `coefficients` texels each, whose R, G, B index a 256-entry codebook (one
  coefficient of the red, green, blue channel).

Decoded as read-sog.ts decodes it, in float64 and rounded once to float32, with the one
deliberate difference of every quantised reader here: an alpha byte of 0 or 255 gives a logit of
-+20 (quantized.py), where splat-transform clamps to 1e-6 (-+13.8). Coordinates are those of the
PLY the file was made from (splat-transform's PLY frame; COLMAP-style, y down). Version 1 (a
meta.json without "version", written by splat-transform before 0.7, September 2025) is refused
with a message saying how to convert it. Written by sog_write.py (what is exact, what is
re-quantised and what becomes of a corrupted value: its docstring).
"""

from __future__ import annotations

import io
import json
import math
import os
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seuwgpu.model.budget import check_model
from seuwgpu.model.fields import Model, sh_rest_count
from seuwgpu.model.formats.base import ANTIALIASED_NOTE, ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError
from seuwgpu.model.formats.quantized import byte_opacity
from seuwgpu.model.formats.zips import shown_members

SUFFIXES = (".sog",)
PALETTE_ROW = 64  # palette entries per row of the centroids image
# The most a bundled SOG's zip entries may declare uncompressed, checked before one is inflated (a
# few kB of deflated zeros can declare gigabytes): meta.json holds four 256-entry codebooks and
# the image names (kilobytes); a lossless WebP about 4 bytes a texel at most (raw RGBA and its
# headers), and an image holds the splats' texels, or the SH palette's (at most 65536 entries of
# 15 coefficients: under 2^20), with some rows of padding: twice that is allowed.
META_BYTES = 16 << 20
TEXEL_BYTES = 8
SLACK_TEXELS = 1 << 20
# notes for meta.json's `model` ("antialiased" gets the note every format gives it)
MODEL_NOTES = {"2dgs": "trained as 2D Gaussians (2DGS): rendered here as 3D Gaussians"}


class SogError(ModelFileError):
    """A SOG file or folder that cannot be read."""


@dataclass
class SogInfo:
    version: int
    bands: int
    palette: int
    model: str


def zip_problem(names: list[str]) -> str | None:
    """Why a zip archive with these members is no bundled SOG (None when it holds meta.json at its root)."""
    if "meta.json" in names:
        return None
    return f"a zip without meta.json (it holds {shown_members(names)}); a SOG is a zip of meta.json and WebP images"


def is_sog_meta(head: bytes) -> bool:
    """The start of a SOG meta.json: a JSON object naming "means" or "version"."""
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    return text[:1] == b"{" and (b'"means"' in head or b'"version"' in head)


def unbundled_files(meta_path) -> list[Path]:
    """An unbundled SOG's meta.json and the images it lists (those present), in that order."""
    meta_path = Path(meta_path)
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8-sig"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return [meta_path]
    names = []
    for key in ("means", "quats", "scales", "sh0", "shN"):
        entry = meta.get(key) if isinstance(meta, dict) else None
        files = entry.get("files") if isinstance(entry, dict) else None
        names += [n for n in files if isinstance(n, str)] if isinstance(files, list) else []
    return [meta_path] + [meta_path.parent / n for n in names if (meta_path.parent / n).is_file()]


class _Files:
    """The meta.json and images of a bundled (zip) or unbundled (folder) SOG."""

    def __init__(self, path: str):
        self.path = path
        self.zip = None
        if zipfile.is_zipfile(path):
            try:
                self.zip = zipfile.ZipFile(path)
            except (zipfile.BadZipFile, OSError) as e:
                raise SogError(f"{path}: a broken zip archive ({e})") from None
            why = zip_problem(self.zip.namelist())
            if why:
                raise SogError(f"{path}: not a SOG: {why}")
            self.base = None
        else:
            self.base = Path(path).parent

    def meta_bytes(self) -> bytes:
        if self.zip is not None:
            return self._zip_read("meta.json", META_BYTES)
        return Path(self.path).read_bytes()

    def _zip_read(self, name: str, limit: int) -> bytes:
        try:
            declared = self.zip.getinfo(name).file_size
        except KeyError:
            raise SogError(f"{self.path}: the SOG zip lacks {name}, which meta.json lists") from None
        if declared > limit:
            raise SogError(
                f"{self.path}: {name} in the SOG zip declares {declared:,} bytes uncompressed, over the {limit:,} "
                "its SOG could need: a damaged archive or a zip bomb, not inflated"
            )
        try:
            return self.zip.read(name)
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise SogError(f"{self.path}: {name} in the SOG zip cannot be read ({e}; truncated?)") from None

    def image(self, name, count: int, what: str, size: tuple[int, int] | None = None) -> tuple[np.ndarray, int, int]:
        """The RGBA texels [W*H, 4] (uint8) of image `name`, its width and height. `size`: the
        (W, H) it must have (a SOG's per-splat images share one size: texel i of each is splat
        i), checked with its holding `count` texels before it is decoded."""
        if not isinstance(name, str):
            raise SogError(f"{self.path}: SOG meta.json names {what}'s image as {name!r}, not a file name")
        if self.zip is not None:
            data = self._zip_read(name, TEXEL_BYTES * (count + SLACK_TEXELS))
        else:
            p = self.base / name
            if not p.is_file():
                raise SogError(f"{self.path}: SOG image {name} ({what}) is missing from {self.base}")
            data = p.read_bytes()
        from PIL import Image, features

        if not features.check("webp"):
            raise SogError(f"{self.path}: this Pillow was built without WebP support, which SOG images need")
        unreadable = f"{self.path}: SOG image {name} ({what}) is no readable WebP image"
        try:
            with warnings.catch_warnings():  # the sizes are checked here, against the splat count
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                im = Image.open(io.BytesIO(data), formats=["WEBP"])
        except Image.DecompressionBombError as e:  # over 179 M texels: no SOG this tool could render
            raise SogError(f"{self.path}: SOG image {name} ({what}) is too large to read ({e})") from None
        except (OSError, ValueError, SyntaxError) as e:
            raise SogError(f"{unreadable} ({e})") from None
        with im:
            w, h = im.size
            if size is not None and (w, h) != size:
                raise SogError(
                    f"{self.path}: SOG image {name} ({what}) has {w} x {h} texels, the means images "
                    f"{size[0]} x {size[1]} (a SOG's per-splat images share one size)"
                )
            if w * h < count:
                raise SogError(
                    f"{self.path}: SOG image {name} ({what}) has {w} x {h} texels, fewer than its {count} splats"
                )
            try:
                rgba = np.asarray(im.convert("RGBA"), dtype=np.uint8).reshape(-1, 4)
            except (OSError, ValueError, SyntaxError) as e:
                raise SogError(f"{unreadable} ({e})") from None
        return rgba, w, h


def _get(meta: dict, path: str, where: str):
    v = meta
    for key in path.split("."):
        if not isinstance(v, dict) or key not in v:
            raise SogError(f"{where}: SOG meta.json lacks {path}")
        v = v[key]
    return v


def _numbers(meta: dict, path: str, where: str, length: int) -> np.ndarray:
    v = _get(meta, path, where)
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (length,):
        raise SogError(f"{where}: SOG meta.json {path} must be {length} numbers")
    return a


def _files(meta: dict, key: str, where: str, k: int) -> list:
    v = _get(meta, f"{key}.files", where)
    if not isinstance(v, list) or len(v) < k:
        raise SogError(f"{where}: SOG meta.json {key}.files must list {k} image(s)")
    return v


def _quats(q: np.ndarray) -> np.ndarray:
    n = len(q)
    tag = q[:, 3].astype(np.int64)
    valid = (tag >= 252) & (tag <= 255)
    largest = np.where(valid, tag - 252, 0)
    abc = (q[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / math.sqrt(2.0)
    # the three stored components fill the slots other than the largest, in order
    others = np.array([[j for j in range(4) if j != m] for m in range(4)])[largest]  # [N, 3]
    quats = np.zeros((n, 4))
    rows = np.arange(n)[:, None]
    quats[rows, others] = abc
    quats[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - (abc * abc).sum(axis=1)))
    quats[~valid] = (1.0, 0.0, 0.0, 0.0)
    return quats


def read_sog(path) -> tuple[Model, SogInfo]:
    """Read a bundled .sog (zip), an unbundled meta.json or a folder holding one."""
    spath = os.fspath(path)
    if os.path.isdir(spath):
        spath = os.path.join(spath, "meta.json")
    files = _Files(spath)
    try:
        meta = json.loads(files.meta_bytes().decode("utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SogError(f"{spath}: SOG meta.json is not valid JSON ({e})") from None
    if not isinstance(meta, dict):
        raise SogError(f"{spath}: SOG meta.json must hold a JSON object")
    version = meta.get("version")
    if version is None:
        raise SogError(
            f'{spath}: SOG version 1 (a meta.json without "version", written by splat-transform before 0.7) '
            "is not supported; convert it with splat-transform 3.x (`splat-transform meta.json out.sog`)"
        )
    if version != 2:
        raise SogError(
            f"{spath}: unsupported SOG version {version!r} (this reader takes version 2, what splat-transform writes)"
        )
    n = meta.get("count")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise SogError(f"{spath}: SOG meta.json count must be a positive integer, got {n!r}")
    # before any image: the images' size limits follow the count, and WebP compresses a constant
    # image to almost nothing (degree 0: the least a model of n splats needs)
    check_model(n, 0, what=f"{spath}: SOG count", use="read and render")

    lo_name, hi_name = _files(meta, "means", spath, 2)[:2]
    lo, w, h = files.image(lo_name, n, "means, low bytes")
    lo = lo[:n, :3].astype(np.int64)
    size = (w, h)  # every per-splat image's
    hi = files.image(hi_name, n, "means, high bytes", size)[0][:n, :3].astype(np.int64)
    mins = _numbers(meta, "means.mins", spath, 3)
    maxs = _numbers(meta, "means.maxs", spath, 3)
    span = np.where(maxs - mins != 0, maxs - mins, 1.0)  # as the reference: a zero range scales by 1
    v = mins + span * ((lo | (hi << 8)) / 65535.0)
    means = np.sign(v) * (np.exp(np.abs(v)) - 1.0)  # the reference's exp(|v|) - 1, not expm1

    quats = _quats(files.image(_files(meta, "quats", spath, 1)[0], n, "quats", size)[0][:n])

    scale_book = _numbers(meta, "scales.codebook", spath, 256).astype(np.float32)
    log_scales = scale_book[files.image(_files(meta, "scales", spath, 1)[0], n, "scales", size)[0][:n, :3]]

    dc_book = _numbers(meta, "sh0.codebook", spath, 256).astype(np.float32)
    sh0 = files.image(_files(meta, "sh0", spath, 1)[0], n, "sh0", size)[0][:n]
    opacity = byte_opacity(sh0[:, 3])

    bands, palette, sh_rest = 0, 0, np.zeros((n, 0, 3), np.float32)
    if meta.get("shN") is not None:
        bands = _get(meta, "shN.bands", spath)
        if bands not in (0, 1, 2, 3) or isinstance(bands, bool):
            raise SogError(f"{spath}: SOG meta.json shN.bands is {bands!r} (0-3 expected)")
    if bands:
        sh_rest, palette = _sh_rest(meta, files, spath, n, bands, size)

    model_name = meta.get("model", "default")
    model = Model(
        means=means,
        log_scales=log_scales,
        quats=quats,
        opacity=opacity,
        sh_dc=dc_book[sh0[:, :3]],
        sh_rest=sh_rest,
    )
    return model, SogInfo(2, bands, palette, str(model_name))


def _sh_rest(meta, files: _Files, spath: str, n: int, bands: int, size) -> tuple[np.ndarray, int]:
    k = sh_rest_count(bands)
    palette = _get(meta, "shN.count", spath)
    if not isinstance(palette, int) or isinstance(palette, bool) or palette < 1:
        raise SogError(f"{spath}: SOG meta.json shN.count must be a positive integer, got {palette!r}")
    book = _numbers(meta, "shN.codebook", spath, 256).astype(np.float32)
    cen_name, lab_name = _files(meta, "shN", spath, 2)[:2]
    cen, cw, ch = files.image(cen_name, 0, "shN centroids")
    if cw != PALETTE_ROW * k:
        raise SogError(
            f"{spath}: SOG shN centroids image is {cw} texels wide; {PALETTE_ROW * k} expected for SH degree {bands}"
        )
    lab = files.image(lab_name, n, "shN labels", size)[0][:n].astype(np.int64)
    label = lab[:, 0] | (lab[:, 1] << 8)
    held = min(palette, ch * PALETTE_ROW)  # palette entries the centroids image holds
    bad = label >= held
    if bad.any():
        raise SogError(
            f"{spath}: SOG shN label {int(label[bad].max())} is beyond the palette ({palette} entries, "
            f"{ch * PALETTE_ROW} in the centroids image)"
        )
    entries = cen.reshape(ch, PALETTE_ROW, k, 4).reshape(ch * PALETTE_ROW, k, 4)
    return book[entries[label, :, :3]], palette  # [N, k, 3]: coefficient-major, channel innermost


def _sniff(probe: Probe) -> bool:
    """A zip holding meta.json (a file named .sog that is not one hears why), or a meta.json itself."""
    if probe.is_zip:
        members, zip_error = probe.zip_members()
        why = zip_error or zip_problem(members)
        if why is None:
            return True
        if probe.named(SUFFIXES):
            raise SogError(f"{probe.path}: not a SOG: {why}")
    return is_sog_meta(probe.head)


def _read(path: str) -> tuple[Model, list[str]]:
    model, info = read_sog(path)
    palette = f", SH palette of {info.palette}" if info.bands else ""
    quantised = f"16-bit log positions, 8-bit rotations, 256-entry codebooks{palette}"
    notes = [f"SOG version {info.version} (quantised: {quantised})"]
    if info.model == "antialiased":
        notes.append(ANTIALIASED_NOTE)
    elif info.model != "default":
        notes.append(MODEL_NOTES.get(info.model, f"unrecognised model {info.model!r} in meta.json, read as default"))
    return model, notes


def _write(model: Model, path: str, up: str | None = None, **options) -> None:
    """Written by sog_write.py (bundled .sog, or an unbundled meta.json and its images)."""
    from seuwgpu.model.formats.sog_write import write_sog

    write_sog(model, path, up=up, **options)


FORMAT = ModelFormat(
    name="sog",
    title="PlayCanvas SOG",
    suffixes=SUFFIXES,
    up="-y",
    sniff=_sniff,
    read=_read,
    write=_write,
)
