"""Defenses against cost: the residual catastrophic rate of each defense (paired arms of one
campaign) with 95% intervals, overall and on the dangerous cells, next to its memory overhead and
time cost, the Pareto front, and the issue's goal check.

Rates come from the estimator layer (analysis/estimate.py `one_rate`): stratified by cell, each
weighted by the stored bits it stands for, with a stratified Wilson interval.

The dangerous cells (DANGEROUS_BITS) are where an unprotected trained model fails: a log-scale's
sign and top exponent bit (a small splat becomes a frame-covering sheet) and opacity's top
exponent bit (a faint splat becomes opaque or a strong one half transparent).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis.estimate import one_rate
from seuwgpu.analysis.records import figure, single_upsets
from seuwgpu.faults.defenses import DEFENSES, FIRST_DEFENSES
from seuwgpu.faults.side import device_overhead, memory_overhead
from seuwgpu.faults.state import FLOAT_TARGETS
from seuwgpu.model import encoding

# goal of issue 16, on each real model
GOAL = {"memory_overhead": 0.05, "time_vs_guard": 2.0, "danger_vs_none": 0.05, "overall_rate": 0.0005}


def dangerous_bits(precision: str) -> dict[str, tuple[int, ...]]:
    nb = encoding.bits_per_value(precision)
    return {"log_scales": (nb - 1, nb - 2), "opacity": (nb - 2,)}


def dangerous_mask(df: pd.DataFrame) -> pd.Series:
    """Rows whose (field, bit) cell is dangerous at their precision."""
    out = pd.Series(False, index=df.index)
    for prec in df["precision"].unique():
        for field, bits in dangerous_bits(prec).items():
            out |= (df["precision"] == prec) & (df["field"] == field) & df["bit"].isin(bits)
    return out


def _rate(df: pd.DataFrame) -> tuple[float, float, float, int, int]:
    """(rate, lo, hi, n, catastrophic), stratified (estimate.one_rate)."""
    r = one_rate(df)
    return float(r["rate"]), float(r["ci_lo"]), float(r["ci_hi"]), int(r["n"]), int(r["events"])


def has_new_defenses(df: pd.DataFrame) -> bool:
    """Records hold a defense beyond the first study's (guard variants, ECC, duplication)."""
    return bool(set(df.get("defense", pd.Series(dtype=str)).unique()) - set(FIRST_DEFENSES))


def defense_table(df: pd.DataFrame, timing: dict | None = None, manifests: Iterable[dict] = ()) -> pd.DataFrame:
    """One row per (scene, defense): residual catastrophic rates (overall and on the dangerous
    cells) with intervals, the dangerous-cell rate relative to no defense, memory overhead (at
    the model's own SH degree: reliability.model_degrees, which reads a degree-0 model's from the
    runs' specs), time fraction (NaN where not measured), Pareto membership and the goal check."""
    from seuwgpu.analysis.reliability import model_degrees

    df = single_upsets(df, None, None)  # the single-upset campaign's records, weighted
    danger = dangerous_mask(df)
    timing = timing or {}
    degrees = model_degrees(df, manifests)
    rows = []
    for (scene, prec), part in df.groupby(["scene", "precision"], observed=True):
        n_prims = int(part["n_primitives"].iloc[0])
        degree = degrees.get((scene, n_prims), 3)
        base = None
        for d in [x for x in DEFENSES if x in set(part["defense"])]:
            arm = part[part["defense"] == d]
            p, lo, hi, n, k = _rate(arm)
            dp, dlo, dhi, dn, dk = _rate(arm[danger.loc[arm.index]])
            if d == "none":
                base = dp
            t = timing.get(d, {})
            rows.append(
                {
                    "scene": scene,
                    "precision": prec,
                    "defense": d,
                    "n": n,
                    "catastrophic": k,
                    "rate_pct": 100 * p,
                    "rate_lo_pct": 100 * lo,
                    "rate_hi_pct": 100 * hi,
                    "danger_n": dn,
                    "danger_catastrophic": dk,
                    "danger_rate_pct": 100 * dp,
                    "danger_lo_pct": 100 * dlo,
                    "danger_hi_pct": 100 * dhi,
                    "danger_vs_none": dp / base if base else float("nan"),
                    "memory_overhead_pct": 100 * memory_overhead(d, prec, degree, n_prims),
                    # what this package's buffers hold on the device for it (side.device_bytes)
                    "device_memory_pct": 100 * device_overhead(d, prec, degree, n_prims),
                    "time_fraction": float(t.get("time_fraction", float("nan"))),
                }
            )
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    out["pareto"] = False
    for _, idx in out.groupby(["scene", "precision"]).groups.items():
        t = out.loc[idx]
        for i in idx:
            r = out.loc[i]
            worse_or_eq = (t["rate_pct"] <= r["rate_pct"]) & (t["memory_overhead_pct"] <= r["memory_overhead_pct"])
            better = (t["rate_pct"] < r["rate_pct"]) | (t["memory_overhead_pct"] < r["memory_overhead_pct"])
            out.loc[i, "pareto"] = not (worse_or_eq & better).any()
    guard_t = out.loc[out["defense"] == "guard", "time_fraction"]
    gt = float(guard_t.iloc[0]) if len(guard_t) else float("nan")

    def meets(x, limit, unknown=None):
        """x <= limit, <NA> where x is undefined (or `unknown`)."""
        x = out[x].to_numpy(float)
        b = pd.array(x <= limit, dtype="boolean")
        b[np.isnan(x) if unknown is None else np.isnan(x) | unknown] = pd.NA
        return b

    # An undefined number (time not measured in this run, or no dangerous-cell catastrophe without
    # defense to compare with) leaves its criterion unknown, and the verdict <NA> unless another
    # criterion already fails (Kleene logic): never a pass, nor a fail, on a missing number.
    out["meets_goal"] = (
        meets("memory_overhead_pct", 100 * GOAL["memory_overhead"])
        & meets("danger_vs_none", GOAL["danger_vs_none"])
        & meets("rate_hi_pct", 100 * GOAL["overall_rate"])
        & meets("time_fraction", GOAL["time_vs_guard"] * gt, unknown=not np.isfinite(gt))
    )
    return out


def pareto_figure(table: pd.DataFrame):
    """Residual catastrophic rate (95% interval) against memory overhead, one panel per scene;
    the Pareto front dashed, its members in bold."""
    scenes = list(table["scene"].unique())
    fig = figure(5 * len(scenes), 4)  # pyplot-free: nothing to close
    axes = fig.subplots(1, len(scenes), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        t = table[table["scene"] == scene]
        x = np.maximum(t["memory_overhead_pct"], 1e-4)
        y = np.maximum(t["rate_pct"], 1e-4)
        err = [y - np.maximum(t["rate_lo_pct"], 1e-4), np.maximum(t["rate_hi_pct"], 1e-4) - y]
        ax.errorbar(x, y, yerr=err, fmt="o", capsize=3)
        for xi, yi, name, front in zip(x, y, t["defense"], t["pareto"]):
            ax.annotate(
                name, (xi, yi), fontsize=8, xytext=(3, 3), textcoords="offset points", weight="bold" if front else None
            )
        front = t[t["pareto"]].sort_values("memory_overhead_pct")
        ax.plot(np.maximum(front["memory_overhead_pct"], 1e-4), np.maximum(front["rate_pct"], 1e-4), "--", alpha=0.5)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("memory overhead (% of the model; 1e-4 = none)")
        ax.set_ylabel("residual catastrophic rate (%)")
        ax.set_title(scene)
    return fig


def storm_figure(df: pd.DataFrame):
    """Footprint and PSNR of every frame of a fault storm, one line per defense (campaign/storm.py
    records); non-finite frames (PSNR undefined) are marked on the footprint panel."""
    fig = figure(11, 4)  # pyplot-free: nothing to close
    a1, a2 = fig.subplots(1, 2)
    for d, t in df.groupby("defense", sort=False):
        t = t.sort_values("frame")
        (line,) = a1.plot(t["frame"], 100 * t["footprint"], label=d)
        bad = t[t["nonfinite"]]
        a1.plot(bad["frame"], 100 * bad["footprint"], "x", color=line.get_color())
        a2.plot(t["frame"], t["psnr"].replace(np.inf, np.nan), label=d, color=line.get_color())
    r = df.iloc[0]
    a1.set_title(f"{r['scene']}: {r['k']} upsets/frame, scrub every {r['scrub_every'] or 'never'}")
    a1.set_xlabel("frame")
    a1.set_ylabel("footprint (% of pixels; x = non-finite)")
    a1.set_yscale("symlog", linthresh=0.01)
    a2.set_xlabel("frame")
    a2.set_ylabel("PSNR (dB; gaps: identical or undefined)")
    a2.legend(fontsize=8)
    return fig


def state_table(df: pd.DataFrame) -> pd.DataFrame:
    """Criticality of each pipeline-state target (faults/state.py records): catastrophic and DUE
    rates with intervals, stratified by bit, per target and bit class (the float targets' sign,
    exponent and mantissa; the integer targets' high half and low half). Both rates keep their
    95% interval (the DUE rate's was computed and dropped)."""
    from seuwgpu.analysis.estimate import rate

    d = df.copy()
    floats = d["target"].isin(FLOAT_TARGETS)
    cls = np.where(d["bit"] == 31, "sign", np.where(d["bit"] >= 23, "exponent", "mantissa"))
    d["bit_class"] = np.where(floats, cls, np.where(d["bit"] >= 16, "high half", "low half"))
    d["weight"] = 1.0  # each (target, bit) cell equally: the table is per cell class
    out = []
    for by in (["target"], ["target", "bit_class"]):
        cat = rate(d, "catastrophic", by, strata=("target", "bit"), prefix="cat_")
        due = rate(d, "due", by, strata=("target", "bit"), prefix="due_")
        t = cat.merge(due[by + ["due_events", "due_rate", "due_ci_lo", "due_ci_hi"]], on=by)
        if "bit_class" not in t:
            t.insert(1, "bit_class", "all")
        out.append(t)
    t = pd.concat(out, ignore_index=True).sort_values(["target", "bit_class"], kind="stable")
    keep = [
        "target",
        "bit_class",
        "cat_n",
        "cat_events",
        "cat_rate",
        "cat_ci_lo",
        "cat_ci_hi",
        "due_events",
        "due_rate",
        "due_ci_lo",
        "due_ci_hi",
    ]
    return t[keep].reset_index(drop=True)
