"""Distributed contamination (analysis/contamination.py)."""

from __future__ import annotations

from seuwgpu.analysis import (
    contamination,
)
from seuwgpu.analysis.records import (
    reference_precision,
)
from seuwgpu.faults.defenses import guard_arms
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def contamination_section(df, manifests, ctx) -> Section:
    cont = contamination.contamination(df)
    sec = Section(
        "contamination",
        "Cross-node contamination in distributed rendering",
        "Sort-first partitions of the screen into P tile-aligned regions (the grid the Ray ranks "
        "render): the weighted share of regions one upset contaminates, predicted from the projected "
        "footprint and measured from changed pixels, and their IoU.",
    )
    sec.figures.append(
        FigureItem(
            "fig_contamination",
            "Contaminated regions against P",
            contamination.plot_contamination(cont, defenses=guard_arms(cont["defense"])),
            "Share of regions contaminated by one log-scale sign-bit upset against P at the reference "
            "precision, predicted (solid) and measured (dashed), without and with the guard.",
            prov(cont),
        )
    )
    cap = (
        "Per subset, precision, defense and P. Per frame, as the paper counts: pred_frame_pct, the share "
        "of the regions of one rendered frame that the tile rectangle of the primitive as the renderer "
        "reads it after the upset and the defense reaches (the whole primitive, also where the frame does "
        "not change: a corrected upset still predicts its clean footprint), and meas_frame_pct, the share "
        "of one frame's regions holding a pixel changed by more than 1/255, each averaged over the views "
        "(NaN for records that predate them). Over the union of the views: pred_fraction_pct and "
        "meas_fraction_pct, the same shares of the regions reached in any view. All "
        "weighted by stored bits, without interval. iou_mean: over the n_iou records where either set is "
        "non-empty (0 where nothing changed). slowest_region_ms and imbalance: plain means over records."
    )
    sec.tables.append(TableItem("contamination", "Region contamination", cont, cap))
    sub = cont[(cont["subset"] == "log-scale sign") & cont["defense"].isin(guard_arms(cont["defense"]))]
    if len(sub):
        sub = sub[sub["precision"] == reference_precision(sub)]
        pmax = int(sub["P"].max())
        for _, r in sub[sub["P"] == pmax].iterrows():
            key = f"{r['precision']}_{r['defense']}_P{pmax}"
            sec.numbers[f"contam_sign_pred_pct_{key}"] = float(r["pred_fraction_pct"])
            sec.numbers[f"contam_sign_meas_pct_{key}"] = float(r["meas_fraction_pct"])
            sec.numbers[f"contam_sign_pred_frame_pct_{key}"] = float(r["pred_frame_pct"])
            sec.numbers[f"contam_sign_meas_frame_pct_{key}"] = float(r["meas_frame_pct"])
            sec.numbers[f"contam_sign_iou_{key}"] = float(r["iou_mean"])
    if cont["slowest_region_ms"].isna().all():
        ctx["skipped"].append(
            (
                "Slowest-region render time and load imbalance",
                "no region_ms_max_P / region_ms_mean_P columns",
                "time the regions with `seuwgpu distributed --scene NAME --ranks 4 16 64` "
                "(each region rendered on its own Ray rank)",
            )
        )
    return sec
