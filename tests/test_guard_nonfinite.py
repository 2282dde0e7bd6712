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


def test_component_ranges_over_tiles_of_rows(monkeypatch):
    """component_ranges reduces tiles of rows: with tiles of 7 rows (the last one short), of the
    model or of the words a GPU is given (split in chunks), it gives numpy's min/max over the
    finite values and the count of the others, per component; a component with no finite value
    has an empty range and a box of [0, 0]."""
    from seuwgpu.faults import guard
    from seuwgpu.model.fields import StoredLayout

    model = nan_model()
    model.sh_dc[:, 1] = np.nan
    monkeypatch.setattr(guard, "RANGE_ROWS", 7)
    lo, hi, bad = guard.component_ranges(guard.model_tiles(model))
    layout = StoredLayout(model.n, model.sh_degree, "fp32", 500)
    from_words = guard.component_ranges(layout.value_tiles(layout.encode(model), 7))
    for got, want in zip(from_words, (lo, hi, bad)):
        np.testing.assert_array_equal(got, want)
    half = StoredLayout(model.n, model.sh_degree, "bf16", 500)  # 16-bit words: two values a word
    from_halves = guard.component_ranges(half.value_tiles(half.encode(model), 7))
    for got, want in zip(from_halves, guard.component_ranges(guard.model_tiles(model.quantized("bf16")))):
        np.testing.assert_array_equal(got, want)
    flat = model.flat()
    fin = np.where(np.isfinite(flat), flat, np.nan)
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):  # the all-NaN column
        want_lo, want_hi = np.nanmin(fin, axis=0), np.nanmax(fin, axis=0)
    c = 12  # sh_dc[1]
    np.testing.assert_array_equal(np.delete(lo, c), np.delete(want_lo, c))
    np.testing.assert_array_equal(np.delete(hi, c), np.delete(want_hi, c))
    assert lo[c] == np.inf and hi[c] == -np.inf
    np.testing.assert_array_equal(bad, (~np.isfinite(flat)).sum(axis=0))
    assert bad[c] == model.n and bad.sum() == model.n + 3
    box = guard.support_box(model, "fp32")
    assert box.lo[c] == box.hi[c] == 0.0
    for lay, p in ((layout, "fp32"), (half, "bf16")):  # the box of the words a GPU holds
        words = lay.encode(model)
        got, want = guard.stored_box(lay, words, p), guard.support_box(lay.decode(words), p)
        np.testing.assert_array_equal(got.lo, want.lo)
        np.testing.assert_array_equal(got.hi, want.hi)


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
