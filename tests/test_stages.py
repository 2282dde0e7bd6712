"""Every stage of PIPELINE on the GPU against its own twin, on the same named inputs
(render/stage.py): `run_stage(S, **x)` writes x into the renderer's buffers by name, records
stage S alone and reads its outputs back by name; `S.twin(**x)` returns the same names. The
inputs of each stage are the previous stages' twin outputs, so every stage is checked on its own.

Exact where the stage declares it (tile rectangles, depth order, pairs, tile sort, ranges);
float outputs to 1e-5 of a record's largest component with the same non-finite pattern (the GPU
may fuse multiply-adds and its exp / rsqrt may differ by an ulp: render/project.py), where the
twin computes them: a culled primitive's records are only its rectangle and depth key."""

import numpy as np
import pytest
from conftest import close_records, random_model

from seuwgpu.model.scenes import make_scene, scene_cameras
from seuwgpu.render.pipeline import PIPELINE
from seuwgpu.render.project import n_tiles_xy
from seuwgpu.render.renderer import Renderer


def corrupted_model():
    """A random scene with the values the rules single out: a culled mean, a frame-covering sheet,
    a zero quaternion, a NaN opacity."""
    m = random_model(900, seed=21)
    m.means[3] = np.nan
    m.log_scales[4] = 60.0
    m.quats[5] = 0.0
    m.opacity[6] = np.nan
    return m


@pytest.fixture(scope="module", params=["blocks", "corrupted"])
def renderer(request, gpu):
    """One view at a time (its buffers hold one view's records), on the session's adapter."""
    if request.param == "corrupted":
        model, cams = corrupted_model(), scene_cameras("blocks", 2, 56, 40)
    else:
        model, cams = make_scene("blocks", n=600, seed=2), scene_cameras("blocks", 2, 56, 40)
    r = Renderer(model, cams, gpu=gpu, batch_views=False)
    r.render()  # sizes the lists and leaves the buffers of the last view
    return r


def context(r: Renderer, v: int) -> dict:
    """The first stage's inputs and every stage's params, as the reference renderer gives them."""
    cam = r.cameras[v]
    tx, ty = n_tiles_xy(cam)
    return {
        "model": r.stored_model(),
        "view": cam,
        "profile": r.profile,
        "tiles_x": tx,
        "n_tiles": tx * ty,
        "exact_binning": r.binning.exact,
        "width": cam.width,
        "height": cam.height,
        "background": r.background,
    }


def records(r: Renderer, output, pairs: int) -> int:
    return {"primitive": r.n, "pair": pairs, "tile": r.n_tiles, "pixel": r.width * r.height}[output.record]


def run_stage(r: Renderer, stage, v: int, pairs: int, **arrays) -> dict:
    """Stage `stage` of view v alone on the GPU: its buffer inputs written from `arrays` by name,
    its outputs cleared, then read back by name (`pairs`: the view's list length, whose total the
    tile sort reads from the GPU)."""
    g, buffers = r.gpu, r.buffers
    for name in stage.inputs:
        if name in buffers:
            g.write(buffers[name], np.ascontiguousarray(arrays[name]).view(np.uint32))
    g.write(r.binning.stats, np.full(r.k + 1, pairs, np.uint32))
    enc = g.device.create_command_encoder()
    for o in stage.outputs:
        if o.name not in stage.inputs:
            enc.clear_buffer(buffers[o.name])
    r.encode_stage(stage, enc, buffers, v, range(v, v + 1))
    g.submit(enc)
    got = {}
    for o in stage.outputs:
        size = 4 * o.words * records(r, o, pairs)
        at = size * v if o.record == "pixel" else 0  # the image holds every view's frame
        got[o.name] = o.view_of(g.read(buffers[o.name], np.uint32, at, size))
    return got


def test_every_stage_equals_its_twin_on_the_same_named_inputs(renderer):
    r, v = renderer, 1
    state = context(r, v)
    names = []
    for stage in PIPELINE:
        want = stage.twin(**state)
        pairs = len(state.get("isect_tiles", want.get("isect_tiles", ())))
        got = run_stage(r, stage, v, pairs, **state)
        for o in stage.outputs:
            if not o.twinned:
                continue
            w = o.view_of(np.ascontiguousarray(want[o.name]).reshape(-1).view(np.uint32))
            if o.exact:
                np.testing.assert_array_equal(got[o.name], w, err_msg=f"{stage.name}: {o.name}")
            else:  # float words, compared as floats (depth keys are the f32 bits of the depth)
                close_records(got[o.name].view(np.float32), w.view(np.float32))
            names.append(o.name)
        state.update(want)
    assert len(state["isect_tiles"]) > r.n  # a real workload: more pairs than primitives
    assert "image" in names and "isect_prims" in names


def test_each_stage_declares_what_it_binds_and_its_twin_returns_its_outputs():
    """A stage's inputs are outputs of stages before it (or the first stage's model and view);
    the twins refuse a missing input by name."""
    made = {"model", "view"}
    for stage in PIPELINE:
        assert set(stage.inputs) <= made, stage.name
        made |= set(stage.output_names)
    with pytest.raises(TypeError, match="stage emit's twin needs depth_vals"):
        PIPELINE[2].twin(proj_rect=0, proj_xy=0, proj_conic=0, tiles_x=1, exact_binning=True)
