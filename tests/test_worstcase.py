"""Worst-case search (faults/worstcase.py): the same maximum as an exhaustive sweep on a tiny
model, every bound above the flip's measured footprint, and fewer flips rendered."""

import numpy as np
import pytest
from conftest import random_model

from seuwgpu.faults.engine import Engine
from seuwgpu.faults.worstcase import _effective, footprint_bounds, site_space, worst_case
from seuwgpu.model.scenes import scene_cameras


@pytest.mark.parametrize("defense", ["none", "parity4"])
def test_search_equals_exhaustive_sweep(defense):
    model = random_model(10, seed=7)  # small splats: most flips cannot reach far
    eng = Engine(model, scene_cameras("spheres", 1, 64, 64), "fp32")
    fields = ("means", "log_scales", "opacity")
    prims, comps, bits = site_space(eng, fields)
    _, eff, gm = _effective(eng, prims, comps, bits, defense, clamped=False)
    full = eng.evaluator.evaluate(prims, eff, gm)["footprint"]
    bound = footprint_bounds(eng, prims, comps, bits, defense, chunk=1000)
    assert (bound >= full).all() and (bound <= 1).all()
    wc = worst_case(eng, defense, fields)
    assert wc.footprint == full.max() > 0
    assert wc.certified == wc.footprint and wc.sites == prims.size
    i = int(np.argmax(full))
    assert full[[j for j in range(prims.size) if (prims[j], comps[j], bits[j]) == (
        wc.site.primitive, wc.site.flat_component(), wc.site.bit)][0]] == full[i]  # fmt: skip
    assert wc.evaluated < prims.size  # the bounds spared most renders
    cut = worst_case(eng, defense, fields, max_evaluations=1)
    assert cut.evaluated <= 1 and cut.certified >= wc.footprint >= cut.footprint


def test_guarded_worst_case_record_is_the_injection_of_its_site():
    """Under the guard the search's record equals a full injection of the flip it found, clamp
    count included (the guard clamps once, in the pipeline, and is counted there)."""
    model = random_model(10, seed=7)
    eng = Engine(model, scene_cameras("spheres", 1, 64, 64), "fp32")
    wc = worst_case(eng, "guard", ("log_scales",), bits=[30, 31])
    rec = eng.inject(wc.site, "guard")
    assert wc.record["footprint"] == rec["footprint"] > 0
    assert wc.record["clamps"] == rec["clamps"] >= 1


def test_worstcase_command(capsys):
    from seuwgpu.apps.cli import main

    args = ["worstcase", "--scene", "blocks", "--n", "40", "--size", "32x32", "--views", "1", "--fields", "opacity"]
    assert main([*args, "--bit", "30", "31", "--defense", "none", "checksum"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("none: worst flip opacity[") and "of 80 flips rendered" in out[0]
    assert out[1].startswith("checksum: worst flip ") and "footprint 0.0000% (certified bound 0.0000%)" in out[1]


@pytest.mark.parametrize("precision, bit", [("fp32", 32), ("fp16", 16), ("fp32", -1)])
def test_worstcase_refuses_bits_outside_the_value(precision, bit, capsys):
    """`--bit 32` at fp32 (or 16 at fp16) searched a flip of no bit and printed 'worst flip ...
    bit 32: footprint 0.0000%' with exit status 0."""
    from types import SimpleNamespace

    from seuwgpu.apps.cli import main

    with pytest.raises(ValueError, match=f"bit {bit} is out of range for {precision}"):
        site_space(SimpleNamespace(precision=precision, n=3, degree=0), ["opacity"], [bit])
    if bit < 0:
        return
    args = ["worstcase", "--scene", "blocks", "--n", "20", "--size", "16x16", "--views", "1", "--fields", "opacity"]
    assert main([*args, "--precision", precision, "--bit", str(bit)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    why = f"bit {bit} is out of range for {precision} (valid bits are 0..{bit - 1})"  # encoding.check_bit's
    assert err[-1] == f"seuwgpu worstcase: error: {why}"
