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

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.api._checks import (
    check_scene,
    defense_names,
    engine_for,
    existing_path,
    fault_bits,
    model_from,
    names_of,
    out_path,
    paths_of,
    spec_of,
    view_list,
)
from seuwgpu.api._injection import FRAME_FILE_FORMATS, Injection, injected_models, mean_lpips, plain, save_frames
from seuwgpu.api._studies import defense_costs, sort_first, state_flips, storm, worst_case
from seuwgpu.campaign.spec_types import Spec
from seuwgpu.campaign.store import CampaignRun
from seuwgpu.errors import InputError, RunInUse, SeuwgpuError, TooBig
from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.faults.sites import (
    FAULT_MODELS,
    INJECT_SAMPLE,
)
from seuwgpu.gpu.constants import PROFILES
from seuwgpu.model import checks, corpus, encoding
from seuwgpu.model.cameras import Camera, image_sizes
from seuwgpu.model.corpus import CorpusModel
from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.formats import writable_formats
from seuwgpu.model.scenes import list_scenes
from seuwgpu.model.sources import Source, load_source, source_views

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
FRAME_FORMATS = FRAME_FILE_FORMATS
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
    if lod is not None:
        checks.lod_level(lod)
    if not isinstance(source, (str, Path)):
        raise InputError(f"source must be a scene name or a model path, got {source!r}")
    path = Path(source)
    if isinstance(source, Path) or path.exists() or path.suffix or "/" in str(source):
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such model file or folder")
        checks.n_of_an_embedded_scene(n, path)  # as the command line refuses --n with --model
        return load_source(path=path, up=up, lod=lod)
    name = str(source)
    checks.lod_of_a_model_file(lod, name)
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
    check_scene(scene)
    if views is not None:
        checks.views(views)
    checks.size_of_orbit_views(size, cameras is not None)  # as the command line refuses --size with --cameras
    w, h = checks.image_size((256, 256) if size is None else size)
    if scale is not None:
        checks.scale(scale)
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
    fmt = save_model(model, out_path(out, "model file"), up="+y" if capture else "+z", **aa)
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
    from seuwgpu.render.project import check_profile
    from seuwgpu.render.renderer import render_split

    model = model_from(scene)
    from seuwgpu.render.composite import check_shape

    shape = None if compositor is None else check_shape(compositor)
    views, precision, profile = view_list(views), encoding.check_precision(precision), check_profile(profile)
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
    defenses = defense_names(defenses)
    checks.integer(sample, "sample", 1)
    checks.integer(component, "component", 0)  # 1.7 was truncated to primitive 1, True taken as 1
    if primitive is not None:
        checks.integer(primitive, "primitive", 0)
    checks.integer(seed, "seed", 0 if primitive is None or fault == "random" else None)  # numpy's seeds are >= 0
    bits, op, value = fault_bits(fault, bit, width, precision, seed)
    eng = engine_for(scene, views, precision, profile, "inject")
    model_of = model_from(scene)
    if primitive is None:
        primitive, _ = eng.worst_primitive(field, component, bits, sample, seed, defenses[0], op, value)
    site = eng.site(field, int(primitive), component, bits, op, value)
    frames = {"clean": eng.clean.copy()}
    metrics = {}
    site_info = None
    for d in defenses:
        rec = eng.inject(site, d)
        frames[d] = eng.last_frame()[..., :3].copy()  # the frame inject measured: no second render
        rec["lpips"] = mean_lpips(frames["clean"], frames[d])
        site_keys = ("scene", "n_primitives", "precision", "fault", "field", "primitive", "component", "bit_class")
        site_info = site_info or {
            **{k: rec[k] for k in site_keys},
            "bits": list(site.bits),
            "clean_value": rec["clean_value"],
            "corrupted_value": rec["corrupted_value"],
        }
        metrics[d] = {k: v for k, v in rec.items() if k not in site_info and k not in ("bit", "k")}
    kept = injected_models(eng, model_of, site, defenses) if models else None
    up = scene.up if isinstance(scene, Source) else None
    src = scene.format if isinstance(scene, Source) else None
    return Injection(plain(site_info), {d: plain(m) for d, m in metrics.items()}, frames, kept, up, src)


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
    as `default_spec()`, or a validated `campaign.spec_types.Spec`) into the run directory `out`.
    `progress(done, total, catastrophic)` is called after each block of injections;
    `progress=True` shows a rich progress bar (also in a notebook), "log" a line on stderr every
    10 s (a batch job's log), None or False nothing. `executor="ray"` runs the shard's blocks on
    Ray workers (`workers` in flight, the cluster at `address`; needs `seuwgpu[ray]`), with the
    bar or the log lines. Returns {injections, new, catastrophic, seconds, campaign_total} (Ray:
    and workers, shards, resubmitted)."""
    from seuwgpu.campaign.runner import Runner

    spec = spec_of(spec)
    if executor not in ("local", "ray"):
        raise InputError(f'executor must be "local" or "ray", got {executor!r}')
    if isinstance(progress, str) and progress != "log":
        raise InputError(f'progress must be a function, True, "log" or None, got {progress!r}')
    out = out_path(out, "run directory")
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

    spec = spec_of(spec)
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

    shards = [out_path(d, "shard directory") for d in paths_of(shards)]
    n = merge(out_path(out, "run directory"), shards, allow_partial=allow_partial)
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
    df, _ = load_runs([Path(existing_path(r, "run directory")) for r in runs])
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

    runs = [r if isinstance(r, CampaignRun) else existing_path(r, "run directory") for r in paths_of(runs)]
    out = make_out_dir(out_path(out, "report folder"), what="report folder")
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
    from seuwgpu.campaign.schema import check_record_columns
    from seuwgpu.campaign.store import campaign_runs, partial_runs_text

    by = list(dict.fromkeys(names_of(by, "by")))  # a column named twice: once
    check_record_columns(by, "by")
    if campaign not in ("single", "size"):
        raise InputError(f'campaign must be "single" or "size", got {campaign!r}')
    found = campaign_runs(paths_of(runs))  # a folder that is no run: fold_runs says so
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
    df, manifests = build.load_runs([existing_path(r, "run directory") for r in runs])
    return build.section_figures(df, manifests)
