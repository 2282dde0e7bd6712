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

The median is fitted only where it rises above the 8-bit floor, one 8-bit level on one channel of
one pixel, (1/255)^2 / (3 W H) of frame MSE (7.8e-11 at 256x256): below it a median is float32
rounding of an unchanged frame, not an error a display shows (`median_floor`; the sizes below it
are counted in n_below_floor and flagged in the table).

Two experiments, fitted apart (`group_fits`): procedural scenes are regenerated at each N (smaller
splats as N grows), captures are random subsets of one model. Each group gets one exponent with an
intercept per scene, and an F test (extra sum of squares) asks whether the two slopes are equal.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis import stats
from seuwgpu.analysis.records import InsufficientData, fields_present, figure, prepare, sort_rows, tag
from seuwgpu.errors import require
from seuwgpu.model.scenes import SCENES

METRICS = ("mean_mse", "median_mse", "mean_footprint_pct")
MIN_SIZES = 3  # sizes with a positive value needed for a fit (two points fit any line exactly)
PROCEDURAL, CAPTURE = "procedural (regenerated per N)", "capture (random subsets)"


def median_floor(width: int, height: int) -> float:
    """Frame MSE (peak 1) of one 8-bit level on one channel of one pixel of a W x H RGB frame."""
    return (1.0 / 255.0) ** 2 / (3.0 * width * height)


def frame_size_of(manifests=()) -> tuple[int, int] | None:
    """(W, H) of the runs' frames from their specs; None when they do not say or disagree."""
    from seuwgpu.campaign.spec_types import stored_size

    sizes = {stored_size(m) for m in manifests or ()} - {None}
    return sizes.pop() if len(sizes) == 1 else None


def scene_group(scene: str, model_scenes=frozenset()) -> str:
    """Procedural scenes are regenerated at each N; anything else (a capture, a model file) is cut
    to random subsets. model_scenes: the runs' model files' labels (`records.model_file_scenes`),
    which may share a procedural scene's name (the corpus' plant.splat)."""
    return PROCEDURAL if scene in SCENES and scene not in model_scenes else CAPTURE


def mark_groups(table: pd.DataFrame, floor: float, model_scenes=frozenset()) -> pd.DataFrame:
    """Adds each row's experiment (group) and whether its median rises above `floor` (a NaN floor:
    above 0), the columns `group_fits` reads; the table, changed in place."""
    table["group"] = [scene_group(x, model_scenes) for x in table["scene"]]
    table["median_above_floor"] = table["median_mse"] > floor if np.isfinite(floor) else table["median_mse"] > 0
    return table


def size_scaling(
    df: pd.DataFrame, conf: float = 0.95, frame_size: tuple[int, int] | None = None, model_scenes=frozenset()
) -> dict:
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
    floor = median_floor(*frame_size) if frame_size else np.nan
    mark_groups(table, floor, model_scenes)
    tag(table, d, source_campaign=src)
    frows = []
    for key, g in table.groupby(["scene", "precision", "defense"], sort=False):
        for metric in METRICS:
            y = g[metric].to_numpy(float)
            usable = np.isfinite(y) & (y > 0)
            if metric == "median_mse":
                usable &= g["median_above_floor"].to_numpy(bool)
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
                    "n_below_floor": int((~g["median_above_floor"]).sum()) if metric == "median_mse" else 0,
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
    groups = group_fits(table, conf)
    return {
        "table": table,
        "fits": fits,
        "groups": groups,
        "median_floor": floor,
        "guard_factor": gf,
        "source_campaign": src,
        **sampled,
    }


def _usable(t: pd.DataFrame, metric: str) -> pd.DataFrame:
    y = t[metric].to_numpy(float)
    ok = np.isfinite(y) & (y > 0)
    if metric == "median_mse":
        ok &= t["median_above_floor"].to_numpy(bool)
    t = t[ok]
    return t[t.groupby("scene")["n_primitives"].transform("nunique") >= MIN_SIZES]


def slopes_equal_test(groups, sets, x, y) -> tuple[float, float, int]:
    """F test (extra sum of squares) of one log-log slope for every set against one slope per set,
    both with an intercept per group: (F, p, residual degrees of freedom of the larger model)."""
    d = pd.DataFrame({"g": np.asarray(groups), "s": np.asarray(sets), "x": np.log10(x), "y": np.log10(y)})
    ss_sep = sum(stats.within_group_slope(h["g"], h["x"], h["y"])[1] for _, h in d.groupby("s"))
    ss_one = stats.within_group_slope(d["g"], d["x"], d["y"])[1]
    dof = len(d) - d["g"].nunique() - d["s"].nunique()
    if dof <= 0 or d["s"].nunique() < 2:
        return np.nan, np.nan, max(dof, 0)
    f_dist = require("scipy.stats", "analysis", "the equal-slopes F test").f

    extra = d["s"].nunique() - 1
    exact = 1e-12 * float(((d["y"] - d["y"].mean()) ** 2).sum())  # residuals below it are rounding
    if ss_sep > exact:
        F = ((ss_one - ss_sep) / extra) / (ss_sep / dof)
        return float(F), float(f_dist.sf(F, extra, dof)), int(dof)
    if ss_one - ss_sep > exact:  # one slope per set fits exactly, one for all does not: they differ
        return np.inf, 0.0, int(dof)
    return np.nan, np.nan, int(dof)  # both fit exactly: the test has nothing to weigh


def group_fits(table: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """Per (group, precision, defense, metric of mean/median MSE): one exponent over the group's
    scenes (an intercept each), the per-scene alphas' mean with its t interval over scenes (the
    models as the population, `analysis.population`), and the F test of equal slopes between the
    groups (same p on both groups' rows)."""
    from seuwgpu.analysis.population import interval_over_models

    rows = []
    for (prec, dfn), t in table.groupby(["precision", "defense"], sort=False):
        for metric in ("median_mse", "mean_mse"):
            u = _usable(t, metric)
            F, p, dof = (np.nan, np.nan, 0)
            if u["group"].nunique() == 2:
                F, p, dof = slopes_equal_test(u["scene"], u["group"], u["n_primitives"], u[metric])
            for grp in (PROCEDURAL, CAPTURE):
                g = u[u["group"] == grp]
                scenes = sorted(t.loc[t["group"] == grp, "scene"].unique())
                if not scenes:
                    continue
                row = {"group": grp, "precision": prec, "defense": dfn, "metric": metric, "scenes": ", ".join(scenes)}
                row["n_scenes_fitted"] = g["scene"].nunique()
                row["n_points"] = len(g)
                sizes = t.loc[t["group"] == grp, "n_primitives"]
                row["n_min"], row["n_max"] = int(sizes.min()), int(sizes.max())
                if g["scene"].nunique():
                    c = stats.common_loglog_fit(g["scene"], g["n_primitives"], g[metric], conf)
                    per = [-stats.loglog_fit(h["n_primitives"], h[metric]).exponent for _, h in g.groupby("scene")]
                else:
                    c, per = stats.PowerFit(np.nan, np.nan, np.nan), []
                om = interval_over_models(per, conf)
                row.update(
                    alpha_common=-c.exponent,
                    alpha_common_lo=-c.exponent_hi,
                    alpha_common_hi=-c.exponent_lo,
                    r2_common=c.r2,
                    alpha_scene_mean=om.mean,
                    alpha_models_lo=om.lo,
                    alpha_models_hi=om.hi,
                    equal_slopes_F=F,
                    equal_slopes_p=p,
                    equal_slopes_dof=dof,
                )
                rows.append(row)
    return pd.DataFrame(rows)


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


# ---- claims rows (analysis.claims gathers them) ----------------------------------------------------
MATCHED_N = (8_192, 32_768, 131_072, 524_288)  # common sizes every real model is cut to where it holds them


def alpha_rows(sz: dict | None, groups=(PROCEDURAL, CAPTURE)) -> list[dict]:
    """Median with median and mean with mean, each experiment apart (`group_fits`); `groups`: the
    experiments of the population asked for (the other's rows are left out)."""
    from seuwgpu.analysis.claimrows import row

    keys = {
        ("median_mse", PROCEDURAL): "alpha_median_procedural",
        ("median_mse", CAPTURE): "alpha_median_capture",
        ("mean_mse", PROCEDURAL): "alpha_mean_procedural",
        ("mean_mse", CAPTURE): "alpha_mean_capture",
    }
    g = sz["groups"] if sz is not None and "groups" in sz else pd.DataFrame(columns=["precision"])
    g = g[(g["precision"] == "fp32") & (g["defense"] == "none")] if len(g) else g
    floor = sz.get("median_floor", np.nan) if sz is not None else np.nan
    rows = []
    for (metric, grp), key in keys.items():
        if grp not in groups:
            continue
        r = g[(g["metric"] == metric) & (g["group"] == grp)] if len(g) else g
        if not len(r):
            rows.append(row(key))
            continue
        r = r.iloc[0]
        basis = (
            f"{r['scenes']}, N {r['n_min']:,}..{r['n_max']:,}; {r['n_points']} points fitted over "
            f"{r['n_scenes_fitted']} scene(s)"
        )
        if metric == "median_mse":
            basis += (
                f" (median above the 8-bit floor {floor:.2g} only)"
                if np.isfinite(floor)
                else " (no frame size: no floor)"
            )
        basis += f"; equal slopes of the two experiments: F test p = {r['equal_slopes_p']:.3g}"
        rows.append(
            row(
                key,
                r["alpha_scene_mean"],
                r["alpha_models_lo"],
                r["alpha_models_hi"],
                basis + "; pooled: one exponent, an intercept per scene",
                n_models=int(r["n_scenes_fitted"]),
                pooled=(r["alpha_common"], r["alpha_common_lo"], r["alpha_common_hi"]),
            )
        )
    return rows


def guard_factor_row(sz: dict | None, conf: float = 0.95, scenes=None) -> dict:
    """The guard factor at each model's largest N (a row that averages sizes only where the models'
    largest N differ, which its basis names; the rows at matched N do not: `matched_rows`)."""
    from seuwgpu.analysis.claimrows import over_models, row

    gf = sz["guard_factor"] if sz is not None and "guard_factor" in sz else pd.DataFrame()
    gf = gf[gf["precision"] == "fp32"] if len(gf) else gf
    if scenes is not None and len(gf):
        gf = gf[gf["scene"].isin(scenes)]
    if not len(gf):
        return row("guard_factor")
    ns = ", ".join(f"{r['scene']} N = {int(r['n_primitives']):,}" for _, r in gf.iterrows())
    mixed = gf["n_primitives"].nunique() > 1
    basis = f"each model at its largest N ({ns}; the paper's largest: 300,000)" + (
        "; these N differ: the rows at matched N compare like with like" if mixed else ""
    )
    r = over_models("guard_factor", gf.rename(columns={"guard_factor": "v"}), "v", basis, conf, scale=1.0)
    return r | ({"verdict": "not comparable"} if mixed and r["verdict"] in ("reproduced", "differs") else {})


def matched_rows(df: pd.DataFrame, conf: float = 0.95, sizes=None) -> list[dict]:
    """Rows at matched N from the size sweep's records (seeded subsets of each model at a common
    primitive count; never an average over sizes): per N in `sizes` (MATCHED_N and the paper's
    300,000 by default) that the records hold, p_c as the plain mean of per-field rates (no defense),
    the mean single-upset MSE, and the guard factor for each guard arm present; over the models at
    that N. The guard factor is compared with the paper's 24 only at the paper's N (within 15%)."""
    from seuwgpu.analysis import population
    from seuwgpu.analysis.claimrows import over_models
    from seuwgpu.analysis.paper import PAPER_LARGEST_N

    d = prepare(df)
    d = d[(d["k"] == 1) & (d["campaign"] == "size") & (d["precision"] == "fp32")]
    if d.empty:
        return []
    sizes = sorted(set(MATCHED_N) | {PAPER_LARGEST_N}) if sizes is None else sizes
    rows = []
    for n in sizes:
        at = d[d["n_primitives"] == n]
        if at.empty:
            continue
        label = f"N = {n:,}"
        # a model of SH degree 0 stores no sh_rest: then the plain mean of the five other fields
        five = population.without_sh_rest(at)
        as_single = at.assign(campaign="single")
        if five:
            as_single = as_single[as_single["field"] != "sh_rest"]
        rates = population.model_rates(as_single, "fp32", "none", conf)
        if len(rates):
            full = int(rates["fields"].min()) == (5 if five else 6)
            r = over_models(
                "matched_pc_none_5" if five else "matched_pc_none",
                rates,
                "fields_p_c",
                f"{label}; size-sweep records, each field weighs 1/{5 if five else 6} within each model",
                conf,
            )
            rows.append((r if full else r | {"verdict": "not measured"}) | {"N": label})
        mse = {}
        for dfn, g in at.groupby("defense", sort=False):
            bad = g["nonfinite"].to_numpy(bool)
            vals = np.where(bad, np.nan, E.mse_of_psnr(g["psnr"].to_numpy(float)))
            mse[dfn] = pd.DataFrame(
                [
                    {"scene": s, "n_primitives": n, "v": E.wmean(vals[idx], g["weight"].to_numpy(float)[idx])}
                    for s, idx in g.groupby("scene", sort=False).indices.items()
                ]
            )
        if "none" in mse:
            r = over_models("matched_mean_mse", mse["none"], "v", f"{label}; over the finite frames", conf, scale=1.0)
            rows.append(r | {"N": label})
        for arm in ("guard", "guard_all"):
            if "none" not in mse or arm not in mse:
                continue
            m = mse["none"].merge(mse[arm], on=["scene", "n_primitives"], suffixes=("_none", "_g"))
            with np.errstate(divide="ignore", invalid="ignore"):
                m["v"] = np.where(m["v_g"] > 0, m["v_none"] / m["v_g"], np.nan)
            at_paper = abs(n - PAPER_LARGEST_N) <= 0.15 * PAPER_LARGEST_N
            r = over_models(
                "matched_guard_factor",
                m,
                "v",
                f"{label}; mean MSE without / with {arm}" + ("" if at_paper else "; the paper's is at 300,000"),
                conf,
                scale=1.0,
                guard=arm,
            )
            if not at_paper and r["verdict"] in ("reproduced", "differs", "inconclusive"):
                r["verdict"] = "not comparable"
            rows.append(r | {"N": label})
    return rows
