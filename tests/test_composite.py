"""Compositing stage (render/composite.py): both entry points on the GPU against the numpy twin,
on the same screen records and tile lists.

Which pixels are non-finite is exact; finite values agree to 1e-5 of max(1, |value|): the GPU's
exp may differ from numpy's float32 by an ulp (measured: <= 2.4e-7)."""

import numpy as np
import pytest
from conftest import random_model

from seuwgpu.gpu.constants import CHUNK
from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.model.fields import Model
from seuwgpu.render.bin import Binning, tile_lists
from seuwgpu.render.composite import Compositing, composite_frame
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


def gpu_frame(gpu, ranges, prims, rec: dict, w: int, h: int, background, chunk=CHUNK, shape="lanes") -> np.ndarray:
    """The full-frame compositor of `shape` (composite.wgsl or composite_wide.wgsl main, chunks,
    then merge) on the given tile lists and screen records: [h, w, 4] (rgb, T)."""
    tx, ty = -(-w // 16), -(-h // 16)
    frame = Binning(gpu, len(rec["opacity"]))
    frame.set_views(1, tx * ty)
    frame.set_capacity(len(prims))
    frame.set_view(0, tiles_x=tx, size=(w, h), origin=(0, 0), background=background)
    frame.params.write()
    stage = Compositing(gpu, chunk=chunk, shape=shape)
    stage.set_views(1, w, h)
    stage.set_capacity(len(prims))
    depth = rec.get("depth", np.zeros(len(rec["opacity"])))
    enc = gpu.device.create_command_encoder()
    buffers = {
        "ranges": np.asarray(ranges).astype(np.uint32),
        "isect_prims": np.asarray(prims).astype(np.uint32),
        "proj_xy": rec["proj_xy"],
        "proj_conic": np.column_stack([rec["conic"], rec["opacity"]]).astype(np.float32),
        "proj_rgb": np.column_stack([rec["rgb"], depth]).astype(np.float32),
    }
    buffers = {name: gpu.upload(a) for name, a in buffers.items()} | {"isect_box": gpu.buffer(4 * len(prims))}
    # a kept frame: the kernel that also writes boxes and stops
    stage.encode(enc, frame.params.binding(0), buffers, (tx, ty), stops=gpu.buffer(4 * w * h))
    gpu.submit(enc)
    return gpu.read(stage.image, np.float32).reshape(h, w, 4)


SHAPES = pytest.mark.parametrize("shape", ["lanes", "wide"])


@SHAPES
def test_frame_matches_twin(gpu, shape):
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
    got = gpu_frame(gpu, ranges, prims, rec, w, h, (0.2, 0.3, 0.4), shape=shape)
    assert (~np.isfinite(want)).any() and (want[..., 3] < 0.5).any()
    assert_close(got, want)


def _edge_records(n: int, rng) -> dict:
    """Screen records around the compositor's shortcuts (the opacity cut, the per-tile pixel box):
    opacities at and near 1/255 and 0.001, above 1, huge, negative, zero, subnormal; conics from
    round to nearly singular (B^2 = A C (1 - 10^-k)), tiny, huge, zero, negative; means near and
    far. All finite: NaN would reach every pixel and hide the rest (test_frame_matches_twin
    covers non-finite records)."""
    ang = rng.uniform(0, np.pi, n)
    s1, s2 = np.exp(rng.uniform(np.log(0.2), np.log(40), (2, n)))
    c, s = np.cos(ang), np.sin(ang)
    a = c * c * s1 * s1 + s * s * s2 * s2 + 0.3
    b = c * s * (s1 * s1 - s2 * s2)
    cc = s * s * s1 * s1 + c * c * s2 * s2 + 0.3
    det = a * cc - b * b
    conic = np.column_stack([cc / det, -b / det, a / det])
    k = rng.integers(0, 8, n)
    near = rng.random(n) < 0.25  # nearly singular: B^2 = A C (1 - 10^-k)
    conic[near, 1] = np.sign(conic[near, 1] + 1e-30) * np.sqrt(conic[near, 0] * conic[near, 2] * (1 - 10.0 ** -k[near]))
    odd = rng.integers(0, 8, n)
    conic[odd == 1] *= 1e7
    conic[odd == 2] *= 1e-14
    conic[odd == 3] = 0.0
    conic[odd == 4, 0] *= -1
    op = rng.uniform(0, 0.05, n)
    which = rng.integers(0, 10, n)
    op[which == 1] = (1 / 255) * (1 + rng.uniform(-2e-3, 2e-3, (which == 1).sum()))
    op[which == 2] = 0.001 * (1 + rng.uniform(-1e-3, 1e-3, (which == 2).sum()))
    op[which == 3] = rng.choice([1.5, 1e31, -0.5, 0.0, 1e-40], (which == 3).sum())
    mean2d = rng.uniform(-12, 52, (n, 2))
    mean2d[rng.random(n) < 0.03] = [[1e5, 20.0]]
    mean2d[rng.random(n) < 0.03] = [[20.0, -3e7]]
    return {
        "proj_xy": mean2d.astype(np.float32),
        "conic": conic.astype(np.float32),
        "opacity": op.astype(np.float32),
        "rgb": rng.uniform(0, 1, (n, 3)).astype(np.float32),
    }


def test_shortcuts_match_twin(gpu):
    """Records crafted around the skips the GPU takes without evaluating exp (the opacity cut and
    the per-tile pixel box, composite.wgsl): every tile draws all of them, and any contribution
    wrongly skipped (at least 1/255 of T) would show far beyond the tolerance."""
    rng = np.random.default_rng(7)
    n, w, h = 700, 40, 36
    rec = _edge_records(n, rng)
    tx, ty = -(-w // 16), -(-h // 16)
    # records that saturate pixels go last, so the others are all evaluated
    loud = ~(np.abs(rec["opacity"]) <= 1)
    order = np.concatenate([rng.permutation(np.flatnonzero(~loud)), np.flatnonzero(loud)])
    prims = np.tile(order, tx * ty)
    ranges = np.stack([np.arange(tx * ty) * n, np.arange(1, tx * ty + 1) * n], axis=1)
    with np.errstate(all="ignore"):
        want = composite_frame(ranges, prims, rec, w, h)
    got = gpu_frame(gpu, ranges, prims, rec, w, h, (1.0, 1.0, 1.0))
    quiet = composite_frame(np.array([[0, (~loud).sum()]] * (tx * ty)), order, rec, w, h)
    assert (quiet[..., 3] > 0.01).mean() > 0.9  # no pixel stops early: each sees the whole list
    assert np.isfinite(want).all()
    assert_close(got, want)


def test_exp_flushes_results_below_the_smallest_normal(gpu):
    """An opacity whose exponent bit 30 flipped (0.5 -> 2^127, a pipeline-state fault in conic.w)
    meets exp's subnormal range: o * exp(-90) = 0.14 if exp(-90) stays subnormal (8e-40), 0 where
    the device flushes it (lavapipe does). docs/renderer.md rule 4: exp(x) is 0 below -87.33, on
    every device and in the twin. A record at a pixel corner with conic (1, 0, 1) has sigma =
    (x^2 + y^2) / 2 at pixel (x, y): 0.99 alpha up to x^2 + y^2 = 174 (sigma 87), nothing beyond."""
    rec = {
        "proj_xy": np.array([[0.5, 0.5]], np.float32),
        "conic": np.array([[1.0, 0.0, 1.0]], np.float32),
        "opacity": np.array([np.float32(0.5).view(np.uint32) ^ np.uint32(1 << 30)]).view(np.float32),
        "rgb": np.zeros((1, 3), np.float32),
    }
    ranges, prims = np.array([[0, 1]]), np.arange(1)
    y, x = np.mgrid[:16, :16]
    want_T = np.where(x * x + y * y <= 174, np.float32(1) - np.float32(0.99), np.float32(1))
    twin = composite_frame(ranges, prims, rec, 16, 16, background=(1.0, 1.0, 1.0))
    np.testing.assert_array_equal(twin[..., 3], want_T)
    for shape in ("lanes", "wide"):
        got = gpu_frame(gpu, ranges, prims, rec, 16, 16, (1.0, 1.0, 1.0), shape=shape)
        np.testing.assert_array_equal(got, twin)


# ---- long tile lists: chunks merged front to back -------------------------------------------------
def _flat_records(opacity, rgb, w=16, h=16) -> dict:
    """Records with conic 0 (sigma = 0 at every pixel: alpha = min(0.99, o) everywhere)."""
    n = len(opacity)
    return {
        "proj_xy": np.full((n, 2), [w / 2, h / 2], np.float32),
        "conic": np.zeros((n, 3), np.float32),
        "opacity": np.asarray(opacity, np.float32),
        "rgb": np.asarray(rgb, np.float32),
    }


def test_chunk_merge_by_hand(gpu):
    """Three chunks of 256: chunk 0 holds a red alpha = 3/4, chunk 1 seven greens alpha = 3/4 and
    chunk 2 a blue (the rest alpha = 0, skipped). All values are short binary fractions, so the
    results are exact on any device. Chunk 0: c = (3/4, 0, 0), t = 1/4. Chunk 1 from T = 1: six
    greens add 3/4 (1 + 1/4 + ... + 1/4^5) = 1 - 4^-6 and the seventh stops it (T would be 4^-7 <=
    1e-4): c = (0, 1 - 4^-6, 0), t = 4^-6, stopped. Merged: C = (3/4, (1 - 4^-6) / 4, 0),
    T = 4^-7, and the pixel ends (chunk 1 stopped), so the blue is ignored. One chunk (the per-pixel
    rule): the fifth green stops it, at green = 3/16 (1 + ... + 1/4^4), T = 4^-6."""
    op = np.zeros(513)
    rgb = np.zeros((513, 3))
    op[0], rgb[0] = 0.75, [1, 0, 0]
    op[256:263], rgb[256:263] = 0.75, [0, 1, 0]
    op[512], rgb[512] = 0.75, [0, 0, 1]
    rec = _flat_records(op, rgb)
    ranges, prims, bg = np.array([[0, 513]]), np.arange(513), (0.5, 0.5, 0.5)
    chunked = [0.75, (1 - 4.0**-6) / 4, 0.0, 4.0**-7]
    whole = [0.75, 3 / 16 * (1 + 1 / 4 + 1 / 16 + 1 / 64 + 1 / 256), 0.0, 4.0**-6]
    for chunk, (r, g, b, T) in ((256, chunked), (4096, whole)):
        want = np.array([r + 0.5 * T, g + 0.5 * T, b + 0.5 * T, T], np.float32)
        got = gpu_frame(gpu, ranges, prims, rec, 16, 16, bg, chunk=chunk)
        twin = composite_frame(ranges, prims, rec, 16, 16, background=bg, chunk=chunk)
        assert (got == want).all() and (twin == want).all(), (chunk, got[0, 0], twin[0, 0], want)


def _dense_records(n: int, rng, w: int, h: int) -> dict:
    """Many small splats over a w x h frame, mostly faint (pixels go through several chunks before
    they saturate), some opaque, a few non-finite colours."""
    s = np.exp(rng.uniform(np.log(1.0), np.log(6.0), (2, n)))
    ang = rng.uniform(0, np.pi, n)
    c, si = np.cos(ang), np.sin(ang)
    a = c * c * s[0] ** 2 + si * si * s[1] ** 2 + 0.3
    b = c * si * (s[0] ** 2 - s[1] ** 2)
    cc = si * si * s[0] ** 2 + c * c * s[1] ** 2 + 0.3
    det = a * cc - b * b
    op = rng.uniform(0.0, 0.3, n)
    op[rng.random(n) < 0.03] = 0.99
    rgb = rng.uniform(0, 1, (n, 3))
    rgb[rng.choice(n, 3, replace=False), 1] = [np.inf, np.nan, 0.5]
    return {
        "proj_xy": rng.uniform(-4, [w + 4, h + 4], (n, 2)).astype(np.float32),
        "conic": np.column_stack([cc / det, -b / det, a / det]).astype(np.float32),
        "opacity": op.astype(np.float32),
        "rgb": rgb.astype(np.float32),
    }


@SHAPES
def test_chunked_frame_matches_twin(gpu, shape):
    """Tiles of ~1,200 pairs in chunks of 256 (five per tile): GPU against the twin under the same
    chunk rule; the rule itself is visible (the twin without chunks differs beyond the tolerance)."""
    rng = np.random.default_rng(21)
    n, w, h = 1200, 40, 36
    rec = _dense_records(n, rng, w, h)
    tx, ty = -(-w // 16), -(-h // 16)
    order = rng.permutation(n)
    prims = np.tile(order, tx * ty)
    ranges = np.stack([np.arange(tx * ty) * n, np.arange(1, tx * ty + 1) * n], axis=1)
    bg = (0.2, 0.3, 0.4)
    with np.errstate(all="ignore"):
        want = composite_frame(ranges, prims, rec, w, h, background=bg, chunk=256)
        whole = composite_frame(ranges, prims, rec, w, h, background=bg)
    got = gpu_frame(gpu, ranges, prims, rec, w, h, bg, chunk=256, shape=shape)
    assert (~np.isfinite(want)).any() and (want[..., 3] < 1e-4).any() and (want[..., 3] > 0.01).any()
    fin = np.isfinite(want) & np.isfinite(whole)
    assert np.abs(want[fin] - whole[fin]).max() > 100 * TOL
    assert_close(got, want)


@SHAPES
def test_chunks_past_the_capacity(gpu, shape):
    """Ranges that list more pairs than the capacity (as a flipped tile range can): every tile lists
    the same 1,200 pairs, in chunks of 256, with slabs for one frame of 1,200 pairs. The tiles that
    find no room composite their chunks in sequence: the same rule, so the twin's image."""
    rng = np.random.default_rng(22)
    n, w, h = 1200, 48, 48
    rec = _dense_records(n, rng, w, h)
    tiles = (w // 16) * (h // 16)
    prims = rng.permutation(n)
    ranges = np.tile([0, n], (tiles, 1))
    with np.errstate(all="ignore"):
        want = composite_frame(ranges, prims, rec, w, h, chunk=256)
    got = gpu_frame(gpu, ranges, prims, rec, w, h, (1.0, 1.0, 1.0), chunk=256, shape=shape)
    assert_close(got, want)


def _dense_model(n: int, seed: int) -> Model:
    """A 32 x 32 frame's worth of primitives: every tile lists ~900 of them (several chunks of 256)."""
    model = random_model(n, seed=seed)
    flat = model.flat()
    flat[:, 10] -= 2.0  # fainter: pixels go through several chunks
    return Model.from_flat(flat, model.sh_degree)


def test_chunked_renders_are_exact(gpu):
    """With chunks of 256: re-renders and a sort-first viewport are bit-exact; the default chunk
    (every tile one chunk here) gives the image of chunking switched off, bit for bit."""
    model = _dense_model(1500, 3)
    cams = orbit_cameras(2, 32, 32)
    r = Renderer(model, cams, gpu=gpu, chunk=256)
    a = r.render_rgba()
    counts = np.diff(gpu.read(r.binning.ranges).reshape(-1, 2), axis=1)
    assert counts.min() > 512  # every tile of the last view has at least three chunks
    b = Renderer(model, cams, gpu=gpu, chunk=256).render_rgba()
    assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
    assert np.array_equal(a.view(np.uint32), r.render_rgba().view(np.uint32))
    band = Renderer(model, cams, gpu=gpu, chunk=256, viewport=(16, 0, 16, 32)).render_rgba()  # sort-first
    assert np.array_equal(band.view(np.uint32), a[:, :, 16:32].view(np.uint32))
    default = Renderer(model, cams, gpu=gpu).render_rgba()
    off = Renderer(model, cams, gpu=gpu, chunk=1 << 30).render_rgba()
    assert np.array_equal(default.view(np.uint32), off.view(np.uint32))
    assert not np.array_equal(a, default)  # the chunk reaches the shader


def _no_room(r: Renderer) -> int:
    """Long tiles of the renderer's last view that found no slab room (their chunks ran in sequence)."""
    counts = np.diff(r.gpu.read(r.binning.ranges).reshape(-1, 2), axis=1)[:, 0]
    merges = int(r.gpu.read(r.compositing.work)[2])  # Work.merges: long tiles that got slabs
    return int((counts > r.compositing.chunk).sum()) - merges


def _cap_slabs(r: Renderer, slots: int) -> Renderer:
    """The renderer with its compositor's slabs cut to `slots` tiles (as the one-binding cap does
    for huge frames), once a first frame has settled its capacity."""
    r.render_rgba()
    r.compositing.slabs = r.gpu.buffer(slots * 16 * 16 * 16)
    return r


def test_slabs_capped_at_one_binding_give_the_same_image(gpu, monkeypatch):
    """Slabs are capped at one storage binding (100M primitives at a small chunk would want more):
    the cap is computed from the device's binding limit, and tiles that find no room composite
    their chunks in sequence. With room for 8 slabs (tiles of 3 chunks each: two long tiles of a
    view get slabs) the frames of both compositor shapes equal the uncapped ones bit for bit."""
    model = _dense_model(1500, 3)
    cams = orbit_cameras(2, 32, 32)
    want = Renderer(model, cams, gpu=gpu, chunk=256).render_rgba()
    monkeypatch.setitem(gpu.limits, "max-storage-buffer-binding-size", 1 << 16)
    r = Renderer(model, cams, gpu=gpu, chunk=256)
    assert r.compositing.slabs.size <= 1 << 16 < 2 * (r.capacity // 256) * 16 * 16 * 16
    monkeypatch.undo()
    for shape in ("lanes", "wide"):
        r = _cap_slabs(Renderer(model, cams, gpu=gpu, chunk=256, compositor=shape), 8)
        got = r.render_rgba()
        assert _no_room(r) >= 1  # the sequential path ran
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), shape


def _kept_frame(gpu, model, cams, **kw) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A kept frame's (image, pair boxes, stop positions) as u32 bits: what the variants entry reads."""
    r = Renderer(model, cams, gpu=gpu, keep_views=True, **kw)
    r.capture_views = True
    img = r.render_rgba().view(np.uint32)
    return img, gpu.read(r.kv_isect_box)[: r.k * r.capacity], gpu.read(r.kv_stop_pos)


def _extreme_model(n: int, seed: int) -> Model:
    """_dense_model with the values upsets make: non-finite colour and opacity, a sheet, a needle."""
    model = _dense_model(n, seed)
    flat = model.flat()
    flat[11, 11:14] = [np.inf, np.nan, -np.inf]
    flat[12, 3:6] = 60.0  # frame-covering sheet
    flat[13, 10] = np.nan
    flat[14, 3] = 30.0  # a needle
    flat[15, 6:10] = 0.0  # zero quaternion: unbounded
    return Model.from_flat(flat, model.sh_degree)


@pytest.mark.parametrize(
    "profile, exact, chunk",
    [("strict", True, 256), ("gsplat", True, 256), ("strict", False, 256), ("strict", True, CHUNK)],
)
def test_wide_compositor_equals_lanes_bit_for_bit(gpu, profile, exact, chunk):
    """composite_wide.wgsl (one pixel per invocation) gives composite.wgsl's frames, pair boxes and
    stop positions bit for bit: long tiles in chunks of 256 (merged by composite.wgsl's merge) or
    one chunk a tile, both profiles, exact binning or whole rectangles, NaN and Inf pixels."""
    model = _extreme_model(1500, 5)
    cams = orbit_cameras(2, 40, 36)
    kw = {"chunk": chunk, "profile": profile, "exact_binning": exact}
    lanes = _kept_frame(gpu, model, cams, compositor="lanes", **kw)
    wide = _kept_frame(gpu, model, cams, compositor="wide", **kw)
    img = lanes[0].view(np.float32)
    assert np.isnan(img).any() and (img[..., 3] <= 1e-4).sum() < img[..., 3].size  # NaN, and pixels left open
    assert (lanes[2] != 0xFFFFFFFF).any() and (lanes[1] == 0xF00 | 0xF << 24).any()  # stops, and FULL_BOXes
    for a, b in zip(lanes, wide):
        assert np.array_equal(a, b)


def test_wide_compositor_viewports_and_capped_slabs(gpu):
    """The wide compositor in a sort-first viewport equals its full frame's pixels; with room for
    8 slabs (some long tiles find none and run their chunks in sequence) kept frames
    of both shapes have the same pixels and stop positions bit for bit. (Their pair boxes may
    differ there: which tiles get room follows the order workgroups reach the slab counter, and a
    tile without room ends pixels earlier, leaving FULL_BOX for more pairs; blend.wgsl.) An
    unknown shape is refused by name."""
    model = _dense_model(1500, 3)
    cams = orbit_cameras(2, 32, 32)
    full = Renderer(model, cams, gpu=gpu, chunk=256, compositor="wide").render_rgba()
    band = Renderer(model, cams, gpu=gpu, chunk=256, compositor="wide", viewport=(16, 0, 16, 32)).render_rgba()
    assert np.array_equal(band.view(np.uint32), full[:, :, 16:32].view(np.uint32))
    capped = {}
    for s in ("lanes", "wide"):
        r = _cap_slabs(Renderer(model, cams, gpu=gpu, chunk=256, compositor=s, keep_views=True), 8)
        r.capture_views = True
        capped[s] = (r.render_rgba().view(np.uint32), gpu.read(r.kv_stop_pos))
        assert _no_room(r) >= 1
    assert np.array_equal(capped["wide"][0], full.view(np.uint32))
    for a, b in zip(capped["lanes"], capped["wide"]):
        assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="unknown compositor shape 'wdie'"):
        Compositing(gpu, shape="wdie")


def test_unfused_build_changes_no_bit(gpu, monkeypatch):
    """GPU adapters build the compositors with every product that feeds a sum passed through an
    XOR with a zero the driver cannot see (blend.wgsl UNFUSED), so that no driver fuses it into a
    multiply-add, differently in the two shapes (an H100 did). The XOR must change no bit: on a CPU
    adapter, which fuses nothing, both builds give the same kept frames, stop positions and pair
    boxes, for both shapes (NaN and Inf pixels, long tiles merged from chunks), and the variants
    entry in the unfused build still re-composites exactly what a full re-render gives. (On a GPU
    the fused build may differ: that is why it is not used there; the shape tests above check the
    unfused one.)"""
    from test_variants import incremental_equals_full

    import seuwgpu.render.composite as composite
    import seuwgpu.render.variants as variants

    here = composite.unfused_products(gpu)
    assert here == (not gpu.is_cpu)
    if here:
        pytest.skip("compares the two builds where the driver fuses nothing (a CPU adapter)")
    model = _extreme_model(1500, 5)
    cams = orbit_cameras(2, 40, 36)
    want = {s: _kept_frame(gpu, model, cams, compositor=s, chunk=256) for s in ("lanes", "wide")}
    monkeypatch.setattr(composite, "unfused_products", lambda g: not here)
    monkeypatch.setattr(variants, "unfused_products", lambda g: not here)  # the variants entry's build
    for s in ("lanes", "wide"):
        r = Renderer(model, cams, gpu=gpu, compositor=s, chunk=256)
        assert r.compositing.kernel.constants["UNFUSED"] == int(not here)  # the other build
        got = _kept_frame(gpu, model, cams, compositor=s, chunk=256)
        for a, b in zip(got, want[s]):
            assert np.array_equal(a, b), s
    kw = {"gpu": gpu, "chunk": 256, "compositor": "wide"}
    prims = np.array([5, 77, 300, 301, 900, 1200, 1499])
    longest = incremental_equals_full(gpu, _dense_model(1500, 4), orbit_cameras(2, 32, 32), kw, prims)
    assert longest > 256


def test_default_chunk_follows_the_adapter(gpu, monkeypatch):
    """Full frames composite in CHUNK pieces on a CPU adapter and GPU_CHUNK on a GPU; a campaign's
    engine keeps CHUNK everywhere (gpu/constants.py says why). Pretending the adapter is a GPU
    switches the constant; the frames are then the ones of Renderer(chunk=GPU_CHUNK)."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.gpu.constants import GPU_CHUNK
    from seuwgpu.render.composite import default_chunk

    model = _dense_model(1500, 3)
    cams = orbit_cameras(1, 32, 32)
    here = CHUNK if gpu.is_cpu else GPU_CHUNK  # the suite also runs on GPUs (tools/gpu_check.sh)
    assert default_chunk(gpu) == here
    assert Renderer(model, cams, gpu=gpu).compositing.chunk == here
    want = Renderer(model, cams, gpu=gpu, chunk=GPU_CHUNK).render_rgba()
    monkeypatch.setattr(type(gpu), "is_cpu", property(lambda self: False))
    assert default_chunk(gpu) == GPU_CHUNK != CHUNK
    r = Renderer(model, cams, gpu=gpu)
    assert r.compositing.chunk == GPU_CHUNK
    assert np.array_equal(r.render_rgba().view(np.uint32), want.view(np.uint32))
    assert Engine(model, cams, gpu=gpu).renderer.compositing.chunk == CHUNK


def test_chunk_and_slab_limits(gpu):
    """A chunk that is not a positive multiple of the batch is refused with a one-line error
    naming the chunk; slabs that would pass one storage binding are capped at it (the tiles past
    the cap composite in sequence: test_slabs_capped_at_one_binding_give_the_same_image)."""
    for bad in (0, 100, -256):
        with pytest.raises(ValueError, match=f"chunk={bad}"):
            Compositing(gpu, chunk=bad)
    stage = Compositing(gpu, chunk=256)
    stage.set_capacity(gpu.max_binding // 4)  # would want 2 * capacity / 256 slabs of 4 KiB: 4x a binding
    assert stage.slabs.size == gpu.max_binding // (16 * 16 * 16) * (16 * 16 * 16)
    stage.set_capacity(1 << 16)  # what a small scene needs: 2 * 256 + 2 slabs
    assert stage.slabs.size == (2 * (1 << 16) // 256 + 2) * 16 * 16 * 16


def test_a_tile_longer_than_the_cpu_loop_limit(gpu):
    """One tile listing 60,000 faint records around its centre (each box meets all four quadrants)
    that leave most pixels far from saturated, so every workgroup walks its whole chunk: chunks
    keep each walk under llvmpipe's 65,535 loop iterations (one workgroup over the whole list
    there leaves pixels unwritten), and the frame matches the twin."""
    rng = np.random.default_rng(9)
    n = 60_000
    rec = {
        "proj_xy": rng.uniform(7, 9, (n, 2)).astype(np.float32),
        "conic": np.tile(np.array([[0.5, 0.0, 0.5]], np.float32), (n, 1)),
        "opacity": np.full(n, 0.0045, np.float32),  # alpha >= 1/255 within ~0.7 px of the mean
        "rgb": rng.uniform(0, 1, (n, 3)).astype(np.float32),
    }
    ranges, prims = np.array([[0, n]]), np.arange(n)
    got = gpu_frame(gpu, ranges, prims, rec, 16, 16, (1, 1, 1))
    want = composite_frame(ranges, prims, rec, 16, 16, background=(1, 1, 1))
    assert (want[..., 3] > 0.5).sum() > 200  # most pixels untouched: every record is walked
    assert not (got == 0).all(-1).any()
    assert_close(got, want)
