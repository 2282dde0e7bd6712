"""The claims table: each quantitative claim of the paper, the value measured from these records
with its 95% interval, the paper's value, the margin of equivalence and a verdict (`paper` states
the values, the margins and the rule; `population.equivalence_verdict` applies it): "reproduced"
(the interval inside the margin), "differs" (wholly outside), "inconclusive" (neither, or under
three models), "not comparable" (a maximum over fewer upsets than the paper's, a guard factor at
another N), "not measured" (the records cannot say).

Each row names its population (real models or procedural scenes, never pooled: every row is
computed over one population's records), its N (the models at full size, or a matched N of the
size sweep) and its guard (guard: skips sh_rest; guard_all: the paper's Algorithm 1). The rows are
built next to their analyses (`criticality.field_rows`, `dose.dose_rows`, `dose.budget_rows`,
`guard.guard_rows`, `contamination.contamination_rows`, `theory.slope_row`,
`scaling.alpha_rows`, `scaling.guard_factor_row`, `scaling.matched_rows`,
`prediction.prediction_rows`); this module gathers them per population and adds the p_c and
sign-flip rows.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis import population
from seuwgpu.analysis.claimrows import (  # noqa: F401  (the names tools and tests use)
    OVER_MODELS,
    OVER_RECORDS,
    claim_range,
    over_models,
    per_model,
    per_model_table,
    row,
)
from seuwgpu.analysis.paper import (  # noqa: F401  (the names tools and tests use)
    FOOTPRINT_QUANTILES,
    MARGINS,
    PAPER,
    PAPER_BUDGET_K,
    PAPER_CHECKED,
    PAPER_CONTAMINATION_P,
    PAPER_DOSE_K_MAX,
    PAPER_FIELD_FOOTPRINT,
    PAPER_FIELD_RATES,
    PAPER_GUARDED_SITES,
    PAPER_INCONSISTENCIES,
    PAPER_PRIMITIVES,
    PRINTED,
    paper_bit_weighted,
    paper_budget_k_per_n,
    paper_half_unit,
    paper_heaviest_k_per_n,
)
from seuwgpu.analysis.records import (
    InsufficientData,
    model_file_scenes,
    scale_sign_flips,
    single_upsets,
    tag,
)
from seuwgpu.analysis.reliability import catastrophe_probability

GUARD_ARMS = ("guard", "guard_all")  # guard: skips sh_rest (l. 1056); guard_all: Algorithm 1
# which renderer profile the paper's numbers correspond to (docs/renderer.md, Profiles)
PAPER_PROFILE = "gsplat"
PAPER_PROFILE_NOTE = (
    "The paper rendered with gsplat's CUDA kernels, which form det = a*c - b*b in fp32: its numbers correspond "
    "to the gsplat profile (for a log-scale sign flip to e^5 or more the determinant cancels there; the strict "
    "profile, free of that cancellation, agrees with float64)."
)


def _arm_columns(rates: pd.DataFrame, arm: str) -> pd.DataFrame:
    """A `population.model_rates` table's estimates named after its arm: fields_pc_<arm>(_lo, _hi)
    and bits_pc_<arm>(_lo, _hi)."""
    names = {}
    for kind in ("fields", "bits"):
        names.update(
            {
                f"{kind}_p_c": f"{kind}_pc_{arm}",
                f"{kind}_ci_lo": f"{kind}_pc_{arm}_lo",
                f"{kind}_ci_hi": f"{kind}_pc_{arm}_hi",
            }
        )
    return rates[population.MODEL + list(names)].rename(columns=names)


def arm_model_rates(df: pd.DataFrame, conf: float = 0.95) -> dict:
    """{arm: population.model_rates} of fp32 without and with the guard, and "conf": what the p_c
    rows of claims_table and model_estimates rest on (the report computes it once for both); an arm
    without records is an empty table."""
    rates = {arm: population.model_rates(df, "fp32", arm, conf) for arm in ("none",) + GUARD_ARMS}
    return {**rates, "conf": conf}


def _rates_at(df: pd.DataFrame, conf: float, rates: dict | None) -> dict:
    """`rates` (arm_model_rates) if computed at `conf`, else computed here."""
    return rates if rates is not None and rates.get("conf") == conf else arm_model_rates(df, conf)


def model_estimates(df: pd.DataFrame, conf: float = 0.95, rates: dict | None = None) -> pd.DataFrame:
    """Per model, fp32: p_c as the equal-field mean and weighted by stored bits, without and with
    the guard, and the guard's share of the equal-field p_c (%, stratified 95% intervals).
    `rates`: arm_model_rates(df, conf) when already computed (used only at the same conf)."""
    rates = _rates_at(df, conf, rates)
    none = rates["none"]
    if none.empty:
        return pd.DataFrame()
    out = none[population.MODEL + ["n", "fields"]].merge(_arm_columns(none, "none"), on=population.MODEL)
    for arm in GUARD_ARMS:
        g = rates.get(arm, pd.DataFrame())
        if not len(g):
            continue
        out = out.merge(_arm_columns(g, arm), on=population.MODEL, how="left")
        share = population.guard_share(none, g)[population.MODEL + ["share"]]
        name = "guard_share" if arm == "guard" else f"{arm}_share"
        out = out.merge(share.rename(columns={"share": name}), on=population.MODEL, how="left")
    for c in out.columns:
        if c.startswith(("fields_pc", "bits_pc")) or c.endswith("_share"):
            out[c] = 100 * out[c]
    out.attrs.update(none.attrs)  # the provenance of the records the rates rest on
    return out


def sign_rows(df: pd.DataFrame, conf: float = 0.95) -> list[dict]:
    """The log-scale sign flip's mean and 99th-percentile footprint (fp32, no defense), per model then
    over models; the pooled bootstrap within cells beside."""
    s = single_upsets(df, "fp32", "none")
    sign = scale_sign_flips(s)
    if not len(sign):
        return [row("sign_mean"), row("sign_p99")]

    def mean_fp(x):
        return 100 * E.wmean(x["footprint"], x["weight"])

    def p99(x):
        return 100 * E.wquantile(x["footprint"], x["weight"], 0.99)

    rows = []
    for key, fn in (("sign_mean", mean_fp), ("sign_p99", p99)):
        if key == "sign_p99" and len(sign) < 100:
            # a resample's 99th percentile is at most the sample's largest value: with fewer than
            # 100 records the bootstrap's upper bound is that value, not a bound
            rows.append(row(key, fn(sign), basis=f"n = {len(sign):,} < 100: no bootstrap interval"))
            continue
        lo, hi = E.bootstrap(sign, fn, conf=conf)
        if not (np.isfinite(lo) and np.isfinite(hi)):  # one record a cell: no spread, no interval
            rows.append(row(key, fn(sign), basis=f"n = {len(sign):,}: one record a cell, no interval"))
            continue
        basis = f"n = {len(sign):,}; pooled: bootstrap within cells"
        if key == "sign_p99":
            basis += "; a quantile with its interval over models"
        rows.append(over_models(key, per_model(sign, fn), "v", basis, conf, (fn(sign), lo, hi), scale=1.0))
    return rows


def _pc_rows(df: pd.DataFrame, est: dict, results: dict, conf: float, manifests) -> list[dict]:
    """p_c as the plain mean of per-field rates (the paper's) and weighted by stored bits, without
    and with each guard arm; the guard's share of the per-field means; the paired share."""
    rows = []
    eq_pooled = {}
    # a model of SH degree 0 stores no sh_rest: the plain means are then over the five other
    # fields on both sides (Table 2's five: 0.7612), never a mean of 5 fields beside one of 6
    five = population.without_sh_rest(single_upsets(df, "fp32", "none"), manifests)
    eq_df = df[df["field"] != "sh_rest"] if five else df
    est_eq = {a: population.model_rates(eq_df, "fp32", a, conf) for a in ("none",) + GUARD_ARMS} if five else est
    n_fields = 5 if five else len(PAPER_FIELD_RATES)
    for dfn in ("none",) + GUARD_ARMS:
        g = single_upsets(df, "fp32", dfn)
        g = g[g["bit"] >= 0]
        per = est.get(dfn, pd.DataFrame())
        per_eq = est_eq.get(dfn, pd.DataFrame())
        key = "pc_none" if dfn == "none" else "pc_guard"
        kw = {} if dfn == "none" else {"guard": dfn}
        if not len(g):
            if dfn != "guard_all":
                rows += [row(key + ("_5" if five else ""), **kw), row(f"{key}_bits", **kw)]
            continue
        # coverage_pct: the claim is over every stored bit, and a campaign over some fields or
        # bits estimates the rate of those only, which says nothing of the claim
        r = catastrophe_probability(g, conf, pooled=True, manifests=manifests).iloc[0]
        cov = float(r["coverage_pct"])
        part = cov < 99.999
        basis = f"n = {int(r['n']):,}" + (f"; covers {cov:.3g}% of the stored bits" if part else "")
        if "pooled_over" in r:
            basis += f"; pooled over {r['pooled_over']}"
        ge = g[g["field"] != "sh_rest"] if five else g
        eq = E.rate(ge.assign(weight=population.equal_field_weights(ge)), "catastrophic", (), conf).iloc[0]
        eq_pooled[dfn] = 100 * eq["rate"]
        all_fields = bool(len(per_eq)) and int(per_eq["fields"].min()) == n_fields
        pooled = (100 * eq["rate"], 100 * eq["ci_lo"], 100 * eq["ci_hi"])
        b = basis + f"; each field weighs 1/{n_fields} within each model"
        if five:
            b += " (sh_rest left out: the population holds models of SH degree 0)"
        r1 = over_models(key + ("_5" if five else ""), per_eq, "fields_p_c", b, conf, pooled, **kw)
        rows.append(r1 | ({} if all_fields and not part else {"verdict": "not measured"}))
        pooled = (100 * r["p_c"], 100 * r["ci_lo"], 100 * r["ci_hi"])
        r2 = over_models(
            f"{key}_bits", per, "bits_p_c", basis + "; fields weigh by their stored bits", conf, pooled, **kw
        )
        rows.append(r2 | ({} if not part else {"verdict": "not measured"}))
    for arm in GUARD_ARMS:
        none, g = est_eq.get("none", pd.DataFrame()), est_eq.get(arm, pd.DataFrame())
        if not (len(none) and len(g)):
            if arm == "guard":
                rows.append(row("guard_share", guard=arm))
            continue
        share = population.guard_share(none, g).dropna(subset=["share"])
        pooled_share = np.nan
        if eq_pooled.get("none", 0) > 0 and arm in eq_pooled:
            pooled_share = 100 * (1 - eq_pooled[arm] / eq_pooled["none"])
        rows.append(
            over_models(
                "guard_share",
                share,
                "share",
                "per model 1 - p_c(guard) / p_c(none) on the per-field means; pooled: the same of the pooled means",
                conf,
                (pooled_share, np.nan, np.nan),
                guard=arm,
            )
        )
    gd = results.get("guard")
    pt = gd["paired"] if gd is not None else pd.DataFrame(columns=["precision"])
    pt = pt[pt["precision"] == "fp32"]  # like the p_c claims beside it, never a pool of precisions
    if len(pt):
        r = pt.iloc[0]
        rows.append(
            row(
                "guard_share_paired",
                r["share_neutralised_pct"],
                r["share_ci_lo_pct"],
                r["share_ci_hi_pct"],
                "paired sites, weighted",
                guard="guard",
            )
        )
    else:
        rows.append(row("guard_share_paired", guard="guard"))
    return rows


def _population_rows(
    df: pd.DataFrame, results: dict, conf: float, manifests, scenes: list[str] | None, group: str | None
) -> list[dict]:
    """Every claims row over one population's records (`results` already restricted to it)."""
    from seuwgpu.analysis.contamination import contamination_rows
    from seuwgpu.analysis.criticality import field_rows
    from seuwgpu.analysis.dose import budget_rows, dose_rows
    from seuwgpu.analysis.guard import guard_rows
    from seuwgpu.analysis.prediction import prediction_rows
    from seuwgpu.analysis.scaling import CAPTURE, PROCEDURAL, alpha_rows, guard_factor_row, matched_rows
    from seuwgpu.analysis.theory import slope_row

    est = _rates_at(df, conf, results.get("model_rates"))
    if scenes is not None:
        est = {k: (v[v["scene"].isin(scenes)] if isinstance(v, pd.DataFrame) else v) for k, v in est.items()}
    arms = tuple(a for a in GUARD_ARMS if (single_upsets(df, None, a)).shape[0]) or ("guard",)
    rows = sign_rows(df, conf)
    rows += _pc_rows(df, est, results, conf, manifests)
    rows.append(slope_row(results.get("theory")))
    rows += alpha_rows(results.get("size"), (group,) if group else (PROCEDURAL, CAPTURE))
    rows += dose_rows(results.get("dose_curves"), conf)
    pred = prediction_rows(results.get("prediction"), conf, scenes)
    rows += pred[:2]
    rows += field_rows(df, conf)
    rows += budget_rows(results.get("dose_curves"), conf)
    rows += guard_rows(df, results, conf, arms)
    rows += contamination_rows(df, conf)
    rows.append(guard_factor_row(results.get("size"), conf, scenes))
    rows += pred[2:]
    rows += matched_rows(df, conf)
    return rows


def _restrict(results: dict, df: pd.DataFrame, scenes: list[str]) -> dict:
    """The analysis results of the whole records cut to one population: tables per model are
    filtered; pooled results (the theory check, the paired guard table) are recomputed from the
    population's records; the classifier's are kept (prediction_rows says where they pool)."""
    from seuwgpu.analysis.guard import guard_analysis
    from seuwgpu.analysis.theory import theory_check

    out = dict(results)
    out.pop("model_rates", None)
    if isinstance(out.get("dose_curves"), pd.DataFrame):
        out["dose_curves"] = out["dose_curves"][out["dose_curves"]["scene"].isin(scenes)]
    for key, fn in (("theory", theory_check), ("guard", guard_analysis)):
        if key in out:
            try:
                out[key] = fn(df)
            except InsufficientData:
                out.pop(key)
    return out


def populations(df: pd.DataFrame, manifests: Iterable[dict] = ()) -> dict[str, list[str]]:
    """{population: its scenes} of the records (`population.population_of`), real models first."""
    ms = model_file_scenes(manifests)
    out: dict[str, list[str]] = {}
    for scene in pd.unique(df["scene"].astype(str)) if len(df) else []:
        out.setdefault(population.population_of(scene, ms), []).append(scene)
    return {k: out[k] for k in (population.REAL, population.PROCEDURAL) if k in out}


def _n_label(df: pd.DataFrame) -> str:
    s = single_upsets(df, None, None)
    if s.empty:
        return ""
    ns = sorted(int(n) for n in s["n_primitives"].unique())
    return f"full size: {ns[0]:,}" if len(ns) == 1 else f"full size: {ns[0]:,}..{ns[-1]:,}"


def claims_table(
    df: pd.DataFrame, results: dict | None = None, conf: float = 0.95, manifests: Iterable[dict] = ()
) -> pd.DataFrame:
    """The claims table from the records and, where given, analysis results already computed
    (keys "theory", "guard", "size", "dose_curves", "prediction" as the report's sections return
    them, "model_rates" as arm_model_rates): every row once per population (real models, procedural
    scenes), never over a pool of both. The per-model values behind each row over models are in
    `attrs["per_model"]` (records of `claimrows.per_model_table`)."""
    from seuwgpu.analysis.scaling import CAPTURE, PROCEDURAL

    results = results or {}
    manifests = list(manifests)
    pops = populations(df, manifests) or {population.REAL: []}
    tables = []
    for pop, scenes in pops.items():
        whole = len(pops) == 1
        sub = df if whole else df[df["scene"].astype(str).isin(scenes)]
        res = results if whole else _restrict(results, sub, scenes)
        group = None if whole else (PROCEDURAL if pop == population.PROCEDURAL else CAPTURE)
        rows = _population_rows(sub, res, conf, manifests, None if whole else scenes, group)
        t = pd.DataFrame(rows)
        s = single_upsets(sub, "fp32", None)
        n_models = s.groupby(population.MODEL).ngroups if len(s) else 0
        t.insert(0, "population", pop)
        if "N" not in t:
            t["N"] = np.nan
        t["N"] = t["N"].astype(object).fillna(_n_label(sub))
        # rows over the records (a bootstrap, bits, a held-out set) of one or two models: no firmer
        # verdict than the rows over models give them (those carry their own n_models)
        few = t["verdict"].isin(["reproduced", "differs"]) & t["n_models"].isna()
        few &= 0 < n_models < population.MIN_MODELS
        note = f"; {pop}: {n_models} model(s), under {population.MIN_MODELS}: inconclusive (was "
        t.loc[few, "basis"] = t.loc[few, "basis"] + note + t.loc[few, "verdict"] + ")"  # each row its own
        t.loc[few, "verdict"] = "inconclusive"
        tables.append(t)
    t = pd.concat(tables, ignore_index=True)
    # records, not a DataFrame: pandas compares attrs when it concatenates frames
    t.attrs["per_model"] = per_model_table(t).to_dict("records")
    t = t.drop(columns=[c for c in ("_per_model",) if c in t])
    cols = ["population", "claim", "N", "guard", "unit", "measured", "ci_lo", "ci_hi", "paper", "margin", "verdict"]
    t = t[cols + [c for c in t.columns if c not in cols]]
    return tag(t, single_upsets(df, None, None))


def sign_rows_by_profile(all_records: pd.DataFrame, conf: float = 0.95) -> pd.DataFrame:
    """The sign-flip rows (mean and 99th-percentile footprint, PSNR of the mean MSE without and with
    the guard) under each renderer profile the records hold, on the models measured under every
    profile (like with like; PAPER_PROFILE_NOTE: the paper's numbers are the gsplat profile's)."""
    from seuwgpu.analysis.guard import guard_rows

    if "profile" not in all_records or all_records.empty:
        return pd.DataFrame()
    s = single_upsets(all_records, "fp32", None)
    sets = [set(g["scene"].astype(str)) for _, g in s.groupby("profile", sort=False)]
    common = sorted(set.intersection(*sets)) if sets else []
    if not common:
        return pd.DataFrame()
    out = []
    for prof, d in s[s["scene"].astype(str).isin(common)].groupby("profile", sort=False):
        rows = sign_rows(d, conf) + [r for r in guard_rows(d, {}, conf) if r["key"].startswith("sign_psnr")]
        t = pd.DataFrame(rows).drop(columns=["_per_model"], errors="ignore")
        t.insert(0, "profile", prof)
        t.insert(0, "models", ", ".join(common))
        t["paper_profile"] = PAPER_PROFILE
        out.append(t)
    return pd.concat(out, ignore_index=True)
