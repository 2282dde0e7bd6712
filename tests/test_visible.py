"""User-visible damage (campaign/visible.py): catastrophic frames per upset measured by running
frames, against a reference built from single-frame injections and the schedule by hand."""

import numpy as np
import pytest

from seuwgpu.campaign.visible import plan_upsets, visible_damage
from seuwgpu.faults.engine import Engine
from seuwgpu.model.scenes import make_scene, scene_cameras


def test_catastrophic_frames_per_upset_are_what_the_frames_showed():
    model = make_scene("blocks", n=200, seed=4)
    eng = Engine(model, scene_cameras("blocks", 1, 32, 32), "fp32", scene="blocks")
    upsets, window, s = 8, 4, 2
    summary, recs = visible_damage(eng, ("none", "parity4r"), check_every=s, upsets=upsets, window=window, seed=5)
    plan, at = plan_upsets(eng, upsets, window, seed=5)
    sites = [plan[u * window + a] for u, a in enumerate(at)]
    bad = np.array([eng.inject(x, "none")["catastrophic"] for x in sites])
    assert bad.any() and not bad.all()  # the draw holds both kinds
    # none: a catastrophic upset is drawn from its frame to the reload; parity4r (every flip of
    # these cells is detected and reloaded) until the next check: (-at) mod S frames
    want_none = (bad * (window - at)).sum() / upsets
    want_p4 = (bad * ((-at) % s)).sum() / upsets
    row = summary.set_index("defense")
    assert row.loc["none", "catastrophic_frames_per_upset"] == pytest.approx(want_none)
    assert row.loc["parity4r", "catastrophic_frames_per_upset"] == pytest.approx(want_p4)
    assert row.loc["parity4r", "residue_frames_per_upset"] == 0  # nothing left after the check
    assert row.loc["none", "residue_frames_per_upset"] == pytest.approx(want_none)  # never repaired
    assert row.loc["parity4r", "of_none"] == pytest.approx(want_p4 / want_none)
    assert row.loc["none", "catastrophic_lo"] <= want_none <= row.loc["none", "catastrophic_hi"]
    assert len(recs) == 2 * upsets * window and (row["window"] == window).all()
    # a window is whole schedules: 5 frames at S = 2 become 6
    assert visible_damage(eng, ("parity4r",), check_every=2, upsets=1, window=5)[0]["window"].item() == 6
    with pytest.raises(ValueError, match="upsets, window and check_every >= 1"):
        visible_damage(eng, ("none",), upsets=0)


def test_no_event_has_a_bound_not_a_degenerate_interval():
    from seuwgpu.campaign.visible import frames_interval

    rng = np.random.default_rng(0)
    lo, hi = frames_interval(np.zeros(40), rng, 20)
    assert lo == 0 and hi == pytest.approx(20 * (1 - 0.025 ** (1 / 40)))  # 0 of 40: share <= 8.8%
    lo, hi = frames_interval(np.array([0.0, 2.0, 4.0, 0.0]), rng, 20)
    assert 0 <= lo <= 1.5 <= hi <= 4
    assert all(np.isnan(frames_interval(np.zeros(1), rng, 20)))
