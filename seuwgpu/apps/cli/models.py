"""`scene` and `render`: export an embedded scene, render views of a model."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import (
    CliError,
    add_camera_args,
    add_compositor_arg,
    add_model_args,
    add_profile_arg,
    load_cams,
    load_source,
    output_folder,
    parse_formats,
    positive_int,
)


# ---- scene ------------------------------------------------------------------------------------------
def scene_arguments(s: argparse.ArgumentParser):
    s.add_argument("name", nargs="?")
    s.add_argument("--n", type=positive_int, help="primitives (default 100000; a real capture: all)")
    s.add_argument("--sh-degree", type=int, default=3, choices=range(4))
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", type=Path)
    s.add_argument("--list", action="store_true")


def cmd_scene(args):
    from seuwgpu import api
    from seuwgpu.model.scenes import list_scenes, scene_description

    if not args.list and not args.name and args.out is not None:
        raise CliError("which scene? give its NAME before --out (`seuwgpu scene --list` names them)")
    if args.list or not args.name:
        width = max(len(s) for s in list_scenes())
        for s in list_scenes():
            print(f"{s:<{width}}  {scene_description(s)}")
        return 0
    if args.out is None:
        raise CliError("--out FILE.ply (INRIA PLY) or FILE.spz (Niantic SPZ) is required")
    model, fmt = api.export_scene(args.name, args.out, n=args.n, sh_degree=args.sh_degree, seed=args.seed)
    print(f"wrote {args.out} ({fmt}): {model.n} primitives, SH degree {model.sh_degree}")
    return 0


SCENE = Command("scene", "export an embedded scene as PLY or SPZ (or --list them)", scene_arguments, cmd_scene)


# ---- render -----------------------------------------------------------------------------------------
def render_arguments(s: argparse.ArgumentParser):
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
        # uncompressed: compression saves little on float32 frames at many times the write time
        # (docs/benchmarks.md, "Frame files")
        np.savez(out, images=images.astype(np.float32))
        print(f"wrote {out}: images {list(images.shape)} float32")
    else:
        paths = api.save_frames(images, out, "view", formats=formats)
        print(f"wrote {len(paths)} files ({', '.join(formats)}) to {out}")
    bad = sum(int((~np.isfinite(im)).any(axis=-1).sum()) for im in images)
    if bad:
        print(f"warning: {bad} non-finite pixels (black in PNGs, kept in TIFF and npz)", file=sys.stderr)
    return 0


RENDER = Command("render", "render views to PNGs or an .npz of float32 images", render_arguments, cmd_render)
