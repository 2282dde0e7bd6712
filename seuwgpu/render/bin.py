"""Binning stage: shaders/bin.wgsl (and a PrefixSum) and its numpy twin.

Per view, on the GPU: `count_tiles` writes the number of tiles each primitive's rectangle covers,
in depth order; PrefixSum turns the counts into offsets and the intersection total (into the
`stats` slot of the view); `emit` writes one (tile id, primitive) pair per covered tile, row-major
within each rectangle, at those offsets; after the tile sort (render/sort.py), `tile_ranges`
finds each tile's [start, end) in the sorted list. Pairs past the intersection capacity are
dropped; the renderer reads the totals back, grows the buffers and re-runs the frame.

The per-view `Binning` uniform (shaders/common.wgsl) is shared with compositing.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.device import GPU, STORAGE
from seuwgpu.gpu.kernel import Kernel, Uniforms
from seuwgpu.gpu.sort import PrefixSum, exclusive_scan


class Binning:
    """Tile binning of `n` primitives: owns the counts and offsets, the per-view intersection
    totals (`stats`, u32 [K]), the per-tile `ranges` (u32 [n_tiles, 2]), the intersection lists
    (`isect_tiles`, `isect_prims`, `isect_box`, `capacity` each) and the `Binning` parameters (`params`, one
    slot per view)."""

    def __init__(self, gpu: GPU, n: int):
        self.gpu, self.n = gpu, int(n)
        self.k_count = Kernel(gpu, "bin", "count_tiles")
        self.k_emit = Kernel(gpu, "bin", "emit")
        self.k_ranges = Kernel(gpu, "bin", "tile_ranges")
        self.scan = PrefixSum(gpu, self.n)
        self.counts = gpu.buffer(4 * self.n, STORAGE, "bin.counts")
        self.offsets = gpu.buffer(4 * self.n, STORAGE, "bin.offsets")
        self.struct = self.k_count.struct("Binning")
        self.capacity = 0

    def set_views(self, k: int, n_tiles: int):
        """(Re)allocate the per-view buffers for K views of n_tiles tiles."""
        g = self.gpu
        self.k, self.n_tiles = int(k), int(n_tiles)
        self.params = Uniforms(g, self.struct, self.k, "bin.params")
        self.stats = g.buffer(4 * self.k, STORAGE, "bin.stats")
        self.ranges = g.buffer(8 * self.n_tiles, STORAGE, "bin.ranges")

    def set_capacity(self, capacity: int):
        """(Re)allocate the intersection lists (the caller rewrites `params`' capacity)."""
        self.capacity = int(capacity)
        self.isect_tiles = self.gpu.buffer(4 * self.capacity, STORAGE, "bin.isect_tiles")
        self.isect_prims = self.gpu.buffer(4 * self.capacity, STORAGE, "bin.isect_prims")
        # per pair, written by compositing: the pixel box of the pair's record in its tile
        # (composite.wgsl), kept with the tile lists for the incremental re-compositor
        self.isect_box = self.gpu.buffer(4 * self.capacity, STORAGE, "bin.isect_box")

    def set_view(self, v: int, *, tiles_x: int, size: tuple[int, int], origin: tuple[int, int], background):
        """Parameters of view v: its viewport (size in pixels, tile-aligned origin) and background."""
        self.struct.fill(
            self.params.rows[v : v + 1],
            n_total=self.n,
            tiles_x=tiles_x,
            n_tiles=self.n_tiles,
            capacity=self.capacity,
            stats_index=v,
            width=size[0],
            height=size[1],
            origin=origin[0] | (origin[1] << 16),
            background=np.append(np.asarray(background, np.float32), 0.0),
        )

    def total(self, v: int) -> tuple:
        """Where the GPU writes view v's intersection total: (buffer, byte_offset)."""
        return (self.stats, 4 * v)

    def encode_emit(self, encoder, v: int, rects, sorted_prims):
        """Counts, offsets, total and pairs of view v from the packed rectangles and the depth order."""
        u = self.params.binding(v)
        self.k_count.dispatch(encoder, {0: u, 1: rects, 2: sorted_prims, 3: self.counts}, threads=self.n)
        self.scan.encode(encoder, self.counts, self.offsets, self.n, total=self.total(v))
        self.k_emit.dispatch(
            encoder,
            {0: u, 1: rects, 2: sorted_prims, 4: self.offsets, 5: self.isect_tiles, 6: self.isect_prims},
            threads=self.n,
        )

    def encode_ranges(self, encoder, v: int):
        """Per-tile ranges of view v's tile-sorted list."""
        self.k_ranges.dispatch(
            encoder,
            {0: self.params.binding(v), 5: self.isect_tiles, 7: self.stats, 8: self.ranges},
            threads=self.n_tiles,
        )


# ---- numpy twin ---------------------------------------------------------------------------------
def emit(rects: np.ndarray, order: np.ndarray, tiles_x: int) -> dict:
    """Twin of count_tiles + scan + emit: rects [N, 4] (x0, y0, x1, y1 in tiles, exclusive max;
    empty when culled) visited in `order` (primitive indices front to back) -> counts and offsets
    per position in `order`, and the (tile, primitive) pairs `isect_tiles`, `isect_prims` in
    emission order (row-major within each rectangle)."""
    order = np.asarray(order, np.int64)
    r = np.asarray(rects, np.int64)[order]
    w, h = r[:, 2] - r[:, 0], r[:, 3] - r[:, 1]
    counts = np.where((w > 0) & (h > 0), w * h, 0)
    offsets = exclusive_scan(counts.astype(np.uint32)).astype(np.int64)
    total = int(counts.sum())
    local = np.arange(total) - np.repeat(offsets, counts)
    wr = np.repeat(np.maximum(w, 1), counts)
    ty = np.repeat(r[:, 1], counts) + local // wr
    tx = np.repeat(r[:, 0], counts) + local % wr
    return {
        "counts": counts,
        "offsets": offsets,
        "isect_tiles": (ty * int(tiles_x) + tx).astype(np.int64),
        "isect_prims": np.repeat(order, counts),
    }


def tile_ranges(sorted_tiles: np.ndarray, n_tiles: int) -> np.ndarray:
    """Twin of tile_ranges: [n_tiles, 2] (start, end) of each tile in the tile-sorted list."""
    edges = np.searchsorted(np.asarray(sorted_tiles), np.arange(int(n_tiles) + 1), side="left")
    return np.stack([edges[:-1], edges[1:]], axis=1)


def tile_lists(rects: np.ndarray, order: np.ndarray, tiles_x: int, n_tiles: int) -> tuple[np.ndarray, np.ndarray]:
    """The whole binning twin: (ranges [n_tiles, 2], primitives of the tile-sorted list); tile t
    draws prims[ranges[t, 0]:ranges[t, 1]], front to back with ties by index."""
    e = emit(rects, order, tiles_x)
    by_tile = np.argsort(e["isect_tiles"], kind="stable")
    return tile_ranges(e["isect_tiles"][by_tile], n_tiles), e["isect_prims"][by_tile]
