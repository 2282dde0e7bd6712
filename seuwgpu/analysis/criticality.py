"""Where single-bit criticality concentrates: per field, per (field, bit) cell, per precision.

Footprint quantiles and means are weighted (each record stands for the stored bits of its cell,
`analysis.estimate`), so a field's numbers describe a uniform upset of that field's bits; rates
carry the estimator layer's intervals (Wilson per cell, stratified when pooled).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import (
    FIELD_LABELS,
    InsufficientData,
    fields_present,
    figure,
    precisions_present,
    record_weights,
    reference_precision,
    require_single,
    tag,
)
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS


def _rates(s: pd.DataFrame, by: list[str], conf: float) -> pd.DataFrame:
    r = E.rate(s, "catastrophic", by, conf)
    r = E.percent(r).rename(columns={"events": "catastrophic"})
    return r.drop(columns=["weight", "n_eff", "method"])


def criticality(df: pd.DataFrame, precision: str | None = None, defense: str = "none", conf: float = 0.95):
    """Per-field footprint quantiles (% of frame, weighted) and catastrophe rate with interval.

    Pooled over scenes and bits of the single-upset campaign at one precision (fp32 by default).
    Columns: field, n, catastrophic (count), cat_rate_pct, cat_ci_lo_pct, cat_ci_hi_pct,
    median_pct, p95_pct, p99_pct, max_pct, mean_pct."""
    s = require_single(df, defense)
    precision = precision or reference_precision(s)
    s = s[s["precision"] == precision]
    if s.empty:
        raise InsufficientData(f"no single-upset records at {precision}", f"run a single-upset campaign at {precision}")
    rows = []
    for field in fields_present(s):
        g = s[s["field"] == field]
        fp, w = g["footprint"].to_numpy(float) * 100.0, record_weights(g)
        rows.append(
            {
                "field": field,
                "median_pct": E.wquantile(fp, w, 0.5),
                "p95_pct": E.wquantile(fp, w, 0.95),
                "p99_pct": E.wquantile(fp, w, 0.99),
                "max_pct": float(np.nanmax(fp)) if np.isfinite(fp).any() else np.nan,
                "mean_pct": E.wmean(fp, w),
            }
        )
    out = _rates(s, ["field"], conf).merge(pd.DataFrame(rows), on="field")
    return tag(out, s, precision=precision)


def field_bit_table(df: pd.DataFrame, defense: str = "none", conf: float = 0.95) -> pd.DataFrame:
    """Long table per (precision, field, bit): n, bit class, mean and max footprint %, weight share
    of the cell in its precision's stored bits, catastrophe rate with its interval (Wilson; pooled
    over scenes, estimate.rate's stratified one)."""
    s = require_single(df, defense)
    s = s[s["bit"] >= 0]
    out = _rates(s, ["precision", "field", "bit"], conf)
    rw = record_weights(s)
    extra = (
        s.assign(_fw=s["footprint"] * rw, _rw=rw)
        .groupby(["precision", "field", "bit"], sort=False)
        .agg(_fw=("_fw", "sum"), _w=("_rw", "sum"), max_footprint_pct=("footprint", "max"))
        .reset_index()
    )
    extra["mean_footprint_pct"] = 100 * extra.pop("_fw") / extra["_w"]
    extra["max_footprint_pct"] *= 100
    extra["weight_share_pct"] = 100 * extra["_w"] / extra.groupby("precision")["_w"].transform("sum")
    out = out.merge(extra.drop(columns="_w"), on=["precision", "field", "bit"])
    out.insert(
        3,
        "bit_class",
        [
            encoding.bit_class(p, b) if p in encoding.PRECISIONS and 0 <= b < encoding.BITS[p] else "?"
            for p, b in zip(out["precision"], out["bit"])
        ],
    )
    porder = {p: i for i, p in enumerate(precisions_present(s))}
    forder = {f: i for i, f in enumerate(fields_present(s))}
    out = out.sort_values(
        ["precision", "field", "bit"],
        key=lambda c: c.map(porder) if c.name == "precision" else (c.map(forder) if c.name == "field" else c),
    ).reset_index(drop=True)
    return tag(out, s)


def heatmap_matrix(table: pd.DataFrame, precision: str, value: str = "mean_footprint_pct") -> pd.DataFrame:
    """field x bit matrix (rows in FIELDS order, columns bit 0..B-1) from `field_bit_table`."""
    t = table[table["precision"] == precision]
    nbits = encoding.BITS.get(precision, int(t["bit"].max()) + 1 if len(t) else 0)
    m = t.pivot_table(index="field", columns="bit", values=value, aggfunc="mean")
    rows = [f for f in FIELDS if f in m.index] + [f for f in m.index if f not in FIELDS]
    return m.reindex(index=rows, columns=range(nbits))


def precision_rates(df: pd.DataFrame, defense: str = "none", conf: float = 0.95) -> pd.DataFrame:
    """Weighted catastrophe rate per (precision, field), pooled over bits and scenes, with the
    stratified interval; plus the weighted mean footprint (%)."""
    s = require_single(df, defense)
    out = _rates(s, ["precision", "field"], conf)
    rw = record_weights(s)
    mf = (
        s.assign(_fw=s["footprint"] * rw, _rw=rw)
        .groupby(["precision", "field"], sort=False)
        .agg(_fw=("_fw", "sum"), _w=("_rw", "sum"))
        .reset_index()
    )
    mf["mean_footprint_pct"] = 100 * mf.pop("_fw") / mf.pop("_w")
    out = out.merge(mf, on=["precision", "field"])
    porder = {p: i for i, p in enumerate(precisions_present(s))}
    forder = {f: i for i, f in enumerate(fields_present(s))}
    out = out.assign(_p=out["precision"].map(porder), _f=out["field"].map(forder))
    out = out.sort_values(["_p", "_f"]).drop(columns=["_p", "_f"]).reset_index(drop=True)
    return tag(out, s)


def plot_field_bit_heatmap(table: pd.DataFrame, precisions: list[str] | None = None):
    """Mean footprint (% of frame, log10 colour scale) over field x bit, one panel per precision.
    Cells with zero mean footprint are drawn grey; unsampled cells white."""
    from matplotlib.colors import LogNorm

    precisions = precisions or [p for p in encoding.PRECISIONS if p in set(table["precision"])]
    mats = {p: heatmap_matrix(table, p) for p in precisions}
    vals = np.concatenate([m.to_numpy(float).ravel() for m in mats.values()]) if mats else []
    pos = np.asarray(vals)[np.isfinite(vals) & (np.asarray(vals) > 0)] if len(vals) else []
    vmin = max(float(np.min(pos)), 1e-6) if len(pos) else 1e-4
    vmax = max(float(np.max(pos)), vmin * 10) if len(pos) else 1.0
    fig = figure(9.0, 1.9 + 1.9 * len(precisions))
    axes = fig.subplots(len(precisions), 1, squeeze=False)[:, 0]
    im = None
    for ax, p in zip(axes, precisions):
        m = mats[p]
        a = m.to_numpy(float)
        zero = np.isfinite(a) & (a <= 0)
        ax.imshow(np.where(zero, 1.0, np.nan), cmap="Greys", vmin=0, vmax=4, aspect="auto", interpolation="nearest")
        im = ax.imshow(
            np.ma.masked_where(~(a > 0), a),
            norm=LogNorm(vmin=vmin, vmax=vmax),
            cmap="magma",
            aspect="auto",
            interpolation="nearest",
        )
        ax.set_yticks(range(len(m.index)), [FIELD_LABELS.get(f, f) for f in m.index])
        nb = a.shape[1]
        step = 1 if nb <= 16 else 2
        ax.set_xticks(range(0, nb, step))
        ax.set_xticklabels([str(b) for b in range(0, nb, step)], fontsize=7)
        man, exp = encoding.LAYOUT.get(p, (nb - 9, 8))
        for x in (man - 0.5, man + exp - 0.5):
            ax.axvline(x, color="cyan", lw=0.8, ls=":")
        ax.set_title(f"{p}: mean footprint (% of frame, log scale); dotted: mantissa | exponent | sign", fontsize=8)
        ax.set_xlabel("bit position (0 = LSB)", fontsize=8)
    if im is not None:
        fig.colorbar(im, ax=list(axes), label="mean footprint (%)", shrink=0.9)
    return fig


def plot_precision_rates(rates: pd.DataFrame):
    """Weighted catastrophe rate by field and precision, with the stratified 95% intervals, on a
    log axis (the rates span decades: on a linear one the fields below 1% were invisible); a
    field without any event is an open triangle at its interval's upper end."""
    from matplotlib.lines import Line2D

    from seuwgpu.analysis.records import rate_points, series_color

    fig = figure(8.0, 3.8)
    ax = fig.subplots()
    precs = precisions_present(rates)
    fields = fields_present(rates)
    w = 0.6 / max(len(precs), 1)
    zeros = 0
    for i, p in enumerate(precs):
        g = rates[rates["precision"] == p].set_index("field").reindex(fields)
        x = np.arange(len(fields)) + (i - (len(precs) - 1) / 2) * w
        ok = g["cat_rate_pct"].notna().to_numpy()
        zeros += rate_points(
            ax,
            x[ok],
            g["cat_rate_pct"][ok],
            g["cat_ci_lo_pct"][ok],
            g["cat_ci_hi_pct"][ok],
            series_color(i),
            label=p,
            marker="osD^"[i % 4],
        )
    ax.set_yscale("log")
    ax.set_xticks(range(len(fields)), [FIELD_LABELS.get(f, f) for f in fields])
    ax.set_ylabel("catastrophic upsets (%), 95% interval")
    handles, labels = ax.get_legend_handles_labels()
    if zeros:
        handles.append(Line2D([], [], color="0.3", ls="", marker="v", mfc="none", ms=7))
        labels.append("no event: below the triangle")
    fig.legend(handles, labels, title="precision", loc="outside right upper", fontsize=8)
    return fig


# ---- claims rows (analysis.claims gathers them) ----------------------------------------------------


def _footprint_stat(q: str):
    """The Table 2 footprint statistic `q` of a set of records (% of frame, weighted by stored bits)."""
    from seuwgpu.analysis.paper import FOOTPRINT_QUANTILES

    def stat(g: pd.DataFrame) -> float:
        fp, w = 100 * g["footprint"].to_numpy(float), record_weights(g)
        if q == "max":
            return float(np.nanmax(fp)) if len(fp) else np.nan
        if q == "mean":
            return E.wmean(fp, w)
        return E.wquantile(fp, w, FOOTPRINT_QUANTILES[q])

    return stat


def field_rows(df: pd.DataFrame, conf: float = 0.95) -> list[dict]:
    """Table 2 per field: the catastrophe rate and the footprint statistics, per model, then over
    models; a maximum only at the paper's number of upsets (`claimrows.tail_row`)."""
    from seuwgpu.analysis.claimrows import over_models, per_model, row, tail_row
    from seuwgpu.analysis.paper import PAPER_FIELD_FOOTPRINT, PAPER_FIELD_RATES
    from seuwgpu.analysis.population import MODEL
    from seuwgpu.analysis.records import multiplicity, n_records, single_upsets

    s = single_upsets(df, "fp32", "none")
    s = s[s["bit"] >= 0]
    rows = []
    rates = E.rate(s, "catastrophic", MODEL + ["field"], conf) if len(s) else pd.DataFrame()
    pooled = E.rate(s, "catastrophic", ["field"], conf).set_index("field") if len(s) else pd.DataFrame()
    for f in PAPER_FIELD_RATES:
        g = s[s["field"] == f]
        if g.empty:
            rows += [row(f"field_rate_{f}")] + [row(f"field_{q}_{f}") for q in PAPER_FIELD_FOOTPRINT[f]]
            continue
        basis = f"n = {n_records(g):,}"
        p = pooled.loc[f]
        rows.append(
            over_models(
                f"field_rate_{f}",
                rates[rates["field"] == f],
                "rate",
                basis + "; stratified over bits; pooled: the same over these models' records",
                conf,
                (100 * p["rate"], 100 * p["ci_lo"], 100 * p["ci_hi"]),
            )
        )
        for q in PAPER_FIELD_FOOTPRINT[f]:
            fn = _footprint_stat(q)
            if q == "max":
                fp = np.repeat(100 * g["footprint"].to_numpy(float), multiplicity(g))
                rows.append(tail_row(f"field_max_{f}", fp, basis, fn(g)))
                continue
            note = "weighted by stored bits" + ("; a quantile with its interval over models" if q == "p99" else "")
            rows.append(
                over_models(
                    f"field_{q}_{f}", per_model(g, fn), "v", f"{basis}; {note}", conf, (fn(g), np.nan, np.nan), 1.0
                )
            )
    return rows
