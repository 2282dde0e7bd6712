"""Pipeline-state faults (faults/state.py): a flip in a compositor input of one view equals the
compositing twin run on the same flipped inputs, other views and the next frame stay clean bit
for bit, a pixel flip is exactly that XOR, and runaway ranges are DUE."""

import numpy as np
import pytest
from conftest import psnr_finite

from seuwgpu.faults.engine import Engine
from seuwgpu.faults.state import FORMER_NAMES, TARGETS, StateFaults, check_target, state_campaign
from seuwgpu.model.scenes import make_scene, scene_cameras
from seuwgpu.render.bin import tile_lists
from seuwgpu.render.composite import composite_frame
from seuwgpu.render.project import unpack_rects


@pytest.fixture(scope="module")
def sf():
    model = make_scene("blocks", n=400, seed=3)
    return StateFaults(Engine(model, scene_cameras("blocks", 2, 48, 40), "fp32", scene="blocks"))


def kept(sf, v):
    r, g = sf.r, sf.engine.gpu
    n, s = r.n, r.kv_stride  # view v's records at v * kv_stride
    return {
        "proj_xy": g.read(r.kv_proj_xy, np.uint32, 8 * s * v, 8 * n).reshape(n, 2),
        "proj_conic": g.read(r.kv_proj_conic, np.uint32, 16 * s * v, 16 * n).reshape(n, 4),
        "proj_rgb": g.read(r.kv_proj_rgb, np.uint32, 16 * s * v, 16 * n).reshape(n, 4),
        "isect_prims": g.read(r.kv_isect_prims, np.uint32, 4 * r.capacity * v, 4 * int(sf.totals[v])).reshape(-1, 1),
        "ranges": sf.ranges[v].copy(),
    }


@pytest.mark.parametrize(
    "target, index, comp, bit",
    [
        ("proj_xy", 5, 0, 28),
        ("proj_conic", 9, 0, 27),
        ("proj_rgb", 7, 1, 30),
        ("isect_prims", 11, 0, 3),
        ("ranges", 4, 1, 0),
    ],
)
def test_compositor_input_flips_equal_the_twin(sf, target, index, comp, bit):
    v = 1
    state = kept(sf, v)
    index = index % len(state[target])
    if target == "ranges":  # a flip that keeps the range inside the list
        rng = state[target][index]
        bit = 0 if rng[1] ^ 1 <= sf.totals[v] and rng[0] <= rng[1] ^ 1 else 1
        assert not sf.is_due(target, v, index, comp, bit)
    got = sf.render(target, v, index, comp, bit)
    state[target][index, comp] ^= np.uint32(1 << bit)
    f = {k: state[k].view(np.float32) for k in ("proj_xy", "proj_conic", "proj_rgb")}
    n = sf.r.n
    ids = np.minimum(state["isect_prims"][:, 0], n - 1)  # an id past the records reads the last (robust access)
    records = {
        "proj_xy": f["proj_xy"],
        "conic": f["proj_conic"][:, :3],
        "opacity": f["proj_conic"][:, 3],
        "rgb": f["proj_rgb"][:, :3],
    }
    ranges = state["ranges"]
    if target in ("proj_xy", "proj_conic"):  # flipped before binning, which reads them (exact binning): re-bin
        g = sf.engine.gpu
        rects = unpack_rects(g.read(sf.r.kv_proj_rect, np.uint32, 8 * sf.r.kv_stride * v, 8 * n).reshape(n, 2))
        order = np.lexsort((np.arange(n), state["proj_rgb"][:, 3]))  # depth bits, ties by index
        bin_records = {"proj_xy": f["proj_xy"], "proj_conic": f["proj_conic"]}
        ranges, ids = tile_lists(rects, order, sf.r.tiles_x, sf.r.n_tiles, bin_records)
    want = composite_frame(ranges, ids, records, sf.r.width, sf.r.height)
    assert psnr_finite(got[v], want) > 60
    np.testing.assert_array_equal(got[0], sf.engine.clean_rgba[0])  # the other view: clean
    np.testing.assert_array_equal(sf.engine.render_current("none")[0], sf.engine.clean_rgba)  # transient


def test_pixel_flip_is_that_xor_and_ranges_past_the_list_are_due(sf):
    got = sf.render("image", 0, 123, 2, 30)
    want = sf.engine.clean_rgba.copy()
    y, x = divmod(123, sf.r.width)
    want.view(np.uint32)[0, y, x, 2] ^= np.uint32(1 << 30)
    np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))
    t = int(np.argmax(sf.ranges[0, :, 1] - sf.ranges[0, :, 0]))
    assert sf.is_due("ranges", 0, t, 1, 31) and sf.is_due("ranges", 0, t, 0, 31)
    rec = sf.inject("ranges", 0, t, 1, 31)
    assert rec["due"] and np.isnan(rec["footprint"]) and not rec["catastrophic"]


def test_targets_are_the_pipelines_declared_outputs_under_their_former_names_too(sf):
    """The targets are PIPELINE's fault outputs, each flipped after the stage that declares it,
    in pipeline order; a former name is read as its buffer's."""
    assert list(TARGETS) == [
        "proj_xy",
        "proj_conic",
        "proj_rgb",
        "depth_keys",
        "isect_tiles",
        "isect_prims",
        "ranges",
        "image",
    ]
    assert [TARGETS[t][0] for t in ("depth_keys", "isect_tiles", "isect_prims")] == ["project", "emit", "tile_sort"]
    assert FORMER_NAMES["pixel"] == "image" and check_target("tile_key") == "isect_tiles"
    assert sf.buffer("isect_prim") is sf.r.binning.isect_prims
    assert sf.word("pixel", 1, 2, 3) == sf.word("image", 1, 2, 3) == sf.r.width * sf.r.height * 4 + 2 * 4 + 3
    with pytest.raises(ValueError, match="unknown pipeline-state target 'rects'"):
        check_target("rects")


def test_state_campaign_covers_every_target(sf):
    df = state_campaign(sf.engine, samples=1, bits=[30], seed=1)
    assert set(df.target) == set(TARGETS) and len(df) == len(TARGETS)
    assert df.loc[~df.due, "footprint"].notna().all()


def test_a_resumed_state_run_flips_what_an_uninterrupted_one_did(sf, monkeypatch):
    """A run given the first m records of a run (a resumed one) renders only the others, replaying
    the draws of those it skips, and its records equal the uninterrupted run's."""
    import pandas as pd

    args = dict(targets=["proj_xy", "isect_tiles", "image"], samples=2, bits=[30, 3], seed=5)
    whole = state_campaign(sf.engine, **args)
    assert len(whole) == 12 and whole[["view", "index", "comp"]].drop_duplicates().shape[0] > 6
    real, calls = StateFaults.inject, []
    monkeypatch.setattr(StateFaults, "inject", lambda self, *a: calls.append(a) or real(self, *a))
    for m in (1, 6, 12):
        calls.clear()
        got = state_campaign(sf.engine, **args, rows=whole.iloc[:m].to_dict("records"))
        assert len(calls) == len(whole) - m
        pd.testing.assert_frame_equal(got, whole)
    with pytest.raises(ValueError, match="13 records given for a pipeline-state run of 12"):
        state_campaign(sf.engine, **args, rows=[*whole.to_dict("records"), {}])


def test_state_table_recomputed_with_pandas(tmp_path):
    import pandas as pd

    from seuwgpu.analysis.defenses import state_table
    from seuwgpu.apps.cli import main

    out = tmp_path / "st"
    args = ["state", "--scene", "blocks", "--n", "300", "--size", "32x32", "--samples", "2", "--bit", "3", "30"]
    # the targets' former names still work; the records carry the buffers' names
    assert main([*args, "--targets", "xy", "tile_range", "--out", str(out)]) == 0
    df = pd.read_parquet(out / "state.parquet")
    assert set(df.target) == {"proj_xy", "ranges"}
    t = state_table(df).set_index(["target", "bit_class"])
    for tgt, g in df.groupby("target"):
        row = t.loc[(tgt, "all")]
        assert row["cat_n"] == len(g) and row["cat_events"] == g.catastrophic.sum()
        # equal cells: the stratified rate is the mean of the per-bit rates
        assert row["cat_rate"] == pytest.approx(g.groupby("bit").catastrophic.mean().mean())
        assert row["due_events"] == g.due.sum()
    assert t.loc[("proj_xy", "exponent"), "cat_n"] == (df[df.target == "proj_xy"].bit == 30).sum()


@pytest.mark.parametrize("bit", [32, -1])
def test_bits_outside_a_word_are_refused(bit, tmp_path, capsys):
    """A state word has bits 0..31: --bit 32 was an OverflowError traceback, -1 'negative shift
    count'; refused before any rendering (the library call too)."""
    from types import SimpleNamespace

    from seuwgpu.apps.cli import main

    with pytest.raises(ValueError, match=f"bit {bit} is out of range for a pipeline-state word"):
        state_campaign(SimpleNamespace(), targets=["xy"], samples=1, bits=[bit])
    args = ["state", "--scene", "blocks", "--n", "50", "--size", "16x16", "--bit", str(bit)]
    with pytest.raises(SystemExit) as exited:
        main([*args, "--out", str(tmp_path / "st")])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error: argument --bit" in err.strip().splitlines()[-1]
    assert not (tmp_path / "st").exists()
