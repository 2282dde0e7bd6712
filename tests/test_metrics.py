"""GPU image metrics (shaders/metrics.wgsl) against the numpy twin and skimage."""

import numpy as np
import pytest

from seuwgpu.metrics import image as M

W, H, K = 40, 24, 3  # not multiples of 16: partial edge tiles in x and y
THR = float(M.THRESHOLD)


@pytest.fixture(scope="module")
def gpu():
    from seuwgpu.gpu import get_gpu

    return get_gpu()


def _clean(rng, k=K, h=H, w=W):
    img = rng.uniform(-0.1, 1.15, (k, h, w, 4)).astype(np.float32)  # beyond [0,1]: display clip
    img[..., 3] = rng.random((k, h, w))  # transmittance: ignored
    # a smooth band and a flat region, so SSIM sees structure, not only noise
    yy, xx = np.mgrid[0:h, 0:w]
    img[:, : h // 2, : w // 2, :3] = (0.5 + 0.4 * np.sin(xx[: h // 2, : w // 2] / 5.0))[None, ..., None]
    img[:, h // 2 :, w // 2 :, :3] = 1.0
    return img


def _planted(rng, clean, B=6):
    """Variants with planted changes: faulted [B, K, H, W, 4]. Sets clean[:, 5, 30] to 0.5."""
    k_, h, w = clean.shape[:3]
    clean[:, 5, 30, :3] = 0.5
    f = np.repeat(clean[None], B, axis=0).copy()
    # b0: single pixels just above / below 1/255 (clean 0.5, so f - c is exact), both signs
    up = np.float32(0.5) + np.float32(THR * (1 + 1e-3))
    dn = np.float32(0.5) + np.float32(THR * (1 - 1e-3))
    f[0, 0, 5, 30, 1] = up  # changed
    f[0, 1, 5, 30, 2] = dn  # not changed, but differs (sse, ssim)
    f[0, 2, 5, 30, 0] = np.float32(0.5) - np.float32(THR * (1 + 1e-3))  # changed (negative)
    # b1: NaN, +Inf, -Inf in different views / channels, one pixel twice
    f[1, 0, 3, 3, 0] = np.nan
    f[1, 1, 20, 39, 2] = np.inf
    f[1, 2, 0, 0, 1] = -np.inf
    f[1, 2, 10, 17, 0] = np.inf
    f[1, 2, 10, 17, 1] = np.nan
    f[1, 0, 4, 3, 3] = np.nan  # 4th channel: ignored
    # b2: huge finite values
    f[2, 0, 12, 12, 0] = 3.0e38
    f[2, 1, 7, 25, 1] = -1.0e30
    f[2, 2, 23, 1, 2] = 1.0e20
    # b3: whole-frame change in view 1, a block in view 2
    f[3, 1, ..., :3] = rng.random((h, w, 3))
    f[3, 2, 8:19, 10:33, :3] += rng.normal(0, 0.05, (11, 23, 3)).astype(np.float32)
    # b4: identical; b5: tiny perturbation everywhere in view 0 (below threshold, SSIM ~ 1)
    f[5, 0, ..., :3] += rng.uniform(-1e-3, 1e-3, (h, w, 3)).astype(np.float32)
    return f


def _check_close(gpu_r, cpu_r, w=W, h=H):
    n_int = M.n_interior(w, h)
    np.testing.assert_array_equal(gpu_r["changed"], cpu_r["changed"])
    np.testing.assert_array_equal(gpu_r["nonfinite"], cpu_r["nonfinite"])
    np.testing.assert_array_equal(gpu_r["peak"], cpu_r["peak"])  # max of f32: exact
    np.testing.assert_allclose(gpu_r["sse"], cpu_r["sse"], rtol=2e-5, atol=1e-9)
    np.testing.assert_array_equal(gpu_r["ssim_count"], cpu_r["ssim_count"])
    s_gpu = (gpu_r["ssim_sum"] + n_int - gpu_r["ssim_count"]) / n_int
    s_cpu = (cpu_r["ssim_sum"] + n_int - cpu_r["ssim_count"]) / n_int
    np.testing.assert_allclose(s_gpu, s_cpu, rtol=0, atol=1e-5)
    np.testing.assert_allclose(1 - gpu_r["ssim_deficit"] / n_int, s_cpu, rtol=0, atol=1e-5)


def _sparse_inputs(clean, faulted, extra_identical=0, rng=None, boxes=False):
    """Slabs for every tile that differs (bitwise) from clean, plus `extra_identical` unchanged
    tiles mapped to slabs anyway; work list = mapped tiles dilated by one tile, or (boxes) the
    tiles with changed pixels and the neighbours their boxes come within PAD px of
    (changed_tiles_mask, as campaigns build it)."""
    B, k_, h, w = faulted.shape[:4]
    TX, TY = M.tiles_of(w, h)
    NT = TX * TY
    # pixels of partial edge tiles beyond W/H do not exist: fill them with garbage (NaN)
    pad = np.full((B, k_, TY * 16, TX * 16, 4), np.nan, np.float32)
    pad[:, :, :h, :w] = faulted
    cpad = np.full((k_, TY * 16, TX * 16, 4), np.nan, np.float32)
    cpad[:, :h, :w] = clean
    tiles = pad.reshape(B, k_, TY, 16, TX, 16, 4).transpose(0, 1, 2, 4, 3, 5, 6).reshape(B, k_, NT, 256, 4)
    ctiles = cpad.reshape(k_, TY, 16, TX, 16, 4).transpose(0, 1, 3, 2, 4, 5).reshape(k_, NT, 256, 4)
    diff = (tiles.view(np.uint32) != ctiles[None].view(np.uint32)).any(axis=(-1, -2))
    if extra_identical:
        idle = np.argwhere(~diff)
        for i in rng.choice(len(idle), size=min(extra_identical, len(idle)), replace=False):
            diff[tuple(idle[i])] = True
    tile_map = np.full((B, k_, NT), -1, np.int32)
    idx = np.argwhere(diff)
    order = rng.permutation(len(idx)) if rng is not None else np.arange(len(idx))  # slab order is free
    slabs = np.zeros((max(1, len(idx)), 256, 4), np.float32)
    for s, j in enumerate(order):
        b, k, t = idx[j]
        tile_map[b, k, t] = s
        slabs[s] = tiles[b, k, t]
    if boxes:
        px = (
            (tiles[..., :3].view(np.uint32) != ctiles[None, ..., :3].view(np.uint32)).any(-1).reshape(B, k_, NT, 16, 16)
        )
        bidx, kidx, tidx = np.nonzero(px.any(axis=(-1, -2)))
        box = np.array(
            [
                [xs.min(), xs.max(), ys.min(), ys.max()]
                for ys, xs in (np.nonzero(px[b, k, t]) for b, k, t in zip(bidx, kidx, tidx))
            ]
        ).reshape(-1, 4)
        mask = M.changed_tiles_mask((B, k_, NT), bidx, kidx, tidx, box, w, h)
        assert mask.sum() < M.tile_map_to_mask(tile_map, w, h, dilate=1).sum()  # fewer tiles than dilating
    else:
        mask = M.tile_map_to_mask(tile_map, w, h, dilate=1)
    worklist, offsets = M.build_worklist(mask)
    return slabs, tile_map, worklist, offsets


# --------------------------------------------------------------------------------------------------


def test_dense_matches_numpy_twin(gpu):
    rng = np.random.default_rng(0)
    clean = _clean(rng)
    f = _planted(rng, clean)
    B = f.shape[0]
    im = M.ImageMetrics(gpu, W, H, K, B)
    r = im.run_dense(gpu.upload(clean), gpu.upload(f), B)
    n = M.numpy_metrics(clean, f)
    _check_close(r, n)
    # the planted facts themselves
    assert r["changed"][0].tolist() == [1, 0, 1]
    assert r["sse"][0, 1] > 0 and r["ssim_deficit"][0, 1] > 0  # below threshold, not equal
    assert r["nonfinite"][1].tolist() == [1, 1, 2]
    assert r["changed"][1].tolist() == [1, 1, 2]
    assert np.isinf(r["peak"][1]).all()
    assert r["peak"][2, 0] == np.float32(3.0e38) - clean[0, 12, 12, 0]
    assert np.isfinite(r["peak"][2]).all() and r["nonfinite"][2].sum() == 0
    assert r["changed"][3, 1] > 0.9 * W * H
    assert (r["changed"][4] == 0).all() and (r["sse"][4] == 0).all() and (r["peak"][4] == 0).all()
    assert (r["ssim_deficit"][4] == 0).all() and (r["ssim_sum"][4] == r["ssim_count"][4]).all()
    assert r["changed"][5, 0] == 0 and r["sse"][5, 0] > 0
    s = M.summarize(r, W, H)
    assert s["ssim"][4] == 1.0 and s["psnr"][4] == np.inf and s["footprint"][4] == 0
    assert s["nonfinite"].tolist() == [False, True, False, False, False, False]
    assert s["nonfinite_pixels"][1] == 4
    assert np.isnan(s["psnr"][1]) and np.isnan(s["ssim"][1]) and np.isfinite(s["psnr"][[0, 2, 3, 5]]).all()
    assert M.catastrophic(s["footprint"], s["nonfinite"]).tolist() == [False, True, False, True, False, False]


def test_ssim_matches_skimage(gpu):
    from skimage.metrics import structural_similarity

    rng = np.random.default_rng(1)
    k_, h, w, B = 2, 37, 23, 3
    clean = rng.random((k_, h, w, 4)).astype(np.float32)
    f = np.repeat(clean[None], B, 0).copy()
    f[0, ..., :3] += rng.normal(0, 0.02, (k_, h, w, 3)).astype(np.float32)
    f[1, 0, ..., :3] = np.clip(f[1, 0, ..., :3] * 0.7 + 0.2, 0, 1)  # contrast / brightness
    f[1, 1, 10:30, 3:20, :3] = 0.0  # black block
    f[2, :, ::5, ::3, :3] = 1.0 - f[2, :, ::5, ::3, :3]  # sparse salt
    im = M.ImageMetrics(gpu, w, h, k_, B)
    r = im.run_dense(gpu.upload(clean), gpu.upload(f), B)
    s_gpu = 1.0 - r["ssim_deficit"] / M.n_interior(w, h)
    for b in range(B):
        for k in range(k_):
            a = M.display(clean[k, ..., :3]).astype(np.float64)  # display-referred
            d = M.display(f[b, k, ..., :3]).astype(np.float64)
            ref = structural_similarity(a, d, channel_axis=-1, data_range=1.0)
            assert abs(s_gpu[b, k] - ref) < 1e-5, (b, k, s_gpu[b, k], ref)
    assert s_gpu.min() < 0.9


def test_identical_is_exact(gpu):
    rng = np.random.default_rng(2)
    clean = _clean(rng, k=2, h=33, w=48)
    clean[0, 3, 3, 0] = 7.5  # out-of-range values: still identical
    f = np.repeat(clean[None], 2, 0).copy()
    im = M.ImageMetrics(gpu, 48, 33, 2, 2)
    r = im.run_dense(gpu.upload(clean), gpu.upload(f), 2)
    assert (r["changed"] == 0).all() and (r["sse"] == 0).all() and (r["peak"] == 0).all()
    assert (r["nonfinite"] == 0).all() and (r["ssim_deficit"] == 0).all()
    assert (r["ssim_count"] == M.n_interior(48, 33)).all()
    assert (r["ssim_sum"] == r["ssim_count"]).all()
    s = M.summarize(r, 48, 33)
    assert (s["ssim"] == 1.0).all() and np.isinf(s["psnr"]).all()


def _planted_setup(gpu, seed: int):
    """(rng, clean, planted variants, B, ImageMetrics for them, the clean image uploaded)."""
    rng = np.random.default_rng(seed)
    clean = _clean(rng)
    f = _planted(rng, clean)
    return rng, clean, f, f.shape[0], M.ImageMetrics(gpu, W, H, K, f.shape[0]), gpu.upload(clean)


def test_sparse_equals_dense(gpu):
    rng, clean, f, B, im, cb = _planted_setup(gpu, 3)
    rd = im.run_dense(cb, gpu.upload(f), B)
    for extra, boxes in ((0, False), (5, False), (0, True)):
        slabs, tile_map, wl, off = _sparse_inputs(clean, f, extra_identical=extra, rng=rng, boxes=boxes)
        rs = im.run_sparse(cb, gpu.upload(slabs), gpu.upload(tile_map), gpu.upload(wl), gpu.upload(off), B)
        for key in ("changed", "peak", "sse", "nonfinite", "ssim_deficit"):
            np.testing.assert_array_equal(rs[key], rd[key], err_msg=key)
        assert (rs["ssim_count"] <= rd["ssim_count"]).all()
        assert (rs["ssim_count"][4] == 0).all()  # identical variant: no work
        sd, ss = M.summarize(rd, W, H), M.summarize(rs, W, H)
        for key in sd:
            np.testing.assert_array_equal(sd[key], ss[key], err_msg=key)
        # frame SSIM from (sum, count) agrees with the deficit form
        n_int = M.n_interior(W, H)
        np.testing.assert_allclose(
            (rs["ssim_sum"] + n_int - rs["ssim_count"]) / n_int, 1 - rs["ssim_deficit"] / n_int, rtol=0, atol=1e-12
        )


def test_changed_boxes_reach_exactly_the_windows_that_see_them(gpu):
    """One changed pixel per variant at 0..3 and 12..15 px from an edge or corner of an interior
    tile of a 48x48 frame: the tiles changed_tiles_mask keeps (the tile, and the neighbours whose
    SSIM windows of PAD px reach the pixel) give the dense metrics bit for bit, while the rule
    keeps neighbours only for pixels within PAD px of them."""
    rng = np.random.default_rng(11)
    w = h = 48
    clean = _clean(rng, k=1, h=h, w=w)
    spots = [(16 + dx, 16 + dy) for dx in (0, 2, 3, 12, 13, 15) for dy in (0, 3, 13, 15)]
    f = np.repeat(clean[None], len(spots), axis=0)
    for b, (x, y) in enumerate(spots):
        f[b, 0, y, x, :3] += 0.25
    im = M.ImageMetrics(gpu, w, h, 1, len(spots))
    cb = gpu.upload(clean)
    rd = im.run_dense(cb, gpu.upload(f), len(spots))
    slabs, tile_map, wl, off = _sparse_inputs(clean, f, boxes=True)
    rs = im.run_sparse(cb, gpu.upload(slabs), gpu.upload(tile_map), gpu.upload(wl), gpu.upload(off), len(spots))
    for key in ("changed", "peak", "sse", "nonfinite", "ssim_deficit"):
        np.testing.assert_array_equal(rs[key], rd[key], err_msg=key)
    n_tiles = np.diff(off.astype(np.int64))
    for b, (x, y) in enumerate(spots):
        lx, ly = x - 16, y - 16
        near_x = int(lx < M.PAD) + int(lx > 15 - M.PAD)
        near_y = int(ly < M.PAD) + int(ly > 15 - M.PAD)
        assert n_tiles[b] == (1 + near_x) * (1 + near_y), (x, y)


def test_sparse_empty_worklist_and_overflow(gpu):
    rng = np.random.default_rng(4)
    clean = _clean(rng, k=2)
    TX, TY = M.tiles_of(W, H)
    im = M.ImageMetrics(gpu, W, H, 2, 3, max_entries=4)
    cb = gpu.upload(clean)
    tm = np.full((3, 2, TX * TY), -1, np.int32)
    wl, off = M.build_worklist(np.zeros((3, 2, TX * TY), bool))
    r = im.run_sparse(
        cb, gpu.upload(np.zeros((1, 256, 4), np.float32)), gpu.upload(tm), gpu.upload(wl), gpu.upload(off), 3
    )
    assert all((r[k] == 0).all() for k in ("changed", "peak", "sse", "nonfinite", "ssim_count", "ssim_deficit"))
    # work list entries that map to unmapped tiles: evaluated, identical to clean
    mask = np.zeros((3, 2, TX * TY), bool)
    mask[1, 1, :3] = True
    wl, off = M.build_worklist(mask)
    r = im.run_sparse(
        cb, gpu.upload(np.zeros((1, 256, 4), np.float32)), gpu.upload(tm), gpu.upload(wl), gpu.upload(off), 3
    )
    assert r["ssim_count"][1, 1] > 0 and r["ssim_count"].sum() == r["ssim_count"][1, 1]
    assert (r["ssim_deficit"] == 0).all() and (r["changed"] == 0).all()
    mask[2, 0, :3] = True  # 6 entries > max_entries = 4
    wl, off = M.build_worklist(mask)
    enc = gpu.device.create_command_encoder()
    im.encode_sparse(
        enc, cb, gpu.upload(np.zeros((1, 256, 4), np.float32)), gpu.upload(tm), gpu.upload(wl), gpu.upload(off), 3
    )
    gpu.submit(enc)
    with pytest.raises(RuntimeError, match="max_entries"):
        im.read(3)
    with pytest.raises(ValueError):
        im.encode_dense(gpu.device.create_command_encoder(), cb, cb, 3)  # dense needs 36 > 4


def test_many_workgroups_2d_dispatch(gpu):
    """More than 32768 work-list entries: the 2-D dispatch path (dispatch_dims / linear_wg)."""
    rng = np.random.default_rng(5)
    h = w = 8  # 1 tile per view
    B = 33000
    clean = rng.random((1, h, w, 4)).astype(np.float32)
    f = np.repeat(clean[None], B, 0)
    picks = [0, 1, 32767, 32768, B - 1]
    for i, b in enumerate(picks):
        f[b, 0, i % h, (3 * i) % w, i % 3] += 0.25
    im = M.ImageMetrics(gpu, w, h, 1, B)
    r = im.run_dense(gpu.upload(clean), gpu.upload(f), B)
    n = M.numpy_metrics(clean, f[picks])
    for key in ("changed", "peak", "nonfinite", "ssim_count"):
        np.testing.assert_array_equal(r[key][picks], n[key])
    np.testing.assert_allclose(r["sse"][picks], n["sse"], rtol=1e-5)
    rest = np.setdiff1d(np.arange(B), picks)
    assert (r["changed"][rest] == 0).all() and (r["ssim_deficit"][rest] == 0).all()
    assert (r["ssim_count"] == 4).all()
    # sparse, every (b, k) listed: indirect dispatch over 2 rows of workgroups
    tile_map = np.full((B, 1, 1), -1, np.int32)
    tile_map[picks, 0, 0] = np.arange(len(picks))
    slabs = np.full((len(picks), 256, 4), np.nan, np.float32)
    slabs.reshape(len(picks), 16, 16, 4)[:, :h, :w] = f[picks, 0]
    wl, off = M.build_worklist(np.ones((B, 1, 1), bool))
    rs = im.run_sparse(gpu.upload(clean), gpu.upload(slabs), gpu.upload(tile_map), gpu.upload(wl), gpu.upload(off), B)
    for key in M.FIELDS:
        np.testing.assert_array_equal(rs[key], r[key], err_msg=key)


def test_summarize_and_catastrophic():
    raw = {
        "changed": np.array([[0, 10], [400, 0]]),
        "peak": np.array([[0.0, 0.5], [np.inf, 0.0]]),
        "sse": np.array([[0.0, 3.0], [0.0, 0.0]]),
        "nonfinite": np.array([[0, 0], [2, 0]]),
        "ssim_sum": np.array([[5.0, 4.5], [0.0, 0.0]]),
        "ssim_count": np.array([[5, 5], [0, 0]]),
    }
    s = M.summarize(raw, 20, 10)  # 200 px, 14*4 = 56 interior
    np.testing.assert_allclose(s["footprint"], [10 / 200 / 2, 400 / 200 / 2])
    np.testing.assert_allclose(s["footprint_max"], [10 / 200, 2.0])
    np.testing.assert_allclose(s["peak_error"], [0.5, np.inf])
    np.testing.assert_allclose(s["psnr"][0], 10 * np.log10(2 * 200 * 3 / 3.0))
    assert np.isnan(s["psnr"][1]) and np.isnan(s["ssim"][1])  # non-finite frame: undefined, not 0 dB
    np.testing.assert_allclose(s["ssim"][0], 1 - 0.5 / 56 / 2)
    assert s["nonfinite"].tolist() == [False, True] and s["nonfinite_pixels"].tolist() == [0, 2]
    assert M.catastrophic(s["footprint"], s["nonfinite"]).tolist() == [True, True]
    assert M.catastrophic([0.01, 0.0101], [False, False]).tolist() == [False, True]


def test_changed_pixel_masks_match_the_twin(gpu):
    """The per-entry changed-pixel masks (sort-first contamination's input) are changed_pixels of
    the faulted images, dense and sparse, NaN/Inf and below-threshold changes included."""
    rng, clean, f, B, im, cb = _planted_setup(gpu, 7)
    want = M.changed_pixels(f, clean[None])  # [B, K, H, W]
    assert want.any() and not want.all()
    TX, TY = M.tiles_of(W, H)
    im.run_dense(cb, gpu.upload(f), B, masks=B * K * TX * TY)
    got = im.read_changed_pixels(B * K * TX * TY).reshape(B, K, TY, TX, 16, 16)
    got = got.transpose(0, 1, 2, 4, 3, 5).reshape(B, K, TY * 16, TX * 16)
    np.testing.assert_array_equal(got[:, :, :H, :W], want)
    assert not got[:, :, H:].any() and not got[:, :, :, W:].any()  # outside the frame
    slabs, tile_map, wl, off = _sparse_inputs(clean, f, extra_identical=0, rng=rng, boxes=True)
    n_e = int(off[-1])
    im.run_sparse(cb, gpu.upload(slabs), gpu.upload(tile_map), gpu.upload(wl), gpu.upload(off), B, masks=n_e)
    masks = im.read_changed_pixels(n_e)
    bk = np.repeat(np.arange(B * K), np.diff(off.astype(np.int64)))
    full = np.zeros((B * K, TY * 16, TX * 16), bool)
    for e in range(n_e):
        ty, tx = divmod(int(wl[e]), TX)
        full[bk[e], ty * 16 : ty * 16 + 16, tx * 16 : tx * 16 + 16] = masks[e]
    np.testing.assert_array_equal(full.reshape(B, K, TY * 16, TX * 16)[:, :, :H, :W], want)
    im.run_sparse(cb, gpu.upload(slabs), gpu.upload(tile_map), gpu.upload(wl), gpu.upload(off), B)  # no masks asked
    with pytest.raises(ValueError, match="copied 0 masks"):
        im.read_changed_pixels(n_e)
