"""The one progress display of the package: a rich bar on stderr, or log lines for a quiet run
(a campaign under a batch system), or nothing when stderr is no terminal."""

from __future__ import annotations

import sys
import time


class ProgressBar:
    """Progress of `total` units of `what` (None: not known yet), `done` of them done before (by
    the run a resumed one continues; counted apart in rates). `rate`: units/s and the time
    elapsed; `catastrophic`: the running count of catastrophic outcomes. `quiet`: no bar (None:
    none unless stderr is a terminal); with `log_lines`, a quiet bar prints a line every 10 s
    and at the end instead. `transient`: the bar disappears when closed.

    `with ProgressBar("frames", total) as bar:` then `bar.advance()` per unit, or
    `bar.update(done, total)` from a callback that counts for itself."""

    LOG_SECONDS = 10

    def __init__(
        self,
        what: str,
        total: int | None = None,
        done: int = 0,
        *,
        rate: bool = False,
        catastrophic: bool = False,
        quiet: bool | None = None,
        log_lines: bool = False,
        transient: bool = True,
    ):
        self.what, self.total, self.done, self.start_done = what, total, done, done
        self.quiet = not sys.stderr.isatty() if quiet is None else quiet
        self.log_lines, self.catastrophic, self.cat = log_lines, catastrophic, 0
        self.t0 = self.last = time.perf_counter()
        self.p = None
        if not self.quiet:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            columns = [TextColumn(f"[bold]{what}"), BarColumn(), MofNCompleteColumn()]
            if rate:
                columns += [TextColumn("{task.fields[rate]:>8.1f}/s"), TimeElapsedColumn()]
            columns += [TextColumn("ETA"), TimeRemainingColumn()]
            if catastrophic:  # resumed: the parts on disk are not re-read, so the count is this session's
                columns.append(TextColumn("catastrophic: {task.fields[cat]}" + (" (since resuming)" if done else "")))
            self.p = Progress(*columns, transient=transient)
            self.p.start()
            self.task = self.p.add_task(what, total=total, completed=done, rate=0.0, cat=0)

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def advance(self, n: int = 1, cat: int = 0):
        """`n` more units done, `cat` of them catastrophic."""
        self.update(self.done + n, cat=cat)

    def update(self, done: int, total: int | None = None, cat: int = 0):
        """`done` units done of `total` (None: as before)."""
        self.done, self.cat = done, self.cat + cat
        self.total = self.total if total is None else total
        now = time.perf_counter()
        rate = (self.done - self.start_done) / max(now - self.t0, 1e-9)
        if self.p is not None:
            self.p.update(self.task, completed=self.done, total=self.total, rate=rate, cat=self.cat)
        elif self.log_lines and (now - self.last > self.LOG_SECONDS or self.done == self.total):
            self.last = now
            eta = "-"  # no rate yet
            if rate > 0 and self.total is not None:
                left = (self.total - self.done) / rate
                eta = time.strftime("%H:%M:%S", time.gmtime(left)) if left < 86400 else f"{left / 3600:.0f} h"
            since = f" (of the {self.done - self.start_done} run since resuming)" if self.start_done else ""
            cat_text = f", catastrophic {self.cat}{since}" if self.catastrophic else since
            print(
                f"{self.done}/{self.total} {self.what}, {rate:.1f}/s, ETA {eta}{cat_text}", file=sys.stderr, flush=True
            )

    def close(self):
        if self.p is not None:
            self.p.stop()
            self.p = None


def injection_bar(total: int, done: int, quiet: bool) -> ProgressBar:
    """A campaign's display: injections/s, ETA and the running catastrophe count; log lines when
    quiet. It stays on screen when the run ends."""
    return ProgressBar("injections", total, done, rate=True, catastrophic=True, quiet=quiet, log_lines=True,
                       transient=False)  # fmt: skip
