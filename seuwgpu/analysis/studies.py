"""Analyses of campaign records: the tables and figures of the paper's Section 5, from any run.

Every analysis is a function over a records DataFrame (one row per injection and defense, the
campaign contract; see `seuwgpu.report.load_runs`) that returns DataFrames or dicts of them.
Each returned DataFrame carries ``df.attrs["provenance"]``: the runs, scenes, precisions,
defenses, campaigns and record count it rests on, so a report can caption it honestly. An
analysis that lacks the data it needs raises `InsufficientData`, whose ``remedy`` names the
campaign that would supply it. ``plot_*`` functions return matplotlib `Figure` objects built
without pyplot (Agg canvas; safe headless and in threads).

Conventions and documented choices
----------------------------------
* Record selection. ``campaign`` is inferred when absent: "dose" for k > 1, else "single".
  Criticality, theory, guard, mitigation, p_c and prediction use the single-upset campaign
  (k = 1, campaign "single"); dose curves use campaign "dose"; the size-scaling fits use k = 1
  records of campaign "size" (falling back to the k = 1 records of a dose campaign, which are
  uniform over the stored bit budget like a size campaign's).
* Reference precision: analyses the paper reports "at fp32" use fp32 when present, else the first
  of fp16, bf16 present; the chosen precision is stated in the provenance.
* Proportions carry 95% Wilson intervals (`stats.wilson_interval`), never a normal approximation.
* PSNR averaging. Identical frames have PSNR = inf and non-finite frames have no PSNR, so a plain
  mean is undefined. Per-record PSNR is clipped to [PSNR_FLOOR_DB, PSNR_CAP_DB] = [0, 100] dB,
  with non-finite frames (or NaN PSNR) at the 0 dB floor, before means; medians and quartiles use
  the same clipped values. 100 dB is an RMS error of 1e-5, far below one 8-bit level.
* Single-upset "error" for the size law is the frame MSE recovered from PSNR assuming a peak of
  1.0 (mse = 10^(-psnr/10)); a fitted log-log exponent does not depend on that peak. Records with
  a non-finite frame are left out of means (their count is reported) and kept in medians as +inf.
* p_c, the probability that one uniform-random upset of the stored bit budget is catastrophic, is
  estimated from the stratified single-upset campaign by weighting each (field, bit) cell by its
  share of stored bits (components of the field / components per primitive / bits per value),
  with a Wilson interval at the Kish effective sample size (`stats.stratified_rate`).
* Reliability inputs (`UPSET_RATES`) are order-of-magnitude soft-error rates, stated with their
  sources; they are assumptions, and the MTBF table is to be read as relative, not absolute.
* Memory overheads of the defenses (`memory_overhead`) come from the run manifest when it states
  them, else from the documented constants below (guard box per model, SEC-DED over sign and
  exponent per stored value, triple-modular duplication).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis import stats
from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS, field_components, n_components, sh_rest_count
from seuwgpu.render.regions import region_edges

# ----------------------------------------------------------------------------------- constants

DEFENSE_LABELS = {
    "none": "none",
    "guard": "support guard",
    "selective": "selective guard (log-scale + opacity)",
    "ecc": "ECC sign+exp (SEC-DED)",
    "dup": "full duplication (TMR vote)",
}
FIELD_LABELS = {
    "means": "mean",
    "log_scales": "log-scale",
    "quats": "quat",
    "opacity": "opacity",
    "sh_dc": "color (DC)",
    "sh_rest": "color (SH)",
}
BIT_CLASSES = ("sign", "exponent", "mantissa", "mixed")

CATASTROPHIC_FOOTPRINT = 0.01  # Definition (catastrophic upset): footprint > 1% or non-finite
PSNR_CAP_DB = 100.0  # identical frames (PSNR = inf) count as 100 dB in means
PSNR_FLOOR_DB = 0.0  # non-finite frames (or NaN PSNR) count as 0 dB
BUDGET_PSNR_DB = 30.0  # redundancy budget threshold (paper, Section 5.4)
THEORY_FIT_RANGE = (1e-5, 0.1)  # peak-error window of the mantissa-slope fit (see theory_check)
GUARD_BOX_BITS = 32  # the support box bounds are held as fp32 values
DEFAULT_SH_DEGREE = 3

HOURS_PER_YEAR = 24.0 * 365.25

# Upset rates per stored bit per hour. Order-of-magnitude inputs, not measurements of any device;
# the MTBF table is relative. 1 FIT/Mbit = 1e-9 upsets per hour per 1e6 bits = 1e-15 /bit/h.
UPSET_RATES = (
    {
        "environment": "ground (sea level)",
        "per_bit_hour": 1.0e-12,  # 1,000 FIT/Mbit
        "source": (
            "~10^3 FIT/Mbit, the order of unprotected SRAM soft-error rates at sea level "
            "(Baumann, IEEE TDMR 5(3) 2005; Normand, IEEE TNS 43(6) 1996), at the JEDEC "
            "JESD89A reference neutron flux (~13 n/cm^2/h, New York City). Commodity "
            "DRAM/HBM is lower per bit."
        ),
    },
    {
        "environment": "avionics (~10-12 km)",
        "per_bit_hour": 3.0e-10,  # 300 x ground
        "source": (
            "ground rate x 300: the atmospheric neutron flux at aircraft cruise altitude "
            "is roughly 300x the sea-level flux (Normand 1996; JESD89A altitude scaling)."
        ),
    },
    {
        "environment": "low-Earth orbit",
        "per_bit_hour": 1.0e-7 / 24.0,  # 1e-7 upsets/bit/day
        "source": (
            "~1e-7 upsets/bit/day, a typical order for commercial memories in LEO "
            "(published rates span ~1e-8 to 1e-6 /bit/day with orbit, shielding and "
            "South Atlantic Anomaly passes)."
        ),
    },
)


class InsufficientData(Exception):
    """An analysis cannot run on these records; `remedy` names the campaign that would help."""

    def __init__(self, reason: str, remedy: str = ""):
        super().__init__(reason)
        self.reason = reason
        self.remedy = remedy


# --------------------------------------------------------------------------- record handling


def prepare(df: pd.DataFrame) -> pd.DataFrame:
    """Fill optional columns and infer defaults (idempotent; returns a new frame)."""
    if df.attrs.get("_seuwgpu_prepared"):
        return df
    d = df.copy()
    if "k" not in d:
        d["k"] = 1
    d["k"] = pd.to_numeric(d["k"], errors="coerce").fillna(1).astype(np.int64)
    if "defense" not in d:
        d["defense"] = "none"
    d["defense"] = d["defense"].astype(object).where(d["defense"].notna(), "none").astype(str)
    inferred = pd.Series(np.where(d["k"] > 1, "dose", "single"), index=d.index, dtype=object)
    if "campaign" in d:
        camp = d["campaign"].astype(object)
        d["campaign"] = camp.where(camp.notna(), inferred).astype(str)
    else:
        d["campaign"] = inferred.astype(str)
    if "run" not in d:
        d["run"] = "run"
    d["run"] = d["run"].astype(str)
    for col in ("scene", "precision", "field", "bit_class"):
        if col in d:
            d[col] = d[col].astype(str)
    for col in ("primitive", "component", "bit"):
        if col in d:
            d[col] = pd.to_numeric(d[col], errors="coerce").fillna(-1).astype(np.int64)
    if "nonfinite" not in d:
        d["nonfinite"] = False
    d["nonfinite"] = d["nonfinite"].fillna(False).astype(bool)
    if "footprint" in d:
        d["footprint"] = pd.to_numeric(d["footprint"], errors="coerce").astype(float)
    if "catastrophic" not in d:
        d["catastrophic"] = (d["footprint"] > CATASTROPHIC_FOOTPRINT) | d["nonfinite"]
    d["catastrophic"] = d["catastrophic"].fillna(False).astype(bool)
    for col in ("time_ms", "psnr", "ssim", "peak_error", "footprint_max", "clean_value", "corrupted_value"):
        if col not in d:
            d[col] = np.nan
        d[col] = pd.to_numeric(d[col], errors="coerce").astype(float)
    if "repeat" not in d:
        d["repeat"] = 0
    if "n_primitives" in d:
        d["n_primitives"] = pd.to_numeric(d["n_primitives"], errors="coerce").astype(np.int64)
    d.attrs["_seuwgpu_prepared"] = True
    return d


def _uniq(values) -> list:
    out = []
    for v in pd.unique(pd.Series(values).dropna()):
        out.append(v.item() if hasattr(v, "item") else v)
    return sorted(out, key=lambda x: (str(type(x)), x))


def provenance(d: pd.DataFrame) -> dict:
    """What a table or figure rests on: runs, scenes, precisions, defenses, campaigns, k, n."""
    order = {"precision": encoding.PRECISIONS, "defense": DEFENSES}

    def col(name):
        vals = _uniq(d[name]) if name in d and len(d) else []
        if name in order:
            known = [v for v in order[name] if v in vals]
            vals = known + [v for v in vals if v not in known]
        return vals

    ks = col("k")
    return {
        "runs": col("run"),
        "scenes": col("scene"),
        "precisions": col("precision"),
        "defenses": col("defense"),
        "campaigns": col("campaign"),
        "k_range": [int(min(ks)), int(max(ks))] if ks else [],
        "n_records": int(len(d)),
    }


def provenance_text(prov: dict) -> str:
    if not prov:
        return ""
    parts = [f"{prov.get('n_records', 0):,} records"]
    for key, label in (
        ("runs", "runs"),
        ("scenes", "scenes"),
        ("precisions", "precisions"),
        ("defenses", "defenses"),
        ("campaigns", "campaigns"),
    ):
        vals = prov.get(key) or []
        if vals:
            parts.append(f"{label}: {', '.join(map(str, vals))}")
    kr = prov.get("k_range") or []
    if kr and kr[1] > 1:
        parts.append(f"k = {kr[0]}..{kr[1]}")
    return "Rests on " + "; ".join(parts) + "."


def _tag(out: pd.DataFrame, d: pd.DataFrame, **extra) -> pd.DataFrame:
    out.attrs["provenance"] = provenance(d)
    out.attrs.update(extra)
    return out


def precisions_present(df: pd.DataFrame) -> list[str]:
    have = set(df["precision"].astype(str)) if "precision" in df else set()
    return [p for p in encoding.PRECISIONS if p in have] + sorted(have - set(encoding.PRECISIONS))


def reference_precision(df: pd.DataFrame) -> str:
    """fp32 when present, else the first of fp16, bf16 present (documented reporting choice)."""
    pres = precisions_present(df)
    if not pres:
        raise InsufficientData("no records", "run a campaign")
    return pres[0]


def defenses_present(df: pd.DataFrame) -> list[str]:
    have = set(df["defense"].astype(str))
    return [x for x in DEFENSES if x in have] + sorted(have - set(DEFENSES))


def fields_present(df: pd.DataFrame) -> list[str]:
    have = set(df["field"].astype(str))
    return [f for f in FIELDS if f in have] + sorted(have - set(FIELDS))


def single_upsets(df: pd.DataFrame, precision: str | None = None, defense: str | None = "none") -> pd.DataFrame:
    """k = 1 records of the single-upset campaign, optionally at one precision and defense."""
    d = prepare(df)
    m = (d["k"] == 1) & (d["campaign"] == "single")
    if precision is not None:
        m &= d["precision"] == precision
    if defense is not None:
        m &= d["defense"] == defense
    return d[m]


def dose_records(df: pd.DataFrame) -> pd.DataFrame:
    d = prepare(df)
    return d[d["campaign"] == "dose"]


def _require_single(df, defense="none") -> pd.DataFrame:
    s = single_upsets(df, None, defense)
    if s.empty:
        raise InsufficientData(
            f"no single-upset records (k = 1, campaign 'single') with defense '{defense}'",
            "run a single-upset campaign over all fields and bits",
        )
    return s


def pair_keys(df: pd.DataFrame) -> list[str]:
    """Columns that identify one fault site across defenses (records are paired on these)."""
    return [c for c in ("run", "scene", "precision", "campaign", "injection_id") if c in df]


def capped_psnr(d: pd.DataFrame) -> pd.Series:
    """Per-record PSNR clipped to [PSNR_FLOOR_DB, PSNR_CAP_DB]; non-finite frames at the floor."""
    p = pd.to_numeric(d["psnr"], errors="coerce").astype(float)
    p = p.clip(lower=PSNR_FLOOR_DB, upper=PSNR_CAP_DB)
    bad = p.isna() | d["nonfinite"].astype(bool)
    return p.mask(bad, PSNR_FLOOR_DB)


def mse_from_psnr(d: pd.DataFrame) -> pd.Series:
    """Frame MSE from PSNR with a peak of 1: 10^(-psnr/10); inf PSNR -> 0, non-finite -> inf."""
    p = pd.to_numeric(d["psnr"], errors="coerce").astype(float)
    with np.errstate(over="ignore"):
        mse = np.power(10.0, -p / 10.0)
    mse = mse.where(~np.isposinf(p), 0.0)
    bad = p.isna() | d["nonfinite"].astype(bool)
    return mse.mask(bad, np.inf)


def _rate_columns(k, n, prefix="cat", conf=0.95) -> dict:
    k = np.asarray(k, dtype=float)
    n = np.asarray(n, dtype=float)
    lo, hi = stats.wilson_interval(k, n, conf)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(n > 0, k / n, np.nan)
    return {
        f"{prefix}_rate_pct": 100 * rate,
        f"{prefix}_ci_lo_pct": 100 * np.asarray(lo),
        f"{prefix}_ci_hi_pct": 100 * np.asarray(hi),
    }


def sh_degree_of(df: pd.DataFrame | None = None, manifests: Iterable[dict] = ()) -> int:
    """SH degree of the models: from a manifest's spec ("sh_degree") when stated, else inferred
    from the largest sh_rest component index in the records (when at least 50 sh_rest records
    name at least 5 distinct components), else DEFAULT_SH_DEGREE (3, the INRIA/gsplat default)."""
    for m in manifests or ():
        for src in (m.get("spec", {}) or {}, m, m.get("model", {}) or {}):
            deg = src.get("sh_degree") if isinstance(src, dict) else None
            if deg is not None:
                try:
                    return int(deg)
                except (TypeError, ValueError):
                    pass
    if df is not None and len(df) and "field" in df and "component" in df:
        comp = df.loc[df["field"].astype(str) == "sh_rest", "component"]
        comp = pd.to_numeric(comp, errors="coerce")
        comp = comp[comp >= 0]
        # with few samples, or a campaign that targets a few components, the largest index
        # sampled says little about the degree
        if len(comp) >= 50 and comp.nunique() >= 5:
            need = int(comp.max()) + 1
            for deg in (1, 2, 3):
                if 3 * sh_rest_count(deg) >= need:
                    return deg
    return DEFAULT_SH_DEGREE


# ------------------------------------------------------------------------------ criticality


def criticality(
    df: pd.DataFrame, precision: str | None = None, defense: str = "none", conf: float = 0.95
) -> pd.DataFrame:
    """Per-field footprint quantiles (% of frame) and catastrophe rate with a Wilson interval.

    Pooled over scenes and bits of the single-upset campaign at one precision (fp32 by default).
    Columns: field, n, median_pct, p95_pct, p99_pct, max_pct, mean_pct, catastrophic,
    cat_rate_pct, cat_ci_lo_pct, cat_ci_hi_pct.
    """
    s = _require_single(df, defense)
    precision = precision or reference_precision(s)
    s = s[s["precision"] == precision]
    if s.empty:
        raise InsufficientData(f"no single-upset records at {precision}", f"run a single-upset campaign at {precision}")
    rows = []
    for field in fields_present(s):
        g = s[s["field"] == field]
        fp = g["footprint"].to_numpy(float) * 100.0
        fp = fp[np.isfinite(fp)]
        q = np.quantile(fp, [0.5, 0.95, 0.99]) if fp.size else [np.nan] * 3
        rows.append(
            {
                "field": field,
                "n": len(g),
                "median_pct": q[0],
                "p95_pct": q[1],
                "p99_pct": q[2],
                "max_pct": fp.max() if fp.size else np.nan,
                "mean_pct": fp.mean() if fp.size else np.nan,
                "catastrophic": int(g["catastrophic"].sum()),
            }
        )
    out = pd.DataFrame(rows)
    out = pd.concat([out, pd.DataFrame(_rate_columns(out["catastrophic"], out["n"], conf=conf))], axis=1)
    return _tag(out, s, precision=precision)


def field_bit_table(df: pd.DataFrame, defense: str = "none", conf: float = 0.95) -> pd.DataFrame:
    """Long table per (precision, field, bit): n, bit class, mean footprint %, catastrophe rate."""
    s = _require_single(df, defense)
    s = s[s["bit"] >= 0]
    g = s.groupby(["precision", "field", "bit"], sort=False)
    out = g.agg(
        n=("footprint", "size"),
        mean_footprint_pct=("footprint", "mean"),
        max_footprint_pct=("footprint", "max"),
        catastrophic=("catastrophic", "sum"),
    ).reset_index()
    out["mean_footprint_pct"] *= 100.0
    out["max_footprint_pct"] *= 100.0
    out["catastrophic"] = out["catastrophic"].astype(np.int64)
    out.insert(
        3,
        "bit_class",
        [
            encoding.bit_class(p, b) if p in encoding.PRECISIONS and 0 <= b < encoding.BITS[p] else "?"
            for p, b in zip(out["precision"], out["bit"])
        ],
    )
    out = pd.concat([out, pd.DataFrame(_rate_columns(out["catastrophic"], out["n"], conf=conf))], axis=1)
    porder = {p: i for i, p in enumerate(precisions_present(s))}
    forder = {f: i for i, f in enumerate(fields_present(s))}
    out = out.sort_values(
        ["precision", "field", "bit"],
        key=lambda c: c.map(porder) if c.name == "precision" else (c.map(forder) if c.name == "field" else c),
    ).reset_index(drop=True)
    return _tag(out, s)


def heatmap_matrix(table: pd.DataFrame, precision: str, value: str = "mean_footprint_pct") -> pd.DataFrame:
    """field x bit matrix (rows in FIELDS order, columns bit 0..B-1) from `field_bit_table`."""
    t = table[table["precision"] == precision]
    nbits = encoding.BITS.get(precision, int(t["bit"].max()) + 1 if len(t) else 0)
    m = t.pivot_table(index="field", columns="bit", values=value, aggfunc="mean")
    rows = [f for f in FIELDS if f in m.index] + [f for f in m.index if f not in FIELDS]
    return m.reindex(index=rows, columns=range(nbits))


def precision_rates(df: pd.DataFrame, defense: str = "none", conf: float = 0.95) -> pd.DataFrame:
    """Catastrophe rate per (precision, field) with Wilson intervals, pooled over bits/scenes."""
    s = _require_single(df, defense)
    g = s.groupby(["precision", "field"], sort=False)
    out = g.agg(
        n=("catastrophic", "size"), catastrophic=("catastrophic", "sum"), mean_footprint_pct=("footprint", "mean")
    ).reset_index()
    out["mean_footprint_pct"] *= 100.0
    out["catastrophic"] = out["catastrophic"].astype(np.int64)
    out = pd.concat([out, pd.DataFrame(_rate_columns(out["catastrophic"], out["n"], conf=conf))], axis=1)
    porder = {p: i for i, p in enumerate(precisions_present(s))}
    forder = {f: i for i, f in enumerate(fields_present(s))}
    out = out.assign(_p=out["precision"].map(porder), _f=out["field"].map(forder))
    out = out.sort_values(["_p", "_f"]).drop(columns=["_p", "_f"]).reset_index(drop=True)
    return _tag(out, s)


# ---------------------------------------------------------------------------- theory check


def theory_check(
    df: pd.DataFrame,
    field: str = "log_scales",
    precision: str | None = None,
    defense: str = "none",
    fit_range: tuple[float, float] = THEORY_FIT_RANGE,
) -> dict:
    """Mean peak error against mantissa bit index, with the fitted log2 slope (Lemma: 1 per bit).

    The fit uses the bits whose mean peak error lies inside `fit_range` (default 1e-5 .. 0.1):
    below, float32 rounding of the render hides the change; above, one primitive's contribution
    saturates the pixels it covers and the curve flattens (the pre-saturation regime of the
    lemma). If fewer than 3 bits fall inside, all bits with a positive mean are fitted (noted).
    Returns {"table", "slope", "intercept", "r2", "fit_bits", "n_fit_bits", "predicted_slope",
    "precision", "field", "note"}.
    """
    s = _require_single(df, defense)
    precision = precision or reference_precision(s)
    d = s[(s["precision"] == precision) & (s["field"] == field) & (s["bit"] >= 0)]
    if "bit_class" in d:
        d = d[d["bit_class"] == "mantissa"]
    if precision in encoding.LAYOUT:
        d = d[d["bit"] < encoding.LAYOUT[precision][0]]
    d = d[np.isfinite(d["peak_error"])]
    if d.empty:
        raise InsufficientData(
            f"no {field} mantissa records with peak_error at {precision}",
            f"run a single-upset campaign covering {field} mantissa bits",
        )
    t = (
        d.groupby("bit")
        .agg(
            n=("peak_error", "size"), mean_peak_error=("peak_error", "mean"), median_peak_error=("peak_error", "median")
        )
        .reset_index()
    )
    with np.errstate(divide="ignore"):
        t["log2_mean_peak_error"] = np.log2(t["mean_peak_error"].where(t["mean_peak_error"] > 0))
    lo, hi = fit_range
    use = (t["mean_peak_error"] > lo) & (t["mean_peak_error"] <= hi)
    note = ""
    if use.sum() < 3:
        use = t["mean_peak_error"] > 0
        note = (
            f"fewer than 3 bits had a mean peak error in [{lo:g}, {hi:g}]; the fit uses every bit with a positive mean"
        )
    if use.sum() < 2:
        raise InsufficientData(
            f"fewer than two {field} mantissa bits with a non-zero peak error",
            f"run a single-upset campaign covering more {field} mantissa bits",
        )
    t["in_fit"] = use.to_numpy()
    fit = stats.linear_fit(t.loc[use, "bit"], t.loc[use, "log2_mean_peak_error"])
    bits_used = t.loc[use, "bit"]
    _tag(t, d, precision=precision)
    return {
        "table": t,
        "slope": fit.slope,
        "intercept": fit.intercept,
        "r2": fit.r2,
        "fit_bits": (int(bits_used.min()), int(bits_used.max())),
        "n_fit_bits": int(use.sum()),
        "predicted_slope": 1.0,
        "precision": precision,
        "field": field,
        "fit_range": fit_range,
        "note": note,
    }


# ------------------------------------------------------------------------------------- guard


def paired(df: pd.DataFrame, a: str = "none", b: str = "guard") -> pd.DataFrame:
    """Single-upset records of defenses a and b joined on the fault site (pair_keys)."""
    s = single_upsets(df, None, None)
    keys = pair_keys(s)
    cols = keys + [
        "field",
        "bit",
        "bit_class",
        "footprint",
        "catastrophic",
        "psnr",
        "nonfinite",
        "peak_error",
        "time_ms",
    ]
    cols = [c for c in dict.fromkeys(cols) if c in s]
    left = s.loc[s["defense"] == a, cols].drop_duplicates(keys)
    rcols = [c for c in cols if c in keys or c not in ("field", "bit", "bit_class")]
    right = s.loc[s["defense"] == b, rcols].drop_duplicates(keys)
    return left.merge(right, on=keys, suffixes=(f"_{a}", f"_{b}"))


def guard_analysis(df: pd.DataFrame, guard: str = "guard", conf: float = 0.95) -> dict:
    """The guard against no defense on the same fault sites (single-upset campaign).

    Returns {"summary": per (precision, defense) footprint stats and catastrophe rate,
             "paired": per precision (+ "all"): pairs, catastrophic without guard, neutralised,
                       share neutralised with CI, residual catastrophic, worst guarded footprint,
             "sign_psnr": log-scale sign flips: mean/median (clipped) PSNR before and after,
             "worst_guarded_footprint_pct", "residual_catastrophic", "n_guarded", "share_pct"}.
    """
    s = single_upsets(df, None, None)
    s = s[s["defense"].isin(["none", guard])]
    if not (s["defense"] == guard).any():
        raise InsufficientData(
            f"no single-upset records with defense '{guard}'",
            f"run the single-upset campaign with defenses none,{guard}",
        )
    p = paired(s, "none", guard)
    if p.empty:
        raise InsufficientData(
            f"no fault sites measured both without and with '{guard}'",
            f"run the single-upset campaign with defenses none,{guard} (same injection ids)",
        )
    rows = []
    for (prec, dfn), g in s.groupby(["precision", "defense"], sort=False):
        fp = g["footprint"].to_numpy(float) * 100
        rows.append(
            {
                "precision": prec,
                "defense": dfn,
                "n": len(g),
                "mean_footprint_pct": np.nanmean(fp),
                "p99_footprint_pct": np.nanquantile(fp, 0.99),
                "max_footprint_pct": np.nanmax(fp),
                "catastrophic": int(g["catastrophic"].sum()),
            }
        )
    summary = pd.DataFrame(rows)
    summary = pd.concat(
        [summary, pd.DataFrame(_rate_columns(summary["catastrophic"], summary["n"], conf=conf))], axis=1
    )
    summary = _sort_prec_def(summary)
    _tag(summary, s)

    cn, cg = "catastrophic_none", f"catastrophic_{guard}"
    fg = f"footprint_{guard}"
    prow = []
    groups = [(prec, g) for prec, g in p.groupby("precision", sort=False)]
    if len(groups) > 1:
        groups.append(("all", p))
    for prec, g in groups:
        cat = g[cn].astype(bool)
        neut = cat & ~g[cg].astype(bool)
        k, n = int(neut.sum()), int(cat.sum())
        lo, hi = stats.wilson_interval(k, n, conf) if n else (np.nan, np.nan)
        prow.append(
            {
                "precision": prec,
                "pairs": len(g),
                "catastrophic_none": n,
                "neutralised": k,
                "share_neutralised_pct": 100 * k / n if n else np.nan,
                "share_ci_lo_pct": 100 * lo,
                "share_ci_hi_pct": 100 * hi,
                "residual_catastrophic": int(g[cg].astype(bool).sum()),
                "worst_guarded_footprint_pct": 100 * float(g[fg].max()),
            }
        )
    ptab = _sort_prec_def(pd.DataFrame(prow))
    _tag(ptab, s[s["injection_id"].isin(p["injection_id"])] if "injection_id" in s else s)

    sp = p[(p["field"] == "log_scales") & (p["bit_class"] == "sign")]
    srow = []
    for prec, g in sp.groupby("precision", sort=False):
        a = capped_psnr(g.rename(columns={"psnr_none": "psnr", "nonfinite_none": "nonfinite"}))
        b = capped_psnr(g.rename(columns={f"psnr_{guard}": "psnr", f"nonfinite_{guard}": "nonfinite"}))
        srow.append(
            {
                "precision": prec,
                "pairs": len(g),
                "mean_psnr_none_db": a.mean(),
                "mean_psnr_guard_db": b.mean(),
                "median_psnr_none_db": a.median(),
                "median_psnr_guard_db": b.median(),
                "mean_footprint_none_pct": 100 * g["footprint_none"].mean(),
                "mean_footprint_guard_pct": 100 * g[fg].mean(),
            }
        )
    stab = _sort_prec_def(
        pd.DataFrame(
            srow,
            columns=[
                "precision",
                "pairs",
                "mean_psnr_none_db",
                "mean_psnr_guard_db",
                "median_psnr_none_db",
                "median_psnr_guard_db",
                "mean_footprint_none_pct",
                "mean_footprint_guard_pct",
            ],
        )
    )
    _tag(stab, s[(s["field"] == "log_scales") & (s["bit_class"] == "sign")])

    allg = s[s["defense"] == guard]
    tot = ptab[ptab["precision"] == "all"] if (ptab["precision"] == "all").any() else ptab
    return {
        "summary": summary,
        "paired": ptab,
        "sign_psnr": stab,
        "worst_guarded_footprint_pct": 100 * float(allg["footprint"].max()),
        "residual_catastrophic": int(allg["catastrophic"].sum()),
        "n_guarded": int(len(allg)),
        "share_pct": float(tot["share_neutralised_pct"].iloc[0]) if len(tot) else np.nan,
    }


def _sort_prec_def(t: pd.DataFrame) -> pd.DataFrame:
    if t.empty:
        return t.reset_index(drop=True)
    porder = {p: i for i, p in enumerate(encoding.PRECISIONS + ("all",))}
    dorder = {x: i for i, x in enumerate(DEFENSES)}
    key = {}
    if "precision" in t:
        key["_p"] = t["precision"].map(lambda x: porder.get(x, 99))
    if "defense" in t:
        key["_d"] = t["defense"].map(lambda x: dorder.get(x, 99))
    if not key:
        return t.reset_index(drop=True)
    t = t.assign(**key)
    return t.sort_values(list(key), kind="stable").drop(columns=list(key)).reset_index(drop=True)


# ------------------------------------------------------------------------------- mitigation


def memory_overhead(
    defense: str,
    precision: str = "fp32",
    n_primitives: int | None = None,
    sh_degree: int = DEFAULT_SH_DEGREE,
    manifests: Iterable[dict] = (),
) -> tuple[float, str]:
    """(fractional memory overhead, basis text) of a defense.

    A manifest may state it: ``manifest["memory_overhead"][defense]`` or
    ``manifest["defenses"][defense]["memory_overhead"]`` (a fraction); else documented constants:
    * none: 0.
    * guard: the support box, 2 fp32 bounds per guarded component per model (not per primitive);
      the guard skips sh_rest, so 2 x 14 values for the whole model: 2*14*32 / (N*C*bits).
    * selective: the box of log-scale and opacity only, 2 x 4 values per model.
    * ecc: a SEC-DED (extended Hamming) code per stored value over its sign+exponent bits:
      fp32 9 data bits -> 5 check bits (+15.6%), fp16 6 -> 5 (+31.3%), bf16 9 -> 5 (+31.3%).
    * dup: duplication with majority voting needs three copies (triple modular redundancy), +200%.
    """
    for m in manifests or ():
        for src in (
            m.get("memory_overhead"),
            (m.get("defenses") or {}).get(defense),
            (m.get("spec", {}) or {}).get("memory_overhead"),
        ):
            if isinstance(src, dict):
                v = src.get(defense) if defense in src else src.get("memory_overhead")
                if isinstance(v, (int, float)):
                    return float(v), "from the run manifest"
    bits = encoding.BITS.get(precision, 32)
    comps = n_components(sh_degree)
    if defense == "none":
        return 0.0, "no redundancy"
    if defense in ("guard", "selective"):
        guarded = (
            sum(field_components(f, sh_degree) for f in FIELDS if f != "sh_rest")
            if defense == "guard"
            else field_components("log_scales", sh_degree) + field_components("opacity", sh_degree)
        )
        if not n_primitives:
            return 0.0, f"2 x {guarded} fp32 box bounds per model (~0 per primitive)"
        frac = 2 * guarded * GUARD_BOX_BITS / (float(n_primitives) * comps * bits)
        return frac, f"2 x {guarded} fp32 box bounds per model, N = {int(n_primitives):,}"
    if defense == "ecc":
        from seuwgpu.faults.defenses import ecc_check_bits  # the code the ECC defense simulates

        chk = ecc_check_bits(precision)
        return chk / bits, f"SEC-DED over sign+exponent: {chk} check bits per {bits}-bit value"
    if defense == "dup":
        return 2.0, "three copies (TMR, majority vote)"
    return float("nan"), "unknown defense"


def mitigation_table(
    df: pd.DataFrame, manifests: Iterable[dict] = (), precision: str | None = None, conf: float = 0.95
) -> pd.DataFrame:
    """none / guard / selective / ecc / dup on the shared fault grid at one precision.

    The shared grid is the set of fault sites (pair_keys) measured under every defense present;
    if no site was measured under all of them, each defense uses all its sites (attrs["paired"]
    is False). Columns: defense, label, n, catastrophic, cat_rate_pct (+ Wilson CI),
    mean_footprint_pct, max_footprint_pct, memory_overhead_pct, memory_basis, time_ms_mean,
    time_ratio (mean time_ms over that of 'none', when time_ms is recorded).
    """
    s = single_upsets(df, None, None)
    if s.empty:
        raise InsufficientData("no single-upset records", "run a single-upset campaign")
    precision = precision or reference_precision(s)
    s = s[s["precision"] == precision]
    defs = defenses_present(s)
    if len(defs) < 2:
        raise InsufficientData(
            f"only defense(s) {', '.join(defs)} at {precision}",
            "run the single-upset campaign with --defenses none,guard,selective,ecc,dup",
        )
    keys = pair_keys(s)
    sites = None
    for x in defs:
        idx = pd.MultiIndex.from_frame(s.loc[s["defense"] == x, keys].drop_duplicates())
        sites = idx if sites is None else sites.intersection(idx)
    is_paired = sites is not None and len(sites) > 0
    if is_paired:
        mi = pd.MultiIndex.from_frame(s[keys])
        s = s[mi.isin(sites)]
    manifests = list(manifests or ())
    deg = sh_degree_of(s, manifests)
    n_prims = float(s["n_primitives"].mean()) if "n_primitives" in s and len(s) else None
    t_none = s.loc[s["defense"] == "none", "time_ms"].mean()
    rows = []
    for x in defs:
        g = s[s["defense"] == x]
        ov, basis = memory_overhead(x, precision, n_prims, deg, manifests)
        tm = g["time_ms"].mean()
        rows.append(
            {
                "defense": x,
                "label": DEFENSE_LABELS.get(x, x),
                "n": len(g),
                "catastrophic": int(g["catastrophic"].sum()),
                "mean_footprint_pct": 100 * g["footprint"].mean(),
                "max_footprint_pct": 100 * g["footprint"].max(),
                "memory_overhead_pct": 100 * ov,
                "memory_basis": basis,
                "time_ms_mean": tm,
                "time_ratio": tm / t_none if np.isfinite(tm) and np.isfinite(t_none) and t_none > 0 else np.nan,
            }
        )
    out = pd.DataFrame(rows)
    rc = pd.DataFrame(_rate_columns(out["catastrophic"], out["n"], conf=conf))
    out = pd.concat([out.iloc[:, :4], rc, out.iloc[:, 4:]], axis=1)
    return _tag(out, s, precision=precision, paired=is_paired, sh_degree=deg)


# -------------------------------------------------------------------------------------- dose


def dose_curves(df: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """PSNR against k per (precision, defense): mean, median, quartiles (clipped PSNR, see module
    notes), mean SSIM and footprint, and the catastrophic fraction with a Wilson interval."""
    d = dose_records(df)
    if d.empty or not (d["k"] > 1).any():
        raise InsufficientData("no k > 1 records", "run a dose campaign (k simultaneous upsets)")
    d = d.assign(_psnr=capped_psnr(d))
    g = d.groupby(["precision", "defense", "k"], sort=False)
    out = g.agg(
        n=("_psnr", "size"),
        psnr_mean_db=("_psnr", "mean"),
        psnr_median_db=("_psnr", "median"),
        psnr_q25_db=("_psnr", lambda x: x.quantile(0.25)),
        psnr_q75_db=("_psnr", lambda x: x.quantile(0.75)),
        ssim_mean=("ssim", "mean"),
        mean_footprint_pct=("footprint", "mean"),
        catastrophic=("catastrophic", "sum"),
        scenes=("scene", "nunique"),
    ).reset_index()
    out["mean_footprint_pct"] *= 100
    out["catastrophic"] = out["catastrophic"].astype(np.int64)
    rc = _rate_columns(out["catastrophic"], out["n"], conf=conf)
    out = pd.concat([out, pd.DataFrame(rc)], axis=1)
    out = _sort_prec_def(out.sort_values("k", kind="stable"))
    return _tag(out, d)


def crossing_k(ks, values, threshold: float = BUDGET_PSNR_DB) -> tuple[float, str]:
    """First k where `values` falls to or below `threshold`, interpolated linearly in log k.

    Returns (k, censor): censor "" for an interpolated crossing, "<=" when the first k is already
    at or below (the budget is at most that k), ">=" when no k reaches it (at least the largest k).
    """
    ks = np.asarray(ks, dtype=float)
    v = np.asarray(values, dtype=float)
    order = np.argsort(ks)
    ks, v = ks[order], v[order]
    below = np.nonzero(v <= threshold)[0]
    if below.size == 0:
        return float(ks[-1]), ">="
    i = int(below[0])
    if i == 0:
        return float(ks[0]), "<="
    k0, k1 = math.log(ks[i - 1]), math.log(ks[i])
    v0, v1 = v[i - 1], v[i]
    t = (v0 - threshold) / (v0 - v1) if v0 != v1 else 0.0
    return float(math.exp(k0 + t * (k1 - k0))), ""


def redundancy_budget(df: pd.DataFrame, threshold_db: float = BUDGET_PSNR_DB) -> pd.DataFrame:
    """k where the mean (clipped) PSNR first crosses `threshold_db`, per (scene, n_primitives,
    precision, defense), interpolated in log k, from dose campaign records (uniform upsets; a size
    campaign's single upsets are stratified by cell, so they do not stand for k = 1 here)."""
    d = prepare(df)
    d = d[d["campaign"] == "dose"]
    if d.empty or not (d["k"] > 1).any():
        raise InsufficientData("no k > 1 records", "run a dose campaign (k simultaneous upsets)")
    d = d.assign(_psnr=capped_psnr(d))
    keys = ["scene", "n_primitives", "precision", "defense"]
    rows = []
    for key, g in d.groupby(keys, sort=False):
        m = g.groupby("k")["_psnr"].mean()
        if len(m) < 2:
            continue
        kb, cens = crossing_k(m.index.to_numpy(), m.to_numpy(), threshold_db)
        rows.append(
            dict(
                zip(keys, key),
                n=len(g),
                k_min=int(m.index.min()),
                k_max=int(m.index.max()),
                n_k=len(m),
                k_budget=kb,
                censored=cens,
            )
        )
    if not rows:
        raise InsufficientData("no dose sweep with two or more k values", "run a dose campaign sweeping k")
    out = _sort_prec_def(pd.DataFrame(rows).sort_values(["scene", "n_primitives"]))
    return _tag(out, d, threshold_db=threshold_db)


def _wquantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    """Weighted quantile (lower, on the sorted values; +inf sorts last)."""
    v = np.asarray(values, float)
    w = np.asarray(weights, float)
    order = np.argsort(v, kind="stable")
    cw = np.cumsum(w[order])
    return float(v[order][np.searchsorted(cw, q * cw[-1])])


def size_scaling(df: pd.DataFrame) -> dict:
    """Median and mean single-upset error against primitive count N, with log-log fits.

    Uses k = 1 records of campaign "size" (else of campaign "dose"). Records are weighted by their
    `weight` column (stored bits each sample stands for), so a stratified size campaign estimates
    the mean and median over a uniformly drawn upset, as a uniform one does directly.
    Error = frame MSE from PSNR (see module notes); footprint too.
    Fits are per (scene, precision, defense) with at least two N values; alpha = -exponent
    (the paper's sigma^2(N) = Theta(N^-alpha)). "guard_factor": mean MSE without / with guard at
    the largest N of each scene and precision.
    Returns {"table", "fits", "guard_factor"}.
    """
    d = prepare(df)
    d = d[d["k"] == 1]
    src = "size" if (d["campaign"] == "size").any() else "dose"
    d = d[d["campaign"] == src]
    if d.empty or "n_primitives" not in d:
        raise InsufficientData(
            "no uniform single-upset records at several primitive counts",
            "run a size campaign (single upsets on subsampled models)",
        )
    nn = d.groupby("scene")["n_primitives"].nunique()
    if not (nn >= 2).any():
        raise InsufficientData(
            "single-upset records at only one primitive count per scene",
            "run a size campaign (single upsets on subsampled models)",
        )
    d = d[d["scene"].isin(nn[nn >= 2].index)]
    d = d.assign(_mse=mse_from_psnr(d))
    rows = []
    for key, g in d.groupby(["scene", "precision", "defense", "n_primitives"], sort=False):
        mse = g["_mse"].to_numpy(float)
        w = g["weight"].to_numpy(float) if "weight" in g and g["weight"].notna().all() else np.ones(len(g))
        fin = np.isfinite(mse)
        foot = g["footprint"].to_numpy(float)
        rows.append(
            {
                "scene": key[0],
                "precision": key[1],
                "defense": key[2],
                "n_primitives": int(key[3]),
                "n": len(g),
                "median_mse": _wquantile(mse, w, 0.5),
                "mean_mse": float(np.average(mse[fin], weights=w[fin])) if fin.any() else np.nan,
                "n_nonfinite": int((~fin).sum()),
                "median_footprint_pct": 100 * _wquantile(foot, w, 0.5),
                "mean_footprint_pct": 100 * float(np.average(foot, weights=w)),
            }
        )
    table = _sort_prec_def(pd.DataFrame(rows).sort_values(["scene", "n_primitives"]))
    _tag(table, d, source_campaign=src)
    frows = []
    for key, g in table.groupby(["scene", "precision", "defense"], sort=False):
        for metric in ("median_mse", "mean_mse", "median_footprint_pct", "mean_footprint_pct"):
            try:
                f = stats.loglog_fit(g["n_primitives"], g[metric])
                exp_, icpt, r2 = f
            except ValueError:
                exp_ = icpt = r2 = np.nan
            frows.append(
                {
                    "scene": key[0],
                    "precision": key[1],
                    "defense": key[2],
                    "metric": metric,
                    "n_sizes": len(g),
                    "exponent": exp_,
                    "alpha": -exp_ if np.isfinite(exp_) else np.nan,
                    "log10_prefactor": icpt,
                    "r2": r2,
                }
            )
    fits = _tag(_sort_prec_def(pd.DataFrame(frows)), d)
    grows = []
    for (scene, prec), g in table.groupby(["scene", "precision"], sort=False):
        top = g[g["n_primitives"] == g["n_primitives"].max()]
        a = top.loc[top["defense"] == "none", "mean_mse"]
        b = top.loc[top["defense"] == "guard", "mean_mse"]
        if len(a) and len(b):
            grows.append(
                {
                    "scene": scene,
                    "precision": prec,
                    "n_primitives": int(top["n_primitives"].iloc[0]),
                    "mean_mse_none": float(a.iloc[0]),
                    "mean_mse_guard": float(b.iloc[0]),
                    "guard_factor": float(a.iloc[0] / b.iloc[0]) if b.iloc[0] > 0 else np.inf,
                }
            )
    gf = _tag(pd.DataFrame(grows), d)
    return {"table": table, "fits": fits, "guard_factor": gf, "source_campaign": src}


# ------------------------------------------------------------------------------- reliability


def cell_weights(precision: str, sh_degree: int = DEFAULT_SH_DEGREE) -> dict[tuple[str, int], float]:
    """Share of the stored bit budget in each (field, bit) cell: a uniform upset's distribution."""
    bits = encoding.BITS[precision]
    comps = n_components(sh_degree)
    w = {}
    for f in FIELDS:
        c = field_components(f, sh_degree)
        if c == 0:
            continue
        for b in range(bits):
            w[(f, b)] = c / comps / bits
    return w


def catastrophe_probability(df: pd.DataFrame, manifests: Iterable[dict] = (), conf: float = 0.95) -> pd.DataFrame:
    """p_c per (precision, defense): stratified from the single-upset campaign (each cell weighted
    by its share of stored bits; Wilson interval at the Kish effective n), plus the direct estimate
    from k = 1 records of a dose campaign where present (source column says which).
    `coverage_pct` is the share of the stored bit budget whose cells were sampled."""
    d = prepare(df)
    deg = sh_degree_of(d, manifests)
    rows = []
    s = single_upsets(d, None, None)
    s = s[s["bit"] >= 0]
    for (prec, dfn), g in s.groupby(["precision", "defense"], sort=False):
        if prec not in encoding.BITS:
            continue
        w = cell_weights(prec, deg)
        cells = g.groupby(["field", "bit"]).agg(k=("catastrophic", "sum"), n=("catastrophic", "size"))
        cw = np.array([w.get(ix, 0.0) for ix in cells.index])
        if cw.sum() <= 0:
            continue
        p, lo, hi, neff = stats.stratified_rate(cells["k"], cells["n"], cw, conf)
        rows.append(
            {
                "precision": prec,
                "defense": dfn,
                "source": "single (stratified)",
                "p_c": p,
                "ci_lo": lo,
                "ci_hi": hi,
                "n": len(g),
                "n_eff": neff,
                "coverage_pct": 100 * cw.sum(),
                "sh_degree": deg,
            }
        )
    dz = d[(d["campaign"] == "dose") & (d["k"] == 1)]
    for (prec, dfn), g in dz.groupby(["precision", "defense"], sort=False):
        k, n = int(g["catastrophic"].sum()), len(g)
        lo, hi = stats.wilson_interval(k, n, conf)
        rows.append(
            {
                "precision": prec,
                "defense": dfn,
                "source": "dose k=1 (uniform)",
                "p_c": k / n,
                "ci_lo": lo,
                "ci_hi": hi,
                "n": n,
                "n_eff": float(n),
                "coverage_pct": 100.0,
                "sh_degree": deg,
            }
        )
    if not rows:
        raise InsufficientData(
            "no single-upset records to estimate p_c", "run a single-upset campaign over all fields and bits"
        )
    out = _sort_prec_def(pd.DataFrame(rows))
    return _tag(out, pd.concat([s, dz]))


def pc_lookup(pc: pd.DataFrame, precision: str, defense: str):
    g = pc[(pc["precision"] == precision) & (pc["defense"] == defense)]
    if g.empty:
        return None
    pref = g[g["source"].str.startswith("single")]
    return (pref if len(pref) else g).iloc[0]


def dose_model(
    df: pd.DataFrame, pc: pd.DataFrame | None = None, conf: float = 0.95, manifests: Iterable[dict] = ()
) -> pd.DataFrame:
    """Measured catastrophic fraction against 1 - (1 - p_c)^k per (precision, defense, k).

    `within_ci` says whether the model lies inside the Wilson interval of the measurement."""
    curves = dose_curves(df, conf)
    if pc is None:
        pc = catastrophe_probability(df, manifests, conf)
    rows = []
    for _, r in curves.iterrows():
        ref = pc_lookup(pc, r["precision"], r["defense"])
        p = ref["p_c"] if ref is not None else np.nan
        lo = ref["ci_lo"] if ref is not None else np.nan
        hi = ref["ci_hi"] if ref is not None else np.nan
        k = r["k"]
        model = 1 - (1 - p) ** k
        meas = r["cat_rate_pct"] / 100
        rows.append(
            {
                "precision": r["precision"],
                "defense": r["defense"],
                "k": int(k),
                "n": int(r["n"]),
                "measured_pct": 100 * meas,
                "measured_ci_lo_pct": r["cat_ci_lo_pct"],
                "measured_ci_hi_pct": r["cat_ci_hi_pct"],
                "p_c": p,
                "model_pct": 100 * model,
                "model_lo_pct": 100 * (1 - (1 - lo) ** k),
                "model_hi_pct": 100 * (1 - (1 - hi) ** k),
                "within_ci": bool(np.isfinite(model) and r["cat_ci_lo_pct"] <= 100 * model <= r["cat_ci_hi_pct"]),
            }
        )
    out = pd.DataFrame(rows)
    out.attrs.update(curves.attrs)
    return out


def format_duration(hours: float) -> str:
    """Human-readable duration: s, min, h, d or yr."""
    if hours is None or not np.isfinite(hours):
        return "inf"
    s = hours * 3600
    if s < 60:
        return f"{s:.3g} s"
    if s < 3600:
        return f"{s / 60:.3g} min"
    if hours < 48:
        return f"{hours:.3g} h"
    if hours < 2 * HOURS_PER_YEAR:
        return f"{hours / 24:.3g} d"
    return f"{hours / HOURS_PER_YEAR:.3g} yr"


def model_bits(df: pd.DataFrame, precision: str, sh_degree: int = DEFAULT_SH_DEGREE) -> float:
    """Stored bits of the model(s) in the records: the mean over scenes of the primitive count
    (single-upset campaign when present) x components per primitive x bits per value."""
    d = prepare(df)
    single = d[d["campaign"] == "single"]
    d = single if len(single) else d  # size campaigns subsample: not the deployed model
    d = d[d["precision"] == precision] if (d["precision"] == precision).any() else d
    n = d.groupby("scene")["n_primitives"].max().mean()
    return float(n) * n_components(sh_degree) * encoding.BITS[precision]


def mtbf_table(
    pc: pd.DataFrame, bits: float, precision: str, rates=UPSET_RATES, defenses: tuple[str, ...] = ("none", "guard")
) -> pd.DataFrame:
    """Mean time between catastrophic frames, 1 / (rate x bits x p_c), per environment/defense.

    Each upset is assumed to persist until scrubbed, so every catastrophic upset yields
    catastrophic frames: the MTBF is the mean time to the next catastrophic upset. Bounds come
    from the Wilson interval of p_c (no events -> the MTBF is unbounded above, 'inf')."""
    rows = []
    for env in rates:
        lam = float(env["per_bit_hour"])
        for dfn in defenses:
            ref = pc_lookup(pc, precision, dfn)
            if ref is None:
                continue
            p, lo, hi = float(ref["p_c"]), float(ref["ci_lo"]), float(ref["ci_hi"])

            def t(x, lam=lam):
                return 1.0 / (lam * bits * x) if x > 0 else np.inf

            rows.append(
                {
                    "environment": env["environment"],
                    "upsets_per_bit_hour": lam,
                    "fit_per_mbit": lam * 1e15,
                    "precision": precision,
                    "model_bits": bits,
                    "defense": dfn,
                    "p_c": p,
                    "mtbf_hours": t(p),
                    "mtbf_hours_lo": t(hi),
                    "mtbf_hours_hi": t(lo),
                    "mtbf": (format_duration(t(p)) if p > 0 else f"> {format_duration(t(hi))}"),
                    "mtbf_range": f"{format_duration(t(hi))} .. {format_duration(t(lo))}",
                    "source": env["source"],
                }
            )
    out = pd.DataFrame(rows)
    out.attrs.update(pc.attrs)
    return out


def reliability(
    df: pd.DataFrame,
    manifests: Iterable[dict] = (),
    rates=UPSET_RATES,
    bits: float | None = None,
    precision: str | None = None,
    conf: float = 0.95,
) -> dict:
    """p_c from the data, the dose model against the measured curve (when dose records exist),
    and the MTBF of catastrophic frames for ground / avionics / LEO rates, with and without guard.
    Returns {"pc", "dose_model" (None without dose records), "mtbf", "mtbf_wide", "bits",
    "precision", "notes"}."""
    manifests = list(manifests or ())
    pc = catastrophe_probability(df, manifests, conf)
    notes = []
    precision = precision or reference_precision(pc)
    deg = int(pc["sh_degree"].iloc[0])
    if bits is None:
        bits = model_bits(df, precision, deg)
    try:
        dm = dose_model(df, pc, conf, manifests)
    except InsufficientData as e:
        dm = None
        notes.append(f"dose model not compared: {e.reason} ({e.remedy})")
    low_cov = pc[pc["coverage_pct"] < 99.999]
    for _, r in low_cov.iterrows():
        notes.append(
            f"p_c at {r['precision']}/{r['defense']} covers only "
            f"{r['coverage_pct']:.1f}% of the stored bits (unsampled cells excluded)"
        )
    mt = mtbf_table(pc, bits, precision, rates)
    d = prepare(df)
    used = d[
        (d["precision"] == precision)
        & d["defense"].isin(["none", "guard"])
        & (((d["campaign"] == "single") & (d["k"] == 1)) | ((d["campaign"] == "dose") & (d["k"] == 1)))
    ]
    mt.attrs["provenance"] = provenance(used)
    wide = None
    if len(mt):
        wide = mt.pivot_table(index="environment", columns="defense", values="mtbf", aggfunc="first", sort=False)
        wide = wide.reindex(columns=[c for c in ("none", "guard") if c in wide.columns])
        wide = wide.reset_index().rename(columns={"none": "no guard", "guard": "support guard"})
        wide.columns.name = None
        wide.attrs.update(mt.attrs)
    return {
        "pc": pc,
        "dose_model": dm,
        "mtbf": mt,
        "mtbf_wide": wide,
        "bits": bits,
        "precision": precision,
        "notes": notes,
    }


# ------------------------------------------------------------------ distributed contamination


def region_set(changed_mask_or_bbox, H: int, W: int, P: int) -> np.ndarray:
    """Boolean array of P regions (row-major: index = row * cols + col) touched by a footprint.

    The footprint is a boolean pixel mask of shape (H, W) (or (V, H, W): any view), or a bbox
    (x0, y0, x1, y1) in continuous pixel coordinates, x1/y1 exclusive, covering the pixels
    floor(x0) .. ceil(x1)-1 (clipped to the screen; an empty or off-screen box touches nothing).
    Region (i, j) spans rows edges_y[i]..edges_y[i+1]-1, edges = floor(t * size / parts)."""
    ey, ex = region_edges(P, H, W)
    rows, cols = len(ey) - 1, len(ex) - 1
    out = np.zeros(rows * cols, dtype=bool)
    obj = changed_mask_or_bbox
    if isinstance(obj, (tuple, list)) and len(obj) == 4 and np.ndim(obj[0]) == 0:
        x0, y0, x1, y1 = (float(v) for v in obj)
        if not all(np.isfinite([x0, y0, x1, y1])):
            # a non-finite box (exploded primitive) is treated as covering the screen
            x0, y0, x1, y1 = 0.0, 0.0, float(W), float(H)
        ix0, iy0 = max(int(math.floor(x0)), 0), max(int(math.floor(y0)), 0)
        ix1, iy1 = min(int(math.ceil(x1)), W), min(int(math.ceil(y1)), H)
        if ix1 <= ix0 or iy1 <= iy0:
            return out
        for i in range(rows):
            if ey[i + 1] <= iy0 or ey[i] >= iy1:
                continue
            for j in range(cols):
                if ex[j + 1] <= ix0 or ex[j] >= ix1:
                    continue
                out[i * cols + j] = True
        return out
    m = np.asarray(obj).astype(bool)
    if m.ndim == 3:
        m = m.any(axis=0)
    if m.shape != (H, W):
        raise ValueError(f"mask shape {m.shape} does not match the screen ({H}, {W})")
    for i in range(rows):
        band = m[ey[i] : ey[i + 1]]
        if not band.any():
            continue
        colany = band.any(axis=0)
        for j in range(cols):
            out[i * cols + j] = bool(colany[ex[j] : ex[j + 1]].any())
    return out


def contaminated_regions(changed_mask_or_bbox, H: int, W: int, P: int) -> int:
    """Number of regions of a P-way sort-first grid touched by a pixel mask or bbox."""
    return int(region_set(changed_mask_or_bbox, H, W, P).sum())


def regions_to_bitmask(regions) -> int:
    """Region set (bool array or index list) -> int bitmask (bit r set when region r touched)."""
    a = np.asarray(regions)
    idx = np.nonzero(a)[0] if a.dtype == bool else a.astype(np.int64).reshape(-1)
    v = 0
    for r in idx:
        v |= 1 << int(r)
    return v


def decode_regions(value, P: int) -> np.ndarray | None:
    """A stored region set -> bool array of P. Accepts an int bitmask (bit r = region r; an int64
    holding a 64-bit mask may be negative), a list/array of region indices, a bool array of
    length P, or a comma-separated string of indices. None/NaN -> None (not measured)."""
    if value is None or value is pd.NA:
        return None
    if isinstance(value, (float, np.floating)):
        if math.isnan(value):
            return None
        if float(value).is_integer():  # an integer column widened to float by missing values
            value = int(value)
    out = np.zeros(P, dtype=bool)
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        v = int(value) & ((1 << 64) - 1)
        for r in range(min(P, 64)):
            if (v >> r) & 1:
                out[r] = True
        return out
    if isinstance(value, str):
        idx = [int(t) for t in value.replace(";", ",").split(",") if t.strip()]
        out[idx] = True
        return out
    a = np.asarray(value)
    if a.dtype == bool and a.size == P:
        return a.reshape(-1).copy()
    if a.size:
        out[a.astype(np.int64).reshape(-1)] = True
    return out


def region_iou(a, b) -> float:
    """IoU of two region sets (bool arrays); NaN when both are empty."""
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    union = int((a | b).sum())
    if union == 0:
        return float("nan")
    return int((a & b).sum()) / union


def popcount64(a) -> np.ndarray:
    """Set bits per element of a uint64 array."""
    a = np.ascontiguousarray(a, dtype=np.uint64)
    if hasattr(np, "bitwise_count"):
        return np.bitwise_count(a).astype(np.int64)
    return np.unpackbits(a.view(np.uint8).reshape(-1, 8), axis=1).sum(axis=1).astype(np.int64)


def _as_bitmask_array(col: pd.Series, P: int):
    """(uint64 masks, valid) for an integer (or integral-float) bitmask column, else None."""
    if P > 64 or not pd.api.types.is_numeric_dtype(col):
        return None
    valid = col.notna().to_numpy()
    if pd.api.types.is_float_dtype(col):
        v = col.to_numpy(float)
        if not np.all(np.mod(v[valid], 1) == 0):
            return None
        out = np.zeros(len(col), dtype=np.uint64)
        out[valid] = v[valid].astype(np.int64).view(np.uint64)
        return out, valid
    if pd.api.types.is_bool_dtype(col):
        return None
    v = col.to_numpy(dtype=np.int64, na_value=0)
    return np.ascontiguousarray(v, dtype=np.int64).view(np.uint64), valid


def _region_stats(pred_col: pd.Series, meas_col: pd.Series, P: int):
    """Per record: regions predicted, regions measured and their IoU (NaN where not measured or
    both empty). Vectorised for bitmask columns; per record otherwise."""
    a, b = _as_bitmask_array(pred_col, P), _as_bitmask_array(meas_col, P)
    if a is not None and b is not None:
        keep = np.uint64((1 << P) - 1) if P < 64 else np.uint64(0xFFFFFFFFFFFFFFFF)
        pa, va = a[0] & keep, a[1]
        pb, vb = b[0] & keep, b[1]
        npred = np.where(va, popcount64(pa), np.nan)
        nmeas = np.where(vb, popcount64(pb), np.nan)
        inter, union = popcount64(pa & pb), popcount64(pa | pb)
        with np.errstate(invalid="ignore", divide="ignore"):
            iou = np.where(va & vb & (union > 0), inter / np.maximum(union, 1), np.nan)
        return npred.astype(float), nmeas.astype(float), iou.astype(float)
    pred = [decode_regions(v, P) for v in pred_col]
    meas = [decode_regions(v, P) for v in meas_col]
    npred = np.array([np.nan if x is None else x.sum() for x in pred], dtype=float)
    nmeas = np.array([np.nan if x is None else x.sum() for x in meas], dtype=float)
    iou = np.array([np.nan if (x is None or y is None) else region_iou(x, y) for x, y in zip(pred, meas)], dtype=float)
    return npred, nmeas, iou


_REGION_RE = re.compile(r"^regions_pred_(\d+)$")


def contamination_partitions(df: pd.DataFrame) -> list[int]:
    """Partition sizes P with both regions_pred_{P} and regions_meas_{P} columns."""
    ps = []
    for c in df.columns:
        m = _REGION_RE.match(str(c))
        if m and f"regions_meas_{m.group(1)}" in df.columns:
            ps.append(int(m.group(1)))
    return sorted(ps)


def contamination(df: pd.DataFrame) -> pd.DataFrame:
    """Fraction of P sort-first regions a single upset contaminates, predicted (projected
    footprint) and measured (changed pixels), their IoU, per (precision, defense, P), for all
    single upsets and for log-scale sign flips. Needs columns regions_pred_{P}/regions_meas_{P}
    (see `decode_regions`); optional region_ms_max_{P}/region_ms_mean_{P} give the slowest-region
    render time and the load imbalance (max / mean). IoU is averaged over records where either
    set is non-empty."""
    d = single_upsets(df, None, None)
    ps = contamination_partitions(d)
    if not ps or d.empty:
        raise InsufficientData(
            "no regions_pred_P / regions_meas_P columns in the records",
            "run a single-upset campaign with regions = [4, 16, 64] in its [single] "
            "table (sort-first partitions; `seuwgpu distributed` times the regions)",
        )
    rows = []
    for P in ps:
        npred, nmeas, iou = _region_stats(d[f"regions_pred_{P}"], d[f"regions_meas_{P}"], P)
        tmax = d.get(f"region_ms_max_{P}")
        tmean = d.get(f"region_ms_mean_{P}")
        e = pd.DataFrame(
            {
                "precision": d["precision"].to_numpy(),
                "defense": d["defense"].to_numpy(),
                "sign_scale": ((d["field"] == "log_scales") & (d["bit_class"] == "sign")).to_numpy(),
                "fp": npred / P,
                "fm": nmeas / P,
                "iou": iou,
                "tmax": np.nan if tmax is None else pd.to_numeric(tmax).to_numpy(float),
                "tmean": np.nan if tmean is None else pd.to_numeric(tmean).to_numpy(float),
            }
        )
        for subset, sel in (("all single upsets", slice(None)), ("log-scale sign", e["sign_scale"])):
            es = e[sel] if not isinstance(sel, slice) else e
            for (prec, dfn), g in es.groupby(["precision", "defense"], sort=False):
                rows.append(
                    {
                        "subset": subset,
                        "precision": prec,
                        "defense": dfn,
                        "P": P,
                        "n": len(g),
                        "pred_fraction_pct": 100 * g["fp"].mean(),
                        "meas_fraction_pct": 100 * g["fm"].mean(),
                        "iou_mean": g["iou"].mean(),
                        "n_iou": int(g["iou"].notna().sum()),
                        "slowest_region_ms": g["tmax"].mean(),
                        "imbalance": (g["tmax"] / g["tmean"]).mean(),
                    }
                )
    out = pd.DataFrame(rows)
    out = out.sort_values(["subset", "precision", "defense", "P"], kind="stable").reset_index(drop=True)
    return _tag(out, d)


# ------------------------------------------------------------------------------- prediction

PREDICTION_FEATURES = ("field", "bit", "bit_class", "log_abs_value", "sign")
FIELD_BIT_FEATURES = ("field", "bit")


def prediction_features(d: pd.DataFrame) -> pd.DataFrame:
    """Static fault-site features: field, bit, bit class, log10|stored value|, sign of the value.
    A zero value gets log10 = -46 (below the smallest fp32 subnormal), a non-finite one +39."""
    v = d["clean_value"].to_numpy(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        la = np.log10(np.abs(v))
    la = np.where(v == 0, -46.0, la)
    la = np.where(~np.isfinite(v), 39.0, la)
    return pd.DataFrame(
        {
            "field": d["field"].astype(str).to_numpy(),
            "bit": d["bit"].to_numpy(np.int64).astype(float),
            "bit_class": d["bit_class"].astype(str).to_numpy(),
            "log_abs_value": la,
            "sign": np.signbit(v).astype(float),
        },
        index=d.index,
    )


def _classifier(features, seed):
    from sklearn.compose import ColumnTransformer
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import OneHotEncoder

    cat = [f for f in features if f in ("field", "bit_class")]
    pre = ColumnTransformer(
        [("cat", OneHotEncoder(handle_unknown="ignore", sparse_output=False), cat)], remainder="passthrough"
    )
    # early stopping on a 10% validation split (log-loss, 10 rounds without improvement)
    clf = HistGradientBoostingClassifier(
        max_iter=200,
        learning_rate=0.1,
        max_leaf_nodes=31,
        early_stopping=True,
        validation_fraction=0.1,
        n_iter_no_change=10,
        random_state=seed,
    )
    return Pipeline([("pre", pre), ("clf", clf)])


def prediction(
    df: pd.DataFrame,
    precision: str | None = None,
    seed: int = 0,
    max_rows: int = 200_000,
    test_size: float = 0.3,
    n_repeats: int = 5,
    n_threads: int | None = 1,
) -> dict:
    """Predict "catastrophic" from static fault-site features (single-upset campaign, no defense,
    one precision: the bit index means different things in different formats).

    Two gradient-boosted classifiers (scikit-learn HistGradientBoosting): on field, bit, bit class,
    log10|stored value| and sign; and on field and bit alone. Held-out ROC AUC on a stratified
    split; leave-one-scene-out AUC (mean and minimum) with >= 2 scenes; the top feature by
    permutation importance (drop in held-out AUC) of the full model.
    Returns {"summary", "importance", "loso", "top_feature", "roc", "precision"}.
    """
    import sklearn.ensemble  # noqa: F401  (load its OpenMP runtime before limiting it)
    from threadpoolctl import threadpool_limits

    # One OpenMP thread by default: on small or shared machines gradient boosting with several
    # spinning threads can be 20x slower than with one (seen on a loaded 2-core CI box).
    with threadpool_limits(limits=n_threads):
        return _prediction(df, precision, seed, max_rows, test_size, n_repeats)


def _prediction(df, precision, seed, max_rows, test_size, n_repeats) -> dict:
    from sklearn.inspection import permutation_importance
    from sklearn.metrics import roc_curve
    from sklearn.model_selection import train_test_split

    s = _require_single(df, "none")
    precision = precision or reference_precision(s)
    s = s[(s["precision"] == precision) & (s["bit"] >= 0)]
    if len(s) > max_rows:
        s = s.sample(n=max_rows, random_state=seed)
    y = s["catastrophic"].astype(bool).to_numpy()
    npos, nneg = int(y.sum()), int((~y).sum())
    if npos < 5 or nneg < 5:
        raise InsufficientData(
            f"too few catastrophic ({npos}) or benign ({nneg}) upsets at "
            f"{precision} to train a classifier (need >= 5 of each)",
            "run a larger single-upset campaign",
        )
    X = prediction_features(s)
    idx_tr, idx_te = train_test_split(np.arange(len(s)), test_size=test_size, stratify=y, random_state=seed)
    models = {"field+bit+class+value": list(PREDICTION_FEATURES), "field+bit": list(FIELD_BIT_FEATURES)}
    rows, loso_rows, roc = [], [], {}
    fitted = {}
    scenes = _uniq(s["scene"])
    for name, feats in models.items():
        m = _classifier(feats, seed).fit(X.iloc[idx_tr][feats], y[idx_tr])
        fitted[name] = m
        score = m.predict_proba(X.iloc[idx_te][feats])[:, 1]
        a = stats.auc(y[idx_te], score)
        fpr, tpr, _ = roc_curve(y[idx_te], score)
        roc[name] = (fpr, tpr, a)
        aucs = []
        if len(scenes) >= 2:
            for sc in scenes:
                te = (s["scene"] == sc).to_numpy()
                if y[~te].all() or not y[~te].any():
                    continue
                ms = _classifier(feats, seed).fit(X[~te][feats], y[~te])
                a_s = stats.auc(y[te], ms.predict_proba(X[te][feats])[:, 1])
                loso_rows.append(
                    {"model": name, "held_out_scene": sc, "n": int(te.sum()), "positives": int(y[te].sum()), "auc": a_s}
                )
                if np.isfinite(a_s):
                    aucs.append(a_s)
        rows.append(
            {
                "model": name,
                "features": ", ".join(feats),
                "auc_holdout": a,
                "loso_auc_mean": float(np.mean(aucs)) if aucs else np.nan,
                "loso_auc_min": float(np.min(aucs)) if aucs else np.nan,
                "n_train": len(idx_tr),
                "n_test": len(idx_te),
                "positives": npos,
            }
        )
    full = list(PREDICTION_FEATURES)
    pi = permutation_importance(
        fitted["field+bit+class+value"],
        X.iloc[idx_te][full],
        y[idx_te],
        scoring="roc_auc",
        n_repeats=n_repeats,
        random_state=seed,
    )
    imp = (
        pd.DataFrame({"feature": full, "importance_mean": pi.importances_mean, "importance_std": pi.importances_std})
        .sort_values("importance_mean", ascending=False)
        .reset_index(drop=True)
    )
    summary = _tag(pd.DataFrame(rows), s, precision=precision)
    _tag(imp, s, precision=precision)
    loso = _tag(pd.DataFrame(loso_rows, columns=["model", "held_out_scene", "n", "positives", "auc"]), s)
    return {
        "summary": summary,
        "importance": imp,
        "loso": loso,
        "top_feature": str(imp["feature"].iloc[0]),
        "roc": roc,
        "precision": precision,
    }


# ---------------------------------------------------------------------------------- figures


def _figure(w=6.4, h=4.0):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=110, layout="constrained")


def plot_field_bit_heatmap(table: pd.DataFrame, precisions: list[str] | None = None):
    """Mean footprint (% of frame, log10 colour scale) over field x bit, one panel per precision.
    Cells with zero mean footprint are drawn grey; unsampled cells white."""
    from matplotlib.colors import LogNorm

    precisions = precisions or [p for p in encoding.PRECISIONS if p in set(table["precision"])]
    mats = {p: heatmap_matrix(table, p) for p in precisions}
    vals = np.concatenate([m.to_numpy(float).ravel() for m in mats.values()]) if mats else []
    pos = np.asarray(vals)[np.isfinite(vals) & (np.asarray(vals) > 0)] if len(vals) else []
    vmin = max(float(np.min(pos)), 1e-6) if len(pos) else 1e-4
    vmax = max(float(np.max(pos)), vmin * 10) if len(pos) else 1.0
    fig = _figure(9.0, 1.9 + 1.9 * len(precisions))
    axes = fig.subplots(len(precisions), 1, squeeze=False)[:, 0]
    im = None
    for ax, p in zip(axes, precisions):
        m = mats[p]
        a = m.to_numpy(float)
        zero = np.isfinite(a) & (a <= 0)
        ax.imshow(np.where(zero, 1.0, np.nan), cmap="Greys", vmin=0, vmax=4, aspect="auto", interpolation="nearest")
        im = ax.imshow(
            np.ma.masked_where(~(a > 0), a),
            norm=LogNorm(vmin=vmin, vmax=vmax),
            cmap="magma",
            aspect="auto",
            interpolation="nearest",
        )
        ax.set_yticks(range(len(m.index)), [FIELD_LABELS.get(f, f) for f in m.index])
        nb = a.shape[1]
        step = 1 if nb <= 16 else 2
        ax.set_xticks(range(0, nb, step))
        ax.set_xticklabels([str(b) for b in range(0, nb, step)], fontsize=7)
        man, exp = encoding.LAYOUT.get(p, (nb - 9, 8))
        for x in (man - 0.5, man + exp - 0.5):
            ax.axvline(x, color="cyan", lw=0.8, ls=":")
        ax.set_title(f"{p}: mean footprint (% of frame, log scale); dotted: mantissa | exponent | sign", fontsize=8)
        ax.set_xlabel("bit position (0 = LSB)", fontsize=8)
    if im is not None:
        fig.colorbar(im, ax=list(axes), label="mean footprint (%)", shrink=0.9)
    return fig


def plot_precision_rates(rates: pd.DataFrame):
    """Catastrophe rate by field and precision, with Wilson intervals."""
    fig = _figure(7.0, 3.8)
    ax = fig.subplots()
    precs = [p for p in encoding.PRECISIONS if p in set(rates["precision"])] + sorted(
        set(rates["precision"]) - set(encoding.PRECISIONS)
    )
    fields = fields_present(rates)
    w = 0.8 / max(len(precs), 1)
    for i, p in enumerate(precs):
        g = rates[rates["precision"] == p].set_index("field").reindex(fields)
        x = np.arange(len(fields)) + (i - (len(precs) - 1) / 2) * w
        y = g["cat_rate_pct"].to_numpy(float)
        err = np.vstack([y - g["cat_ci_lo_pct"].to_numpy(float), g["cat_ci_hi_pct"].to_numpy(float) - y])
        ax.bar(x, y, w, label=p, yerr=np.nan_to_num(err), capsize=2)
    ax.set_xticks(range(len(fields)), [FIELD_LABELS.get(f, f) for f in fields])
    ax.set_ylabel("catastrophic upsets (%, 95% Wilson CI)")
    ax.legend(title="precision")
    return fig


def plot_theory(res: dict):
    t = res["table"]
    fig = _figure(5.6, 3.8)
    ax = fig.subplots()
    pos = t[t["mean_peak_error"] > 0]
    ax.semilogy(pos["bit"], pos["mean_peak_error"], "o-", base=2, label="measured mean peak error")
    fit = t[t["in_fit"]]
    if len(fit):
        xb = fit["bit"].to_numpy(float)
        ax.semilogy(
            xb,
            2.0 ** (res["slope"] * xb + res["intercept"]),
            "-",
            base=2,
            label=f"fit: {res['slope']:.3f} per bit (R$^2$={res['r2']:.3f})",
        )
        xc = xb.mean()
        yc = res["slope"] * xc + res["intercept"]
        ax.semilogy(xb, 2.0 ** (yc + (xb - xc)), "k--", base=2, lw=1, label="unit slope (perturbation lemma)")
    ax.set_xlabel(f"mantissa bit index ({res['field']}, {res['precision']})")
    ax.set_ylabel(r"mean peak error $|\Delta I|_\infty$")
    ax.legend(fontsize=8)
    return fig


def plot_guard_ccdf(df: pd.DataFrame, guard: str = "guard", precision: str | None = None):
    """Complementary CDF of the footprint with and without the guard (single upsets)."""
    s = single_upsets(df, precision, None)
    fig = _figure(5.6, 3.8)
    ax = fig.subplots()
    x = np.logspace(-5, 2, 200)
    for dfn, style in (("none", "-"), (guard, "--")):
        fp = np.sort(s.loc[s["defense"] == dfn, "footprint"].to_numpy(float) * 100)
        fp = fp[np.isfinite(fp)]
        if not fp.size:
            continue
        surv = 1.0 - np.searchsorted(fp, x, side="right") / fp.size
        ax.loglog(
            x,
            np.where(surv > 0, surv, np.nan),
            style,
            label=f"{DEFENSE_LABELS.get(dfn, dfn)} (n={fp.size:,})",
            drawstyle="steps-post",
        )
    ax.axvline(100 * CATASTROPHIC_FOOTPRINT, color="grey", ls=":", lw=1)
    ax.set_xlabel("footprint x (% of frame)")
    ax.set_ylabel("P(footprint > x)")
    ax.legend(fontsize=8)
    return fig


def plot_dose(curves: pd.DataFrame, threshold_db: float = BUDGET_PSNR_DB):
    """PSNR against k per precision (colour) and defense (none thin solid, guard bold dashed),
    medians with interquartile bands, means as dots."""
    fig = _figure(6.4, 4.0)
    ax = fig.subplots()
    colors = {"fp32": "C0", "fp16": "C1", "bf16": "C2"}
    styles = {
        "none": ("-", 1.2),
        "guard": ("--", 2.4),
        "selective": (":", 1.6),
        "ecc": ("-.", 1.2),
        "dup": ((0, (1, 1)), 1.2),
    }
    for (p, dfn), g in curves.groupby(["precision", "defense"], sort=False):
        g = g.sort_values("k")
        c = colors.get(p, None)
        ls, lw = styles.get(dfn, ("-", 1))
        ax.plot(g["k"], g["psnr_median_db"], ls=ls, lw=lw, color=c, label=f"{p} {DEFENSE_LABELS.get(dfn, dfn)}")
        ax.fill_between(g["k"], g["psnr_q25_db"], g["psnr_q75_db"], color=c, alpha=0.15, lw=0)
        ax.plot(g["k"], g["psnr_mean_db"], ".", color=c, ms=4)
    ax.axhline(threshold_db, color="grey", ls=":", lw=1)
    ax.set_xscale("log")
    ax.set_xlabel("simultaneous upsets k")
    ax.set_ylabel(f"PSNR (dB, clipped to [{PSNR_FLOOR_DB:g}, {PSNR_CAP_DB:g}])")
    ax.legend(fontsize=7)
    return fig


def plot_budget(budget: pd.DataFrame):
    fig = _figure(5.6, 3.8)
    ax = fig.subplots()
    # one line per scene when a scene was swept over sizes, else one across the scenes
    per_scene = (budget.groupby("scene")["n_primitives"].nunique() > 1).any()
    keys = ["scene", "precision", "defense"] if per_scene else ["precision", "defense"]
    for key, g in budget.groupby(keys, sort=False):
        g = g.sort_values("n_primitives")
        (line,) = ax.plot(g["n_primitives"], g["k_budget"], "-", label=" ".join(map(str, key)))
        cens = g["censored"] != ""
        ax.plot(g.loc[~cens, "n_primitives"], g.loc[~cens, "k_budget"], "o", color=line.get_color())
        ax.plot(g.loc[cens, "n_primitives"], g.loc[cens, "k_budget"], "^", mfc="none", color=line.get_color())
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("primitive count N")
    ax.set_ylabel(f"redundancy budget k ({budget.attrs.get('threshold_db', BUDGET_PSNR_DB):g} dB)")
    ax.legend(fontsize=7, title="open markers: censored (bound)", title_fontsize=7)
    return fig


def plot_size_scaling(res: dict):
    t = res["table"]
    fig = _figure(6.4, 4.0)
    ax = fig.subplots()
    for (sc, p, dfn), g in t.groupby(["scene", "precision", "defense"], sort=False):
        g = g.sort_values("n_primitives")
        for metric, ls in (("median_mse", "-"), ("mean_mse", "--")):
            y = g[metric].where(g[metric] > 0)
            ax.plot(g["n_primitives"], y, ls, marker="o", ms=3, label=f"{sc} {p} {dfn} {metric.split('_')[0]}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("primitive count N")
    ax.set_ylabel("single-upset frame MSE")
    ax.legend(fontsize=6)
    return fig


def plot_dose_model(dm: pd.DataFrame):
    """Measured catastrophic fraction (Wilson bars) and the dose model, one panel per defense."""
    defs = [x for x in DEFENSES if x in set(dm["defense"])] + sorted(set(dm["defense"]) - set(DEFENSES))
    fig = _figure(4.2 * max(len(defs), 1), 3.8)
    axes = fig.subplots(1, max(len(defs), 1), squeeze=False, sharey=True)[0]
    colors = {"fp32": "C0", "fp16": "C1", "bf16": "C2"}
    for ax, dfn in zip(axes, defs):
        for i, (p, g) in enumerate(dm[dm["defense"] == dfn].groupby("precision", sort=False)):
            g = g.sort_values("k")
            c = colors.get(p, f"C{i + 3}")
            err = np.vstack([g["measured_pct"] - g["measured_ci_lo_pct"], g["measured_ci_hi_pct"] - g["measured_pct"]])
            # stagger the precisions a little along k so the bars do not hide each other
            x = g["k"].to_numpy(float) * (1.0 + 0.08 * (i - 1))
            ax.errorbar(x, g["measured_pct"], yerr=err, fmt="o", ms=3, capsize=2, color=c, label=f"{p} measured")
            ax.plot(g["k"], g["model_pct"], "-", color=c, lw=1, label=f"{p} 1-(1-p_c)^k")
        ax.set_xscale("log")
        ax.set_title(DEFENSE_LABELS.get(dfn, dfn), fontsize=9)
        ax.set_xlabel("simultaneous upsets k")
        ax.legend(fontsize=6)
    axes[0].set_ylabel("catastrophic frames (%)")
    return fig


def plot_contamination(cont: pd.DataFrame, precision: str | None = None, defenses: tuple[str, ...] = ("none", "guard")):
    """Share of regions contaminated against P at one precision (fp32 by default), predicted
    (solid) and measured (dashed), for log-scale sign flips (all single upsets if none)."""
    fig = _figure(6.0, 3.8)
    ax = fig.subplots()
    sub = cont[cont["subset"] == "log-scale sign"]
    if sub.empty:
        sub = cont[cont["subset"] == "all single upsets"]
    if len(sub):
        precision = precision or reference_precision(sub)
        sub = sub[(sub["precision"] == precision)]
        if sub["defense"].isin(defenses).any():
            sub = sub[sub["defense"].isin(defenses)]
    for dfn, g in sub.groupby("defense", sort=False):
        g = g.sort_values("P")
        (line,) = ax.plot(
            g["P"], g["pred_fraction_pct"], "-o", ms=3, label=f"{DEFENSE_LABELS.get(dfn, dfn)}: predicted"
        )
        ax.plot(
            g["P"],
            g["meas_fraction_pct"],
            "--s",
            ms=3,
            color=line.get_color(),
            label=f"{DEFENSE_LABELS.get(dfn, dfn)}: measured",
        )
    ax.set_xscale("log", base=2)
    if len(sub):
        ps = sorted(set(sub["P"]))
        ax.set_xticks(ps, [str(p) for p in ps])
        ax.set_title(f"{sub['subset'].iloc[0]}, {precision}", fontsize=9)
    ax.set_ylim(-2, 102)
    ax.set_xlabel("regions P (sort-first partition)")
    ax.set_ylabel("regions contaminated (%)")
    ax.legend(fontsize=7)
    return fig


def plot_roc(res: dict):
    fig = _figure(4.6, 4.2)
    ax = fig.subplots()
    for name, (fpr, tpr, a) in res["roc"].items():
        ax.plot(fpr, tpr, label=f"{name} (AUC {a:.3f})")
    ax.plot([0, 1], [0, 1], "k:", lw=1)
    ax.set_xlabel("false positive rate")
    ax.set_ylabel("true positive rate")
    ax.legend(fontsize=7)
    return fig
