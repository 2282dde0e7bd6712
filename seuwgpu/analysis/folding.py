"""Records folded as they are read, so that a planner-sized study's report fits in memory.

A study at planner sample sizes holds tens of millions of records (docs/study): about 2 KB each
while a report is built, more than a workstation has. Most records differ only in columns no
analysis reads of them: the site (primitive, injection id, stored value) and image metrics that
only a few subsets need row by row. `fold_part` therefore blanks, record by record, the detail
columns nothing will read of that record, then folds records that agree in every remaining column
into one row carrying their number (records.MULTIPLICITY); the estimator layer and the analyses
weigh each row by it, so every rate, interval, weighted mean, weighted quantile and maximum equals
that of the records themselves (tests/test_folding.py compares whole reports).

What each record keeps, and which analysis needs it:
* multi-upset and non-single campaigns (dose, size, state, storm): everything (read row by row);
* log-scale sign flips: everything (guard PSNR table, claims' bootstrap, criticality notes);
* the prediction sample (defense none): everything; a Bernoulli sample of the records, each kept
  with probability max_pred_rows / (records of its profile and precision), decided by a hash of
  the site so that the sample does not depend on the order the parts are read in;
* log-scale mantissa flips without defense: peak_error (theory check: mean and median per bit);
* colour SH coefficients: component (the SH degree the records reach);
* single upsets under a renderer profile other than strict, when strict records are there too:
  only their outcome rates (RATES_ONLY; the report's profile table; its other sections rest on
  the strict records alone);
* every record: the same site's catastrophic flag under "none" and the defenses measured at the
  site (records.pair_columns; computed within the part, where a block writes all its arms), and
  the sort-first contamination as per-row sums (contamination.region_sums).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis.contamination import REGION_STATS, contamination_partitions, region_sum_columns, region_sums
from seuwgpu.analysis.records import (
    MULTIPLICITY,
    NONE_CATASTROPHIC,
    PREDICTION_SAMPLE,
    SITE_DEFENSES,
    draw_share,
    key_hash,
    pair_columns,
    pair_keys,
    single_mask,
)

# columns read only of the records that keep them (see the module notes)
DETAIL = (
    "primitive",
    "component",
    "injection_id",
    "seed",
    "clean_value",
    "corrupted_value",
    "psnr",
    "ssim",
    "lpips",
    "peak_error",
    "footprint_max",
    "clamps",
)
# what the outcome rates of a record need (analysis.outcomes.catastrophic_by_profile)
RATES_ONLY = ("run", "campaign", "scene", "n_primitives", "precision", "profile", "field", "bit", "bit_class")
RATES_ONLY += ("defense", "nonfinite", "catastrophic", "outcome", "k", "repeat", "weight")
# columns no analysis reads: not carried at all
UNREAD = ("seed", "fault", "clamps", "footprint_max", "corrupted_value")


def prediction_mask(d: pd.DataFrame) -> np.ndarray:
    """Prepared records the prediction samples from: k = 1 single upsets at a bit, no defense."""
    return single_mask(d) & (d["defense"] == "none").to_numpy() & (d["bit"] >= 0).to_numpy()


def prediction_population(d: pd.DataFrame) -> pd.Series:
    """Records per (profile, precision) that the prediction samples from (prediction_mask)."""
    return d[prediction_mask(d)].groupby(["profile", "precision"]).size()


def fold_part(d: pd.DataFrame, keep_share: dict, rates_only=()) -> pd.DataFrame:
    """Fold one part's prepared records (records.prepare). keep_share maps (profile, precision)
    to the prediction sample's probability (missing: keep all). Single upsets of the profiles in
    rates_only keep only what their outcome rates need (RATES_ONLY): a report of several
    profiles rests on the strict profile's records but for their catastrophe rates."""
    d = pair_columns_of_single(d)
    single = single_mask(d)
    field, defense = d["field"].to_numpy(), d["defense"].to_numpy()
    bit_class = d["bit_class"].to_numpy() if "bit_class" in d else np.full(len(d), "")
    sign = (field == "log_scales") & (bit_class == "sign")
    coarse = single & d["profile"].isin(list(rates_only)).to_numpy()
    share = np.array([keep_share.get(k, 1.0) for k in zip(d["profile"], d["precision"])], float)
    sample = prediction_mask(d) & ~coarse & (draw_share(d) < share)
    whole = ~single | ((sign | sample) & ~coarse)
    out = d.drop(columns=[c for c in UNREAD if c in d])
    sums = region_sum_columns(out.columns)
    for c in out.columns:
        if c in RATES_ONLY or c in sums or (c not in DETAIL and not coarse.any()):
            continue
        keep = whole.copy() if c in DETAIL else ~coarse
        blank = 0 if c == SITE_DEFENSES else -1  # no defense known, not "every one"
        if c == "peak_error":
            keep |= (field == "log_scales") & (defense == "none") & (bit_class == "mantissa") & ~coarse
        elif c == "component":
            keep |= (field == "sh_rest") & ~coarse
        if not keep.all():
            v = out[c]
            out[c] = v.where(keep, blank if pd.api.types.is_integer_dtype(v) else np.nan)
    out[PREDICTION_SAMPLE] = sample
    out[MULTIPLICITY] = np.ones(len(out), np.int64)
    # records kept whole stay one row each, even where two agree in every column (repeats)
    out["_row"] = np.where(whole, np.arange(len(out)), -1)
    keys = [c for c in out.columns if c not in sums and c != MULTIPLICITY]
    folded = out.groupby(keys, sort=False, dropna=False, as_index=False, observed=True)[[MULTIPLICITY, *sums]].sum()
    return folded.drop(columns="_row")


def site_hashes(d: pd.DataFrame) -> np.ndarray:
    """Distinct hashes of the single-upset fault sites (records.pair_keys) of one part: folding
    pairs a site's defenses within its part, so no site may appear in two parts."""
    s = d[single_mask(d)]
    return np.unique(key_hash(s, pair_keys(s)))


def pair_columns_of_single(d: pd.DataFrame) -> pd.DataFrame:
    """records.pair_columns over the part's single upsets, contamination as per-row sums."""
    single = single_mask(d)
    paired = pair_columns(d[single])
    d = d.assign(
        **{
            NONE_CATASTROPHIC: paired[NONE_CATASTROPHIC].reindex(d.index),
            SITE_DEFENSES: paired[SITE_DEFENSES].reindex(d.index).fillna(0).astype(np.int64),
        }
    )
    for P in contamination_partitions(d):
        sums = region_sums(d, P)
        d = d.assign(**{f"region_{k}_{P}_{x}": sums[f"{k}_{x}"] for k in REGION_STATS for x in ("sum", "n")})
    drop = [c for c in d.columns if str(c).startswith(("regions_pred_", "regions_meas_"))]
    return d.drop(columns=drop)
