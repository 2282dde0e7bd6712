"""How report values are written: numbers to 4 significant digits, Markdown and HTML tables,
strict JSON (NaN -> null, +-inf -> "inf"/"-inf")."""

from __future__ import annotations

import html
import math

import numpy as np
import pandas as pd


def format_value(v) -> str:
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        x = float(v)
        if math.isnan(x):
            return "n/a"
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        if x == 0:
            return "0"
        if x == int(x) and abs(x) < 1e12:
            return str(int(x))
        ax = abs(x)
        if ax >= 1e4 and ax < 1e12:
            return f"{x:.0f}"
        return f"{x:.4g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(format_value(x) for x in v)
    return str(v)


def formatted(df: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame(
        {c: [format_value(v) for v in df[c].tolist()] for c in df.columns}, index=range(len(df)), dtype=object
    )


def markdown_table(df: pd.DataFrame) -> str:
    """A GitHub-style Markdown table of a DataFrame (values formatted to 4 significant digits)."""
    f = formatted(df)
    cols = [str(c) for c in f.columns]

    def esc(s):
        return str(s).replace("|", "\\|").replace("\n", " ")

    lines = [
        "| " + " | ".join(esc(c) for c in cols) + " |",
        "|" + "|".join("---" if f[c].map(lambda s: not numlike(s)).any() else "---:" for c in f.columns) + "|",
    ]
    for row in f.itertuples(index=False):
        lines.append("| " + " | ".join(esc(x) for x in row) + " |")
    return "\n".join(lines) + "\n"


def numlike(s: str) -> bool:
    try:
        float(str(s).replace(",", ""))
        return True
    except ValueError:
        return s in ("n/a", "inf", "-inf", "")


def html_table(df: pd.DataFrame) -> str:
    f = formatted(df)
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in f.columns)
    body = []
    for row in f.itertuples(index=False):
        cells = "".join(f"<td class='{'num' if numlike(x) else 'txt'}'>{html.escape(x)}</td>" for x in row)
        body.append(f"<tr>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def json_safe(o):
    """Plain JSON: NaN (undefined) -> null, +-inf -> "inf" / "-inf" (a median frame that is
    non-finite, an unbounded MTBF): strict parsers reject NaN and Infinity literals."""
    if isinstance(o, dict):
        return {str(k): json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_safe(v) for v in o]
    if isinstance(o, (float, np.floating)):
        x = float(o)
        if math.isnan(x):
            return None
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        return x
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    return o


def json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
