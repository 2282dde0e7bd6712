"""What a report section holds: its tables, figures, notes and headline numbers."""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field

import pandas as pd

from seuwgpu.analysis.records import provenance_text


@dataclass
class TableItem:
    name: str  # file stem
    title: str
    df: pd.DataFrame
    caption: str  # what it shows (provenance is appended)
    prov: dict | None = None
    csv_only: bool = False  # a long table: linked as CSV/Markdown, not inlined in the page

    def full_caption(self) -> str:
        prov = self.prov if self.prov is not None else self.df.attrs.get("provenance", {})
        return f"{self.caption} {provenance_text(prov)}".strip()


@dataclass
class FigureItem:
    name: str
    title: str
    fig: object  # matplotlib Figure
    caption: str
    prov: dict | None = None

    def full_caption(self) -> str:
        return f"{self.caption} {provenance_text(self.prov or {})}".strip()


@dataclass
class Section:
    key: str
    title: str
    text: str = ""
    tables: list[TableItem] = dc_field(default_factory=list)
    figures: list[FigureItem] = dc_field(default_factory=list)
    notes: list[str] = dc_field(default_factory=list)
    skipped: list[tuple[str, str, str]] = dc_field(default_factory=list)  # partial skips
    numbers: dict = dc_field(default_factory=dict)


def prov(t) -> dict:
    return t.attrs.get("provenance", {}) if hasattr(t, "attrs") else {}
