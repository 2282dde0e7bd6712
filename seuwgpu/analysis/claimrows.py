"""One row of the claims table: the value measured with its 95% interval, the paper's value, the
margin and the verdict (`population.claim_verdict`), and over what the interval is taken.

Every analysis module builds its own claims rows with these (`dose.dose_rows`,
`scaling.alpha_rows`, `guard.guard_rows`, ...); `claims.claims_table` gathers them per population.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

from seuwgpu.analysis import population
from seuwgpu.analysis.paper import PAPER, margin_text, paper_upsets
from seuwgpu.analysis.population import claim_verdict

OVER_MODELS = "models (t, n-1 df)"
OVER_RECORDS = "records of these models"


def row(
    key,
    value=np.nan,
    lo=np.nan,
    hi=np.nan,
    basis="",
    measures_claim=True,
    n_models=None,
    pooled=None,
    guard=None,
    per_model=None,
):
    """measures_claim=False: the value is not the claim's quantity (basis says why): no verdict.
    With n_models the interval is over models (`analysis.population`); without, over the records
    (a bootstrap, bits, a held-out set), and the claims table holds the verdict to the number of
    models its population has. pooled: (value, lo, hi) over the records of these models, beside.
    guard: the arm a guarded row measured (guard: skips sh_rest; guard_all: the paper's Algorithm 1).
    per_model: the per-model values (a DataFrame with scene, n_primitives, v), for the per-model table."""
    claim, unit, paper = PAPER[key]
    over = OVER_RECORDS if n_models is None else OVER_MODELS
    pv, plo, phi = pooled if pooled is not None else (np.nan, np.nan, np.nan)
    verdict = claim_verdict(key, lo, hi, n_models) if measures_claim and not np.isnan(value) else "not measured"
    if verdict == "not measured" and measures_claim and not np.isnan(value):
        basis = (basis + "; " if basis else "") + "no interval"
    if guard not in (None, "guard"):  # the guard column names every row's; the text only the other arms'
        claim = f"{claim} [{guard}]"
    out = {
        "claim": claim,
        "key": key,
        "unit": unit,
        "measured": value,
        "ci_lo": lo,
        "ci_hi": hi,
        "paper": paper,
        "margin": margin_text(key),
        "verdict": verdict,
        "interval_over": over,
        "n_models": np.nan if n_models is None else n_models,
        "guard": guard if guard is not None else ("guard" if "guard" in key else "none"),
        "pooled": pv,
        "pooled_lo": plo,
        "pooled_hi": phi,
        "basis": basis,
    }
    if per_model is not None and len(per_model):
        out["_per_model"] = per_model
    return out


def claim_range(key: str) -> tuple[float, float]:
    """The values a claim's quantity can take: a t interval over a few models can run past them
    (a rate below 0, a share above 100%), and is cut there."""
    unit = PAPER[key][1]
    if key == "guard_share":
        return -np.inf, 100.0  # the guard may make things worse, never better than all
    if unit in ("%", "% of frame"):
        return 0.0, 100.0
    if key.startswith("auc"):
        return 0.0, 1.0
    if key.endswith(("guard_factor", "mean_mse")) or key.startswith("budget"):
        return 0.0, np.inf
    return -np.inf, np.inf


class ModelsInterval(NamedTuple):
    """A claim's mean over models with its interval as its row gives it (`models_interval`)."""

    mean: float
    lo: float
    hi: float
    n_models: int
    at_neg_inf: int  # models at -inf
    cut: list[str]  # the ends cut to the quantity's range, as the basis says them


def models_interval(key: str, values, conf: float = 0.95, scale: float = 1.0) -> ModelsInterval:
    """The t interval over one value a model (times `scale`), cut to the values the quantity can
    take (claim_range). A model at -inf (a PSNR over frames of which some are non-finite) makes the
    mean -inf: the interval is [-inf, -inf] when every model is there, else [-inf, NaN]; a model
    without a value (NaN) is not one of them. Under two models: no interval (NaN)."""
    vals = np.asarray(values, dtype=float)
    neg = np.isneginf(vals)
    if neg.any():
        n = int(np.isfinite(vals).sum() + neg.sum())
        hi = -np.inf if neg.sum() == n else np.nan
        return ModelsInterval(-np.inf, -np.inf, hi, n, int(neg.sum()), [])
    om = population.interval_over_models(vals, conf)
    if om.n_models < 2:
        return ModelsInterval(scale * om.mean, np.nan, np.nan, om.n_models, 0, [])
    low, high = claim_range(key)
    lo, hi = scale * om.lo, scale * om.hi
    cut = [f"{name} {v:.4g} cut to {bound:g}" for name, v, bound in (("lower", lo, low), ("upper", hi, high))]
    cut = [c for c, over in zip(cut, (lo < low, hi > high)) if over]
    return ModelsInterval(
        scale * om.mean,
        min(max(lo, low), high) if np.isfinite(lo) else lo,
        max(min(hi, high), low) if np.isfinite(hi) else hi,
        om.n_models,
        0,
        cut,
    )


def over_models(key, per_model: pd.DataFrame, column: str, basis: str, conf: float, pooled=None, scale=100.0, **kw):
    """The claim's row over models (`models_interval`). Records of one model give its value but no
    interval over models, so no firmer verdict than two ("inconclusive"); the pooled records'
    interval stays beside. The basis says where the interval was cut to the quantity's range."""
    vals = per_model[column].to_numpy(float) if len(per_model) else np.array([])
    pm = None
    if len(per_model):
        pm = per_model.assign(v=scale * vals)
        pm = pm.assign(**{c: pm[c] if c in pm else np.nan for c in population.MODEL})[population.MODEL + ["v"]]
    per = "; ".join(f"{r['scene']} {scale * r[column]:.4g}" for _, r in per_model.iterrows())
    mi = models_interval(key, vals, conf, scale)
    mean = mi.mean
    if mi.at_neg_inf:
        b = f"{basis}; per model: {per}; {mi.at_neg_inf} of {mi.n_models} models at -inf"
    elif mi.n_models < 2:
        b = f"{basis}; one model: no interval over models" + (f" ({per})" if per else "")
        if not mi.n_models:
            mean = pooled[0] if pooled is not None else np.nan
    else:
        b = f"{basis}; per model: {per}"
        if mi.cut:
            b += f"; t interval {', '.join(mi.cut)} (the quantity's range)"
    return row(key, mean, mi.lo, mi.hi, b, n_models=mi.n_models, pooled=pooled, per_model=pm, **kw)


def per_model(d: pd.DataFrame, fn) -> pd.DataFrame:
    """One value a model: fn over each model's records (column v)."""
    return pd.DataFrame(
        [{"scene": k[0], "n_primitives": k[1], "v": fn(g)} for k, g in d.groupby(population.MODEL, sort=False)],
        columns=population.MODEL + ["v"],
    )


def matched_maximum(values, n_paper: int, reps: int = 200, seed: int = 0) -> tuple[float, float, float]:
    """The maximum of `n_paper` values drawn without replacement from `values` (the records' own,
    unweighted: equal upsets a cell, as the paper's design): its mean over `reps` seeded subsamples
    and their 2.5 and 97.5 percentiles. NaN when there are fewer values than the paper's upsets: a
    maximum grows with the sample, and one over fewer upsets is not the paper's quantity."""
    v = np.asarray(values, float)
    if v.size < n_paper or n_paper < 1:
        return np.nan, np.nan, np.nan
    rng = np.random.default_rng(seed)
    maxima = np.array([np.nanmax(rng.choice(v, n_paper, replace=False)) for _ in range(reps)])
    return float(maxima.mean()), float(np.percentile(maxima, 2.5)), float(np.percentile(maxima, 97.5))


def tail_row(key: str, values, basis: str, pooled_value: float, **kw) -> dict:
    """A maximum compared at the paper's number of upsets (`paper.paper_upsets`): subsampled to it
    where the records hold as many, else the row says "not comparable" (the pooled maximum beside)."""
    n_paper = paper_upsets(key)
    v = np.asarray(values, float)
    m, lo, hi = matched_maximum(v, n_paper)
    if np.isnan(m):
        r = row(
            key,
            pooled_value,
            basis=f"{basis}; a maximum over {v.size:,} upsets, the paper's over {n_paper:,}: a maximum grows "
            "with the sample",
            **kw,
        )
        return r | {"verdict": claim_verdict(key, np.nan, np.nan, matched=False)}
    return row(
        key,
        m,
        lo,
        hi,
        f"{basis}; the maximum of {n_paper:,} upsets (the paper's number) drawn from {v.size:,}, mean and 95% "
        "range over 200 seeded subsamples",
        pooled=(pooled_value, np.nan, np.nan),
        **kw,
    )


def per_model_table(t: pd.DataFrame) -> pd.DataFrame:
    """The per-model values behind each row over models (claims_models_long): one row a (claim, model)."""
    if "_per_model" not in t:
        return pd.DataFrame(columns=["population", "claim", "guard", "scene", "n_primitives", "value"])
    rows = []
    for _, r in t.iterrows():
        pm = r["_per_model"]
        if not isinstance(pm, pd.DataFrame):
            continue
        for _, m in pm.iterrows():
            rows.append(
                {
                    "population": r.get("population", ""),
                    "claim": r["claim"],
                    "N": r.get("N", ""),
                    "guard": r["guard"],
                    "scene": m["scene"],
                    "n_primitives": m["n_primitives"],
                    "value": m["v"],
                    "unit": r["unit"],
                }
            )
    return pd.DataFrame(rows)
