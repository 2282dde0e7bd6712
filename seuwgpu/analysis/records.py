"""Campaign records as the analyses read them: defaults filled, weights attached, selections.

Every analysis is a function over a records DataFrame (one row per injection and defense, the
campaign contract; `seuwgpu.report.load_runs` reads run directories into one). Each returned table
carries ``df.attrs["provenance"]``: the runs, scenes, precisions, defenses, campaigns and record
count it rests on, so a report can caption it honestly. An analysis that lacks the data it needs
raises `InsufficientData`, whose ``remedy`` names the campaign that would supply it.

Record selection: ``campaign`` is inferred when absent ("dose" for k > 1, else "single").
Reference precision: analyses reported "at fp32" use fp32 when present, else the first of fp16,
bf16 present; the provenance states the precision used.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.metrics.image import FOOTPRINT_THRESHOLD, PIXEL_THRESHOLD, outcome_class
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS, field_components, sh_rest_count

FIELD_LABELS = {
    "means": "mean",
    "log_scales": "log-scale",
    "quats": "quat",
    "opacity": "opacity",
    "sh_dc": "color (DC)",
    "sh_rest": "color (SH)",
}
DEFAULT_SH_DEGREE = 3


# Rows of a folded frame (analysis/folding.py) each stand for `multiplicity` records that agree in
# every column the analyses read; a frame without the column holds one record per row.
MULTIPLICITY = "multiplicity"
# On a folded frame, the unfolded records that form the prediction's random sample.
PREDICTION_SAMPLE = "prediction_sample"


def multiplicity(d: pd.DataFrame) -> np.ndarray:
    """Records per row (ones for a plain record frame)."""
    if MULTIPLICITY in d:
        return d[MULTIPLICITY].to_numpy(np.int64)
    return np.ones(len(d), np.int64)


def n_records(d: pd.DataFrame) -> int:
    """Records a frame stands for (its rows, on a plain record frame)."""
    return int(d[MULTIPLICITY].sum()) if MULTIPLICITY in d else len(d)


def record_weights(d: pd.DataFrame) -> np.ndarray:
    """Stored bits each row stands for: its records' weight times their number."""
    return d["weight"].to_numpy(float) * multiplicity(d)


class InsufficientData(Exception):
    """An analysis cannot run on these records; `remedy` names the campaign that would help."""

    def __init__(self, reason: str, remedy: str = ""):
        super().__init__(reason)
        self.reason = reason
        self.remedy = remedy


def thresholds_of(manifests: Iterable[dict] = ()) -> dict:
    """Outcome thresholds of the runs (manifest "outcomes"; the metric defaults otherwise).
    Runs with different thresholds cannot be pooled: that is an error naming both."""
    seen = []
    for m in manifests or ():
        t = m.get("outcomes") or (m.get("spec") or {}).get("outcomes")
        if isinstance(t, dict):
            seen.append(
                (
                    float(t.get("pixel_threshold", PIXEL_THRESHOLD)),
                    float(t.get("footprint_threshold", t.get("footprint", FOOTPRINT_THRESHOLD))),
                )
            )
    if len(set(seen)) > 1:
        raise ValueError(f"runs use different outcome thresholds {sorted(set(seen))}: report them separately")
    pix, foot = seen[0] if seen else (PIXEL_THRESHOLD, FOOTPRINT_THRESHOLD)
    return {"pixel_threshold": pix, "footprint_threshold": foot}


def _stratum_weights(d: pd.DataFrame, deg: int) -> np.ndarray:
    """Weights for records that lack a `weight` column: the stored bits of the record's (scene, N,
    precision, field, bit) cell over the records that sampled it; 1 for multi-upset records."""
    w = np.ones(len(d))
    single = (d["k"] == 1) & (d["bit"] >= 0) & d["field"].isin(FIELDS)
    if not single.any():
        return w
    s = d[single]
    comps = s["field"].map(lambda f: field_components(f, deg)).to_numpy(float)
    n = pd.to_numeric(s.get("n_primitives", pd.Series(1, index=s.index)), errors="coerce").fillna(1).to_numpy(float)
    keys = [c for c in ("run", "scene", "n_primitives", "precision", "defense", "field", "bit") if c in s]
    count = s.groupby(keys, sort=False)["k"].transform("size").to_numpy(float)
    w[single.to_numpy()] = n * comps / count
    return w


def prepare(df: pd.DataFrame, thresholds: dict | None = None) -> pd.DataFrame:
    """Fill optional columns, attach weights and outcome classes (idempotent; a new frame).

    * PSNR, SSIM and LPIPS of frames with a non-finite pixel are set to NaN (older records hold a
      display-referred number there; it is not defined).
    * ``weight``: stored bits each record stands for (written by the runner; derived per cell
      for records without it).
    * ``outcome``: masked / tolerable / sdc / catastrophic (`metrics.image.outcome_class`) with
      the runs' thresholds; ``catastrophic`` is recomputed from it so both agree.
    """
    if df.attrs.get("_seuwgpu_prepared") or MULTIPLICITY in df:  # a folded frame is prepared by folding
        return df
    thr = thresholds or {"pixel_threshold": PIXEL_THRESHOLD, "footprint_threshold": FOOTPRINT_THRESHOLD}
    d = df.copy()
    if "k" not in d:
        d["k"] = 1
    d["k"] = pd.to_numeric(d["k"], errors="coerce").fillna(1).astype(np.int64)
    if "defense" not in d:
        d["defense"] = "none"
    d["defense"] = d["defense"].astype(object).where(d["defense"].notna(), "none").astype(str)
    inferred = pd.Series(np.where(d["k"] > 1, "dose", "single"), index=d.index, dtype=object)
    if "campaign" in d:
        camp = d["campaign"].astype(object)
        d["campaign"] = camp.where(camp.notna(), inferred).astype(str)
    else:
        d["campaign"] = inferred.astype(str)
    # the renderer profile (docs/renderer.md); records written before profiles existed are strict
    profile = d["profile"].astype(object) if "profile" in d else pd.Series("strict", index=d.index, dtype=object)
    d["profile"] = profile.where(profile.notna(), "strict").astype(str)
    if "run" not in d:
        d["run"] = "run"
    d["run"] = d["run"].astype(str)
    for col in ("scene", "precision", "field", "bit_class"):
        if col in d:
            d[col] = d[col].astype(str)
    for col in ("primitive", "component", "bit"):
        if col in d:
            d[col] = pd.to_numeric(d[col], errors="coerce").fillna(-1).astype(np.int64)
    if "nonfinite" not in d:
        d["nonfinite"] = False
    d["nonfinite"] = d["nonfinite"].fillna(False).astype(bool)
    for col in (
        "time_ms",
        "psnr",
        "ssim",
        "peak_error",
        "footprint",
        "footprint_max",
        "clean_value",
        "corrupted_value",
    ):
        if col not in d:
            d[col] = np.nan
        d[col] = pd.to_numeric(d[col], errors="coerce").astype(float)
    d.loc[d["nonfinite"], ["psnr", "ssim", "lpips"]] = np.nan
    if "repeat" not in d:
        d["repeat"] = 0
    if "n_primitives" in d:
        d["n_primitives"] = pd.to_numeric(d["n_primitives"], errors="coerce").astype(np.int64)
    if "field" not in d:
        d["field"] = "mixed"
    if "bit" not in d:
        d["bit"] = -1
    w = pd.to_numeric(d["weight"], errors="coerce") if "weight" in d else pd.Series(np.nan, index=d.index)
    if w.isna().any():
        w = w.fillna(pd.Series(_stratum_weights(d, sh_degree_of(d)), index=d.index))
    d["weight"] = w.astype(float)
    d["outcome"] = outcome_class(
        d["peak_error"].to_numpy(float),
        d["footprint"].to_numpy(float),
        d["nonfinite"].to_numpy(bool),
        thr["pixel_threshold"],
        thr["footprint_threshold"],
    )
    d["catastrophic"] = (d["outcome"] == "catastrophic").to_numpy()
    d.attrs["_seuwgpu_prepared"] = True
    d.attrs["thresholds"] = dict(thr)
    return d


def unique_sorted(values) -> list:
    out = []
    for v in pd.unique(pd.Series(values).dropna()):
        out.append(v.item() if hasattr(v, "item") else v)
    return sorted(out, key=lambda x: (str(type(x)), x))


PROVENANCE_COLUMNS = ("run", "scene", "precision", "defense", "campaign", "k", "profile")


def provenance(d: pd.DataFrame) -> dict:
    """What a table or figure rests on: runs, scenes, precisions, defenses, campaigns, k, n."""
    order = {"precision": encoding.PRECISIONS, "defense": DEFENSES}

    def col(name):
        vals = unique_sorted(d[name]) if name in d and len(d) else []
        if name in order:
            known = [v for v in order[name] if v in vals]
            vals = known + [v for v in vals if v not in known]
        return vals

    ks = col("k")
    return {
        "runs": col("run"),
        "scenes": col("scene"),
        "precisions": col("precision"),
        "defenses": col("defense"),
        "campaigns": col("campaign"),
        "k_range": [int(min(ks)), int(max(ks))] if ks else [],
        "n_records": n_records(d),
    }


def provenance_text(prov: dict) -> str:
    if not prov:
        return ""
    parts = [f"{prov.get('n_records', 0):,} records"]
    for key in ("runs", "scenes", "precisions", "defenses", "campaigns"):
        vals = prov.get(key) or []
        if vals:
            parts.append(f"{key}: {', '.join(map(str, vals))}")
    kr = prov.get("k_range") or []
    if kr and kr[1] > 1:
        parts.append(f"k = {kr[0]}..{kr[1]}")
    return "Rests on " + "; ".join(parts) + "."


def tag(out: pd.DataFrame, d: pd.DataFrame, **extra) -> pd.DataFrame:
    """Attach the provenance of records `d` (and extra attrs) to a result table."""
    out.attrs["provenance"] = provenance(d)
    out.attrs.update(extra)
    return out


def ordered(have, order) -> list:
    have = set(have)
    return [x for x in order if x in have] + sorted(have - set(order))


def precisions_present(df: pd.DataFrame) -> list[str]:
    return ordered(df["precision"].astype(str), encoding.PRECISIONS) if "precision" in df else []


def reference_precision(df: pd.DataFrame) -> str:
    """fp32 when present, else the first of fp16, bf16 present (documented reporting choice)."""
    pres = precisions_present(df)
    if not pres:
        raise InsufficientData("no records", "run a campaign")
    return pres[0]


def defenses_present(df: pd.DataFrame) -> list[str]:
    return ordered(df["defense"].astype(str), DEFENSES)


def fields_present(df: pd.DataFrame) -> list[str]:
    return ordered(df["field"].astype(str), FIELDS)


def sort_rows(t: pd.DataFrame) -> pd.DataFrame:
    """Rows in the canonical order: precision (fp32, fp16, bf16, all), then defense."""
    if t.empty:
        return t.reset_index(drop=True)
    porder = {p: i for i, p in enumerate(encoding.PRECISIONS + ("all",))}
    dorder = {x: i for i, x in enumerate(DEFENSES)}
    key = {}
    if "precision" in t:
        key["_p"] = t["precision"].map(lambda x: porder.get(x, 99))
    if "defense" in t:
        key["_d"] = t["defense"].map(lambda x: dorder.get(x, 99))
    if not key:
        return t.reset_index(drop=True)
    t = t.assign(**key)
    return t.sort_values(list(key), kind="stable").drop(columns=list(key)).reset_index(drop=True)


def single_mask(d: pd.DataFrame) -> np.ndarray:
    """Rows of prepared records that are k = 1 upsets of the single-upset campaign."""
    return ((d["k"] == 1) & (d["campaign"] == "single")).to_numpy()


def single_upsets(df: pd.DataFrame, precision: str | None = None, defense: str | None = "none") -> pd.DataFrame:
    """k = 1 records of the single-upset campaign, optionally at one precision and defense."""
    d = prepare(df)
    m = single_mask(d)
    if precision is not None:
        m = m & (d["precision"] == precision).to_numpy()
    if defense is not None:
        m = m & (d["defense"] == defense).to_numpy()
    # every record selected (a single-upset run): a lazy copy (copy-on-write), not a second frame
    return d.copy(deep=False) if m.all() else d[m]


def scale_sign_flips(s: pd.DataFrame) -> pd.DataFrame:
    """The log-scale sign-bit flips among single-upset records: the paper's worst case, which
    several claims rows, the guard's table and the criticality section each report."""
    return s[(s["field"] == "log_scales") & (s["bit_class"] == "sign")]


def require_single(df, defense="none") -> pd.DataFrame:
    s = single_upsets(df, None, defense)
    if s.empty:
        raise InsufficientData(
            f"no single-upset records (k = 1, campaign 'single') with defense '{defense}'",
            "run a single-upset campaign over all fields and bits",
        )
    return s


def dose_records(df: pd.DataFrame) -> pd.DataFrame:
    d = prepare(df)
    return d[d["campaign"] == "dose"]


def pair_keys(df: pd.DataFrame) -> list[str]:
    """Columns that identify one fault site across defenses (records are paired on these)."""
    return [c for c in ("run", "scene", "precision", "campaign", "injection_id") if c in df]


def key_hash(d: pd.DataFrame, columns) -> np.ndarray:
    """A uint64 hash per row of the given columns, independent of how a part happened to store
    them (integers with or without nulls hash alike; -1 stands for a missing integer)."""
    cols = {}
    for c in columns:
        v = d[c]
        if pd.api.types.is_numeric_dtype(v) and not pd.api.types.is_bool_dtype(v):
            x = pd.to_numeric(v, errors="coerce")
            whole = x.isna() | (x == np.round(x))
            cols[c] = x.fillna(-1).astype(np.int64) if whole.all() else x.astype(float)
        else:
            cols[c] = v.astype(str)
    return pd.util.hash_pandas_object(pd.DataFrame(cols), index=False).to_numpy(np.uint64)


# what identifies a record's fault site for the prediction's random draw
DRAW_SITE = ("run", "scene", "precision", "field", "bit", "injection_id", "primitive", "component", "seed")


def draw_share(d: pd.DataFrame) -> np.ndarray:
    """A uniform number in [0, 1) per record from a hash of its site: a random draw that does not
    depend on the order records are read in (the prediction's sample, folded or not)."""
    h = key_hash(d, [c for c in DRAW_SITE if c in d])
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def prediction_draw(population: int, max_rows: int) -> float:
    """The probability with which the prediction keeps each of `population` records."""
    return min(1.0, max_rows / population) if population else 1.0


# Per record, what the same fault site gave under the other defenses (folded frames carry these,
# as the sites themselves are gone): the catastrophic flag under "none" (NaN where not measured)
# and the defenses measured at the site, as a bit mask over DEFENSES (`defense_bit`).
NONE_CATASTROPHIC = "none_catastrophic"
SITE_DEFENSES = "site_defenses"
# A defense name the package does not know (records of an older version: campaign specs accept only
# DEFENSES): one bit for all such names, below 2^53 so that it survives a float column.
OTHER_DEFENSE_BIT = 52


def defense_bit(names) -> np.ndarray:
    """Each defense's bit in a SITE_DEFENSES mask."""
    pos = {d: i for i, d in enumerate(DEFENSES)}
    return np.array([1 << pos.get(str(n), OTHER_DEFENSE_BIT) for n in names], dtype=np.int64)


def pair_columns(s: pd.DataFrame) -> pd.DataFrame:
    """Records with NONE_CATASTROPHIC and SITE_DEFENSES (computed over `s` from pair_keys unless
    present). A site measured twice under "none" takes the first record's flag; each record under
    another defense counts (folded frames cannot tell repeats apart)."""
    if NONE_CATASTROPHIC in s and SITE_DEFENSES in s:
        return s
    keys = pair_keys(s)
    if not len(s):
        return s.assign(**{NONE_CATASTROPHIC: np.nan, SITE_DEFENSES: np.int64(0)})
    site = pd.MultiIndex.from_frame(s[keys])
    none = s.loc[s["defense"] == "none", keys + ["catastrophic"]].drop_duplicates(keys)
    flag = none.set_index(keys)["catastrophic"].astype(float).reindex(site).to_numpy()
    codes, names = pd.factorize(s["defense"])
    arms = s[keys].assign(_bit=defense_bit(names)[codes])
    arms = arms.drop_duplicates(keys + ["_bit"]).groupby(keys, sort=False)["_bit"].sum()
    return s.assign(**{NONE_CATASTROPHIC: flag, SITE_DEFENSES: arms.reindex(site).to_numpy(np.int64)})


def measured_under(s: pd.DataFrame, defenses) -> np.ndarray:
    """Rows (with pair_columns) whose fault site was measured under every one of `defenses`."""
    need = np.bitwise_or.reduce(defense_bit(list(defenses))) if len(defenses) else np.int64(0)
    return (s[SITE_DEFENSES].to_numpy(np.int64) & need) == need


def scene_degrees(manifests: Iterable[dict] = ()) -> dict[str, int]:
    """SH degree of each scene, by the label records give it, as the runs' specs state it (a
    model file's own degree since specs read it; runs of older versions stated 3 for every model
    file, so inference from the records comes first where there is any: reliability.model_degrees)."""
    from seuwgpu.campaign.spec import scene_label
    from seuwgpu.campaign.spec_types import stored_scenes

    out: dict[str, int] = {}
    for m in manifests or ():
        for sc in stored_scenes(m):
            label = scene_label(sc) if sc.sh_degree is not None else None
            if label:
                out.setdefault(str(label), int(sc.sh_degree))
    return out


def model_file_scenes(manifests: Iterable[dict] = ()) -> frozenset[str]:
    """The labels records give the runs' model files (a spec's `model = FILE`), which may share a
    name with an embedded procedural scene (the corpus' plant.splat and the procedural plant):
    what tells a real model from a procedural one (`population.population_of`)."""
    from seuwgpu.campaign.spec import scene_label
    from seuwgpu.campaign.spec_types import stored_scenes

    return frozenset(str(scene_label(sc)) for m in manifests or () for sc in stored_scenes(m) if sc.model)


def sh_degree_of(df: pd.DataFrame | None = None, manifests: Iterable[dict] = ()) -> int:
    """SH degree of the models: from a manifest's spec ("sh_degree") when stated, else inferred
    from the largest sh_rest component index in the records (when at least 50 sh_rest records
    name at least 5 distinct components), else DEFAULT_SH_DEGREE (3, the INRIA/gsplat default)."""
    for m in manifests or ():
        spec = m.get("spec", {}) or {}
        for src in [spec, m, m.get("model", {}) or {}] + list(spec.get("scenes", []) or []):
            deg = src.get("sh_degree") if isinstance(src, dict) else None
            if deg is not None:
                try:
                    return int(deg)
                except (TypeError, ValueError):
                    pass
    if df is not None and len(df) and "field" in df and "component" in df:
        sh = df[df["field"].astype(str) == "sh_rest"]
        comp = pd.to_numeric(sh["component"], errors="coerce")
        ok = (comp >= 0).to_numpy()
        comp = comp[ok]
        # with few samples, or a campaign that targets a few components, the largest index
        # sampled says little about the degree
        if multiplicity(sh)[ok].sum() >= 50 and comp.nunique() >= 5:
            need = int(comp.max()) + 1
            for deg in (1, 2, 3):
                if 3 * sh_rest_count(deg) >= need:
                    return deg
    return DEFAULT_SH_DEGREE


# Okabe & Ito's colour-blind safe palette (yellow last: faint on white): series told apart by
# colour stay apart under deuteranopia and protanopia, which matplotlib's default cycle does not
# (its orange/green/red/brown pairs merge)
PALETTE = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#56B4E9", "#CC79A7", "#000000", "#F0E442")


def series_color(i: int) -> str:
    """The i-th colour of PALETTE (cycling)."""
    return PALETTE[i % len(PALETTE)]


def rate_points(ax, x, rate, lo, hi, color, label=None, marker="o", horizontal=False):
    """Rates (%) with their 95% intervals on a log axis: a point and whiskers where events were
    seen; where none were (rate 0, no logarithm) an open triangle at the interval's upper end,
    pointing down (or left): the rate lies below it, never drawn as a 0 the axis cannot hold. An
    undefined rate (NaN: no records) is not drawn. Returns the number of no-event triangles."""
    x, rate, lo, hi = (np.asarray(v, float) for v in (x, rate, lo, hi))
    pos = rate > 0
    none = rate == 0
    err = np.vstack([rate - np.maximum(lo, rate * 1e-3), hi - rate])[:, pos]
    kw = dict(fmt=marker, color=color, ms=5, capsize=2, elinewidth=1, label=label)
    if horizontal:
        ax.errorbar(rate[pos], x[pos], xerr=err, **kw)
        ax.plot(hi[none], x[none], "<", mfc="none", color=color, ms=7)
    else:
        ax.errorbar(x[pos], rate[pos], yerr=err, **kw)
        ax.plot(x[none], hi[none], "v", mfc="none", color=color, ms=7)
    return int(none.sum())


def figure(w=6.4, h=4.0):
    """A matplotlib Figure without pyplot (Agg canvas; safe headless and in threads)."""
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=110, layout="constrained")
