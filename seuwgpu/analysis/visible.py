"""What the user sees under each defense and schedule: the visible-damage records a run folder
keeps (`seuwgpu defenses --visible N --out RUN`, campaign/visible.py) summarised per
measurement, with the same numbers `seuwgpu defenses --visible N` printed when it measured them
(campaign/visible.py `summarise`, its bootstrap seeded by the measurement's seed)."""

from __future__ import annotations

import pandas as pd

from seuwgpu.campaign.visible import MEASUREMENT, summarise


def visible_table(counts: pd.DataFrame) -> pd.DataFrame:
    """One row per measurement (and run folder) and defense: the MEASUREMENT keys, device and date, then
    summarise's columns (frames per upset, catastrophic and SDC, with 95% intervals; the residue
    after the check; the share of the unguarded arm's catastrophic frames)."""
    keys = [*MEASUREMENT, "run"] if "run" in counts else list(MEASUREMENT)
    rows = []
    for key, g in counts.groupby(keys, sort=False):
        s = summarise(g, seed=int(dict(zip(keys, key))["seed"])).drop(columns=["window", "upsets"])
        for k, v in zip(keys, key):
            s[k] = v
        for k in ("device", "date"):
            s[k] = ", ".join(sorted(set(g[k].astype(str)))) if k in g else ""
        rows.append(s)
    cols = [*keys, "device", "date"]
    out = pd.concat(rows, ignore_index=True)
    return out[cols + [c for c in out.columns if c not in cols]]
