"""Validation of the perturbation lemma: a mantissa flip of bit b changes a value by 2^(e+b-p), so
the peak image error doubles per bit (unit slope in log2) until one primitive saturates the pixels
it covers. Mean peak errors per bit are weighted means (`analysis.estimate`)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis import stats
from seuwgpu.analysis.records import (
    InsufficientData,
    figure,
    n_records,
    record_weights,
    reference_precision,
    require_single,
    tag,
)
from seuwgpu.model import encoding

THEORY_FIT_RANGE = (1e-5, 0.1)  # peak-error window of the mantissa-slope fit (see theory_check)


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
    s = require_single(df, defense)
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
    rows = []
    for bit, g in d.groupby("bit"):
        v, w = g["peak_error"].to_numpy(float), record_weights(g)
        rows.append(
            {
                "bit": bit,
                "n": n_records(g),
                "mean_peak_error": E.wmean(v, w),
                "median_peak_error": E.wquantile(v, w, 0.5),
            }
        )
    t = pd.DataFrame(rows)
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
    tag(t, d, precision=precision)
    return {
        "table": t,
        "slope": fit.slope,
        "intercept": fit.intercept,
        "r2": fit.r2,
        "slope_lo": fit.slope_lo,
        "slope_hi": fit.slope_hi,
        "fit_bits": (int(bits_used.min()), int(bits_used.max())),
        "n_fit_bits": int(use.sum()),
        "predicted_slope": 1.0,
        "precision": precision,
        "field": field,
        "fit_range": fit_range,
        "note": note,
    }


def plot_theory(res: dict):
    t = res["table"]
    fig = figure(5.6, 3.8)
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


def slope_windows(res: dict) -> pd.DataFrame:
    """The mantissa slope over other fit windows of `theory_check`'s table: the default window
    with its top bit in and out, and that window shortened from below and from above, so a reader
    sees how much the slope (and the verdict set on it) rests on the window's edges (bit 22, the
    top mantissa bit of fp32, sits above the trend where one primitive starts to saturate)."""
    t = res["table"]
    ok = t[np.isfinite(t["log2_mean_peak_error"])]
    lo, hi = res["fit_bits"]
    windows = [("default (error in the fit range)", lo, hi)]
    for a, b in ((lo, hi - 1), (lo, hi - 2), (lo + 2, hi), (lo + 2, hi - 1), (lo - 1, hi), (lo - 1, hi - 1)):
        if b - a >= 2:
            windows.append((f"bits {a}..{b}", a, b))
    rows = []
    for name, a, b in windows:
        w = ok[(ok["bit"] >= a) & (ok["bit"] <= b)]
        if w["bit"].nunique() < 3:
            continue
        f = stats.linear_fit(w["bit"], w["log2_mean_peak_error"])
        rows.append(
            {
                "window": name,
                "fit_bits": f"{a}..{b}",
                "n_fit_bits": len(w),
                "top_bit_in": bool(b >= hi),
                "slope": f.slope,
                "slope_lo": f.slope_lo,
                "slope_hi": f.slope_hi,
                "r2": f.r2,
            }
        )
    out = pd.DataFrame(rows)
    out.attrs.update(t.attrs)  # the provenance of the records the table rests on
    return out


# ---- claims rows (analysis.claims gathers them) ----------------------------------------------------


def theory_windows(res: dict) -> pd.DataFrame:
    """The mantissa slope over several fit windows (`slope_windows`) with the verdict each would
    give against the paper's 0.94 and its margin (`population.claim_verdict`, interval over bits)."""
    from seuwgpu.analysis.paper import PAPER, margin_text
    from seuwgpu.analysis.population import claim_verdict

    w = slope_windows(res)
    if w.empty:
        return w
    w["paper"] = PAPER["theory_slope"][2]
    w["margin"] = margin_text("theory_slope")
    w["verdict"] = [claim_verdict("theory_slope", lo, hi) for lo, hi in zip(w["slope_lo"], w["slope_hi"])]
    return w


def slope_row(th: dict | None) -> dict:
    """The mantissa-slope headline: its value is the default window's; its verdict is the windows'
    majority ("reproduced" needs more than half of the windows to reproduce, "differs" more than half
    to differ; else "inconclusive"), so the verdict does not rest on where one window's edge falls."""
    from seuwgpu.analysis.claimrows import row

    if th is None or th.get("precision") != "fp32":
        return row("theory_slope")
    r = row(
        "theory_slope",
        th["slope"],
        th["slope_lo"],
        th["slope_hi"],
        f"{th['n_fit_bits']} bits ({th['fit_bits'][0]}..{th['fit_bits'][1]}); other windows in claims_theory_windows",
    )
    w = theory_windows(th) if "table" in th else pd.DataFrame()
    if len(w) and r["verdict"] in ("reproduced", "differs", "inconclusive"):
        counts = w["verdict"].value_counts()
        n = len(w)
        rep, dif = int(counts.get("reproduced", 0)), int(counts.get("differs", 0))
        verdict = "reproduced" if rep > n / 2 else "differs" if dif > n / 2 else "inconclusive"
        r = r | {
            "verdict": verdict,
            "basis": f"{r['basis']}; verdict over the {n} fit windows: {rep} reproduce, {dif} differ "
            f"(the default window alone: {r['verdict']})",
        }
    return r
