"""Binning stage (render/bin.py): count_tiles + scan + emit and tile_ranges on the GPU against the
numpy twin, exactly, on the same rectangles and depth order."""

import numpy as np
from conftest import random_model

from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.render.bin import Binning, emit, tile_lists, tile_ranges
from seuwgpu.render.project import n_tiles_xy, project
from seuwgpu.render.sort import depth_order


def packed(rects):
    r = np.asarray(rects, np.uint32)
    return np.stack([r[:, 0] | (r[:, 1] << 16), r[:, 2] | (r[:, 3] << 16)], axis=1)


def inputs(n=1500, seed=3, size=(72, 40)):
    """Rectangles of a twin projection, with a frame-covering sheet, and the full depth order
    (culled primitives last, as the GPU's depth sort leaves them)."""
    model = random_model(n, seed=seed)
    model.log_scales[7] = [60.0, 60.0, 60.0]  # overflowing scale: the whole frame
    cam = orbit_cameras(2, *size)[1]
    with np.errstate(all="ignore"):
        proj = project(model, cam)
    order = depth_order(proj)
    full = np.concatenate([order, np.setdiff1d(np.arange(n), order)])
    return proj["rect"], full, n_tiles_xy(cam), size


def run_stage(gpu, rects, order, tiles, size, capacity):
    tx, ty = tiles
    n = len(order)
    stage = Binning(gpu, n)
    stage.set_views(1, tx * ty)
    stage.set_capacity(capacity)
    stage.set_view(0, tiles_x=tx, size=size, origin=(0, 0), background=(1, 1, 1))
    stage.params.write()
    enc = gpu.device.create_command_encoder()
    stage.encode_emit(enc, 0, gpu.upload(packed(rects)), gpu.upload(order.astype(np.uint32)))
    gpu.submit(enc)
    return stage


def test_emit_matches_twin(gpu):
    rects, order, tiles, size = inputs()
    want = emit(rects, order, tiles[0])
    total = len(want["isect_tiles"])
    stage = run_stage(gpu, rects, order, tiles, size, capacity=total + 64)
    n = len(order)
    np.testing.assert_array_equal(gpu.read(stage.counts)[:n], want["counts"])
    np.testing.assert_array_equal(gpu.read(stage.offsets)[:n], want["offsets"])
    assert gpu.read(stage.stats)[0] == total > tiles[0] * tiles[1]  # the sheet covers every tile
    np.testing.assert_array_equal(gpu.read(stage.isect_tiles)[:total], want["isect_tiles"])
    np.testing.assert_array_equal(gpu.read(stage.isect_prims)[:total], want["isect_prims"])


def test_pairs_past_the_capacity_are_dropped_but_counted(gpu):
    rects, order, tiles, size = inputs(n=800, seed=4)
    want = emit(rects, order, tiles[0])
    cap = len(want["isect_tiles"]) // 2
    stage = run_stage(gpu, rects, order, tiles, size, capacity=cap)
    assert gpu.read(stage.stats)[0] == len(want["isect_tiles"])  # the renderer grows and re-runs
    np.testing.assert_array_equal(gpu.read(stage.isect_tiles)[:cap], want["isect_tiles"][:cap])
    np.testing.assert_array_equal(gpu.read(stage.isect_prims)[:cap], want["isect_prims"][:cap])


def test_tile_ranges_match_twin(gpu):
    rects, order, tiles, size = inputs(seed=5)
    n_tiles = tiles[0] * tiles[1]
    want_ranges, want_prims = tile_lists(rects, order, tiles[0], n_tiles)
    e = emit(rects, order, tiles[0])
    sorted_tiles = np.sort(e["isect_tiles"], kind="stable")
    stage = run_stage(gpu, rects, order, tiles, size, capacity=len(sorted_tiles) + 16)
    gpu.write(stage.isect_tiles, sorted_tiles.astype(np.uint32))  # the tile sort's output
    enc = gpu.device.create_command_encoder()
    stage.encode_ranges(enc, 0)
    gpu.submit(enc)
    got = gpu.read(stage.ranges).reshape(-1, 2)[:n_tiles]
    np.testing.assert_array_equal(got, tile_ranges(sorted_tiles, n_tiles))
    np.testing.assert_array_equal(got, want_ranges)
    assert (got[:, 1] > got[:, 0]).all()  # every tile lists at least the sheet
    # the twin's lists: each tile's primitives front to back, exactly those whose rectangle covers it
    t = 5
    ids = want_prims[want_ranges[t, 0] : want_ranges[t, 1]]
    cover = (rects[:, 0] <= t % tiles[0]) & (rects[:, 2] > t % tiles[0])
    cover &= (rects[:, 1] <= t // tiles[0]) & (rects[:, 3] > t // tiles[0])
    np.testing.assert_array_equal(ids, [i for i in order if cover[i]])
