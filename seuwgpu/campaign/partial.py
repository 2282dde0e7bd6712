"""Resumable records of the commands that are no campaign (`storm`, `state`): the records measured
so far in OUT/NAME.partial.parquet, with what identifies the run (`run`: every argument that
changes a record, the model and camera files standing for their content) in the file's Parquet
metadata.

A re-run of the same arguments continues after the records the file holds: the commands measure
their units in a fixed order, and no unit's draws depend on which units were measured (storm draws
every frame's upsets before the first frame and replays a skipped frame's flips into its memory
without rendering it; state replays the draws of the flips it skips). A re-run of other arguments
is refused, naming what differs, and the file is left as it is.

The file is rewritten whole and atomically (temp file + rename) when the command ends early
(Ctrl-C, an error) and, while it runs, at most every SAVE_EVERY_S seconds, so a killed process
(kill -9, a lost node) loses at most the last seconds of measurements. A write waits at least 20
times as long as the last one took, so rewriting stays under 5% of the run. One file rewritten,
not parts appended: these runs hold thousands of records (the default `state` run 2,560), not a
campaign's millions, and the file stays the records as the finished run writes them.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import time
from pathlib import Path

import pandas as pd

from seuwgpu.campaign.progress import ProgressBar
from seuwgpu.campaign.store import atomic_write, lock, remove_stale_temps
from seuwgpu.errors import InputError

RUN_META = b"seuwgpu.run"  # Parquet schema metadata of a partial file: its run, as JSON
SAVE_EVERY_S = 10.0
WRITE_SHARE = 20  # a write waits at least this many times as long as the last write took


def _shown(value) -> str:
    if value is None:
        return "unset"
    if isinstance(value, list):
        return " ".join(map(str, value))
    if isinstance(value, str) and value.startswith("sha256:"):
        return value[:19] + ".."
    return str(value)


def differences(old: dict, new: dict) -> list[str]:
    """'--KEY THEN there, NOW now' for each key of a run whose value differs."""
    return [
        f"--{key} {_shown(old.get(key))} there, {_shown(new.get(key))} now"
        for key in dict.fromkeys([*new, *old])
        if key != "command" and old.get(key) != new.get(key)
    ]


class PartialRecords:
    """The records of an interrupted run found at `path` (`rows`, in the order they were
    measured; [] when there is none), refused when they are another run's (InputError naming what
    differs). `records(rows)` makes the records' DataFrame, as the finished run writes them."""

    def __init__(self, path, run: dict, records=pd.DataFrame):
        self.path, self.records = Path(path), records
        self.run = json.loads(json.dumps(run))  # as it reads back: lists, not tuples
        # one run of the command per directory at a time (RunInUse), from reading the file until
        # kept() ends (or the process does)
        self._lock = contextlib.ExitStack()
        self._lock.enter_context(lock(self.path.parent, command=self.run.get("command", self.path.stem)))
        remove_stale_temps(self.path.parent)  # a write cut off by a kill
        self.rows = self._read()
        self._saved = len(self.rows)
        self._due = time.monotonic() + SAVE_EVERY_S

    def _read(self) -> list[dict]:
        import pyarrow.parquet as pq

        if not self.path.exists():
            return []
        try:
            table = pq.read_table(self.path)
            run = json.loads((table.schema.metadata or {})[RUN_META])
        except (OSError, ValueError, KeyError) as e:  # pyarrow's ArrowInvalid is a ValueError
            why = "written by a seuwgpu that did not record its arguments" if isinstance(e, KeyError) else "unreadable"
            print(f"seuwgpu: {self.path}: {why}; starting over (it is replaced)", file=sys.stderr)
            return []
        if run != self.run:
            what = "; ".join(differences(run, self.run)) or "other arguments"
            raise InputError(
                f"{self.path} holds an interrupted `seuwgpu {run.get('command', self.run.get('command'))}` run of "
                f"other arguments ({what}): re-run it with its arguments to resume it, or use another --out, or "
                f"delete {self.path} to start over"
            )
        return table.to_pandas().to_dict("records")

    def save(self):
        """Write the records measured so far (nothing when no record is new since the last write)."""
        if len(self.rows) <= self._saved:
            return
        import pyarrow as pa
        import pyarrow.parquet as pq

        t0 = time.monotonic()

        table = pa.Table.from_pandas(self.records(self.rows), preserve_index=False)
        meta = dict(table.schema.metadata or {})
        meta[RUN_META] = json.dumps(self.run).encode()
        buf = io.BytesIO()
        pq.write_table(table.replace_schema_metadata(meta), buf)
        atomic_write(self.path, buf.getvalue())
        self._saved = len(self.rows)
        now = time.monotonic()
        self._due = now + max(SAVE_EVERY_S, WRITE_SHARE * (now - t0))

    def progress(self, step=None):
        """A progress callback for the command's loop: `step()`, then the file rewritten when a
        write is due."""

        def advance():
            if step is not None:
                step()
            if time.monotonic() >= self._due:
                self.save()

        return advance

    @contextlib.contextmanager
    def kept(self):
        """Around the run and the writing of its results: when it ends early, the records measured
        so far are saved (and said so); when it finishes, the partial file is removed. The
        directory's lock is released either way."""
        try:
            yield self.rows
            self.path.unlink(missing_ok=True)
        except BaseException as e:
            self.save()
            if self.rows:
                how = "interrupted" if isinstance(e, KeyboardInterrupt) else "stopped by an error"
                print(
                    f"seuwgpu: {how}: the {len(self.rows):,} records measured so far are in {self.path} "
                    "(re-run the same command to resume)",
                    file=sys.stderr,
                )
            raise
        finally:
            self._lock.close()


def run_identity(
    command: str,
    source,
    views: list,
    *,
    model=None,
    cameras=None,
    sh_degree: int,
    seed: int | None,
    size: tuple[int, int],
    scale: float | None,
    precision: str,
    profile: str,
    **options,
) -> dict:
    """What makes a resumed run the same run: every argument that decides its records. The model
    and camera files (`model`, `cameras`: their paths, None for an embedded scene or orbit views)
    stand for their content (sha256: the same files through another path are the same run); the
    other arguments as read, defaults spelled out; the up axis as resolved (`source.up`), so that
    naming the default axis, or one beside a cameras file, is the same run; then the command's
    `options`, named as its command-line options."""
    from seuwgpu.campaign.spec import content_hash

    def content(key, path):
        return None if path is None else "sha256:" + content_hash(key, path)

    return {
        "command": command,
        "model": content("model", model),
        "scene": None if model else source.name,
        "n": None if model else source.model.n,
        "sh-degree": None if model else sh_degree,
        "seed": seed,
        "up": None if cameras else source.up,  # what frames the orbit; unused by cameras
        "cameras": content("cameras", cameras),
        "views": len(views),
        "size": None if cameras else "x".join(map(str, size)),
        "scale": scale or 1.0,
        "precision": precision,
        "profile": profile,
        **options,
    }


@contextlib.contextmanager
def resumed(out, name: str, run: dict, records, unit: str, total: int):
    """Around a resumable run (`storm`, `state`) and the writing of its results: the records of an
    interrupted run of the same `run` (run_identity) in OUT/NAME.partial.parquet, read before any
    rendering, and a bar of `total` `unit`s. Yields (rows, progress) for the API call (its `rows`
    and `progress`)."""
    partial = PartialRecords(Path(out) / f"{name}.partial.parquet", run, records)
    with partial.kept() as rows, ProgressBar(unit, total, len(rows)) as bar:
        yield rows, partial.progress(bar.advance)
