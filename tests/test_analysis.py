"""Statistics and analyses on synthetic record tables with known answers."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from seuwgpu.analysis import (
    claims,
    contamination,
    criticality,
    dose,
    estimate,
    guard,
    mitigation,
    prediction,
    records,
    reliability,
    scaling,
    stats,
    theory,
)
from seuwgpu.campaign import plan
from seuwgpu.model import encoding
from seuwgpu.render.regions import region_edges, region_grid

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
    assert fit.exponent_lo == pytest.approx(-1.5, abs=1e-9) and fit.exponent_hi == pytest.approx(-1.5, abs=1e-9)
    noisy = stats.loglog_fit(x, y * np.array([1.3, 0.8, 1.2, 0.9, 1.1]))
    assert 0.9 < noisy.r2 < 1.0
    assert noisy.exponent_lo < noisy.exponent < noisy.exponent_hi and noisy.n == 5
    # the interval by hand: t(0.975, 3) * sqrt(SSR / 3 / Sxx)
    lx, ly = np.log10(x), np.log10(y * np.array([1.3, 0.8, 1.2, 0.9, 1.1]))
    b, a = np.polyfit(lx, ly, 1)
    se = np.sqrt(np.sum((ly - (a + b * lx)) ** 2) / 3 / np.sum((lx - lx.mean()) ** 2))
    assert noisy.exponent_hi - noisy.exponent == pytest.approx(3.182446305284263 * se)
    two = stats.loglog_fit([1e3, 1e4], [1.0, 0.1])  # a line through two points: no interval
    assert math.isnan(two.exponent_lo) and two.n == 2
    with pytest.raises(ValueError):
        stats.loglog_fit([1, 2], [0, 0])


def test_auc_perfect_and_random():
    rng = np.random.default_rng(1)
    y = rng.random(20_000) < 0.3
    assert stats.auc(y, y.astype(float)) == 1.0
    assert stats.auc(y, 1.0 - y) == 0.0
    assert stats.auc(y, rng.random(y.size)) == pytest.approx(0.5, abs=0.02)
    assert math.isnan(stats.auc(np.ones(5, bool), np.arange(5)))


def test_auc_interval_matches_hanley_mcneil_and_keeps_both_classes():
    """Unweighted, the bootstrap interval's half-width is Hanley and McNeil's (Radiology 1982)
    standard error times 1.96. Each class is resampled apart, so 5 positives among 400 records
    still give an interval from every resample."""
    rng = np.random.default_rng(3)
    y = np.r_[np.ones(300, bool), np.zeros(900, bool)]
    score = np.where(y, rng.normal(1.0, 1, y.size), rng.normal(0.0, 1, y.size))
    a = stats.auc(y, score)
    q1, q2 = a / (2 - a), 2 * a * a / (1 + a)
    npos, nneg = 300, 900
    se = np.sqrt((a * (1 - a) + (npos - 1) * (q1 - a * a) + (nneg - 1) * (q2 - a * a)) / (npos * nneg))
    lo, hi = stats.auc_interval(y, score, n_boot=400)
    assert (hi - lo) / 2 == pytest.approx(1.96 * se, rel=0.2)
    assert lo < a < hi
    few = np.r_[np.ones(5, bool), np.zeros(395, bool)]
    lo5, hi5 = stats.auc_interval(few, rng.random(few.size))
    assert 0 <= lo5 < hi5 <= 1


def test_auc_interval_undefined_when_weights_leave_too_few_effective_events():
    """Eighteen positives, one of them carrying most of the weight and ranked low: the weighted
    AUC is that record's rank, and a bootstrap of it is no interval (it read [0.52, 1.0] around
    0.61 before): NaN, and prediction says why."""
    rng = np.random.default_rng(4)
    y = np.r_[np.ones(18, bool), np.zeros(443, bool)]
    score = np.where(y, 1.0 + rng.random(y.size), rng.random(y.size))
    score[0] = 0.4  # the heavy positive, below 60% of the negatives
    w = np.ones(y.size)
    w[1:18] = 0.01
    assert stats.effective_size(w[y]) == pytest.approx((1 + 17 * 0.01) ** 2 / (1 + 17 * 1e-4))
    assert stats.auc(y, score, w) < 0.7
    assert all(math.isnan(v) for v in stats.auc_interval(y, score, w))
    assert all(np.isfinite(stats.auc_interval(y, score)))  # the same records unweighted: defined


def test_stratified_interval_design_effect_and_zero_counts():
    # two strata, weights 0.9 / 0.1, 0 of 100 and 50 of 100: the variance uses the add-half
    # rates (0.5 / 101 and 50.5 / 101), the rate the raw ones
    p, lo, hi, neff = estimate.stratified_interval([0.0, 0.5], [100, 100], [0.9, 0.1])
    s = np.array([0.5, 50.5]) / 101
    W = np.array([0.9, 0.1])
    ps = float(W @ s)
    assert p == pytest.approx(0.05)
    assert neff == pytest.approx(min(ps * (1 - ps) / float((W * W * s * (1 - s) / 100).sum()), 200))
    assert (lo, hi) == pytest.approx(stats.wilson_interval(0.05 * neff, neff))
    # no event anywhere: equal strata give n_eff = n (the add-half rates are equal), so the exact
    # Wilson edge of 0 in 200: lower bound 0, upper bound > 0
    p0, lo0, hi0, n0 = estimate.stratified_interval([0.0, 0.0], [100, 100], [0.5, 0.5])
    assert p0 == 0 and lo0 == 0 and n0 == pytest.approx(200)
    assert hi0 == pytest.approx(stats.wilson_interval(0, 200)[1])
    # one stratum: the plain Wilson interval of (k, n)
    assert estimate.stratified_interval([0.3], [10], [1.0])[1:3] == pytest.approx(stats.wilson_interval(3, 10))


def test_stratified_interval_continuous_in_sparse_strata():
    """One event in a light stratum must not shrink the interval: with the raw rates it cut the
    upper bound from 0.27 to 0.0004 (n_eff jumped to the record count). And half the weight on
    one record leaves the rate anywhere in [0.5, 1], so the interval must stay wide."""
    hi0 = estimate.stratified_interval([0, 0], [10, 10_000], [0.99, 0.01])[2]
    hi1 = estimate.stratified_interval([0, 1e-4], [10, 10_000], [0.99, 0.01])[2]
    assert hi0 > 0.2 and hi1 == pytest.approx(hi0, rel=0.02)
    _, lo, hi, _ = estimate.stratified_interval([1, 0.5], [1, 100], [0.5, 0.5])
    assert lo < 0.5 and hi > 0.9  # the raw-rate variance gave [0.657, 0.824]


def test_stratified_interval_covers_at_campaign_shape():
    """Coverage by simulation at a campaign's shape: 192 (field, bit) strata of 8 records with
    fp32-like weights, a 1% rate in half of them (mostly 0 or 1 event a stratum). 95.1% of these
    intervals cover the truth; the raw-rate variance covered 82.7% (same seed)."""
    rng = np.random.default_rng(11)
    H, n = 192, 8
    W = rng.choice([256.0, 768.0, 3840.0, 85.3], H)
    truth_h = np.where(rng.random(H) < 0.5, 0.01, 0.0)
    truth = float((W / W.sum()) @ truth_h)
    hits = 0
    reps = 1500
    for _ in range(reps):
        k = rng.binomial(n, truth_h)
        _, lo, hi, _ = estimate.stratified_interval(k / n, np.full(H, n), W)
        hits += lo <= truth <= hi
    assert hits / reps > 0.93


def test_weighted_rate_differs_from_pooled_counts():
    # cell A: 1000 stored bits, 0 of 10 catastrophic; cell B: 10 bits, 10 of 10: the unweighted
    # pool says 50%, a uniform upset is catastrophic with probability 10 / 1010
    d = pd.DataFrame(
        {
            "field": ["a"] * 10 + ["b"] * 10,
            "bit": 0,
            "weight": [100.0] * 10 + [1.0] * 10,
            "catastrophic": [False] * 10 + [True] * 10,
        }
    )
    r = estimate.one_rate(d)
    assert r["rate"] == pytest.approx(10 / 1010) and r["n"] == 20 and r["events"] == 10
    assert r["ci_lo"] < r["rate"] < r["ci_hi"]


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
    crit = criticality.criticality(pd.concat([a, b], ignore_index=True)).set_index("field")
    ls = crit.loc["log_scales"]
    assert ls["n"] == 100
    # equal weights: the weighted quantile is the inverted-CDF one (no interpolation)
    assert ls["median_pct"] == pytest.approx(np.quantile(fp * 100, 0.5, method="inverted_cdf"))
    assert ls["p95_pct"] == pytest.approx(np.quantile(fp * 100, 0.95, method="inverted_cdf"))
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
    crit = criticality.criticality(pd.concat([a, b, c, d], ignore_index=True))
    assert crit.attrs["precision"] == "fp32"
    assert crit["n"].tolist() == [10] and crit["catastrophic"].tolist() == [10]
    with pytest.raises(records.InsufficientData) as e:
        criticality.criticality(d)
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
    t = criticality.field_bit_table(pd.concat(rows, ignore_index=True))
    assert len(t) == 16 and (t["n"] == 3).all()
    assert t.loc[t["bit"] == 15, "bit_class"].item() == "sign"
    m = criticality.heatmap_matrix(t, "fp16")
    assert m.shape == (1, 16) and m.loc["opacity", 5] == pytest.approx(0.5)


def test_theory_check_unit_slope_on_exact_power_law():
    rows = []
    for b in range(23):
        peak = min(0.25 * 2.0 ** (b - 23), 0.5)  # doubles per bit; bit 22 leaves the window
        rows.append(_records(4, field="log_scales", bit=b, peak_error=peak))
    res = theory.theory_check(pd.concat(rows, ignore_index=True))
    assert res["slope"] == pytest.approx(1.0, abs=1e-9)
    assert res["r2"] == pytest.approx(1.0, abs=1e-9)
    # window (1e-5, 0.1]: 0.25 * 2^(b-23) > 1e-5 from b = 9, <= 0.1 up to b = 21
    assert res["fit_bits"] == (9, 21) and res["predicted_slope"] == 1.0


def test_common_loglog_fit_one_exponent_across_scenes():
    x = np.array([1e3, 3e3, 1e4, 3e4])
    # two scenes at different sizes, the same exponent -1.5, intercepts 10^4 apart: the common
    # fit recovers -1.5 exactly, where a single pooled line would not
    g = ["a"] * 4 + ["b"] * 4
    xs, ys = np.r_[x, 100 * x], np.r_[3.0 * x**-1.5, 3e4 * (100 * x) ** -1.5]
    f = stats.common_loglog_fit(g, xs, ys)
    assert f.exponent == pytest.approx(-1.5, abs=1e-12) and f.n == 8 and f.r2 == pytest.approx(1.0)
    assert stats.loglog_fit(xs, ys).exponent != pytest.approx(-1.5, abs=0.1)
    # one scene: the ordinary fit, interval included
    noise = np.array([1.3, 0.8, 1.2, 0.9])
    one = stats.common_loglog_fit(["a"] * 4, x, 3.0 * x**-1.5 * noise)
    ref = stats.loglog_fit(x, 3.0 * x**-1.5 * noise)
    assert (one.exponent, one.exponent_lo, one.exponent_hi) == pytest.approx(
        (ref.exponent, ref.exponent_lo, ref.exponent_hi)
    )
    # by hand for two noisy scenes: slope of the within-scene centred logs, t on 8 - 2 - 1 dof
    ys = ys * np.r_[noise, noise[::-1]]
    f = stats.common_loglog_fit(g, xs, ys)
    lx, ly = np.log10(xs), np.log10(ys)
    xc = np.r_[lx[:4] - lx[:4].mean(), lx[4:] - lx[4:].mean()]
    yc = np.r_[ly[:4] - ly[:4].mean(), ly[4:] - ly[4:].mean()]
    b = (xc @ yc) / (xc @ xc)
    se = np.sqrt(np.sum((yc - b * xc) ** 2) / 5 / (xc @ xc))
    assert f.exponent == pytest.approx(b) and f.exponent_hi - b == pytest.approx(2.570581835636314 * se)
    # zeros have no logarithm; a scene left with one point drops out
    f0 = stats.common_loglog_fit(g + ["c"] * 2, np.r_[xs, 1e3, 1e4], np.r_[ys, 0.0, 1.0])
    assert f0.exponent == pytest.approx(f.exponent) and f0.n == 8
    with pytest.raises(ValueError):
        stats.common_loglog_fit(["a", "a"], [1, 2], [0, 0])


def test_claims_guard_share_is_fp32_not_pooled():
    """The claim sits beside fp32 p_c claims: it must take the fp32 row of the paired table, not
    the pool of every precision (which the guard section reports, labelled as such)."""
    n = 20
    kw = dict(field="log_scales", bit=31, bit_class="sign")
    parts = []
    for prec, fixed in (("fp32", 8), ("fp16", 2)):  # fp32: 8 of 10 neutralised, fp16: 2 of 10
        fp_none = np.where(np.arange(n) < 10, 0.5, 0.0)
        fp_guard = np.where(np.arange(n) < 10 - fixed, 0.5, 0.0)
        parts += [
            _records(n, precision=prec, footprint=fp_none, psnr=np.where(fp_none > 0, 10.0, np.inf), **kw),
            _records(n, precision=prec, defense="guard", footprint=fp_guard, psnr=10.0, **kw),
        ]
    df = pd.concat(parts, ignore_index=True)
    res = guard.guard_analysis(df)
    assert res["share_precision"] == "all" and res["share_pct"] == pytest.approx(50.0)
    t = claims.claims_table(df, {"guard": res}).set_index("claim")
    r = t.loc[claims.PAPER["guard_share_paired"][0]]  # the paired share: this project's estimate
    assert r["measured"] == pytest.approx(80.0)
    assert r["ci_lo"] == pytest.approx(100 * stats.wilson_interval(8, 10)[0])
    # 20 sign flips: a bootstrap cannot bound a 99th percentile above their maximum, so none
    r = t.loc["log-scale sign flip: 99th-percentile footprint, fp32"]
    assert r["measured"] == pytest.approx(50.0) and math.isnan(r["ci_hi"]) and r["verdict"] == "not measured"
    assert "< 100" in r["basis"]


def test_guard_share_neutralised_and_sign_psnr():
    n = 20
    fp_none = np.where(np.arange(n) < 10, 0.5, 0.0)  # 10 catastrophic sites
    fp_guard = np.where(np.arange(n) < 2, 0.5, 0.001)  # the guard fixes 8 of them
    kw = dict(field="log_scales", bit=31, bit_class="sign")
    a = _records(n, footprint=fp_none, psnr=np.where(fp_none > 0, 10.0, np.inf), **kw)
    b = _records(n, defense="guard", footprint=fp_guard, psnr=np.where(fp_guard > 0.1, 10.0, 60.0), **kw)
    res = guard.guard_analysis(pd.concat([a, b], ignore_index=True))
    p = res["paired"].iloc[0]
    assert p["catastrophic_none"] == 10 and p["neutralised"] == 8
    assert p["share_neutralised_pct"] == pytest.approx(80.0)
    lo, hi = stats.wilson_interval(8, 10)
    assert p["share_ci_lo_pct"] == pytest.approx(100 * lo)
    assert res["residual_catastrophic"] == 2
    assert res["worst_guarded_footprint_pct"] == pytest.approx(50.0)
    sp = res["sign_psnr"].set_index("defense")
    # none: 10 x 10 dB (mse 0.1) + 10 identical (mse 0): PSNR of the mean MSE = 10 log10(1 / 0.05)
    assert sp.loc["none", "psnr_mean_mse_db"] == pytest.approx(10 * math.log10(20))
    assert sp.loc["guard", "psnr_mean_mse_db"] == pytest.approx(10 * math.log10(20 / (2 * 0.1 + 18 * 1e-6)))
    assert sp.loc["none", "psnr_median_db"] == 10.0 and sp.loc["none", "nonfinite_pct"] == 0
    with pytest.raises(records.InsufficientData):
        guard.guard_analysis(a)


def test_mitigation_shared_grid_and_memory():
    a = _records(10, footprint=np.r_[np.full(5, 0.5), np.zeros(5)])
    b = _records(10, defense="guard", footprint=0.0)
    c = _records(12, defense="dup", footprint=0.0)  # two extra sites: not on the grid
    t = mitigation.mitigation_table(pd.concat([a, b, c], ignore_index=True)).set_index("defense")
    assert t.attrs["paired"] is True
    assert t.loc["dup", "n"] == 10 and t.loc["none", "cat_rate_pct"] == pytest.approx(50)
    assert t.loc["dup", "memory_overhead_pct"] == pytest.approx(200)
    assert t.loc["guard", "memory_overhead_pct"] == pytest.approx(100 * 2 * 14 / (1000 * 59))
    assert mitigation.memory_overhead("ecc", "fp32")[0] == pytest.approx(5 / 32)
    assert mitigation.memory_overhead("ecc", "fp16")[0] == pytest.approx(5 / 16)
    assert mitigation.memory_overhead("ecc", "bf16")[0] == pytest.approx(5 / 16)
    assert mitigation.memory_overhead("selective", "fp32", 100)[0] == pytest.approx(8 / (100 * 59))
    man = [{"memory_overhead": {"ecc": 0.3}}]
    assert mitigation.memory_overhead("ecc", "fp32", manifests=man) == (0.3, "from the run manifest")


def test_crossing_k_interpolates_in_log_k():
    k, c, lo, hi = dose.crossing_k([1, 10, 100], [50, 40, 20], 30)
    assert c == "" and k == pytest.approx(10**1.5) and (lo, hi) == (10, 100)
    assert dose.crossing_k([1, 10], [50, 40], 30)[:2] == (10.0, ">=")
    assert dose.crossing_k([2, 10], [20, 10], 30)[:2] == (2.0, "<=")
    # the median frame at k = 100 is non-finite: bracketed, not interpolated to a made-up value
    assert dose.crossing_k([1, 10, 100], [50, 40, -np.inf], 30) == (100.0, "<=", 10.0, 100.0)


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
    cur = dose.dose_curves(d)
    assert len(cur) == 8 and cur["psnr_median_db"].iloc[0] == pytest.approx(60)
    assert (cur["nonfinite_pct"] == 0).all()
    b = dose.redundancy_budget(d).set_index("defense")
    assert b.loc["none", "k_budget"] == pytest.approx(1000) and b.loc["none", "censored"] == ""
    assert (b.loc["none", "k_lo"], b.loc["none", "k_hi"]) == (100, 1000)
    assert b.loc["guard", "censored"] == ">="
    # the dose model fitted per model: p near the planted 2%, a good fit; guard: no event, p = 0
    fits = dose.dose_fits(cur).set_index("defense")
    assert fits.loc["none", "p_pct"] == pytest.approx(2.0, rel=0.15)
    assert fits.loc["none", "p_lo_pct"] < 2.0 < fits.loc["none", "p_hi_pct"]
    assert fits.loc["none", "fit_pvalue"] > 0.05 and fits.loc["none", "points_within_ci"] == 1.0
    assert fits.loc["guard", "p_pct"] == 0 and fits.loc["guard", "p_lo_pct"] == 0 and fits.loc["guard", "p_hi_pct"] > 0
    with pytest.raises(records.InsufficientData) as e:
        dose.dose_curves(_records(5))
    assert "dose campaign" in e.value.remedy


def test_size_scaling_recovers_exponent():
    rows = []
    for n in (1000, 4000, 16000, 64000):
        mse = 1e-4 * (n / 1000) ** -0.5
        rows.append(_records(7, campaign="size", n_primitives=n, psnr=-10 * math.log10(mse)))
    res = scaling.size_scaling(pd.concat(rows, ignore_index=True))
    f = res["fits"].set_index("metric")
    assert f.loc["median_mse", "alpha"] == pytest.approx(0.5, abs=1e-9)
    assert f.loc["mean_mse", "r2"] == pytest.approx(1.0, abs=1e-9)
    assert f.loc["mean_mse", "n_fitted"] == 4 and f.loc["mean_mse", "n_zero"] == 0
    # what the upsets sampled, for the section's caption: fields in the model's order (as every
    # table lists them), not alphabetical
    two = [r.assign(field=np.where(r.index % 2, "log_scales", "means")) for r in rows]
    sampled = scaling.size_scaling(pd.concat(two, ignore_index=True))
    assert sampled["fields"] == ["means", "log_scales"]
    d = pd.concat(rows, ignore_index=True)
    assert res["fields"] == ["means"] and res["bits"] == sorted(d["bit"].unique())
    # two sizes whose median error is 0 (identical frames): shown, counted, and no exponent made
    # up from the two points left
    zeros = [r.assign(psnr=np.inf) if i < 2 else r for i, r in enumerate(rows)]
    fz = scaling.size_scaling(pd.concat(zeros, ignore_index=True))["fits"].set_index("metric")
    assert fz.loc["median_mse", "n_zero"] == 2 and fz.loc["median_mse", "n_fitted"] == 2
    assert math.isnan(fz.loc["median_mse", "alpha"])
    with pytest.raises(records.InsufficientData) as e:
        scaling.size_scaling(rows[0])
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
    pc = reliability.catastrophe_probability(d)
    r = pc.iloc[0]
    assert r["p_c"] == pytest.approx(3 / 59 / 16) and r["coverage_pct"] == pytest.approx(100)
    assert r["ci_lo"] < r["p_c"] < r["ci_hi"]
    rel = reliability.reliability(d)
    bits = 1000 * 59 * 16
    assert rel["bits"] == pytest.approx(bits)
    mt = rel["mtbf"].set_index("environment")
    ground = mt.loc["ground (sea level)"]
    # upsets accumulate until the daily scrub: MTBF = T / (1 - exp(-rate * bits * p * T))
    x = 1e-12 * bits * 3 / 59 / 16 * 24.0
    assert ground["mtbf_hours"] == pytest.approx(24.0 / (1 - math.exp(-x)))
    assert reliability.mtbf(1e-12, bits, 3 / 59 / 16, math.inf) == pytest.approx(1 / (1e-12 * bits * 3 / 59 / 16))
    assert reliability.mtbf(1e-3, bits, 0.5, 24.0) == pytest.approx(24.0)  # every interval is hit
    # an unmeasured p stays unmeasured (it used to read as "never": inf and 0%)
    assert math.isnan(reliability.mtbf(1e-12, bits, float("nan"), 24.0))
    assert math.isnan(reliability.catastrophic_frame_share(1e-12, bits, float("nan"), 24.0))
    # the rates are documented inputs with sources
    assert all(env["source"] for env in reliability.UPSET_RATES)


def test_undefined_psnr_stays_undefined():
    d = records.prepare(_records(4, psnr=[np.inf, 40.0, 12.0, 20.0], nonfinite=[False, False, True, False]))
    assert np.isnan(d["psnr"].iloc[2]) and np.isnan(d["ssim"].iloc[2])  # not 0 dB, not 12 dB
    q = estimate.quality(d).iloc[0]
    assert q["n"] == 4 and q["n_finite"] == 3 and q["nonfinite_pct"] == pytest.approx(25)
    assert q["psnr_median_db"] == 40.0  # over finite frames: inf, 40, 20
    mse = np.mean([0.0, 1e-4, 1e-2])
    assert q["psnr_mean_mse_db"] == pytest.approx(10 * math.log10(1 / mse))
    assert estimate.mse_of_psnr([np.inf, 40.0, np.nan])[0] == 0.0


def test_outcome_classes():
    d = records.prepare(
        _records(
            5,
            peak_error=[0.0, 1e-3, 0.5, 0.5, 0.0],
            footprint=[0.0, 0.0, 0.005, 0.02, 0.0],
            nonfinite=[False, False, False, False, True],
        )
    )
    assert d["outcome"].tolist() == ["masked", "tolerable", "sdc", "catastrophic", "catastrophic"]
    assert d["catastrophic"].tolist() == [False, False, False, True, True]
    strict = records.prepare(
        _records(2, peak_error=[1e-3, 0.5], footprint=[0.0, 0.005]),
        {"pixel_threshold": 1e-4, "footprint_threshold": 0.001},
    )
    assert strict["outcome"].tolist() == ["sdc", "catastrophic"]


# --------------------------------------------------------------------- distributed contamination


def test_region_grid_tile_aligned_and_square_in_tiles():
    assert region_grid(4, 64, 64) == (2, 2)
    assert region_grid(8, 128, 128) == (2, 4)  # a tie goes to more columns
    assert region_grid(16, 128, 128) == (4, 4)
    assert region_grid(64, 128, 128) == (8, 8)
    assert region_grid(6, 128, 128) == (2, 3)  # the old pixel grid was 3 x 2 here, the ranks' 2 x 3
    assert region_grid(8, 256, 128) == (4, 2)  # portrait: more rows
    assert region_grid(3, 40, 96) == (1, 3)
    ey, ex = region_edges(4, 64, 80)  # 80 px = 5 tiles: edges on tile borders, not at 40 px
    assert ex.tolist() == [0, 32, 80] and ey.tolist() == [0, 32, 64]
    ey, ex = region_edges(4, 38, 50)  # partial last tiles: clipped to the frame
    assert ex.tolist() == [0, 32, 50] and ey.tolist() == [0, 32, 38]
    with pytest.raises(ValueError, match="do not fit"):
        region_grid(64, 64, 64)  # 4 x 4 tiles hold at most 16 regions


def test_contaminated_regions_planted_masks():
    H = W = 64  # P = 16: 4 x 4 regions of 16 x 16
    m = np.zeros((H, W), bool)
    assert contamination.contaminated_regions(m, H, W, 16) == 0
    m[0, 0] = True
    assert contamination.contaminated_regions(m, H, W, 16) == 1
    m[15, 15] = True  # same region
    assert contamination.contaminated_regions(m, H, W, 16) == 1
    m[15:17, 15:17] = True  # crosses a corner: 4 regions
    assert contamination.contaminated_regions(m, H, W, 16) == 4
    assert contamination.contaminated_regions(np.ones((H, W), bool), H, W, 16) == 16
    assert contamination.contaminated_regions(np.ones((128, 128), bool), 128, 128, 64) == 64
    row = np.zeros((H, W), bool)
    row[40, :] = True  # one pixel row: a full band of regions
    assert contamination.contaminated_regions(row, H, W, 4) == 2
    assert contamination.contaminated_regions(row, H, W, 16) == 4
    assert contamination.region_set(row, H, W, 16).tolist() == [False] * 8 + [True] * 4 + [False] * 4
    views = np.zeros((2, H, W), bool)
    views[1, 63, 63] = True
    assert contamination.contaminated_regions(views, H, W, 4) == 1
    with pytest.raises(ValueError):
        contamination.contaminated_regions(np.zeros((3, 3), bool), H, W, 4)


def test_contaminated_regions_bbox():
    H, W = 64, 128  # P = 8: 2 x 4 regions of 32 x 32
    assert contamination.contaminated_regions((10, 10, 20, 12), H, W, 8) == 1
    assert contamination.contaminated_regions((30.5, 10, 33.2, 40), H, W, 8) == 4
    assert contamination.contaminated_regions((0, 0, W, H), H, W, 8) == 8
    assert contamination.contaminated_regions((-1e9, -1e9, 1e9, 1e9), H, W, 8) == 8
    assert contamination.contaminated_regions((200, 0, 300, 10), H, W, 8) == 0  # off screen
    assert contamination.contaminated_regions((5, 5, 5, 9), H, W, 8) == 0  # empty
    assert contamination.contaminated_regions((0, 0, np.inf, np.nan), H, W, 8) == 8  # exploded


def test_region_iou_and_bitmasks():
    a = contamination.decode_regions(0b1111, 4)
    b = contamination.decode_regions([0, 1], 4)
    assert contamination.region_iou(a, b) == 0.5
    assert math.isnan(contamination.region_iou(np.zeros(4, bool), np.zeros(4, bool)))
    full64 = contamination.decode_regions(np.int64(-1), 64)  # all 64 bits, stored as int64
    assert full64.sum() == 64
    assert contamination.regions_to_bitmask(contamination.region_set((0, 0, 64, 64), 64, 64, 4)) == 0b1111
    assert contamination.decode_regions("0,3", 4).tolist() == [True, False, False, True]
    assert contamination.decode_regions(float("nan"), 4) is None
    assert contamination.popcount64(np.array([0, 1, 3, 2**63], dtype=np.uint64)).tolist() == [0, 1, 2, 1]


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
    t = contamination.contamination(pd.concat([d, g], ignore_index=True))
    r = t[(t["subset"] == "log-scale sign") & (t["defense"] == "none")].set_index("P")
    assert r.loc[4, "pred_fraction_pct"] == 100 and r.loc[4, "meas_fraction_pct"] == 50
    assert r.loc[4, "iou_mean"] == pytest.approx(0.5) and r.loc[16, "iou_mean"] == 1.0
    rg = t[(t["subset"] == "log-scale sign") & (t["defense"] == "guard")].set_index("P")
    assert rg.loc[4, "pred_fraction_pct"] == 25 and rg.loc[16, "meas_fraction_pct"] == 0
    assert rg.loc[4, "iou_mean"] == 0.0
    with pytest.raises(records.InsufficientData):
        contamination.contamination(_records(3))


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
    d["footprint"] = np.where(label(d), 0.5, 0.0)  # the outcome class follows the footprint
    return d


def test_prediction_perfect_and_random():
    rng = np.random.default_rng(0)
    d = _prediction_table(rng, lambda d: (d["field"] == "log_scales") & (d["bit"] >= 29))
    res = prediction.prediction(d, n_repeats=2)
    s = res["summary"].set_index("model")
    clf, look, const = s.index
    assert s.loc[clf, "auc_holdout"] > 0.99 and s.loc[look, "auc_holdout"] > 0.99
    assert s.loc[look, "loso_auc_min"] > 0.99 and s.loc[look, "loso_scenes"] >= 2
    assert s.loc[const, "auc_holdout"] == 0.5  # a constant ranks nothing
    assert s.loc[look, "brier"] < s.loc[const, "brier"]
    assert s.loc[clf, "auc_lo"] <= s.loc[clf, "auc_holdout"] <= s.loc[clf, "auc_hi"]
    assert res["lookup_as_good"] is True and any("lookup" in n for n in res["notes"])
    assert res["top_feature"] in ("bit", "field", "bit_class")
    r = _prediction_table(rng, lambda d: pd.Series(rng.random(len(d)) < 0.2, index=d.index))
    res_r = prediction.prediction(r, n_repeats=2)
    assert res_r["summary"]["auc_holdout"].iloc[1] == pytest.approx(0.5, abs=0.12)
    # too few events: NaN and a note, not a failure (a tiny run's report must still build)
    tiny = prediction.prediction(_records(50))
    assert tiny["summary"]["auc_holdout"].isna().all() and "too few" in tiny["notes"][0]


def test_size_scaling_weights_stratified_records():
    """Stratified size-campaign records are weighted by the bits each stands for: a rare,
    heavily damaging cell must not dominate the mean in proportion to its sample count."""
    import pandas as pd

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
    res = scaling.size_scaling(pd.DataFrame(rows))
    t = res["table"]
    want = (9 * 1e-6 + 1 * 1e-2) / 10
    assert np.allclose(t["mean_mse"], want, rtol=1e-6)
    assert np.allclose(t["median_mse"], 1e-6, rtol=1e-6)


def test_durations_keep_undefined_apart_from_unbounded():
    """An MTBF with no measured rate (NaN) reads n/a, an unbounded one inf; finite ones in units."""
    from seuwgpu.analysis.reliability import format_duration

    assert format_duration(float("nan")) == "n/a" and format_duration(None) == "n/a"
    assert format_duration(float("inf")) == "inf"
    assert format_duration(1.0) == "1 h" and format_duration(0.5 / 60) == "30 s" and format_duration(72) == "3 d"


def test_prediction_importance_is_weighted_like_its_aucs():
    """Opacity sites, where the stored value's sign decides the outcome, carry almost no weight;
    means sites, where the bit does, carry the rest. Permuting the sign then costs the weighted
    AUC nothing: its importance is ~0 (unweighted it was the top feature), the bit's is not."""
    rng = np.random.default_rng(5)
    parts = []
    for field, weight in (("opacity", 1e-6), ("means", 1.0)):
        for bit in range(32):
            v = rng.choice([-1.0, 1.0], 16) * rng.uniform(0.5, 2, 16)
            cls = encoding.bit_class("fp32", bit)
            parts.append(_records(16, field=field, bit=bit, bit_class=cls, clean_value=v, weight=weight))
    d = pd.concat(parts, ignore_index=True)
    bad = np.where(d["field"] == "opacity", d["clean_value"] < 0, d["bit"] >= 28)
    d["catastrophic"] = bad
    d["footprint"] = np.where(bad, 0.5, 0.0)
    res = prediction.prediction(d, n_repeats=3)
    imp = res["importance"].set_index("feature")["importance_mean"]
    assert abs(imp["sign"]) < 0.01
    assert imp["bit"] > 0.05
    s = res["summary"]
    assert (s["test_positives_effective"] > 5).all() and not any("effective" in n for n in res["notes"])


def test_the_bootstraps_auc_of_reweighted_records_is_sklearns():
    """auc_interval scores a resample as the records reweighted by their draw counts, from tie
    groups sorted once: that AUC is sklearn's roc_auc_score of the resampled records, ties and
    weights included."""
    from sklearn.metrics import roc_auc_score

    rng = np.random.default_rng(6)
    y = rng.random(3000) < 0.1
    score = np.round(rng.normal(y * 0.8, 1), 1)  # many ties
    w = rng.choice([0.2, 1.0, 7.0], y.size)
    group, n = stats._tie_groups(score)
    for _ in range(5):
        i = rng.integers(0, y.size, y.size)
        pos_w = np.bincount(group[i], w[i] * y[i], n)
        neg_w = np.bincount(group[i], w[i] * ~y[i], n)
        got = stats._auc_of_group_weights(pos_w, neg_w)
        assert got == pytest.approx(roc_auc_score(y[i], score[i], sample_weight=w[i]), rel=1e-12)


def test_budget_figure_points_censored_bounds_the_right_way():
    """plot_budget drew both kinds of censored budget as '^': a '<=' bound (the first k already
    at the threshold: the budget is at most that k) read as 'at least'. Now '>=' is '^', '<=' 'v'."""
    b = pd.DataFrame(
        {
            "scene": ["s"] * 3,
            "n_primitives": [1000, 2000, 4000],
            "precision": ["fp32"] * 3,
            "defense": ["none"] * 3,
            "k_budget": [10.0, 40.0, 1000.0],
            "censored": ["<=", "", ">="],
            "k_lo": [0.0, 20.0, 1000.0],
            "k_hi": [10.0, 80.0, np.inf],
        }
    )
    ax = dose.plot_budget(b).axes[0]
    drawn = {}
    for line in ax.get_lines():
        for x in line.get_xdata():
            drawn.setdefault(int(x), set()).add(line.get_marker())
    assert "v" in drawn[1000] and "^" not in drawn[1000]
    assert "^" in drawn[4000] and "v" not in drawn[4000]
    assert "o" in drawn[2000]


def test_contamination_table_says_what_its_columns_are():
    """The contamination table's caption was 'Per subset, precision, defense and P.': nothing said
    that the prediction is the whole primitive's rectangle (ECC and duplication rows read ~66%
    predicted against 0% measured in docs/study/cpu), nor over which records the IoU is averaged."""
    from seuwgpu.report.sections.contamination import contamination_section

    d = _records(4, field="log_scales", bit=31, bit_class="sign", footprint=0.5, regions_pred_4=15, regions_meas_4=3)
    sec = contamination_section(d, [], {"results": {}, "skipped": []})
    cap = sec.tables[0].caption
    assert "n_iou" in cap and "weighted by stored bits" in cap and "without interval" in cap
    assert "clean footprint" in cap
