"""Campaigns: spec errors, kill-and-resume, shards, replay by id, stratified sampling."""

import dataclasses
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from seuwgpu.campaign import store
from seuwgpu.campaign.merge import merge
from seuwgpu.campaign.runner import Runner, replay
from seuwgpu.campaign.sampling import enumerate_contexts
from seuwgpu.campaign.schema import COLUMNS, RECORD_SCHEMA, REPRODUCIBLE_COLUMNS
from seuwgpu.campaign.spec import SpecError, load_spec, normalize_spec
from seuwgpu.campaign.store import read_records
from seuwgpu.render.regions import REGION_GRID_VERSION

SPEC = textwrap.dedent("""
    seed = 7
    views = 2
    size = "32x32"
    batch = 24

    [[scenes]]
    scene = "blocks"
    n = 1500

    [single]
    fields = ["log_scales", "opacity", "sh_dc"]
    bits = [0, 22, 23, 30, 31]
    samples = 6
    defenses = ["none", "guard"]

    [dose]
    k = [1, 30]
    repeats = 2
    defenses = ["none", "guard"]
""")


def write_spec(tmp_path, text=SPEC, name="spec.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def canonical(df: pd.DataFrame) -> pd.DataFrame:
    # every column but the wall-clock ones (time_ms) is reproduced bit for bit
    return df.sort_values(["injection_id", "defense"]).reset_index(drop=True)[REPRODUCIBLE_COLUMNS]


@pytest.fixture(scope="module")
def reference_dir(tmp_path_factory):
    """(spec, folder) of one finished, uninterrupted run of SPEC; tests read it, never write it
    (copy it to change it)."""
    tmp = tmp_path_factory.mktemp("ref")
    spec = load_spec(write_spec(tmp))
    Runner(spec, tmp / "run", quiet=True).run()
    return spec, tmp / "run"


@pytest.fixture(scope="module")
def reference_run(reference_dir):
    spec, run = reference_dir
    return spec, canonical(read_records(run))


def test_records_have_the_contract_columns(reference_run):
    spec, df = reference_run
    total = sum(c.count for c in enumerate_contexts(spec))
    assert total == 3 * 5 * 6 + 2 * 2
    assert len(df) == 2 * total
    assert list(df.columns) == REPRODUCIBLE_COLUMNS
    # outcome classes agree with the catastrophic flag and the metrics
    assert set(df["outcome"]) <= {"masked", "tolerable", "sdc", "catastrophic"}
    assert ((df["outcome"] == "catastrophic") == df["catastrophic"]).all()
    assert ((df["outcome"] == "masked") == ((df["peak_error"] == 0) & ~df["nonfinite"])).all()

    assert df.injection_id.nunique() == total
    single = df[df.campaign == "single"]
    # stratified: exactly `samples` injections per (field, bit) cell
    counts = single[single.defense == "none"].groupby(["field", "bit"]).size()
    assert (counts == 6).all() and len(counts) == 15
    # paired arms: same site for every defense
    pairs = single.pivot_table(index="injection_id", columns="defense", values=["primitive", "component", "bit"])
    assert (pairs["primitive"]["none"] == pairs["primitive"]["guard"]).all()
    dose = df[df.campaign == "dose"]
    assert sorted(dose.k.unique()) == [1, 30]
    assert (dose[dose.k > 1].primitive == -1).all() and (dose[dose.k == 1].primitive >= 0).all()
    assert (single.k == 1).all()


def test_records_time_each_defense_and_manifest_states_thresholds(reference_dir):
    _, run = reference_dir  # a fresh run of SPEC (this test ran its own copy of it before)
    raw = read_records(run)
    assert list(raw.columns) == COLUMNS
    t = raw.groupby(["campaign", "scene", "n_primitives", "precision", "defense"])["time_ms"].agg(["min", "nunique"])
    assert (t["min"] > 0).all() and (t["nunique"] == 1).all()  # one measurement per engine and defense
    m = store.read_manifest(run)
    assert m["outcomes"] == {"pixel_threshold": 1 / 255, "footprint_threshold": 0.01}
    assert m["region_grid"] == REGION_GRID_VERSION


def test_sharded_and_merged_equals_unsharded(reference_run, tmp_path):
    spec, ref = reference_run
    dirs = []
    for i in range(3):
        d = tmp_path / f"shard{i}"
        Runner(spec, d, shard=(i, 3), quiet=True).run()
        dirs.append(d)
    # visible-damage records kept in shards (`defenses --visible N --out SHARD`) come along
    kept = {}
    for i, name in ((0, "m0"), (1, "m1"), (2, "m1")):
        path = store.visible_path(dirs[i], name)
        path.parent.mkdir(exist_ok=True)
        pd.DataFrame({"defense": ["none"], "catastrophic_frames": [int(name[1])]}).to_parquet(path)
        kept[name] = path.read_bytes()
    merge(tmp_path / "merged", dirs)
    got = canonical(read_records(tmp_path / "merged"))
    pd.testing.assert_frame_equal(got, ref)
    for name, data in kept.items():
        assert store.visible_path(tmp_path / "merged", name).read_bytes() == data
    # one measurement whose copies differ between shards is refused, naming it
    pd.DataFrame({"defense": ["none"], "catastrophic_frames": [7]}).to_parquet(store.visible_path(dirs[2], "m1"))
    with pytest.raises(SpecError, match="m1.parquet differ"):
        merge(tmp_path / "merged2", dirs)


def test_blocks_evaluated_one_by_one_equal_grouped_ones(reference_run, tmp_path, monkeypatch):
    """The runner evaluates consecutive single-upset blocks in one call (Runner.next_group); with
    groups of one block the records are the same, and each part still holds its own block."""
    spec, ref = reference_run
    monkeypatch.setattr(Runner, "GROUP_BATCHES", 0)  # every group is its first block alone
    groups = []
    real = Runner.run_blocks
    monkeypatch.setattr(
        Runner, "run_blocks", lambda self, eng, ctx, blocks: groups.append(blocks) or real(self, eng, ctx, blocks)
    )
    Runner(spec, tmp_path / "run", quiet=True).run()
    assert groups and all(len(g) == 1 for g in groups)
    pd.testing.assert_frame_equal(canonical(read_records(tmp_path / "run")), ref)
    for path in store.records_dir(tmp_path / "run").glob("part-*.parquet"):
        first, count = store.parse_part_name(path.name)
        ids = pd.read_parquet(path, columns=["injection_id"]).injection_id
        assert set(ids) == set(range(first, first + count)), path.name
    # the reference run grouped: consecutive blocks of one single-upset context, up to 8 batches
    monkeypatch.undo()
    runner = Runner(spec, tmp_path / "other", quiet=True)
    todo = list(runner.blocks())
    eng = SimpleNamespace(evaluator=SimpleNamespace(B=spec.batch))  # groups of 8 blocks
    group, j = runner.next_group(todo, 0, eng)
    single = [b for b in todo if b[0] is todo[0][0]]  # the first context's blocks
    assert len(group) == min(8, len(single)) > 1 and j == len(group)
    assert all(b[0] is todo[0][0] for b in group)
    dose_at = next(i for i, b in enumerate(todo) if b[0].kind == "dose")
    assert runner.next_group(todo, dose_at, eng) == ([todo[dose_at]], dose_at + 1)
    # at a slow measured rate a group holds what it evaluates in GROUP_SECONDS (at least a batch),
    # so its parts are written, and the bar moves, that often
    slow = 2 * spec.batch / Runner.GROUP_SECONDS
    assert runner.next_group(todo, 0, eng, rate=slow) == (todo[:2], 2)
    assert runner.next_group(todo, 0, eng, rate=1e-6) == (todo[:1], 1)


def test_replay_one_injection_by_id(reference_run):
    spec, ref = reference_run
    for iid in (5, 61, ref.injection_id.max()):
        got = canonical(replay(spec, int(iid)))
        want = ref[ref.injection_id == iid].reset_index(drop=True)
        pd.testing.assert_frame_equal(got, want)


def test_kill_and_resume_gives_the_uninterrupted_records(reference_run, tmp_path):
    spec, ref = reference_run
    spec_path = write_spec(tmp_path)
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "seuwgpu", "campaign", str(spec_path), "--out", str(run), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and len(list((run / "records").glob("part-*.parquet"))) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    n_parts = len(list((run / "records").glob("part-*.parquet")))
    n_blocks = len(list(Runner(spec, run).blocks()))
    assert 2 <= n_parts < n_blocks, "the kill should land mid-run"
    Runner(load_spec(spec_path), run, quiet=True).run()
    got = canonical(read_records(run))
    pd.testing.assert_frame_equal(got, ref)
    # every part carries the time it took, the killed invocation's parts included
    seconds, untimed = store.run_seconds(run)
    assert untimed == 0 and seconds > 0


@pytest.mark.parametrize("sig, code, said", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
def test_interrupt_writes_the_parts_computed_and_resumes(reference_run, tmp_path, sig, code, said):
    """Ctrl-C (SIGINT) or a scheduler's SIGTERM mid-run: exit 130 / 143 with a message, the parts
    already computed are on disk whole (the part writer is closed on the way out), and a re-run
    completes the same records."""
    spec, ref = reference_run
    spec_path = write_spec(tmp_path)
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "seuwgpu", "campaign", str(spec_path), "--out", str(run), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and len(list((run / "records").glob("part-*.parquet"))) < 1:
        time.sleep(0.05)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the run finished before the interrupt landed")
    assert proc.returncode == code and said in err, err
    parts = list((run / "records").glob("part-*.parquet"))
    assert parts and not list((run / "records").glob("*.tmp"))
    for path in parts:  # whole parts only
        first, count = store.parse_part_name(path.name)
        assert set(pd.read_parquet(path, columns=["injection_id"]).injection_id) == set(range(first, first + count))
    Runner(load_spec(spec_path), run, quiet=True).run()
    pd.testing.assert_frame_equal(canonical(read_records(run)), ref)


def test_a_write_error_never_replaces_the_error_that_ended_the_run(reference_run, tmp_path, monkeypatch):
    """A part fails to write (the writer thread keeps the error) and then evaluation fails: the
    run ends with the evaluation's error, not the write error raised again on the way out; on a
    run that ends normally the write error is raised. The write is held until evaluation fails, so
    no put() can meet the error first."""
    import threading

    spec, _ = reference_run
    release = threading.Event()

    def failing_write(*a, **k):
        release.wait(60)
        raise OSError("disk full")

    monkeypatch.setattr(store, "write_part", failing_write)
    real = Runner.run_blocks
    calls = []

    def failing_second(self, *a, **k):
        calls.append(1)
        if len(calls) == 2:
            release.set()  # the queued write now fails, while this error ends the run
            raise RuntimeError("device lost")
        return real(self, *a, **k)

    monkeypatch.setattr(Runner, "run_blocks", failing_second)
    monkeypatch.setattr(Runner, "GROUP_BATCHES", 1)  # one batch a group: several calls
    with pytest.raises(RuntimeError, match="device lost"):
        Runner(spec, tmp_path / "a", quiet=True).run()
    assert len(calls) == 2
    monkeypatch.setattr(Runner, "run_blocks", real)
    with pytest.raises(OSError, match="disk full"):
        Runner(spec, tmp_path / "b", quiet=True).run()


def test_view_times_are_measured_once_per_run_and_kept_for_a_resume(reference_dir, tmp_path, monkeypatch):
    """A run keeps each engine's view times in view_times/ (its rounds beside the medians); a
    resumed run reads them instead of measuring again, so every part records the same time_ms;
    two shards claiming at once keep the first writer's."""
    from seuwgpu.faults.engine import Engine

    spec, ref_dir = reference_dir
    run = tmp_path / "run"
    shutil.copytree(ref_dir, run)  # a finished run of SPEC (this test ran its own before)
    said = store.read_manifest(run)["time_ms"]  # the manifest states the rule the engine applies
    assert f"{Engine.VIEW_TIME_ROUNDS} rounds" in said and f"as fit {Engine.VIEW_TIME_BUDGET_S:g} s" in said
    files = sorted((run / "view_times").glob("*.json"))
    assert [f.name for f in files] == ["dose-scene0-n1500-fp32.json", "single-scene0-n1500-fp32.json"]
    stored = {f.name.split("-")[0]: store.read_view_times(run, f.stem) for f in files}
    for t in stored.values():
        rounds = len(t["samples_ms"]["none"])
        assert Engine.VIEW_TIME_LEAST_ROUNDS <= rounds <= 9 and len(t["samples_ms"]["guard"]) == rounds
        assert t["time_ms"] == {d: float(np.median(v)) for d, v in t["samples_ms"].items()}
    parts = sorted((run / "records").glob("part-*.parquet"))
    for p in parts[::2]:
        p.unlink()

    def no_measuring(*a, **k):
        raise AssertionError("a resumed run measured its view times again")

    monkeypatch.setattr(Engine, "view_time_samples", no_measuring)
    Runner(spec, run, quiet=True).run()
    df = read_records(run)
    assert len(store.part_files(run)) == len(parts)
    want = df.apply(lambda r: stored[r.campaign]["time_ms"][r.defense], axis=1)
    np.testing.assert_array_equal(df.time_ms.to_numpy(), want.to_numpy())
    first = store.claim_view_times(tmp_path, "k", {"time_ms": {"none": 1.0}})
    second = store.claim_view_times(tmp_path, "k", {"time_ms": {"none": 2.0}})
    assert first == second == {"time_ms": {"none": 1.0}} and not list((tmp_path / "view_times").glob("*.tmp"))
    (tmp_path / "view_times" / "k.json").write_text("{not json")
    with pytest.raises(ValueError, match="k.json: cannot read the run's view times"):
        store.read_view_times(tmp_path, "k")


def test_warm_up_compiles_every_pipeline_an_engine_of_that_shape_uses(monkeypatch):
    """Engine.warm_up on a stand-in scene leaves nothing for a real engine of the same views'
    shape to compile (on a device of its own, so no earlier test compiled them), and a second
    warm-up of that shape builds nothing; the runner warms its engine's shape."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.gpu.device import GPU
    from seuwgpu.model import scenes
    from seuwgpu.model.sources import Source, source_views

    gpu = GPU()
    views = source_views(Source(None, "x", "+z", "blocks"), None, 2, (32, 24))
    Engine.warm_up(views, "fp32", "strict", True, gpu)
    compiled = dict(gpu._pipelines)
    assert compiled
    eng = Engine(scenes.make_scene("blocks", 1500), views, gpu=gpu)
    eng.evaluate_frame([eng.site("opacity", 3, 0, 30), eng.site("means", 9, 1, 29)], ("none", "guard"), ())
    assert gpu._pipelines == compiled
    Engine.warm_up(views, "fp32", "strict", True, gpu, sh_degree=0)  # the projection depends on the degree
    compiled = dict(gpu._pipelines)
    eng = Engine(scenes.make_scene("blocks", 1500, sh_degree=0), views, gpu=gpu)
    eng.evaluate_frame([eng.site("opacity", 3, 0, 30)], ("none", "guard"), ())
    assert gpu._pipelines == compiled
    monkeypatch.setattr(scenes, "make_scene", lambda *a, **k: pytest.fail("warmed twice"))
    Engine.warm_up(views, "fp32", "strict", True, gpu)
    monkeypatch.undo()
    single = {"fields": ["opacity"], "bits": [31], "samples": 1}
    scene = {"scene": "blocks", "n": 500, "sh_degree": 1}
    spec = normalize_spec({"views": 3, "size": "40x16", "scenes": [scene], "single": single})
    runner = Runner(spec, Path("unused"), gpu=gpu)
    shapes = set(Engine._warmed[gpu])
    runner.engine_for(runner.contexts[0])
    assert Engine._warmed[gpu] - shapes == {(3, 40, 16, "fp32", "strict", True, 1)}


def test_a_replaced_run_forgets_the_view_times_of_its_old_spec(tmp_path):
    """A run directory without parts may be taken by another spec (check_same_run): the view times
    and guard notes measured for the old one (another size, other defenses) are not the new run's."""
    raw = {"views": 1, "size": "32x32", "scenes": [{"scene": "blocks", "n": 500}], "single": {"samples": 1}}
    old, new = normalize_spec(raw), normalize_spec({**raw, "size": "48x32"})
    run = tmp_path / "run"
    Runner(old, run).prepare_dir()
    store.claim_view_times(run, "single-scene0-n500-fp32", {"time_ms": {"none": 1.0, "guard": 1.0}})
    note = store.guard_note_path(run, "blocks", "fp32", "strict")
    store.write_guard_note(run, "blocks", "fp32", "strict", {"nonfinite_values": {"opacity": 1}})
    Runner(old, run).prepare_dir()  # the same spec resumed: what it measured stays
    assert store.read_view_times(run, "single-scene0-n500-fp32") is not None and note.exists()
    replacing = Runner(new, run)
    replacing.prepare_dir()
    assert store.read_manifest(run)["spec_hash"] == replacing.hash != Runner(old, run).hash
    assert store.read_view_times(run, "single-scene0-n500-fp32") is None and not note.exists()


def test_changed_spec_is_refused(reference_run, tmp_path):
    spec, _ = reference_run
    run = tmp_path / "run"
    small = normalize_spec(
        {
            "seed": 1,
            "views": 1,
            "size": "32x32",
            "scenes": [{"scene": "blocks", "n": 500}],
            "single": {"fields": ["opacity"], "bits": [31], "samples": 2},
        }
    )
    Runner(small, run, quiet=True).run()
    other = dataclasses.replace(small, seed=2)
    with pytest.raises(SpecError, match="different spec"):
        Runner(other, run, quiet=True).run()


@pytest.mark.parametrize(
    "text, message",
    [
        ("seed = 1\nviews = 2\n[[scenes]]\nscene='blocks'\n[single]\nsampels = 3\n", "unknown key 'sampels' in single"),
        ("seed = 1\nbogus = 2\n[[scenes]]\nscene='blocks'\n[single]\n", "unknown key 'bogus'"),
        ("[[scenes]]\nscene='nope'\n[single]\n", "unknown scene 'nope'"),
        ("[[scenes]]\nscene='blocks'\n[single]\nprecisions=['fp64']\n", "single.precisions"),
        ("[[scenes]]\nscene='blocks'\n[single]\nbits=[32]\n", "bit 32 is out of range for fp32"),
        ("[[scenes]]\nscene='blocks'\n[single]\nprecisions=['bf16']\nbits=[16]\n", "bit 16 is out of range for bf16"),
        ("[[scenes]]\nscene='blocks'\n[single]\nfields=['colour_x']\n", "unknown field"),
        ("[[scenes]]\nscene='blocks'\n[single]\nsamples=0\n", "single.samples"),
        ("[[scenes]]\nscene='blocks'\n[single]\ndefenses=['magic']\n", "single.defenses"),
        ("[[scenes]]\nscene='blocks'\n", "at least one of [single]"),
        ("size='12'\n[[scenes]]\nscene='blocks'\n[single]\n", "size"),
        ("[[scenes]]\nply='missing.ply'\n[single]\n", "file not found"),
        ("[[scenes]]\nscene='blocks'\n[dose]\nk=[1]\nk_max=5\n", "either k"),
        ("[[scenes]]\nscene='blocks'\n[single\n", "not valid TOML"),
    ],
)
def test_bad_specs_fail_with_a_message_naming_the_key(tmp_path, text, message):
    with pytest.raises(SpecError, match=message.replace("[", r"\[").replace("(", r"\(")):
        load_spec(write_spec(tmp_path, text))


def test_size_sweep_and_uniform_sampling(tmp_path):
    spec = normalize_spec(
        {
            "seed": 3,
            "views": 1,
            "size": "32x32",
            "batch": 64,
            "scenes": [{"scene": "plant", "n": 999}],
            "single": {"fields": "all", "bits": [31], "samples": 40, "sampling": "uniform", "defenses": ["none"]},
            "sizes": {
                "n": [400, 1600],
                "fields": ["log_scales"],
                "bits": [30, 31],
                "samples": 3,
                "defenses": ["none", "guard"],
            },
        }
    )
    Runner(spec, tmp_path / "run", quiet=True).run()
    df = read_records(tmp_path / "run")
    size = df[df.campaign == "size"]
    assert sorted(size.n_primitives.unique()) == [400, 1600]
    assert len(size) == 2 * 2 * 3 * 2  # n values x bits x samples x defenses
    uni = df[df.campaign == "single"]
    assert len(uni) == 6 * 40  # uniform mode: samples x cells injections
    # uniform over all stored bits: every injection stands for the same number of bits
    assert np.allclose(uni.weight, 999 * 59 * 32 / 240)
    assert uni.field.nunique() >= 2 and uni.bit.nunique() > 5


def test_size_sweep_over_several_scenes():
    base = {
        "size": "32x32",
        "scenes": [{"scene": "plant", "n": 999}, {"scene": "spheres", "n": 999}],
        "sizes": {"n": [100, 200], "fields": ["opacity"], "bits": [31], "samples": 2, "defenses": ["none"]},
    }
    one = enumerate_contexts(normalize_spec(base))
    first = normalize_spec(base)
    assert {c.scene_index for c in one} == {0} and first.sizes.scenes is None
    assert "scenes" not in first.to_dict()["sizes"]  # the default is not recorded (older hashes stay)
    base["sizes"]["scenes"] = "all"
    both = enumerate_contexts(normalize_spec(base))
    assert sorted((c.scene_index, c.n) for c in both) == [(0, 100), (0, 200), (1, 100), (1, 200)]
    base["sizes"]["scenes"] = [2]
    with pytest.raises(SpecError, match="sizes.scenes"):
        normalize_spec(base)


def test_size_sweep_over_a_model_file_cuts_seeded_subsets(tmp_path, monkeypatch):
    """A model file in [sizes] (a reviewer's own trained model) is cut to a seeded random subset
    of each n, framed as the whole model (Model.sample, the paper's subsampling of trained
    models); an n above its primitive count is refused naming the file. The run reads the file
    once: its check before the manifest and both sizes' engines share the read."""
    import seuwgpu.model.sources as sources
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.scenes import make_scene

    reads, read = [], sources.read_model
    monkeypatch.setattr(sources, "read_model", lambda p, **kw: reads.append(p) or read(p, **kw))

    path = tmp_path / "mine.ply"
    full = make_scene("plant", 700, seed=4)
    save_model(full, path)
    base = {
        "seed": 5,
        "views": 1,
        "size": "32x32",
        "scenes": [{"model": str(path), "seed": 7}],
        "sizes": {"n": [150, 300], "fields": ["opacity"], "bits": [31], "samples": 2, "defenses": ["none"]},
    }
    spec = normalize_spec(base)
    runner = Runner(spec, tmp_path / "run", quiet=True)
    runner.run()
    assert reads == [str(path)]
    size = read_records(tmp_path / "run")
    assert sorted(size.n_primitives.unique()) == [150, 300] and len(size) == 2 * 2
    ctx = [c for c in enumerate_contexts(spec) if c.n == 150][0]
    eng = runner.engine_for(ctx)
    want = full.sample(150, 7, size.scene.iloc[0])  # seeded by the scene's seed and the model's label
    assert eng.n == 150 and np.array_equal(eng.layout.decode(eng.renderer.clean_words).means, want.means)
    assert len({tuple(m) for m in want.means}) == 150 and set(map(tuple, want.means)) <= set(map(tuple, full.means))
    base["sizes"]["n"] = [150, 701]
    with pytest.raises(SpecError, match="mine.ply has 700 primitives"):
        normalize_spec(base)


def test_unreadable_model_or_camera_file_stops_before_the_manifest(tmp_path):
    """A model file that exists but cannot be read is refused with the loader's one-line error
    by the spec (which reads the model's SH degree) and, were a resolved spec handed over, by the
    run before its manifest is written, so the folder is not claimed: the same folder then runs
    with the corrected spec (its manifest keeping the loader's notes of the model file, for the
    report). (A camera file that cannot be read is refused with the spec.)"""
    from seuwgpu.errors import InputError
    from seuwgpu.model.formats import read_model, save_model
    from seuwgpu.model.scenes import make_scene

    good = tmp_path / "good.ply"
    save_model(make_scene("plant", 300, seed=4), good)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(good.read_bytes()[:-100])  # truncated body
    cams = tmp_path / "cams.json"
    cams.write_text("[{")
    single = {"fields": ["opacity"], "bits": [31], "samples": 2, "defenses": ["none"]}
    base = {"seed": 5, "views": 1, "size": "32x32", "single": single}
    with pytest.raises(InputError, match="bad.ply"):
        normalize_spec({**base, "scenes": [{"model": str(bad)}]})
    spec = normalize_spec({**base, "scenes": [{"model": str(good)}]})
    spec = dataclasses.replace(spec, scenes=(dataclasses.replace(spec.scenes[0], model=str(bad)),))  # broken after read
    with pytest.raises(InputError, match="bad.ply"):
        Runner(spec, tmp_path / "run", quiet=True).run()
    assert store.read_manifest(tmp_path / "run") is None
    with pytest.raises(InputError, match="cams.json"):  # camera files are read with the spec already
        normalize_spec({**base, "scenes": [{"scene": "plant", "n": 300, "cameras": str(cams)}]})
    noted = tmp_path / "noted.spz"  # a format whose loader has notes ("SPZ version 3")
    save_model(make_scene("plant", 300, seed=4), noted)
    Runner(normalize_spec({**base, "scenes": [{"model": str(noted)}]}), tmp_path / "run", quiet=True).run()
    assert len(read_records(tmp_path / "run")) == 2
    notes = read_model(noted).notes
    models = store.read_manifest(tmp_path / "run")["models"]
    assert notes and [m["notes"] for m in models if m["name"] == "noted"] == [notes]


def test_cell_sites_are_drawn_with_replacement():
    """Why the planner uses no finite-population correction: each injection draws its site from
    its own stream (so any block can be re-run alone), i.e. with replacement: as many draws as a
    cell has sites repeat some (a draw without replacement would be a permutation)."""
    from seuwgpu.campaign.sampling import draw_sites, enumerate_contexts, injection_seeds

    spec = normalize_spec(
        {
            "views": 1,
            "size": "32x32",
            "scenes": [{"scene": "blocks", "n": 64}],
            "single": {"fields": ["opacity"], "bits": [3], "samples": 64},
        }
    )
    ctx = enumerate_contexts(spec)[0]
    ids = np.arange(64)
    sites, weights = draw_sites(ctx, ids, injection_seeds(spec.seed, ids), 64, 3)
    prims = [s.primitive for s in sites]
    assert len(set(prims)) < 64  # 64 draws over the cell's 64 sites: repeats
    assert np.allclose(weights, 64 / 64)
    alone, _ = draw_sites(ctx, ids[40:41], injection_seeds(spec.seed, ids[40:41]), 64, 3)
    assert alone[0] == sites[40]  # one injection's site does not depend on the others drawn


def test_samples_planned_from_a_margin(tmp_path):
    from seuwgpu.campaign.plan import sample_size

    spec = normalize_spec(
        {
            "views": 1,
            "size": "32x32",
            "scenes": [{"scene": "blocks", "n": 2000}],
            "single": {"samples": {"margin": 0.05, "confidence": 0.9}},
        }
    )
    # sites are drawn with replacement, so the plan takes no finite-population correction (a
    # correction for 2,000 primitives would plan 239 instead of 271)
    assert spec.single.samples == sample_size(0.05, 0.9) == 271
    with pytest.raises(SpecError, match="single.samples.margin"):
        normalize_spec({"scenes": [{"scene": "blocks"}], "single": {"samples": {"margin": 5}}})
    with pytest.raises(SpecError, match="unknown key 'margn' in single.samples"):
        normalize_spec({"scenes": [{"scene": "blocks"}], "single": {"samples": {"margn": 0.1}}})
    p = write_spec(tmp_path, "views=1\nsize='32x32'\n[[scenes]]\nscene='blocks'\nn=2000\n[single]\nsamples=7\n")
    out = subprocess.run([sys.executable, "-m", "seuwgpu", "plan", str(p)], capture_output=True, text=True)
    assert out.returncode == 0
    assert "total: 1,344 injections, 2,688 records" in out.stdout  # 6 fields x 32 bits x 7, 2 arms


def test_outcome_and_reliability_tables_of_the_spec():
    base = {"scenes": [{"scene": "spheres", "n": 100}], "single": {"samples": 1}}
    plain = normalize_spec(base)
    assert "outcomes" not in plain.to_dict() and "reliability" not in plain.to_dict()  # older specs keep their hash
    s = normalize_spec(
        base
        | {
            "outcomes": {"footprint": 0.05},
            "reliability": {"scrub_hours": 6, "rates": [{"environment": "lab", "per_bit_hour": 1e-9, "source": "x"}]},
        }
    )
    assert s.outcomes.to_dict() == {"pixel_threshold": 1 / 255, "footprint": 0.05}
    assert s.reliability.scrub_hours == 6.0 and s.reliability.rates[0].per_bit_hour == 1e-9
    sched = normalize_spec(base | {"reliability": {"check_every": 10, "frames_per_second": 60}})
    assert (sched.reliability.check_every, sched.reliability.frames_per_second) == (10, 60.0)
    assert sched.to_dict()["reliability"] == {"check_every": 10, "frames_per_second": 60.0}
    for bad, what in (
        ({"reliability": {"check_every": 0}}, "reliability.check_every"),
        ({"reliability": {"check_every": 2.5}}, "reliability.check_every"),
        ({"reliability": {"check_every": {"guard": 3}}}, "unknown check defense 'guard'; expected one of parity"),
        ({"reliability": {"check_every": {"parity4r": 0}}}, "reliability.check_every.parity4r"),
        ({"reliability": {"frames_per_second": -30}}, "reliability.frames_per_second"),
        ({"outcomes": {"footprint": 2}}, "outcomes.footprint"),
        ({"outcomes": {"pixel": 0.1}}, "unknown key 'pixel'"),
        ({"reliability": {"scrub_hours": 0}}, "reliability.scrub_hours"),
        ({"reliability": {"rates": [{"environment": "a", "per_bit_hour": -1, "source": "s"}]}}, "per_bit_hour"),
        ({"single": {"samples": 1, "regions": [64]}, "size": "64x64"}, "do not fit"),
        (
            {"single": {"samples": 1, "regions": [4], "precisions": ["fp16"], "defenses": ["none", "parity2f"]}},
            r"^single.regions under parity2f at fp16: a detected upset drops its word partner too",
        ),
    ):
        with pytest.raises(SpecError, match=what):
            normalize_spec(base | bad)


def test_quiet_progress_lines_carry_an_eta(capsys, monkeypatch):
    import re

    from seuwgpu.campaign import progress as P

    clock = iter([0.0, 20.0, 40.0])  # t0, then one call per advance
    monkeypatch.setattr(P.time, "perf_counter", lambda: next(clock))
    p = P.injection_bar(total=1000, done=100, quiet=True)
    p.advance(300, 2)  # 300 in 20 s: 15/s, 600 left: 40 s
    p.advance(600, 1)  # done
    lines = capsys.readouterr().err.strip().splitlines()
    # resumed from 100 done: the count covers the injections of this session only, and says so
    assert lines[0] == "400/1000 injections, 15.0/s, ETA 00:00:40, catastrophic 2 (of the 300 run since resuming)"
    assert re.fullmatch(
        r"1000/1000 injections, 22\.5/s, ETA 00:00:00, catastrophic 3 \(of the 900 run since resuming\)", lines[1]
    )
    clock = iter([0.0, 10.0])  # a fresh run: every injection is this session's
    P.injection_bar(total=100, done=0, quiet=True).advance(100, 4)
    assert capsys.readouterr().err.strip() == "100/100 injections, 10.0/s, ETA 00:00:00, catastrophic 4"


def test_parts_carry_their_compute_time(tmp_path):
    df = pd.DataFrame({"injection_id": np.arange(3), "footprint": [0.0, 0.5, 1.0]})
    store.records_dir(tmp_path).mkdir(parents=True)
    store.write_part(tmp_path, 0, 3, df, seconds=1.5)
    store.write_part(tmp_path, 3, 3, df)  # a part written without its time
    assert store.run_seconds(tmp_path) == (1.5, 1)
    pd.testing.assert_frame_equal(pd.read_parquet(store.part_path(tmp_path, 0, 3)), df)


def test_parts_are_written_with_the_records_schema_and_checked_when_read(tmp_path):
    """schema.RECORD_SCHEMA: a part's columns are written with its types (an integer column given as
    whole floats is stored int64, a bitmask computed as uint64 keeps its 64 bits as int64), a
    column no record has is refused, and a part whose column holds another kind of value is
    refused when read, naming the part and the column."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    store.records_dir(tmp_path).mkdir(parents=True)
    mask = np.array([1 << 63, 5], dtype=np.uint64)
    df = pd.DataFrame({"scene": ["a", "b"], "primitive": [3.0, 4.0], "footprint": [0, 1], "regions_meas_64": mask})
    store.write_part(tmp_path, 0, 2, df)
    path = store.part_path(tmp_path, 0, 2)
    schema = pq.read_schema(path)
    assert [(f.name, f.type) for f in schema] == [
        ("scene", pa.large_string()), ("primitive", pa.int64()), ("footprint", pa.float64()),
        ("regions_meas_64", pa.int64()),
    ]  # fmt: skip
    back = store.read_part(path)
    assert back["primitive"].tolist() == [3, 4] and back["regions_meas_64"].to_numpy().view(np.uint64).tolist() == [
        1 << 63, 5
    ]  # fmt: skip
    with pytest.raises(store.InputError, match="'run' is not a record column"):
        store.write_part(tmp_path, 2, 2, df.assign(run="x"))
    pd.DataFrame({"scene": [1, 2]}).to_parquet(store.part_path(tmp_path, 4, 2))  # another tool's file
    with pytest.raises(store.InputError, match=r"part-0000000004-000002.parquet: column scene holds int64, records"):
        store.read_part(store.part_path(tmp_path, 4, 2))
    assert COLUMNS == RECORD_SCHEMA.names


def test_part_writer_writes_every_queued_part_and_reports_errors(tmp_path):
    """campaign/store.py PartWriter: every part queued before close is on disk, with its time;
    a write that fails (here: no records folder) is raised by close, not lost in the thread."""
    df = pd.DataFrame({"injection_id": np.arange(4), "footprint": np.linspace(0, 1, 4)})
    store.records_dir(tmp_path).mkdir(parents=True)
    writer = store.PartWriter(tmp_path, depth=2)
    for a in range(0, 40, 4):
        writer.put(a, 4, df.assign(injection_id=df.injection_id + a), seconds=0.25)
    writer.close()
    got = read_records(tmp_path)
    assert sorted(got.injection_id) == list(range(40))
    assert store.run_seconds(tmp_path) == (2.5, 0)
    broken = store.PartWriter(tmp_path / "missing")
    broken.put(0, 4, df)
    with pytest.raises(OSError):
        broken.close()


def test_view_times_render_view_0_within_their_budget(gpu, monkeypatch):
    """time_ms: each defense's view 0 rendered alone, timed interleaved with no warm-up round
    (the engine's clean capture ran the pipelines), 9 rounds, or, once VIEW_TIME_LEAST_ROUNDS ran,
    only rounds that would end within VIEW_TIME_BUDGET_S (a 1M-primitive campaign spent 62 of its
    98 s timing all K views 10 times per defense)."""
    from seuwgpu.faults.costs import interleaved_medians, interleaved_samples
    from seuwgpu.faults.engine import Engine
    from seuwgpu.model.scenes import make_scene, scene_cameras
    from seuwgpu.render.renderer import Renderer

    calls = {"a": 0, "b": 0}

    def timed(name):
        def f():
            calls[name] += 1
            time.sleep(0.002)

        return f

    med = interleaved_medians({"a": timed("a"), "b": timed("b")}, 9, budget_s=0.0)
    assert calls == {"a": 4, "b": 4} and min(med.values()) >= 0.002  # warm-up + the 3 rounds at least
    calls.update(a=0, b=0)
    interleaved_medians({"a": timed("a"), "b": timed("b")}, 9, budget_s=60.0)
    assert calls == {"a": 10, "b": 10}
    calls.update(a=0, b=0)
    got = interleaved_samples({"a": timed("a"), "b": timed("b")}, 9, budget_s=0.0, least=2, warm_up=False)
    assert calls == {"a": 2, "b": 2} and [len(v) for v in got.values()] == [2, 2]
    # on a clock where each call takes 0.5 s (a round 1 s), a 2.2 s budget holds 2 rounds: a third
    # would end at 3 s (it used to start, since 2 s had not passed the budget)
    import types

    from seuwgpu.faults import costs

    clock = [0.0]

    def slow():
        clock[0] += 0.5

    monkeypatch.setattr(costs, "time", types.SimpleNamespace(perf_counter=lambda: clock[0]))
    got = interleaved_samples({"a": slow, "b": slow}, 9, budget_s=2.2, least=1, warm_up=False)
    assert got == {"a": [0.5, 0.5], "b": [0.5, 0.5]} and clock[0] == 2.0
    clock[0] = 0.0
    assert len(interleaved_samples({"a": slow}, 9, budget_s=2.2, least=1, warm_up=False)["a"]) == 4  # ends at 2.0
    monkeypatch.undo()
    eng = Engine(make_scene("spheres", 3000), scene_cameras("spheres", 3, 32, 32), gpu=gpu)
    seen = []
    real = Renderer.encode
    monkeypatch.setattr(
        Renderer,
        "encode",
        lambda self, enc, views=None, split=None: seen.append(views) or real(self, enc, views, split),
    )
    samples = eng.view_time_samples(("none", "guard"))
    assert set(samples) == {"none", "guard"} and min(min(v) for v in samples.values()) > 0
    rounds = len(samples["none"])
    assert len(samples["guard"]) == rounds and eng.VIEW_TIME_LEAST_ROUNDS <= rounds <= 9
    assert len(seen) == 2 * rounds and all(list(v) == [0] for v in seen)
    monkeypatch.undo()
    site = eng.site("log_scales", 7, 0, 30)
    assert eng.evaluate([site])[0]["footprint"] == eng.inject(site)["footprint"]  # the kept views unharmed
    # a full re-rendering engine (campaign --full) batches its views: they are timed together
    full = Engine(make_scene("spheres", 3000), scene_cameras("spheres", 3, 32, 32), gpu=gpu, incremental=False)
    assert full.renderer.batched
    seen.clear()
    monkeypatch.setattr(
        Renderer,
        "encode",
        lambda self, enc, views=None, split=None: seen.append(views) or real(self, enc, views, split),
    )
    samples = full.view_time_samples(("none", "guard"))
    assert min(min(v) for v in samples.values()) > 0 and all(v is None for v in seen)
    assert len(seen) == 2 * len(samples["none"])


def test_the_spec_is_typed_and_its_stored_form_round_trips():
    """normalize_spec returns a Spec (typed sections, frozen); its stored form (the manifest's
    `spec`, what the hash covers) reads back as the same Spec, and a typo is still one line."""
    import json

    from seuwgpu.campaign.spec_hash import spec_hash
    from seuwgpu.campaign.spec_types import DoseSpec, SizesSpec, Spec, UpsetSpec

    raw = {
        "seed": 3,
        "size": "64x48",
        "scenes": [{"scene": "spheres", "n": 300}, {"scene": "blocks", "n": 200, "sh_degree": 0}],
        "single": {"fields": ["log_scale", "opacity"], "bits": [31, 30], "samples": 2, "regions": [4]},
        "dose": {"k": [4, 1, 4], "repeats": 2},
        "sizes": {"n": [100, 50], "scenes": "all", "samples": 1},
        "outcomes": {"footprint": 0.02},
        "reliability": {"rates": [{"environment": "ground", "per_bit_hour": 1e-12, "source": "x"}]},
    }
    spec = normalize_spec(raw)
    assert isinstance(spec.single, UpsetSpec) and isinstance(spec.dose, DoseSpec) and isinstance(spec.sizes, SizesSpec)
    assert spec.single.fields == ("log_scales", "opacity") and spec.single.bits == (30, 31)
    assert spec.dose.k == (1, 4) and spec.sizes.n == (50, 100) and spec.sizes.scenes == (0, 1)
    assert spec.size == (64, 48) and spec.scenes[1].sh_degree == 0 and spec.outcomes.footprint == 0.02
    assert spec.reliability.rates[0].per_bit_hour == 1e-12 and spec.reliability.scrub_hours is None
    stored = json.loads(json.dumps(spec.to_dict()))
    assert stored["size"] == [64, 48] and "fault" not in stored["single"] and "lpips" not in stored
    assert Spec.from_dict(stored) == spec and spec_hash(stored) == spec_hash(spec)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.seed = 4
    with pytest.raises(SpecError, match=r"^unknown key 'sampels' in single \(allowed: "):
        normalize_spec({"scenes": [{"scene": "spheres"}], "single": {"sampels": 2}})


def test_each_spec_key_is_written_once_and_the_checker_the_defaults_and_the_docstring_agree():
    """campaign/spec_types.py writes each key once; the checker's key sets, the defaults a spec
    that leaves a key out gets and the docstring's reference are derived from it: every table
    refuses a key it does not hold naming exactly its keys (hand-listed here), and a minimal spec
    gets the defaults the docstring shows (hand-written here)."""
    import re

    from seuwgpu.campaign import spec as spec_module
    from seuwgpu.campaign.spec_types import DoseSpec, SceneSpec, SizesSpec, Spec, UpsetSpec, key_names

    upset = ["bits", "defenses", "fault", "fields", "precisions", "regions", "samples", "sampling"]
    tables = {
        "the spec": (
            Spec,
            [
                "batch",
                "dose",
                "lpips",
                "name",
                "outcomes",
                "profile",
                "reliability",
                "scale",
                "scenes",
                "seed",
                "single",
                "size",
                "sizes",
                "summary",
                "views",
            ],
        ),
        "scenes[0]": (SceneSpec, ["cameras", "lod", "model", "n", "ply", "scene", "seed", "sh_degree", "up"]),
        "single": (UpsetSpec, upset),
        "sizes": (SizesSpec, sorted([*upset, "n", "scenes"])),
        "dose": (DoseSpec, ["defenses", "k", "k_max", "points", "precisions", "repeats"]),
    }
    for where, (cls, keys) in tables.items():
        assert sorted(key_names(cls)) == keys
        raw = {"scenes": [{"scene": "spheres", "n": 100}], "single": {}, "sizes": {"n": [10]}, "dose": {"k": [1]}}
        table = raw if where == "the spec" else raw["scenes"][0] if where == "scenes[0]" else raw[where]
        table["zz"] = 1
        with pytest.raises(SpecError, match=re.escape(f"unknown key 'zz' in {where} (allowed: {', '.join(keys)})")):
            normalize_spec(raw)
    spec = normalize_spec({"scenes": [{"scene": "spheres"}], "single": {}, "sizes": {"n": [10]}, "dose": {}})
    assert (spec.name, spec.seed, spec.views, spec.size, spec.batch) == ("campaign", 0, 4, (256, 256), 256)
    assert (spec.scenes[0].n, spec.scenes[0].sh_degree, spec.scenes[0].seed) == (100_000, 3, 0)
    assert (spec.single.samples, spec.single.defenses, spec.single.sampling) == (20, ("none", "guard"), "stratified")
    assert (spec.sizes.samples, spec.sizes.defenses, spec.sizes.scene_indices) == (10, ("none",), (0,))
    assert spec.dose.repeats == 3 and len(spec.dose.k) == 12 and spec.dose.k[-1] == 20_000
    doc = spec_module.__doc__
    for line in (
        "    samples = 20 ",
        "    samples = 10 ",
        "    n = 100000 ",
        '    defenses = ["none"] ',
        "    repeats = 3 ",
    ):
        assert line in doc


def test_a_manifest_s_stored_scenes_and_size_read_typed_old_runs_included(reference_dir):
    """The analyses read a run's [[scenes]] and size typed (spec_types.stored_scenes/stored_size):
    this run's entries round-trip to their stored dicts; an older run's entry without sh_degree
    or seed reads them as None and drops a key this version no longer knows; no spec, no scenes."""
    import json

    from seuwgpu.campaign.spec_types import SceneSpec, stored_scenes, stored_size

    spec, run = reference_dir
    m = json.loads((run / "manifest.json").read_text())
    scenes = stored_scenes(m)
    assert [sc.to_dict() for sc in scenes] == m["spec"]["scenes"] and scenes == spec.scenes
    assert stored_size(m) == tuple(m["spec"]["size"]) == spec.size
    old = {"spec": {"size": [64, 48], "scenes": [{"scene": "spheres", "n": 500, "retired_key": 1}, "not a table"]}}
    assert stored_scenes(old) == (SceneSpec(sh_degree=None, seed=None, scene="spheres", n=500),)
    assert stored_size(old) == (64, 48)
    assert stored_scenes({}) == () and stored_size({"spec": {"size": [64]}}) is None


def test_interleaved_rounds_alternate_their_order_when_asked():
    """alternate=True: every other round runs the configurations in reverse order (a, b, b, a,
    a, b), so what follows one configuration does not always fall on the same other; each still
    gets one sample a round, timed around its own call (a fake clock: a costs 1 s, b 2 s)."""
    from seuwgpu.faults.costs import interleaved_samples

    clock, order = [0.0], []

    def config(name, cost):
        def f():
            order.append(name)
            clock[0] += cost

        return f

    configs = {"a": config("a", 1.0), "b": config("b", 2.0)}
    got = interleaved_samples(configs, 3, warm_up=False, clock=lambda: clock[0], alternate=True)
    assert order == ["a", "b", "b", "a", "a", "b"] and got == {"a": [1.0] * 3, "b": [2.0] * 3}
    order.clear()
    interleaved_samples(configs, 3, warm_up=False, clock=lambda: clock[0])
    assert order == ["a", "b"] * 3
