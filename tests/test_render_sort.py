"""Sorting stage (render/sort.py): the depth sort and the tile sort on the GPU against stable
argsort, exactly, on the same keys."""

import numpy as np
from conftest import random_model

from seuwgpu.gpu.sort import stable_sort
from seuwgpu.model.cameras import orbit_cameras
from seuwgpu.render.bin import emit
from seuwgpu.render.project import depth_keys, n_tiles_xy, project
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


def test_tile_sort_matches_stable_argsort(gpu):
    n = 1200
    model = random_model(n, seed=8)
    cam = orbit_cameras(2, 80, 48)[1]
    tx, ty = n_tiles_xy(cam)
    with np.errstate(all="ignore"):
        proj = project(model, cam)
    e = emit(proj["rect"], depth_order(proj), tx)
    tiles, prims = e["isect_tiles"].astype(np.uint32), e["isect_prims"].astype(np.uint32)
    total = len(tiles)
    stage = Sorting(gpu, n, capacity=total + 100)
    tb, pb = gpu.upload(tiles), gpu.upload(prims)
    count = gpu.upload(np.array([total], np.uint32))  # the total as the GPU's scan leaves it
    enc = gpu.device.create_command_encoder()
    stage.encode_tiles(enc, tb, pb, (count, 0), tx * ty)
    gpu.submit(enc)
    assert tile_key_bits(tx * ty) == int(tx * ty - 1).bit_length() and tile_key_bits(1) == 1
    want_tiles, want_prims = stable_sort(tiles, prims, tile_key_bits(tx * ty))
    np.testing.assert_array_equal(gpu.read(tb)[:total], want_tiles)
    np.testing.assert_array_equal(gpu.read(pb)[:total], want_prims)
