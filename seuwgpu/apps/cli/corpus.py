"""The `corpus` command: list the real trained models of the packaged manifest, or assemble them
into a folder (downloaded, or read from a folder), every file's sha256 checked."""

from __future__ import annotations

import argparse
import sys

from seuwgpu.apps.cli.command import Command
from seuwgpu.apps.cli.options import CliError


# ---- corpus -----------------------------------------------------------------------------------------
def corpus_arguments(s: argparse.ArgumentParser):
    s.add_argument(
        "--list", action="store_true", help="list the models (name, primitives, SH, format, licence) and stop"
    )
    s.add_argument("--models", help="comma-separated model names (default: all)")
    s.add_argument("--out", help="the folder to assemble the corpus in (OUT/<model>/..., OUT/INDEX.md)")
    s.add_argument(
        "--from",
        dest="source",
        metavar="FOLDER",
        help="read the files from this folder (same layout, or found by name) instead of downloading them",
    )
    s.add_argument("--manifest", help=argparse.SUPPRESS)  # another manifest (tests, a private corpus)


def cmd_corpus(args):
    """Assemble (or list) the corpus of real trained models."""
    from seuwgpu import api

    names = None if args.models is None else args.models.split(",")
    if args.list:
        if args.out or args.source:
            raise CliError("--list prints the manifest: it takes no --out or --from")
        models = api.corpus_models(args.manifest)
        if names is not None:
            from seuwgpu.model.corpus import select

            models = select({m.name: m for m in models}, names)
        print(f"{'model':<10} {'primitives':>10} {'SH':>2}  {'format':<14} {'MB':>6}  licence")
        for m in models:
            print(
                f"{m.name:<10} {m.primitives:>10,} {m.sh_degree:>2}  {m.format:<14} {m.size / 1e6:>6.1f}  {m.licence}"
                f"  ({m.source.split('@')[0]})"
            )
        return 0
    if not args.out:
        raise CliError("--out DIR is required (or --list)")
    with _Bar() as bar:
        paths = api.assemble_corpus(
            args.out, source=args.source, models=names, manifest=args.manifest, progress=bar.update, log=bar.log
        )
    for name, path in paths.items():
        print(f"{name}: --model {path}")
    print(f"index: {args.out}/INDEX.md")
    return 0


class _Bar:
    """A rich progress bar of the bytes on a terminal; nothing otherwise (the log lines still print)."""

    def __init__(self):
        self.p = None
        if sys.stderr.isatty():
            from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

            self.p = Progress(TextColumn("[bold]corpus"), BarColumn(), DownloadColumn(), TransferSpeedColumn())

    def __enter__(self):
        if self.p is not None:
            self.p.start()
            self.task = self.p.add_task("corpus", total=None)
        return self

    def __exit__(self, *exc):
        if self.p is not None:
            self.p.stop()
        return False

    def update(self, done: int, total: int):
        if self.p is not None:
            self.p.update(self.task, completed=done, total=total)

    def log(self, line: str):
        if self.p is not None:
            self.p.console.print(line, markup=False, highlight=False)
        else:
            print(line)


CORPUS = Command(
    "corpus",
    "list or assemble the corpus of real trained models (sha256-checked)",
    corpus_arguments,
    cmd_corpus,
    resumable=True,
)
