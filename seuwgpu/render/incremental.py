"""Incremental re-compositing of single-primitive variants: redraw only the tiles a change reaches.

A single upset alters one primitive. Its clean and corrupted tile rectangles, per view, bound the
pixels that can change; everything else of the frame is the clean render, bit for bit. For a batch
of B variants (each: one primitive replaced by new stored bits) the compositor
1. projects each variant's new primitive for all K views with the renderer's own project shader
   (a tiny "model" of B primitives);
2. lists the dirty tiles (clean rect union new rect) per (variant, view) on the host;
3. re-composites those tiles with `variants.wgsl:variants` (render/variants.py
   VariantCompositing: the clean tile list with the primitive removed and its new record merged
   in at its depth) into TILE x TILE slabs, from the clean frame's checkpoints (CleanViews) to
   where the changed pixels end, so an upset costs its footprint rather than the lists' length.
The caller reduces metrics over the slabs (faults/incremental.py). Slabs equal the tiles of a full
re-render of the variant bit for bit (tests/test_incremental.py, tests/test_variants.py check it).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.constants import TILE
from seuwgpu.gpu.device import STORAGE, Readback
from seuwgpu.model.fields import StoredLayout
from seuwgpu.render.composite import SLAB_BYTES
from seuwgpu.render.project import Projection, unpack_rects
from seuwgpu.render.regions import region_edges
from seuwgpu.render.variants import CHECKPOINT_EVERY, VariantCompositing, checkpoint_every


class CleanViews:
    """A keep_views renderer's clean per-view state that every compositor re-compositing against
    it shares (faults/incremental.py: one per batch in flight), renewed once per set of kept
    buffers (the renderer's `version`): the tile rectangles (host, packed as the GPU holds them,
    [K, N, 2] u32: 32 MB at 1M primitives and K = 4, where unpacked to [K, N, 4] int64 they took
    128 MB; `rects_of` unpacks the few a batch needs), the longest clean tile list, and the
    checkpoints. The checkpoint pass (variants.wgsl:checkpoints, one frame's worth of
    compositing) keeps each pixel's state every `every` positions of every longer tile list and
    each pixel's end (the last position its value depends on) in the renderer's kv_stop_pos, so a
    variant's walk starts at most `every` positions before its change and stops where its pixels
    end: an upset costs its footprint, not the length of the lists (docs/renderer.md)."""

    def __init__(self, renderer, every: int | None = None):
        if not renderer.keep_views:
            raise ValueError("the renderer must keep its per-view state (keep_views=True)")
        self.r, self.version = renderer, None
        self.want_every = CHECKPOINT_EVERY if every is None else int(every)
        self.ckpt_states = self.chunk_states = None
        self.pass_ = None
        self.ensure_current()

    def rects_of(self, prims) -> np.ndarray:
        """[K, m, 4] clean tile rectangles (x0, y0, x1, y1) of primitives `prims`."""
        return unpack_rects(self.rect_words[:, prims])

    def ensure_current(self):
        r, g = self.r, self.r.gpu
        if self.version == r.version:
            return
        rects = g.read(r.kv_proj_rect, np.uint32, 0, 8 * r.kv_stride * r.k).reshape(r.k, r.kv_stride, 2)
        self.rect_words = rects[:, : r.n]
        ranges = g.read(r.kv_ranges, np.uint32, 0, 8 * r.n_tiles * r.k).reshape(-1, 2).astype(np.int64)
        lengths = ranges[:, 1] - ranges[:, 0]
        self.longest_list = int(lengths.max(initial=0))  # chunk dispatches
        self._checkpoint(lengths)
        self.version = r.version

    def _checkpoint(self, lengths: np.ndarray):
        """Lay out the checkpoints of the clean lists (`lengths` per view and tile) and run the pass."""
        r, g = self.r, self.r.gpu
        chunk = r.compositing.chunk
        every = checkpoint_every(chunk, self.want_every)
        while True:  # the states in one binding: sparser checkpoints on huge frames
            counts = np.where(lengths > 0, (lengths - 1) // every, 0)
            if int(counts.sum()) * SLAB_BYTES <= g.max_binding or every == chunk:
                break
            every = checkpoint_every(chunk, 2 * every)
        self.every = every
        self.slots = int(counts.sum())
        self.ckpt_base, self.ckpt_states = self._slots(counts, "ckpt", self.ckpt_states)
        # each later chunk's own result, for the lists of several chunks
        self.chunk_base, self.chunk_states = self._slots(
            np.maximum(-(-lengths // chunk) - 1, 0), "chunk", self.chunk_states
        )
        listed = np.flatnonzero(lengths > 0)  # every listed tile: its pixels' ends
        if not listed.size:
            return
        if self.pass_ is None:
            self.pass_ = VariantCompositing(g, 2048, r.profile, chunk, r.binning.exact)
        view, tile = np.divmod(listed, r.n_tiles)
        for a in range(0, listed.size, self.pass_.max_entries):
            sl = slice(a, a + self.pass_.max_entries)
            enc = g.device.create_command_encoder()
            self.pass_.encode_checkpoints(
                enc,
                {"view": view[sl], "tile": tile[sl]},
                self.kept,
                int(lengths[listed[sl]].max()),
                groups=r.kept_view_groups(),
                **self.params(n_variants=1),
            )
            g.submit(enc)

    def _slots(self, counts: np.ndarray, name: str, states):
        """(first slot of each view and tile, a buffer of at least their total of TILE x TILE
        vec4 states: `states` when it is large enough)."""
        g = self.r.gpu
        base = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.uint32)
        need = max(1, int(counts.sum())) * SLAB_BYTES
        if need > g.max_binding:
            raise MemoryError(f"{name} states need {need:,} bytes, above one storage binding ({g.max_binding:,})")
        if states is None or states.size < need:
            states = None  # release the old states first
            states = g.buffer(need, STORAGE, f"{name}_states")
        return g.upload(base, STORAGE, f"{name}_base"), states

    @property
    def kept(self) -> dict:
        """The kept buffers by the names variants.wgsl's variants entry binds them under."""
        r = self.r
        return {
            # the variants entry binds them under the same names; the rectangles are read here
            **{name: buf for name, buf in r.kept_buffers.items() if name != "kv_proj_rect"},
            "ckpt_base": self.ckpt_base,
            "ckpt_states": self.ckpt_states,
            "chunk_base": self.chunk_base,
            "chunk_states": self.chunk_states,
        }

    def params(self, n_variants: int) -> dict:
        """The `Recomp` parameters of a re-compositing against these views."""
        r = self.r
        return {
            "width": r.width,
            "height": r.height,
            "tiles_x": r.tiles_x,
            "n_tiles": r.n_tiles,
            "n_prims": r.kv_stride,
            "n_variants": n_variants,
            "capacity": r.capacity,
            "background": r.background,
            "ckpt_every": self.every,
        }


class IncrementalCompositor:
    """Variant re-compositing against a keep_views renderer's clean frame (`clean_buf`, [K, H, W, 4]);
    `clean`: the renderer's CleanViews when several compositors share them (default: its own)."""

    def __init__(
        self, renderer, clean_buf, max_variants: int = 256, max_entries: int = 8192, clean: CleanViews | None = None
    ):
        r = renderer
        self.clean = clean or CleanViews(r)
        self.r, self.gpu, self.clean_buf = r, r.gpu, clean_buf
        self.B = int(max_variants) + (int(max_variants) & 1)
        self.max_entries = int(max_entries)
        g, k = self.gpu, r.k
        self.vlayout = StoredLayout(self.B, r.degree, r.precision, self.B)
        self.var_words = g.buffer(4 * self.vlayout.chunk_words, label="var_words")
        # view v's variant records at [v * B, v * B + B)
        self.projection = Projection(g, k * self.B, k, "var", r.profile)
        self.rects_readback = Readback(g, 8 * k * self.B, "var_rects.readback")
        self.compositing = VariantCompositing(g, self.max_entries, r.profile, r.compositing.chunk, r.binning.exact)
        # the metrics pass's tile map of a batch (encode returns it; faults/incremental.py uploads it)
        self.tile_map = g.buffer(4 * self.B * k * r.n_tiles, label="tile_map")
        self.bound_version = None
        self.refresh()

    @property
    def slabs(self):
        return self.compositing.slabs

    # ---- clean state -----------------------------------------------------------------------------
    def clean_rects_of(self, prims) -> np.ndarray:
        return self.clean.rects_of(prims)

    @property
    def longest_list(self) -> int:
        return self.clean.longest_list

    def refresh(self):
        """The clean views (shared) and the variant projection's parameters (the renderer's view
        parameters with this compositor's chunk layout), renewed when the renderer replaced its
        kept buffers (its `version` moved)."""
        r = self.r
        self.clean.ensure_current()
        rows = self.projection.params.rows
        rows[:] = r.projection.params.rows[:: r.layout.n_chunks]  # chunk 0 of each view
        # chunk_base = v * B puts view v's outputs at [v*B, v*B + B); no in-pipeline guard
        self.projection.params.struct.fill(
            rows, chunk_base=np.arange(r.k) * self.B, chunk_count=self.B, plane_words=self.vlayout.plane_words
        )
        rows["guard_lo"] = rows["guard_hi"] = 0
        self.projection.params.write()
        self.bound_version = r.version

    def ensure_current(self):
        if self.bound_version != self.r.version:
            self.refresh()

    # ---- variants ----------------------------------------------------------------------------------
    def project(self, bits: np.ndarray) -> np.ndarray:
        """Project up to B variant primitives (stored bits [m, ncomp]) for every view; returns
        their tile rectangles [K, m, 4] (x0, y0, x1, y1, exclusive max)."""
        return self.projected_rects(self.submit_project(bits))

    def submit_project(self, bits: np.ndarray) -> int:
        """The projection of `project`, submitted; returns the variant count for projected_rects."""
        g, B, K, p = self.gpu, self.B, self.r.k, self.projection
        m = bits.shape[0]
        padded = np.zeros((B, bits.shape[1]), dtype=bits.dtype)
        padded[:m] = bits
        g.write(self.var_words, self.vlayout.encode_bits(padded)[0])
        p.params.rows["chunk_count"] = m
        p.params.write()
        enc = g.device.create_command_encoder()
        for v in range(K):
            p.encode(enc, v, self.var_words, m, self.r.box_buf, self.r.guard_counts)
        self.rects_readback.encode(enc, p.buffers["proj_rect"], 0, 8 * K * B)
        g.submit(enc)
        return m

    def projected_rects(self, m: int) -> np.ndarray:
        """Tile rectangles [K, m, 4] of the last submit_project (waits for that submission only)."""
        rects = self.rects_readback.read(np.uint32).reshape(self.r.k, self.B, 2)
        return unpack_rects(rects[:, :m])

    def dirty_tiles(self, prims: np.ndarray, new_rects: np.ndarray) -> np.ndarray:
        """[m, K, T] bool: tiles inside the clean or the new rectangle of each variant's primitive."""
        r = self.r
        tx = np.arange(r.n_tiles) % r.tiles_x
        ty = np.arange(r.n_tiles) // r.tiles_x

        def inside(rc):
            return (tx >= rc[..., 0:1]) & (tx < rc[..., 2:3]) & (ty >= rc[..., 1:2]) & (ty < rc[..., 3:4])

        old = self.clean_rects_of(prims)  # [K, m, 4]
        return (inside(old) | inside(new_rects)).transpose(1, 0, 2)

    def groups(self, dirty: np.ndarray):
        """(start, end) runs of variants whose dirty tiles fit the slab budget together."""
        m = dirty.shape[0]
        per_variant = dirty.reshape(m, -1).sum(axis=1)
        start = 0
        while start < m:
            total, end = 0, start
            while end < m and (total + per_variant[end] <= self.max_entries or end == start):
                total += per_variant[end]
                end += 1
            if total > self.max_entries:
                raise RuntimeError(f"one variant dirties {total} tiles, more than max_entries={self.max_entries}")
            yield start, end
            start = end

    def encode(self, encoder, prims: np.ndarray, dirty: np.ndarray, first: int):
        """Record the re-compositing of the dirty tiles of variants `first .. first + m - 1` (their
        projected records sit at those indices) into the slabs. Returns (tile_map, variant, view,
        tile) per slab: tile_map [m, K, T] int32, slab index or -1, which the caller uploads to
        `tile_map` once it has marked the slabs equal to the clean tiles (faults/incremental.py)."""
        p = self.projection
        v_idx, b_idx, t_idx = np.nonzero(dirty.transpose(1, 0, 2))  # by view: kept view groups
        tile_map = np.full(dirty.shape, -1, dtype=np.int32)
        tile_map[b_idx, v_idx, t_idx] = np.arange(b_idx.size, dtype=np.int32)
        self.compositing.encode(
            encoder,
            {"variant": b_idx + first, "view": v_idx, "tile": t_idx, "prim": prims[b_idx]},
            kept=self.clean.kept,
            variant={
                "var_xy": p.buffers["proj_xy"],
                "var_conic": p.buffers["proj_conic"],
                "var_rgb": p.buffers["proj_rgb"],
                "var_rect": p.buffers["proj_rect"],
            },
            clean_image=self.clean_buf,
            longest=self.longest_list,
            groups=self.r.kept_view_groups(),
            **self.clean.params(n_variants=self.B),
        )
        return tile_map, b_idx, v_idx, t_idx

    def read_slabs(self, n: int) -> np.ndarray:
        """The first n re-composited tiles ([n, TILE, TILE, 4]): what the tests compare with full
        renders and the twin (campaigns read only boxes and metrics)."""
        return self.compositing.read_slabs(n)

    def read_changed(self, n: int) -> np.ndarray:
        return self.compositing.read_changed(n)

    def predicted_regions(self, new_rects: np.ndarray, P: int) -> tuple[np.ndarray, np.ndarray]:
        """Regions of the P-way sort-first grid that each variant primitive's tile rectangle (its
        projected 3.33-sigma footprint, as binned) reaches: (in any view, as int64 bitmasks [M];
        the share of the P regions it reaches in each view's frame, [K, M]).
        new_rects [K, M, 4] in tiles."""
        r = self.r
        ey, ex = region_edges(P, r.height, r.width)
        rows, cols = len(ey) - 1, len(ex) - 1
        x0, y0 = new_rects[..., 0] * TILE, new_rects[..., 1] * TILE
        x1 = np.minimum(new_rects[..., 2] * TILE, r.width)
        y1 = np.minimum(new_rects[..., 3] * TILE, r.height)
        nonempty = (x1 > x0) & (y1 > y0)
        hit_y = (ey[None, None, :-1] < y1[..., None]) & (ey[None, None, 1:] > y0[..., None])  # [K, M, rows]
        hit_x = (ex[None, None, :-1] < x1[..., None]) & (ex[None, None, 1:] > x0[..., None])  # [K, M, cols]
        hit = hit_y[..., :, None] & hit_x[..., None, :] & nonempty[..., None, None]  # [K, M, rows, cols]
        shares = hit.reshape(hit.shape[0], hit.shape[1], -1).sum(axis=2) / float(rows * cols)
        hit = hit.any(axis=0)  # [M, rows, cols]
        weights = np.left_shift(np.uint64(1), np.arange(rows * cols, dtype=np.uint64))
        return (hit.reshape(hit.shape[0], -1).astype(np.uint64) * weights).sum(axis=1).view(np.int64), shares
