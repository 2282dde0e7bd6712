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


def _report_section(run_dirs, defenses=("none",)):
    """The report's defenses section over campaign records holding only `defenses`."""
    import pandas as pd

    from seuwgpu.report.sections.guard import defenses_section

    return defenses_section(pd.DataFrame({"defense": list(defenses)}), [{"_run_dir": str(d)} for d in run_dirs], {})


def test_the_report_shows_what_defenses_visible_measured(tmp_path, capsys):
    """`seuwgpu defenses --visible N --out RUN` keeps per-upset records in RUN; the report's
    defenses section shows the numbers the command printed, and pandas recomputes them."""
    import json

    import pandas as pd

    from seuwgpu.apps.cli import main

    cmd = ["defenses", "--scene", "blocks", "--n", "200", "--size", "32x32", "--no-time", "--check-every", "2"]
    cmd += ["--visible", "6", "--window", "4", "--visible-defenses", "none", "parity4r", "--seed", "3"]
    assert main([*cmd, "--json", "--out", str(tmp_path)]) == 0
    printed = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    files = list((tmp_path / "visible").glob("*.parquet"))
    assert len(files) == 1
    recs = pd.read_parquet(files[0])
    assert len(recs) == 2 * 6 and set(recs["defense"]) == {"none", "parity4r"}
    assert (recs["scene"] == "blocks").all() and (recs["width"] == 32).all() and (recs["schedule"] == 2).all()
    sec = _report_section([tmp_path])
    (item,) = [t for t in sec.tables if t.name == "visible_damage"]
    shown = item.df.set_index("defense")
    by = recs.groupby("defense")
    want = by[["catastrophic_frames", "sdc_frames", "residue_frames"]].mean()
    for d in ("none", "parity4r"):
        row = shown.loc[d]
        assert row["catastrophic frames / upset"] == pytest.approx(want.loc[d, "catastrophic_frames"])
        assert row["SDC frames / upset"] == pytest.approx(want.loc[d, "sdc_frames"])
        assert row["after the check"] == pytest.approx(want.loc[d, "residue_frames"])
        assert row["catastrophic lo"] <= row["catastrophic frames / upset"] <= row["catastrophic hi"]
        # the command's own numbers, intervals included (the same seeded bootstrap)
        for col, key in (("catastrophic lo", "catastrophic_lo"), ("catastrophic hi", "catastrophic_hi")):
            assert row[col] == pytest.approx(printed[d][key])
        assert row["catastrophic frames / upset"] == pytest.approx(printed[d]["catastrophic_frames_per_upset"])
    assert shown.loc["parity4r", "S"] == "2" and shown.loc["none", "S"] == ""
    totals = by["catastrophic_frames"].sum()
    if totals["none"]:
        assert shown.loc["parity4r", "x none"] == pytest.approx(totals["parity4r"] / totals["none"])


def test_no_visible_records_no_table_and_an_event_free_arm_has_its_bound(tmp_path):
    import pandas as pd

    from seuwgpu.analysis.records import InsufficientData
    from seuwgpu.campaign.visible import save_counts

    with pytest.raises(InsufficientData):  # no records of either kind: no section, not zeros
        _report_section([tmp_path])
    n, window = 40, 20
    counts = pd.DataFrame(
        {
            "defense": ["none"] * n + ["parity4f"] * n,
            "check_every": 0,
            "upset": list(range(n)) * 2,
            "catastrophic_frames": [5] * 10 + [0] * (n - 10) + [0] * n,
            "sdc_frames": [1] * n + [2] * 4 + [0] * (n - 4),
            "residue_frames": [5] * 10 + [0] * (n - 10) + [0] * n,
            "window": window,
            "upsets": n,
            "schedule": 10,
        }
    )
    meta = dict(scene="s", n_primitives=9, precision="fp32", width=8, height=8, fault="bit", seed=0)
    save_counts(tmp_path, counts, **meta, device="llvmpipe", date="2026-12-07")
    shown = next(t for t in _report_section([tmp_path]).tables if t.name == "visible_damage").df.set_index("defense")
    assert shown.loc["none", "catastrophic frames / upset"] == 50 / 40  # 10 upsets of 5 frames
    assert shown.loc["parity4f", "catastrophic frames / upset"] == 0
    assert shown.loc["parity4f", "catastrophic hi"] == pytest.approx(20 * (1 - 0.025 ** (1 / 40)))
    assert shown.loc["parity4f", "SDC frames / upset"] == 8 / 40
    assert shown.loc["parity4f", "x none"] == 0
    assert shown.loc["parity4f", "x none hi"] == pytest.approx(20 * (1 - 0.025 ** (1 / 40)) / 1.25)
    assert (shown["device"] == "llvmpipe").all() and (shown["date"] == "2026-12-07").all()
    # the same measurement kept in a second folder: a row of its own, not pooled upsets
    other = tmp_path / "second"
    save_counts(other, counts.assign(catastrophic_frames=0), **meta, device="llvmpipe", date="2026-12-08")
    both = next(t for t in _report_section([tmp_path, other]).tables if t.name == "visible_damage").df
    got = both.set_index(["run", "defense"])["catastrophic frames / upset"]
    assert got[(tmp_path.name, "none")] == 50 / 40 and got[("second", "none")] == 0 and len(both) == 4
