"""Incremental (dirty-tile) evaluation equals full re-rendering, bit for bit."""

import numpy as np
import pytest

from seuwgpu import formats
from seuwgpu.engine import Engine
from seuwgpu.faults import DEFENSES
from seuwgpu.model import FIELDS, field_components
from seuwgpu.scenes import make_scene, scene_cameras

METRICS = ("footprint", "footprint_max", "peak_error", "psnr", "ssim", "nonfinite", "clamps")


def sample_sites(engine, rng, per_class=4):
    """Sites covering every field and every bit class, plus scale sign flips (frame-covering)."""
    sites = []
    for field in FIELDS:
        nc = field_components(field, engine.degree)
        for cls in ("sign", "exponent", "mantissa"):
            bits = formats.bits_of_class(engine.precision, cls)
            for _ in range(per_class):
                sites.append(engine.site(field, int(rng.integers(engine.n)), int(rng.integers(nc)),
                                         int(rng.choice(bits))))
    sign = formats.bits_of_class(engine.precision, "sign")[0]
    top_exp = formats.bits_of_class(engine.precision, "exponent")[-1]
    for p in rng.choice(engine.n, 6, replace=False):
        sites.append(engine.site("log_scales", int(p), int(rng.integers(3)), sign))
        sites.append(engine.site("log_scales", int(p), int(rng.integers(3)), top_exp))
    return sites


def same(a, b):
    if isinstance(a, float) and np.isnan(a):
        return isinstance(b, float) and np.isnan(b)
    return a == b


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_incremental_equals_full_rerender(precision):
    model = make_scene("blocks", n=2500, seed=2)
    eng = Engine(model, scene_cameras("blocks", 2, 48, 40), precision, scene="blocks")
    rng = np.random.default_rng(11)
    sites = sample_sites(eng, rng)
    defenses = ("none", "guard", "ecc")
    inc = eng.evaluate(sites, defenses)
    assert len(inc) == len(sites) * len(defenses)
    catastrophic = 0
    for rec in inc:
        site = eng.site(rec["field"], rec["primitive"], rec["component"], rec["bit"])
        full = eng.inject(site, rec["defense"])
        for key in METRICS:
            assert same(rec[key], full[key]), (rec, key, full[key])
        catastrophic += rec["catastrophic"]
    assert catastrophic > 0, "the sample should hold frame-covering flips"


def test_defense_arms_are_paired_and_correct():
    model = make_scene("spheres", n=2000, seed=3)
    eng = Engine(model, scene_cameras("spheres", 2, 40, 40), "fp32")
    site = eng.site("log_scales", 10, 0, 31)
    recs = eng.evaluate([site], DEFENSES)
    by = {r["defense"]: r for r in recs}
    assert set(by) == set(DEFENSES)
    assert all(r["primitive"] == 10 and r["bit"] == 31 for r in recs)
    assert by["ecc"]["footprint"] == 0 and by["dup"]["footprint"] == 0
    assert by["ecc"]["psnr"] == np.inf
    assert by["guard"]["clamps"] == 1 and by["none"]["clamps"] == 0
