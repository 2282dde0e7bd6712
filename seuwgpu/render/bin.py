"""Binning stage: shaders/bin.wgsl (and a PrefixSum) and its numpy twin.

Per view, on the GPU: `count_tiles` writes the number of tiles each screen record is paired
with, in the records' order; `gather_counts` puts the counts in depth order, PrefixSum turns
them into offsets there and the intersection total (into the `stats` slot of the view), and
`scatter_offsets` gives each record its offset back; `emit` writes one (tile id, primitive) pair
per paired tile, row-major within each rectangle, at those offsets, so the list is in depth
order; after the tile sort (render/sort.py), `tile_ranges` finds each tile's [start, end) in the
sorted list. Counting and emission walk the records in their own order because their screen
data is then read sequentially: walked in depth order they read 32 bytes a record at random,
and took 167 of a 1M-primitive view's 736 GPU ms on lavapipe, 68 now (docs/benchmarks.md).
Pairs past the intersection capacity are dropped; the renderer reads the totals back, grows the
buffers and re-runs the frame.

Exact binning (docs/renderer.md): a primitive is paired with the tiles of its rectangle that its
footprint may reach (`reach`, `row_tiles`: per tile row, the columns crossed by the ellipse where
sigma is within 5% of the opacity's cut, widened by 1/8 px), not with every tile of the
rectangle; a dropped pair is one the compositor would skip at every pixel of the tile, so the
images are the same bit for bit (tests compare `exact=False`, the whole rectangle). This removes
14-17% of the pairs of the embedded scenes at 256x256 (docs/renderer.md).

The per-view `Binning` uniform (shaders/common.wgsl) is shared with compositing.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.constants import TILE
from seuwgpu.gpu.device import GPU, STORAGE
from seuwgpu.gpu.kernel import Kernel, Uniforms
from seuwgpu.gpu.sort import PrefixSum, exclusive_scan
from seuwgpu.render.project import unpack_rects
from seuwgpu.render.stage import Output, Stage

F = np.float32
CARRIED = 2  # words of other buffers the frame's read of `stats` carries back (Renderer.carry_back)


class Binning:
    """Tile binning of `n` primitives: owns the counts and offsets, the intersection totals
    (`stats`, u32 [K + 1 + CARRIED]: view v's at v, a batched list's at K, then the words the
    renderer carries back with them, Renderer.carry_back), the per-tile `ranges` (u32
    [n_tiles, 2], K times that when batched), the intersection lists (`isect_tiles`,
    `isect_prims`, `isect_box`, `capacity` each) and the `Binning` parameters (`params`: slot v
    for view v alone, slot K for the K views in one list).

    Batched (`set_views(..., batched=True)`, render/renderer.py): the K views' screen records lie
    one after the other (view v's from v * n), sorted by depth all together; their pairs carry tile
    ids v * n_tiles + tile (bin.wgsl), so one count, scan, emit, tile sort and ranges serve all K,
    and `tile_ranges` also writes each view's total at stats[v]."""

    def __init__(self, gpu: GPU, n: int, exact: bool = True):
        self.gpu, self.n = gpu, int(n)
        self.exact = bool(exact)
        self.k_count = Kernel(gpu, "bin", "count_tiles", constants={"EXACT_BIN": int(self.exact)})
        self.k_gather = Kernel(gpu, "bin", "gather_counts")
        self.k_scatter = Kernel(gpu, "bin", "scatter_offsets")
        self.k_emit = Kernel(gpu, "bin", "emit", constants={"EXACT_BIN": int(self.exact)})
        self.k_ranges = Kernel(gpu, "bin", "tile_ranges")
        self.struct = self.k_count.struct("Binning")
        self.entries = 0
        self._set_entries(self.n)
        self.capacity = 0

    def _set_entries(self, entries: int):
        """Counts and offsets of `entries` records (n, or K n batched): `counts` in depth order
        (scanned in place into offsets), `by_record` in the records' order (a record's count, then
        its offset); and the scan."""
        if entries == self.entries:
            return
        g, self.entries = self.gpu, int(entries)
        self.scan = PrefixSum(g, self.entries)
        self.counts = g.buffer(4 * self.entries, STORAGE, "bin.counts")
        self.by_record = g.buffer(4 * self.entries, STORAGE, "bin.by_record")

    def set_views(self, k: int, n_tiles: int, batched: bool = False):
        """(Re)allocate the per-view buffers for K views of n_tiles tiles, binned one view at a time
        or, `batched`, all K in one list."""
        g = self.gpu
        self.k, self.n_tiles = int(k), int(n_tiles)
        lists = self.k if batched else 1  # views binned in one list
        self._set_entries(self.n * lists)
        self.params = Uniforms(g, self.struct, self.k + 1, "bin.params")
        self.stats = g.buffer(4 * (self.k + 1 + CARRIED), STORAGE, "bin.stats")
        self.ranges = g.buffer(8 * self.n_tiles * lists, STORAGE, "bin.ranges")

    @property
    def batch_slot(self) -> int:
        """The parameter slot (and stats word) of the K views binned in one list."""
        return self.k

    def _views_of(self, slot: int) -> int:
        return self.k if slot == self.batch_slot else 1

    def set_capacity(self, capacity: int):
        """(Re)allocate the intersection lists (the caller rewrites `params`' capacity)."""
        self.capacity = int(capacity)
        self.isect_tiles = self.gpu.buffer(4 * self.capacity, STORAGE, "bin.isect_tiles")
        self.isect_prims = self.gpu.buffer(4 * self.capacity, STORAGE, "bin.isect_prims")
        # per pair, written by compositing: the pixel box of the pair's record in its tile
        # (composite.wgsl), kept with the tile lists for the incremental re-compositor
        self.isect_box = self.gpu.buffer(4 * self.capacity, STORAGE, "bin.isect_box")

    def set_view(self, v: int, *, tiles_x: int, size: tuple[int, int], origin: tuple[int, int], background):
        """Parameters of view v: its viewport (size in pixels, tile-aligned origin) and background;
        the batched slot's follow view 0's (every view of a renderer shares them)."""
        for slot in (v, self.batch_slot) if v == 0 else (v,):
            views = self._views_of(slot)
            self.struct.fill(
                self.params.rows[slot : slot + 1],
                n_total=self.n,
                tiles_x=tiles_x,
                n_tiles=self.n_tiles,
                capacity=self.capacity,
                stats_index=slot,
                width=size[0],
                height=size[1],
                origin=origin[0] | (origin[1] << 16),
                views=views,
                frame=0 if views > 1 else v,
                background=np.append(np.asarray(background, np.float32), 0.0),
            )

    def total(self, slot: int) -> tuple:
        """Where the GPU writes the intersection total of slot `slot` (view v alone, or the
        batched list): (buffer, byte_offset)."""
        return (self.stats, 4 * slot)

    @property
    def buffers(self) -> dict:
        """The buffers it owns that bin.wgsl binds, by their names there (the pairs' pixel boxes,
        `isect_box`, are compositing's)."""
        names = ("counts", "by_record", "isect_tiles", "isect_prims", "stats", "ranges")
        return {name: getattr(self, name) for name in names}

    def encode_emit(self, encoder, slot: int, buffers: dict):
        """Counts, offsets, total and pairs of slot `slot` (view v, or the K views batched) from
        the depth order and the screen records (`buffers`: proj_rect, depth_vals, proj_xy,
        proj_conic with opacity: render/project.py); the pairs go to `buffers`' isect lists."""
        shared = {**self.buffers, **buffers, "bin": self.params.binding(slot)}
        count = self.n * self._views_of(slot)
        self.k_count.dispatch(encoder, shared, threads=count)
        self.k_gather.dispatch(encoder, shared, threads=count)
        self.scan.encode(encoder, self.counts, self.counts, count, total=self.total(slot))
        self.k_scatter.dispatch(encoder, shared, threads=count)
        self.k_emit.dispatch(encoder, shared, threads=count)

    def encode_ranges(self, encoder, slot: int, buffers: dict | None = None):
        """Per-tile ranges of slot `slot`'s tile-sorted list (and, batched, each view's total)."""
        self.k_ranges.dispatch(
            encoder,
            {**self.buffers, **(buffers or {})},
            bin=self.params.binding(slot),
            threads=self.n_tiles * self._views_of(slot),
        )


# ---- numpy twin ---------------------------------------------------------------------------------
def cut_of(o: np.ndarray) -> np.ndarray:
    """Twin of common.wgsl cut_of: the sigma beyond which alpha < 1/255 for certain."""
    o = np.asarray(o, F)
    with np.errstate(all="ignore"):
        cut = np.log(F(255) * o) + F(0.01)
    cut = np.where(o < F(0.001), -np.inf, cut)
    return np.where(~np.isfinite(o) | (np.abs(o) > F(1e30)), np.inf, cut).astype(F)


def footprint_bounded(xy: np.ndarray, co: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """Twin of common.wgsl footprint_bounded (rows of xy [M, 2], co [M, 4], cut [M])."""
    A, B, C = co[:, 0], co[:, 1], co[:, 2]
    with np.errstate(all="ignore"):
        ok = np.isfinite(A) & np.isfinite(B) & np.isfinite(C) & np.isfinite(xy).all(axis=1)
        ok &= (A >= F(1e-12)) & (C >= F(1e-12)) & (A <= F(1e6)) & (C <= F(1e6)) & (np.abs(B) <= F(1e6))
        ok &= (np.abs(xy) <= F(1e6)).all(axis=1) & (cut < F(1e30)) & (B * B <= F(0.99) * (A * C))
    return ok


REACH_NONE, REACH_ELLIPSE, REACH_ALL = 0, 1, 2


def reach(xy: np.ndarray, co: np.ndarray) -> dict:
    """Twin of common.wgsl reach, per row of xy [M, 2] and co [M, 4] (conic, opacity)."""
    xy, co = np.asarray(xy, F), np.asarray(co, F)
    cut = cut_of(co[:, 3])
    A, B, C = co[:, 0], co[:, 1], co[:, 2]
    kind = np.where(footprint_bounded(xy, co, cut), np.where(cut < 0, REACH_NONE, REACH_ELLIPSE), REACH_ALL)
    with np.errstate(all="ignore"):
        s2 = F(2) * (F(1.05) * np.maximum(cut, F(1e-3)))
        d = A * C - B * B
        ry = np.sqrt(s2 * A / d)
        k = np.sqrt(s2 / (d * C))
    return {"kind": kind, "xy": xy, "co": co, "s2": s2, "d": d, "ry": ry, "k": k}


def _edge(r: dict, uy: np.ndarray, side: float) -> np.ndarray:
    A, B = r["co"][:, 0], r["co"][:, 1]
    disc = np.maximum(r["s2"] * A - r["d"] * uy * uy, F(0))
    return (-B * uy + F(side) * np.sqrt(disc)) / A


def band_extent(r: dict, y0: np.ndarray, y1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Twin of common.wgsl band_extent, per row of `r`: the pixel-x interval [ex, ey] reached
    within the band of pixel-centre rows [y0, y1], and where the band misses the ellipse."""
    with np.errstate(all="ignore"):
        lo = np.maximum(np.asarray(y0, F) - F(0.125) - r["xy"][:, 1], -r["ry"])
        hi = np.minimum(np.asarray(y1, F) + F(0.125) - r["xy"][:, 1], r["ry"])
        B, k = r["co"][:, 1], r["k"]
        right = _edge(r, np.clip(-B * k, lo, hi), 1.0)
        left = _edge(r, np.clip(B * k, lo, hi), -1.0)
        ex, ey = r["xy"][:, 0] + left - F(0.125), r["xy"][:, 0] + right + F(0.125)
    return ex, ey, lo > hi


def row_tiles(r: dict, y: np.ndarray, fx: float, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Twin of common.wgsl row_tiles, per row of `r` (float32, the same operations): the paired
    columns [c0, c1) of the tile row whose first pixel row is y."""
    y, ts = np.asarray(y, F), F(TILE)
    ex, ey, miss = band_extent(r, y + F(0.5), y + ts - F(0.5))
    with np.errstate(all="ignore"):
        c0 = np.clip(np.ceil((ex - F(fx) - (ts - F(0.5))) / ts), x0.astype(F), x1.astype(F))
        c1 = np.clip(np.floor((ey - F(fx) - F(0.5)) / ts) + F(1), x0.astype(F), x1.astype(F))
        c1 = np.maximum(c0, c1)
        empty = (r["kind"] == REACH_NONE) | miss | (ex > ey)
    c0 = np.where(r["kind"] == REACH_ALL, x0, np.where(empty, x0, np.nan_to_num(c0).astype(np.int64)))
    c1 = np.where(r["kind"] == REACH_ALL, x1, np.where(empty, x0, np.nan_to_num(c1).astype(np.int64)))
    return c0.astype(np.int64), c1.astype(np.int64)


def emit(rects: np.ndarray, order: np.ndarray, tiles_x: int, records: dict | None = None, origin=(0, 0)) -> dict:
    """Twin of count_tiles, gather_counts, the scan, scatter_offsets and emit: rects [N, 4] (x0,
    y0, x1, y1 in tiles, exclusive max; empty when culled) visited in `order` (primitive indices
    front to back) -> counts and offsets per position in `order`, and the (tile, primitive) pairs
    `isect_tiles`, `isect_prims` in emission order (row-major within each rectangle). `records`
    ({"proj_xy" [N, 2], "proj_conic" [N, 4]: conic and opacity}) turns on exact binning (`reach`,
    `row_tiles`); without it every tile of the rectangle is paired. `origin`: the viewport's
    first pixel."""
    order = np.asarray(order, np.int64)
    r = np.asarray(rects, np.int64)[order]
    w, h = r[:, 2] - r[:, 0], r[:, 3] - r[:, 1]
    h = np.where((w > 0) & (h > 0), h, 0)
    # one entry per (primitive, tile row), in emission order
    pos = np.repeat(np.arange(len(order)), h)
    ty = r[pos, 1] + (np.arange(len(pos)) - np.repeat(np.cumsum(h) - h, h))
    c0, c1 = r[pos, 0], r[pos, 2]
    if records is not None:
        prims = order[pos]
        rr = reach(np.asarray(records["proj_xy"])[prims], np.asarray(records["proj_conic"])[prims])
        c0, c1 = row_tiles(rr, ty * TILE + origin[1], origin[0], c0, c1)
    n_row = c1 - c0
    counts = np.bincount(pos, weights=n_row, minlength=len(order)).astype(np.int64)
    offsets = exclusive_scan(counts.astype(np.uint32)).astype(np.int64)
    at = np.repeat(np.arange(len(pos)), n_row)
    tx = c0[at] + (np.arange(len(at)) - np.repeat(np.cumsum(n_row) - n_row, n_row))
    return {
        "counts": counts,
        "offsets": offsets,
        "isect_tiles": (ty[at] * int(tiles_x) + tx).astype(np.int64),
        "isect_prims": order[pos[at]],
    }


def tile_ranges(sorted_tiles: np.ndarray, n_tiles: int) -> np.ndarray:
    """Twin of tile_ranges: [n_tiles, 2] (start, end) of each tile in the tile-sorted list."""
    edges = np.searchsorted(np.asarray(sorted_tiles), np.arange(int(n_tiles) + 1), side="left")
    return np.stack([edges[:-1], edges[1:]], axis=1)


def tile_lists(
    rects: np.ndarray, order: np.ndarray, tiles_x: int, n_tiles: int, records: dict | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The whole binning twin: (ranges [n_tiles, 2], primitives of the tile-sorted list); tile t
    draws prims[ranges[t, 0]:ranges[t, 1]], front to back with ties by index. `records`: as `emit`."""
    e = emit(rects, order, tiles_x, records)
    by_tile = np.argsort(e["isect_tiles"], kind="stable")
    return tile_ranges(e["isect_tiles"][by_tile], n_tiles), e["isect_prims"][by_tile]


# ---- the stages ---------------------------------------------------------------------------------
def _encode_emit(encoder, buffers, r, slot, views):
    r.binning.encode_emit(encoder, slot, buffers)


def emit_twin(proj_rect, depth_vals, proj_xy, proj_conic, tiles_x, exact_binning) -> dict:
    """`emit` over the kernel's buffers: every record in depth order (a culled one's rectangle
    is empty)."""
    records = {"proj_xy": proj_xy, "proj_conic": proj_conic} if exact_binning else None
    e = emit(unpack_rects(proj_rect), depth_vals, tiles_x, records)
    return {"isect_tiles": e["isect_tiles"].astype(np.uint32), "isect_prims": e["isect_prims"].astype(np.uint32)}


EMIT = Stage(
    "emit",
    inputs=("proj_rect", "depth_vals", "proj_xy", "proj_conic"),
    params=("tiles_x", "exact_binning"),
    outputs=(
        # the pairs' tile keys, flipped before the tile sort
        Output("isect_tiles", 1, "pair", fault=True, former="tile_key"),
        Output("isect_prims", 1, "pair"),
    ),
    run=_encode_emit,
    twin_of=emit_twin,
    split_before=True,
)


def _encode_ranges(encoder, buffers, r, slot, views):
    r.binning.encode_ranges(encoder, slot, buffers)


def ranges_twin(isect_tiles, n_tiles) -> dict:
    return {"ranges": tile_ranges(isect_tiles, n_tiles).astype(np.uint32)}


RANGES = Stage(
    "ranges",
    inputs=("isect_tiles",),
    params=("n_tiles",),
    outputs=(Output("ranges", 2, "tile", fault=True, kept=True, former="tile_range"),),
    run=_encode_ranges,
    twin_of=ranges_twin,
    split_before=True,
)
