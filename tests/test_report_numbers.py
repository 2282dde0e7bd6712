"""An independent audit of the report: every headline number of summary.json and the main tables,
recomputed here from the Parquet records with plain pandas and the textbook formulas (not through
seuwgpu.analysis), must match what the report wrote."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pandas as pd
import pytest
from conftest import undrawn_report_figures

from seuwgpu.report.build import build_report

Z = 1.959963984540054  # two-sided 95% normal quantile
COMPS = {"means": 3, "log_scales": 3, "quats": 4, "opacity": 1, "sh_dc": 3, "sh_rest": 45}
SCENES = {"big": 4000, "small": 500}  # different sizes: pooled rates must weight by stored bits
DEFS = ("none", "guard", "ecc")
SAMPLES = 3


def wilson(k, n):
    if n == 0:
        return math.nan, math.nan
    p = k / n
    d = 1 + Z * Z / n
    c = (p + Z * Z / (2 * n)) / d
    h = Z / d * math.sqrt(p * (1 - p) / n + Z * Z / (4 * n * n))
    return (0.0 if k == 0 else max(c - h, 0.0)), (1.0 if k == n else min(c + h, 1.0))


def stratified(g: pd.DataFrame, y: str):
    """Weighted rate over (scene, N, precision, field, bit) strata and its Wilson interval at the
    design-effect n_eff (variance from add-half stratum rates)."""
    cells = g.groupby(["scene", "n_primitives", "precision", "field", "bit"])
    W = cells["weight"].sum()
    p_h = cells.apply(lambda c: (c["weight"] * c[y]).sum() / c["weight"].sum(), include_groups=False)
    n_h = cells.size()
    Wn = W / W.sum()
    p = float((Wn * p_h).sum())
    if len(W) == 1:
        return (p, *wilson(p * n_h.iloc[0], n_h.iloc[0]))
    sm = (p_h * n_h + 0.5) / (n_h + 1)
    var = float((Wn**2 * sm * (1 - sm) / n_h).sum())
    ps = float((Wn * sm).sum())
    n_eff = min(ps * (1 - ps) / var, float(n_h.sum()))
    return (p, *wilson(p * n_eff, n_eff))


def textbook_mtbf(lam, bits, p, T=24.0):
    """MTBF (hours) of a model of `bits` stored bits at upset rates `lam` per bit-hour and
    catastrophe probability p, scrubbed every T hours: T / (1 - exp(-lam bits p T)), the textbook
    formula apart from the code under test (1 - exp(-x) loses digits for small x, where the code
    uses expm1: compare to 1e-6)."""
    lam = np.asarray(lam, float)
    return T / (1 - np.exp(-lam * bits * p * T)) if p > 0 else np.full(lam.shape, np.inf)


def wq(v, w, q):
    o = np.argsort(v, kind="stable")
    cw = np.cumsum(np.asarray(w)[o])
    return float(np.asarray(v)[o][np.searchsorted(cw, q * cw[-1] * (1 - 1e-12))])


@pytest.fixture(scope="module", params=[False, True], ids=["records", "folded"])
def run(tmp_path_factory, request):
    rng = np.random.default_rng(7)
    rows, iid = [], 0
    for scene, n in SCENES.items():
        for field, nc in COMPS.items():
            for bit in range(32):
                for _ in range(SAMPLES):
                    iid += 1
                    hot = field in ("log_scales", "opacity") and bit >= 29
                    u = rng.random()
                    for d in DEFS:
                        bad = d == "none" and hot and u < 0.3 and field == "log_scales"
                        fp = (0.3 if hot and u < 0.7 else 0.002 * u) if d != "guard" else 0.002 * u
                        peak = 0.0 if u < 0.2 and not hot else (0.5 if fp > 0 else 0.001)
                        rows.append(
                            {
                                "campaign": "single",
                                "scene": scene,
                                "n_primitives": n,
                                "precision": "fp32",
                                "field": field,
                                "primitive": int(rng.integers(n)),
                                "component": 0,
                                "bit": bit,
                                "bit_class": "sign" if bit == 31 else ("exponent" if bit >= 23 else "mantissa"),
                                "clean_value": float(rng.normal()),
                                "corrupted_value": 0.0,
                                "defense": d,
                                "footprint": fp if peak > 0 else 0.0,
                                "footprint_max": fp,
                                "peak_error": math.inf if bad else peak,
                                "psnr": math.nan if bad else (math.inf if peak == 0 else 30 + 20 * u),
                                "ssim": math.nan if bad else 0.99,
                                "nonfinite": bad,
                                "clamps": 0,
                                "k": 1,
                                "repeat": 0,
                                "weight": n * nc / SAMPLES,
                                "seed": 0,
                                "injection_id": iid,
                                "time_ms": {"none": 2.0, "guard": 2.5, "ecc": 2.0}[d],
                            }
                        )
    for d in ("none", "guard"):
        for k in (1, 10, 100):
            for r in range(10):
                iid += 1
                bad = d == "none" and k == 100 and r < 6
                rows.append(
                    {
                        "campaign": "dose",
                        "scene": "big",
                        "n_primitives": 4000,
                        "precision": "fp32",
                        "field": "mixed",
                        "bit": -1,
                        "bit_class": "mixed",
                        "defense": d,
                        "footprint": 0.5 if bad or (k == 100 and r < 8) else 0.001,
                        "peak_error": math.inf if bad else 0.4,
                        "psnr": math.nan if bad else 50 - 8 * math.log10(k) - r,
                        "ssim": math.nan if bad else 0.9,
                        "nonfinite": bad,
                        "k": k,
                        "repeat": r,
                        "weight": 1.0,
                        "injection_id": iid,
                        "time_ms": 2.0,
                    }
                )
    df = pd.DataFrame(rows)
    df["catastrophic"] = (df["footprint"] > 0.01) | df["nonfinite"]
    base = tmp_path_factory.mktemp("audit")
    rd = base / "run"
    (rd / "records").mkdir(parents=True)
    manifest = {"spec": {"scenes": [{"scene": s, "n": n} for s, n in SCENES.items()]}, "spec_hash": "x"}
    (rd / "manifest.json").write_text(json.dumps(manifest))
    # three parts, each holding all the defenses of its fault sites (as the runner writes blocks)
    for i, ids in enumerate(np.array_split(np.unique(df["injection_id"]), 3)):
        df[df["injection_id"].isin(ids)].to_parquet(rd / "records" / f"part-{i:05d}.parquet", index=False)
    out = base / "report"
    with undrawn_report_figures():  # the tests read the numbers and tables, not the pictures
        build_report([rd], out, max_pred_rows=20_000, fold=request.param)  # folded: analysis.folding
    records = pd.concat([pd.read_parquet(p) for p in sorted((rd / "records").glob("*.parquet"))], ignore_index=True)
    return records, out, json.loads((out / "summary.json").read_text())


def test_summary_catastrophic_list(run):
    rec, _, summary = run
    single = rec[(rec["campaign"] == "single")]
    got = {(e["scene"], e["precision"], e["defense"]): e for e in summary["catastrophic"]}
    assert len(got) == len(SCENES) * len(DEFS)
    for (scene, prec, d), g in single.groupby(["scene", "precision", "defense"]):
        p, lo, hi = stratified(g, "catastrophic")
        e = got[(scene, prec, d)]
        assert e["n"] == len(g)
        assert e["rate"] == pytest.approx(p, abs=1e-12)
        assert e["ci_low"] == pytest.approx(lo, abs=1e-9) and e["ci_high"] == pytest.approx(hi, abs=1e-9)
    # the weighted rate is not the pooled count: the audit would catch an unweighted pool
    g = single[single["defense"] == "none"]
    assert stratified(g, "catastrophic")[0] != pytest.approx(g["catastrophic"].mean(), rel=0.05)


def test_outcome_table(run):
    rec, out, summary = run
    s = rec[rec["campaign"] == "single"].copy()
    cls = np.where(s["peak_error"] == 0, "masked", "tolerable").astype(object)
    cls[s["peak_error"] > 1 / 255] = "sdc"
    cls[(s["footprint"] > 0.01) | s["nonfinite"]] = "catastrophic"
    t = pd.read_csv(out / "outcomes_long.csv")
    assert summary["numbers"]["outcome_thresholds"] == {"pixel_threshold": 1 / 255, "footprint_threshold": 0.01}
    for (prec, d), g in s.groupby(["precision", "defense"]):
        for c in ("masked", "tolerable", "sdc", "catastrophic"):
            g2 = g.assign(_y=(cls[g.index.to_numpy()] == c))
            p, lo, hi = stratified(g2, "_y")
            r = t[(t["precision"] == prec) & (t["defense"] == d) & (t["outcome"] == c)].iloc[0]
            assert r["rate_pct"] == pytest.approx(100 * p, abs=1e-9), (d, c)
            assert r["ci_lo_pct"] == pytest.approx(100 * lo, abs=1e-7) and r["ci_hi_pct"] == pytest.approx(100 * hi)
        shares = t[(t["precision"] == prec) & (t["defense"] == d)]["rate_pct"].sum()
        assert shares == pytest.approx(100)


def test_criticality_and_mitigation_tables(run):
    rec, out, summary = run
    s = rec[(rec["campaign"] == "single") & (rec["defense"] == "none")]
    crit = pd.read_csv(out / "criticality.csv").set_index("field")
    for f, g in s.groupby("field"):
        p, lo, hi = stratified(g, "catastrophic")
        r = crit.loc[f]
        assert r["n"] == len(g) and r["catastrophic"] == g["catastrophic"].sum()
        assert r["cat_rate_pct"] == pytest.approx(100 * p) and r["cat_ci_hi_pct"] == pytest.approx(100 * hi)
        fp = g["footprint"].to_numpy() * 100
        assert r["mean_pct"] == pytest.approx(np.average(fp, weights=g["weight"]))
        assert r["p99_pct"] == pytest.approx(wq(fp, g["weight"], 0.99))
    sign = s[(s["field"] == "log_scales") & (s["bit_class"] == "sign")]
    num = summary["numbers"]
    assert num["scale_sign_footprint_mean_pct"] == pytest.approx(
        np.average(sign["footprint"] * 100, weights=sign["weight"])
    )
    mit = pd.read_csv(out / "mitigation.csv").set_index("defense")
    single = rec[rec["campaign"] == "single"]
    for d, g in single.groupby("defense"):
        p, lo, hi = stratified(g, "catastrophic")
        assert mit.loc[d, "cat_rate_pct"] == pytest.approx(100 * p)
        assert mit.loc[d, "cat_ci_lo_pct"] == pytest.approx(100 * lo, abs=1e-7)
    assert mit.loc["guard", "time_overhead_pct"] == pytest.approx(25.0)  # 2.5 ms against 2.0 ms per view
    assert math.isnan(mit.loc["ecc", "time_overhead_pct"])  # simulated read: not measured, not 0
    assert mit.loc["ecc", "memory_overhead_pct"] == pytest.approx(100 * 5 / 32)
    m = {r["defense"]: r for r in num["mitigation"]}
    assert m["none"]["cat_rate_pct"] == pytest.approx(mit.loc["none", "cat_rate_pct"])


def test_guard_reliability_and_claims(run):
    rec, out, summary = run
    single = rec[rec["campaign"] == "single"]
    a = single[single["defense"] == "none"].set_index("injection_id")
    b = single[single["defense"] == "guard"].set_index("injection_id")
    cat = a[a["catastrophic"]].assign(_n=~b.loc[a[a["catastrophic"]].index, "catastrophic"].to_numpy())
    p, lo, hi = stratified(cat, "_n")
    num = summary["numbers"]
    assert num["guard_share_neutralised_pct"] == pytest.approx(100 * p)
    assert num["guard_share_neutralised_ci_pct"] == pytest.approx([100 * lo, 100 * hi])
    precisions = single["precision"].unique()
    assert num["guard_share_precision"] == (precisions[0] if len(precisions) == 1 else "all")
    # two scenes (two models): p_c per scene, each its own stratified rate and interval
    pc = pd.read_csv(out / "reliability_pc.csv").set_index(["scene", "defense"])
    assert len(pc) == len(SCENES) * len(DEFS) and "pooled_over" not in pc
    for scene, n in SCENES.items():
        for d in DEFS:
            p, lo, hi = stratified(single[(single["scene"] == scene) & (single["defense"] == d)], "catastrophic")
            r = pc.loc[(scene, d)]
            assert r["n_primitives"] == n
            assert r["p_c"] == pytest.approx(p) and r["ci_lo"] == pytest.approx(lo, abs=1e-9)
            assert r["ci_hi"] == pytest.approx(hi)
            if d in ("none", "guard"):
                assert num[f"p_c_{scene}_{d}_pct"] == pytest.approx([100 * p, 100 * lo, 100 * hi], abs=1e-9)
    assert "p_c_none_pct" not in num  # no number stands for both models
    assert num["model_bits"] == {s: n * 59 * 32 for s, n in SCENES.items()}
    # the paper's 0.634 is the plain mean of its six per-field rates: compared with each model's
    # plain mean of its per-field rates, averaged over the models; the weighted rate (the pool over
    # both scenes, weighted by stored bits) is this project's, beside Table 2 weighted the same way
    claims = pd.read_csv(out / "claims.csv").set_index("claim")
    none = single[single["defense"] == "none"]
    per_field = {
        scene: np.mean([stratified(g, "catastrophic")[0] for _, g in none[none["scene"] == scene].groupby("field")])
        for scene in SCENES
    }
    r = claims.loc["p_c as the plain mean of the six per-field rates (Table 2), fp32, no defense"]
    assert r["measured"] == pytest.approx(100 * np.mean(list(per_field.values()))) and r["paper"] == 0.634
    assert r["n_models"] == 2 and r["verdict"] == "inconclusive"  # two models cannot tell
    r = claims.loc[
        "p_c weighted by stored bits (uniform upset), fp32, no defense; paper: Table 2 weighted the same way"
    ]
    p, lo, hi = stratified(none, "catastrophic")
    assert r["pooled"] == pytest.approx(100 * p) and r["pooled_hi"] == pytest.approx(100 * hi)
    per_model = [stratified(none[none["scene"] == s], "catastrophic")[0] for s in SCENES]
    assert r["measured"] == pytest.approx(100 * np.mean(per_model))
    table2 = (0.004 * 3 + 2.782 * 3 + 0.0 * 4 + 0.004 * 1 + 1.016 * 3 + 0.0 * 45) / 59
    assert r["paper"] == pytest.approx(round(table2, 4))
    assert "pooled over 2 models" in r["basis"] and "big (N=4,000), small (N=500)" in r["basis"]
    assert summary["sections"][:2] == ["summary", "claims"]  # the user's answer first, then the paper


def test_summary_numbers(run):
    """The report's opening summary (report/summary.py), recomputed from the records: p_c per model
    (never one number for both sizes), the most dangerous cells and their share of p_c, the worst
    flip, each defense's residual rate, time per frame and exposure, the cheapest meeting the target."""
    rec, out, summary = run
    num = summary["numbers"]["summary"]
    single = rec[rec["campaign"] == "single"]
    none = single[single["defense"] == "none"]
    assert num["target"] == 0.001 and num["target_source"] == "the default" and num["check_every"] == 10
    models = {m["scene"]: m for m in num["models"]}
    assert {s: m["n_primitives"] for s, m in models.items()} == SCENES
    assert all(m["sh_degree"] == 3 and m["precisions"] == "fp32" for m in models.values())
    assert all(m["loader_notes"] is None for m in models.values())  # this manifest does not say: n/a, not "none"
    pc = {r["scene"]: r for r in num["p_c"]}
    assert len(pc) == len(SCENES)
    for scene, g in none.groupby("scene"):
        p, lo, hi = stratified(g, "catastrophic")
        assert (pc[scene]["rate"], pc[scene]["ci_lo"], pc[scene]["ci_hi"]) == pytest.approx((p, lo, hi), abs=1e-12)
        assert pc[scene]["n"] == len(g) and pc[scene]["events"] == g["catastrophic"].sum()
        # the top cells: rate (Wilson of the cell), n, and W_h p_h / p_c
        cells = g.groupby(["field", "bit"])
        rate = cells.apply(lambda c: (c["weight"] * c["catastrophic"]).sum() / c["weight"].sum(), include_groups=False)
        share = cells["weight"].sum() * rate / (cells["weight"].sum() * rate).sum()
        top = [c for c in num["cells"] if c["scene"] == scene]
        assert 0 < len(top) <= 5
        assert [c["rate"] for c in top] == sorted((c["rate"] for c in top), reverse=True)
        assert top[0]["rate"] == pytest.approx(rate.max())
        for c in top:
            key = (c["field"], c["bit"])
            assert c["rate"] == pytest.approx(rate[key]) and c["n"] == cells.size()[key]
            k, n = cells["catastrophic"].sum()[key], cells.size()[key]
            assert (c["ci_lo"], c["ci_hi"]) == pytest.approx(wilson(k, n))
            assert c["share_of_pc"] == pytest.approx(share[key])
    # the worst flip: the largest footprint of the unguarded arm, a non-finite frame first among equals
    w = num["worst"]
    top = none[none["footprint"] == none["footprint"].max()]
    assert w["footprint"] == top["footprint"].iloc[0] and w["nonfinite"] == top["nonfinite"].any()
    # each defense, per model: rate and interval, the time its records measured, exposure
    times = {"none": 2.0, "guard": 2.5, "ecc": 2.0}
    got = {(r["scene"], r["defense"]): r for r in num["defenses"]}
    assert len(got) == len(SCENES) * len(DEFS)
    for (scene, d), g in single.groupby(["scene", "defense"]):
        r = got[(scene, d)]
        assert (r["rate"], r["ci_lo"], r["ci_hi"]) == pytest.approx(stratified(g, "catastrophic"), abs=1e-12)
        assert r["time_ms"] == times[d]
        assert r["time_vs_none_pct"] == pytest.approx(100 * (times[d] / 2.0 - 1))
        model_bytes = SCENES[scene] * 59 * 4
        assert r["device_pct"] == pytest.approx(100 * r["device_bytes"] / model_bytes)
        assert (r["device_bytes"] == 0) == (d == "none")
        assert r["exposure_frames"] == ("inf" if d == "none" else 0)  # strict JSON: inf as a string
    # the cheapest: among those whose interval's upper end is at most the target, by time then bytes
    for scene in SCENES:
        rows = [got[(scene, d)] for d in DEFS]
        ok = [r for r in rows if r["ci_hi"] <= 0.001]
        ok = sorted(ok, key=lambda r: (r["defense"] != "none", r["time_ms"], r["device_bytes"]))
        c = next(c for c in num["cheapest"] if c["scene"] == scene)
        assert c["met"] == bool(ok) and c["defense"] == (ok[0]["defense"] if ok else None)
    page = (out / "report.md").read_text()
    assert page.index("## Summary") < page.index("## Runs") < page.index("## Claims")


def test_mtbf_per_scene(run):
    """Each scene's MTBF rows pair its own single-upset p_c with its own stored bits:
    T / (1 - exp(-rate x bits x p x T)), with the live upsets per scrub interval beside (the
    report never sets a dose fit's p, measured with many upsets alive, as a per-upset probability)."""
    rec, out, summary = run
    single = rec[rec["campaign"] == "single"]
    mt = pd.read_csv(out / "mtbf_detail.csv")
    assert set(mt["scene"]) == set(SCENES)
    assert set(mt["p_source"]) == {"single-upset p_c"}
    live = mt["upsets_per_bit_hour"] * mt["model_bits"] * 24.0
    assert mt["live_upsets_per_scrub"].to_numpy() == pytest.approx(live.to_numpy())
    assert (mt["regime"].str.startswith("single upsets") == (live < 1)).all()
    for (scene, d, src), g in mt.groupby(["scene", "defense", "p_source"]):
        n = SCENES[scene]
        bits = n * 59 * 32
        assert (g["n_primitives"] == n).all() and (g["model_bits"] == bits).all()
        if src == "single-upset p_c":
            p = stratified(single[(single["scene"] == scene) & (single["defense"] == d)], "catastrophic")[0]
        else:
            assert scene == "big"  # small has no dose run: no dose rows, never big's p with small's bits
            fit = pd.read_csv(out / "dose_fits.csv").set_index(["scene", "defense"]).loc[(scene, d)]
            p = fit["p_pct"] / 100
        assert g["p_pct"].to_numpy() == pytest.approx(100 * p)
        want = textbook_mtbf(g["upsets_per_bit_hour"], bits, p)
        assert g["mtbf_hours"].to_numpy() == pytest.approx(want, rel=1e-6)
    wide = pd.read_csv(out / "mtbf.csv")
    assert list(wide.columns[:3]) == ["scene", "model_bits", "environment"] and len(wide) == 2 * 3


def test_dose_numbers(run):
    rec, out, summary = run
    d = rec[rec["campaign"] == "dose"]
    cur = pd.read_csv(out / "dose_curves.csv")
    for (dfn, k), g in d.groupby(["defense", "k"]):
        r = cur[(cur["defense"] == dfn) & (cur["k"] == k)].iloc[0]
        ranked = np.sort(np.where(g["nonfinite"], -np.inf, g["psnr"]))  # non-finite frames rank lowest
        assert r["psnr_median_db"] == ranked[(len(g) - 1) // 2]  # the lower median
        # quartiles: the smallest frame whose share reaches q (dose draws weigh 1 each)
        assert (r["psnr_q25_db"], r["psnr_q75_db"]) == (ranked[-(-len(g) // 4) - 1], ranked[-(-3 * len(g) // 4) - 1])
        assert r["nonfinite_pct"] == pytest.approx(100 * g["nonfinite"].mean())
        lo, hi = wilson(int(g["catastrophic"].sum()), len(g))
        assert r["cat_rate_pct"] == pytest.approx(100 * g["catastrophic"].mean())
        assert r["cat_ci_lo_pct"] == pytest.approx(100 * lo) and r["cat_ci_hi_pct"] == pytest.approx(100 * hi)
        fin = g[~g["nonfinite"]]
        if len(fin):
            assert r["ssim_mean"] == pytest.approx(fin["ssim"].mean())
    num = summary["numbers"]
    # 6 of 10 frames at k = 100 are non-finite: the median frame is non-finite, never "0 dB"
    assert num["dose_psnr_median_at_kmax_none_db"] == "-inf" and num["dose_nonfinite_at_kmax_none_pct"] == 60
    assert not re.search(r"(?<![0-9.])0(\.0+)? dB", (out / "report.md").read_text())


def test_theory_budget_and_lookup_auc(run):
    rec, out, summary = run
    num = summary["numbers"]
    # theory: weighted mean peak error per log-scale mantissa bit, log2 slope over the bits whose
    # mean lies in (1e-5, 0.1] (all positive ones when fewer than 3 do)
    s = rec[(rec["campaign"] == "single") & (rec["defense"] == "none")]
    m = s[(s["field"] == "log_scales") & (s["bit"] < 23) & np.isfinite(s["peak_error"])]
    mean = m.groupby("bit").apply(lambda g: np.average(g["peak_error"], weights=g["weight"]), include_groups=False)
    use = mean[(mean > 1e-5) & (mean <= 0.1)]
    if len(use) < 3:
        use = mean[mean > 0]
    slope = np.polyfit(use.index.to_numpy(float), np.log2(use.to_numpy()), 1)[0]
    assert num["theory_slope"] == pytest.approx(slope)
    # redundancy budget: first k where the lower median PSNR (non-finite lowest) is <= 30 dB,
    # interpolated linearly in log k
    d = rec[rec["campaign"] == "dose"]
    for dfn, g in d.groupby("defense"):
        med = g.groupby("k").apply(
            lambda x: np.sort(np.where(x["nonfinite"], -np.inf, x["psnr"]))[(len(x) - 1) // 2], include_groups=False
        )
        ks, v = med.index.to_numpy(float), med.to_numpy()
        below = np.nonzero(v <= 30)[0]
        key = f"budget_k_big_4000_fp32_{dfn}"
        if not below.size:
            assert num[key] == f">={ks[-1]:.4g}"
            continue
        i = below[0]
        if i == 0 or not np.isfinite(v[i]):
            assert num[key] == f"<={ks[i]:.4g}"
            continue
        t = (v[i - 1] - 30) / (v[i - 1] - v[i])
        kb = math.exp(math.log(ks[i - 1]) + t * (math.log(ks[i]) - math.log(ks[i - 1])))
        assert num[key] == f"{kb:.4g}"
    # the (field, bit) lookup's held-out AUC, weighted, on the same stratified 30% split
    from sklearn.metrics import roc_auc_score
    from sklearn.model_selection import train_test_split

    p = s[s["bit"] >= 0]
    y = p["catastrophic"].to_numpy(bool)
    tr, te = train_test_split(np.arange(len(p)), test_size=0.3, stratify=y, random_state=0)
    a, b = p.iloc[tr], p.iloc[te]
    cell = a.assign(wy=a["weight"] * a["catastrophic"]).groupby(["field", "bit"])[["wy", "weight"]].sum()
    rate = (cell["wy"] / cell["weight"]).to_dict()
    base = (a["weight"] * a["catastrophic"]).sum() / a["weight"].sum()
    score = [rate.get((f, bb), base) for f, bb in zip(b["field"], b["bit"])]
    auc = roc_auc_score(b["catastrophic"], score, sample_weight=b["weight"])
    assert num["pred_auc_lookup"][0] == pytest.approx(auc)
