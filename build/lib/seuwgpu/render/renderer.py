"""The WGSL 3DGS renderer: GPU-resident model, K views per submission.

Per view, all on the GPU inside one command encoder: project (per model chunk) -> depth sort of
primitives (stable radix sort) -> tiles touched per primitive in depth order -> exclusive scan ->
emit (tile, primitive) pairs -> stable radix sort by tile -> per-tile ranges -> composite.
Because the pairs are emitted in depth order and the tile sort is stable, each tile's list is
front to back with ties broken by primitive index, exactly as the numpy twin orders them.
Scratch buffers are shared by the views of a submission (the passes are ordered).

If a frame needs more intersections than the buffers hold (a corrupted primitive can touch every
tile), the totals that come back with the image reveal it; the buffers grow and the frame is
re-run, so no intersection is ever dropped.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.device import GPU, STORAGE, UNIFORM, dispatch, dispatch_dims, get_gpu
from seuwgpu.gpu.sort import PrefixSum, RadixSort
from seuwgpu.model import encoding
from seuwgpu.model.cameras import Camera
from seuwgpu.model.fields import Model, StoredLayout

TILE = 16
PRECISION_CODE = {"fp32": 0, "fp16": 1, "bf16": 2}
UNIFORM_STRIDE = 256


def _next_pow2(x: int) -> int:
    return 1 << max(0, int(x - 1).bit_length())


def check_cameras(cameras: list[Camera]) -> tuple[int, int]:
    if not cameras:
        raise ValueError("at least one camera is needed")
    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) != 1:
        raise ValueError(f"all cameras of one render must share one image size, got {sorted(sizes)}")
    return sizes.pop()


class Renderer:
    """Holds one model on the GPU (in its stored precision) and renders it from a camera set."""

    def __init__(
        self,
        model: Model,
        cameras: list[Camera],
        precision: str = "fp32",
        background=(1.0, 1.0, 1.0),
        gpu: GPU | None = None,
        chunk_prims: int | None = None,
        capacity: int | None = None,
        keep_views: bool = False,
        viewport=None,
    ):
        self.gpu = gpu or get_gpu()
        # viewport (x0, y0, w, h): render only this tile-aligned region of every camera's frame (the
        # sort-first split of distributed rendering); pixels equal the full frame's bit for bit.
        self.viewport = None if viewport is None else tuple(int(v) for v in viewport)
        # keep_views: also keep each view's projection, tile lists and ranges after the frame
        # (the incremental re-compositor of single upsets reads them).
        self.keep_views = keep_views
        self.capture_views = False  # set while rendering the frame whose state is to be kept
        self.precision = encoding.check_precision(precision)
        self.background = np.asarray(background, dtype=np.float32).reshape(3)
        self.degree = model.sh_degree
        self.n = model.n
        max_chunk = StoredLayout.max_chunk_prims(self.degree, precision, self.gpu.max_binding)
        self.layout = StoredLayout(self.n, self.degree, precision, min(chunk_prims or max_chunk, max_chunk))
        # Host copy of the clean stored words: flips are undone against it, variants built from it.
        self.clean_words = self.layout.encode(model)
        self.chunks = [self.gpu.upload(w, STORAGE, f"model-chunk-{k}") for k, w in enumerate(self.clean_words)]
        # In-pipeline guard state (off by default): box of the clean model and clamp counters.
        self.guard_mask = 0
        self.box_buf = self.gpu.buffer(16 * self.layout.ncomp, STORAGE, "box")
        self.guard_counts = self.gpu.buffer(4 * 8, STORAGE, "guard_counts")
        self.scrub_cache: dict = {}  # guard.scrub's buffers and bind groups for this model
        self._alloc_primitive_scratch()
        self.max_capacity = self.gpu.max_binding // 4
        self.capacity = 0
        self.version = 0  # bumped when the intersection / kept-view buffers are replaced
        self._want_capacity = capacity
        self.cameras: list[Camera] = []
        self.set_cameras(cameras)

    # ---- set-up ----------------------------------------------------------------------------------
    def _alloc_primitive_scratch(self):
        g, n = self.gpu, self.n
        self.proj_xy = g.buffer(8 * n, STORAGE, "proj_xy")
        self.proj_conic = g.buffer(16 * n, STORAGE, "proj_conic")
        self.proj_rgb = g.buffer(16 * n, STORAGE, "proj_rgb")
        self.proj_rect = g.buffer(8 * n, STORAGE, "proj_rect")
        self.depth_keys = g.buffer(4 * n, STORAGE, "depth_keys")
        self.depth_vals = g.buffer(4 * n, STORAGE, "depth_vals")
        self.counts = g.buffer(4 * n, STORAGE, "tile_counts")
        self.offsets = g.buffer(4 * n, STORAGE, "tile_offsets")
        self.depth_sort = RadixSort(g, n)
        self.scan = PrefixSum(g, n)
        self.p_project = g.pipeline("project")
        self.p_count = g.pipeline("tiles", "count_tiles")
        self.p_emit = g.pipeline("emit")
        self.p_ranges = g.pipeline("ranges")
        self.p_composite = g.pipeline("composite")

    def set_cameras(self, cameras: list[Camera]):
        """Change the view set. Same count and size: only the parameters are rewritten (cheap,
        for interactive use); otherwise the view buffers are rebuilt."""
        size = check_cameras(cameras)
        if self.cameras and len(cameras) == self.k and size == (self.cam_width, self.cam_height):
            self.cameras = list(cameras)
            self._write_params()
            return
        self.cam_width, self.cam_height = size
        self.origin = (0, 0)
        self.width, self.height = size
        if self.viewport is not None:
            x0, y0, w, h = self.viewport
            if x0 % TILE or y0 % TILE or w <= 0 or h <= 0 or x0 + w > size[0] or y0 + h > size[1]:
                raise ValueError(
                    f"viewport {self.viewport} must be tile-aligned ({TILE} px) and inside the "
                    f"{size[0]}x{size[1]} frame"
                )
            self.origin = (x0, y0)
            self.width, self.height = w, h
        self.cameras = list(cameras)
        self.k = len(cameras)
        self.tiles_x = -(-self.width // TILE)
        self.tiles_y = -(-self.height // TILE)
        self.n_tiles = self.tiles_x * self.tiles_y
        if self.tiles_x > 0xFFFF or self.tiles_y > 0xFFFF:
            raise ValueError("image too large")
        g = self.gpu
        self.image = g.buffer(16 * self.k * self.width * self.height, STORAGE, "image")
        self.stats = g.buffer(4 * self.k, STORAGE, "stats")
        self.ranges = g.buffer(8 * self.n_tiles, STORAGE, "ranges")
        self.view_params = g.buffer(UNIFORM_STRIDE * self.k * self.layout.n_chunks, UNIFORM, "view_params")
        if self.keep_views:
            n, k = self.n, self.k
            self.kv_xy = g.buffer(8 * n * k, STORAGE, "kv_xy")
            self.kv_conic = g.buffer(16 * n * k, STORAGE, "kv_conic")
            self.kv_rgb = g.buffer(16 * n * k, STORAGE, "kv_rgb")
            self.kv_rect = g.buffer(8 * n * k, STORAGE, "kv_rect")
            self.kv_ranges = g.buffer(8 * self.n_tiles * k, STORAGE, "kv_ranges")
        self.bin_params = g.buffer(UNIFORM_STRIDE * self.k, UNIFORM, "bin_params")
        want = self._want_capacity or max(65536, 4 * self.n)
        self._set_capacity(max(self.capacity, min(_next_pow2(want), self.max_capacity)), force=True)

    def _write_params(self):
        L = self.layout
        vp = np.zeros((self.k * L.n_chunks, UNIFORM_STRIDE // 4), dtype=np.uint32)
        bp = np.zeros((self.k, UNIFORM_STRIDE // 4), dtype=np.uint32)
        for v, cam in enumerate(self.cameras):
            for c in range(L.n_chunks):
                row = vp[v * L.n_chunks + c]
                f = row.view(np.float32)
                f[0:16] = cam.viewmat.T.reshape(-1)  # WGSL matrices are column-major
                f[16:19] = cam.position.astype(np.float32)
                f[20:24] = [cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]]
                f[24:27] = self.background
                a, b = L.chunk_range(c)
                row[28:41] = [
                    self.cam_width,
                    self.cam_height,
                    self.tiles_x,
                    self.tiles_y,
                    self.n,
                    a,
                    b - a,
                    L.plane_words,
                    self.degree,
                    PRECISION_CODE[self.precision],
                    v,
                    self.guard_mask & 0xFFFFFFFF,
                    self.guard_mask >> 32,
                ]
                f[41:43] = [self.origin[0] // TILE, self.origin[1] // TILE]
            bp[v, 0:8] = [
                self.n,
                self.tiles_x,
                self.n_tiles,
                self.capacity,
                v,
                self.width,
                self.height,
                self.origin[0] | (self.origin[1] << 16),
            ]
            bp[v].view(np.float32)[8:11] = self.background
        self.view_rows = vp  # host copy (the incremental path derives its own parameters from it)
        self.gpu.write(self.view_params, vp)
        self.gpu.write(self.bin_params, bp)

    def _set_capacity(self, capacity: int, force: bool = False):
        """(Re)allocate the intersection buffers. Growth during a frame keeps the clean per-view
        tile lists of a keep_views renderer (copied to the new per-view stride); `force` (a new
        view set) rebuilds them empty, to be captured again."""
        if capacity == self.capacity and not force:
            return
        g = self.gpu
        old_capacity, old_kv = self.capacity, getattr(self, "kv_isect", None)
        if capacity != self.capacity:
            self.capacity = capacity
            self.isect_tiles = g.buffer(4 * capacity, STORAGE, "isect_tiles")
            self.isect_prims = g.buffer(4 * capacity, STORAGE, "isect_prims")
            self.tile_sort = RadixSort(g, capacity)
        if self.keep_views:  # one tile list per view: follows both the capacity and the view count
            self.kv_isect = g.buffer(4 * self.capacity * self.k, STORAGE, "kv_isect")
            if old_kv is not None and not force:
                enc = g.device.create_command_encoder()
                for v in range(self.k):
                    enc.copy_buffer_to_buffer(
                        old_kv, 4 * old_capacity * v, self.kv_isect, 4 * self.capacity * v, 4 * old_capacity
                    )
                g.submit(enc)
        self.version += 1  # bind groups on the replaced buffers must be rebuilt
        self._write_params()
        self._make_bind_groups()

    def _make_bind_groups(self):
        g, L = self.gpu, self.layout
        S = UNIFORM_STRIDE
        self.bg_project = []
        for v in range(self.k):
            row = []
            for c in range(L.n_chunks):
                row.append(
                    g.bind(
                        self.p_project,
                        {
                            0: (self.view_params, (v * L.n_chunks + c) * S, 176),
                            1: self.chunks[c],
                            2: self.proj_xy,
                            3: self.proj_conic,
                            4: self.proj_rgb,
                            5: self.proj_rect,
                            6: self.depth_keys,
                            7: self.depth_vals,
                            8: self.box_buf,
                            9: self.guard_counts,
                        },
                    )
                )
            self.bg_project.append(row)
        self.bg_count, self.bg_emit, self.bg_ranges, self.bg_composite = [], [], [], []
        for v in range(self.k):
            u = (self.bin_params, v * S, 48)
            self.bg_count.append(g.bind(self.p_count, {0: u, 1: self.proj_rect, 2: self.depth_vals, 3: self.counts}))
            self.bg_emit.append(
                g.bind(
                    self.p_emit,
                    {
                        0: u,
                        1: self.proj_rect,
                        2: self.depth_vals,
                        3: self.offsets,
                        4: self.isect_tiles,
                        5: self.isect_prims,
                    },
                )
            )
            self.bg_ranges.append(g.bind(self.p_ranges, {0: u, 1: self.isect_tiles, 2: self.stats, 3: self.ranges}))
            self.bg_composite.append(
                g.bind(
                    self.p_composite,
                    {
                        0: u,
                        1: self.ranges,
                        2: self.isect_prims,
                        3: self.proj_xy,
                        4: self.proj_conic,
                        5: self.proj_rgb,
                        6: self.image,
                    },
                )
            )

    # ---- encoding --------------------------------------------------------------------------------
    def encode_view(self, encoder, v: int):
        L, n = self.layout, self.n
        for c in range(L.n_chunks):
            a, b = L.chunk_range(c)
            dispatch(encoder, self.p_project, self.bg_project[v][c], dispatch_dims(-(-(b - a) // 256)))
        self.depth_sort.encode(encoder, self.depth_keys, self.depth_vals, n, key_bits=32)
        prim_groups = dispatch_dims(-(-n // 256))
        dispatch(encoder, self.p_count, self.bg_count[v], prim_groups)
        self.scan.encode(encoder, self.counts, self.offsets, n, total=(self.stats, 4 * v))
        dispatch(encoder, self.p_emit, self.bg_emit[v], prim_groups)
        tile_bits = max(1, int(self.n_tiles - 1).bit_length())
        self.tile_sort.encode(encoder, self.isect_tiles, self.isect_prims, (self.stats, 4 * v), key_bits=tile_bits)
        dispatch(encoder, self.p_ranges, self.bg_ranges[v], dispatch_dims(-(-self.n_tiles // 256)))
        dispatch(encoder, self.p_composite, self.bg_composite[v], (self.tiles_x, self.tiles_y, 1))
        if self.keep_views and self.capture_views:
            n = self.n
            encoder.copy_buffer_to_buffer(self.proj_xy, 0, self.kv_xy, 8 * n * v, 8 * n)
            encoder.copy_buffer_to_buffer(self.proj_conic, 0, self.kv_conic, 16 * n * v, 16 * n)
            encoder.copy_buffer_to_buffer(self.proj_rgb, 0, self.kv_rgb, 16 * n * v, 16 * n)
            encoder.copy_buffer_to_buffer(self.proj_rect, 0, self.kv_rect, 8 * n * v, 8 * n)
            encoder.copy_buffer_to_buffer(self.isect_prims, 0, self.kv_isect, 4 * self.capacity * v, 4 * self.capacity)
            encoder.copy_buffer_to_buffer(self.ranges, 0, self.kv_ranges, 8 * self.n_tiles * v, 8 * self.n_tiles)

    def encode(self, encoder):
        for v in range(self.k):
            self.encode_view(v=v, encoder=encoder)

    def run(self) -> np.ndarray:
        """Encode, submit and wait for the K views (growing the intersection buffers and re-running
        as needed); returns the per-view intersection totals."""
        while True:
            enc = self.gpu.device.create_command_encoder()
            self.encode(enc)
            self.gpu.submit(enc)
            totals = self.gpu.read(self.stats, np.uint32)
            need = int(totals.max())
            if need <= self.capacity:
                return totals
            if need > self.max_capacity:
                raise RuntimeError(
                    f"frame needs {need} tile intersections, more than one storage binding "
                    f"holds ({self.max_capacity}); render at a smaller size or fewer primitives"
                )
            self._set_capacity(min(_next_pow2(need), self.max_capacity))

    def render_rgba(self) -> np.ndarray:
        """[K, H, W, 4] float32: rgb (unclamped) and final transmittance."""
        self.last_totals = self.run()
        img = self.gpu.read(self.image, np.float32, 0, 16 * self.k * self.width * self.height)
        return img.reshape(self.k, self.height, self.width, 4)

    def render(self) -> np.ndarray:
        """[K, H, W, 3] float32 images, unclamped."""
        return self.render_rgba()[..., :3].copy()

    # ---- in-pipeline guard ----------------------------------------------------------------------
    def set_guard(self, box_rows: np.ndarray | None, mask: int = 0):
        """Clamp the components in `mask` into the box while projecting; memory is untouched.
        box_rows: u32 [ncomp, 4] (lo, hi as f32 bits, then their stored bits) from guard.py."""
        if box_rows is not None:
            self.gpu.write(self.box_buf, np.ascontiguousarray(box_rows, dtype=np.uint32))
        self.guard_mask = int(mask)
        self._write_params()

    def reset_guard_counts(self):
        self.gpu.write(self.guard_counts, np.zeros(8, np.uint32))

    def read_guard_counts(self) -> np.ndarray:
        return self.gpu.read(self.guard_counts, np.uint32, 0, 32)[:6]

    # ---- stored words --------------------------------------------------------------------------
    def read_words(self, chunk: int) -> np.ndarray:
        return self.gpu.read(self.chunks[chunk], np.uint32, 0, 4 * self.layout.chunk_words)

    def stored_model(self) -> Model:
        """The model as the GPU holds it now (decoded from the stored words)."""
        return self.layout.decode([self.read_words(c) for c in range(self.layout.n_chunks)])


def render(model: Model, cameras: list[Camera], precision: str = "fp32", **kw) -> np.ndarray:
    """One-shot convenience: [K, H, W, 3] float32."""
    return Renderer(model, cameras, precision, **kw).render()


def gpu_decode(words: np.ndarray, precision: str, gpu: GPU | None = None) -> np.ndarray:
    """Decode raw stored words with the shaders' decode (for tests and inspection)."""
    gpu = gpu or get_gpu()
    words = np.ascontiguousarray(words, dtype=np.uint32).reshape(-1)
    count = words.size * (2 if encoding.bits_per_value(precision) == 16 else 1)
    params = gpu.upload(np.array([count, PRECISION_CODE[precision], 0, 0], dtype=np.uint32), UNIFORM)
    src = gpu.upload(words)
    dst = gpu.buffer(4 * count)
    pipe = gpu.pipeline("decode")
    enc = gpu.device.create_command_encoder()
    dispatch(enc, pipe, gpu.bind(pipe, {0: params, 1: src, 2: dst}), dispatch_dims(-(-count // 256)))
    gpu.submit(enc)
    return gpu.read(dst, np.float32, 0, 4 * count)
