"""Criticality: the per-field table, the field x bit heat map and the per-precision rates (analysis/criticality.py)."""

from __future__ import annotations

from seuwgpu.analysis import (
    criticality,
)
from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import (
    InsufficientData,
    n_records,
    precisions_present,
    record_weights,
    scale_sign_flips,
    single_upsets,
)
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def criticality_section(df, manifests, ctx) -> Section:
    crit = criticality.criticality(df)
    prec = crit.attrs["precision"]
    fb = criticality.field_bit_table(df)
    sec = Section(
        "criticality",
        "Concentration of single-bit criticality",
        "Single-bit upsets of the single-upset campaign without defense. Footprint is "
        "the percent of pixels whose colour changes by more than 1/255 (mean over "
        "views); catastrophic means footprint > 1% or a non-finite pixel. Quantiles, means "
        "and rates are weighted by the stored bits each record stands for.",
    )
    sec.tables.append(
        TableItem(
            "criticality",
            f"Per-field severity at {prec}",
            crit,
            f"Per-field single-bit upset severity at {prec}, pooled over scenes and bits: weighted footprint "
            "quantiles (% of frame) and catastrophe rate (%) with its 95% stratified interval.",
        )
    )
    sec.figures.append(
        FigureItem(
            "fig_heatmap",
            "Field x bit mean footprint",
            criticality.plot_field_bit_heatmap(fb),
            "Mean corruption footprint (% of frame, log colour scale) over field and bit position, "
            "one panel per precision, pooled over scenes; grey cells: zero mean footprint.",
            prov(fb),
        )
    )
    sec.tables.append(
        TableItem(
            "field_bit",
            "Per (precision, field, bit) cell",
            fb,
            "Per-cell sample count, weight share, mean and max footprint (%) and catastrophe rate with "
            "its 95% interval (Wilson; stratified over scenes where a cell pools several); the data "
            "behind the heat map.",
            csv_only=True,
        )
    )
    s = single_upsets(df, prec, "none")
    sign = scale_sign_flips(s)
    if len(sign):
        fp, w = sign["footprint"].to_numpy(float) * 100, record_weights(sign)
        mean, p99 = E.wmean(fp, w), E.wquantile(fp, w, 0.99)
        sec.numbers.update(
            scale_sign_footprint_mean_pct=mean, scale_sign_footprint_p99_pct=p99, scale_sign_n=n_records(sign)
        )
        sec.notes.append(
            f"log-scale sign bit at {prec}: mean footprint {mean:.4g}%, p99 {p99:.4g}% (n = {n_records(sign):,})."
        )
    cells = fb[fb["precision"] == prec]
    if len(cells):
        sec.notes.append(
            f"{prec}: {len(cells)} (field, bit) cells sampled; fewest samples in a "
            f"cell: {int(cells['n'].min()):,}, most: {int(cells['n'].max()):,}."
        )
        sec.numbers["min_samples_per_cell"] = int(cells["n"].min())
    return sec


def precision_section(df, manifests, ctx) -> Section:
    rates = criticality.precision_rates(df)
    precs = precisions_present(rates)
    if len(precs) < 2:
        raise InsufficientData(
            f"single-upset records at one precision only ({', '.join(precs)})",
            "run the single-upset campaign at fp32, fp16 and bf16",
        )
    sec = Section(
        "precision",
        "Numeric precision changes the exposure",
        "Weighted catastrophe rate by field for each stored precision (no defense).",
    )
    sec.figures.append(
        FigureItem(
            "fig_precision",
            "Catastrophe rate by field and precision",
            criticality.plot_precision_rates(rates),
            "Weighted catastrophic-upset rate (%, log scale) by field and numeric format, with 95% "
            "stratified intervals, pooled over scenes and bits; open triangles: no event, the rate lies "
            "below the interval's upper end.",
            prov(rates),
        )
    )
    sec.tables.append(
        TableItem(
            "precision_rates",
            "Catastrophe rate by precision and field",
            rates,
            "Weighted catastrophe rate (%) per precision and field with 95% stratified intervals, and "
            "the weighted mean footprint (%).",
        )
    )
    return sec
