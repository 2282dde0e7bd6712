"""What the commands share: argument types, the model and camera options, and how they are read."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from seuwgpu.errors import InputError, SeuwgpuError
from seuwgpu.faults.defenses import check_defense
from seuwgpu.model import checks
from seuwgpu.model.encoding import PRECISIONS, check_precision
from seuwgpu.model.formats import UP_AXES


class CliError(SeuwgpuError):
    """A user error: printed as one line, exit status 2."""


def argument_type(check):
    """An argparse type from a shared check (model/checks.py): its message, as argparse prints it
    after `argument --OPTION:`."""

    def parse(text: str):
        try:
            return check(text)
        except InputError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    parse.__name__ = check.__name__
    return parse


precision_name = argument_type(check_precision)
defense_name = argument_type(check_defense)


def one_of_metavar(names) -> str:
    """How argparse shows a `choices` option's names ({a,b,c}), for one checked by its type."""
    return "{" + ",".join(names) + "}"


@argument_type
def parse_size(text: str) -> tuple[int, int]:
    """WxH of views (a campaign spec's `size` and the API's take the same)."""
    return checks.image_size(text, None)


@argument_type
def positive_int(text: str) -> int:
    """An argument that counts something (primitives, views, samples): an integer >= 1."""
    return checks.integer(int_word(text), None, 1)


@argument_type
def view_count(text: str) -> int:
    """A number of views: 1 to checks.MAX_VIEWS (a campaign spec's `views` limit too)."""
    return checks.views(int_word(text), None)


@argument_type
def index_int(text: str) -> int:
    """An index or threshold argument: an integer >= 0."""
    return checks.integer(int_word(text), None, 0)


@argument_type
def word_bit(text: str) -> int:
    """A bit of a 32-bit pipeline-state word: 0 to 31."""
    return checks.integer(int_word(text), None, 0, 31)


@argument_type
def scale_factor(text: str) -> float:
    """--scale: in (0, checks.MAX_SCALE] (a campaign spec's `scale` limit too)."""
    return checks.scale(float_word(text), None)


@argument_type
def proportion(text: str) -> float:
    return checks.proportion(float_word(text), None)


def int_word(text: str):
    """A command-line word as an integer, or as itself for the check to name."""
    try:
        return int(text)
    except ValueError:
        return text


def float_word(text: str):
    """A command-line word as a number, or as itself for the check to name."""
    try:
        return float(text)
    except ValueError:
        return text


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
        "its folder), a PlayCanvas LOD set (lod-meta.json or its folder) or a gsplat .pt (recognised by content; "
        "a .splat, which has no header, by its extension)",
    )
    src.add_argument("--scene", help="an embedded scene (see `seuwgpu scene --list`)")
    add_lod_arg(p)
    p.add_argument(
        "--n", type=positive_int, help="primitives of an embedded scene (default 100000; a real capture: all)"
    )
    p.add_argument("--sh-degree", type=int, choices=range(4), help="SH degree of an embedded scene (default 3)")
    if seed_draws:
        p.add_argument("--seed", type=int, default=0, help=f"seed of an embedded scene and of {seed_draws} (default 0)")
    else:
        p.add_argument("--seed", type=int, help="seed of an embedded scene (default 0)")
    p.set_defaults(seed_draws=bool(seed_draws))
    p.add_argument(
        "--precision", type=precision_name, metavar=one_of_metavar(PRECISIONS), default="fp32", help="stored precision"
    )
    p.add_argument(
        "--up",
        choices=UP_AXES,
        help="up axis of the orbit views (default: the file format's convention, see README)",
    )


def add_lod_arg(p: argparse.ArgumentParser):
    p.add_argument(
        "--lod",
        type=level,
        help="the level of a PlayCanvas LOD set (lod-meta.json) to read: 0 the finest (the default), then coarser",
    )


@argument_type
def level(text: str) -> int:
    """A LOD level: a non-negative integer."""
    return checks.lod_level(int_word(text), None)


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
    from seuwgpu.render.project import check_profile

    p.add_argument(
        "--profile",
        type=argument_type(check_profile),  # the API's and a spec's check and wording
        metavar=one_of_metavar(PROFILES),
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
        scene=args.scene,
        path=args.model,
        n=args.n,
        sh_degree=scene_sh_degree(args),
        seed=args.seed or 0,
        up=args.up,
        lod=getattr(args, "lod", None),
    )
    if src.notes:
        print(f"seuwgpu: {args.model or src.name}: {'; '.join(src.notes)}", file=sys.stderr)
    return src


def refuse_ignored_options(args):
    """Options the other arguments make meaningless are refused, not silently ignored."""
    for option in ("defense", "visible_defenses"):  # a list of arms: each named once, as the API and a spec
        if isinstance(getattr(args, option, None), list):
            checks.listed_once(getattr(args, option), "--" + option.replace("_", "-"))
    if getattr(args, "model", None) is None:
        checks.lod_of_a_model_file(getattr(args, "lod", None), getattr(args, "scene", None), "--lod")
    checks.n_of_an_embedded_scene(getattr(args, "n", None), getattr(args, "model", None), "--n")
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
    checks.size_of_orbit_views(orbit_size, getattr(args, "cameras", None) is not None, "--size", "--scale")


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


def parse_formats(text: str) -> tuple[str, ...]:
    from seuwgpu.api import FRAME_FORMATS

    formats = tuple(dict.fromkeys(f.strip().lower() for f in text.split(",") if f.strip()))
    bad = [f for f in formats if f not in FRAME_FORMATS]
    if bad or not formats:
        raise argparse.ArgumentTypeError(
            f"--formats takes a comma-separated list of {', '.join(FRAME_FORMATS)}, got {text!r}"
        )
    return formats
