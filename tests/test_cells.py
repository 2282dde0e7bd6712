"""Records folded into stratum cells part by part (analysis/cells.py) give the rates, intervals
and counts of the records themselves, checked against estimate.rate on the whole frame and
against a plain pandas recomputation of the weighted rates."""

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from seuwgpu.analysis import cells as C
from seuwgpu.analysis import estimate as E
from seuwgpu.campaign import store
from seuwgpu.errors import InputError
from seuwgpu.metrics.image import OUTCOMES


def synthetic_records(rng, n: int, weight_scale: float) -> pd.DataFrame:
    """Stratified-looking records: the weight is constant per (scene, precision, field, bit) cell
    (as the runner writes it), outcomes random with cell-dependent rates."""
    scene = rng.choice(["a", "b"], n)
    precision = rng.choice(["fp32", "fp16"], n)
    field = rng.choice(["means", "opacity", "sh_rest"], n)
    bit = rng.integers(0, 4, n)
    ncomp = pd.Series(field).map({"means": 3, "opacity": 1, "sh_rest": 45}).to_numpy()
    p_cat = 0.02 + 0.2 * (bit == 3) + 0.1 * (field == "opacity")
    u = rng.random(n)
    outcome = np.where(u < p_cat, "catastrophic", np.where(u < 0.4, "sdc", np.where(u < 0.7, "tolerable", "masked")))
    return pd.DataFrame(
        {
            "campaign": rng.choice(["single", "single", "single", "size"], n),
            "k": np.where(rng.random(n) < 0.95, 1, 3),
            "scene": scene,
            "n_primitives": np.where(scene == "a", 500, 800),
            "precision": precision,
            "field": field,
            "bit": bit,
            "defense": rng.choice(["none", "guard"], n),
            "weight": weight_scale * ncomp * np.where(scene == "a", 500, 800) / 7.0,
            "outcome": outcome,
            "nonfinite": (outcome == "catastrophic") & (rng.random(n) < 0.5),
        }
    )


@pytest.fixture
def runs(tmp_path):
    """Two run directories of parts (no manifest: every part file counts), with different
    per-record weights, as runs of different sample sizes have."""
    rng = np.random.default_rng(12)
    dirs, frames = [], []
    for r, scale in enumerate((1.0, 0.37)):
        d = tmp_path / f"run{r}"
        store.records_dir(d).mkdir(parents=True)
        for j in range(5):
            df = synthetic_records(rng, 400, scale)
            store.write_part(d, 400 * j, 400, df)
            frames.append(df.assign(run=d.name))
        dirs.append(d)
    return dirs, pd.concat(frames, ignore_index=True)


@pytest.mark.parametrize("by", [["precision", "defense"], ["run", "scene"], []])
def test_folded_cells_give_the_records_rates(runs, by, monkeypatch):
    monkeypatch.setattr(C, "FOLD_EVERY", 2)  # exercise the re-folding of accumulated cells
    dirs, records = runs
    seen = []
    cells, n_parts = C.fold_runs(dirs, by, progress=lambda i, n: seen.append((i, n)))
    assert n_parts == 10 and seen[-1] == (10, 10)
    single = records[(records.campaign == "single") & (records.k == 1)]
    assert cells["n_records"].sum() == len(single)
    assert len(cells) < len(single) / 5  # folded
    for y in (*OUTCOMES, "nonfinite"):
        ref = E.rate(single.assign(**{o: single.outcome == o for o in OUTCOMES}), y, by)
        got = E.rate(cells, y, by)
        if by:
            got = got.set_index(by).loc[ref.set_index(by).index].reset_index()
        assert got["n"].tolist() == ref["n"].tolist() and got["events"].tolist() == ref["events"].tolist()
        for col in ("weight", "rate", "ci_lo", "ci_hi", "n_eff"):
            np.testing.assert_allclose(got[col].to_numpy(float), ref[col].to_numpy(float), rtol=1e-12, err_msg=col)
        assert got["method"].tolist() == ref["method"].tolist()


def test_rates_command_matches_pandas(runs, tmp_path):
    dirs, records = runs
    out = tmp_path / "rates.csv"
    cmd = [sys.executable, "-m", "seuwgpu", "rates", *map(str, dirs), "--by", "precision", "--csv", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "catastrophic" in res.stdout and "fp16" in res.stdout
    got = pd.read_csv(out).set_index(["precision", "defense"])  # defenses are never pooled
    single = records[(records.campaign == "single") & (records.k == 1)]
    for prec, g in single.groupby(["precision", "defense"]):
        w = g["weight"].to_numpy()
        for o in OUTCOMES:
            want = (w * (g["outcome"] == o)).sum() / w.sum()  # the weighted rate, recomputed plainly
            assert got.loc[prec, f"{o}_rate"] == pytest.approx(want, rel=1e-12)
            assert got.loc[prec, f"{o}_ci_lo"] <= want <= got.loc[prec, f"{o}_ci_hi"]
        assert got.loc[prec, "n"] == len(g)
    deep = tmp_path / "new" / "dir" / "rates.csv"  # --csv creates its folder
    res = subprocess.run([*cmd[:-1], str(deep)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and pd.read_csv(deep).equals(pd.read_csv(out))
    typo = subprocess.run([*cmd[:-4], "--by", "precison"], capture_output=True, text=True, timeout=300)
    assert typo.returncode == 2 and "--by precison: not a record column" in typo.stderr
    assert "Traceback" not in typo.stderr


def test_missing_columns_and_empty_runs_are_clear_errors(tmp_path):
    d = tmp_path / "old"
    store.records_dir(d).mkdir(parents=True)
    store.write_part(d, 0, 2, pd.DataFrame({"campaign": ["single"] * 2, "k": [1, 1], "scene": ["a", "a"]}))
    with pytest.raises(ValueError, match="records lack .*weight.*seuwgpu report"):
        C.fold_runs([d])
    with pytest.raises(FileNotFoundError, match="no records"):
        C.fold_runs([tmp_path / "old" / "records"])
    with pytest.raises(FileNotFoundError, match="not a run directory"):
        C.fold_runs([tmp_path / "missing"])


def test_runs_sharing_a_folder_name_stay_apart(runs, tmp_path):
    """Two runs in folders of one name are two runs (labelled as the report labels them)."""
    dirs, records = runs
    twin = tmp_path / "elsewhere" / dirs[0].name
    store.records_dir(twin).mkdir(parents=True)
    store.write_part(twin, 0, 400, records[records.run == dirs[0].name].iloc[:400].drop(columns="run"))
    assert store.run_names([dirs[0], twin, dirs[1]]) == ["run0", "run0#2", "run1"]
    cells, _ = C.fold_runs([dirs[0], twin], ["run"])
    got = cells.groupby("run")["n_records"].sum().to_dict()
    first = records[(records.run == "run0") & (records.campaign == "single") & (records.k == 1)]
    assert got == {"run0": len(first), "run0#2": len(first.loc[first.index < 400])}


def _manifest(run_dir, spec_hash: str, profile: str):
    import json

    store.manifest_path(run_dir).write_text(json.dumps({"spec_hash": spec_hash, "profile": profile}))


def test_the_same_sites_twice_are_refused_unless_grouped_by_run(runs, tmp_path):
    """A run copied (or re-run with the same spec, seed and profile) holds the same sites: pooled,
    n would double and the interval shrink by sqrt(2) with no new information."""
    dirs, records = runs
    copy = tmp_path / "again"
    store.records_dir(copy).mkdir(parents=True)
    first = records[records.run == dirs[0].name].drop(columns="run")
    for j in range(5):
        store.write_part(copy, 400 * j, 400, first.iloc[400 * j : 400 * (j + 1)])
    for d in (dirs[0], copy):
        _manifest(d, "abc", "strict")
    _manifest(dirs[1], "abc", "gsplat")  # the same spec under another profile: other frames
    assert store.repeated_sites([dirs[0], dirs[1], copy]) == [("run0", "again", 5)]
    assert store.repeated_sites([dirs[1], dirs[1]]) == [("run1", "run1#2", 5)]  # one folder twice
    with pytest.raises(InputError, match="run0 and again hold 5 part"):
        C.fold_runs([dirs[0], copy])
    cells, _ = C.fold_runs([dirs[0], copy], ["run"])  # compared side by side: allowed
    assert set(cells["run"]) == {"run0", "again"}
    C.fold_runs([dirs[0], dirs[1]])  # different profiles: not the same sites


def test_profiles_are_never_pooled(runs, tmp_path):
    """Records of two renderer profiles get a row each, equal to each profile's records alone."""
    dirs, records = runs
    mixed = tmp_path / "mixed"
    store.records_dir(mixed).mkdir(parents=True)
    rec = records[records.run == dirs[0].name].drop(columns="run")
    rec = rec.assign(profile=np.where(np.arange(len(rec)) % 3 == 0, "gsplat", "strict"))
    for j in range(5):
        store.write_part(mixed, 400 * j, 400, rec.iloc[400 * j : 400 * (j + 1)])
    cells, _ = C.fold_runs([mixed], ["precision"])
    by = C.groups(cells, ["precision"])
    assert by == ["precision", "defense", "profile"]
    got = C.outcome_rates(cells, by).set_index(by)
    single = rec[(rec.campaign == "single") & (rec.k == 1)]
    for key, g in single.groupby(["precision", "defense", "profile"]):
        ref = E.rate(g.assign(catastrophic=g.outcome == "catastrophic"), "catastrophic")
        assert got.loc[key, "n"] == len(g)
        assert got.loc[key, "catastrophic_rate"] == pytest.approx(ref["rate"].iloc[0], rel=1e-12)
        assert got.loc[key, "catastrophic_ci_hi"] == pytest.approx(ref["ci_hi"].iloc[0], rel=1e-12)
    # one profile (or records from before profiles): no extra column
    assert C.groups(C.fold_runs([dirs[1]], ["precision", "defense"])[0], ["precision", "defense"]) == [
        "precision",
        "defense",
    ]


def test_the_report_refuses_the_same_sites_twice(runs, tmp_path):
    from seuwgpu.report.build import load_runs

    dirs, _ = runs
    for d in dirs:
        _manifest(d, "abc", "strict")
    store.part_path(dirs[1], 0, 400).unlink()  # run1 keeps parts 1..4 in common with run0
    with pytest.raises(InputError, match="run0 and run1 hold 4 part"):
        load_runs(dirs)


def test_rates_says_when_a_run_is_unfinished(runs):
    import json

    dirs, _ = runs
    store.manifest_path(dirs[0]).write_text(json.dumps({"total_injections": 2600}))  # 5 parts of 400 written
    assert store.partial_runs_text(dirs).startswith("Unfinished: run0 holds 2,000 of 2,600 injections.")
    cmd = [sys.executable, "-m", "seuwgpu", "rates", *map(str, dirs)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert (
        "Unfinished: run0 holds 2,000 of 2,600 injections" in res.stdout
        and "run1" not in res.stdout.split("Unfinished")[1]
    )


def test_shards_in_folders_of_their_own_are_counted_together(runs, tmp_path):
    """Each shard's manifest plans the whole spec: the shards of one campaign, given together, are
    complete when their parts are, and a missing part is reported once for the group."""
    import json

    dirs, records = runs
    rec = records[records.run == dirs[0].name].drop(columns="run")
    shards = [tmp_path / "exp" / f"shard-{i}" for i in range(2)]
    for i, d in enumerate(shards):
        store.records_dir(d).mkdir(parents=True)
        store.manifest_path(d).write_text(json.dumps({"spec_hash": "s1", "total_injections": 2000}))
        for j in range(i, 5, 2):  # shard 0: parts 0, 2, 4; shard 1: parts 1, 3
            store.write_part(d, 400 * j, 400, rec.iloc[400 * j : 400 * (j + 1)])
    assert store.repeated_sites(shards) == [] and store.partial_runs_text(shards) == ""
    store.part_path(shards[1], 1200, 400).unlink()
    assert store.partial_runs_text(shards).startswith("Unfinished: shard-0 + shard-1 hold 1,600 of 2,000 injections.")
    assert store.partial_runs_text(shards[:1]).startswith("Unfinished: shard-0 holds 1,200 of 2,000")


def test_runs_read_each_manifest_once(runs, monkeypatch, capsys):
    """`seuwgpu rates` reads each run's manifest once (the refusal of repeated sites, the parts and
    the unfinished-run sentence used to read every manifest again)."""
    import json

    from seuwgpu.apps.cli import main

    dirs, _ = runs
    store.manifest_path(dirs[0]).write_text(json.dumps({"total_injections": 2600}))
    reads, real = [], store.read_manifest
    monkeypatch.setattr(store, "read_manifest", lambda rd: reads.append(rd.name) or real(rd))
    assert main(["rates", *map(str, dirs)]) == 0
    assert "Unfinished: run0 holds 2,000 of 2,600 injections" in capsys.readouterr().out
    assert sorted(reads) == ["run0", "run1"]


def test_damaged_parts_do_not_count_toward_completion(runs):
    """A part that cannot be read, or holds fewer rows than its name says, is redone when the
    campaign resumes (store.completed_parts): until then the run is unfinished, and says which."""
    import json

    dirs, records = runs
    run = dirs[0]
    store.manifest_path(run).write_text(json.dumps({"total_injections": 2000}))
    assert store.partial_runs_text([run]) == ""
    cut = store.part_path(run, 800, 400)
    cut.write_bytes(cut.read_bytes()[:200])  # truncated: no Parquet footer
    store.write_part(run, 1600, 400, records[records.run == "run0"].iloc[:300].drop(columns="run"))
    assert store.partial_runs_text([run]).startswith(
        "Unfinished: run0 holds 1,200 of 2,000 injections (2 damaged parts, unreadable or of the wrong row count, "
        "not counted: part-0000000800-000400.parquet, part-0000001600-000400.parquet; resuming the campaign "
        "redoes them). "
    )


SITES_SPEC = {
    "name": "a",
    "seed": 1,
    "views": 1,
    "size": "64x64",
    "batch": 100,
    "scenes": [{"scene": "spheres", "n": 100}],
    "single": {"fields": ["opacity"], "bits": [30, 31], "samples": 200, "defenses": ["none", "guard"]},
}


def _spec_run(run_dir, records, raw: dict, ids=range(0, 400)) -> dict:
    """A run directory of the campaign `raw` (normalised) holding the parts of its blocks whose
    first id is in `ids` (records of the right row count; their values do not matter here)."""
    import json

    from seuwgpu.campaign.spec import normalize_spec
    from seuwgpu.campaign.spec_hash import spec_hash

    spec = normalize_spec(raw)
    store.records_dir(run_dir).mkdir(parents=True)
    manifest = {"spec": spec.to_dict(), "spec_hash": spec_hash(spec), "profile": spec.renderer_profile}
    store.manifest_path(run_dir).write_text(json.dumps({**manifest, "total_injections": 400}))
    rec = records.drop(columns="run")
    for (first, count), rows in store.expected_parts(spec).items():
        if first in ids:
            store.write_part(run_dir, first, count, rec.iloc[:rows])
    return spec


def test_the_same_sites_under_another_spec_hash_are_caught(runs, tmp_path):
    """Specs that differ only in what draws and measures no site (a name, the batch, thresholds,
    LPIPS, region columns, an explicit default profile) have other spec hashes but the same sites
    key: their runs hold the same sites, and pooled would count them twice."""
    from seuwgpu.campaign.spec_hash import sites_key, spec_hash
    from seuwgpu.report.build import load_runs

    _, records = runs
    a = _spec_run(tmp_path / "a", records, SITES_SPEC)
    cosmetic = {
        **SITES_SPEC,
        "name": "b",
        "batch": 50,  # other part boundaries: compared by injection id
        "lpips": True,
        "profile": "strict",
        "outcomes": {"footprint": 0.05},
        "reliability": {"scrub_hours": 1.0},
        "single": {**SITES_SPEC["single"], "regions": [4]},
    }
    b = _spec_run(tmp_path / "b", records, cosmetic, ids=range(0, 150))  # parts 0-49, 50-99, 100-149
    assert spec_hash(a) != spec_hash(b) and sites_key(a) == sites_key(b)
    assert store.repeated_sites([tmp_path / "a", tmp_path / "b"]) == [("a", "b", 3)]
    assert store.repeated_sites([tmp_path / "b", tmp_path / "a"]) == [("b", "a", 2)]  # parts 0-99, 100-199
    with pytest.raises(InputError, match="runs a and b hold 3 part.* same fault sites.*report one of them"):
        load_runs([tmp_path / "a", tmp_path / "b"])
    with pytest.raises(InputError, match="pass one of them, or group by run"):
        C.fold_runs([tmp_path / "a", tmp_path / "b"])
    # the same sites key, other ids (the two halves of the campaign): no site in common
    _spec_run(tmp_path / "half", records, cosmetic, ids=range(200, 400))
    assert store.repeated_sites([tmp_path / "b", tmp_path / "half"]) == []
    # other sites, or other frames: never flagged
    others = {
        "seed": {**SITES_SPEC, "seed": 2},
        "samples": {**SITES_SPEC, "single": {**SITES_SPEC["single"], "samples": 100, "bits": [29, 30, 31, 28]}},
        "defenses": {**SITES_SPEC, "single": {**SITES_SPEC["single"], "defenses": ["none", "ecc"]}},
        "size": {**SITES_SPEC, "size": "64x48"},
        "gsplat": {**SITES_SPEC, "profile": "gsplat"},
    }
    for name, raw in others.items():
        spec = _spec_run(tmp_path / name, records, raw)
        assert sites_key(spec) != sites_key(a) or raw.get("profile") == "gsplat", name
        assert store.repeated_sites([tmp_path / "a", tmp_path / name]) == [], name


def test_a_part_of_the_wrong_row_count_for_its_spec_is_damaged(runs, tmp_path):
    """With a spec, a part is whole when it holds a row per injection and defense."""
    _, records = runs
    _spec_run(tmp_path / "a", records, SITES_SPEC)
    assert store.partial_runs_text([tmp_path / "a"]) == ""
    store.write_part(tmp_path / "a", 100, 100, records.drop(columns="run").iloc[:100])  # one arm of two
    assert store.partial_runs_text([tmp_path / "a"]).startswith(
        "Unfinished: a holds 300 of 400 injections (1 damaged part, unreadable or of the wrong row count, not "
        "counted: part-0000000100-000100.parquet;"
    )


def test_defenses_are_never_pooled(runs):
    """Each fault site is measured once per defense: `rates --by` without `defense` must not pool a
    site's rows under different defenses (that counts every site twice and blends defended with
    undefended frames); like profiles, defenses always get a row each."""
    dirs, records = runs
    cells, _ = C.fold_runs([dirs[0]], ["precision"])
    by = C.groups(cells, ["precision"])
    assert by == ["precision", "defense"]
    got = C.outcome_rates(cells, by).set_index(by)
    rec = records[(records.run == dirs[0].name) & (records.campaign == "single") & (records.k == 1)]
    for (prec, dfn), g in rec.groupby(["precision", "defense"]):
        w = g["weight"].to_numpy()
        want = (w * (g["outcome"] == "catastrophic")).sum() / w.sum()  # the weighted rate, plainly
        assert got.loc[(prec, dfn), "n"] == len(g)
        assert got.loc[(prec, dfn), "catastrophic_rate"] == pytest.approx(want, rel=1e-12)
    # grouping by nothing still splits the defenses; a single defense adds no column
    assert C.groups(C.fold_runs([dirs[0]], [])[0], []) == ["defense"]
    one = dirs[0].parent / "one"
    store.records_dir(one).mkdir(parents=True)
    store.write_part(
        one, 0, 400, records[records.run == dirs[0].name].drop(columns="run").iloc[:400].assign(defense="none")
    )
    assert C.groups(C.fold_runs([one], ["precision"])[0], ["precision"]) == ["precision"]


def test_the_api_rates_are_the_records_weighted_rates(runs):
    """seuwgpu.outcome_rates (what `seuwgpu rates` prints): per group, each outcome's weighted rate
    recomputed plainly from the records, inside its interval; its counts in .attrs."""
    import seuwgpu as sg

    dirs, records = runs
    read = []
    t = sg.outcome_rates(dirs, by=["scene", "scene"], progress=lambda i, n: read.append((i, n)))
    single = records[(records.campaign == "single") & (records.k == 1)]
    assert t.attrs["groups"] == ["scene", "defense"] and t.attrs["parts"] == 10 and read[-1] == (10, 10)
    assert t.attrs["records"] == len(single) and t.attrs["partial"] == ""
    got = t.set_index(["scene", "defense"])
    for key, g in single.groupby(["scene", "defense"]):
        w = g["weight"].to_numpy()
        for o in OUTCOMES:
            want = (w * (g["outcome"] == o)).sum() / w.sum()
            assert got.loc[key, f"{o}_rate"] == pytest.approx(want, rel=1e-12)
            assert got.loc[key, f"{o}_ci_lo"] <= want <= got.loc[key, f"{o}_ci_hi"]
    with pytest.raises(sg.InputError, match="^by precison: not a record column"):
        sg.outcome_rates(dirs, by=["precison"])
