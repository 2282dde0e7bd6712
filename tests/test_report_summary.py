"""The report's opening summary (report/summary.py, analysis/summary.py): the cheapest-defense
rule, the target's spec key and option, what the runner keeps of a model file for it. Its
numbers against the records: tests/test_report_numbers.py; the page: test_report_browser.py."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from seuwgpu.analysis.summary import DEFAULT_TARGET, cheapest, spec_target
from seuwgpu.campaign.spec import SpecError, normalize_spec
from seuwgpu.campaign.spec_hash import sites_key
from seuwgpu.campaign.spec_types import as_spec


def defenses(rows):
    cols = ["defense", "rate", "ci_lo", "ci_hi", "time_ms", "device_bytes"]
    t = pd.DataFrame(rows, columns=cols)
    return t.assign(scene="m", n_primitives=1000, precision="fp32")


def test_the_cheapest_defense_that_meets_the_target_is_the_fastest_then_the_smallest():
    t = defenses(
        [
            ("none", 0.05, 0.04, 0.06, 2.0, 0),
            ("checksum", 0.0, 0.0, 0.0004, 2.1, 34_000),  # the best rate, but slower
            ("parity4", 0.0002, 0.0, 0.0008, 2.05, 5_400),  # as fast as guard, larger
            ("guard", 0.0003, 0.0, 0.0009, 2.05, 976),  # meets the target: fastest, then smallest
            ("scalebound", 0.0001, 0.0, 0.0003, math.nan, 64),  # time not measured: after the measured
        ]
    )
    r = cheapest(t, 0.001).iloc[0]
    assert r["met"] and r["defense"] == "guard" and r["candidates"] == 4
    assert r["time_ms"] == 2.05 and r["device_bytes"] == 976
    # a stricter target leaves only the slower checksum and the unmeasured scalebound: the measured first
    assert cheapest(t, 0.0005).iloc[0]["defense"] == "checksum"
    # no defense meets a loose target: nothing to add, although guard was timed faster (noise)
    loose = t.assign(time_ms=t["time_ms"].where(t["defense"] != "guard", 1.9))
    r = cheapest(loose, 0.1).iloc[0]
    assert r["defense"] == "none" and r["candidates"] == 5
    # only the unmeasured one meets it: it is the answer (its time shown as not measured, never 0)
    r = cheapest(t, 0.00035).iloc[0]
    assert r["defense"] == "scalebound" and math.isnan(r["time_ms"])


def test_no_defense_meets_the_target_and_the_summary_says_which_came_closest():
    t = defenses([("none", 0.05, 0.04, 0.06, 2.0, 0), ("guard", 0.001, 0.0002, 0.004, 2.5, 976)])
    r = cheapest(t, 0.001).iloc[0]  # guard's rate equals the target, but its interval reaches 0.4%
    assert not r["met"] and pd.isna(r["defense"]) and r["candidates"] == 0
    assert r["closest"] == "guard" and r["closest_ci_hi"] == 0.004
    with pytest.raises(ValueError, match="target"):
        cheapest(t, 0)


def test_the_target_is_a_spec_key_that_changes_no_fault_site():
    raw = {"views": 1, "size": "16x16", "scenes": [{"scene": "spheres", "n": 100}], "single": {"samples": 1}}
    spec = normalize_spec({**raw, "summary": {"target": 0.02}})
    assert spec.summary.target == 0.02 and as_spec(spec.to_dict()) == spec
    assert spec_target([{"spec": spec.to_dict()}]) == 0.02
    assert spec_target([{"spec": normalize_spec(raw).to_dict()}]) is None  # the report's default then
    assert DEFAULT_TARGET == 0.001
    assert sites_key(spec) == sites_key(normalize_spec(raw))
    for bad in (0, 1, -0.1, "0.1", True):
        with pytest.raises(SpecError, match="summary.target"):
            normalize_spec({**raw, "summary": {"target": bad}})
    with pytest.raises(SpecError, match="unknown key"):
        normalize_spec({**raw, "summary": {"goal": 0.1}})


def test_report_takes_the_target_on_its_command_line():
    from seuwgpu.apps.cli import build_parser

    args = build_parser().parse_args(["report", "runs/a", "--out", "r", "--target", "0.005"])
    assert args.target == 0.005
    assert build_parser().parse_args(["report", "runs/a", "--out", "r"]).target is None
    with pytest.raises(SystemExit):
        build_parser().parse_args(["report", "runs/a", "--out", "r", "--target", "2"])


def test_the_manifest_keeps_the_model_files_format_size_degree_and_loader_notes(tmp_path):
    """What the summary's model table reads: Runner.check_files, before a new run's manifest."""
    from seuwgpu.campaign.runner import Runner
    from seuwgpu.model.fields import Model
    from seuwgpu.model.formats import save_model

    rng = np.random.default_rng(0)
    n = 40
    model = Model(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=np.full((n, 3), -3.0, np.float32),
        quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
        opacity=np.zeros(n, np.float32),
        sh_dc=rng.normal(size=(n, 3)).astype(np.float32),
        sh_rest=np.zeros((n, 3, 3), np.float32),
    )
    path = tmp_path / "tiny.ply"
    save_model(model, path)
    spec = normalize_spec(
        {"views": 1, "size": "16x16", "scenes": [{"model": str(path)}, {"scene": "spheres", "n": 50}], "single": {}}
    )
    models = Runner(spec, None).check_files()
    assert models[0] == {"name": "tiny", "format": "ply", "primitives": n, "sh_degree": 1, "notes": []}
    assert models[1] == {"name": "spheres", "format": "embedded scene", "primitives": 50, "sh_degree": 3, "notes": []}


def records(time_ms=float("nan")) -> pd.DataFrame:
    """A few single-upset records of one model under none and guard (no run: the summary's rows)."""
    rows = []
    for field, bit in [("opacity", 30), ("opacity", 0), ("log_scales", 30), ("log_scales", 0)]:
        for i in range(4):
            for d in ("none", "guard"):
                bad = d == "none" and bit == 30 and i < 3
                rows.append(
                    {
                        "campaign": "single",
                        "scene": "m",
                        "n_primitives": 100,
                        "precision": "fp32",
                        "field": field,
                        "primitive": i,
                        "component": 0,
                        "bit": bit,
                        "defense": d,
                        "footprint": 0.5 if bad else 0.0,
                        "peak_error": 1.0 if bad else 0.0,
                        "nonfinite": False,
                        "catastrophic": bad,
                        "k": 1,
                        "weight": 100.0 * (3 if field == "log_scales" else 1) / 4,
                        "time_ms": time_ms,
                    }
                )
    return pd.DataFrame(rows)


def test_a_time_not_measured_is_said_so_never_zero_and_a_missing_arm_is_named():
    from seuwgpu.report.summary import summary_section

    manifests = [{"spec": {"scenes": [{"scene": "m", "n": 100}], "summary": {"target": 0.5}}}]
    sec = summary_section(records(), manifests, panel=False)
    t = next(t.df for t in sec.tables if t.name == "summary_defenses")
    assert list(t["time per frame"]) == ["not measured"] * 2 and list(t["time vs none"]) == [
        "reference",
        "not measured",
    ]
    num = sec.numbers["summary"]
    assert num["target"] == 0.5 and num["target_source"] == "the spec's [summary] target"
    assert all(math.isnan(d["time_ms"]) for d in num["defenses"])
    # guard meets 50% (no catastrophe), none does not: guard is the answer though its time is unknown
    assert [c["defense"] for c in num["cheapest"]] == ["guard"]
    assert "Its panel (clean | faulted | guarded | error): `seuwgpu inject --scene m --n 100" in " ".join(sec.notes)
    # no arm without a defense: p_c is not measured, and the summary says how to measure it
    df = records()
    sec = summary_section(df[df["defense"] == "guard"], manifests, panel=False)
    assert "p_c: not measured" in sec.text and not any(t.name == "summary_pc" for t in sec.tables)
    # no single upset at all
    sec = summary_section(df.assign(campaign="dose"), manifests, panel=False)
    assert "no single upset" in sec.text and not sec.tables


def test_the_worst_flip_is_the_largest_footprint_a_non_finite_frame_first_among_equals():
    from seuwgpu.analysis.summary import worst_record

    df = records()
    none = df["defense"] == "none"
    df.loc[none & (df["field"] == "opacity") & (df["bit"] == 0), ["nonfinite", "footprint"]] = [True, 0.01]
    assert worst_record(df)["footprint"] == 0.5  # a sheet over half the frame beats a non-finite speck
    df.loc[none & (df["field"] == "opacity") & (df["bit"] == 0) & (df["primitive"] == 2), "footprint"] = 0.5
    w = worst_record(df)
    assert w["nonfinite"] and (w["field"], w["bit"], w["primitive"]) == ("opacity", 0, 2)
    assert worst_record(df[~none]) is None  # no unguarded record: no worst flip to show
