"""Incremental evaluation of single upsets: the support guard's clamp on the host twin, the
re-compositing of the dirty tiles (render/incremental.py), and the metric reductions over them
(metrics/image.py, sparse mode), in two submissions per group of variants.

The re-compositor re-blends only pixels the change can reach (in front of where the clean frame
stopped blending them: render/incremental.py, docs/renderer.md) and returns, per dirty tile, the
box of the pixels that differ from the clean frame's. Metrics are reduced over the tiles with such
pixels and the neighbours whose SSIM windows (3 px) reach the box, every other tile adding exact
zeros, so every number equals a full re-render's bit for bit. Reading the boxes back splits a
group into two submissions; it cut the metric work of a campaign by three quarters (spheres 100k,
stratified sites: a quarter of the dirty tiles differ, mostly in their interior).

A batch thus takes three submissions (projection, re-compositing, metrics), each followed by host
work on its results. Two batches are in flight, each on a `Lane` of its own buffers: the host
works on one batch's results while the device runs the other's next submission (more injections
a second, same records: docs/renderer.md "Measurements"). Sort-first
regions' changed-pixel masks come back the same way, with their batch's results.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from seuwgpu.faults.guard import clamp_bits
from seuwgpu.gpu.constants import TILE
from seuwgpu.gpu.device import STORAGE
from seuwgpu.metrics.image import ImageMetrics, build_worklist, changed_tiles_mask, max_variants_of, summarize
from seuwgpu.render.incremental import CleanViews, IncrementalCompositor
from seuwgpu.render.regions import region_id_map


class Lane:
    """The GPU buffers of one batch of variants in flight: the compositor's variant projection and
    slabs, the metric work list and reductions, each with its own readback. A batch holds at most
    `max_variants`, and no more than the metrics of every tile of their views fit one binding."""

    def __init__(self, engine, max_variants: int, max_entries: int, clean: CleanViews | None = None):
        r, g = engine.renderer, engine.gpu
        max_variants = min(int(max_variants), max_variants_of(g, r.width, r.height, r.k))
        self.compositor = IncrementalCompositor(r, engine.clean_buf, max_variants, max_entries, clean)
        self.B, k = self.compositor.B, r.k
        self.worklist = g.buffer(4 * self.B * k * r.n_tiles, STORAGE, "worklist")
        self.offsets = g.buffer(4 * (self.B * k + 1), STORAGE, "offsets")
        self.metrics = ImageMetrics(g, r.width, r.height, k, self.B, max_entries=self.B * k * r.n_tiles)


class IncrementalEvaluator:
    """Evaluates variants in batches of B. With `lanes` = 2, two batches are in flight: while
    the GPU works on one, the host prepares the other's next step (each step waits for its own
    submission only: gpu/device.py Readback). Every batch's numbers are the same either way."""

    def __init__(self, engine, max_variants: int = 256, max_entries: int = 8192, lanes: int = 1):
        if lanes not in (1, 2):
            raise ValueError(f"lanes must be 1 or 2, got {lanes}")
        self.engine, self.gpu = engine, engine.gpu
        self.r = engine.renderer
        self.lanes = [Lane(engine, max_variants, max_entries)]
        self.want_lanes, self._sizes = lanes, (max_variants, max_entries)

    @property
    def compositor(self) -> IncrementalCompositor:
        """The first lane's (faults/worstcase.py projects with it between evaluations)."""
        return self.lanes[0].compositor

    @property
    def B(self) -> int:
        return self.lanes[0].B

    def evaluate(
        self, prims: np.ndarray, bits: np.ndarray, guard_masks: np.ndarray | None = None, regions=(), clean_bits=None
    ) -> dict:
        """Metrics of variants: `prims` [M] primitive replaced in each variant, `bits` [M, ncomp]
        its effective stored bits (flip and defense already applied, except the support guard:
        `guard_masks` [M] component masks to clamp, 0 for none). Returns dict of [M] arrays
        (summarize's fields plus clamps). `regions`: sort-first partition sizes P for which to add
        regions_pred_P (regions the corrupted footprint's tile rectangle reaches in any view) and
        regions_meas_P (regions with a changed pixel in any view) as int64 bitmasks, and the same
        per frame, regions_pred_frame_P and regions_meas_frame_P (the share of the P regions one
        view's frame reaches, averaged over the views: what one rendered frame contaminates). `clean_bits`
        [M, ncomp]: the primitives' clean stored bits; clamps then count beyond the clean
        primitive's own (the reference's), as the full path does."""
        rows, clamps = self.drawn_rows(bits, guard_masks, clean_bits)
        out = self.evaluate_rows(prims, rows, regions)
        out["clamps"] = clamps
        return out

    def drawn_rows(self, bits: np.ndarray, guard_masks: np.ndarray | None = None, clean_bits=None):
        """(the stored bits [M, ncomp] the pipeline draws once the support guard clamped `bits`,
        clamps [M] beyond the clean primitive's own when `clean_bits` is given); see evaluate."""
        bits = np.asarray(bits)
        clamps = np.zeros(bits.shape[0], dtype=np.int64)
        if guard_masks is not None:
            bits = bits.copy()
            for mask in np.unique(guard_masks):
                if mask:
                    sel = guard_masks == mask
                    bits[sel], hit = clamp_bits(bits[sel], self.engine.box, int(mask))
                    clamps[sel] = hit.sum(axis=1)
                    if clean_bits is not None:
                        clamps[sel] -= clamp_bits(clean_bits[sel], self.engine.box, int(mask))[1].sum(axis=1)
        return bits, clamps

    def evaluate_rows(self, prims: np.ndarray, rows: np.ndarray, regions=()) -> dict:
        """Metrics of variants whose primitive `prims[i]` is drawn from the stored bits `rows[i]`
        (guard already applied), against the engine's current clean reference. A variant drawing
        exactly the reference's own bits is the clean frame: it is projected (for the predicted
        regions) but re-composites no tile, so its metrics are those of an unchanged frame."""
        prims = np.asarray(prims, dtype=np.int64)
        rows = np.asarray(rows)
        m = prims.size
        starts = range(0, m, self.B)
        if len(starts) > 1 and len(self.lanes) < self.want_lanes:  # the clean views are the first lane's
            self.lanes.append(Lane(self.engine, *self._sizes, clean=self.compositor.clean))
        for lane in self.lanes:
            lane.compositor.ensure_current()
        unchanged = (rows == self.engine.reference_rows(prims)).all(axis=1)
        regions = tuple(regions)
        jobs = [
            lambda lane, sl=slice(a, a + self.B): self._batch(lane, prims[sl], rows[sl], regions, unchanged[sl])
            for a in starts
        ]
        parts = run_interleaved(jobs, self.lanes)
        if not parts:
            return None
        return {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}

    def _batch(self, lane: Lane, prims: np.ndarray, bits: np.ndarray, regions, unchanged):
        """One batch's steps, as a generator that yields after each submission (run_interleaved
        resumes it to read that submission's results); returns its metrics."""
        comp = lane.compositor
        m = comp.submit_project(bits)
        yield
        new = comp.projected_rects(m)
        dirty = comp.dirty_tiles(prims, new)
        dirty[unchanged] = False
        results = {}
        for start, end in comp.groups(dirty):
            part = yield from self._recomposite(lane, prims[start:end], dirty[start:end], start, regions)
            for k2, v2 in part.items():
                results.setdefault(k2, []).append(v2)
        out = {k2: np.concatenate(v2) for k2, v2 in results.items()}
        for P in regions:
            masks, shares = comp.predicted_regions(new, P)
            out[f"regions_pred_{P}"] = masks
            out[f"regions_pred_frame_{P}"] = shares.mean(axis=0)
        return out

    def _recomposite(self, lane: Lane, prims, dirty, first: int, regions=()):
        r, g, comp = self.r, self.gpu, lane.compositor
        m = prims.size
        if dirty.any():
            enc = g.device.create_command_encoder()
            tile_map, b_idx, v_idx, t_idx = comp.encode(enc, prims, dirty, first)
            g.submit(enc)
            yield
            # Only the slabs that differ from the clean tiles, and the neighbours whose SSIM windows
            # reach their changed pixels, are reduced: the others add exact zeros (metrics/image.py),
            # so the numbers are those of the whole dirty set.
            boxes = comp.read_changed(b_idx.size)
        else:  # variants that draw the clean frame (evaluate_rows): nothing to re-composite
            tile_map = np.full(dirty.shape, -1, dtype=np.int32)
            b_idx = v_idx = t_idx = np.zeros(0, dtype=np.int64)
            boxes = np.zeros((0, 4), dtype=np.int64)
        same = boxes[:, 0] > boxes[:, 1]
        tile_map[b_idx[same], v_idx[same], t_idx[same]] = -1
        g.write(comp.tile_map, tile_map)
        mask = changed_tiles_mask(tile_map.shape, b_idx, v_idx, t_idx, boxes, r.width, r.height)
        worklist, offsets = build_worklist(mask)
        g.write(lane.worklist, worklist)
        g.write(lane.offsets, offsets)
        enc = g.device.create_command_encoder()
        n_e = int(offsets[-1]) if regions else 0  # their changed-pixel masks come back with the results
        lane.metrics.encode_sparse(
            enc, self.engine.clean_buf, comp.slabs, comp.tile_map, lane.worklist, lane.offsets, m, masks=n_e
        )
        g.submit(enc)
        yield
        raw = lane.metrics.read(m)
        out = summarize(raw, r.width, r.height)
        out["dirty_tiles"] = dirty.reshape(m, -1).sum(axis=1)
        if regions:
            out.update(self._measured_regions(lane, worklist, offsets, m, regions))
        return out

    def _measured_regions(self, lane: Lane, worklist, offsets, m: int, regions) -> dict:
        """Regions with a changed pixel (metrics.image.changed_pixels) in any view, from the
        metrics pass's changed-pixel masks of the work list's tiles (every tile with a changed
        pixel is on it)."""
        r, K = self.r, self.r.k
        out = {f"regions_meas_{P}": np.zeros(m, dtype=np.int64) for P in regions}
        out.update({f"regions_meas_frame_{P}": np.zeros(m) for P in regions})
        n_e = int(offsets[-1])
        e, py, px = np.nonzero(lane.metrics.read_changed_pixels(n_e))  # the changed pixels
        if e.size == 0:
            return out
        frame = np.repeat(np.arange(m * K), np.diff(offsets.astype(np.int64)))[e]  # variant * K + view
        tile = worklist[e].astype(np.int64)
        ys, xs = (tile // r.tiles_x) * TILE + py, (tile % r.tiles_x) * TILE + px
        for P in regions:
            ids = region_id_map(P, r.height, r.width)
            bit = np.left_shift(np.uint64(1), ids[ys, xs].astype(np.uint64))
            per_frame = np.zeros(m * K, dtype=np.uint64)
            np.bitwise_or.at(per_frame, frame, bit)
            out[f"regions_meas_{P}"] = np.bitwise_or.reduce(per_frame.reshape(m, K), axis=1).view(np.int64)
            reached = np.unpackbits(per_frame.view(np.uint8).reshape(-1, 8), axis=1).sum(axis=1)
            out[f"regions_meas_frame_{P}"] = reached.reshape(m, K).mean(axis=1) / (int(ids.max()) + 1)
        return out


def run_interleaved(jobs, lanes) -> list:
    """Results of `jobs` (callables lane -> generator that yields after each submission and
    returns its result), in order, with one job per lane in flight: resuming a job waits for its
    own last submission, and the GPU meanwhile runs the other lane's."""
    results = [None] * len(jobs)
    active = deque()
    queue = iter(enumerate(jobs))

    def advance(i, gen, lane):
        while True:
            try:
                next(gen)
                active.append((i, gen, lane))
                return
            except StopIteration as stop:
                results[i] = stop.value
            nxt = next(queue, None)  # the lane is free: its next job
            if nxt is None:
                return
            i, gen = nxt[0], nxt[1](lane)

    for lane in lanes:
        nxt = next(queue, None)
        if nxt is not None:
            advance(nxt[0], nxt[1](lane), lane)
    while active:
        advance(*active.popleft())
    return results
