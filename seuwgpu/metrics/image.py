"""Per-injection image metrics on the GPU (shaders/metrics.wgsl), and their numpy twin.

Only a few numbers per (variant, view) come back to the host: one [B, K, 6] readback.

Conventions
-----------
Images are float32 RGBA (rgb + final transmittance; the 4th channel is ignored), as the renderer
writes them: never clamped, possibly non-finite after a fault.

* Raw-float metrics (what the renderer produced): ``changed`` (pixels whose r, g or b differs from
  the clean render by more than 1/255, or is non-finite), ``peak`` (max |faulted - clean| over
  pixels and channels, +Inf as soon as a difference is non-finite), ``nonfinite`` (pixels with a
  non-finite r, g or b; exponent-bit test, never ``x != x``). A pixel bit-identical to the clean
  one counts for none of them: a clean model's own NaN pixels are not charged to every upset
  (and sparse mode, which takes unlisted tiles as identical, equals dense mode).
* Display-referred metrics (what an 8-bit display shows): ``sse`` (hence PSNR) and SSIM are
  computed on both images clipped to [0, 1] with NaN -> 0 (+Inf -> 1, -Inf -> 0). A frame full of
  Inf therefore has a finite PSNR; the raw metrics and the non-finite flag report it instead.
* SSIM is ``skimage.metrics.structural_similarity(clean, faulted, channel_axis=-1,
  data_range=1.0)`` with its defaults (7x7 uniform window, sample covariance, K1=0.01, K2=0.03,
  map cropped by 3 px on each side, mean over channels). Images need W, H >= 7.

Storage modes
-------------
* dense: ``faulted`` [B, K, H, W, 4] float32; every tile is evaluated.
* sparse: ``slabs`` [S, TILE*TILE, 4] float32 (one tile per slab, pixel (tx, ty) at ty*TILE+tx),
  ``tile_map`` int32 [B, K, TY*TX] (slab index or -1 = identical to clean), a work list
  ``worklist`` uint32 [E] of tile indices (ty*TX + tx) grouped by bk = b*K + k in increasing bk
  order, and its CSR ``offsets`` uint32 [B*K + 1] (entries of bk are worklist[offsets[bk] :
  offsets[bk+1]]). Tiles outside the work list are taken as identical to clean: 0 changed pixels,
  0 error, SSIM exactly 1 at every window centred in them. A window centred in a listed tile reads
  its neighbours correctly (slab if mapped, else clean), so the work list must hold the tiles a
  fault changed dilated by one tile (``build_worklist(tile_map_to_mask(...))`` does that), or,
  where the box of each tile's changed pixels is known, those tiles and the neighbours whose
  windows reach the box (``changed_tiles_mask``, what campaigns use).

Results (``read``) per (b, k): changed, peak, sse, nonfinite, ssim_sum, ssim_count and
ssim_deficit. ``ssim_count`` is the number of evaluated interior window centres and
``ssim_sum`` the sum of SSIM over them, so the frame SSIM is
``(ssim_sum + n_interior - ssim_count) / n_interior`` with n_interior = (W-6)*(H-6). The GPU
accumulates the deficit 1 - SSIM (accurate in float32; exactly 0 for unchanged windows), and
``ssim_sum = ssim_count - ssim_deficit`` is formed on the host in float64; ``summarize`` uses the
deficit directly: SSIM = 1 - deficit / n_interior.

Sums are float32 on the GPU, in a fixed order: per tile (one workgroup, 4 pixels per thread,
then thread 0 adds the thread records in order), then the tiles of one (b, k) added
sequentially in work-list order by one thread. Tiles whose partials are all zero therefore change
nothing, bit for bit: sparse mode with a correct work list (tiles in increasing order within a
(b, k), as build_worklist makes them) gives exactly the dense numbers. No float atomics.

One ``encode_*`` per submission and ``read``: the parameters, partial and result buffers are
reused by every call. Records are the shader's ``MetricsRecord`` (gpu/kernel.py Struct).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.errors import require
from seuwgpu.gpu.constants import TILE
from seuwgpu.gpu.device import INDIRECT, STORAGE, Readback
from seuwgpu.gpu.kernel import Kernel, Struct, Uniforms

WIN = 7
PAD = (WIN - 1) // 2
THRESHOLD = np.float32(1.0 / 255.0)
MASK_BYTES = TILE * TILE // 8  # one entry's changed-pixel mask (metrics.wgsl m_masks)
FIELDS = ("changed", "peak", "sse", "nonfinite", "ssim_sum", "ssim_count", "ssim_deficit")


def entry_bytes() -> int:
    """Bytes one work-list entry takes in the largest per-entry buffer (its partials record or its
    changed-pixel mask): what bounds the entries of one ImageMetrics to one binding."""
    return max(Struct.from_shader("metrics", "MetricsRecord").size, MASK_BYTES)


def max_variants_of(gpu, width: int, height: int, n_views: int) -> int:
    """Most variants whose every tile (n_views frames) one ImageMetrics can hold in one binding."""
    tx, ty = tiles_of(width, height)
    fit = gpu.max_binding // (n_views * tx * ty * entry_bytes())
    return max(2, fit - fit % 2)  # the compositor's batches are even (render/incremental.py)


def tiles_of(width: int, height: int) -> tuple[int, int]:
    """(TX, TY): tiles per row and per column."""
    return -(-int(width) // TILE), -(-int(height) // TILE)


def n_interior(width: int, height: int) -> int:
    """Window centres of the cropped SSIM map."""
    return max(0, int(width) - 2 * PAD) * max(0, int(height) - 2 * PAD)


# ------------------------------------------------------------------------------------------------
# GPU
# ------------------------------------------------------------------------------------------------
class ImageMetrics:
    """GPU reductions for B variants x K views of W x H images. Buffers and pipelines are made
    once; ``encode_dense`` / ``encode_sparse`` record the kernels into a caller's command encoder
    (submit it before ``read``)."""

    def __init__(self, gpu, width: int, height: int, n_views: int, max_variants: int, max_entries: int | None = None):
        if width < WIN or height < WIN:
            raise ValueError(f"SSIM needs images of at least {WIN}x{WIN}, got {width}x{height}")
        self.gpu = gpu
        self.width, self.height = int(width), int(height)
        self.n_views, self.max_variants = int(n_views), int(max_variants)
        self.tiles_x, self.tiles_y = tiles_of(width, height)
        self.n_tiles = self.tiles_x * self.tiles_y
        self.n_interior = n_interior(width, height)
        self.capacity = int(max_entries) if max_entries else self.max_variants * self.n_views * self.n_tiles
        self.k_tile = Kernel(gpu, "metrics", "tile_partials")
        self.k_reduce = Kernel(gpu, "metrics", "reduce_entries")
        self.k_dispatch = Kernel(gpu, "metrics", "sparse_dispatch")
        self.record = self.k_tile.struct("MetricsRecord")
        self.layout = self.k_tile.struct("MetricsResults")  # status, then records
        if self.capacity * entry_bytes() > gpu.max_binding:
            raise ValueError(
                f"max_entries={self.capacity} needs more than one storage binding "
                f"({gpu.max_binding} bytes): evaluate fewer variants per call"
            )
        self.params = Uniforms(gpu, self.k_tile.struct("MetricsParams"), 1, "metrics.params")
        self.partials = gpu.buffer(self.capacity * self.record.size, STORAGE, "metrics.partials")
        n_results = self.max_variants * self.n_views
        self.results = gpu.buffer(
            self.layout.offset("records") + n_results * self.record.size, STORAGE, "metrics.results"
        )
        self.masks = gpu.buffer(self.capacity * MASK_BYTES, STORAGE, "metrics.masks")
        self.results_readback = Readback(gpu, self.results.size, "metrics.results.readback")
        self.masks_readback = Readback(gpu, 0, "metrics.masks.readback")  # sized by the first copy
        self.indirect = gpu.buffer(16, INDIRECT, "metrics.indirect")
        self._dummy = gpu.buffer(16, STORAGE, "metrics.dummy")
        self._mode = None

    # ---- recording -----------------------------------------------------------------------------
    def _params(self, n_variants: int, sparse: bool):
        n_variants = int(n_variants)
        if not 0 < n_variants <= self.max_variants:
            raise ValueError(f"n_variants={n_variants} outside 1..{self.max_variants}")
        self.params.struct.fill(
            self.params.rows,
            width=self.width,
            height=self.height,
            n_views=self.n_views,
            n_bk=n_variants * self.n_views,
            tiles_x=self.tiles_x,
            n_tiles=self.n_tiles,
            capacity=self.capacity,
            sparse=int(sparse),
        )
        self.params.write()

    def _need(self, buf, nbytes: int, what: str):
        if buf.size < nbytes:
            raise ValueError(f"{what} buffer holds {buf.size} bytes, needs {nbytes}")

    def _record(self, encoder, clean_buf, fimg_buf, tile_map_buf, worklist_buf, offsets_buf, n_bk, n_entries, masks):
        # metrics.wgsl's buffers; each entry point binds those it uses
        buffers = {
            "mp": self.params.binding(0),
            "m_clean": clean_buf,
            "m_fimg": fimg_buf,
            "m_tile_map": tile_map_buf,
            "m_worklist": worklist_buf,
            "m_offsets": offsets_buf,
            "m_partials": self.partials,
            "m_results": self.results,
            "m_indirect": self.indirect,
            "m_masks": self.masks,
        }
        cp = encoder.begin_compute_pass()
        if n_entries is None:  # sparse: size from offsets[B*K] on the GPU
            self.k_dispatch.record(cp, buffers, workgroups=(1, 1, 1))
            self.k_tile.record(cp, buffers, indirect=(self.indirect, 0))
        elif n_entries > 0:
            self.k_tile.record(cp, buffers, workgroups=n_entries)
        self.k_reduce.record(cp, buffers, threads=n_bk)
        cp.end()
        self.results_readback.encode(encoder, self.results, 0, self.layout.offset("records") + n_bk * self.record.size)
        self.masks_readback.encode(encoder, self.masks, 0, MASK_BYTES * min(int(masks), self.capacity))

    def encode_dense(self, encoder, clean_buf, faulted_buf, n_variants: int, masks: int = 0):
        """clean_buf: [K, H, W, 4] f32; faulted_buf: [B, K, H, W, 4] f32 with B >= n_variants.
        Evaluates every tile. `masks`: the entries whose changed-pixel masks are copied back with
        the submission (read_changed_pixels)."""
        n_bk = int(n_variants) * self.n_views
        n_entries = n_bk * self.n_tiles
        if n_entries > self.capacity:
            raise ValueError(f"dense mode needs {n_entries} partials > max_entries={self.capacity}")
        px = self.height * self.width * 16
        self._need(clean_buf, self.n_views * px, "clean")
        self._need(faulted_buf, n_bk * px, "faulted")
        self._params(n_variants, False)
        self._record(encoder, clean_buf, faulted_buf, self._dummy, self._dummy, self._dummy, n_bk, n_entries, masks)
        self._mode = ("dense", int(n_variants))

    def encode_sparse(
        self, encoder, clean_buf, slabs_buf, tile_map_buf, worklist_buf, offsets_buf, n_variants: int, masks: int = 0
    ):
        """slabs_buf [S, 256, 4] f32; tile_map_buf i32 [B, K, TY*TX]; worklist_buf u32 [E] tile
        indices grouped by bk = b*K + k (increasing bk; within a group in increasing tile order
        for results bit-identical to dense mode); offsets_buf u32 [B*K + 1] (CSR, offsets[0] = 0).
        The number of entries is read on the GPU (offsets[B*K]) and the tile kernel dispatched
        indirectly, so the work list may be built on the GPU; more entries than max_entries
        makes ``read`` raise. `masks`: as encode_dense (the host knows the count: offsets[B*K])."""
        n_bk = int(n_variants) * self.n_views
        self._need(clean_buf, self.n_views * self.height * self.width * 16, "clean")
        self._need(tile_map_buf, n_bk * self.n_tiles * 4, "tile_map")
        self._need(offsets_buf, (n_bk + 1) * 4, "offsets")
        self._params(n_variants, True)
        self._record(encoder, clean_buf, slabs_buf, tile_map_buf, worklist_buf, offsets_buf, n_bk, None, masks)
        self._mode = ("sparse", int(n_variants))

    # ---- results -------------------------------------------------------------------------------
    def read(self, n_variants: int | None = None) -> dict:
        """Results of the last submitted encode: dict of [B, K] numpy arrays (see FIELDS). Waits
        for that submission only (gpu/device.py Readback)."""
        if self._mode is None:
            raise RuntimeError("nothing encoded")
        B = self._mode[1] if n_variants is None else int(n_variants)
        K = self.n_views
        start = self.layout.offset("records")
        raw = self.results_readback.read(np.uint8)
        if raw.size < start + B * K * self.record.size:
            raise ValueError(f"the last encode measured fewer than {B} variants")
        raw = raw[: start + B * K * self.record.size]
        status = raw[: self.layout.size].view(self.layout.dtype)["status"][0]
        if status["requested"] > status["evaluated"]:
            raise RuntimeError(
                f"metrics work list has {status['requested']} entries > max_entries="
                f"{self.capacity}: results incomplete (raise max_entries)"
            )
        return _unpack(raw[start:].view(self.record.dtype).reshape(B, K))

    def read_changed_pixels(self, n_entries: int) -> np.ndarray:
        """[n_entries, TILE, TILE] bool of the last submitted encode, which copied at least that
        many (its `masks`): the pixels of each evaluated work-list entry (dense: entry
        bk * n_tiles + tile; sparse: the work list's order) that count as changed
        (`changed_pixels`, inside the frame). Sort-first contamination reads these instead of the
        faulted tiles. Waits for that submission only (gpu/device.py Readback)."""
        n = int(n_entries)
        if n == 0:
            return np.zeros((0, TILE, TILE), dtype=bool)
        if MASK_BYTES * n > self.masks_readback.size:
            raise ValueError(
                f"the last encode copied {self.masks_readback.size // MASK_BYTES} masks, not {n}: pass masks="
            )
        words = self.masks_readback.read(np.uint32)[: MASK_BYTES * n // 4]
        return np.unpackbits(words.view(np.uint8), bitorder="little").reshape(n, TILE, TILE).astype(bool)

    def run_dense(self, clean_buf, faulted_buf, n_variants: int, masks: int = 0) -> dict:
        """encode_dense + submit + read."""
        enc = self.gpu.device.create_command_encoder()
        self.encode_dense(enc, clean_buf, faulted_buf, n_variants, masks)
        self.gpu.submit(enc)
        return self.read(n_variants)

    def run_sparse(
        self, clean_buf, slabs_buf, tile_map_buf, worklist_buf, offsets_buf, n_variants: int, masks: int = 0
    ) -> dict:
        """encode_sparse + submit + read."""
        enc = self.gpu.device.create_command_encoder()
        self.encode_sparse(enc, clean_buf, slabs_buf, tile_map_buf, worklist_buf, offsets_buf, n_variants, masks)
        self.gpu.submit(enc)
        return self.read(n_variants)


def _unpack(rec: np.ndarray) -> dict:
    """MetricsRecord [B, K] -> the FIELDS as [B, K] arrays."""
    count = rec["count"].astype(np.int64)
    deficit = rec["deficit"].astype(np.float64)
    return {
        "changed": rec["changed"].astype(np.int64),
        "peak": rec["peak"].astype(np.float64),
        "sse": rec["sse"].astype(np.float64),
        "nonfinite": rec["nonfinite"].astype(np.int64),
        "ssim_sum": count - deficit,
        "ssim_count": count,
        "ssim_deficit": deficit,
    }


# ------------------------------------------------------------------------------------------------
# Work lists for sparse mode
# ------------------------------------------------------------------------------------------------
def tile_map_to_mask(tile_map: np.ndarray, width: int, height: int, dilate: int = 1) -> np.ndarray:
    """Tiles to evaluate: mapped tiles (tile_map >= 0) dilated by `dilate` tiles (8-neighbour,
    so windows centred next to a changed tile are evaluated). tile_map [B, K, TY*TX] ->
    bool [B, K, TY*TX]."""
    TX, TY = tiles_of(width, height)
    tm = np.asarray(tile_map)
    m = (tm >= 0).reshape(tm.shape[0], tm.shape[1], TY, TX)
    out = m.copy()
    for _ in range(int(dilate)):
        src = out.copy()
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                ys = slice(max(dy, 0), TY + min(dy, 0))
                yd = slice(max(-dy, 0), TY + min(-dy, 0))
                xs = slice(max(dx, 0), TX + min(dx, 0))
                xd = slice(max(-dx, 0), TX + min(-dx, 0))
                out[:, :, yd, xd] |= src[:, :, ys, xs]
    return out.reshape(tm.shape[0], tm.shape[1], TY * TX)


def changed_tiles_mask(shape, b, k, tile, boxes, width: int, height: int) -> np.ndarray:
    """Tiles to evaluate when the changed pixels are known: each tile (b, k, tile) whose box
    [N, 4] (x0, x1, y0, y1, tile-local, inclusive; x0 > x1: nothing changed) holds a change, and
    the neighbours whose SSIM windows (PAD px around their centres) reach one of its changed
    pixels. Every other tile has partials of exactly zero. shape = (B, K, TY*TX) -> bool."""
    TX, TY = tiles_of(width, height)
    out = np.zeros((shape[0], shape[1], TY, TX), bool)
    boxes = np.asarray(boxes, np.int64).reshape(-1, 4)
    hit = boxes[:, 0] <= boxes[:, 1]
    b, k, tile, boxes = np.asarray(b)[hit], np.asarray(k)[hit], np.asarray(tile)[hit], boxes[hit]
    ty, tx = tile // TX, tile % TX
    near = {  # whether the changed pixels come within PAD px of each side
        (-1, "x"): boxes[:, 0] < PAD,
        (1, "x"): boxes[:, 1] > TILE - 1 - PAD,
        (-1, "y"): boxes[:, 2] < PAD,
        (1, "y"): boxes[:, 3] > TILE - 1 - PAD,
    }
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            sel = np.ones(len(b), bool)
            if dx:
                sel &= near[(dx, "x")]
            if dy:
                sel &= near[(dy, "y")]
            y, x = ty + dy, tx + dx
            sel &= (y >= 0) & (y < TY) & (x >= 0) & (x < TX)
            out[b[sel], k[sel], y[sel], x[sel]] = True
    return out.reshape(shape[0], shape[1], TY * TX)


def build_worklist(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """bool [B, K, NT] -> (worklist u32 [E] tile indices grouped by b*K + k, offsets u32 [B*K+1])."""
    m = np.asarray(mask, bool)
    flat = m.reshape(-1, m.shape[-1])
    bk, tile = np.nonzero(flat)  # row-major: grouped by bk, tiles increasing
    offsets = np.zeros(flat.shape[0] + 1, np.uint32)
    np.cumsum(flat.sum(axis=1), out=offsets[1:])
    worklist = tile.astype(np.uint32)
    if worklist.size == 0:
        worklist = np.zeros(1, np.uint32)  # a binding cannot be empty; offsets say E = 0
    return worklist, offsets


# ------------------------------------------------------------------------------------------------
# Host-side summaries
# ------------------------------------------------------------------------------------------------
def summarize(raw: dict, width: int, height: int) -> dict:
    """[B, K] results -> [B] per-injection metrics: footprint (mean over views of changed/(W*H)),
    footprint_max, peak_error (max over views), psnr (10 log10(1/mse) over all views' pixels and
    channels, display-referred, +inf when sse == 0), ssim (mean over views), nonfinite (any),
    nonfinite_pixels (total).

    PSNR and SSIM of a frame with a non-finite pixel in any view are NaN: its display-referred
    numbers would rest on how NaN/Inf happen to be clipped, so they stay undefined (the
    non-finite flag and the raw metrics report such frames)."""
    n_px = float(width) * float(height)
    n_int = n_interior(width, height)
    changed = np.asarray(raw["changed"], np.float64)
    K = changed.shape[1]
    sse = np.asarray(raw["sse"], np.float64).sum(axis=1)
    with np.errstate(divide="ignore"):
        psnr = np.where(sse > 0, 10.0 * np.log10((K * n_px * 3.0) / np.where(sse > 0, sse, 1.0)), np.inf)
    if "ssim_deficit" in raw:
        ssim_view = 1.0 - np.asarray(raw["ssim_deficit"], np.float64) / n_int
    else:
        ssim_view = (
            np.asarray(raw["ssim_sum"], np.float64) + n_int - np.asarray(raw["ssim_count"], np.float64)
        ) / n_int
    nonfinite_px = np.asarray(raw["nonfinite"], np.int64).sum(axis=1)
    bad = nonfinite_px > 0
    psnr = np.where(bad, np.nan, psnr)
    ssim = np.where(bad, np.nan, ssim_view.mean(axis=1))
    foot = changed / n_px
    return {
        "footprint": foot.mean(axis=1),
        "footprint_max": foot.max(axis=1),
        "peak_error": np.asarray(raw["peak"], np.float64).max(axis=1),
        "psnr": psnr,
        "ssim": ssim,
        "nonfinite": bad,
        "nonfinite_pixels": nonfinite_px,
    }


ImageMetrics.summarize = staticmethod(summarize)


# a channel change above one 8-bit level is visible (paper's definition): THRESHOLD in float64
PIXEL_THRESHOLD = 1.0 / 255.0
FOOTPRINT_THRESHOLD = 0.01  # a frame with more than 1% of its pixels changed is catastrophic
OUTCOMES = ("masked", "tolerable", "sdc", "catastrophic")


def catastrophic(footprint, nonfinite, threshold: float = FOOTPRINT_THRESHOLD):
    """Catastrophic injection: footprint > threshold (1% of the pixels) or any non-finite pixel."""
    return (np.asarray(footprint) > threshold) | np.asarray(nonfinite, bool)


def outcome_class(
    peak_error, footprint, nonfinite, pixel_threshold: float = PIXEL_THRESHOLD, footprint_threshold=FOOTPRINT_THRESHOLD
) -> np.ndarray:
    """Outcome class of each injection (object array of OUTCOMES):

    * masked: the frame is bit-identical to clean (peak error 0, every pixel finite);
    * tolerable: changed, but no channel by more than `pixel_threshold`;
    * sdc: silent data corruption, visible (a channel changed by more than `pixel_threshold`),
      with a footprint of at most `footprint_threshold`;
    * catastrophic: footprint over `footprint_threshold`, or a non-finite pixel.

    The footprint counts pixels changed by more than 1/255 (the metric shader's fixed test);
    `pixel_threshold` sets the tolerable / SDC boundary on the peak change. A NaN peak error
    (not measured) with a zero footprint counts as tolerable, never as masked."""
    peak = np.asarray(peak_error, np.float64)
    foot = np.asarray(footprint, np.float64)
    bad = np.asarray(nonfinite, bool)
    out = np.full(peak.shape, "tolerable", dtype=object)
    out[peak == 0] = "masked"
    out[peak > pixel_threshold] = "sdc"
    out[(foot > footprint_threshold) | bad] = "catastrophic"
    return out


# ------------------------------------------------------------------------------------------------
# numpy twin
# ------------------------------------------------------------------------------------------------
def display(img: np.ndarray) -> np.ndarray:
    """Display-referred image: clip to [0, 1], NaN -> 0 (+Inf -> 1, -Inf -> 0)."""
    a = np.asarray(img, np.float32)
    return np.clip(np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)


def changed_pixels(faulted: np.ndarray, clean: np.ndarray, threshold=THRESHOLD) -> np.ndarray:
    """The one pixel-changed test of the project ([..., H, W] bool), as the metrics shader makes it
    (M_THR): a pixel changed when a colour channel of the faulted render is non-finite, or differs
    from the clean one by more than 1/255 (the float32 difference, as on the GPU). Only r, g, b
    count; a fourth (transmittance) channel is ignored; a pixel bit-identical to the clean one is
    unchanged (a clean model's own NaN pixels are not charged to an upset). The footprint, the viewer's heat map and
    both contamination measures (incremental and sort-first) all use it."""
    f = np.asarray(faulted, np.float32)[..., :3]
    c = np.asarray(clean, np.float32)[..., :3]
    with np.errstate(invalid="ignore", over="ignore"):
        d = f - c
    bad = ~np.isfinite(f) | ~np.isfinite(d)
    changed = (bad | (np.abs(np.where(bad, np.float32(0), d)) > np.float32(threshold))).any(axis=-1)
    same = (f.view(np.uint32) == np.broadcast_to(c, f.shape).view(np.uint32)).all(axis=-1)
    return changed & ~same


def numpy_metrics(clean: np.ndarray, faulted: np.ndarray) -> dict:
    """Independent CPU twin of ImageMetrics.read() (full frames evaluated): clean [K, H, W, 3|4],
    faulted [B, K, H, W, 3|4] -> dict of [B, K] arrays. SSIM from skimage (float64), which only
    the test extra installs: the GPU computes the metrics, this twin checks them."""
    skimage_metrics = require("skimage.metrics", "test", "the numpy twin of the image metrics")

    c = np.asarray(clean, np.float32)[..., :3]
    f = np.asarray(faulted, np.float32)[..., :3]
    B, K, H, W = f.shape[:4]
    n_int = n_interior(W, H)
    with np.errstate(invalid="ignore", over="ignore"):
        d = f - c[None]  # float32, like the GPU
    same = (f.view(np.uint32) == c[None].view(np.uint32)).all(axis=-1)  # bit-identical: unchanged
    bad_f = ~np.isfinite(f)
    bad_d = ~np.isfinite(d)
    nonfin_px = bad_f.any(axis=-1) & ~same
    inf_px = nonfin_px | (bad_d.any(axis=-1) & ~same)
    ad = np.where(bad_d | same[..., None], np.float32(0), np.abs(d))
    changed_px = changed_pixels(f, c[None])
    peak_px = np.where(inf_px, np.float32(np.inf), ad.max(axis=-1))
    dc = display(c).astype(np.float64)
    df = display(f).astype(np.float64)
    sse = ((df - dc[None]) ** 2).sum(axis=(2, 3, 4))
    ssim = np.empty((B, K))
    for b in range(B):
        for k in range(K):
            ssim[b, k] = skimage_metrics.structural_similarity(dc[k], df[b, k], channel_axis=-1, data_range=1.0)
    deficit = (1.0 - ssim) * n_int
    return {
        "changed": changed_px.sum(axis=(2, 3)).astype(np.int64),
        "peak": peak_px.max(axis=(2, 3)).astype(np.float64),
        "sse": sse,
        "nonfinite": nonfin_px.sum(axis=(2, 3)).astype(np.int64),
        "ssim_sum": ssim * n_int,
        "ssim_count": np.full((B, K), n_int, np.int64),
        "ssim_deficit": deficit,
    }
