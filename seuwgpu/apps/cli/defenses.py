"""Defense and fault-model commands: `defenses`, `worstcase`, `storm`, `state`."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import (
    add_camera_args,
    add_model_args,
    add_profile_arg,
    defense_name,
    index_int,
    load_cams,
    load_source,
    output_folder,
    positive_int,
    scene_sh_degree,
    view_size,
    word_bit,
)
from seuwgpu.campaign.partial import resumed, run_identity
from seuwgpu.faults.defenses import DEFENSES as DEFENSE_NAMES
from seuwgpu.faults.schedule import DEFAULT_CHECK_EVERY
from seuwgpu.faults.sites import FAULT_MODELS
from seuwgpu.faults.state import FORMER_NAMES, check_target
from seuwgpu.faults.state import TARGETS as STATE_TARGETS


def add_resumable_out(s: argparse.ArgumentParser, name: str, results: str):
    s.add_argument(
        "--out",
        type=Path,
        required=True,
        help=f"folder for {results} (an interrupted run keeps {name}.partial.parquet: re-run the same "
        "command to resume it)",
    )


@contextlib.contextmanager
def resumable(args, src, cams, name: str, records, unit: str, total: int, **options):
    """campaign/partial.py `resumed` of the run the arguments name (`run_identity`)."""
    run = run_identity(
        args.command,
        src,
        cams,
        model=args.model,
        cameras=args.cameras,
        sh_degree=scene_sh_degree(args),
        seed=args.seed,
        size=view_size(args),
        scale=args.scale,
        precision=args.precision,
        profile=getattr(args, "profile", "strict"),  # `defenses` has none: strict
        **({"lod": args.lod} if getattr(args, "lod", None) is not None else {}),  # older runs' keys kept
        **options,
    )
    with resumed(args.out, name, run, records, unit, total) as (rows, progress):
        yield rows, progress


def pd_display():
    import pandas as pd

    return pd.option_context("display.width", 200, "display.max_columns", 20, "display.precision", 4)


# ---- defenses ---------------------------------------------------------------------------------------
def defenses_arguments(s: argparse.ArgumentParser):
    add_model_args(s, seed_draws="the --visible upsets")
    add_camera_args(s, views=1, size="256x256")
    s.add_argument("--repeats", type=positive_int, default=7, help="timing rounds (medians)")
    s.add_argument("--no-time", action="store_true", help="skip the timing (time_fraction NaN)")
    s.add_argument("--json", action="store_true", help="print [{name, memory_overhead, time_fraction, ...}]")
    s.add_argument(
        "--check-every",
        type=positive_int,
        default=DEFAULT_CHECK_EVERY,
        help="check schedule S of the check defenses: check every S frames (timed as S frames and a check "
        f"against S frames; default {DEFAULT_CHECK_EVERY})",
    )
    s.add_argument(
        "--visible",
        type=index_int,
        default=0,
        metavar="N",
        help="measure what the user sees: N upsets of the dangerous cells, one per window of --window frames, "
        "landing at a uniform frame; catastrophic and SDC frames per upset (exposure counted) per defense "
        "(default 0: not measured)",
    )
    s.add_argument("--window", type=positive_int, default=20, help="frames between reloads for --visible (default 20)")
    s.add_argument(
        "--visible-defenses",
        nargs="+",
        type=defense_name,
        metavar="DEFENSE",
        help="the arms of --visible (default: every defense)",
    )
    s.add_argument("--fault", default="bit", choices=FAULT_MODELS, help="fault model of the --visible upsets")
    s.add_argument(
        "--out",
        type=Path,
        metavar="RUN",
        help="keep the --visible records in the run folder RUN (RUN/visible/), whose report then shows them; "
        "an interrupted --visible measurement keeps its frames in RUN/defenses-visible.partial.parquet: re-run "
        "the same command to resume it",
    )


def cmd_defenses(args):
    """Every defense with its memory overhead and its time cost, measured on this device for the
    named model (or not measured with --no-time: time_fraction NaN)."""
    from seuwgpu import api

    if args.scene is None and args.model is None:
        args.scene = "leica-sofort"
    src = load_source(args)
    cam = load_cams(args, src, one_size=False)[0]  # one view: any size
    with visible_records(args, src, cam) as (frames, progress):
        rows = api.defense_costs(
            src,
            cam,
            precision=args.precision,
            repeats=args.repeats,
            time_it=not args.no_time,
            check_every=args.check_every,
            visible=args.visible,
            window=args.window,
            visible_defenses=args.visible_defenses,
            seed=args.seed,
            fault=args.fault,
            out=args.out,
            progress=progress,
            rows=frames,
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
    # numbers stay on one line at any width; what each defense does follows the table
    t.caption = (
        "bytes: held on the device; memory: of the model's bytes; S: checked every S frames; time: of a frame, "
        "measured as S frames and a check against S frames [95% interval]; repair: one reload, of a frame; "
        "exposure: frames drawn from a corrupted model before the check, mean (worst)"
        + (
            "; seen: catastrophic frames per upset [95%] (x none), measured as " + rows[0]["visible_basis"]
            if args.visible
            else ""
        )
    )
    cols = ["defense", "bytes", "memory", "S", "time", "repair", "exposure"] + (["seen"] if args.visible else [])
    for c in cols:
        t.add_column(c, justify="left" if c == "defense" else "right", no_wrap=True)
    for r in rows:
        tf, ex, worst = r["time_fraction"], r["exposure_frames"], r["exposure_frames_worst"]
        lo, hi, rep = r["time_lo"], r["time_hi"], r["repair_fraction"]
        band = "" if lo != lo or r["name"] == "none" else f" [{100 * lo:+.1f}, {100 * hi:+.1f}]"
        t.add_row(
            r["name"],
            f"{r['device_bytes']:,}",
            f"{100 * r['memory_overhead']:.3f}%",
            "" if r["check_every"] is None else str(r["check_every"]),
            "n/a" if tf != tf else f"{100 * tf:+.2f}%{band}",
            "" if rep != rep else f"{100 * rep:.1f}%",
            "until reloaded" if ex == float("inf") else f"{ex:g} ({worst:g})",
            *([_seen(r)] if args.visible else []),
        )
    console = Console()
    console.print(t)
    for r in rows:
        console.print(f"[bold]{r['name']}[/bold]: {r['description']}", highlight=False)
    return 0


@contextlib.contextmanager
def visible_records(args, src, cam):
    """(frame records, progress) of the --visible measurement: with --out, resumable as storm is
    (RUN/defenses-visible.partial.parquet, kept when the run stops early); without, a bar alone."""
    from seuwgpu.campaign.progress import ProgressBar
    from seuwgpu.campaign.storm import storm_records
    from seuwgpu.campaign.visible import visible_frames

    if not args.visible:
        yield None, None
        return
    arms = args.visible_defenses or list(DEFENSE_NAMES)
    total = visible_frames(args.visible, args.window, args.check_every, len(arms))
    if args.out is None:
        with ProgressBar("frames", total) as bar:
            yield None, bar.advance
        return
    options = {"visible": args.visible, "window": args.window, "check-every": args.check_every}
    options.update({"visible-defenses": arms, "fault": args.fault})
    with resumable(args, src, [cam], "defenses-visible", storm_records, "frames", total, **options) as got:
        yield got


def _seen(r) -> str:
    c = r["catastrophic_frames_per_upset"]
    if c != c:
        return ""
    x = r["of_none"]
    return f"{c:.3g} [{r['catastrophic_lo']:.3g}, {r['catastrophic_hi']:.3g}]" + ("" if x != x else f" (x{x:.3f})")


DEFENSES = Command(
    "defenses",
    "every defense with its device memory, time per frame and exposure on this device",
    defenses_arguments,
    cmd_defenses,
)


# ---- worstcase --------------------------------------------------------------------------------------
def worstcase_arguments(s: argparse.ArgumentParser):
    add_model_args(s)
    add_camera_args(s, views=2, size="128x128")
    add_profile_arg(s)
    s.add_argument(
        "--defense",
        nargs="+",
        default=["none"],
        type=defense_name,
        metavar="DEFENSE",
        help=f"defenses to search under, each on its own (default none; {', '.join(DEFENSE_NAMES)})",
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


def cmd_worstcase(args):
    """The single-bit flip with the largest footprint under a defense, by bounded search."""
    from seuwgpu import api

    src = load_source(args)
    found = api.worst_case(
        src,
        load_cams(args, src),
        defenses=args.defense,  # each named once (refuse_ignored_options)
        fields=args.fields,
        bits=args.bit,
        max_evaluations=args.max_evaluations,
        precision=args.precision,
        profile=args.profile,
    )
    for d, wc in found.items():
        where = f"{wc.site.field}[{wc.site.primitive}][{wc.site.component}] bit {wc.site.bit}" if wc.site else "none"
        print(
            f"{d}: worst flip {where}: footprint {100 * wc.footprint:.4f}% (certified bound "
            f"{100 * wc.certified:.4f}%), {wc.evaluated:,} of {wc.sites:,} flips rendered"
        )
    return 0


WORSTCASE = Command(
    "worstcase",
    "the single flip with the largest footprint under a defense (bounded search)",
    worstcase_arguments,
    cmd_worstcase,
)


# ---- storm ------------------------------------------------------------------------------------------
def storm_arguments(s: argparse.ArgumentParser):
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
        type=defense_name,
        metavar="DEFENSE",
        help=f"arms, each seeing the same upsets (default none guard parity4r; {', '.join(DEFENSE_NAMES)})",
    )
    s.add_argument(
        "--fault",
        default="bit",
        choices=FAULT_MODELS,
        help="fault model of every upset: bit (default), adjacent (2-4 bits), burst (2-8 bits), random or zero "
        "(the value), stuck0/stuck1, mcu_prim (the bit in two values of one primitive), mcu_neighbour (in the "
        "neighbouring word of the device layout)",
    )
    add_resumable_out(s, "storm", "storm.parquet and storm.png")


def cmd_storm(args):
    """k upsets per frame accumulating, scrubbed every S frames: records and a plot per defense."""
    from seuwgpu import api
    from seuwgpu.analysis.defenses import storm_figure
    from seuwgpu.campaign.storm import storm_records

    output_folder(args, args.out)
    src = load_source(args)
    cams = load_cams(args, src)
    defenses = args.defense  # each named once (refuse_ignored_options)
    options = {"k": args.k, "frames": args.frames, "scrub-every": args.scrub_every, "defense": defenses}
    options["check-every"] = args.check_every
    if args.fault != "bit":  # a bit storm's partial records keep their key
        options["fault"] = args.fault
    frames = args.frames * len(defenses)
    with resumable(args, src, cams, "storm", storm_records, "frames", frames, **options) as (rows, progress):
        df = api.storm(
            src,
            cams,
            k=args.k,
            frames=args.frames,
            scrub_every=args.scrub_every,
            defenses=defenses,
            seed=args.seed,
            precision=args.precision,
            profile=args.profile,
            progress=progress,
            rows=rows,
            check_every=args.check_every,
            fault=args.fault,
        )
        df.to_parquet(args.out / "storm.parquet", index=False)
        storm_figure(df).savefig(args.out / "storm.png", dpi=120)
    summary = df.groupby("defense", sort=False).agg(
        catastrophic_frames=("catastrophic", "sum"), mean_footprint=("footprint", "mean")
    )
    print(summary.to_string())
    print(f"records: {args.out / 'storm.parquet'}; plot: {args.out / 'storm.png'}")
    return 0


STORM = Command(
    "storm", "k upsets per frame accumulating, scrubbed every S frames, per defense", storm_arguments, cmd_storm
)


# ---- state ------------------------------------------------------------------------------------------
def state_arguments(s: argparse.ArgumentParser):
    add_model_args(s, seed_draws="the flips")
    add_camera_args(s, views=2, size="128x128")
    add_profile_arg(s)
    s.add_argument(
        "--targets",
        nargs="+",
        default=list(STATE_TARGETS),
        choices=[*STATE_TARGETS, *FORMER_NAMES],
        help="pipeline-state buffers to flip bits in (default: all); the former names "
        f"({', '.join(FORMER_NAMES)}) still work",
    )
    s.add_argument("--samples", type=positive_int, default=10, help="flips per (target, bit) cell")
    s.add_argument("--bit", type=word_bit, nargs="+", help="bits 0..31 (default: all 32)")
    add_resumable_out(s, "state", "state.parquet and state_criticality.csv")


def cmd_state(args):
    """Transient pipeline-state flips of one frame: records and a criticality table per target."""
    import pandas as pd

    from seuwgpu import api
    from seuwgpu.analysis.defenses import state_table

    output_folder(args, args.out)
    src = load_source(args)
    cams = load_cams(args, src)
    targets = list(dict.fromkeys(check_target(t) for t in args.targets))
    bits = list(dict.fromkeys(args.bit or range(32)))
    options = {"targets": targets, "samples": args.samples, "bit": bits}
    flips = len(targets) * len(bits) * args.samples
    with resumable(args, src, cams, "state", pd.DataFrame, "flips", flips, **options) as (rows, progress):
        df = api.state_flips(
            src,
            cams,
            targets=targets,
            samples=args.samples,
            bits=bits,
            seed=args.seed,
            precision=args.precision,
            profile=args.profile,
            progress=progress,
            rows=rows,
        )
        df.to_parquet(args.out / "state.parquet", index=False)
        t = state_table(df)
        (args.out / "state_criticality.csv").write_text(t.to_csv(index=False))
    with pd_display():
        print(t.to_string(index=False))
    print(f"records: {args.out / 'state.parquet'}; table: {args.out / 'state_criticality.csv'}")
    return 0


STATE = Command(
    "state", "transient flips in one frame's pipeline state: criticality per target", state_arguments, cmd_state
)
