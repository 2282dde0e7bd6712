"""Compositing stage (render/composite.py): both entry points on the GPU against the numpy twin,
on the same screen records and tile lists.

Which pixels are non-finite is exact; finite values agree to 1e-5 of max(1, |value|): the GPU's
exp and fused multiply-adds may differ from numpy's float32 by an ulp (measured: <= 2.4e-7)."""

import numpy as np
from conftest import random_model

from seuwgpu.model import encoding
from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.model.fields import Model
from seuwgpu.render.bin import Binning, tile_lists
from seuwgpu.render.composite import Compositing, composite_frame, composite_tile, tile_pixels, variant_list
from seuwgpu.render.incremental import IncrementalCompositor
from seuwgpu.render.project import n_tiles_xy, project
from seuwgpu.render.renderer import Renderer
from seuwgpu.render.sort import depth_order

TOL = 1e-5


def assert_close(got, want):
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.array_equal(np.isinf(got), np.isinf(want))
    assert np.array_equal(got[np.isinf(got)], want[np.isinf(want)])
    fin = np.isfinite(want)
    err = np.abs(got[fin] - want[fin]) / np.maximum(1.0, np.abs(want[fin]))
    assert err.max(initial=0) <= TOL, err.max()


def test_frame_matches_twin(gpu):
    model = random_model(2000, seed=2)
    flat = model.flat()
    flat[11, 11:14] = [np.inf, np.nan, -np.inf]  # non-finite colour: reaches its pixels
    flat[12, 3:6] = 60.0  # a translucent frame-covering sheet
    flat[13, 10] = np.nan  # NaN opacity
    model = Model.from_flat(flat, model.sh_degree)
    cam = orbit_cameras(3, 72, 40)[1]
    w, h = cam.width, cam.height
    tx, ty = n_tiles_xy(cam)
    with np.errstate(all="ignore"):
        rec = project(model, cam)
    ranges, prims = tile_lists(rec["rect"], depth_order(rec), tx, tx * ty)
    want = composite_frame(ranges, prims, rec, w, h, background=(0.2, 0.3, 0.4))
    frame = Binning(gpu, model.n)
    frame.set_views(1, tx * ty)
    frame.set_capacity(len(prims))
    frame.set_view(0, tiles_x=tx, size=(w, h), origin=(0, 0), background=(0.2, 0.3, 0.4))
    frame.params.write()
    stage = Compositing(gpu)
    stage.set_views(1, w, h)
    enc = gpu.device.create_command_encoder()
    stage.encode(
        enc,
        frame.params.binding(0),
        gpu.upload(ranges.astype(np.uint32)),
        gpu.upload(prims.astype(np.uint32)),
        gpu.upload(rec["mean2d"]),
        gpu.upload(np.column_stack([rec["conic"], rec["opacity"]]).astype(np.float32)),
        gpu.upload(np.column_stack([rec["rgb"], rec["depth"]]).astype(np.float32)),
        (tx, ty),
    )
    gpu.submit(enc)
    got = gpu.read(stage.image, np.float32).reshape(h, w, 4)
    assert (~np.isfinite(want)).any() and (want[..., 3] < 0.5).any()
    assert_close(got, want)


def test_variants_match_twin(gpu):
    """composite.wgsl:variants re-composites tiles of single-upset variants from the clean frame's
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
    k, n, B, cap = r.k, r.n, comp.B, r.capacity
    kv = {
        "xy": gpu.read(r.kv_xy, np.float32).reshape(k, n, 2),
        "conic": gpu.read(r.kv_conic, np.float32).reshape(k, n, 4),
        "rgb": gpu.read(r.kv_rgb, np.float32).reshape(k, n, 4),
        "ranges": gpu.read(r.kv_ranges).reshape(k, r.n_tiles, 2),
        "isect": gpu.read(r.kv_isect).reshape(k, cap),
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
        xy[p], conic[p], rgb[p, :3] = var["xy"][vi], np.append(var["conic"][vi], var["opacity"][vi]), var["rgb"][vi]
        (ys, xs), pxs, pys = tile_pixels(tx, ty, r.width, r.height)
        want, T = composite_tile(ids, pxs, pys, xy[:, 0], xy[:, 1], conic[:, :3], conic[:, 3], rgb[:, :3], bg)
        got = slabs[e, : ys.stop - ys.start, : xs.stop - xs.start].reshape(-1, 4)
        assert_close(got[:, :3], want)
        assert_close(got[:, 3], T)
