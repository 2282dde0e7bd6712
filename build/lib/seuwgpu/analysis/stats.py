"""Statistics helpers: confidence intervals, campaign sample sizes, power-law fits, ROC AUC.

Conventions
-----------
* Proportions get **Wilson score intervals**, never the normal (Wald) approximation, which
  collapses to a zero-width interval at zero events. The Wilson interval is exact at the edges:
  its lower bound is 0 when k = 0 and its upper bound is 1 when k = n.
* `sample_size` is the per-cell sample size of Leveugle et al., "Statistical fault injection:
  quantified error and confidence", DATE 2009:  n = N / (1 + e^2 (N-1) / (t^2 p (1-p))), where
  N is the population (fault sites in the cell), e the margin of error, t the two-sided normal
  quantile of the confidence level and p the (unknown, worst case 0.5) proportion. With no
  population (N -> infinity) it is the familiar n = t^2 p (1-p) / e^2.
* `loglog_fit` fits log10(y) = exponent * log10(x) + intercept by least squares; R^2 is that of
  the fit in log-log space.

Only numpy and the standard library are needed, except `auc`, which uses scikit-learn.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from seuwgpu.campaign.plan import z_value

__all__ = [
    "wilson_interval",
    "PowerFit",
    "LinearFit",
    "loglog_fit",
    "linear_fit",
    "auc",
    "kish_effective_n",
    "stratified_rate",
]


def wilson_interval(k, n, conf: float = 0.95):
    """Wilson score interval for k successes in n trials, vectorised.

    Returns (lower, upper) with the shape of the broadcast inputs (floats for scalar inputs).
    Exact at the edges: lower = 0 when k = 0, upper = 1 when k = n. Where n = 0 the interval is
    undefined and both bounds are NaN.
    """
    k_arr = np.asarray(k, dtype=float)
    n_arr = np.asarray(n, dtype=float)
    if np.any(k_arr < 0) or np.any(k_arr > n_arr):
        raise ValueError("wilson_interval needs 0 <= k <= n")
    z = z_value(conf)
    z2 = z * z
    with np.errstate(invalid="ignore", divide="ignore"):
        p = k_arr / n_arr
        denom = 1.0 + z2 / n_arr
        centre = (p + z2 / (2.0 * n_arr)) / denom
        half = (z / denom) * np.sqrt(p * (1.0 - p) / n_arr + z2 / (4.0 * n_arr * n_arr))
        lo = np.clip(centre - half, 0.0, 1.0)
        hi = np.clip(centre + half, 0.0, 1.0)
    lo = np.where(k_arr == 0, 0.0, lo)
    hi = np.where(k_arr == n_arr, 1.0, hi)
    empty = n_arr == 0
    lo = np.where(empty, np.nan, lo)
    hi = np.where(empty, np.nan, hi)
    if lo.ndim == 0:
        return float(lo), float(hi)
    return lo, hi


class PowerFit(NamedTuple):
    """y = 10**intercept * x**exponent, fitted in log10-log10 space."""

    exponent: float
    intercept: float
    r2: float


class LinearFit(NamedTuple):
    slope: float
    intercept: float
    r2: float


def linear_fit(x, y) -> LinearFit:
    """Least-squares line y = slope * x + intercept over the finite points, with R^2."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 2 or np.ptp(x) == 0:
        raise ValueError("a line fit needs at least two distinct finite x values")
    slope, intercept = np.polyfit(x, y, 1)
    resid = y - (slope * x + intercept)
    ss_res = float(np.sum(resid**2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else (1.0 if ss_res == 0 else 0.0)
    return LinearFit(float(slope), float(intercept), float(r2))


def loglog_fit(x, y) -> PowerFit:
    """Fit y = A x^b in log10-log10 space; returns (exponent b, intercept log10 A, R^2).

    Points with non-positive or non-finite x or y are dropped (they have no logarithm); at least
    two distinct x values must remain.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if ok.sum() < 2:
        raise ValueError("a log-log fit needs at least two points with positive x and y")
    f = linear_fit(np.log10(x[ok]), np.log10(y[ok]))
    return PowerFit(f.slope, f.intercept, f.r2)


def auc(y, score) -> float:
    """ROC AUC of a score for binary labels y (NaN when y holds a single class)."""
    from sklearn.metrics import roc_auc_score

    y = np.asarray(y).astype(bool)
    score = np.asarray(score, dtype=float)
    if y.size == 0 or y.all() or not y.any():
        return float("nan")
    return float(roc_auc_score(y, score))


def kish_effective_n(weights, n) -> float:
    """Effective sample size of a stratified mean: 1 / sum_h (w_h^2 / n_h), weights summing to 1.

    This is the n a simple random sample would need for the same variance when the strata share
    one proportion; used to put a Wilson interval on a stratified rate (see `stratified_rate`).
    """
    w = np.asarray(weights, dtype=float)
    n = np.asarray(n, dtype=float)
    ok = n > 0
    w = w[ok] / w[ok].sum()
    return float(1.0 / np.sum(w * w / n[ok]))


def stratified_rate(k, n, weights, conf: float = 0.95):
    """Population rate from per-stratum counts: p = sum_h w_h k_h / n_h.

    Strata with n_h = 0 are dropped and the remaining weights renormalised (the caller reports
    coverage). The interval is a Wilson interval at the Kish effective sample size n_eff (with
    k_eff = p * n_eff), which stays honest at zero events where a normal approximation collapses.
    Returns (p, lo, hi, n_eff).
    """
    k = np.asarray(k, dtype=float)
    n = np.asarray(n, dtype=float)
    w = np.asarray(weights, dtype=float)
    ok = n > 0
    if not ok.any():
        return float("nan"), float("nan"), float("nan"), 0.0
    w = w[ok] / w[ok].sum()
    p = float(np.sum(w * k[ok] / n[ok]))
    n_eff = kish_effective_n(w, n[ok])
    lo, hi = wilson_interval(min(p * n_eff, n_eff), n_eff, conf)
    return p, lo, hi, n_eff
