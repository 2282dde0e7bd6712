"""Projection stage (render/project.py): the GPU kernel against its numpy twin `project`, record by
record, on the same stored model and camera.

Exact: which primitives are drawn, their tile rectangles, the non-finite pattern of every record.
Float records (screen mean, conic, colour) agree to 1e-5 of the record's largest component, and
depth and opacity to 2e-6 relative (a few float32 ulps: the GPU may fuse multiply-adds and its
exp / rsqrt may differ by an ulp; measured: ~1e-6 and ~3 ulps)."""

import numpy as np
import pytest
from conftest import close_records, random_model

from seuwgpu.faults.guard import clamp_values, component_mask, guard_fields, support_box
from seuwgpu.gpu.constants import TILE
from seuwgpu.model import encoding
from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.model.fields import Model, StoredLayout
from seuwgpu.render.project import Projection, depth_keys, n_tiles_xy, project
from seuwgpu.render.renderer import Renderer

SPECIAL = [np.nan, np.inf, -np.inf, 1e30, -1e30, 30.0, 0.0, -0.0]


def corrupted(n, seed, n_bad=40, degree=3):
    """A random scene with special values planted in random components (sheets, NaN colours,
    culled means, zero quaternions, ...)."""
    m = random_model(n, degree=degree, seed=seed)
    flat = m.flat()
    rng = np.random.default_rng(seed)
    for _ in range(n_bad):
        flat[rng.integers(n), rng.integers(flat.shape[1])] = SPECIAL[rng.integers(len(SPECIAL))]
    flat[3, 0] = np.nan  # no screen position: culled
    flat[4, 3:6] = 60.0  # overflowing scale: the frame-covering sheet
    flat[5, 6:10] = 0.0  # zero quaternion: NaN rotation, unbounded too
    flat[6, 10] = np.nan  # NaN opacity: drawn, NaN
    return Model.from_flat(flat, m.sh_degree)


def gpu_project(gpu, model, cam, precision, chunk_prims, guard=None):
    """Run the Projection stage alone over every chunk of the stored model; `guard` = (Bound
    rows, component mask) turns the in-pipeline guard on. Returns (records, chunks, clamp counts)."""
    L = StoredLayout(model.n, model.sh_degree, precision, chunk_prims)
    words = [gpu.upload(w) for w in L.encode(model)]
    stage = Projection(gpu, model.n, L.n_chunks)
    box = gpu.upload(guard[0]) if guard else gpu.buffer(16 * L.ncomp)
    counts = gpu.upload(np.zeros(8, np.uint32))
    for c in range(L.n_chunks):
        a, b = L.chunk_range(c)
        stage.set_view(
            c,
            cam,
            tiles=n_tiles_xy(cam),
            n_total=model.n,
            chunk=(a, b - a),
            plane_words=L.plane_words,
            degree=model.sh_degree,
            precision=precision,
            view_index=0,
            guard_mask=guard[1] if guard else 0,
        )
    stage.params.write()
    enc = gpu.device.create_command_encoder()
    for c in range(L.n_chunks):
        a, b = L.chunk_range(c)
        stage.encode(enc, c, words[c], b - a, box, counts)
    gpu.submit(enc)
    return stage.read(model.n), L.n_chunks, gpu.read(counts)[:6]


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_projection_matches_twin(gpu, precision):
    model = corrupted(3001, seed=1)
    cam = orbit_cameras(3, 72, 40)[1]
    got, n_chunks, _ = gpu_project(gpu, model, cam, precision, chunk_prims=1024)
    assert n_chunks == 3
    with np.errstate(all="ignore"):
        want = project(model.quantized(precision), cam)
    vis = want["visible"]
    assert 0.5 * model.n < vis.sum() < model.n and not vis[3] and vis[6] and want["unbounded"][[4, 5]].all()
    assert_records_match(got, want, cam)


def assert_records_match(got, want, cam):
    """GPU records against the twin's: the exact parts exactly, floats to the module's tolerances."""
    vis = want["visible"]
    # exact: drawn or culled, tile rectangles (zero when culled), primitive ids, culled keys
    np.testing.assert_array_equal(got["depth_keys"] != 0xFFFFFFFF, vis)
    np.testing.assert_array_equal(got["rect"], want["rect"])
    np.testing.assert_array_equal(got["depth_vals"], np.arange(len(vis)))
    assert (got["rect"][want["unbounded"]] == [0, 0, *n_tiles_xy(cam)]).all()
    assert (got["conic"][want["unbounded"]] == 0).all()
    # float records of the drawn primitives
    close_records(got["proj_xy"][vis], want["proj_xy"][vis])
    close_records(got["conic"][vis], want["conic"][vis])
    close_records(got["rgb"][vis], want["rgb"][vis])
    np.testing.assert_allclose(got["depth"][vis], want["depth"][vis], rtol=2e-6)
    np.testing.assert_allclose(got["opacity"][vis], want["opacity"][vis], rtol=2e-6, atol=0)
    keys = depth_keys(want)
    rel = np.abs(got["depth_keys"][vis].astype(np.int64) - keys[vis].astype(np.int64))
    assert rel.max() <= 4  # depth bits within a few ulps (same sign, same binade neighbours)


def test_viewport_rectangles_are_the_full_frames_shifted(gpu):
    """A sort-first region projects into its own tiles: the full frame's rectangles minus the
    region's tile origin, clamped to the region."""
    model = random_model(700, seed=12)
    cams = orbit_cameras(2, 72, 40)
    full = Renderer(model, cams)
    part = Renderer(model, cams, viewport=(32, 16, 40, 24))
    for r in (full, part):
        r.render()  # leaves the last view's records in the projection buffers
    rf, rp = full.projection.read(model.n)["rect"], part.projection.read(model.n)["rect"]
    x0, y0, tx, ty = 32 // TILE, 16 // TILE, part.tiles_x, part.tiles_y
    shifted = np.stack(
        [
            np.clip(rf[:, 0] - x0, 0, tx),
            np.clip(rf[:, 1] - y0, 0, ty),
            np.clip(rf[:, 2] - x0, 0, tx),
            np.clip(rf[:, 3] - y0, 0, ty),
        ],
        axis=1,
    )
    empty = (shifted[:, 2] <= shifted[:, 0]) | (shifted[:, 3] <= shifted[:, 1])
    shifted[empty] = 0
    np.testing.assert_array_equal(rp, shifted)


@pytest.mark.parametrize(
    "precision, degree, fields", [("fp32", 1, "guard"), ("fp16", 2, "selective"), ("bf16", 0, "guard")]
)
def test_guarded_projection_variants_match_twin(gpu, precision, degree, fields):
    """The pipelines specialised per precision, SH degree and guard mask: the guarded projection
    of a corrupted model equals the twin's projection of the model clamped by the guard's twin,
    and the clamp counts are the twin's."""
    model = corrupted(2000, seed=3, degree=degree)
    cam = orbit_cameras(3, 72, 40)[2]
    stored = model.quantized(precision)
    clean = random_model(2000, degree=degree, seed=3).quantized(precision)
    box = support_box(clean, precision)
    mask = component_mask(guard_fields(fields), degree)
    got, _, counts = gpu_project(gpu, model, cam, precision, chunk_prims=1024, guard=(box.rows(), mask))
    clamped, want_counts = clamp_values(stored.flat(), box, mask)
    with np.errstate(all="ignore"):
        want = project(Model.from_flat(clamped, degree), cam)
    assert want_counts.sum() > 0
    np.testing.assert_array_equal(counts, want_counts)
    assert_records_match(got, want, cam)


def test_exp_flushes_results_below_the_smallest_normal(gpu):
    """Opacity logits and log-scales in exp's subnormal range (-104 < x < -87.33): docs/renderer.md
    rule 4 flushes exp to 0 there on every device (GPUs may flush subnormal results; lavapipe
    does), so the opacity is exactly 0 on the GPU and in the twin, not 1e-40 in one of them."""
    model = random_model(12, seed=4)
    x = np.array([-103.9, -100.0, -95.0, -90.0, -87.5, -87.3366, -87.335, -87.33, -20.0, -104.0, -1.0, 2.0])
    model.opacity[:] = x
    model.log_scales[:, 0] = x
    cam = orbit_cameras(3, 72, 40)[0]
    got, _, _ = gpu_project(gpu, model, cam, "fp32", chunk_prims=1024)
    with np.errstate(all="ignore"):
        want = project(model, cam)
    assert want["visible"].all()
    np.testing.assert_array_equal(want["opacity"][:8] == 0, [True] * 7 + [False])
    np.testing.assert_array_equal(got["opacity"] == 0, want["opacity"] == 0)
    assert_records_match(got, want, cam)
