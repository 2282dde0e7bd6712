"""Outcome classes, the scenes table and the renderer profiles' rows (analysis/outcomes.py, analysis/scenes.py)."""

from __future__ import annotations

import pandas as pd

from seuwgpu.analysis import estimate as E
from seuwgpu.analysis import (
    outcomes,
    scenes,
)
from seuwgpu.report.sections.base import Section, TableItem


def profile_section(all_records: pd.DataFrame) -> Section | None:
    """Headline catastrophe rates under each renderer profile, when the runs hold more than one
    (the other sections then rest on the strict profile's records alone, never on a mix)."""
    if all_records["profile"].nunique() < 2:
        return None
    t = outcomes.catastrophic_by_profile(all_records)
    if t.empty:
        return None
    sec = Section(
        "profiles",
        "Renderer profiles",
        "The runs hold records under several renderer profiles (docs/renderer.md, Profiles: strict "
        "draws a non-finite covariance as a frame-covering sheet, gsplat follows gsplat's CUDA "
        "arithmetic and culls it). Every other section rests on the strict records alone; this "
        "table gives the weighted single-upset catastrophe rate under each profile.",
    )
    sec.tables.append(
        TableItem(
            "profiles",
            "Catastrophe rate by renderer profile",
            E.percent(t[["profile", "scene", "precision", "defense", "n", "events", "rate", "ci_lo", "ci_hi"]]),
            "Weighted catastrophe rate (%) of single upsets per profile, scene, precision and defense, "
            "with its 95% interval (Wilson per cell, stratified when pooled over cells).",
        )
    )
    sec.numbers["catastrophic_by_profile"] = [
        {
            k: (x[k] if k in ("profile", "scene", "precision", "defense") else float(x[k]))
            for k in ("profile", "scene", "precision", "defense", "rate", "ci_lo", "ci_hi")
        }
        | {"n": int(x["n"])}
        for _, x in t.iterrows()
    ]
    return sec


def outcomes_section(df, manifests, ctx) -> Section:
    long = outcomes.outcome_table(df)
    thr = long.attrs.get("thresholds", {})
    sec = Section(
        "outcomes",
        "Outcome classes of single upsets",
        "Every single upset in one class: masked (frame bit-identical to clean), tolerable (changed, "
        f"no channel by more than {thr.get('pixel_threshold', 1 / 255):.4g}), SDC (visible change, "
        f"footprint at most {100 * thr.get('footprint_threshold', 0.01):g}%), catastrophic (footprint "
        f"over {100 * thr.get('footprint_threshold', 0.01):g}% or a non-finite pixel). Shares are weighted "
        "by the stored bits each record stands for (a uniform upset's view), pooled over scenes.",
    )
    wide = outcomes.outcome_wide(long)
    sec.tables.append(
        TableItem(
            "outcomes",
            "Outcome classes by precision and defense",
            wide,
            "Weighted share (%) of single upsets per outcome class with its 95% stratified interval.",
        )
    )
    sec.tables.append(
        TableItem("outcomes_long", "Outcome classes (long form)", long, "The same, one row per class.", csv_only=True)
    )
    sec.numbers["outcome_thresholds"] = thr
    sec.numbers["outcomes"] = long[
        ["precision", "defense", "outcome", "n", "rate_pct", "ci_lo_pct", "ci_hi_pct"]
    ].to_dict("records")
    return sec


def scenes_section(df, manifests, ctx) -> Section:
    t, notes = scenes.scene_table(df, manifests)
    sec = Section(
        "scenes",
        "Table 1: scenes",
        "The models the records rest on; box_<field>: the widest component of the support guard's "
        "box (max - min of the clean stored values) in each field.",
    )
    sec.tables.append(TableItem("scenes", "Scenes", t, "Scenes, primitive counts, SH degree and support boxes."))
    sec.notes.extend(notes)
    return sec
