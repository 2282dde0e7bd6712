"""Campaign commands: `campaign`, `plan`, `demo`, `merge` and their criticality table."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import (
    CliError,
    add_lod_arg,
    add_profile_arg,
    argument_type,
    parse_size,
    positive_int,
    proportion,
    refuse_ignored_options,
    scale_factor,
    view_count,
)
from seuwgpu.apps.cli.results import print_criticality
from seuwgpu.model import checks
from seuwgpu.model.formats import UP_AXES


@argument_type
def parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--shard must look like I/N (e.g. 0/4), got {text!r}") from None
    return checks.shard((i, n), None)


def run_campaign(
    spec,
    out: Path,
    shard=(0, 1),
    quiet=False,
    full=False,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
) -> dict:
    """Run a campaign (api.run_campaign) on the local or the Ray executor (local, with a message
    saying how to install Ray, when Ray is missing) and print its one-line summary."""
    from seuwgpu import api

    progress = "log" if quiet else True
    if executor == "ray":
        from seuwgpu.campaign.ray import INSTALL_HINT, ray_available

        if not ray_available():
            print(f"seuwgpu campaign: {INSTALL_HINT}; running on the local executor instead", file=sys.stderr)
        else:
            try:
                stats = api.run_campaign(
                    spec,
                    out,
                    progress=progress,
                    full=full,
                    shard=shard,
                    executor="ray",
                    workers=workers,
                    address=address,
                )
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
    stats = api.run_campaign(spec, out, progress=progress, full=full, shard=shard)
    if not stats["new"]:
        print(f"{out}: {stats['injections']} of {stats['campaign_total']} injections recorded (nothing new to run)")
        return stats
    rate = stats["new"] / stats["seconds"] if stats["seconds"] > 0 else float("nan")
    print(
        f"{out}: {stats['injections']} of {stats['campaign_total']} injections recorded"
        f" ({stats['new']} new in {stats['seconds']:.1f} s, {rate:.1f} injections/s"
        f"{', full re-render' if full else ''})"
    )
    return stats


# ---- campaign ---------------------------------------------------------------------------------------
def campaign_arguments(s: argparse.ArgumentParser):
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


def cmd_campaign(args):
    from seuwgpu.campaign.spec import load_spec

    spec = load_spec(args.spec)
    if args.profile:
        spec = dataclasses.replace(spec, profile=args.profile)
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


CAMPAIGN = Command(
    "campaign",
    "run a fault-injection campaign from a TOML spec (resumable)",
    campaign_arguments,
    cmd_campaign,
    resumable=True,
)


# ---- plan -------------------------------------------------------------------------------------------
def plan_arguments(s: argparse.ArgumentParser):
    s.add_argument("spec", type=Path)
    s.add_argument("--margin", type=proportion, help="also print the samples per cell this margin needs (e.g. 0.01)")
    s.add_argument("--confidence", type=proportion, default=0.95)


def cmd_plan(args):
    """What a spec will run: injections per context, and the margin each cell's sample gives."""
    import pandas as pd
    from rich.console import Console
    from rich.table import Table

    from seuwgpu import api
    from seuwgpu.campaign.plan import sample_size
    from seuwgpu.campaign.spec import load_spec

    plan = api.plan_campaign(load_spec(args.spec))
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
    for r in plan.itertuples():
        tab.add_row(
            r.campaign,
            r.scene,
            "file" if pd.isna(r.n) else f"{r.n:,}",
            r.precision,
            str(r.cells),
            str(r.per_cell),
            f"{r.injections:,}",
            str(r.arms),
            f"{r.records:,}",
            "-" if r.campaign == "dose" else f"+-{100 * r.margin:.2f} pt",
        )
    total, rows = int(plan["injections"].sum()), int(plan["records"].sum())
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


PLAN = Command("plan", "what a campaign spec will run, and the margin of error per cell", plan_arguments, cmd_plan)


# ---- demo -------------------------------------------------------------------------------------------
def demo_arguments(s: argparse.ArgumentParser):
    s.add_argument("--out", type=Path, default=Path("runs/demo"))
    src = s.add_mutually_exclusive_group()
    src.add_argument("--model", "--ply", dest="model", type=Path, help="run it on this model file (any format)")
    src.add_argument("--scene", help="run it on this embedded scene (`seuwgpu scene --list`)")
    add_lod_arg(s)
    s.add_argument("--cameras", type=Path, help="the capture's cameras (any format `render` takes)")
    s.add_argument("--views", type=view_count, help="orbit views, or this many of the capture's (default 4)")
    s.add_argument("--size", type=parse_size, help="WxH of orbit views (default from the spec)")
    s.add_argument("--scale", type=scale_factor, help="render at S times the views' resolution (at most 16)")
    s.add_argument("--up", choices=UP_AXES, help="up axis of the orbit views")
    s.add_argument("--n", type=positive_int, help="primitives (default from the spec: 100000)")
    s.add_argument("--samples", type=positive_int, help="samples per (field, bit) cell")
    s.add_argument("--quiet", action="store_true")
    s.add_argument("--no-report", action="store_true")
    s.set_defaults(default_size=None)


def cmd_demo(args):
    import tomllib

    from seuwgpu import api
    from seuwgpu.campaign.spec import normalize_spec
    from seuwgpu.model.scenes import is_capture, make_scene

    refuse_ignored_options(args)
    raw = tomllib.loads(api.default_spec().read_text(encoding="utf-8"))  # the spec the API names
    if args.model is not None or args.scene is not None:  # the default campaign on another model
        raw["scenes"] = [{"model": str(args.model)} if args.model is not None else {"scene": args.scene}]
        if args.lod is not None:
            raw["scenes"][0]["lod"] = args.lod
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
    sc = spec.scenes[0]
    from seuwgpu.model.formats import inria_iteration_note, model_file

    what = f"{sc.scene} scene, {sc.n} primitives" if sc.scene else f"model {sc.model}"
    what += f", level {sc.lod}" if sc.lod is not None else ""
    if sc.model and Path(sc.model).is_dir() and Path(model_file(sc.model)).name == "point_cloud.ply":
        what += f", {inria_iteration_note(sc.model)}"  # an INRIA output folder: say which iteration
    views = f"{spec.views} of the views in {sc.cameras}" if sc.cameras else f"{spec.views} views"
    views += f" at {spec.size[0]}x{spec.size[1]}" if not sc.cameras else ""
    views += f", scaled by {spec.scale:g}" if spec.scale is not None else ""
    print(
        f"seuwgpu demo: {what}, {views}, every field and bit at fp32, "
        f"{spec.single.samples} samples per (field, bit) cell, defenses {list(spec.single.defenses)}"
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


DEMO = Command(
    "demo",
    "the main job: the default campaign on the embedded scene, then its criticality table",
    demo_arguments,
    cmd_demo,
    resumable=True,
)


# ---- merge ------------------------------------------------------------------------------------------
def merge_arguments(s: argparse.ArgumentParser):
    s.add_argument("shards", type=Path, nargs="+")
    s.add_argument("--out", type=Path, required=True, help="run directory of the merged campaign")
    s.add_argument(
        "--allow-partial",
        action="store_true",
        help="merge even when shards are missing (the manifest lists the missing parts)",
    )


def cmd_merge(args):
    from seuwgpu import api

    merged = api.merge_runs(args.shards, args.out, allow_partial=args.allow_partial)
    n, missing = merged["parts"], merged["missing_parts"]
    gap = f"; {len(missing)} parts missing (listed in the manifest)" if missing else ""
    print(f"merged {n} parts from {len(args.shards)} shard directories into {args.out}{gap}")
    return 0


MERGE = Command("merge", "join shard run directories of one spec", merge_arguments, cmd_merge)
