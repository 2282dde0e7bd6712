"""Like with like, over models: the equal-field p_c against the bit-weighted one, the t interval over
models and its verdicts, the 8-bit floor of the median fit, the two size experiments, the dose at
matched k/N and the mantissa-slope windows, each recomputed here with plain pandas and scipy from
records made for the test."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps
from test_reliability_models import COMPS, single_records
from test_report_numbers import stratified

from seuwgpu.analysis import claimrows, claims, dose, population, scaling, theory


def models(*hot):
    """Single-upset records of len(hot) models of 1,000 primitives each."""
    return pd.concat(
        [single_records(f"m{i}", 1000, 10 + i, h, iid0=100_000 * i) for i, h in enumerate(hot)], ignore_index=True
    )


def test_equal_field_mean_is_the_plain_mean_of_field_rates_not_the_weighted_rate():
    df = models(0.6, 0.3, 0.45)
    est = population.model_rates(df, "fp32", "none").set_index("scene")
    none = df[df["defense"] == "none"].assign(catastrophic=lambda d: d["footprint"] > 0.01)
    for scene, g in none.groupby("scene"):
        fields = [stratified(h, "catastrophic")[0] for _, h in g.groupby("field")]
        assert est.loc[scene, "fields_p_c"] == pytest.approx(np.mean(fields), rel=1e-12)
        weighted = sum(stratified(h, "catastrophic")[0] * COMPS[f] for f, h in g.groupby("field")) / 59
        assert est.loc[scene, "bits_p_c"] == pytest.approx(weighted, rel=1e-12)
        # sh_rest (45 of 59 components) is inert here: the plain mean is far above the weighted rate
        assert est.loc[scene, "fields_p_c"] > 3 * est.loc[scene, "bits_p_c"]
        assert est.loc[scene, "fields_ci_lo"] <= est.loc[scene, "fields_p_c"] <= est.loc[scene, "fields_ci_hi"]


def test_t_interval_over_models():
    v = np.array([0.2, 0.5, 0.35, 0.9])
    om = population.interval_over_models(v)
    half = sps.t.ppf(0.975, 3) * v.std(ddof=1) / 2
    assert (om.mean, om.lo, om.hi, om.n_models) == pytest.approx((v.mean(), v.mean() - half, v.mean() + half, 4))
    one = population.interval_over_models([0.3, np.nan])
    assert one.n_models == 1 and np.isnan(one.lo) and np.isnan(one.hi)  # undefined stays NaN


@pytest.mark.parametrize(
    "key, lo, hi, n, kw, want",
    [
        ("pc_none", 0.40, 1.20, 4, {}, "reproduced"),  # inside [0.6335 / 2, 0.6345 x 2]
        ("pc_none", 1.30, 2.00, 4, {}, "differs"),
        ("pc_none", 0.40, 1.20, 2, {}, "inconclusive"),  # under MIN_MODELS
        ("pc_none", 0.40, 1.20, None, {}, "reproduced"),  # over the records: the claims table holds it
        ("pc_none", np.nan, np.nan, None, {}, "not measured"),  # over the records, no interval
        ("pc_none", np.nan, np.nan, 4, {}, "inconclusive"),  # over models, no interval
        ("pc_none", 0.40, 1.20, 4, {"population": population.POOLED}, "inconclusive"),
        ("pc_guard_bits", 0.1, 0.2, 4, {}, "no paper value"),  # this project's own estimate
        ("field_rate_quats", 0.0, 0.004, 4, {}, "reproduced"),  # 0.000 as printed: under the 0.01 bound
        ("dose_none_all", -np.inf, -np.inf, 7, {}, "differs"),  # every model at -inf: below any band
        ("dose_guard_all", -np.inf, np.nan, 7, {}, "inconclusive"),
        ("guard_worst_footprint", 8.0, 12.0, None, {"matched": False}, "not comparable"),
        ("guard_worst_footprint", 8.0, 12.0, None, {}, "reproduced"),  # at the paper's number of upsets
    ],
)
def test_claim_verdict_is_the_one_rule_of_a_row(key, lo, hi, n, kw, want):
    assert population.claim_verdict(key, lo, hi, n, **kw) == want
    if kw or n is None or want == "no paper value":
        return
    r = claimrows.row(key, 1.0, lo, hi, n_models=n)  # the claims table's rows take the same verdict
    assert r["verdict"] == want


@pytest.mark.parametrize(
    "lo, hi, n, want",
    [
        (0.40, 1.20, 4, "reproduced"),  # inside [0.6335 / 2, 0.6345 x 2]
        (0.40, 1.30, 4, "inconclusive"),  # reaches past the band: the test cannot reject "above"
        (1.30, 2.00, 4, "differs"),  # wholly above the band
        (0.10, 0.30, 4, "differs"),  # wholly below
        (0.40, 1.20, 2, "inconclusive"),  # too few models: never firmer with one or two
        (0.40, 1.20, 1, "inconclusive"),
        (-0.2, 1.20, 4, "inconclusive"),  # holds 0 and values far below the band
    ],
)
def test_equivalence_verdict_needs_the_interval_inside_the_margin(lo, hi, n, want):
    h = claims.paper_half_unit(0.634)
    assert population.equivalence_verdict(lo, hi, 0.634, h, ("factor", 2.0), n) == want


@pytest.mark.parametrize(
    "lo, hi, want", [(0.0, 0.008, "reproduced"), (0.0, 0.02, "inconclusive"), (0.011, 0.05, "differs")]
)
def test_a_paper_zero_gets_an_upper_bound(lo, hi, want):
    h = claims.paper_half_unit("0.000")
    assert population.equivalence_verdict(lo, hi, 0.0, h, ("bound", 0.01), 4) == want
    assert claims.MARGINS.get("field_rate_quats") == ("factor", 2.0)  # the factor is not used for a 0
    from seuwgpu.analysis.paper import margin_of

    assert margin_of("field_rate_quats") == ("bound", 0.01)


def test_absolute_margin_and_minus_infinity():
    assert population.equivalence_verdict(47.0, 52.0, 49.2, 0.05, ("abs", 3.0), 4) == "reproduced"
    assert population.equivalence_verdict(40.0, 46.0, 49.2, 0.05, ("abs", 3.0), 4) == "differs"
    assert population.equivalence_verdict(-np.inf, -np.inf, 10.6, 0.05, ("abs", 3.0), 4) == "differs"
    assert population.equivalence_verdict(-np.inf, np.nan, 10.6, 0.05, ("abs", 3.0), 4) == "inconclusive"


def test_one_model_never_gives_a_firmer_verdict_than_two():
    """The older rows over models fell back to the pooled records' verdict with one model; now one
    model's row keeps its value and the pooled interval beside, and is inconclusive."""
    one = pd.DataFrame({"scene": ["a"], "n_primitives": [8192], "v": [0.006]})
    r = claimrows.over_models("pc_none", one, "v", "test", 0.95, pooled=(0.6, 0.55, 0.65))
    assert r["verdict"] == "inconclusive" and r["measured"] == pytest.approx(0.6)
    assert (r["pooled_lo"], r["pooled_hi"]) == (0.55, 0.65) and np.isnan(r["ci_lo"])
    df = models(0.6)
    t = claims.claims_table(df).set_index("claim")
    assert not t["verdict"].isin(["reproduced", "differs"]).any()


def test_an_interval_over_models_stays_inside_the_quantity_s_range():
    """A t interval over four models of a rate (0, 0, 0.011, 0.13 %: the guarded p_c) runs below 0
    and one of a share above 100%: the row is cut to the range, says so, and the verdict is the
    one the uncut interval gives (it held 0 either way)."""
    per = pd.DataFrame({"scene": ["a", "b", "c", "d"], "v": [0.0, 0.0, 0.011e-2, 0.13e-2]})
    v = per["v"].to_numpy() * 100
    half = sps.t.ppf(0.975, 3) * v.std(ddof=1) / 2
    assert v.mean() - half < 0  # the uncut interval leaves the range
    row = claimrows.over_models("pc_guard", per, "v", "test", 0.95)
    assert row["ci_lo"] == 0.0 and row["ci_hi"] == pytest.approx(v.mean() + half)
    assert "lower" in row["basis"] and "cut to 0" in row["basis"]
    # [0, 0.055]% against the paper's 0.0612 within a factor 2, [0.0306, 0.1224]: neither inside nor outside
    assert row["verdict"] == "inconclusive"
    share = pd.DataFrame({"scene": ["a", "b", "c", "d"], "s": [1.0, 1.0, 0.9935, 0.9314]})
    s = share["s"].to_numpy() * 100
    top = s.mean() + sps.t.ppf(0.975, 3) * s.std(ddof=1) / 2
    assert top > 100
    row = claimrows.over_models("guard_share", share, "s", "test", 0.95)
    assert row["ci_hi"] == 100.0 and row["ci_lo"] == pytest.approx(2 * s.mean() - top)
    # [92.8, 100] against 90.4 +- 5 points, [85.35, 95.45]: it reaches past the band, not wholly outside
    assert 85.35 < row["ci_lo"] < 95.45 < row["ci_hi"] and row["verdict"] == "inconclusive"
    inside = claimrows.over_models("pc_none", per.assign(v=[0.01, 0.012, 0.015, 0.02]), "v", "test", 0.95)
    assert "cut" not in inside["basis"]


def test_claims_compare_the_paper_with_the_equal_field_mean_over_models():
    df = models(0.6, 0.3, 0.45, 0.2)
    t = claims.claims_table(df).set_index("claim")
    est = population.model_rates(df, "fp32", "none")
    guard = population.model_rates(df, "fp32", "guard")
    r = t.loc[claims.PAPER["pc_none"][0]]
    v = 100 * est["fields_p_c"].to_numpy()
    half = sps.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v))
    assert (r["measured"], r["ci_lo"], r["ci_hi"]) == pytest.approx((v.mean(), v.mean() - half, v.mean() + half))
    assert r["paper"] == 0.634 and r["n_models"] == 4 and r["interval_over"] == claims.OVER_MODELS
    band = (0.6335 / 2, 0.6345 * 2)
    inside = band[0] <= r["ci_lo"] and r["ci_hi"] <= band[1]
    outside = r["ci_hi"] < band[0] or r["ci_lo"] > band[1]
    assert r["verdict"] == ("reproduced" if inside else "differs" if outside else "inconclusive")
    assert r["population"] == population.REAL and r["margin"] == "x/2" and r["N"] == "full size: 1,000"
    b = t.loc[claims.PAPER["pc_none_bits"][0]]
    assert b["measured"] == pytest.approx(100 * est["bits_p_c"].mean())
    assert b["paper"] == pytest.approx(0.1934, abs=5e-5)  # Table 2 weighted by 3, 3, 4, 1, 3, 45 components
    share = 1 - guard["fields_p_c"].to_numpy() / est["fields_p_c"].to_numpy()
    s = t.loc[claims.PAPER["guard_share"][0]]
    assert s["measured"] == pytest.approx(100 * share.mean()) and s["paper"] == 90.4
    own = t.loc[claims.PAPER["pc_guard_bits"][0]]
    assert np.isnan(own["paper"]) and own["verdict"] == "no paper value"
    # rates the report computes once serve both tables, at their own conf only
    shared = claims.arm_model_rates(df)
    pd.testing.assert_frame_equal(claims.claims_table(df, {"model_rates": shared}).set_index("claim"), t)
    at95 = claims.model_estimates(df, rates=shared)
    pd.testing.assert_frame_equal(at95, claims.model_estimates(df))
    at90 = claims.model_estimates(df, conf=0.9, rates=shared)  # recomputed at 0.9
    pd.testing.assert_frame_equal(at90, claims.model_estimates(df, conf=0.9))
    assert (at90["fields_pc_none_hi"] < at95["fields_pc_none_hi"]).all()


def size_table(median, mean, scenes, ns=(1000, 4000, 16000, 64000)):
    rows = []
    for scene, (a_med, a_mean) in scenes.items():
        for i, n in enumerate(ns):
            rows.append(
                {
                    "scene": scene,
                    "precision": "fp32",
                    "defense": "none",
                    "n_primitives": n,
                    "median_mse": median(scene, n, a_med, i),
                    "mean_mse": 1e-4 * n**-a_mean * (1 + 0.05 * (-1) ** i),
                }
            )
    return pd.DataFrame(rows)


def test_median_is_fitted_only_above_the_8_bit_floor_and_experiments_apart():
    floor = scaling.median_floor(256, 256)
    assert floor == pytest.approx((1 / 255) ** 2 / (3 * 256 * 256)) and floor == pytest.approx(7.8e-11, rel=0.01)

    def median(scene, n, a, i):  # spheres: above the floor; blocks: its two largest sizes are rounding
        v = 1e-4 * n**-a * (1 + 0.03 * i)
        return v if scene != "blocks" or i < 2 else 1e-18

    scenes = {"spheres": (1.0, 0.1), "blocks": (0.8, 0.2), "leica-sofort": (0.5, 0.0), "yashica-t4": (0.6, 0.05)}
    t = size_table(median, None, scenes)
    t["group"] = [scaling.scene_group(s) for s in t["scene"]]
    t["median_above_floor"] = t["median_mse"] > floor
    g = scaling.group_fits(t).set_index(["group", "metric"])
    proc = g.loc[(scaling.PROCEDURAL, "median_mse")]
    # blocks keeps two sizes above the floor: no fit; spheres alone
    assert proc["n_scenes_fitted"] == 1 and proc["n_points"] == 4
    sp = t[t["scene"] == "spheres"]
    slope = np.polyfit(np.log10(sp["n_primitives"]), np.log10(sp["median_mse"]), 1)[0]
    assert proc["alpha_common"] == pytest.approx(-slope)
    # the captures' common slope and the F test of equal slopes, recomputed
    cap = t[t["group"] == scaling.CAPTURE]
    x = np.log10(cap["n_primitives"].to_numpy(float))
    y = np.log10(cap["median_mse"].to_numpy(float))
    xc = x - cap.groupby("scene")["n_primitives"].transform(lambda v: np.log10(v).mean()).to_numpy()
    yc = y - pd.Series(y, index=cap.index).groupby(cap["scene"]).transform("mean").to_numpy()
    assert g.loc[(scaling.CAPTURE, "median_mse"), "alpha_common"] == pytest.approx(-(xc @ yc) / (xc @ xc))
    use = t[(t["scene"] != "blocks")]
    lx = np.log10(use["n_primitives"].to_numpy(float))
    ly = np.log10(use["median_mse"].to_numpy(float))
    X_one = np.column_stack([pd.get_dummies(use["scene"]).to_numpy(float), lx])
    X_two = np.column_stack(
        [
            pd.get_dummies(use["scene"]).to_numpy(float),
            lx * (use["group"] == scaling.PROCEDURAL),
            lx * (use["group"] == scaling.CAPTURE),
        ]
    )
    rss = [np.sum((ly - X @ np.linalg.lstsq(X, ly, rcond=None)[0]) ** 2) for X in (X_one, X_two)]
    dof = len(ly) - X_two.shape[1]
    F = (rss[0] - rss[1]) / (rss[1] / dof)
    assert proc["equal_slopes_F"] == pytest.approx(F, rel=1e-6)
    assert proc["equal_slopes_p"] == pytest.approx(sps.f.sf(F, 1, dof), rel=1e-6)
    # the mean, with the mean: both procedural scenes fitted, t interval over their two alphas
    mean = g.loc[(scaling.PROCEDURAL, "mean_mse")]
    alphas = [
        -np.polyfit(np.log10(h["n_primitives"]), np.log10(h["mean_mse"]), 1)[0]
        for _, h in t[t["group"] == scaling.PROCEDURAL].groupby("scene")
    ]
    om = population.interval_over_models(alphas)
    assert (mean["alpha_scene_mean"], mean["alpha_models_lo"]) == pytest.approx((om.mean, om.lo))


def test_dose_at_matched_dose_per_primitive():
    curves = pd.DataFrame(
        {
            "scene": "a",
            "n_primitives": 2000,
            "precision": "fp32",
            "defense": "none",
            "k": [10, 100, 1000],
            "psnr_mean_mse_db": [40.0, 30.0, np.nan],
        }
    )
    at = dose.at_dose_per_primitive(curves, 0.025, "psnr_mean_mse_db").iloc[0]  # k = 50
    t = (np.log(50) - np.log(10)) / (np.log(100) - np.log(10))
    assert at["k"] == 50 and at["psnr_mean_mse_db"] == pytest.approx(40 - 10 * t)
    assert np.isnan(dose.at_dose_per_primitive(curves, 0.25, "psnr_mean_mse_db").iloc[0]["psnr_mean_mse_db"])
    assert np.isnan(dose.at_dose_per_primitive(curves, 1.0, "psnr_mean_mse_db").iloc[0]["psnr_mean_mse_db"])
    paper = np.mean([20_000 / n for n in claims.PAPER_PRIMITIVES])
    assert claims.paper_heaviest_k_per_n() == pytest.approx(paper)


def test_mantissa_slope_windows():
    bits = np.arange(23)
    log2 = np.where(bits < 22, -24 + bits.astype(float), -24 + 21 + 2.5)  # unit slope, bit 22 off trend
    t = pd.DataFrame({"bit": bits, "log2_mean_peak_error": log2, "mean_peak_error": 2.0**log2})
    w = theory.slope_windows({"table": t, "fit_bits": (9, 22)}).set_index("fit_bits")
    for window, (a, b) in {"9..22": (9, 22), "9..21": (9, 21), "11..22": (11, 22)}.items():
        sel = t[(t["bit"] >= a) & (t["bit"] <= b)]
        assert w.loc[window, "slope"] == pytest.approx(np.polyfit(sel["bit"], sel["log2_mean_peak_error"], 1)[0])
    assert w.loc["9..21", "slope"] == pytest.approx(1.0) and w.loc["9..22", "slope"] > 1.0
    assert bool(w.loc["9..22", "top_bit_in"]) and not bool(w.loc["9..21", "top_bit_in"])


def test_contamination_per_frame_beside_the_union_over_views():
    from test_analysis import _records

    from seuwgpu.analysis import contamination, folding, records

    # an upset that reaches all 4 regions over the views, but one region in each of its frames,
    # and one of the same site whose frames reach 2 and 4 regions (mean 3 of 4)
    a = _records(6, field="log_scales", bit=31, bit_class="sign", footprint=0.5, regions_pred_4=0b1111,
                 regions_meas_4=0b0111, regions_pred_frame_4=0.25, regions_meas_frame_4=0.25)  # fmt: skip
    b = _records(2, field="log_scales", bit=30, bit_class="exponent", footprint=0.5, regions_pred_4=0b1111,
                 regions_meas_4=0b1111, regions_pred_frame_4=0.75, regions_meas_frame_4=0.5)  # fmt: skip
    b["injection_id"] += 100
    d = pd.concat([a, b], ignore_index=True)
    t = contamination.contamination(d)
    r = t[(t["subset"] == "all single upsets") & (t["defense"] == "none")].iloc[0]
    w = records.single_upsets(d, None, None)["weight"].to_numpy()
    frame = np.r_[np.full(6, 0.25), np.full(2, 0.75)]
    assert r["pred_frame_pct"] == pytest.approx(100 * np.average(frame, weights=w))
    assert r["meas_frame_pct"] == pytest.approx(100 * np.average(np.r_[np.full(6, 0.25), np.full(2, 0.5)], weights=w))
    assert r["pred_fraction_pct"] == 100  # the union over views reaches every region
    union = np.r_[np.full(6, 3 / 4), np.full(2, 1.0)]
    assert r["meas_fraction_pct"] == pytest.approx(100 * np.average(union, weights=w))
    # records that predate the per-frame columns: undefined, not 0
    old = d.drop(columns=["regions_pred_frame_4", "regions_meas_frame_4"])
    r = contamination.contamination(old).iloc[0]
    assert np.isnan(r["pred_frame_pct"]) and np.isnan(r["meas_frame_pct"]) and r["pred_fraction_pct"] == 100
    # folded rows carry the per-frame sums too, and give the same shares
    f = folding.fold_part(records.prepare(d), {})
    assert {"region_fpf_4_sum", "region_fmf_4_n"} <= set(f.columns)
    cols = ["subset", "defense", "P", "pred_frame_pct", "meas_frame_pct", "pred_fraction_pct", "meas_fraction_pct"]
    pd.testing.assert_frame_equal(contamination.contamination(f)[cols], t[cols])


def test_the_equal_slopes_test_on_exact_fits():
    """Two sets of exact power laws: with different slopes the test is certain (F = inf, p = 0);
    with the same slope it has nothing to weigh (NaN, never a made-up F or p)."""
    n = np.array([1e3, 1e4, 1e5, 1e6] * 2)
    groups = np.repeat(["a", "b"], 4)
    sets = np.repeat(["procedural", "capture"], 4)
    differ = np.where(sets == "procedural", n**0.5, 3.0 * n**0.2)
    F, p, dof = scaling.slopes_equal_test(groups, sets, n, differ)
    assert (F, p, dof) == (np.inf, 0.0, 4)
    same = np.where(sets == "procedural", n**0.5, 3.0 * n**0.5)
    F, p, dof = scaling.slopes_equal_test(groups, sets, n, same)
    assert np.isnan(F) and np.isnan(p) and dof == 4
    noisy = same * np.array([1.0, 1.1, 0.95, 1.02, 1.0, 0.9, 1.05, 1.0])
    F, p, dof = scaling.slopes_equal_test(groups, sets, n, noisy)
    assert np.isfinite(F) and 0.0 <= p <= 1.0
