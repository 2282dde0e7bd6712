"""The guard, the mitigation table and the defenses against their cost (analysis/guard.py,
mitigation.py, defenses.py)."""

from __future__ import annotations

from seuwgpu.analysis import (
    guard,
    mitigation,
)
from seuwgpu.analysis.records import (
    InsufficientData,
)
from seuwgpu.faults.defenses import DEFENSES, FIRST_DEFENSES
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def guard_section(df, manifests, ctx) -> Section:
    res = guard.guard_analysis(df)
    ctx["results"]["guard"] = res
    sec = Section(
        "guard",
        "Support guard evaluation",
        "The same single-upset fault sites rendered without defense and with the "
        "support guard (records paired by injection id); rates and shares weighted.",
    )
    sec.figures.append(
        FigureItem(
            "fig_guard",
            "Footprint distribution with and without the guard",
            guard.plot_guard_ccdf(df),
            "Weighted complementary CDF of the corruption footprint (% of frame) of a uniform upset, "
            "without defense and with the support guard, all precisions pooled; dotted: the 1% threshold.",
            prov(res["summary"]),
        )
    )
    sec.tables.append(
        TableItem(
            "guard_summary",
            "Footprint and catastrophe rate by defense",
            res["summary"],
            "Weighted footprint statistics (% of frame) and catastrophe rate with its 95% stratified "
            "interval, without and with the guard, per precision.",
        )
    )
    sec.tables.append(
        TableItem(
            "guard_paired",
            "Catastrophic upsets neutralised",
            res["paired"],
            "On paired fault sites: catastrophic upsets without defense, the weighted share the guard "
            "neutralises (95% stratified interval), residual catastrophic events, of which catastrophic "
            "without the guard too (catastrophic_both) and turned catastrophic by it (turned_catastrophic, "
            "not catastrophic without it; turned_share_pct: their weighted share of the paired sites), worst "
            "guarded footprint (%).",
        )
    )
    if len(res["sign_psnr"]):
        sec.tables.append(
            TableItem(
                "guard_sign_psnr",
                "Image quality after log-scale sign flips",
                res["sign_psnr"],
                "Log-scale sign-bit upsets without and with the guard: share of frames with a non-finite "
                "pixel (their PSNR and SSIM are undefined), median PSNR and PSNR of the mean MSE over the "
                "finite frames (dB; identical frames count as infinite / zero error), mean SSIM, footprint.",
            )
        )
    sec.notes.append(
        f"{res['n_guarded']:,} guarded single-bit upsets: worst footprint "
        f"{res['worst_guarded_footprint_pct']:.4g}% of the frame, "
        f"{res['residual_catastrophic']} residual catastrophic events "
        f"({res['catastrophic_both']} catastrophic without the guard too, {res['turned_catastrophic']} "
        "turned catastrophic by it: not catastrophic without it); "
        f"weighted share of catastrophic upsets neutralised {res['share_pct']:.4g}% "
        f"[{res['share_ci'][0]:.4g}, {res['share_ci'][1]:.4g}] "
        + (
            "(every precision pooled, weighted by stored bits; per precision in the paired table)."
            if res["share_precision"] == "all"
            else f"({res['share_precision']})."
        )
    )
    sec.numbers.update(
        guard_share_neutralised_pct=res["share_pct"],
        guard_share_neutralised_ci_pct=list(res["share_ci"]),
        # which records the share pools: one precision, or "all" (weighted by stored bits)
        guard_share_precision=res["share_precision"],
        guard_worst_footprint_pct=res["worst_guarded_footprint_pct"],
        guard_residual_catastrophic=res["residual_catastrophic"],
        # of the residual on paired sites: catastrophic under both arms, and made catastrophic by the guard
        guard_catastrophic_both=res["catastrophic_both"],
        guard_turned_catastrophic=res["turned_catastrophic"],
        guard_n_sites=res["n_guarded"],
    )
    return sec


def mitigation_section(df, manifests, ctx) -> Section:
    t = mitigation.mitigation_table(df, manifests)
    sec = Section(
        "mitigation",
        "Alternative defenses",
        "Each defense on the shared fault grid (the fault sites measured under every "
        "defense present) at one precision, with its measured cost.",
    )
    cap = (
        f"Mitigations at {t.attrs['precision']}"
        + (" on a shared (paired) fault grid" if t.attrs.get("paired") else " (unpaired: no shared site)")
        + ": weighted catastrophe rate (%) with 95% stratified interval, footprint (%), memory overhead "
        "(% of the stored model; memory_basis) and time overhead (% of one view's render time, measured "
        "in the same run; time_basis; time_overhead_mean_pct with its 95% t interval over the models, each "
        "model's mean time with the defense over its mean time without, and time_resolved: 'not resolved' "
        "where the interval holds 0). Per scene and precision, on the dangerous cells and against the "
        "Pareto front: the defenses table (Defenses against cost), where the records hold its defenses."
    )
    sec.figures.append(
        FigureItem(
            "fig_mitigation",
            "Catastrophe rate by defense",
            mitigation.plot_mitigation(t),
            "The mitigation table's weighted catastrophe rate (%, log scale) per defense with its 95% "
            "stratified interval and its memory overhead; open triangles: no catastrophic event, the rate "
            "lies below the interval's upper end.",
            prov(t),
        )
    )
    sec.tables.append(TableItem("mitigation", "Mitigation table", t, cap))
    sec.numbers["mitigation"] = t[
        [
            "defense",
            "n",
            "cat_rate_pct",
            "cat_ci_lo_pct",
            "cat_ci_hi_pct",
            "memory_overhead_pct",
            "time_ms",
            "time_overhead_pct",
            "time_overhead_mean_pct",
            "time_overhead_lo_pct",
            "time_overhead_hi_pct",
            "time_resolved",
        ]
    ].to_dict("records")
    for _, r in t[t["time_resolved"] == "not resolved"].iterrows():
        sec.notes.append(
            f"{r['label']}: time overhead {r['time_overhead_mean_pct']:.3g}% "
            f"[{r['time_overhead_lo_pct']:.3g}, {r['time_overhead_hi_pct']:.3g}] over {int(r['time_groups'])} "
            "models: not resolved (the interval holds 0)"
        )
    if t["time_ms"].isna().all():
        sec.notes.append("no time_ms recorded (records of an older run): time cost not reported")
    return sec


def defenses_section(df, manifests, ctx) -> Section:
    from seuwgpu.analysis import defenses as D  # issue 16: defenses against cost (own module)
    from seuwgpu.report.sections.visible import visible_item

    seen = visible_item(manifests)  # what the user sees (issue 47), where the run folders keep it
    if not D.has_new_defenses(df):
        if seen is not None:
            sec = Section("defenses", "Defenses against cost", "What the user sees under each defense.")
            sec.tables.append(seen[0])
            sec.numbers.update(seen[1])
            return sec
        others = ", ".join(d for d in DEFENSES if d not in FIRST_DEFENSES)
        raise InsufficientData(
            "no defense beyond guard/ECC/duplication in the records",
            f"run the single-upset campaign with defenses from {others} beside none (`seuwgpu defenses` lists them)",
        )
    t = D.defense_table(df, manifests=manifests)
    sec = Section("defenses", "Defenses against cost", "Residual catastrophic rate of every defense (paired arms).")
    cap = (
        "Per scene and defense: catastrophic rate (%) stratified by (field, bit) cell with 95% interval, "
        "the same on the dangerous cells (log-scale sign and top exponent bit, opacity top exponent bit) and "
        "relative to no defense, memory overhead (% of the stored model). Time: `seuwgpu defenses` "
        "(not measured here, so meets_goal is <NA> where every other criterion passes). "
        "Pooled over scenes on the shared fault grid, with footprints and the time measured in the run: "
        "the mitigation table (Alternative defenses)."
    )
    sec.tables.append(TableItem("defenses", "Defenses against cost", t, cap))
    sec.figures.append(FigureItem("fig_pareto", "Pareto", D.pareto_figure(t), "Residual rate against memory."))
    if seen is not None:
        sec.tables.append(seen[0])
        sec.numbers.update(seen[1])
    return sec
