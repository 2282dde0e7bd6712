"""analysis/defenses.py: stratified residual rates, dangerous cells, Pareto membership, recomputed
by hand from a small record set."""

import pandas as pd
import pytest

from seuwgpu.analysis.defenses import dangerous_mask, defense_table
from seuwgpu.faults.defenses import memory_overhead


def records():
    rows = []
    for d, cats in (("none", [1, 1, 1, 0]), ("parity", [0, 0, 0, 0]), ("guard", [1, 0, 0, 0])):
        for field, bit, w in (("log_scales", 31, 300.0), ("means", 3, 900.0)):
            for i, c in enumerate(cats if field == "log_scales" else [0, 0, 1 if d == "guard" else 0, 0]):
                rows.append(
                    dict(scene="s", precision="fp32", n_primitives=100, k=1, defense=d, field=field, bit=bit,
                         component=0, catastrophic=bool(c), footprint=0.5 if c else 0.0, nonfinite=False,
                         weight=w, primitive=i)
                )  # fmt: skip
    return pd.DataFrame(rows)


def test_defense_table_by_hand():
    df = records()
    assert dangerous_mask(df).sum() == 12  # log_scales bit 31 rows only
    t = defense_table(df).set_index("defense")
    # none: cell 1 (weight 1200) 3/4, cell 2 (weight 3600) 0 -> 0.75 * 1200 / 4800
    assert t.loc["none", "rate_pct"] == pytest.approx(100 * 0.75 * 0.25)
    assert t.loc["none", "danger_rate_pct"] == pytest.approx(75.0)
    assert t.loc["guard", "rate_pct"] == pytest.approx(100 * (0.25 * 0.25 + 0.25 * 0.75))
    assert t.loc["guard", "danger_vs_none"] == pytest.approx(1 / 3)
    assert t.loc["parity", "danger_vs_none"] == 0 and t.loc["parity", "rate_hi_pct"] > 0
    assert t.loc["parity", "memory_overhead_pct"] == pytest.approx(100 * memory_overhead("parity", "fp32", 3, 100))
    assert bool(t.loc["parity", "pareto"]) and bool(t.loc["none", "pareto"]) and not bool(t.loc["guard", "pareto"])
    assert t["time_fraction"].isna().all()
