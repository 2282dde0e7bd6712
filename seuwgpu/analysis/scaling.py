"""Single-upset error against primitive count N (the paper's sigma^2(N) = Theta(N^-alpha)).

Uses k = 1 records of campaign "size" (else of campaign "dose", whose k = 1 draws are uniform).
Per (scene, precision, defense, N), weighted over the stored bits (`analysis.estimate`):
* mean frame MSE over finite frames (from the display-referred PSNR, peak 1; identical frames
  count 0), with the share of non-finite frames beside it;
* median frame MSE, non-finite frames ranked highest (worse than any finite frame).
A zero median (most upsets leave the frame identical) has no logarithm: such points are shown
in the table and figure (in_fit = False), not silently dropped, and the fit says how many it used.
Fits are least squares in log-log space with a Student-t interval on the exponent; alpha =
-exponent. At least three sizes with a positive value are needed (two points fit any line
exactly); with fewer the exponent is NaN.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis import stats
from seuwgpu.analysis.records import InsufficientData, fields_present, figure, prepare, sort_rows, tag

METRICS = ("mean_mse", "median_mse", "mean_footprint_pct")
MIN_SIZES = 3  # sizes with a positive value needed for a fit (two points fit any line exactly)


def size_scaling(df: pd.DataFrame, conf: float = 0.95) -> dict:
    """Returns {"table", "fits", "guard_factor", "source_campaign", "fields", "bits"}: the last two
    are what the upsets sampled (the error is over those, not over every stored bit)."""
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
    rows = []
    for key, g in d.groupby(["scene", "precision", "defense", "n_primitives"], sort=False):
        w = g["weight"].to_numpy(float)
        bad = g["nonfinite"].to_numpy(bool)
        mse = E.mse_of_psnr(g["psnr"].to_numpy(float))
        ranked = np.where(bad, np.inf, mse)
        foot = g["footprint"].to_numpy(float)
        rows.append(
            {
                "scene": key[0],
                "precision": key[1],
                "defense": key[2],
                "n_primitives": int(key[3]),
                "n": len(g),
                "nonfinite_pct": 100 * float(np.sum(w[bad]) / np.sum(w)),
                "mean_mse": E.wmean(np.where(bad, np.nan, mse), w),
                "median_mse": E.wquantile(ranked, w, 0.5),
                "mean_footprint_pct": 100 * E.wmean(foot, w),
                "median_footprint_pct": 100 * E.wquantile(foot, w, 0.5),
            }
        )
    table = sort_rows(pd.DataFrame(rows).sort_values(["scene", "n_primitives"]))
    tag(table, d, source_campaign=src)
    frows = []
    for key, g in table.groupby(["scene", "precision", "defense"], sort=False):
        for metric in METRICS:
            y = g[metric].to_numpy(float)
            usable = np.isfinite(y) & (y > 0)
            if usable.sum() >= MIN_SIZES:
                f = stats.loglog_fit(g["n_primitives"], y, conf)
            else:  # a line through two points fits whatever they are: no exponent, not a made-up one
                f = stats.PowerFit(np.nan, np.nan, np.nan)
            frows.append(
                {
                    "scene": key[0],
                    "precision": key[1],
                    "defense": key[2],
                    "metric": metric,
                    "n_sizes": len(g),
                    "n_fitted": int(usable.sum()),
                    "n_zero": int((y == 0).sum()),
                    "exponent": f.exponent,
                    "exponent_lo": f.exponent_lo,
                    "exponent_hi": f.exponent_hi,
                    "alpha": -f.exponent,
                    "alpha_lo": -f.exponent_hi,
                    "alpha_hi": -f.exponent_lo,
                    "r2": f.r2,
                }
            )
    fits = tag(sort_rows(pd.DataFrame(frows)), d)
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
                    "guard_factor": float(a.iloc[0] / b.iloc[0]) if b.iloc[0] > 0 else np.nan,
                }
            )
    gf = tag(pd.DataFrame(grows), d)
    sampled = {"fields": fields_present(d), "bits": sorted(int(b) for b in d["bit"].unique())}
    return {"table": table, "fits": fits, "guard_factor": gf, "source_campaign": src, **sampled}


def plot_size_scaling(res: dict, metric: str = "mean_mse"):
    """`metric` against N per scene, precision and defense (log-log; colour: scene and precision,
    marker and line: defense) with the fitted power law; zero values, which have no logarithm,
    are drawn as open triangles at the panel's foot. The legend sits below the axes (it hid the
    smallest values)."""
    from matplotlib.lines import Line2D

    from seuwgpu.analysis.dose import series_styles
    from seuwgpu.faults.defenses import defense_label

    t = res["table"]
    fits = res["fits"]
    groups = list(t.groupby(["scene", "precision", "defense"], sort=False))
    colors, lines = series_styles([k for k, _ in groups])
    fig = figure(7.0, 3.6 + 0.22 * (len(groups) + 2))
    ax = fig.subplots()
    pos = t[metric][(t[metric] > 0) & np.isfinite(t[metric])]
    foot = float(pos.min()) / 3 if len(pos) else 1e-12
    fitted = []
    any_zero = False
    for key, g in groups:
        g = g.sort_values("n_primitives")
        c, ls = colors[tuple(key[:-1])], lines[key[-1]]
        marker, mfc = ("o", c) if key[-1] == "none" else ("s", "white")
        y = g[metric].to_numpy(float)
        ok = np.isfinite(y) & (y > 0)
        f = fits[
            (fits["scene"] == key[0])
            & (fits["precision"] == key[1])
            & (fits["defense"] == key[2])
            & (fits["metric"] == metric)
        ]
        lab = f"{key[0]} {key[1]} {defense_label(key[2])}"
        if len(f) and np.isfinite(f["alpha"].iloc[0]):
            r = f.iloc[0]
            ci = f" [{r['alpha_lo']:.2f}, {r['alpha_hi']:.2f}]" if np.isfinite(r["alpha_lo"]) else " (2 points: exact)"
            lab += f": alpha {r['alpha']:.2f}{ci}"
            xx = g["n_primitives"].to_numpy(float)
            b = r["exponent"]
            a0 = np.mean(np.log10(y[ok]) - b * np.log10(xx[ok]))
            ax.plot(xx, 10**a0 * xx**b, ls, color=c, lw=1)
        else:
            lab += ": no fit"
        fitted.append(Line2D([], [], color=c, ls=ls, marker=marker, mfc=mfc, ms=4, label=lab))
        ax.plot(g["n_primitives"][ok], y[ok], marker, color=c, mfc=mfc, ms=4)
        zero = y == 0
        if zero.any():
            any_zero = True
            ax.plot(g["n_primitives"][zero], np.full(zero.sum(), foot), "v", mfc="none", color=c, ms=6)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("primitive count N")
    what = {"mean_mse": "mean frame MSE (peak 1)", "median_mse": "median frame MSE (peak 1)"}
    ax.set_ylabel(f"single-upset {what.get(metric, metric.replace('_', ' '))}")
    if any_zero:
        fitted.append(Line2D([], [], color="0.3", ls="", marker="v", mfc="none", ms=6, label="zero (no logarithm)"))
    fig.legend(
        handles=fitted,
        loc="outside lower center",
        ncols=2,
        fontsize=7,
        title="fitted power law N^-alpha, 95% t interval",
        title_fontsize=7,
    )
    return fig
