"""What the user asked, answered from the records: the statistics of the report's opening summary.

`user_summary(df, manifests, target)` is the one function every number of the summary comes from
(report/summary.py only writes them). Over the single-upset records (k = 1), each estimate
weighted by the stored bits its records stand for, with its 95% interval (analysis/estimate.py):

* models: per model (scene, N): its format, primitives, SH degree, precisions, and what the
  loader changed (the notes the run's manifest kept: `Runner.prepare_dir` writes them, with
  the NaN/Inf counts of the runs' guard notes beside them);
* p_c: the catastrophic probability per upset under no defense, per model and precision
  (models of different sizes are never pooled into one number);
* cells: the (field, bit) cells with the highest catastrophic rate under no defense, each with
  n, its interval and the share of p_c it carries (W_h p_h / p_c, W_h the cell's share of the
  model's stored bits);
* worst: the single record of the worst flip found under no defense (the largest footprint, a
  non-finite frame before a finite one of the same footprint);
* defenses: per model, precision and defense: the residual catastrophic rate (interval), the
  device memory it adds (faults.defenses.device_bytes, bytes and % of the stored model), the time
  per frame the records measured (time_ms, the median over the arm's records; NaN where none
  was measured, never 0) and the exposure under the check schedule (`[reliability]
  check_every = S`, default 1): frames drawn from a corrupted model before a check repairs it;
  0 for a guard (every frame clamped) or a read-time code, infinite without a defense;
* cheapest: per model and precision, the defense whose residual rate meets the target (the
  upper end of its 95% interval at most `target`, per upset) that is cheapest in the order
  CHEAPEST_ORDER: no defense when it meets the target (it costs nothing: a measured time below
  it is noise), then time per frame (unmeasured times last), then device memory.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import single_upsets
from seuwgpu.campaign.spec_types import stored_table

# the residual catastrophic rate per upset a defense must meet, unless the spec's
# `[summary] target` or `seuwgpu report --target` says otherwise
DEFAULT_TARGET = 0.001
CHEAPEST_ORDER = ("no defense (it adds nothing)", "time per frame", "device memory")
TOP_CELLS = 5
MODEL = ["scene", "n_primitives"]


def spec_target(manifests: Iterable[dict] = ()) -> float | None:
    """The `[summary] target` the runs' specs set (the first one set), or None."""
    for m in manifests or ():
        t = stored_table(m, "summary")
        if t is not None and t.target is not None:
            return float(t.target)
    return None


def spec_check_every(manifests: Iterable[dict] = ()) -> int | dict:
    """The check schedule of the runs' specs (`[reliability] check_every`: one S or a table per
    check defense; default schedule.DEFAULT_CHECK_EVERY), as the reliability analysis reads it."""
    from seuwgpu.analysis.reliability import check_schedule

    return check_schedule(manifests)[0]


def model_table(df: pd.DataFrame, manifests: Iterable[dict] = ()) -> pd.DataFrame:
    """One row per model of the records: scene, primitives, format, SH degree, precisions and the
    loader's notes ("none" when the manifest says the loader changed nothing; NaN where the
    manifest of an older run does not say)."""
    from seuwgpu.analysis.reliability import model_degrees
    from seuwgpu.campaign.spec import scene_label
    from seuwgpu.campaign.spec_types import stored_scenes

    manifests = list(manifests or ())
    stated: dict[str, dict] = {}
    for m in manifests:
        for info in m.get("models") or []:
            stated.setdefault(str(info.get("name")), info)
        for sc in stored_scenes(m):
            label = scene_label(sc)
            if label and label not in stated:
                stated[label] = {"format": "embedded scene" if sc.scene else np.nan}
    s = single_upsets(df, None, None)
    degrees = model_degrees(df, manifests)
    nonfinite = _nonfinite_notes(manifests)
    rows = []
    for (scene, n), g in s.groupby(MODEL, sort=False):
        info = stated.get(str(scene), {})
        notes = info.get("notes")
        if nonfinite.get(str(scene)):
            notes = [*(notes or []), nonfinite[str(scene)]]
        rows.append(
            {
                "scene": scene,
                "n_primitives": int(n),
                "format": info.get("format", np.nan),
                "sh_degree": int(info.get("sh_degree", degrees.get((scene, n), 3))),
                "precisions": ", ".join(sorted(g["precision"].unique())),
                "loader_notes": np.nan if notes is None else ("; ".join(notes) if notes else "none"),
            }
        )
    return pd.DataFrame(rows)


def _nonfinite_notes(manifests: list[dict]) -> dict[str, str]:
    """Per scene: the NaN/Inf the runs found in the clean model (their guard notes), as a note."""
    from seuwgpu.campaign import store

    out: dict[str, str] = {}
    for m in manifests:
        if not m.get("_run_dir"):
            continue
        for scene, precision, _profile, note in store.read_guard_notes(m["_run_dir"]):
            counts = note.get("nonfinite_values") or {}
            if counts and scene not in out:
                what = ", ".join(f"{f} {int(c)}" for f, c in counts.items())
                out[scene] = f"the clean model holds NaN/Inf at {precision}: {what} values (the guard maps them)"
    return out


def pc_table(s: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """p_c (no defense) per model and precision, weighted by stored bits, with its interval."""
    none = s[s["defense"] == "none"]
    return E.rate(none, "catastrophic", by=[*MODEL, "precision"], conf=conf)


def top_cells(s: pd.DataFrame, top: int = TOP_CELLS, conf: float = 0.95) -> pd.DataFrame:
    """The `top` (field, bit) cells of highest catastrophic rate under no defense, per model and
    precision, with n, interval and the share of that model's p_c each carries."""
    none = s[s["defense"] == "none"]
    if none.empty:
        return pd.DataFrame()
    cells = E.rate(none, "catastrophic", by=[*MODEL, "precision", "field", "bit"], conf=conf)
    out = []
    for _, g in cells.groupby([*MODEL, "precision"], sort=False):
        total = float((g["weight"] * g["rate"]).sum())
        g = g.assign(share_of_pc=(g["weight"] * g["rate"]) / total if total > 0 else np.nan)
        g = g.sort_values(["rate", "events", "weight"], ascending=False, kind="stable")
        out.append(g[g["events"] > 0].head(top))
    if not out:
        return pd.DataFrame()
    return pd.concat(out, ignore_index=True)


def worst_record(s: pd.DataFrame) -> dict | None:
    """The worst flip found under no defense: the largest footprint (the share of the frame it
    changes), then a non-finite frame, then the largest peak error (ties: the first record)."""
    none = s[s["defense"] == "none"]
    if none.empty:
        return None
    key = pd.DataFrame(
        {
            "nf": none["nonfinite"].astype(bool).to_numpy(),
            "fp": none["footprint"].astype(float).fillna(-1.0).to_numpy(),
            "pe": none["peak_error"].astype(float).fillna(np.inf).to_numpy() if "peak_error" in none else 0.0,
        }
    )
    i = int(np.lexsort((-np.arange(len(key)), key["pe"], key["nf"], key["fp"]))[-1])
    rec = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in none.iloc[i].to_dict().items()}
    for k in ("primitive", "component"):  # None where not recorded (folded records keep few sites)
        v = rec.get(k)
        rec[k] = int(v) if v is not None and not pd.isna(v) and v >= 0 else None
    return rec


def _exposure(defense: str, check_every) -> tuple[float, float]:
    """(expected, worst) frames drawn from the corrupted model before a repair (schedule.exposure)."""
    from seuwgpu.faults.defenses import REGISTRY
    from seuwgpu.faults.schedule import check_every_of, exposure

    if defense == "none":
        return math.inf, math.inf
    d = REGISTRY.get(defense)
    if d is not None and d.checked:
        ex = exposure(check_every_of(check_every, defense))
        return ex.expected, ex.worst
    return 0.0, 0.0


def defense_rows(s: pd.DataFrame, manifests: Iterable[dict] = (), conf: float = 0.95) -> pd.DataFrame:
    """Per model, precision and defense: residual catastrophic rate with its interval, device
    memory, measured time per frame and exposure (module notes)."""
    from seuwgpu.analysis.reliability import model_degrees
    from seuwgpu.faults.defenses import DEFENSES
    from seuwgpu.faults.schedule import check_every_of
    from seuwgpu.faults.side import device_bytes, device_overhead

    if s.empty:
        return pd.DataFrame()
    manifests = list(manifests or ())
    degrees = model_degrees(s, manifests)
    check_every = spec_check_every(manifests)
    order = {d: i for i, d in enumerate(DEFENSES)}
    rates = E.rate(s, "catastrophic", by=[*MODEL, "precision", "defense"], conf=conf)
    rates = rates.sort_values(
        [*MODEL, "precision", "defense"], key=lambda c: c.map(order) if c.name == "defense" else c, kind="stable"
    )
    times = s["time_ms"] if "time_ms" in s else pd.Series(np.nan, index=s.index)
    med = times.astype(float).groupby([s[c] for c in [*MODEL, "precision", "defense"]], sort=False).median()
    rows = []
    for r in rates.itertuples(index=False):
        n, prec, d = int(r.n_primitives), r.precision, r.defense
        deg = degrees.get((r.scene, r.n_primitives), 3)
        known = d in order
        exp_mean, exp_worst = _exposure(d, check_every)
        t = med.get((r.scene, r.n_primitives, prec, d), np.nan)
        rows.append(
            {
                "scene": r.scene,
                "n_primitives": n,
                "precision": prec,
                "defense": d,
                "n": int(r.n),
                "catastrophic": int(r.events),
                "rate": float(r.rate),
                "ci_lo": float(r.ci_lo),
                "ci_hi": float(r.ci_hi),
                "device_bytes": device_bytes(d, prec, deg, n) if known else np.nan,
                "device_pct": 100 * device_overhead(d, prec, deg, n) if known else np.nan,
                "time_ms": float(t) if t is not None else np.nan,
                "check_every": check_every_of(check_every, d) if _checked(d) else np.nan,
                "exposure_frames": exp_mean,
                "exposure_worst_frames": exp_worst,
            }
        )
    out = pd.DataFrame(rows)
    base = out[out["defense"] == "none"].set_index([*MODEL, "precision"])["time_ms"]
    ref = [base.get(tuple(k), np.nan) for k in out[[*MODEL, "precision"]].itertuples(index=False)]
    out["time_vs_none_pct"] = 100 * (out["time_ms"] / np.asarray(ref, float) - 1)
    return out


def _checked(defense: str) -> bool:
    from seuwgpu.faults.defenses import REGISTRY

    d = REGISTRY.get(defense)
    return bool(d is not None and d.checked)


def cheapest(defenses: pd.DataFrame, target: float) -> pd.DataFrame:
    """Per model and precision, the defense that meets `target` (its interval's upper end at most
    `target`) and comes first in CHEAPEST_ORDER (none; then time per frame, unmeasured last; then
    device bytes; then the registry's order). A row with defense NaN and met False where none meets it."""
    if not 0 < float(target) < 1:
        raise ValueError(f"the target is a catastrophic rate per upset in (0, 1), got {target!r}")
    rows = []
    if defenses.empty:
        return pd.DataFrame(rows)
    for key, g in defenses.groupby([*MODEL, "precision"], sort=False):
        ok = g[g["ci_hi"] <= target]
        base = dict(zip([*MODEL, "precision"], key))
        if ok.empty:
            best = g.sort_values("ci_hi", kind="stable").iloc[0]
            rows.append(
                {
                    **base,
                    "target": float(target),
                    "met": False,
                    "defense": np.nan,
                    "closest": best["defense"],
                    "closest_ci_hi": float(best["ci_hi"]),
                    "candidates": 0,
                }
            )
            continue
        ok = ok.assign(_n=ok["defense"] != "none", _t=ok["time_ms"].fillna(np.inf), _i=np.arange(len(ok)))
        best = ok.sort_values(["_n", "_t", "device_bytes", "_i"], kind="stable").iloc[0]
        rows.append(
            {
                **base,
                "target": float(target),
                "met": True,
                "defense": best["defense"],
                "rate": float(best["rate"]),
                "ci_hi": float(best["ci_hi"]),
                "time_ms": float(best["time_ms"]),
                "device_bytes": float(best["device_bytes"]),
                "candidates": len(ok),
            }
        )
    return pd.DataFrame(rows)


def user_summary(
    df: pd.DataFrame, manifests: Iterable[dict] = (), target: float | None = None, conf: float = 0.95
) -> dict:
    """Every number of the report's summary (module notes): {"models", "p_c", "cells", "worst",
    "defenses", "cheapest", "target", "target_source", "check_every"}.
    target None: the specs' `[summary] target`, else DEFAULT_TARGET."""
    manifests = list(manifests or ())
    source = "given to the report"
    if target is None:
        target = spec_target(manifests)
        source = "the spec's [summary] target"
    if target is None:
        target, source = DEFAULT_TARGET, "the default"
    s = single_upsets(df, None, None)
    defenses = defense_rows(s, manifests, conf)
    return {
        "models": model_table(df, manifests),
        "p_c": pc_table(s, conf),
        "cells": top_cells(s, conf=conf),
        "worst": worst_record(s),
        "defenses": defenses,
        "cheapest": cheapest(defenses, target),
        "target": float(target),
        "target_source": source,
        "check_every": spec_check_every(manifests),
    }
