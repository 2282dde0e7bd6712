"""Reliability under realistic upset rates: p_c, the probability that one upset uniform over the
stored bits is catastrophic, and the mean time between catastrophic frames (MTBF) with upsets
accumulating between scrubs.

* p_c per (precision, defense): the weighted rate of the single-upset campaign
  (`estimate.rate`, stratified interval). The MTBF uses it alone, with each row's regime: the
  expected upsets alive per scrub interval (rate x stored bits x interval, column
  live_upsets_per_scrub). The dose
  fit's p (`dose.dose_fits`) describes k in the tens to thousands alive together, where an
  upset's footprint past 1% of the frame adds to others': a regime these rates never reach, so the
  report's MTBF uses p_c alone; `reliability(dose_fits=...)` still adds the fit's rows on request,
  each model's own.
* Per model: records of several models (several (scene, n_primitives) of the single-upset
  campaign: several trained models) give each model its own p_c and interval, its own stored bits
  (its primitive count x components x bits per value), its own dose-fit p (that scene's fit) and
  its own MTBF rows, with `scene` and `n_primitives` columns. An MTBF of a p_c averaged over models
  and of their mean size would describe none of them. A p_c pooled over models
  (`catastrophe_probability(pooled=True)`, weighted by stored bits, labelled `pooled_over`) exists
  only to set one number beside the paper's (claims table); `mtbf_table` refuses it. Records of
  one model give the tables they always gave (no model columns).
* Accumulation: upsets arrive as a Poisson process of rate L = lambda * b (per-bit rate times
  stored bits) and stay until the next scrub (every T hours), when the model is restored. Under
  the dose model the first catastrophic state after a scrub comes at rate L * p, so an interval
  sees a catastrophic frame with probability q = 1 - exp(-L p T), the mean time between such
  intervals is MTBF = T / q (-> 1 / (L p) for frequent scrubs, -> T when every interval is hit),
  and the share of frames that are catastrophic is 1 - (1 - exp(-x)) / x with x = L p T.
* A check defense (parity, checksum, ...: `faults/defenses.py`) repairs what it detects only at
  its next check, every S frames: the catastrophes it repairs (its p_c below none's) are drawn
  until then, (S - 1) / 2 frames on average (`schedule.exposure`), and its MTBF rows count them
  (`with_exposure`, column exposure_hours). S and the frame rate are spec parameters
  ([reliability] check_every: one S or a {defense: S} table, frames_per_second; defaults
  schedule.DEFAULT_CHECK_EVERY = 10 and 30), so a check defense's MTBF is bounded by default:
  at S = 1 what it repairs would never be drawn and a check that left no residue would have an
  MTBF without bound. The report states S and where it came from.
* Upset rates and the scrub interval are spec parameters ([reliability] rates = [...],
  scrub_hours = ...); the defaults below name their sources. They are orders of magnitude, so the
  sensitivity figure shows the MTBF over the whole range of rates.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import (
    DEFAULT_SH_DEGREE,
    InsufficientData,
    figure,
    prepare,
    provenance,
    record_weights,
    reference_precision,
    scene_degrees,
    series_color,
    sh_degree_of,
    single_upsets,
    sort_rows,
    tag,
)
from seuwgpu.campaign.spec_types import stored_table
from seuwgpu.faults.defenses import REGISTRY as dfn_registry
from seuwgpu.faults.defenses import guard_arm
from seuwgpu.faults.schedule import DEFAULT_CHECK_EVERY, check_every_of
from seuwgpu.model import encoding
from seuwgpu.model.fields import field_components, n_components, sh_rest_count

DEFAULT_SCRUB_HOURS = 24.0  # assumption: a daily scrub (reload) of the model from protected storage

HOURS_PER_YEAR = 24.0 * 365.25

# Upset rates per stored bit per hour. Order-of-magnitude inputs, not measurements of any device;
# the MTBF table is relative. 1 FIT/Mbit = 1e-9 upsets per hour per 1e6 bits = 1e-15 /bit/h.
UPSET_RATES = (
    {
        "environment": "ground (sea level)",
        "per_bit_hour": 1.0e-12,  # 1,000 FIT/Mbit
        "source": (
            "~10^3 FIT/Mbit, the order of unprotected SRAM soft-error rates at sea level "
            "(Baumann, IEEE TDMR 5(3) 2005; Normand, IEEE TNS 43(6) 1996), at the JEDEC "
            "JESD89A reference neutron flux (~13 n/cm^2/h, New York City). Commodity "
            "DRAM/HBM is lower per bit."
        ),
    },
    {
        "environment": "avionics (~10-12 km)",
        "per_bit_hour": 3.0e-10,  # 300 x ground
        "source": (
            "ground rate x 300: the atmospheric neutron flux at aircraft cruise altitude "
            "is roughly 300x the sea-level flux (Normand 1996; JESD89A altitude scaling)."
        ),
    },
    {
        "environment": "low-Earth orbit",
        "per_bit_hour": 1.0e-7 / 24.0,  # 1e-7 upsets/bit/day
        "source": (
            "~1e-7 upsets/bit/day, a typical order for commercial memories in LEO "
            "(published rates span ~1e-8 to 1e-6 /bit/day with orbit, shielding and "
            "South Atlantic Anomaly passes)."
        ),
    },
)


def format_duration(hours: float) -> str:
    """Human-readable duration: s, min, h, d or yr; "inf" for an unbounded one, "n/a" for an
    undefined one (NaN: no rate measured)."""
    if hours is None or np.isnan(hours):
        return "n/a"
    if not np.isfinite(hours):
        return "inf"
    s = hours * 3600
    if s < 60:
        return f"{s:.3g} s"
    if s < 3600:
        return f"{s / 60:.3g} min"
    if hours < 48:
        return f"{hours:.3g} h"
    if hours < 2 * HOURS_PER_YEAR:
        return f"{hours / 24:.3g} d"
    return f"{hours / HOURS_PER_YEAR:.3g} yr"


def reliability_parameters(manifests: Iterable[dict] = ()) -> tuple[list[dict], float, str]:
    """(rates, scrub_hours, where they came from): the runs' [reliability] table, else defaults."""
    for m in manifests or ():
        t = stored_table(m, "reliability")
        if t is not None:
            rates = [r.to_dict() for r in t.rates] if t.rates else list(UPSET_RATES)
            scrub = DEFAULT_SCRUB_HOURS if t.scrub_hours is None else t.scrub_hours
            return rates, float(scrub), "run spec [reliability]"
    return list(UPSET_RATES), DEFAULT_SCRUB_HOURS, "defaults (sources in the table)"


DEFAULT_FRAMES_PER_SECOND = 30.0


def check_schedule(manifests: Iterable[dict] = ()) -> tuple[int | dict, float, str]:
    """(check every S frames: one S or {defense: S}, frames per second, where S came from) of the
    runs' [reliability] table, else defaults: how long what a check defense repairs is drawn
    before it is (check_exposure)."""
    for m in manifests or ():
        t = stored_table(m, "reliability")
        if t is not None:
            s = t.check_every
            fps = float(DEFAULT_FRAMES_PER_SECOND if t.frames_per_second is None else t.frames_per_second)
            if s is not None:
                return (dict(s) if isinstance(s, dict) else int(s)), fps, "run spec [reliability]"
            return DEFAULT_CHECK_EVERY, fps, f"the default (S = {DEFAULT_CHECK_EVERY}; the spec names none)"
    return DEFAULT_CHECK_EVERY, DEFAULT_FRAMES_PER_SECOND, f"the default (S = {DEFAULT_CHECK_EVERY})"


MODEL = ["scene", "n_primitives"]


def _single_bits(df: pd.DataFrame) -> pd.DataFrame:
    """Single-upset records of one stored bit each (bit >= 0): what p_c is estimated from."""
    s = single_upsets(prepare(df), None, None)
    return s[s["bit"] >= 0]


def models_of(df: pd.DataFrame) -> pd.DataFrame:
    """The models (scene, n_primitives) of the single-upset campaign, in order of appearance, with
    `key` (the scene, or scene_N<n> when a scene holds several counts: summary.json keys) and
    `label` (the scene, or "scene (N=n)": tables and figures)."""
    return models_in(_single_bits(df))


def models_in(s: pd.DataFrame) -> pd.DataFrame:
    """The models (scene, n_primitives) of any records or per-model rows (`s`, e.g. the dose
    curves), in order of appearance, with `key` and `label` as models_of gives them."""
    m = s[MODEL].drop_duplicates().reset_index(drop=True)
    twice = m["scene"].duplicated(keep=False)
    n = m["n_primitives"].astype(np.int64)
    m["key"] = np.where(twice, m["scene"] + "_N" + n.astype(str), m["scene"])
    m["label"] = np.where(twice, m["scene"] + " (N=" + n.map("{:,}".format) + ")", m["scene"])
    return m


def model_degrees(df: pd.DataFrame, manifests: Iterable[dict] = ()) -> dict:
    """SH degree of each model (scene, n_primitives) of the single-upset records, each its own
    (a scene at degree 1 beside one at 3 has 23, not 59, components): from its sh_rest records'
    weights (the runner's weight is N x components / records of the cell, so a (precision,
    defense, bit) cell's weights sum to N x 3 x the sh_rest coefficients); a model without sh_rest
    records (degree 0, or sh_rest not sampled) from the runs' specs (`records.scene_degrees`:
    a degree-0 model read as degree 3 had 59 components counted for its 14, 4.2x its stored
    bits); else `records.sh_degree_of` of that model's records."""
    s = _single_bits(df)
    stated = scene_degrees(manifests)
    out = {}
    for (scene, n), g in s.groupby(MODEL, sort=False):
        sh = g[g["field"] == "sh_rest"]
        deg = None
        if len(sh):
            cell = (
                pd.Series(record_weights(sh), index=sh.index).groupby([sh["precision"], sh["defense"], sh["bit"]]).sum()
            )
            comps = float(np.median(cell.to_numpy(float))) / float(n)
            deg = next((d for d in range(4) if abs(3 * sh_rest_count(d) - comps) < 0.5), None)
        if deg is None:
            deg = stated.get(str(scene), sh_degree_of(g))
        out[(scene, n)] = deg
    return out


def _pooled_text(m: pd.DataFrame) -> str:
    names = ", ".join(f"{r.scene} (N={int(r.n_primitives):,})" for r in m.itertuples())
    return f"{len(m)} models, weighted by stored bits: {names}"


def catastrophe_probability(
    df: pd.DataFrame, conf: float = 0.95, pooled: bool = False, manifests: Iterable[dict] = ()
) -> pd.DataFrame:
    """p_c per (precision, defense) from the single-upset campaign: the weighted rate over the
    model's stored bits with the stratified interval; coverage_pct is the share of the stored bits
    whose (field, bit) cells were sampled.

    Records of several models (scene, n_primitives): a row per model (columns scene, n_primitives
    first), each its own stratified rate and interval. pooled=True gives instead one row per
    (precision, defense) over every model (an upset uniform over all their stored bits together,
    so weighted by stored bits), with a `pooled_over` column naming what it pools: a number to set
    beside the paper's single p_c, never an input of an MTBF (`mtbf_table` refuses it)."""
    s = _single_bits(df)
    if s.empty:
        raise InsufficientData(
            "no single-upset records to estimate p_c", "run a single-upset campaign over all fields and bits"
        )
    models = models_in(s)
    per_model = len(models) > 1 and not pooled
    by = (MODEL if per_model else []) + ["precision", "defense"]
    r = E.rate(s, "catastrophic", by, conf)
    degree = model_degrees(s, manifests)
    cov = []
    for key, g in s.groupby(by, sort=False):
        # stored bits of the sampled (field, bit) cells over the stored bits of the models, each
        # model with its own primitive count and SH degree
        have = g.groupby(["scene", "n_primitives", "field", "bit"]).size().reset_index()
        bits = encoding.BITS.get(key[-2], 32)
        deg = [degree[(a, b)] for a, b in zip(have["scene"], have["n_primitives"])]
        covered = sum(n * field_components(f, d) for n, f, d in zip(have["n_primitives"], have["field"], deg))
        ms = have[MODEL].drop_duplicates()
        total = sum(n * n_components(degree[(a, n)]) * bits for a, n in zip(ms["scene"], ms["n_primitives"]))
        degs = {degree[(a, n)] for a, n in zip(ms["scene"], ms["n_primitives"])}
        cov.append(
            {
                **dict(zip(by, key)),
                "coverage_pct": 100 * covered / total,
                # one model's degree; a pool of models of different degrees has none (-1)
                "sh_degree": degs.pop() if len(degs) == 1 else -1,
            }
        )
    out = r.rename(columns={"rate": "p_c"}).merge(pd.DataFrame(cov), on=by)
    out = sort_rows(out)
    if per_model:  # precision, then model (order of appearance), then defense
        rank = {tuple(k): i for i, k in enumerate(models[MODEL].itertuples(index=False))}
        porder = {p: i for i, p in enumerate(encoding.PRECISIONS)}
        key = out.assign(
            _p=out["precision"].map(lambda p: porder.get(p, 99)),
            _m=[rank[(a, b)] for a, b in zip(out["scene"], out["n_primitives"])],
        )
        out = out.loc[key.sort_values(["_p", "_m"], kind="stable").index].reset_index(drop=True)
    elif pooled and len(models) > 1:
        out.insert(0, "pooled_over", _pooled_text(models))
    return tag(out, s)


def pc_lookup(pc: pd.DataFrame, precision: str, defense: str):
    """The p_c row of one model at (precision, defense); None when there is none. A table of
    several models has several such rows: refused (select one model's rows first)."""
    g = pc[(pc["precision"] == precision) & (pc["defense"] == defense)]
    if len(g) > 1:
        raise ValueError(f"p_c of {len(g)} models at {precision}/{defense}: look it up in one model's rows")
    return None if g.empty else g.iloc[0]


def stored_bits(n_primitives: float, precision: str, sh_degree: int = DEFAULT_SH_DEGREE) -> float:
    """Stored bits of a model: primitives x components x bits per value."""
    return float(n_primitives) * n_components(sh_degree) * encoding.BITS[precision]


def mtbf(rate_per_bit_hour: float, bits: float, p: float, scrub_hours: float) -> float:
    """Mean time (h) between scrub intervals that hold a catastrophic frame (module notes);
    inf when p = 0; 1 / (L p) without scrubbing (scrub_hours = inf); NaN when p is (unmeasured)."""
    lam = float(rate_per_bit_hour) * float(bits) * float(p)
    if math.isnan(lam):
        return float("nan")
    if not lam > 0:
        return float("inf")
    if not math.isfinite(scrub_hours):
        return 1.0 / lam
    x = lam * scrub_hours
    return scrub_hours / -math.expm1(-x)


def catastrophic_frame_share(rate_per_bit_hour: float, bits: float, p: float, scrub_hours: float) -> float:
    """Share of frames that are catastrophic, upsets accumulating over a scrub interval (NaN when
    p is: undefined stays undefined)."""
    x = float(rate_per_bit_hour) * float(bits) * float(p) * scrub_hours
    if math.isnan(x):
        return float("nan")
    if not x > 0:
        return 0.0
    if not math.isfinite(x):
        return 1.0
    return 1.0 - (-math.expm1(-x)) / x


def check_exposure(check_every: int, frames_per_hour: float) -> tuple[float, float]:
    """(share of upsets a check every S frames lets be drawn at all, hours they are drawn on
    average): schedule.exposure over every phase, in hours at `frames_per_hour`."""
    from seuwgpu.faults.schedule import exposure

    ex = exposure(check_every)
    return float((ex.per_upset >= 1).mean()), ex.expected / float(frames_per_hour)


def with_exposure(
    mtbf_hours: float, share: float, rate_per_bit_hour: float, bits: float, p_repaired: float, exposure: tuple
) -> tuple[float, float]:
    """(MTBF h, catastrophic frame share) with the upsets a check repairs counted for what they
    are: a catastrophe (probability p_repaired per upset) drawn until the next check, `exposure`
    = (share drawn at all, mean hours drawn) from check_exposure, on top of the residual ones
    (mtbf_hours, share: those the check misses, which stay until the scrub)."""
    shown, hours = exposure
    r = float(rate_per_bit_hour) * float(bits) * max(float(p_repaired), 0.0)
    if math.isnan(r) or not r > 0:
        return mtbf_hours, share
    rate = (1.0 / mtbf_hours if mtbf_hours > 0 else float("inf")) + r * shown
    return (1.0 / rate if rate > 0 else float("inf")), min(1.0, share - math.expm1(-r * hours))


def live_upsets(rate_per_bit_hour: float, bits: float, scrub_hours: float) -> float:
    """Expected upsets alive in the model just before a scrub: rate x stored bits x interval."""
    return float(rate_per_bit_hour) * float(bits) * float(scrub_hours)


def regime(live: float) -> str:
    """Which p an MTBF may use at `live` expected upsets per scrub interval: below one, upsets
    come one at a time and the single-upset p_c is the probability that one is catastrophic; the
    dose fits' p describes tens to thousands of upsets alive together, a regime no listed
    environment reaches under a daily scrub."""
    if not np.isfinite(live):
        return "undefined"
    if live < 1:
        return "single upsets (< 1 live per scrub): single-upset p_c"
    return "several upsets live per scrub: p_c holds while they do not interact (see the dose fits)"


def mtbf_table(
    pc: pd.DataFrame,
    bits: float,
    precision: str,
    rates=UPSET_RATES,
    scrub_hours: float = DEFAULT_SCRUB_HOURS,
    defenses: tuple[str, ...] = ("none", "guard"),
    dose_p: dict | None = None,
    exposure: dict | None = None,
) -> pd.DataFrame:
    """MTBF per environment and defense of one model of `bits` stored bits, from its p_c
    (single-upset, stratified) and, where given, its dose fit (dose_p[defense] = (p, lo, hi) as
    proportions); bounds from the p interval (no event: unbounded above). `pc` holds one model's
    rows: a p_c pooled over models, or the rows of several, is refused (`reliability` calls this
    once per model). `exposure` {defense: check_exposure(...)}: a check defense's repaired upsets
    (p_c of none minus its own) are drawn for their exposure (with_exposure)."""
    if "pooled_over" in pc:
        raise ValueError(f"p_c pooled over {pc['pooled_over'].iloc[0]}: an MTBF needs one model's p_c and bits")
    if all(c in pc for c in MODEL) and len(pc[MODEL].drop_duplicates()) > 1:
        raise ValueError("p_c of several models: an MTBF needs one model's p_c and its own bits (select its rows)")
    rows = []
    sources = []
    for dfn in defenses:
        ref = pc_lookup(pc, precision, dfn)
        if ref is not None:
            sources.append((dfn, "single-upset p_c", float(ref["p_c"]), float(ref["ci_lo"]), float(ref["ci_hi"])))
        if dose_p and dfn in dose_p:
            sources.append((dfn, "dose fit p", *map(float, dose_p[dfn])))
    for env in rates:
        lam = float(env["per_bit_hour"])
        live = live_upsets(lam, bits, scrub_hours)
        for dfn, src, p, lo, hi in sources:
            t, t_lo, t_hi = (mtbf(lam, bits, x, scrub_hours) for x in (p, hi, lo))
            share = catastrophic_frame_share(lam, bits, p, scrub_hours)
            none = pc_lookup(pc, precision, "none") if exposure and dfn in exposure else None
            if none is not None:
                p0 = float(none["p_c"])
                t, share = with_exposure(t, share, lam, bits, p0 - p, exposure[dfn])
                t_lo = with_exposure(t_lo, 0.0, lam, bits, float(none["ci_hi"]) - lo, exposure[dfn])[0]
                t_hi = with_exposure(t_hi, 0.0, lam, bits, float(none["ci_lo"]) - hi, exposure[dfn])[0]
            row = {
                "environment": env["environment"],
                "upsets_per_bit_hour": lam,
                "fit_per_mbit": lam * 1e15,
                "live_upsets_per_scrub": live,
                "regime": regime(live),
                "defense": dfn,
                "p_source": src,
                "p_pct": 100 * p,
                "scrub_hours": scrub_hours,
                "mtbf_hours": t,
                "mtbf_hours_lo": t_lo,
                "mtbf_hours_hi": t_hi,
                "mtbf": format_duration(t) if p != 0 or none is not None else f"> {format_duration(t_lo)}",  # NaN: n/a
                "mtbf_range": f"{format_duration(t_lo)} .. {format_duration(t_hi)}",
                "catastrophic_frames_pct": 100 * share,
                "source": env.get("source", ""),
            }
            if exposure:  # the column only where a check's exposure was given
                row["exposure_hours"] = exposure[dfn][1] if none is not None else float("nan")
            rows.append(row)
    out = pd.DataFrame(rows)
    out.attrs.update(pc.attrs)
    out.attrs.update(precision=precision, model_bits=bits)
    return out


def _dose_p(dose_fits: pd.DataFrame | None, precision: str, scene: str, n: int) -> tuple[dict, list[str]]:
    """dose_p[defense] = (p, lo, hi) of one model from the dose fits of its own scene: the fit at
    its primitive count, else the scene's largest model's fit, which stands for the deployed model
    (a note says so). Another scene's fit is never used."""
    dose_p, notes = {}, []
    if dose_fits is None or not len(dose_fits):
        return dose_p, notes
    f = dose_fits[(dose_fits["precision"] == precision) & (dose_fits["scene"].astype(str) == scene)]
    for dfn, g in f.groupby("defense"):
        same = g[g["n_primitives"] == n]
        r = same.iloc[-1] if len(same) else g.sort_values("n_primitives").iloc[-1]
        if not len(same):
            notes.append(
                f"dose fit p of {scene}/{dfn}: its fit at N = {int(r['n_primitives']):,} stands for the model "
                f"of N = {int(n):,} (no dose run at that size)"
            )
        if np.isfinite(r["p_pct"]):
            dose_p[dfn] = (r["p_pct"] / 100, r["p_lo_pct"] / 100, r["p_hi_pct"] / 100)
    return dose_p, notes


def _wide(mt: pd.DataFrame, index: list[str]) -> pd.DataFrame:
    """The MTBF column per defense (p source), a row per `index` (environment, or model and
    environment)."""
    mt2 = mt.assign(col=mt["defense"] + " (" + mt["p_source"] + ")")
    wide = mt2.pivot_table(index=index, columns="col", values="mtbf", aggfunc="first", sort=False)
    wide = wide.reset_index()
    wide.columns.name = None
    wide.attrs.update(mt.attrs)
    return wide


def reliability(
    df: pd.DataFrame,
    manifests: Iterable[dict] = (),
    bits: float | dict | None = None,
    precision: str | None = None,
    conf: float = 0.95,
    dose_fits: pd.DataFrame | None = None,
    exposure: dict | None = None,
) -> dict:
    """p_c, the MTBF table (rates and scrub interval from the runs' spec or the defaults) and the
    inputs of the sensitivity figure. Returns {"pc", "mtbf", "mtbf_wide", "bits", "precision",
    "scrub_hours", "rates", "rates_from", "dose_p", "notes", "models", "per_model"}.

    One model (scene, n_primitives) in the single-upset records: bits is its stored bits (or the
    `bits` given), dose_p[defense] its dose fit. Several: everything per model (module notes):
    pc and mtbf have scene and n_primitives columns (mtbf also model_bits), mtbf_wide a row per
    model and environment, bits and dose_p are dicts by model key (`models_of`; `bits` given as
    such a dict overrides), and models lists {scene, n_primitives, key, label, bits, dose_p}."""
    manifests = list(manifests or ())
    s = _single_bits(df)  # selected once: p_c, the degrees and the models read these
    pc = catastrophe_probability(s, conf, manifests=manifests)
    notes = []
    precision = precision or reference_precision(pc)
    degree = model_degrees(s, manifests)
    rates, scrub, rates_from = reliability_parameters(manifests)
    check_every, fps, schedule_from = check_schedule(manifests)
    checked = [d for d in pd.unique(pc["defense"]) if d in dfn_registry and dfn_registry[d].checked]
    if exposure is None and checked:  # what a check repairs is drawn until the check: counted
        exposure = {d: check_exposure(check_every_of(check_every, d), fps * 3600.0) for d in checked}
    guard = guard_arm(pc["defense"])  # a run without guard: its own guard (guard_all, ...) beside none
    defenses = ("none", "guard", *([guard] if guard not in (None, "guard") else []), *checked)
    models = models_in(s)
    per_model = len(models) > 1
    if per_model and bits is not None and not isinstance(bits, dict):
        raise ValueError(f"records of {len(models)} models: give bits per model key ({', '.join(models['key'])})")
    for _, r in pc[pc["coverage_pct"] < 99.999].iterrows():
        of = f"{r['scene']} (N = {int(r['n_primitives']):,}) " if per_model else ""
        notes.append(
            f"p_c {of}at {r['precision']}/{r['defense']} covers only "
            f"{r['coverage_pct']:.1f}% of the stored bits (unsampled cells excluded)"
        )
    if per_model:
        notes.append(
            f"These records hold {len(models)} models (scene, primitive count): "
            + ", ".join(f"{m.label} (N = {int(m.n_primitives):,})" for m in models.itertuples())
            + ". p_c, stored bits, dose-fit p and MTBF are each model's own, never pooled: a p_c averaged "
            "over models with their mean size would describe none of them (the claims table's p_c pools "
            "them, weighted by stored bits, only to compare with the paper's single number)."
        )
    info, tables = [], []
    for m in models.itertuples():
        if per_model:
            sub = pc[(pc["scene"] == m.scene) & (pc["n_primitives"] == m.n_primitives)].drop(columns=MODEL)
            b = bits.get(m.key) if isinstance(bits, dict) else None
        else:
            sub, b = pc, bits
        b = stored_bits(m.n_primitives, precision, degree[(m.scene, m.n_primitives)]) if b is None else float(b)
        dp, dnotes = _dose_p(dose_fits, precision, m.scene, m.n_primitives)
        notes.extend(dnotes)
        if per_model and not (sub["precision"] == precision).any():
            notes.append(f"{m.label}: no single-upset records at {precision}, no MTBF")
            continue
        mt = mtbf_table(sub, b, precision, rates, scrub, defenses=defenses, dose_p=dp, exposure=exposure)
        if per_model:
            for i, (c, v) in enumerate((("scene", m.scene), ("n_primitives", m.n_primitives), ("model_bits", b))):
                mt.insert(i, c, v)
        model = {"scene": m.scene, "n_primitives": int(m.n_primitives), "key": m.key, "label": m.label}
        info.append({**model, "bits": b, "dose_p": dp})
        tables.append(mt)
    if dose_fits is not None and len(dose_fits):
        f = dose_fits[dose_fits["precision"] == precision]
        unused = sorted(set(f["scene"].astype(str)) - {m["scene"] for m in info})
        if unused:
            notes.append(
                f"dose fits of {', '.join(unused)} not used: no single-upset records of that model at {precision} "
                "(its p is never paired with another model's bits)"
            )
    one = None if per_model else info[0]  # one model: the tables it always had
    mt = pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()
    mt.attrs.update(pc.attrs)
    mt.attrs.update(precision=precision, model_bits=one["bits"] if one else {m["key"]: m["bits"] for m in info})
    d = prepare(df)
    used = d[(d["precision"] == precision) & d["defense"].isin(list(defenses)) & (d["k"] >= 1)]
    mt.attrs["provenance"] = provenance(used)
    wide = None
    if len(mt) and one:
        wide = _wide(mt, ["environment"])
    elif len(mt):
        label = {(m["scene"], m["n_primitives"]): m["label"] for m in info}
        named = mt.assign(scene=[label[(a, int(b))] for a, b in zip(mt["scene"], mt["n_primitives"])])
        wide = _wide(named, ["scene", "model_bits", "environment"])
    return {
        "pc": pc,
        "mtbf": mt,
        "mtbf_wide": wide,
        "bits": one["bits"] if one else {m["key"]: m["bits"] for m in info},
        "precision": precision,
        "scrub_hours": scrub,
        "check_every": check_every,
        "check_every_of": {d: check_every_of(check_every, d) for d in checked},
        "check_every_from": schedule_from,
        "frames_per_second": fps,
        "rates": rates,
        "rates_from": rates_from,
        "dose_p": one["dose_p"] if one else {m["key"]: m["dose_p"] for m in info},
        "notes": notes,
        "models": info,
        "per_model": per_model,
    }


def _sensitivity_panel(ax, mt, pc, model: dict, precision: str, scrub: float, rates, colors: dict):
    """One model's MTBF curves against the upset rate, per defense and p source, with the band
    from the p interval."""
    lam = np.logspace(-16, -6, 120)
    bits, dose_p = model["bits"], model["dose_p"]
    for (dfn, src), g in mt.groupby(["defense", "p_source"], sort=False):
        r = g.iloc[0]
        p = r["p_pct"] / 100
        c = colors[(dfn, src)]
        y = np.array([mtbf(x, bits, p, scrub) for x in lam])
        lo_p = hi_p = None
        if src == "single-upset p_c":
            ref = pc_lookup(pc, precision, dfn)
            lo_p, hi_p = float(ref["ci_lo"]), float(ref["ci_hi"])
        elif dfn in dose_p:
            lo_p, hi_p = dose_p[dfn][1], dose_p[dfn][2]
        ls = "-" if src.startswith("single") else "--"
        if p > 0 or hi_p is None or not hi_p > 0:
            ax.plot(lam, np.where(np.isfinite(y), y, np.nan), ls, color=c, label=f"{dfn}, {src}")
        else:  # no event: the MTBF is unbounded above; draw its lower bound (the p interval's upper end)
            bound = np.array([mtbf(x, bits, hi_p, scrub) for x in lam])
            ax.plot(
                lam, bound, ls, color=c, lw=1, marker="^", markevery=10, ms=4, label=f"{dfn}, {src}: no event, MTBF >"
            )
            ax.fill_between(lam, bound, 1e12, color=c, alpha=0.12, lw=0)
            continue
        if lo_p is not None:
            a = np.array([mtbf(x, bits, hi_p, scrub) for x in lam])
            b = np.array([mtbf(x, bits, lo_p, scrub) for x in lam])
            ax.fill_between(lam, a, np.where(np.isfinite(b), b, 1e12), color=c, alpha=0.12, lw=0)
    for env in rates:
        ax.axvline(float(env["per_bit_hour"]), color="grey", ls=":", lw=0.8)
        ax.text(float(env["per_bit_hour"]), 1e-2, env["environment"], rotation=90, fontsize=6, va="bottom")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(1e-3, 1e10)


def plot_sensitivity(res: dict):
    """MTBF against the per-bit upset rate (log-log), per defense and p source, with the band from
    the p interval; vertical lines mark the named environments. Several models: a panel each (its
    own p and bits; a colour means the same defense, a line the same p source, in every panel).
    The legend sits below the panels. A defense without any catastrophic event (p = 0, MTBF
    unbounded) is drawn as the lower bound from its p interval's upper end, marked with triangles."""
    mt, scrub, prec = res["mtbf"], res["scrub_hours"], res["precision"]
    keys = list(dict.fromkeys(zip(mt["defense"], mt["p_source"])))
    # a colour per defense, its p sources told apart by line (solid: single-upset p_c, dashed: dose fit)
    defenses = list(dict.fromkeys(d for d, _ in keys))
    colors = {(d, src): series_color(defenses.index(d)) for d, src in keys}
    ylabel = f"MTBF of catastrophic frames (h), scrub every {scrub:g} h"
    if not res.get("per_model"):
        fig = figure(6.4, 4.2)
        ax = fig.subplots()
        _sensitivity_panel(ax, mt, res["pc"], res["models"][0], prec, scrub, res["rates"], colors)
        ax.set_xlabel("upset rate per stored bit per hour")
        ax.set_ylabel("MTBF of catastrophic frames (h)")  # the whole of ylabel ran off a 4.2 in figure
        ax.set_title(f"{prec}, {res['models'][0]['bits']:.3g} stored bits, scrub every {scrub:g} h", fontsize=8)
        fig.legend(loc="outside lower center", ncols=2, fontsize=7)
        return fig
    models = res["models"]
    ncols = min(len(models), 3)
    nrows = -(-len(models) // ncols)
    fig = figure(3.6 * ncols + 0.6, 3.6 * nrows + 0.4)
    axes = np.atleast_1d(fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False)).ravel()
    pc = res["pc"]
    for ax, m in zip(axes, models):
        g = mt[(mt["scene"] == m["scene"]) & (mt["n_primitives"] == m["n_primitives"])]
        sub = pc[(pc["scene"] == m["scene"]) & (pc["n_primitives"] == m["n_primitives"])]
        _sensitivity_panel(ax, g, sub, m, prec, scrub, res["rates"], colors)
        ax.set_title(f"{m['label']}: {m['bits']:.3g} stored bits", fontsize=8)
    for ax in axes[len(models) :]:
        ax.set_visible(False)
    for ax in axes[(nrows - 1) * ncols : len(models)]:
        ax.set_xlabel("upset rate per stored bit per hour")
    for ax in axes[::ncols]:
        ax.set_ylabel(ylabel if nrows == 1 else "MTBF (h)")
    if nrows > 1:
        fig.suptitle(f"{ylabel} at {prec}", fontsize=9)
    # one legend for every panel: a line that only some panels draw (a no-event bound) is named too
    handles = {}
    for ax in axes[: len(models)]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncols=min(3, len(handles)), fontsize=7)
    return fig
