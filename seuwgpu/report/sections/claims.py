"""The claims table: each claim of the paper against these records (analysis/claims.py)."""

from __future__ import annotations

import pandas as pd

from seuwgpu.analysis import claims, theory
from seuwgpu.report.sections.base import Section, TableItem


def claims_section(df, manifests, ctx) -> Section:
    rates = ctx["results"]["model_rates"] = claims.arm_model_rates(df)  # p_c rows and per-model table
    t = claims.claims_table(df, ctx["results"], manifests=manifests)
    sec = Section(
        "claims",
        "Claims of the paper against these records",
        "Each quantitative claim of the paper, the value measured here with its 95% interval, the "
        "paper's value, the margin within which the two count as the same (stated before the numbers: "
        "analysis/paper.py) and the verdict: reproduced (the whole interval inside the margin: two "
        "one-sided tests), differs (wholly outside), inconclusive (neither, or fewer than 3 models), not "
        "comparable (a maximum over fewer upsets than the paper's), or not measured. Every row names its "
        "population (real models and procedural scenes are never pooled), its N and its guard. The "
        "paper's models are not these: a difference is a finding, not an error.",
    )
    sec.tables.append(
        TableItem(
            "claims",
            "Claims",
            t,
            "Claims of the paper, measured on these records. interval_over says what the interval (and "
            "so the verdict) is over: the models (a t interval of the per-model estimates, n_models - 1 "
            "degrees of freedom) or the records of these models; pooled: the estimate over all records "
            "with its within-model interval. margin: x/f a factor, +-d an absolute difference, <= b an "
            "upper bound for a paper value of 0. A NaN paper value: this project's own estimate.",
        )
    )
    per = pd.DataFrame(t.attrs.get("per_model", []))
    if len(per):
        sec.tables.append(
            TableItem(
                "claims_per_model",
                "Claims per model",
                per,
                "The per-model value behind each claims row over models.",
                csv_only=True,
            )
        )
    me = claims.model_estimates(df, rates=rates)
    if len(me):
        sec.tables.append(
            TableItem(
                "claims_models",
                "p_c per model",
                me,
                "Per model, fp32 (%, stratified 95% intervals): p_c as the plain mean of the per-field rates "
                "(fields_*, the paper's definition) and weighted by stored bits (bits_*), without and with each "
                "guard, and each guard's share 1 - p_c(guard) / p_c(none) of the per-field means.",
            )
        )
    th = ctx["results"].get("theory")
    if th is not None and th.get("precision") == "fp32":
        sec.tables.append(
            TableItem(
                "claims_theory_windows",
                "Mantissa slope against the fit window",
                theory.theory_windows(th),
                "The log2 slope of the mean peak error per mantissa bit over other fit windows (bits in, "
                "95% t interval over bits) and the verdict each would give against the paper's value and "
                "margin; the claims row's verdict is their majority.",
            )
        )
    sec.notes += [f"The paper's own inconsistency: {n}" for n in claims.PAPER_INCONSISTENCIES]
    sec.notes += list(claims.PAPER_CHECKED)
    sec.numbers["claims"] = t.to_dict("records")
    return sec
