"""The viewer window: a rendercanvas canvas (glfw, or offscreen for headless use) showing
`ViewerState` frames, with a Dear ImGui control panel (imgui-bundle, through wgpu-py's
`wgpu.utils.imgui.ImguiRenderer`).

Layout: the panel is docked on the left (PANEL_WIDTH logical pixels); the render fills the rest
of the window at its physical resolution (H hides the panel: the render fills the window). The
render is uploaded as an RGBA8 texture and drawn 1:1 with a full-screen triangle into the image
viewport; the swap chain is configured with a non-sRGB format, so pixel values reach the screen
unchanged (3DGS colours are display-referred), and ImGui draws over it in the same frame.

Input: left drag orbits, right or middle drag (or shift + left drag) pans, the wheel zooms.
Keys: R reset view, S screenshot of the window (panel included), P screenshot of the render
only, H hide/show the panel, M heat map, G cycle the defense (off and every registered one), U undo all
faults, Space start/stop the storm, ] / [ (or the arrow keys) next / previous capture view (with
--cameras), O back to the orbit camera, Q or Escape close. Events the panel uses (clicks, typing
in a field) do not reach the view.

Short clicks: Dear ImGui applies at most one press or release of a button per frame (its input
queue trickles them), so a press and release that arrive between two frames need two frames to
become a click. With on-demand drawing nothing else may ask for that second frame, so after any
button or key event the window draws until ImGui's queue is empty (`pending_input`).

The panel keeps its layout while values change: numbers have fixed widths (the font is
monospaced), and the lines that come and go (alert, fault sites, status) have reserved rows.

Frames are rendered only when something changed (camera, faults, guard, size, heat map) or a
storm runs; drawing the panel alone is cheap.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import wgpu

from seuwgpu.apps.viewer import GUARD_MODES, MIN_SIZE, OrbitCamera, ViewerState
from seuwgpu.model import encoding
from seuwgpu.model.fields import FIELDS

PANEL_WIDTH = 340  # logical pixels
PRECISIONS = encoding.PRECISIONS

BLIT_WGSL = """
@group(0) @binding(0) var img: texture_2d<f32>;
@group(0) @binding(1) var samp: sampler;

struct VOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

@vertex
fn vs(@builtin(vertex_index) i: u32) -> VOut {
    // one triangle covering the viewport
    var p = array<vec2<f32>, 3>(vec2<f32>(-1.0, -1.0), vec2<f32>(3.0, -1.0), vec2<f32>(-1.0, 3.0));
    var o: VOut;
    o.pos = vec4<f32>(p[i], 0.0, 1.0);
    o.uv = vec2<f32>(0.5 * (p[i].x + 1.0), 0.5 * (1.0 - p[i].y));
    return o;
}

@fragment
fn fs(v: VOut) -> @location(0) vec4<f32> {
    return vec4<f32>(textureSample(img, samp, v.uv).rgb, 1.0);
}
"""


def _rgb(r, g, b, a=1.0):
    from imgui_bundle import imgui

    return imgui.ImVec4(r, g, b, a)


class ViewerApp:
    """Binds a ViewerState to a canvas: draws frames and the panel, maps input to actions."""

    def __init__(self, state: ViewerState, canvas, screenshot_dir: Path | str = ".", show_panel: bool = True):
        from imgui_bundle import imgui
        from wgpu.utils.imgui import ImguiRenderer

        self.state = state
        self.canvas = canvas
        self.device = state.gpu.device
        self.screenshot_dir = Path(screenshot_dir)
        self.show_panel = bool(show_panel)
        self.frames = 0  # draws (panel included)
        self.renders = 0  # frames rendered by the state
        self.last_rgba: np.ndarray | None = None
        self.last_window: np.ndarray | None = None  # last window capture (RGBA8)
        self._drag = None
        self.pending_input = 0  # frames to draw so that ImGui's queued input (a short click) is applied
        self.button_rects: dict[str, tuple[float, float, float, float]] = {}  # panel buttons (x0, y0, x1, y1)
        self.pending_shots: list[tuple[str, Path | None]] = []
        self.saved: list[Path] = []
        self.after_draw = None  # optional callback(app) at the end of each draw (scripts)

        # swap chain: a non-sRGB format so values reach the screen as they are
        self.ctx = canvas.get_wgpu_context()
        fmt = self.ctx.get_preferred_format(state.gpu.adapter)
        self.format = fmt[:-5] if fmt.endswith("-srgb") else fmt
        try:
            self.ctx.configure(device=self.device, format=self.format, usage="RENDER_ATTACHMENT|COPY_SRC")
            self.can_capture = True
        except Exception:
            self.ctx.configure(device=self.device, format=self.format)
            self.can_capture = False

        self.imgui = ImguiRenderer(self.device, canvas)
        imgui.get_io().set_ini_filename("")
        self.imgui.set_gui(self._gui)
        self._make_blit()
        self._tex = None
        self._tex_size = None
        self._bind = None

        # GUI state of the panel's widgets
        self.ui = {
            "field": FIELDS.index("log_scales"),
            "component": 2,
            "bit": encoding.bits_per_value(state.precision) - 1,
            "worst": True,
            "primitive": 0,
            "k_random": 10,
            "k_storm": 100,
            "accumulate": True,
        }

        canvas.add_event_handler(
            self._wake,
            "pointer_move",
            "pointer_down",
            "pointer_up",
            "wheel",
            "key_down",
            "key_up",
            "char",
            "resize",
            order=-100,
        )
        canvas.add_event_handler(self._on_pointer, "pointer_down", "pointer_move", "pointer_up")
        canvas.add_event_handler(self._on_wheel, "wheel")
        canvas.add_event_handler(self._on_key, "key_down")
        canvas.request_draw(self.draw)

    # ---- GPU objects --------------------------------------------------------------------------
    def _make_blit(self):
        d = self.device
        module = d.create_shader_module(label="viewer-blit", code=BLIT_WGSL)
        self.pipeline = d.create_render_pipeline(
            label="viewer-blit",
            layout="auto",
            vertex={"module": module, "entry_point": "vs", "buffers": []},
            primitive={"topology": wgpu.PrimitiveTopology.triangle_list},
            fragment={"module": module, "entry_point": "fs", "targets": [{"format": self.format}]},
        )
        self.sampler = d.create_sampler(mag_filter="nearest", min_filter="nearest")

    def _upload(self, rgba: np.ndarray):
        h, w = rgba.shape[:2]
        if self._tex_size != (w, h):
            self._tex = self.device.create_texture(
                size=(w, h, 1),
                format=wgpu.TextureFormat.rgba8unorm,
                usage=wgpu.TextureUsage.TEXTURE_BINDING | wgpu.TextureUsage.COPY_DST,
            )
            self._tex_size = (w, h)
            self._bind = self.device.create_bind_group(
                layout=self.pipeline.get_bind_group_layout(0),
                entries=[{"binding": 0, "resource": self._tex.create_view()}, {"binding": 1, "resource": self.sampler}],
            )
        self.device.queue.write_texture(
            {"texture": self._tex}, np.ascontiguousarray(rgba), {"bytes_per_row": 4 * w, "rows_per_image": h}, (w, h, 1)
        )

    # ---- geometry -----------------------------------------------------------------------------
    def pixel_ratio(self) -> float:
        return float(self.canvas.get_pixel_ratio() or 1.0)

    def panel_px(self) -> int:
        return int(round(PANEL_WIDTH * self.pixel_ratio())) if self.show_panel else 0

    def image_area(self) -> tuple[int, int, int, int]:
        """(x, y, width, height) of the render in the window, physical pixels."""
        W, H = self.canvas.get_physical_size()
        x0 = min(self.panel_px(), max(0, W - MIN_SIZE))
        return x0, 0, max(1, W - x0), max(1, H)

    # ---- drawing ------------------------------------------------------------------------------
    def draw(self):
        st = self.state
        x0, y0, aw, ah = self.image_area()
        st.resize(aw, ah)
        if st.needs_frame():
            try:
                self.last_rgba, _ = st.frame()
                self.renders += 1
                self._upload(self.last_rgba)
            except Exception as e:  # keep the window alive, say what went wrong
                st.status = f"render failed: {type(e).__name__}: {e}"
                st.storm_stop()
                st.dirty = False
        tex = self.ctx.get_current_texture()
        W, H = tex.size[0], tex.size[1]
        enc = self.device.create_command_encoder()
        rp = enc.begin_render_pass(
            color_attachments=[
                {
                    "view": tex.create_view(),
                    "resolve_target": None,
                    "clear_value": (0.09, 0.09, 0.1, 1.0),
                    "load_op": wgpu.LoadOp.clear,
                    "store_op": wgpu.StoreOp.store,
                }
            ]
        )
        if self._tex is not None and x0 < W:
            tw, th = self._tex_size
            rp.set_viewport(x0, y0, min(tw, W - x0), min(th, H - y0), 0.0, 1.0)
            rp.set_pipeline(self.pipeline)
            rp.set_bind_group(0, self._bind)
            rp.draw(3, 1, 0, 0)
        rp.end()
        self.device.queue.submit([enc.finish()])
        self.imgui.render()
        self._take_pending_shots(tex)
        self.frames += 1
        if self.pending_input > 0:
            self.pending_input -= 1
        if self.after_draw is not None:
            self.after_draw(self)
        if st.needs_frame() or self.pending_input > 0:
            self.canvas.request_draw()

    # ---- screenshots --------------------------------------------------------------------------
    def screenshot(self, window: bool = True, path: Path | str | None = None):
        """Queue a screenshot: the whole window (panel included) at the end of the next draw, or
        the render alone. The PNG path is reported in the status line and in `saved`."""
        self.pending_shots.append(("window" if window else "render", None if path is None else Path(path)))
        self.canvas.request_draw()

    def _shot_path(self, kind: str) -> Path:
        st = self.state
        stamp = time.strftime("%Y%m%d-%H%M%S")
        base = f"seuwgpu-{st.scene or 'model'}-{st.precision}-{stamp}" + ("" if kind == "window" else "-render")
        p = self.screenshot_dir / f"{base}.png"
        i = 1
        while p.exists():
            p = self.screenshot_dir / f"{base}-{i}.png"
            i += 1
        return p

    def capture_window(self, tex=None) -> np.ndarray:
        """The window's current swap-chain image as [H, W, 4] RGBA8 (after this frame's draws)."""
        if not self.can_capture:
            raise RuntimeError("this canvas's swap chain cannot be read back (no COPY_SRC usage)")
        tex = tex or self.ctx.get_current_texture()
        w, h = tex.size[0], tex.size[1]
        data = self.device.queue.read_texture(
            {"texture": tex, "origin": (0, 0, 0), "mip_level": 0},
            {"offset": 0, "bytes_per_row": 4 * w, "rows_per_image": h},
            (w, h, 1),
        )
        img = np.frombuffer(data, np.uint8).reshape(h, w, 4).copy()
        if self.format.startswith("bgra"):
            img = img[..., [2, 1, 0, 3]]
        img[..., 3] = 255
        return img

    def _take_pending_shots(self, tex):
        import imageio.v3 as iio

        shots, self.pending_shots = self.pending_shots, []
        for kind, path in shots:
            try:
                img = self.capture_window(tex) if kind == "window" else self.last_rgba
                if kind == "window":
                    self.last_window = img
                if img is None:
                    raise RuntimeError("nothing rendered yet")
                path = path or self._shot_path(kind)
                path.parent.mkdir(parents=True, exist_ok=True)
                iio.imwrite(path, img[..., :3])
                self.saved.append(path)
                self.state.status = f"saved {path}"
            except Exception as e:
                self.state.status = f"screenshot failed: {e}"

    # ---- input --------------------------------------------------------------------------------
    def _wake(self, event):
        if event.get("event_type") in ("pointer_down", "pointer_up", "key_down", "key_up", "char"):
            self.pending_input = 2  # a press and a release between two frames take two frames
        self.canvas.request_draw()

    def _in_panel(self, x: float) -> bool:
        return self.show_panel and x < PANEL_WIDTH

    def _on_pointer(self, ev):
        t = ev["event_type"]
        x, y = ev.get("x", 0.0), ev.get("y", 0.0)
        if t == "pointer_down":
            if self._in_panel(x) or self._drag is not None:
                return
            shift = "Shift" in ev.get("modifiers", ())
            mode = "pan" if ev.get("button") in (2, 3) or shift else "orbit"
            self._drag = (mode, ev.get("button"), x, y)
        elif t == "pointer_up":
            if self._drag is not None and ev.get("button") == self._drag[1]:
                self._drag = None
        elif t == "pointer_move" and self._drag is not None:
            mode, b, x1, y1 = self._drag
            dx, dy = x - x1, y - y1
            self._drag = (mode, b, x, y)
            if mode == "orbit":
                self.state.orbit_by(dx, dy)
            else:
                r = self.pixel_ratio()
                self.state.pan_by(dx * r, dy * r)
            self.canvas.request_draw()

    def _on_wheel(self, ev):
        if self._in_panel(ev.get("x", PANEL_WIDTH)):
            return
        self.state.zoom_by(1.1 ** (ev.get("dy", 0.0) / 100.0))
        self.canvas.request_draw()

    def _on_key(self, ev):
        key = str(ev.get("key", ""))
        k = key.lower()
        st = self.state
        if k == "r":
            st.reset_view()
        elif k == "s":
            self.screenshot(window=True)
        elif k == "p":
            self.screenshot(window=False)
        elif k == "h":
            self.show_panel = not self.show_panel
        elif k == "m":
            st.toggle_heatmap()
        elif k == "g":
            modes = list(GUARD_MODES)
            st.set_guard(modes[(modes.index(st.guard) + 1) % len(modes)])
        elif k == "u":
            st.undo_all()
        elif k == " ":
            self._toggle_storm()
        elif k in ("]", "arrowright"):
            st.step_view(1)
        elif k in ("[", "arrowleft"):
            st.step_view(-1)
        elif k == "o":
            st.orbit_view()
        elif k in ("q", "escape"):
            self.canvas.close()
            return
        self.canvas.request_draw()

    # ---- actions shared by keys and panel -------------------------------------------------------
    def _toggle_storm(self):
        st = self.state
        if st.storm_running:
            st.storm_stop()
            st.status = "storm stopped"
        else:
            st.storm_start(self.ui["k_storm"], self.ui["accumulate"])

    def _act(self, fn, *args, **kw):
        try:
            fn(*args, **kw)
        except (ValueError, RuntimeError) as e:
            self.state.status = f"error: {e}"
        self.canvas.request_draw()

    def inject_from_panel(self):
        ui, st = self.ui, self.state
        field = st.stored_fields()[ui["field"]]
        prim = None if ui["worst"] else int(ui["primitive"])
        if prim is None:
            st.status = "searching the worst primitive of a sample..."
        self._act(st.inject, field, int(ui["bit"]), prim, int(ui["component"]))

    # ---- panel --------------------------------------------------------------------------------
    def _button(self, label: str, width: float = 0.0) -> bool:
        """imgui.button that remembers where it was drawn (tests click it by position)."""
        from imgui_bundle import imgui

        hit = imgui.button(label, imgui.ImVec2(width, 0))
        lo, hi = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        self.button_rects[label] = (lo.x, lo.y, hi.x, hi.y)
        return hit

    def _gui(self):
        from imgui_bundle import imgui

        if not self.show_panel:
            return
        st, ui = self.state, self.ui
        ro = st.readout or {}
        _, H = self.canvas.get_logical_size()
        imgui.set_next_window_pos(imgui.ImVec2(0, 0), imgui.Cond_.always)
        imgui.set_next_window_size(imgui.ImVec2(PANEL_WIDTH, H), imgui.Cond_.always)
        flags = imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_collapse
        imgui.begin("seuwgpu viewer", None, flags)
        imgui.text(f"{st.scene or 'model'}: {st.n} primitives, {st.precision}")
        w, h = st.size
        ms = ro.get("frame_ms", 0.0)
        fps = 1000.0 / ms if ms > 0 else 0.0
        imgui.text(f"render {w:>5}x{h:<5} frame {ms:6.0f} ms {fps:6.1f} fps")

        imgui.separator_text("Frame vs clean render")
        foot = ro.get("footprint", 0.0)
        col = _rgb(1.0, 0.35, 0.3) if foot > 0.01 else _rgb(0.85, 0.85, 0.85)
        imgui.text_colored(col, f"footprint {100 * foot:7.2f} %  {ro.get('changed_pixels', 0):>8} px")
        psnr = ro.get("psnr", float("inf"))
        psnr_text = f"{psnr:7.2f}" if np.isfinite(psnr) else f"{'inf' if psnr > 0 else 'NaN':>7}"  # NaN: undefined
        imgui.text(f"PSNR {psnr_text} dB  non-finite {ro.get('nonfinite_pixels', 0):>8} px")
        # what the user has seen since the faults or the defense changed (fits the panel's width)
        imgui.text(f"seen {ro.get('seen_frames', 0):>6} faulty frames, {ro.get('seen_catastrophic', 0):>5} catastr.")
        # two reserved rows for the guard line and its alert details
        if st.guard == "off":
            imgui.text_colored(_rgb(0.6, 0.6, 0.6), "guard off: clamps not monitored")
            imgui.text("")
        elif ro.get("alert"):
            per = {k: v for k, v in ro.get("clamps_per_field", {}).items() if v}
            imgui.text_colored(_rgb(1.0, 0.25, 0.2), f"ALERT: {ro.get('clamps', 0):>8} clamps > {st.clamp_threshold}")
            imgui.text_colored(_rgb(1.0, 0.6, 0.5), _fit("  " + ", ".join(f"{k} {v}" for k, v in per.items())))
        else:
            imgui.text_colored(_rgb(0.4, 0.9, 0.4), f"guard ({st.guard:>9}): {ro.get('clamps', 0):>8} clamps, ok")
            imgui.text("")
        sites = st.active_sites
        imgui.text(f"active fault sites: {len(sites):>8}")
        shown = ro.get("sites", [])[-SITE_ROWS:]
        for i in range(SITE_ROWS):  # reserved rows: the list never pushes the panel down
            imgui.text_colored(_rgb(0.75, 0.75, 1.0), _fit("  " + shown[i]) if i < len(shown) else "")
        imgui.text(_fit(st.status))

        imgui.separator_text("Capture views")
        n_views = len(st.views)
        if n_views:
            cur = "orbit" if st.view_index is None else f"{st.view_index + 1:>4}/{n_views:<4}"
            imgui.text(f"view {cur:>9}  " + _fit("" if st.view_index is None else st.view_names[st.view_index], 20))
        else:
            imgui.text_colored(_rgb(0.6, 0.6, 0.6), "none (open with --cameras FILE)")
        if self._button("< prev", 70):
            self._act(st.step_view, -1)
        imgui.same_line()
        if self._button("next >", 70):
            self._act(st.step_view, 1)
        imgui.same_line()
        if self._button("orbit", 70):
            self._act(st.orbit_view)

        imgui.separator_text("Inject a bit flip")
        imgui.set_next_item_width(180)
        fields = st.stored_fields()  # a degree-0 model has no sh_rest to offer (nor a component -1)
        _, ui["field"] = imgui.combo("field", min(ui["field"], len(fields) - 1), fields)
        nc = st.field_components(fields[ui["field"]])
        ui["component"] = max(0, min(ui["component"], nc - 1))
        nb = st.bits_per_value()
        ui["bit"] = min(ui["bit"], nb - 1)
        imgui.set_next_item_width(180)
        _, ui["component"] = imgui.slider_int("component", ui["component"], 0, nc - 1)
        imgui.set_next_item_width(180)
        _, ui["bit"] = imgui.slider_int(f"bit ({encoding.bit_class(st.precision, ui['bit'])})", ui["bit"], 0, nb - 1)
        _, ui["worst"] = imgui.checkbox("worst of a sample of", ui["worst"])
        imgui.same_line()
        imgui.set_next_item_width(90)
        ch, v = imgui.input_int("##sample", st.sample)
        if ch:
            st.sample = max(1, min(v, st.n))
        imgui.begin_disabled(ui["worst"])  # always drawn: toggling "worst" does not move the rows below
        imgui.set_next_item_width(180)
        ch, v = imgui.input_int("primitive", ui["primitive"])
        if ch:
            ui["primitive"] = max(0, min(v, st.n - 1))
        imgui.end_disabled()
        if self._button("Inject flip", 120):
            self.inject_from_panel()

        imgui.separator_text("Random upsets / storm")
        imgui.set_next_item_width(110)
        _, ui["k_random"] = imgui.input_int("k##random", ui["k_random"])
        ui["k_random"] = max(1, ui["k_random"])
        imgui.same_line()
        if self._button("Inject k random", 130):
            self._act(st.inject_random, ui["k_random"])
        imgui.set_next_item_width(110)
        _, ui["k_storm"] = imgui.input_int("k/frame", ui["k_storm"])
        ui["k_storm"] = max(1, ui["k_storm"])
        imgui.same_line()
        _, ui["accumulate"] = imgui.checkbox("accumulate", ui["accumulate"])
        if self._button("Stop storm" if st.storm_running else "Start storm", 120):
            self._act(self._toggle_storm)
        imgui.same_line()
        imgui.text(f"step {st.storm['steps']:>7}" if st.storm_running else "")

        imgui.separator_text("Defense")
        for i, mode in enumerate(GUARD_MODES):
            if imgui.radio_button(mode + "##guard", st.guard == mode):
                self._act(st.set_guard, mode)
            if i % 5 != 4:  # five to a row: every registered defense fits the panel
                imgui.same_line()
        imgui.new_line()
        changed, every = imgui.input_int("check every (frames)", st.check_every)
        if changed and every >= 1:
            self._act(st.set_check_every, every)

        imgui.separator_text("View")
        ch, v = imgui.checkbox("heat map |render - clean|", st.heatmap)
        if ch:
            self._act(st.set_heatmap, v)
        imgui.text("precision")
        for p in PRECISIONS:
            imgui.same_line()
            if imgui.radio_button(p, st.precision == p) and p != st.precision:
                self._act(st.set_precision, p)
                ui["bit"] = min(ui["bit"], st.bits_per_value() - 1)
        if self._button("Undo all", 90):
            self._act(st.undo_all)
        imgui.same_line()
        if self._button("Reset view", 90):
            self._act(st.reset_view)
        imgui.same_line()
        if self._button("Screenshot", 90):
            self.screenshot(window=True)
        imgui.text_colored(_rgb(0.6, 0.6, 0.6), "left drag: orbit   wheel: zoom")
        imgui.text_colored(_rgb(0.6, 0.6, 0.6), "right, middle or shift drag: pan")
        imgui.text_colored(_rgb(0.6, 0.6, 0.6), "R reset  S/P screenshot  H panel  M heat")
        imgui.text_colored(_rgb(0.6, 0.6, 0.6), "G guard  U undo  Space storm  Q quit")
        imgui.text_colored(_rgb(0.6, 0.6, 0.6), "[ ] capture views  O orbit")
        imgui.end()


SITE_ROWS = 4
PANEL_COLUMNS = 44  # characters of the monospaced default font that fit the panel


def _fit(text: str, width: int = PANEL_COLUMNS) -> str:
    """One row of at most `width` characters (longer text is cut with an ellipsis)."""
    text = str(text).replace("\n", " ")
    return text if len(text) <= width else text[: width - 3] + "..."


# ------------------------------------------------------------------------------------------------
def make_canvas(backend: str, size, title: str = "seuwgpu view"):
    """(canvas, loop) for a rendercanvas backend: 'offscreen' (loop None), 'glfw' or another."""
    if backend == "offscreen":
        from rendercanvas.offscreen import RenderCanvas

        return RenderCanvas(size=size), None
    if backend == "glfw":
        from rendercanvas.glfw import RenderCanvas, loop
    else:
        from rendercanvas.auto import RenderCanvas, loop
    return RenderCanvas(size=size, title=title, update_mode="ondemand"), loop


def run_viewer(
    model,
    scene: str,
    precision: str,
    size,
    orbit: OrbitCamera | None = None,
    backend: str = "glfw",
    sample: int = 16,
    clamp_threshold: int = 0,
    screenshot_dir: Path | str = ".",
    frames: int = 0,
    views=None,
    view_names=None,
    profile: str = "strict",
) -> int:
    """Open the viewer. frames > 0 (or an offscreen canvas): draw that many frames, save a
    window screenshot in screenshot_dir, and return."""
    w, h = (int(v) for v in size)
    title = f"seuwgpu view - {scene} ({model.n} primitives)"
    canvas, loop = make_canvas(backend, (w, h), title)
    pw, ph = canvas.get_physical_size()
    r = canvas.get_pixel_ratio() or 1.0
    state = ViewerState(
        model,
        precision,
        (max(MIN_SIZE, pw - int(round(PANEL_WIDTH * r))), ph),
        scene=scene,
        orbit=orbit,
        sample=sample,
        clamp_threshold=clamp_threshold,
        views=views,
        view_names=view_names,
        profile=profile,
    )
    app = ViewerApp(state, canvas, screenshot_dir)
    if loop is None:  # offscreen: no event loop, we draw
        n = max(1, frames)
        for i in range(n):
            if i == n - 1:
                app.screenshot(window=True)
            canvas.draw()
        for p in app.saved:
            print(f"wrote {p}")
        return 0 if app.saved else 1
    if frames > 0:
        if frames == 1:  # after_draw runs after the first draw: too late to ask for its screenshot
            app.screenshot(window=True)

        def stop_after(a):
            if a.frames == frames - 1:
                a.screenshot(window=True)
            if a.frames >= frames and not a.pending_shots:
                a.canvas.close()
            else:
                a.canvas.request_draw()

        app.after_draw = stop_after
    loop.run()
    for p in app.saved:
        print(f"wrote {p}")
    return 0


# ------------------------------------------------------------------------------------------------
# Where a window can open
# ------------------------------------------------------------------------------------------------
def canvas_backend() -> str:
    """'offscreen', 'glfw', or another rendercanvas backend named by RENDERCANVAS_BACKEND."""
    force = os.environ.get("RENDERCANVAS_FORCE_OFFSCREEN", "").lower() in ("1", "true", "yes")
    name = os.environ.get("RENDERCANVAS_BACKEND", "").strip().lower()
    if force or name == "offscreen":
        return "offscreen"
    return name if name and name != "auto" else "glfw"


def missing_package(backend: str) -> str | None:
    """Why the viewer's own packages (the `viewer` extra: rendercanvas, imgui-bundle, and glfw for
    a glfw window) cannot be imported, or None. They are imported where they are used, so without
    this check a missing one ended `seuwgpu view` in a traceback once the model had loaded."""
    import importlib

    for name in ("rendercanvas", "imgui_bundle", "wgpu.utils.imgui", *(("glfw",) if backend == "glfw" else ())):
        try:
            importlib.import_module(name)
        except ImportError as e:
            return str(e)
    return None


def display_problem(backend: str) -> str | None:
    """Why a window cannot open here (None when it can, as far as we can tell without opening
    one: glfw aborts the whole process when there is no display)."""
    if backend == "offscreen":
        return None
    if os.environ.get("WAYLAND_DISPLAY"):
        return None
    disp = os.environ.get("DISPLAY", "")
    if not disp:
        return "no display: DISPLAY is not set"
    if disp.startswith(":"):
        num = disp[1:].split(".")[0]
        if num.isdigit() and not os.path.exists(f"/tmp/.X11-unix/X{num}"):
            return f"no X server answers on DISPLAY={disp} (no /tmp/.X11-unix/X{num})"
    return None


NO_DISPLAY_HELP = """\
seuwgpu view: {why}.
The viewer opens a desktop window. Either
  - run it on a desktop session, or under a virtual X server:  xvfb-run -a seuwgpu view ...
    (Debian: apt-get install xvfb), or
  - render headless: RENDERCANVAS_BACKEND=offscreen seuwgpu view --frames 1 --screenshot-dir OUT
    (draws the viewer, panel included, and saves a screenshot PNG)."""
