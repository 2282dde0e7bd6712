"""The theory check: the mantissa slope (analysis/theory.py)."""

from __future__ import annotations

import pandas as pd

from seuwgpu.analysis import (
    theory,
)
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def theory_section(df, manifests, ctx) -> Section:
    res = theory.theory_check(df)
    ctx["results"]["theory"] = res
    t = res["table"]
    sec = Section(
        "theory",
        "Validation of the perturbation bound",
        "Lemma (value perturbation): a mantissa flip of bit b changes the value by "
        "2^(e+b-p), so the peak image error doubles per bit (unit slope in log2) until "
        "one primitive's contribution saturates the pixels it covers.",
    )
    sec.figures.append(
        FigureItem(
            "fig_theory",
            "Peak error against mantissa bit",
            theory.plot_theory(res),
            f"Weighted mean peak error |dI|_inf against mantissa bit index for {res['field']} at "
            f"{res['precision']} (log2 axis), the fitted line over bits {res['fit_bits'][0]}.."
            f"{res['fit_bits'][1]} and the unit-slope prediction.",
            prov(t),
        )
    )
    fit = pd.DataFrame(
        [
            {
                "field": res["field"],
                "precision": res["precision"],
                "fitted_log2_slope": res["slope"],
                "slope_ci_lo": res["slope_lo"],
                "slope_ci_hi": res["slope_hi"],
                "predicted_slope": 1.0,
                "r2": res["r2"],
                "fit_bits": f"{res['fit_bits'][0]}..{res['fit_bits'][1]}",
                "n_fit_bits": res["n_fit_bits"],
            }
        ]
    )
    sec.tables.append(
        TableItem(
            "theory_fit",
            "Fitted slope",
            fit,
            "Fitted log2 slope of the mean peak error per mantissa bit (95% t interval) against the unit "
            "slope of the perturbation lemma.",
            prov(t),
        )
    )
    sec.tables.append(TableItem("theory", "Mean peak error per mantissa bit", t, "Per mantissa bit.", csv_only=True))
    if res["note"]:
        sec.notes.append(res["note"])
    sec.numbers.update(
        theory_slope=res["slope"], theory_slope_ci=[res["slope_lo"], res["slope_hi"]], theory_r2=res["r2"]
    )
    return sec
