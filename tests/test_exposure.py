"""A check schedule's exposure in the reliability analysis: upsets a check repairs count for the
frames they are drawn (analysis/reliability.py check_exposure, with_exposure, mtbf_table)."""

import math

import pandas as pd
import pytest

from seuwgpu.analysis import reliability as R


def test_check_exposure_in_hours():
    fph = 30 * 3600.0  # 30 frames a second
    shown, hours = R.check_exposure(10, fph)
    assert shown == pytest.approx(0.9)  # phases 1..9 of 10 are drawn at least once
    assert hours == pytest.approx(4.5 / fph)
    assert R.check_exposure(1, fph) == (0.0, 0.0)  # checked before every frame: never drawn


def test_with_exposure_by_hand():
    lam, bits, p_rep = 1e-12, 1e8, 1e-3
    r = lam * bits * p_rep  # catastrophic upsets a check repairs, per hour
    t, share = R.with_exposure(math.inf, 0.0, lam, bits, p_rep, (0.9, 2.0))
    assert t == pytest.approx(1 / (0.9 * r))
    assert share == pytest.approx(1 - math.exp(-2.0 * r))
    # on top of residual catastrophes that stay until the scrub: the rates add
    t2, _ = R.with_exposure(1e6, 0.0, lam, bits, p_rep, (0.9, 2.0))
    assert t2 == pytest.approx(1 / (1e-6 + 0.9 * r))
    assert R.with_exposure(5.0, 0.1, lam, bits, 0.0, (0.9, 2.0)) == (5.0, 0.1)  # nothing repaired


def test_mtbf_table_counts_a_checked_catastrophe_for_its_exposure():
    pc = pd.DataFrame(
        {
            "precision": ["fp32", "fp32"],
            "defense": ["none", "parity4r"],
            "p_c": [2e-3, 0.0],
            "ci_lo": [1e-3, 0.0],
            "ci_hi": [3e-3, 1e-4],
        }
    )
    rates = [{"environment": "test", "per_bit_hour": 1e-12}]
    bits, fph = 1e9, 60 * 3600.0
    ex = R.check_exposure(6, fph)
    mt = R.mtbf_table(pc, bits, "fp32", rates, 24.0, defenses=("none", "parity4r"), exposure={"parity4r": ex})
    row = mt.set_index("defense").loc["parity4r"]
    r = 1e-12 * bits * 2e-3
    assert row["mtbf_hours"] == pytest.approx(1 / (r * 5 / 6))
    assert row["catastrophic_frames_pct"] == pytest.approx(100 * (1 - math.exp(-r * 2.5 / fph)))
    assert row["exposure_hours"] == pytest.approx(2.5 / fph)
    plain = R.mtbf_table(pc, bits, "fp32", rates, 24.0, defenses=("none", "parity4r"))
    assert math.isinf(plain.set_index("defense").loc["parity4r", "mtbf_hours"])  # without: never
    assert "exposure_hours" not in plain
    none = mt.set_index("defense").loc["none"]
    assert none["mtbf_hours"] == plain.set_index("defense").loc["none", "mtbf_hours"]  # no check: unchanged


def test_reliability_reads_the_check_schedule_from_the_spec():
    """`reliability` (what the report runs) gives a check defense's arm its MTBF rows with the
    exposure of the spec's [reliability] check_every and frames_per_second, recomputed here from
    the records with plain pandas: parity4r repairs every catastrophe none shows, so its MTBF is
    that of the repaired ones drawn for the share of phases a check lets through."""
    from test_reliability_models import single_records

    base = single_records("m", 1000, seed=3, hot=0.5)
    none = base[base["defense"] == "none"]
    checked = none.assign(defense="parity4r", footprint=0.0, peak_error=0.0)  # every flip repaired
    df = pd.concat([none, checked], ignore_index=True)
    rates = [{"environment": "test", "per_bit_hour": 1e-12, "source": "t"}]
    spec = {"reliability": {"rates": rates, "scrub_hours": 24.0, "check_every": 8, "frames_per_second": 60.0}}
    res = R.reliability(df, [{"spec": spec}])
    assert (res["check_every"], res["frames_per_second"]) == (8, 60.0)
    mt = res["mtbf"].set_index("defense")
    # p_c of none from the records: the weighted share of catastrophic sites (stratified by cell)
    cat = none.assign(c=none["footprint"] > 0.01)
    pc = (cat["c"] * cat["weight"]).sum() / cat["weight"].sum()
    bits = res["bits"]
    r = 1e-12 * bits * pc
    assert mt.loc["parity4r", "mtbf_hours"] == pytest.approx(1 / (r * 7 / 8), rel=1e-9)
    assert mt.loc["parity4r", "exposure_hours"] == pytest.approx(3.5 / (60 * 3600.0))
    assert math.isnan(mt.loc["none", "exposure_hours"])
    # no S in the spec: the default S = 10 at 30 frames/s, stated; the MTBF is bounded
    plain = R.reliability(df, [{"spec": {"reliability": {"rates": rates, "scrub_hours": 24.0}}}])
    assert plain["check_every"] == 10 and "default (S = 10" in plain["check_every_from"]
    assert plain["mtbf"].set_index("defense").loc["parity4r", "mtbf_hours"] == pytest.approx(1 / (r * 9 / 10))
    assert R.reliability(df)["check_every_from"] == "the default (S = 10)"  # no manifest at all
    # a schedule per check defense: parity4r's own S
    per = {"reliability": {"rates": rates, "scrub_hours": 24.0, "check_every": {"parity4r": 4}}}
    res4 = R.reliability(df, [{"spec": per}])
    assert res4["check_every_of"] == {"parity4r": 4}
    assert res4["mtbf"].set_index("defense").loc["parity4r", "mtbf_hours"] == pytest.approx(1 / (r * 3 / 4))
