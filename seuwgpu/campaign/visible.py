"""What the user sees: the frames drawn from a corrupted model that are catastrophic (or SDC),
per upset, exposure counted, under each defense and its check schedule (issue 47 point 1).

Measured by running frames, as a storm does (campaign/storm.py), never derived from the exposure
formula: `upsets` windows of `window` frames each, the model reloaded at the start of each window
(the scrub); one upset per window, landing before a frame drawn uniformly in the window; a check
defense checks before every S-th frame (frames 0, S, 2S, ... of the storm; a window is a whole
number of S, so every window sees the same phases). Every frame is rendered and measured against
the clean render. Every arm sees the same upsets at the same frames (paired).

Per arm: catastrophic and SDC frames per upset (mean over the upsets, 95% bootstrap interval; with
no event, the exact binomial bound on the share of upsets showing any, times the window),
the share of them that follow a check (`residue`: what the check left, seen until the reload),
and the ratio of catastrophic frames to the unguarded arm's ("none", when measured; paired
bootstrap interval). The unguarded arm draws an upset until the reload, so its count, and every
ratio to it, grows with `window`: the window is part of every number.

Upsets are drawn from `cells` ((field, bit) pairs; default the dangerous cells, log-scale and
opacity bits 30 and 31, where nearly every catastrophe of a single flip lives), primitive and
component uniform, shaped by the fault model (`fault`, sites.FAULT_MODELS).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd

from seuwgpu.campaign.store import atomic_write, visible_path
from seuwgpu.campaign.storm import shape_upsets, storm
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.sites import DANGEROUS_CELLS, Site, check_fault_model
from seuwgpu.metrics.image import PIXEL_THRESHOLD
from seuwgpu.model.fields import field_components

BOOTSTRAP = 2000


def plan_upsets(engine, upsets: int, window: int, cells=DANGEROUS_CELLS, fault: str = "bit", seed: int = 0):
    """(a storm plan: `upsets * window` frames of sites, the frame in its window each lands at)."""
    check_fault_model(fault)
    rng = np.random.default_rng(seed)
    plan = [[] for _ in range(upsets * window)]
    at = rng.integers(0, window, size=upsets)
    for u in range(upsets):
        field, bit = cells[int(rng.integers(len(cells)))]
        nc = field_components(field, engine.degree)
        site = Site(field, int(rng.integers(engine.n)), int(rng.integers(nc)), (int(bit),))
        if fault != "bit":
            site_list = shape_upsets([site], fault, engine.n, engine.degree, engine.precision, rng)
        else:
            site_list = [site]
        plan[u * window + int(at[u])] = site_list
    return plan, at


def whole_window(window: int, check_every: int) -> int:
    """The window rounded up to whole schedules, so that every window sees the same check phases."""
    return -(-window // check_every) * check_every


def visible_frames(upsets: int, window: int, check_every: int, arms: int) -> int:
    """The frames a visible-damage measurement renders (its progress bar's total)."""
    return upsets * whole_window(window, check_every) * arms


def frames_interval(x: np.ndarray, rng, window: int) -> tuple[float, float]:
    """95% interval of the mean frames per upset: a bootstrap over the upsets; with no event at
    all (the bootstrap would say [0, 0]) the exact binomial bound on the share of upsets that show
    any, each at most `window` frames: [0, window (1 - 0.025^(1/n))]."""
    if x.size < 2:
        return float("nan"), float("nan")
    if not x.any():
        return 0.0, float(window * (1 - 0.025 ** (1 / x.size)))
    means = x[rng.integers(0, x.size, size=(BOOTSTRAP, x.size))].mean(axis=1)
    return float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975))


def visible_damage(
    engine,
    defenses=("none", "parity4r"),
    check_every: int = 10,
    upsets: int = 50,
    window: int = 20,
    cells=DANGEROUS_CELLS,
    fault: str = "bit",
    seed: int = 0,
    progress=None,
    rows=None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(summary: one row per defense, the storm's frame records). Summary columns: defense,
    check_every (0: not a check defense), window, upsets, catastrophic_frames_per_upset [lo, hi],
    sdc_frames_per_upset [lo, hi], residue_frames_per_upset (catastrophic frames after the first
    check that follows the upset), of_none [lo, hi] (catastrophic frames over the unguarded arm's;
    NaN without a "none" arm or when it shows none). `upset_counts(recs, ...)` are the records the
    summary is made of (what `seuwgpu defenses --visible N --out RUN` keeps for the report).
    `progress()` is called after each frame; `rows`: the storm's record list (campaign/storm.py:
    an interrupted measurement's records first, and it goes on after them; visible_frames of them
    in all)."""
    if upsets < 1 or window < 1 or check_every < 1:
        raise ValueError(
            f"visible damage needs upsets, window and check_every >= 1 (got {upsets}, {window}, {check_every})"
        )
    window = whole_window(window, check_every)
    plan, at = plan_upsets(engine, upsets, window, cells, fault, seed)
    frames = upsets * window
    recs = storm(
        engine, 1, frames, window, tuple(defenses), seed, progress, rows=rows, check_every=check_every, upsets=plan
    )
    recs["upset"] = recs["frame"] // window
    f_in = recs["frame"] % window
    landed = f_in >= at[recs["upset"].to_numpy()]
    recs["after_upset"] = landed
    first_check = -(-at // check_every) * check_every  # the first check at or after the upset lands
    recs["after_check"] = landed & (f_in >= first_check[recs["upset"].to_numpy()])
    recs["sdc"] = (recs["peak_error"] > PIXEL_THRESHOLD) & ~recs["catastrophic"]
    return summarise(upset_counts(recs, upsets, window, check_every), seed), recs


def upset_counts(recs: pd.DataFrame, upsets: int, window: int, schedule: int) -> pd.DataFrame:
    """One row per (defense, upset) of visible_damage's frame records: the frames drawn after the
    upset landed that were catastrophic, SDC, and catastrophic after the check that follows it
    (`residue_frames`: for a defense without a check every catastrophic frame, never repaired),
    with the measurement's window, upsets, schedule (its S) and each arm's check_every (0: no check)."""
    defenses = list(dict.fromkeys(recs["defense"]))
    checked = recs["defense"].map({d: dfn.get(d).checked for d in defenses})
    seen = recs["after_upset"]
    frames = pd.DataFrame(
        {
            "defense": recs["defense"],
            "upset": recs["upset"],
            "catastrophic_frames": recs["catastrophic"] & seen,
            "sdc_frames": recs["sdc"] & seen,
            "residue_frames": recs["catastrophic"] & seen & (recs["after_check"] | ~checked),
        }
    )
    full = pd.MultiIndex.from_product([defenses, range(upsets)], names=["defense", "upset"])
    out = frames.groupby(["defense", "upset"], sort=False).sum().reindex(full, fill_value=0).astype(np.int64)
    out = out.reset_index()
    out.insert(1, "check_every", [schedule if dfn.get(d).checked else 0 for d in out["defense"]])
    out["window"], out["upsets"], out["schedule"] = window, upsets, schedule
    return out


def summarise(counts: pd.DataFrame, seed: int = 0) -> pd.DataFrame:
    """The summary of one measurement's upset_counts (one row per defense, in their order; the
    columns of visible_damage's), its bootstrap seeded by `seed`: the CLI's and the report's
    numbers alike."""
    window, upsets = int(counts["window"].iloc[0]), int(counts["upsets"].iloc[0])
    defenses = list(dict.fromkeys(counts["defense"]))
    per = {
        d: tuple(
            g.sort_values("upset")[c].to_numpy(float) for c in ("catastrophic_frames", "sdc_frames", "residue_frames")
        )
        for d, g in counts.groupby("defense", sort=False)
    }
    rng = np.random.default_rng(seed)
    rows = []
    none = per.get("none")
    for d in defenses:
        cat, sdc, res = per[d]
        lo, hi = frames_interval(cat, rng, window)
        slo, shi = frames_interval(sdc, rng, window)
        ratio = r_lo = r_hi = float("nan")
        if none is not None and none[0].sum() > 0:
            ratio = cat.sum() / none[0].sum()
            if cat.any():  # paired bootstrap over the upsets
                idx = rng.integers(0, upsets, size=(BOOTSTRAP, upsets))
                num, den = cat[idx].sum(1), none[0][idx].sum(1)
                ok = den > 0
                r_lo, r_hi = (float(np.quantile(num[ok] / den[ok], q)) for q in (0.025, 0.975))
            else:  # no event: the bound above over the unguarded mean
                r_lo, r_hi = 0.0, hi / float(none[0].mean())
        rows.append(
            {
                "defense": d,
                "check_every": int(counts.loc[counts["defense"] == d, "check_every"].iloc[0]),
                "window": window,
                "upsets": upsets,
                "catastrophic_frames_per_upset": float(cat.mean()),
                "catastrophic_lo": lo,
                "catastrophic_hi": hi,
                "sdc_frames_per_upset": float(sdc.mean()),
                "sdc_lo": slo,
                "sdc_hi": shi,
                "residue_frames_per_upset": float(res.mean()),
                "of_none": ratio,
                "of_none_lo": r_lo,
                "of_none_hi": r_hi,
            }
        )
    return pd.DataFrame(rows)


# what identifies one measurement among the records of a run folder (one file each)
MEASUREMENT = ("scene", "n_primitives", "precision", "width", "height", "fault", "window", "upsets", "schedule", "seed")


def save_counts(run_dir, counts: pd.DataFrame, **measurement) -> Path:
    """Write one measurement's upset_counts into the run folder (store.visible_path), each row
    carrying `measurement` (the MEASUREMENT keys besides window, upsets and schedule; device and
    date too). The same measurement of the same arms measured again replaces its file."""
    df = counts.assign(**measurement)
    missing = [k for k in MEASUREMENT if k not in df.columns]
    if missing:
        raise ValueError(f"a visible-damage record needs {', '.join(missing)}")
    key = "-".join([*(str(df[k].iloc[0]) for k in MEASUREMENT), "+".join(dict.fromkeys(df["defense"]))])
    path = visible_path(run_dir, "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in key))
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    atomic_write(path, buf.getvalue())
    return path


def read_counts(run_dirs) -> pd.DataFrame | None:
    """The visible-damage records of run folders (save_counts), each row with its folder's name
    (`run`: one measurement kept in two folders stays two), None where they hold none."""
    files = [(Path(d).name, f) for d in run_dirs for f in sorted(visible_path(d, "*").parent.glob("*.parquet"))]
    if not files:
        return None
    return pd.concat([pd.read_parquet(f).assign(run=run) for run, f in files], ignore_index=True)
