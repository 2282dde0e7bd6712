"""Opacity +Inf (what converters give for a saturated alpha: a PLY written by splat-transform
from a compressed PLY holds it): the numpy twin draws it exactly as a splat of sigmoid 1, and the
guard's support box is taken over the finite values, the +Inf clamped into it."""

from __future__ import annotations

import numpy as np

from seuwgpu.faults.guard import clamp_values, component_mask, support_box
from seuwgpu.model.fields import FIELD_OFFSET
from seuwgpu.model.scenes import make_scene, scene_cameras
from seuwgpu.render import reference

ROWS = [3, 40, 41, 90]


def with_opacity(model, value):
    m = model.copy()
    m.opacity[ROWS] = value
    return m


def test_opacity_inf_draws_as_a_splat_of_sigmoid_one():
    model = make_scene("blocks", n=200, seed=3)
    cams = scene_cameras("blocks", 1, 32, 24)
    inf = reference.render(with_opacity(model, np.inf), cams)
    assert np.isfinite(inf).all()
    for same in (20.0, 1e30):  # float32 sigmoid: exactly 1.0
        np.testing.assert_array_equal(inf, reference.render(with_opacity(model, same), cams))
    assert not np.array_equal(inf, reference.render(with_opacity(model, 2.0), cams))  # the rows are seen


def test_guard_box_is_over_finite_opacities_and_clamps_inf_into_it():
    model = with_opacity(make_scene("blocks", n=200, seed=3), np.inf)
    c = FIELD_OFFSET["opacity"]
    finite = np.delete(model.opacity, ROWS)
    box = support_box(model, "fp32")
    assert box.hi[c] == finite.max() and box.lo[c] == finite.min()
    clamped, counts = clamp_values(model.flat(), box, component_mask(["opacity"], model.sh_degree))
    assert (clamped[ROWS, c] == finite.max()).all() and counts.sum() == len(ROWS)
    rest = np.setdiff1d(np.arange(model.n), ROWS)
    np.testing.assert_array_equal(clamped[rest], model.flat()[rest])
