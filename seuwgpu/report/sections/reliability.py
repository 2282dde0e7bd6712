"""Reliability: p_c and the MTBF with scrubbing (analysis/reliability.py)."""

from __future__ import annotations

from seuwgpu.analysis import (
    reliability,
)
from seuwgpu.faults.defenses import guard_arms
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def schedule_text(res) -> str:
    """The check schedule the MTBF rows used: one S, or S per check defense."""
    per = res.get("check_every_of") or {}
    if isinstance(res["check_every"], dict) and per:
        return ", ".join(f"{d} S = {s}" for d, s in per.items())
    return f"S = {res['check_every']}"


def reliability_section(df, manifests, ctx) -> Section:
    # the single-upset p_c alone (analysis.reliability notes): no dose fit's p as a per-upset probability
    res = reliability.reliability(df, manifests)
    prec = res["precision"]
    per_model = res["per_model"]
    sec = Section(
        "reliability",
        "Reliability under realistic upset rates",
        "p_c is the probability that one upset, uniform over the stored bits, is catastrophic (the "
        "weighted single-upset rate), each model's own. The MTBF uses it alone: at these rates the "
        "expected upsets alive per scrub interval (live_upsets_per_scrub in mtbf_detail, with its regime) "
        "stay far below the tens to thousands where the dose fits' p was measured. Upsets accumulate "
        "until the next scrub, every "
        f"{res['scrub_hours']:g} h: MTBF = T / (1 - exp(-rate x bits x p x T)). Rates and scrub interval: "
        f"{res['rates_from']}. A check defense repairs what it detects at its next check, every S frames "
        f"({schedule_text(res)}; S from {res['check_every_from']}) at {res['frames_per_second']:g} frames/s: "
        "what it repairs counts for the frames it is drawn until then, (S - 1) / 2 on average (exposure_hours)."
        + (
            f" These records hold {len(res['models'])} models (scenes): each has its own p_c, stored bits, "
            "MTBF rows; none is pooled over scenes."
            if per_model
            else ""
        ),
    )
    cap = (
        "Per-upset catastrophe probability per precision and defense with its 95% stratified "
        "interval and the share of stored bits covered by sampled cells. Upsets are drawn over "
        "the model's stored values only: ECC's check bits and duplication's second copy are "
        "assumed intact (faults/defenses.py), so for those arms p_c is per upset in the data "
        "bits, and duplication's 0 follows from that assumption, not from the sample."
    )
    if per_model:
        cap = "Per model (scene, primitive count), its own rows: p" + cap[1:]
    sec.tables.append(TableItem("reliability_pc", "p_c", res["pc"], cap))
    if res["mtbf_wide"] is not None and len(res["mtbf_wide"]):
        if per_model:
            cap = (
                f"Per model at {prec}, each with its own single-upset p_c and its own "
                f"stored bits (model_bits), scrubbed every {res['scrub_hours']:g} h "
                "('> x': no event, bound from the upper limit of p)."
            )
        else:
            cap = (
                f"For a model of {res['bits']:.3g} stored bits at {prec}, scrubbed every {res['scrub_hours']:g} h "
                "('> x': no event, bound from the upper limit of p)."
            )
        sec.tables.append(
            TableItem("mtbf", "Mean time between catastrophic frames", res["mtbf_wide"], cap, prov(res["mtbf"]))
        )
        sec.tables.append(
            TableItem(
                "mtbf_detail",
                "MTBF inputs and intervals",
                res["mtbf"],
                "Per model and environment." if per_model else "Per environment.",
                csv_only=True,
            )
        )
        sec.figures.append(
            FigureItem(
                "fig_reliability",
                "MTBF against the upset rate",
                reliability.plot_sensitivity(res),
                "MTBF of catastrophic frames against the per-bit upset rate, per defense and source of p "
                "(colour: defense; single-upset p_c; bands: 95% interval of p); "
                "triangles: no catastrophic event, the line is the lower bound from the upper limit of p; "
                "dotted: the named environments."
                + (" A panel per model, with its own p and stored bits." if per_model else ""),
                prov(res["mtbf"]),
            )
        )
    for env in res["rates"]:
        sec.notes.append(
            f"rate, {env['environment']}: {float(env['per_bit_hour']):.3g} upsets/bit/h "
            f"({float(env['per_bit_hour']) * 1e15:.3g} FIT/Mbit). {env.get('source', '')}"
        )
    sec.notes.extend(res["notes"])
    pc = res["pc"]
    for m in res["models"]:
        rows = pc[(pc["scene"] == m["scene"]) & (pc["n_primitives"] == m["n_primitives"])] if per_model else pc
        for dfn in guard_arms(pc["defense"]):
            r = reliability.pc_lookup(rows, prec, dfn)
            if r is not None:
                key = f"p_c_{m['key']}_{dfn}_pct" if per_model else f"p_c_{dfn}_pct"
                sec.numbers[key] = [100 * float(r["p_c"]), 100 * float(r["ci_lo"]), 100 * float(r["ci_hi"])]
    sec.numbers["model_bits"] = res["bits"]  # a number for one model, {model key: bits} for several
    sec.numbers["scrub_hours"] = res["scrub_hours"]
    sec.numbers["check_every"] = res["check_every"]
    sec.numbers["frames_per_second"] = res["frames_per_second"]
    return sec
