"""End-to-end: a small synthetic campaign (manifest + parquet parts) -> report files and tables."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from seuwgpu.model import encoding
from seuwgpu.report.build import build_report, criticality_table_text, load_runs, markdown_table

FIELD_COMPS = {"means": 3, "log_scales": 3, "quats": 4, "opacity": 1, "sh_dc": 3, "sh_rest": 45}
DEFS = ("none", "guard", "selective", "ecc", "dup")
SCENES = {"lego": 1000, "ficus": 2000}


def _single_rows(rng, per_cell=4):
    """Single-upset records with a planted criticality structure (all fields/bits/precisions,
    five defenses per injection)."""
    rows = []
    inj = 0
    for scene, n_prims in SCENES.items():
        for prec in encoding.PRECISIONS:
            man, exp = encoding.LAYOUT[prec]
            nb = encoding.BITS[prec]
            for field, ncomp in FIELD_COMPS.items():
                for bit in range(nb):
                    cls = encoding.bit_class(prec, bit)
                    for _ in range(per_cell):
                        inj += 1
                        clean = float(rng.normal(-3.0 if field == "log_scales" else 0.2, 0.5))
                        # planted severity
                        if field == "log_scales" and cls == "sign":
                            fp, peak = 0.2 + 0.1 * rng.random(), 0.9
                        elif field == "log_scales" and cls == "exponent" and bit >= man + exp - 2:
                            fp, peak = 0.05 + 0.05 * rng.random(), 0.8
                        elif cls == "mantissa":
                            rel = 2.0 ** (bit - man)
                            peak = min(0.5 * rel, 0.3) if field != "sh_rest" else 0.0
                            fp = min(1e-3 * rel, 0.005) if field != "sh_rest" else 0.0
                        else:
                            fp, peak = 1e-4 * rng.random(), 0.01
                        nonfinite = bool(field == "sh_dc" and cls == "exponent" and bit == man + exp - 1)
                        for d in DEFS:
                            f, pk, nf = fp, peak, nonfinite
                            if d in ("guard", "ecc", "dup") or (
                                d == "selective" and field in ("log_scales", "opacity")
                            ):
                                if f > 0.01 or nf:
                                    f, pk, nf = 0.002, 0.05, False
                            if d in ("ecc", "dup") and cls != "mantissa":
                                f, pk = 0.0, 0.0
                            if d == "dup":
                                f, pk = 0.0, 0.0
                            psnr = (
                                math.inf
                                if pk == 0
                                else (5.0 if nf else 20 - 20 * math.log10(pk + 1e-9) - 10 * math.log10(f + 1e-9) / 2)
                            )
                            rows.append(
                                {
                                    "scene": scene,
                                    "n_primitives": n_prims,
                                    "precision": prec,
                                    "field": field,
                                    "primitive": int(rng.integers(n_prims)),
                                    "component": int(rng.integers(ncomp)),
                                    "bit": bit,
                                    "bit_class": cls,
                                    "clean_value": clean,
                                    "corrupted_value": -clean if cls == "sign" else clean * 1.01,
                                    "defense": d,
                                    "footprint": f,
                                    "footprint_max": min(1.0, 2 * f),
                                    "peak_error": pk,
                                    "psnr": psnr,
                                    "ssim": 1.0 - f,
                                    "nonfinite": nf,
                                    "catastrophic": bool(f > 0.01 or nf),
                                    "clamps": int(d == "guard" and fp > 0.01),
                                    "k": 1,
                                    "seed": 7,
                                    "injection_id": inj,
                                    "campaign": "single",
                                    "repeat": 0,
                                    "time_ms": 2.0 if d == "none" else 2.1,
                                    "regions_pred_4": 15 if f > 0.01 else 1,
                                    "regions_meas_4": 15 if f > 0.01 else (1 if f > 0 else 0),
                                    "regions_pred_16": (1 << 16) - 1 if f > 0.01 else 3,
                                    "regions_meas_16": (1 << 16) - 1 if f > 0.01 else (1 if f > 0 else 0),
                                }
                            )
    return rows


def _dose_rows(rng, repeats=3):
    rows = []
    inj = 10_000_000
    pc = {"none": 0.01, "guard": 0.0005}
    for scene, n_prims in SCENES.items():
        for prec in encoding.PRECISIONS:
            for d in ("none", "guard"):
                for k in (1, 10, 100, 1000, 10000):
                    for r in range(repeats):
                        inj += 1
                        base = (65 if d == "none" else 80) - (12 if d == "none" else 5) * math.log10(k)
                        base += 5 * math.log10(n_prims / 1000)
                        cat = bool(rng.random() < 1 - (1 - pc[d]) ** k)
                        rows.append(
                            {
                                "scene": scene,
                                "n_primitives": n_prims,
                                "precision": prec,
                                "field": "means" if k == 1 else "mixed",
                                "primitive": -1 if k > 1 else 0,
                                "component": -1 if k > 1 else 0,
                                "bit": -1 if k > 1 else 3,
                                "bit_class": "mixed" if k > 1 else "mantissa",
                                "clean_value": 0.0,
                                "corrupted_value": 0.0,
                                "defense": d,
                                "footprint": 0.2 if cat else 0.001,
                                "footprint_max": 0.3,
                                "peak_error": 0.5,
                                "psnr": base + rng.normal(0, 1),
                                "ssim": 0.9,
                                "nonfinite": False,
                                "catastrophic": cat,
                                "clamps": 0,
                                "k": k,
                                "seed": 1,
                                "injection_id": inj,
                                "campaign": "dose",
                                "repeat": r,
                                "time_ms": 3.0,
                            }
                        )
    return rows


def _size_rows(rng):
    rows = []
    inj = 20_000_000
    for n in (1000, 4000, 16000):
        for d in ("none", "guard"):
            for _i in range(30):
                inj += 1
                mse = 1e-4 * (n / 1000.0) ** -1.0 * math.exp(rng.normal(0, 0.1))
                rows.append(
                    {
                        "scene": "lego",
                        "n_primitives": n,
                        "precision": "fp32",
                        "field": "means",
                        "primitive": 0,
                        "component": 0,
                        "bit": 10,
                        "bit_class": "mantissa",
                        "clean_value": 0.1,
                        "corrupted_value": 0.1,
                        "defense": d,
                        "footprint": 0.001,
                        "footprint_max": 0.002,
                        "peak_error": 0.01,
                        "psnr": -10 * math.log10(mse),
                        "ssim": 0.99,
                        "nonfinite": False,
                        "catastrophic": False,
                        "clamps": 0,
                        "k": 1,
                        "seed": 2,
                        "injection_id": inj,
                        "campaign": "size",
                        "repeat": 0,
                    }
                )
    return rows


def write_run(run_dir: Path, df: pd.DataFrame, parts: int = 2, spec_hash: str = "abc123") -> Path:
    (run_dir / "records").mkdir(parents=True, exist_ok=True)
    manifest = {
        "spec": {"scenes": list(SCENES), "sh_degree": 3},
        "spec_hash": spec_hash,
        "version": "0.1.0",
        "git_commit": "deadbeef",
        "adapter": {"name": "llvmpipe (LLVM)", "backend": "Vulkan"},
    }
    (run_dir / "manifest.json").write_text(json.dumps(manifest))
    for i, chunk in enumerate(np.array_split(np.arange(len(df)), parts)):
        df.iloc[chunk].to_parquet(run_dir / "records" / f"part-{i:05d}.parquet", index=False)
    return run_dir


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    rng = np.random.default_rng(0)
    single = pd.DataFrame(_single_rows(rng))
    dose = pd.DataFrame(_dose_rows(rng))
    size = pd.DataFrame(_size_rows(rng))
    base = tmp_path_factory.mktemp("runs")
    full = write_run(base / "run_full", pd.concat([single, dose, size], ignore_index=True))
    # a run without dose rows and without optional columns (campaign, repeat, time_ms)
    nodose = single.drop(columns=["campaign", "repeat", "time_ms"])
    nodose = nodose.drop(columns=[c for c in nodose if c.startswith("regions_")])
    lean = write_run(base / "run_single", nodose, spec_hash="lean01")  # another spec: load_runs may pool them
    return {"full": full, "single": lean, "base": base, "single_df": single}


def test_load_runs_concatenates_parts(synthetic):
    df, manifests = load_runs([synthetic["full"]])
    assert len(manifests) == 1 and manifests[0]["spec_hash"] == "abc123"
    assert manifests[0]["_n_records"] == len(df)
    assert set(df["campaign"]) == {"single", "dose", "size"}
    df2, _ = load_runs([synthetic["single"]])
    # missing optional columns are tolerated and filled
    assert {"campaign", "repeat", "time_ms", "run"} <= set(df2.columns)
    assert set(df2["campaign"]) == {"single"}
    both, ms = load_runs([synthetic["full"], synthetic["single"]])
    assert len(both) == len(df) + len(df2) and len(ms) == 2


def test_end_to_end_report(synthetic, tmp_path):
    out = tmp_path / "report"
    index = build_report([synthetic["full"]], out, max_pred_rows=20_000)
    assert index == out / "index.html" and index.is_file()
    page = index.read_text()
    assert "data:image/png;base64," in page
    for fig in (
        "fig_heatmap",
        "fig_precision",
        "fig_theory",
        "fig_guard",
        "fig_dose",
        "fig_budget",
        "fig_size",
        "fig_reliability",
        "fig_contamination",
        "fig_roc",
        "fig_mitigation",
    ):
        assert (out / f"{fig}.png").stat().st_size > 1000, fig
    for tab in (
        "claims",
        "outcomes",
        "outcomes_long",
        "scenes",
        "criticality",
        "field_bit",
        "precision_rates",
        "theory",
        "theory_fit",
        "guard_summary",
        "guard_paired",
        "guard_sign_psnr",
        "mitigation",
        "dose_curves",
        "redundancy_budget",
        "size_scaling",
        "size_fits",
        "reliability_pc",
        "mtbf",
        "mtbf_detail",
        "dose_fits",
        "contamination",
        "prediction",
        "prediction_importance",
        "prediction_loso",
    ):
        assert (out / f"{tab}.csv").is_file(), tab
        md = (out / f"{tab}.md").read_text()
        assert "Rests on" in md and "|" in md, tab
    for f in ("report.md", "summary.json", "skipped.csv"):
        assert (out / f).is_file()

    crit = pd.read_csv(out / "criticality.csv")
    assert list(crit["field"]) == list(FIELD_COMPS)
    assert (crit["n"] == 2 * 32 * 4).all()  # 2 scenes x 32 bits x 4 per cell at fp32
    ls = crit.set_index("field").loc["log_scales"]
    assert ls["catastrophic"] == 2 * 3 * 4  # sign + top-2 exponent bits, 2 scenes
    fb = pd.read_csv(out / "field_bit.csv")
    assert len(fb) == 6 * (32 + 16 + 16)
    mit = pd.read_csv(out / "mitigation.csv")
    assert list(mit["defense"]) == list(DEFS)
    assert mit.set_index("defense").loc["dup", "catastrophic"] == 0
    assert mit.set_index("defense").loc["dup", "memory_overhead_pct"] == pytest.approx(200)
    assert mit.set_index("defense").loc["ecc", "memory_overhead_pct"] == pytest.approx(100 * 5 / 32)
    mtbf = pd.read_csv(out / "mtbf.csv")  # two scenes: 3 environments each, never one averaged model
    assert len(mtbf) == 2 * 3 and {"none (single-upset p_c)", "guard (single-upset p_c)"} <= set(mtbf.columns)
    assert list(mtbf["scene"].unique()) == list(SCENES)
    dc = pd.read_csv(out / "dose_curves.csv")
    assert len(dc) == 2 * 3 * 2 * 5  # models x precisions x defenses x k: models never averaged
    bud = pd.read_csv(out / "redundancy_budget.csv")
    assert len(bud) == 2 * 3 * 2 + 1 * 1 * 0  # scenes x precisions x defenses
    fits = pd.read_csv(out / "size_fits.csv")
    med = fits[(fits["metric"] == "median_mse") & (fits["defense"] == "none")]
    assert med["alpha"].iloc[0] == pytest.approx(1.0, abs=0.1)
    cont = pd.read_csv(out / "contamination.csv")
    assert set(cont["P"]) == {4, 16}

    summary = json.loads((out / "summary.json").read_text())
    skipped = [s["analysis"] for s in summary["skipped"]]
    assert not any(s.startswith("Dose response") for s in skipped)
    assert "Slowest-region render time and load imbalance" in skipped
    assert summary["numbers"]["guard_residual_catastrophic"] == 0
    assert 0.9 <= summary["numbers"]["pred_auc"][0] <= 1.0
    # the report opens with the summary (report/summary.py), then the claims table
    assert summary["sections"][:2] == ["summary", "claims"]
    assert page.index("id='summary'") < page.index("id='claims'") < page.index("id='outcomes'")


def test_skipped_when_no_dose_rows(synthetic, tmp_path, undrawn_figures):
    out = tmp_path / "report"
    # an earlier report in the same folder wrote dose files: they must not survive as stale
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"files": ["dose_curves.csv", "fig_dose.png"]}))
    (out / "dose_curves.csv").write_text("stale")
    (out / "fig_dose.png").write_bytes(b"stale")
    (out / "notes.txt").write_text("a user's file")
    build_report([synthetic["single"]], out, max_pred_rows=20_000)
    assert not (out / "fig_dose.png").exists()
    assert (out / "notes.txt").read_text() == "a user's file"
    summary = json.loads((out / "summary.json").read_text())
    assert "criticality.csv" in summary["files"]
    skipped = {s["analysis"]: s for s in summary["skipped"]}
    dose = skipped["Dose response (quality and catastrophes against k)"]
    assert "k > 1" in dose["missing"] and "dose campaign" in dose["remedy"]
    assert "Redundancy budget" in skipped
    assert "size campaign" in skipped["Single-upset error against N"]["remedy"]
    assert "Distributed contamination" in skipped
    assert not (out / "dose_curves.csv").exists()
    page = (out / "index.html").read_text()
    assert "Skipped analyses" in page and "run a dose campaign" in page
    # what does not need dose rows is still there
    for tab in ("criticality", "mitigation", "mtbf", "prediction"):
        assert (out / f"{tab}.csv").is_file()


def test_criticality_table_text(synthetic):
    df, _ = load_runs([synthetic["full"]])
    txt = criticality_table_text(df)
    assert "fp32" in txt and "95% interval" in txt
    lines = [ln for ln in txt.splitlines() if ln.startswith("| ")]
    assert len(lines) == 1 + 6  # header + six fields
    assert "log-scale" in txt and "color (SH)" in txt


def test_markdown_table_formatting():
    md = markdown_table(pd.DataFrame({"a": ["x|y", "z"], "b": [0.000123456, float("nan")], "c": [1, 2]}))
    lines = md.strip().splitlines()
    assert lines[0] == "| a | b | c |"
    assert "x\\|y" in lines[2] and "0.0001235" in lines[2] and "n/a" in lines[3]


def test_only_single_defense_skips_mitigation(synthetic, tmp_path, undrawn_figures):
    df = synthetic["single_df"]
    df = df[(df["defense"] == "none") & (df["precision"] == "fp32")]
    run = write_run(tmp_path / "run_none", df, parts=1)
    out = tmp_path / "rep"
    build_report([run], out, max_pred_rows=5_000)
    summary = json.loads((out / "summary.json").read_text())
    skipped = {s["analysis"] for s in summary["skipped"]}
    assert {"Mitigation table", "Guard evaluation", "Per-precision catastrophe rates"} <= skipped
    assert (out / "criticality.csv").is_file()


def test_a_report_too_big_for_memory_is_refused_before_loading(synthetic, tmp_path, monkeypatch):
    from seuwgpu.errors import TooBig
    from seuwgpu.report.build import REPORT_BYTES_PER_RECORD, check_report_memory

    n = check_report_memory([synthetic["full"]])
    assert n == len(load_runs([synthetic["full"]])[0])  # counted from the footers, nothing loaded
    monkeypatch.setenv("SEUWGPU_HOST_MEMORY", str(n * REPORT_BYTES_PER_RECORD // 2))
    with pytest.raises(TooBig, match=f"{n:,} records needs .*seuwgpu rates"):
        load_runs([synthetic["full"]])
    # the report then folds the records as it reads them (tests/test_folding.py); these records,
    # written without weights, cannot be folded, and it says so before writing anything
    with pytest.raises(ValueError, match="without weights .* cannot be folded"):
        build_report([synthetic["full"]], tmp_path / "rep")
    assert not (tmp_path / "rep" / "index.html").exists()


def test_a_report_reads_each_manifest_and_footer_once(synthetic, tmp_path, monkeypatch):
    """The refusal of repeated sites, the memory check, the loading and the unfinished-run
    sentence share one read of each run's manifest and of each part's footer."""
    from seuwgpu.campaign import store
    from seuwgpu.report import build

    reads, footers = [], []
    read_manifest, part_rows = store.read_manifest, store.part_rows
    monkeypatch.setattr(store, "read_manifest", lambda rd: reads.append(Path(rd).name) or read_manifest(rd))
    monkeypatch.setattr(store, "part_rows", lambda p: footers.append(str(p)) or part_rows(p))
    monkeypatch.setattr(build, "run_sections", lambda df, manifests, ctx: [])  # the analyses read nothing
    build_report([synthetic["full"], synthetic["single"]], tmp_path / "rep", max_pred_rows=5_000)
    assert sorted(reads) == ["run_full", "run_single"]
    assert len(footers) == 4 and len(set(footers)) == 4  # two parts each


def test_tables_of_an_unfinished_run_say_so(synthetic, tmp_path, undrawn_figures):
    """The criticality table `seuwgpu report` prints, and every table file of the report, say that
    the run is unfinished (not only the page's header): a table copied out of the report, or read
    on the terminal, must not pass for the spec's population."""
    from seuwgpu.campaign import store

    single = synthetic["single_df"]
    run = tmp_path / "half"
    store.records_dir(run).mkdir(parents=True)
    store.write_part(run, 0, len(single), single)
    (run / "manifest.json").write_text(json.dumps({"total_injections": 3 * len(single)}))
    df, _ = load_runs([run])
    txt = criticality_table_text(df[df["k"] == 1])
    assert f"Unfinished: half holds {len(single):,} of {3 * len(single):,} injections" in txt
    out = tmp_path / "report"
    build_report([run], out, max_pred_rows=20_000)
    for name in ("criticality.md", "field_bit.md", "guard_paired.md"):
        assert "Unfinished: half holds" in (out / name).read_text(), name
    # a finished run's tables carry no such line
    done, _ = load_runs([synthetic["full"]])
    assert "Unfinished" not in criticality_table_text(done)


def test_dose_numbers_name_their_model_when_several():
    """summary.json's dose numbers at the largest k: with several models, one per model (keyed as
    p_c's). They were one row chosen by sort order (the last scene at the largest N), unnamed: the
    CPU study's dose_psnr_median_at_kmax_guard_db was yashica-t4's 17.6 dB, beside blocks' 13.5."""
    from seuwgpu.report.sections.dose import dose_section

    rows = []
    for scene, psnr in (("a", 40.0), ("b", 20.0)):
        for d in ("none", "guard"):
            for k in (1, 10):
                for r in range(10):
                    bad = scene == "a" and d == "none" and k == 10 and r < 3
                    rows.append(
                        {
                            "scene": scene,
                            "n_primitives": 1000,
                            "precision": "fp32",
                            "field": "mixed",
                            "bit": -1,
                            "defense": d,
                            "k": k,
                            "repeat": r,
                            "campaign": "dose",
                            "footprint": 0.001,
                            "peak_error": 0.1,
                            "psnr": math.nan if bad else psnr + (d == "guard") + r * 0.1,
                            "ssim": 0.9,
                            "nonfinite": bad,
                            "weight": 1.0,
                        }
                    )
    df = pd.DataFrame(rows)
    num = dose_section(df, [], {"results": {}, "skipped": []}).numbers
    assert not any(k.startswith("dose_psnr_median_at_kmax_none") for k in num)  # no unnamed model
    for scene in ("a", "b"):
        for d in ("none", "guard"):
            g = df[(df["scene"] == scene) & (df["defense"] == d) & (df["k"] == 10)]
            ranked = np.sort(np.where(g["nonfinite"], -np.inf, g["psnr"]))
            assert num[f"dose_psnr_median_at_kmax_{scene}_{d}_db"] == ranked[(len(g) - 1) // 2]
            assert num[f"dose_nonfinite_at_kmax_{scene}_{d}_pct"] == pytest.approx(100 * g["nonfinite"].mean())
        assert num[f"dose_kmax_{scene}"] == 10
    one = dose_section(df[df["scene"] == "a"], [], {"results": {}, "skipped": []}).numbers
    assert one["dose_kmax"] == 10 and one["dose_nonfinite_at_kmax_none_pct"] == pytest.approx(30)


def test_a_folder_of_visible_damage_records_alone_is_refused_saying_what_it_holds(tmp_path, capsys):
    """`defenses --visible N --out RUN` into a fresh folder keeps records a report shows beside a
    campaign's: reporting the folder alone says so, instead of only that part files are missing."""
    import pandas as pd

    from seuwgpu.apps.cli import main
    from seuwgpu.campaign import store

    run = tmp_path / "run"
    path = store.visible_path(run, "m")
    path.parent.mkdir(parents=True)
    pd.DataFrame({"defense": ["none"], "catastrophic_frames": [1]}).to_parquet(path)
    assert main(["report", str(run), "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert "no records/part-*.parquet (it holds visible-damage records alone" in err
    (tmp_path / "empty").mkdir()
    assert main(["report", str(tmp_path / "empty"), "--out", str(tmp_path / "rep")]) == 2
    assert "visible-damage" not in capsys.readouterr().err
