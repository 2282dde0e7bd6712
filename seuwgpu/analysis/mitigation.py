"""Defenses side by side on the shared fault grid: weighted catastrophe rate with its interval,
footprint, memory overhead (fraction of the model's stored bytes) and time overhead (fraction of
one view's render time, measured in the same run: the runner times each defense's render of the
clean model and writes it as ``time_ms``, ms per view)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import (
    DEFAULT_SH_DEGREE,
    InsufficientData,
    defenses_present,
    measured_under,
    multiplicity,
    pair_columns,
    record_weights,
    reference_precision,
    sh_degree_of,
    single_upsets,
    tag,
)
from seuwgpu.faults.defenses import defense_label

GUARD_BOX_BITS = 32  # the support box bounds are held as fp32 values
# defenses whose read path the engine simulates on the stored words (no render-time work to time)
SIMULATED_READ = ("ecc", "dup")


def memory_overhead(
    defense: str,
    precision: str = "fp32",
    n_primitives: int | None = None,
    sh_degree: int = DEFAULT_SH_DEGREE,
    manifests: Iterable[dict] = (),
) -> tuple[float, str]:
    """(fractional memory overhead, basis text) of a defense.

    A manifest may state it: ``manifest["memory_overhead"][defense]`` or
    ``manifest["defenses"][defense]["memory_overhead"]`` (a fraction); else documented constants:
    * none: 0.
    * guard: the support box, 2 fp32 bounds per guarded component per model (not per primitive);
      the guard skips sh_rest, so 2 x 14 values for the whole model: 2*14*32 / (N*C*bits).
    * selective: the box of log-scale and opacity only, 2 x 4 values per model.
    * ecc: a SEC-DED (extended Hamming) code per stored value over its sign+exponent bits:
      fp32 9 data bits -> 5 check bits (+15.6%), fp16 6 -> 5 (+31.3%), bf16 9 -> 5 (+31.3%).
    * dup: duplication with majority voting needs three copies (triple modular redundancy), +200%.
    """
    for m in manifests or ():
        for src in (
            m.get("memory_overhead"),
            (m.get("defenses") or {}).get(defense),
            (m.get("spec", {}) or {}).get("memory_overhead"),
        ):
            if isinstance(src, dict):
                v = src.get(defense) if defense in src else src.get("memory_overhead")
                if isinstance(v, (int, float)):
                    return float(v), "from the run manifest"
    from seuwgpu.faults import defenses as dfn  # the stored bits each defense adds, defined there
    from seuwgpu.faults import side

    d = dfn.REGISTRY.get(defense)
    if d is None:
        return float("nan"), "unknown defense"
    if defense == "none":
        return 0.0, "no redundancy"
    if not n_primitives and d.bits_per_model(precision, sh_degree) and not d.bits_per_primitive(precision, sh_degree):
        return 0.0, "fp32 box bounds per model (~0 per primitive)"
    n = int(n_primitives or 1)  # without N only per-primitive overheads are stated (exact for them)
    frac = side.memory_overhead(defense, precision, sh_degree, n)
    where = f", N = {n:,}" if n_primitives else ""
    return frac, f"{d.info}{where}"


def _pooled_overhead(defense: str, precision: str, models: dict, manifests) -> tuple[float, str]:
    """Memory overhead of a defense over several models pooled as the records are: the bits it
    adds to each model over their stored bits, each model at its own N and SH degree (a degree-0
    model beside a degree-3 one has 14 components to its 59)."""
    from seuwgpu.analysis.reliability import stored_bits

    added = stored = 0.0
    basis = ""
    for (_, n), deg in models.items():
        frac, basis = memory_overhead(defense, precision, int(n), deg, manifests)
        if defense == "none" or basis in ("from the run manifest", "unknown defense"):
            return frac, basis
        bits = stored_bits(n, precision, deg)
        added, stored = added + frac * bits, stored + bits
    what = basis.rsplit(", N = ", 1)[0]
    return added / stored, f"{what}, pooled over {len(models)} models (each its own N and SH degree)"


def time_overhead(s: pd.DataFrame, defense: str, conf: float = 0.95) -> dict:
    """The defense's time overhead over no defense, with a t interval over models.

    The runner times every defense's render of the clean model once per engine, interleaved, and
    writes it on each record (time_ms): each distinct value of a (run, campaign, scene, N,
    precision) group and defense is one measurement. Per group (a model at a precision) the
    overhead is mean t(defense) / mean t(none) - 1 over its measurements (both arms timed by the
    same engines, so the host's load moves them alike), and the interval is the Student-t interval
    of the groups' mean (distinct values survive folding, so a folded report gives the same).
    resolved: False where the interval holds 0 (the sign of the cost is not known); NaN under
    two groups."""
    from seuwgpu.analysis.population import interval_over_models

    keys = [c for c in ("run", "campaign", "scene", "n_primitives", "precision") if c in s]
    t = s[s["defense"].isin(["none", defense]) & s["time_ms"].notna()]
    per = t.drop_duplicates(keys + ["defense", "time_ms"]).groupby(keys + ["defense"])["time_ms"].mean()
    per = per.unstack("defense") if len(per) else pd.DataFrame()
    if defense == "none" or defense not in per or "none" not in per:
        return {"mean_pct": np.nan, "lo_pct": np.nan, "hi_pct": np.nan, "n_groups": 0, "resolved": np.nan}
    per = per.dropna(subset=["none", defense])
    per = per[per["none"] > 0]
    om = interval_over_models(100 * (per[defense] / per["none"] - 1.0), conf)
    resolved = bool(not (om.lo <= 0 <= om.hi)) if np.isfinite(om.lo) and np.isfinite(om.hi) else np.nan
    return {"mean_pct": om.mean, "lo_pct": om.lo, "hi_pct": om.hi, "n_groups": om.n_models, "resolved": resolved}


def mitigation_table(
    df: pd.DataFrame, manifests: Iterable[dict] = (), precision: str | None = None, conf: float = 0.95
) -> pd.DataFrame:
    """Every defense present on the shared fault grid at one precision.

    The shared grid is the set of fault sites (pair_keys) measured under every defense present;
    if no site was measured under all of them, each defense uses all its sites (attrs["paired"]
    is False). Columns: defense, label, n, catastrophic, cat_rate_pct (+ interval),
    mean_footprint_pct, max_footprint_pct, memory_overhead_pct, memory_basis, time_ms (per view),
    time_overhead_pct (time over that of 'none', minus 1; NaN where not measured), time_basis,
    and the overhead as the mean over models with its t interval (`time_overhead`):
    time_overhead_mean_pct, time_overhead_lo_pct, time_overhead_hi_pct, time_groups (models at
    this precision) and time_resolved ("resolved", "not resolved" where the interval holds 0, ""
    where there is none).
    """
    s = single_upsets(df, None, None)
    if s.empty:
        raise InsufficientData("no single-upset records", "run a single-upset campaign")
    precision = precision or reference_precision(s)
    s = s[s["precision"] == precision]
    defs = defenses_present(s)
    if len(defs) < 2:
        raise InsufficientData(
            f"only defense(s) {', '.join(defs)} at {precision}",
            "run the single-upset campaign with --defenses none,guard,selective,ecc,dup",
        )
    s = pair_columns(s)
    shared = measured_under(s, defs)
    is_paired = bool(shared.any())
    if is_paired:
        s = s[shared]
    manifests = list(manifests or ())
    deg = sh_degree_of(s, manifests)
    n_prims = float(np.average(s["n_primitives"], weights=multiplicity(s))) if "n_primitives" in s and len(s) else None
    from seuwgpu.analysis.reliability import model_degrees

    models = model_degrees(s, manifests) if "n_primitives" in s else {}  # (scene, N) -> its SH degree
    rates = E.percent(E.rate(s, "catastrophic", ["defense"], conf)).set_index("defense")
    base = s[s["defense"] == "none"]
    t_none = E.wmean(base["time_ms"], record_weights(base))
    rows = []
    for x in defs:
        g = s[s["defense"] == x]
        ov, basis = (
            _pooled_overhead(x, precision, models, manifests)
            if len(models) > 1
            else memory_overhead(x, precision, n_prims, deg, manifests)
        )
        tm = E.wmean(g["time_ms"], record_weights(g)) if g["time_ms"].notna().any() else np.nan
        if x in SIMULATED_READ:
            tfrac, tbasis = np.nan, "not measured: the read-side decode is simulated on the stored words"
        elif x == "none":
            tfrac, tbasis = 0.0, "reference" if np.isfinite(tm) else "no time_ms recorded"
        elif np.isfinite(tm) and np.isfinite(t_none) and t_none > 0:
            tfrac, tbasis = tm / t_none - 1.0, "render of the clean model, same run"
        else:
            tfrac, tbasis = np.nan, "no time_ms recorded"
        r = rates.loc[x]
        ti = time_overhead(s, x if np.isfinite(tfrac) else "none", conf)
        rows.append(
            {
                "defense": x,
                "label": defense_label(x),
                "n": int(r["n"]),
                "catastrophic": int(r["events"]),
                "cat_rate_pct": r["cat_rate_pct"],
                "cat_ci_lo_pct": r["cat_ci_lo_pct"],
                "cat_ci_hi_pct": r["cat_ci_hi_pct"],
                "mean_footprint_pct": 100 * E.wmean(g["footprint"], record_weights(g)),
                "max_footprint_pct": 100 * g["footprint"].max(),
                "memory_overhead_pct": 100 * ov,
                "memory_basis": basis,
                "time_ms": tm,
                "time_overhead_pct": 100 * tfrac,
                "time_basis": tbasis,
                "time_overhead_mean_pct": ti["mean_pct"],
                "time_overhead_lo_pct": ti["lo_pct"],
                "time_overhead_hi_pct": ti["hi_pct"],
                "time_groups": ti["n_groups"],
                "time_resolved": ""
                if not isinstance(ti["resolved"], bool)
                else ("resolved" if ti["resolved"] else "not resolved"),
            }
        )
    return tag(pd.DataFrame(rows), s, precision=precision, paired=is_paired, sh_degree=deg)


def plot_mitigation(table: pd.DataFrame):
    """The mitigation table drawn: each defense's weighted catastrophe rate (%, log axis) with its
    95% interval (no event: an open triangle at the upper end), its memory overhead beside it."""
    from seuwgpu.analysis.records import figure, rate_points, series_color

    t = table.reset_index(drop=True)
    fig = figure(7.0, 1.2 + 0.45 * len(t))
    ax = fig.subplots()
    y = np.arange(len(t))[::-1]
    zeros = rate_points(
        ax, y, t["cat_rate_pct"], t["cat_ci_lo_pct"], t["cat_ci_hi_pct"], series_color(0), horizontal=True
    )
    names = [
        f"{lab}\n(memory +{m:.3g}%)" if np.isfinite(m) else str(lab)
        for lab, m in zip(t["label"], t["memory_overhead_pct"].astype(float))
    ]
    ax.set_yticks(y, names, fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("catastrophic upsets (%), 95% interval" + ("; open triangle: no event, below it" if zeros else ""))
    ax.set_title(f"at {t.attrs.get('precision', '')}, single upsets, shared fault grid", fontsize=8)
    return fig
