"""The paper's numbers (Alpay and Basaran, "Single-Event Upsets in 3D Gaussian Splatting
Rendering", ../shared/paper/seu-3dgs.tex), what they are compared against, and the margin each
comparison allows, stated here before any record is read.

They are what the claims table compares against, never a target of any computation. The paper
prints its values rounded (0.997, 0.634): such a value stands for every number that rounds to it,
[v - h, v + h] with h half a unit of its last printed digit (`paper_half_unit`).

The verdict rule (`population.claim_verdict`, the one function every row takes): each row has an equivalence margin
(`MARGINS`): a factor (the paper's value times or over it) or an absolute difference. A paper value
of 0 gets an upper bound instead (`ZERO_BOUND`). "reproduced" needs the whole 95% interval inside
the margin (two one-sided tests at 2.5% each), "differs" needs it wholly outside, anything else is
"inconclusive"; so is a row resting on fewer than `population.MIN_MODELS` models.
"""

from __future__ import annotations

import math
from decimal import Decimal

import numpy as np

# the paper's Table 2: catastrophe rate per field (%), fp32, pooled over its scenes and bits
PAPER_FIELD_RATES = {
    "means": 0.004,
    "log_scales": 2.782,
    "quats": 0.000,
    "opacity": 0.004,
    "sh_dc": 1.016,
    "sh_rest": 0.000,
}
# the paper's Table 2: footprint quantiles per field (% of frame), fp32, pooled over its scenes and bits
# (as printed: the digits set the half unit a verdict allows, `paper_half_unit`)
PAPER_FIELD_FOOTPRINT = {
    f: dict(zip(("median", "p95", "p99", "max", "mean"), row.split()))
    for f, row in {
        "means": "0.000 0.015 0.05 1.8 0.004",
        "log_scales": "0.000 0.237 6.16 99.4 0.351",
        "quats": "0.000 0.002 0.01 0.6 0.000",
        "opacity": "0.000 0.003 0.02 2.4 0.002",
        "sh_dc": "0.000 0.005 0.02 1.0 0.001",
        "sh_rest": "0.000 0.000 0.01 0.7 0.000",
    }.items()
}
FOOTPRINT_QUANTILES = {"median": 0.5, "p95": 0.95, "p99": 0.99}
PAPER_GUARDED_SITES = 768_000  # "across all 768,000 guarded single-bit upsets"
PAPER_BUDGET_K = 1_000  # "absorbs 1,000 simultaneous random upsets before the mean PSNR falls below 30 dB"
PAPER_CONTAMINATION_P = 64  # its finest partition
# the paper's design, needed to place a comparison (not compared): its scenes' primitive counts
# (Table 1), its heaviest dose, its largest size (the guard factor's), the upsets per (field, bit,
# scene) cell that Table 2's Wilson intervals imply (log_scales 2.782 [2.719, 2.847]: n = 256,000
# a field = 32 bits x 4 scenes x 2,000) and its fp32 bits per value
PAPER_PRIMITIVES = (134_826, 121_691, 125_606, 63_452)
PAPER_DOSE_K_MAX = 20_000
PAPER_LARGEST_N = 300_000
PAPER_CELL_UPSETS = 2_000
PAPER_SCENES = len(PAPER_PRIMITIVES)
PAPER_BITS = 32
# Table 4: the unguarded MTBF at ground level (71 yr), from p_c = 0.634%
PAPER_MTBF_GROUND_YEARS = 71
PAPER_PC = 0.634


def paper_half_unit(value: float | str) -> float:
    """Half a unit of the last digit the paper prints of `value` (0.997 -> 0.0005, 10.3 -> 0.05;
    a string as printed: "0.000" -> 0.0005, "24" -> 0.5): the paper's number is any value in
    [value - h, value + h]."""
    exponent = Decimal(value if isinstance(value, str) else repr(float(value))).as_tuple().exponent
    return 0.5 * 10.0 ** int(exponent)


def paper_bit_weighted(sh_degree: int = 3) -> float:
    """Table 2's per-field rates weighted by each field's stored components (an upset uniform over
    the stored bits, as this project's own p_c), in %: 0.1934 at SH degree 3."""
    from seuwgpu.model.fields import field_components

    w = {f: field_components(f, sh_degree) for f in PAPER_FIELD_RATES}
    return sum(PAPER_FIELD_RATES[f] * w[f] for f in w) / sum(w.values())


def paper_pc_without_sh_rest() -> float:
    """Table 2's plain mean over the five fields a model of SH degree 0 stores (sh_rest's 0.000 left
    out), in %: 0.7612, the like of 0.634 for a population holding such models."""
    return float(np.mean([v for f, v in PAPER_FIELD_RATES.items() if f != "sh_rest"]))


def paper_budget_k_per_n() -> float:
    """The paper's unguarded budget (1,000 upsets to a mean PSNR of 30 dB) per primitive, averaged
    over its scenes (1,000 / N: 0.0074 .. 0.0158)."""
    return float(np.mean([PAPER_BUDGET_K / n for n in PAPER_PRIMITIVES]))


def paper_heaviest_k_per_n() -> float:
    """The paper's heaviest dose per primitive, averaged over its scenes (20,000 / N: 0.148 .. 0.315)."""
    return float(np.mean([PAPER_DOSE_K_MAX / n for n in PAPER_PRIMITIVES]))


def paper_mtbf_bit_weighted_years() -> float:
    """Table 4's 71-year ground MTBF with Table 2's own bit-weighted rate in place of 0.634%: the
    paper's rate x bits follows from 71 yr = 1 / (L x 0.634%), and the same L with p = 0.1934%
    gives about 233 years (`reliability.mtbf` without scrubbing)."""
    from seuwgpu.analysis.reliability import mtbf

    hours = PAPER_MTBF_GROUND_YEARS * 365.25 * 24
    load = 1.0 / (hours * PAPER_PC / 100)  # upsets per hour over the model's stored bits
    return mtbf(load, 1.0, paper_bit_weighted() / 100, math.inf) / (365.25 * 24)


def paper_field_upsets() -> int:
    """Upsets behind one field's Table 2 statistics: bits x scenes x upsets a cell (256,000)."""
    return PAPER_BITS * PAPER_SCENES * PAPER_CELL_UPSETS


def _inconsistencies() -> tuple[str, ...]:
    return (
        "alpha = 2.78 (the median's exponent) lies outside the range its own proof of Lemma 2 (redundancy "
        "scaling) derives, alpha in (0, 1] (alpha = 1 for a regular refinement, below 1 otherwise).",
        "The redundancy budget 'grows from 5,000 at 6,741 primitives to 5,000 at 134,826, approximately in "
        "proportion to the count': the two ends are equal.",
        "With the guard the MTBF moves 'beyond any mission duration', but its own Table 4 gives 27 d in "
        "low-Earth orbit (2.4 yr avionics).",
        "Algorithm 1 (l. 576-586) clamps every field and component, but l. 1056 says the guard skips the "
        "45 inert sh_rest components; the study runs both (guard: skips sh_rest; guard_all: Algorithm 1).",
        f"The MTBF (Table 4) applies p_c = {PAPER_PC}% (the plain mean of Table 2's per-field rates) to upsets "
        f"spread uniformly over the stored bits, while Table 2 weighted by stored bits gives "
        f"{paper_bit_weighted():.4f}%: the 71-year ground figure becomes {paper_mtbf_bit_weighted_years():.0f} "
        "years with the paper's own numbers.",
    )


# checked and found consistent (issue 46, item 11 iv): listed beside the inconsistencies
PAPER_CHECKED = (
    "Not an inconsistency (re-checked): the guarded 0.0612% is a share of sites (470 / 768,000) and the "
    "unguarded 0.634% the plain mean of Table 2's per-field rates; with equal sampling per (field, bit, "
    f"scene) cell (Table 2's Wilson intervals imply {PAPER_CELL_UPSETS:,} a cell; 768,000 = 6 fields x 32 "
    "bits x 4 scenes x 1,000) every field holds the same number of sites, so the share of sites is the "
    "plain mean of the per-field rates: one definition.",
)
PAPER_INCONSISTENCIES = _inconsistencies()

# the rows over the finite frames; each has its twin `_all` where a non-finite frame fails
# (`_every_frame`): the same claim, unit and paper value
FINITE_ONLY = "(finite frames only)"
_DOSE = {
    "dose_none": (
        f"PSNR of the mean MSE at the paper's heaviest dose per primitive, fp32, no defense {FINITE_ONLY}",
        "dB",
        10.6,
    ),
    "dose_guard": (
        f"PSNR of the mean MSE at the paper's heaviest dose per primitive, fp32, guard {FINITE_ONLY}",
        "dB",
        21.8,
    ),
}
_BUDGET = {
    "budget_mean_psnr": (
        "redundancy budget per primitive: k/N where the PSNR of the mean MSE falls to 30 dB, fp32, no defense "
        + FINITE_ONLY,
        "upsets per primitive",
        round(paper_budget_k_per_n(), 4),
    ),
}


def _every_frame(rows: dict, fails: str = "") -> dict:
    """The `_all` twin of each finite-frame row: a non-finite frame counted as a failure (its text
    says so, `fails` after it: ": -inf" where the value is then -inf)."""
    return {
        f"{k}_all": (claim.replace(FINITE_ONLY, f"(a non-finite frame fails{fails})"), unit, v)
        for k, (claim, unit, v) in rows.items()
    }


# key: (claim, unit, paper value); NaN: this project's own estimate, beside no paper number
PAPER = {
    "sign_mean": ("log-scale sign flip: mean footprint, fp32", "% of frame", 10.3),
    "sign_p99": ("log-scale sign flip: 99th-percentile footprint, fp32", "% of frame", 75.7),
    "pc_none": ("p_c as the plain mean of the six per-field rates (Table 2), fp32, no defense", "%", PAPER_PC),
    "pc_none_bits": (
        "p_c weighted by stored bits (uniform upset), fp32, no defense; paper: Table 2 weighted the same way",
        "%",
        round(paper_bit_weighted(), 4),
    ),
    "pc_none_5": (
        "p_c as the plain mean of the five per-field rates but sh_rest (Table 2's, 0.000, left out: the "
        "population holds models of SH degree 0), fp32, no defense",
        "%",
        round(paper_pc_without_sh_rest(), 4),
    ),
    "pc_guard": ("p_c with the support guard as the plain mean of per-field rates, fp32", "%", 0.0612),
    "pc_guard_5": (
        "p_c with the support guard as the plain mean of the five per-field rates but sh_rest, fp32 (the "
        "paper gives no guarded per-field rates)",
        "%",
        np.nan,
    ),
    "pc_guard_bits": ("p_c with the support guard weighted by stored bits, fp32 (this project's)", "%", np.nan),
    "guard_share": ("share the guard neutralises, 1 - p_c(guard) / p_c(none), per-field means, fp32", "%", 90.4),
    "guard_share_paired": (
        "share of catastrophic sites the guard neutralises, paired, bit-weighted (this project's)",
        "%",
        np.nan,
    ),
    "theory_slope": ("log2 peak error per mantissa bit (log-scale), fp32", "per bit", 0.94),
    "alpha_median_procedural": (
        "alpha of the median single-upset error, procedural scenes (regenerated per N)",
        "",
        2.78,
    ),
    "alpha_median_capture": ("alpha of the median single-upset error, captures (random subsets)", "", 2.78),
    "alpha_mean_procedural": ("alpha of the mean single-upset error, procedural scenes (regenerated per N)", "", 0.09),
    "alpha_mean_capture": ("alpha of the mean single-upset error, captures (random subsets)", "", 0.09),
    **_DOSE,
    **_every_frame(_DOSE, ": -inf"),
    **{
        f"field_rate_{f}": (f"Table 2: catastrophe rate of {f} upsets, fp32, no defense", "%", v)
        for f, v in PAPER_FIELD_RATES.items()
    },
    **{
        f"field_{q}_{f}": (f"Table 2: {q} footprint of {f} upsets, fp32, no defense", "% of frame", float(v))
        for f, qs in PAPER_FIELD_FOOTPRINT.items()
        for q, v in qs.items()
    },
    **_BUDGET,
    **_every_frame(_BUDGET),
    "sign_psnr_none": ("log-scale sign flip: PSNR of the mean MSE, fp32, no defense", "dB", 49.2),
    "sign_psnr_guard": ("log-scale sign flip: PSNR of the mean MSE, fp32, guard", "dB", 65.8),
    "guard_worst_footprint": ("worst guarded footprint over the guarded single upsets", "% of frame", 11.68),
    "guard_residual_share": (
        "residual catastrophic guarded upsets, share of the guarded sites (paper: 470 of 768,000)",
        "%",
        round(100 * 470 / PAPER_GUARDED_SITES, 4),
    ),
    "contam_none": ("log-scale sign flip: nodes contaminated per frame at P = 64, fp32, no defense", "%", 99.2),
    "contam_guard": ("log-scale sign flip: nodes contaminated per frame at P = 64, fp32, guard", "%", 24.5),
    "contam_none_union": (
        "log-scale sign flip: nodes contaminated over the union of the views at P = 64, fp32, no defense "
        "(the paper's is per frame)",
        "%",
        np.nan,
    ),
    "contam_guard_union": (
        "log-scale sign flip: nodes contaminated over the union of the views at P = 64, fp32, guard "
        "(the paper's is per frame)",
        "%",
        np.nan,
    ),
    "contam_iou": (
        "IoU of predicted and measured contaminated regions at P = 64, fp32, no defense (union of the views)",
        "",
        0.323,
    ),
    "guard_factor": ("guard factor: mean single-upset MSE without / with the guard at the largest N", "", 24),
    "auc_loso_mean": ("leave-one-scene-out AUC of the classifier, mean over held-out scenes", "", 0.999),
    "auc_loso_min": ("leave-one-scene-out AUC of the classifier, minimum over held-out scenes", "", 0.998),
    "auc_fieldbit": ("AUC predicting catastrophic upsets from field and bit", "", 0.997),
    "auc_full": ("AUC of the classifier on all static features", "", 0.999),
    # at matched N (size-sweep records: seeded subsets of every model at a common primitive count)
    "matched_pc_none": ("p_c as the plain mean of per-field rates at matched N, fp32, no defense", "%", PAPER_PC),
    "matched_pc_none_5": (
        "p_c as the plain mean of the five per-field rates but sh_rest at matched N, fp32, no defense",
        "%",
        round(paper_pc_without_sh_rest(), 4),
    ),
    "matched_mean_mse": ("mean single-upset MSE at matched N, fp32, no defense (this project's)", "", np.nan),
    "matched_guard_factor": ("guard factor: mean single-upset MSE without / with the guard at matched N", "", 24),
}
# values whose printed digits a float loses (0.000, 1.0, 24): the paper's text
PRINTED = {
    **{f"field_rate_{f}": f"{v:.3f}" for f, v in PAPER_FIELD_RATES.items()},
    **{f"field_{q}_{f}": v for f, qs in PAPER_FIELD_FOOTPRINT.items() for q, v in qs.items()},
    "guard_factor": "24",
    "matched_guard_factor": "24",
}

# ---- the equivalence margins, stated before the numbers ------------------------------------------
# ("factor", f): the interval must lie in [v / f, v * f]; ("abs", d): in [v - d, v + d]; the band is
# widened by the printed half unit. Reasons: a rate or a footprint differs between sets of trained
# models by tens of percent, so agreement within 2x is "the same" for a claim of this kind; a PSNR
# within 3 dB (a factor 2 in MSE); a share or a contamination percentage within 5 or 10 points; an
# AUC within 0.005 (the third digit the paper prints); an exponent within 0.1 (0.5 for the
# median's 2.78, which its own lemma bounds by 1).
FACTOR2 = ("factor", 2.0)
MARGINS: dict[str, tuple[str, float]] = {
    "sign_mean": FACTOR2,
    "sign_p99": FACTOR2,
    "pc_none": FACTOR2,
    "pc_none_bits": FACTOR2,
    "pc_none_5": FACTOR2,
    "pc_guard": FACTOR2,
    "guard_share": ("abs", 5.0),
    "theory_slope": ("abs", 0.1),
    "alpha_median_procedural": ("abs", 0.5),
    "alpha_median_capture": ("abs", 0.5),
    "alpha_mean_procedural": ("abs", 0.1),
    "alpha_mean_capture": ("abs", 0.1),
    **{k: ("abs", 3.0) for k in (*_DOSE, *_every_frame(_DOSE))},
    **{f"field_rate_{f}": FACTOR2 for f in PAPER_FIELD_RATES},
    **{f"field_{q}_{f}": FACTOR2 for f, qs in PAPER_FIELD_FOOTPRINT.items() for q in qs},
    **{k: FACTOR2 for k in (*_BUDGET, *_every_frame(_BUDGET))},
    "sign_psnr_none": ("abs", 3.0),
    "sign_psnr_guard": ("abs", 3.0),
    "guard_worst_footprint": FACTOR2,
    "guard_residual_share": FACTOR2,
    "contam_none": ("abs", 10.0),
    "contam_guard": ("abs", 10.0),
    "contam_iou": ("abs", 0.1),
    "guard_factor": FACTOR2,
    "auc_loso_mean": ("abs", 0.005),
    "auc_loso_min": ("abs", 0.005),
    "auc_fieldbit": ("abs", 0.005),
    "auc_full": ("abs", 0.005),
    "matched_pc_none": FACTOR2,
    "matched_pc_none_5": FACTOR2,
    "matched_guard_factor": FACTOR2,
}
# a paper value of 0 (as printed, e.g. 0.000): an upper bound in the row's unit; "reproduced" when
# the interval's upper end stays below it, "differs" when its lower end lies above
ZERO_BOUND = {"%": 0.01, "% of frame": 0.01}

# tails: a maximum grows with the sample, so it is compared only at the paper's number of upsets
# (`paper_upsets`); a 99th percentile is compared as a quantile with its interval
TAIL_MAXIMA = {f"field_max_{f}" for f in PAPER_FIELD_RATES} | {"guard_worst_footprint"}


def paper_upsets(key: str) -> int | None:
    """The number of upsets behind the paper's value of a tail row (None: not a tail row)."""
    if key == "guard_worst_footprint":
        return PAPER_GUARDED_SITES
    if key.startswith("field_max_"):
        return paper_field_upsets()
    return None


def margin_of(key: str) -> tuple[str, float] | None:
    """The row's margin (None: no paper value to compare, or this project's own estimate)."""
    paper = PAPER[key][2]
    if not np.isfinite(paper):
        return None
    if paper == 0:
        bound = ZERO_BOUND.get(PAPER[key][1])
        return ("bound", bound) if bound is not None else None
    return MARGINS.get(key)


def margin_text(key: str) -> str:
    m = margin_of(key)
    if m is None:
        return ""
    kind, v = m
    if kind == "factor":
        return f"x/{v:g}"
    if kind == "bound":
        return f"<= {v:g} (upper bound)"
    return f"+-{v:g}"


def margins_table():
    """The margins beside the paper's values, one row a claim (the README's table)."""
    import pandas as pd

    rows = []
    for key, (claim, unit, paper) in PAPER.items():
        rows.append({"key": key, "claim": claim, "unit": unit, "paper": paper, "margin": margin_text(key)})
    return pd.DataFrame(rows)
