"""The public Python API: what a script or a notebook needs, importable from the package root.

    import seuwgpu as sg
    scene = sg.load_model("leica-sofort")             # an embedded scene, or any model file
    cams = sg.cameras(scene, views=2, size=(256, 256))  # or cameras=PATH: the capture's own
    images = sg.render_views(scene, cams)                    # float32 [K, H, W, 3], unclamped
    inj = sg.inject(scene, cams, field="log_scales", bit=31, defenses=("none", "guard"))
    inj.metrics["none"]["footprint"]                   # a fraction of the frame's pixels
    inj.save("out/")                                   # PNG, float32 TIFF, metrics.json
    stats = sg.run_campaign({"scenes": [{"scene": "spheres"}], ...}, "runs/x", progress=print)
    sg.run_campaign(sg.default_spec(), "runs/demo")     # the packaged default spec (seuwgpu demo)
    df = sg.read_records("runs/x")                     # a pandas DataFrame of the records
    sg.make_report(["runs/x"], "runs/x/report")        # HTML, figures, tables, summary.json
    sg.storm(scene, cams, k=10, frames=50)             # upsets accumulating, one record a frame
    sg.state_flips(scene, cams, samples=10)            # transient flips in the pipeline state
    sg.worst_case(scene, cams, defenses=("guard",))    # the largest footprint, certified

`render_views` is not called `render` because `seuwgpu.render` is the renderer's sub-package.
The command line (apps/cli/) is a thin layer over these functions. Units: the footprint is a
fraction (0-1) in every record, dict and JSON file; only text for people prints it as a percent.
Undefined values (PSNR of a frame with non-finite pixels, say) are NaN in data and null in JSON.
Bad input raises seuwgpu.InputError (a ValueError) or FileNotFoundError whose message names the
input and the problem, as the command line prints it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.campaign.spec import Spec
from seuwgpu.campaign.store import CampaignRun
from seuwgpu.errors import InputError, RunInUse, SeuwgpuError, TooBig
from seuwgpu.faults.defenses import DEFENSES, check_defense
from seuwgpu.faults.schedule import DEFAULT_CHECK_EVERY
from seuwgpu.faults.sites import (
    ADJACENT_WIDTHS,
    BURST_WIDTHS,
    FAULT_MODELS,
    INJECT_SAMPLE,
    VALUE_MODELS,
    check_site_model,
    model_bits,
)
from seuwgpu.gpu.constants import PROFILES
from seuwgpu.metrics.image import display
from seuwgpu.model import corpus, encoding
from seuwgpu.model.budget import MAX_SCALE, MAX_VIEWS, MIN_VIEW_SIZE
from seuwgpu.model.cameras import Camera, check_one_size, image_sizes
from seuwgpu.model.corpus import CorpusModel
from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.formats import writable_formats
from seuwgpu.model.scenes import list_scenes
from seuwgpu.model.sources import Source, load_source, source_views
from seuwgpu.report.format import json_safe

__all__ = [
    "DEFENSES",
    "FAULT_MODELS",
    "FIELDS",
    "FRAME_FORMATS",
    "MODEL_FORMATS",
    "PRECISIONS",
    "PROFILES",
    "Camera",
    "InputError",
    "Injection",
    "Model",
    "RunInUse",
    "Scene",
    "SeuwgpuError",
    "TooBig",
    "assemble_corpus",
    "cameras",
    "corpus_models",
    "default_spec",
    "defense_costs",
    "device_info",
    "export_scene",
    "inject",
    "list_scenes",
    "load_model",
    "make_report",
    "merge_runs",
    "outcome_rates",
    "plan_campaign",
    "read_records",
    "render_views",
    "report_figures",
    "run_campaign",
    "save_frames",
    "sort_first",
    "state_flips",
    "storm",
    "worst_case",
]

PRECISIONS = tuple(encoding.PRECISIONS)
FRAME_FORMATS = ("png", "tiff", "npz")
"""png: 8-bit display frames (clipped to [0, 1], non-finite pixels black); tiff: float32,
unclamped, non-finite values kept; npz: all frames of a call in one float32 array."""
MODEL_FORMATS = writable_formats()
"""The formats Injection.save_models writes: model.formats.REGISTRY's with a writer."""

Scene = Source
"""A loaded model (`.model`), its display name (`.name`), the up axis that frames it (`.up`) and
notes for the user (`.notes`, e.g. "trained antialiased")."""


# ---- models and cameras ---------------------------------------------------------------------------
def load_model(
    source: str | Path,
    *,
    n: int | None = None,
    sh_degree: int = 3,
    seed: int = 0,
    up: str | None = None,
    lod: int | None = None,
) -> Scene:
    """An embedded scene by name (`list_scenes()`: procedural ones and two real captures) or any
    supported model file or INRIA output folder, recognised by content (INRIA PLY, compressed PLY,
    .splat, .spz, .ksplat, SOG, a PlayCanvas LOD set, gsplat .pt). `n`, `sh_degree` and `seed`
    shape embedded scenes (`n` with a file is refused: a model file keeps all of its primitives);
    `up` overrides the up axis used to frame the model without cameras ("+z", "-y", ...); `lod` picks the level of
    a PlayCanvas LOD set (lod-meta.json or its folder; default 0, the finest), refused otherwise."""
    if lod is not None and (isinstance(lod, bool) or not isinstance(lod, int) or lod < 0):
        raise InputError(f"lod must be a level 0, 1, 2, ..., got {lod!r}")
    if not isinstance(source, (str, Path)):
        raise InputError(f"source must be a scene name or a model path, got {source!r}")
    path = Path(source)
    if isinstance(source, Path) or path.exists() or path.suffix or "/" in str(source):
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such model file or folder")
        if n is not None:  # refused, not ignored, as the command line refuses --n with --model
            raise InputError(f"n sets the primitives of an embedded scene; a model file keeps all of its own ({path})")
        return load_source(path=path, up=up, lod=lod)
    name = str(source)
    if lod is not None:
        raise InputError(f"lod picks a level of a PlayCanvas LOD set (a model path), not of the scene {source!r}")
    if name not in list_scenes():
        raise InputError(f"{name!r} is neither a file nor an embedded scene; scenes: {', '.join(list_scenes())}")
    return load_source(scene=name, n=n, sh_degree=sh_degree, seed=seed, up=up)


def cameras(
    scene: Scene,
    *,
    cameras: str | Path | None = None,
    views: int | None = None,
    size: tuple[int, int] | None = None,
    scale: float | None = None,
) -> list[Camera]:
    """The views to render: a camera file's (CAMS.json, INRIA cameras.json, a COLMAP model,
    nerfstudio transforms.json; all of them or `views` evenly), else `views` (default 4) orbit
    views of `size` (width, height; default 256 x 256) that frame the model; `scale` multiplies
    the resolution. A camera file gives each view its own size: `size` beside `cameras` is
    refused (as the command line refuses --size with --cameras), not ignored; use `scale`. The
    command line's limits hold here too: 1..64 views, sides of at least 16 px, scale in (0, 16]."""
    _check_scene(scene)
    if views is not None and _whole(views, "views", 1) > MAX_VIEWS:
        raise InputError(f"views must be at most {MAX_VIEWS}, got {views}")
    if cameras is not None and size is not None:
        raise InputError("size sets orbit views; a cameras file gives each view its own size (use scale)")
    w, h = _size((256, 256) if size is None else size)
    if min(w, h) < MIN_VIEW_SIZE:
        raise InputError(f"size must be at least {MIN_VIEW_SIZE} px a side (one tile), got {size!r}")
    number = isinstance(scale, (int, float)) and not isinstance(scale, bool)
    if scale is not None and not (number and math.isfinite(scale) and 0 < scale <= MAX_SCALE):
        raise InputError(f"scale must be a number in (0, {MAX_SCALE}], got {scale!r}")
    return source_views(scene, cameras, views, (w, h), scale, default_views=4)


def export_scene(
    name: str, out: str | Path, *, n: int | None = None, sh_degree: int = 3, seed: int = 0
) -> tuple[Model, str]:
    """Write an embedded scene (`list_scenes()`) as an INRIA PLY (`.ply`) or a Niantic SPZ
    (`.spz`), chosen by the extension: a procedural scene +z up, a real capture +y up with its
    antialiased flag in the SPZ header. Returns (the model written, the format)."""
    from seuwgpu.model.captures import capture_antialiased
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.scenes import is_capture, make_scene

    if name not in list_scenes():
        raise InputError(f"{name!r} is not an embedded scene; scenes: {', '.join(list_scenes())}")
    model = make_scene(name, n=n, sh_degree=sh_degree, seed=seed)
    capture = is_capture(name)  # a real capture's antialiased flag goes into an SPZ header (PLY has none)
    aa = {"antialiased": True} if capture and capture_antialiased(name) else {}
    fmt = save_model(model, _out_path(out, "model file"), up="+y" if capture else "+z", **aa)
    return model, fmt


def corpus_models(manifest: str | Path | None = None) -> list[CorpusModel]:
    """The models of the corpus of real trained models (the packaged manifest, or `manifest`): each
    with its subject, primitives, SH degree, format, source, licence, credit and files (docs/corpus.md)."""
    return list(corpus.load_manifest(manifest).values())


def assemble_corpus(
    out: str | Path,
    source: str | Path | None = None,
    models: Iterable[str] | None = None,
    *,
    manifest: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> dict[str, Path]:
    """Assemble the corpus (or the named `models`) into the folder `out`: every file read from the
    folder `source` (same layout, or found by its name) or, without it, downloaded from its pinned
    URL; its size and sha256 checked (a differing file is refused, naming it, and not kept); files
    already there with the right hash kept. Writes `out/corpus.json` and `out/INDEX.md`; returns
    {model: the path to pass as --model}. `progress(done_bytes, total_bytes)`, `log(line)`."""
    return corpus.assemble(out, source=source, models=models, manifest=manifest, progress=progress, log=log)


def device_info() -> dict:
    """The adapter in use: device, vendor, backend, adapter type, driver, its features and its
    limits (WebGPU names)."""
    from seuwgpu.gpu.device import get_gpu

    gpu = get_gpu()
    info = gpu.info
    return {
        "device": info.get("device"),
        "vendor": info.get("vendor"),
        "backend": info.get("backend_type"),
        "adapter_type": info.get("adapter_type"),
        "driver": info.get("description"),
        "features": sorted(gpu.adapter.features),
        "limits": dict(gpu.limits),
    }


# ---- rendering ------------------------------------------------------------------------------------
def render_views(
    scene: Scene | Model,
    views: Sequence[Camera],
    *,
    precision: str = "fp32",
    profile: str = "strict",
    compositor: str | None = None,
) -> np.ndarray | list[np.ndarray]:
    """The views of the model stored at `precision`: float32 [K, H, W, 3], unclamped (values of a
    corrupted model may be negative, above 1 or non-finite); views of several image sizes (a
    capture mixing portrait and landscape photos) are rendered size by size and returned as a
    list of K float32 [H, W, 3] frames in the views' order. `profile` is the renderer's rule set
    for corrupted values (PROFILES: "strict", or "gsplat" as gsplat's CUDA kernels; docs/renderer.md).
    `compositor`: the compositor's shape, "lanes" or "wide" (the same frames bit for bit; "wide"
    is the shape GPUs fill, docs/renderer.md); None: the device's default."""
    from seuwgpu.render.renderer import render_split

    model = _model_of(scene)
    from seuwgpu.render.composite import check_shape

    shape = None if compositor is None else check_shape(compositor)
    views, precision, profile = _views(views), encoding.check_precision(precision), _profile(profile)
    sizes = image_sizes(views)
    if len(sizes) == 1:  # frames larger than one storage binding: in view groups or tile-row bands
        return render_split(model, views, precision, profile=profile, compositor=shape)
    frames: list = [None] * len(views)
    for size in sizes:
        idx = [i for i, c in enumerate(views) if (c.width, c.height) == size]
        group = render_split(model, [views[i] for i in idx], precision, profile=profile, compositor=shape)
        for i, frame in zip(idx, group):
            frames[i] = frame
    return frames


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
            files += save_frames(frames, out, _frame_stem(name), formats=formats)
        for d in self.metrics:
            files += save_frames(self.error_map(d)[..., None], out, f"error_{_frame_stem(d)}", formats=formats)
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
        names = None if formats is None else _names(formats, "formats")
        return save_models(self.models, out, names, up=self.up, source=self.source_format)


def inject(
    scene: Scene | Model,
    views: Sequence[Camera],
    *,
    field: str,
    bit: int | Sequence[int] | None,
    component: int = 0,
    primitive: int | None = None,
    precision: str = "fp32",
    defenses: Sequence[str] = ("none", "guard"),
    sample: int = INJECT_SAMPLE,
    seed: int = 0,
    profile: str = "strict",
    fault: str = "bit",
    width: int = 2,
    models: bool = False,
) -> Injection:
    """Corrupt `field[primitive][component]` in the stored model with one fault and evaluate the
    render under each defense against the clean render. `fault` is a FAULT_MODELS name: "bit"
    flips `bit` (or each of several bits of the word), "adjacent" flips `width` neighbouring bits
    ending at `bit` (a multi-cell upset), "stuck0"/"stuck1" force the bits, "zero"/"random" replace
    the whole value (random: drawn from `seed`; `bit` is ignored) (footprint, peak
    error, PSNR, SSIM, non-finite pixels, and LPIPS when `seuwgpu[lpips]` is installed). Without
    `primitive`, the most harmful of `sample` (default 64, as `seuwgpu inject --sample`) randomly
    drawn primitives (seeded) is taken. The
    stored model is restored exactly afterwards. `models`: also keep the faulted model and each
    defense's repaired one (`Injection.models`, written by `Injection.save_models`)."""
    defenses = _defense_names(defenses)
    if not isinstance(sample, int) or isinstance(sample, bool) or sample < 1:
        raise InputError(f"sample must be a positive integer, got {sample!r}")
    _whole(component, "component", 0)  # 1.7 was truncated to primitive 1, True taken as 1
    if primitive is not None:
        _whole(primitive, "primitive", 0)
    _whole(seed, "seed", 0 if primitive is None or fault == "random" else None)  # numpy's seeds are >= 0
    bits, op, value = _fault_bits(fault, bit, width, precision, seed)
    eng = _engine(scene, views, precision, profile, "inject")
    model_of = _model_of(scene)
    if primitive is None:
        primitive, _ = eng.worst_primitive(field, component, bits, sample, seed, defenses[0], op, value)
    site = eng.site(field, int(primitive), component, bits, op, value)
    frames = {"clean": eng.clean.copy()}
    metrics = {}
    site_info = None
    for d in defenses:
        rec = eng.inject(site, d)
        frames[d] = eng.last_frame()[..., :3].copy()  # the frame inject measured: no second render
        rec["lpips"] = _mean_lpips(frames["clean"], frames[d])
        site_keys = ("scene", "n_primitives", "precision", "fault", "field", "primitive", "component", "bit_class")
        site_info = site_info or {
            **{k: rec[k] for k in site_keys},
            "bits": list(site.bits),
            "clean_value": rec["clean_value"],
            "corrupted_value": rec["corrupted_value"],
        }
        metrics[d] = {k: v for k, v in rec.items() if k not in site_info and k not in ("bit", "k")}
    kept = _injected_models(eng, model_of, site, defenses) if models else None
    up = scene.up if isinstance(scene, Source) else None
    src = scene.format if isinstance(scene, Source) else None
    return Injection(_plain(site_info), {d: _plain(m) for d, m in metrics.items()}, frames, kept, up, src)


def storm(
    scene: Scene | Model,
    views: Sequence[Camera],
    *,
    k: int = 10,
    frames: int = 50,
    scrub_every: int = 10,
    defenses: Sequence[str] = ("none", "guard", "parity4r"),
    seed: int = 0,
    precision: str = "fp32",
    profile: str = "strict",
    progress: Callable[[], None] | None = None,
    rows: list | None = None,
    check_every: int = 1,
    fault: str = "bit",
) -> pd.DataFrame:
    """A fault storm (campaign/storm.py): `k` upsets per frame accumulating in the stored model for
    `frames` frames, reloaded every `scrub_every` frames (0: never), each defense an arm that sees
    the same upsets; a check defense checks (and repairs) every `check_every` frames. `fault`: the
    upsets' fault model (FAULT_MODELS: a burst, a random value, a multi-cell upset). One record
    per frame and defense. `progress()` is called after each frame;
    `rows`: a list the records are appended to as they are measured (a resumed storm's records
    first: it goes on after them)."""
    from seuwgpu.campaign.storm import storm as run_storm

    defenses = _defense_names(defenses)
    for value, what in ((k, "k"), (frames, "frames"), (scrub_every, "scrub_every"), (seed, "seed")):
        _whole(value, what, None)  # the ranges: campaign/storm.py's own check, which names all three
    _whole(check_every, "check_every", 1)
    if fault not in FAULT_MODELS:
        raise InputError(f"unknown fault model {fault!r}; expected one of {', '.join(FAULT_MODELS)}")
    eng = _engine(scene, views, precision, profile, "storm")
    return run_storm(
        eng, k, frames, scrub_every, defenses, seed, progress, rows=rows, check_every=check_every, fault=fault
    )


def state_flips(
    scene: Scene | Model,
    views: Sequence[Camera],
    *,
    targets: Sequence[str] | None = None,
    samples: int = 10,
    bits: Sequence[int] | None = None,
    seed: int = 0,
    precision: str = "fp32",
    profile: str = "strict",
    progress: Callable[[], None] | None = None,
    rows: list | None = None,
) -> pd.DataFrame:
    """Transient bit flips in one frame's pipeline state (faults/state.py): `samples` flips per
    (target, bit) cell, `targets` the pipeline-state buffers (default: all), `bits` 0..31 (default:
    all). One record per flip; `progress` and `rows` as `storm`'s."""
    from seuwgpu.faults.state import TARGETS, state_campaign

    targets = list(TARGETS) if targets is None else list(dict.fromkeys(_names(targets, "targets")))
    bits = list(range(32)) if bits is None else list(dict.fromkeys(_whole(b, "bit", None) for b in bits))
    _whole(samples, "samples", 1)
    _whole(seed, "seed", None)
    eng = _engine(scene, views, precision, profile, "state_flips")
    return state_campaign(eng, targets, samples, bits, seed, progress, rows=rows)


def worst_case(
    scene: Scene | Model,
    views: Sequence[Camera],
    *,
    defenses: Sequence[str] = ("none",),
    fields: Sequence[str] | None = None,
    bits: Sequence[int] | None = None,
    max_evaluations: int | None = None,
    precision: str = "fp32",
    profile: str = "strict",
) -> dict:
    """The single-bit flip with the largest footprint under each defense, by bounded search
    (faults/worstcase.py): {defense: WorstCase(site, footprint, certified bound, evaluated,
    sites)}. `fields`: default every field the model stores; `bits`: default all;
    `max_evaluations`: stop after this many renders (the bound stays certified)."""
    from seuwgpu.faults.worstcase import worst_case as search
    from seuwgpu.model.fields import canonical_field

    defenses = _defense_names(defenses)
    if fields is not None:
        try:
            fields = [canonical_field(f) for f in _names(fields, "fields")]
        except ValueError as e:
            raise InputError(str(e)) from None
    if bits is not None:
        bits = [_whole(b, "bit", 0) for b in bits]
    if max_evaluations is not None:
        _whole(max_evaluations, "max_evaluations", 1)
    eng = _engine(scene, views, precision, profile, "worst_case")
    return {d: search(eng, d, fields, bits, max_evaluations=max_evaluations) for d in defenses}


def defense_costs(
    scene: Scene | Model,
    view: Camera,
    *,
    precision: str = "fp32",
    repeats: int = 7,
    time_it: bool = True,
    check_every: int = DEFAULT_CHECK_EVERY,
    visible: int = 0,
    window: int = 20,
    visible_defenses: Sequence[str] | None = None,
    seed: int = 0,
    fault: str = "bit",
) -> list[dict]:
    """Every defense with the bytes it holds on the device (and as a fraction of the model's), its
    time per frame (a fraction of the undefended view's on this device, measured as a schedule:
    `check_every` frames and a check against `check_every` frames, interleaved, the median of
    `repeats` rounds with its 95% interval; NaN with time_it=False), its exposure and, with
    `visible` upsets, what the user sees (campaign/visible.py: catastrophic and SDC frames per
    upset, exposure counted, measured by running `visible` windows of `window` frames on `view`,
    for `visible_defenses` (default every defense); NaN for those not measured):
    [{name, device_bytes, memory_overhead, check_every, time_fraction, time_lo, time_hi,
    check_fraction, repair_fraction, exposure_frames, exposure_frames_worst,
    catastrophic_frames_per_upset, catastrophic_lo, catastrophic_hi, sdc_frames_per_upset,
    residue_frames_per_upset, of_none, of_none_lo, of_none_hi, visible_basis, time_basis,
    description}]."""
    from seuwgpu.faults.costs import defense_costs as costs

    _whole(repeats, "repeats", 1)
    _whole(check_every, "check_every", 1)
    _whole(visible, "visible", 0)
    _whole(window, "window", 1)
    if fault not in FAULT_MODELS:
        raise InputError(f"unknown fault model {fault!r}; expected one of {', '.join(FAULT_MODELS)}")
    if not isinstance(view, Camera):
        raise InputError(f"view must be a Camera (from cameras()), got {type(view).__name__}")
    names = _defense_names(visible_defenses) if visible_defenses is not None else list(DEFENSES)
    model = _model_of(scene)
    rows = costs(model, view, encoding.check_precision(precision), repeats, time_it=time_it, check_every=check_every)
    keys = ("catastrophic_frames_per_upset", "catastrophic_lo", "catastrophic_hi", "sdc_frames_per_upset")
    keys += ("residue_frames_per_upset", "of_none", "of_none_lo", "of_none_hi")
    got, basis = {}, "not measured (--visible N)"
    if visible:
        from seuwgpu.campaign.visible import visible_damage

        eng = _engine(scene, [view], precision, "strict", "measure visible damage")
        summary, _ = visible_damage(eng, names, check_every, visible, window, fault=fault, seed=seed)
        got = {r["defense"]: r for r in summary.to_dict("records")}
        w = int(summary["window"].iloc[0])
        basis = (
            f"measured: {visible} upsets ({fault} faults of the dangerous cells), one per window of {w} frames "
            f"reloaded at its start, landing at a uniform frame; {view.width}x{view.height}, seed {seed}"
        )
    for r in rows:
        m = got.get(r["name"])
        for k in keys:
            r[k] = float(m[k]) if m is not None else float("nan")
        r["visible_basis"] = basis if m is not None else "not measured"
    return rows


def sort_first(
    scene: Scene | Model,
    views: Sequence[Camera],
    *,
    ranks: Sequence[int] = (4,),
    upset: str | None = None,
    component: int = 0,
    primitive: int | None = None,
    sample: int = 32,
    seed: int = 0,
    guard: str = "scrub",
    repeats: int = 3,
    precision: str = "fp32",
    address: str | None = None,
) -> list[dict]:
    """Sort-first rendering over Ray ranks (campaign/sortfirst.py; needs `seuwgpu[ray]`): for each
    rank count P, the per-rank render times and, with `upset` ("field:bit", e.g. "log_scales:31",
    applied to every rank's copy), the ranks it contaminates with and without the node-local
    `guard` ("scrub" the stored copy, or "clamp" in the pipeline). Without `primitive`, the most
    harmful of `sample` primitives. Prints a table per rank count; returns the results."""
    from seuwgpu.campaign.ray import INSTALL_HINT, ray_available
    from seuwgpu.campaign.sortfirst import parse_upset, sort_first_tables

    if not ray_available():
        raise InputError(f"sort-first rendering needs Ray. {INSTALL_HINT}")
    for p in ranks:
        _whole(p, "ranks", 1)
    parsed = None if upset is None else parse_upset(upset)
    kw = {"component": component, "primitive": primitive, "sample": sample, "seed": seed, "guard": guard}
    return sort_first_tables(
        _model_of(scene), _views(views), encoding.check_precision(precision), list(ranks), parsed,
        address=address, repeats=repeats, **kw,
    )  # fmt: skip


def save_frames(
    images: np.ndarray | Sequence[np.ndarray], out: str | Path, stem: str, *, formats: Iterable[str] = ("png",)
) -> list[Path]:
    """Write [K, H, W, C] frames (C = 1 or 3) as `{stem}_{k:03d}.png` (display: clipped to [0, 1],
    non-finite pixels black), `.tiff` (float32, unclamped, non-finite kept) and/or one `{stem}.npz`.
    A list of [H, W, C] frames of several sizes (render_views of mixed views) is written as PNG
    and TIFF files alike; one npz array cannot hold it."""
    formats = tuple(_names(formats, "formats"))
    unknown = sorted(set(formats) - set(FRAME_FORMATS))
    if unknown:
        raise InputError(f"unknown frame format(s) {', '.join(unknown)}; expected some of {', '.join(FRAME_FORMATS)}")
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


# ---- campaigns and reports ------------------------------------------------------------------------
def default_spec() -> Path:
    """The path of the packaged default spec (the main job that `seuwgpu demo` runs: every field
    and bit of the `spheres` scene at fp32, with and without the guard), wherever the package is
    installed and whatever the working directory: `run_campaign(default_spec(), "runs/x")`, or a
    starting point to copy (`default_spec().read_text()`)."""
    from seuwgpu.campaign.spec import default_spec_path

    return default_spec_path()


def run_campaign(
    spec: dict | str | Path | Spec,
    out: str | Path,
    *,
    progress: Callable[[int, int, int], None] | bool | str | None = None,
    full: bool = False,
    shard: tuple[int, int] = (0, 1),
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
) -> dict:
    """Run (or resume) the campaign of a spec (a dict with the keys of a spec file, a TOML path such
    as `default_spec()`, or a validated `campaign.spec.Spec`) into the run directory `out`.
    `progress(done, total, catastrophic)` is called after each block of injections;
    `progress=True` shows a rich progress bar (also in a notebook), "log" a line on stderr every
    10 s (a batch job's log), None or False nothing. `executor="ray"` runs the shard's blocks on
    Ray workers (`workers` in flight, the cluster at `address`; needs `seuwgpu[ray]`), with the
    bar or the log lines. Returns {injections, new, catastrophic, seconds, campaign_total} (Ray:
    and workers, shards, resubmitted)."""
    from seuwgpu.campaign.runner import Runner

    spec = _spec(spec)
    if executor not in ("local", "ray"):
        raise InputError(f'executor must be "local" or "ray", got {executor!r}')
    if isinstance(progress, str) and progress != "log":
        raise InputError(f'progress must be a function, True, "log" or None, got {progress!r}')
    out = _out_path(out, "run directory")
    if executor == "ray":
        from seuwgpu.campaign.ray import run_ray

        quiet = progress is not True
        return run_ray(spec, out, workers=workers, address=address, quiet=quiet, full=full, shard=shard)
    runner = Runner(spec, out, shard=shard, quiet=progress is not True, full=full)
    if progress is True or progress == "log":
        stats = runner.run()
    else:
        stats = runner.run(lambda total, done: _Callback(progress or None, total, done))
    return {**stats, "campaign_total": runner.total}


def plan_campaign(spec: dict | str | Path | Spec) -> pd.DataFrame:
    """What a spec will run, one row per context (campaign section, scene, primitive count,
    precision): cells, samples per cell, injections, arms (defenses), records, and the margin of
    error of a cell's rate (95% confidence, worst case p = 0.5, sites drawn with replacement; NaN
    for dose contexts); `n` is <NA> for a model file's own primitives. `spec` as run_campaign
    takes it."""
    from seuwgpu.campaign.plan import margin_of_error
    from seuwgpu.campaign.sampling import enumerate_contexts
    from seuwgpu.campaign.spec import scene_label

    spec = _spec(spec)
    rows = []
    for ctx in enumerate_contexts(spec):
        sc = spec.scenes[ctx.scene_index]
        rows.append(
            {
                "campaign": ctx.kind,
                "scene": scene_label(sc),
                "n": ctx.n or sc.n,
                "precision": ctx.precision,
                "cells": len(ctx.cells),
                "per_cell": ctx.per_cell,
                "injections": ctx.count,
                "arms": len(ctx.defenses),
                "records": ctx.count * len(ctx.defenses),
                "margin": float("nan") if ctx.kind == "dose" else margin_of_error(ctx.per_cell, 0.95),
            }
        )
    plan = pd.DataFrame(rows)
    plan["n"] = pd.array(plan["n"].tolist(), dtype="Int64")  # exact counts; <NA>: a model file's own
    return plan


def merge_runs(shards: Iterable[str | Path], out: str | Path, *, allow_partial: bool = False) -> dict:
    """Join the run directories of `--shard` slices of one spec into the run directory `out` (a
    slice run twice, or a whole run beside its slices, merges). `allow_partial`: merge even when
    parts are missing. Returns {parts, missing_parts} (missing: [first id, count] each)."""
    from seuwgpu.campaign import store
    from seuwgpu.campaign.merge import merge

    shards = [_out_path(d, "shard directory") for d in _paths(shards)]
    n = merge(_out_path(out, "run directory"), shards, allow_partial=allow_partial)
    missing = (store.read_manifest(out) or {}).get("missing_parts", [])
    return {"parts": n, "missing_parts": missing}


class _Callback:
    """Adapts a progress function to the runner's progress protocol (advance, close)."""

    def __init__(self, fn, total: int, done: int):
        # made by the runner once the run directory is locked and checked: reading (and deleting
        # damaged) parts before then removed the parts of another spec's run in `out`
        self.fn, self.total, self.done, self.cat = fn, total, done, 0

    def advance(self, n: int, cat: int):
        self.done += n
        self.cat += cat
        if callable(self.fn):
            self.fn(self.done, self.total, self.cat)

    def close(self):
        pass


def read_records(*runs: str | Path) -> pd.DataFrame:
    """The Parquet records of one or more run directories (or one list of them) as one DataFrame
    (one row per injection and defense; the footprint is a fraction)."""
    from seuwgpu.report.build import load_runs

    if len(runs) == 1 and isinstance(runs[0], (list, tuple)):  # a list of runs, as make_report takes
        runs = tuple(runs[0])
    if not runs:
        raise InputError("read_records needs at least one run directory")
    df, _ = load_runs([Path(_existing(r, "run directory")) for r in runs])
    return df


def make_report(
    runs: str | Path | Iterable[str | Path],
    out: str | Path,
    fold: bool | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
    target: float | None = None,
) -> Path:
    """Write the report of the runs (HTML, figures as PNG, tables as CSV and Markdown,
    summary.json) into `out`; returns the path of index.html. fold: fold the records as they
    are read (the same numbers in less memory; None: only when they would not fit unfolded).
    target: the residual catastrophic rate per upset the summary's cheapest defense must meet
    (None: the runs' spec `[summary] target`, else 0.001).
    `progress(parts read, parts)` as the parts are read; `workers`: processes folding parts side
    by side (default: one per CPU, at most 8, from 256 parts on). `runs` may also be the
    campaign_runs of campaign/store.py (their manifests read once by the caller)."""
    from seuwgpu.campaign.store import make_out_dir
    from seuwgpu.report.build import build_report

    runs = [r if isinstance(r, CampaignRun) else _existing(r, "run directory") for r in _paths(runs)]
    out = make_out_dir(_out_path(out, "report folder"), what="report folder")
    return build_report(runs, out, fold=fold, progress=progress, workers=workers, target=target)


def outcome_rates(
    runs: str | Path | Iterable[str | Path],
    *,
    by: Sequence[str] = ("scene", "precision", "defense"),
    campaign: str = "single",
    progress: Callable[[int, int], None] | None = None,
) -> pd.DataFrame:
    """The weighted rate of each outcome class and of non-finite frames, with its 95% interval
    (Wilson per cell, stratified Wilson when pooled), per group of the record columns `by`
    (`run` too), folded part by part: any number of records, and runs still going. Defenses and
    renderer profiles always get rows of their own. `campaign`: "single" or "size" (the
    primitive-count sweep). Columns: the groups, n, then {outcome}_rate, _ci_lo, _ci_hi as
    proportions; `.attrs`: records, parts, groups (the columns grouped by) and partial (a
    sentence naming unfinished runs, "" if none)."""
    from seuwgpu.analysis.cells import fold_runs, groups
    from seuwgpu.analysis.cells import outcome_rates as rates
    from seuwgpu.campaign.store import campaign_runs, check_record_columns, partial_runs_text

    by = list(dict.fromkeys(_names(by, "by")))  # a column named twice: once
    check_record_columns(by, "by")
    if campaign not in ("single", "size"):
        raise InputError(f'campaign must be "single" or "size", got {campaign!r}')
    found = campaign_runs(_paths(runs))  # a folder that is no run: fold_runs says so
    cells, n_parts = fold_runs(found, by, campaign, progress)
    by = groups(cells, by)  # several renderer profiles: a row each, never pooled
    table = rates(cells, by)
    table.attrs.update(records=int(cells["n_records"].sum()), parts=n_parts, groups=by)
    table.attrs["partial"] = partial_runs_text(found)
    return table


def report_figures(runs: str | Path | Iterable[str | Path]) -> dict:
    """The report's figures as matplotlib figures, by name (analyses the records cannot support
    are left out, as the report skips them)."""
    from seuwgpu.report import build

    runs = [runs] if isinstance(runs, (str, Path)) else list(runs)
    df, manifests = build.load_runs([_existing(r, "run directory") for r in runs])
    return build.section_figures(df, manifests)


# ---- helpers --------------------------------------------------------------------------------------
def _fault_bits(fault, bit, width, precision, seed) -> tuple[tuple[int, ...], str, int]:
    """(bits, op, value) of one fault, as faults/sites.py applies it."""
    try:
        check_site_model(fault)
    except ValueError as e:
        raise InputError(str(e)) from None
    if fault in VALUE_MODELS:
        return model_bits(fault, -1, precision, int(np.random.default_rng(seed).integers(2**63)))
    if bit is None:
        raise InputError(f"fault {fault!r} needs bit=")
    if isinstance(bit, (str, bytes)) or not isinstance(bit, (int, np.integer, Iterable)):
        raise InputError(f"bit must be an integer or a list of integers, got {bit!r}")
    bits = [bit] if isinstance(bit, (int, np.integer)) else list(bit)
    for b in bits:  # the bit asked for, named before an adjacent burst moves below it
        _whole(b, "bit", None)
        try:
            encoding.check_bit(precision, b)
        except ValueError as e:
            raise InputError(str(e)) from None
    if fault in ("adjacent", "burst") and len(bits) == 1:
        widths = ADJACENT_WIDTHS if fault == "adjacent" else BURST_WIDTHS
        if width not in widths:
            raise InputError(f"{fault} width must be one of {', '.join(map(str, widths))}, got {width!r}")
        return model_bits(fault, int(bits[0]), precision, widths.index(width))
    return tuple(int(b) for b in bits), ("flip" if fault in ("bit", "adjacent", "burst") else fault), 0


def _spec(spec) -> Spec:
    """A validated spec from a dict (files relative to the working folder), a TOML path or a Spec."""
    from seuwgpu.campaign.spec import load_spec, normalize_spec

    if isinstance(spec, dict):
        return normalize_spec(spec, base_dir=Path.cwd())
    if isinstance(spec, (str, Path)):
        return load_spec(spec)
    if not isinstance(spec, Spec):
        raise InputError(f"spec must be a dict, a Spec or the path of a TOML file, got {type(spec).__name__}")
    return spec


def _engine(scene, views, precision: str, profile: str, what: str):
    """The fault-injection engine (faults/engine.py) of a model and its views, one image size."""
    from seuwgpu.faults.engine import Engine

    model = _model_of(scene)
    name = scene.name if isinstance(scene, Source) else "model"
    views = _views(views)
    check_one_size(views, "views", what)
    return Engine(model, views, encoding.check_precision(precision), scene=name, profile=_profile(profile))


def _injected_models(eng, model: Model, site, defenses) -> dict[str, Model]:
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
        prims, rows, masks = eng.variant_bits([site], d)
        out[d] = with_rows(prims, eng.drawn_rows(rows, masks[0]))
    return out


def _defense_names(defenses) -> tuple[str, ...]:
    """Defense names checked, each once (an arm named twice is one arm)."""
    names = tuple(dict.fromkeys(check_defense(d) for d in _names(defenses, "defenses")))
    if not names:
        raise InputError("defenses must name at least one defense")
    return names


def _profile(profile) -> str:
    """render's check_profile (the one definition of the names) raising the API's InputError."""
    from seuwgpu.render.project import check_profile

    try:
        return check_profile(profile if isinstance(profile, str) else repr(profile))
    except ValueError as e:
        raise InputError(str(e)) from None


def _check_scene(scene):
    if not isinstance(scene, Source):
        raise InputError(f"expected a scene from load_model(), got {type(scene).__name__}")


def _model_of(scene) -> Model:
    if isinstance(scene, Source):
        return scene.model
    if isinstance(scene, Model):
        return scene
    raise InputError(f"expected a scene from load_model() or a Model, got {type(scene).__name__}")


def _views(views) -> list[Camera]:
    if isinstance(views, Camera):
        views = [views]
    views = list(views) if isinstance(views, (list, tuple)) else None
    if not views or not all(isinstance(c, Camera) for c in views):
        raise InputError("views must be a non-empty list of Camera (from cameras())")
    return views


def _whole(value, what: str, lo: int | None) -> int:
    """An integer argument (not a bool, not a float to be truncated) of at least `lo`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{what} must be an integer, got {value!r}")
    if lo is not None and value < lo:
        raise InputError(f"{what} must be at least {lo}, got {value}")
    return int(value)


def _size(size) -> tuple[int, int]:
    try:
        w, h = size
    except (TypeError, ValueError):
        raise InputError(f"size must be (width, height), got {size!r}") from None
    for v in (w, h):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise InputError(f"size must be two positive integers (width, height), got {size!r}")
    return int(w), int(h)


def _paths(values) -> list:
    """One path, or an iterable of them, as a list."""
    return [values] if isinstance(values, (str, Path)) else list(values)


def _names(values, what: str) -> list[str]:
    if isinstance(values, str):
        return [values]
    try:
        values = list(values)
    except TypeError:
        raise InputError(f"{what} must be a name or a list of names, got {values!r}") from None
    if not all(isinstance(v, str) for v in values):
        raise InputError(f"{what} must be names (strings), got {values!r}")
    return values


def _out_path(path, what: str) -> Path:
    """The path of an output folder (store.make_out_dir makes it, or says why it cannot: a run's
    through store.lock, a report's here)."""
    if not isinstance(path, (str, Path)):
        raise InputError(f"{what} must be a path, got {path!r}")
    return Path(path)


def _existing(path, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such {what}")
    return p


def _mean_lpips(clean: np.ndarray, faulted: np.ndarray) -> float:
    """LPIPS (AlexNet) mean over the views; NaN when its weights are not installed, a frame is
    smaller than 32x32 or non-finite (undefined, not 0)."""
    from seuwgpu.metrics import lpips

    if not lpips.available() or min(clean.shape[1:3]) < 32:
        return float("nan")
    return float(np.mean(lpips.lpips(clean, faulted)))


def _frame_stem(name: str) -> str:
    return "faulted" if name == "none" else name


def _plain(d: dict) -> dict:
    """numpy scalars -> Python numbers, so the dicts serialise and compare plainly."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in d.items()}
