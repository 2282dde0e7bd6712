"""Accumulated dose: k simultaneous upsets drawn uniformly over a model's stored bits (campaign
"dose"; every defense arm sees the same upset set). Everything is per model, i.e. per (scene,
primitive count): curves of different models are never averaged together.

* Quality per k: `estimate.quality` (PSNR over finite frames, non-finite share beside it).
  Medians and quartiles (estimate.wquantile, no interpolation) rank a non-finite frame below every
  finite one (it is worse than any finite frame, though its PSNR is undefined); no number is made
  up for it.
* Catastrophic fraction per k: Wilson interval (the draws are a simple random sample).
* Dose model per model and defense: P(catastrophic | k) = 1 - (1 - p)^k, p fitted by maximum
  likelihood to the binomial counts over k, with a profile-likelihood 95% interval and its fit
  quality (deviance G^2 against the saturated model, degrees of freedom = points - 1, p-value).
* Redundancy budget: the k at which the median PSNR first falls to `threshold_db` (30 dB),
  interpolated in log k between the bracketing grid points (k_lo, k_hi), censored when the grid
  does not bracket it.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import InsufficientData, dose_records, figure, series_color, sort_rows, tag
from seuwgpu.errors import require
from seuwgpu.faults.defenses import defense_label

BUDGET_PSNR_DB = 30.0  # redundancy budget threshold (paper, Section 5.4)
MODEL = ["scene", "n_primitives"]


def _ranked_psnr(d: pd.DataFrame) -> np.ndarray:
    """PSNR for ordering only: non-finite frames rank lowest (-inf)."""
    return np.where(d["nonfinite"].to_numpy(bool), -np.inf, d["psnr"].to_numpy(float))


def dose_curves(df: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """Per (scene, n_primitives, precision, defense, k): samples, non-finite share (interval),
    median and quartile PSNR (non-finite ranked lowest), PSNR of the mean MSE over finite frames,
    mean SSIM (finite frames), mean footprint, catastrophic fraction with its Wilson interval."""
    d = dose_records(df)
    if d.empty or not (d["k"] > 1).any():
        raise InsufficientData("no k > 1 records", "run a dose campaign (k simultaneous upsets)")
    keys = MODEL + ["precision", "defense", "k"]
    d = d.assign(_rank=_ranked_psnr(d))
    q = E.quality(d, keys, conf)
    # E.quality's quartiles are over finite frames only; here every frame counts, a non-finite one
    # ranked lowest, through the same weighted quantile (dose draws are a simple random sample:
    # weight 1 each, so this is the plain order statistic at ceil(q n))
    qs = {"psnr_q25_db": 0.25, "psnr_median_db": 0.5, "psnr_q75_db": 0.75}
    med = d.groupby(keys, sort=False)[["_rank", "weight"]].apply(
        lambda g: pd.Series({c: E.wquantile(g["_rank"], g["weight"], p) for c, p in qs.items()})
    )
    q = q.drop(columns=list(qs)).merge(med.reset_index(), on=keys)
    r = E.percent(E.rate(d, "catastrophic", keys, conf, strata=())).rename(columns={"events": "catastrophic"})
    out = q.merge(r[keys + ["catastrophic", "cat_rate_pct", "cat_ci_lo_pct", "cat_ci_hi_pct"]], on=keys)
    # the dose per primitive: k alone does not compare models of different sizes
    out.insert(out.columns.get_loc("k") + 1, "k_per_n", out["k"] / out["n_primitives"].astype(float))
    out = sort_rows(out.sort_values(MODEL + ["k"], kind="stable"))
    return tag(out, d)


def at_dose_per_primitive(curves: pd.DataFrame, k_per_n: float, column: str = "psnr_mean_mse_db") -> pd.DataFrame:
    """Per (model, precision, defense): `column` at the dose k = k_per_n x N, interpolated linearly
    in log k between the two grid points around it (NaN outside the grid or where either neighbour
    is not finite: no extrapolation)."""
    rows = []
    for key, g in curves.groupby(MODEL + ["precision", "defense"], sort=False):
        g = g.sort_values("k")
        k = float(k_per_n) * float(key[1])
        ks, v = g["k"].to_numpy(float), g[column].to_numpy(float)
        value = np.nan
        if ks.size and ks[0] <= k <= ks[-1]:
            i = int(np.searchsorted(ks, k))
            if ks[i] == k:
                value = float(v[i])
            elif np.isfinite(v[i - 1]) and np.isfinite(v[i]):
                t = (math.log(k) - math.log(ks[i - 1])) / (math.log(ks[i]) - math.log(ks[i - 1]))
                value = float(v[i - 1] + t * (v[i] - v[i - 1]))
        rows.append({**dict(zip(MODEL + ["precision", "defense"], key)), "k_per_n": k_per_n, "k": k, column: value})
    return pd.DataFrame(rows)


def fit_dose_model(k, events, n, conf: float = 0.95) -> dict:
    """Maximum-likelihood p of P(k) = 1 - (1-p)^k from binomial counts (events of n at each k);
    profile-likelihood interval; deviance G^2, degrees of freedom and p-value of the fit."""
    optimize = require("scipy.optimize", "analysis", "the dose-model fit")
    chi2 = require("scipy.stats", "analysis", "the dose-model fit's interval").chi2

    k = np.asarray(k, float)
    x = np.asarray(events, float)
    n = np.asarray(n, float)

    def nll(logp):
        p = math.exp(logp)
        s = np.clip((1 - p) ** k, 1e-300, 1.0)  # P(not catastrophic)
        q = np.clip(1 - s, 1e-300, 1.0)
        return -float(np.sum(x * np.log(q) + (n - x) * np.log(s)))

    out = {
        "p": np.nan,
        "p_lo": np.nan,
        "p_hi": np.nan,
        "deviance": np.nan,
        "dof": int(k.size - 1),
        "fit_pvalue": np.nan,
    }
    if k.size == 0 or n.sum() == 0:
        return out
    lo_b, hi_b = math.log(1e-12), math.log(1 - 1e-12)
    if x.sum() == 0:
        p_hat, f_hat = 0.0, 0.0
    else:
        res = optimize.minimize_scalar(nll, bounds=(lo_b, hi_b), method="bounded", options={"xatol": 1e-10})
        p_hat, f_hat = math.exp(res.x), float(res.fun)
    cut = float(chi2.ppf(conf, 1)) / 2

    def excess(logp):
        return nll(logp) - f_hat - cut

    # the log-likelihood is concave in p (log q and log(1-q) are), so the interval is one piece
    # around the MLE (where excess = -cut < 0): each end is the root of `excess` between the MLE
    # and that bound, or the bound itself when excess stays <= 0 up to it
    mid = math.log(p_hat) if p_hat > 0 else lo_b
    lo = lo_b if excess(lo_b) <= 0 else optimize.brentq(excess, lo_b, mid, xtol=1e-12)
    hi = hi_b if excess(hi_b) <= 0 else optimize.brentq(excess, mid, hi_b, xtol=1e-12)
    out["p_lo"] = 0.0 if x.sum() == 0 else float(math.exp(lo))
    out["p_hi"] = float(math.exp(hi))
    # deviance against the saturated model (each k its own rate)
    with np.errstate(divide="ignore", invalid="ignore"):
        ph = x / n
        s = (1 - p_hat) ** k
        m = 1 - s
        t1 = np.where(x > 0, x * np.log(ph / np.maximum(m, 1e-300)), 0.0)
        t2 = np.where(n - x > 0, (n - x) * np.log((1 - ph) / np.maximum(s, 1e-300)), 0.0)
    dev = float(2 * np.sum(t1 + t2))
    out.update(p=p_hat, deviance=dev)
    if k.size > 1:
        out["fit_pvalue"] = float(chi2.sf(dev, k.size - 1))
    return out


def dose_fits(curves: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """`fit_dose_model` per (scene, n_primitives, precision, defense) of `dose_curves`; also the
    share of grid points whose Wilson interval holds the fitted curve."""
    rows = []
    for key, g in curves.groupby(MODEL + ["precision", "defense"], sort=False):
        f = fit_dose_model(g["k"], g["catastrophic"], g["n"], conf)
        model = 100 * (1 - (1 - f["p"]) ** g["k"].to_numpy(float)) if np.isfinite(f["p"]) else np.nan
        within = (g["cat_ci_lo_pct"] <= model + 1e-9) & (model <= g["cat_ci_hi_pct"] + 1e-9)
        row = dict(zip(MODEL + ["precision", "defense"], key))
        row.update(n_k=len(g), n=int(g["n"].sum()), events=int(g["catastrophic"].sum()))
        row.update({f"{a}_pct" if a.startswith("p") and a != "fit_pvalue" else a: v for a, v in f.items()})
        for c in ("p_pct", "p_lo_pct", "p_hi_pct"):
            row[c] = 100 * row[c]
        row["points_within_ci"] = float(np.mean(within)) if np.isfinite(f["p"]) else np.nan
        rows.append(row)
    out = sort_rows(pd.DataFrame(rows))
    out.attrs.update(curves.attrs)
    return out


def crossing_k(ks, values, threshold: float = BUDGET_PSNR_DB) -> tuple[float, str, float, float]:
    """First k where `values` falls to or below `threshold`, interpolated linearly in log k
    between finite neighbours. Returns (k, censor, k_lo, k_hi): censor "" for an interpolated
    crossing, "<=" when the first k is already at or below it (or the value below is not finite:
    the crossing lies in (k_lo, k_hi]), ">=" when no k reaches it."""
    ks = np.asarray(ks, dtype=float)
    v = np.asarray(values, dtype=float)
    order = np.argsort(ks)
    ks, v = ks[order], v[order]
    below = np.nonzero(v <= threshold)[0]
    if below.size == 0:
        return float(ks[-1]), ">=", float(ks[-1]), float("inf")
    i = int(below[0])
    if i == 0:
        return float(ks[0]), "<=", 0.0, float(ks[0])
    v0, v1 = v[i - 1], v[i]
    if not (np.isfinite(v0) and np.isfinite(v1)):
        return float(ks[i]), "<=", float(ks[i - 1]), float(ks[i])
    k0, k1 = math.log(ks[i - 1]), math.log(ks[i])
    t = (v0 - threshold) / (v0 - v1) if v0 != v1 else 0.0
    return float(math.exp(k0 + t * (k1 - k0))), "", float(ks[i - 1]), float(ks[i])


def redundancy_budget(df: pd.DataFrame, threshold_db: float = BUDGET_PSNR_DB) -> pd.DataFrame:
    """Per (scene, n_primitives, precision, defense): the k where the median PSNR (non-finite
    frames ranked lowest) first falls to `threshold_db`, with its bracket on the k grid."""
    curves = dose_curves(df)
    rows = []
    for key, g in curves.groupby(MODEL + ["precision", "defense"], sort=False):
        if len(g) < 2:
            continue
        kb, cens, klo, khi = crossing_k(g["k"].to_numpy(), g["psnr_median_db"].to_numpy(), threshold_db)
        rows.append(
            dict(
                zip(MODEL + ["precision", "defense"], key),
                n=int(g["n"].sum()),
                n_k=len(g),
                k_min=int(g["k"].min()),
                k_max=int(g["k"].max()),
                k_budget=kb,
                k_budget_per_n=kb / float(key[1]),
                censored=cens,
                k_lo=klo,
                k_hi=khi,
            )
        )
    if not rows:
        raise InsufficientData("no dose sweep with two or more k values", "run a dose campaign sweeping k")
    out = sort_rows(pd.DataFrame(rows).sort_values(MODEL))
    out.attrs.update(curves.attrs)
    out.attrs["threshold_db"] = threshold_db
    return out


DEFENSE_LINES = ("-", "--", ":", "-.")  # no defense first: solid


def series_styles(keys) -> tuple[dict, dict]:
    """Colours per model (every key but the last, the defense) and line styles per defense (no
    defense solid), so a figure tells models apart by colour and defenses by line, never by a
    colour each."""
    models = list(dict.fromkeys(tuple(k[:-1]) for k in keys))
    defenses = sorted(dict.fromkeys(k[-1] for k in keys), key=lambda d: d != "none")
    return (
        {m: series_color(i) for i, m in enumerate(models)},
        {d: DEFENSE_LINES[i % len(DEFENSE_LINES)] for i, d in enumerate(defenses)},
    )


def style_legend(fig, colors: dict, lines: dict, name, extra=(), ncols: int = 4):
    """One legend below the panels: a colour per model (name(model) -> its label), a line per
    defense, and `extra` handles; outside the axes, so it hides no data."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=c, lw=2, label=name(m)) for m, c in colors.items()]
    handles += [
        Line2D(
            [],
            [],
            color="0.3",
            ls=ls,
            marker="o" if d == "none" else "s",
            mfc="0.3" if d == "none" else "white",
            ms=4,
            label=defense_label(d),
        )
        for d, ls in lines.items()
    ]
    handles += list(extra)
    fig.legend(handles=handles, loc="outside lower center", ncols=min(ncols, len(handles)), fontsize=7)


def plot_dose(curves: pd.DataFrame, fits: pd.DataFrame | None = None, threshold_db: float = BUDGET_PSNR_DB):
    """Two panels against k, one line per model, precision and defense (colour: model and
    precision; line: defense): median PSNR with its interquartile band (a median frame that is
    non-finite is marked at the panel's foot, one row per series, never drawn at a made-up value;
    one identical to clean, infinite PSNR, at its top) and the catastrophic fraction with Wilson
    intervals (markers spread a little along k per series, so equal rates stay apart) and the
    fitted dose model."""
    from matplotlib.lines import Line2D

    fig = figure(10.5, 5.0)
    ax, bx = fig.subplots(1, 2)
    keys = MODEL + ["precision", "defense"]
    groups = list(curves.groupby(keys, sort=False))
    colors, lines = series_styles([k for k, _ in groups])
    fin = curves[["psnr_median_db", "psnr_q25_db", "psnr_q75_db"]].replace([np.inf, -np.inf], np.nan).stack()
    ymin = float(fin.min()) - 3 if len(fin) else 0.0
    ytop = float(fin.max()) + 3 if len(fin) else 100.0
    step = 0.025 * (ytop - ymin)
    n = len(groups)
    foot_rows = top_rows = 0
    for i, (key, g) in enumerate(groups):
        g = g.sort_values("k")
        k = g["k"].to_numpy(float)
        c, ls = colors[tuple(key[:-1])], lines[key[-1]]
        mfc = c if key[-1] == "none" else "white"
        marker = "o" if key[-1] == "none" else "s"
        y = g["psnr_median_db"].to_numpy(float)
        ax.plot(k, np.where(np.isfinite(y), y, np.nan), ls, color=c, marker=marker, mfc=mfc, ms=3, lw=1.2)
        lo = np.where(np.isfinite(g["psnr_q25_db"]), g["psnr_q25_db"], ymin)
        hi = g["psnr_q75_db"].to_numpy(float)
        hi = np.where(np.isposinf(hi), ytop, np.where(np.isfinite(hi), hi, np.nan))
        ax.fill_between(k, lo, hi, color=c, alpha=0.10, lw=0)
        bad = np.isneginf(y)
        if bad.any():  # each series its own row at the foot: no triangle hides another
            ax.plot(k[bad], np.full(bad.sum(), ymin - step * foot_rows), "v", color=c, mfc=mfc, ms=5)
            foot_rows += 1
        same = np.isposinf(y)
        if same.any():
            ax.plot(k[same], np.full(same.sum(), ytop + step * top_rows), "^", color=c, mfc=mfc, ms=5)
            top_rows += 1
        yc = g["cat_rate_pct"].to_numpy(float)
        err = np.vstack([yc - g["cat_ci_lo_pct"], g["cat_ci_hi_pct"] - yc])
        spread = 10 ** (0.02 * (i - (n - 1) / 2))
        bx.errorbar(k * spread, yc, yerr=err, fmt=marker, mfc=mfc, ms=3, capsize=2, color=c, elinewidth=0.8)
        if fits is not None and len(fits):
            f = fits
            for col, v in zip(keys, key):
                f = f[f[col] == v]
            if len(f) and np.isfinite(f["p_pct"].iloc[0]):
                kk = np.logspace(0, np.log10(g["k"].max()), 100)
                bx.plot(kk, 100 * (1 - (1 - f["p_pct"].iloc[0] / 100) ** kk), ls, color=c, lw=1)
    ax.axhline(threshold_db, color="grey", ls=":", lw=1)
    for a in (ax, bx):
        a.set_xscale("log")
        a.set_xlabel("simultaneous upsets k")
    ax.set_ylim(ymin - step * max(foot_rows, 1), ytop + step * max(top_rows, 1))
    ax.set_ylabel("median PSNR (dB)")
    ax.set_title("median PSNR, interquartile band", fontsize=9)
    bx.set_ylabel("catastrophic frames (%)")
    bx.set_title("catastrophic fraction, 95% Wilson interval; lines: fitted 1-(1-p)^k", fontsize=9)
    extra = [Line2D([], [], color="grey", ls=":", lw=1, label=f"{threshold_db:g} dB")]
    if foot_rows:
        extra.append(Line2D([], [], color="0.3", ls="", marker="v", ms=5, label="median frame non-finite"))
    if top_rows:
        extra.append(Line2D([], [], color="0.3", ls="", marker="^", ms=5, label="median frame identical (inf dB)"))
    style_legend(fig, colors, lines, lambda m: f"{m[0]} N={int(m[1]):,} {m[2]}", extra)
    return fig


def plot_budget(budget: pd.DataFrame):
    """Redundancy budget against N per scene, precision and defense, with the k-grid bracket as
    the error bar; open markers are censored bounds, pointing where the budget lies (^: at least,
    the sweep never fell to the threshold; v: at most, the first k already had)."""
    groups = list(budget.groupby(["scene", "precision", "defense"], sort=False))
    colors, lines = series_styles([k for k, _ in groups])
    fig = figure(5.6, 3.8 + 0.2 * len(groups))
    ax = fig.subplots()
    for key, g in groups:
        g = g.sort_values("n_primitives")
        c, ls = colors[tuple(key[:-1])], lines[key[-1]]
        ax.plot(g["n_primitives"], g["k_budget"], ls, color=c, label=f"{key[0]} {key[1]} {defense_label(key[2])}")
        lo = np.clip(g["k_budget"] - g["k_lo"].where(g["k_lo"] > 0, g["k_budget"]), 0, None)
        hi = np.clip(g["k_hi"].where(np.isfinite(g["k_hi"]), g["k_budget"]) - g["k_budget"], 0, None)
        ax.errorbar(g["n_primitives"], g["k_budget"], yerr=np.vstack([lo, hi]), fmt="none", ecolor=c, capsize=2)
        # a bound points where the budget lies: '>=' above the marker, '<=' below it
        for cens, marker, mfc in (("", "o", c), (">=", "^", "none"), ("<=", "v", "none")):
            at = g["censored"] == cens
            ax.plot(g.loc[at, "n_primitives"], g.loc[at, "k_budget"], marker, mfc=mfc, color=c)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("primitive count N")
    ax.set_ylabel(f"redundancy budget k (median PSNR {budget.attrs.get('threshold_db', BUDGET_PSNR_DB):g} dB)")
    fig.legend(
        loc="outside lower center",
        ncols=2,
        fontsize=7,
        title="bars: k-grid bracket; open: censored (^ at least, v at most)",
        title_fontsize=7,
    )
    return fig


# ---- claims rows (analysis.claims gathers them) ----------------------------------------------------


def _all_frames_psnr(c: pd.DataFrame) -> np.ndarray:
    """PSNR of the mean MSE over every frame: -inf where a frame is non-finite (it fails)."""
    return np.where(c["nonfinite_pct"].to_numpy(float) > 0, -np.inf, c["psnr_mean_mse_db"].to_numpy(float))


def dose_rows(curves: pd.DataFrame | None, conf: float = 0.95) -> list[dict]:
    """PSNR of the mean MSE per model at the paper's heaviest dose per primitive, over the finite
    frames (as before: the survivors) and with a non-finite frame counted as a failure (-inf at a
    k where any frame is non-finite; the value at k/N is that of the grid point at or above it)."""
    from seuwgpu.analysis.claimrows import over_models, row
    from seuwgpu.analysis.paper import PAPER_DOSE_K_MAX, PAPER_PRIMITIVES, paper_heaviest_k_per_n

    kn = paper_heaviest_k_per_n()
    rows = []
    for dfn in ("none", "guard"):
        key = f"dose_{dfn}"
        c = curves[(curves["precision"] == "fp32") & (curves["defense"] == dfn)] if curves is not None else None
        if c is None or c.empty:
            rows += [row(key), row(f"{key}_all")]
            continue
        at = at_dose_per_primitive(c, kn, "psnr_mean_mse_db")
        bad = at_dose_per_primitive(c, kn, "nonfinite_pct")["nonfinite_pct"]
        basis = (
            f"k/N = {kn:.3g} (the paper's {PAPER_DOSE_K_MAX:,} on its scenes: "
            f"{PAPER_DOSE_K_MAX / max(PAPER_PRIMITIVES):.3g}..{PAPER_DOSE_K_MAX / min(PAPER_PRIMITIVES):.3g}), "
            f"k = {', '.join(f'{k:,.0f}' for k in at['k'])} on these models, interpolated in log k"
        )
        survivors = (
            f"{basis}; PSNR over the finite frames, NaN where a grid neighbour has none; non-finite frames "
            f"there: {bad.min():.3g}..{bad.max():.3g}% over models"
        )
        rows.append(over_models(key, at.rename(columns={"psnr_mean_mse_db": "v"}), "v", survivors, conf, scale=1.0))
        allf = []
        for (scene, n), g in c.groupby(MODEL, sort=False):
            g = g.sort_values("k")
            k = kn * float(n)
            above = g[g["k"] >= k]
            if above.empty:
                allf.append({"scene": scene, "n_primitives": n, "v": np.nan})
                continue
            lower = g[g["k"] <= k]
            pts = pd.concat([lower.tail(1), above.head(1)])
            if np.isneginf(_all_frames_psnr(pts)).any():
                v = -np.inf
            else:  # every frame finite at both neighbours: the finite-frame value is every frame's
                v = float(at.loc[(at["scene"] == scene) & (at["n_primitives"] == n), "psnr_mean_mse_db"].iloc[0])
            allf.append({"scene": scene, "n_primitives": n, "v": v})
        rows.append(
            over_models(
                f"{key}_all",
                pd.DataFrame(allf, columns=MODEL + ["v"]),
                "v",
                f"{basis}; a model with a non-finite frame at either grid neighbour is at -inf (the mean MSE over "
                "every frame is infinite)",
                conf,
                scale=1.0,
            )
        )
    return rows


def budget_rows(curves: pd.DataFrame | None, conf: float = 0.95) -> list[dict]:
    """The paper's budget reads the mean PSNR: k/N where the PSNR of the mean MSE first falls to
    30 dB (crossing_k), per model, two ways: over the finite frames (a censored model left out), and
    with a non-finite frame counted as a failure (a k with any non-finite frame is at -inf, so the
    crossing lies at or before it; a bracketed crossing takes the bracket's geometric middle)."""
    from seuwgpu.analysis.claimrows import over_models, row
    from seuwgpu.analysis.paper import PAPER_BUDGET_K, PAPER_PRIMITIVES

    c = curves[(curves["precision"] == "fp32") & (curves["defense"] == "none")] if curves is not None else None
    if c is None or c.empty:
        return [row("budget_mean_psnr"), row("budget_mean_psnr_all")]
    out = []
    for key, values in (("budget_mean_psnr", None), ("budget_mean_psnr_all", _all_frames_psnr)):
        vals, notes = [], []
        for (scene, n), g in c.groupby(MODEL, sort=False):
            v = g["psnr_mean_mse_db"].to_numpy() if values is None else values(g)
            k, cens, klo, khi = crossing_k(g["k"].to_numpy(), v, BUDGET_PSNR_DB)
            if values is not None and cens == "<=" and klo > 0:
                k, cens = math.sqrt(klo * khi), ""
                notes.append(f"{scene} in ({klo:,.0f}, {khi:,.0f}]")
            vals.append({"scene": scene, "n_primitives": n, "v": k / n if not cens else np.nan})
            if cens:
                notes.append(f"{scene} censored ({cens} k = {k:,.0f})")
        basis = (
            f"the paper's {PAPER_BUDGET_K:,} upsets on its scenes, {PAPER_BUDGET_K / max(PAPER_PRIMITIVES):.3g}.."
            f"{PAPER_BUDGET_K / min(PAPER_PRIMITIVES):.3g} per primitive; here the first fall to "
            f"{BUDGET_PSNR_DB:g} dB, "
            "interpolated in log k; "
            + ("PSNR over the finite frames" if values is None else "a k with a non-finite frame fails")
        ) + (f"; {', '.join(notes)}" if notes else "")
        out.append(over_models(key, pd.DataFrame(vals, columns=MODEL + ["v"]), "v", basis, conf, scale=1.0))
    return out
