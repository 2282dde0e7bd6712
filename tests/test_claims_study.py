"""The study a referee would accept (issue 46): populations never pooled, rows at matched N, the
margins' verdicts, non-finite frames counted as failures, tails only at the paper's number of
upsets, contamination per frame and over the union, the mantissa slope's verdict over windows,
the paper's inconsistencies recomputed from its own numbers, and the sign-flip rows per renderer
profile. Small frames made for the test; pandas only."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from test_reliability_models import single_records

from seuwgpu.analysis import claimrows, claims, dose, paper, population, scaling, theory


def models(*hot, names=None):
    names = names or [f"m{i}" for i in range(len(hot))]
    return pd.concat(
        [single_records(s, 1000, 10 + i, h, iid0=100_000 * i) for i, (s, h) in enumerate(zip(names, hot))],
        ignore_index=True,
    )


def test_real_models_and_procedural_scenes_are_never_pooled():
    df = models(0.6, 0.3, 0.45, 0.5, 0.4, names=["m0", "m1", "m2", "spheres", "blocks"])
    t = claims.claims_table(df)
    assert set(t["population"]) == {population.REAL, population.PROCEDURAL}
    real = t[(t["population"] == population.REAL) & (t["key"] == "pc_none")].iloc[0]
    proc = t[(t["population"] == population.PROCEDURAL) & (t["key"] == "pc_none")].iloc[0]
    est = population.model_rates(df, "fp32", "none").set_index("scene")
    assert real["measured"] == pytest.approx(100 * est.loc[["m0", "m1", "m2"], "fields_p_c"].mean())
    assert proc["measured"] == pytest.approx(100 * est.loc[["spheres", "blocks"], "fields_p_c"].mean())
    assert real["n_models"] == 3 and proc["n_models"] == 2 and proc["verdict"] == "inconclusive"
    assert (t["N"] == "full size: 1,000").all() and set(t["guard"]) >= {"none", "guard"}
    per = pd.DataFrame(t.attrs["per_model"])
    assert set(per.loc[per["population"] == population.PROCEDURAL, "scene"]) == {"spheres", "blocks"}


def test_a_model_file_named_like_a_procedural_scene_is_a_real_model():
    """The corpus' plant.splat gets the label "plant", the procedural scene's name: the runs'
    manifests say it is a model file."""
    df = models(0.6, 0.3, 0.45, names=["plant", "m1", "m2"])
    manifests = [{"spec": {"scenes": [{"model": "/c/plant/plant.splat"}, {"model": "/c/m1.ply"}]}}]
    t = claims.claims_table(df, manifests=manifests)
    assert set(t["population"]) == {population.REAL}
    assert claims.populations(df) == {population.REAL: ["m1", "m2"], population.PROCEDURAL: ["plant"]}
    assert scaling.scene_group("plant") == scaling.PROCEDURAL
    assert scaling.scene_group("plant", frozenset({"plant"})) == scaling.CAPTURE


def size_records(ns=(8192, 32768), scenes=("a", "b", "c")):
    """Size-sweep records: each model at each N, arms none, guard and guard_all; the guard cuts the
    MSE by a factor 10 + N / 8192, guard_all by twice that."""
    parts = []
    for i, s in enumerate(scenes):
        for n in ns:
            d = single_records(s, n, 7 + i, 0.4 + 0.1 * i, iid0=1_000_000 * i + n)
            d = pd.concat([d, d[d["defense"] == "guard"].assign(defense="guard_all")], ignore_index=True)
            f = {"none": 1.0, "guard": 1 / (10 + n / 8192), "guard_all": 1 / (2 * (10 + n / 8192))}
            mse = 1e-4 * (1 + i) * d["defense"].map(f)
            d["psnr"] = -10 * np.log10(mse)
            parts.append(d.assign(campaign="size"))
    return pd.concat(parts, ignore_index=True)


def test_rows_at_matched_n_never_average_sizes():
    rows = pd.DataFrame(scaling.matched_rows(size_records()))
    assert set(rows["N"]) == {"N = 8,192", "N = 32,768"}
    gf = rows[rows["key"] == "matched_guard_factor"]
    for n, g in gf.groupby("N"):
        size = int(n.split("= ")[1].replace(",", ""))
        want = {"guard": 10 + size / 8192, "guard_all": 2 * (10 + size / 8192)}
        for _, r in g.iterrows():
            assert r["measured"] == pytest.approx(want[r["guard"]], rel=1e-9) and r["n_models"] == 3
            assert r["verdict"] == "not comparable"  # the paper's factor is at 300,000
    pc = rows[rows["key"] == "matched_pc_none"]
    d = size_records()
    at = d[(d["n_primitives"] == 8192)].assign(campaign="single")
    est = population.model_rates(at, "fp32", "none")
    r = pc[pc["N"] == "N = 8,192"].iloc[0]
    assert r["measured"] == pytest.approx(100 * est["fields_p_c"].mean())
    # at the paper's N the factor is compared
    near = pd.DataFrame(scaling.matched_rows(size_records(ns=(300_000,)), sizes=[300_000]))
    assert (near.loc[near["key"] == "matched_guard_factor", "verdict"] != "not comparable").all()


def curves(nonfinite: dict) -> pd.DataFrame:
    """Dose curves of three models of 1,000 primitives: PSNR of the mean MSE 60, 40, 25, 12 dB at
    k = 10 .. 1e4 (finite frames); nonfinite[scene] = % of non-finite frames from k = 1,000 on."""
    ks = np.array([10, 100, 1000, 10000])
    out = []
    for s in ("a", "b", "c"):
        out.append(
            pd.DataFrame(
                {
                    "scene": s,
                    "n_primitives": 1000,
                    "precision": "fp32",
                    "defense": "none",
                    "k": ks,
                    "psnr_mean_mse_db": [60.0, 40.0, 25.0, 12.0],
                    "psnr_median_db": [60.0, 40.0, 25.0, 12.0],
                    "nonfinite_pct": np.where(ks >= 1000, nonfinite.get(s, 0.0), 0.0),
                }
            )
        )
    return pd.concat(out, ignore_index=True)


def test_budget_counts_a_non_finite_frame_as_a_failure():
    finite, allf = dose.budget_rows(curves({"a": 20.0, "b": 10.0}))
    # finite frames only: every model crosses 30 dB between k = 100 and 1,000 at the same point
    k = math.exp(math.log(100) + (40 - 30) / (40 - 25) * (math.log(1000) - math.log(100)))
    assert finite["measured"] == pytest.approx(k / 1000) and "finite frames" in finite["basis"]
    # a and b fail at k = 1,000 for their non-finite frames: the crossing lies in (100, 1,000], its
    # geometric middle; c (no non-finite frame) keeps the interpolated crossing
    per = [math.sqrt(100 * 1000) / 1000, math.sqrt(100 * 1000) / 1000, k / 1000]
    assert allf["measured"] == pytest.approx(np.mean(per)) and "(100, 1,000]" in allf["basis"]
    assert finite["key"] == "budget_mean_psnr" and allf["key"] == "budget_mean_psnr_all"


def test_dose_rows_show_survivors_and_all_frames():
    c = curves({"a": 30.0, "b": 5.0, "c": 1.0})
    c = pd.concat([c, c.assign(defense="guard")], ignore_index=True)
    rows = {r["key"]: r for r in dose.dose_rows(c)}
    assert np.isfinite(rows["dose_none"]["measured"])  # the survivors' PSNR
    r = rows["dose_none_all"]
    assert r["measured"] == -np.inf and r["ci_lo"] == r["ci_hi"] == -np.inf and r["verdict"] == "differs"
    some = {r["key"]: r for r in dose.dose_rows(curves({"a": 30.0}))}["dose_none_all"]
    assert some["measured"] == -np.inf and np.isnan(some["ci_hi"]) and some["verdict"] == "inconclusive"


def test_a_model_without_a_value_neither_softens_a_row_at_minus_inf_nor_a_budget_below_zero():
    """Three models at -inf and one the dose grid does not reach (NaN): every model with a value is
    at -inf, so the interval is [-inf, -inf] and the row differs (the real study's flowers). A
    budget's t interval is cut at 0 (a k/N below 0 is no budget)."""
    per = pd.DataFrame({"scene": list("abcd"), "n_primitives": [1] * 4, "v": [-np.inf] * 3 + [np.nan]})
    r = claimrows.over_models("dose_none_all", per, "v", "basis", 0.95, scale=1.0)
    assert r["ci_lo"] == r["ci_hi"] == -np.inf and r["verdict"] == "differs" and r["n_models"] == 3
    per = pd.DataFrame({"scene": list("abc"), "n_primitives": [1] * 3, "v": [0.0001, 0.001, 0.02]})
    r = claimrows.over_models("budget_mean_psnr", per, "v", "basis", 0.95, scale=1.0)
    assert r["ci_lo"] == 0.0 and r["ci_hi"] > 0.02 and "cut to 0" in r["basis"]


def test_a_maximum_is_compared_only_at_the_paper_s_number_of_upsets():
    v = np.arange(1000.0)
    m, lo, hi = claimrows.matched_maximum(v, 100, reps=300, seed=1)
    # the expected maximum of 100 of 0..999 drawn without replacement: (1000 + 1) * 100 / 101 - 1
    assert m == pytest.approx(1001 * 100 / 101 - 1, rel=0.01) and lo < m < hi <= 999
    assert all(np.isnan(x) for x in claimrows.matched_maximum(v, 1001))
    r = claimrows.tail_row("guard_worst_footprint", v, "test", 999.0)
    assert r["verdict"] == "not comparable" and r["measured"] == 999.0 and "768,000" in r["basis"]
    assert paper.paper_upsets("field_max_log_scales") == 32 * 4 * 2000


def test_the_mantissa_slope_verdict_is_the_windows_majority():
    bits = np.arange(6, 23)
    slope = np.where(bits >= 21, 1.6, 0.94)  # steep at the top
    y = np.cumsum(np.r_[0, slope[1:]]) - 20
    table = pd.DataFrame({"bit": bits, "log2_mean_peak_error": y + 0.01 * np.sin(bits)})
    th = {"table": table, "slope": 0.95, "slope_lo": 0.9, "slope_hi": 1.0, "n_fit_bits": 15, "fit_bits": (8, 22)}
    th["precision"] = "fp32"
    w = theory.theory_windows(th)
    r = theory.slope_row(th)
    # 6 of the 7 windows reproduce (the steep top makes one inconclusive): the majority reproduces
    assert w["verdict"].value_counts().to_dict() == {"reproduced": 6, "inconclusive": 1}
    assert r["verdict"] == "reproduced" and "verdict over the 7 fit windows: 6 reproduce, 0 differ" in r["basis"]
    assert "(the default window alone: reproduced)" in r["basis"]


def test_the_paper_s_inconsistencies_are_recomputed_from_its_numbers():
    weighted = sum(v * c for v, c in zip((0.004, 2.782, 0.0, 0.004, 1.016, 0.0), (3, 3, 4, 1, 3, 45))) / 59
    assert paper.paper_bit_weighted() == pytest.approx(weighted)
    assert paper.paper_mtbf_bit_weighted_years() == pytest.approx(71 * 0.634 / weighted, rel=1e-9)
    assert 232 < paper.paper_mtbf_bit_weighted_years() < 234
    text = " ".join(paper.PAPER_INCONSISTENCIES)
    assert "Algorithm 1" in text and "l. 1056" in text and "233 years" in text
    assert "two definitions side by side" not in text  # item iv, re-checked: one definition
    assert "Not an inconsistency" in paper.PAPER_CHECKED[0]


def test_every_margin_is_stated_and_a_zero_gets_a_bound():
    t = paper.margins_table()
    compared = t[np.isfinite(t["paper"].astype(float))]
    assert (compared["margin"] != "").all()
    assert t.set_index("key").loc["field_rate_quats", "margin"] == "<= 0.01 (upper bound)"
    assert t.set_index("key").loc["sign_psnr_none", "margin"] == "+-3"


def test_sign_rows_under_both_profiles():
    df = models(0.6, 0.3, 0.45, 0.5, names=["plant", "m1", "m2", "m3"])
    # strict on four models, gsplat on two: the rows compare the two measured under both
    both = pd.concat([df.assign(profile="strict"), df[df["scene"].isin(["plant", "m1"])].assign(profile="gsplat")])
    t = claims.sign_rows_by_profile(both)
    assert (t["models"] == "m1, plant").all()
    assert set(t["profile"]) == {"strict", "gsplat"} and (t["paper_profile"] == "gsplat").all()
    assert set(t["key"]) == {"sign_mean", "sign_p99", "sign_psnr_none", "sign_psnr_guard"}
    a = t[(t["profile"] == "strict") & (t["key"] == "sign_mean")].iloc[0]
    b = t[(t["profile"] == "gsplat") & (t["key"] == "sign_mean")].iloc[0]
    assert a["measured"] == b["measured"]  # the same records under both names


def _tool(name):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"seuwgpu_tool_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_reverdict_splits_a_stored_row_by_population(tmp_path):
    tool = _tool("claims_from_tables")
    assert (
        tool.claim_key(
            "redundancy budget per primitive: k/N where the PSNR of the mean MSE falls to 30 dB, fp32, no defense"
        )
        == "budget_mean_psnr"
    )
    basis = "n = 192; per model: spheres 3.5; blocks 3.9; m1 1.8; m2 1.9; m3 2.0"
    assert tool.per_model_values(basis) == {"spheres": 3.5, "blocks": 3.9, "m1": 1.8, "m2": 1.9, "m3": 2.0}
    row = {
        "claim": claims.PAPER["sign_mean"][0],
        "unit": "% of frame",
        "measured": 2.6,
        "ci_lo": 1.0,
        "ci_hi": 4.5,
        "paper": 10.3,
        "verdict": "differs",
        "interval_over": "models",
        "n_models": 5,
        "pooled": 2.6,
        "pooled_lo": 2.5,
        "pooled_hi": 2.7,
        "basis": basis,
    }
    pd.DataFrame([row]).to_csv(tmp_path / "claims.csv", index=False)
    t = tool.reverdict(tmp_path).set_index("population")
    real = t.loc[population.REAL]
    om = population.interval_over_models([1.8, 1.9, 2.0])
    assert (real["measured"], real["ci_lo"], real["ci_hi"]) == pytest.approx((om.mean, om.lo, om.hi))
    assert real["verdict"] == "differs"  # [1.65, 2.15] lies below 10.25 / 2
    assert t.loc[population.PROCEDURAL, "verdict"] == "inconclusive"  # two models
    assert real["verdict_issue36"] == "differs" and real["verdict_margin_pooled"] == "differs"  # 4.5 < 5.15


def test_reverdict_keeps_a_corpus_model_real_and_a_model_at_minus_inf(tmp_path):
    """A corpus model named like a procedural scene (plant) is a real model where scenes.csv says it
    is a model file, or where claims.csv names the row's population; a model at -inf keeps the mean
    at -inf (the interval [-inf, -inf] when every model is there: below any band, differs), where
    the t interval over the finite values alone would drop it."""
    tool = _tool("claims_from_tables")
    basis = "k/N = 0.197; per model: plant -inf; m1 -inf; m2 -inf; m3 nan; 3 of 3 models at -inf"
    assert tool.per_model_values(basis) == pytest.approx(
        {"plant": -np.inf, "m1": -np.inf, "m2": -np.inf, "m3": np.nan}, nan_ok=True
    )
    row = {
        "claim": claims.PAPER["dose_none_all"][0],
        "unit": "dB",
        "measured": -np.inf,
        "ci_lo": -np.inf,
        "ci_hi": -np.inf,
        "paper": 10.6,
        "verdict": "differs",
        "n_models": 3,
        "basis": basis,
    }
    pd.DataFrame([row]).to_csv(tmp_path / "claims.csv", index=False)
    pd.DataFrame({"scene": ["plant", "m1", "m2", "m3"], "kind": "model file"}).to_csv(
        tmp_path / "scenes.csv", index=False
    )
    t = tool.reverdict(tmp_path)
    assert list(t["population"]) == [population.REAL]  # plant is not the procedural plant here
    r = t.iloc[0]
    assert r["n_models"] == 3 and r["measured"] == r["ci_lo"] == r["ci_hi"] == -np.inf
    assert r["verdict"] == "differs" and r["verdict_margin_pooled"] == "differs"  # -inf read back from the CSV
    # without scenes.csv, the population claims.csv names
    (tmp_path / "scenes.csv").unlink()
    pd.DataFrame([row | {"population": population.REAL}]).to_csv(tmp_path / "claims.csv", index=False)
    assert list(tool.reverdict(tmp_path)["population"]) == [population.REAL]
    # one of two models at -inf: [-inf, NaN], no verdict either way
    pd.DataFrame([row | {"basis": "per model: m1 -inf; m2 12.0; m3 11.0"}]).to_csv(tmp_path / "claims.csv", index=False)
    r = tool.reverdict(tmp_path).iloc[0]
    assert r["measured"] == r["ci_lo"] == -np.inf and np.isnan(r["ci_hi"]) and r["verdict"] == "inconclusive"


def test_the_real_study_specs_and_their_planner():
    tool = _tool("study")
    raw = {"scenes": [{"model": "flowers/lod-meta.json"}], "single": {"samples": 64}, "dose": {"repeats": 4}}
    out = tool.with_samples(raw, 4)
    assert out["single"]["samples"] == 4 and out["dose"]["repeats"] == 2 and raw["single"]["samples"] == 64
    # the planner's estimate as properties, not its formula restated: more injections or more arms
    # cost more, and a second (model, spec) context adds its start
    four = {"single": {"defenses": ["none", "guard", "guard_all", "parity4r"]}}
    two = {"single": {"defenses": ["none", "guard"]}}

    def plan(*injections):
        return pd.DataFrame([{"campaign": "single", "injections": n, "arms": 4} for n in injections])

    assert tool.estimate_seconds(plan(3040), four) > tool.estimate_seconds(plan(1520), four) > 0
    assert tool.estimate_seconds(plan(1520), four) > tool.estimate_seconds(plan(1520), two)
    assert tool.estimate_seconds(plan(760, 760), four) > tool.estimate_seconds(plan(1520), four)
    import tomllib
    from pathlib import Path

    real = Path(__file__).resolve().parents[1] / "docs" / "study" / "real"
    for name in tool.REAL_SPECS:
        spec = tomllib.loads((real / name).read_text())
        models = [s["model"] for s in spec["scenes"]]
        if "single" in spec:
            assert spec["single"]["samples"] >= 64 and spec["single"]["bits"] == "all"
        if name == "real.toml":
            assert len(models) == 8 and spec["single"]["defenses"] == ["none", "guard", "guard_all", "parity4r"]
            assert spec["reliability"]["check_every"] >= 1


def test_models_without_sh_rest_compare_the_five_field_mean():
    """A model of SH degree 0 stores no sh_rest: the plain mean is then over the five other fields
    on both sides (Table 2's five: 0.7612), never 5 fields beside 6."""
    df = models(0.6, 0.3, 0.45)
    df = df[(df["scene"] != "m0") | (df["field"] != "sh_rest")]
    scenes = [{"model": f"/c/m{i}.ply", "sh_degree": 0 if i == 0 else 3} for i in range(3)]
    t = claims.claims_table(df, manifests=[{"spec": {"scenes": scenes}}]).set_index("key")
    assert "pc_none" not in t.index
    r = t.loc["pc_none_5"]
    assert r["paper"] == pytest.approx(np.mean([0.004, 2.782, 0.0, 0.004, 1.016]), abs=5e-5)
    five = df[df["field"] != "sh_rest"]
    est = population.model_rates(five, "fp32", "none")
    assert (est["fields"] == 5).all()
    assert r["measured"] == pytest.approx(100 * est["fields_p_c"].mean()) and r["verdict"] != "not measured"
