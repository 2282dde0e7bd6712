"""antimatter15 `.splat`: 32 bytes a splat, no header.

Layout (github antimatter15/splat, convert.py and main.js): position float32 x 3, linear scale
float32 x 3, colour RGBA uint8 x 4 (RGB = 0.5 + C0 * f_dc, A = sigmoid(opacity), times 255),
rotation uint8 x 4 (w, x, y, z; q / |q| * 128 + 128). Decoded as the viewer and PlayCanvas's
splat-transform (src/lib/readers/read-splat.ts) read it, in float64 then rounded once to float32:
log_scales = log(scale), sh_dc = (byte / 255 - 0.5) / C0, opacity = logit(byte / 255) (saturated
bytes 0 and 255 become -+20, see quantized.py), quats = byte / 128 - 1 with w first and not
normalised (the renderer normalises; an all-128 rotation, which no encoder writes, becomes the
identity as in splat-transform). The format carries no SH beyond DC (degree 0). Coordinates are
those of the PLY it was converted from (COLMAP-style, y down).

Written (write_splat) as antimatter15's convert.py writes it, in float64: positions exact
(float32), scale = exp(log-scale) rounded once to float32, colour bytes clip((0.5 + C0 * f_dc) *
255, 0, 255), alpha sigmoid(opacity) * 255, rotation bytes clip(q / |q| * 128 + 128, 0, 255); SH
beyond DC is dropped (the format has none). Two deliberate differences from convert.py: bytes are
rounded to nearest (floor(x + 0.5)), not truncated, so a .splat read and written again keeps its
colour and alpha bytes (truncation would lose one step a trip; rotations are renormalised and may
move one step); and the records keep the model's order (record i is primitive i, the index the
reports name), not a size x opacity sort (viewers sort by depth anyway).

A damaged model (quantized.py, "writing"): NaN is refused; an infinite position becomes
+-3.4e38; a scale is clamped to the positive finite float32s (a log-scale above 88.72 stores the
largest, 3.4e38; one below -103.28, or -Inf, the smallest, 1.4e-45), since a reader (this one
included) refuses a file whose scales are 0 or Inf; colours and opacity saturate at bytes 0 and
255. A model whose up axis is not -y is turned to -y first, as SPZ's writer turns it.
"""

from __future__ import annotations

import os

import numpy as np

from seuwgpu.model.fields import Model
from seuwgpu.model.formats.base import ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError
from seuwgpu.model.formats.quantized import (
    alpha_bytes,
    byte_opacity,
    byte_sh_dc,
    colour_bytes,
    linear_scales,
    storable,
    turned_to_minus_y,
)

SUFFIXES = (".splat",)
RECORD = np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])


class SplatError(ModelFileError):
    """A .splat file that cannot be read."""


def looks_like_splat(size: int, head: bytes) -> bool:
    """A headerless file without the .splat extension is taken as .splat when its size is a
    multiple of 32 and its first records (8 to 64) have finite positions, positive finite scales
    and encoded unit quaternions (q / |q| * 128 + 128: the bytes minus 128 have a length within 4
    of 128, the rounding of four bytes). Finite positions and scales alone let about one text file
    in 32 through (printable bytes read as floats are small and finite); printable rotation bytes
    (32-126) meet the length test only by chance (11% of random printable records), and every
    record tested must: at least 8, so a shorter file needs the .splat extension."""
    return splat_problem(size, head) is None and len(head) >= 8 * RECORD.itemsize  # head: a prefix of the file


def splat_problem(size: int, head: bytes) -> str | None:
    """Why a file (its size, its first bytes) is no .splat, or None: the content check of
    looks_like_splat, also applied to a file named .splat, and text refused; a file of fewer
    than 8 records that is not text passes (too few records to test)."""
    if size == 0:
        return "the file is empty"
    if size % RECORD.itemsize:
        return f"its size, {size} bytes, is not a multiple of the 32-byte record (truncated or not a .splat)"
    k = min(len(head), 64 * RECORD.itemsize) // RECORD.itemsize
    if all(32 <= b < 127 or b in b"\t\n\r" for b in head[: k * RECORD.itemsize]):
        return "its first bytes are text"
    if k < 8:
        return None
    rec = np.frombuffer(head[: k * RECORD.itemsize], dtype=RECORD)
    q = np.linalg.norm(rec["rot"].astype(np.float64) - 128.0, axis=1)
    with np.errstate(invalid="ignore"):
        if not (np.isfinite(rec["pos"]).all() and np.isfinite(rec["scale"]).all() and (rec["scale"] > 0).all()):
            return f"its first {k} records do not all hold finite positions and positive scales"
        if not (np.abs(q - 128.0) <= 4.0).all():
            return f"the rotation bytes of its first {k} records are not all unit quaternions"
    return None


def read_splat(path) -> Model:
    spath = os.fspath(path)
    size = os.path.getsize(spath)
    if size == 0:
        raise SplatError(f"{spath}: empty .splat file")
    if size % RECORD.itemsize:
        raise SplatError(
            f"{spath}: .splat size {size} bytes is not a multiple of the 32-byte record (truncated or not a .splat)"
        )
    rec = np.fromfile(spath, dtype=RECORD)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.log(rec["scale"].astype(np.float64))
    quats = rec["rot"].astype(np.float64) / 128.0 - 1.0
    quats[(rec["rot"] == 128).all(axis=1)] = (1.0, 0.0, 0.0, 0.0)
    n = len(rec)
    return Model(
        means=rec["pos"],
        log_scales=log_scales,
        quats=quats,
        opacity=byte_opacity(rec["rgba"][:, 3]),
        sh_dc=byte_sh_dc(rec["rgba"][:, :3]),
        sh_rest=np.zeros((n, 0, 3), np.float32),
    )


def splat_records(model: Model, path: str = "<model>") -> np.ndarray:
    """The .splat records of a model (RECORD array), as described in the module docstring."""
    v = storable(model, path, "antimatter15 .splat")
    rec = np.zeros(model.n, dtype=RECORD)
    rec["pos"] = v["means"]
    rec["scale"] = linear_scales(v["log_scales"])
    rec["rgba"][:, :3] = colour_bytes(v["sh_dc"])
    rec["rgba"][:, 3] = alpha_bytes(v["opacity"])
    rec["rot"] = np.clip(np.floor(v["quats"] * 128.0 + 128.5), 0, 255).astype(np.uint8)
    return rec


def write_splat(model: Model, path, up: str | None = None, **_options) -> None:
    """Write `model` as an antimatter15 .splat file (turned to -y up first when `up` says otherwise)."""
    spath = os.fspath(path)
    rec = splat_records(turned_to_minus_y(model, up), spath)
    with open(spath, "wb") as f:
        f.write(rec.tobytes())


def _sniff(probe: Probe) -> bool:
    """No header: a file named .splat must pass the content check, any other file the stricter one."""
    if probe.named(SUFFIXES):
        why = splat_problem(probe.size, probe.head)
        if why:
            raise SplatError(f"{probe.path} does not look like an antimatter15 .splat file: {why}")
        return True
    return looks_like_splat(probe.size, probe.head)


FORMAT = ModelFormat(
    name="splat",
    title="antimatter15 .splat",
    suffixes=SUFFIXES,
    up="-y",
    sniff=_sniff,
    read=lambda path: (read_splat(path), []),
    write=write_splat,
    hint="a .splat file, which has no header, is recognised by its extension",
)
