"""`inject`: one fault, measured under a defense and the guard, with its panel and frames."""

from __future__ import annotations

import argparse
from pathlib import Path

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import (
    CliError,
    add_camera_args,
    add_model_args,
    add_profile_arg,
    defense_name,
    index_int,
    load_cams,
    load_source,
    one_of_metavar,
    output_folder,
    parse_formats,
    positive_int,
)
from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.faults.sites import INJECT_SAMPLE, SITE_MODELS


def lpips_text(value: float) -> str:
    from seuwgpu.metrics import lpips

    if value == value:
        return f"{value:.6f}"
    return "nan (undefined: frames under 32x32 or non-finite)" if lpips.available() else f"n/a ({lpips.INSTALL_HINT})"


# ---- inject -----------------------------------------------------------------------------------------
def inject_arguments(s: argparse.ArgumentParser):
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
        choices=SITE_MODELS,
        help="bit/adjacent/burst: flip the bits (adjacent (2-4) or burst (2-8) with one --bit: --width bits "
        "ending there); "
        "stuck0/stuck1: the bits stuck; zero/random: the whole value replaced (random from --seed)",
    )
    s.add_argument("--width", type=int, choices=range(2, 9), help="adjacent (2-4) or burst (2-8) width (default 2)")
    s.add_argument("--defense", default="none", type=defense_name, metavar=one_of_metavar(DEFENSES))
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
    s.add_argument(
        "--save-model",
        type=Path,
        metavar="DIR",
        help="also write the faulted model and each defense's repaired one (faulted.ply, guard.ply, ...), to open "
        "in a splat viewer: in the --model file's format (compressed PLY, SOG, .splat, .ksplat, SPZ, PLY) and as "
        "INRIA PLY (float32, exact); a scene by name as PLY and SPZ",
    )
    add_profile_arg(s)


def cmd_inject(args):
    from seuwgpu import api
    from seuwgpu.report.panel import save_panel

    if args.width is not None and (args.fault != "adjacent" or len(args.bit or ()) > 1):
        raise CliError("--width sets the burst of --fault adjacent from one --bit; here it would be ignored")
    from seuwgpu.faults.sites import VALUE_MODELS

    if args.bit is not None and args.fault in VALUE_MODELS:
        raise CliError(f"--fault {args.fault} replaces the whole value; --bit does not apply")
    output_folder(args, args.out)
    if args.save_model is not None:
        from seuwgpu.campaign.store import make_out_dir

        make_out_dir(args.save_model, "--save-model", "output folder")
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
        models=args.save_model is not None,
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
    if args.save_model is not None:
        written = inj.save_models(args.save_model)
        lines["models"] = f"{', '.join(p.name for p in written)} in {args.save_model}"
    for k, v in lines.items():
        print(f"{k}: {v}")
    return 0


INJECT = Command(
    "inject", "flip one stored bit (or several of one value), measure, write the panel", inject_arguments, cmd_inject
)
