"""Sorting stage: primitives by depth, then tile intersections by tile (gpu/sort.py RadixSort).

Both sorts are stable, so with the pairs emitted in depth order each tile's list ends up front to
back with ties broken by primitive index, exactly as the twin orders them. Twins: `depth_order`
(the drawn primitives, front to back) and gpu/sort.py `stable_sort` (the GPU's exact output,
culled keys 0xffffffff last).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.device import GPU
from seuwgpu.gpu.sort import RadixSort


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
