"""Binning stage (render/bin.py): count_tiles + scan + emit and tile_ranges on the GPU against the
numpy twin, exactly, on the same rectangles, screen records and depth order; exact binning's
dropped pairs checked against a brute-force float64 evaluation at every pixel of their tile, and
images with and without it compared bit for bit."""

import numpy as np
from conftest import random_model

from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.model.fields import Model
from seuwgpu.render.bin import Binning, emit, tile_lists, tile_ranges
from seuwgpu.render.composite import ellipse_quadrants
from seuwgpu.render.project import n_tiles_xy, project
from seuwgpu.render.renderer import Renderer
from seuwgpu.render.sort import depth_order


def packed(rects):
    r = np.asarray(rects, np.uint32)
    return np.stack([r[:, 0] | (r[:, 1] << 16), r[:, 2] | (r[:, 3] << 16)], axis=1)


def inputs(n=1500, seed=3, size=(72, 40)):
    """Rectangles and screen records of a twin projection, with a frame-covering sheet, and the
    full depth order (culled primitives last, as the GPU's depth sort leaves them)."""
    model = random_model(n, seed=seed)
    model.log_scales[7] = [60.0, 60.0, 60.0]  # overflowing scale: the whole frame
    model.opacity[9] = np.nan  # NaN opacity: never cut
    model.opacity[11] = -8.0  # alpha < 1/255 everywhere: paired with no tile
    cam = orbit_cameras(2, *size)[1]
    with np.errstate(all="ignore"):
        proj = project(model, cam)
    order = depth_order(proj)
    full = np.concatenate([order, np.setdiff1d(np.arange(n), order)])
    conic = np.column_stack([proj["conic"], proj["opacity"]]).astype(np.float32)
    records = {"proj_xy": proj["proj_xy"], "proj_conic": conic}
    return proj["rect"], full, n_tiles_xy(cam), size, records


def run_stage(gpu, rects, order, tiles, size, capacity, records, exact=True):
    tx, ty = tiles
    n = len(order)
    stage = Binning(gpu, n, exact=exact)
    stage.set_views(1, tx * ty)
    stage.set_capacity(capacity)
    stage.set_view(0, tiles_x=tx, size=size, origin=(0, 0), background=(1, 1, 1))
    stage.params.write()
    enc = gpu.device.create_command_encoder()
    xy, conic = gpu.upload(records["proj_xy"].astype(np.float32)), gpu.upload(records["proj_conic"])
    given = {"proj_rect": gpu.upload(packed(rects)), "depth_vals": gpu.upload(order.astype(np.uint32))}
    stage.encode_emit(enc, 0, {**given, "proj_xy": xy, "proj_conic": conic})
    gpu.submit(enc)
    return stage


def check_emit(gpu, stage, want, order):
    """The depth-ordered counts scanned in place into the offsets, each record's own offset (by
    record: the scatter back), the total and the pairs."""
    n, total = len(order), len(want["isect_tiles"])
    offsets = gpu.read(stage.counts)[:n]
    np.testing.assert_array_equal(offsets, want["offsets"])
    np.testing.assert_array_equal(np.diff(offsets.astype(np.int64), append=total), want["counts"])
    np.testing.assert_array_equal(gpu.read(stage.by_record)[:n][order], want["offsets"])
    assert gpu.read(stage.stats)[0] == total
    np.testing.assert_array_equal(gpu.read(stage.isect_tiles)[:total], want["isect_tiles"])
    np.testing.assert_array_equal(gpu.read(stage.isect_prims)[:total], want["isect_prims"])


def test_emit_matches_twin(gpu):
    rects, order, tiles, size, records = inputs()
    for exact in (True, False):
        want = emit(rects, order, tiles[0], records if exact else None)
        total = len(want["isect_tiles"])
        assert total > tiles[0] * tiles[1]  # the sheet covers every tile
        stage = run_stage(gpu, rects, order, tiles, size, total + 64, records, exact)
        check_emit(gpu, stage, want, order)


def test_exact_binning_drops_only_unreachable_pairs():
    """Every pair exact binning drops is one the compositor skips at every pixel of its tile
    (alpha < 1/255 or sigma < 0, evaluated here in float64 at all TILE^2 pixel centres, with no
    margin), the sheet and the NaN-opacity record keep every tile, the invisible record none, and
    a good share of the rectangles' pairs goes."""
    rects, order, tiles, size, records = inputs()
    full = emit(rects, order, tiles[0])
    exact = emit(rects, order, tiles[0], records)
    pair = lambda e: set(zip(e["isect_tiles"].tolist(), e["isect_prims"].tolist()))  # noqa: E731
    kept, every = pair(exact), pair(full)
    assert kept <= every
    dropped = every - kept
    assert 0.05 * len(every) < len(dropped) < 0.6 * len(every)
    xy = records["proj_xy"].astype(np.float64)
    co = records["proj_conic"].astype(np.float64)
    ii, jj = np.meshgrid(np.arange(16) + 0.5, np.arange(16) + 0.5)
    for t, g in dropped:
        px, py = (t % tiles[0]) * 16 + ii, (t // tiles[0]) * 16 + jj
        dx, dy = xy[g, 0] - px, xy[g, 1] - py
        sigma = 0.5 * (co[g, 0] * dx * dx + co[g, 2] * dy * dy) + co[g, 1] * dx * dy
        alpha = co[g, 3] * np.exp(-sigma)
        assert ((sigma < 0) | (alpha < 1 / 255)).all(), (t, g)
    n_tiles = tiles[0] * tiles[1]
    assert sum(1 for t, g in kept if g == 7) == n_tiles
    assert sum(1 for t, g in kept if g == 9) == sum(1 for t, g in every if g == 9) > 0
    assert not any(g == 11 for t, g in kept) and any(g == 11 for t, g in every)


def test_quadrant_masks_drop_only_unreachable_quadrants():
    """The compositor visits a record only in the 8 x 8 quadrants of its tile that its ellipse may
    reach (render/composite.py ellipse_quadrants): every (pair, quadrant) the rule drops has
    alpha < 1/255 or sigma < 0 at all 64 pixel centres (float64, no margin); the sheet and the
    NaN-opacity record keep every quadrant, and the rule drops a good share of the quadrants."""
    rects, order, tiles, size, records = inputs(n=2500, seed=12)
    e = emit(rects, order, tiles[0], records)
    t, g = e["isect_tiles"], e["isect_prims"]
    origin = np.stack([(t % tiles[0]) * 16, (t // tiles[0]) * 16], axis=1)
    quads = ellipse_quadrants(records["proj_xy"][g], records["proj_conic"][g], origin)
    assert (quads[g == 7] == 15).all() and (quads[g == 9] == 15).all()
    xy = records["proj_xy"].astype(np.float64)
    co = records["proj_conic"].astype(np.float64)
    ii, jj = np.meshgrid(np.arange(8) + 0.5, np.arange(8) + 0.5)
    dropped = 0
    for p in range(len(t)):
        for q in range(4):
            if quads[p] >> q & 1:
                continue
            dropped += 1
            px = origin[p, 0] + 8 * (q % 2) + ii
            py = origin[p, 1] + 8 * (q // 2) + jj
            dx, dy = xy[g[p], 0] - px, xy[g[p], 1] - py
            sigma = 0.5 * (co[g[p], 0] * dx * dx + co[g[p], 2] * dy * dy) + co[g[p], 1] * dx * dy
            alpha = co[g[p], 3] * np.exp(-sigma)
            assert ((sigma < 0) | (alpha < 1 / 255)).all(), (t[p], g[p], q)
    assert 0.2 * 4 * len(t) < dropped < 0.9 * 4 * len(t)


def test_exact_binning_leaves_images_bit_for_bit(gpu):
    """Exact binning (and the compositor's quadrant masks) against whole rectangles (and pixel
    boxes), on a model with non-finite and huge values, under both renderer profiles: the same
    frames bit for bit, with fewer pairs."""
    model = random_model(1200, seed=8)
    flat = model.flat()
    flat[3, 3:6] = 60.0  # frame-covering sheet
    flat[4, 10] = np.nan  # NaN opacity
    flat[5, 0] = np.nan  # NaN mean
    flat[6, 6:10] = [1e30, 0, 0, 1e-30]  # degenerate rotation
    flat[8, 3] = 12.0  # a needle
    flat[10, 11] = np.inf  # infinite colour
    model = Model.from_flat(flat, model.sh_degree)
    cams = orbit_cameras(3, 80, 48)
    for profile in ("strict", "gsplat"):
        a = Renderer(model, cams, gpu=gpu, profile=profile)
        b = Renderer(model, cams, gpu=gpu, profile=profile, exact_binning=False)
        img_a, img_b = a.render_rgba(), b.render_rgba()
        assert np.array_equal(img_a.view(np.uint32), img_b.view(np.uint32)), profile
        assert (a.last_totals[:3] < b.last_totals[:3]).all() and (~np.isfinite(img_a)).any()


def test_pairs_past_the_capacity_are_dropped_but_counted(gpu):
    rects, order, tiles, size, records = inputs(n=800, seed=4)
    want = emit(rects, order, tiles[0], records)
    cap = len(want["isect_tiles"]) // 2
    stage = run_stage(gpu, rects, order, tiles, size, cap, records)
    assert gpu.read(stage.stats)[0] == len(want["isect_tiles"])  # the renderer grows and re-runs
    np.testing.assert_array_equal(gpu.read(stage.isect_tiles)[:cap], want["isect_tiles"][:cap])
    np.testing.assert_array_equal(gpu.read(stage.isect_prims)[:cap], want["isect_prims"][:cap])


def test_tile_ranges_match_twin(gpu):
    rects, order, tiles, size, records = inputs(seed=5)
    n_tiles = tiles[0] * tiles[1]
    want_ranges, want_prims = tile_lists(rects, order, tiles[0], n_tiles)
    e = emit(rects, order, tiles[0])
    sorted_tiles = np.sort(e["isect_tiles"], kind="stable")
    stage = run_stage(gpu, rects, order, tiles, size, len(sorted_tiles) + 16, records, exact=False)
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


def test_batched_views_bin_as_each_view_alone(gpu):
    """The batched variant (Binning.set_views(batched=True), bin.wgsl with views = K): K views'
    records one after the other, in one mixed depth order, give pair tile ids v * n_tiles + tile,
    and after a stable sort by tile id, each view's tile lists, ranges and total are the twin's for
    that view alone."""
    n, size, k = 700, (72, 40), 3
    model = random_model(n, seed=8)
    model.log_scales[5] = [60.0, 60.0, 60.0]  # a frame-covering sheet in every view
    cams = orbit_cameras(k, *size)
    tx, ty = n_tiles_xy(cams[0])
    projs = []
    with np.errstate(all="ignore"):
        projs = [project(model, cam) for cam in cams]
    rects = np.concatenate([p["rect"] for p in projs])
    xy = np.concatenate([p["proj_xy"] for p in projs]).astype(np.float32)
    conic = np.concatenate([np.column_stack([p["conic"], p["opacity"]]) for p in projs]).astype(np.float32)
    depth = np.concatenate([np.where(p["visible"], p["depth"], np.inf) for p in projs]).astype(np.float32)
    order = np.argsort(depth, kind="stable")  # all K views mixed, ties by record index
    stage = Binning(gpu, n)
    stage.set_views(k, tx * ty, batched=True)
    stage.set_capacity(1 << 16)
    stage.set_view(0, tiles_x=tx, size=size, origin=(0, 0), background=(1, 1, 1))
    stage.params.write()
    slot = stage.batch_slot
    enc = gpu.device.create_command_encoder()
    names = ("proj_rect", "depth_vals", "proj_xy", "proj_conic")
    arrays = (packed(rects), order.astype(np.uint32), xy, conic)
    stage.encode_emit(enc, slot, {name: gpu.upload(a) for name, a in zip(names, arrays)})
    gpu.submit(enc)
    total = int(gpu.read(stage.stats)[slot])
    tiles = gpu.read(stage.isect_tiles)[:total].astype(np.int64)
    prims = gpu.read(stage.isect_prims)[:total].astype(np.int64)
    by_tile = np.argsort(tiles, kind="stable")
    gpu.write(stage.isect_tiles, tiles[by_tile].astype(np.uint32))
    enc = gpu.device.create_command_encoder()
    stage.encode_ranges(enc, slot)
    gpu.submit(enc)
    ranges = gpu.read(stage.ranges, np.uint32, 0, 8 * k * tx * ty).reshape(k * tx * ty, 2).astype(np.int64)
    totals = gpu.read(stage.stats)[:k]
    wanted = 0
    for v, p in enumerate(projs):
        rec = {"proj_xy": p["proj_xy"], "proj_conic": np.column_stack([p["conic"], p["opacity"]]).astype(np.float32)}
        want_ranges, want_prims = tile_lists(p["rect"], depth_order(p), tx, tx * ty, rec)
        mine = ranges[v * tx * ty : (v + 1) * tx * ty]
        first = mine[0, 0]
        np.testing.assert_array_equal(mine - first, want_ranges)
        np.testing.assert_array_equal(prims[by_tile][mine[0, 0] : mine[-1, 1]] - v * n, want_prims)
        assert totals[v] == len(want_prims)
        wanted += len(want_prims)
    assert total == wanted
