"""The support guard against no defense on the same fault sites (single-upset campaign, records
paired by fault site: records.pair_columns). Rates and shares are weighted (`analysis.estimate`); PSNR summaries are
over frames without non-finite pixels, with the non-finite share beside them."""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import (
    MULTIPLICITY,
    NONE_CATASTROPHIC,
    PROVENANCE_COLUMNS,
    SITE_DEFENSES,
    InsufficientData,
    figure,
    n_records,
    pair_columns,
    record_weights,
    scale_sign_flips,
    single_upsets,
    sort_rows,
    tag,
)
from seuwgpu.faults.defenses import defense_label

GUARD_COLUMNS = (
    *PROVENANCE_COLUMNS,
    "bit_class",
    "catastrophic",
    "footprint",
    "weight",
    "nonfinite",
    "psnr",
    "ssim",
    "lpips",
    "injection_id",
    MULTIPLICITY,
    NONE_CATASTROPHIC,
    SITE_DEFENSES,
)


def guard_analysis(df: pd.DataFrame, guard: str = "guard", conf: float = 0.95) -> dict:
    """Returns {"summary": per (precision, defense) weighted footprint stats and catastrophe rate,
    "paired": per precision (+ "all"): pairs, catastrophic without guard, weighted share of them
    neutralised with its interval, residual catastrophic, of which catastrophic under both arms
    (catastrophic_both) and turned catastrophic by the guard (turned_catastrophic: not catastrophic
    without it; `turned_catastrophic`), worst guarded footprint,
    "sign_psnr": log-scale sign flips: PSNR without and with the guard over finite frames and the
    non-finite share, "worst_guarded_footprint_pct", "residual_catastrophic", "n_guarded",
    "share_pct", "share_ci"}."""
    s = single_upsets(df, None, None)
    # the columns read here (a lazy selection: the filters below then copy only these)
    s = s[[c for c in s.columns if c in GUARD_COLUMNS or c in E.STRATA]]
    s = s[s["defense"].isin(["none", guard])]
    if not (s["defense"] == guard).any():
        raise InsufficientData(
            f"no single-upset records with defense '{guard}'",
            f"run the single-upset campaign with defenses none,{guard}",
        )
    s = pair_columns(s)
    p = s[(s["defense"] == guard) & s[NONE_CATASTROPHIC].notna()]
    if p.empty:
        raise InsufficientData(
            f"no fault sites measured both without and with '{guard}'",
            f"run the single-upset campaign with defenses none,{guard} (same injection ids)",
        )
    r = E.percent(E.rate(s, "catastrophic", ["precision", "defense"], conf)).rename(columns={"events": "catastrophic"})
    extra = []
    for (prec, dfn), g in s.groupby(["precision", "defense"], sort=False):
        fp, w = g["footprint"].to_numpy(float) * 100, record_weights(g)
        extra.append(
            {
                "precision": prec,
                "defense": dfn,
                "mean_footprint_pct": E.wmean(fp, w),
                "p99_footprint_pct": E.wquantile(fp, w, 0.99),
                "max_footprint_pct": float(np.nanmax(fp)),
            }
        )
    summary = r.drop(columns=["weight", "n_eff", "method"]).merge(pd.DataFrame(extra), on=["precision", "defense"])
    summary = tag(sort_rows(summary), s)

    # the guarded records of sites also measured without it: neutralised = catastrophic without
    # the guard, not with it (weights are the site's, the same under both)
    p = p.assign(_neut=(p[NONE_CATASTROPHIC] == 1) & ~p["catastrophic"].astype(bool))
    groups = [(prec, g) for prec, g in p.groupby("precision", sort=False)]
    if len(groups) > 1:
        groups.append(("all", p))
    prow = []
    for prec, g in groups:
        cat = g[g[NONE_CATASTROPHIC] == 1]
        sh = E.one_rate(cat, "_neut", conf) if len(cat) else {"rate": np.nan, "ci_lo": np.nan, "ci_hi": np.nan}
        prow.append(
            {
                "precision": prec,
                "pairs": n_records(g),
                "catastrophic_none": n_records(cat),
                "neutralised": n_records(cat[cat["_neut"]]),
                "share_neutralised_pct": 100 * sh["rate"],
                "share_ci_lo_pct": 100 * sh["ci_lo"],
                "share_ci_hi_pct": 100 * sh["ci_hi"],
                "residual_catastrophic": n_records(g[g["catastrophic"].astype(bool)]),
                **turned_catastrophic(g),
                "worst_guarded_footprint_pct": 100 * float(g["footprint"].max()),
            }
        )
    ptab = tag(sort_rows(pd.DataFrame(prow)), s)

    sign = scale_sign_flips(s)
    stab = pd.DataFrame()
    if len(sign):
        q = E.quality(sign, ["precision", "defense"], conf)
        stab = q[
            [
                "precision",
                "defense",
                "n",
                "nonfinite_pct",
                "psnr_median_db",
                "psnr_mean_mse_db",
                "ssim_mean",
                "mean_footprint_pct",
            ]
        ]
        stab = sort_rows(stab)
    tag(stab, sign)

    allg = s[s["defense"] == guard]
    tot = ptab[ptab["precision"] == "all"] if (ptab["precision"] == "all").any() else ptab
    return {
        "summary": summary,
        "paired": ptab,
        "sign_psnr": stab,
        "worst_guarded_footprint_pct": 100 * float(allg["footprint"].max()),
        "residual_catastrophic": n_records(allg[allg["catastrophic"].astype(bool)]),
        "n_guarded": n_records(allg),
        "turned_catastrophic": int(tot["turned_catastrophic"].iloc[0]) if len(tot) else 0,
        "catastrophic_both": int(tot["catastrophic_both"].iloc[0]) if len(tot) else 0,
        # the pooled row ("all": every precision, weighted by stored bits) or the one precision
        "share_precision": str(tot["precision"].iloc[0]) if len(tot) else "",
        "share_pct": float(tot["share_neutralised_pct"].iloc[0]) if len(tot) else np.nan,
        "share_ci": (float(tot["share_ci_lo_pct"].iloc[0]), float(tot["share_ci_hi_pct"].iloc[0]))
        if len(tot)
        else (np.nan, np.nan),
    }


def turned_catastrophic(paired: pd.DataFrame) -> dict:
    """Of guarded records paired with the same site without the guard (NONE_CATASTROPHIC set): how
    many are catastrophic under both arms, how many the guard turned catastrophic (not without it),
    and the weighted share of the paired sites so turned (%). A guard that clamps a value into the
    box can itself make a catastrophe: the residual is not only what it failed to neutralise."""
    cat = paired["catastrophic"].astype(bool).to_numpy()
    was = (paired[NONE_CATASTROPHIC] == 1).to_numpy()
    w = record_weights(paired)
    total = float(w.sum())
    return {
        "catastrophic_both": n_records(paired[cat & was]),
        "turned_catastrophic": n_records(paired[cat & ~was]),
        "turned_share_pct": 100 * float(w[cat & ~was].sum()) / total if total > 0 else np.nan,
    }


def plot_guard_ccdf(df: pd.DataFrame, guard: str = "guard", precision: str | None = None, threshold: float = 0.01):
    """Weighted complementary CDF of the footprint with and without the guard (single upsets):
    the probability that a uniform upset's footprint exceeds x."""
    s = single_upsets(df, precision, None)
    fig = figure(5.6, 3.8)
    ax = fig.subplots()
    x = np.logspace(-5, 2, 200)
    for dfn, style in (("none", "-"), (guard, "--")):
        g = s[(s["defense"] == dfn) & np.isfinite(s["footprint"])]
        if g.empty:
            continue
        fp, w = g["footprint"].to_numpy(float) * 100, record_weights(g)
        order = np.argsort(fp)
        fp, cw = fp[order], np.cumsum(w[order]) / w.sum()
        surv = 1.0 - np.concatenate([[0.0], cw])[np.searchsorted(fp, x, side="right")]
        ax.loglog(
            x,
            np.where(surv > 1e-12, surv, np.nan),
            style,
            label=f"{defense_label(dfn)} (n={n_records(g):,})",
            drawstyle="steps-post",
        )
    ax.axvline(100 * threshold, color="grey", ls=":", lw=1)
    ax.set_xlabel("footprint x (% of frame)")
    ax.set_ylabel("P(footprint > x), uniform upset")
    ax.legend(fontsize=8)
    return fig


# ---- claims rows (analysis.claims gathers them) ----------------------------------------------------


def guard_rows(df: pd.DataFrame, results: dict, conf: float = 0.95, arms=("guard",)) -> list[dict]:
    """Sign-flip PSNR without and with each guard arm, the worst guarded footprint (a maximum:
    compared at the paper's number of upsets only, `claimrows.tail_row`) and the residual share."""
    from seuwgpu.analysis.claimrows import over_models, per_model, row, tail_row
    from seuwgpu.analysis.paper import PAPER_GUARDED_SITES
    from seuwgpu.analysis.stats import wilson_interval

    rows = []
    s = single_upsets(df, "fp32", None)
    sign = scale_sign_flips(s)

    def psnr(x):
        return float(E.quality(x)["psnr_mean_mse_db"].iloc[0])

    for dfn in ("none",) + tuple(arms):
        g = sign[sign["defense"] == dfn]
        key = "sign_psnr_none" if dfn == "none" else "sign_psnr_guard"
        kw = {} if dfn == "none" else {"guard": dfn}
        if g.empty:
            rows.append(row(key, **kw))
            continue
        nf = float(E.quality(g)["nonfinite_pct"].iloc[0])
        basis = (
            f"n = {n_records(g):,}; the paper's 'mean global PSNR' read as the PSNR of the weighted mean MSE over "
            f"the finite frames ({nf:.3g}% non-finite)"
        )
        rows.append(over_models(key, per_model(g, psnr), "v", basis, conf, (psnr(g), np.nan, np.nan), 1.0, **kw))
    for arm in arms:
        allg = single_upsets(df, "fp32", arm)  # the paper's 768,000 guarded sites are fp32, never a pool of precisions
        if allg.empty:
            rows += [row("guard_worst_footprint", guard=arm), row("guard_residual_share", guard=arm)]
            continue
        n = n_records(allg)
        fp = 100 * allg["footprint"].to_numpy(float)
        if MULTIPLICITY in allg:  # folded rows: each stands for its records
            fp = np.repeat(fp, allg[MULTIPLICITY].to_numpy(int))
        rows.append(
            tail_row(
                "guard_worst_footprint",
                fp,
                f"n = {n:,} guarded upsets, fp32 (paper: {PAPER_GUARDED_SITES:,})",
                float(np.nanmax(fp)),
                guard=arm,
            )
        )
        k = n_records(allg[allg["catastrophic"].astype(bool)])
        lo, hi = wilson_interval(k, n, conf) if n else (np.nan, np.nan)
        gd = results.get("guard") if arm == "guard" else None
        split = ""
        if gd is not None and "catastrophic_both" in gd:
            split = (
                f"; of the residual on paired sites: {gd['catastrophic_both']:,} catastrophic without the guard "
                f"too, {gd['turned_catastrophic']:,} turned catastrophic by it"
            )
        rows.append(
            over_models(
                "guard_residual_share",
                per_model(allg, lambda g: n_records(g[g["catastrophic"].astype(bool)]) / max(n_records(g), 1)),
                "v",
                f"{k:,} residual of {n:,} guarded upsets, every precision, counted over the sites (unweighted, as "
                f"the paper's count){split}; pooled: Wilson",
                conf,
                (100 * k / n, 100 * lo, 100 * hi) if n else None,
                guard=arm,
            )
        )
    return rows
