"""A report over runs of two renderer profiles never pools them."""

from __future__ import annotations

import json

import pandas as pd

import seuwgpu as sg


def _spec(profile: str) -> dict:
    return {
        "name": f"profiles-{profile}",
        "seed": 5,
        "views": 1,
        "size": "32x32",
        "batch": 64,
        "profile": profile,
        "scenes": [{"scene": "spheres", "n": 300}],
        "single": {
            "precisions": ["fp32"],
            "fields": ["log_scales", "quats"],
            "bits": [30, 31],
            "samples": 3,
            "defenses": ["none", "guard"],
        },
    }


def test_profiles_get_their_own_table_and_the_rest_rests_on_strict(tmp_path):
    for p in ("strict", "gsplat"):
        sg.run_campaign(_spec(p), tmp_path / p)
    sg.make_report([tmp_path / "strict", tmp_path / "gsplat"], tmp_path / "rep")
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert "profiles" in summary["sections"]
    strict = sg.read_records(tmp_path / "strict")
    both = pd.concat([strict, sg.read_records(tmp_path / "gsplat")])
    # the headline list rests on the strict records alone (12 single upsets per defense)
    assert {(c["defense"], c["n"]) for c in summary["catastrophic"]} == {("none", 12), ("guard", 12)}
    by_profile = summary["numbers"]["catastrophic_by_profile"]
    assert {(c["profile"], c["defense"]) for c in by_profile} == {
        (p, d) for p in ("strict", "gsplat") for d in ("none", "guard")
    }
    for c in by_profile:  # one scene and one cell weight per (field, bit): the weighted rate by hand
        g = both[(both["profile"] == c["profile"]) & (both["defense"] == c["defense"])]
        cells = g.groupby(["field", "bit"])["catastrophic"].mean()
        weights = g.groupby(["field", "bit"])["weight"].sum()  # the stored bits each record stands for
        want = float((cells * weights).sum() / weights.sum())
        assert c["n"] == len(g) and abs(c["rate"] - want) < 1e-12
