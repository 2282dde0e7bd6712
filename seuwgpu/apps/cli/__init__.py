"""The `seuwgpu` command line: one module per command group, each command one `Command` (its
options and its handler side by side), registered once in COMMANDS."""

from __future__ import annotations

import argparse
import sys

from seuwgpu.apps.cli import campaigns, corpus, defenses, distributed, info, inject, models, results, view
from seuwgpu.apps.cli.campaigns import run_campaign
from seuwgpu.apps.cli.options import CliError, parse_size, refuse_ignored_options
from seuwgpu.errors import SeuwgpuError, Terminated
from seuwgpu.model.formats import UP_AXES
from seuwgpu.version import __version__

__all__ = [
    "COMMANDS",
    "CliError",
    "build_parser",
    "console_main",
    "main",
    "parse_size",
    "refuse_ignored_options",
    "run_campaign",
]


COMMANDS = (
    info.INFO,
    models.SCENE,
    corpus.CORPUS,
    models.RENDER,
    inject.INJECT,
    campaigns.CAMPAIGN,
    distributed.DISTRIBUTED,
    campaigns.PLAN,
    campaigns.DEMO,
    campaigns.MERGE,
    view.VIEW,
    defenses.DEFENSES,
    defenses.WORSTCASE,
    defenses.STORM,
    defenses.STATE,
    results.RATES,
    results.REPORT,
)
"""Every command, in the order `seuwgpu --help` lists them: adding a command is one entry here."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="seuwgpu", description="Single-event-upset fault injection for 3D Gaussian splatting (WGSL, wgpu)"
    )
    p.add_argument("--version", action="version", version=f"seuwgpu {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_to(sub)
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
        resumable = any(c.resumable for c in COMMANDS if c.name == args.command)
        kept = " (completed parts are kept; re-run to resume)" if resumable else ""
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
