"""Statistics and analyses on synthetic record tables with known answers."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from seuwgpu.analysis import stats
from seuwgpu.analysis import studies as A
from seuwgpu.campaign import plan
from seuwgpu.model import encoding
from seuwgpu.render.regions import region_grid

# ------------------------------------------------------------------------------------ stats


def test_wilson_hand_computed():
    lo, hi = stats.wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=5e-5)
    lo, hi = stats.wilson_interval(5, 10)
    assert lo == pytest.approx(0.2366, abs=5e-5) and hi == pytest.approx(0.7634, abs=5e-5)
    lo, hi = stats.wilson_interval(1, 10)
    assert lo == pytest.approx(0.0179, abs=5e-5) and hi == pytest.approx(0.4042, abs=5e-5)
    lo, hi = stats.wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(1 - 0.2775, abs=5e-5)


def test_wilson_vectorised_and_edges():
    k = np.array([0, 5, 10, 0, 0])
    n = np.array([10, 10, 10, 1000, 0])
    lo, hi = stats.wilson_interval(k, n)
    assert lo.shape == (5,) and hi.shape == (5,)
    assert lo[0] == 0.0 and hi[2] == 1.0  # exact at k = 0 and k = n
    assert hi[3] == pytest.approx(3.8415 / (1000 + 3.8415), rel=1e-4)
    assert np.isnan(lo[4]) and np.isnan(hi[4])  # n = 0: undefined
    # a 99% interval is wider than a 95% one
    lo99, hi99 = stats.wilson_interval(5, 10, conf=0.99)
    assert lo99 < 0.2366 and hi99 > 0.7634
    with pytest.raises(ValueError):
        stats.wilson_interval(11, 10)


def test_sample_size_leveugle():
    # infinite population: t^2 p(1-p) / e^2 = 1.959964^2 * 0.25 / 0.01^2 = 9603.6 -> 9604
    assert plan.sample_size(0.01, 0.95) == 9604
    # N = 1000, e = 5%: 1000 / (1 + 0.0025 * 999 / (3.841459 * 0.25)) = 277.7 -> 278
    assert plan.sample_size(0.05, 0.95, population=1000) == 278
    # N = 1e6, e = 1%: 1e6 / (1 + 1e-4 * 999999 / 0.960365) = 9512.6 -> 9513
    assert plan.sample_size(0.01, 0.95, population=1_000_000) == 9513
    # p = 0.1: 3.841459 * 0.09 / 0.0001 = 3457.3 -> 3458
    assert plan.sample_size(0.01, 0.95, p=0.1) == 3458
    # never more than the population
    assert plan.sample_size(0.001, 0.99, population=50) <= 50
    # the margin achieved by that many samples is (at most) the target
    n = plan.sample_size(0.02, 0.95, population=20_000)
    assert plan.margin_of_error(n, 0.95, population=20_000) <= 0.02
    with pytest.raises(ValueError):
        plan.sample_size(0.0, 0.95)


def test_loglog_fit_exact_power_law():
    x = np.array([1e3, 3e3, 1e4, 3e4, 1e5])
    y = 3.0 * x**-1.5
    fit = stats.loglog_fit(x, y)
    assert fit.exponent == pytest.approx(-1.5, abs=1e-12)
    assert fit.intercept == pytest.approx(math.log10(3.0), abs=1e-12)
    assert fit.r2 == pytest.approx(1.0, abs=1e-12)
    exp_, icpt, r2 = fit  # unpacks as (exponent, intercept, R^2)
    assert exp_ == fit.exponent
    noisy = stats.loglog_fit(x, y * np.array([1.3, 0.8, 1.2, 0.9, 1.1]))
    assert 0.9 < noisy.r2 < 1.0
    with pytest.raises(ValueError):
        stats.loglog_fit([1, 2], [0, 0])


def test_auc_perfect_and_random():
    rng = np.random.default_rng(1)
    y = rng.random(20_000) < 0.3
    assert stats.auc(y, y.astype(float)) == 1.0
    assert stats.auc(y, 1.0 - y) == 0.0
    assert stats.auc(y, rng.random(y.size)) == pytest.approx(0.5, abs=0.02)
    assert math.isnan(stats.auc(np.ones(5, bool), np.arange(5)))


def test_stratified_rate_and_kish():
    # two strata, weights 0.9 / 0.1, rates 0 and 0.5
    p, lo, hi, neff = stats.stratified_rate([0, 50], [100, 100], [0.9, 0.1])
    assert p == pytest.approx(0.05)
    assert neff == pytest.approx(1 / (0.81 / 100 + 0.01 / 100))
    assert lo < p < hi
    p0, lo0, hi0, _ = stats.stratified_rate([0, 0], [100, 100], [0.5, 0.5])
    assert p0 == 0 and lo0 == 0 and hi0 > 0  # honest at zero events


# ---------------------------------------------------------------------------- record helpers


def _records(n, **cols):
    base = {
        "scene": "s",
        "n_primitives": 1000,
        "precision": "fp32",
        "field": "means",
        "primitive": 0,
        "component": 0,
        "bit": 0,
        "bit_class": "mantissa",
        "clean_value": 1.0,
        "corrupted_value": 1.0,
        "defense": "none",
        "footprint": 0.0,
        "footprint_max": 0.0,
        "peak_error": 0.0,
        "psnr": np.inf,
        "ssim": 1.0,
        "nonfinite": False,
        "clamps": 0,
        "k": 1,
        "seed": 0,
        "injection_id": np.arange(n),
        "campaign": "single",
    }
    base.update(cols)
    df = pd.DataFrame({k: (v if np.ndim(v) else [v] * n) for k, v in base.items()})
    if "catastrophic" not in cols:
        df["catastrophic"] = (df["footprint"] > 0.01) | df["nonfinite"]
    return df


def test_criticality_known_quantiles_and_rates():
    fp = np.arange(100) / 1000.0  # 0 .. 9.9 % of the frame
    a = _records(100, field="log_scales", footprint=fp)
    b = _records(50, field="quats", footprint=0.0)
    crit = A.criticality(pd.concat([a, b], ignore_index=True)).set_index("field")
    ls = crit.loc["log_scales"]
    assert ls["n"] == 100
    assert ls["median_pct"] == pytest.approx(4.95)
    assert ls["p95_pct"] == pytest.approx(np.quantile(fp * 100, 0.95))
    assert ls["max_pct"] == pytest.approx(9.9) and ls["mean_pct"] == pytest.approx(4.95)
    assert ls["catastrophic"] == 89  # footprint > 1%: i = 11..99
    lo, hi = stats.wilson_interval(89, 100)
    assert ls["cat_ci_lo_pct"] == pytest.approx(100 * lo)
    assert ls["cat_ci_hi_pct"] == pytest.approx(100 * hi)
    q = crit.loc["quats"]
    assert q["catastrophic"] == 0 and q["cat_ci_lo_pct"] == 0
    assert q["cat_ci_hi_pct"] == pytest.approx(100 * stats.wilson_interval(0, 50)[1])
    prov = crit.attrs["provenance"]
    assert prov["n_records"] == 150 and prov["precisions"] == ["fp32"]


def test_criticality_uses_fp32_and_ignores_dose_and_guard():
    a = _records(10, footprint=0.5)  # fp32 none: all catastrophic
    b = _records(10, precision="fp16", footprint=0.0)
    c = _records(10, defense="guard", footprint=0.0)
    d = _records(10, k=5, campaign="dose", footprint=0.0)
    crit = A.criticality(pd.concat([a, b, c, d], ignore_index=True))
    assert crit.attrs["precision"] == "fp32"
    assert crit["n"].tolist() == [10] and crit["catastrophic"].tolist() == [10]
    with pytest.raises(A.InsufficientData) as e:
        A.criticality(d)
    assert "single" in e.value.remedy


def test_field_bit_table_and_heatmap():
    rows = []
    for bit in range(16):
        rows.append(
            _records(
                3,
                precision="fp16",
                field="opacity",
                bit=bit,
                bit_class=encoding.bit_class("fp16", bit),
                footprint=bit / 1000,
            )
        )
    t = A.field_bit_table(pd.concat(rows, ignore_index=True))
    assert len(t) == 16 and (t["n"] == 3).all()
    assert t.loc[t["bit"] == 15, "bit_class"].item() == "sign"
    m = A.heatmap_matrix(t, "fp16")
    assert m.shape == (1, 16) and m.loc["opacity", 5] == pytest.approx(0.5)


def test_theory_check_unit_slope_on_exact_power_law():
    rows = []
    for b in range(23):
        peak = min(0.25 * 2.0 ** (b - 23), 0.5)  # doubles per bit; bit 22 leaves the window
        rows.append(_records(4, field="log_scales", bit=b, peak_error=peak))
    res = A.theory_check(pd.concat(rows, ignore_index=True))
    assert res["slope"] == pytest.approx(1.0, abs=1e-9)
    assert res["r2"] == pytest.approx(1.0, abs=1e-9)
    # window (1e-5, 0.1]: 0.25 * 2^(b-23) > 1e-5 from b = 9, <= 0.1 up to b = 21
    assert res["fit_bits"] == (9, 21) and res["predicted_slope"] == 1.0


def test_guard_share_neutralised_and_sign_psnr():
    n = 20
    fp_none = np.where(np.arange(n) < 10, 0.5, 0.0)  # 10 catastrophic sites
    fp_guard = np.where(np.arange(n) < 2, 0.5, 0.001)  # the guard fixes 8 of them
    kw = dict(field="log_scales", bit=31, bit_class="sign")
    a = _records(n, footprint=fp_none, psnr=np.where(fp_none > 0, 10.0, np.inf), **kw)
    b = _records(n, defense="guard", footprint=fp_guard, psnr=np.where(fp_guard > 0.1, 10.0, 60.0), **kw)
    res = A.guard_analysis(pd.concat([a, b], ignore_index=True))
    p = res["paired"].iloc[0]
    assert p["catastrophic_none"] == 10 and p["neutralised"] == 8
    assert p["share_neutralised_pct"] == pytest.approx(80.0)
    lo, hi = stats.wilson_interval(8, 10)
    assert p["share_ci_lo_pct"] == pytest.approx(100 * lo)
    assert res["residual_catastrophic"] == 2
    assert res["worst_guarded_footprint_pct"] == pytest.approx(50.0)
    sp = res["sign_psnr"].iloc[0]
    # none: 10 x 10 dB + 10 x inf (capped at 100) -> mean 55; guard: 2 x 10 + 18 x 60 -> 55
    assert sp["mean_psnr_none_db"] == pytest.approx(55.0)
    assert sp["mean_psnr_guard_db"] == pytest.approx((2 * 10 + 18 * 60) / 20)
    with pytest.raises(A.InsufficientData):
        A.guard_analysis(a)


def test_mitigation_shared_grid_and_memory():
    a = _records(10, footprint=np.r_[np.full(5, 0.5), np.zeros(5)])
    b = _records(10, defense="guard", footprint=0.0)
    c = _records(12, defense="dup", footprint=0.0)  # two extra sites: not on the grid
    t = A.mitigation_table(pd.concat([a, b, c], ignore_index=True)).set_index("defense")
    assert t.attrs["paired"] is True
    assert t.loc["dup", "n"] == 10 and t.loc["none", "cat_rate_pct"] == pytest.approx(50)
    assert t.loc["dup", "memory_overhead_pct"] == pytest.approx(200)
    assert t.loc["guard", "memory_overhead_pct"] == pytest.approx(100 * 2 * 14 / (1000 * 59))
    assert A.memory_overhead("ecc", "fp32")[0] == pytest.approx(5 / 32)
    assert A.memory_overhead("ecc", "fp16")[0] == pytest.approx(5 / 16)
    assert A.memory_overhead("ecc", "bf16")[0] == pytest.approx(5 / 16)
    assert A.memory_overhead("selective", "fp32", 100)[0] == pytest.approx(8 / (100 * 59))
    man = [{"memory_overhead": {"ecc": 0.3}}]
    assert A.memory_overhead("ecc", "fp32", manifests=man) == (0.3, "from the run manifest")


def test_crossing_k_interpolates_in_log_k():
    k, c = A.crossing_k([1, 10, 100], [50, 40, 20], 30)
    assert c == "" and k == pytest.approx(10**1.5)
    assert A.crossing_k([1, 10], [50, 40], 30) == (10.0, ">=")
    assert A.crossing_k([2, 10], [20, 10], 30) == (2.0, "<=")


def test_dose_curves_budget_and_model():
    rows = []
    for dfn, pc in (("none", 0.02), ("guard", 0.0)):
        for k in (1, 10, 100, 1000):
            psnr = 60 - 10 * math.log10(k) if dfn == "none" else 70.0
            n = 200
            ncat = round(n * (1 - (1 - pc) ** k))
            fp = np.r_[np.full(ncat, 0.5), np.zeros(n - ncat)]
            rows.append(
                _records(
                    n,
                    defense=dfn,
                    k=k,
                    campaign="dose",
                    psnr=psnr,
                    footprint=fp,
                    field="mixed",
                    bit=-1,
                    bit_class="mixed",
                )
            )
    d = pd.concat(rows, ignore_index=True)
    cur = A.dose_curves(d)
    assert len(cur) == 8 and cur["psnr_mean_db"].iloc[0] == pytest.approx(60)
    b = A.redundancy_budget(d).set_index("defense")
    assert b.loc["none", "k_budget"] == pytest.approx(1000) and b.loc["none", "censored"] == ""
    assert b.loc["guard", "censored"] == ">="
    # p_c from the dose k=1 rows: 4/200 none (round(200*0.02)), 0 guard
    dm = A.dose_model(d).set_index(["defense", "k"])
    assert dm.loc[("none", 10), "model_pct"] == pytest.approx(100 * (1 - (1 - 0.02) ** 10))
    assert dm.loc[("none", 10), "within_ci"]
    assert dm.loc[("guard", 1000), "model_pct"] == 0.0
    with pytest.raises(A.InsufficientData) as e:
        A.dose_curves(_records(5))
    assert "dose campaign" in e.value.remedy


def test_size_scaling_recovers_exponent():
    rows = []
    for n in (1000, 4000, 16000, 64000):
        mse = 1e-4 * (n / 1000) ** -0.5
        rows.append(_records(7, campaign="size", n_primitives=n, psnr=-10 * math.log10(mse)))
    res = A.size_scaling(pd.concat(rows, ignore_index=True))
    f = res["fits"].set_index("metric")
    assert f.loc["median_mse", "alpha"] == pytest.approx(0.5, abs=1e-9)
    assert f.loc["mean_mse", "r2"] == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(A.InsufficientData) as e:
        A.size_scaling(rows[0])
    assert "size campaign" in e.value.remedy


def test_pc_stratified_weights_and_mtbf():
    rows = []
    for field in ("means", "log_scales", "quats", "opacity", "sh_dc", "sh_rest"):
        for bit in range(16):
            cat = field == "log_scales" and bit == 15
            rows.append(
                _records(
                    5,
                    precision="fp16",
                    field=field,
                    bit=bit,
                    bit_class=encoding.bit_class("fp16", bit),
                    footprint=0.5 if cat else 0.0,
                )
            )
    d = pd.concat(rows, ignore_index=True)
    w = A.cell_weights("fp16", 3)
    assert sum(w.values()) == pytest.approx(1.0)
    pc = A.catastrophe_probability(d)
    r = pc.iloc[0]
    assert r["p_c"] == pytest.approx(3 / 59 / 16) and r["coverage_pct"] == pytest.approx(100)
    assert r["ci_lo"] < r["p_c"] < r["ci_hi"]
    rel = A.reliability(d)
    bits = 1000 * 59 * 16
    assert rel["bits"] == pytest.approx(bits)
    mt = rel["mtbf"].set_index("environment")
    ground = mt.loc["ground (sea level)"]
    assert ground["mtbf_hours"] == pytest.approx(1 / (1e-12 * bits * 3 / 59 / 16))
    assert rel["dose_model"] is None and any("dose" in n for n in rel["notes"])
    # the rates are documented inputs with sources
    assert all(env["source"] for env in A.UPSET_RATES)


def test_capped_psnr_and_mse():
    d = A.prepare(_records(4, psnr=[np.inf, 40.0, np.nan, 250.0], nonfinite=[False, False, True, False]))
    assert A.capped_psnr(d).tolist() == [100.0, 40.0, 0.0, 100.0]
    mse = A.mse_from_psnr(d).tolist()
    assert mse[0] == 0.0 and mse[1] == pytest.approx(1e-4) and mse[2] == np.inf


# --------------------------------------------------------------------- distributed contamination


def test_region_grid_square_as_possible():
    assert region_grid(4) == (2, 2)
    assert region_grid(8) == (2, 4)
    assert region_grid(12) == (3, 4)
    assert region_grid(16) == (4, 4)
    assert region_grid(32) == (4, 8)
    assert region_grid(64) == (8, 8)
    assert region_grid(7) == (1, 7)
    assert region_grid(8, H=100, W=50) == (4, 2)  # portrait: more rows


def test_contaminated_regions_planted_masks():
    H = W = 64  # P = 16: 4 x 4 regions of 16 x 16
    m = np.zeros((H, W), bool)
    assert A.contaminated_regions(m, H, W, 16) == 0
    m[0, 0] = True
    assert A.contaminated_regions(m, H, W, 16) == 1
    m[15, 15] = True  # same region
    assert A.contaminated_regions(m, H, W, 16) == 1
    m[15:17, 15:17] = True  # crosses a corner: 4 regions
    assert A.contaminated_regions(m, H, W, 16) == 4
    assert A.contaminated_regions(np.ones((H, W), bool), H, W, 16) == 16
    assert A.contaminated_regions(np.ones((H, W), bool), H, W, 64) == 64
    row = np.zeros((H, W), bool)
    row[40, :] = True  # one pixel row: a full band of regions
    assert A.contaminated_regions(row, H, W, 4) == 2
    assert A.contaminated_regions(row, H, W, 64) == 8
    assert A.region_set(row, H, W, 16).tolist() == [False] * 8 + [True] * 4 + [False] * 4
    views = np.zeros((2, H, W), bool)
    views[1, 63, 63] = True
    assert A.contaminated_regions(views, H, W, 4) == 1
    with pytest.raises(ValueError):
        A.contaminated_regions(np.zeros((3, 3), bool), H, W, 4)


def test_contaminated_regions_bbox():
    H, W = 64, 128  # P = 8: 2 x 4 regions of 32 x 32
    assert A.contaminated_regions((10, 10, 20, 12), H, W, 8) == 1
    assert A.contaminated_regions((30.5, 10, 33.2, 40), H, W, 8) == 4
    assert A.contaminated_regions((0, 0, W, H), H, W, 8) == 8
    assert A.contaminated_regions((-1e9, -1e9, 1e9, 1e9), H, W, 8) == 8
    assert A.contaminated_regions((200, 0, 300, 10), H, W, 8) == 0  # off screen
    assert A.contaminated_regions((5, 5, 5, 9), H, W, 8) == 0  # empty
    assert A.contaminated_regions((0, 0, np.inf, np.nan), H, W, 8) == 8  # exploded


def test_region_iou_and_bitmasks():
    a = A.decode_regions(0b1111, 4)
    b = A.decode_regions([0, 1], 4)
    assert A.region_iou(a, b) == 0.5
    assert math.isnan(A.region_iou(np.zeros(4, bool), np.zeros(4, bool)))
    full64 = A.decode_regions(np.int64(-1), 64)  # all 64 bits, stored as int64
    assert full64.sum() == 64
    assert A.regions_to_bitmask(A.region_set((0, 0, 64, 64), 64, 64, 4)) == 0b1111
    assert A.decode_regions("0,3", 4).tolist() == [True, False, False, True]
    assert A.decode_regions(float("nan"), 4) is None
    assert A.popcount64(np.array([0, 1, 3, 2**63], dtype=np.uint64)).tolist() == [0, 1, 2, 1]


def test_contamination_table_from_region_columns():
    n = 10
    d = _records(
        n,
        field="log_scales",
        bit=31,
        bit_class="sign",
        footprint=0.5,
        regions_pred_4=0b1111,
        regions_meas_4=0b0011,
        regions_pred_16=np.int64(0xFFFF),
        regions_meas_16=np.int64(0xFFFF),
    )
    g = _records(
        n,
        defense="guard",
        field="log_scales",
        bit=31,
        bit_class="sign",
        footprint=0.0,
        regions_pred_4=0b0001,
        regions_meas_4=0,
        regions_pred_16=1,
        regions_meas_16=0,
    )
    t = A.contamination(pd.concat([d, g], ignore_index=True))
    r = t[(t["subset"] == "log-scale sign") & (t["defense"] == "none")].set_index("P")
    assert r.loc[4, "pred_fraction_pct"] == 100 and r.loc[4, "meas_fraction_pct"] == 50
    assert r.loc[4, "iou_mean"] == pytest.approx(0.5) and r.loc[16, "iou_mean"] == 1.0
    rg = t[(t["subset"] == "log-scale sign") & (t["defense"] == "guard")].set_index("P")
    assert rg.loc[4, "pred_fraction_pct"] == 25 and rg.loc[16, "meas_fraction_pct"] == 0
    assert rg.loc[4, "iou_mean"] == 0.0
    with pytest.raises(A.InsufficientData):
        A.contamination(_records(3))


# ------------------------------------------------------------------------------- prediction


def _prediction_table(rng, label):
    rows = []
    for scene in ("a", "b"):
        for field in ("means", "log_scales", "opacity"):
            for bit in range(32):
                n = 12
                v = rng.normal(0, 2, n)
                rows.append(
                    _records(
                        n,
                        scene=scene,
                        field=field,
                        bit=bit,
                        bit_class=encoding.bit_class("fp32", bit),
                        clean_value=v,
                        footprint=0.0,
                    )
                )
    d = pd.concat(rows, ignore_index=True)
    d["catastrophic"] = label(d)
    return d


def test_prediction_perfect_and_random():
    rng = np.random.default_rng(0)
    d = _prediction_table(rng, lambda d: (d["field"] == "log_scales") & (d["bit"] >= 29))
    res = A.prediction(d, n_repeats=2)
    s = res["summary"].set_index("model")
    assert s.loc["field+bit+class+value", "auc_holdout"] > 0.99
    assert s.loc["field+bit", "auc_holdout"] > 0.99
    assert s.loc["field+bit", "loso_auc_min"] > 0.99
    assert res["top_feature"] in ("bit", "field", "bit_class")
    r = _prediction_table(rng, lambda d: pd.Series(rng.random(len(d)) < 0.2, index=d.index))
    res_r = A.prediction(r, n_repeats=2)
    assert res_r["summary"]["auc_holdout"].iloc[1] == pytest.approx(0.5, abs=0.12)
    with pytest.raises(A.InsufficientData):
        A.prediction(_records(50))


def test_size_scaling_weights_stratified_records():
    """Stratified size-campaign records are weighted by the bits each stands for: a rare,
    heavily damaging cell must not dominate the mean in proportion to its sample count."""
    import pandas as pd

    from seuwgpu.analysis import studies as A

    rows = []
    for n in (1000, 4000):
        for i in range(20):
            # cell A: 10 samples standing for 9 bits each, error 1e-6; cell B: 10 samples standing
            # for 1 bit each, error 1e-2
            heavy = i < 10
            mse = 1e-6 if heavy else 1e-2
            rows.append(
                dict(
                    scene="s",
                    n_primitives=n,
                    precision="fp32",
                    field="means",
                    primitive=0,
                    component=0,
                    bit=0,
                    bit_class="mantissa",
                    clean_value=0.0,
                    corrupted_value=0.0,
                    defense="none",
                    footprint=0.0,
                    footprint_max=0.0,
                    peak_error=0.0,
                    psnr=10 * np.log10(1 / mse),
                    ssim=1.0,
                    nonfinite=False,
                    catastrophic=False,
                    clamps=0,
                    k=1,
                    seed=i,
                    injection_id=i + n,
                    campaign="size",
                    repeat=0,
                    weight=9.0 if heavy else 1.0,
                )
            )
    res = A.size_scaling(pd.DataFrame(rows))
    t = res["table"]
    want = (9 * 1e-6 + 1 * 1e-2) / 10
    assert np.allclose(t["mean_mse"], want, rtol=1e-6)
    assert np.allclose(t["median_mse"], 1e-6, rtol=1e-6)
