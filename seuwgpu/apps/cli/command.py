"""One command of the command line: its name, its help line, the function that adds its options
and the handler that runs it, kept side by side in the command's module."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Command:
    """`add_arguments(parser)` adds the command's options; `run(args)` returns its exit status.
    `resumable`: an interrupted run keeps its completed parts (said when it is stopped)."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int | None]
    resumable: bool = False

    def add_to(self, commands) -> argparse.ArgumentParser:
        """Its parser among `commands` (argparse's subparsers), the handler set as args.func."""
        parser = commands.add_parser(self.name, help=self.help)
        self.add_arguments(parser)
        parser.set_defaults(func=self.run)
        return parser
