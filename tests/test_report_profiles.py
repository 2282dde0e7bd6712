"""A report over runs of two renderer profiles never pools them."""

from __future__ import annotations

import json

import pandas as pd
import pytest

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


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("profiles")
    for p in ("strict", "gsplat"):
        sg.run_campaign(_spec(p), base / p)
    return base


@pytest.mark.parametrize("fold", [False, True])  # folded: the gsplat records keep only their rates
def test_profiles_get_their_own_table_and_the_rest_rests_on_strict(runs, tmp_path, fold):
    sg.make_report([runs / "strict", runs / "gsplat"], tmp_path / "rep", fold=fold)
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert "profiles" in summary["sections"]
    strict = sg.read_records(runs / "strict")
    both = pd.concat([strict, sg.read_records(runs / "gsplat")])
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


def test_folded_report_of_two_profiles_equals_the_records_report(runs, tmp_path, undrawn_figures):
    from test_folding import _same_numbers, _same_table, _tables

    out = {f: sg.make_report([runs / "strict", runs / "gsplat"], tmp_path / str(f), fold=f).parent for f in (0, 1)}
    a, b = _tables(out[0]), _tables(out[1])
    assert set(a) == set(b) and "profiles.csv" in a
    for name in a:
        _same_table(name, a[name], b[name])
    sa, sb = (json.loads((out[f] / "summary.json").read_text()) for f in (0, 1))
    _same_numbers(sa["numbers"], sb["numbers"], "numbers")
    _same_numbers(sa["catastrophic"], sb["catastrophic"], "catastrophic")
