"""The models as the population: per-model estimates, an interval over models, and a verdict.

The study's records come from a handful of models (scenes). A rate pooled over their records with a
stratified interval describes those models and nothing beyond them: with millions of records any
difference between models reads as a difference from the paper. To speak of 3DGS models in
general, each model gives one estimate and the interval is over models: the Student-t interval of
their mean (n_models - 1 degrees of freedom), which carries the between-model variation.

A claims row's verdict is `claim_verdict` (the claims table's rows, the mantissa slope's fit windows,
tools/claims_from_tables.py): the paper's value and margin of the row's key, then the rule
`equivalence_verdict` against a paper value v printed to half-unit h (`paper.paper_half_unit`) with
the row's equivalence margin (`paper.MARGINS`, stated before the numbers):
* the band: [(v - h) / f, (v + h) * f] for a factor f, [v - h - d, v + h + d] for an absolute d, and
  [0, bound] for a paper value of 0 (an upper bound: `paper.ZERO_BOUND`);
* "reproduced" when the whole 95% interval lies inside the band: two one-sided tests at 2.5% each
  reject "below the band" and "above the band";
* "differs" when the whole interval lies outside the band (above or below);
* "inconclusive" otherwise, with fewer than MIN_MODELS models (one model never gives a firmer
  verdict than two), without an interval, or without a margin;
* "no paper value" for this project's own estimates, "not comparable" for a maximum not taken at
  the paper's number of upsets (`paper.TAIL_MAXIMA`), and "inconclusive" for an interval over the
  records of both populations pooled (`POOLED`).

Populations (`population_of`): the real models (model files, and the embedded captures) and the
procedural scenes are never pooled: the claims table computes each population's rows apart.

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
from seuwgpu.analysis.paper import PAPER, PRINTED, TAIL_MAXIMA, margin_of, paper_half_unit
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


REAL, PROCEDURAL = "real models", "procedural scenes"


def population_of(scene: str, model_scenes=frozenset()) -> str:
    """REAL for a model file's label (`records.model_file_scenes`: a corpus model named "plant" is
    not the procedural plant) or an embedded capture, PROCEDURAL for an embedded procedural scene;
    a label the runs do not state (records made elsewhere) counts as a real model."""
    from seuwgpu.model.scenes import SCENES

    return PROCEDURAL if scene in SCENES and scene not in model_scenes else REAL


def without_sh_rest(d: pd.DataFrame, manifests=()) -> bool:
    """Whether the models of `d` (single-upset records) include one that stores no sh_rest (SH degree
    0): the runs' specs say so (`records.scene_degrees`), or, where they do not, some models have
    sh_rest records and others none. The plain mean of per-field rates is then over the five other
    fields on both sides (`paper.paper_pc_without_sh_rest`)."""
    from seuwgpu.analysis.records import scene_degrees

    if d.empty:
        return False
    degrees = scene_degrees(manifests)
    if any(degrees.get(str(s)) == 0 for s in d["scene"].unique()):
        return True
    has = d.assign(_sh=d["field"] == "sh_rest").groupby(MODEL)["_sh"].any()
    return bool(has.any()) and not bool(has.all())


def equivalence_band(paper: float, half_unit: float, margin: tuple[str, float] | None) -> tuple[float, float]:
    """The values the margin calls the paper's (module notes); (NaN, NaN) without a margin."""
    if margin is None or not np.isfinite(paper):
        return np.nan, np.nan
    kind, m = margin
    if kind == "bound":
        return -np.inf, max(m, half_unit)
    if kind == "factor":
        lo, hi = (paper - half_unit) / m, (paper + half_unit) * m
        return (lo, hi) if paper > 0 else (hi, lo)
    return paper - half_unit - m, paper + half_unit + m


POOLED = "both populations, pooled"  # an interval over both populations' records: no verdict
NOT_COMPARABLE = "not comparable"


def claim_verdict(
    key: str, lo: float, hi: float, n_models: int | None = None, population: str | None = None, matched: bool = True
) -> str:
    """The verdict of the claims row `key` (`paper.PAPER`) on its 95% interval [lo, hi] (module
    notes): n_models, the models the interval is over, or None for an interval over the records (a
    bootstrap, bits, a held-out set: counted as MIN_MODELS here, the claims table holds it to its
    population's models); population: the row's, POOLED for both pooled (no verdict); matched:
    False for a maximum (`paper.TAIL_MAXIMA`) over another number of upsets than the paper's. An
    interval over the records without its ends is "not measured"."""
    paper = PAPER[key][2]
    if not np.isfinite(paper):
        return "no paper value"
    if key in TAIL_MAXIMA and not matched:
        return NOT_COMPARABLE
    if population == POOLED:
        return "inconclusive"
    if n_models is None and (np.isnan(lo) or np.isnan(hi)):
        return "not measured"
    n = MIN_MODELS if n_models is None else n_models
    return equivalence_verdict(lo, hi, paper, paper_half_unit(PRINTED.get(key, paper)), margin_of(key), n)


def equivalence_verdict(lo: float, hi: float, paper: float, half_unit: float, margin, n_models: int) -> str:
    """reproduced / differs / inconclusive against the margin's band (module notes). An interval at
    -inf on both ends (a PSNR over frames of which some are non-finite) lies below any band."""
    if n_models < MIN_MODELS or margin is None or np.isnan(lo) or np.isnan(hi) or not np.isfinite(paper):
        return "inconclusive"
    blo, bhi = equivalence_band(paper, half_unit, margin)
    if hi < blo or lo > bhi:
        return "differs"
    if blo <= lo and hi <= bhi:
        return "reproduced"
    return "inconclusive"


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
