"""Outcome classes of single upsets (`metrics.image.outcome_class`: masked, tolerable, SDC,
catastrophic; thresholds from the runs' manifests) as weighted shares with intervals, and the
headline catastrophe rate per (scene, precision, defense) that summary.json carries."""

from __future__ import annotations

import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import InsufficientData, single_upsets, sort_rows, tag
from seuwgpu.metrics.image import OUTCOMES


def outcome_table(df: pd.DataFrame, by=("precision", "defense"), conf: float = 0.95) -> pd.DataFrame:
    """Long table: ``by`` + outcome, n, events, rate_pct, ci_lo_pct, ci_hi_pct (weighted share of
    single upsets in each class, stratified interval)."""
    s = single_upsets(df, None, None)
    if s.empty:
        raise InsufficientData("no single-upset records", "run a single-upset campaign")
    parts = []
    for cls in OUTCOMES:
        r = E.rate(s, (s["outcome"] == cls).to_numpy(), list(by), conf)
        r.insert(len(by), "outcome", cls)
        parts.append(r)
    out = pd.concat(parts, ignore_index=True)
    out = E.percent(out, out="x").rename(columns={"x_rate_pct": "rate_pct", "x_ci_lo_pct": "ci_lo_pct"})
    out = out.rename(columns={"x_ci_hi_pct": "ci_hi_pct"}).drop(columns=["weight", "n_eff"])
    order = {c: i for i, c in enumerate(OUTCOMES)}
    out = sort_rows(out.sort_values("outcome", key=lambda c: c.map(order), kind="stable"))
    return tag(out, s, thresholds=dict(s.attrs.get("thresholds", {})))


def outcome_wide(long: pd.DataFrame, by=("precision", "defense")) -> pd.DataFrame:
    """One row per group, one column per class: "rate [lo, hi]" in %, plus n."""
    rows = []
    for key, g in long.groupby(list(by), sort=False):
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key))
        row["n"] = int(g["n"].iloc[0])
        for _, r in g.iterrows():
            row[f"{r['outcome']} (%)"] = f"{r['rate_pct']:.3g} [{r['ci_lo_pct']:.3g}, {r['ci_hi_pct']:.3g}]"
        rows.append(row)
    out = pd.DataFrame(rows)
    out.attrs.update(long.attrs)
    return out


def catastrophic_by_profile(df: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """Weighted catastrophe rate of single upsets per (profile, scene, precision, defense), as
    proportions with their intervals: the headline numbers under each renderer profile."""
    s = single_upsets(df, None, None)
    if s.empty:
        return pd.DataFrame()
    return sort_rows(E.rate(s, "catastrophic", ["profile", "scene", "precision", "defense"], conf))


def catastrophic_summary(df: pd.DataFrame, conf: float = 0.95) -> list[dict]:
    """summary.json's ``catastrophic``: one entry per (scene, precision, defense) of the single-upset
    campaign: {scene, precision, defense, rate, ci_low, ci_high, n} (proportions, weighted)."""
    s = single_upsets(df, None, None)
    if s.empty:
        return []
    r = sort_rows(E.rate(s, "catastrophic", ["scene", "precision", "defense"], conf))
    return [
        {
            "scene": str(x["scene"]),
            "precision": str(x["precision"]),
            "defense": str(x["defense"]),
            "rate": float(x["rate"]),
            "ci_low": float(x["ci_lo"]),
            "ci_high": float(x["ci_hi"]),
            "n": int(x["n"]),
        }
        for _, x in r.iterrows()
    ]
