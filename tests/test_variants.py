"""Variant re-compositing stage (render/variants.py, shaders/variants.wgsl): the variants entry
against its numpy twin (variant_list over the kept records) and against full re-renders of each
variant, bit for bit; the checkpoint pass against its twin (tile_checkpoints)."""

import numpy as np
import pytest
from conftest import random_model
from test_composite import _dense_model, assert_close

from seuwgpu.gpu.constants import CHUNK
from seuwgpu.model import encoding
from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.model.fields import Model
from seuwgpu.render.composite import composite_tile, tile_pixels
from seuwgpu.render.incremental import CleanViews, IncrementalCompositor
from seuwgpu.render.renderer import Renderer
from seuwgpu.render.variants import OPEN, tile_checkpoints, variant_list


def test_variants_match_twin(gpu):
    """variants.wgsl:variants re-composites tiles of single-upset variants from the clean frame's
    kept state; the twin rebuilds each tile's list (variant_list) from the same kept records."""
    model = random_model(900, seed=5)
    cams = orbit_cameras(2, 56, 40)
    r = Renderer(model, cams, keep_views=True)
    r.capture_views = True
    clean = r.render_rgba()
    r.capture_views = False
    clean_buf = gpu.upload(clean)
    comp = IncrementalCompositor(r, clean_buf, max_variants=8, max_entries=512)
    prims = np.array([3, 40, 41, 500, 899])
    bits = encoding.to_bits(r.layout.decode(r.clean_words).flat()[prims], "fp32")
    bits[0, 3] ^= np.uint32(1 << 31)  # log-scale sign flip: a large footprint
    bits[1, 10] ^= np.uint32(1 << 30)  # opacity exponent: opaque or gone
    bits[2, 0] ^= np.uint32(1 << 29)  # mean moves: leaves some tiles, enters others
    bits[3, 11] = 0x7FC00000  # NaN colour
    new_rects = comp.project(bits)
    dirty = comp.dirty_tiles(prims, new_rects)
    enc = gpu.device.create_command_encoder()
    _, b_idx, v_idx, t_idx = comp.encode(enc, prims, dirty, 0)
    gpu.submit(enc)
    slabs = comp.read_slabs(len(b_idx))
    assert len(b_idx) > 20
    k, n, B, cap, stride = r.k, r.n, comp.B, r.capacity, r.kv_stride  # view v's records at v * stride
    kv = {
        "xy": gpu.read(r.kv_proj_xy, np.float32).reshape(k, stride, 2)[:, :n],
        "conic": gpu.read(r.kv_proj_conic, np.float32).reshape(k, stride, 4)[:, :n],
        "rgb": gpu.read(r.kv_proj_rgb, np.float32).reshape(k, stride, 4)[:, :n],
        "ranges": gpu.read(r.kv_ranges).reshape(k, r.n_tiles, 2),
        "isect": gpu.read(r.kv_isect_prims).reshape(k, cap),
    }
    var = comp.projection.read(k * B)
    bg = r.background
    for e, (b, v, t) in enumerate(zip(b_idx, v_idx, t_idx)):
        p, vi = int(prims[b]), v * B + b
        a, z = kv["ranges"][v, t]
        keys = kv["rgb"][v, :, 3].view(np.uint32)
        x0, y0, x1, y1 = var["rect"][vi]
        tx, ty = t % r.tiles_x, t // r.tiles_x
        ids = variant_list(kv["isect"][v, a:z], keys, p, var["depth_keys"][vi], x0 <= tx < x1 and y0 <= ty < y1)
        xy, conic, rgb = kv["xy"][v].copy(), kv["conic"][v].copy(), kv["rgb"][v].copy()
        xy[p], rgb[p, :3] = var["proj_xy"][vi], var["rgb"][vi]
        conic[p] = np.append(var["conic"][vi], var["opacity"][vi])
        (ys, xs), pxs, pys = tile_pixels(tx, ty, r.width, r.height)
        want, T = composite_tile(ids, pxs, pys, xy[:, 0], xy[:, 1], conic[:, :3], conic[:, 3], rgb[:, :3], bg)
        got = slabs[e, : ys.stop - ys.start, : xs.stop - xs.start].reshape(-1, 4)
        assert_close(got[:, :3], want)
        assert_close(got[:, 3], T)


def incremental_equals_full(gpu, model, cams, kw, prims, min_entries=20, every=None) -> int:
    """Upsets of `prims` that move a primitive inside the tile lists (depth), make it a sheet,
    opaque or NaN, or remove it, re-composited by the variants entry: every dirty tile equals a
    full re-render of the variant bit for bit. Returns the longest clean tile list. `every`: the
    clean views' checkpoint interval (render/incremental.py CleanViews; default its own)."""
    r = Renderer(model, cams, keep_views=True, **kw)
    r.capture_views = True
    clean = r.render_rgba()
    r.capture_views = False
    views = CleanViews(r, every)
    comp = IncrementalCompositor(r, gpu.upload(clean), max_variants=8, max_entries=512, clean=views)
    flat = r.layout.decode(r.clean_words).flat()
    bits = encoding.to_bits(flat[prims], "fp32")
    bits[0, 2] ^= np.uint32(1 << 29)  # mean z: moves in depth
    bits[1, 2] ^= np.uint32(1 << 22)  # mean z mantissa: a small move in the list
    bits[2, 3] ^= np.uint32(1 << 31)  # log-scale sign: a sheet over every tile
    bits[3, 10] ^= np.uint32(1 << 30)  # opacity exponent
    bits[4, 11] = 0x7FC00000  # NaN colour
    bits[5, 0] = 0x7FC00000  # NaN mean: removed from every list
    bits[6, 5] ^= np.uint32(1 << 30)  # log-scale exponent: huge
    new_rects = comp.project(bits)
    dirty = comp.dirty_tiles(prims, new_rects)
    enc = gpu.device.create_command_encoder()
    _, b_idx, v_idx, t_idx = comp.encode(enc, prims, dirty, 0)
    gpu.submit(enc)
    slabs = comp.read_slabs(len(b_idx)).view(np.uint32)
    assert len(b_idx) >= min_entries
    # the box of each slab's pixels that differ from the clean tile (rgb bits): the metrics reduce
    # only those tiles and the neighbours their SSIM windows reach
    clean_bits = clean.view(np.uint32)
    boxes = comp.read_changed(len(b_idx))
    for e, (v, t) in enumerate(zip(v_idx, t_idx)):
        ty, tx = divmod(int(t), r.tiles_x)
        diff = (slabs[e, :, :, :3] != clean_bits[v, ty * 16 : ty * 16 + 16, tx * 16 : tx * 16 + 16, :3]).any(axis=2)
        ys, xs = np.nonzero(diff)
        want = [xs.min(), xs.max(), ys.min(), ys.max()] if diff.any() else None
        assert (boxes[e].tolist() if boxes[e, 0] <= boxes[e, 1] else None) == want, e
    differ = boxes[:, 0] <= boxes[:, 1]
    assert 0 < differ.sum() < len(differ)
    for b, p in enumerate(prims):
        f = flat.copy()
        f[p] = encoding.from_bits(bits[b : b + 1], "fp32")[0]
        full = Renderer(Model.from_flat(f, r.degree), cams, **kw).render_rgba()
        full = full.view(np.uint32)
        for e in np.flatnonzero(b_idx == b):
            v, t = v_idx[e], t_idx[e]
            ty, tx = divmod(int(t), r.tiles_x)
            want = full[v, ty * 16 : ty * 16 + 16, tx * 16 : tx * 16 + 16]
            assert np.array_equal(slabs[e], want), (b, v, t)
    return comp.longest_list


@pytest.mark.parametrize(
    "profile, exact, chunk, shape",
    [
        ("strict", True, 256, "lanes"),
        ("gsplat", True, 256, "lanes"),
        ("strict", False, 256, "lanes"),
        ("strict", True, 512, "lanes"),
        ("strict", True, 256, "wide"),
    ],
)
def test_chunked_incremental_equals_full_rerender(gpu, profile, exact, chunk, shape):
    """The variants entry under chunks of 256 (or 512: it then walks the lists 512 entries a
    round), one chunk per dispatch, re-composites every dirty tile exactly as a full re-render of
    the variant does, bit for bit, with exact binning (the variant is listed only on the tiles its
    footprint reaches, as the binning lists it) and without; also where the clean frame (its pair
    boxes and stop positions) and the full re-renders come from the wide compositor."""
    model = _dense_model(1500, 4)
    kw = {"gpu": gpu, "chunk": chunk, "profile": profile, "exact_binning": exact, "compositor": shape}
    longest = incremental_equals_full(
        gpu, model, orbit_cameras(2, 32, 32), kw, np.array([5, 77, 300, 301, 900, 1200, 1499])
    )
    assert longest > chunk  # two chunks and more: later dispatches carry the running state


@pytest.mark.parametrize("every", [1024, 2048])
def test_incremental_resumes_from_checkpoints(gpu, every):
    """Chunks of 2048 with checkpoints every 1024 (inside a chunk, and at chunk starts) or 2048
    (chunk starts only): every variant's walk resumes at the clean frame's last checkpoint before
    its change, its other pixels are copied unless a record that reaches them crossed a chunk
    boundary, and every dirty tile still equals a full re-render bit for bit."""
    model = _dense_model(5000, 5)
    kw = {"gpu": gpu, "chunk": 2048}
    prims = np.array([5, 77, 1300, 2501, 3900, 4200, 4999])
    longest = incremental_equals_full(gpu, model, orbit_cameras(2, 32, 32), kw, prims, every=every)
    assert longest > 2048  # two chunks: a checkpoint at the second one's start (and at 1024)


def test_checkpoint_pass_matches_twin(gpu):
    """The checkpoint pass (variants.wgsl:checkpoints) against its numpy twin on the renderer's
    own screen records and tile lists: each pixel's end (the last list position its value depends
    on, across chunk merges; for a pixel that never ends, the last record that reaches it) and its
    state at every checkpoint it is alive at; on lists of one chunk the ends of the pixels that
    stop are the stops main wrote, bit for bit."""
    model = _dense_model(5000, 6)
    r = Renderer(model, orbit_cameras(1, 32, 32), keep_views=True, gpu=gpu, chunk=2048)
    r.capture_views = True
    r.render_rgba()
    r.capture_views = False
    stops_main = gpu.read(r.kv_stop_pos).copy()
    views = CleanViews(r, 1024)
    ends = gpu.read(r.kv_stop_pos).reshape(r.height, r.width).astype(np.int64)
    main_ends = stops_main.reshape(r.height, r.width).astype(np.int64)
    states = gpu.read(views.ckpt_states, np.float32).reshape(-1, 16, 16, 4)
    base = gpu.read(views.ckpt_base)
    ranges = gpu.read(r.kv_ranges).reshape(-1, 2).astype(np.int64)
    isect = gpu.read(r.kv_isect_prims)
    xy = gpu.read(r.kv_proj_xy, np.float32).reshape(-1, 2)
    co = gpu.read(r.kv_proj_conic, np.float32).reshape(-1, 4)
    rgb = gpu.read(r.kv_proj_rgb, np.float32).reshape(-1, 4)
    long_tiles = checked = 0
    for t in range(r.n_tiles):
        a, b = ranges[t]
        ty, tx = divmod(t, r.tiles_x)
        (ys, xs), pxs, pys = tile_pixels(tx, ty, r.width, r.height)
        want_states, want_ends = tile_checkpoints(
            isect[a:b], pxs, pys, xy[:, 0], xy[:, 1], co[:, :3], co[:, 3], rgb[:, :3], 2048, 1024
        )
        got_ends = ends[ys, xs].reshape(-1)
        assert (got_ends == want_ends).mean() > 0.99  # a stop may move by float32 rounding of exp
        if b - a <= 2048:
            stopped = main_ends[ys, xs].reshape(-1) != 0xFFFFFFFF
            assert np.array_equal(got_ends[stopped], main_ends[ys, xs].reshape(-1)[stopped])
            assert (got_ends[~stopped] >= OPEN).all()
            continue
        long_tiles += 1
        for pos, (C, T) in sorted(want_states.items()):
            alive = ((got_ends >= pos) | (got_ends >= OPEN)) & (got_ends == want_ends)
            got = states[base[t] + pos // 1024 - 1].reshape(-1, 4)
            assert_close(got[alive, :3], C[alive])
            assert_close(got[alive, 3], T[alive])
            checked += int(alive.sum())
    assert long_tiles and checked


def test_incremental_lists_past_the_cpu_loop_limit(gpu):
    """A one-tile frame listing ~90k faint records (pixels stay unsaturated), past llvmpipe's
    walk bound (~54k pairs: gpu/constants.py CHUNK): the variants entry walks one default chunk per dispatch, and
    every variant's tile equals a full re-render bit for bit, the frame-covering sheet (which walks
    every entry) included. Walking the whole list on one workgroup, as before, fails here on
    lavapipe (the first variant's tile already differs)."""
    model = random_model(100_000, seed=6)
    flat = model.flat()
    flat[:, 10] -= 5.0  # faint: most pixels are walked through the whole list
    model = Model.from_flat(flat, model.sh_degree)
    kw = {"gpu": gpu}
    longest = incremental_equals_full(
        gpu, model, orbit_cameras(1, 16, 16), kw, np.array([3, 900, 17000, 30001, 41000, 52000, 99999]), 7
    )
    assert longest > CHUNK
