"""3DGS model files: one loader that recognises a file by its content, and writers.

| format | recognised by | module | up axis | written |
|---|---|---|---|---|
| INRIA PLY (`.ply`; binary LE/BE, ASCII) | `ply` magic, `vertex` element | ply.py (own header + numpy) | -y | yes |
| SuperSplat/PlayCanvas compressed PLY | `ply` magic, `chunk` element, packed_* | compressed_ply.py | -y | yes |
| Niantic SPZ v1-v4 (`.spz`) | gzip header / NGSP magic | spz.py (v4: zstandard) | +y | v2, v3 |
| PlayCanvas SOG v2 (`.sog` zip; `meta.json` + WebP) | zip with meta.json; JSON: "means" | sog.py (Pillow) | -y | yes |
| PlayCanvas LOD set (`lod-meta.json`, SOG tiles; one level) | JSON: "lodLevels" | lod.py | -y | no |
| GaussianSplats3D `.ksplat` (v0.1, levels 0-2) | its header, sizes adding up to the file's | ksplat.py | -y | level 0 |
| gsplat checkpoint (`.pt`) | zip / pickle magic | gsplat.py (torch) | -y | no |
| antimatter15 `.splat` | no header: size % 32 == 0, plausible records | splat.py | -y | yes |

Each module exports one `FORMAT` (base.ModelFormat: name, suffixes, up axis, sniff, read ->
(Model, notes), write or None); REGISTRY below lists them in sniffing order, and everything here
loops over it. Adding a format: CONTRIBUTING.md, "Add a model format". The quantised writers
(compressed PLY, .splat, SOG, .ksplat) share one rule for corrupted values (quantized.py, "writing"): NaN
is refused, +-Inf stored as the largest finite float32, and an upset's value kept as a range end
or codebook entry rather than clipped into the clean range.

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
from seuwgpu.model.formats import compressed_ply, gsplat, ksplat, ply, sog, spz
from seuwgpu.model.formats import lod as lod_set
from seuwgpu.model.formats import splat as splat_format
from seuwgpu.model.formats.base import ANTIALIASED_NOTE, UP_AXES, ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError, NonFiniteWarning

__all__ = [
    "ANTIALIASED_NOTE",
    "FORMATS",
    "REGISTRY",
    "UP_AXES",
    "ModelFile",
    "ModelFormat",
    "check_renderable",
    "ModelFileError",
    "NonFiniteWarning",
    "detect_format",
    "format_named",
    "load_model",
    "model_files",
    "nonfinite_counts",
    "read_model",
    "save_model",
    "save_models",
    "sniff_format",
    "writable_formats",
]

# Every format, in sniffing order: the first whose sniff says yes reads the file. The compressed
# PLY comes before the PLY (which takes any PLY), the headerless .splat last.
REGISTRY: tuple[ModelFormat, ...] = (
    compressed_ply.FORMAT,
    ply.FORMAT,
    spz.FORMAT,
    lod_set.FORMAT,
    sog.FORMAT,
    ksplat.FORMAT,
    gsplat.FORMAT,
    splat_format.FORMAT,
)
FORMATS = {f.name: f.title for f in REGISTRY}  # name -> title (kept for callers; the code below asks REGISTRY)


def writable_formats() -> tuple[str, ...]:
    """The names of the formats with a writer, in REGISTRY order."""
    return tuple(f.name for f in REGISTRY if f.write is not None)


def format_named(name: str) -> ModelFormat:
    """The registered format of this name (ModelFileError naming the known ones otherwise)."""
    for f in REGISTRY:
        if f.name == name:
            return f
    raise ModelFileError(f"unknown model format {name!r}; known: {', '.join(f.name for f in REGISTRY)}")


@dataclass
class ModelFile:
    """A loaded model file: the model, its format, the up axis of its convention, and notes
    (e.g. the SPZ version, an antialiased flag) worth telling the user."""

    model: Model
    path: Path
    format: str
    up: str
    notes: list[str] = field(default_factory=list)
    lod: int | None = None  # the level read of a LOD set, when one was asked for

    @property
    def name(self) -> str:
        return model_label(self.path, self.lod)


def model_label(path, lod: int | None = None) -> str:
    """The name records, reports and `plan` give a model: the file's name without its format's
    extension, or for an INRIA output folder (or the point_cloud.ply of one of its iterations)
    the folder's name: every INRIA output holds a point_cloud.ply, and two captures labelled
    "point_cloud" would be pooled as one scene. A LOD set's level other than the finest (`lod`
    1, 2, ...) is another model: "-lod2" is added (level 0 is the set's own name)."""
    if lod:
        return f"{model_label(path)}-lod{lod}"
    p = Path(path)
    if p.name in ("meta.json", lod_set.NAME):  # an unbundled SOG's or a LOD set's: its folder's name
        return p.resolve().parent.name
    if p.is_dir():  # an INRIA output or unbundled SOG folder
        return p.resolve().name
    if p.name == "point_cloud.ply" and p.parent.name.startswith("iteration_") and p.parent.parent.name == "point_cloud":
        return p.resolve().parents[2].name
    name = p.name
    # longest first: "x.compressed.ply" loses ".compressed.ply", not ".ply"
    for suffix in sorted({s for f in REGISTRY for s in f.suffixes}, key=len, reverse=True):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return p.stem


def _unrecognised(spath: str) -> ModelFileError:
    titles = ", ".join(f.title for f in REGISTRY)
    hints = "".join(f"; {f.hint}" for f in REGISTRY if f.hint)
    return ModelFileError(f"{spath}: unrecognised model file (supported: {titles}{hints})")


def sniff_format(path) -> ModelFormat:
    """The registered format of a file, from its content (REGISTRY's sniffers, in order)."""
    spath = os.fspath(path)
    if not os.path.exists(spath):
        raise FileNotFoundError(f"{spath}: no such file")
    if os.path.isdir(spath):
        if os.path.isfile(os.path.join(spath, lod_set.NAME)):
            return lod_set.FORMAT
        if os.path.isfile(os.path.join(spath, "meta.json")):
            return sog.FORMAT
        raise ModelFileError(
            f"{spath}: is a folder without point_cloud/iteration_*/point_cloud.ply (INRIA output), meta.json (SOG) "
            f"or {lod_set.NAME} (PlayCanvas LOD set)"
        )
    if not os.path.isfile(spath):  # reading a pipe would wait for a writer forever
        raise ModelFileError(f"{spath}: not a regular file (a pipe or device cannot be read as a model)")
    probe = Probe.of(spath)
    for f in REGISTRY:
        if f.sniff(probe):
            return f
    raise _unrecognised(spath)


def detect_format(path) -> str:
    """The format of a file from its content (magic bytes, gzip header, PLY header): its name."""
    return sniff_format(path).name


def read_model(path, warn_nonfinite: bool = True, lod: int | None = None) -> ModelFile:
    """Load any supported model file (see the module table). Raises ModelFileError (a ValueError)
    naming the file and the problem; warns (NonFiniteWarning) when the model holds NaN or Inf.
    `lod`: the level of detail of a LOD set (default: its finest, 0); refused for other formats."""
    spath = os.fspath(model_file(path))
    fmt = sniff_format(spath)
    inria = os.path.isdir(path) and fmt not in (sog.FORMAT, lod_set.FORMAT)
    notes: list[str] = [inria_iteration_note(path)] if inria else []
    if lod is None:
        model, format_notes = fmt.read(spath)
    elif fmt.read_level is None:
        raise ModelFileError(
            f"{spath}: a level of detail (lod = {lod}) picks a level of a PlayCanvas LOD set; this is a {fmt.title}"
        )
    else:
        model, format_notes = fmt.read_level(spath, lod)
    notes += format_notes
    up = (fmt.recorded_up(spath) if fmt.recorded_up else None) or fmt.up
    check_renderable(model, spath)
    if warn_nonfinite:
        counts = nonfinite_counts(model)
        if counts:
            total = sum(counts.values())
            per = ", ".join(f"{f} {c}" for f, c in counts.items())
            warnings.warn(f"{spath}: the model holds {total} non-finite values ({per})", NonFiniteWarning)
    return ModelFile(model, Path(spath), fmt.name, up, notes, lod)


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
    if (p / lod_set.NAME).is_file():
        return p / lod_set.NAME
    return p / "meta.json" if (p / "meta.json").is_file() else inria_output_model(p)


def model_files(path) -> list[Path]:
    """The files a model path stands for: model_file's, and an unbundled SOG's images after its
    meta.json, or a LOD set's lod-meta.json and every tile's files (what a campaign hashes to know
    its model). A folder that is none of these comes back as itself (read_model refuses it with the reason)."""
    p = Path(model_file(path))
    if p.is_file() and p.suffix.lower() == ".json":
        with open(p, "rb") as f:
            head = f.read(4096)
        if lod_set.is_lod_meta(head):
            return lod_set.lod_files(p)
        if sog.is_sog_meta(head):
            return sog.unbundled_files(p)
    return [p]


def load_model(path, lod: int | None = None) -> Model:
    """The Model in any supported file (read_model without the metadata)."""
    return read_model(path, lod=lod).model


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
    """Write `model` in a writable format (writable_formats(): INRIA PLY `.ply`, SPZ `.spz`
    (options: version=3, antialiased=False), compressed PLY `.compressed.ply`, `.splat`, `.ksplat` (level 0),
    SOG `.sog` or an unbundled SOG's `meta.json`), chosen by `format` or the file extension (the longest
    suffix that matches: `x.compressed.ply` is a compressed PLY). Returns the format written.

    `up`: the model's up axis. A PLY records it (`comment up +z`, which read_model honours). SPZ
    has no such field and its frame is y-up (RUB), so a model whose up is another axis is turned
    to +y first (model.sh.rotate_model: positions, orientations and SH together), and the file
    stands upright in every SPZ viewer, this one included."""
    spath = os.fspath(path)
    writable = [f for f in REGISTRY if f.write is not None]
    if format is not None:
        fmt = next((f for f in writable if f.name == format), None)
    else:
        by_suffix = sorted(((s, f) for f in writable for s in f.suffixes), key=lambda sf: -len(sf[0]))
        fmt = next((f for s, f in by_suffix if spath.lower().endswith(s)), None)
    if fmt is None:
        ranked = sorted(writable, key=lambda f: not f.exact)  # the exact one first
        items = [f"{f.suffixes[0]} ({f.title})" for f in ranked]
        choices = ", ".join(items[:-1]) + " or " + items[-1] if len(items) > 1 else items[0]
        raise ModelFileError(f"{spath}: cannot write this format; write {choices}")
    fmt.write(model, spath, up=up, **options)
    return fmt.name


EXACT = next(f for f in REGISTRY if f.exact)  # the format every kept model is written in
EMBEDDED_FORMATS = (EXACT.name, spz.FORMAT.name)  # save_models' default without a source format (an embedded scene)


def save_models(models: dict[str, Model], out, formats=None, up: str | None = None, source: str | None = None):
    """Write each model of `models` (name -> Model: `faulted`, a defense's repair) in each of
    `formats` (writable_formats() names) into the folder `out` as NAME + the format's suffix.
    Default: the `source` file's format where it has a writer, and the EXACT one (PLY); without one
    EMBEDDED_FORMATS. The source's own format is written in the source's coordinates (not turned
    to `up`), so the file overlays the original in the user's viewer; PLY records `up`. A
    quantised file that cannot hold a model (NaN; SPZ: any non-finite value) is left out with a
    warning saying why; the exact one is always written (its failure raises). Returns the paths written."""
    writable = writable_formats()
    if formats is None:
        formats = (source, EXACT.name) if source in writable else EMBEDDED_FORMATS
    formats = tuple(dict.fromkeys(formats))
    unknown = [f for f in formats if f not in writable]
    if unknown:
        raise ModelFileError(f"unknown model format(s) {', '.join(unknown)}; writable: {', '.join(writable)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, model in models.items():
        for fmt in formats:
            spec = format_named(fmt)
            path = out / f"{name}{spec.suffixes[0]}"
            turn = fmt != source or spec.recorded_up is not None  # PLY's up is a comment, not a turn
            try:
                save_model(model, path, format=fmt, up=up if turn else None)
            except ValueError as e:
                if spec.exact:
                    raise
                warnings.warn(f"{path.name} not written: {e}", stacklevel=3)
                continue
            paths.append(path)
    return paths
