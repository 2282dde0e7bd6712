"""The checks inside the frame (faults/check.py FrameCheck, shaders/project.wgsl FRAME_CHECK):
parity4f (parity4r's 4 ways, a flag bit per primitive) and parity2f (2 ways grouped diagonally,
no flags; at fp16/bf16 one code a stored word pair). A flip written into the device buffer is
dropped from that very frame; the frame equals the twin's (the model with the failing primitives
culled) bit for bit; the device repair rewrites them from the golden copy and the next frame is
the clean one."""

import numpy as np
import pytest
from conftest import random_model

from seuwgpu.faults import codes
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.check import DeviceRepair, FrameCheck
from seuwgpu.model import encoding
from seuwgpu.model.fields import Model
from seuwgpu.model.scenes import scene_cameras
from seuwgpu.render.project import project
from seuwgpu.render.renderer import Renderer


def _flip(r, prim, comp, bit):
    """XOR bit `bit` of value (prim, comp) in the renderer's device buffer."""
    chunk, word, shift = r.layout.locate(np.array([prim]), np.array([comp]))
    w = r.read_words(int(chunk[0]))
    w[word] ^= np.uint32(1 << bit) << shift.astype(np.uint32)
    r.gpu.write(r.chunks[int(chunk[0])], w)


@pytest.mark.parametrize("profile", ["strict", "gsplat"])
@pytest.mark.parametrize("degree,precision", [(0, "fp32"), (1, "fp16"), (2, "bf16"), (3, "fp32")])
def test_a_clean_model_passes_the_frame_check_under_every_profile(profile, degree, precision):
    """The check folds each value as the projection reads it (project.wgsl `stored`): every path
    (both profiles, every SH degree and precision) reads each value of a drawn primitive once, so
    a clean model fails nothing and its frame is today's, for both codes."""
    model = random_model(150, degree=degree, seed=degree)
    r = Renderer(model, scene_cameras("spheres", 2, 32, 32), precision, chunk_prims=64, profile=profile)
    clean = encoding.to_bits(model.flat(), precision)
    want = r.render()
    for defense in ("parity4f", "parity2f"):
        fc = FrameCheck(r, clean, defense)
        np.testing.assert_array_equal(r.render(), want)
        assert fc.count() == 0, defense
        fc.off()


@pytest.mark.parametrize(
    "defense,precision", [("parity4f", "fp32"), ("parity4f", "bf16"), ("parity2f", "fp32"), ("parity2f", "bf16")]
)
def test_a_flip_in_the_device_buffer_is_dropped_from_the_frame(defense, precision):
    """Three upsets: the big splat's log-scales x and y (values 3, 4) at the top exponent bit (the
    same bit in two values of different index parity: parity2f's ways 0 and 1, parity4r's one way
    twice), an sh_rest sign (value 40: a single flip, seen by both), and log-scales x and z
    (values 3, 5: the same bit in values of equal index parity, unseen by both). parity2f at bf16
    codes word pairs: both primitives of a failing pair are dropped, the clean partner too."""
    model = random_model(200, seed=4)
    cams = scene_cameras("spheres", 2, 32, 32)
    r = Renderer(model, cams, precision, chunk_prims=128)
    clean = encoding.to_bits(model.flat(), precision)
    want_clean = r.render()
    fc = FrameCheck(r, clean, defense)
    np.testing.assert_array_equal(r.render(), want_clean)  # the clean model: the same frame
    assert fc.count() == 0
    nb = encoding.bits_per_value(precision)
    big = int(np.argmax(model.opacity))
    upsets = [(big, 3, nb - 2), (big, 4, nb - 2), (7, 40, nb - 1), (20, 3, nb - 2), (20, 5, nb - 2)]
    bad = clean.copy()
    for prim, comp, bit in upsets:
        bad[prim, comp] ^= bad.dtype.type(1 << bit)
        _flip(r, prim, comp, bit)
    got = r.render()
    d = dfn.get(defense)
    detected = d.hit(d.side_data(clean, precision, 3), bad, precision, 3)  # the twin's
    want = {7, big} if defense == "parity2f" else {7}
    if d.code.pairs(precision):  # a failing word pair is dropped together
        want |= {p ^ 1 for p in want}
    assert set(np.flatnonzero(detected)) == want
    if d.flags:  # checked where drawn: flagged exactly where a view would draw it
        faulted = Model.from_flat(encoding.from_bits(bad, precision), 3)
        drawn = np.logical_or.reduce([project(faulted, cam)["visible"] for cam in cams])
        np.testing.assert_array_equal(fc.flags(), detected & drawn)
        assert fc.flags().any()
    else:
        with pytest.raises(ValueError, match="keeps no flags"):
            fc.flags()
    assert fc.count() >= (2 if defense == "parity2f" else 1)  # parity2f: the sheet, in both views
    assert fc.frame_count() == fc.count()  # carried back with the frame's stats
    # the twin: the corrupted model with the detected primitives culled (one no view draws is
    # culled either way), rendered without the check
    fc.off()
    culled = codes.cull(bad, detected, precision)
    for c, words in enumerate(r.layout.encode_bits(culled)):
        r.gpu.write(r.chunks[c], words)
    np.testing.assert_array_equal(got, r.render())
    assert not np.array_equal(got, want_clean)


def test_the_detection_count_rides_on_the_frames_own_read(monkeypatch):
    """A frame checked inside the projection reads from the device as often as a plain frame
    (once: its stats), its detection count carried in that read: 0 for the clean model, and after
    an upset what a read of its own gives. Before a checked frame there is no carried count (an
    error, not a made-up 0); turned off, the frame carries nothing."""
    model = random_model(120, seed=2)
    r = Renderer(model, scene_cameras("spheres", 1, 32, 32), "fp32", chunk_prims=64)
    clean = encoding.to_bits(model.flat(), "fp32")
    reads = []
    real = r.gpu.read
    monkeypatch.setattr(r.gpu, "read", lambda *a, **k: reads.append(1) or real(*a, **k))
    r.run()
    plain = len(reads)
    fc = FrameCheck(r, clean, "parity2f")
    with pytest.raises(RuntimeError, match="no frame was rendered"):
        fc.frame_count()
    reads.clear()
    r.run()
    assert len(reads) == plain == 1 and fc.frame_count() == 0
    _flip(r, int(np.argmax(model.opacity)), 3, 30)
    r.run()
    assert fc.frame_count() == fc.count() > 0
    fc.off()
    r.run()
    assert r.carried.size == 0


def _repairing(defense, precision):
    """A 300-primitive model in chunks of 128, one 32x32 view, its clean frame, the frame check
    and the device repair."""
    model = random_model(300, seed=6)
    r = Renderer(model, scene_cameras("spheres", 1, 32, 32), precision, chunk_prims=128)
    clean = encoding.to_bits(model.flat(), precision)
    want = r.render()
    fc = FrameCheck(r, clean, defense)
    return model, r, clean, want, fc, DeviceRepair(r, clean, fc)


@pytest.mark.parametrize(
    "defense,precision", [("parity4f", "fp32"), ("parity4f", "fp16"), ("parity2f", "fp32"), ("parity2f", "fp16")]
)
def test_the_device_repairs_a_flip_and_the_next_frame_is_the_clean_one(defense, precision):
    """End to end, on the device: flips written into the model's device buffer are dropped by the
    frame's check, repaired from the golden device copy (its checksum verified), and the next
    frame equals the clean frame bit for bit. parity2f keeps no flags: its repair re-verifies
    every primitive's code (here also the same bit in values 3 and 4 of a third primitive, which
    parity4r's code cannot see); at fp16 it codes word pairs and rewrites both primitives of a
    failing word (repaired: 130, 131, 140 and its clean partner 141). A golden row that fails its
    checksum is refused: the primitive stays dropped."""
    model, r, clean, want, fc, rep = _repairing(defense, precision)
    d = dfn.get(defense)
    nb = encoding.bits_per_value(precision)
    p, q = 130, 131  # chunk 1; at fp16 the two share a word
    upsets = [(p, 4, nb - 2), (q, 11, nb - 2)]  # values 4 and 11: ways 0 and 1 of parity2f's pair code
    if defense == "parity2f":
        upsets += [(140, 3, nb - 2), (140, 4, nb - 2)]
    for prim, comp, bit in upsets:
        _flip(r, prim, comp, bit)
    dropped = r.render()
    assert fc.count() > 0 and not np.array_equal(dropped, want)
    if d.flags:
        assert set(np.flatnonzero(fc.flags())) == {p, q}
    hit = d.partners(sorted({u[0] for u in upsets}), model.n, precision)
    assert rep.run() == (len(hit), 0)
    assert len(hit) == (4 if d.code.pairs(precision) else len({u[0] for u in upsets}))
    assert fc.count() == 0 and not (dfn.get(defense).flags and fc.flags().any())
    np.testing.assert_array_equal(r.render(), want)  # the next frame: the clean one, bit for bit
    for c in range(r.layout.n_chunks):
        np.testing.assert_array_equal(r.read_words(c), r.clean_words[c])
    # a corrupted golden row is refused
    g = r.gpu.read(rep.golden[1], np.uint32)
    chunk, word, shift = r.layout.locate(np.array([p]), np.array([0]))
    g[word] ^= np.uint32(1) << shift.astype(np.uint32)
    r.gpu.write(rep.golden[1], g)
    _flip(r, p, 4, nb - 2)
    r.render()
    assert rep.run() == (0, 1)
    r.render()
    assert rep.run() == (0, 1) and fc.count() > 0  # still dropped, still refused
    if dfn.get(defense).flags:
        assert fc.flags()[p]


@pytest.mark.parametrize(
    "defense,precision", [("parity4f", "fp32"), ("parity4f", "fp16"), ("parity2f", "fp32"), ("parity2f", "fp16")]
)
def test_the_device_repair_rewrites_an_upset_code(defense, precision):
    """An upset in the code bits makes a clean primitive fail: the frame drops it, and the repair
    rewrites its code from the verified golden row (its row is clean: rewritten to itself), so
    the side data is again the clean model's packed codes, the next frame the clean frame and the
    frame after it detects nothing (no repair after every frame). A code upset of a primitive the
    row upset of another shares a code word with is repaired with it. parity2f at fp16: the codes
    are word pairs', and each failing pair is rewritten whole (4 primitives repaired)."""
    from seuwgpu.faults import side as sd

    model, r, clean, want, fc, rep = _repairing(defense, precision)
    d = dfn.get(defense)
    packed = sd.pack_side(d.side_data(clean, precision, 3), d.side_bits)
    assert packed.size == -(-d.n_codes(model.n, precision) * d.side_bits // 32)
    drawn = int(np.argmax(model.opacity))  # the big splat: drawn in the view
    span = d.code.span(precision)  # primitives a code covers
    per = 32 // d.side_bits
    code = drawn // span
    other = code + 1 if code % per != per - 1 else code - 1  # shares the code word
    bad = packed.copy()
    bad[code // per] ^= np.uint32(1) << np.uint32((code % per) * d.side_bits)  # code bit 0
    r.gpu.write(fc.side, bad)
    _flip(r, other * span, 10, encoding.bits_per_value(precision) - 2)
    assert not np.array_equal(r.render(), want) and fc.count() > 0
    if d.flags:
        assert fc.flags()[drawn]
    assert rep.run() == (2 * span, 0)
    np.testing.assert_array_equal(r.gpu.read(fc.side, np.uint32)[: packed.size], packed)
    np.testing.assert_array_equal(r.render(), want)
    assert fc.count() == 0
    r.render()
    assert fc.count() == 0


def test_a_flagless_repair_rewrites_only_what_fails_its_code():
    """parity2f's repair recomputes every primitive's code on the device: a primitive whose flip its
    code cannot see (the same bit in values 3 and 5) is left as it is, one it sees is rewritten,
    whether a view drew it or not (the repair does not know what the frame dropped)."""
    model = random_model(300, seed=6)
    r = Renderer(model, scene_cameras("spheres", 1, 32, 32), "fp32", chunk_prims=128)
    clean = encoding.to_bits(model.flat(), "fp32")
    fc = FrameCheck(r, clean, "parity2f")
    rep = DeviceRepair(r, clean, fc)
    for prim, comp, bit in [(5, 3, 30), (5, 5, 30), (250, 0, 31), (250, 1, 31)]:
        _flip(r, prim, comp, bit)
    assert rep.run() == (1, 0)  # 250 (bit 31 of values 0, 1: ways 1, 0), not 5 (way 1 twice)
    rows = clean.copy()  # what the device must hold now: 250 clean, 5 as corrupted
    rows[5, 3] ^= np.uint32(1 << 30)
    rows[5, 5] ^= np.uint32(1 << 30)
    for c, words in enumerate(r.layout.encode_bits(rows)):
        np.testing.assert_array_equal(r.read_words(c), words)


def test_the_frame_checks_device_bytes_are_their_buffers():
    """side.device_bytes counts what FrameCheck uploads: the packed codes and the output (4 header
    words, and parity4f's flag bits), in 16-byte-aligned buffers, by hand at 333 primitives; on an
    fp32 SH-0 model of 114,865 (tarot's size) parity2f's 2 bits stay within 0.5% of the model, and
    at fp16 (224 bits a primitive) its per-word code's 1 bit a primitive does too."""
    from seuwgpu.faults import side as sd

    model = random_model(333, seed=2)
    r = Renderer(model, scene_cameras("spheres", 1, 16, 16), "fp32", chunk_prims=128)
    clean = encoding.to_bits(model.flat(), "fp32")
    by_hand = {"parity4f": 176 + 64, "parity2f": 96 + 16}  # codes 42 / 21 words; header 16 + 11 flag words
    for d, want in by_hand.items():
        fc = FrameCheck(r, clean, d)
        fc.off()
        assert fc.device_bytes() == sd.device_bytes(d, "fp32", 3, 333) == want, d
    n = 114_865
    assert sd.device_bytes("parity2f", "fp32", 0, n) == 7180 * 4 + 16
    assert sd.device_overhead("parity2f", "fp32", 0, n) == pytest.approx(28_736 / (n * 14 * 4))
    assert sd.device_overhead("parity2f", "fp32", 0, n) < 0.005 < sd.device_overhead("parity4f", "fp32", 0, n)
    # fp16: 167 word pairs of 2 bits = 334 bits, 11 words (48 B aligned), and the 16-byte header
    r = Renderer(model, scene_cameras("spheres", 1, 16, 16), "fp16", chunk_prims=128)
    fc = FrameCheck(r, encoding.to_bits(model.flat(), "fp16"), "parity2f")
    fc.off()
    assert fc.device_bytes() == sd.device_bytes("parity2f", "fp16", 3, 333) == 48 + 16
    assert (
        dfn.get("parity2f").bits_per_primitive("fp16", 0) == 1
        and dfn.get("parity4f").bits_per_primitive("fp16", 0) == 4
    )
    # tarot's size at fp16 SH 0: 57,433 pairs of 2 bits, 3,590 words (14,368 B aligned) + 16
    assert sd.device_bytes("parity2f", "fp16", 0, n) == 14_368 + 16
    assert sd.device_overhead("parity2f", "fp16", 0, n) == pytest.approx(14_384 / (n * 14 * 2))
    assert sd.device_overhead("parity2f", "fp16", 0, n) < 0.005


def test_parity2f_codes_word_pairs_at_16_bits_and_primitives_at_fp32():
    """fp32: parity2f's code is the per-primitive code it always was (codes.parity_bits, counted bit
    by bit, and ParityCode without per_word agree). fp16/bf16: one code a stored word pair (2i,
    2i + 1), the bit-by-bit parity of both rows' covered bits; detect marks both of a failing pair;
    the same bit of values of one way flipped in both primitives of a pair cancels (unseen), the
    same flip in one primitive of two different pairs is seen in both."""
    d = dfn.get("parity2f")
    plain = codes.ParityCode(2, dfn.FIELDS, diagonal=1)
    for precision in ("fp32", "fp16", "bf16"):
        rows = encoding.to_bits(random_model(101, seed=9).flat(), precision)
        oracle = codes.parity_bits(rows, precision, 3, 2, dfn.FIELDS, 1)  # [M, 2], bit by bit
        per_prim = (oracle[:, 0] | oracle[:, 1] << 1).astype(np.uint32)
        np.testing.assert_array_equal(plain.side_data(rows, precision, 3), per_prim)
        side = d.side_data(rows, precision, 3)
        if precision == "fp32":
            np.testing.assert_array_equal(side, per_prim)  # unchanged
            assert d.n_codes(101, precision) == 101 and d.bits_per_primitive(precision, 3) == 2
            continue
        pairs = np.append(per_prim, 0)
        np.testing.assert_array_equal(side, pairs[0::2] ^ pairs[1::2])
        assert side.size == d.n_codes(101, precision) == 51 and d.bits_per_primitive(precision, 3) == 1
        nb = encoding.bits_per_value(precision)
        bad = rows.copy()
        for prim in (10, 11, 20):  # pair (10, 11): value 3 twice, one way: unseen; 20 alone: seen
            bad[prim, 3] ^= bad.dtype.type(1 << (nb - 2))
        hit = d.hit(side, bad, precision, 3)
        assert set(np.flatnonzero(hit)) == {20, 21}
        np.testing.assert_array_equal(hit, d.code.detect_changed(rows, bad, np.arange(101), precision, 3))
        # the twin on a subset (the engine's faulted rows): grouped by pair, the rest clean
        sub = np.array([10, 11, 20])
        np.testing.assert_array_equal(d.code.detect_changed(rows[sub], bad[sub], sub, precision, 3), [0, 0, 1])
        np.testing.assert_array_equal(d.partners(sub, 101, precision), [10, 11, 20, 21])
        np.testing.assert_array_equal(d.partners([100], 101, precision), [100])  # 101 is padding


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_parity2f_the_same_flip_in_both_primitives_of_a_word(precision):
    """The same bit of value 3 flipped in primitives 130 and 131 (one stored word at fp16): at fp32
    two codes each see it (both dropped and repaired), at fp16 one code sees it twice in one way and
    misses it (nothing dropped, nothing repaired: the device agrees with the twin)."""
    model, r, clean, want, fc, rep = _repairing("parity2f", precision)
    nb = encoding.bits_per_value(precision)
    bad = clean.copy()
    for prim in (130, 131):
        bad[prim, 3] ^= bad.dtype.type(1 << (nb - 2))
        _flip(r, prim, 3, nb - 2)
    d = dfn.get("parity2f")
    seen = precision == "fp32"
    assert d.hit(d.side_data(clean, precision, 3), bad, precision, 3)[[130, 131]].tolist() == [seen, seen]
    r.render()
    assert rep.run() == ((2, 0) if seen else (0, 0))


def test_the_engines_twin_drops_a_failing_pairs_clean_partner():
    """The engine's twin (faults/engine.py, what the storm, the visible-damage measurement and the
    viewer draw) on the faulted primitives and, for parity2f at fp16, their word partners: a single
    opacity flip of primitive 21 drops 20 and 21 from the frame (means written as the cull
    pattern), then the repair leaves both clean; at fp32 only 21 is dropped."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.faults.sites import Site

    model = random_model(100, seed=5)
    for precision, dropped in (("fp16", [20, 21]), ("fp32", [21])):
        eng = Engine(model, scene_cameras("spheres", 1, 16, 16), precision)
        site = Site("opacity", 21, 0, (encoding.bits_per_value(precision) - 2,))
        clean = eng.renderer.clean_words
        handle = eng.apply([site], "parity2f")
        rows = eng.layout.chunk_values(0, eng.renderer.read_words(0))
        assert np.isnan(rows[0]).tolist()[19:23] == [p in dropped for p in range(19, 23)], precision
        eng.undo(handle)
        handle = eng.apply([site], "parity2f", after_repair=True)  # repaired: the clean words
        np.testing.assert_array_equal(eng.renderer.read_words(0), clean[0])
        eng.undo(handle)


@pytest.mark.parametrize("precision", ["fp16", "bf16"])
def test_the_batched_evaluator_draws_parity2f_variants_as_a_full_render_does(precision):
    """A campaign's batched records under parity2f at 16 bits (faults/engine.py evaluate_frame)
    equal full renders site by site: each variant is checked alone (covered flips of one primitive
    in one batch do not cancel each other's code change), and a detected one drops its clean word
    partner too (drawn whole: pair_drop_metrics), so two primitives go missing, not one."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.model.fields import FIELDS, field_components
    from seuwgpu.model.scenes import make_scene

    eng = Engine(make_scene("spheres", n=6, seed=3), scene_cameras("spheres", 1, 16, 16), precision)
    nb = encoding.bits_per_value(precision)
    sites = [
        eng.site(f, p, c, b)
        for p in (2, 3, 5)
        for f in FIELDS
        for c in range(field_components(f, eng.degree))[:2]
        for b in (0, nb - 6, nb - 2)
    ]
    sites.append(eng.site("opacity", 2, 0, nb - 2))  # an odd count of covered flips on pair (2, 3)
    df = eng.evaluate_frame(sites, ["parity2f"])
    covered = codes.parity_cover_mask(precision)
    hit = np.array([bool((covered >> s.bits[0]) & 1) for s in sites])
    assert hit.any() and (~hit).any()
    for s, (_, rec) in zip(sites, df.iterrows()):
        full = eng.inject(s, "parity2f")
        for key in ("footprint", "peak_error", "clamps"):
            assert full[key] == rec[key], (s, key, full[key], rec[key])
    clean = eng.primitive_bits(np.array([2]))
    drops = eng.partner_drops(
        np.full(len(sites), 2),
        np.repeat(clean, len(sites), 0),
        np.array([s.flat_component() for s in sites]),
        np.array([int(clean[0, s.flat_component()]) ^ (1 << s.bits[0]) for s in sites]),
        "parity2f",
    )
    assert drops.tolist() == hit.tolist()


def test_worstcase_refuses_a_defense_that_drops_a_word_partner():
    """The incremental worst-case search draws one primitive a variant: parity2f at fp16 (a detected
    flip drops its word partner too) is refused with a one-line reason, at fp32 it runs."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.faults.worstcase import worst_case
    from seuwgpu.model.scenes import make_scene

    scene = make_scene("spheres", n=6, seed=3)
    eng = Engine(scene, scene_cameras("spheres", 1, 16, 16), "fp16")
    with pytest.raises(ValueError, match="drops its word partner"):
        worst_case(eng, "parity2f", fields=["opacity"])
    eng = Engine(scene, scene_cameras("spheres", 1, 16, 16), "fp32")
    assert worst_case(eng, "parity2f", fields=["opacity"]).evaluated > 0


def test_the_injected_model_under_parity2f_drops_the_word_partner_at_16_bits():
    """`inject`'s kept models (api injected_models) are what the renderer reads: under parity2f
    at fp16 a detected flip of primitive 21 culls 20 and 21 (the frame drops the word pair), at
    fp32 only 21; an uncovered low bit is read as flipped, nothing culled."""
    from seuwgpu.api import injected_models
    from seuwgpu.faults.engine import Engine
    from seuwgpu.faults.sites import Site

    model = random_model(100, seed=5)
    for precision, dropped in (("fp16", [20, 21]), ("fp32", [21])):
        eng = Engine(model, scene_cameras("spheres", 1, 16, 16), precision)
        nb = encoding.bits_per_value(precision)
        kept = injected_models(eng, model, Site("opacity", 21, 0, (nb - 2,)), ["parity2f"])
        culled = np.isnan(kept["parity2f"].means).any(axis=1)
        assert np.flatnonzero(culled).tolist() == dropped, precision
        assert not np.isnan(kept["faulted"].means).any()
        low = injected_models(eng, model, Site("opacity", 21, 0, (0,)), ["parity2f"])["parity2f"]
        assert not np.isnan(low.means).any() and low.opacity[21] != model.quantized(precision).opacity[21]
