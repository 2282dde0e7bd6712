"""Sorting stage: primitives by depth, then tile intersections by tile (gpu/sort.py RadixSort).

Both sorts are stable, so with the pairs emitted in depth order each tile's list ends up front to
back with ties broken by primitive index, exactly as the twin orders them. Twins: `depth_order`
(the drawn primitives, front to back) and gpu/sort.py `stable_sort` (the GPU's exact output,
culled keys 0xffffffff last).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.device import GPU
from seuwgpu.gpu.sort import RadixSort, stable_sort
from seuwgpu.render.stage import Output, Stage


def tile_key_bits(n_tiles: int) -> int:
    """Key bits of the tile sort: enough for tile ids 0 .. n_tiles - 1 (at least one)."""
    return max(1, int(n_tiles - 1).bit_length())


class Sorting:
    """The depth sort of `n` primitives (32-bit keys: the f32 bits of p.z order positive depths)
    and the tile sort of up to `capacity` intersections (`set_capacity` replaces its sorter)."""

    def __init__(self, gpu: GPU, n: int, capacity: int | None = None):
        self.gpu = gpu
        self.n = int(n)
        self.depth = RadixSort(gpu, self.n)
        self.capacity, self.tiles = 0, None
        if capacity is not None:
            self.set_capacity(capacity)

    def set_capacity(self, capacity: int):
        self.capacity = int(capacity)
        self.tiles = RadixSort(self.gpu, self.capacity)

    def set_depth_count(self, count: int):
        """Sort `count` depth keys from now on (n, or K n for a batched renderer's K views)."""
        if int(count) != self.n:
            self.n = int(count)
            self.depth = RadixSort(self.gpu, self.n)

    def encode_depth(self, encoder, keys, values):
        """Stable sort of the n (depth key, primitive) pairs, in place."""
        self.depth.encode(encoder, keys, values, self.n, key_bits=32)

    def encode_tiles(self, encoder, tiles, prims, count, n_tiles: int):
        """Stable sort of the (tile, primitive) pairs by tile, in place; `count` is the
        intersection total (a python int or (buffer, byte_offset) written on the GPU)."""
        self.tiles.encode(encoder, tiles, prims, count, key_bits=tile_key_bits(n_tiles))


# ---- numpy twin ---------------------------------------------------------------------------------
def depth_order(proj: dict) -> np.ndarray:
    """Indices of the visible primitives, front to back by depth, ties by index."""
    vis = np.nonzero(proj["visible"])[0]
    return vis[np.argsort(proj["depth"][vis], kind="stable")]


# ---- the stages ---------------------------------------------------------------------------------
def _encode_depth_sort(encoder, buffers, r, slot, views):
    r.sorting.encode_depth(encoder, buffers["depth_keys"], buffers["depth_vals"])


def depth_sort_twin(depth_keys, depth_vals) -> dict:
    keys, vals = stable_sort(depth_keys, depth_vals, 32)
    return {"depth_keys": keys, "depth_vals": np.asarray(vals, np.uint32)}


DEPTH_SORT = Stage(
    "depth_sort",
    inputs=("depth_keys", "depth_vals"),
    outputs=(Output("depth_keys", 1, "primitive"), Output("depth_vals", 1, "primitive")),
    run=_encode_depth_sort,
    twin_of=depth_sort_twin,
    split_before=True,
)


def _encode_tile_sort(encoder, buffers, r, slot, views):
    count = r.binning.total(slot)
    r.sorting.encode_tiles(encoder, buffers["isect_tiles"], buffers["isect_prims"], count, len(views) * r.n_tiles)


def tile_sort_twin(isect_tiles, isect_prims, n_tiles) -> dict:
    tiles, prims = stable_sort(isect_tiles, isect_prims, tile_key_bits(n_tiles))
    return {"isect_tiles": tiles, "isect_prims": np.asarray(prims, np.uint32)}


TILE_SORT = Stage(
    "tile_sort",
    inputs=("isect_tiles", "isect_prims"),
    params=("n_tiles",),
    outputs=(
        Output("isect_tiles", 1, "pair"),
        # the sorted lists' primitives, flipped before the ranges are found
        Output("isect_prims", 1, "pair", fault=True, kept=True, former="isect_prim"),
    ),
    run=_encode_tile_sort,
    twin_of=tile_sort_twin,
)
