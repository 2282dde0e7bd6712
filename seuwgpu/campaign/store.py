"""The run directory: the one place that knows its layout.

    RUN_DIR/manifest.json                              spec, spec hash, provenance, totals
    RUN_DIR/records/part-FFFFFFFFFF-CCCCCC.parquet     rows of injections F .. F+C-1 (all arms)
    RUN_DIR/records/part-....parquet.HOST.PID.tmp      a part being written (atomic rename)
    RUN_DIR/.lock-I-of-N                               held (flock) by the campaign running shard I/N

Records are written in atomic parts (temp file + rename); a re-run skips the parts already
written, and a changed spec is refused (`check_same_run`, naming a model or camera file whose
content changed). A part that cannot be read, or holds the wrong number of rows, is deleted and
redone; a part that is no block of the spec (a stray file) is never read (`record_parts`).
A second campaign on the same shard of one directory is refused (RunInUse) while the first holds
its lock; the lock is an flock, so a killed campaign releases it and can be resumed at once.
"""

from __future__ import annotations

import bisect
import contextlib
import io
import json
import os
import platform
import queue
import shutil
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from seuwgpu.campaign.schema import COLUMNS, REGION_TYPE, check_part_schema, column_type, records_schema
from seuwgpu.errors import InputError, RunInUse
from seuwgpu.model import checks

MANIFEST = "manifest.json"
RECORDS = "records"


def manifest_path(run_dir) -> Path:
    return Path(run_dir) / MANIFEST


def records_dir(run_dir) -> Path:
    return Path(run_dir) / RECORDS


def part_name(first: int, count: int) -> str:
    return f"part-{first:010d}-{count:06d}.parquet"


def part_path(run_dir, first: int, count: int) -> Path:
    return records_dir(run_dir) / part_name(first, count)


def parse_part_name(name: str) -> tuple[int, int] | None:
    """(first id, count) of a part file name, or None for any other name."""
    if not (name.startswith("part-") and name.endswith(".parquet")):
        return None
    fields = name[: -len(".parquet")].split("-")[1:]
    if len(fields) != 2 or not all(f.isdigit() for f in fields):
        return None
    return int(fields[0]), int(fields[1])


def part_files(run_dir) -> list[Path]:
    return sorted(records_dir(run_dir).glob("part-*.parquet"))


def parts_in(run_dir) -> set[tuple[int, int]]:
    """(first id, count) of the parts already written (cheap: one directory scan)."""
    out = set()
    try:
        it = os.scandir(records_dir(run_dir))
    except FileNotFoundError:
        return out
    with it:
        for e in it:
            key = parse_part_name(e.name)
            if key is not None:
                out.add(key)
    return out


def part_rows(path: Path) -> int | None:
    """Rows of a part from its Parquet footer, or None when the file is empty or unreadable."""
    try:
        return int(pq.read_metadata(path).num_rows)
    except (OSError, ValueError):  # pyarrow's ArrowInvalid is a ValueError
        return None


def expected_parts(spec) -> dict[tuple[int, int], int]:
    """{(first id, count): rows} of every part a spec's campaign writes (blocks of `batch`
    injections per context, one row per injection and defense). `spec`: a Spec or its stored
    form (a manifest's)."""
    from seuwgpu.campaign.sampling import enumerate_contexts
    from seuwgpu.campaign.spec_types import as_spec

    spec = as_spec(spec)
    out, bs = {}, spec.batch
    for ctx in enumerate_contexts(spec):
        for a in range(0, ctx.count, bs):
            m = min(bs, ctx.count - a)
            out[(ctx.first_id + a, m)] = m * len(ctx.defenses)
    return out


def completed_parts(run_dir, expected: dict[tuple[int, int], int]) -> set[tuple[int, int]]:
    """The parts among `expected` ({(first, count): rows}) already written whole. A part that is
    empty, unreadable or holds another number of rows is deleted, so the caller redoes it."""
    done = set()
    for key in parts_in(run_dir) & set(expected):
        path = part_path(run_dir, *key)
        if part_rows(path) == expected[key]:
            done.add(key)
        else:
            path.unlink(missing_ok=True)
    return done


def _spec_parts(manifest: dict) -> dict[tuple[int, int], int] | None:
    """expected_parts of a manifest's campaign spec, or None without one (runs of other tools)."""
    try:
        return expected_parts(manifest["spec"])
    except (KeyError, TypeError, ValueError):
        return None


def _named_parts(parts: list[Path], want) -> list[Path]:
    return parts if want is None else [p for p in parts if parse_part_name(p.name) in want]


def record_parts(run_dir, manifest: dict | None = None) -> list[Path]:
    """The parts of a run that hold its records: the blocks its spec names (stray part files are
    left out). Without a manifest holding a campaign spec (runs written by other tools), every
    part file."""
    manifest = manifest if manifest is not None else read_manifest(run_dir)
    return _named_parts(part_files(run_dir), _spec_parts(manifest or {}))


@dataclass(eq=False)
class CampaignRun:
    """A run directory as reports and `seuwgpu rates` read it, its manifest read (and its spec's
    parts enumerated) once: `campaign_runs` makes them, and `repeated_sites`, `partial_runs_text`,
    report.build.load_runs and analysis.cells.fold_runs take them in place of the folders."""

    name: str  # as run_names gives it
    path: Path  # as given
    here: Path  # resolved: one folder given twice is one run
    manifest: dict  # {} without one
    key: tuple | None  # (spec hash, profile), None without a campaign's manifest
    sites: tuple | None  # (spec.sites_key, profile), None without a campaign spec
    expected: dict | None  # {(first id, count): rows} of the parts its spec names, None without one
    parts: list[Path]  # record_parts
    _rows: dict | None = field(default=None, repr=False)

    def rows(self) -> dict[str, int | None]:
        """{part file name: rows in its Parquet footer, None when unreadable}, read once."""
        if self._rows is None:
            self._rows = {p.name: part_rows(p) for p in self.parts}
        return self._rows

    def whole(self, part: str) -> bool:
        """Whether a part holds the rows its block should: the spec's count (injections x defenses),
        or, without a spec, a readable multiple of its injections."""
        rows, key = self.rows().get(part), parse_part_name(part)
        if rows is None or key is None:
            return False
        if self.expected is not None:
            return rows == self.expected.get(key)
        return key[1] > 0 and rows >= key[1] and rows % key[1] == 0


def campaign_runs(run_dirs) -> list[CampaignRun]:
    """Each run directory's CampaignRun (a list of them is returned as it is)."""
    from seuwgpu.campaign.spec_hash import sites_key

    run_dirs = list(run_dirs)
    if all(isinstance(r, CampaignRun) for r in run_dirs):
        return run_dirs
    out = []
    for rd, name in zip(run_dirs, run_names(run_dirs)):
        m = read_manifest(rd) or {}
        profile = m.get("profile", "strict")
        key = (m["spec_hash"], profile) if m.get("spec_hash") else None
        want = _spec_parts(m)
        sites = (sites_key(m["spec"]), profile) if want is not None else None
        parts = _named_parts(part_files(rd), want)
        out.append(CampaignRun(name, Path(rd), Path(rd).resolve(), m, key, sites, want, parts))
    return out


def partial_runs_text(run_dirs) -> str:
    """One sentence naming the runs that hold fewer injections than their spec plans ("" if none).
    A stratified campaign writes its cells in order, so an unfinished run's estimates lack whole
    cells, not a random share of each: reports must say so. Runs of one spec and profile (the
    shards of a campaign in folders of their own, or a partial merge and the shard that fills it)
    are counted together, by the parts they hold between them. Only whole parts count (their rows
    from the Parquet footers, as a resumed campaign checks them): a damaged one is named.
    `run_dirs`: run directories, or their campaign_runs."""
    groups: dict[tuple, tuple[list[str], dict[str, bool], int]] = {}
    for run in campaign_runs(run_dirs):
        total = run.manifest.get("total_injections")
        if not isinstance(total, int):
            continue  # a run without a campaign manifest cannot say
        names, held, _ = groups.setdefault(run.key or (run.name,), ([], {}, total))
        names.append(run.name)
        for p in run.parts:
            held[p.name] = held.get(p.name, False) or run.whole(p.name)
    out = []
    for names, held, total in groups.values():
        done = sum((parse_part_name(p) or (0, 0))[1] for p, ok in held.items() if ok)
        if done < total:
            verb = "hold" if len(names) > 1 else "holds"
            text = f"{' + '.join(names)} {verb} {done:,} of {total:,} injections"
            damaged = sorted(p for p, ok in held.items() if not ok)
            if damaged:
                shown = ", ".join(damaged[:3]) + (f" and {len(damaged) - 3} more" if len(damaged) > 3 else "")
                text += (
                    f" ({len(damaged)} damaged part{'s' if len(damaged) > 1 else ''}, unreadable or of the wrong "
                    f"row count, not counted: {shown}; resuming the campaign redoes them)"
                )
            out.append(text)
    if not out:
        return ""
    return (
        "Unfinished: " + "; ".join(out) + ". A campaign writes its cells in order, so the cells not yet run are "
        "missing from every estimate (rates describe the cells run so far, not the spec's population)."
    )


def _overlapping(parts: list[Path], other: list[Path]) -> int:
    """How many of `parts` hold an injection id that one of `other` holds too (by their names)."""
    keys = [parse_part_name(p.name) for p in other]
    spans = sorted((k[0], k[0] + k[1]) for k in keys if k and k[1] > 0)
    starts, ends = [], []  # the other's ids as disjoint [start, end) spans
    for a, b in spans:
        if ends and a <= ends[-1]:
            ends[-1] = max(ends[-1], b)
        else:
            starts.append(a)
            ends.append(b)
    n = 0
    for p in parts:
        k = parse_part_name(p.name)
        if k is None or k[1] < 1:
            continue
        i = bisect.bisect_right(starts, k[0] + k[1] - 1) - 1  # the last span starting before the part ends
        if i >= 0 and ends[i] > k[0]:
            n += 1
    return n


def repeated_sites(run_dirs) -> list[tuple[str, str, int]]:
    """Pairs of runs holding the same fault sites under the same renderer profile, or one folder
    given twice: the same sites measured twice, which a pooled estimate would count as twice the
    sample. Runs of one spec share sites where they hold the same parts (shards hold different
    parts); runs of specs that differ only in what draws and measures no site (spec.sites_key: a
    name, the batch, thresholds, extra metrics) where their parts hold the same injection ids.
    Another profile renders other frames. Returns (run name, run name, parts in common) per such
    pair. `run_dirs`: run directories, or their campaign_runs."""
    out = []
    seen: list[tuple[CampaignRun, set]] = []
    for run in campaign_runs(run_dirs):
        names = {p.name for p in run.parts}
        for other, other_names in seen:
            if run.here == other.here:
                common = len(run.parts)
            elif run.key and run.key == other.key:
                common = len(names & other_names)
            elif run.sites and run.sites == other.sites:
                common = _overlapping(run.parts, other.parts)
            else:
                common = 0
            if common:
                out.append((other.name, run.name, common))
        seen.append((run, names))
    return out


def refuse_repeated_sites(runs, hint: str):
    """Refuse, in one line naming the first pair and ending with `hint` (what to do), runs that
    hold the same fault sites (repeated_sites): every analysis pools runs, and the same sites twice
    would count as twice the sample."""
    twice = repeated_sites(runs)
    if twice:
        a, b, k = twice[0]
        raise InputError(
            f"runs {a} and {b} hold {k} part(s) of the same fault sites under the same profile (one spec run "
            f"twice, or specs differing only in name, batch, thresholds or extra metrics), which pooled would "
            f"count as twice the sample: {hint}"
        )


def read_manifest(run_dir) -> dict | None:
    from seuwgpu.campaign.spec import SpecError

    path = manifest_path(run_dir)
    if not path.exists():
        return None
    try:
        m = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SpecError(f"{path}: not a readable run manifest ({e})") from None
    if not isinstance(m, dict):
        raise SpecError(f"{path}: not a run manifest (a JSON object expected)")
    return m


def check_same_run(run_dir, manifest: dict | None, spec, spec_hash: str):
    """Refuse to add records of `spec` (a Spec, or its stored form) to a run of another spec,
    naming what differs (a model or camera file whose content changed since the run began, else
    the spec hashes). A run without any part may be replaced (the caller writes the new manifest)."""
    from seuwgpu.campaign.spec import SpecError
    from seuwgpu.campaign.spec_types import spec_dict

    spec = spec_dict(spec)

    if manifest is None or manifest.get("spec_hash") == spec_hash:
        return
    if not part_files(run_dir):
        return  # a run that stopped before its first part (a model that failed to load, ...) holds nothing
    old = manifest.get("spec") or {}
    for i, (a, b) in enumerate(zip(old.get("scenes", []), spec.get("scenes", []))):
        for key in ("model", "cameras"):
            ha, hb = a.get(f"{key}_sha256"), b.get(f"{key}_sha256")
            if ha and hb and ha != hb:
                raise SpecError(
                    f"{run_dir} holds a run made with other content in {b.get(key)} (scenes[{i}].{key}: sha256 "
                    f"{ha[:12]}.. then, {hb[:12]}.. now): the file changed since the run began; restore it, or "
                    "use a new --out directory"
                )
    from seuwgpu.campaign.spec_hash import renamed_models

    renamed = renamed_models(old, spec)
    if renamed:
        raise SpecError(
            f"{run_dir} holds a run whose records name its model otherwise: {'; '.join(renamed)}. Records "
            "name a model by its file (or INRIA output folder) name: give it the run's name again, or use a "
            "new --out directory"
        )
    raise SpecError(
        f"{run_dir} holds a run of a different spec (hash {manifest.get('spec_hash')} != {spec_hash}); "
        "use a new --out directory, or the original spec to resume"
    )


def make_out_dir(path, option: str = "--out", what: str = "run directory") -> Path:
    """Create an output folder (and its parents) before any work is done, or say in one line why
    it cannot be: a file where it or one of its parents would be, no permission."""
    p = Path(path)
    for q in (p, *p.parents):
        if q.exists() and not q.is_dir():
            raise InputError(f"{option} {p}: {'it' if q == p else q} is a file, not a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"{option} {p}: cannot create the {what} ({e.strerror or e})") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: the {what} is not writable")
    return p


@contextlib.contextmanager
def lock(run_dir, shard: tuple[int, int] = (0, 1), command: str | None = None):
    """Hold the run directory's lock for shard I/N (an exclusive flock: released when the
    process ends, however it ends). Raises RunInUse when another process holds it; a shard
    outside 0 <= I < N is refused before anything is created. `command`: the lock of a command
    that is no campaign (`storm`, `state`: one run per directory) instead."""
    import fcntl

    i, n = checks.shard(shard)
    make_out_dir(run_dir)
    path = Path(run_dir) / (f".lock-{command}" if command else f".lock-{i}-of-{n}")
    what = f"a `seuwgpu {command}` run" if command else "a campaign"
    where = "there" if command else f"shard {i}/{n} there"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            raise RunInUse(
                f"{run_dir} is in use: {what} ({holder}) is running {where}; "
                "wait for it to finish (or stop it), or use another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {platform.node() or 'this host'}".encode(), 0)
        yield path
    finally:
        os.close(fd)  # closing the descriptor releases the flock


def write_manifest(run_dir, manifest: dict):
    atomic_write(manifest_path(run_dir), json.dumps(manifest, indent=1).encode())


def guard_note_path(run_dir, scene: str, precision: str, profile: str) -> Path:
    """Where a run records the guard's effect on a clean model holding NaN/Inf (once per model)."""
    return Path(run_dir) / f"guard_on_clean-{scene}-{precision}-{profile}.json"


def write_guard_note(run_dir, scene: str, precision: str, profile: str, note: dict):
    atomic_write(guard_note_path(run_dir, scene, precision, profile), json.dumps(note, indent=1).encode())


def read_guard_notes(run_dir) -> list[tuple[str, str, str, dict]]:
    """(scene, precision, profile, note) of each guard note a run wrote (write_guard_note)."""
    out = []
    head = "guard_on_clean-"
    for path in sorted(Path(run_dir).glob(guard_note_path(run_dir, "*", "*", "*").name)):
        parts = path.stem[len(head) :].rsplit("-", 2)
        try:
            note = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if len(parts) == 3 and isinstance(note, dict):
            out.append((*parts, note))
    return out


def view_times_path(run_dir, key: str) -> Path:
    """Where a run keeps one engine's view times (Runner.view_times): measured once per run, so a
    resumed run or another shard records the same time_ms and pays no second measurement."""
    return Path(run_dir) / "view_times" / f"{key}.json"


def visible_path(run_dir, name: str) -> Path:
    """Where a run folder keeps one visible-damage measurement's per-upset records
    (`seuwgpu defenses --visible N --out RUN`, campaign/visible.py), which the report of RUN reads."""
    return Path(run_dir) / "visible" / f"{name}.parquet"


def forget_measurements(run_dir):
    """Remove what a run measured beside its records (view times, guard notes): the run directory
    is taken by another spec (check_same_run lets one without parts be), and they were measured
    for the old one."""
    shutil.rmtree(view_times_path(run_dir, "").parent, ignore_errors=True)
    for note in Path(run_dir).glob(guard_note_path(run_dir, "*", "*", "*").name):
        note.unlink(missing_ok=True)


def read_view_times(run_dir, key: str) -> dict | None:
    path = view_times_path(run_dir, key)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read the run's view times ({e}); delete it to measure them again") from None


def claim_view_times(run_dir, key: str, times: dict) -> dict:
    """Store `times` unless another shard stored its own first; returns the stored ones (the first
    writer's), so every part of a run carries the same time_ms."""
    path = view_times_path(run_dir, key)
    path.parent.mkdir(exist_ok=True)
    if not atomic_write(path, json.dumps(times, indent=1).encode(), exclusive=True):
        return read_view_times(run_dir, key)
    return times


def git_commit() -> str:
    try:
        return (
            subprocess.run(
                ["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True, text=True, timeout=5
            ).stdout.strip()
            or "unknown"
        )
    except Exception:
        return "unknown"


PART_META = "seuwgpu.block_seconds"  # Parquet schema metadata of a part: the seconds it took


def parquet_bytes(df: pd.DataFrame, seconds: float | None = None) -> bytes:
    """The records as Parquet; `seconds` (the compute time of the block, engine set-up included
    when the block paid it) is kept in the file's schema metadata, so a run's compute time is
    the sum over its parts, however often it was interrupted and resumed (`run_seconds`)."""
    df = df.copy(deep=False)
    for c in df.columns:  # bitmasks computed as uint64: stored as int64, the same 64 bits
        if column_type(str(c)) == REGION_TYPE and df[c].dtype == "uint64":
            df[c] = df[c].to_numpy().view("int64")
    table = pa.Table.from_pandas(df, schema=records_schema(df.columns), preserve_index=False)
    if seconds is not None:
        meta = dict(table.schema.metadata or {})
        meta[PART_META.encode()] = repr(float(seconds)).encode()
        table = table.replace_schema_metadata(meta)
    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def write_part(run_dir, first: int, count: int, df: pd.DataFrame, seconds: float | None = None):
    atomic_write(part_path(run_dir, first, count), parquet_bytes(df, seconds))


class PartWriter:
    """Writes parts in a thread of its own, so that their Parquet encoding and fsync overlap the
    evaluation of the next blocks (written inline, they would more than halve a GPU's rate:
    docs/renderer.md "Measurements"). `close` writes every part queued, even after
    an interrupt, and raises the first error a write met unless told not to."""

    def __init__(self, run_dir, depth: int = 64):
        self.run_dir, self.error = run_dir, None
        self.queue = queue.Queue(maxsize=depth)  # bounded: records wait in memory, not without end
        self.thread = threading.Thread(target=self._loop, name="seuwgpu-part-writer", daemon=True)
        self.thread.start()

    def _loop(self):
        while (item := self.queue.get()) is not None:
            if self.error is None:
                try:
                    write_part(self.run_dir, *item)
                except BaseException as e:  # reported by the next put or by close
                    self.error = e

    def put(self, first: int, count: int, df: pd.DataFrame, seconds: float | None = None):
        if self.error is not None:
            raise self.error
        self.queue.put((first, count, df, seconds))

    def close(self, raise_error: bool = True):
        """Write what is queued and stop; `raise_error=False` when another exception is already
        ending the run (the caller's must not be replaced by a write error)."""
        self.queue.put(None)
        self.thread.join()
        if raise_error and self.error is not None:
            raise self.error


def run_names(run_dirs) -> list[str]:
    """The `run` label of each run directory: its folder's name, made unique ("study#2") when two
    runs share one, as the report and `seuwgpu rates` label records."""
    names, seen = [], set()
    for rd in run_dirs:
        p = Path(rd)
        name = p.resolve().name or str(p)
        base, i = name, 2
        while name in seen:
            name, i = f"{base}#{i}", i + 1
        seen.add(name)
        names.append(name)
    return names


def run_seconds(run_dir, manifest: dict | None = None) -> tuple[float, int]:
    """(compute seconds summed over the run's parts that record them, parts that do not: written
    before parts carried their time, or by other tools)."""
    total, untimed = 0.0, 0
    for path in record_parts(run_dir, manifest):
        meta = pq.read_schema(path).metadata or {}
        value = meta.get(PART_META.encode())
        if value is None:
            untimed += 1
        else:
            total += float(value)
    return total, untimed


def host() -> str:
    return platform.node().replace(".", "_") or "host"


def remove_stale_temps(folder: Path):
    """Delete half-written parts left by dead writers of this host (other shards may share the
    folder: their live temp files, and other hosts', are left alone)."""
    me = host()
    for tmp in folder.glob("*.tmp"):
        parts = tmp.name.rsplit(".", 3)  # NAME.parquet . host . pid . tmp
        if len(parts) != 4 or parts[1] != me:
            continue
        try:
            os.kill(int(parts[2]), 0)
        except (ProcessLookupError, ValueError):
            tmp.unlink(missing_ok=True)
        except PermissionError:
            pass


def atomic_write(path: Path, data: bytes, exclusive: bool = False) -> bool:
    """Write `path` whole or not at all (a temp file named as remove_stale_temps expects, then
    put in place). `exclusive`: leave a file already there as it is (the first writer wins); returns whether
    `data` was written."""
    tmp = path.with_name(path.name + f".{host()}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    if not exclusive:
        os.replace(tmp, path)
        return True
    try:
        os.link(tmp, path)  # fails when the name exists
    except FileExistsError:
        return False
    finally:
        tmp.unlink(missing_ok=True)
    return True


def read_part(path: Path, columns=None) -> pd.DataFrame:
    """One part's records (`columns` of them), its column types checked (check_part_schema)."""
    check_part_schema(path)
    return pd.read_parquet(path, columns=columns)


def read_records(run_dir) -> pd.DataFrame:
    parts = record_parts(run_dir)
    if not parts:
        return pd.DataFrame(columns=COLUMNS)
    return pd.concat([read_part(p) for p in parts], ignore_index=True)
