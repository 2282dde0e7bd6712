"""Bit flips on the GPU-resident model, the support guard, ECC and duplication."""

import numpy as np
import pytest
from conftest import random_model

from seuwgpu.faults.codes import dup_read, ecc_read
from seuwgpu.faults.defenses import DEFENSES
from seuwgpu.faults.engine import Engine
from seuwgpu.faults.guard import GuardAlert, GuardMonitor, clamp_values, component_mask, scrub, support_box
from seuwgpu.faults.sites import uniform_upsets
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS, field_components
from seuwgpu.model.scenes import make_scene, scene_cameras
from seuwgpu.render.renderer import Renderer


@pytest.fixture(scope="module")
def engines():
    model = make_scene("spheres", n=3000, seed=5)
    cams = scene_cameras("spheres", 2, 48, 48)
    return {p: Engine(model, cams, p, scene="spheres", incremental=False) for p in encoding.PRECISIONS}


def bits_u32(x):
    return np.ascontiguousarray(x).view(np.uint32)


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_each_flip_changes_exactly_one_stored_bit_and_restores_exactly(engines, precision):
    eng = engines[precision]
    r = eng.renderer
    clean_words = [r.read_words(c).copy() for c in range(r.layout.n_chunks)]
    rng = np.random.default_rng(1)
    for field in FIELDS:
        nc = field_components(field, eng.degree)
        site = eng.site(
            field,
            int(rng.integers(eng.n)),
            int(rng.integers(nc)),
            int(rng.integers(encoding.bits_per_value(precision))),
        )
        h = eng.apply([site])
        now = [r.read_words(c) for c in range(r.layout.n_chunks)]
        diff = sum(int(np.unpackbits((a ^ b).view(np.uint8)).sum()) for a, b in zip(clean_words, now))
        assert diff == 1
        chunk, word, shift = r.layout.locate(site.primitive, site.flat_component())
        assert (now[int(chunk)][int(word)] ^ clean_words[int(chunk)][int(word)]) == 1 << (int(shift) + site.bit)
        eng.undo(h)
        assert all(np.array_equal(a, r.read_words(c)) for c, a in enumerate(clean_words))
    img = r.render_rgba()
    assert np.array_equal(bits_u32(img), bits_u32(eng.clean_rgba))


def test_out_of_range_sites_are_rejected(engines):
    eng = engines["fp32"]
    with pytest.raises(ValueError, match="bit 32 is out of range for fp32"):
        eng.site("log_scales", 0, 0, 32)
    with pytest.raises(ValueError, match="bit 16 is out of range for bf16"):
        engines["bf16"].site("opacity", 0, 0, 16)
    with pytest.raises(ValueError, match=f"primitive {eng.n} is out of range"):
        eng.site("means", eng.n, 0, 3)
    with pytest.raises(ValueError, match="unknown field"):
        eng.site("colour", 0, 0, 3)
    with pytest.raises(ValueError, match="component 4 is out of range for field quats"):
        eng.site("quats", 0, 4, 3)


def test_scale_sign_flip_is_catastrophic_and_contained_by_the_guard(engines):
    eng = engines["fp32"]
    # a representative primitive: the median-sized one among the front-most visible ones
    scales = eng.layout.decode(eng.renderer.clean_words).log_scales
    prim = int(np.argsort(scales.max(axis=1))[eng.n // 2])
    site = eng.site("log_scales", prim, int(np.argmax(scales[prim])), 31)
    none = eng.inject(site, "none")
    site2 = eng.site("log_scales", prim, int(np.argmin(scales[prim])), 31)
    both = eng.inject([site, site2], "none")
    guarded = eng.inject([site, site2], "guard")
    assert max(none["footprint"], both["footprint"]) > 0.05
    assert both["catastrophic"]
    assert guarded["footprint"] < 0.01 and not guarded["catastrophic"]
    assert guarded["clamps"] == 2


def test_guard_is_identity_on_clean_model_and_clamps_into_box(engines):
    eng = engines["bf16"]
    r = eng.renderer
    img, clamps = eng.render_current("guard")
    assert sum(clamps.values()) == 0
    assert np.array_equal(bits_u32(img), bits_u32(eng.clean_rgba))
    counts = scrub(r, eng.box, FIELDS)
    assert sum(counts.values()) == 0
    assert np.array_equal(bits_u32(r.render_rgba()), bits_u32(eng.clean_rgba))


def test_planted_values_clamp_counts_nan_inf_and_scrub_matches_in_pipeline():
    model = random_model(401, seed=9)
    cams = scene_cameras("spheres", 1, 32, 32)
    clean_r = Renderer(model, cams, "fp16")
    box = support_box(clean_r.layout.decode(clean_r.clean_words), "fp16")
    bad = model.copy()
    planted = {
        ("log_scales", 3, 0): np.inf,
        ("log_scales", 7, 2): np.nan,
        ("opacity", 11, 0): -np.inf,
        ("means", 20, 1): 1e4,
        ("sh_dc", 30, 2): -1e4,
        ("quats", 40, 3): np.nan,
        ("sh_rest", 50, 5): 1e3,
    }
    for (f, p, c), v in planted.items():
        bad.field(f)[p, c] = v
    r = Renderer(bad, cams, "fp16")
    r.set_guard(box.rows(), component_mask(FIELDS[:5], 3))
    r.reset_guard_counts()
    in_pipeline = r.render_rgba()
    counts = dict(zip(FIELDS, r.read_guard_counts()))
    assert counts == {"means": 1, "log_scales": 2, "quats": 1, "opacity": 1, "sh_dc": 1, "sh_rest": 0}
    r.set_guard(None, 0)
    scrubbed, per_prim = scrub(r, box, FIELDS[:5], per_primitive=True)
    assert scrubbed == counts
    assert per_prim[[3, 7, 11, 20, 30, 40]].tolist() == [1] * 6 and per_prim.sum() == 6
    stored = r.stored_model().flat()
    mask = component_mask(FIELDS[:5], 3)
    for c in range(stored.shape[1]):
        if (mask >> c) & 1:
            assert np.all(stored[:, c] >= box.lo[c]) and np.all(stored[:, c] <= box.hi[c])
    assert stored[7, 3 + 2] == box.lo[5]  # NaN -> lower bound
    assert stored[3, 3] == box.hi[3]  # +Inf -> upper bound
    assert stored[11, 10] == box.lo[10]  # -Inf -> lower bound
    assert stored[50, 14 + 5] == 1000.0  # sh_rest is not guarded by default
    # the repaired memory renders exactly as the in-pipeline clamp did
    assert np.array_equal(bits_u32(r.render_rgba()), bits_u32(in_pipeline))
    # numpy twin agrees on the counts
    _, twin_counts = clamp_values(encoding.quantize(bad.flat(), "fp16"), box, mask)
    assert twin_counts.tolist() == [1, 2, 1, 1, 1, 0]


def test_guard_monitor_alerts_above_threshold():
    mon = GuardMonitor(threshold=0)
    assert not mon.update({"means": 0, "opacity": 0})
    with pytest.warns(GuardAlert, match="clamped 3"):
        assert mon.update({"log_scales": 2, "opacity": 1})
    assert mon.alert and "log_scales: 2" in mon.message


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_ecc_corrects_every_single_sign_exponent_flip_and_dup_every_flip(precision):
    rng = np.random.default_rng(3)
    vals = encoding.to_bits(rng.normal(0, 3, 500).astype(np.float32), precision)
    for bit in range(encoding.bits_per_value(precision)):
        flipped = encoding.flip_bits(vals, bit, precision)
        got = ecc_read(vals, flipped, precision)
        if encoding.bit_class(precision, bit) == "mantissa":
            assert np.array_equal(got, flipped)
        else:
            assert np.array_equal(got, vals)
        assert np.array_equal(dup_read(vals, flipped), vals)


def test_defenses_on_the_gpu_model(engines, monkeypatch):
    """ECC corrects a single exponent upset and passes a mantissa one; duplication outvotes both.
    The primitive is the most harmful of a sample and the undefended render is asserted changed
    first, so every defended zero is the defense's doing (a primitive hidden from the views would
    give zeros under any defense); with the defenses' reads made pass-through, the checks fail."""
    import seuwgpu.faults.defenses as defenses_module

    eng = engines["fp32"]
    prim, _ = eng.worst_primitive("sh_dc", 1, [30], sample=64, seed=0)
    site, mant = eng.site("sh_dc", prim, 1, 30), eng.site("sh_dc", prim, 1, 22)
    recs = {d: eng.inject(site, d) for d in DEFENSES}
    assert recs["none"]["footprint"] > 0 and recs["none"]["psnr"] != np.inf  # NaN when non-finite
    assert recs["ecc"]["footprint"] == 0 and recs["ecc"]["psnr"] == np.inf
    assert recs["dup"]["footprint"] == 0 and recs["dup"]["psnr"] == np.inf
    none, ecc, dup = (eng.inject(mant, d) for d in ("none", "ecc", "dup"))
    assert none["peak_error"] > 0
    assert ecc["peak_error"] == none["peak_error"] and ecc["footprint"] == none["footprint"]
    assert dup["peak_error"] == 0
    monkeypatch.setattr(defenses_module, "ecc_read", lambda clean, stored, precision: stored)
    monkeypatch.setattr(defenses_module, "dup_read", lambda clean, stored: stored)
    assert eng.inject(site, "ecc")["footprint"] > 0 and eng.inject(site, "dup")["footprint"] > 0


def test_uniform_upsets_cover_the_whole_budget():
    model = random_model(50, seed=2)
    sites = uniform_upsets(model, "bf16", 2000, np.random.default_rng(0))
    assert len({(s.field, s.primitive, s.component, s.bit) for s in sites}) == 2000
    share = {f: sum(s.field == f for s in sites) / 2000 for f in FIELDS}
    assert abs(share["sh_rest"] - 45 / 59) < 0.05 and abs(share["opacity"] - 1 / 59) < 0.02


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
@pytest.mark.parametrize("fields, wpt", [(FIELDS[:5], 4), (("log_scales", "opacity"), 128)])
def test_clamp_bits_twin_equals_the_scrub_shader_word_for_word(precision, fields, wpt):
    """The scrub against its twin, for both thread shapes (GPU: 4 words per thread, CPU: 128)."""
    from seuwgpu.faults.guard import Scrub, clamp_bits

    model = random_model(97, seed=13)
    r = Renderer(model, scene_cameras("spheres", 1, 32, 32), precision)
    box = support_box(r.layout.decode(r.clean_words), precision)
    bits = encoding.to_bits(model.flat(), precision)
    nb = encoding.bits_per_value(precision)
    sign, top = 1 << (nb - 1), (1 << (nb - 1)) - 1  # sign bit; all exponent+mantissa ones
    snan = {16: 0x7C01 if precision == "fp16" else 0x7F81, 32: 0x7F800001}[nb]
    bits[3, 4] ^= sign  # log-scale sign flip: above the box
    bits[5, 10] = top  # opacity NaN -> lower bound
    bits[7, 20] = snan  # signalling NaN in sh_rest: not guarded
    bits[9, 0] = snan  # ... and in a mean: guarded by the full guard only
    bits[96, 4] ^= sign  # the last primitive (the low half of a 16-bit word)
    mask = component_mask(fields, 3)
    want, hit = clamp_bits(bits, box, mask)
    for c, words in enumerate(r.layout.encode_bits(bits)):
        r.gpu.write(r.chunks[c], words)
    counts = Scrub(r, words_per_thread=wpt).run(box, component_mask(fields, 3))
    got = np.concatenate([r.read_words(c) for c in range(r.layout.n_chunks)])
    assert np.array_equal(got, np.concatenate(r.layout.encode_bits(want)))
    assert hit[5, 10] and hit[96, 4] and hit[9, 0] == ("means" in fields) and not hit[7, 20]
    assert sum(counts.values()) == hit.sum()
    assert want[7, 20] == snan  # payload untouched, bit for bit
