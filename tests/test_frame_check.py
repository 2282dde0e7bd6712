"""The checks inside the frame (faults/check.py FrameCheck, shaders/project.wgsl FRAME_CHECK):
parity4f (parity4r's 4 ways, a flag bit per primitive) and parity2f (2 ways grouped diagonally,
no flags). A flip written into the device buffer is dropped from that very frame; the frame
equals the twin's (the model with the failing primitives culled) bit for bit; the device repair
rewrites them from the golden copy and the next frame is the clean one."""

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


@pytest.mark.parametrize(
    "defense,precision", [("parity4f", "fp32"), ("parity4f", "bf16"), ("parity2f", "fp32"), ("parity2f", "bf16")]
)
def test_a_flip_in_the_device_buffer_is_dropped_from_the_frame(defense, precision):
    """Three upsets: the big splat's log-scales x and y (values 3, 4) at the top exponent bit (the
    same bit in two values of different index parity: parity2f's ways 0 and 1, parity4r's one way
    twice), an sh_rest sign (value 40: a single flip, seen by both), and log-scales x and z
    (values 3, 5: the same bit in values of equal index parity, unseen by both)."""
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
    assert set(np.flatnonzero(detected)) == ({7, big} if defense == "parity2f" else {7})
    if d.flags:  # checked where drawn: flagged exactly where a view would draw it
        faulted = Model.from_flat(encoding.from_bits(bad, precision), 3)
        drawn = np.logical_or.reduce([project(faulted, cam)["visible"] for cam in cams])
        np.testing.assert_array_equal(fc.flags(), detected & drawn)
        assert fc.flags().any()
    else:
        with pytest.raises(ValueError, match="keeps no flags"):
            fc.flags()
    assert fc.count() >= (2 if defense == "parity2f" else 1)  # parity2f: the sheet, in both views
    # the twin: the corrupted model with the detected primitives culled (one no view draws is
    # culled either way), rendered without the check
    fc.off()
    culled = codes.cull(bad, detected, precision)
    for c, words in enumerate(r.layout.encode_bits(culled)):
        r.gpu.write(r.chunks[c], words)
    np.testing.assert_array_equal(got, r.render())
    assert not np.array_equal(got, want_clean)


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
    parity4r's code cannot see). A golden row that fails its checksum is refused: the primitive
    stays dropped."""
    model, r, clean, want, fc, rep = _repairing(defense, precision)
    nb = encoding.bits_per_value(precision)
    p, q = 130, 131  # chunk 1; at fp16 the two share a word
    upsets = [(p, 4, nb - 2), (q, 10, nb - 2)]
    if defense == "parity2f":
        upsets += [(140, 3, nb - 2), (140, 4, nb - 2)]
    for prim, comp, bit in upsets:
        _flip(r, prim, comp, bit)
    dropped = r.render()
    assert fc.count() > 0 and not np.array_equal(dropped, want)
    if dfn.get(defense).flags:
        assert set(np.flatnonzero(fc.flags())) == {p, q}
    assert rep.run() == (len({u[0] for u in upsets}), 0)
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
    row upset of another shares a code word with is repaired with it."""
    from seuwgpu.faults import side as sd

    model, r, clean, want, fc, rep = _repairing(defense, precision)
    d = dfn.get(defense)
    packed = sd.pack_side(d.side_data(clean, precision, 3), d.side_bits)
    drawn = int(np.argmax(model.opacity))  # the big splat: drawn in the view
    per = 32 // d.side_bits
    neighbour = drawn + 1 if drawn % per != per - 1 else drawn - 1  # shares the code word
    bad = packed.copy()
    bad[drawn // per] ^= np.uint32(1) << np.uint32((drawn % per) * d.side_bits)  # code bit 0
    r.gpu.write(fc.side, bad)
    _flip(r, neighbour, 10, encoding.bits_per_value(precision) - 2)
    assert not np.array_equal(r.render(), want) and fc.count() > 0
    if d.flags:
        assert fc.flags()[drawn]
    assert rep.run() == (2, 0)
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
    fp32 SH-0 model of 114,865 (tarot's size) parity2f's 2 bits stay within 0.5% of the model."""
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


def test_a_parity_code_folds_by_rotation_class_so_its_diagonal_is_0_or_1():
    """The shaders XOR each rotation class's words before one fold (codes.wgsl parity_classes);
    a diagonal they cannot fold that way is refused where the code is made."""
    with pytest.raises(ValueError, match="diagonal is 0 or 1"):
        codes.ParityCode(4, dfn.FIELDS, diagonal=2)
