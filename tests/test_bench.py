"""Smoke test of tools/bench.py: its core function on a tiny scene yields the JSON fields, positive.
No speed assertions (timings depend on the machine and its load)."""

import importlib.util
import json
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "tools" / "bench.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("seuwgpu_bench", BENCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_floors_are_measured(bench, gpu):
    fl = bench.measure_floors(gpu, repeats=1, groups=16, iters=16, copy_mb=1)
    assert fl["exp_per_s"] > 0 and fl["copy_bytes_per_s"] > 0 and fl["exp_evals"] == 4 * 64 * 16 * 16
    # a stage's floor: its bytes at the copy rate; compositing: pairs x tile pixels at the exp rate
    kw = {"n": 1000, "pairs": 5000, "n_tiles": 16, "model_bytes": 4 * 59 * 1000, "floors": fl}
    assert bench.stage_floor_s("project", **kw) == (4 * 59 * 1000 + 56 * 1000) / (2 * fl["copy_bytes_per_s"])
    assert bench.stage_floor_s("composite", **kw) == 5000 * 256 / fl["exp_per_s"]
    assert bench.stage_floor_s("ranges", **kw) is None


def test_bench_config_fields(bench, gpu):
    from seuwgpu.model import scenes

    model = scenes.make_scene("spheres", 2000, 3, 0)
    twin = bench.measure_twin("spheres", model, 32)
    floors = bench.measure_floors(gpu, repeats=1, groups=16, iters=16, copy_mb=1)
    rec = bench.bench_config(model, "spheres", 32, 2, repeats=2, gpu=gpu, twin=twin, floors=floors)
    json.dumps(rec)  # JSON-serialisable (the twin image is not in the record)
    assert rec["n"] == 2000 and rec["width"] == rec["height"] == 32 and rec["k"] == 2
    assert rec["compositor"] == ("lanes" if gpu.is_cpu else "wide") and len(rec["view0_sha256"]) == 64
    assert 1 <= rec["repeats"] <= 2 and len(rec["times_s"]) == rec["repeats"]
    for key in ("mpix_per_s", "ms_per_view", "seconds_per_submission", "warmup_s", "twin_ratio"):
        assert rec[key] > 0, key
    assert rec["twin"]["seconds_per_view"] > 0 and rec["twin"]["n"] == 2000
    assert rec["psnr_view0_vs_twin_db"] > 50  # the timed renderer draws the right image
    assert len(rec["intersections_per_view"]) == 2 and min(rec["intersections_per_view"]) > 0
    # the depth sort alone records 17 (a plan, then upsweep and scatter for each of 8 passes); the
    # two views are batched: one sort, binning and compositing for both
    total = rec["dispatches_per_view"] * rec["k"]
    assert rec["batched"] and total == int(total) > 17 and rec["dispatches_per_view"] < 0.75 * total
    assert rec["encode_ceiling_mpix_s"] == pytest.approx(2 * 32 * 32 / (rec["encode_ms"] / 1e3) / 1e6)
    if "timestamp-query" in gpu.features:
        st = rec["stages_ms"]
        for s in bench.STAGES:
            assert st[s] >= 0, s
        assert st["project"] > 0 and st["composite"] > 0
        assert rec["untimed_passes"] == 0 and rec["timed_passes"] > 0
        assert rec["floors_ms_per_view"]["composite"] > 0 and rec["floors_ms_per_view"]["project"] > 0
    else:
        assert rec["stages_ms"] is None and "timestamp-query" in rec["stage_source"]


def test_stage_timing_on_a_gpu_adapters_split_submissions(bench, gpu, monkeypatch):
    """On a GPU a batched frame set is submitted stage group by stage group (Renderer
    split_submissions); the instrumented submission still goes through `encode`, in one encoder,
    so every pass is timed (this adapter posing as a GPU)."""
    if "timestamp-query" not in gpu.features:
        pytest.skip("no timestamp queries on this adapter")
    monkeypatch.setattr(type(gpu), "is_cpu", property(lambda self: False))
    from conftest import random_model

    from seuwgpu.model.cameras import orbit_cameras

    submits = []
    real_submit = gpu.submit
    monkeypatch.setattr(gpu, "submit", lambda enc: (submits.append(enc), real_submit(enc)))
    r = bench.StageTimedRenderer(random_model(2000, seed=4), orbit_cameras(2, 32, 32), gpu=gpu)
    assert r.batched and r.split_submissions
    r.run()
    submits.clear()
    r.timed = True
    r.run()
    assert len(submits) == 1  # one encoder
    st = r.stage_times()
    assert st["project"] > 0 and st["composite"] > 0 and st["untimed_passes"] == 0
    r.timed = False
    submits.clear()
    r.run()
    assert len(submits) == 4  # stage groups again


def test_twin_above_max_n_gives_no_ratio(bench, gpu):
    from seuwgpu.model import scenes

    model = scenes.make_scene("plant", 3000, 1, 0)
    twin = bench.measure_twin("plant", model, 32, max_n=1000)
    assert twin["n"] == 1000 and "N=1000" in twin["what"]
    rec = bench.bench_config(model, "plant", 32, 1, repeats=1, gpu=gpu, twin=twin, stages=False)
    assert rec["twin_ratio"] is None and rec["stages_ms"] is None and rec["mpix_per_s"] > 0


def test_main_writes_json_only_where_told(bench, gpu, tmp_path, capsys, monkeypatch):
    out = tmp_path / "b.json"
    monkeypatch.chdir(tmp_path)
    args = ["--scenes", "spheres", "--n", "2000", "--sizes", "32", "--views", "1", "--repeats", "1"]
    args += [] if gpu.is_cpu else ["--compositors", "wide"]  # a GPU times both shapes unless told
    assert bench.main([*args, "--campaign-samples", "8", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["adapter"]["backend"] and doc["adapter"]["device"]
    assert len(doc["results"]) == 1 and doc["results"][0]["mpix_per_s"] > 0 and doc["total_wall_s"] > 0
    assert doc["floors"]["exp_per_s"] > 0 and doc["settings"]["date"]
    assert doc["campaigns"][0]["injections_per_s"] > 0 and doc["campaigns"][0]["injections"] == 8
    printed = capsys.readouterr().out
    assert "Mpix/s" in printed and "injections/s" in printed
    out.unlink()
    assert bench.main([*args, "--campaign-samples", "0", "--no-twin"]) == 0
    assert list(tmp_path.iterdir()) == []  # no --out: nothing written


def test_bench_times_both_compositors_and_checks_their_frames(bench, gpu, tmp_path, monkeypatch):
    """--compositors lanes wide: one record per shape and configuration, with the shape named and
    view 0's bits hashed; the shapes' frames are the same bit for bit, so the digests are equal,
    and a view's digest is the SHA-256 of the image the renderer reads back. A GPU adapter times
    both shapes unless told, and sweeps the chunks with each (here posed by pretending the adapter
    is not a CPU)."""
    import hashlib

    from seuwgpu.model import scenes
    from seuwgpu.render.renderer import Renderer

    out = tmp_path / "b.json"
    args = ["--scenes", "spheres", "--n", "2000", "--sizes", "32", "--views", "2", "--repeats", "1", "--no-twin"]
    args.append("--no-one-by-one")  # (on by default on a GPU: a third record)
    assert bench.main([*args, "--campaign-samples", "0", "--compositors", "lanes", "wide", "--out", str(out)]) == 0
    recs = json.loads(out.read_text())["results"]
    assert [r["compositor"] for r in recs] == ["lanes", "wide"]
    assert recs[0]["view0_sha256"] == recs[1]["view0_sha256"] and recs[1]["view0_same_as_first_compositor"]
    model = scenes.make_scene("spheres", 2000, 3, 0)
    r = Renderer(model, scenes.scene_cameras("spheres", 2, 32, 32), gpu=gpu)
    img = r.render_rgba()
    assert hashlib.sha256(img[0].tobytes()).hexdigest() == recs[0]["view0_sha256"]
    monkeypatch.setattr(type(gpu), "is_cpu", property(lambda self: False))
    monkeypatch.setattr(bench, "WARM_UP_S", 0.0)  # no clocks to raise here
    doc = bench.run_grid(
        ["spheres"],
        [2000],
        [32],
        [1],
        repeats=1,
        twin=False,
        stages=False,
        campaign_samples=0,
        chunks=[256],
        log=lambda m: None,
    )
    assert [r["compositor"] for r in doc["results"]] == ["lanes", "wide"]
    assert [(c["compositor"], c["chunk"]) for c in doc["chunk_sweep"]] == [("lanes", 256), ("wide", 256)]


def test_a_failing_candidate_compositor_is_dropped_not_fatal(bench, gpu, monkeypatch):
    """A shape after the first that fails on the device (a driver rejecting its pipeline, say) is
    recorded with its error and dropped from the rest of the run; the first shape's failure is
    fatal (it is the measurement)."""

    def failing_for_wide(fn, message):
        def wrapped(*args, compositor=None, **kw):
            if compositor == "wide":
                raise RuntimeError(message)
            return fn(*args, compositor=compositor, **kw)

        return wrapped

    real = bench.bench_config
    monkeypatch.setattr(bench, "bench_config", failing_for_wide(real, "pipeline rejected\nby a driver"))
    kw = {
        "repeats": 1,
        "twin": False,
        "stages": False,
        "campaign_samples": 0,
        "one_by_one": False,
        "log": lambda m: None,
    }
    doc = bench.run_grid(["spheres"], [2000], [32], [1, 2], compositors=["lanes", "wide"], **kw)
    assert [(r["compositor"], r["k"]) for r in doc["results"]] == [("lanes", 1), ("lanes", 2)]
    assert doc["compositor_errors"] == {"wide": "RuntimeError: pipeline rejected\nby a driver"}
    with pytest.raises(RuntimeError, match="pipeline rejected"):
        bench.run_grid(["spheres"], [2000], [32], [1], compositors=["wide", "lanes"], **kw)
    # the same where the shape fails in its chunk sweep (new pipelines per chunk)
    monkeypatch.setattr(bench, "bench_config", real)
    monkeypatch.setattr(
        bench, "measure_chunk_sweep", failing_for_wide(bench.measure_chunk_sweep, "chunk pipeline rejected")
    )
    doc = bench.run_grid(["spheres"], [2000], [32], [1, 2], compositors=["lanes", "wide"], chunks=[256], **kw)
    assert [(r["compositor"], r["k"]) for r in doc["results"]] == [("lanes", 1), ("lanes", 2)]
    assert [c["compositor"] for c in doc["chunk_sweep"]] == ["lanes", "lanes"]
    assert doc["compositor_errors"] == {"wide": "RuntimeError: chunk pipeline rejected"}


def test_memory_tool_accounts_every_buffer(tmp_path, gpu):
    """tools/memory.py: the stored model is exactly 4 bytes per fp32 value, the buckets add up to
    the device total, the tile lists are 3 u32 per pair slot, plus the compositing slabs (two
    4 KiB tile slabs per chunk of pairs)."""
    from seuwgpu.render.composite import default_chunk

    spec = importlib.util.spec_from_file_location("seuwgpu_memory", BENCH.parent / "memory.py")
    mem = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mem)
    out = tmp_path / "m.json"
    assert mem.main(["--n", "3000", "--size", "48x32", "--json", str(out)]) == 0
    (rec,) = json.loads(out.read_text())
    model = sum(v for k, v in rec["by_label"].items() if k.startswith("model-chunk"))
    assert 236 * 3000 <= model < 236 * 3000 + 16  # 59 fp32 values per primitive, 16-byte padding
    assert sum(rec["by_label"].values()) == rec["device_bytes"]
    lists = sum(v for k, v in rec["by_label"].items() if k.startswith("bin.isect"))
    assert lists == 12 * rec["capacity"] and 12 < rec["bytes_per_pair_capacity"] < 12.5 + 8192 / default_chunk(gpu)
    assert 0 < rec["pairs"] <= rec["capacity"]
    assert rec["pixel_bytes"] == 16 * 48 * 32 and rec["view_s"] > 0


def test_chunking_fields(bench, gpu):
    """--dense: the shrunk scene lists long tiles (chunks of 256 here); both timings are measured
    and draw nearly the same image (the chunk rule differs only where pixels saturate)."""
    from seuwgpu.model import scenes

    model = bench.dense_model(scenes.make_scene("spheres", 3000, 1, 0), 0.3)
    rec = bench.measure_chunking(model, "spheres", 32, 1, repeats=1, gpu=gpu, chunk=256)
    json.dumps(rec)
    assert rec["ms_per_view_chunked"] > 0 and rec["ms_per_view_off"] > 0 and rec["speedup"] > 0
    assert rec["max_pairs_per_tile"] > 256 and rec["long_tiles"] > 0 and rec["tiles"] == 4
    assert rec["psnr_view0_chunked_vs_off_db"] > 40


def test_bench_times_views_one_at_a_time_against_batched(bench, gpu):
    """--one-by-one (the default on GPU adapters): the same configuration with the views rendered
    one at a time, recorded as not batched, draws the same frames (view 0's digest)."""
    from seuwgpu.model import scenes

    model = scenes.make_scene("blocks", 1500, 3, 0)
    kw = dict(repeats=1, gpu=gpu, stages=False)
    batched = bench.bench_config(model, "blocks", 32, 2, **kw)
    alone = bench.bench_config(model, "blocks", 32, 2, batch_views=False, **kw)
    assert batched["batched"] and not alone["batched"]
    assert alone["view0_sha256"] == batched["view0_sha256"]
    assert alone["dispatches_per_view"] > batched["dispatches_per_view"]
