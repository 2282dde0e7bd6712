"""3DGS model files: one loader that recognises a file by its content, and writers.

| format | recognised by | read with | up axis |
|---|---|---|---|
| INRIA PLY (`.ply`; binary LE/BE, ASCII) | `ply` magic, `vertex` element | ply.py (own header + numpy) | -y |
| SuperSplat/PlayCanvas compressed PLY | `ply` magic, `chunk` element, packed_* | compressed_ply.py | -y |
| Niantic SPZ v1-v4 (`.spz`) | gzip header / NGSP magic | spz.py (v4: zstandard) | +y |
| antimatter15 `.splat` | no header: size % 32 == 0, plausible records | splat.py | -y |
| gsplat checkpoint (`.pt`) | zip / pickle magic | gsplat.py (torch) | -y |
| GaussianSplats3D `.ksplat` (v0.1, levels 0-2) | its header, sizes adding up to the file's | ksplat.py | -y |
| PlayCanvas SOG v2 (`.sog` zip; `meta.json` + WebP) | zip holding meta.json; JSON with "means" | sog.py (Pillow) | -y |

The up axis is the file format's convention, used to frame a model when no cameras are given:
SPZ stores RUB axes (y up); PLY, .splat, .ksplat, SOG and gsplat models live in their capture's COLMAP world,
which follows the first camera (x right, y down), so -y is up; viewers such as SuperSplat make
the same assumption. A PLY written by seuwgpu with an up axis records it in a `comment up` line
(`comment up +z` for the procedural scenes, which are z up; `+y` for the real captures);
`--up` overrides all of this.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.formats import compressed_ply, gsplat, ksplat, ply, sog, spz, zips
from seuwgpu.model.formats import splat as splat_format
from seuwgpu.model.formats.errors import ModelFileError, NonFiniteWarning

__all__ = [
    "FORMATS",
    "ModelFile",
    "check_renderable",
    "ModelFileError",
    "NonFiniteWarning",
    "detect_format",
    "load_model",
    "model_files",
    "nonfinite_counts",
    "read_model",
    "save_model",
]

FORMATS = {
    "ply": "INRIA 3DGS PLY",
    "compressed-ply": "SuperSplat/PlayCanvas compressed PLY",
    "spz": "Niantic SPZ",
    "splat": "antimatter15 .splat",
    "gsplat": "gsplat checkpoint",
    "ksplat": "GaussianSplats3D .ksplat",
    "sog": "PlayCanvas SOG",
}
UP = {"ply": "-y", "compressed-ply": "-y", "spz": "+y", "splat": "-y", "gsplat": "-y", "ksplat": "-y", "sog": "-y"}
KSPLAT_LEVELS = {
    0: "float32, 8-bit colour and opacity",
    1: "16-bit positions in buckets, float16 scales, rotations and SH, 8-bit colour and opacity",
    2: "16-bit positions in buckets, float16 scales and rotations, 8-bit colour, opacity and SH",
}
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
ANTIALIASED_NOTE = "trained antialiased (mip-splatting): rendered here without the opacity compensation"


@dataclass
class ModelFile:
    """A loaded model file: the model, its format, the up axis of its convention, and notes
    (e.g. the SPZ version, an antialiased flag) worth telling the user."""

    model: Model
    path: Path
    format: str
    up: str
    notes: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        return model_label(self.path)


def model_label(path) -> str:
    """The name records, reports and `plan` give a model: the file's name without its format's
    extension, or for an INRIA output folder (or the point_cloud.ply of one of its iterations)
    the folder's name: every INRIA output holds a point_cloud.ply, and two captures labelled
    "point_cloud" would be pooled as one scene."""
    p = Path(path)
    if p.name == "meta.json":  # an unbundled SOG's: its folder's name
        return p.resolve().parent.name
    if p.is_dir():  # an INRIA output or unbundled SOG folder
        return p.resolve().name
    if p.name == "point_cloud.ply" and p.parent.name.startswith("iteration_") and p.parent.parent.name == "point_cloud":
        return p.resolve().parents[2].name
    name = p.name
    for suffix in (".compressed.ply", ".ply", ".spz", ".splat", ".ksplat", ".sog", ".pt", ".pth", ".ckpt"):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return p.stem


def detect_format(path) -> str:
    """The format of a file from its content (magic bytes, gzip header, PLY header)."""
    spath = os.fspath(path)
    if not os.path.exists(spath):
        raise FileNotFoundError(f"{spath}: no such file")
    if os.path.isdir(spath):
        if os.path.isfile(os.path.join(spath, "meta.json")):
            return "sog"
        raise ModelFileError(
            f"{spath}: is a folder without point_cloud/iteration_*/point_cloud.ply (INRIA output) or meta.json (SOG)"
        )
    if not os.path.isfile(spath):  # reading a pipe would wait for a writer forever
        raise ModelFileError(f"{spath}: not a regular file (a pipe or device cannot be read as a model)")
    size = os.path.getsize(spath)
    with open(spath, "rb") as f:
        head = f.read(4096)
    if head.startswith(b"ply\n") or head.startswith(b"ply\r\n"):
        return "compressed-ply" if compressed_ply.is_compressed_ply(ply.read_header(spath)) else "ply"
    if spz.is_spz(head):
        return "spz"
    members, zip_error = [], None  # a zip's names, listed once for the SOG and checkpoint tests
    if head[:4] == b"PK\x03\x04":
        try:
            members = zips.zip_members(spath)
        except ValueError as e:
            zip_error = str(e)
        why = zip_error or sog.zip_problem(members)
        if why is None:
            return "sog"
        if spath.lower().endswith(".sog"):
            raise sog.SogError(f"{spath}: not a SOG: {why}")
    if sog.is_sog_meta(head):
        return "sog"
    if spath.lower().endswith(".ksplat"):
        why = ksplat.ksplat_problem(spath)
        if why:
            raise ksplat.KsplatError(f"{spath}: not a .ksplat this reader takes: {why}")
        return "ksplat"
    if ksplat.looks_like_ksplat(spath, head):
        return "ksplat"
    if gsplat.is_torch_file(head):
        why = (zip_error or gsplat.zip_problem(members)) if head[:4] == b"PK\x03\x04" else None
        if why:
            raise ModelFileError(f"{spath}: {why}")
        return "gsplat"
    if spath.lower().endswith(".splat"):  # no header: the name says .splat, the content must agree
        why = splat_format.splat_problem(size, head)
        if why:
            raise splat_format.SplatError(f"{spath} does not look like an antimatter15 .splat file: {why}")
        return "splat"
    if splat_format.looks_like_splat(size, head):
        return "splat"
    raise ModelFileError(
        f"{spath}: unrecognised model file (not a PLY, SPZ, .splat, .ksplat, SOG or PyTorch checkpoint; a .splat file, "
        "which has no header, is recognised by its extension); "
        f"supported: {', '.join(FORMATS.values())}"
    )


def _ply_up(header: ply.PlyHeader) -> str | None:
    for c in header.comments:
        words = c.split()
        if len(words) == 2 and words[0] == "up" and words[1] in UP_AXES:
            return words[1]
    return None


def read_model(path, warn_nonfinite: bool = True) -> ModelFile:
    """Load any supported model file (see the module table). Raises ModelFileError (a ValueError)
    naming the file and the problem; warns (NonFiniteWarning) when the model holds NaN or Inf."""
    spath = os.fspath(model_file(path))
    fmt = detect_format(spath)
    notes: list[str] = [inria_iteration_note(path)] if os.path.isdir(path) and fmt != "sog" else []
    up = UP[fmt]
    if fmt in ("ply", "compressed-ply"):
        header = ply.read_header(spath)
        up = _ply_up(header) or up
        if fmt == "ply":
            model = ply.model_from_header(header)
            if header.format != "binary_little_endian":
                notes.append(header.format.replace("_", " "))
        else:
            model = compressed_ply.read_compressed_ply(header)
    elif fmt == "spz":
        model, info = spz.read_spz(spath)
        notes.append(f"SPZ version {info.version}")
        if info.antialiased:
            notes.append(ANTIALIASED_NOTE)
    elif fmt == "splat":
        model = splat_format.read_splat(spath)
    elif fmt == "ksplat":
        model, kinfo = ksplat.read_ksplat(spath)
        notes.append(f"ksplat v{kinfo.version}, compression level {kinfo.level} ({KSPLAT_LEVELS[kinfo.level]})")
    elif fmt == "sog":
        model, sinfo = sog.read_sog(spath)
        palette = f", SH palette of {sinfo.palette}" if sinfo.bands else ""
        quantised = f"16-bit log positions, 8-bit rotations, 256-entry codebooks{palette}"
        notes.append(f"SOG version {sinfo.version} (quantised: {quantised})")
        if sinfo.model == "antialiased":
            notes.append(ANTIALIASED_NOTE)
        elif sinfo.model != "default":
            notes.append(
                sog.MODEL_NOTES.get(sinfo.model, f"unrecognised model {sinfo.model!r} in meta.json, read as default")
            )
    else:
        model = gsplat.read_gsplat(spath)
    check_renderable(model, spath)
    if warn_nonfinite:
        counts = nonfinite_counts(model)
        if counts:
            total = sum(counts.values())
            per = ", ".join(f"{f} {c}" for f, c in counts.items())
            warnings.warn(f"{spath}: the model holds {total} non-finite values ({per})", NonFiniteWarning)
    return ModelFile(model, Path(spath), fmt, up, notes)


def _inria_iterations(folder) -> list[tuple[int, Path]]:
    """(iteration, point_cloud.ply) of each iteration an INRIA 3DGS output folder holds, in order."""
    found = []
    for p in Path(folder).glob("point_cloud/iteration_*/point_cloud.ply"):
        it = p.parent.name.removeprefix("iteration_")
        if it.isdigit():
            found.append((int(it), p))
    return sorted(found)


def inria_output_model(folder) -> Path:
    """The last iteration's point_cloud.ply of an INRIA 3DGS output folder (or the folder itself,
    which detect_format then refuses with a clear message)."""
    found = _inria_iterations(folder)
    return found[-1][1] if found else Path(folder)


def inria_iteration_note(folder) -> str:
    """Which iteration of an INRIA output folder is read (a note for the user)."""
    found = _inria_iterations(folder)
    it, p = found[-1]
    last = f", the last of {len(found)}" if len(found) > 1 else ""
    return f"iteration {it} ({p.relative_to(folder).as_posix()}{last})"


def model_file(path):
    """The file a model path names: the path itself (as given) unless it is a folder, an
    unbundled SOG folder's meta.json, or an INRIA output folder's last PLY (a folder that is
    neither: itself, refused by detect_format)."""
    if not os.path.isdir(path):
        return path
    p = Path(path)
    return p / "meta.json" if (p / "meta.json").is_file() else inria_output_model(p)


def model_files(path) -> list[Path]:
    """The files a model path stands for: model_file's, and an unbundled SOG's images after its
    meta.json (what a campaign hashes to know its model). A folder that is neither an INRIA
    output nor a SOG comes back as itself (read_model refuses it with the reason)."""
    p = Path(model_file(path))
    if p.is_file() and p.suffix.lower() == ".json":
        with open(p, "rb") as f:
            head = f.read(4096)
        if sog.is_sog_meta(head):
            return sog.unbundled_files(p)
    return [p]


def load_model(path) -> Model:
    """The Model in any supported file (read_model without the metadata)."""
    return read_model(path).model


def check_renderable(model: Model, where: str):
    """Refuse a model none of whose primitives has a finite position, scale, rotation and opacity:
    it would render as an empty frame with no word of why (some NaN primitives only warn)."""
    ok = np.ones(model.n, dtype=bool)
    for f in ("means", "log_scales", "quats", "opacity"):
        v = getattr(model, f)
        ok &= np.isfinite(v.reshape(model.n, -1)).all(axis=1)
    if model.n and not ok.any():
        raise ModelFileError(
            f"{where}: none of its {model.n} primitives has a finite position, scale, rotation and opacity "
            "(all NaN or Inf): nothing to render"
        )


def nonfinite_counts(model: Model) -> dict[str, int]:
    """NaN/Inf values per field, fields without any left out."""
    out = {}
    for f in FIELDS:
        c = int(np.count_nonzero(~np.isfinite(getattr(model, f))))
        if c:
            out[f] = c
    return out


def save_model(model: Model, path, format: str | None = None, up: str | None = None, **options) -> str:
    """Write `model` as an INRIA PLY (`.ply`) or an SPZ (`.spz`; options: version=3,
    antialiased=False), chosen by `format` or the file extension. Returns the format written.

    `up`: the model's up axis. A PLY records it (`comment up +z`, which read_model honours). SPZ
    has no such field and its frame is y-up (RUB), so a model whose up is another axis is turned
    to +y first (model.sh.rotate_model: positions, orientations and SH together), and the file
    stands upright in every SPZ viewer, this one included."""
    spath = os.fspath(path)
    fmt = format or {".ply": "ply", ".spz": "spz"}.get(Path(spath).suffix.lower())
    if fmt == "ply":
        ply.save_ply(model, spath, comments=[f"up {up}"] if up else ())
    elif fmt == "spz":
        if up not in (None, "+y"):
            from seuwgpu.model.sh import rotate_model, rotation_to_y

            model = rotate_model(model, rotation_to_y(up))
        spz.save_spz(model, spath, **options)
    else:
        raise ModelFileError(f"{spath}: cannot write this format; write .ply (INRIA PLY) or .spz (Niantic SPZ)")
    return fmt
