"""Campaign records folded into stratum cells while they are read, part by part.

A planner-sized study holds tens of millions of records (docs/study): more than a workstation's
memory once loaded as one frame. Rates only need, per stratum cell, how many records fell in each
outcome, so the records are folded into cell rows as each Parquet part is read: one row per
(group keys, stratum (estimate.STRATA), weight), holding `n_records` and the count of records of
each outcome class (metrics.image.OUTCOMES) and of non-finite frames. Memory then grows with the
cells, not the records, and a campaign still running can be read (only whole parts are).

`estimate.rate` takes such rows as it takes records (it reads `n_records` when present; the 0/1
column then holds counts), so the rates and intervals are those of the records themselves,
floating-point summation order aside (tests/test_cells.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate
from seuwgpu.campaign import store
from seuwgpu.campaign.schema import check_part_schema
from seuwgpu.metrics.image import OUTCOMES

COUNTS = (*OUTCOMES, "nonfinite")
NEEDED = ("campaign", "k", "weight", "outcome", "nonfinite")
NEVER_POOLED = ("defense", "profile")  # kept in the cells, a row each when several (`groups`)
FOLD_EVERY = 64  # parts between re-folds of the accumulated cells (bounds memory)


def fold(records: pd.DataFrame, by=()) -> pd.DataFrame:
    """Cell rows of records (or of cell rows already folded: counts add up)."""
    keys = list(dict.fromkeys([*by, *(c for c in estimate.STRATA if c in records), "weight"]))
    t = pd.DataFrame({k: records[k].to_numpy() for k in keys})
    if "n_records" in records:
        for c in ("n_records", *COUNTS):
            t[c] = records[c].to_numpy(np.int64)
    else:
        outcome = records["outcome"].to_numpy()
        t["n_records"] = np.ones(len(records), np.int64)
        for o in OUTCOMES:
            t[o] = (outcome == o).astype(np.int64)
        t["nonfinite"] = records["nonfinite"].to_numpy(bool).astype(np.int64)
    return t.groupby(keys, sort=False, dropna=False, as_index=False)[["n_records", *COUNTS]].sum()


def fold_runs(run_dirs, by=("scene", "precision", "defense"), campaign: str = "single", progress=None):
    """(cell rows of the k = 1 records of `campaign` in the runs' parts, parts read). `by` may name
    any record column and `run` (store.run_names: the label the report gives the run).
    `progress(i, n)` is called per part.

    The cells always keep the renderer `profile` and the `defense` (`groups` adds each when several
    are present: a profile renders other frames, and every site is measured once per defense, so
    pooling defenses would count each site twice and blend defended with undefended frames). Runs
    holding the same parts of one spec and profile (the same sites twice, store.repeated_sites) are
    refused unless `by` names `run`.
    run_dirs: run directories, or their store.campaign_runs (each manifest read once)."""
    by = list(by)
    parts = []
    runs = store.campaign_runs(run_dirs)
    if "run" not in by:
        store.refuse_repeated_sites(runs, "pass one of them, or group by run (--by ...,run)")

    for run in runs:
        if not run.path.is_dir():
            raise FileNotFoundError(f"{run.path}: not a run directory")
        if not run.parts:
            raise FileNotFoundError(f"{run.path}: no records/part-*.parquet")
        parts += [(run.name, p) for p in run.parts]
    want = [c for c in dict.fromkeys([*by, *estimate.STRATA, *NEEDED]) if c != "run"]
    acc, pending = None, []
    keep = [*by, *(c for c in NEVER_POOLED if c not in by)]
    for i, (run, path) in enumerate(parts):
        d = _read(path, want, optional=NEVER_POOLED)  # records of older versions lack them
        d = d[(d["campaign"] == campaign) & (d["k"] == 1)]
        if len(d):
            if "run" in by:
                d = d.assign(run=run)
            if "profile" not in d:
                d = d.assign(profile="strict")  # the only renderer before profiles existed
            if "defense" not in d:
                d = d.assign(defense="none")
            pending.append(fold(d, keep))
        if pending and (len(pending) >= FOLD_EVERY or i == len(parts) - 1):
            acc = fold(pd.concat(([acc] if acc is not None else []) + pending, ignore_index=True), keep)
            pending = []
        if progress:
            progress(i + 1, len(parts))
    if acc is None:
        raise ValueError(f"the runs hold no k = 1 records of the {campaign!r} campaign")
    return acc, len(parts)


def _read(path: Path, columns: list[str], optional=()) -> pd.DataFrame:
    import pyarrow.parquet as pq

    schema = pq.read_schema(path)
    check_part_schema(path, schema)  # a column of the wrong kind: refused, naming the part
    have = set(schema.names)
    missing = [c for c in columns if c not in have]
    if missing:
        raise ValueError(
            f"{path}: records lack {', '.join(missing)} (written by an older version?): `seuwgpu report` derives them"
        )
    return pd.read_parquet(path, columns=[*columns, *(c for c in optional if c in have and c not in columns)])


def groups(cells: pd.DataFrame, by) -> list[str]:
    """`by`, plus `defense` and `profile` where the cells hold more than one of them (never pooled)."""
    by = list(by)
    for c in NEVER_POOLED:
        if c in cells and c not in by and cells[c].nunique(dropna=False) > 1:
            by.append(c)
    return by


def outcome_rates(cells: pd.DataFrame, by=(), conf: float = 0.95) -> pd.DataFrame:
    """Per group: n, then the weighted rate and interval of each outcome class and of non-finite
    frames (as proportions: {name}_rate, {name}_ci_lo, {name}_ci_hi)."""
    by = list(by)
    out = None
    for c in COUNTS:
        r = estimate.rate(cells, c, by, conf, prefix=f"{c}_")
        if out is None:
            out = r[by].assign(n=r[f"{c}_n"])
        out = pd.concat([out, r[[f"{c}_rate", f"{c}_ci_lo", f"{c}_ci_hi"]]], axis=1)  # same group order
    return out
