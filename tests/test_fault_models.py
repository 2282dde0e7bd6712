"""Fault models (faults/sites.py): each changes exactly the bits it names (hand-computed patterns),
the engine writes them to the GPU-resident model and restores the words exactly, and campaigns
draw them as the spec says."""

import numpy as np
import pytest

from seuwgpu.campaign.sampling import Context, draw_sites, injection_seeds
from seuwgpu.campaign.spec import SpecError, normalize_spec
from seuwgpu.campaign.spec_hash import spec_hash
from seuwgpu.faults.engine import Engine
from seuwgpu.faults.sites import Site, corrupt_bits, fault_name, model_bits
from seuwgpu.model.scenes import make_scene, scene_cameras

ONE = 0x3F800000  # 1.0f: 0 01111111 000...


@pytest.mark.parametrize(
    "op, mask, value, want",
    [
        ("flip", 1 << 30, 0, 0x7F800000),  # exponent 127 -> 255: +Inf
        ("flip", 0b11 << 29, 0, 0x5F800000),
        ("flip", 0b111 << 28, 0, 0x4F800000),
        ("flip", 0b1111 << 27, 0, 0x47800000),
        ("stuck0", 1 << 29, 0, 0x1F800000),
        ("stuck1", 1 << 30, 0, 0x7F800000),
        ("stuck1", 1 << 29, 0, ONE),  # already 1: masked
        ("stuck0", 1 << 31, 0, ONE),
        ("set", 0xFFFFFFFF, 0, 0),
        ("set", 0xFFFFFFFF, 0x12345678, 0x12345678),
    ],
)
def test_each_operation_changes_exactly_the_named_bits(op, mask, value, want):
    got = corrupt_bits(np.array([ONE], np.uint32), [op], [mask], [value])
    assert got.dtype == np.uint32 and int(got[0]) == want
    assert (int(got[0]) ^ ONE) & ~mask == 0  # nothing outside the mask moves


def test_models_name_their_bits():
    assert model_bits("bit", 30, "fp32", 7) == ((30,), "flip", 0)
    # adjacent: width 2, 3, 4 from r % 3; the cell's bit is the burst's top bit
    assert model_bits("adjacent", 30, "fp32", 0) == ((29, 30), "flip", 0)
    assert model_bits("adjacent", 30, "fp32", 1) == ((28, 29, 30), "flip", 0)
    assert model_bits("adjacent", 15, "bf16", 5) == ((12, 13, 14, 15), "flip", 0)
    assert model_bits("adjacent", 1, "fp32", 2) == ((0, 1, 2, 3), "flip", 0)  # moved up to fit
    # a bit out of range is named as asked, not as the burst's lowest bit
    from seuwgpu.api._checks import fault_bits as _fault_bits

    with pytest.raises(ValueError, match="bit 30 is out of range for fp16"):
        _fault_bits("adjacent", 30, 3, "fp16", 0)
    assert model_bits("stuck1", 7, "fp16", 0) == ((7,), "stuck1", 0)
    assert model_bits("zero", -1, "fp16", 99) == (tuple(range(16)), "set", 0)
    assert model_bits("random", -1, "bf16", 0xDEADBEEF12345678) == (tuple(range(16)), "set", 0x5678)
    # burst: width 2..8 from r % 7, top bit the cell's
    assert model_bits("burst", 31, "fp32", 6) == (tuple(range(24, 32)), "flip", 0)
    assert model_bits("burst", 2, "bf16", 4) == (tuple(range(6)), "flip", 0)  # moved up to fit
    with pytest.raises(ValueError, match="unknown fault model 'bursts'"):
        model_bits("bursts", 3, "fp32", 0)
    names = {
        fault_name(Site("opacity", 0, 0, b, op, v), "fp32")
        for b, op, v in [((3,), "flip", 0), ((3, 4), "flip", 0), ((3, 9), "flip", 0), ((3,), "stuck0", 0)]
    }
    assert names == {"bit", "adjacent", "multi", "stuck0"}
    assert fault_name(Site("opacity", 0, 0, tuple(range(32)), "set", 0), "fp32") == "zero"


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_engine_writes_each_model_into_the_stored_word_and_restores_exactly(precision):
    model = make_scene("blocks", n=300, seed=1)
    eng = Engine(model, scene_cameras("blocks", 1, 32, 32), precision, scene="blocks")
    clean_words = [eng.renderer.read_words(c).copy() for c in range(eng.layout.n_chunks)]
    nb = 32 if precision == "fp32" else 16
    for op, bits, value in [
        ("flip", (nb - 3, nb - 2), 0),
        ("stuck0", (nb - 2,), 0),
        ("stuck1", (nb - 2,), 0),
        ("set", tuple(range(nb)), 0),
        ("set", tuple(range(nb)), 0x3C00),
    ]:
        site = eng.site("log_scales", 41, 2, bits, op, value)
        clean = eng.stored_bits([41], [site.flat_component()])
        want = corrupt_bits(clean, [op], [sum(1 << b for b in bits)], [value])
        h = eng.apply([site])
        chunk, word, shift = eng.layout.locate(41, site.flat_component())
        now = eng.renderer.read_words(int(chunk))[int(word)]
        assert (int(now) ^ int(clean_words[int(chunk)][int(word)])) == (int(want[0]) ^ int(clean[0])) << int(shift)
        assert eng.corrupted_value(site) == float(np.asarray(want).view(np.float32 if nb == 32 else np.float16)[0])
        eng.undo(h)
        for c, w in enumerate(clean_words):
            np.testing.assert_array_equal(eng.renderer.read_words(c), w)
    # two faults on one value compose in order: stuck1 then flip of the same bit = 0 there
    site1 = eng.site("opacity", 5, 0, (nb - 2,), "stuck1")
    site2 = eng.site("opacity", 5, 0, (nb - 2,), "flip")
    h = eng.apply([site1, site2])
    v = eng.stored_bits([5], [site1.flat_component()])
    chunk, word, shift = eng.layout.locate(5, site1.flat_component())
    now = (int(eng.renderer.read_words(int(chunk))[int(word)]) >> int(shift)) & ((1 << nb) - 1)
    assert now == int(v[0]) & ~(1 << (nb - 2))
    eng.undo(h)
    rec = eng.evaluate_frame([eng.site("log_scales", 3, 0, (nb - 3, nb - 2))], ("none",))
    assert rec["fault"].tolist() == ["adjacent"] and rec["bit"].tolist() == [nb - 2]


def test_campaigns_draw_the_spec_fault_model():
    base = {"scenes": [{"scene": "blocks", "n": 500}], "single": {"bits": [30, 31], "samples": 4}}
    assert spec_hash(normalize_spec(base)) == spec_hash(
        normalize_spec({**base, "single": {**base["single"], "fault": "bit"}})
    )
    spec = normalize_spec({**base, "single": {**base["single"], "fault": "adjacent"}})
    assert spec.single.fault == "adjacent"
    assert normalize_spec({**base, "single": {**base["single"], "fault": "burst"}}).single.fault == "burst"
    with pytest.raises(SpecError, match="single.fault: unknown fault model 'bursts'"):
        normalize_spec({**base, "single": {**base["single"], "fault": "bursts"}})
    with pytest.raises(SpecError, match="fault model 'mcu_prim' hits several stored values at once: a storm"):
        normalize_spec({**base, "single": {**base["single"], "fault": "mcu_prim"}})
    ctx = Context("single", 0, 500, "fp32", ["none"], 0, 8, [("opacity", 30), ("opacity", 31)], 4, fault="adjacent")
    sites, w = draw_sites(ctx, np.arange(8), injection_seeds(0, np.arange(8)), 500, 3)
    for i, s in enumerate(sites):
        top = 30 if i < 4 else 31
        assert max(s.bits) == top and len(s.bits) in (2, 3, 4) and s.op == "flip"
        assert sorted(s.bits) == list(range(top - len(s.bits) + 1, top + 1))
    np.testing.assert_allclose(w, 500 / 4)
    ctx = Context("single", 0, 500, "bf16", ["none"], 0, 4, [("opacity", -1)], 4, fault="random")
    sites, _ = draw_sites(ctx, np.arange(4), injection_seeds(0, np.arange(4)), 500, 3)
    assert all(s.op == "set" and s.bits == tuple(range(16)) for s in sites)
    assert len({s.value for s in sites}) == 4


@pytest.mark.parametrize("precision", ["fp32", "fp16", "bf16"])
@pytest.mark.parametrize("chunk_prims", [None, 128])
def test_stored_bits_are_the_models_encoded_values(precision, chunk_prims):
    """Engine.stored_bits (what every injection reads its clean pattern from) at every (primitive,
    component): the model's values encoded at the precision, whether the model is one storage
    chunk or several (half-word packing included)."""
    from seuwgpu.model import encoding

    model = make_scene("blocks", n=300, seed=3)
    eng = Engine(model, scene_cameras("blocks", 1, 32, 32), precision, chunk_prims=chunk_prims)
    assert eng.layout.n_chunks == (1 if chunk_prims is None else 3)
    nc = eng.layout.ncomp
    got = eng.stored_bits(np.repeat(np.arange(300), nc), np.tile(np.arange(nc), 300)).reshape(300, nc)
    want = encoding.to_bits(model.flat(), precision)
    assert got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)


def test_multi_cell_upsets_hit_the_neighbouring_word_or_another_value_of_the_primitive():
    from seuwgpu.faults.sites import multi_cell_sites, neighbour_primitive

    a = Site("opacity", 7, 0, (30,))
    # the device layout is planar: the next word holds primitive 8 (fp32) or 9 (two halves a word)
    assert [s.primitive for s in multi_cell_sites(a, "mcu_neighbour", 100, 3, "fp32", 0)] == [7, 8]
    assert [s.primitive for s in multi_cell_sites(a, "mcu_neighbour", 100, 3, "bf16", 0)] == [7, 9]
    assert neighbour_primitive(99, 100, "fp32") == 98 and neighbour_primitive(98, 100, "fp16") == 96
    both = multi_cell_sites(a, "mcu_prim", 100, 3, "fp32", 0)
    assert [(s.primitive, s.flat_component(), s.bits) for s in both] == [(7, 10, (30,)), (7, 11, (30,))]
    last = multi_cell_sites(Site("sh_rest", 7, 44, (3,)), "mcu_prim", 100, 3, "fp32", 57)
    assert [s.flat_component() for s in last] == [58, 57]  # wraps round the primitive's 59 values
    assert multi_cell_sites(a, "burst", 100, 3, "fp32", 0) == [a]
