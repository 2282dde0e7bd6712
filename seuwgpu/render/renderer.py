"""The WGSL 3DGS renderer: GPU-resident model, K views per `run`.

A thin orchestration of the stages. Batched (the default where it fits: `batch_views`), the K
views share every dispatch after projection: their screen records lie one after the other in
buffers of K n records, one depth sort orders all K n of them, one binning pass emits pairs whose
tile ids carry the view (v * n_tiles + tile), one tile sort and one ranges pass serve all K, and
one compositing dispatch covers K layers of tiles (render/bin.py, shaders/bin.wgsl). Each tile of
each view still gets its own list, front to back with ties by primitive index (the sorts are
stable and a view's records keep their order among the others'), so the frames are the same bit
for bit as one view at a time. A frame set costs K projection dispatches per model chunk plus
about one view's others, instead of K views' (K = 8 at 100k primitives on lavapipe: 63
dispatches, not 360), and Python records it 3-6x faster a view. Not batched:
renderers that keep views for the incremental re-compositor (their per-view lists are what it
reads), one view, or K n records past `BATCH_MAX_RECORDS`; then on a CPU adapter all K views go
into one command buffer (`submission_groups`). On a GPU every stage group (projections | depth
sort | binning and tile sort | ranges and compositing, of the batched views or of each view) is
submitted as soon as it is recorded, so the device works while Python records the next
(`split_submissions`). Per view:
projection of every model chunk (render/project.py) -> depth sort of the primitives
(render/sort.py) -> binning: tiles touched per primitive in depth order, their scan and the
emission of (tile, primitive) pairs (render/bin.py) -> tile sort (render/sort.py) -> per-tile
ranges (render/bin.py) -> compositing (render/composite.py). Because the pairs are emitted in
depth order and both sorts are stable, each tile's list is front to back with ties broken by
primitive index, exactly as the numpy twin (render/reference.py) orders them. The stages' scratch
buffers are shared by the K views (submissions run in order, as passes do).

If a frame needs more intersections than the buffers hold (a corrupted primitive can touch every
tile), the totals that come back with the image reveal it; the buffers grow and the frame is
re-run, so no intersection is ever dropped.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.constants import TILE
from seuwgpu.gpu.device import GPU, STORAGE, get_gpu
from seuwgpu.model import encoding
from seuwgpu.model.budget import check_frames, check_render
from seuwgpu.model.cameras import Camera
from seuwgpu.model.fields import Model, StoredLayout
from seuwgpu.render.bin import CARRIED, Binning
from seuwgpu.render.composite import Compositing, check_shape, default_chunk, default_shape
from seuwgpu.render.pipeline import KEPT, PIPELINE
from seuwgpu.render.project import Projection, check_profile
from seuwgpu.render.sort import Sorting

BATCH_MAX_RECORDS = {"gpu": 1 << 24, "cpu": 1 << 22}
"""Most screen records (K views x n primitives) a batched renderer holds, at about 70 bytes each
(records, depth keys, sort and binning scratch): on a GPU 16 Mi (about 1.1 GiB), on a CPU adapter
4 Mi (host memory). Past them the views are rendered one at a time."""


def _same_encoder(encoder):
    """No split: the stages go on in the same command encoder."""
    return encoder


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
        profile: str = "strict",
        exact_binning: bool = True,
        chunk: int | None = None,
        compositor: str | None = None,
        batch_views: bool | None = None,
    ):
        self.gpu = gpu or get_gpu()
        # batch_views: the K views share the dispatches after projection (module docstring); None:
        # wherever it applies (not with keep_views, K > 1, within BATCH_MAX_RECORDS); False: one
        # view at a time (the frames are the same either way)
        self._batch_views = batch_views
        # on GPUs `run` submits each stage group (projections | depth sort | binning and tile sort |
        # ranges and compositing; of the batched views, or of each view) as soon as it is recorded,
        # so the device works on one while Python records the next (recording is a large share of
        # a GPU frame's wall time: docs/renderer.md "Measurements"). CPU adapters record all in
        # one: there the device is the same cores.
        self.split_submissions = not self.gpu.is_cpu
        # renderer profile (docs/renderer.md "Profiles"): what corrupted values draw
        self.profile = check_profile(profile)
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
        w, h = check_cameras(cameras)
        if self.viewport is not None:  # only the viewport's pixels are held (render_split's bands)
            w, h = self.viewport[2], self.viewport[3]
        check_render(self.gpu.limits, self.gpu.is_cpu, self.n, self.degree, len(cameras), w, h, keep_views)
        max_chunk = StoredLayout.max_chunk_prims(self.degree, precision, self.gpu.max_binding)
        chunk_prims = min(chunk_prims or StoredLayout.balanced_chunk_prims(self.n, max_chunk), max_chunk)
        self.layout = StoredLayout(self.n, self.degree, precision, chunk_prims)
        # Host copy of the clean stored words: flips are undone against it, variants built from it.
        self.clean_words = self.layout.encode(model)
        self.chunks = [self.gpu.upload(w, STORAGE, f"model-chunk-{k}") for k, w in enumerate(self.clean_words)]
        self.projection = Projection(self.gpu, self.n, profile=self.profile)
        self.sorting = Sorting(self.gpu, self.n)
        # exact_binning=False pairs whole rectangles and composites by pixel boxes alone (same images;
        # render/bin.py, render/composite.py)
        self.binning = Binning(self.gpu, self.n, exact=exact_binning)
        # chunk: pairs of a tile list per compositing workgroup (render/composite.py; not chunk_prims,
        # the model's storage chunks); None: the device's default; tests force small ones
        chunk = default_chunk(self.gpu) if chunk is None else chunk
        # compositor: the full-frame compositor's shape, "lanes" or "wide" (render/composite.py
        # SHAPES; the same frames bit for bit); None: the device's default (lanes on a CPU, wide on a GPU)
        shape = default_shape(self.gpu) if compositor is None else check_shape(compositor)
        self.compositing = Compositing(self.gpu, self.profile, chunk, exact=exact_binning, shape=shape)
        # In-pipeline guard state (off by default): box of the clean model and clamp counters.
        self.guard_mask = 0
        bound = self.projection.kernel.struct("Bound")
        self.box_buf = self.gpu.buffer(bound.size * self.layout.ncomp, STORAGE, "box")
        self.guard_counts = self.gpu.buffer(4 * 8, STORAGE, "guard_counts")
        self.capacity = 0
        self.version = 0  # bumped when the intersection / kept-view buffers are replaced
        self._want_capacity = capacity
        self.cameras: list[Camera] = []
        self.set_cameras(cameras)

    @property
    def max_capacity(self) -> int:
        """Most pairs a view's tile list may hold: one binding of u32, and with kept views, the K
        lists of kv_isect_prims and kv_isect_box in one buffer each (bound a view group at a time:
        kept_view_groups)."""
        cap = self.gpu.max_binding // 4
        if self.keep_views:
            cap = min(cap, int(self.gpu.limits["max-buffer-size"]) // (4 * self.k))
        return cap

    def kept_view_groups(self) -> list[tuple[int, int]]:
        """Views [v0, v1) whose kept records (kv_proj_xy, kv_proj_conic, kv_proj_rgb at `kv_stride` a view) and
        tile lists (kv_isect_prims, kv_isect_box at `capacity` a view) each fit one storage binding: the
        incremental re-compositor binds one group per dispatch, so kept views are limited by the
        buffer size, not by one binding (4M primitives x 4 views: 256 MB of kv_proj_rgb)."""
        per_view = max(16 * self.kv_stride, 4 * self.capacity)
        size = max(1, self.gpu.max_binding // per_view)
        if size < self.k and (4 * self.capacity) % 256:
            raise ValueError(f"capacity {self.capacity} splits the kept views at unaligned offsets (use a power of 2)")
        return [(v, min(v + size, self.k)) for v in range(0, self.k, size)]

    @property
    def image(self):
        """The last frames: [K, H, W] vec4 (rgb unclamped, final transmittance)."""
        return self.compositing.image

    # ---- set-up ----------------------------------------------------------------------------------
    def set_cameras(self, cameras: list[Camera]):
        """Change the view set. Same count and size: only the parameters are rewritten (cheap,
        for interactive use); otherwise the view buffers are rebuilt."""
        size = check_cameras(cameras)
        if self.cameras and len(cameras) == self.k and size == (self.cam_width, self.cam_height):
            self.cameras = list(cameras)
            self._write_params()
            return
        frame_bytes = 16 * len(cameras) * (self.viewport[2] * self.viewport[3] if self.viewport else size[0] * size[1])
        if frame_bytes > self.gpu.max_binding:
            raise ValueError(
                f"{len(cameras)} views of {size[0]}x{size[1]} need {frame_bytes / 2**20:.0f} MiB of frames, more "
                f"than one storage binding holds ({self.gpu.max_binding / 2**20:.0f} MiB): use fewer views or a "
                "smaller --scale (`seuwgpu render` splits such frames itself)"
            )
        self.cam_width, self.cam_height = size
        self.origin = (0, 0)
        self.width, self.height = size
        if self.viewport is not None:
            self._check_viewport(size)
            x0, y0, w, h = self.viewport
            self.origin = (x0, y0)
            self.width, self.height = w, h
        self.cameras = list(cameras)
        self.k = len(cameras)
        self.tiles_x = -(-self.width // TILE)
        self.tiles_y = -(-self.height // TILE)
        self.n_tiles = self.tiles_x * self.tiles_y
        if self.tiles_x > 0xFFFF or self.tiles_y > 0xFFFF:
            raise ValueError("image too large")
        self.projection.set_slots(self.k * self.layout.n_chunks)
        self._set_batched(self._batching())
        self.compositing.set_views(self.k, self.width, self.height)
        if self.keep_views:
            # view v's records at v * kv_stride: a multiple of 64, so a view group binds aligned
            g, k = self.gpu, self.k
            self.kv_stride = -(-self.n // 64) * 64
            for o in KEPT:  # the tile lists follow the capacity: _set_capacity
                if o.record != "pair":
                    setattr(
                        self, o.kept_name, g.buffer(4 * o.words * self.kept_records(o)[0] * k, STORAGE, o.kept_name)
                    )
            # per pixel of each view, the list position of the record it stopped at (composite.wgsl)
            self.kv_stop_pos = g.buffer(4 * k * self.width * self.height, STORAGE, "kv_stop_pos")
        # a batched frame set's one list holds all K views' pairs (a first guess of 4 a primitive
        # and view; a frame that needs more grows the buffers and runs again)
        want = self._want_capacity or max(65536, 4 * self.n) * (self.k if self.batched else 1)
        self._set_capacity(min(max(self.capacity, _next_pow2(want)), self.max_capacity), force=True)

    def kept_records(self, output) -> tuple[int, int]:
        """(records a view apart, records copied a view) of the kept copy of `output`."""
        return {
            "primitive": (self.kv_stride, self.n),
            "pair": (self.capacity, self.capacity),
            "tile": (self.n_tiles, self.n_tiles),
        }[output.record]

    @property
    def kept_buffers(self) -> dict:
        """The kept views' buffers by name (kv_<output>, kv_stop_pos); empty without keep_views."""
        if not self.keep_views:
            return {}
        return {name: getattr(self, name) for name in (*(o.kept_name for o in KEPT), "kv_stop_pos")}

    @property
    def buffers(self) -> dict:
        """Every buffer the stages bind, by its shader name (PIPELINE's inputs and outputs)."""
        p, b = self.projection, self.binning
        own = {"isect_box": b.isect_box, "image": self.compositing.image}
        return {**p.buffers, **b.buffers, **own, **self.kept_buffers}

    def _batching(self) -> bool:
        """Whether the current views can be batched (module docstring)."""
        if self._batch_views is False or self.keep_views or self.k < 2:
            return False
        records = self.k * self.n
        limit = BATCH_MAX_RECORDS["cpu" if self.gpu.is_cpu else "gpu"]
        return records <= limit and 16 * records <= self.gpu.max_binding

    def _set_batched(self, batched: bool):
        """Size the projection records, depth sort and binning for K views batched or one by one."""
        self.batched = bool(batched)
        records = self.n * (self.k if self.batched else 1)
        self.projection.set_capacity(records)
        self.sorting.set_depth_count(records)
        self.binning.set_views(self.k, self.n_tiles, self.batched)

    def _write_params(self):
        L, tile_origin = self.layout, (self.origin[0] // TILE, self.origin[1] // TILE)
        for v, cam in enumerate(self.cameras):
            for c in range(L.n_chunks):
                a, b = L.chunk_range(c)
                self.projection.set_view(
                    v * L.n_chunks + c,
                    cam,
                    tiles=(self.tiles_x, self.tiles_y),
                    n_total=self.n,
                    chunk=(a, b - a),
                    plane_words=L.plane_words,
                    degree=self.degree,
                    precision=self.precision,
                    view_index=v,
                    guard_mask=self.guard_mask,
                    tile_origin=tile_origin,
                    background=self.background,
                    records_at=v * self.n + a if self.batched else a,
                )
            self.binning.set_view(
                v, tiles_x=self.tiles_x, size=(self.width, self.height), origin=self.origin, background=self.background
            )
        self.projection.params.write()
        self.binning.params.write()

    def _set_capacity(self, capacity: int, force: bool = False):
        """(Re)allocate the intersection buffers. Growth during a frame keeps the clean per-view
        tile lists of a keep_views renderer (copied to the new per-view stride); `force` (a new
        view set) rebuilds them empty, to be captured again."""
        if capacity == self.capacity and not force:
            return
        g = self.gpu
        old_capacity = self.capacity
        lists = [o for o in KEPT if o.record == "pair"]
        old_kv = {o.kept_name: getattr(self, o.kept_name, None) for o in lists}
        if capacity != self.capacity:
            self.compositing.set_capacity(capacity)  # its slabs: at most one binding
            self.capacity = capacity
            self.binning.set_capacity(capacity)
            self.sorting.set_capacity(capacity)
        if self.keep_views:  # one tile list per view: follows both the capacity and the view count
            enc = g.device.create_command_encoder()
            for o in lists:  # the pairs' primitives and pixel boxes
                old, per = old_kv[o.kept_name], 4 * o.words
                new = g.buffer(per * self.capacity * self.k, STORAGE, o.kept_name)
                setattr(self, o.kept_name, new)
                if old is not None and not force:
                    for v in range(self.k):
                        old_at, new_at = per * old_capacity * v, per * self.capacity * v
                        enc.copy_buffer_to_buffer(old, old_at, new, new_at, per * old_capacity)
            g.submit(enc)
        self.version += 1  # the kept-view buffers may have been replaced
        self._write_params()

    def _check_viewport(self, size):
        x0, y0, w, h = self.viewport
        if x0 % TILE or y0 % TILE or w <= 0 or h <= 0 or x0 + w > size[0] or y0 + h > size[1]:
            raise ValueError(
                f"viewport {self.viewport} must be tile-aligned ({TILE} px) and inside the {size[0]}x{size[1]} frame"
            )

    def set_viewport(self, viewport):
        """Render another tile-aligned region (x0, y0, w, h) of the same cameras (or None). A region
        of the current one's size only moves the origin (parameters rewritten, buffers kept)."""
        new = None if viewport is None else tuple(int(v) for v in viewport)
        moved_only = new is not None and self.viewport is not None and new[2:] == self.viewport[2:] and self.cameras
        self.viewport = new
        if moved_only:
            self._check_viewport((self.cam_width, self.cam_height))
            self.origin = new[:2]
            self._write_params()
            return
        cams, self.cameras = self.cameras, []
        self.set_cameras(cams)

    # ---- encoding --------------------------------------------------------------------------------
    def encode_projection(self, encoder, v: int, buffers=None):
        """View v's projection of every model chunk (its own projection slot per chunk)."""
        L, p = self.layout, self.projection
        for c in range(L.n_chunks):
            lo, hi = L.chunk_range(c)
            p.encode(encoder, v * L.n_chunks + c, self.chunks[c], hi - lo, self.box_buf, self.guard_counts, buffers)

    def encode_stage(self, stage, encoder, buffers: dict, slot: int, views: range):
        """Record one PIPELINE stage (tools/bench.py times the passes each records)."""
        stage.encode(encoder, buffers, self, slot, views)

    def _encode_pipeline(self, encoder, slot: int, views: range, split):
        split = split or _same_encoder
        buffers = self.buffers
        for stage in PIPELINE:
            if stage.split_before:
                encoder = split(encoder)
            self.encode_stage(stage, encoder, buffers, slot, views)
            self._state_hook(encoder, slot, stage.name)
        return encoder

    def encode_view(self, encoder, v: int, split=None):
        """View v's passes; `split` as in encode_batch (returns the encoder left to submit)."""
        encoder = self._encode_pipeline(encoder, v, range(v, v + 1), split)
        if self.keep_views and self.capture_views:
            self._copy_kept(encoder, v)
        return encoder

    def _copy_kept(self, encoder, v: int):
        """View v's kept copies of the outputs PIPELINE declares kept."""
        buffers = self.buffers
        for o in KEPT:
            stride, count = self.kept_records(o)
            per = 4 * o.words
            encoder.copy_buffer_to_buffer(buffers[o.name], 0, buffers[o.kept_name], per * stride * v, per * count)

    # A transient fault in the pipeline state of one frame (faults/state.py): `state_fault` is
    # None or an object with .view, .point (a stage's name) and .encode(encoder), recorded after
    # that stage of that view.
    state_fault = None

    def _state_hook(self, encoder, v: int, point: str):
        f = self.state_fault
        if f is not None and f.view == v and f.point == point:
            f.encode(encoder)

    def encode_batch(self, encoder, split=None):
        """All K views, batched (module docstring): K projections per model chunk, then one
        depth sort, binning, tile sort, ranges and compositing pass for all of them. `split`
        (run's, on a GPU): called between stages with the encoder so far, it submits it and
        returns a fresh one, so that the device starts on a stage while Python records the next;
        returns the encoder left to submit."""
        return self._encode_pipeline(encoder, self.binning.batch_slot, range(self.k), split)

    def encode(self, encoder, views=None, split=None):
        """Record `views` (all K by default); `split` as in encode_batch. Returns the encoder left
        to submit."""
        if self.batched:
            if views is not None and list(views) != list(range(self.k)):
                raise ValueError("a batched renderer records its K views together (batch_views=False for fewer)")
            if self.state_fault is not None:
                raise RuntimeError("pipeline-state faults need a renderer that keeps its views (keep_views=True)")
            return self.encode_batch(encoder, split)
        for v in range(self.k) if views is None else views:
            encoder = self.encode_view(encoder, v, split)
        return encoder

    def submission_groups(self) -> list[range]:
        """The views of each command encoder `run` records (on a GPU, `split_submissions` also
        submits it between stage groups). On a GPU one view each, so that the device works on view
        v while Python encodes view v + 1. On a CPU adapter all K in one: recording is a small
        share of a view there, and one by one was slower (docs/renderer.md "Measurements"). Same
        passes in the same order either way: same frames. Batched views: one, of all K."""
        if self.gpu.is_cpu or self.batched:
            return [range(self.k)]
        return [range(v, v + 1) for v in range(self.k)]

    def _submit_and_renew(self, encoder):
        self.gpu.submit(encoder)
        return self.gpu.device.create_command_encoder()

    # (buffer, byte offset, words) of another buffer copied at the end of every frame into the
    # stats the frame reads back anyway (at most bin.CARRIED words), or None; `carried` holds them
    # as the last frame left them. A frame check's detection count rides so (faults/check.py): a
    # check inside the frame adds no read, and no wait, of its own.
    _carry = None
    carried = np.zeros(0, np.uint32)

    def carry_back(self, source: tuple | None):
        """Read `source` ((buffer, byte offset, words), words <= bin.CARRIED) back with every
        frame's stats from now on (None: stop)."""
        if source is not None and not 0 < int(source[2]) <= CARRIED:
            raise ValueError(f"a frame carries back 1 to {CARRIED} words, not {source[2]}")
        self._carry = source
        self.carried = np.zeros(0, np.uint32)  # until a frame carries them

    def run(self) -> np.ndarray:
        """Encode, submit and wait for the K views (growing the intersection buffers and re-running
        as needed); returns the per-view intersection totals."""
        while True:
            groups = self.submission_groups()
            for i, views in enumerate(groups):
                enc = self.gpu.device.create_command_encoder()
                enc = self.encode(enc, views, self._submit_and_renew if self.split_submissions else None)
                if self._carry is not None and i == len(groups) - 1:
                    buf, offset, words = self._carry
                    enc.copy_buffer_to_buffer(buf, int(offset), self.binning.stats, 4 * (self.k + 1), 4 * int(words))
                self.gpu.submit(enc)
            stats = self.gpu.read(self.binning.stats, np.uint32)
            totals = stats[: self.k]
            carried = 0 if self._carry is None else int(self._carry[2])
            self.carried = stats[self.k + 1 : self.k + 1 + carried]
            # batched: the K views' pairs share one list (their sum at the batched slot)
            need = int(stats[self.binning.batch_slot] if self.batched else totals.max())
            if need <= self.capacity:
                return totals
            if self.batched and need > self.max_capacity:
                self._set_batched(False)  # the views one at a time: each list alone may still fit
                self._write_params()
                continue
            if need > self.max_capacity:
                kept = f" per view with {self.k} kept views" if self.keep_views and self.k > 1 else ""
                raise RuntimeError(
                    f"frame needs {need} tile intersections, more than one storage binding "
                    f"holds ({self.max_capacity}{kept}); render at a smaller size, fewer views or fewer primitives"
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
        box_rows: the guard's Bound records, one per component (faults/guard.py Box.rows)."""
        if box_rows is not None:
            self.gpu.write(self.box_buf, box_rows)
        self.guard_mask = int(mask)
        rows = self.projection.params.rows
        rows["guard_lo"] = self.guard_mask & 0xFFFFFFFF
        rows["guard_hi"] = self.guard_mask >> 32
        self.projection.params.write()

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


def split_plan(k: int, width: int, height: int, limit: int) -> tuple[int, int]:
    """(views per submission, rows per band) so that one submission's frames fit `limit` bytes
    (16 bytes a pixel): whole views in groups while one view fits, else one view at a time in
    bands of whole tile rows."""
    per_view = 16 * width * height
    if per_view <= limit:
        return max(1, min(k, limit // per_view)), height
    rows = (limit // (16 * width)) // TILE * TILE
    if rows < TILE:
        raise ValueError(f"a {width} px wide tile row needs {16 * width * TILE} bytes, more than {limit}")
    return 1, rows


def render_split(
    model: Model, cameras: list[Camera], precision: str = "fp32", split_bytes: int | None = None, **kw
) -> np.ndarray:
    """[K, H, W, 3] float32 frames of any size: frames that do not fit one storage binding
    (`split_bytes`, default the adapter's limit) are rendered in groups of views, or a single
    huge frame in bands of tile rows (sort-first viewports), bit-identical to one submission."""
    width, height = check_cameras(cameras)
    check_frames(len(cameras), width, height)
    gpu = kw.pop("gpu", None) or get_gpu()
    limit = int(split_bytes or gpu.max_binding)
    group, rows = split_plan(len(cameras), width, height, limit)
    out = np.empty((len(cameras), height, width, 3), np.float32)
    renderers: dict[tuple, Renderer] = {}  # one per band shape (at most two): the model uploaded once each
    for a in range(0, len(cameras), group):
        views = cameras[a : a + group]
        for y0 in range(0, height, rows):
            h = min(rows, height - y0)
            vp = None if rows == height else (0, y0, width, h)
            key = (len(views), h)
            if key not in renderers:
                renderers[key] = Renderer(model, views, precision, gpu=gpu, viewport=vp, **kw)
            r = renderers[key]
            if r.viewport != vp:
                r.set_viewport(vp)
            if len(r.cameras) != len(views) or any(a is not b for a, b in zip(r.cameras, views)):
                r.set_cameras(views)
            out[a : a + len(views), y0 : y0 + h] = r.render()
    return out
