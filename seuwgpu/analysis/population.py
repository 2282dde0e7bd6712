"""The models as the population: per-model estimates, an interval over models, and a verdict.

The study's records come from a handful of models (scenes). A rate pooled over their records with a
stratified interval describes those models and nothing beyond them: with millions of records any
difference between models reads as a difference from the paper. To speak of 3DGS models in
general, each model gives one estimate and the interval is over models: the Student-t interval of
their mean (n_models - 1 degrees of freedom), which carries the between-model variation.

Verdict against a paper value v printed to half-unit h (`claims.paper_half_unit`):
* "inconclusive" with fewer than MIN_MODELS models, or when the interval holds the paper's value
  and also holds 0 (the models cannot tell the paper's number from no effect at all);
* "differs" when the interval misses [v - h, v + h];
* "reproduced" otherwise.

p_c two ways (paper Table 2 gives per-field rates, and its 0.634% is their plain mean):
* equal-field: the mean over fields of each field's rate (every field weighs the same);
* stored-bit-weighted: an upset uniform over every stored bit (fields weigh by their bits), this
  project's own estimate; Table 2 weighted the same way is `claims.paper_bit_weighted`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import multiplicity, single_upsets, tag
from seuwgpu.errors import require

MIN_MODELS = 3  # fewer models than this give no verdict (a t interval on 1 degree of freedom is +-12.7 sd)
MODEL = ["scene", "n_primitives"]


class OverModels(NamedTuple):
    """Mean of per-model estimates with its Student-t interval (NaN under two models)."""

    mean: float
    lo: float
    hi: float
    n_models: int
    sd: float


def interval_over_models(values, conf: float = 0.95) -> OverModels:
    """t interval of the mean of one estimate per model (finite values only)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    n = int(v.size)
    if n == 0:
        return OverModels(np.nan, np.nan, np.nan, 0, np.nan)
    mean = float(v.mean())
    if n < 2:
        return OverModels(mean, np.nan, np.nan, n, np.nan)
    student_t = require("scipy.stats", "analysis", "the t interval over models").t

    sd = float(v.std(ddof=1))
    half = float(student_t.ppf(0.5 + conf / 2, n - 1)) * sd / np.sqrt(n)
    return OverModels(mean, mean - half, mean + half, n, sd)


def verdict(lo: float, hi: float, paper: float, half_unit: float, n_models: int) -> str:
    """reproduced / differs / inconclusive (module notes)."""
    if n_models < MIN_MODELS or not (np.isfinite(lo) and np.isfinite(hi)) or not np.isfinite(paper):
        return "inconclusive"
    if hi < paper - half_unit or lo > paper + half_unit:
        return "differs"
    if lo <= 0 <= hi:
        return "inconclusive"
    return "reproduced"


def equal_field_weights(d: pd.DataFrame) -> np.ndarray:
    """Record weights rescaled so that every field of a model weighs the same (its bits keep their
    shares within the field): the weighted rate is then the plain mean of the per-field rates."""
    w = d["weight"].to_numpy(float)
    # the stored bits a row stands for: a folded row's records, or a cell row's (analysis.cells)
    stands = w * (d["n_records"].to_numpy(float) if "n_records" in d else multiplicity(d))
    keys = [c for c in MODEL + ["precision", "defense"] if c in d]
    field_total = d.assign(_w=stands).groupby(keys + ["field"], sort=False)["_w"].transform("sum").to_numpy(float)
    n_fields = d.groupby(keys, sort=False)["field"].transform("nunique").to_numpy(float)
    model_total = d.assign(_w=stands).groupby(keys, sort=False)["_w"].transform("sum").to_numpy(float)
    return np.where(field_total > 0, w / np.where(field_total > 0, field_total, 1.0) * model_total / n_fields, 0.0)


def model_rates(df: pd.DataFrame, precision: str = "fp32", defense: str = "none", conf: float = 0.95) -> pd.DataFrame:
    """Per model: p_c weighted by stored bits and p_c as the equal-field mean, each a stratified
    rate with its interval (proportions); `fields`: how many fields were sampled."""
    s = single_upsets(df, precision, defense)
    s = s[s["bit"] >= 0]
    cols = MODEL + ["precision", "defense", "n", "fields"]
    cols += [f"{p}{c}" for p in ("bits_", "fields_") for c in ("p_c", "ci_lo", "ci_hi")]
    if s.empty:
        return pd.DataFrame(columns=cols)
    by = MODEL + ["precision", "defense"]
    bits = E.rate(s, "catastrophic", by, conf)
    eq = E.rate(s.assign(weight=equal_field_weights(s)), "catastrophic", by, conf)
    out = bits[by + ["n"]].copy()
    out["fields"] = s.groupby(by, sort=False)["field"].nunique().to_numpy()
    for prefix, r in (("bits_", bits), ("fields_", eq)):
        out[f"{prefix}p_c"] = r["rate"].to_numpy()
        out[f"{prefix}ci_lo"] = r["ci_lo"].to_numpy()
        out[f"{prefix}ci_hi"] = r["ci_hi"].to_numpy()
    return tag(out[cols], s)


def guard_share(none: pd.DataFrame, guard: pd.DataFrame, column: str = "fields_p_c") -> pd.DataFrame:
    """Per model, 1 - p_c(guard) / p_c(none) from two `model_rates` tables (NaN where p_c(none) is 0)."""
    m = none[MODEL + [column]].merge(guard[MODEL + [column]], on=MODEL, suffixes=("_none", "_guard"))
    a, b = m[f"{column}_none"].to_numpy(float), m[f"{column}_guard"].to_numpy(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        m["share"] = np.where(a > 0, 1.0 - b / a, np.nan)
    return m
