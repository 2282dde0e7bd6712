"""Compositing stage: shaders/composite.wgsl (the "lanes" shape and the merge of long tiles),
composite_wide.wgsl (the "wide" shape) and their numpy twin.

Front to back over each tile's depth-ordered list, per pixel (docs/renderer.md): skip when
sigma < 0 or alpha < 1/255, alpha = min(0.99, o * exp(-sigma)) with NaN propagating, stop before
T drops to 1e-4 or below, output (C + T * background, T). Nothing is clamped.

Long tile lists (docs/renderer.md, "Long tile lists"): a tile list of n pairs is cut by list
position into ceil(n / CHUNK) chunks; each chunk runs that rule from C = 0, T = 1 (with its own
early stop) and the chunks merge front to back per pixel: the first chunk's (C, T) as is, each
later one as C = C + T * c, T = T * t; a pixel ends (later chunks ignored) once a chunk stopped
early at it or T <= 1e-4 after a merge. A tile of at most CHUNK pairs is thus composited as
before chunks existed, bit for bit; longer ones run their chunks on separate workgroups.

The GPU entry points share the blending and merging code (shaders/blend.wgsl), so their
arithmetic is identical bit for bit: `Compositing` (main, chunks, merge: the tiles of full frames,
in either compositor shape, `SHAPES`) and render/variants.py's `VariantCompositing`
(shaders/variants.wgsl: tiles of single-upset variants re-composited from a clean frame's kept
lists, one chunk per dispatch, render/incremental.py).

Twin: `composite_tile` blends one tile exactly as the sequential per-pixel rule does, vectorised
over pixels and blocks of primitives: the transmittance and colour recurrences use
`np.multiply.accumulate` / `np.add.accumulate`, which are strictly sequential in float32, so it
equals the per-pixel loop `T = T * (1 - alpha)`, `C = C + rgb * (alpha * T)` bit for bit.
sigma = 0.5 * ((conic.x*dx)*dx + (conic.z*dy)*dy) + (conic.y*dx)*dy with dx = mx - px (gsplat's
left-to-right order: with conic = 0, sigma is 0 even where dx*dx overflows). The GPU may fuse
multiply-adds and its exp may differ by an ulp, so GPU and twin agree to float32 rounding
(tests/test_composite.py documents the tolerance), not bit for bit.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.errors import InputError
from seuwgpu.gpu.constants import CHUNK, COMPOSITORS, GPU_CHUNK, PROFILE_CODE, TILE
from seuwgpu.gpu.device import GPU, INDIRECT, STORAGE
from seuwgpu.gpu.kernel import Kernel
from seuwgpu.render.bin import REACH_ALL, REACH_ELLIPSE, band_extent, reach
from seuwgpu.render.project import exp_f32
from seuwgpu.render.stage import Output, Stage

F = np.float32
ALPHA_MAX = F(0.99)
ALPHA_MIN = F(1.0 / 255.0)
T_MIN = F(1e-4)
TILE_PIXELS = TILE * TILE
SLAB_BYTES = TILE_PIXELS * 16  # one re-composited tile: TILE x TILE vec4 (rgb, T)


SHAPES = dict(zip(COMPOSITORS, ("composite", "composite_wide")))
"""The shader of each full-frame compositor shape (gpu/constants.py COMPOSITORS): "lanes" for CPU
Vulkan, "wide" the shape GPUs fill; the same operations per pixel (shaders/blend.wgsl), so the
same frames, bit for bit (on a GPU with products kept out of multiply-adds: `unfused_products`)."""


def default_shape(gpu: GPU) -> str:
    """The compositor a Renderer uses unless told: "lanes" on a CPU adapter, "wide" on a GPU,
    each the faster on its kind of device (docs/renderer.md "Measurements")."""
    return "lanes" if gpu.is_cpu else "wide"


def unfused_products(gpu: GPU) -> bool:
    """Whether the compositors keep products out of multiply-adds (blend.wgsl UNFUSED): on every
    GPU adapter, whose driver may fuse them differently in the two shapes; lavapipe fuses none, so
    there it would only cost time (the frames are the same either way, tests/test_composite.py)."""
    return not gpu.is_cpu


def check_shape(shape) -> str:
    if shape not in COMPOSITORS:
        raise InputError(f"unknown compositor shape {shape!r}: choose one of {', '.join(COMPOSITORS)}")
    return shape


class Compositing:
    """main / chunks (shaders/composite_frame.wgsl, compiled into composite.wgsl for the "lanes"
    shape and into composite_wide.wgsl for "wide"), then composite.wgsl merge: one TILE x TILE
    workgroup per tile (per tile and view of a batched list: a grid layer per view) runs the
    first `chunk` pairs of its list; the later chunks of long tiles run in parallel (`chunks`, an
    indirect dispatch over the work main lists) into slabs that `merge` blends front to back into
    the image. Owns the frames `image` ([K, H, W] vec4: rgb, final transmittance), the slabs and the
    work lists (sized by the intersection capacity: `set_capacity`)."""

    def __init__(self, gpu: GPU, profile: str = "strict", chunk: int = CHUNK, exact: bool = True, shape: str = "lanes"):
        self.gpu = gpu
        self.chunk = check_chunk(chunk)
        self.shape = check_shape(shape)
        shader = SHAPES[self.shape]
        # exact (lanes): a record visits only the quadrants its ellipse may reach
        # (ellipse_quadrants), as exact binning pairs it only with such tiles; False: its pixel box
        # decides (same image). The wide shape tests each pixel against the box alone.
        constants = {
            "PROFILE": PROFILE_CODE[profile],
            "CHUNK_PAIRS": self.chunk,
            "EXACT_BIN": int(exact),
            "UNFUSED": int(unfused_products(gpu)),
        }
        self.kernel = Kernel(gpu, shader, "main", constants=constants)
        self.k_chunks = Kernel(gpu, shader, "chunks", constants=constants)
        self.k_merge = Kernel(gpu, "composite", "merge", constants=constants)
        # the same without writing the pairs' pixel boxes (frames not kept for re-compositing)
        lean = {**constants, "KEEP_BOXES": 0}
        self._lean = (
            Kernel(gpu, shader, "main", constants=lean),
            Kernel(gpu, shader, "chunks", constants=lean),
        )
        # Work (blend.wgsl): counters zeroed per view; the dispatch arguments' y, z stay 1
        self.work = gpu.upload(np.array([0, 0, 0, 0, 0, 1, 1, 0, 0, 1, 1, 0], np.uint32), INDIRECT, "composite.work")
        self.no_stops = gpu.buffer(16, STORAGE, "composite.no_stops")  # bound (never written) by _lean
        self.capacity = None

    def set_views(self, k: int, width: int, height: int):
        self.image = self.gpu.buffer(16 * int(k) * int(width) * int(height), STORAGE, "composite.image")

    def set_capacity(self, capacity: int):
        """Slabs and work lists for frames of up to `capacity` pairs: a tile of n > chunk pairs
        takes ceil(n / chunk) < 2 n / chunk slab slots and lists ceil(n / chunk) - 1 <= n / chunk
        later chunks. Slots are taken in the order tiles finish chunk 0 (an atomic counter): where
        a chunk's pixels wait does not change them, and the slabs scale with the pairs, not with
        the number of tiles. Ranges that list more pairs than the capacity (a flipped tile range,
        faults/state.py) can outgrow them: a tile that finds no room composites its chunks in
        sequence on its own workgroup (same rule, same image). So the slabs are capped at one
        binding, which huge frames at small chunks would pass (100M primitives at GPU_CHUNK: 536M
        pairs want 2 GiB of slabs): their long tiles past the cap run in sequence."""
        cap = int(capacity)
        slots = min(2 * (cap // self.chunk) + 2, self.gpu.max_binding // SLAB_BYTES)
        need = slots * SLAB_BYTES
        g = self.gpu
        self.capacity = cap
        self.slabs = g.buffer(need, STORAGE, "composite.slabs")
        self.extra_list = g.buffer(16 * (cap // self.chunk + 1), STORAGE, "composite.extra_list")
        self.merge_list = g.buffer(8 * (slots // 2 + 1), STORAGE, "composite.merge_list")  # >= 2 slots a tile

    def encode(self, encoder, frame, buffers: dict, tiles: tuple[int, int], stops=None, frames: int = 1):
        """One view: `frame` its Binning slot (render/bin.py), `buffers` its tile lists (`ranges`,
        `isect_prims`), the screen records (`proj_xy`, `proj_conic`, `proj_rgb`: render/project.py)
        and `isect_box`; tiles = (TX, TY).
        A frame kept for re-compositing passes `stops` (u32 per pixel, indexed as the image),
        which receives the position in its tile's list of the record each pixel stopped at
        (0xffffffff: none, or a list longer than a chunk), while `isect_box` (u32 per pair)
        receives each pair's pixel box (FULL_BOX where a chunk stopped early): the variants entry
        reads both. Without `stops` neither is written (same image, less traffic). Three passes:
        main over every tile, then chunks and merge (indirect: no workgroup when no tile is
        longer than a chunk). `frames`: the views of a batched list (tile ids v * TX * TY + tile,
        one layer of main's grid each; `frame` is then the batched Binning slot)."""
        if self.capacity is None:
            raise RuntimeError("Compositing.set_capacity must be called before encode")
        encoder.clear_buffer(self.work, 0, 20)  # counters and the chunks' group count
        encoder.clear_buffer(self.work, 32, 4)  # the merge's group count
        # blend.wgsl's buffers; each entry point binds those it uses (`work` is read by the
        # later passes as their `work_counts`)
        buffers = {
            **buffers,
            "bin": frame,
            "image": self.image,
            "work": self.work,
            "chunk_slabs": self.slabs,
            "extra_list": self.extra_list,
            "merge_list": self.merge_list,
            "work_counts": self.work,
            "stop_pos": self.no_stops if stops is None else stops,
        }
        main, chunks = self._lean if stops is None else (self.kernel, self.k_chunks)
        main.dispatch(encoder, buffers, workgroups=(int(tiles[0]), int(tiles[1]), int(frames)))
        chunks.dispatch(encoder, buffers, indirect=(self.work, 16))
        self.k_merge.dispatch(encoder, buffers, indirect=(self.work, 32))


# ---- numpy twin ---------------------------------------------------------------------------------
def ellipse_quadrants(xy: np.ndarray, co: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Twin of composite_lanes.wgsl ellipse_quadrants, per row (xy [M, 2], co [M, 4]: conic and
    opacity, origin [M, 2]: the first pixel of the record's tile, full frame): bit 2 j + i set
    when the record's margined ellipse (render/bin.py reach) may reach a pixel centre of the
    quadrant in column half i, row half j; all four bits for a record without a bound. The
    compositor visits a record only in those quadrants (and those its pixel box meets)."""
    r = reach(xy, co)
    origin = np.asarray(origin, F)
    h = F(TILE // 2)
    q = np.zeros(len(r["kind"]), np.int64)
    for j in range(2):
        y0 = origin[:, 1] + F(j) * h + F(0.5)
        ex, ey, miss = band_extent(r, y0, y0 + h - F(1))
        with np.errstate(invalid="ignore"):
            hit = (r["kind"] == REACH_ELLIPSE) & ~miss & (ex <= ey)
            left = hit & (ex <= origin[:, 0] + h - F(0.5)) & (ey >= origin[:, 0] + F(0.5))
            right = hit & (ex <= origin[:, 0] + F(2) * h - F(0.5)) & (ey >= origin[:, 0] + h + F(0.5))
        q |= (left.astype(np.int64) | (right.astype(np.int64) << 1)) << (2 * j)
    return np.where(r["kind"] == REACH_ALL, 15, q)


def default_chunk(gpu: GPU) -> int:
    """Pairs a compositing workgroup walks on this device: CHUNK on a CPU adapter (lavapipe, where
    the cores, not the walk, bound a frame), GPU_CHUNK on a GPU (gpu/constants.py says why)."""
    return CHUNK if gpu.is_cpu else GPU_CHUNK


def check_chunk(chunk) -> int:
    """Pairs per compositing chunk: a positive multiple of the batch (TILE * TILE records)."""
    c = int(chunk)
    if c <= 0 or c % TILE_PIXELS:
        raise ValueError(f"chunk={chunk!r} must be a positive multiple of {TILE_PIXELS} pairs (TILE * TILE)")
    return c


def blend_chunk(ids, pxs, pys, mx, my, conic, opac, rgb, block0=32, block_max=512, profile="strict", where=False):
    """The per-pixel rule over the list `ids` from C = 0, T = 1 at pixel centres (pxs, pys) [P]:
    (C [P, 3], T [P], stopped [P]: the pixel stopped early), vectorised over pixels and blocks of
    primitives. `where`: also the position in `ids` of the record each pixel stopped at, and of
    the last record blended into it (-1 for none)."""
    nan_alpha = F(np.nan) if profile == "strict" else ALPHA_MAX
    P = pxs.shape[0]
    T = np.ones(P, dtype=F)
    C = np.zeros((P, 3), dtype=F)
    stopped = np.zeros(P, dtype=bool)
    stop_at = np.full(P, -1, np.int64)
    last_at = np.full(P, -1, np.int64)
    active = np.arange(P)  # pixels not yet stopped
    pos, L, B = 0, len(ids), block0
    with np.errstate(all="ignore"):
        while pos < L and active.size:
            blk = ids[pos : pos + B]
            pos += len(blk)
            nb = len(blk)
            apx, apy = pxs[active], pys[active]
            dx = mx[blk, None] - apx[None, :]
            dy = my[blk, None] - apy[None, :]
            cxx, cxy, czz = conic[blk, 0, None], conic[blk, 1, None], conic[blk, 2, None]
            sigma = F(0.5) * ((cxx * dx) * dx + (czz * dy) * dy) + (cxy * dx) * dy
            a = opac[blk, None] * exp_f32(-sigma)
            alpha = np.where(np.isnan(a), nan_alpha, np.minimum(ALPHA_MAX, a)).astype(F)
            skip = (sigma < 0) | (alpha < ALPHA_MIN)
            f = F(1) - np.where(skip, F(0), alpha)
            Ta = T[active]
            Tc = np.multiply.accumulate(np.concatenate([Ta[None, :], f], axis=0), axis=0)  # [nb+1, Pa]
            stop = Tc[1:] <= T_MIN  # skipped steps keep T (> T_MIN), so they never stop
            any_stop = stop.any(axis=0)
            first = np.where(any_stop, np.argmax(stop, axis=0), nb)
            include = (np.arange(nb)[:, None] < first[None, :]) & ~skip
            vis = alpha * Tc[:-1]
            contrib = rgb[blk][:, None, :] * vis[:, :, None]
            contrib = np.where(include[:, :, None], contrib, F(0))
            Cc = np.add.accumulate(np.concatenate([C[active][None], contrib], axis=0), axis=0)
            cols = np.arange(active.size)
            C[active] = Cc[first, cols]
            T[active] = Tc[first, cols]
            stopped[active[any_stop]] = True
            stop_at[active[any_stop]] = pos - nb + first[any_stop]
            took = include.any(axis=0)
            last_at[active[took]] = pos - 1 - np.argmax(include[::-1], axis=0)[took]
            active = active[~any_stop]
            B = min(2 * B, block_max)
    return (C, T, stopped, stop_at, last_at) if where else (C, T, stopped)


def merge_chunk(C, T, ended, c, t, stopped):
    """Merge a later chunk's (c, t, stopped) into the pixels' (C, T, ended) front to back, in
    place: C = C + T * c, T = T * t where not ended; a pixel ends once its chunk stopped early or
    T <= 1e-4 after the merge (blend.wgsl `merge_quad`)."""
    live = ~ended
    with np.errstate(all="ignore"):
        C[live] = C[live] + T[live, None] * c[live]
        T[live] = T[live] * t[live]
    ended |= live & (stopped | (T <= T_MIN))


def composite_tile(
    ids, pxs, pys, mx, my, conic, opac, rgb, bg, block0=32, block_max=512, profile="strict", chunk=CHUNK
):
    """Composite the depth-ordered primitive list `ids` over pixel centres (pxs, pys) [P]:
    (C + T * bg [P, 3], T [P]). The list is cut into chunks of `chunk` pairs, each blended from
    C = 0, T = 1 by the per-pixel rule (`blend_chunk`), then merged front to back (`merge_chunk`;
    the first chunk taken as is). Profile "gsplat": a NaN alpha becomes 0.99 (CUDA's fminf)."""
    chunk = check_chunk(chunk)
    kw = {"block0": block0, "block_max": block_max, "profile": profile}
    C, T, ended = blend_chunk(ids[:chunk], pxs, pys, mx, my, conic, opac, rgb, **kw)
    for a in range(chunk, len(ids), chunk):
        live = np.flatnonzero(~ended)
        if not live.size:
            break
        c, t, stopped = (np.zeros((len(T), 3), F), np.ones(len(T), F), np.zeros(len(T), bool))
        c[live], t[live], stopped[live] = blend_chunk(
            ids[a : a + chunk], pxs[live], pys[live], mx, my, conic, opac, rgb, **kw
        )
        merge_chunk(C, T, ended, c, t, stopped)
    with np.errstate(all="ignore"):
        return C + T[:, None] * bg[None, :], T


def tile_pixels(tx: int, ty: int, width: int, height: int, origin=(0, 0)):
    """Pixel rows / columns of tile (tx, ty) inside a width x height viewport, and their centres
    in full-frame coordinates (the viewport starts at `origin`)."""
    xa, xb = tx * TILE, min(width, (tx + 1) * TILE)
    ya, yb = ty * TILE, min(height, (ty + 1) * TILE)
    gy, gx = np.mgrid[ya:yb, xa:xb]
    pxs = (gx.reshape(-1) + origin[0]).astype(F) + F(0.5)
    pys = (gy.reshape(-1) + origin[1]).astype(F) + F(0.5)
    return (slice(ya, yb), slice(xa, xb)), pxs, pys


def composite_frame(
    ranges,
    prims,
    records: dict,
    width: int,
    height: int,
    background=(1.0, 1.0, 1.0),
    origin=(0, 0),
    profile="strict",
    chunk=CHUNK,
):
    """Twin of the main entry for one view: tile t draws prims[ranges[t, 0]:ranges[t, 1]] with
    the screen records (`proj_xy` [N, 2], `conic` [N, 3], `opacity`, `rgb` [N, 3]). Returns
    [H, W, 4] float32 (rgb, T) like the GPU's image."""
    bg = np.asarray(background, dtype=F).reshape(3)
    tiles_x, tiles_y = -(-int(width) // TILE), -(-int(height) // TILE)
    mx, my = records["proj_xy"][:, 0], records["proj_xy"][:, 1]
    img = np.empty((height, width, 4), dtype=F)
    prims = np.asarray(prims, np.int64)
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            (ys, xs), pxs, pys = tile_pixels(tx, ty, width, height, origin)
            a, b = ranges[ty * tiles_x + tx]
            rgb, T = composite_tile(
                prims[a:b],
                pxs,
                pys,
                mx,
                my,
                records["conic"],
                records["opacity"],
                records["rgb"],
                bg,
                profile=profile,
                chunk=chunk,
            )
            img[ys, xs, :3] = rgb.reshape(img[ys, xs].shape[:2] + (3,))
            img[ys, xs, 3] = T.reshape(img[ys, xs].shape[:2])
    return img


# ---- the stage ----------------------------------------------------------------------------------
def _encode_composite(encoder, buffers, r, slot, views):
    # a kept frame also records where each pixel stopped (and each pair's pixel box)
    stops = r.kv_stop_pos if r.keep_views and r.capture_views else None
    frame = r.binning.params.binding(slot)
    r.compositing.encode(encoder, frame, buffers, (r.tiles_x, r.tiles_y), stops=stops, frames=len(views))


def composite_twin(ranges, isect_prims, proj_xy, proj_conic, proj_rgb, width, height, background, profile) -> dict:
    """`composite_frame` over the kernel's buffers: image [H * W, 4] (rgb, T)."""
    records = {"proj_xy": proj_xy, "conic": proj_conic[:, :3], "opacity": proj_conic[:, 3], "rgb": proj_rgb[:, :3]}
    with np.errstate(all="ignore"):
        frame = composite_frame(ranges, isect_prims, records, width, height, background, profile=profile)
    return {"image": frame.reshape(-1, 4)}


COMPOSITE = Stage(
    "composite",
    inputs=("ranges", "isect_prims", "proj_xy", "proj_conic", "proj_rgb"),
    params=("width", "height", "background", "profile"),
    outputs=(
        # the pixels as written at the end of the compositor's loop (it keeps them in registers)
        Output("image", 4, "pixel", "f32", exact=False, fault=True, former="pixel"),
        # each pair's pixel box, written for kept frames only (the variants entry reads it)
        Output("isect_box", 1, "pair", kept=True, twinned=False),
    ),
    run=_encode_composite,
    twin_of=composite_twin,
)
