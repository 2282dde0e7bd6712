"""GPU renderer against the numpy twin, adversarial parameters, and determinism."""

import numpy as np
import pytest
from conftest import psnr_finite, random_model

from seuwgpu.gpu.constants import GPU_CHUNK
from seuwgpu.model import encoding
from seuwgpu.model.cameras import Camera, intrinsics, look_at, orbit_cameras
from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.scenes import list_scenes, make_scene, scene_cameras
from seuwgpu.render import reference
from seuwgpu.render.renderer import Renderer

W, H = 64, 48


def both(model, cams, precision="fp32", **kw):
    gpu_img = Renderer(model, cams, precision, **kw).render()
    ref_img = reference.render(model.quantized(precision), cams)
    return gpu_img, ref_img


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
@pytest.mark.parametrize("scene", list_scenes())
def test_scenes_match_reference(scene, precision):
    model = make_scene(scene, n=3000, seed=1)
    cams = scene_cameras(scene, 2, W, H)
    g, r = both(model, cams, precision)
    assert g.shape == (2, H, W, 3) and g.dtype == np.float32
    assert psnr_finite(g, r) >= 50
    assert (np.abs(g - 1.0) > 0.05).mean() > 0.05, "scene should cover part of the frame"


def test_rerender_is_bit_identical():
    model = random_model(500, seed=3)
    r = Renderer(model, orbit_cameras(3, W, H))
    a = r.render()
    b = r.render()
    assert np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_chunked_model_and_grown_buffers_give_identical_images():
    model = random_model(701, seed=4)
    cams = orbit_cameras(2, W, H)
    base = Renderer(model, cams).render()
    chunked = Renderer(model, cams, chunk_prims=128)
    assert chunked.layout.n_chunks == 6
    small = Renderer(model, cams, capacity=16)
    out = small.render()
    assert small.capacity > 16  # grew and re-ran
    assert np.array_equal(base.view(np.uint32), chunked.render().view(np.uint32))
    assert np.array_equal(base.view(np.uint32), out.view(np.uint32))


def corrupt(model: Model, field: str, prim: int, comp: int, value: float) -> Model:
    m = model.copy()
    m.field(field)[prim, comp] = value
    return m


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 3.0e38])
def test_nonfinite_and_huge_values_in_every_field(field, value):
    model = random_model(300, seed=5)
    cams = orbit_cameras(2, W, H)
    comp = 1 if field not in ("opacity",) else 0
    bad = corrupt(model, field, 17, comp, value)
    g, r = both(bad, cams)
    assert psnr_finite(g, r) >= 50


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_frame_covering_sheet(precision):
    model = random_model(200, seed=6)
    cams = orbit_cameras(2, W, H)
    sheet = corrupt(model, "log_scales", 5, 0, 4.5)  # the scale sign-bit sheet: exp(4.5) ~ 90
    sheet = corrupt(sheet, "log_scales", 6, 1, 1e30)  # exponent overflow: exp -> inf
    g, r = both(sheet, cams, precision)
    clean = Renderer(model, cams, precision).render()
    assert psnr_finite(g, r) >= 50
    changed = (np.abs(g - clean) > 1 / 255).any(-1).mean()
    assert changed > 0.5


def test_one_primitive_touching_every_tile_and_single_primitive_model():
    cam = Camera(look_at((0, 0, -3), (0, 0, 0), up=(0, -1, 0)), intrinsics(W, H, 60), W, H)
    m = Model(
        means=[[0, 0, 0]],
        log_scales=[[1.0, 1.0, -3.0]],
        quats=[[1, 0, 0, 0]],
        opacity=[0.0],
        sh_dc=[[1.0, -0.5, 0.2]],
        sh_rest=np.zeros((1, 15, 3)),
    )
    r = Renderer(m, [cam])
    g = r.render()
    ref = reference.render(m, [cam])
    assert psnr_finite(g, ref) >= 50
    assert r.last_totals[0] == r.n_tiles  # one intersection per tile
    assert (np.abs(g[0] - 1) > 1 / 255).any(-1).all()


def test_behind_camera_and_near_plane():
    cam = Camera(look_at((0, 0, -3), (0, 0, 0), up=(0, -1, 0)), intrinsics(W, H, 60), W, H)
    rng = np.random.default_rng(7)
    n = 64
    means = np.zeros((n, 3), np.float32)
    means[:, :2] = rng.uniform(-0.5, 0.5, (n, 2))
    means[:, 2] = np.concatenate(
        [
            rng.uniform(-6, -3.2, n // 2),  # behind the camera
            -3 + rng.uniform(0.0, 0.05, n // 2),
        ]
    )  # straddling the near plane
    m = Model(
        means=means,
        log_scales=np.full((n, 3), -1.0),
        quats=rng.normal(size=(n, 4)),
        opacity=np.full(n, 2.0),
        sh_dc=rng.normal(size=(n, 3)),
        sh_rest=np.zeros((n, 0, 3)),
    )
    g, r = both(m, [cam])
    assert psnr_finite(g, r) >= 50


def test_viewport_regions_equal_the_full_frame_bit_for_bit():
    model = random_model(600, seed=12)
    cams = orbit_cameras(2, 72, 40)
    full = Renderer(model, cams).render()
    for vp in [(0, 0, 32, 16), (32, 16, 40, 24), (64, 32, 8, 8), (16, 0, 48, 40)]:
        x0, y0, w, h = vp
        part = Renderer(model, cams, viewport=vp).render()
        assert part.shape == (2, h, w, 3)
        assert np.array_equal(part.view(np.uint32), full[:, y0 : y0 + h, x0 : x0 + w].view(np.uint32))
    with pytest.raises(ValueError, match="tile-aligned"):
        Renderer(model, cams, viewport=(8, 0, 16, 16))


def test_views_submitted_one_by_one_equal_one_command_buffer(gpu, monkeypatch):
    """Renderer.run submits each view in a command buffer of its own on a GPU adapter, all K in
    one on a CPU adapter (submission_groups); the frames and totals of the views submitted one by
    one (this adapter posing as a GPU) are those of all K views recorded in one command buffer,
    bit for bit."""
    model = make_scene("blocks", 3000, seed=1)
    r = Renderer(model, scene_cameras("blocks", 3, 48, 40), gpu=gpu, batch_views=False)
    if gpu.is_cpu:
        assert [list(g) for g in r.submission_groups()] == [[0, 1, 2]]
        monkeypatch.setattr(type(gpu), "is_cpu", property(lambda self: False))
    assert [list(g) for g in r.submission_groups()] == [[0], [1], [2]]
    split = r.render_rgba()
    totals = r.last_totals[:3].copy()
    enc = gpu.device.create_command_encoder()
    r.encode(enc)
    gpu.submit(enc)
    one = gpu.read(r.image, np.float32, 0, 16 * 3 * 48 * 40).reshape(3, 40, 48, 4)
    assert np.array_equal(split.view(np.uint32), one.view(np.uint32))
    assert np.array_equal(totals, gpu.read(r.binning.stats, np.uint32)[:3])
    assert np.unique(split[..., :3].reshape(3, -1), axis=0).shape[0] == 3  # three different views


def _bits(a):
    return np.ascontiguousarray(a).view(np.uint32)


@pytest.mark.parametrize("compositor", ["lanes", "wide"])
@pytest.mark.parametrize("exact", [True, False])
def test_batched_views_equal_views_one_at_a_time(gpu, compositor, exact):
    """K views sharing one depth sort, binning, tile sort and compositing pass (renderer.py
    batch_views) give the frames and per-view totals of the views rendered one at a time, bit for
    bit: with long tiles split in chunks (small chunk), grown intersection buffers, a viewport,
    both compositors and both binnings. The frames of the one-at-a-time path are themselves
    checked against the numpy twin (test_scenes_match_reference renders K = 2 batched, too)."""
    model = make_scene("spheres", 6000, seed=2)
    cams = scene_cameras("spheres", 3, 72, 56)
    kw = dict(gpu=gpu, compositor=compositor, exact_binning=exact, chunk=256)
    one = Renderer(model, cams, batch_views=False, **kw)
    want = one.render()
    assert not one.batched
    for extra in ({}, {"capacity": 1000}, {"viewport": (16, 16, 48, 32)}):
        r = Renderer(model, cams, **kw, **extra)
        got = r.render()
        assert r.batched and r.submission_groups() == [range(3)]
        x0, y0, w, h = extra.get("viewport", (0, 0, 72, 56))
        assert np.array_equal(_bits(got), _bits(want[:, y0 : y0 + h, x0 : x0 + w]))
        if "viewport" not in extra:
            assert np.array_equal(r.last_totals, one.last_totals)
            assert r.capacity >= one.last_totals.sum()
    assert (one.last_totals > 256).all()  # long lists exist: the tiles run chunks and merges


def test_batched_views_with_a_gpu_adapters_defaults(gpu, monkeypatch):
    """The configuration a GPU adapter gets (this adapter posing as one): radix sorts of 16
    elements a thread with the fused scatter, compositing chunks of GPU_CHUNK pairs, a submission
    per stage group; batched frames and totals equal the same adapter's views one at a time, bit
    for bit, with both compositors."""
    monkeypatch.setattr(type(gpu), "is_cpu", property(lambda self: False))
    submits = []
    real_submit = gpu.submit
    monkeypatch.setattr(gpu, "submit", lambda enc: (submits.append(enc), real_submit(enc)))
    model = make_scene("spheres", 20000, seed=3)
    cams = scene_cameras("spheres", 3, 80, 64)
    for compositor in ("lanes", "wide"):
        one = Renderer(model, cams, gpu=gpu, compositor=compositor, batch_views=False)
        want = one.render()
        r = Renderer(model, cams, gpu=gpu, compositor=compositor)
        assert r.batched and r.sorting.depth.fused  # 60k keys: 15 blocks
        assert r.split_submissions
        assert np.array_equal(_bits(r.render()), _bits(want))
        assert np.array_equal(r.last_totals, one.last_totals)
        submits.clear()
        r.run()
        assert len(submits) == 4  # projections | depth sort | binning, tile sort | ranges, compositing
    ranges = gpu.read(one.binning.ranges, np.uint32, 0, 8 * one.n_tiles).reshape(-1, 2).astype(np.int64)
    assert (ranges[:, 1] - ranges[:, 0]).max() > GPU_CHUNK  # long tiles ran in chunks and merged


def test_split_submissions_equal_one_command_buffer(gpu, monkeypatch):
    """On a GPU `run` submits each stage group as soon as it is recorded, three more command
    buffers a view where views are not batched (one view; kept views, as campaigns render their
    clean frames): the frames, totals and kept per-view lists equal those of one command buffer
    bit for bit."""
    submits = []
    real_submit = gpu.submit
    monkeypatch.setattr(gpu, "submit", lambda enc: (submits.append(enc), real_submit(enc)))
    model = random_model(3000, seed=8)
    for cams, kw in ((orbit_cameras(1, 48, 40), {}), (orbit_cameras(2, 48, 40), {"keep_views": True})):
        out = {}
        for split in (False, True):
            r = Renderer(model, cams, gpu=gpu, **kw)
            assert not r.batched
            r.split_submissions = split
            r.capture_views = bool(kw)
            r.run()  # settles the capacity
            submits.clear()
            totals = r.run()
            groups = len(r.submission_groups())  # one command buffer per group, unsplit
            assert len(submits) == (3 * len(cams) + groups if split else groups)
            kept = gpu.read(r.kv_ranges, np.uint32) if kw else np.zeros(1)
            out[split] = (_bits(r.render()), totals, kept)
        for a, b in zip(out[False], out[True]):
            assert np.array_equal(a, b)


def test_batching_applies_where_it_can(gpu, monkeypatch):
    """Views are batched by default; not for one view, for kept views (the incremental
    re-compositor reads per-view lists), when asked not to, or past BATCH_MAX_RECORDS; a batched
    frame set whose one list would pass the binding limit falls back to one view at a time (same
    frames); a batched renderer records fewer dispatches than K views one at a time."""
    import seuwgpu.render.renderer as renderer_module

    model = random_model(800, seed=5)
    cams = orbit_cameras(3, 40, 32)
    assert Renderer(model, cams, gpu=gpu).batched
    assert not Renderer(model, cams[:1], gpu=gpu).batched
    assert not Renderer(model, cams, gpu=gpu, keep_views=True).batched
    assert not Renderer(model, cams, gpu=gpu, batch_views=False).batched
    monkeypatch.setitem(renderer_module.BATCH_MAX_RECORDS, "cpu" if gpu.is_cpu else "gpu", 3 * 800 - 1)
    assert not Renderer(model, cams, gpu=gpu).batched
    monkeypatch.undo()

    want = Renderer(model, cams, gpu=gpu, batch_views=False)
    want_img = want.render()
    per_view = int(want.last_totals.max())
    assert per_view < want.last_totals.sum()
    monkeypatch.setattr(Renderer, "max_capacity", property(lambda self: per_view))
    r = Renderer(model, cams, gpu=gpu)
    assert r.batched
    got = r.render()
    assert not r.batched  # the K lists together pass the (patched) limit; one alone fits
    assert np.array_equal(_bits(got), _bits(want_img))
    assert np.array_equal(r.last_totals, want.last_totals)

    class Counter:
        def __init__(self, enc):
            self.enc, self.n = enc, 0

        def begin_compute_pass(self, **kw):
            outer, cpass = self, self.enc.begin_compute_pass(**kw)

            class Pass:
                def __getattr__(self, name):
                    attr = getattr(cpass, name)
                    if name.startswith("dispatch_workgroups"):
                        outer.n += 1
                    return attr

            return Pass()

        def __getattr__(self, name):
            return getattr(self.enc, name)

    counts = {}
    for batch in (True, False):
        c = Counter(gpu.device.create_command_encoder())
        Renderer(model, cams, gpu=gpu, batch_views=batch).encode(c)
        counts[batch] = c.n
    assert counts[True] < counts[False] / 2
