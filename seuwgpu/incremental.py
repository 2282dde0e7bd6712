"""Incremental evaluation of single upsets: re-composite only the tiles a flip can change.

A single upset alters one primitive. Its clean and corrupted tile rectangles, per view, bound the
pixels that can change; everything else of the frame is the clean render, bit for bit. For a batch
of variants (site x defense arms) this module
1. builds each variant's corrupted primitive (the defense applied to its stored bits) as a tiny
   "model" of B primitives and projects it for all K views with the renderer's own project shader;
2. reads back the K x B tile rectangles and, on the host, lists the dirty tiles (clean rect union
   corrupted rect) per (variant, view);
3. re-composites those tiles with `composite.wgsl:variants` (the clean tile list with the primitive
   removed and its new record merged in at its depth), into 16x16 slabs;
4. reduces the metrics over the dirty tiles dilated by one (SSIM windows reach 3 px), with
   unchanged windows counting exactly 1.
The result equals a full re-render bit for bit (tests/test_incremental.py checks it).
"""

from __future__ import annotations

import numpy as np

from .gpu.device import STORAGE, UNIFORM, dispatch_dims
from .guard import clamp_bits
from .metrics import ImageMetrics, build_worklist, summarize, tile_map_to_mask
from .model import StoredLayout
from .render import _UNIFORM_STRIDE, TILE

_SLAB_BYTES = 256 * 16


class IncrementalEvaluator:
    def __init__(self, engine, max_variants: int = 256, max_entries: int = 8192):
        r = engine.renderer
        if not r.keep_views:
            raise ValueError("the engine's renderer must keep its per-view state (keep_views=True)")
        self.engine, self.r, self.gpu = engine, r, engine.gpu
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
        self.view_params = g.buffer(_UNIFORM_STRIDE * k, UNIFORM, "var_view_params")
        self.rc_params = g.buffer(64, UNIFORM, "recomp_params")
        self.entries = g.buffer(16 * self.max_entries, STORAGE, "entries")
        self.slabs = g.buffer(_SLAB_BYTES * self.max_entries, STORAGE, "slabs")
        self.tile_map = g.buffer(4 * self.B * k * r.n_tiles, STORAGE, "tile_map")
        self.worklist = g.buffer(4 * self.B * k * r.n_tiles, STORAGE, "worklist")
        self.offsets = g.buffer(4 * (self.B * k + 1), STORAGE, "offsets")
        self.metrics = ImageMetrics(g, r.width, r.height, k, self.B, max_entries=self.B * k * r.n_tiles)
        self.p_project = g.pipeline("project")
        self.p_variants = g.pipeline("composite", "variants")
        self._bound_version = None
        self._refresh_clean_state()

    # ---- clean state -----------------------------------------------------------------------------
    def _refresh_clean_state(self):
        """Clean per-view rectangles (host) and the bind groups on the renderer's kept buffers."""
        r, g = self.r, self.gpu
        rects = g.read(r.kv_rect, np.uint32, 0, 8 * r.n * r.k).reshape(r.k, r.n, 2)
        self.clean_rects = _unpack_rects(rects)  # [K, N, 4] x0, y0, x1, y1
        L = self.vlayout
        vp = np.zeros((r.k, _UNIFORM_STRIDE // 4), dtype=np.uint32)
        src = r.view_rows
        for v in range(r.k):
            vp[v] = src[v * r.layout.n_chunks]
            # chunk_base = v * B puts view v's outputs at [v*B, v*B + B); no in-pipeline guard
            vp[v, 33:35] = [v * self.B, self.B]
            vp[v, 35] = L.plane_words
            vp[v, 39:41] = [0, 0]
        self._vp = vp
        g.write(self.view_params, vp)
        self.bg_project = [g.bind(self.p_project, {
            0: (self.view_params, v * _UNIFORM_STRIDE, 176), 1: self.var_words, 2: self.var_xy,
            3: self.var_conic, 4: self.var_rgb, 5: self.var_rect, 6: self.var_keys, 7: self.var_vals,
            8: r.box_buf, 9: r.guard_counts}) for v in range(r.k)]
        self.bg_variants = g.bind(self.p_variants, {
            10: self.rc_params, 11: self.entries, 12: r.kv_ranges, 13: r.kv_isect, 14: r.kv_xy,
            15: r.kv_conic, 16: r.kv_rgb, 17: self.var_xy, 18: self.var_conic, 19: self.var_rgb,
            20: self.var_rect, 21: self.slabs, 22: self.engine.clean_buf})
        self._bound_version = r.version

    # ---- evaluation ------------------------------------------------------------------------------
    def evaluate(self, prims: np.ndarray, bits: np.ndarray, guard_masks: np.ndarray | None = None,
                 regions=()) -> dict:
        """Metrics of variants: `prims` [M] primitive replaced in each variant, `bits` [M, ncomp]
        its effective stored bits (flip and defense already applied, except the support guard:
        `guard_masks` [M] component masks to clamp, 0 for none). Returns dict of [M] arrays
        (summarize's fields plus clamps). `regions`: sort-first partition sizes P for which to add
        regions_pred_P (regions the corrupted footprint's tile rectangle reaches in any view) and
        regions_meas_P (regions with a changed pixel in any view) as int64 bitmasks."""
        prims = np.asarray(prims, dtype=np.int64)
        bits = np.asarray(bits)
        m = prims.size
        if self._bound_version != self.r.version:
            self._refresh_clean_state()
        clamps = np.zeros(m, dtype=np.int64)
        if guard_masks is not None:
            bits = bits.copy()
            for mask in np.unique(guard_masks):
                if mask:
                    sel = guard_masks == mask
                    bits[sel], hit = clamp_bits(bits[sel], self.engine.box, int(mask))
                    clamps[sel] = hit.sum(axis=1)
        out = None
        for a in range(0, m, self.B):
            part = self._evaluate_batch(prims[a:a + self.B], bits[a:a + self.B], tuple(regions))
            out = part if out is None else {k: np.concatenate([out[k], part[k]]) for k in out}
        out["clamps"] = clamps
        return out

    def _evaluate_batch(self, prims: np.ndarray, bits: np.ndarray, regions=()) -> dict:
        r, g, B, K = self.r, self.gpu, self.B, self.r.k
        m = prims.size
        # 1. project the corrupted primitives for every view
        padded = np.zeros((B, bits.shape[1]), dtype=bits.dtype)
        padded[:m] = bits
        g.write(self.var_words, self.vlayout.encode_bits(padded)[0])
        self._vp[:, 34] = m
        g.write(self.view_params, self._vp)
        enc = g.device.create_command_encoder()
        for v in range(K):
            r._dispatch(enc, self.p_project, self.bg_project[v], dispatch_dims(-(-m // 256)))
        g.submit(enc)
        new = _unpack_rects(g.read(self.var_rect, np.uint32, 0, 8 * K * B).reshape(K, B, 2)[:, :m])
        old = self.clean_rects[:, prims]                       # [K, m, 4]
        # 2. dirty tiles per (variant, view): clean rect union corrupted rect
        tx = np.arange(r.n_tiles) % r.tiles_x
        ty = np.arange(r.n_tiles) // r.tiles_x

        def inside(rc):
            return ((tx >= rc[..., 0:1]) & (tx < rc[..., 2:3]) & (ty >= rc[..., 1:2]) & (ty < rc[..., 3:4]))

        dirty = (inside(old) | inside(new)).transpose(1, 0, 2)  # [m, K, T]
        results = {}
        # 3-4. re-composite and reduce, in groups that fit the slab budget
        per_variant = dirty.reshape(m, -1).sum(axis=1)
        start = 0
        while start < m:
            total, end = 0, start
            while end < m and (total + per_variant[end] <= self.max_entries or end == start):
                total += per_variant[end]
                end += 1
            if total > self.max_entries:
                raise RuntimeError(f"one variant dirties {total} tiles, more than max_entries={self.max_entries}")
            part = self._recomposite(prims[start:end], dirty[start:end], start, regions)
            for k2, v2 in part.items():
                results.setdefault(k2, []).append(v2)
            start = end
        out = {k2: np.concatenate(v2) for k2, v2 in results.items()}
        for P in regions:
            out[f"regions_pred_{P}"] = self._predicted_regions(new, P)
        return out

    def _recomposite(self, prims, dirty, first: int, regions=()) -> dict:
        r, g = self.r, self.gpu
        m = prims.size
        b_idx, v_idx, t_idx = np.nonzero(dirty)
        n_e = b_idx.size
        tile_map = np.full(dirty.shape, -1, dtype=np.int32)
        tile_map[b_idx, v_idx, t_idx] = np.arange(n_e, dtype=np.int32)
        worklist, offsets = build_worklist(tile_map_to_mask(tile_map, r.width, r.height, 1))
        if n_e:
            ent = np.stack([b_idx + first, v_idx, t_idx, prims[b_idx]], axis=1).astype(np.uint32)
            g.write(self.entries, ent)
        g.write(self.tile_map, tile_map)
        g.write(self.worklist, worklist)
        g.write(self.offsets, offsets)
        params = np.zeros(16, dtype=np.uint32)
        params[:8] = [r.width, r.height, r.tiles_x, r.n_tiles, r.n, self.B, r.capacity, n_e]
        params.view(np.float32)[8:11] = r.background
        g.write(self.rc_params, params)
        enc = g.device.create_command_encoder()
        if n_e:
            r._dispatch(enc, self.p_variants, self.bg_variants, dispatch_dims(n_e))
        self.metrics.encode_sparse(enc, self.engine.clean_buf, self.slabs, self.tile_map, self.worklist,
                                   self.offsets, m)
        g.submit(enc)
        raw = self.metrics.read(m)
        out = summarize(raw, r.width, r.height)
        out["dirty_tiles"] = dirty.reshape(m, -1).sum(axis=1)
        if regions:
            out.update(self._measured_regions(b_idx, v_idx, t_idx, m, regions))
        return out

    # ---- sort-first contamination ---------------------------------------------------------------
    def _measured_regions(self, b_idx, v_idx, t_idx, m: int, regions) -> dict:
        """Regions with a changed pixel (|d| > 1/255 in a channel, or non-finite) in any view,
        from the re-composited slabs against the clean frame."""
        r, n_e = self.r, b_idx.size
        out = {f"regions_meas_{P}": np.zeros(m, dtype=np.int64) for P in regions}
        if n_e == 0:
            return out
        slabs = self.read_slabs(n_e)                                   # [E, 16, 16, 4]
        ys = (t_idx // r.tiles_x)[:, None, None] * TILE + np.arange(TILE)[None, :, None]
        xs = (t_idx % r.tiles_x)[:, None, None] * TILE + np.arange(TILE)[None, None, :]
        inside = (ys < r.height) & (xs < r.width)
        yc, xc = np.minimum(ys, r.height - 1), np.minimum(xs, r.width - 1)
        clean = self.engine.clean_rgba[v_idx[:, None, None], yc, xc, :3]
        with np.errstate(invalid="ignore"):
            diff = np.abs(slabs[..., :3].astype(np.float64) - clean)
            changed = ((diff > 1.0 / 255.0) | ~np.isfinite(slabs[..., :3])).any(axis=-1) & inside
        from .analysis import region_id_map
        for P in regions:
            rid = region_id_map(P, r.height, r.width)[yc, xc]
            bits = np.where(changed, np.left_shift(np.uint64(1), rid.astype(np.uint64)), np.uint64(0))
            per_entry = np.bitwise_or.reduce(bits.reshape(n_e, -1), axis=1)
            acc = np.zeros(m, dtype=np.uint64)
            np.bitwise_or.at(acc, b_idx, per_entry)
            out[f"regions_meas_{P}"] = acc.view(np.int64)
        return out

    def _predicted_regions(self, new_rects: np.ndarray, P: int) -> np.ndarray:
        """Regions the corrupted primitive's tile rectangle (its projected 3.33-sigma footprint,
        as binned) reaches in any view. new_rects [K, M, 4] in tiles."""
        from .analysis import region_edges
        r = self.r
        ey, ex = region_edges(P, r.height, r.width)
        rows, cols = len(ey) - 1, len(ex) - 1
        x0, y0 = new_rects[..., 0] * TILE, new_rects[..., 1] * TILE
        x1 = np.minimum(new_rects[..., 2] * TILE, r.width)
        y1 = np.minimum(new_rects[..., 3] * TILE, r.height)
        nonempty = (x1 > x0) & (y1 > y0)
        hit_y = (ey[None, None, :-1] < y1[..., None]) & (ey[None, None, 1:] > y0[..., None])   # [K, M, rows]
        hit_x = (ex[None, None, :-1] < x1[..., None]) & (ex[None, None, 1:] > x0[..., None])   # [K, M, cols]
        hit = (hit_y[..., :, None] & hit_x[..., None, :] & nonempty[..., None, None]).any(axis=0)  # [M, rows, cols]
        weights = np.left_shift(np.uint64(1), np.arange(rows * cols, dtype=np.uint64))
        return (hit.reshape(hit.shape[0], -1).astype(np.uint64) * weights).sum(axis=1).view(np.int64)

    def read_slabs(self, n: int) -> np.ndarray:
        return self.gpu.read(self.slabs, np.float32, 0, _SLAB_BYTES * n).reshape(n, TILE, TILE, 4)


def _unpack_rects(packed: np.ndarray) -> np.ndarray:
    p = packed.astype(np.int64)
    return np.stack([p[..., 0] & 0xFFFF, p[..., 0] >> 16, p[..., 1] & 0xFFFF, p[..., 1] >> 16], axis=-1)
