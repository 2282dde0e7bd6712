"""Sorting stage (render/sort.py): the depth sort on the GPU against stable argsort, exactly, on
keys with ties and culled primitives (the tile sort on real pairs: tests/test_stages.py)."""

import numpy as np
from conftest import random_model

from seuwgpu.gpu.sort import stable_sort
from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.render.project import depth_keys, project
from seuwgpu.render.sort import Sorting, depth_order, tile_key_bits


def test_depth_sort_matches_stable_argsort(gpu):
    n = 3000
    model = random_model(n, seed=7)
    model.means[100:120] = model.means[100]  # equal depths: ties keep primitive order
    model.means[200:230, 2] = -50.0  # behind the camera: culled
    cam = orbit_cameras(2, 64, 48)[0]
    with np.errstate(all="ignore"):
        proj = project(model, cam)
    keys = depth_keys(proj)
    assert (keys == 0xFFFFFFFF).sum() >= 30 and len(np.unique(keys)) < n - 20
    stage = Sorting(gpu, n)
    kb, vb = gpu.upload(keys), gpu.upload(np.arange(n, dtype=np.uint32))
    enc = gpu.device.create_command_encoder()
    stage.encode_depth(enc, kb, vb)
    gpu.submit(enc)
    want_keys, want_vals = stable_sort(keys, np.arange(n))
    np.testing.assert_array_equal(gpu.read(vb)[:n], want_vals)
    np.testing.assert_array_equal(gpu.read(kb)[:n], want_keys)
    # the drawn primitives lead, in the twin's depth order
    drawn = proj["visible"].sum()
    np.testing.assert_array_equal(gpu.read(vb)[:drawn], depth_order(proj))


def test_tile_keys_take_the_bits_of_the_tile_count():
    """The tile sort on the GPU against its twin is tests/test_stages.py's; its key width here."""
    assert tile_key_bits(80) == 7 and tile_key_bits(64) == 6 and tile_key_bits(1) == 1
