"""Incremental re-compositing of single-primitive variants: redraw only the tiles a change reaches.

A single upset alters one primitive. Its clean and corrupted tile rectangles, per view, bound the
pixels that can change; everything else of the frame is the clean render, bit for bit. For a batch
of B variants (each: one primitive replaced by new stored bits) the compositor
1. projects each variant's new primitive for all K views with the renderer's own project shader
   (a tiny "model" of B primitives);
2. lists the dirty tiles (clean rect union new rect) per (variant, view) on the host;
3. re-composites those tiles with `composite.wgsl:variants` (the clean tile list with the primitive
   removed and its new record merged in at its depth) into 16x16 slabs.
The caller reduces metrics over the slabs (faults/incremental.py). Slabs equal the tiles of a full
re-render of the variant bit for bit (tests/test_incremental.py checks it).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.device import STORAGE, UNIFORM, dispatch, dispatch_dims
from seuwgpu.model.fields import StoredLayout
from seuwgpu.render.regions import region_edges
from seuwgpu.render.renderer import TILE, UNIFORM_STRIDE

SLAB_BYTES = TILE * TILE * 16


class IncrementalCompositor:
    """Variant re-compositing against a keep_views renderer's clean frame (`clean_buf`, [K, H, W, 4])."""

    def __init__(self, renderer, clean_buf, max_variants: int = 256, max_entries: int = 8192):
        r = renderer
        if not r.keep_views:
            raise ValueError("the renderer must keep its per-view state (keep_views=True)")
        self.r, self.gpu, self.clean_buf = r, r.gpu, clean_buf
        self.B = int(max_variants) + (int(max_variants) & 1)
        self.max_entries = int(max_entries)
        g, k = self.gpu, r.k
        self.vlayout = StoredLayout(self.B, r.degree, r.precision, self.B)
        self.var_words = g.buffer(4 * self.vlayout.chunk_words, STORAGE, "var_words")
        self.var_xy = g.buffer(8 * k * self.B, STORAGE, "var_xy")
        self.var_conic = g.buffer(16 * k * self.B, STORAGE, "var_conic")
        self.var_rgb = g.buffer(16 * k * self.B, STORAGE, "var_rgb")
        self.var_rect = g.buffer(8 * k * self.B, STORAGE, "var_rect")
        self.var_keys = g.buffer(4 * k * self.B, STORAGE, "var_keys")
        self.var_vals = g.buffer(4 * k * self.B, STORAGE, "var_vals")
        self.view_params = g.buffer(UNIFORM_STRIDE * k, UNIFORM, "var_view_params")
        self.rc_params = g.buffer(64, UNIFORM, "recomp_params")
        self.entries = g.buffer(16 * self.max_entries, STORAGE, "entries")
        self.slabs = g.buffer(SLAB_BYTES * self.max_entries, STORAGE, "slabs")
        self.tile_map = g.buffer(4 * self.B * k * r.n_tiles, STORAGE, "tile_map")
        self.p_project = g.pipeline("project")
        self.p_variants = g.pipeline("composite", "variants")
        self.bound_version = None
        self.refresh()

    # ---- clean state -----------------------------------------------------------------------------
    def refresh(self):
        """Clean per-view rectangles (host) and the bind groups on the renderer's kept buffers
        (re-made when the renderer replaced them: its `version` moved)."""
        r, g = self.r, self.gpu
        rects = g.read(r.kv_rect, np.uint32, 0, 8 * r.n * r.k).reshape(r.k, r.n, 2)
        self.clean_rects = unpack_rects(rects)  # [K, N, 4] x0, y0, x1, y1
        L = self.vlayout
        vp = np.zeros((r.k, UNIFORM_STRIDE // 4), dtype=np.uint32)
        src = r.view_rows
        for v in range(r.k):
            vp[v] = src[v * r.layout.n_chunks]
            # chunk_base = v * B puts view v's outputs at [v*B, v*B + B); no in-pipeline guard
            vp[v, 33:35] = [v * self.B, self.B]
            vp[v, 35] = L.plane_words
            vp[v, 39:41] = [0, 0]
        self.vp = vp
        g.write(self.view_params, vp)
        self.bg_project = [
            g.bind(
                self.p_project,
                {
                    0: (self.view_params, v * UNIFORM_STRIDE, 176),
                    1: self.var_words,
                    2: self.var_xy,
                    3: self.var_conic,
                    4: self.var_rgb,
                    5: self.var_rect,
                    6: self.var_keys,
                    7: self.var_vals,
                    8: r.box_buf,
                    9: r.guard_counts,
                },
            )
            for v in range(r.k)
        ]
        self.bg_variants = g.bind(
            self.p_variants,
            {
                10: self.rc_params,
                11: self.entries,
                12: r.kv_ranges,
                13: r.kv_isect,
                14: r.kv_xy,
                15: r.kv_conic,
                16: r.kv_rgb,
                17: self.var_xy,
                18: self.var_conic,
                19: self.var_rgb,
                20: self.var_rect,
                21: self.slabs,
                22: self.clean_buf,
            },
        )
        self.bound_version = r.version

    def ensure_current(self):
        if self.bound_version != self.r.version:
            self.refresh()

    # ---- variants ----------------------------------------------------------------------------------
    def project(self, bits: np.ndarray) -> np.ndarray:
        """Project up to B variant primitives (stored bits [m, ncomp]) for every view; returns
        their tile rectangles [K, m, 4] (x0, y0, x1, y1, exclusive max)."""
        g, B, K = self.gpu, self.B, self.r.k
        m = bits.shape[0]
        padded = np.zeros((B, bits.shape[1]), dtype=bits.dtype)
        padded[:m] = bits
        g.write(self.var_words, self.vlayout.encode_bits(padded)[0])
        self.vp[:, 34] = m
        g.write(self.view_params, self.vp)
        enc = g.device.create_command_encoder()
        for v in range(K):
            dispatch(enc, self.p_project, self.bg_project[v], dispatch_dims(-(-m // 256)))
        g.submit(enc)
        return unpack_rects(g.read(self.var_rect, np.uint32, 0, 8 * K * B).reshape(K, B, 2)[:, :m])

    def dirty_tiles(self, prims: np.ndarray, new_rects: np.ndarray) -> np.ndarray:
        """[m, K, T] bool: tiles inside the clean or the new rectangle of each variant's primitive."""
        r = self.r
        tx = np.arange(r.n_tiles) % r.tiles_x
        ty = np.arange(r.n_tiles) // r.tiles_x

        def inside(rc):
            return (tx >= rc[..., 0:1]) & (tx < rc[..., 2:3]) & (ty >= rc[..., 1:2]) & (ty < rc[..., 3:4])

        old = self.clean_rects[:, prims]  # [K, m, 4]
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
        projected records sit at those indices) into the slabs; writes the tile map
        ([m, K, T] int32, slab index or -1). Returns (tile_map, variant, view, tile) per slab."""
        r, g = self.r, self.gpu
        b_idx, v_idx, t_idx = np.nonzero(dirty)
        n_e = b_idx.size
        tile_map = np.full(dirty.shape, -1, dtype=np.int32)
        tile_map[b_idx, v_idx, t_idx] = np.arange(n_e, dtype=np.int32)
        if n_e:
            ent = np.stack([b_idx + first, v_idx, t_idx, prims[b_idx]], axis=1).astype(np.uint32)
            g.write(self.entries, ent)
        g.write(self.tile_map, tile_map)
        params = np.zeros(16, dtype=np.uint32)
        params[:8] = [r.width, r.height, r.tiles_x, r.n_tiles, r.n, self.B, r.capacity, n_e]
        params.view(np.float32)[8:11] = r.background
        g.write(self.rc_params, params)
        if n_e:
            dispatch(encoder, self.p_variants, self.bg_variants, dispatch_dims(n_e))
        return tile_map, b_idx, v_idx, t_idx

    def read_slabs(self, n: int) -> np.ndarray:
        return self.gpu.read(self.slabs, np.float32, 0, SLAB_BYTES * n).reshape(n, TILE, TILE, 4)

    def predicted_regions(self, new_rects: np.ndarray, P: int) -> np.ndarray:
        """Regions of the P-way sort-first grid that each variant primitive's tile rectangle (its
        projected 3.33-sigma footprint, as binned) reaches in any view, as int64 bitmasks.
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
        hit = (hit_y[..., :, None] & hit_x[..., None, :] & nonempty[..., None, None]).any(axis=0)  # [M, rows, cols]
        weights = np.left_shift(np.uint64(1), np.arange(rows * cols, dtype=np.uint64))
        return (hit.reshape(hit.shape[0], -1).astype(np.uint64) * weights).sum(axis=1).view(np.int64)


def unpack_rects(packed: np.ndarray) -> np.ndarray:
    p = packed.astype(np.int64)
    return np.stack([p[..., 0] & 0xFFFF, p[..., 0] >> 16, p[..., 1] & 0xFFFF, p[..., 1] >> 16], axis=-1)
