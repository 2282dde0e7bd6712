"""Cross-node contamination in sort-first rendering: the share of a P-way screen partition that
one upset reaches, predicted (the primitive's projected tile rectangle) and measured (pixels
changed by more than 1/255), and their IoU. The grid is `render.regions` (tile-aligned, the same
one the Ray ranks render), so a tile-quantised prediction loses nothing at region borders. Means
are weighted over the stored bits (`analysis.estimate`)."""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd

from seuwgpu.analysis.records import (
    InsufficientData,
    figure,
    multiplicity,
    reference_precision,
    single_upsets,
    tag,
)
from seuwgpu.faults.defenses import defense_label
from seuwgpu.render.regions import region_edges


def region_set(changed_mask_or_bbox, H: int, W: int, P: int) -> np.ndarray:
    """Boolean array of P regions (row-major: index = row * cols + col) touched by a footprint.

    The footprint is a boolean pixel mask of shape (H, W) (or (V, H, W): any view), or a bbox
    (x0, y0, x1, y1) in continuous pixel coordinates, x1/y1 exclusive, covering the pixels
    floor(x0) .. ceil(x1)-1 (clipped to the screen; an empty or off-screen box touches nothing).
    Region (i, j) spans rows edges_y[i]..edges_y[i+1]-1, edges = floor(t * size / parts)."""
    ey, ex = region_edges(P, H, W)
    rows, cols = len(ey) - 1, len(ex) - 1
    out = np.zeros(rows * cols, dtype=bool)
    obj = changed_mask_or_bbox
    if isinstance(obj, (tuple, list)) and len(obj) == 4 and np.ndim(obj[0]) == 0:
        x0, y0, x1, y1 = (float(v) for v in obj)
        if not all(np.isfinite([x0, y0, x1, y1])):
            # a non-finite box (exploded primitive) is treated as covering the screen
            x0, y0, x1, y1 = 0.0, 0.0, float(W), float(H)
        ix0, iy0 = max(int(math.floor(x0)), 0), max(int(math.floor(y0)), 0)
        ix1, iy1 = min(int(math.ceil(x1)), W), min(int(math.ceil(y1)), H)
        if ix1 <= ix0 or iy1 <= iy0:
            return out
        for i in range(rows):
            if ey[i + 1] <= iy0 or ey[i] >= iy1:
                continue
            for j in range(cols):
                if ex[j + 1] <= ix0 or ex[j] >= ix1:
                    continue
                out[i * cols + j] = True
        return out
    m = np.asarray(obj).astype(bool)
    if m.ndim == 3:
        m = m.any(axis=0)
    if m.shape != (H, W):
        raise ValueError(f"mask shape {m.shape} does not match the screen ({H}, {W})")
    for i in range(rows):
        band = m[ey[i] : ey[i + 1]]
        if not band.any():
            continue
        colany = band.any(axis=0)
        for j in range(cols):
            out[i * cols + j] = bool(colany[ex[j] : ex[j + 1]].any())
    return out


def contaminated_regions(changed_mask_or_bbox, H: int, W: int, P: int) -> int:
    """Number of regions of a P-way sort-first grid touched by a pixel mask or bbox."""
    return int(region_set(changed_mask_or_bbox, H, W, P).sum())


def regions_to_bitmask(regions) -> int:
    """Region set (bool array or index list) -> int bitmask (bit r set when region r touched)."""
    a = np.asarray(regions)
    idx = np.nonzero(a)[0] if a.dtype == bool else a.astype(np.int64).reshape(-1)
    v = 0
    for r in idx:
        v |= 1 << int(r)
    return v


def decode_regions(value, P: int) -> np.ndarray | None:
    """A stored region set -> bool array of P. Accepts an int bitmask (bit r = region r; an int64
    holding a 64-bit mask may be negative), a list/array of region indices, a bool array of
    length P, or a comma-separated string of indices. None/NaN -> None (not measured)."""
    if value is None or value is pd.NA:
        return None
    if isinstance(value, (float, np.floating)):
        if math.isnan(value):
            return None
        if float(value).is_integer():  # an integer column widened to float by missing values
            value = int(value)
    out = np.zeros(P, dtype=bool)
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        v = int(value) & ((1 << 64) - 1)
        for r in range(min(P, 64)):
            if (v >> r) & 1:
                out[r] = True
        return out
    if isinstance(value, str):
        idx = [int(t) for t in value.replace(";", ",").split(",") if t.strip()]
        out[idx] = True
        return out
    a = np.asarray(value)
    if a.dtype == bool and a.size == P:
        return a.reshape(-1).copy()
    if a.size:
        out[a.astype(np.int64).reshape(-1)] = True
    return out


def region_iou(a, b) -> float:
    """IoU of two region sets (bool arrays); NaN when both are empty."""
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    union = int((a | b).sum())
    if union == 0:
        return float("nan")
    return int((a & b).sum()) / union


def popcount64(a) -> np.ndarray:
    """Set bits per element of a uint64 array."""
    a = np.ascontiguousarray(a, dtype=np.uint64)
    if hasattr(np, "bitwise_count"):
        return np.bitwise_count(a).astype(np.int64)
    return np.unpackbits(a.view(np.uint8).reshape(-1, 8), axis=1).sum(axis=1).astype(np.int64)


def bitmask_array(col: pd.Series, P: int):
    """(uint64 masks, valid) for an integer (or integral-float) bitmask column, else None."""
    if P > 64 or not pd.api.types.is_numeric_dtype(col):
        return None
    valid = col.notna().to_numpy()
    if pd.api.types.is_float_dtype(col):
        v = col.to_numpy(float)
        if not np.all(np.mod(v[valid], 1) == 0):
            return None
        out = np.zeros(len(col), dtype=np.uint64)
        out[valid] = v[valid].astype(np.int64).view(np.uint64)
        return out, valid
    if pd.api.types.is_bool_dtype(col):
        return None
    v = col.to_numpy(dtype=np.int64, na_value=0)
    return np.ascontiguousarray(v, dtype=np.int64).view(np.uint64), valid


def region_stats(pred_col: pd.Series, meas_col: pd.Series, P: int):
    """Per record: regions predicted, regions measured and their IoU (NaN where not measured or
    both empty). Vectorised for bitmask columns; per record otherwise."""
    a, b = bitmask_array(pred_col, P), bitmask_array(meas_col, P)
    if a is not None and b is not None:
        keep = np.uint64((1 << P) - 1) if P < 64 else np.uint64(0xFFFFFFFFFFFFFFFF)
        pa, va = a[0] & keep, a[1]
        pb, vb = b[0] & keep, b[1]
        npred = np.where(va, popcount64(pa), np.nan)
        nmeas = np.where(vb, popcount64(pb), np.nan)
        inter, union = popcount64(pa & pb), popcount64(pa | pb)
        with np.errstate(invalid="ignore", divide="ignore"):
            iou = np.where(va & vb & (union > 0), inter / np.maximum(union, 1), np.nan)
        return npred.astype(float), nmeas.astype(float), iou.astype(float)
    pred = [decode_regions(v, P) for v in pred_col]
    meas = [decode_regions(v, P) for v in meas_col]
    npred = np.array([np.nan if x is None else x.sum() for x in pred], dtype=float)
    nmeas = np.array([np.nan if x is None else x.sum() for x in meas], dtype=float)
    iou = np.array([np.nan if (x is None or y is None) else region_iou(x, y) for x, y in zip(pred, meas)], dtype=float)
    return npred, nmeas, iou


REGION_COLUMN = re.compile(r"^regions_pred_(\d+)$")


REGION_SUM = re.compile(r"^region_fp_(\d+)_sum$")
REGION_STATS = ("fp", "fm", "iou", "fpf", "fmf")  # fpf, fmf: per frame (mean over the views)
REGION_SUM_COLUMN = re.compile(r"^region_(fp|fm|iou|fpf|fmf)_\d+_(sum|n)$")


def region_sum_columns(columns) -> list:
    """The per-row contamination sums among `columns` (`region_sums`; added up when rows fold)."""
    return [c for c in columns if REGION_SUM_COLUMN.match(str(c))]


def contamination_partitions(df: pd.DataFrame) -> list[int]:
    """Partition sizes P with both regions_pred_{P} and regions_meas_{P} columns (or, on a folded
    frame, their per-row sums: `region_sums`)."""
    ps = set()
    for c in df.columns:
        m = REGION_COLUMN.match(str(c))
        if m and f"regions_meas_{m.group(1)}" in df.columns:
            ps.add(int(m.group(1)))
        m = REGION_SUM.match(str(c))
        if m:
            ps.add(int(m.group(1)))
    return sorted(ps)


def region_sums(d: pd.DataFrame, P: int) -> dict[str, np.ndarray]:
    """Per row: for each of fp (predicted share of the P regions), fm (measured share) and iou,
    the sum over the row's records where it is defined and their count, as
    {"fp_sum", "fp_n", ...}. Folded rows (analysis.folding) carry them as region_{stat}_{P}_sum
    and _n columns; a record's sum is its value (0 where undefined) and its count 1 or 0."""
    if f"region_fp_{P}_sum" in d:
        zero = np.zeros(len(d))  # folded by older code: no per-frame sums (undefined, count 0)
        return {
            f"{k}_{x}": d[f"region_{k}_{P}_{x}"].to_numpy(float).copy() if f"region_{k}_{P}_{x}" in d else zero.copy()
            for k in REGION_STATS
            for x in ("sum", "n")
        }
    if f"regions_pred_{P}" not in d or f"regions_meas_{P}" not in d:
        return {f"{k}_{x}": np.zeros(len(d)) for k in REGION_STATS for x in ("sum", "n")}
    npred, nmeas, iou = region_stats(d[f"regions_pred_{P}"], d[f"regions_meas_{P}"], P)
    nan = np.full(len(d), np.nan)
    frames = [
        pd.to_numeric(d[c], errors="coerce").to_numpy(float) if c in d else nan
        for c in (f"regions_pred_frame_{P}", f"regions_meas_frame_{P}")
    ]
    out = {}
    for k, v in (("fp", npred / P), ("fm", nmeas / P), ("iou", iou), ("fpf", frames[0]), ("fmf", frames[1])):
        ok = np.isfinite(v)
        out[f"{k}_sum"], out[f"{k}_n"] = np.where(ok, v, 0.0), ok.astype(float)
    return out


def contamination(df: pd.DataFrame) -> pd.DataFrame:
    """Fraction of P sort-first regions a single upset contaminates, predicted (projected
    footprint) and measured (changed pixels), their IoU, per (precision, defense, P), for all
    single upsets and for log-scale sign flips. Per frame as the paper counts (pred_frame_pct,
    meas_frame_pct: the regions one rendered frame reaches, averaged over the views; NaN for
    records that predate them), and over the union of the views (pred_fraction_pct,
    meas_fraction_pct, and the IoU, which is of the union masks). Needs columns regions_pred_{P}/regions_meas_{P}
    (see `decode_regions`); optional region_ms_max_{P}/region_ms_mean_{P} give the slowest-region
    render time and the load imbalance (max / mean). IoU is averaged over records where either
    set is non-empty."""
    d = single_upsets(df, None, None)
    ps = contamination_partitions(d)
    if not ps or d.empty:
        raise InsufficientData(
            "no regions_pred_P / regions_meas_P columns in the records",
            "run a single-upset campaign with regions = [4, 16, 64] in its [single] "
            "table (sort-first partitions; `seuwgpu distributed` times the regions)",
        )
    rows = []
    m = multiplicity(d).astype(float)
    for P in ps:
        sums = region_sums(d, P)
        tmax = d.get(f"region_ms_max_{P}")
        tmean = d.get(f"region_ms_mean_{P}")
        e = pd.DataFrame(
            {
                "weight": d["weight"].to_numpy(float),
                "m": m,
                "precision": d["precision"].to_numpy(),
                "defense": d["defense"].to_numpy(),
                "sign_scale": ((d["field"] == "log_scales") & (d["bit_class"] == "sign")).to_numpy(),
                **sums,
                "tmax": np.nan if tmax is None else pd.to_numeric(tmax).to_numpy(float),
                "tmean": np.nan if tmean is None else pd.to_numeric(tmean).to_numpy(float),
            }
        )
        for subset, sel in (("all single upsets", slice(None)), ("log-scale sign", e["sign_scale"])):
            es = e[sel] if not isinstance(sel, slice) else e
            for (prec, dfn), g in es.groupby(["precision", "defense"], sort=False):
                w = g["weight"].to_numpy(float)
                rows.append(
                    {
                        "subset": subset,
                        "precision": prec,
                        "defense": dfn,
                        "P": P,
                        "n": int(g["m"].sum()),
                        "pred_frame_pct": 100 * _wmean_of_sums(g["fpf_sum"], g["fpf_n"], w),
                        "meas_frame_pct": 100 * _wmean_of_sums(g["fmf_sum"], g["fmf_n"], w),
                        "pred_fraction_pct": 100 * _wmean_of_sums(g["fp_sum"], g["fp_n"], w),
                        "meas_fraction_pct": 100 * _wmean_of_sums(g["fm_sum"], g["fm_n"], w),
                        "iou_mean": _wmean_of_sums(g["iou_sum"], g["iou_n"], w),
                        "n_iou": int(g["iou_n"].sum()),
                        "slowest_region_ms": _mean_of_rows(g["tmax"], g["m"]),
                        "imbalance": _mean_of_rows(g["tmax"] / g["tmean"], g["m"]),
                    }
                )
    out = pd.DataFrame(rows)
    out = out.sort_values(["subset", "precision", "defense", "P"], kind="stable").reset_index(drop=True)
    return tag(out, d)


def _wmean_of_sums(sums, counts, w) -> float:
    """Weighted mean over the defined values, from per-row sums and counts (estimate.wmean's
    definition: NaN when none is defined)."""
    den = float(np.sum(w * np.asarray(counts, float)))
    return float(np.sum(w * np.asarray(sums, float)) / den) if den > 0 else float("nan")


def _mean_of_rows(values, m) -> float:
    """Unweighted mean over the records (each row counted m times) where the value is defined."""
    v, m = np.asarray(values, float), np.asarray(m, float)
    ok = ~np.isnan(v)
    return float(np.sum(v[ok] * m[ok]) / np.sum(m[ok])) if ok.any() else float("nan")


def plot_contamination(cont: pd.DataFrame, precision: str | None = None, defenses: tuple[str, ...] = ("none", "guard")):
    """Share of regions contaminated against P at one precision (fp32 by default), predicted
    (solid) and measured (dashed), for log-scale sign flips (all single upsets if none)."""
    fig = figure(6.0, 3.8)
    ax = fig.subplots()
    sub = cont[cont["subset"] == "log-scale sign"]
    if sub.empty:
        sub = cont[cont["subset"] == "all single upsets"]
    if len(sub):
        precision = precision or reference_precision(sub)
        sub = sub[(sub["precision"] == precision)]
        if sub["defense"].isin(defenses).any():
            sub = sub[sub["defense"].isin(defenses)]
    for dfn, g in sub.groupby("defense", sort=False):
        g = g.sort_values("P")
        (line,) = ax.plot(g["P"], g["pred_fraction_pct"], "-o", ms=3, label=f"{defense_label(dfn)}: predicted")
        ax.plot(
            g["P"],
            g["meas_fraction_pct"],
            "--s",
            ms=3,
            color=line.get_color(),
            label=f"{defense_label(dfn)}: measured",
        )
    ax.set_xscale("log", base=2)
    if len(sub):
        ps = sorted(set(sub["P"]))
        ax.set_xticks(ps, [str(p) for p in ps])
        ax.set_title(f"{sub['subset'].iloc[0]}, {precision}", fontsize=9)
    ax.set_ylim(-2, 102)
    ax.set_xlabel("regions P (sort-first partition)")
    ax.set_ylabel("regions contaminated (%)")
    ax.legend(fontsize=7)
    return fig


# ---- claims rows (analysis.claims gathers them) ----------------------------------------------------


def contamination_rows(df: pd.DataFrame, conf: float = 0.95) -> list[dict]:
    """At the paper's finest partition, per model then over models, both ways and labelled: per
    frame (as the paper counts, `pred_frame_pct`) and over the union of the views
    (`pred_fraction_pct`); the IoU is of the union masks (the records hold no per-frame IoU)."""
    from seuwgpu.analysis.claimrows import over_models, row
    from seuwgpu.analysis.paper import PAPER_CONTAMINATION_P
    from seuwgpu.analysis.population import MODEL
    from seuwgpu.analysis.records import n_records, scale_sign_flips

    s = single_upsets(df, "fp32", None)
    sign = scale_sign_flips(s)
    keys = {
        ("none", "pred_frame_pct"): "contam_none",
        ("guard", "pred_frame_pct"): "contam_guard",
        ("none", "pred_fraction_pct"): "contam_none_union",
        ("guard", "pred_fraction_pct"): "contam_guard_union",
        ("none", "iou_mean"): "contam_iou",
    }
    what = {
        "pred_frame_pct": "predicted share of one frame's regions, averaged over the views (per frame, as the paper "
        "counts)",
        "pred_fraction_pct": "predicted share of the regions any view reaches (union of the views)",
        "iou_mean": "IoU of the union masks over the views (the records hold no per-frame IoU)",
    }
    per: dict[str, list] = {k: [] for k in keys.values()}
    pooled: dict[str, float] = {}

    def pick(t: pd.DataFrame, dfn: str, col: str) -> float:
        r = t[(t["subset"] == "log-scale sign") & (t["defense"] == dfn) & (t["P"] == PAPER_CONTAMINATION_P)]
        return float(r[col].iloc[0]) if len(r) and col in r else np.nan

    for part, d in [(None, sign)] + [(k, g) for k, g in sign.groupby(MODEL, sort=False)]:
        try:
            t = contamination(d)
        except InsufficientData:
            continue
        for (dfn, col), key in keys.items():
            if part is None:
                pooled[key] = pick(t, dfn, col)
            else:
                per[key].append({"scene": part[0], "n_primitives": part[1], "v": pick(t, dfn, col)})
    rows = []
    for (dfn, col), key in keys.items():
        if not np.isfinite(pooled.get(key, np.nan)):
            rows.append(row(key))
            continue
        basis = f"n = {n_records(sign[sign['defense'] == dfn]):,} log-scale sign flips; {what[col]}"
        rows.append(
            over_models(
                key, pd.DataFrame(per[key], columns=MODEL + ["v"]), "v", basis, conf, (pooled[key], np.nan, np.nan), 1.0
            )
        )
    return rows
