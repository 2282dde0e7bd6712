"""analysis/defenses.py: stratified residual rates, dangerous cells, Pareto membership, recomputed
by hand from a small record set."""

import pandas as pd
import pytest

from seuwgpu.analysis.defenses import dangerous_mask, defense_table
from seuwgpu.faults.side import memory_overhead


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
    # on the device: 100 packed parity bits and 100 flag bits (16-byte buffers), the check's count
    # and table, one 256-byte uniform slot, over 100 x 59 fp32 values
    assert t.loc["parity", "device_memory_pct"] == pytest.approx(100 * (16 + 32 + 16 + 256) / (100 * 59 * 4))
    assert bool(t.loc["parity", "pareto"]) and bool(t.loc["none", "pareto"]) and not bool(t.loc["guard", "pareto"])
    assert t["time_fraction"].isna().all()


def test_goal_verdict_is_unknown_without_time_and_false_on_a_failed_criterion():
    """meets_goal never passes on a missing number: no timing -> <NA> where the measured criteria
    pass, False where one fails (none: its dangerous-cell rate is the baseline itself)."""
    df = records()
    df = pd.concat([df] + [df[df["defense"] == "parity"]] * 1500, ignore_index=True)  # a narrow interval
    t = defense_table(df).set_index("defense")
    assert t.loc["parity", "rate_hi_pct"] <= 0.05 and t.loc["parity", "memory_overhead_pct"] <= 5
    assert not pd.isna(t.loc["none", "meets_goal"]) and not t.loc["none", "meets_goal"]
    assert pd.isna(t.loc["parity", "meets_goal"])
    timed = defense_table(df, {"guard": {"time_fraction": 0.01}, "parity": {"time_fraction": 0.5}})
    assert not timed.set_index("defense").loc["parity", "meets_goal"]  # 0.5 > 2 x guard's 0.01
    # the guard's own time unknown: the comparison with it is unknown too, not a fail
    untimed_guard = defense_table(df, {"parity": {"time_fraction": 0.5}}).set_index("defense")
    assert pd.isna(untimed_guard.loc["parity", "meets_goal"])


def test_state_table_carries_the_due_interval():
    """The DUE rate of the pipeline-state table is reported with its 95% interval, as the
    catastrophic rate is (state_table computed it and dropped it: a bare 0 for 0 of 4 DUE)."""
    from seuwgpu.analysis.defenses import state_table
    from seuwgpu.analysis.stats import wilson_interval

    rows = [
        dict(target=t, bit=b, catastrophic=False, due=t == "tile_range" and i < due)
        for t in ("xy", "tile_range")
        for b, due in ((3, 1), (30, 2))
        for i in range(4)
    ]
    t = state_table(pd.DataFrame(rows)).set_index(["target", "bit_class"])
    for tgt, cls, k in (("xy", "exponent", 0), ("tile_range", "high half", 2), ("tile_range", "low half", 1)):
        lo, hi = wilson_interval(k, 4)  # one bit per class here: the plain Wilson interval
        r = t.loc[(tgt, cls)]
        assert r["due_rate"] == pytest.approx(k / 4)
        assert (r["due_ci_lo"], r["due_ci_hi"]) == pytest.approx((lo, hi))
    assert t.loc[("xy", "all"), "due_ci_hi"] > 0  # no event: an upper bound, not a zero-width 0


def test_goal_verdict_is_unknown_when_none_has_no_dangerous_catastrophe():
    """danger_vs_none is undefined (NaN) when no dangerous-cell upset was catastrophic without
    defense; the verdict then read False (NaN <= 0.05 is False), a fail on a missing number, while
    a missing time gave <NA>. Now <NA> too, and still False where a measured criterion fails."""
    df = records()
    df.loc[df["defense"] == "none", ["catastrophic", "footprint"]] = (False, 0.0)
    df = pd.concat([df] + [df[df["defense"] == "parity"]] * 1500, ignore_index=True)  # a narrow interval
    t = defense_table(df, {"guard": {"time_fraction": 0.5}, "parity": {"time_fraction": 0.5}}).set_index("defense")
    assert t.loc["none", "danger_rate_pct"] == 0 and pd.isna(t.loc["parity", "danger_vs_none"])
    assert t.loc["parity", "rate_hi_pct"] <= 0.05 and t.loc["parity", "memory_overhead_pct"] <= 5
    assert pd.isna(t.loc["parity", "meets_goal"])
    assert t.loc["guard", "rate_hi_pct"] > 0.05 and not pd.isna(t.loc["guard", "meets_goal"])
    assert not t.loc["guard", "meets_goal"]
