"""What `inject` returns: one injection evaluated under several defenses, with its frames and
(on request) its models, and the helpers that build them."""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.api._checks import names_of
from seuwgpu.errors import InputError
from seuwgpu.metrics.image import display
from seuwgpu.model import encoding
from seuwgpu.model.fields import Model
from seuwgpu.report.format import json_safe

FRAME_FILE_FORMATS = ("png", "tiff", "npz")  # the API names them FRAME_FORMATS


@dataclass
class Injection:
    """One injection evaluated under several defenses: the site, the metrics per defense and the
    frames (`frames["clean"]` and one [K, H, W, 3] float32 array per defense)."""

    site: dict
    metrics: dict[str, dict]
    frames: dict[str, np.ndarray] = field(repr=False)
    models: dict[str, Model] | None = field(default=None, repr=False)
    """With inject(models=True): the model as stored after the fault (`models["faulted"]`) and as
    each other defense leaves it (`models[defense]`), at the stored precision."""
    up: str | None = field(default=None, repr=False)
    source_format: str | None = field(default=None, repr=False)
    """The format of the model file the scene came from (None: an embedded scene or a Model)."""

    def error_map(self, defense: str = "none") -> np.ndarray:
        """Per-pixel maximum absolute channel error against the clean frames, [K, H, W] (NaN where
        a pixel is non-finite)."""
        from seuwgpu.report.panel import error_map

        err = error_map(self.frames["clean"], self.frames[defense])  # non-finite pixels: +inf there
        err[np.isinf(err)] = np.nan
        return err.astype(np.float32)

    def table(self) -> pd.DataFrame:
        """One row per defense: the site and its metrics, as a campaign record holds them."""
        return pd.DataFrame([{**self.site, **m} for m in self.metrics.values()])

    def save(self, out: str | Path, *, formats: Iterable[str] = ("png", "tiff")) -> list[Path]:
        """Every frame in each format - `clean_000.png`, `faulted_000.png` (no defense),
        `guard_000.png` (each defense by name), `error_faulted_000.png`, `error_guard_000.png`
        (max absolute channel error) - and the metrics as `metrics.json` (footprint as a fraction;
        NaN as null, an infinite value such as an identical frame's PSNR as "inf"). Returns the files written."""
        out = Path(out)
        files = []
        for name, frames in self.frames.items():
            files += save_frames(frames, out, frame_stem(name), formats=formats)
        for d in self.metrics:
            files += save_frames(self.error_map(d)[..., None], out, f"error_{frame_stem(d)}", formats=formats)
        out.mkdir(parents=True, exist_ok=True)
        path = out / "metrics.json"
        doc = {"site": self.site, "metrics": self.metrics, "units": {"footprint": "fraction of pixels (0-1)"}}
        path.write_text(json.dumps(json_safe(doc), indent=2, allow_nan=False) + "\n")
        return [*files, path]

    def save_models(self, out: str | Path, *, formats: Iterable[str] | None = None) -> list[Path]:
        """The faulted model and each defense's repaired one (`models`) as model files a splat viewer
        opens (`faulted.ply`, `guard.sog`, ...). Default `formats`: the scene file's format, where
        it has a writer (in the file's coordinates, to overlay the original), and the exact
        float32 PLY; an embedded scene: PLY and SPZ. Any of MODEL_FORMATS may be named; a file
        its format cannot hold (NaN) is left out with a warning (model.formats.save_models;
        docs/models.md, "Writing a damaged model"). Returns the files written."""
        from seuwgpu.model.formats import save_models

        if self.models is None:
            raise InputError("this injection kept no models: call inject(..., models=True)")
        names = None if formats is None else names_of(formats, "formats")
        return save_models(self.models, out, names, up=self.up, source=self.source_format)


def injected_models(eng, model: Model, site, defenses) -> dict[str, Model]:
    """The stored model (at the engine's precision) with the site's fault, as stored
    ("faulted"), and as each defense leaves what the renderer reads: its repair of memory (a
    reload, a correction, a culled primitive) and, for a support-guard defense, the clamp the
    pipeline applies to the hit primitive's values."""
    stored = model.quantized(eng.precision).flat()

    def with_rows(prims, rows) -> Model:
        flat = stored.copy()
        flat[prims] = encoding.from_bits(rows, eng.precision)
        return Model.from_flat(flat, model.sh_degree)

    prims, rows, _ = eng.variant_bits([site], "none")
    out = {"faulted": with_rows(prims, rows)}
    for d in defenses:
        if d == "none":
            continue
        prims, rows = eng.defended_rows([site], d)  # a frame check's dropped pair partner included
        out[d] = with_rows(prims, eng.drawn_rows(rows, eng.masks.get(d, 0)))
    return out


def mean_lpips(clean: np.ndarray, faulted: np.ndarray) -> float:
    """LPIPS (AlexNet) mean over the views; NaN when its weights are not installed, a frame is
    smaller than 32x32 or non-finite (undefined, not 0)."""
    from seuwgpu.metrics import lpips

    if not lpips.available() or min(clean.shape[1:3]) < 32:
        return float("nan")
    return float(np.mean(lpips.lpips(clean, faulted)))


def frame_stem(name: str) -> str:
    return "faulted" if name == "none" else name


def plain(d: dict) -> dict:
    """numpy scalars -> Python numbers, so the dicts serialise and compare plainly."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in d.items()}


def save_frames(
    images: np.ndarray | Sequence[np.ndarray], out: str | Path, stem: str, *, formats: Iterable[str] = ("png",)
) -> list[Path]:
    """Write [K, H, W, C] frames (C = 1 or 3) as `{stem}_{k:03d}.png` (display: clipped to [0, 1],
    non-finite pixels black), `.tiff` (float32, unclamped, non-finite kept) and/or one `{stem}.npz`.
    A list of [H, W, C] frames of several sizes (render_views of mixed views) is written as PNG
    and TIFF files alike; one npz array cannot hold it."""
    formats = tuple(names_of(formats, "formats"))
    unknown = sorted(set(formats) - set(FRAME_FILE_FORMATS))
    if unknown:
        raise InputError(
            f"unknown frame format(s) {', '.join(unknown)}; expected some of {', '.join(FRAME_FILE_FORMATS)}"
        )
    if isinstance(images, (list, tuple)) and len({np.shape(f) for f in images}) > 1:
        if "npz" in formats:
            raise InputError("frames of several sizes do not fit one npz array; write png or tiff files")
        images = [np.asarray(f, np.float32) for f in images]
        if any(f.ndim != 3 or f.shape[-1] not in (1, 3) for f in images):
            raise InputError(f"frames must be [H, W, 1 or 3], got shapes {[list(f.shape) for f in images]}")
    else:
        images = np.asarray(images, np.float32)
        if images.ndim != 4 or images.shape[-1] not in (1, 3):
            raise InputError(f"frames must be [K, H, W, 1 or 3], got shape {list(images.shape)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    if "npz" in formats:
        paths.append(out / f"{stem}.npz")
        np.savez(paths[-1], images=images)  # uncompressed, as the CLI's (float32 frames barely compress)
    for i, img in enumerate(images):
        if "png" in formats:
            import imageio.v3 as iio

            disp = display(img)  # the display-referred frame the metrics use
            paths.append(out / f"{stem}_{i:03d}.png")
            pixels = (disp * 255 + 0.5).astype(np.uint8)
            iio.imwrite(paths[-1], pixels[..., 0] if img.shape[-1] == 1 else pixels, extension=".png")
        if "tiff" in formats:
            import tifffile

            paths.append(out / f"{stem}_{i:03d}.tiff")
            grey = img.shape[-1] == 1
            tifffile.imwrite(paths[-1], img[..., 0] if grey else img, photometric="minisblack" if grey else "rgb")
    return paths
