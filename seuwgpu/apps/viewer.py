"""The interactive viewer's state machine: an Engine, an orbit camera and live faults, no window.

`ViewerState` is pure logic: every action of the viewer window (`viewer_window.ViewerApp`) is a
method here, so tests drive it headless and check the frames it produces. `frame()` renders the
current view at the window size with the same WGSL pipeline as the campaigns and returns the
RGBA8 image to show plus a readout (frame time, footprint and PSNR against the clean render of
the same camera, guard clamps and alert, active fault sites).

Choices (see also the README):
- Faults are XORs on the stored words in the GPU buffer (`Engine.apply`) and stay there until
  undone. The guard is the in-pipeline clamp (`Engine.render_current(defense)`): memory keeps
  the corrupted word, so toggling the guard is instant and exact in both directions.
- The clean render of the current camera: rendered with the faults undone (XOR them off, render,
  XOR them back: two tiny scatter submits) and cached per camera and size. It costs one extra
  render only when the view changes while faults are active, and no second copy of the model.
  With no active fault the current render *is* the clean render. PSNR/footprint follow
  `metrics.py`: changed = |d| > 1/255 in any channel or non-finite; PSNR over the display-
  referred images (clipped to [0, 1]), undefined (NaN) when a changed pixel is non-finite, as in
  the records. A model that itself holds NaN/Inf values the guard clamps is measured, when
  guarded, against its guarded clean render (the Engine's reference rule), and the alert fires
  on clamps beyond the clean model's own (the Engine's GuardMonitor).
- "Worst of a sample" picks, among `sample` random primitives, the one whose flip harms the
  current view most (Engine.worst_primitive, defense none) on a low-resolution probe of the
  current camera (longest side `probe` px), so it stays interactive on CPU Vulkan.
- Storm: k uniform upsets (faults.uniform_upsets, the whole stored bit budget) per frame;
  accumulating (they stay) or transient (each frame's upsets replace the previous frame's).
- Defense: every registered defense. The guards clamp in the pipeline; the others are drawn as
  they read the faulted words (`Engine.apply(sites, defense)` on a copy of the faults, the raw
  faults XORed back after the frame). A check defense checks before every `check_every`-th frame:
  from the first check after the faults last changed its repair stands (it is written back), and
  until then the frame shows the faults as stored (its exposure window).
- Guard alert: the guard counts clamped components per frame; a clean model never clamps (its
  box is its own min/max), so the alert fires when clamps > `clamp_threshold` (default 0; the
  Engine's GuardMonitor gets the same threshold and also logs a GuardAlert warning). With the
  guard off nothing is clamped or counted.
- Camera: turntable orbit around a target about an up axis (z for the embedded scenes; a model
  file's format convention, y for SPZ, -y for PLY, or --up), framed by model/framing.py like
  every command; pinhole with `fov_deg` across the shorter image side, so resizing the window
  never distorts or crops the view. With the capture's cameras (`views`), `step_view` shows
  them one by one, letterboxed into the window (the capture's frame scaled to fit, centred);
  any orbit, pan or zoom goes back to the orbit camera.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.sites import Site, uniform_upsets
from seuwgpu.model import encoding
from seuwgpu.model.cameras import Camera, look_at
from seuwgpu.model.fields import Model, field_components, stored_fields
from seuwgpu.model.framing import bounding_region, framing_distance, orbit_basis

# every registered defense ("off": none); the check defenses check every `check_every` frames
GUARD_MODES = {"off": "none", **{d: d for d in dfn.DEFENSES if d != "none"}}
MIN_SIZE = 16  # smallest render (the GPU metrics used by worst-of-sample need >= 7 px)


# ------------------------------------------------------------------------------------------------
# Orbit camera
# ------------------------------------------------------------------------------------------------
@dataclass
class OrbitCamera:
    """Turntable camera around `target` about the `up` axis ('+z' for the embedded scenes, the
    file format's convention for a model file). Angles in degrees; `fov_deg` spans the shorter
    image side. The same conventions as `framing.orbit_views` (eye = target + distance *
    (cos el cos az e1 + cos el sin az e2 + sin el up))."""

    target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distance: float = 4.0
    azimuth_deg: float = 30.0
    elevation_deg: float = 25.0
    fov_deg: float = 40.0
    up: str = "+z"

    def __post_init__(self):
        self.target = np.asarray(self.target, dtype=np.float64).reshape(3).copy()
        self.basis = orbit_basis(self.up)
        self._home = (self.target.copy(), self.distance, self.azimuth_deg, self.elevation_deg, self.fov_deg)

    @classmethod
    def for_scene(cls, name: str) -> OrbitCamera:
        from seuwgpu.model.captures import capture_model
        from seuwgpu.model.scenes import is_capture, scene_spec

        if is_capture(name):
            return cls.fit(capture_model(name).means, up="+y")
        s = scene_spec(name)
        # scene_cameras' fov is across the image width of square views: the same framing here
        return cls(np.asarray(s.target, float), s.radius, 30.0, s.elevation_deg, s.fov_x_deg)

    @classmethod
    def fit(cls, means: np.ndarray, up: str = "+z", fov_deg: float = 40.0, log_scales=None) -> OrbitCamera:
        """Frame a model of unknown extent the way every command does (model/framing.py)."""
        region = bounding_region(means, log_scales)
        return cls(region.center, framing_distance(region.radius, fov_deg), 30.0, 25.0, fov_deg, up)

    def reset(self):
        t, self.distance, self.azimuth_deg, self.elevation_deg, self.fov_deg = self._home
        self.target = t.copy()

    def eye(self) -> np.ndarray:
        az, el = np.radians(self.azimuth_deg), np.radians(self.elevation_deg)
        e1, e2, u = self.basis
        return self.target + self.distance * (
            np.cos(el) * np.cos(az) * e1 + np.cos(el) * np.sin(az) * e2 + np.sin(el) * u
        )

    def focal(self, width: int, height: int) -> float:
        return 0.5 * min(width, height) / np.tan(np.radians(self.fov_deg) / 2)

    def camera(self, width: int, height: int) -> Camera:
        f = self.focal(width, height)
        K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=np.float32)
        return Camera(look_at(self.eye(), self.target, self.basis[2]), K, int(width), int(height))

    # ---- mouse gestures (pixels) ----------------------------------------------------------------
    def orbit(self, dx: float, dy: float, deg_per_px: float = 0.3):
        """Drag right/down: the model follows the mouse (the camera turns the other way)."""
        self.azimuth_deg = (self.azimuth_deg - deg_per_px * dx) % 360.0
        self.elevation_deg = float(np.clip(self.elevation_deg + deg_per_px * dy, -89.0, 89.0))

    def pan(self, dx: float, dy: float, width: int, height: int):
        """Drag: the point under the mouse (at the target's depth) follows the mouse."""
        R = look_at(self.eye(), self.target, self.basis[2])[:3, :3].astype(np.float64)  # rows: right, down, forward
        s = self.distance / self.focal(width, height)
        self.target = self.target - s * (dx * R[0] + dy * R[1])

    def zoom(self, factor: float):
        """factor > 1 moves away, < 1 closer."""
        if np.isfinite(factor) and factor > 0:
            self.distance = float(np.clip(self.distance * factor, 1e-4, 1e6))


def letterbox(cam: Camera, width: int, height: int) -> Camera:
    """`cam` drawn into a width x height image: its frame scaled to fit and centred, the margins
    showing what lies beyond it."""
    s = min(width / cam.width, height / cam.height)
    K = cam.K.astype(np.float64) * np.array([[s], [s], [1.0]])
    K[0, 2] += 0.5 * (width - cam.width * s)
    K[1, 2] += 0.5 * (height - cam.height * s)
    return Camera(cam.viewmat, K, int(width), int(height))


# ------------------------------------------------------------------------------------------------
# Viewer state
# ------------------------------------------------------------------------------------------------
@dataclass(eq=False)  # compared by identity (handles hold numpy arrays)
class FaultGroup:
    """Sites applied together (one action); `handles` are the Engine's undo handles."""

    label: str
    sites: list
    handles: list = field(default_factory=list)


def site_text(s: Site, precision: str) -> str:
    cls = encoding.bit_class(precision, s.bit) if s.bit >= 0 else "multi"
    bits = s.bit if s.bit >= 0 else "+".join(map(str, s.bits))
    return f"{s.field}[{s.primitive}][{s.component}] bit {bits} ({cls})"


class ViewerState:
    """Everything the viewer does, without a window. Units: sizes in physical pixels."""

    def __init__(
        self,
        model: Model,
        precision: str = "fp32",
        size=(800, 600),
        scene: str = "",
        orbit: OrbitCamera | None = None,
        sample: int = 16,
        probe: int = 128,
        seed: int = 0,
        clamp_threshold: int = 0,
        gpu=None,
        views: list[Camera] | None = None,
        view_names: list[str] | None = None,
        profile: str = "strict",
    ):
        from seuwgpu.gpu.device import get_gpu

        self.model = model
        self.scene = scene
        self.profile = profile  # the renderer's rules for corrupted values (docs/renderer.md)
        self.gpu = gpu or get_gpu()
        self.orbit = orbit or OrbitCamera.fit(model.means, log_scales=model.log_scales)
        self.views = list(views or [])
        self.view_names = list(view_names or [str(i) for i in range(len(self.views))])
        self.view_index: int | None = None  # a capture view shown, or None: the orbit camera
        self.size = self._check_size(size)
        self.sample, self.probe, self.seed = int(sample), int(probe), int(seed)
        self.clamp_threshold = int(clamp_threshold)
        self.guard = "off"
        self.check_every = 1
        self.frame_count = 0  # frames drawn: a check defense checks when frame_count % check_every == 0
        self._checked_faults = None  # the faults (their key) a check has repaired
        self.heatmap = False
        self.groups: list[FaultGroup] = []
        self.storm: dict | None = None  # {"k", "accumulate", "steps", "group"}
        self.rng = np.random.default_rng(seed)
        self.last_image: np.ndarray | None = None  # [H, W, 4] float32 of the last frame
        self.clean_image: np.ndarray | None = None  # [H, W, 4] float32, clean render of _clean_key
        self.readout: dict = {}
        self.status = ""
        self.dirty = True
        self._build_engine(encoding.check_precision(precision))

    # ---- set-up -----------------------------------------------------------------------------------
    @staticmethod
    def _check_size(size) -> tuple[int, int]:
        w, h = (int(v) for v in size)
        return max(MIN_SIZE, w), max(MIN_SIZE, h)

    def _build_engine(self, precision: str):
        from seuwgpu.faults.engine import Engine

        self.engine = None  # free the old model's GPU buffers before making the new ones
        self.engine = Engine(
            self.model, [self.camera()], precision, gpu=self.gpu, scene=self.scene, profile=self.profile
        )
        self.engine.monitor.threshold = self.clamp_threshold  # the engine's guard health signal, at our threshold
        self.precision = precision
        self.groups = []
        if self.storm is not None:
            self.storm["group"] = None
        self.clean_image = self.engine.clean_rgba[0].copy()
        self._clean_key = (self._view_key(self.camera()), 0)  # the engine's reference: unguarded
        self.dirty = True

    @property
    def n(self) -> int:
        return self.model.n

    @property
    def defense(self) -> str:
        return GUARD_MODES[self.guard]

    def camera(self, size: tuple[int, int] | None = None) -> Camera:
        """The view shown, at the window's size or `size`: the orbit camera, or the capture view
        letterboxed into it."""
        w, h = size or self.size
        if self.view_index is None:
            return self.orbit.camera(w, h)
        return letterbox(self.views[self.view_index], w, h)

    @staticmethod
    def _view_key(cam: Camera):
        return cam.width, cam.height, cam.viewmat.tobytes(), cam.K.tobytes()

    # ---- camera actions ---------------------------------------------------------------------------
    def orbit_by(self, dx, dy):
        self.view_index = None
        self.orbit.orbit(dx, dy)
        self.dirty = True

    def pan_by(self, dx, dy):
        self.view_index = None
        self.orbit.pan(dx, dy, *self.size)
        self.dirty = True

    def zoom_by(self, factor):
        self.view_index = None
        self.orbit.zoom(factor)
        self.dirty = True

    def reset_view(self):
        self.view_index = None
        self.orbit.reset()
        self.dirty = True

    def step_view(self, step: int = 1):
        """Show the next (or, step -1, the previous) capture view; from the orbit camera the
        first (or last)."""
        if not self.views:
            self.status = "no capture views (open the model with --cameras)"
            return
        n = len(self.views)
        if self.view_index is None:
            self.view_index = 0 if step > 0 else n - 1
        else:
            self.view_index = (self.view_index + step) % n
        self.status = f"capture view {self.view_index + 1}/{n}: {self.view_names[self.view_index]}"
        self.dirty = True

    def orbit_view(self):
        """Back to the orbit camera."""
        self.view_index = None
        self.dirty = True

    def resize(self, width, height):
        size = self._check_size((width, height))
        if size != self.size:
            self.size = size
            self.dirty = True

    # ---- faults -----------------------------------------------------------------------------------
    @property
    def active_sites(self) -> list[Site]:
        return [s for g in self.groups for s in g.sites]

    def _add(self, label: str, sites: list[Site]) -> FaultGroup:
        g = FaultGroup(label, list(sites))
        g.handles.append(self.engine.apply(g.sites, "none"))
        self.groups.append(g)
        self.dirty = True
        return g

    def _remove(self, g: FaultGroup):
        for h in reversed(g.handles):
            self.engine.undo(h)
        self.groups.remove(g)
        self.dirty = True

    def bits_per_value(self) -> int:
        return encoding.bits_per_value(self.precision)

    def worst_primitive(self, field: str, component: int, bits) -> tuple[int, dict]:
        """The primitive of a random sample whose flip harms the current view most (no defense),
        scored on a probe of the current camera (longest side `probe` px)."""
        e = self.engine
        sample = max(1, min(self.sample, self.n))
        w, h = self.size
        s = min(1.0, self.probe / max(w, h))
        probe = self.camera((max(MIN_SIZE, round(w * s)), max(MIN_SIZE, round(h * s))))  # the view shown, smaller
        active = list(self.groups)
        e.undo_all()
        try:
            e.set_cameras([probe])
            prim, rec = e.worst_primitive(field, component, bits, sample=sample, seed=self.seed)
            e.set_cameras([self.camera()])  # renders the clean view: keep it
            self.clean_image = e.clean_rgba[0].copy()
            self._clean_key = (self._view_key(self.camera()), 0)
        finally:
            for g in active:
                g.handles = [e.apply(g.sites, "none")]
        return prim, rec

    def inject(self, field: str, bit, primitive: int | None = None, component: int = 0) -> Site:
        """Flip `bit` (an int, or several bits of one value) of one stored component; primitive
        None = the worst of a sample for the current view."""
        if primitive is None:
            self.engine.site(field, 0, component, bit)  # validate before the search
            primitive, _ = self.worst_primitive(field, component, bit)
        site = self.engine.site(field, primitive, component, bit)
        self._add("flip", [site])
        self.status = "injected " + site_text(site, self.precision)
        return site

    def inject_random(self, k: int) -> list[Site]:
        """k distinct uniform upsets over the whole stored bit budget."""
        k = int(k)
        if k < 1:
            raise ValueError("k must be at least 1")
        sites = uniform_upsets(self.model, self.precision, k, self.rng)
        self._add(f"random x{k}", sites)
        self.status = f"injected {k} random upsets"
        return sites

    def storm_start(self, k: int, accumulate: bool = True):
        k = int(k)
        if k < 1:
            raise ValueError("k must be at least 1")
        self.storm_stop()
        self.storm = {"k": k, "accumulate": bool(accumulate), "steps": 0, "group": None}
        self.status = f"storm: {k} upsets per frame, {'accumulating' if accumulate else 'transient'}"

    @property
    def storm_running(self) -> bool:
        return self.storm is not None

    def storm_step(self) -> list[Site]:
        """One storm frame's upsets (frame() calls this while the storm runs)."""
        st = self.storm
        if st is None:
            raise RuntimeError("no storm is running (storm_start first)")
        sites = uniform_upsets(self.model, self.precision, st["k"], self.rng)
        g = st["group"]
        if g is not None and g not in self.groups:
            g = None  # undone meanwhile
        if g is not None and not st["accumulate"]:
            self._remove(g)
            g = None
        if g is None:
            g = st["group"] = self._add("storm", sites)
        else:
            g.handles.append(self.engine.apply(sites, "none"))
            g.sites.extend(sites)
        st["steps"] += 1
        self.dirty = True
        return sites

    def storm_stop(self):
        """Stop the storm. Transient upsets vanish with it; accumulated ones stay (undo_all)."""
        st, self.storm = self.storm, None
        if st and not st["accumulate"] and st["group"] in self.groups:
            self._remove(st["group"])
        self.dirty = True

    def undo_all(self):
        self.engine.undo_all()
        self.groups = []
        if self.storm is not None:
            self.storm["group"] = None
        self.status = "all faults undone"
        self.dirty = True

    def set_guard(self, mode: str):
        if mode not in GUARD_MODES:
            raise ValueError(f"unknown guard mode {mode!r}; expected one of {', '.join(GUARD_MODES)}")
        self.guard = mode
        self.dirty = True

    def set_check_every(self, frames: int):
        """The check schedule of the check defenses: check every `frames` frames (>= 1)."""
        if int(frames) < 1:
            raise ValueError(f"a check schedule is every S >= 1 frames (got {frames})")
        self.check_every = int(frames)
        self.dirty = True

    def _faults_key(self):
        return tuple((id(g), len(g.sites)) for g in self.groups)

    def _render_defended(self):
        """The current faults drawn under the defense: the pipeline's clamp for the guards; for
        the others what they read (a check defense: once checked since the faults changed)."""
        e, d = self.engine, dfn.get(self.defense)
        after_repair = False
        if d.frame_check:  # checked inside the frame: the faults' first frame drops, then repaired
            key = self._faults_key()
            after_repair = getattr(self, "_framed_faults", None) == key  # reloaded before this frame
            self._framed_faults = key
        if d.checked:
            key = self._faults_key()
            if self.frame_count % self.check_every == 0:
                self._checked_faults = key  # the check runs before this frame; its repair stays
            repaired = self._checked_faults == key
        else:
            repaired = True
        self.frame_count += 1
        if not self.groups or not repaired or d.reads_stored_bits:
            return e.render_current(self.defense)
        active = list(self.groups)
        e.undo_all()
        handle = e.apply([s for g in active for s in g.sites], self.defense, after_repair=after_repair)
        try:
            return e.render_current(self.defense)
        finally:
            e.undo(handle)
            for g in active:
                g.handles = [e.apply(g.sites, "none")]

    def set_heatmap(self, on: bool):
        self.heatmap = bool(on)
        self.dirty = True

    def toggle_heatmap(self):
        self.set_heatmap(not self.heatmap)

    def set_precision(self, precision: str):
        """Rebuild the Engine at another stored precision. Active faults are dropped (a site's
        bit means something else in another format); a running storm goes on."""
        precision = encoding.check_precision(precision)
        if precision != self.precision:
            self._build_engine(precision)
            self.status = f"precision {precision}: faults cleared"

    # ---- frames -----------------------------------------------------------------------------------
    def needs_frame(self) -> bool:
        return self.dirty or self.storm_running or self.last_image is None

    def _render_clean(self, defense: str = "none") -> np.ndarray:
        """Clean render of the renderer's current camera under `defense`'s in-pipeline guard:
        faults XORed off, render, XORed back."""
        e = self.engine
        active = list(self.groups)
        e.undo_all()
        try:
            img = e.render_current(defense)[0][0].copy()
        finally:
            for g in active:
                g.handles = [e.apply(g.sites, "none")]
        return img

    def frame(self) -> tuple[np.ndarray, dict]:
        """Advance a running storm, render the current view and measure it against the clean
        render of the same camera. Returns ([H, W, 4] uint8 RGBA to show, readout)."""
        if self.storm_running:
            self.storm_step()
        t0 = time.perf_counter()
        cam = self.camera()
        # the clean reference: guarded only where the guard changes the clean model (its NaN/Inf)
        ref_mask = self.engine.reference_mask(self.defense)
        ref = self.defense if ref_mask else "none"
        key = (self._view_key(cam), ref_mask)
        self.engine.renderer.set_cameras([cam])  # same size: only the view parameters change
        clean_render = False  # an extra render of the clean model was needed for this frame
        if key != self._clean_key and self.groups:
            self.clean_image, self._clean_key, clean_render = self._render_clean(ref), key, True
        img, clamps = self._render_defended()
        img = img[0]
        if key != self._clean_key:  # no active fault: this render is the clean one
            self.clean_image, self._clean_key = img, key
        frame_ms = 1000.0 * (time.perf_counter() - t0)
        self.last_image = img
        self.readout = self._measure(img, self.clean_image, clamps, frame_ms)
        self.readout["clean_render"] = clean_render
        # what the user has seen: frames drawn while faults were active, and how many were
        # catastrophic (footprint > 1% or a non-finite pixel), since the faults or the defense changed
        tally = (self.defense, self._faults_key())
        if getattr(self, "_tally_key", None) != tally:
            self._tally_key, self.seen = tally, [0, 0]
        if self.groups:
            self.seen[0] += 1
            self.seen[1] += bool(self.readout["footprint"] > 0.01 or self.readout["nonfinite_pixels"])
        self.readout["seen_frames"], self.readout["seen_catastrophic"] = self.seen
        self.dirty = False
        return self.compose(img, self.clean_image), self.readout

    def _measure(self, img, clean, clamps: dict, frame_ms: float) -> dict:
        from seuwgpu.metrics.image import changed_pixels, display

        f, c = img[..., :3], clean[..., :3]
        nonfin = ~np.isfinite(f).all(axis=-1)
        if img is clean:  # no active fault: this render is the clean one (skips ~6 ms a frame)
            changed, mse = np.zeros(f.shape[:2], bool), 0.0
        else:
            changed = changed_pixels(f, c)
            mse = float(np.mean((display(f).astype(np.float64) - display(c)) ** 2))
        if (changed & nonfin).any():  # display-referred PSNR of a non-finite frame is undefined
            mse = float("nan")
        total = int(sum(clamps.values()))
        monitor = self.engine.monitor
        sites = self.active_sites
        guarded = bool(dfn.get(self.defense).guard_fields)  # only a guard clamps and alerts
        return {
            "frame_ms": frame_ms,
            "size": self.size,
            "footprint": float(changed.mean()),
            "changed_pixels": int(changed.sum()),
            "psnr": float("inf") if mse == 0 else float(10 * np.log10(1.0 / mse)),  # NaN stays NaN
            "nonfinite_pixels": int(nonfin.sum()),
            "guard": self.guard,
            "clamps": total,
            "clamps_per_field": dict(clamps),
            # clamps beyond the clean model's own (its NaN/Inf), as the Engine's monitor counts them
            "alert": guarded and monitor.alert,
            "alert_message": monitor.message if guarded else "",
            "check_every": self.check_every if dfn.get(self.defense).checked else None,
            "active_sites": len(sites),
            "sites": [site_text(s, self.precision) for s in sites[-6:]],
            "precision": self.precision,
            "storm": None if self.storm is None else {k: v for k, v in self.storm.items() if k != "group"},
            "heatmap": self.heatmap,
        }

    def compose(self, img: np.ndarray, clean: np.ndarray) -> np.ndarray:
        """What the window shows: the display-referred render, or the heat map of |render - clean|
        (log scale from 1/255 to 1 over a dimmed grey copy of the clean view; non-finite pixels
        magenta)."""
        from seuwgpu.metrics.image import changed_pixels, display

        h, w = img.shape[:2]
        out = np.empty((h, w, 4), np.uint8)
        out[..., 3] = 255
        if not self.heatmap:
            out[..., :3] = (display(img[..., :3]) * 255.0 + 0.5).astype(np.uint8)
            return out
        f, c = img[..., :3], clean[..., :3]
        dd = np.abs(display(f) - display(c)).max(axis=-1)
        changed = changed_pixels(f, c)
        nonfin = ~np.isfinite(f).all(axis=-1)
        grey = display(c).mean(axis=-1, keepdims=True) * 0.3 * 255.0
        rgb = np.repeat(grey, 3, axis=-1)
        v = np.clip(np.log10(np.maximum(dd, 1.0 / 255.0) * 255.0) / np.log10(255.0), 0.0, 1.0)
        lut = _heat_lut()
        rgb[changed] = lut[(64 + v[changed] * 191).astype(np.int64)]
        rgb[nonfin] = (255, 0, 255)
        out[..., :3] = (rgb + 0.5).astype(np.uint8)
        return out

    def field_components(self, field: str) -> int:
        return field_components(field, self.model.sh_degree)

    def stored_fields(self) -> list[str]:
        """The fields the model stores (no sh_rest at SH degree 0): what the panel offers."""
        return stored_fields(self.model.sh_degree)


_LUT = None


def _heat_lut() -> np.ndarray:
    global _LUT
    if _LUT is None:
        try:
            from matplotlib import colormaps

            _LUT = colormaps["inferno"](np.linspace(0, 1, 256))[:, :3] * 255.0
        except Exception:  # matplotlib missing: a black-red-yellow-white ramp
            t = np.linspace(0, 1, 256)[:, None]
            _LUT = np.clip(np.concatenate([3 * t, 3 * t - 1, 3 * t - 2], axis=1), 0, 1) * 255.0
    return _LUT
