"""The report's sections: one builder per analysis, in a module of its own beside the analysis it
reports (claims.py, dose.py, ...), each returning the tables, figures, notes and headline numbers
of one `Section`; `run_sections` runs those the records support and lists the others as skipped
(with the campaign that would supply them)."""

from __future__ import annotations

from collections.abc import Callable

import pandas as pd

from seuwgpu.analysis.records import InsufficientData
from seuwgpu.errors import MissingExtra
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov
from seuwgpu.report.sections.claims import claims_section
from seuwgpu.report.sections.contamination import contamination_section
from seuwgpu.report.sections.criticality import criticality_section, precision_section
from seuwgpu.report.sections.dose import budget_section, dose_section
from seuwgpu.report.sections.guard import defenses_section, guard_section, mitigation_section
from seuwgpu.report.sections.outcomes import outcomes_section, profile_section, scenes_section
from seuwgpu.report.sections.prediction import prediction_section
from seuwgpu.report.sections.reliability import reliability_section
from seuwgpu.report.sections.size import size_section
from seuwgpu.report.sections.theory import theory_section

__all__ = [
    "SECTIONS",
    "FigureItem",
    "Section",
    "TableItem",
    "profile_section",
    "prov",
    "run_sections",
    "section_figures",
]


# (key, label, builder); the claims table is built last (it reads the others' results) but shown first
SECTIONS: list[tuple[str, str, Callable]] = [
    ("outcomes", "Outcome classes", outcomes_section),
    ("scenes", "Table 1: scenes", scenes_section),
    ("criticality", "Criticality (per-field table, field x bit heat map)", criticality_section),
    ("precision", "Per-precision catastrophe rates", precision_section),
    ("theory", "Theory check (mantissa slope)", theory_section),
    ("guard", "Guard evaluation", guard_section),
    ("mitigation", "Mitigation table", mitigation_section),
    ("defenses", "Defenses against cost (Pareto)", defenses_section),
    ("dose", "Dose response (quality and catastrophes against k)", dose_section),
    ("budget", "Redundancy budget", budget_section),
    ("size", "Single-upset error against N", size_section),
    ("reliability", "Reliability (p_c, MTBF with scrubbing)", reliability_section),
    ("contamination", "Distributed contamination", contamination_section),
    ("prediction", "Prediction of criticality", prediction_section),
    ("claims", "Claims table", claims_section),
]


def run_sections(df: pd.DataFrame, manifests: list[dict], ctx: dict) -> list[Section]:
    """Every analysis the records support, in report order; the others go to ctx["skipped"]."""
    sections: list[Section] = []
    ctx.setdefault("skipped", [])
    ctx.setdefault("max_pred_rows", 200_000)
    ctx.setdefault("results", {})
    for _key, label, builder in SECTIONS:
        try:
            sections.append(builder(df, manifests, ctx))
        except (InsufficientData, MissingExtra) as e:  # too few records, or a library the install left out
            ctx["skipped"].append((label, e.reason, e.remedy))
    return sections


def section_figures(df: pd.DataFrame, manifests: list[dict]) -> dict:
    """The report's matplotlib figures by name (what the Python API hands to a notebook)."""
    return {fi.name: fi.fig for sec in run_sections(df, manifests, {}) for fi in sec.figures}
