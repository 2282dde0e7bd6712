"""`distributed`: sort-first rendering over Ray ranks."""

from __future__ import annotations

import argparse

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import (
    CliError,
    add_camera_args,
    add_model_args,
    index_int,
    load_cams,
    load_source,
    positive_int,
)


# ---- distributed ------------------------------------------------------------------------------------
def distributed_arguments(s: argparse.ArgumentParser):
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


def cmd_distributed(args):
    """Sort-first rendering across Ray actors: per-rank times and the ranks an upset contaminates."""
    from seuwgpu import api
    from seuwgpu.campaign.ray import INSTALL_HINT, ray_available

    if not ray_available():
        raise CliError(f"needs Ray. {INSTALL_HINT}")
    src = load_source(args)
    cams = load_cams(args, src)
    api.sort_first(
        src,
        cams,
        ranks=args.ranks,
        upset=args.upset,
        component=args.component,
        primitive=args.primitive,
        sample=args.sample,
        seed=args.seed,
        guard=args.guard,
        repeats=args.repeats,
        precision=args.precision,
        address=args.address,
    )
    return 0


DISTRIBUTED = Command(
    "distributed",
    "sort-first rendering over Ray ranks: per-rank times, ranks an upset contaminates",
    distributed_arguments,
    cmd_distributed,
)
