"""Reliability per model: p_c, stored bits and MTBF of records holding several scenes (trained
models) are each scene's own, recomputed here with plain pandas and the textbook formulas; a
record set of one scene gives what it always gave."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_report_numbers import stratified, textbook_mtbf

from seuwgpu.analysis import claims, dose, reliability

COMPS = {"means": 3, "log_scales": 3, "quats": 4, "opacity": 1, "sh_dc": 3, "sh_rest": 45}
SAMPLES = 4
Z = 1.959963984540054


def single_records(scene: str, n: int, seed: int, hot: float, iid0: int = 0) -> pd.DataFrame:
    """Every field and bit at fp32, SAMPLES records a cell, arms none and guard on the same sites:
    log-scale and opacity bits 29-31 are catastrophic with probability `hot` without the guard
    and hot / 8 with it; means bit 30 with probability hot / 4 without."""
    cells = [(f, nc, b) for f, nc in COMPS.items() for b in range(32)]
    field = np.repeat([c[0] for c in cells], SAMPLES)
    bit = np.repeat([c[2] for c in cells], SAMPLES)
    weight = np.repeat([n * c[1] / SAMPLES for c in cells], SAMPLES)
    u = np.random.default_rng(seed).random(field.size)  # one draw per site, both arms
    top = np.isin(field, ["log_scales", "opacity"]) & (bit >= 29)
    arms = []
    for d in ("none", "guard"):
        cat = top & (u < (hot if d == "none" else hot / 8))
        if d == "none":
            cat |= (field == "means") & (bit == 30) & (u < hot / 4)
        arms.append(
            pd.DataFrame(
                {
                    "field": field,
                    "bit": bit,
                    "weight": weight,
                    "injection_id": iid0 + 1 + np.arange(field.size),
                    "defense": d,
                    "footprint": np.where(cat, 0.5, 0.0),
                    "peak_error": np.where(cat, 0.5, 0.0),
                }
            )
        )
    t = pd.concat(arms, ignore_index=True)
    cls = np.where(t["bit"] == 31, "sign", np.where(t["bit"] >= 23, "exponent", "mantissa"))
    model = {"campaign": "single", "scene": scene, "n_primitives": n, "precision": "fp32"}
    return t.assign(**model, bit_class=cls, component=0, k=1, nonfinite=False)


def dose_records(scene: str, n: int, bad: dict, iid0: int) -> pd.DataFrame:
    """Dose campaign of one model: 10 repeats at k = 1, 10, 100; bad[(defense, k)] of them are
    catastrophic."""
    rows, iid = [], iid0
    for d in ("none", "guard"):
        for k in (1, 10, 100):
            for r in range(10):
                iid += 1
                cat = r < bad.get((d, k), 0)
                rows.append(
                    {
                        "campaign": "dose",
                        "scene": scene,
                        "n_primitives": n,
                        "precision": "fp32",
                        "field": "mixed",
                        "bit": -1,
                        "bit_class": "mixed",
                        "defense": d,
                        "footprint": 0.5 if cat else 0.001,
                        "peak_error": 0.5,
                        "psnr": 30.0,
                        "nonfinite": False,
                        "k": k,
                        "repeat": r,
                        "weight": 1.0,
                        "injection_id": iid,
                    }
                )
    return pd.DataFrame(rows)


def two_scenes() -> pd.DataFrame:
    return pd.concat(
        [
            single_records("big", 4000, 1, 0.5),
            single_records("small", 500, 2, 0.1, iid0=100_000),
            dose_records("big", 4000, {("none", 10): 1, ("none", 100): 6, ("guard", 100): 2}, 200_000),
            dose_records("small", 500, {("none", 100): 3, ("guard", 100): 1}, 300_000),
        ],
        ignore_index=True,
    )


def fits_of(df: pd.DataFrame) -> pd.DataFrame:
    return dose.dose_fits(dose.dose_curves(df))


def test_pc_per_scene_is_each_scene_own_weighted_rate():
    df = two_scenes()
    pc = reliability.catastrophe_probability(df)
    assert list(pc.columns[:4]) == ["scene", "n_primitives", "precision", "defense"]
    assert list(zip(pc["scene"], pc["defense"])) == [
        ("big", "none"),
        ("big", "guard"),
        ("small", "none"),
        ("small", "guard"),
    ]
    got = pc.set_index(["scene", "defense"])
    for (scene, d), g in df[df["campaign"] == "single"].groupby(["scene", "defense"]):
        y = (g["footprint"] > 0.01).astype(float)
        r = got.loc[(scene, d)]
        assert r["p_c"] == pytest.approx((g["weight"] * y).sum() / g["weight"].sum(), rel=1e-12)
        assert r["n"] == len(g) and r["weight"] == pytest.approx(g["weight"].sum())
        p, lo, hi = stratified(g.assign(catastrophic=y.astype(bool)), "catastrophic")
        assert (r["p_c"], r["ci_lo"], r["ci_hi"]) == pytest.approx((p, lo, hi), abs=1e-12)
    # the two models differ: a pool would be neither (the test is not vacuous)
    assert got.loc[("big", "none"), "p_c"] > 5 * got.loc[("small", "none"), "p_c"]


def test_mtbf_pairs_each_scene_p_with_its_own_bits():
    df = two_scenes()
    fits = fits_of(df)
    res = reliability.reliability(df, dose_fits=fits)
    assert res["per_model"] and res["bits"] == {"big": 4000 * 59 * 32, "small": 500 * 59 * 32}
    mt = res["mtbf"]
    assert list(mt.columns[:3]) == ["scene", "n_primitives", "model_bits"]
    assert len(mt) == 2 * 3 * 4  # scenes x environments x (defense, p source)
    single = df[df["campaign"] == "single"]
    fit = fits.set_index(["scene", "defense"])
    for (scene, d, src), g in mt.groupby(["scene", "defense", "p_source"]):
        n = {"big": 4000, "small": 500}[scene]
        bits = n * 59 * 32
        assert (g["model_bits"] == bits).all() and (g["n_primitives"] == n).all()
        if src == "single-upset p_c":
            s = single[(single["scene"] == scene) & (single["defense"] == d)]
            p = (s["weight"] * (s["footprint"] > 0.01)).sum() / s["weight"].sum()
        else:
            p = fit.loc[(scene, d), "p_pct"] / 100
        assert g["p_pct"].to_numpy() == pytest.approx(np.full(len(g), 100 * p), rel=1e-12)
        assert g["mtbf_hours"].to_numpy() == pytest.approx(textbook_mtbf(g["upsets_per_bit_hour"], bits, p), rel=1e-6)
    wide = res["mtbf_wide"]
    assert list(wide.columns[:3]) == ["scene", "model_bits", "environment"]
    assert list(wide["scene"]) == ["big"] * 3 + ["small"] * 3
    fig = reliability.plot_sensitivity(res)
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert len(titles) == 2 and titles[0].startswith("big:") and titles[1].startswith("small:")


def test_dose_fit_of_one_scene_never_meets_another_scene_bits():
    df = two_scenes()
    no_small_dose = df[~((df["campaign"] == "dose") & (df["scene"] == "small"))]
    res = reliability.reliability(no_small_dose, dose_fits=fits_of(no_small_dose))
    mt = res["mtbf"]
    assert set(mt.loc[mt["p_source"] == "dose fit p", "scene"]) == {"big"}
    assert res["dose_p"]["small"] == {}
    # one model's records beside another scene's dose fit: that fit is not used, and a note says why
    small = df[(df["scene"] == "small") & (df["campaign"] == "single")]
    res = reliability.reliability(small, dose_fits=fits_of(df[df["scene"] == "big"]))
    assert set(res["mtbf"]["p_source"]) == {"single-upset p_c"} and res["dose_p"] == {}
    assert any("dose fits of big not used" in n for n in res["notes"])


def test_pooled_pc_is_labelled_and_never_feeds_an_mtbf():
    df = two_scenes()
    pooled = reliability.catastrophe_probability(df, pooled=True).set_index("defense")
    per = reliability.catastrophe_probability(df).set_index(["scene", "defense"])
    assert pooled["pooled_over"].iloc[0] == "2 models, weighted by stored bits: big (N=4,000), small (N=500)"
    for d in ("none", "guard"):  # an upset uniform over both models' bits: weighted by their sizes
        w = per.xs(d, level="defense")["weight"]
        p = per.xs(d, level="defense")["p_c"]
        assert pooled.loc[d, "p_c"] == pytest.approx((w * p).sum() / w.sum(), rel=1e-12)
    with pytest.raises(ValueError, match="pooled"):
        reliability.mtbf_table(pooled.reset_index(), 1e6, "fp32")
    with pytest.raises(ValueError, match="several models"):
        reliability.mtbf_table(per.reset_index(), 1e6, "fp32")
    with pytest.raises(ValueError, match="models"):
        reliability.pc_lookup(per.reset_index(), "fp32", "none")
    assert reliability.reliability(df)["bits"]["small"] == 500 * 59 * 32
    # the pool over stored bits is the claims table's own estimate (its "pooled" column)
    t = claims.claims_table(df).set_index("claim").loc[claims.PAPER["pc_none_bits"][0]]
    assert t["pooled"] == pytest.approx(100 * pooled.loc["none", "p_c"])
    assert "pooled over 2 models" in t["basis"]


def test_one_scene_at_two_sizes_is_two_models():
    df = pd.concat([single_records("a", 4000, 1, 0.5), single_records("a", 500, 2, 0.1, iid0=100_000)])
    res = reliability.reliability(df)
    assert [m["label"] for m in res["models"]] == ["a (N=4,000)", "a (N=500)"]
    assert res["bits"] == {"a_N4000": 4000 * 59 * 32, "a_N500": 500 * 59 * 32}
    assert list(res["mtbf_wide"]["scene"].unique()) == ["a (N=4,000)", "a (N=500)"]


# the single-scene tables of commit d21b1f8 (before p_c and MTBF went per model), for the records
# of "big" alone with its dose fits
OLD_PC = {
    "p_c": [0.004502118644067797, 0.0005296610169491525],
    "ci_lo": [0.0007952038950161666, 1.4907564716698518e-05],
}
OLD_MTBF_HOURS = [
    29411776.705883987,
    14432969.850357253,
    250000012.00000015,
    66716864.2609096,
    98051.21617587452,
    48121.86049889623,
    833345.3333909335,
    222401.50775220044,
    7070.830329410454,
    3475.923741247282,
    60012.0008,
    16024.047540361365,
]


def test_one_scene_output_is_unchanged():
    df = two_scenes()
    one = df[df["scene"] == "big"]
    res = reliability.reliability(one, dose_fits=fits_of(one))
    assert not res["per_model"] and res["bits"] == 4000 * 59 * 32
    pc, mt, wide = res["pc"], res["mtbf"], res["mtbf_wide"]
    assert list(pc.columns) == [
        "precision", "defense", "n", "events", "weight", "p_c", "ci_lo", "ci_hi", "n_eff", "method",
        "coverage_pct", "sh_degree",
    ]  # fmt: skip
    assert list(mt.columns) == [
        "environment", "upsets_per_bit_hour", "fit_per_mbit", "live_upsets_per_scrub", "regime", "defense",
        "p_source", "p_pct", "scrub_hours",
        "mtbf_hours", "mtbf_hours_lo", "mtbf_hours_hi", "mtbf", "mtbf_range", "catastrophic_frames_pct", "source",
    ]  # fmt: skip
    assert list(wide.columns) == [
        "environment", "none (single-upset p_c)", "none (dose fit p)", "guard (single-upset p_c)",
        "guard (dose fit p)",
    ]  # fmt: skip
    assert list(pc["p_c"]) == pytest.approx(OLD_PC["p_c"], rel=1e-12)
    assert list(pc["ci_lo"]) == pytest.approx(OLD_PC["ci_lo"], rel=1e-9)
    assert list(mt["mtbf_hours"]) == pytest.approx(OLD_MTBF_HOURS, rel=1e-9)
    assert list(wide["none (single-upset p_c)"]) == ["3.36e+03 yr", "11.2 yr", "295 d"]
    assert mt.attrs["model_bits"] == 4000 * 59 * 32
    # and the same numbers as big's own rows among two scenes
    both = reliability.reliability(df, dose_fits=fits_of(df))
    rows = both["pc"][both["pc"]["scene"] == "big"].drop(columns=["scene", "n_primitives"]).reset_index(drop=True)
    pd.testing.assert_frame_equal(rows, pc.reset_index(drop=True), check_exact=False, rtol=1e-12)
    m = both["mtbf"]
    m = m[m["scene"] == "big"].drop(columns=["scene", "n_primitives", "model_bits"]).reset_index(drop=True)
    pd.testing.assert_frame_equal(m, mt.reset_index(drop=True), check_exact=False, rtol=1e-12)


def test_stored_bits_of_each_model_at_its_own_sh_degree():
    """A degree-1 model (23 components) beside a degree-3 one (59): each model's stored bits and
    coverage are its own (the degree came from the pooled records: 500 x 59 x 32 bits for the
    degree-1 model, 2.6x too many, and its MTBF that much too short)."""
    big = single_records("big", 4000, 1, 0.3)
    small = single_records("small", 500, 2, 0.05, iid0=10**6)
    small.loc[small["field"] == "sh_rest", "weight"] = 500 * 9 / SAMPLES  # degree 1: 3 x 3 coefficients
    df = pd.concat([big, small], ignore_index=True)
    assert reliability.model_degrees(df) == {("big", 4000): 3, ("small", 500): 1}
    res = reliability.reliability(df)
    assert res["bits"] == {"big": 4000 * 59 * 32, "small": 500 * 23 * 32}
    # the stored bits are the records' weights: every cell sampled, one arm
    for scene, g in df[df["defense"] == "none"].groupby("scene"):
        assert res["bits"][scene] == pytest.approx(g["weight"].sum())
    pc = res["pc"].set_index(["scene", "defense"])
    assert pc.loc[("small", "none"), "sh_degree"] == 1 and pc.loc[("big", "none"), "sh_degree"] == 3
    assert np.allclose(res["pc"]["coverage_pct"], 100.0) and not any("covers only" in n for n in res["notes"])
    mt = res["mtbf"]
    assert set(mt.loc[mt["scene"] == "small", "model_bits"]) == {500 * 23 * 32}
    pooled = reliability.catastrophe_probability(df, pooled=True)
    assert np.allclose(pooled["coverage_pct"], 100.0) and (pooled["sh_degree"] == -1).all()
    # pooled over stored bits: each model's p_c weighted by its bits
    p = pc["p_c"].xs("none", level="defense")
    want = (p["big"] * 4000 * 59 + p["small"] * 500 * 23) / (4000 * 59 + 500 * 23)
    assert pooled.set_index("defense").loc["none", "p_c"] == pytest.approx(want, rel=1e-12)
