"""The check inside the frame (faults/check.py FrameCheck, shaders/project.wgsl FRAME_CHECK): a
flip written into the device buffer is dropped from that very frame and flagged; the frame equals
the twin's (the model with that primitive culled) bit for bit; a clean frame is unchanged."""

import numpy as np
import pytest
from conftest import random_model

from seuwgpu.faults import codes
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.check import FrameCheck
from seuwgpu.model import encoding
from seuwgpu.model.scenes import scene_cameras
from seuwgpu.render.renderer import Renderer


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_a_flip_in_the_device_buffer_is_dropped_from_the_frame_and_flagged(precision):
    model = random_model(200, seed=4)
    cams = scene_cameras("spheres", 2, 32, 32)
    r = Renderer(model, cams, precision, chunk_prims=128)
    clean = encoding.to_bits(model.flat(), precision)
    want_clean = r.render()
    fc = FrameCheck(r, clean)
    np.testing.assert_array_equal(r.render(), want_clean)  # the clean model: the same frame
    assert fc.count() == 0
    nb = encoding.bits_per_value(precision)
    big = int(np.argmax(model.opacity))
    bad = clean.copy()
    bad[big, 3] ^= bad.dtype.type(1 << (nb - 2))  # a log-scale exponent: a frame-covering sheet
    bad[7, 40] ^= bad.dtype.type(1 << (nb - 1))  # an sh_rest sign: parity4r covers every value
    for c, words in enumerate(r.layout.encode_bits(bad)):
        r.gpu.write(r.chunks[c], words)
    got = r.render()
    flagged = fc.flags()
    side = dfn.side_data("parity4r", clean, precision, 3)
    detected = dfn.detect("parity4r", side, bad, precision, 3)
    assert set(np.flatnonzero(detected)) == {7, big}
    # checked where drawn: a primitive is flagged in the views that would draw it (the sheet in both)
    assert flagged[big] and not (flagged & ~detected).any() and fc.count() >= 2
    # the twin: the corrupted model with the detected primitives culled (one no view draws is
    # culled either way), rendered without the check
    fc.off()
    culled = codes.cull(bad, detected, precision)
    for c, words in enumerate(r.layout.encode_bits(culled)):
        r.gpu.write(r.chunks[c], words)
    np.testing.assert_array_equal(got, r.render())
    assert not np.array_equal(got, want_clean)  # two splats are missing, not drawn corrupted


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_the_device_repairs_a_flip_and_the_next_frame_is_the_clean_one(precision):
    """End to end, on the device: a flip written into the model's device buffer is dropped and
    flagged by the frame's check, repaired from the golden device copy (its checksum verified),
    and the next frame equals the clean frame bit for bit. A golden row that fails its checksum
    is refused: the primitive stays flagged and dropped."""
    from seuwgpu.faults.check import DeviceRepair

    model = random_model(300, seed=6)
    r = Renderer(model, scene_cameras("spheres", 1, 32, 32), precision, chunk_prims=128)
    clean = encoding.to_bits(model.flat(), precision)
    want = r.render()
    fc = FrameCheck(r, clean)
    rep = DeviceRepair(r, clean, fc)
    nb = encoding.bits_per_value(precision)
    p, q = 130, 131  # chunk 1; at fp16 the two share a word
    for prim, comp in ((p, 4), (q, 10)):
        chunk, word, shift = r.layout.locate(np.array([prim]), np.array([comp]))
        w = r.read_words(int(chunk[0]))
        w[word] ^= np.uint32(1 << (nb - 2)) << shift.astype(np.uint32)
        r.gpu.write(r.chunks[int(chunk[0])], w)
    dropped = r.render()
    assert set(np.flatnonzero(fc.flags())) == {p, q} and not np.array_equal(dropped, want)
    assert rep.run() == (2, 0)
    assert not fc.flags().any() and fc.count() == 0
    np.testing.assert_array_equal(r.render(), want)  # the next frame: the clean one, bit for bit
    for c in range(r.layout.n_chunks):
        np.testing.assert_array_equal(r.read_words(c), r.clean_words[c])
    # a corrupted golden row is refused
    g = r.gpu.read(rep.golden[1], np.uint32)
    chunk, word, shift = r.layout.locate(np.array([p]), np.array([0]))
    g[word] ^= np.uint32(1) << shift.astype(np.uint32)
    r.gpu.write(rep.golden[1], g)
    w = r.read_words(1)
    chunk, word, shift = r.layout.locate(np.array([p]), np.array([4]))
    w[word] ^= np.uint32(1 << (nb - 2)) << shift.astype(np.uint32)
    r.gpu.write(r.chunks[1], w)
    r.render()
    assert rep.run() == (0, 1) and fc.flags()[p]
    r.render()
    assert rep.run() == (0, 1) and fc.flags()[p] and fc.count() > 0  # still dropped, still refused
