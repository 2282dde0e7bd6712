"""A report built from records folded as they are read (analysis.folding) says exactly what the
report of the records themselves says: every table, figure list and headline number. The reports
compared here make their figures but leave them undrawn (conftest.undrawn_report_figures: the
pictures are not compared); test_report_profiles.py draws a folded report's figures."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from test_report import SCENES, _dose_rows, _single_rows, _size_rows

from seuwgpu.analysis import folding
from seuwgpu.analysis.records import MULTIPLICITY, PREDICTION_SAMPLE, draw_share, n_records, prepare
from seuwgpu.report.build import build_report, load_runs


def _write(run_dir, df, manifest):
    """One part per (scene, precision) block: a block writes all its defenses together, as the
    runner does (folding pairs a site's defenses within its part)."""
    (run_dir / "records").mkdir(parents=True)
    (run_dir / "manifest.json").write_text(json.dumps(manifest))
    for i, (_, g) in enumerate(df.groupby(["campaign", "scene", "precision"], sort=False)):
        g.to_parquet(run_dir / "records" / f"part-{i:05d}.parquet", index=False)
    return run_dir


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    rng = np.random.default_rng(3)
    df = pd.concat(
        [pd.DataFrame(_single_rows(rng, per_cell=6)), pd.DataFrame(_dose_rows(rng)), pd.DataFrame(_size_rows(rng))],
        ignore_index=True,
    )
    df["weight"] = prepare(df)["weight"].to_numpy()  # the runner writes each record's weight
    # many records alike in what the analyses read: footprints on a coarse grid
    df["footprint"] = np.round(df["footprint"] * 200) / 200
    manifest = {"spec": {"scenes": list(SCENES), "sh_degree": 3}, "spec_hash": "f0"}
    return _write(tmp_path_factory.mktemp("fold") / "run", df, manifest), df


def _tables(out):
    return {p.name: pd.read_csv(p) for p in sorted(out.glob("*.csv"))}


def _same_table(name, a, b):
    assert list(a.columns) == list(b.columns), name
    assert len(a) == len(b), name
    for c in a.columns:
        x, y = a[c], b[c]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            np.testing.assert_allclose(
                x.to_numpy(float), y.to_numpy(float), rtol=1e-9, atol=1e-12, err_msg=f"{name}:{c}"
            )
        else:
            assert x.astype(str).tolist() == y.astype(str).tolist(), f"{name}:{c}"


def _same_numbers(a, b, path=""):
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _same_numbers(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same_numbers(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, (int, float)):
        assert b == pytest.approx(a, rel=1e-9, abs=1e-12) or (math.isnan(a) and math.isnan(b)), path
    else:
        assert a == b, path


def _same_reports(plain, folded, n_records):
    """The records report `plain` and the folded report `folded` of the same n_records say the
    same: every table, the file and section lists, the skipped analyses and the summary's numbers."""
    sp, sf = (json.loads((d / "summary.json").read_text()) for d in (plain, folded))
    assert sf["folded"]["records"] == n_records and sp["folded"] is None
    said = f"The {n_records:,} records were folded as they were read into {sf['folded']['rows']:,} rows"
    assert said in (folded / "report.md").read_text() and said in (folded / "index.html").read_text()
    assert "folded" not in (plain / "report.md").read_text().split("##")[0]
    assert sp["files"] == sf["files"] and sp["sections"] == sf["sections"] and sp["skipped"] == sf["skipped"]
    tp, tf = _tables(plain), _tables(folded)
    assert len(tp) >= 20 and "prediction.csv" in tp and set(tp) == set(tf)
    for name in tp:  # the prediction too: both draw its sample by the same hash of the sites
        _same_table(name, tp[name], tf[name])
    for key in ("catastrophic", "provenance", "thresholds", "numbers"):
        _same_numbers(sp[key], sf[key], key)
    return sp, sf


def test_folded_report_equals_the_records_report(run, tmp_path, undrawn_figures):
    """Every record in the prediction (max_pred_rows above the records); a sampled prediction
    (max_pred_rows=1000) is test_several_runs_fold_alike's."""
    rd, df = run
    plain = build_report([rd], tmp_path / "plain", max_pred_rows=200_000, fold=False).parent
    folded = build_report([rd], tmp_path / "folded", max_pred_rows=200_000, fold=True).parent
    _same_reports(plain, folded, len(df))
    n_train = pd.read_csv(plain / "prediction.csv")["n_train"].iloc[0]
    assert n_train > 1600  # 70% of the 2,304 records at fp32 train


def test_folding_keeps_what_each_analysis_reads(run):
    rd, df = run
    f, _ = load_runs([rd], fold=True, max_pred_rows=40)
    assert n_records(f) == len(df) and f[MULTIPLICITY].min() >= 1
    assert len(f) < len(df) / 2  # it folds: alike records are one row
    single = (f["campaign"] == "single") & (f["k"] == 1)
    # kept whole: other campaigns, log-scale sign flips and the prediction sample (about 40 per precision)
    whole = f[~single | ((f["field"] == "log_scales") & (f["bit_class"] == "sign")) | f[PREDICTION_SAMPLE]]
    assert (whole[MULTIPLICITY] == 1).all() and (whole["injection_id"] >= 0).all()
    per_prec = f[f[PREDICTION_SAMPLE]].groupby("precision").size()
    assert set(per_prec.index) == set(df["precision"].dropna()) and per_prec.between(15, 80).all()
    # blanked elsewhere (integers to -1, the records' "none"): site and image metrics; but the
    # theory keeps peak_error, and the degree inference keeps the SH component
    rest = f[single & ~f[PREDICTION_SAMPLE] & (f["field"] != "log_scales")]
    assert (rest["injection_id"] == -1).all() and rest["psnr"].isna().all()
    assert (
        rest.loc[rest["field"] == "sh_rest", "component"].max() == df.loc[df["field"] == "sh_rest", "component"].max()
    )
    theory = f[single & (f["field"] == "log_scales") & (f["defense"] == "none") & (f["bit_class"] == "mantissa")]
    assert theory["peak_error"].notna().all()


def test_the_prediction_sample_does_not_depend_on_part_order(run):
    rd, df = run
    s = prepare(df[(df["campaign"] == "single")])
    share = {("strict", p): 0.25 for p in ("fp32", "fp16", "bf16")}
    # nor on how a part stores its site columns
    d = s.assign(injection_id=s["injection_id"].astype(float))
    np.testing.assert_array_equal(draw_share(d), draw_share(s))
    a = folding.fold_part(s, share)
    b = folding.fold_part(s.iloc[::-1], share)
    key = ["scene", "precision", "injection_id"]
    ka = a.loc[a[PREDICTION_SAMPLE], key].sort_values(key).reset_index(drop=True)
    kb = b.loc[b[PREDICTION_SAMPLE], key].sort_values(key).reset_index(drop=True)
    pd.testing.assert_frame_equal(ka, kb)
    assert 0.15 < len(ka) / (s["defense"] == "none").sum() < 0.35


def test_sites_split_across_parts_are_refused(run, tmp_path):
    _, df = run
    single = df[df["campaign"] == "single"]
    rd = tmp_path / "split"
    (rd / "records").mkdir(parents=True)
    (rd / "manifest.json").write_text(json.dumps({"spec": {"scenes": list(SCENES)}}))
    half = len(single) // 2 + 1  # the cut falls inside one site's five defenses
    single.iloc[:half].to_parquet(rd / "records" / "part-00000.parquet", index=False)
    single.iloc[half:].to_parquet(rd / "records" / "part-00001.parquet", index=False)
    with pytest.raises(ValueError, match="defenses lie in different parts"):
        load_runs([rd], fold=True)
    assert n_records(load_runs([rd])[0]) == len(single)  # unfolded, they pair wherever they lie


def test_runs_too_big_even_folded_are_refused_before_loading(run, monkeypatch):
    from seuwgpu.errors import TooBig
    from seuwgpu.report.build import FOLDED_BYTES_PER_RECORD, check_report_memory

    rd, df = run
    assert check_report_memory([rd], folded=True) == len(df)
    monkeypatch.setenv("SEUWGPU_HOST_MEMORY", str(len(df) * FOLDED_BYTES_PER_RECORD // 2))
    with pytest.raises(TooBig, match="even folded as read.*seuwgpu rates"):
        load_runs([rd], fold=True)


def test_partly_paired_sites_and_mixed_parts_fold_alike(run, tmp_path, undrawn_figures):
    """Sites missing some defenses (the mitigation table's shared grid, the guard's pairs) and
    parts that mix single upsets with dose records (whose pairing columns are empty)."""
    _, df = run
    single = df[df["campaign"] == "single"]
    rng = np.random.default_rng(5)
    drop = set(rng.choice(single["injection_id"].unique(), 300, replace=False))
    gone = single["injection_id"].isin(drop) & single["defense"].isin(["guard", "ecc"])
    mixed = pd.concat([single[~gone], df[df["campaign"] == "dose"]], ignore_index=True)
    rd = tmp_path / "mixed"
    (rd / "records").mkdir(parents=True)
    (rd / "manifest.json").write_text(json.dumps({"spec": {"scenes": list(SCENES), "sh_degree": 3}}))
    for i, (_, g) in enumerate(mixed.groupby("scene", sort=False)):  # dose rows share a part
        g.to_parquet(rd / "records" / f"part-{i:05d}.parquet", index=False)
    out = {f: build_report([rd], tmp_path / f"r{f}", fold=bool(f)).parent for f in (0, 1)}
    a, b = _tables(out[0]), _tables(out[1])
    assert set(a) == set(b) and {"mitigation.csv", "guard_paired.csv"} <= set(a)
    for name in a:
        _same_table(name, a[name], b[name])
    sa, sb = (json.loads((out[f] / "summary.json").read_text()) for f in (0, 1))
    _same_numbers(sa["numbers"], sb["numbers"], "numbers")
    # the shared grid left the sites without ecc out
    none32 = mixed[(mixed["defense"] == "none") & (mixed["precision"] == "fp32")]
    shared = none32["injection_id"].isin(mixed.loc[mixed["defense"] == "ecc", "injection_id"])
    assert a["mitigation.csv"]["n"].iloc[0] == shared.sum() < len(none32)


@pytest.mark.parametrize("fold", [False, True])
def test_an_unreadable_part_is_named(tmp_path, fold):
    from seuwgpu.errors import InputError

    (tmp_path / "run" / "records").mkdir(parents=True)
    (tmp_path / "run" / "records" / "part-00000.parquet").write_text("not parquet")
    with pytest.raises(InputError, match="part-00000.parquet: not a readable record part"):
        load_runs([tmp_path / "run"], fold=fold)


def test_several_runs_fold_alike(run, tmp_path, undrawn_figures):
    """Two runs, with the prediction on a sample (max_pred_rows=1000 of 4,608 records at fp32):
    the folded report says what the records report says. (A single run's sampled prediction was
    a test of its own, test_folded_report_equals_the_records_report[1000]: the shares are summed
    over the runs' parts in the same loop for one run or two, so this covers it.)"""
    import shutil

    rd, df = run
    other = tmp_path / "other" / "run"  # the same folder name: the report labels it run#2
    shutil.copytree(rd, other)
    # as another spec's run (the same spec's parts twice are refused: the same sites twice)
    m = json.loads((other / "manifest.json").read_text())
    (other / "manifest.json").write_text(json.dumps(dict(m, spec_hash="another")))
    out = {f: build_report([rd, other], tmp_path / f"r{f}", max_pred_rows=1000, fold=bool(f)).parent for f in (0, 1)}
    sa, sb = _same_reports(out[0], out[1], 2 * len(df))
    _same_numbers(sa["runs"], sb["runs"], "runs")
    assert sa["provenance"]["runs"] == ["run", "run#2"]
    n_train = pd.read_csv(out[0] / "prediction.csv")["n_train"].iloc[0]
    assert n_train <= 700  # 70% of the sample of 1,000 trains


def test_parts_folded_by_worker_processes_give_the_same_frame(run):
    """Folding parts in spawned worker processes (load_runs workers=2) returns the very frame of
    folding them in this process: the same rows in the same order, the same counts."""
    rd, df = run
    a, ma = load_runs([rd], fold=True, workers=1)
    b, mb = load_runs([rd], fold=True, workers=2)
    pd.testing.assert_frame_equal(a, b)
    assert a.attrs == b.attrs and a.attrs["folded"]["records"] == len(df)
    assert [m["_n_records"] for m in ma] == [m["_n_records"] for m in mb] == [len(df)]


def test_a_worker_s_error_reaches_the_caller(tmp_path):
    from seuwgpu.errors import InputError

    (tmp_path / "run" / "records").mkdir(parents=True)
    (tmp_path / "run" / "records" / "part-00000.parquet").write_text("not parquet")
    with pytest.raises(InputError, match="part-00000.parquet: not a readable record part"):
        load_runs([tmp_path / "run"], fold=True, workers=2)


def test_fold_workers_default_and_bounds():
    import os

    from seuwgpu.report.build import PARALLEL_MIN_PARTS, fold_workers

    assert fold_workers(PARALLEL_MIN_PARTS - 1) == 1  # a small run stays in this process
    assert fold_workers(PARALLEL_MIN_PARTS) == min(8, len(os.sched_getaffinity(0)))
    assert fold_workers(10, workers=3) == 3
    with pytest.raises(ValueError, match="at least 1"):
        fold_workers(10, workers=0)


def test_the_readme_says_how_equal_the_folded_numbers_are():
    """The README said a folded report gives "the same numbers"; a mean of measured values
    (time_ms, and the time overhead from it) can differ in its last digits (this module's
    records with time_ms drawn from 1.9, 2.1, 2.3: mitigation time_ms 2.1113163087979734 unfolded,
    2.111316308797974 folded; the time overhead 3e-13 apart, relative), so it says that."""
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    row = next(line for line in readme.splitlines() if line.startswith("| `seuwgpu report "))
    assert "(the same numbers)" not in row
    assert "time_ms" in row and "last digits" in row
