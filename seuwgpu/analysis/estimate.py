"""The one estimator layer: every rate, mean and quantile in a table, figure or summary.json.

Records are a stratified sample: a single-upset campaign draws `samples` sites in every
(field, bit) cell, although cells hold very different numbers of stored bits (a colour
coefficient's mantissa bit is ~45x more common than an opacity sign bit). Each record therefore
stands for ``weight`` stored bits (the runner writes it; `records.prepare` derives it when absent)
and a population quantity is a weighted one:

* **rate** of a 0/1 outcome y over a group: ``p = sum(w*y) / sum(w)``, i.e. the probability that
  one upset drawn uniformly over the group's stored bits has y. Per stratum h (a (scene, N,
  precision, field, bit) cell) p_h is the weighted mean inside the cell, W_h its weight share.
* **interval** (95% by default): in one stratum the Wilson score interval of (k, n). Pooled over
  strata: the Wilson interval at a design-based effective sample size n_eff = p~(1-p~) / V, with
  the stratified variance V = sum_h W_h^2 p~_h (1-p~_h) / n_h of add-half stratum rates
  p~_h = (k_h + 1/2) / (n_h + 1), p~ = sum_h W_h p~_h, capped at the record count (the idea of
  Korn & Graubard, Survey Methodology 24(2), 1998, without their degrees-of-freedom
  adjustment). The smoothing enters the variance only, never the rate p = sum_h W_h p_h: with the
  raw p_h, a stratum with no event, all events or one record adds nothing to V, so one event in a
  light stratum could shrink the interval 700-fold and pooled intervals covered 81-87% at the
  campaigns' 6-9 samples a cell. Smoothed, simulated designs of the campaigns' shape (192 strata,
  6-50 records each, rates 0.4-30%) covered 93.5-96.4% (tests/test_analysis.py checks one). One
  stratum gives n_eff = n: the plain Wilson interval.
* **means and quantiles** of a measured quantity are weighted over the records where it is
  defined (finite); the share of undefined (non-finite frame) records is reported beside them,
  weighted the same way. Nothing undefined is replaced by a number.

`rate` and `summary` are what the analyses call; nothing else in the package computes a rate.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import stats
from seuwgpu.analysis.records import multiplicity, n_records, record_weights

STRATA = ("scene", "n_primitives", "precision", "field", "bit")
METHOD_CELL = "Wilson"
METHOD_POOLED = "stratified Wilson (design-effect n_eff)"


def stratified_interval(p_h, n_h, W_h, conf: float = 0.95) -> tuple[float, float, float, float]:
    """(p, lo, hi, n_eff) of a stratified proportion from per-stratum rates p_h (weighted
    within the stratum), sizes n_h and weights W_h (any scale). Strata with n_h = 0 are dropped."""
    p_h = np.asarray(p_h, float)
    n_h = np.asarray(n_h, float)
    W_h = np.asarray(W_h, float)
    ok = (n_h > 0) & (W_h > 0)
    if not ok.any():
        return float("nan"), float("nan"), float("nan"), 0.0
    p_h, n_h, W = p_h[ok], n_h[ok], W_h[ok] / W_h[ok].sum()
    p = float(np.sum(W * p_h))
    n_tot = float(n_h.sum())
    if p_h.size == 1:
        n_eff = n_tot
    else:
        smooth = (p_h * n_h + 0.5) / (n_h + 1.0)  # in (0, 1): V > 0 (module notes)
        var = float(np.sum(W * W * smooth * (1.0 - smooth) / n_h))
        p_s = float(np.sum(W * smooth))
        n_eff = min(p_s * (1.0 - p_s) / var, n_tot)
    k_eff = min(max(p * n_eff, 0.0), n_eff)
    lo, hi = stats.wilson_interval(k_eff, n_eff, conf)
    return p, float(lo), float(hi), float(n_eff)


def _cells(d: pd.DataFrame, y: np.ndarray, by: list[str], strata: list[str]) -> pd.DataFrame:
    w = d["weight"].to_numpy(float)
    t = pd.DataFrame({c: d[c].to_numpy() for c in dict.fromkeys(by + strata)})
    if "n_records" in d:  # cell rows of analysis.cells: n_records records each, y counts their events
        n = d["n_records"].to_numpy(float)
    else:  # records, or folded rows (analysis.folding): `multiplicity` identical records each
        n = multiplicity(d).astype(float)
        y = y * n
    t["_w"], t["_wy"], t["_y"], t["_n"] = w * n, w * y, y, n
    return t.groupby(list(dict.fromkeys(by + strata)), sort=False, dropna=False)[["_w", "_wy", "_y", "_n"]].sum()


def rate(
    d: pd.DataFrame,
    y="catastrophic",
    by=(),
    conf: float = 0.95,
    strata=STRATA,
    prefix: str = "",
) -> pd.DataFrame:
    """Weighted rate of a 0/1 outcome per group, with its interval (see module notes).

    y: a column name or a boolean array aligned with d (on rows folded by analysis.cells: a
    count column, each row standing for n_records records). Returns one row per group (in order of
    appearance) with columns ``by`` + n, events, weight, rate, ci_lo, ci_hi, n_eff, method
    (rates as proportions; `prefix` is put before the names of the added columns)."""
    by = list(by)
    strata = [c for c in strata if c in d and c not in by]
    yv = (d[y] if isinstance(y, str) else pd.Series(np.asarray(y), index=d.index)).astype(float).to_numpy()
    cols = [f"{prefix}{c}" for c in ("n", "events", "weight", "rate", "ci_lo", "ci_hi", "n_eff", "method")]
    if len(d) == 0:
        return pd.DataFrame(columns=by + cols)
    cells = _cells(d, yv, by, strata).reset_index()
    cells["_p"] = cells["_wy"] / cells["_w"].where(cells["_w"] > 0)
    rows = []
    groups = cells.groupby(by, sort=False, dropna=False) if by else [((), cells)]
    for key, g in groups:
        key = key if isinstance(key, tuple) else (key,)
        p, lo, hi, n_eff = stratified_interval(g["_p"], g["_n"], g["_w"], conf)
        row = dict(zip(by, key))
        row.update(
            zip(
                cols,
                (
                    int(g["_n"].sum()),
                    int(g["_y"].sum()),
                    float(g["_w"].sum()),
                    p,
                    lo,
                    hi,
                    n_eff,
                    METHOD_CELL if len(g) == 1 else METHOD_POOLED,
                ),
            )
        )
        rows.append(row)
    return pd.DataFrame(rows, columns=by + cols)


def one_rate(d: pd.DataFrame, y="catastrophic", conf: float = 0.95, strata=STRATA) -> dict:
    """`rate` of the whole frame as a dict (rate, ci_lo, ci_hi, n, events, n_eff, ...)."""
    r = rate(d, y, (), conf, strata)
    if r.empty:
        return {"n": 0, "events": 0, "weight": 0.0, "rate": np.nan, "ci_lo": np.nan, "ci_hi": np.nan, "n_eff": 0.0}
    return r.iloc[0].to_dict()


def percent(t: pd.DataFrame, prefix: str = "", out: str = "cat") -> pd.DataFrame:
    """`rate` columns as percentages named {out}_rate_pct, {out}_ci_lo_pct, {out}_ci_hi_pct."""
    t = t.copy()
    for c in ("rate", "ci_lo", "ci_hi"):
        t[f"{out}_{c}_pct"] = 100 * t.pop(f"{prefix}{c}").astype(float)
    return t


def wquantile(values, weights, q) -> float:
    """Weighted quantile (the smallest value whose cumulative weight reaches q; +inf sorts last).
    NaN values are ignored; NaN when nothing is left."""
    v = np.asarray(values, float)
    w = np.asarray(weights, float)
    ok = ~np.isnan(v) & (w > 0)
    if not ok.any():
        return float("nan")
    v, w = v[ok], w[ok]
    order = np.argsort(v, kind="stable")
    cw = np.cumsum(w[order])
    i = int(np.searchsorted(cw, q * cw[-1] * (1 - 1e-12)))
    return float(v[order][min(i, v.size - 1)])


def wmean(values, weights) -> float:
    """Weighted mean over the finite values (NaN when none)."""
    v = np.asarray(values, float)
    w = np.asarray(weights, float)
    ok = np.isfinite(v) & (w > 0)
    return float(np.sum(w[ok] * v[ok]) / np.sum(w[ok])) if ok.any() else float("nan")


def psnr_of_mse(mse) -> float:
    """PSNR (dB, peak 1) of a mean squared error; +inf for 0, NaN for NaN."""
    m = float(mse)
    if np.isnan(m):
        return float("nan")
    return float("inf") if m == 0 else float(10.0 * np.log10(1.0 / m))


def mse_of_psnr(psnr) -> np.ndarray:
    """Frame MSE (peak 1) from PSNR: 10^(-psnr/10); inf PSNR -> 0, NaN stays NaN."""
    p = np.asarray(psnr, float)
    with np.errstate(over="ignore"):
        m = np.power(10.0, -p / 10.0)
    return np.where(np.isposinf(p), 0.0, m)


def quality(d: pd.DataFrame, by=(), conf: float = 0.95) -> pd.DataFrame:
    """Image-quality summary per group, over the frames where it is defined.

    Columns: n, nonfinite_pct (+ interval: weighted share of frames with a non-finite pixel, whose
    PSNR/SSIM are undefined), n_finite, psnr_median_db, psnr_q25_db, psnr_q75_db (weighted
    quantiles over finite frames; identical frames are +inf), psnr_mean_mse_db (PSNR of the
    weighted mean frame MSE over finite frames: an average that stays defined when some frames
    are identical), ssim_mean and lpips_mean (finite frames; LPIPS NaN where not computed),
    mean_footprint_pct (all frames)."""
    by = list(by)
    nf = rate(d, "nonfinite", by, conf, prefix="nf_")
    rows = []
    groups = d.groupby(by, sort=False, dropna=False) if by else [((), d)]
    for key, g in groups:
        key = key if isinstance(key, tuple) else (key,)
        fin = g[~g["nonfinite"].astype(bool)]
        w = record_weights(fin)
        ps = fin["psnr"].to_numpy(float)
        mse = mse_of_psnr(ps)
        row = dict(zip(by, key))
        row.update(
            n_finite=n_records(fin),
            psnr_median_db=wquantile(ps, w, 0.5),
            psnr_q25_db=wquantile(ps, w, 0.25),
            psnr_q75_db=wquantile(ps, w, 0.75),
            psnr_mean_mse_db=psnr_of_mse(wmean(mse, w)),
            ssim_mean=wmean(fin["ssim"].to_numpy(float), w),
            lpips_mean=wmean(fin["lpips"].to_numpy(float), w) if "lpips" in fin else np.nan,
            mean_footprint_pct=100 * wmean(g["footprint"].to_numpy(float), record_weights(g)),
        )
        rows.append(row)
    q = pd.DataFrame(rows)
    nf = nf.rename(columns={"nf_n": "n"})[by + ["n", "nf_rate", "nf_ci_lo", "nf_ci_hi"]]
    out = nf.merge(q, on=by, how="left") if by else pd.concat([nf, q], axis=1)
    for c, name in (("rate", "nonfinite_pct"), ("ci_lo", "nonfinite_ci_lo_pct"), ("ci_hi", "nonfinite_ci_hi_pct")):
        out.insert(len(by) + 1 + ("rate", "ci_lo", "ci_hi").index(c), name, 100 * out.pop(f"nf_{c}"))
    return out


def bootstrap(d: pd.DataFrame, fn, n_boot: int = 200, conf: float = 0.95, seed: int = 0, strata=STRATA):
    """Percentile bootstrap interval of a statistic fn(records) -> float, resampling records
    with replacement within each stratum (the design). Returns (lo, hi); NaN when undefined,
    which includes a stratum of a single record: resampling it always gives that record back, so
    its variance would count as 0 (one record alone gave a zero-width "interval")."""
    if (multiplicity(d) != 1).any():
        raise ValueError("bootstrap resamples records: it needs unfolded rows")
    strata = [c for c in strata if c in d]
    rng = np.random.default_rng(seed)
    idx = list(d.groupby(strata, sort=False).indices.values()) if strata else [np.arange(len(d))]
    if not idx or min(ix.size for ix in idx) < 2:
        return float("nan"), float("nan")
    vals = []
    for _ in range(n_boot):
        take = np.concatenate([ix[rng.integers(0, ix.size, ix.size)] for ix in idx])
        v = fn(d.iloc[take])
        if np.isfinite(v):
            vals.append(v)
    if len(vals) < max(10, n_boot // 2):
        return float("nan"), float("nan")
    a = (1 - conf) / 2
    return float(np.quantile(vals, a)), float(np.quantile(vals, 1 - a))
