"""The `seuwgpu` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from seuwgpu.errors import InputError, SeuwgpuError, Terminated
from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.model.encoding import PRECISIONS
from seuwgpu.model.formats import UP_AXES
from seuwgpu.version import __version__


class CliError(SeuwgpuError):
    """A user error: printed as one line, exit status 2."""


def parse_size(text: str) -> tuple[int, int]:
    """WxH of views, each at least budget.MIN_VIEW_SIZE (a campaign spec's `size` limit too)."""
    from seuwgpu.model.budget import MIN_VIEW_SIZE

    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 128x96, got {text!r}") from None
    if w < MIN_VIEW_SIZE or h < MIN_VIEW_SIZE:
        raise argparse.ArgumentTypeError(f"width and height must be at least {MIN_VIEW_SIZE} px, got {text!r}")
    return w, h


def _whole(text: str, lo: int) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < lo:
        raise argparse.ArgumentTypeError(f"must be at least {lo}, got {v}")
    return v


def positive_int(text: str) -> int:
    """An argument that counts something (primitives, views, samples): an integer >= 1."""
    return _whole(text, 1)


def view_count(text: str) -> int:
    """A number of views: 1 to budget.MAX_VIEWS (a campaign spec's `views` limit too)."""
    from seuwgpu.model.budget import MAX_VIEWS

    v = _whole(text, 1)
    if v > MAX_VIEWS:
        raise argparse.ArgumentTypeError(f"at most {MAX_VIEWS} views, got {v}")
    return v


def index_int(text: str) -> int:
    """An index or threshold argument: an integer >= 0."""
    return _whole(text, 0)


def word_bit(text: str) -> int:
    """A bit of a 32-bit pipeline-state word: 0 to 31."""
    v = _whole(text, 0)
    if v > 31:
        raise argparse.ArgumentTypeError(f"a pipeline-state word has bits 0..31, got {v}")
    return v


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return v


def scale_factor(text: str) -> float:
    """--scale: in (0, budget.MAX_SCALE] (a campaign spec's `scale` limit too)."""
    from seuwgpu.model.budget import MAX_SCALE

    v = positive_float(text)
    if v > MAX_SCALE:
        raise argparse.ArgumentTypeError(f"at most {MAX_SCALE} (times the views' resolution), got {text!r}")
    return v


def proportion(text: str) -> float:
    v = positive_float(text)
    if v >= 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, got {text!r}")
    return v


def add_model_args(p: argparse.ArgumentParser, seed_draws: str | None = None):
    """--model/--scene and the options that shape an embedded scene. seed_draws: what else the
    command draws from --seed (inject's sampled primitives, a storm's upsets); without it --seed
    only seeds an embedded scene, and is refused beside --model as --n and --sh-degree are."""
    src = p.add_mutually_exclusive_group()
    src.add_argument(
        "--model",
        "--ply",
        dest="model",
        type=Path,
        help="a 3DGS model file: INRIA PLY, compressed PLY, .spz, .splat, .ksplat, SOG (.sog, or meta.json or "
        "its folder) or a gsplat .pt (recognised by content; a .splat, which has no header, by its extension)",
    )
    src.add_argument("--scene", help="an embedded scene (see `seuwgpu scene --list`)")
    p.add_argument(
        "--n", type=positive_int, help="primitives of an embedded scene (default 100000; a real capture: all)"
    )
    p.add_argument("--sh-degree", type=int, choices=range(4), help="SH degree of an embedded scene (default 3)")
    if seed_draws:
        p.add_argument("--seed", type=int, default=0, help=f"seed of an embedded scene and of {seed_draws} (default 0)")
    else:
        p.add_argument("--seed", type=int, help="seed of an embedded scene (default 0)")
    p.set_defaults(seed_draws=bool(seed_draws))
    p.add_argument("--precision", choices=PRECISIONS, default="fp32", help="stored precision")
    p.add_argument(
        "--up",
        choices=UP_AXES,
        help="up axis of the orbit views (default: the file format's convention, see README)",
    )


def add_compositor_arg(p: argparse.ArgumentParser):
    from seuwgpu.gpu.constants import COMPOSITORS

    p.add_argument(
        "--compositor",
        choices=COMPOSITORS,
        help="the compositor's shape: lanes (8 pixels an invocation, the default on CPU Vulkan) or wide (one "
        "pixel an invocation, the default on GPUs); the same frames bit for bit (docs/renderer.md)",
    )


def add_profile_arg(p: argparse.ArgumentParser, default: str | None = "strict"):
    from seuwgpu.gpu.constants import PROFILES

    p.add_argument(
        "--profile",
        choices=PROFILES,
        default=default,
        help="what corrupted values draw: strict (NaN covariance = frame-covering sheet) or gsplat "
        "(gsplat's CUDA arithmetic); docs/renderer.md" + ("" if default else "; overrides the spec's profile"),
    )


def add_camera_args(p: argparse.ArgumentParser, views: int = 4, size: str = "256x256"):
    p.add_argument(
        "--cameras",
        type=Path,
        help="the capture's cameras: CAMS.json, INRIA cameras.json, a COLMAP model folder, nerfstudio transforms.json",
    )
    p.add_argument(
        "--views",
        type=view_count,
        help=f"orbit views (default {views}), or with --cameras: this many of them, evenly",
    )
    p.add_argument("--size", type=parse_size, help=f"WxH of orbit views (default {size})")
    p.add_argument("--scale", type=scale_factor, help="render at S times the views' resolution (e.g. 0.25; at most 16)")
    p.set_defaults(default_views=views, default_size=parse_size(size))


def load_source(args):
    """The model the arguments name (sources.load_source), its notes printed once."""
    from seuwgpu.model.sources import load_source as load

    refuse_ignored_options(args)

    src = load(
        scene=args.scene, path=args.model, n=args.n, sh_degree=scene_sh_degree(args), seed=args.seed or 0, up=args.up
    )
    if src.notes:
        print(f"seuwgpu: {args.model or src.name}: {'; '.join(src.notes)}", file=sys.stderr)
    return src


def refuse_ignored_options(args):
    """Options the other arguments make meaningless are refused, not silently ignored."""
    if getattr(args, "model", None) is not None and getattr(args, "n", None) is not None:
        raise CliError("--n sets the primitives of an embedded scene; a model file keeps all of its own")
    if getattr(args, "model", None) is not None and getattr(args, "sh_degree", None) is not None:
        raise CliError("--sh-degree sets the SH degree of an embedded scene; a model file has its own")
    seed_only_shapes_a_scene = getattr(args, "seed", None) is not None and not getattr(args, "seed_draws", True)
    if getattr(args, "model", None) is not None and seed_only_shapes_a_scene:
        raise CliError(
            f"--seed seeds an embedded scene, and `seuwgpu {args.command}` draws nothing else from it: "
            "with a model file it would be ignored"
        )
    if getattr(args, "command", None) == "view" and args.views is not None and args.cameras is None:
        raise CliError("--views picks views of a --cameras file; the viewer's orbit is one view you steer")
    # --size of the commands that take camera options (add_camera_args, and demo's; `view`'s is its window)
    orbit_size = getattr(args, "size", None) if hasattr(args, "default_size") else None
    if getattr(args, "cameras", None) is not None and orbit_size is not None:
        raise CliError("--size sets orbit views; a cameras file gives each view its own size (use --scale)")


def scene_sh_degree(args) -> int:
    """--sh-degree, or an embedded scene's default (3)."""
    return 3 if args.sh_degree is None else args.sh_degree


def view_size(args) -> tuple[int, int]:
    """--size, or the command's default."""
    return args.size or args.default_size


def load_cams(args, src, one_size: bool = True):
    """The views the arguments name; one_size: refuse a cameras file's views of several image
    sizes (every command but `render` renders its views as one frame set)."""
    from seuwgpu.model.cameras import check_one_size
    from seuwgpu.model.sources import source_views

    cams = source_views(src, args.cameras, args.views, view_size(args), args.scale, args.default_views)
    note_views(args, len(cams))
    if one_size and args.cameras is not None:
        check_one_size(cams, f"--cameras {args.cameras}", f"`seuwgpu {args.command}`")
    return cams


def output_folder(args, path: Path) -> Path:
    """Refuse meaningless options, then make the output folder: both before any work is done."""
    from seuwgpu.campaign.store import make_out_dir

    refuse_ignored_options(args)
    return make_out_dir(path, what="output folder")


def note_views(args, held: int):
    """Say so when --views asks for more views than the cameras file holds (all are used)."""
    if args.cameras is not None and args.views is not None and args.views > held:
        print(f"seuwgpu: --views {args.views}: {args.cameras} holds {held}, all rendered", file=sys.stderr)


# ---- commands -------------------------------------------------------------------------------------
def cmd_info(args):
    from seuwgpu.gpu.device import get_gpu

    gpu = get_gpu()
    info = gpu.info
    print(f"adapter: {info.get('device')} ({info.get('vendor')})")
    print(f"backend: {info.get('backend_type')}  type: {info.get('adapter_type')}  driver: {info.get('description')}")
    feats = sorted(gpu.adapter.features)
    print("features that matter: " + ", ".join(f for f in ("shader-f16", "timestamp-query", "subgroup") if f in feats))
    for k in (
        "max-storage-buffer-binding-size",
        "max-buffer-size",
        "max-compute-workgroup-storage-size",
        "max-compute-invocations-per-workgroup",
        "max-compute-workgroups-per-dimension",
        "max-storage-buffers-per-shader-stage",
    ):
        print(f"{k}: {gpu.limits.get(k)}")
    return 0


def cmd_scene(args):
    from seuwgpu.model.captures import capture_antialiased
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.scenes import is_capture, list_scenes, make_scene, scene_description

    if not args.list and not args.name and args.out is not None:
        raise CliError("which scene? give its NAME before --out (`seuwgpu scene --list` names them)")
    if args.list or not args.name:
        width = max(len(s) for s in list_scenes())
        for s in list_scenes():
            print(f"{s:<{width}}  {scene_description(s)}")
        return 0
    if args.out is None:
        raise CliError("--out FILE.ply (INRIA PLY) or FILE.spz (Niantic SPZ) is required")
    model = make_scene(args.name, n=args.n, sh_degree=args.sh_degree, seed=args.seed)
    capture = is_capture(args.name)  # a real capture's antialiased flag goes into an SPZ header (PLY has none)
    aa = {"antialiased": True} if capture and capture_antialiased(args.name) else {}
    fmt = save_model(model, args.out, up="+y" if capture else "+z", **aa)
    print(f"wrote {args.out} ({fmt}): {model.n} primitives, SH degree {model.sh_degree}")
    return 0


def parse_formats(text: str) -> tuple[str, ...]:
    from seuwgpu.api import FRAME_FORMATS

    formats = tuple(dict.fromkeys(f.strip().lower() for f in text.split(",") if f.strip()))
    bad = [f for f in formats if f not in FRAME_FORMATS]
    if bad or not formats:
        raise argparse.ArgumentTypeError(
            f"--formats takes a comma-separated list of {', '.join(FRAME_FORMATS)}, got {text!r}"
        )
    return formats


def cmd_render(args):
    from seuwgpu import api
    from seuwgpu.model.cameras import image_sizes

    out: Path = args.out
    if out.suffix == ".npz" and args.formats not in (None, ("npz",)):
        raise CliError(f"--out {out} writes one npz of every view; give a folder for {', '.join(args.formats)} files")
    output_folder(args, out.parent if out.suffix == ".npz" else out)
    src = load_source(args)
    cams = load_cams(args, src, one_size=False)  # views of several sizes: rendered size by size
    formats = args.formats or ("png",)
    sizes = len(image_sizes(cams))
    if sizes > 1 and (out.suffix == ".npz" or "npz" in formats):
        raise CliError(
            f"--cameras {args.cameras}: views of {sizes} image sizes do not fit one npz array "
            "[K, H, W, 3]; write png or tiff files to a folder (--formats png,tiff)"
        )
    images = api.render_views(src, cams, precision=args.precision, profile=args.profile, compositor=args.compositor)
    if out.suffix == ".npz":
        # uncompressed: float32 frames compress by ~11% at 15x the write time (25 views of 256x256:
        # 0.70 s against 0.046 s, lavapipe host, 2026-11-26)
        np.savez(out, images=images.astype(np.float32))
        print(f"wrote {out}: images {list(images.shape)} float32")
    else:
        paths = api.save_frames(images, out, "view", formats=formats)
        print(f"wrote {len(paths)} files ({', '.join(formats)}) to {out}")
    bad = sum(int((~np.isfinite(im)).any(axis=-1).sum()) for im in images)
    if bad:
        print(f"warning: {bad} non-finite pixels (black in PNGs, kept in TIFF and npz)", file=sys.stderr)
    return 0


def parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--shard must look like I/N (e.g. 0/4), got {text!r}") from None
    if n < 1 or not 0 <= i < n:
        raise argparse.ArgumentTypeError(f"--shard I/N needs 0 <= I < N, got {text!r}")
    return i, n


def run_campaign(
    spec: dict,
    out: Path,
    shard=(0, 1),
    quiet=False,
    full=False,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
) -> dict:
    """Run a campaign on the local or the Ray executor (local, with a message saying how to install
    Ray, when Ray is missing) and print its one-line summary."""
    if executor == "ray":
        from seuwgpu.campaign.ray import INSTALL_HINT, ray_available, run_ray

        if not ray_available():
            print(f"seuwgpu campaign: {INSTALL_HINT}; running on the local executor instead", file=sys.stderr)
        else:
            try:
                stats = run_ray(spec, out, workers=workers, address=address, quiet=quiet, full=full, shard=shard)
            except RuntimeError as e:
                raise CliError(str(e)) from None
            rate = stats["new"] / stats["seconds"] if stats["seconds"] > 0 and stats["new"] else float("nan")
            resub = f", {stats['resubmitted']} resubmitted" if stats["resubmitted"] else ""
            print(
                f"{out}: {stats['injections']} of {stats['campaign_total']} injections recorded "
                f"({stats['new']} new in {stats['seconds']:.1f} s, "
                f"{rate:.1f} injections/s on {stats['workers']} Ray worker{'s' if stats['workers'] != 1 else ''}, "
                f"{stats['shards']} shards{resub}{', full re-render' if full else ''})"
            )
            return stats
    from seuwgpu.campaign.runner import Runner

    runner = Runner(spec, out, shard=shard, quiet=quiet, full=full)
    stats = runner.run()
    if not stats["new"]:
        print(f"{out}: {stats['injections']} of {runner.total} injections recorded (nothing new to run)")
        return stats
    rate = stats["new"] / stats["seconds"] if stats["seconds"] > 0 else float("nan")
    print(
        f"{out}: {stats['injections']} of {runner.total} injections recorded"
        f" ({stats['new']} new in {stats['seconds']:.1f} s, {rate:.1f} injections/s"
        f"{', full re-render' if full else ''})"
    )
    return stats


def print_criticality(run_dirs):
    """run_dirs: run directories, or their store.campaign_runs."""
    from seuwgpu.analysis.records import InsufficientData
    from seuwgpu.report.build import criticality_table_text, load_runs, needs_folding

    df, _ = load_runs(run_dirs, fold=needs_folding(run_dirs))
    if df["profile"].nunique() > 1:  # as the report: the tables rest on the strict profile
        df = df[df["profile"] == "strict"]
    single = df[(df["k"] == 1) & (df["campaign"].isin(["single", "size"]))]
    for prec in sorted(single["precision"].unique()):
        try:
            table = criticality_table_text(single, prec)
        except InsufficientData as e:
            print(f"\n(no criticality table at {prec}: {e})")
            continue
        print(f"\nPer-field single-upset criticality at {prec} (defense: none)")
        print(table)


def cmd_campaign(args):
    from seuwgpu.campaign.spec import load_spec

    spec = load_spec(args.spec)
    if args.profile:
        spec["profile"] = args.profile
    run_campaign(
        spec,
        args.out,
        args.shard,
        args.quiet,
        args.full,
        getattr(args, "executor", "local"),
        args.workers,
        args.address,
    )
    if args.shard[1] == 1:
        print_criticality([args.out])
    return 0


def cmd_distributed(args):
    """Sort-first rendering across Ray actors: per-rank times and the ranks an upset contaminates."""
    from seuwgpu.campaign.ray import INSTALL_HINT, ray_available
    from seuwgpu.campaign.sortfirst import parse_upset, sort_first_tables

    if not ray_available():
        raise CliError(f"needs Ray. {INSTALL_HINT}")
    src = load_source(args)
    cams = load_cams(args, src)
    upset = parse_upset(args.upset) if args.upset else None
    sort_first_tables(
        src.model,
        cams,
        args.precision,
        args.ranks,
        upset,
        component=args.component,
        primitive=args.primitive,
        sample=args.sample,
        seed=args.seed,
        guard=args.guard,
        repeats=args.repeats,
        address=args.address,
    )
    return 0


def cmd_rates(args):
    """Weighted outcome rates of runs (finished or still running), folded part by part."""
    import sys

    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    from seuwgpu.analysis.cells import COUNTS, fold_runs, groups, outcome_rates
    from seuwgpu.campaign.store import COLUMNS, campaign_runs, partial_runs_text

    by = list(dict.fromkeys(c.strip() for c in args.by.split(",") if c.strip()))  # a column named twice: once
    unknown = [c for c in by if c != "run" and c not in COLUMNS]
    if unknown:
        known = ", ".join(["run", *COLUMNS])
        raise InputError(f"--by {', '.join(unknown)}: not a record column (one of {known})")
    quiet = not sys.stderr.isatty()
    runs = campaign_runs(args.runs)  # each manifest read once
    with Progress(transient=True, disable=quiet) as bar:
        task = bar.add_task("reading parts", total=None)
        cells, n_parts = fold_runs(runs, by, args.campaign, lambda i, n: bar.update(task, completed=i, total=n))
    by = groups(cells, by)  # several renderer profiles: a row each, never pooled
    t = outcome_rates(cells, by)
    partial = partial_runs_text(runs)
    if args.csv:
        from seuwgpu.campaign.store import make_out_dir

        make_out_dir(args.csv.parent, "--csv", "folder")
        t.to_csv(args.csv, index=False)
    tab = Table(
        title=f"{args.campaign} upsets, {int(cells['n_records'].sum()):,} records in {n_parts:,} parts: weighted "
        "rate per outcome, % [95% interval: Wilson per cell, stratified Wilson when pooled]"
    )
    for c in [*by, "n", *COUNTS]:
        tab.add_column(c, justify="right")
    for _, r in t.iterrows():
        pct = [[100 * r[f"{c}_{x}"] for x in ("rate", "ci_lo", "ci_hi")] for c in COUNTS]
        cells_text = (f"{p:.3g} [{lo:.3g}, {hi:.3g}]" for p, lo, hi in pct)
        tab.add_row(*(str(r[c]) for c in by), f"{int(r['n']):,}", *cells_text)
    Console(width=200).print(tab)
    if partial:
        print(partial)
    return 0


def cmd_plan(args):
    """What a spec will run: injections per context, and the margin each cell's sample gives."""
    from rich.console import Console
    from rich.table import Table

    from seuwgpu.campaign.plan import margin_of_error, sample_size
    from seuwgpu.campaign.sampling import enumerate_contexts
    from seuwgpu.campaign.spec import load_spec, scene_label

    spec = load_spec(args.spec)
    tab = Table(
        title=f"{args.spec}: campaign plan (margins: 95% confidence, worst case p = 0.5, sites drawn with replacement)"
    )
    for c in (
        "campaign",
        "scene",
        "N",
        "precision",
        "cells",
        "per cell",
        "injections",
        "arms",
        "rows",
        "margin per cell",
    ):
        tab.add_column(c, justify="right")
    total = rows = 0
    for ctx in enumerate_contexts(spec):
        sc = spec["scenes"][ctx.scene_index]
        name = scene_label(sc)
        n = ctx.n or sc.get("n")
        margin = "-" if ctx.kind == "dose" else f"+-{100 * margin_of_error(ctx.per_cell, 0.95):.2f} pt"
        tab.add_row(
            ctx.kind,
            name,
            f"{n:,}" if n else "file",
            ctx.precision,
            str(len(ctx.cells)),
            str(ctx.per_cell),
            f"{ctx.count:,}",
            str(len(ctx.defenses)),
            f"{ctx.count * len(ctx.defenses):,}",
            margin,
        )
        total += ctx.count
        rows += ctx.count * len(ctx.defenses)
    Console(width=140).print(tab)
    print(f"total: {total:,} injections, {rows:,} records")
    if args.margin:
        n = sample_size(args.margin, args.confidence)
        print(
            f"for +-{100 * args.margin:g} pt at {100 * args.confidence:g}% confidence a cell needs {n:,} samples "
            "(sites drawn with replacement: no finite-population correction; "
            f"set samples = {{margin = {args.margin}, confidence = {args.confidence}}})"
        )
    return 0


def cmd_demo(args):
    import tomllib
    from importlib.resources import files

    from seuwgpu.campaign.spec import normalize_spec
    from seuwgpu.model.scenes import is_capture, make_scene

    refuse_ignored_options(args)
    raw = tomllib.loads(files("seuwgpu.campaign.specs").joinpath("default.toml").read_text())
    if args.model is not None or args.scene is not None:  # the default campaign on another model
        raw["scenes"] = [{"model": str(args.model)} if args.model is not None else {"scene": args.scene}]
        if args.scene is not None and args.n is None and is_capture(args.scene):
            raw["scenes"][0]["n"] = make_scene(args.scene).n
    if args.cameras is not None:
        raw["scenes"][0]["cameras"] = str(args.cameras)
        raw.pop("size", None)  # the camera file's size rules (a spec refuses a size it would ignore)
    if args.up is not None:
        raw["scenes"][0]["up"] = args.up
    for key in ("views", "scale"):
        if getattr(args, key) is not None:
            raw[key] = getattr(args, key)
    if args.size is not None:
        raw["size"] = f"{args.size[0]}x{args.size[1]}"
    if args.n is not None and "model" not in raw["scenes"][0]:
        raw["scenes"][0]["n"] = args.n
    if args.samples is not None:
        raw["single"]["samples"] = args.samples
    spec = normalize_spec(raw)
    sc = spec["scenes"][0]
    what = f"{sc['scene']} scene, {sc['n']} primitives" if "scene" in sc else f"model {sc['model']}"
    if "model" in sc and Path(sc["model"]).is_dir():  # an INRIA output folder: say which iteration
        from seuwgpu.model.formats import inria_iteration_note

        what += f", {inria_iteration_note(sc['model'])}"
    views = f"{spec['views']} of the views in {sc['cameras']}" if "cameras" in sc else f"{spec['views']} views"
    views += f" at {spec['size'][0]}x{spec['size'][1]}" if "cameras" not in sc else ""
    views += f", scaled by {spec['scale']:g}" if "scale" in spec else ""
    print(
        f"seuwgpu demo: {what}, {views}, every field and bit at fp32, "
        f"{spec['single']['samples']} samples per (field, bit) cell, defenses {spec['single']['defenses']}"
    )
    run_campaign(spec, args.out, quiet=args.quiet)
    from seuwgpu.campaign.store import campaign_runs

    runs = campaign_runs([args.out])  # the manifest read once for the table and the report
    print_criticality(runs)
    if not args.no_report:
        from seuwgpu.report.build import build_report

        index = build_report(runs, args.out / "report")
        print(f"\nreport: {index}")
    return 0


def cmd_merge(args):
    from seuwgpu.campaign import store
    from seuwgpu.campaign.merge import merge

    n = merge(args.out, args.shards, allow_partial=args.allow_partial)
    missing = (store.read_manifest(args.out) or {}).get("missing_parts", [])
    gap = f"; {len(missing)} parts missing (listed in the manifest)" if missing else ""
    print(f"merged {n} parts from {len(args.shards)} shard directories into {args.out}{gap}")
    return 0


def cmd_report(args):
    import sys

    from rich.progress import Progress

    from seuwgpu.campaign.store import campaign_runs
    from seuwgpu.report.build import build_report, needs_folding

    runs = campaign_runs(args.runs)  # each manifest (and part footer) read once
    fold = {"auto": needs_folding(runs), "yes": True, "no": False}[args.fold]
    with Progress(transient=True, disable=not sys.stderr.isatty()) as bar:
        task = bar.add_task("reading parts" + (" (folding)" if fold else ""), total=None)
        index = build_report(
            runs,
            args.out,
            fold=fold,
            progress=lambda i, n: bar.update(task, completed=i, total=n),
            workers=args.workers,
        )
    print(f"wrote {index}")
    if fold:  # reading the records a second time would double a long load: the report's own table
        table = index.parent / "criticality.md"
        print(
            f"\nrecords folded as read (analysis/folding.py); per-field criticality at the reference "
            f"precision ({table}; every precision: {index.parent / 'field_bit.csv'}):"
        )
        if table.is_file():
            print(table.read_text())
    else:
        print_criticality(runs)
    return 0


def lpips_text(value: float) -> str:
    from seuwgpu.metrics import lpips

    if value == value:
        return f"{value:.6f}"
    return "nan (undefined: frames under 32x32 or non-finite)" if lpips.available() else f"n/a ({lpips.INSTALL_HINT})"


def cmd_inject(args):
    from seuwgpu import api
    from seuwgpu.report.panel import save_panel

    if args.width is not None and (args.fault != "adjacent" or len(args.bit or ()) > 1):
        raise CliError("--width sets the burst of --fault adjacent from one --bit; here it would be ignored")
    from seuwgpu.faults.sites import VALUE_MODELS

    if args.bit is not None and args.fault in VALUE_MODELS:
        raise CliError(f"--fault {args.fault} replaces the whole value; --bit does not apply")
    output_folder(args, args.out)
    src = load_source(args)
    cams = load_cams(args, src)
    defenses = tuple(dict.fromkeys((args.defense, "guard")))
    inj = api.inject(
        src,
        cams,
        field=args.field,
        bit=args.bit,
        component=args.component,
        primitive=args.primitive,
        precision=args.precision,
        defenses=defenses,
        sample=args.sample,
        seed=args.seed,
        profile=args.profile,
        fault=args.fault,
        width=args.width or 2,
    )
    site, rec, g = inj.site, inj.metrics[args.defense], inj.metrics["guard"]
    if args.primitive is None:
        print(f"primitive: {site['primitive']} (most harmful of {min(args.sample, site['n_primitives'])} sampled)")
    bits = site["bits"]
    title = (
        f"{src.name}, {site['n_primitives']} primitives, {args.precision}: {site['fault']} fault of {site['field']}"
        f"[{site['primitive']}][{site['component']}] bit{'s' if len(bits) > 1 else ''} {','.join(map(str, bits))} "
        f"({site['bit_class']}) {site['clean_value']:.6g} -> {site['corrupted_value']:.6g}; defense {args.defense}"
    )
    frames = inj.frames
    panel = save_panel(
        args.out / "panel.png", frames["clean"], frames[args.defense], frames["guard"], title, defense=args.defense
    )
    files = inj.save(args.out, formats=args.formats)
    lines = {
        "field": site["field"],
        "primitive": site["primitive"],
        "component": site["component"],
        "bit": ",".join(map(str, bits)),
        "bit_class": site["bit_class"],
        "fault": site["fault"],
        "clean_value": f"{site['clean_value']:.9g}",
        "corrupted_value": f"{site['corrupted_value']:.9g}",
        "defense": args.defense,
        "footprint": f"{100 * rec['footprint']:.4f}%",
        "footprint_max": f"{100 * rec['footprint_max']:.4f}%",
        "peak_error": f"{rec['peak_error']:.6g}",
        "psnr": f"{rec['psnr']:.3f}",
        "ssim": f"{rec['ssim']:.6f}",
        "lpips": lpips_text(rec["lpips"]),
        "nonfinite": rec["nonfinite"],
        "catastrophic": rec["catastrophic"],
        "clamps": rec["clamps"],
        "guarded_footprint": f"{100 * g['footprint']:.4f}%",
        "guarded_psnr": f"{g['psnr']:.3f}",
        "guarded_clamps": g["clamps"],
        "panel": panel,
        "frames": f"{len(files) - 1} files ({', '.join(args.formats)}) and metrics.json in {args.out}",
    }
    for k, v in lines.items():
        print(f"{k}: {v}")
    return 0


def cmd_defenses(args):
    """Every defense with its memory overhead and its time cost, measured on this device for the
    named model (or not measured with --no-time: time_fraction NaN)."""
    from seuwgpu.faults.costs import defense_costs

    if args.scene is None and args.model is None:
        args.scene = "leica-sofort"
    src = load_source(args)
    cam = load_cams(args, src, one_size=False)[0]  # one view: any size
    rows = defense_costs(
        src.model, cam, args.precision, args.repeats, time_it=not args.no_time, check_every=args.check_every
    )
    if args.json:
        import json

        from seuwgpu.report.format import json_safe

        print(json.dumps(json_safe(rows), indent=1, allow_nan=False))  # NaN (not measured) -> null
        return 0
    from rich.console import Console
    from rich.table import Table

    t = Table(
        title=f"defenses on {src.name} ({src.model.n:,} primitives, {args.precision}); time: {rows[0]['time_basis']}"
    )
    for c in ("defense", "device bytes", "memory", "check every", "time / frame", "exposure (frames)", "what it does"):
        t.add_column(c, justify="left" if c in ("defense", "what it does") else "right")
    for r in rows:
        tf, ex, worst = r["time_fraction"], r["exposure_frames"], r["exposure_frames_worst"]
        t.add_row(
            r["name"],
            f"{r['device_bytes']:,}",
            f"{100 * r['memory_overhead']:.3f}%",
            "" if r["check_every"] is None else str(r["check_every"]),
            "n/a" if tf != tf else f"{100 * tf:+.1f}%",
            "until reloaded" if ex == float("inf") else f"{ex:g} (worst {worst:g})",
            r["description"],
        )
    Console().print(t)
    return 0


def cmd_worstcase(args):
    """The single-bit flip with the largest footprint under a defense, by bounded search."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.faults.worstcase import worst_case
    from seuwgpu.model.fields import canonical_field

    src = load_source(args)
    eng = Engine(src.model, load_cams(args, src), args.precision, scene=src.name, profile=args.profile)
    fields = None if args.fields is None else [canonical_field(f) for f in args.fields]
    for d in dict.fromkeys(args.defense):  # a defense named twice is searched once
        wc = worst_case(eng, d, fields, args.bit, max_evaluations=args.max_evaluations)
        where = f"{wc.site.field}[{wc.site.primitive}][{wc.site.component}] bit {wc.site.bit}" if wc.site else "none"
        print(
            f"{d}: worst flip {where}: footprint {100 * wc.footprint:.4f}% (certified bound "
            f"{100 * wc.certified:.4f}%), {wc.evaluated:,} of {wc.sites:,} flips rendered"
        )
    return 0


class work_bar:
    """A progress bar on stderr for a long loop (none when stderr is no terminal): `with
    work_bar("frames", total, done) as step:` then `step()` once a unit of work is done (`done`:
    the units done before, by the run a resumed one continues)."""

    def __init__(self, what: str, total: int, done: int = 0):
        self.what, self.total, self.done = what, total, done

    def __enter__(self):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.p = Progress(
            TextColumn(f"[bold]{self.what}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            transient=True,
            disable=not sys.stderr.isatty(),
        )
        self.p.start()
        task = self.p.add_task(self.what, total=self.total, completed=self.done)
        return lambda: self.p.advance(task)

    def __exit__(self, *exc):
        self.p.stop()
        return False


def partial_records(args, src, cams, name: str, records, **options):
    """The records of an interrupted run of the same arguments in `--out` (campaign/partial.py;
    another run's are refused, naming what differs). The run is what decides its records: the
    model and camera files by their content (sha256: the same files through another path are the
    same run), the other options as read (defaults spelled out; the up axis as resolved, so that
    `--up` naming the default, or given with --cameras, is the same run), then the command's
    `options`. `records(rows)`: the DataFrame of the records, as the finished run writes it."""
    from seuwgpu.campaign.partial import PartialRecords
    from seuwgpu.campaign.spec import content_hash

    def content(key):
        path = getattr(args, key)
        return None if path is None else "sha256:" + content_hash(key, path)

    run = {
        "command": args.command,
        "model": content("model"),
        "scene": None if args.model else src.name,
        "n": None if args.model else src.model.n,
        "sh-degree": None if args.model else scene_sh_degree(args),
        "seed": args.seed,
        "up": None if args.cameras else src.up,  # what frames the orbit: --up or the format's; unused by cameras
        "cameras": content("cameras"),
        "views": len(cams),
        "size": None if args.cameras else "x".join(map(str, view_size(args))),
        "scale": args.scale or 1.0,
        "precision": args.precision,
        "profile": args.profile,
        **options,
    }
    return PartialRecords(args.out / f"{name}.partial.parquet", run, records)


def cmd_storm(args):
    """k upsets per frame accumulating, scrubbed every S frames: records and a plot per defense."""
    from seuwgpu.analysis.defenses import storm_figure
    from seuwgpu.campaign.storm import storm, storm_records
    from seuwgpu.faults.engine import Engine

    output_folder(args, args.out)
    src = load_source(args)
    cams = load_cams(args, src)
    defenses = list(dict.fromkeys(args.defense))  # a defense named twice is one arm
    options = {"k": args.k, "frames": args.frames, "scrub-every": args.scrub_every, "defense": defenses}
    options["check-every"] = args.check_every
    partial = partial_records(args, src, cams, "storm", storm_records, **options)  # before any rendering
    eng = Engine(src.model, cams, args.precision, scene=src.name, profile=args.profile)
    with partial.kept() as rows:
        with work_bar("frames", args.frames * len(defenses), len(rows)) as step:
            df = storm(
                eng,
                args.k,
                args.frames,
                args.scrub_every,
                defenses,
                args.seed,
                partial.progress(step),
                rows=rows,
                check_every=args.check_every,
            )
        df.to_parquet(args.out / "storm.parquet", index=False)
        storm_figure(df).savefig(args.out / "storm.png", dpi=120)
    summary = df.groupby("defense", sort=False).agg(
        catastrophic_frames=("catastrophic", "sum"), mean_footprint=("footprint", "mean")
    )
    print(summary.to_string())
    print(f"records: {args.out / 'storm.parquet'}; plot: {args.out / 'storm.png'}")
    return 0


def cmd_state(args):
    """Transient pipeline-state flips of one frame: records and a criticality table per target."""
    import pandas as pd

    from seuwgpu.analysis.defenses import state_table
    from seuwgpu.faults.engine import Engine
    from seuwgpu.faults.state import state_campaign

    output_folder(args, args.out)
    src = load_source(args)
    cams = load_cams(args, src)
    targets, bits = list(dict.fromkeys(args.targets)), list(dict.fromkeys(args.bit or range(32)))
    options = {"targets": targets, "samples": args.samples, "bit": bits}
    partial = partial_records(args, src, cams, "state", pd.DataFrame, **options)  # before any rendering
    eng = Engine(src.model, cams, args.precision, scene=src.name, profile=args.profile)
    with partial.kept() as rows:
        with work_bar("flips", len(targets) * len(bits) * args.samples, len(rows)) as step:
            df = state_campaign(eng, targets, args.samples, bits, args.seed, partial.progress(step), rows=rows)
        df.to_parquet(args.out / "state.parquet", index=False)
        t = state_table(df)
        (args.out / "state_criticality.csv").write_text(t.to_csv(index=False))
    with pd_display():
        print(t.to_string(index=False))
    print(f"records: {args.out / 'state.parquet'}; table: {args.out / 'state_criticality.csv'}")
    return 0


def pd_display():
    import pandas as pd

    return pd.option_context("display.width", 200, "display.max_columns", 20, "display.precision", 4)


def cmd_view(args):
    """`seuwgpu view`: the interactive viewer (apps/viewer_window.py)."""
    from seuwgpu.apps.viewer_window import NO_DISPLAY_HELP, canvas_backend, display_problem, missing_package

    refuse_ignored_options(args)  # a bad argument is exit status 2 with or without a display
    for option in ("model", "cameras"):  # so is a missing file (read after the display check)
        path = getattr(args, option, None)
        if path is not None and not Path(path).exists():
            raise CliError(f"--{option} {path}: no such file or folder")
    backend = canvas_backend()
    why = display_problem(backend)
    if why:
        print(NO_DISPLAY_HELP.format(why=why), file=sys.stderr)
        return 3
    missing = missing_package(backend)
    if missing:
        print(
            f"seuwgpu view: error: {missing}. The viewer needs the `viewer` extra: pip install 'seuwgpu[viewer]' "
            "(rendercanvas, glfw, imgui-bundle)",
            file=sys.stderr,
        )
        return 2
    from seuwgpu.apps.viewer import OrbitCamera
    from seuwgpu.model.cameras import read_cameras, select_views

    src = load_source(args)
    model, name = src.model, src.name
    orbit = (
        OrbitCamera.for_scene(src.scene)
        if src.scene
        else OrbitCamera.fit(model.means, up=src.up, log_scales=model.log_scales)
    )
    views, names = None, None
    if args.cameras is not None:
        views, names, _ = read_cameras(args.cameras)
        note_views(args, len(views))
        keep = select_views(list(range(len(views))), args.views)
        views, names = [views[i] for i in keep], [names[i] for i in keep]
    from seuwgpu.apps.viewer_window import run_viewer

    return run_viewer(
        model,
        name,
        args.precision,
        tuple(args.size or args.default_size),
        orbit=orbit,
        backend=backend,
        sample=args.sample,
        clamp_threshold=args.clamp_threshold,
        screenshot_dir=args.screenshot_dir,
        frames=args.frames,
        views=views,
        view_names=names,
        profile=args.profile,
    )


def build_parser() -> argparse.ArgumentParser:
    from seuwgpu.faults.sites import FAULT_MODELS, INJECT_SAMPLE
    from seuwgpu.faults.state import TARGETS as STATE_TARGETS

    p = argparse.ArgumentParser(
        prog="seuwgpu", description="Single-event-upset fault injection for 3D Gaussian splatting (WGSL, wgpu)"
    )
    p.add_argument("--version", action="version", version=f"seuwgpu {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("info", help="adapter, backend, features and limits in use")
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("scene", help="export an embedded scene as PLY or SPZ (or --list them)")
    s.add_argument("name", nargs="?")
    s.add_argument("--n", type=positive_int, help="primitives (default 100000; a real capture: all)")
    s.add_argument("--sh-degree", type=int, default=3, choices=range(4))
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", type=Path)
    s.add_argument("--list", action="store_true")
    s.set_defaults(func=cmd_scene)

    s = sub.add_parser("render", help="render views to PNGs or an .npz of float32 images")
    add_model_args(s)
    add_camera_args(s)
    s.add_argument("--out", type=Path, required=True, help="a folder for the frames, or X.npz")
    s.add_argument(
        "--formats",
        type=parse_formats,
        help="frame files: png (display), tiff (float32, unclamped), npz; comma-separated (default png)",
    )
    add_profile_arg(s)
    add_compositor_arg(s)
    s.set_defaults(func=cmd_render)

    s = sub.add_parser("inject", help="flip one stored bit (or several of one value), measure, write the panel")
    add_model_args(s, seed_draws="the --sample of primitives and a --fault random value")
    add_camera_args(s, views=2, size="256x256")
    s.add_argument(
        "--field",
        required=True,
        help="means | log_scales | quats | opacity | sh_dc | sh_rest (aliases: log_scale, mean, ...)",
    )
    s.add_argument("--primitive", type=index_int, help="primitive index (default: the most harmful of --sample)")
    s.add_argument("--component", type=index_int, default=0)
    s.add_argument("--bit", type=index_int, nargs="+", help="bit(s) of the stored value (0 = LSB)")
    s.add_argument(
        "--fault",
        default="bit",
        choices=FAULT_MODELS,
        help="bit/adjacent: flip the bits (adjacent with one --bit: --width bits ending there); "
        "stuck0/stuck1: the bits stuck; zero/random: the whole value replaced (random from --seed)",
    )
    s.add_argument("--width", type=int, choices=(2, 3, 4), help="adjacent burst width (default 2)")
    s.add_argument("--defense", default="none", choices=DEFENSES)
    s.add_argument(
        "--sample",
        type=positive_int,
        default=INJECT_SAMPLE,
        help=f"primitives tried when --primitive is not given (default {INJECT_SAMPLE}, as seuwgpu.inject's sample)",
    )
    s.add_argument("--out", type=Path, required=True)
    s.add_argument(
        "--formats",
        type=parse_formats,
        default=("png", "tiff"),
        help="frame files besides panel.png and metrics.json: png, tiff (float32, unclamped), npz (default png,tiff)",
    )
    add_profile_arg(s)
    s.set_defaults(func=cmd_inject)

    s = sub.add_parser("campaign", help="run a fault-injection campaign from a TOML spec (resumable)")
    s.add_argument("spec", type=Path)
    s.add_argument("--out", type=Path, required=True, help="run directory (re-run the same command to resume)")
    s.add_argument("--shard", type=parse_shard, default=(0, 1), help="run the deterministic slice I of N")
    s.add_argument("--quiet", action="store_true", help="log lines instead of a progress display")
    s.add_argument(
        "--full", action="store_true", help="re-render full frames for every injection (no incremental path)"
    )
    s.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="local (this process) or ray (shards over Ray workers; needs pip install seuwgpu[ray])",
    )
    s.add_argument("--address", help="Ray cluster address (e.g. auto); default: start a local Ray instance")
    s.add_argument(
        "--workers", type=positive_int, help="Ray workers in flight (default: the cluster's GPUs, else CPUs)"
    )
    add_profile_arg(s, default=None)
    s.set_defaults(func=cmd_campaign)

    s = sub.add_parser(
        "distributed", help="sort-first rendering over Ray ranks: per-rank times, ranks an upset contaminates"
    )
    add_model_args(s, seed_draws="the --sample of primitives")
    add_camera_args(s, views=2, size="256x256")
    s.add_argument(
        "--ranks",
        type=positive_int,
        nargs="+",
        default=[4],
        help="ranks P (screen regions); several values: one table each",
    )
    s.add_argument("--upset", help="field:bit (e.g. log_scales:31), applied to every rank's copy")
    s.add_argument("--component", type=index_int, default=0)
    s.add_argument("--primitive", type=index_int, help="primitive index (default: the most harmful of --sample)")
    s.add_argument("--sample", type=positive_int, default=32, help="primitives tried when --primitive is not given")
    s.add_argument(
        "--guard",
        choices=("scrub", "clamp"),
        default="scrub",
        help="node-local guard: scrub each rank's stored copy, or clamp in the pipeline (default scrub)",
    )
    s.add_argument("--repeats", type=positive_int, default=3, help="renders per rank for its median time")
    s.add_argument("--address", help="Ray cluster address (e.g. auto); default: start a local Ray instance")
    s.set_defaults(func=cmd_distributed)

    s = sub.add_parser("plan", help="what a campaign spec will run, and the margin of error per cell")
    s.add_argument("spec", type=Path)
    s.add_argument("--margin", type=proportion, help="also print the samples per cell this margin needs (e.g. 0.01)")
    s.add_argument("--confidence", type=proportion, default=0.95)
    s.set_defaults(func=cmd_plan)

    s = sub.add_parser(
        "demo", help="the main job: the default campaign on the embedded scene, then its criticality table"
    )
    s.add_argument("--out", type=Path, default=Path("runs/demo"))
    src = s.add_mutually_exclusive_group()
    src.add_argument("--model", "--ply", dest="model", type=Path, help="run it on this model file (any format)")
    src.add_argument("--scene", help="run it on this embedded scene (`seuwgpu scene --list`)")
    s.add_argument("--cameras", type=Path, help="the capture's cameras (any format `render` takes)")
    s.add_argument("--views", type=view_count, help="orbit views, or this many of the capture's (default 4)")
    s.add_argument("--size", type=parse_size, help="WxH of orbit views (default from the spec)")
    s.add_argument("--scale", type=scale_factor, help="render at S times the views' resolution (at most 16)")
    s.add_argument("--up", choices=UP_AXES, help="up axis of the orbit views")
    s.add_argument("--n", type=positive_int, help="primitives (default from the spec: 100000)")
    s.add_argument("--samples", type=positive_int, help="samples per (field, bit) cell")
    s.add_argument("--quiet", action="store_true")
    s.add_argument("--no-report", action="store_true")
    s.set_defaults(func=cmd_demo, default_size=None)  # its --size sizes orbit views; the default is the spec's

    s = sub.add_parser("merge", help="join shard run directories of one spec")
    s.add_argument("shards", type=Path, nargs="+")
    s.add_argument("--out", type=Path, required=True, help="run directory of the merged campaign")
    s.add_argument(
        "--allow-partial",
        action="store_true",
        help="merge even when shards are missing (the manifest lists the missing parts)",
    )
    s.set_defaults(func=cmd_merge)

    s = sub.add_parser("view", help="interactive viewer: toggle faults and the guard live")
    add_model_args(s)
    add_profile_arg(s)
    s.add_argument(
        "--cameras",
        type=Path,
        help="the capture's cameras (any format `render` takes): step through them with [ and ] or the panel",
    )
    s.add_argument("--views", type=view_count, help="with --cameras: this many of them, evenly")
    s.add_argument(
        "--size",
        type=parse_size,
        default=parse_size("960x600"),
        help="window size WxH in pixels, the panel included (default 960x600)",
    )
    s.add_argument(
        "--sample", type=positive_int, default=16, help="primitives tried by 'worst of a sample' (default 16)"
    )
    s.add_argument(
        "--clamp-threshold",
        type=index_int,
        default=0,
        help="guard alert when a frame clamps more components than this (default 0)",
    )
    s.add_argument("--screenshot-dir", type=Path, default=Path("."), help="where S/P screenshots go (default .)")
    s.add_argument(
        "--frames",
        type=index_int,
        default=0,
        help="draw this many frames, save a screenshot and exit (0 = interactive; "
        "with RENDERCANVAS_BACKEND=offscreen the default is 1)",
    )
    s.set_defaults(func=cmd_view)

    s = sub.add_parser("defenses", help="every defense with its memory overhead and time cost on this device")
    add_model_args(s)
    add_camera_args(s, views=1, size="256x256")
    s.add_argument("--repeats", type=positive_int, default=7, help="timing rounds (medians)")
    s.add_argument("--no-time", action="store_true", help="skip the timing (time_fraction NaN)")
    s.add_argument("--json", action="store_true", help="print [{name, memory_overhead, time_fraction, ...}]")
    s.add_argument(
        "--check-every",
        type=positive_int,
        default=1,
        help="check schedule S of the check defenses: check every S frames (time amortised over S; default 1)",
    )
    s.set_defaults(func=cmd_defenses)

    s = sub.add_parser("worstcase", help="the single flip with the largest footprint under a defense (bounded search)")
    add_model_args(s)
    add_camera_args(s, views=2, size="128x128")
    add_profile_arg(s)
    s.add_argument(
        "--defense",
        nargs="+",
        default=["none"],
        choices=DEFENSES,
        metavar="DEFENSE",
        help=f"defenses to search under, each on its own (default none; {', '.join(DEFENSES)})",
    )
    s.add_argument(
        "--fields",
        nargs="+",
        help="fields to search (default: every field the model stores; sh_rest only at SH degree 1-3)",
    )
    s.add_argument("--bit", type=index_int, nargs="+", help="bits to search (0 = LSB; default: all)")
    s.add_argument(
        "--max-evaluations", type=positive_int, help="stop after this many renders (the bound stays certified)"
    )
    s.set_defaults(func=cmd_worstcase)

    s = sub.add_parser("storm", help="k upsets per frame accumulating, scrubbed every S frames, per defense")
    add_model_args(s, seed_draws="the upsets")
    add_camera_args(s, views=1, size="128x128")
    add_profile_arg(s)
    s.add_argument("--k", type=positive_int, default=10, help="upsets per frame")
    s.add_argument("--frames", type=positive_int, default=50, help="frames rendered, each after its k new upsets")
    s.add_argument("--scrub-every", type=int, default=10, help="reload the model every S frames (0 = never)")
    s.add_argument(
        "--check-every",
        type=positive_int,
        default=1,
        help="check schedule of the check defenses: check (and repair) every S frames (default 1)",
    )
    s.add_argument(
        "--defense",
        nargs="+",
        default=["none", "guard", "parity4r"],
        choices=DEFENSES,
        metavar="DEFENSE",
        help=f"arms, each seeing the same upsets (default none guard parity4r; {', '.join(DEFENSES)})",
    )
    s.add_argument(
        "--out",
        type=Path,
        required=True,
        help="folder for storm.parquet and storm.png (an interrupted run keeps storm.partial.parquet: re-run "
        "the same command to resume it)",
    )
    s.set_defaults(func=cmd_storm)

    s = sub.add_parser("state", help="transient flips in one frame's pipeline state: criticality per target")
    add_model_args(s, seed_draws="the flips")
    add_camera_args(s, views=2, size="128x128")
    add_profile_arg(s)
    s.add_argument(
        "--targets",
        nargs="+",
        default=list(STATE_TARGETS),
        choices=STATE_TARGETS,
        help="pipeline-state buffers to flip bits in (default: all)",
    )
    s.add_argument("--samples", type=positive_int, default=10, help="flips per (target, bit) cell")
    s.add_argument("--bit", type=word_bit, nargs="+", help="bits 0..31 (default: all 32)")
    s.add_argument(
        "--out",
        type=Path,
        required=True,
        help="folder for state.parquet and state_criticality.csv (an interrupted run keeps "
        "state.partial.parquet: re-run the same command to resume it)",
    )
    s.set_defaults(func=cmd_state)

    s = sub.add_parser(
        "rates", help="weighted outcome rates with intervals, read part by part (any size, runs still going)"
    )
    s.add_argument("runs", type=Path, nargs="+")
    s.add_argument("--by", default="scene,precision,defense", help="comma-separated record columns (or run)")
    s.add_argument(
        "--campaign",
        default="single",
        choices=["single", "size"],
        help="records of the single-upset campaign (default) or of the primitive-count sweep",
    )
    s.add_argument("--csv", type=Path, help="write the table as CSV (rates as proportions)")
    s.set_defaults(func=cmd_rates)

    s = sub.add_parser("report", help="tables, figures and an HTML page from run directories")
    s.add_argument("runs", type=Path, nargs="+")
    s.add_argument("--out", type=Path, required=True)
    s.add_argument(
        "--fold",
        choices=["auto", "yes", "no"],
        default="auto",
        help="fold the records as they are read (the same numbers in far less memory; auto: when "
        "they would not fit unfolded)",
    )
    s.add_argument(
        "--workers",
        type=positive_int,
        help="processes folding parts side by side (default: one per CPU, at most 8, from 256 parts on)",
    )
    s.set_defaults(func=cmd_report)
    p.commands = sub.choices  # parse_arguments: an unknown option is the command's error
    return p


def parse_arguments(argv: list[str]) -> argparse.Namespace:
    """The command line's arguments. An option no command knows is refused by that command's
    parser, with its usage and `seuwgpu CMD: error: ...` (argparse left it to the top-level parser,
    which printed `seuwgpu: error: unrecognized arguments` under the list of commands)."""
    parser = build_parser()
    args, extra = parser.parse_known_args(join_up_axes(argv))
    if extra:
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def join_up_axes(argv: list[str]) -> list[str]:
    """`--up -y` as `--up=-y`: argparse reads a value that starts with '-' as an option, so the
    README's own axis names (-x, -y, -z) failed with 'argument --up: expected one argument'."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--up" and i + 1 < len(argv) and argv[i + 1] in UP_AXES:
            out.append(f"--up={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def stopped_by(e: KeyboardInterrupt) -> tuple[str, int]:
    """(what stopped the command, its exit status): SIGTERM 143, Ctrl-C 130. Ray's ray.get turns
    any KeyboardInterrupt into a plain one: Terminated.received says it was SIGTERM."""
    if isinstance(e, Terminated) or Terminated.received:
        return "terminated (SIGTERM)", 143
    return "interrupted", 130


def main(argv=None) -> int:
    import warnings

    warnings.formatwarning = lambda msg, cat, *a, **k: f"seuwgpu: {cat.__name__}: {msg}\n"
    Terminated.received = False  # this command's SIGTERM only (main runs many times in one test process)
    try:  # a signal while the arguments are read ends the command as one while it runs does
        args = parse_arguments(sys.argv[1:] if argv is None else list(argv))
    except KeyboardInterrupt as e:
        how, code = stopped_by(e)
        print(f"seuwgpu: {how}", file=sys.stderr)
        return code
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt as e:
        kept = " (completed parts are kept; re-run to resume)" if args.command in ("campaign", "demo") else ""
        how, code = stopped_by(e)
        print(f"seuwgpu {args.command}: {how}{kept}", file=sys.stderr)
        return code
    except (SeuwgpuError, ValueError) as e:  # the project's errors, and plain ValueErrors naming a bad value
        print(f"seuwgpu {args.command}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a file or folder that cannot be read or written: name it, no traceback
        where = f"{e.filename}: " if e.filename else ""
        why = e.strerror or str(e)
        if isinstance(e, (FileExistsError, NotADirectoryError)):
            why = "a file is in the way of a folder (or of a path under it)"
        print(f"seuwgpu {args.command}: error: {where}{why}", file=sys.stderr)
        return 2
    except MemoryError:
        print(
            f"seuwgpu {args.command}: error: out of host memory "
            "(use fewer primitives, views or samples, or a smaller size)",
            file=sys.stderr,
        )
        return 2


def console_main() -> int:
    """The `seuwgpu` command (and `python -m seuwgpu`): `main`, then Ctrl-C is ignored while the
    interpreter shuts down (releasing the GPU device, joining writer threads): the work is done
    and its exit status stands. An interrupt landing there used to kill the process with SIGINT
    (exit -2 to its parent) after a campaign had finished and written everything.

    SIGTERM (`kill`, SLURM or Kubernetes stopping a job) stops a command as Ctrl-C does (exit 143,
    what was measured kept): by default it ended the process at once, without writing the part in
    hand or a storm's or state's partial records."""
    import signal

    def terminate(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # one orderly stop, not one per signal
        Terminated.received = True
        raise Terminated()

    signal.signal(signal.SIGTERM, terminate)
    code = main()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(console_main())
