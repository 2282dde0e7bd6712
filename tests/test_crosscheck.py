"""tools/crosscheck.py: the site sampler, the metrics and classes on hand-made frames, the tables;
and, where torch and gsplat are installed (tools/crosscheck_env.sh), the gsplat-side renderer."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(f"tools_{name}", ROOT / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


cc = _tool("crosscheck")


def test_sampler_covers_every_field_and_every_top_bit():
    sites = cc.sample_sites([("a", 1000, 0), ("b", 500, 3)], seed=3, top=1, mantissa=2)
    for model, fields in (("a", cc.FIELDS[:5]), ("b", cc.FIELDS)):
        s = sites[sites["model"] == model]
        assert set(s["field"]) == set(fields)  # sh_rest only where the model stores it
        for f in fields:
            bits = s[s["field"] == f]["bit"]
            assert set(cc.TOP_BITS) <= set(bits)  # sign and every exponent bit
            assert (bits < 23).sum() == 2  # mantissa bits besides
    assert (sites["primitive"] < sites["model"].map({"a": 1000, "b": 500})).all()
    assert sites[(sites["model"] == "a") & (sites["field"] == "opacity")]["component"].eq(0).all()
    assert sites[sites["field"] == "sh_rest"]["component"].max() < 45
    assert set(sites["bit_kind"]) == {"sign", "exponent", "mantissa"}
    assert sites["site_id"].is_unique
    # seeded per model name: another model added leaves these sites as they were
    again = cc.sample_sites([("c", 10, 1), ("b", 500, 3), ("a", 1000, 0)], seed=3, top=1, mantissa=2)
    pd.testing.assert_frame_equal(
        again[again["model"] != "c"].sort_values("site_id").reset_index(drop=True),
        sites.sort_values("site_id").reset_index(drop=True),
    )


def test_flip_fp32():
    assert cc.flip_fp32(1.5, 31) == -1.5
    assert cc.flip_fp32(1.0, 30) == math.inf
    assert cc.flip_fp32(2.0, 23) == 4.0
    assert cc.same_bits(cc.flip_fp32(cc.flip_fp32(0.3, 7), 7), 0.3)


def _frames(k=2, h=20, w=10):
    rng = np.random.default_rng(0)
    return rng.random((k, h, w, 3), dtype=np.float32)


def test_metrics_and_classes_on_hand_made_frames():
    clean = _frames()
    n_px = 20 * 10

    def cls(f):
        m = cc.frame_metrics(clean, f)
        return m, cc.classify(m["footprint"], m["peak_error"], m["nonfinite"], m["identical"])

    m, c = cls(clean.copy())
    assert c == "masked" and m["footprint"] == 0 and m["peak_error"] == 0
    f = clean.copy()
    f[0, 3, 4, 1] = np.nextafter(f[0, 3, 4, 1], np.float32(2))  # one ulp: changed, invisible
    m, c = cls(f)
    assert c == "tolerable" and m["footprint"] == 0 and 0 < m["peak_error"] < 1e-6
    f = clean.copy()
    f[1, 0, 0, 2] += 0.5  # one visible pixel in one of two views
    m, c = cls(f)
    assert c == "sdc" and m["footprint"] == pytest.approx(0.5 / n_px)
    f = clean.copy()
    f[0, :3, :, 0] += 0.1  # 30 of 200 pixels in view 0: 7.5% of the frame averaged over views
    m, c = cls(f)
    assert c == "catastrophic" and m["footprint"] == pytest.approx(0.075)
    f = clean.copy()
    f[0, 0, 0, 0] = np.nan
    m, c = cls(f)
    assert c == "catastrophic" and m["nonfinite"] and m["peak_error"] == math.inf
    assert m["footprint"] == pytest.approx(0.5 / n_px)
    # a clean frame's own NaN, left bit for bit as it was, is not charged to the upset
    clean2 = clean.copy()
    clean2[0, 0, 0, 0] = np.nan
    m = cc.frame_metrics(clean2, clean2.copy())
    assert m["identical"] and not m["nonfinite"] and m["footprint"] == 0
    # the change threshold is 1/255, strictly
    f = clean.copy()
    f[0, 5, 5, 0] = clean[0, 5, 5, 0] + np.float32(0.5 / 255)
    assert cls(f)[1] == "tolerable"


def test_classes_match_seuwgpu_on_the_same_numbers():
    from seuwgpu.metrics.image import outcome_class

    cases = [(0.0, 0.0, False, True), (0.0, 1e-7, False, False), (0.001, 0.2, False, False), (0.02, 0.2, False, False)]
    cases += [(0.0001, math.inf, True, False), (0.01, 0.2, False, False)]
    for foot, peak, nonfinite, identical in cases:
        assert cc.classify(foot, peak, nonfinite, identical) == outcome_class(peak, foot, nonfinite)[()]


def test_wilson_and_tables():
    df = pd.DataFrame(
        {
            "site_id": ["a", "b", "c", "d"],
            "model": ["m", "m", "n", "n"],
            "field": ["means", "opacity", "means", "opacity"],
            "bit_kind": ["sign", "exponent", "mantissa", "sign"],
            "bit": [31, 25, 3, 31],
            "clean_value": [1.0] * 4,
            "corrupted_value": [-1.0] * 4,
            "sg_class": ["masked", "sdc", "catastrophic", "tolerable"],
            "gs_class": ["masked", "sdc", "catastrophic", "masked"],
            "sg_footprint": [0.0, 0.001, 0.5, 0.0],
            "gs_footprint": [0.0, 0.001, 0.4, 0.0],
        }
    )
    a = cc.agreement(df, None)
    assert a["sites"].iloc[0] == 4 and a["same class"].iloc[0].startswith("3 (75.0%")
    assert a["footprint within 0.5%"].iloc[0].startswith("3 (75.0%")
    assert a["same class, masked = tolerable"].iloc[0].startswith("4 (100.0%")
    assert a["max |Δ footprint|"].iloc[0] == "10.000%"
    conf = cc.confusion(df)
    assert list(conf.index) == list(cc.CLASSES) == list(conf.columns)
    assert conf.loc["tolerable", "masked"] == 1 and int(conf.to_numpy().sum()) == 4
    assert list(cc.disagreements(df)["site_id"]) == ["c", "d"]
    text = cc.tables(df)
    assert "### Per field" in text and "### Disagreements (2)" in text
    assert "| all but log-scale sign flips | 4 |" in text


def test_gsplat_renderer_matches_gsplat_and_seuwgpu():
    """Needs .venv-crosscheck (torch + gsplat): the vectorised tile lists equal gsplat's own
    `_isect_tiles`; a faulted frame re-composited in part equals a whole new frame; the clean frame
    is close to seuwgpu's gsplat profile (the alpha cap set to the profile's 0.99)."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("gsplat")  # not a test extra: tools/crosscheck_env.sh installs it
    _isect_tiles = importlib.import_module("gsplat.cuda._torch_impl")._isect_tiles

    import seuwgpu as sg
    from seuwgpu.model.fields import FIELDS, Model

    torch.set_num_threads(1)
    sys.path.insert(0, str(ROOT / "tools"))
    gs = _tool("crosscheck_gsplat")
    scene = sg.load_model("leica-sofort")
    model = scene.model
    cams = sg.cameras(scene, views=1, size=(48, 32))
    fields = {f: getattr(model, f)[:1500].copy() for f in FIELDS}
    cam = cams[0]
    view = gs.GsplatView(fields, model.sh_degree, cam.viewmat, cam.K, cam.width, cam.height, cap=0.99)
    _, isect_ids, flat = _isect_tiles(view.p["means2d"][None], view.p["radii"][None], view.p["depths"][None], 16, 3, 2)
    theirs = list(zip((isect_ids >> 32).tolist(), flat.tolist()))
    mine = [(t, int(g)) for t, ids in sorted(view.lists.items()) for g in ids]
    assert sorted(mine) == sorted(theirs)  # the same intersections, in the same (tile, depth) order:
    key = gs.depth_keys(view.p["depths"]).tolist()  # gsplat's torch.sort is not stable, so equal
    assert [(t, key[g]) for t, g in mine] == [(t, key[g]) for t, g in theirs]  # depths may swap
    ref = sg.render_views(Model(**fields), cams, profile="gsplat")[0]
    assert np.abs(view.frame - ref).max() < 2e-3
    prims = np.flatnonzero((view.p["radii"] > 0).all(-1).numpy())
    p = int(prims[len(prims) // 2])
    for field, comp, bit in (("opacity", 0, 30), ("log_scales", 1, 31), ("sh_dc", 0, 29)):
        row = {k: v[p : p + 1].copy() for k, v in fields.items()}
        row[field].reshape(-1)[comp] = cc.flip_fp32(row[field].reshape(-1)[comp], bit)
        clean, bad, info = view.faulted(p, row)
        whole = {k: v.copy() for k, v in fields.items()}
        whole[field][p : p + 1] = row[field]
        again = gs.GsplatView(whole, model.sh_degree, cam.viewmat, cam.K, cam.width, cam.height, cap=0.99)
        assert np.array_equal(bad.view(np.uint32), again.frame.view(np.uint32)), field
        if info["row_exact"]:  # else the clean pixels come from the lone projection (its last bits)
            assert np.array_equal(clean.view(np.uint32), view.frame.view(np.uint32))
