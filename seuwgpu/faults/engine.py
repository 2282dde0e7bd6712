"""The fault-injection engine: a GPU-resident model, its cameras and clean renders, and
`inject(sites, defense)` answering with a result record.

Flips are XORs on the stored words in the GPU buffers (faults/flips.py, `shaders/flip.wgsl`),
never re-uploads; undoing applies the same XOR again, so restores are exact. Defenses decide what
the renderer reads from a corrupted word:
- none: the corrupted word;
- guard / selective: the corrupted word, clamped into the clean model's support box while
  projecting (in-pipeline clamp, memory untouched; `guard.scrub` is the memory-repairing mode);
- every other defense: what its twin (faults/defenses.read) returns for the hit primitives.
Sites carry a fault model (faults/sites.py: flips, stuck-at, value replacement); whatever it is,
the engine XORs the difference between the clean and the read pattern, so undo is exact.
"""

from __future__ import annotations

import weakref

import numpy as np
import pandas as pd

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.codes import cull
from seuwgpu.faults.costs import interleaved_samples
from seuwgpu.faults.flips import Flips
from seuwgpu.faults.guard import Box, GuardMonitor, clamp_bits, component_mask, stored_ranges, support_box
from seuwgpu.faults.sites import Site, apply_sites, fault_name, make_site, site_bit_class
from seuwgpu.gpu.constants import CHUNK
from seuwgpu.gpu.device import GPU, STORAGE, get_gpu
from seuwgpu.metrics.image import ImageMetrics, catastrophic, summarize
from seuwgpu.model import encoding
from seuwgpu.model.budget import check_model
from seuwgpu.model.cameras import Camera
from seuwgpu.model.fields import FIELD_OFFSET, FIELDS, Model, n_components
from seuwgpu.render.renderer import Renderer


def field_of_components(degree: int) -> np.ndarray:
    """Field index (FIELDS order) of each flat component."""
    offs = [FIELD_OFFSET[f] for f in FIELDS]
    return np.searchsorted(offs, np.arange(n_components(degree)), side="right") - 1


class Engine:
    def __init__(
        self,
        model: Model,
        cameras: list[Camera],
        precision: str = "fp32",
        gpu: GPU | None = None,
        scene: str = "",
        chunk_prims: int | None = None,
        background=(1.0, 1.0, 1.0),
        incremental: bool = True,
        capacity: int | None = None,
        profile: str = "strict",
        chunk: int | None = None,
    ):
        self.gpu = gpu or get_gpu()
        self.precision = encoding.check_precision(precision)
        self.scene = scene
        check_model(model.n, model.sh_degree, "a model of", "inject into")  # the engine's copies
        self.renderer = Renderer(
            model,
            cameras,
            precision,
            gpu=self.gpu,
            chunk_prims=chunk_prims,
            background=background,
            keep_views=incremental,
            capacity=capacity,
            profile=profile,
            # campaigns composite in CHUNK pieces on every device (gpu/constants.py GPU_CHUNK says why)
            chunk=CHUNK if chunk is None else chunk,
        )
        self.profile = self.renderer.profile
        self.incremental = incremental
        self.layout = self.renderer.layout
        self.n, self.degree = model.n, model.sh_degree
        # the stored values' ranges, read from the words the GPU was given (no decoded copy)
        ranges = stored_ranges(self.layout, self.renderer.clean_words)
        self.box: Box = support_box(None, precision, ranges)
        self.renderer.set_guard(self.box.rows(), 0)
        # in-pipeline clamp mask of each guard defense (other defenses: 0)
        self.masks = {d: component_mask(f, self.degree) for d, f in dfn.pipeline_guards().items()}
        # Components where the clean model itself holds NaN or Inf (rare): the guard changes them
        # like corrupted values, so a guarded upset is measured against the guarded clean render
        # (its "reference"), and the guard's effect on the clean model is reported once
        # (`guard_on_clean`), never charged to every upset.
        nonfinite = ranges[2]
        self.nonfinite_mask = int(sum(1 << int(c) for c in np.flatnonzero(nonfinite)))
        self.nonfinite_counts = {
            f: int(v)
            for f, v in zip(FIELDS, np.bincount(field_of_components(self.degree), nonfinite, len(FIELDS)))
            if v
        }
        self._ref_mask = 0  # guard mask of the render held as the clean reference
        self.reference_clamps = 0
        self.flips = Flips(self.gpu, self.renderer.chunks)
        self._active: list[dict] = []  # applied XOR lists, for undo
        self._model_states = {}  # per defense: what it builds from the clean model (cellbox's boxes), on first use
        self.monitor = GuardMonitor(threshold=0)  # health signal of interactive/guarded renders
        self._set_up_views()

    WARM_UP_PRIMITIVES = 64
    _warmed: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # GPU -> engine shapes warmed

    @classmethod
    def warm_up(
        cls,
        cameras: list[Camera],
        precision: str,
        profile: str,
        incremental: bool,
        gpu: GPU | None = None,
        sh_degree: int = 3,
    ):
        """Compile the pipelines an engine of these views uses (the GPU caches them, gpu/device.py)
        by building one, and its evaluator, on a stand-in scene of WARM_UP_PRIMITIVES primitives.
        The campaign runner runs it on a thread while the model is read or made: on lavapipe the
        compiles take seconds, and they depend only on the number and size of the views, the
        precision, the profile and the SH degree (each shape is warmed once per GPU)."""
        from seuwgpu.model.scenes import make_scene

        gpu = gpu or get_gpu()
        shape = (len(cameras), cameras[0].width, cameras[0].height, precision, profile, incremental, sh_degree)
        done = cls._warmed.setdefault(gpu, set())
        if shape in done:
            return
        model = make_scene("spheres", cls.WARM_UP_PRIMITIVES, sh_degree=sh_degree)
        eng = cls(model, cameras, precision, gpu=gpu, scene="warm-up", incremental=incremental, profile=profile)
        if incremental:
            eng.evaluator  # noqa: B018 (built for its pipelines)
        done.add(shape)

    # ---- views and clean renders ------------------------------------------------------------------
    def _set_up_views(self):
        r = self.renderer
        self.cameras = r.cameras
        self.width, self.height, self.k = r.width, r.height, r.k
        self.clean_buf = self.gpu.buffer(r.image.size, STORAGE, "clean_images")
        self._capture_reference(0)
        # the guard's clamps on the clean model itself, per field, for each guard mask that meets
        # its non-finite values (only such models pay these renders): the health monitor alerts on
        # clamps beyond them, not forever on the clean model's own NaN/Inf
        self._clean_clamps = {}
        for d, m in self.masks.items():
            if m & self.nonfinite_mask and m not in self._clean_clamps:
                self._clean_clamps[m] = self._run_guarded(d)
        self.metrics = ImageMetrics(self.gpu, self.width, self.height, self.k, max_variants=1)
        self._evaluator = None

    def _capture_reference(self, mask: int):
        """Render the clean model under the in-pipeline guard `mask` (0: unguarded) as the reference
        of the metrics: its frame into clean_buf / clean_rgba, its per-view state kept for the
        incremental path (only this render: faulted ones must not overwrite it), its clamp total."""
        if self._active:
            raise RuntimeError("undo active faults before changing the clean reference")
        r = self.renderer
        r.capture_views = r.keep_views
        r.set_guard(None, mask)
        r.reset_guard_counts()
        try:
            self.clean_rgba = r.render_rgba()
            self.reference_clamps = int(r.read_guard_counts().sum())
        finally:
            r.capture_views = False
            r.set_guard(None, 0)
        enc = self.gpu.device.create_command_encoder()
        enc.copy_buffer_to_buffer(r.image, 0, self.clean_buf, 0, r.image.size)
        self.gpu.submit(enc)
        r.version += 1  # kept views re-captured: the incremental compositor re-reads them
        self._ref_mask = mask

    def reference_mask(self, defense: str) -> int:
        """Guard mask of the clean reference of `defense`: its own mask where the clean model holds
        non-finite values the guard changes, else 0 (the guard is then the identity on it)."""
        mask = self._guard_mask(defense)
        return mask if mask & self.nonfinite_mask else 0

    def reference_rows(self, prims) -> np.ndarray:
        """[M, ncomp] stored bits the clean reference draws for primitives `prims`: the clean ones,
        clamped by the reference's guard mask where it has one."""
        return self.drawn_rows(self.primitive_bits(prims), self._ref_mask)

    def drawn_rows(self, rows: np.ndarray, mask: int) -> np.ndarray:
        """[M, ncomp] bits the pipeline draws from stored bits `rows` read under guard `mask`:
        the support guard's clamp into the clean box (its numpy twin), or `rows` when unguarded."""
        return clamp_bits(rows, self.box, int(mask))[0] if mask else rows

    def use_reference(self, defense: str):
        """Make the clean reference of `defense` current (a re-render only when it changes)."""
        mask = self.reference_mask(defense)
        if mask != self._ref_mask:
            self._capture_reference(mask)

    def guard_on_clean(self, defense: str = "guard") -> dict:
        """The guard's own effect on the clean model, reported once: the model's non-finite
        values per field, and the guarded clean render against the unguarded one (metrics and
        clamps). All zeros for a finite model."""
        mask = self.reference_mask(defense)
        self.use_reference("none")
        out = self.measure_current(defense) if mask else {"footprint": 0.0, "clamps": 0}
        out = {k: v for k, v in out.items() if not hasattr(v, "__len__")}
        return {"defense": defense, **out, "nonfinite_values": dict(self.nonfinite_counts)}

    def set_cameras(self, cameras: list[Camera]):
        if self._active:
            raise RuntimeError("undo active faults before changing cameras (the clean render is re-made)")
        self.renderer.set_cameras(cameras)
        self._set_up_views()

    @property
    def clean(self) -> np.ndarray:
        return self.clean_rgba[..., :3]

    # ---- sites -------------------------------------------------------------------------------------
    def site(self, field: str, primitive: int, component: int, bits, op: str = "flip", value: int = 0) -> Site:
        return make_site(self.n, field, primitive, component, bits, self.precision, self.degree, op, value)

    def stored_bits(self, primitive, flat_component) -> np.ndarray:
        """Clean stored bit patterns (uint32 or uint16) at (primitive, flat component) pairs."""
        chunk, word, shift = self.layout.locate(primitive, flat_component)
        chunk, word, shift = np.atleast_1d(chunk), np.atleast_1d(word), np.atleast_1d(shift)
        words = self.renderer.clean_words
        if len(words) == 1:  # most models: no per-chunk split (a campaign reads ~60 values a site)
            w = words[0][word]
        else:
            w = np.empty(word.shape, dtype=np.uint32)
            for c in np.unique(chunk):
                sel = chunk == c
                w[sel] = words[int(c)][word[sel]]
        if not self.layout.halves:
            return w.astype(np.uint32, copy=False)
        return ((w >> shift.astype(np.uint32)) & np.uint32(0xFFFF)).astype(np.uint16)

    def clean_value(self, site: Site) -> float:
        return float(encoding.from_bits(self.stored_bits([site.primitive], [site.flat_component()]), self.precision)[0])

    def corrupted_value(self, site: Site) -> float:
        b = self.stored_bits([site.primitive], [site.flat_component()])
        return float(encoding.from_bits(apply_sites(b, [site]), self.precision)[0])

    def read_through(self, prims, clean: np.ndarray, corrupt: np.ndarray, defense: str) -> np.ndarray:
        """What `defense` reads from primitives `prims` (stored bits [M, ncomp]) that went from
        `clean` to `corrupt` (the support guard is applied later, in the pipeline or by clamp_bits)."""
        d = dfn.get(defense)
        return d.read(
            np.asarray(clean), np.asarray(corrupt), self.precision, self.degree, self.box, prims, self._state(d)
        )

    def frame_through(self, prims, clean: np.ndarray, corrupt: np.ndarray, defense: str):
        """(read_through, the stored rows after the frame's repair or None: Defense.frame)."""
        d = dfn.get(defense)
        return d.frame(
            np.asarray(clean), np.asarray(corrupt), self.precision, self.degree, self.box, prims, self._state(d)
        )

    def _state(self, d):
        """What `d` stores beside the model (Defense.model_state), built once from the clean model."""
        if not d.has_model_state:
            return None
        if d.name not in self._model_states:
            rows = self.primitive_bits(np.arange(self.n))
            self._model_states[d.name] = d.model_state(rows, self.precision, self.degree)
        return self._model_states[d.name]

    def _faulted(self, sites: list[Site]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(primitives [P] hit, their clean bits [P, ncomp], their bits after every site in order:
        sites hitting one value compose, the k-th hit of a value applied in round k)."""
        prims_of = np.array([s.primitive for s in sites], dtype=np.int64)
        comps = np.array([s.flat_component() for s in sites], dtype=np.int64)
        prims, row = np.unique(prims_of, return_inverse=True)
        clean = self.primitive_bits(prims)
        cur = clean.copy()
        key = row * self.layout.ncomp + comps
        order = np.argsort(key, kind="stable")
        ks = key[order]
        first = np.r_[True, ks[1:] != ks[:-1]]
        rank = np.empty(len(sites), dtype=np.int64)
        rank[order] = np.arange(len(sites)) - np.maximum.accumulate(np.where(first, np.arange(len(sites)), 0))
        for k in range(int(rank.max()) + 1 if len(sites) else 0):
            sel = np.flatnonzero(rank == k)
            cur[row[sel], comps[sel]] = apply_sites(cur[row[sel], comps[sel]], [sites[i] for i in sel])
        return prims, clean, cur

    # ---- flips on the GPU --------------------------------------------------------------------------
    def _xor_lists(self, sites: list[Site], defense: str, after_repair: bool = False) -> dict[int, np.ndarray]:
        """Per chunk: [(word, xor mask)] turning the clean words into what the defense reads (with
        `after_repair`, the stored rows once a frame's repair landed: Defense.after_frame)."""
        if not sites:
            return {}
        d = dfn.get(defense)
        prims, clean, cur = self.with_partners(*self._faulted(sites), defense)
        rows = d.after_frame(clean, cur, self.precision, self.degree, prims) if after_repair else None
        return self.xor_rows(prims, clean, self.read_through(prims, clean, cur, defense) if rows is None else rows)

    def defended_rows(self, sites: list[Site], defense: str) -> tuple[np.ndarray, np.ndarray]:
        """(primitives, their stored bits as `defense` reads them with every site applied): what
        the renderer reads of the model, the clean pair partners a frame check drops included
        (the in-pipeline guard's clamp is drawn_rows')."""
        prims, clean, cur = self.with_partners(*self._faulted(list(sites)), defense)
        return prims, self.read_through(prims, clean, cur, defense)

    def with_partners(self, prims, clean: np.ndarray, cur: np.ndarray, defense: str):
        """(prims, clean, cur) with the primitives the defense's twin needs beside them
        (Defense.partners: a per-word frame code's pair partners, clean), in primitive order."""
        prims = np.asarray(prims, np.int64)
        ext = dfn.get(defense).partners(prims, self.n, self.precision)
        if ext.size == prims.size:
            return prims, clean, cur
        base = self.primitive_bits(ext)
        now = base.copy()
        now[np.searchsorted(ext, prims)] = cur
        return ext, base, now

    def xor_rows(self, prims: np.ndarray, clean: np.ndarray, rows: np.ndarray) -> dict[int, np.ndarray]:
        """Per chunk: [(word, xor mask)] turning primitives `prims` (clean bits `clean`) into `rows`."""
        delta = clean.astype(np.uint64) ^ np.asarray(rows).astype(np.uint64)
        pi, c = np.nonzero(delta)
        p = np.asarray(prims)[pi]
        delta = delta[pi, c]
        chunk, word, shift = self.layout.locate(p, c)
        wmask = delta << shift.astype(np.uint64)
        out = {}
        for ch in np.unique(chunk):
            sel = chunk == ch
            w, wi = np.unique(word[sel], return_inverse=True)
            m = np.zeros(w.size, dtype=np.uint64)
            np.bitwise_xor.at(m, wi, wmask[sel])
            keep = m != 0
            if keep.any():
                out[int(ch)] = np.stack([w[keep], m[keep]], axis=1).astype(np.uint32)
        return out

    def apply(self, sites: list[Site], defense: str = "none", after_repair: bool = False) -> dict:
        """Flip the sites in the GPU-resident model (as the defense reads them; `after_repair`: as
        its repair between frames left them, for a check inside the frame); returns a handle."""
        xors = self._xor_lists(list(sites), dfn.check_defense(defense), after_repair)
        self.flips.apply(xors)
        self._active.append(xors)
        return xors

    def undo(self, handle: dict):
        self.flips.apply(handle)
        self._active = [h for h in self._active if h is not handle]

    def undo_all(self):
        while self._active:
            self.undo(self._active[-1])

    # ---- rendering and metrics ---------------------------------------------------------------------
    def _guard_mask(self, defense: str) -> int:
        return self.masks.get(defense, 0)

    def _run_guarded(self, defense: str) -> dict:
        """Render the K views as the model is now, under the defense's in-pipeline clamp; the frame
        stays in the renderer's image buffer. Returns clamps per field."""
        r = self.renderer
        r.set_guard(None, self._guard_mask(defense))
        r.reset_guard_counts()
        try:
            r.run()
            return dict(zip(FIELDS, map(int, r.read_guard_counts())))
        finally:
            r.set_guard(None, 0)

    def render_current(self, defense: str = "none") -> tuple[np.ndarray, dict]:
        """Render the model as it is now (faults applied) under a defense's in-pipeline guard.
        Returns ([K, H, W, 4] images, clamps per field); guarded renders feed the health monitor."""
        counts = self._run_guarded(defense)
        mask = self._guard_mask(defense)
        if mask:
            base = self._clean_clamps.get(mask, {})
            self.monitor.update({f: max(0, c - base.get(f, 0)) for f, c in counts.items()})
        return self.last_frame(), counts

    def last_frame(self) -> np.ndarray:
        """[K, H, W, 4] frames of the last render (render_current, or inject's faulted frame: the
        restore after it flips stored words back but renders nothing)."""
        r = self.renderer
        return r.gpu.read(r.image, np.float32, 0, 16 * r.k * r.width * r.height).reshape(r.k, r.height, r.width, 4)

    VIEW_TIME_BUDGET_S = 3.0
    """Seconds the defenses' view times may take once VIEW_TIME_LEAST_ROUNDS rounds ran."""
    VIEW_TIME_LEAST_ROUNDS = 2
    VIEW_TIME_ROUNDS = 9

    def view_time_samples(self, defenses=("none",), repeats: int = VIEW_TIME_ROUNDS) -> dict:
        """{defense: [ms of each round]}: wall time of rendering one view of the model as it is now
        under each defense's in-pipeline guard: view 0 rendered alone and waited for where the
        renderer draws its views one at a time (an incremental engine keeps them, so it does;
        timing all K cost a 1M-primitive campaign K times as much), else its K batched views over K.
        The defenses are timed interleaved, round by round, so a drift of the machine's load hits
        them alike: `repeats` (VIEW_TIME_ROUNDS) rounds, or as many (at least VIEW_TIME_LEAST_ROUNDS) as fit
        VIEW_TIME_BUDGET_S. No warm-up round: the clean capture (_set_up_views) ran these
        pipelines on these views just before, and the guard is a uniform, not a pipeline (a
        warm-up round cost a 1M-primitive campaign a view per defense)."""
        views = [0] if not self.renderer.batched else None
        configs = {d: (lambda d=d: self._render_guarded(d, views)) for d in dict.fromkeys(defenses)}
        samples = interleaved_samples(
            configs,
            repeats,
            budget_s=self.VIEW_TIME_BUDGET_S,
            least=self.VIEW_TIME_LEAST_ROUNDS,
            warm_up=False,
        )
        per = 1 if views else self.k
        return {d: [1e3 * s / per for s in v] for d, v in samples.items()}

    def _render_guarded(self, defense: str, views=None):
        """`views` (all K by default) of the model as it is now, under the defense's in-pipeline
        clamp, waited for (the clean model's intersection buffers already hold its lists)."""
        r, g = self.renderer, self.gpu
        r.set_guard(None, self._guard_mask(defense))
        try:
            g.submit(r.encode(g.device.create_command_encoder(), views))
            g.sync()
        finally:
            r.set_guard(None, 0)

    def measure_current(self, defense: str = "none") -> dict:
        """GPU metrics of the current model against the current clean reference (the frame stays
        on the GPU). clamps: the guard's clamps beyond the reference's own (negative when an upset
        turns a clean non-finite value into one inside the box)."""
        clamps = sum(self._run_guarded(defense).values()) - self.reference_clamps
        raw = self.metrics.run_dense(self.clean_buf, self.renderer.image, 1)
        out = {
            k: (v[0].item() if hasattr(v, "__len__") else v) for k, v in summarize(raw, self.width, self.height).items()
        }
        out["clamps"] = clamps
        return out

    def inject(self, sites, defense: str = "none") -> dict:
        """Apply the site(s), render the K views under `defense`, measure, restore. One record."""
        sites = [sites] if isinstance(sites, Site) else list(sites)
        self.use_reference(defense)
        handle = self.apply(sites, defense)
        try:
            m = self.measure_current(defense)
        finally:
            self.undo(handle)
        names = {fault_name(s, self.precision) for s in sites}
        rec = {
            "scene": self.scene,
            "n_primitives": self.n,
            "precision": self.precision,
            "profile": self.profile,
            "defense": defense,
            "k": len(sites),
            "fault": names.pop() if len(names) == 1 else "mixed",
        }
        if len(sites) == 1:
            s = sites[0]
            rec.update(
                field=s.field,
                primitive=s.primitive,
                component=s.component,
                bit=s.record_bit,
                bit_class=site_bit_class(s, self.precision),
                clean_value=self.clean_value(s),
                corrupted_value=self.corrupted_value(s),
            )
        else:
            fields = {s.field for s in sites}
            rec.update(
                field=fields.pop() if len(fields) == 1 else "mixed",
                primitive=-1,
                component=-1,
                bit=-1,
                bit_class="mixed",
                clean_value=float("nan"),
                corrupted_value=float("nan"),
            )
        rec.update(m)
        rec["catastrophic"] = bool(catastrophic(rec["footprint"], rec["nonfinite"]))
        return rec

    def worst_primitive(
        self,
        field: str,
        component: int,
        bits,
        sample: int = 32,
        seed: int = 0,
        defense: str = "none",
        op: str = "flip",
        value: int = 0,
    ) -> tuple[int, dict]:
        """The primitive whose flip does the most harm (footprint, then peak error) among a sample."""
        rng = np.random.default_rng(seed)
        cand = rng.choice(self.n, size=min(sample, self.n), replace=False)
        sites = [self.site(field, int(p), component, bits, op, value) for p in cand]
        if self.incremental:
            recs = self.evaluate(sites, (defense,))  # same numbers as inject, without full re-renders
        else:
            recs = [self.inject(s, defense) for s in sites]
        best, best_rec = -1, None
        for p, rec in zip(cand, recs):
            score = (rec["nonfinite"], rec["footprint"], rec["peak_error"])
            if best_rec is None or score > (best_rec["nonfinite"], best_rec["footprint"], best_rec["peak_error"]):
                best, best_rec = int(p), rec
        return best, best_rec

    # ---- batched single upsets (incremental path) --------------------------------------------------
    @property
    def evaluator(self):
        if self._evaluator is None:
            from seuwgpu.faults.incremental import IncrementalEvaluator

            # a CPU adapter gains nothing from huge batches; a GPU needs them to stay busy (the
            # evaluator shrinks a batch to what one binding holds for its metrics). Two batches
            # in flight (faults/incremental.py): the host prepares one while the device runs the
            # other (on lavapipe too: docs/renderer.md "Measurements").
            if self.gpu.is_cpu:
                self._evaluator = IncrementalEvaluator(self, 256, max_entries=8192, lanes=2)
            else:
                entries = int(min(65536, self.gpu.max_binding // (256 * 16)))
                self._evaluator = IncrementalEvaluator(self, 2048, max_entries=entries, lanes=2)
        return self._evaluator

    def primitive_bits(self, prims) -> np.ndarray:
        """Clean stored bits [M, ncomp] of whole primitives."""
        prims = np.asarray(prims, dtype=np.int64)
        nc = self.layout.ncomp
        flat = self.stored_bits(np.repeat(prims, nc), np.tile(np.arange(nc), prims.size))
        return flat.reshape(prims.size, nc)

    def variant_bits(self, sites: list[Site], defense: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(primitives [M], effective stored bits [M, ncomp] as `defense` reads them, guard masks [M])."""
        prims = np.array([s.primitive for s in sites], dtype=np.int64)
        comps = np.array([s.flat_component() for s in sites], dtype=np.int64)
        clean = self.primitive_bits(prims)
        rows = np.arange(len(sites))
        return prims, *self.variant_rows(prims, clean, comps, apply_sites(clean[rows, comps], sites), defense)

    def variant_rows(self, prims, clean: np.ndarray, comps: np.ndarray, values: np.ndarray, defense: str):
        """(effective bits [M, ncomp], guard masks [M]) of primitives `prims` (clean bits `clean`)
        whose component `comps[i]` now holds the stored pattern `values[i]`, as `defense` reads them."""
        bits = clean.copy()
        bits[np.arange(len(comps)), comps] = values
        d = dfn.get(defense)
        bits = d.read_variants(clean, bits, self.precision, self.degree, self.box, prims, self._state(d))
        return bits, np.full(len(comps), self._guard_mask(defense), dtype=np.int64)

    def partner_drops(self, prims, clean: np.ndarray, comps: np.ndarray, values: np.ndarray, defense: str):
        """[M] bool: the variants of variant_rows whose frame also drops a clean primitive beside
        the hit one (Defense.drops_partner: a per-word frame code's pair partner, when the model has
        it). The incremental evaluator draws one primitive a variant, so these frames are drawn
        whole (pair_drop_metrics)."""
        bits = clean.copy()
        bits[np.arange(len(comps)), comps] = values
        drops = dfn.get(defense).drops_partner(clean, bits, self.precision, self.degree)
        return drops & ((np.asarray(prims, np.int64) ^ 1) < self.n)

    def pair_drop_metrics(self, prims, defense: str) -> dict:
        """Metrics of the frames that drop primitive p and its word partner p ^ 1 (both culled,
        nothing else changed) for each p of `prims`, by full renders, one a pair: every detected
        upset of a pair draws that same frame."""
        pairs, inv = np.unique(np.asarray(prims, np.int64) >> 1, return_inverse=True)
        per_pair = []
        for q in pairs:
            both = np.array([2 * q, 2 * q + 1], np.int64)
            base = self.primitive_bits(both)
            handle = self.xor_rows(both, base, cull(base, np.ones(2, bool), self.precision))
            self.flips.apply(handle)
            self._active.append(handle)
            try:
                per_pair.append(self.measure_current(defense))
            finally:
                self.undo(handle)
        keys = ("footprint", "footprint_max", "peak_error", "psnr", "ssim", "nonfinite", "clamps")
        return {k: np.array([per_pair[i][k] for i in inv]) for k in keys}

    def _arm_metrics(self, prims, rows: np.ndarray, regions, drawn: list) -> dict:
        """Metrics of one arm's variants (drawn stored bits `rows`). A variant that draws the same
        bits as an earlier arm's, against the same clean reference, is the same frame: its metrics
        are copied from that arm instead of re-composited (ECC and duplication correct most upsets,
        and the guards leave most unclamped, so an arm often repeats another's frames). `drawn`
        collects (reference mask, rows, metrics) per arm."""
        if len(rows) == 0:  # no sites: empty columns
            empty = {key: np.zeros(0) for key in ("footprint", "footprint_max", "peak_error", "psnr", "ssim")}
            empty["nonfinite"] = np.zeros(0, bool)
            for P in regions:
                empty[f"regions_pred_{P}"] = empty[f"regions_meas_{P}"] = np.zeros(0, np.int64)
                empty[f"regions_pred_frame_{P}"] = empty[f"regions_meas_frame_{P}"] = np.zeros(0)
            return empty
        todo = np.ones(len(rows), dtype=bool)
        source = np.full(len(rows), -1, dtype=np.int64)
        for j, (mask, rows0, _) in enumerate(drawn):
            if mask == self._ref_mask:
                same = todo & (rows0 == rows).all(axis=1)
                source[same], todo[same] = j, False
        fresh = self.evaluator.evaluate_rows(prims[todo], rows[todo], regions) if todo.any() else None
        template = fresh if fresh is not None else drawn[int(source[0])][2]
        m = {}
        for key, ref in template.items():
            col = np.empty(len(rows), dtype=np.asarray(ref).dtype)
            if fresh is not None:
                col[todo] = fresh[key]
            for j in np.unique(source[~todo]):
                sel = source == j
                col[sel] = drawn[int(j)][2][key][sel]
            m[key] = col
        drawn.append((self._ref_mask, rows, m))
        return m

    def evaluate(self, sites: list[Site], defenses=("none",), regions=()) -> list[dict]:
        """Records (dicts) for single-value sites under each defense; see evaluate_frame."""
        return self.evaluate_frame(sites, defenses, regions).to_dict("records")

    def evaluate_frame(self, sites: list[Site], defenses=("none",), regions=()) -> pd.DataFrame:
        """Records for single-value sites under each defense (paired: same sites for every arm,
        rows defense-major), by incremental re-compositing, built column-wise."""
        sites = list(sites)
        m_sites = len(sites)
        comps = np.array([s.flat_component() for s in sites], dtype=np.int64)
        base = {
            "scene": [self.scene] * m_sites,
            "n_primitives": np.full(m_sites, self.n, np.int64),
            "precision": [self.precision] * m_sites,
            "profile": [self.profile] * m_sites,
            "field": [s.field for s in sites],
            "primitive": np.array([s.primitive for s in sites], np.int64),
            "component": np.array([s.component for s in sites], np.int64),
            "bit": np.array([s.record_bit for s in sites], np.int64),
            "bit_class": [site_bit_class(s, self.precision) for s in sites],
            "fault": [fault_name(s, self.precision) for s in sites],
            "k": np.ones(m_sites, np.int64),
        }
        frames = []
        prims = np.array([s.primitive for s in sites], dtype=np.int64)
        clean = self.primitive_bits(prims)  # the hit primitives' clean rows, read once for every arm
        clean.flags.writeable = False  # shared by the arms: a twin writing into it would raise
        clean_b = clean[np.arange(m_sites), comps]
        corrupt_b = apply_sites(clean_b, sites)
        # clean_value / corrupted_value: the stored value before and after the upset, whatever the
        # defense then reads (the same in every arm, and equal to inject()'s)
        clean_v = encoding.from_bits(clean_b, self.precision)
        corr_v = encoding.from_bits(corrupt_b, self.precision)
        drawn = []  # (reference mask, drawn rows, metrics) of the arms evaluated so far
        for d in defenses:
            dfn.check_defense(d)
            bits, gm = self.variant_rows(prims, clean, comps, corrupt_b, d)
            pair = self.partner_drops(prims, clean, comps, corrupt_b, d)
            refusal = dfn.partner_drop_refusal("regions (sort-first contamination)", d, self.precision)
            if regions and refusal:
                raise ValueError(refusal)
            self.use_reference(d)
            rows, clamps = self.evaluator.drawn_rows(bits, gm, clean if gm.any() else None)
            m = dict(self._arm_metrics(prims, rows, regions, drawn), clamps=clamps)
            if pair.any():  # drawn whole (the twin's rows stay as drawn: an arm repeating them is the same)
                whole = self.pair_drop_metrics(prims[pair], d)
                m = {k: np.array(v, copy=True) for k, v in m.items()}
                for k, v in whole.items():
                    m[k][pair] = v
            cols = dict(base)
            with np.errstate(invalid="ignore"):  # NaN values are data here
                cols.update(
                    defense=[d] * m_sites,
                    clean_value=clean_v.astype(np.float64),
                    corrupted_value=corr_v.astype(np.float64),
                )
            for key in ("footprint", "footprint_max", "peak_error", "psnr", "ssim"):
                cols[key] = np.asarray(m[key], np.float64)
            cols["nonfinite"] = np.asarray(m["nonfinite"], bool)
            cols["clamps"] = np.asarray(m["clamps"], np.int64)
            cols["catastrophic"] = np.asarray(catastrophic(cols["footprint"], cols["nonfinite"]), bool)
            for P in regions:
                cols[f"regions_pred_{P}"] = np.asarray(m[f"regions_pred_{P}"], np.int64)
                cols[f"regions_meas_{P}"] = np.asarray(m[f"regions_meas_{P}"], np.int64)
                for what in ("pred", "meas"):  # the share one view's frame reaches, mean over views
                    cols[f"regions_{what}_frame_{P}"] = np.asarray(m[f"regions_{what}_frame_{P}"], np.float64)
            frames.append(pd.DataFrame(cols))
        return pd.concat(frames, ignore_index=True)
