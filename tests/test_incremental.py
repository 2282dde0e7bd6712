"""Incremental (dirty-tile) evaluation equals full re-rendering, bit for bit."""

import numpy as np
import pytest

from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.faults.engine import Engine
from seuwgpu.gpu.constants import TILE
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS, field_components
from seuwgpu.model.scenes import make_scene, scene_cameras

METRICS = ("footprint", "footprint_max", "peak_error", "psnr", "ssim", "nonfinite", "clamps")


def sample_sites(engine, rng, per_class=4):
    """Sites covering every field and every bit class, plus scale sign flips (frame-covering)."""
    sites = []
    for field in FIELDS:
        nc = field_components(field, engine.degree)
        for cls in ("sign", "exponent", "mantissa"):
            bits = encoding.bits_of_class(engine.precision, cls)
            for _ in range(per_class):
                sites.append(
                    engine.site(field, int(rng.integers(engine.n)), int(rng.integers(nc)), int(rng.choice(bits)))
                )
    sign = encoding.bits_of_class(engine.precision, "sign")[0]
    top_exp = encoding.bits_of_class(engine.precision, "exponent")[-1]
    for p in rng.choice(engine.n, 6, replace=False):
        sites.append(engine.site("log_scales", int(p), int(rng.integers(3)), sign))
        sites.append(engine.site("log_scales", int(p), int(rng.integers(3)), top_exp))
    return sites


def same(a, b):
    if isinstance(a, float) and np.isnan(a):
        return isinstance(b, float) and np.isnan(b)
    return a == b


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_incremental_equals_full_rerender(precision):
    model = make_scene("blocks", n=2500, seed=2)
    eng = Engine(model, scene_cameras("blocks", 2, 48, 40), precision, scene="blocks")
    rng = np.random.default_rng(11)
    sites = sample_sites(eng, rng, per_class=2)  # every field and bit class twice, 12 scale flips: 48 sites
    defenses = ("none", "guard", "ecc", "dup")
    inc = eng.evaluate(sites, defenses)
    assert len(inc) == len(sites) * len(defenses)
    catastrophic = 0
    for rec in inc:
        site = eng.site(rec["field"], rec["primitive"], rec["component"], rec["bit"])
        full = eng.inject(site, rec["defense"])
        for key in METRICS + ("clean_value", "corrupted_value"):  # values: the stored ones, in every arm
            assert same(rec[key], full[key]), (rec, key, full[key])
        catastrophic += rec["catastrophic"]
    assert catastrophic > 0, "the sample should hold frame-covering flips"


def test_defense_arms_are_paired_and_correct():
    model = make_scene("spheres", n=2000, seed=3)
    eng = Engine(model, scene_cameras("spheres", 2, 40, 40), "fp32")
    site = eng.site("log_scales", 10, 0, 31)
    recs = eng.evaluate([site], DEFENSES)
    by = {r["defense"]: r for r in recs}
    assert set(by) == set(DEFENSES)
    assert all(r["primitive"] == 10 and r["bit"] == 31 for r in recs)
    assert by["ecc"]["footprint"] == 0 and by["dup"]["footprint"] == 0
    assert by["ecc"]["psnr"] == np.inf
    assert by["guard"]["clamps"] == 1 and by["none"]["clamps"] == 0


def predicted(eng, site, defense, P, per_frame=False):
    """Regions reached by the corrupted primitive's tile rectangle, from the numpy twin (per_frame:
    the share of the P regions each view reaches, averaged over the views)."""
    from seuwgpu.analysis.contamination import region_set, regions_to_bitmask
    from seuwgpu.faults.guard import clamp_values
    from seuwgpu.model.fields import Model
    from seuwgpu.render.project import project

    _, bits, gm = eng.variant_bits([site], defense)
    vals = encoding.from_bits(bits, eng.precision)
    if gm[0]:
        vals, _ = clamp_values(vals, eng.box, int(gm[0]))
    one = Model.from_flat(vals, eng.degree)
    hit = np.zeros(P, bool)
    shares = []
    for cam in eng.cameras:
        x0, y0, x1, y1 = project(one, cam)["rect"][0] * TILE
        view = region_set((x0, y0, min(x1, eng.width), min(y1, eng.height)), eng.height, eng.width, P)
        hit |= view
        shares.append(view.sum() / P)
    return float(np.mean(shares)) if per_frame else regions_to_bitmask(hit)


@pytest.mark.parametrize("size", [(64, 48), (50, 38)])  # grids that divide the frame, and that do not
def test_region_contamination_matches_full_frames(size):
    from seuwgpu.analysis.contamination import region_set, regions_to_bitmask

    model = make_scene("spheres", n=2000, seed=4)
    eng = Engine(model, scene_cameras("spheres", 2, *size), "fp32")
    rng = np.random.default_rng(5)
    sites = sample_sites(eng, rng, per_class=1)
    regions = (2, 4, 12)  # the tile-aligned grids of a 4 x 3-tile frame
    recs = eng.evaluate(sites, ("none", "guard"), regions)
    seen_multi = False
    for rec in recs:
        site = eng.site(rec["field"], rec["primitive"], rec["component"], rec["bit"])
        h = eng.apply([site], rec["defense"])
        img, _ = eng.render_current(rec["defense"])
        eng.undo(h)
        with np.errstate(invalid="ignore"):
            changed = ((np.abs(img[..., :3] - eng.clean) > 1 / 255) | ~np.isfinite(img[..., :3])).any(-1)
        for P in regions:
            want = regions_to_bitmask(region_set(changed, eng.height, eng.width, P))
            assert rec[f"regions_meas_{P}"] == np.int64(np.uint64(want)), (rec, P)
            pred = int(np.uint64(np.int64(rec[f"regions_pred_{P}"])))
            assert pred == predicted(eng, site, rec["defense"], P), (rec, P)
            # per frame: each view's own regions, averaged over the views (never above the union)
            per_view = [region_set(changed[v], eng.height, eng.width, P).sum() / P for v in range(len(changed))]
            assert rec[f"regions_meas_frame_{P}"] == pytest.approx(np.mean(per_view)), (rec, P)
            assert rec[f"regions_pred_frame_{P}"] == pytest.approx(predicted(eng, site, rec["defense"], P, True))
            assert rec[f"regions_meas_frame_{P}"] <= bin(int(np.uint64(want))).count("1") / P + 1e-12
        seen_multi |= bin(int(np.uint64(np.int64(rec["regions_meas_12"])))).count("1") > 2
    assert seen_multi, "some flip in the sample should reach several of 12 regions"


def test_full_renders_in_between_leave_the_incremental_state_clean():
    model = make_scene("plant", n=1500, seed=6)
    eng = Engine(model, scene_cameras("plant", 2, 48, 48), "fp32", capacity=16)
    sites = [eng.site("log_scales", p, 0, 31) for p in range(0, 1500, 150)]
    before = eng.evaluate(sites)
    cap = eng.renderer.capacity
    for s in sites:  # full re-renders of corrupted models
        eng.inject([s, eng.site("log_scales", s.primitive, 1, 31)])
    # top exponent bit of every log-scale: -4 becomes about -4e-38, a unit-scale Gaussian filling
    # the frame, so the intersection buffers must grow during this faulted frame
    eng.inject([eng.site("log_scales", p, 0, 30) for p in range(1500)])
    assert eng.renderer.capacity > cap
    after = eng.evaluate(sites)
    for a, b in zip(before, after):
        for key in METRICS:
            assert same(a[key], b[key]), (a, key)


def test_arms_that_draw_the_same_frames_recomposite_nothing(monkeypatch):
    """ECC corrects sign/exponent upsets and repeats the unprotected arm's mantissa ones; TMR
    corrects all: neither re-composites a tile beyond the unprotected arm's, and their records
    still equal full re-renders (test_incremental_equals_full_rerender)."""
    from seuwgpu.render.incremental import IncrementalCompositor

    model = make_scene("spheres", n=1500, seed=8)
    eng = Engine(model, scene_cameras("spheres", 2, 48, 40), "fp32")
    sites = sample_sites(eng, np.random.default_rng(9), per_class=2)
    slabs = []
    encode = IncrementalCompositor.encode

    def counting(self, enc, prims, dirty, first):
        out = encode(self, enc, prims, dirty, first)
        slabs.append(out[1].size)
        return out

    monkeypatch.setattr(IncrementalCompositor, "encode", counting)
    eng.evaluate_frame(sites, ("none",))
    n_alone, slabs[:] = sum(slabs), []
    arms = eng.evaluate_frame(sites, ("none", "ecc", "dup"))
    assert n_alone > 0 and sum(slabs) == n_alone
    by = {d: g.reset_index(drop=True) for d, g in arms.groupby("defense")}
    assert (by["dup"]["footprint"] == 0).all() and (by["dup"]["psnr"] == np.inf).all()
    mantissa = (by["ecc"]["bit_class"] == "mantissa").to_numpy()
    for key in METRICS:  # ECC does not cover mantissa bits: the same frames as unprotected
        assert by["ecc"][key][mantissa].equals(by["none"][key][mantissa]), key
    assert (by["ecc"]["footprint"][~mantissa] == 0).all() and (by["none"]["footprint"][~mantissa] > 0).any()
    empty = eng.evaluate_frame([], ("none", "ecc", "dup"))  # no sites: no rows, the same columns
    assert len(empty) == 0 and list(empty.columns) == list(arms.columns)


@pytest.mark.parametrize("as_gpu", [False, True])
def test_kept_views_are_bound_a_view_group_at_a_time(gpu, monkeypatch, as_gpu):
    """A kept view set holds K tile lists (kv_isect_prims, kv_isect_box) and K views' records in one buffer
    each, bound one view group at a time (Renderer.kept_view_groups): with a 512 KiB binding, 4
    kept views of 65,536-pair lists (1 MiB buffers) are bound two views at a time, and a sheet's
    records (every tile of every view) equal a full re-render's. The evaluator's batches shrink to
    fit the binding too (as_gpu: the batch size a GPU adapter asks for, 2048 variants, whose
    metrics would need 2 MiB; it failed so on an H200, 2026-11-26)."""
    monkeypatch.setitem(gpu.limits, "max-storage-buffer-binding-size", 1 << 19)
    if as_gpu:
        monkeypatch.setattr(type(gpu), "is_cpu", property(lambda self: False))
    model = make_scene("spheres", 2000, 1, 0)
    cams = scene_cameras("spheres", 4, 32, 32)
    eng = Engine(model, cams, "fp32", gpu=gpu)
    r = eng.renderer
    assert r.max_capacity == (1 << 19) // 4 and r.capacity == 65536
    assert r.kv_isect_prims.size == 4 * 4 * 65536 > 1 << 19
    assert r.kept_view_groups() == [(0, 2), (2, 4)]
    site = eng.site("log_scales", 0, 0, 31)  # a sheet: every tile of every view
    recs = eng.evaluate_frame([site])
    assert len(recs) == 1 and recs["footprint"].iloc[0] > 0
    full = eng.inject(site)
    for key in ("footprint", "peak_error", "psnr", "ssim"):
        assert recs[key].iloc[0] == full[key], key
    from seuwgpu.metrics.image import entry_bytes

    B, cap = eng.evaluator.B, (256 if gpu.is_cpu else 2048)
    per_variant = 4 * r.n_tiles * entry_bytes()  # the metrics of every tile of its 4 views
    assert B % 2 == 0 and B <= cap and B * per_variant <= 1 << 19
    assert B == cap or (B + 2) * per_variant > 1 << 19  # the batch asked for, or all the binding holds
    if not gpu.is_cpu:
        assert B < 2048  # the binding, not the GPU batch, bounds it here


def test_run_interleaved_keeps_one_job_per_lane_and_the_order():
    """faults/incremental.py run_interleaved: results in job order; a lane runs its jobs one after
    another (a job's steps are never interleaved with another job on the same lane); jobs that
    finish at once or take many steps mix freely."""
    from seuwgpu.faults.incremental import run_interleaved

    busy, log = {}, []

    def job(i, steps):
        def start(lane):
            assert busy.get(lane) is None, f"lane {lane} already runs job {busy[lane]}"
            busy[lane] = i
            for s in range(steps):
                log.append((i, lane, s))
                yield
            busy[lane] = None
            return i * 10

        return start

    steps = [3, 0, 1, 5, 2, 0, 4]
    out = run_interleaved([job(i, s) for i, s in enumerate(steps)], ["x", "y"])
    assert out == [i * 10 for i in range(len(steps))]
    assert sum(steps) == len(log)
    first_steps = [i for i, _, s in log if s == 0]
    assert first_steps[:2] == [0, 2]  # job 1 ends before its first yield, so lane y goes on to job 2
    assert {lane for i, lane, _ in log if i == 0} == {"x"}
    assert run_interleaved([], ["x", "y"]) == []
    assert run_interleaved([job(0, 2)], ["x", "y"]) == [0]


def test_two_lanes_give_the_records_of_full_rerenders():
    """Batches of 8 variants, two in flight (IncrementalEvaluator lanes=2), groups split by a small
    slab budget so that batches take different numbers of steps: every record equals a full
    re-render's, and the sort-first regions those of one lane. The lanes share one host copy of
    the clean views' rectangles."""
    from seuwgpu.faults.incremental import IncrementalEvaluator

    model = make_scene("spheres", n=1200, seed=4)
    eng = Engine(model, scene_cameras("spheres", 2, 48, 40), "fp32", scene="spheres")
    sites = sample_sites(eng, np.random.default_rng(5), per_class=1)
    one = eng.evaluate_frame(sites, ("none", "guard"), regions=(4,))
    eng._evaluator = IncrementalEvaluator(eng, max_variants=8, max_entries=24, lanes=2)
    two = eng.evaluate_frame(sites, ("none", "guard"), regions=(4,))
    lanes = eng._evaluator.lanes
    assert len(lanes) == 2 and lanes[1].compositor.clean is lanes[0].compositor.clean  # one host copy
    import pandas as pd

    pd.testing.assert_frame_equal(one, two)
    for rec in two[two.defense == "none"].to_dict("records"):
        full = eng.inject(eng.site(rec["field"], rec["primitive"], rec["component"], rec["bit"]), "none")
        for key in METRICS:
            assert same(rec[key], full[key]), (rec, key, full[key])
