"""`view`: the interactive viewer."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import (
    CliError,
    add_model_args,
    add_profile_arg,
    index_int,
    load_source,
    note_views,
    parse_size,
    positive_int,
    refuse_ignored_options,
    view_count,
)


# ---- view -------------------------------------------------------------------------------------------
def view_arguments(s: argparse.ArgumentParser):
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
        args.size,  # the window: --size, default 960x600
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


VIEW = Command("view", "interactive viewer: toggle faults and the guard live", view_arguments, cmd_view)
