"""Reliability under realistic upset rates: p_c, the probability that one upset uniform over the
stored bits is catastrophic, and the mean time between catastrophic frames (MTBF) with upsets
accumulating between scrubs.

* p_c per (precision, defense): the weighted rate of the single-upset campaign
  (`estimate.rate`, stratified interval), and per model the dose fit's p (`dose.dose_fits`: the
  per-upset probability that best explains catastrophes of k accumulated upsets, which includes
  upsets that are harmless alone but not together).
* Accumulation: upsets arrive as a Poisson process of rate L = lambda * b (per-bit rate times
  stored bits) and stay until the next scrub (every T hours), when the model is restored. Under
  the dose model the first catastrophic state after a scrub comes at rate L * p, so an interval
  sees a catastrophic frame with probability q = 1 - exp(-L p T), the mean time between such
  intervals is MTBF = T / q (-> 1 / (L p) for frequent scrubs, -> T when every interval is hit),
  and the share of frames that are catastrophic is 1 - (1 - exp(-x)) / x with x = L p T.
* Upset rates and the scrub interval are spec parameters ([reliability] rates = [...],
  scrub_hours = ...); the defaults below name their sources. They are orders of magnitude, so the
  sensitivity figure shows the MTBF over the whole range of rates.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import (
    DEFAULT_SH_DEGREE,
    InsufficientData,
    figure,
    prepare,
    provenance,
    reference_precision,
    sh_degree_of,
    single_upsets,
    sort_rows,
    tag,
)
from seuwgpu.model import encoding
from seuwgpu.model.fields import field_components, n_components

DEFAULT_SCRUB_HOURS = 24.0  # assumption: a daily scrub (reload) of the model from protected storage

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


def format_duration(hours: float) -> str:
    """Human-readable duration: s, min, h, d or yr; "inf" for an unbounded one, "n/a" for an
    undefined one (NaN: no rate measured)."""
    if hours is None or np.isnan(hours):
        return "n/a"
    if not np.isfinite(hours):
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


def reliability_parameters(manifests: Iterable[dict] = ()) -> tuple[list[dict], float, str]:
    """(rates, scrub_hours, where they came from): the runs' [reliability] table, else defaults."""
    for m in manifests or ():
        t = (m.get("spec") or {}).get("reliability")
        if isinstance(t, dict):
            rates = t.get("rates") or list(UPSET_RATES)
            return list(rates), float(t.get("scrub_hours", DEFAULT_SCRUB_HOURS)), "run spec [reliability]"
    return list(UPSET_RATES), DEFAULT_SCRUB_HOURS, "defaults (sources in the table)"


def catastrophe_probability(df: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """p_c per (precision, defense) from the single-upset campaign: weighted rate over the stored
    bits of every scene, with the stratified interval; coverage_pct is the share of each scene's
    stored bits whose (field, bit) cells were sampled."""
    s = single_upsets(prepare(df), None, None)
    s = s[s["bit"] >= 0]
    if s.empty:
        raise InsufficientData(
            "no single-upset records to estimate p_c", "run a single-upset campaign over all fields and bits"
        )
    r = E.rate(s, "catastrophic", ["precision", "defense"], conf)
    deg = sh_degree_of(s)
    cov = []
    for (prec, dfn), g in s.groupby(["precision", "defense"], sort=False):
        have = g.groupby(["scene", "n_primitives", "field", "bit"]).size().reset_index()
        bits = encoding.BITS.get(prec, 32)
        comps = have["field"].map(lambda f: field_components(f, deg)).sum()
        per_scene = have.groupby(["scene", "n_primitives"]).ngroups
        cov.append(
            {"precision": prec, "defense": dfn, "coverage_pct": 100 * comps / (per_scene * n_components(deg) * bits)}
        )
    out = r.rename(columns={"rate": "p_c"}).merge(pd.DataFrame(cov), on=["precision", "defense"])
    out["sh_degree"] = deg
    return tag(sort_rows(out), s)


def pc_lookup(pc: pd.DataFrame, precision: str, defense: str):
    g = pc[(pc["precision"] == precision) & (pc["defense"] == defense)]
    return None if g.empty else g.iloc[0]


def model_bits(df: pd.DataFrame, precision: str, sh_degree: int = DEFAULT_SH_DEGREE) -> float:
    """Stored bits of the deployed model(s): the mean over scenes of the largest primitive count
    of the single-upset campaign (size campaigns subsample) x components x bits per value."""
    d = prepare(df)
    single = d[d["campaign"] == "single"]
    d = single if len(single) else d
    n = d.groupby("scene")["n_primitives"].max().mean()
    return float(n) * n_components(sh_degree) * encoding.BITS[precision]


def mtbf(rate_per_bit_hour: float, bits: float, p: float, scrub_hours: float) -> float:
    """Mean time (h) between scrub intervals that hold a catastrophic frame (module notes);
    inf when p = 0; 1 / (L p) without scrubbing (scrub_hours = inf); NaN when p is (unmeasured)."""
    lam = float(rate_per_bit_hour) * float(bits) * float(p)
    if math.isnan(lam):
        return float("nan")
    if not lam > 0:
        return float("inf")
    if not math.isfinite(scrub_hours):
        return 1.0 / lam
    x = lam * scrub_hours
    return scrub_hours / -math.expm1(-x)


def catastrophic_frame_share(rate_per_bit_hour: float, bits: float, p: float, scrub_hours: float) -> float:
    """Share of frames that are catastrophic, upsets accumulating over a scrub interval (NaN when
    p is: undefined stays undefined)."""
    x = float(rate_per_bit_hour) * float(bits) * float(p) * scrub_hours
    if math.isnan(x):
        return float("nan")
    if not x > 0:
        return 0.0
    if not math.isfinite(x):
        return 1.0
    return 1.0 - (-math.expm1(-x)) / x


def mtbf_table(
    pc: pd.DataFrame,
    bits: float,
    precision: str,
    rates=UPSET_RATES,
    scrub_hours: float = DEFAULT_SCRUB_HOURS,
    defenses: tuple[str, ...] = ("none", "guard"),
    dose_p: dict | None = None,
) -> pd.DataFrame:
    """MTBF per environment and defense from p_c (single-upset, stratified) and, where given,
    from the dose fit (dose_p[defense] = (p, lo, hi) as proportions); bounds from the p interval
    (no event: unbounded above)."""
    rows = []
    sources = []
    for dfn in defenses:
        ref = pc_lookup(pc, precision, dfn)
        if ref is not None:
            sources.append((dfn, "single-upset p_c", float(ref["p_c"]), float(ref["ci_lo"]), float(ref["ci_hi"])))
        if dose_p and dfn in dose_p:
            sources.append((dfn, "dose fit p", *map(float, dose_p[dfn])))
    for env in rates:
        lam = float(env["per_bit_hour"])
        for dfn, src, p, lo, hi in sources:
            t, t_lo, t_hi = (mtbf(lam, bits, x, scrub_hours) for x in (p, hi, lo))
            rows.append(
                {
                    "environment": env["environment"],
                    "upsets_per_bit_hour": lam,
                    "fit_per_mbit": lam * 1e15,
                    "defense": dfn,
                    "p_source": src,
                    "p_pct": 100 * p,
                    "scrub_hours": scrub_hours,
                    "mtbf_hours": t,
                    "mtbf_hours_lo": t_lo,
                    "mtbf_hours_hi": t_hi,
                    "mtbf": format_duration(t) if p != 0 else f"> {format_duration(t_lo)}",  # NaN: n/a
                    "mtbf_range": f"{format_duration(t_lo)} .. {format_duration(t_hi)}",
                    "catastrophic_frames_pct": 100 * catastrophic_frame_share(lam, bits, p, scrub_hours),
                    "source": env.get("source", ""),
                }
            )
    out = pd.DataFrame(rows)
    out.attrs.update(pc.attrs)
    out.attrs.update(precision=precision, model_bits=bits)
    return out


def reliability(
    df: pd.DataFrame,
    manifests: Iterable[dict] = (),
    bits: float | None = None,
    precision: str | None = None,
    conf: float = 0.95,
    dose_fits: pd.DataFrame | None = None,
) -> dict:
    """p_c, the MTBF table (rates and scrub interval from the runs' spec or the defaults) and the
    inputs of the sensitivity figure. Returns {"pc", "mtbf", "mtbf_wide", "bits", "precision",
    "scrub_hours", "rates", "rates_from", "dose_p", "notes"}."""
    manifests = list(manifests or ())
    pc = catastrophe_probability(df, conf)
    notes = []
    precision = precision or reference_precision(pc)
    deg = int(pc["sh_degree"].iloc[0])
    if bits is None:
        bits = model_bits(df, precision, deg)
    rates, scrub, rates_from = reliability_parameters(manifests)
    dose_p = {}
    if dose_fits is not None and len(dose_fits):
        f = dose_fits[dose_fits["precision"] == precision]
        for dfn, g in f.groupby("defense"):
            # the largest model's fit stands for the deployed model
            r = g.sort_values("n_primitives").iloc[-1]
            if np.isfinite(r["p_pct"]):
                dose_p[dfn] = (r["p_pct"] / 100, r["p_lo_pct"] / 100, r["p_hi_pct"] / 100)
    for _, r in pc[pc["coverage_pct"] < 99.999].iterrows():
        notes.append(
            f"p_c at {r['precision']}/{r['defense']} covers only "
            f"{r['coverage_pct']:.1f}% of the stored bits (unsampled cells excluded)"
        )
    mt = mtbf_table(pc, bits, precision, rates, scrub, dose_p=dose_p)
    d = prepare(df)
    used = d[(d["precision"] == precision) & d["defense"].isin(["none", "guard"]) & (d["k"] >= 1)]
    mt.attrs["provenance"] = provenance(used)
    wide = None
    if len(mt):
        mt2 = mt.assign(col=mt["defense"] + " (" + mt["p_source"] + ")")
        wide = mt2.pivot_table(index="environment", columns="col", values="mtbf", aggfunc="first", sort=False)
        wide = wide.reset_index()
        wide.columns.name = None
        wide.attrs.update(mt.attrs)
    return {
        "pc": pc,
        "mtbf": mt,
        "mtbf_wide": wide,
        "bits": bits,
        "precision": precision,
        "scrub_hours": scrub,
        "rates": rates,
        "rates_from": rates_from,
        "dose_p": dose_p,
        "notes": notes,
    }


def plot_sensitivity(res: dict):
    """MTBF against the per-bit upset rate (log-log), per defense and p source, with the band from
    the p interval; vertical lines mark the named environments."""
    fig = figure(6.4, 4.2)
    ax = fig.subplots()
    lam = np.logspace(-16, -6, 120)
    bits, scrub = res["bits"], res["scrub_hours"]
    mt = res["mtbf"]
    i = 0
    for (dfn, src), g in mt.groupby(["defense", "p_source"], sort=False):
        r = g.iloc[0]
        p = r["p_pct"] / 100
        c = f"C{i}"
        i += 1
        y = np.array([mtbf(x, bits, p, scrub) for x in lam])
        lo_p = hi_p = None
        if src == "single-upset p_c":
            ref = pc_lookup(res["pc"], res["precision"], dfn)
            lo_p, hi_p = float(ref["ci_lo"]), float(ref["ci_hi"])
        elif dfn in res["dose_p"]:
            lo_p, hi_p = res["dose_p"][dfn][1], res["dose_p"][dfn][2]
        ls = "-" if src.startswith("single") else "--"
        ax.plot(lam, np.where(np.isfinite(y), y, np.nan), ls, color=c, label=f"{dfn}, {src}")
        if lo_p is not None:
            a = np.array([mtbf(x, bits, hi_p, scrub) for x in lam])
            b = np.array([mtbf(x, bits, lo_p, scrub) for x in lam])
            ax.fill_between(lam, a, np.where(np.isfinite(b), b, 1e12), color=c, alpha=0.12, lw=0)
    for env in res["rates"]:
        ax.axvline(float(env["per_bit_hour"]), color="grey", ls=":", lw=0.8)
        ax.text(float(env["per_bit_hour"]), 1e-2, env["environment"], rotation=90, fontsize=6, va="bottom")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(1e-3, 1e10)
    ax.set_xlabel("upset rate per stored bit per hour")
    ax.set_ylabel(f"MTBF of catastrophic frames (h), scrub every {scrub:g} h")
    ax.legend(fontsize=6)
    return fig
