"""The run directory: the one place that knows its layout.

    RUN_DIR/manifest.json                              spec, spec hash, provenance, totals
    RUN_DIR/records/part-FFFFFFFFFF-CCCCCC.parquet     rows of injections F .. F+C-1 (all arms)
    RUN_DIR/records/part-....parquet.HOST.PID.tmp      a part being written (atomic rename)

Records are written in atomic parts (temp file + rename); a re-run skips the parts already
written, and a changed spec is refused.
"""

from __future__ import annotations

import io
import json
import os
import platform
import subprocess
from pathlib import Path

import pandas as pd

MANIFEST = "manifest.json"
RECORDS = "records"

COLUMNS = [
    "campaign",
    "scene",
    "n_primitives",
    "precision",
    "field",
    "primitive",
    "component",
    "bit",
    "bit_class",
    "clean_value",
    "corrupted_value",
    "defense",
    "footprint",
    "footprint_max",
    "peak_error",
    "psnr",
    "ssim",
    "lpips",
    "nonfinite",
    "catastrophic",
    "outcome",
    "clamps",
    "k",
    "repeat",
    "weight",
    "seed",
    "injection_id",
    "time_ms",
]
# wall-clock measurements: the only columns a replay, a shard or a Ray worker may not reproduce
TIMED_COLUMNS = ("time_ms",)
REPRODUCIBLE_COLUMNS = [c for c in COLUMNS if c not in TIMED_COLUMNS]


def columns_of(ctx) -> list[str]:
    """The columns of a context's records: COLUMNS plus its sort-first contamination columns."""
    return COLUMNS + [f"regions_{kind}_{P}" for P in ctx.regions for kind in ("pred", "meas")]


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
    a, b = name[: -len(".parquet")].split("-")[1:3]
    return int(a), int(b)


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


def read_manifest(run_dir) -> dict | None:
    path = manifest_path(run_dir)
    if not path.exists():
        return None
    return json.loads(path.read_text())


def write_manifest(run_dir, manifest: dict):
    atomic_write(manifest_path(run_dir), json.dumps(manifest, indent=1).encode())


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


def parquet_bytes(df: pd.DataFrame) -> bytes:
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()


def write_part(run_dir, first: int, count: int, df: pd.DataFrame):
    atomic_write(part_path(run_dir, first, count), parquet_bytes(df))


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


def atomic_write(path: Path, data: bytes):
    tmp = path.with_name(path.name + f".{host()}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def read_records(run_dir) -> pd.DataFrame:
    parts = part_files(run_dir)
    if not parts:
        return pd.DataFrame(columns=COLUMNS)
    return pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
