"""A clean model holding NaN/Inf: the guard's box over finite values, its effect on the clean
model reported once, guarded upsets against the guarded clean render, incremental = full."""

import numpy as np
import pytest
from test_incremental import METRICS, same, sample_sites

from seuwgpu.faults.engine import Engine
from seuwgpu.faults.guard import clamp_values
from seuwgpu.model.scenes import make_scene, scene_cameras


def nan_model():
    model = make_scene("blocks", n=1500, seed=2)
    model.quats[5, 1] = np.nan
    model.log_scales[9, 0] = np.inf
    model.opacity[20] = np.nan
    return model


@pytest.fixture(scope="module")
def eng():
    return Engine(nan_model(), scene_cameras("blocks", 2, 48, 40), "fp32", scene="blocks")


def test_box_over_finite_values_and_guard_identity(eng):
    flat = nan_model().flat().astype(np.float32)
    fin = np.where(np.isfinite(flat), flat, np.nan)
    np.testing.assert_array_equal(eng.box.lo, np.nanmin(fin, axis=0))
    np.testing.assert_array_equal(eng.box.hi, np.nanmax(fin, axis=0))
    clamped, counts = clamp_values(flat, eng.box, eng.masks["guard"])
    ok = np.isfinite(flat)
    assert np.array_equal(clamped[ok].view(np.uint32), flat[ok].view(np.uint32))  # finite: untouched
    assert counts.sum() == 3


def test_guard_effect_on_the_clean_model_is_reported_once(eng):
    rep = eng.guard_on_clean("guard")
    assert rep["nonfinite_values"] == {"log_scales": 1, "quats": 1, "opacity": 1}
    assert rep["clamps"] == 3 and rep["footprint"] > 0  # the strict NaN-quaternion sheet goes away
    # an upset that changes nothing the guard reads (a NaN stays NaN) is masked under the guard,
    # instead of being charged the guard's effect on the clean model
    site = eng.site("opacity", 20, 0, 0)
    assert np.isnan(eng.corrupted_value(site))
    for rec in (eng.inject(site, "guard"), *eng.evaluate([site], ("guard",))):
        assert rec["footprint"] == 0 and rec["psnr"] == np.inf and rec["clamps"] == 0, rec


def test_incremental_equals_full_on_every_guard_row(eng):
    rng = np.random.default_rng(3)
    sites = sample_sites(eng, rng, per_class=2) + [eng.site("quats", 5, 2, 30), eng.site("opacity", 20, 0, 22)]
    defenses = ("guard", "none", "selective")  # the reference switches between arms
    inc = eng.evaluate(sites, defenses)
    for rec in inc:
        site = eng.site(rec["field"], rec["primitive"], rec["component"], rec["bit"])
        full = eng.inject(site, rec["defense"])
        for key in METRICS:
            assert same(rec[key], full[key]), (rec, key, full[key])


def test_campaign_notes_the_guard_effect_once(eng, tmp_path):
    import json
    from types import SimpleNamespace

    from seuwgpu.campaign.runner import Runner
    from seuwgpu.campaign.store import guard_note_path

    runner = Runner.__new__(Runner)
    runner.out = tmp_path
    runner.note_clean_model(eng, SimpleNamespace(precision="fp32", defenses=["none", "guard"]))
    note = json.loads(guard_note_path(tmp_path, "blocks", "fp32", "strict").read_text())
    assert note["nonfinite_values"] == {"log_scales": 1, "quats": 1, "opacity": 1}
    assert note["guard"]["clamps"] == 3 and "selective" not in note


def test_health_monitor_alerts_on_upsets_not_on_the_clean_models_own_nan(eng):
    """The guard clamps the clean model's NaN/Inf on every guarded render; the health monitor
    (viewer, interactive use) must not alert on that, only on clamps an upset adds."""
    import warnings

    from seuwgpu.faults.guard import GuardAlert

    with warnings.catch_warnings():
        warnings.simplefilter("error", GuardAlert)
        _, counts = eng.render_current("guard")
    assert sum(counts.values()) == 3 and not eng.monitor.alert  # raw clamps: the clean model's own
    site = eng.site("log_scales", 30, 1, 30)  # exponent bit: far outside the box
    handle = eng.apply([site], "guard")
    try:
        with pytest.warns(GuardAlert, match="log_scales: 1"):
            eng.render_current("guard")
    finally:
        eng.undo(handle)
    assert eng.monitor.alert
