"""The interactive viewer: its state machine driven headless, its window on an offscreen canvas,
the command's behaviour without a display, and the real glfw window under Xvfb."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
# guarded frames of a faulted model clamp: the engine's monitor warns, the viewer shows it
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning:seuwgpu.engine")
N, SIZE = 3000, (96, 96)


@pytest.fixture(scope="module")
def model():
    from seuwgpu.model.scenes import make_scene

    return make_scene("spheres", n=N)


@pytest.fixture
def state(model, gpu):
    from seuwgpu.apps.viewer import OrbitCamera, ViewerState

    return ViewerState(model, "fp32", SIZE, scene="spheres", orbit=OrbitCamera.for_scene("spheres"), sample=16)


def stored_words(st):
    r = st.engine.renderer
    return [r.read_words(c) for c in range(r.layout.n_chunks)]


def flipped_bits(st) -> int:
    """Bits of the GPU-resident model that differ from the clean stored words."""
    now = stored_words(st)
    return int(sum(np.unpackbits((a ^ b).view(np.uint8)).sum() for a, b in zip(now, st.engine.renderer.clean_words)))


def odd_sites(sites) -> int:
    """Bits an XOR of these single-bit sites leaves flipped (a bit hit twice is restored)."""
    from collections import Counter

    return sum(1 for c in Counter((s.primitive, s.flat_component(), s.bits) for s in sites).values() if c % 2)


def direct_render(model, cam, precision="fp32"):
    from seuwgpu.render.renderer import Renderer

    return Renderer(model, [cam], precision).render_rgba()[0]


# ---- ViewerState, headless ----------------------------------------------------------------------
def test_clean_frame_is_the_pipeline_render(state, model):
    rgba, ro = state.frame()
    assert rgba.shape == (SIZE[1], SIZE[0], 4) and rgba.dtype == np.uint8
    assert ro["footprint"] == 0.0 and ro["psnr"] == float("inf") and ro["clamps"] == 0
    assert not ro["alert"] and ro["active_sites"] == 0 and ro["frame_ms"] > 0
    np.testing.assert_array_equal(state.last_image, direct_render(model, state.camera()))
    from seuwgpu.metrics.image import display

    np.testing.assert_array_equal(rgba[..., :3], (display(state.last_image[..., :3]) * 255 + 0.5).astype(np.uint8))


def test_every_defense_and_its_check_schedule(state):
    """The viewer offers every registered defense. Read-time codes draw what they read (ECC
    corrects a sign flip); a check defense checked every 3 frames shows the fault until its
    check (frames before frame_count 3), then its repair stands; the memory keeps the raw flip."""
    from seuwgpu.apps.viewer import GUARD_MODES
    from seuwgpu.faults import defenses as dfn

    assert set(GUARD_MODES.values()) == set(dfn.DEFENSES)
    state.frame()  # frame 0, clean
    state.inject("log_scales", 31, None, component=2)
    _, ro = state.frame()
    assert ro["footprint"] > 0.01
    state.set_guard("ecc")
    _, ro = state.frame()
    assert ro["footprint"] == 0 and flipped_bits(state) == 1
    state.set_guard("parity4r")
    state.set_check_every(3)
    state.frame_count = 1  # the check runs before frames 3, 6, ...
    feet = [state.frame()[1]["footprint"] for _ in range(4)]  # frames 1, 2 exposed; 3, 4 repaired
    assert feet[0] > 0.01 and feet[1] > 0.01 and feet[2] == 0 and feet[3] == 0, feet
    assert state.readout["check_every"] == 3 and flipped_bits(state) == 1
    # what the user saw under this defense: 4 frames with the fault, 2 of them catastrophic
    assert (state.readout["seen_frames"], state.readout["seen_catastrophic"]) == (4, 2)
    state.set_guard("parity4f")  # checked inside the frame: dropped in the first frame, then repaired
    feet = [state.frame()[1]["footprint"] for _ in range(2)]
    assert feet[0] < 0.01 and feet[1] == 0 and flipped_bits(state) == 1, feet
    state.set_guard("parity2f")  # the same faults, already framed: drawn as its repair left them
    assert state.frame()[1]["footprint"] == 0 and flipped_bits(state) == 1
    with pytest.raises(ValueError, match="every S >= 1 frames"):
        state.set_check_every(0)


def test_scale_sign_flip_guard_and_undo(state):
    _, ro0 = state.frame()
    clean_img, clean_rgba = state.last_image.copy(), state.compose(state.last_image, state.last_image)
    site = state.inject("log_scales", 31, None, component=2)  # worst primitive of a 16 sample
    assert (site.field, site.component, site.bits) == ("log_scales", 2, (31,))
    assert state.engine.corrupted_value(site) == -state.engine.clean_value(site)
    _, ro = state.frame()
    open_foot = ro["footprint"]
    assert open_foot > 0.01, f"a scale sign flip changed only {open_foot:.2%} of the pixels"
    assert ro["psnr"] < 40 and ro["active_sites"] == 1 and "bit 31 (sign)" in ro["sites"][0]
    assert not ro["alert"] and ro["clamps"] == 0  # guard off: nothing monitored

    for mode in ("guard", "selective"):
        state.set_guard(mode)
        _, ro = state.frame()
        assert ro["footprint"] < 0.01, f"{mode}: the guarded flip still changes {ro['footprint']:.2%}"
        assert ro["clamps_per_field"]["log_scales"] >= 1 and ro["alert"]
        assert "log_scales" in ro["alert_message"]
        assert flipped_bits(state) == 1  # bounded while rendering, not restored in memory

    state.set_guard("off")  # toggling is exact both ways
    _, ro = state.frame()
    assert ro["footprint"] == open_foot

    state.undo_all()
    rgba, ro = state.frame()
    assert flipped_bits(state) == 0
    np.testing.assert_array_equal(state.last_image, clean_img)  # bit for bit
    np.testing.assert_array_equal(rgba, clean_rgba)
    assert ro["footprint"] == 0.0 and ro["psnr"] == float("inf") and ro["active_sites"] == 0


def test_explicit_site_and_random_upsets(state):
    s = state.inject("opacity", 30, primitive=7, component=0)
    assert (s.primitive, s.component, s.bits) == (7, 0, (30,))
    with pytest.raises(ValueError):
        state.inject("opacity", 32, primitive=7)
    with pytest.raises(ValueError):
        state.inject("log_scales", 31, primitive=N)
    sites = state.inject_random(25)
    assert len(sites) == 25 and len(state.active_sites) == 26
    assert flipped_bits(state) == odd_sites(state.active_sites)
    state.frame()
    state.undo_all()
    assert flipped_bits(state) == 0


def test_storm_accumulates_and_transient_replaces(state):
    state.frame()
    state.storm_start(40, accumulate=True)
    for step in range(1, 4):
        state.frame()  # one storm step per frame
        assert state.readout["storm"]["steps"] == step
        assert len(state.active_sites) == 40 * step
        assert flipped_bits(state) == odd_sites(state.active_sites)
    sites = state.storm_step()
    assert len(sites) == 40 and len(state.active_sites) == 160
    state.storm_stop()
    assert not state.storm_running and len(state.active_sites) == 160  # accumulated faults stay
    state.undo_all()
    assert flipped_bits(state) == 0

    state.storm_start(40, accumulate=False)
    for _ in range(3):
        state.frame()
        assert len(state.active_sites) == 40  # each frame's upsets replace the previous ones
        assert flipped_bits(state) == odd_sites(state.active_sites)
    state.storm_stop()
    assert state.active_sites == [] and flipped_bits(state) == 0
    _, ro = state.frame()
    assert ro["footprint"] == 0.0


def test_precision_switch(state, model):
    state.frame()
    fp32 = state.last_image.copy()
    state.inject("log_scales", 31, primitive=0, component=0)
    state.set_precision("bf16")
    assert state.precision == "bf16" and state.engine.precision == "bf16" and state.bits_per_value() == 16
    assert state.active_sites == []  # faults do not survive a change of format
    _, ro = state.frame()
    assert ro["footprint"] == 0.0 and ro["precision"] == "bf16"
    np.testing.assert_array_equal(state.last_image, direct_render(model, state.camera(), "bf16"))
    assert not np.array_equal(state.last_image, fp32)  # rounded parameters, a slightly different image
    with pytest.raises(ValueError):
        state.inject("log_scales", 31, primitive=0)  # no bit 31 in a 16-bit value
    state.inject("log_scales", 15, None, component=2)  # bf16 sign bit
    _, ro = state.frame()
    assert ro["footprint"] > 0.01
    state.set_precision("fp16")
    _, ro = state.frame()
    assert state.precision == "fp16" and ro["footprint"] == 0.0


def test_camera_moves_with_faults_active(state, model):
    state.frame()
    cam0 = state.camera()
    state.inject("log_scales", 31, None, component=2)
    state.orbit_by(40, -10)
    state.zoom_by(0.8)
    state.pan_by(5, 3)
    state.resize(80, 64)
    cam = state.camera()
    assert (cam.width, cam.height) == (80, 64) and not np.allclose(cam.viewmat, cam0.viewmat)
    rgba, ro = state.frame()
    assert rgba.shape == (64, 80, 4) and ro["clean_render"]  # faults off, clean render, faults back
    # the clean reference of the new view is the clean model's render of that view
    np.testing.assert_array_equal(state.clean_image, direct_render(model, cam))
    assert flipped_bits(state) == 1  # the fault is back after the clean render
    assert ro["footprint"] > 0.0
    _, ro = state.frame()  # same view: the cached clean render serves
    assert not ro["clean_render"]
    state.reset_view()
    state.resize(*SIZE)
    np.testing.assert_array_equal(state.camera().viewmat, cam0.viewmat)


def test_heatmap(state):
    state.set_heatmap(True)
    rgba, _ = state.frame()
    grey = rgba[..., :3]
    assert (grey[..., 0] == grey[..., 1]).all() and (grey[..., 1] == grey[..., 2]).all()  # no change: dim grey
    assert grey.max() <= 0.3 * 255 + 1
    state.inject("log_scales", 31, None, component=2)
    rgba, ro = state.frame()
    coloured = rgba[..., 0] != rgba[..., 2]
    assert abs(coloured.mean() - ro["footprint"]) < 0.01 and coloured.mean() > 0.01
    state.toggle_heatmap()
    rgba2, _ = state.frame()
    assert not np.array_equal(rgba, rgba2)


# ---- the window on an offscreen canvas --------------------------------------------------------
def test_offscreen_window_panel_and_input(model, gpu):
    pytest.importorskip("rendercanvas")
    pytest.importorskip("imgui_bundle")
    from rendercanvas.offscreen import RenderCanvas

    from seuwgpu.apps.viewer import OrbitCamera, ViewerState
    from seuwgpu.apps.viewer_window import PANEL_WIDTH, ViewerApp

    W, H = PANEL_WIDTH + 120, 400  # the whole panel down to its inject section
    canvas = RenderCanvas(size=(W, H))
    st = ViewerState(model, "fp32", (120, H), scene="spheres", orbit=OrbitCamera.for_scene("spheres"))
    app = ViewerApp(st, canvas)
    img = np.asarray(canvas.draw())
    assert img.shape == (H, W, 4)
    # the render is blitted 1:1 into the image area; the panel is drawn beside it
    np.testing.assert_array_equal(img[:, PANEL_WIDTH:, :3], app.last_rgba[..., :3])
    panel = img[:, :PANEL_WIDTH, :3]
    assert panel.std() > 10 and len(np.unique(panel.reshape(-1, 3), axis=0)) > 10

    def send(*events):
        for ev in events:
            ev.setdefault("modifiers", ())
            canvas.submit_event(ev)
        canvas._process_events()

    az = st.orbit.azimuth_deg
    x, y = PANEL_WIDTH + 60, 100
    send(
        {"event_type": "pointer_down", "x": x, "y": y, "button": 1, "buttons": (1,)},
        {"event_type": "pointer_move", "x": x + 30, "y": y, "button": 0, "buttons": (1,)},
        {"event_type": "pointer_up", "x": x + 30, "y": y, "button": 1, "buttons": ()},
    )
    assert st.orbit.azimuth_deg != az and st.dirty
    send({"event_type": "key_down", "key": "r"})
    assert st.orbit.azimuth_deg == az
    send(
        {"event_type": "pointer_down", "x": 20, "y": 100, "button": 1, "buttons": (1,)},  # in the panel
        {"event_type": "pointer_move", "x": 60, "y": 100, "button": 0, "buttons": (1,)},
        {"event_type": "pointer_up", "x": 60, "y": 100, "button": 1, "buttons": ()},
    )
    assert st.orbit.azimuth_deg == az
    send({"event_type": "key_down", "key": "g"}, {"event_type": "key_down", "key": "m"})
    assert st.guard == "guard" and st.heatmap
    app.ui.update(field=1, component=2, bit=31, worst=True)  # log_scales
    app.inject_from_panel()
    img = np.asarray(canvas.draw())
    assert st.readout["active_sites"] == 1 and st.readout["alert"]
    np.testing.assert_array_equal(img[:, PANEL_WIDTH:, :3], app.last_rgba[..., :3])
    canvas.set_logical_size(W + 40, H)  # resize: the render follows the window
    canvas.draw()
    assert st.size == (160, H) and app.last_rgba.shape == (H, 160, 4)
    canvas.set_logical_size(W, H)
    send({"event_type": "key_down", "key": "h"})  # hide the panel: the render fills the window
    img = np.asarray(canvas.draw())
    assert st.size == (W, H) and app.last_rgba.shape == (H, W, 4)
    np.testing.assert_array_equal(img[..., :3], app.last_rgba[..., :3])
    canvas.close()


def test_the_panel_offers_a_degree_0_model_only_the_fields_it_stores(gpu):
    """A model without sh_rest: the field list holds the five fields it stores; a field index
    past them (sh_rest's, chosen on another model) falls back to the last, and the component
    stays >= 0, so an inject from the panel works (it set the component to -1 and failed)."""
    pytest.importorskip("rendercanvas")
    pytest.importorskip("imgui_bundle")
    from rendercanvas.offscreen import RenderCanvas

    from seuwgpu.apps.viewer import OrbitCamera, ViewerState
    from seuwgpu.apps.viewer_window import PANEL_WIDTH, ViewerApp
    from seuwgpu.model.scenes import make_scene

    flat = make_scene("spheres", n=N, sh_degree=0)
    st = ViewerState(flat, "fp32", (64, 64), scene="spheres", orbit=OrbitCamera.for_scene("spheres"))
    assert st.stored_fields() == ["means", "log_scales", "quats", "opacity", "sh_dc"]
    canvas = RenderCanvas(size=(PANEL_WIDTH + 64, 240))
    app = ViewerApp(st, canvas)
    app.ui.update(field=5, component=0, bit=31, worst=False, primitive=0)  # sh_rest's index in FIELDS
    canvas.draw()
    assert app.ui["field"] == 4 and app.ui["component"] >= 0
    app.inject_from_panel()
    canvas.draw()
    assert st.readout["active_sites"] == 1 and not st.status.startswith("error")
    canvas.close()


def test_capture_views_step_and_letterbox(model, gpu):
    from seuwgpu.apps.viewer import OrbitCamera, ViewerState, letterbox
    from seuwgpu.model.scenes import scene_cameras

    views = scene_cameras("spheres", 3, 64, 32)
    st = ViewerState(model, "fp32", (96, 96), scene="spheres", orbit=OrbitCamera.for_scene("spheres"), views=views)
    orbit_cam = st.camera()
    st.step_view(1)
    assert st.view_index == 0 and "1/3" in st.status
    cam = st.camera()
    np.testing.assert_array_equal(cam.viewmat, views[0].viewmat)
    # the 64x32 frame scaled by 1.5 to 96x48 and centred: 24 px bands above and below
    np.testing.assert_allclose(cam.K[0], [views[0].K[0, 0] * 1.5, 0, 48.0])
    np.testing.assert_allclose(cam.K[1], [0, views[0].K[1, 1] * 1.5, 48.0])
    img, _ = st.frame()
    inner = letterbox(views[0], 96, 48)
    want = direct_render(model, inner)
    got = st.last_image[24:72]
    assert np.mean(np.abs(got[..., :3] - want[..., :3])) < 2e-3  # the capture's frame, scaled
    st.step_view(-1)  # wraps around
    assert st.view_index == 2
    st.orbit_by(5, 0)  # any orbit returns to the orbit camera
    assert st.view_index is None
    st.reset_view()
    np.testing.assert_array_equal(st.camera().viewmat, orbit_cam.viewmat)


def test_short_click_and_steady_panel(model, gpu):
    """A press and release that arrive between two frames still click a panel button, and the
    panel's buttons stay where they are while the readout changes."""
    pytest.importorskip("rendercanvas")
    pytest.importorskip("imgui_bundle")
    from rendercanvas.offscreen import RenderCanvas

    from seuwgpu.apps.viewer import OrbitCamera, ViewerState
    from seuwgpu.apps.viewer_window import PANEL_WIDTH, ViewerApp
    from seuwgpu.model.scenes import scene_cameras

    canvas = RenderCanvas(size=(PANEL_WIDTH + 64, 760))
    st = ViewerState(
        model,
        "fp32",
        (64, 760),
        scene="spheres",
        orbit=OrbitCamera.for_scene("spheres"),
        views=scene_cameras("spheres", 2, 48, 48),
    )
    app = ViewerApp(st, canvas)
    canvas.draw()
    canvas.draw()
    before = dict(app.button_rects)
    x0, y0, x1, y1 = before["next >"]
    for ev in (
        {"event_type": "pointer_move", "x": (x0 + x1) / 2, "y": (y0 + y1) / 2, "button": 0, "buttons": ()},
        {"event_type": "pointer_down", "x": (x0 + x1) / 2, "y": (y0 + y1) / 2, "button": 1, "buttons": (1,)},
        {"event_type": "pointer_up", "x": (x0 + x1) / 2, "y": (y0 + y1) / 2, "button": 1, "buttons": ()},
    ):
        ev["modifiers"] = ()
        canvas.submit_event(ev)
    canvas._process_events()  # press and release, both before the next frame
    draws = 0
    while st.view_index is None and draws < 4:
        canvas.draw()
        draws += 1
        if st.view_index is None:
            # ImGui has applied only the press: the window must ask for another frame itself
            assert app.pending_input > 0
    assert st.view_index == 0, "the short click was lost"
    # values change (faults, alert, long status, a capture view): the buttons do not move
    st.set_guard("guard")
    st.inject("log_scales", 30, primitive=0, component=0)
    st.status = "x" * 200
    for _ in range(2):
        canvas.draw()
    assert st.readout["active_sites"] == 1
    assert app.button_rects == before
    canvas.close()


# ---- the command ----------------------------------------------------------------------------------
def _env(**kw):
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("DISPLAY", "WAYLAND_DISPLAY", "RENDERCANVAS_BACKEND", "RENDERCANVAS_FORCE_OFFSCREEN")
    }
    env.setdefault("XDG_RUNTIME_DIR", "/tmp")
    env.update(kw)
    return env


def _view_commands():
    return [[sys.executable, "-m", "seuwgpu", "view"]]


def test_view_without_display_says_what_to_do():
    for cmd in _view_commands():
        p = subprocess.run(cmd + ["--n", "100"], cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=60)
        assert p.returncode == 3, (cmd, p.stderr)
        assert "xvfb-run" in p.stderr and "RENDERCANVAS_BACKEND=offscreen" in p.stderr


def test_view_offscreen_command(tmp_path):
    pytest.importorskip("rendercanvas")
    pytest.importorskip("imgui_bundle")
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "seuwgpu",
            "view",
            "--n",
            "2000",
            "--size",
            "480x200",
            "--frames",
            "1",
            "--screenshot-dir",
            str(tmp_path),
        ],
        cwd=ROOT,
        env=_env(RENDERCANVAS_BACKEND="offscreen"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    import imageio.v3 as iio

    pngs = list(tmp_path.glob("*.png"))
    assert len(pngs) == 1
    img = iio.imread(pngs[0])
    assert img.shape[:2] == (200, 480) and img.std() > 10


@pytest.mark.parametrize("frames", [1, 2, 3])
def test_view_frames_in_a_window_draws_them_and_saves_one_screenshot(frames, model, gpu, tmp_path, monkeypatch):
    """`view --frames N` in a window (glfw, its own event loop): N draws, then one screenshot of the
    last. With --frames 1 the window closed after its first draw without a screenshot (the
    request came after that draw), and the command still exited 0."""
    pytest.importorskip("rendercanvas")
    pytest.importorskip("imgui_bundle")
    from rendercanvas.offscreen import RenderCanvas

    from seuwgpu.apps import viewer_window

    class Loop:  # the window's event loop: draws while the window asks, until it closes
        def __init__(self, canvas):
            self.canvas, self.draws = canvas, 0

        def run(self):
            while not self.canvas.get_closed() and self.draws < 10:
                self.canvas.draw()
                self.draws += 1

    made = {}

    def make_canvas(backend, size, title=""):
        canvas = RenderCanvas(size=size)
        made["loop"] = Loop(canvas)
        return canvas, made["loop"]

    monkeypatch.setattr(viewer_window, "make_canvas", make_canvas)
    size = (viewer_window.PANEL_WIDTH + 48, 200)
    rc = viewer_window.run_viewer(
        model, "spheres", "fp32", size, backend="glfw", screenshot_dir=tmp_path, frames=frames
    )
    assert rc == 0 and made["loop"].draws == frames
    assert len(list(tmp_path.glob("*.png"))) == 1


@pytest.mark.parametrize("package", ["rendercanvas", "imgui_bundle"])
def test_view_without_the_viewer_extra_says_how_to_get_it(package, monkeypatch, capsys):
    """Without the `viewer` extra (an environment of the package alone, as `./dev main` makes),
    `view` ended in a ModuleNotFoundError traceback once the model had loaded: the packages are
    imported where they are used. It is one error line naming the extra, exit status 2."""
    from seuwgpu.apps.cli import main

    monkeypatch.setenv("RENDERCANVAS_BACKEND", "offscreen")
    monkeypatch.setitem(sys.modules, package, None)  # importing it raises ImportError, as if absent
    assert main(["view", "--scene", "spheres", "--n", "100", "--frames", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("seuwgpu view: error: ") and "pip install 'seuwgpu[viewer]'" in err
    assert len(err.strip().splitlines()) == 1


# ---- the real window under Xvfb -------------------------------------------------------------------
def test_real_window_under_xvfb(tmp_path):
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian: apt-get install xvfb); the real-window test needs it")
    for mod in ("rendercanvas", "glfw", "imgui_bundle"):
        pytest.importorskip(mod)
    p = subprocess.run(
        [
            sys.executable,
            str(ROOT / "tools" / "viewer_xvfb.py"),
            "--out",
            str(tmp_path),
            "--n",
            "3000",
            "--size",
            "900x560",
            "--component",
            "2",
        ],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert p.returncode == 0, p.stdout + p.stderr
    import imageio.v3 as iio

    report = json.loads((tmp_path / "viewer_report.json").read_text())
    assert all(c["ok"] for c in report["checks"].values()), report["checks"]
    clean = iio.imread(tmp_path / "viewer_clean.png")
    sheet = iio.imread(tmp_path / "viewer_sheet.png")
    assert clean.shape == sheet.shape == (560, 900, 3)
    for img in (clean, sheet):  # not blank: varied colours, the panel and the model
        assert img.std() > 10 and len(np.unique(img.reshape(-1, 3), axis=0)) > 100
    from seuwgpu.apps.viewer_window import PANEL_WIDTH

    render_clean, render_sheet = clean[:, PANEL_WIDTH:], sheet[:, PANEL_WIDTH:]
    assert (render_clean < 250).any(axis=-1).mean() > 0.05  # the model covers part of the white view
    assert (np.abs(render_sheet.astype(int) - render_clean).max(axis=-1) > 2).mean() > 0.01


def test_viewer_renders_under_the_chosen_profile(model):
    """`seuwgpu view --profile gsplat`: the viewer's engine draws corrupted values by gsplat's rules
    (a NaN quaternion is culled there and a frame-covering sheet under strict)."""
    from seuwgpu.apps.cli import build_parser
    from seuwgpu.apps.viewer import OrbitCamera, ViewerState

    assert build_parser().parse_args(["view", "--profile", "gsplat"]).profile == "gsplat"
    seen = {}
    for profile in ("strict", "gsplat"):
        orbit = OrbitCamera.for_scene("spheres")
        st = ViewerState(model, "fp32", (64, 64), scene="spheres", orbit=orbit, profile=profile)
        assert st.engine.profile == profile
        site = st.engine.site("quats", 0, 0, tuple(range(32)), "set", 0x7FC00000)  # w = NaN
        seen[profile] = st.engine.inject(site)["footprint"]
    assert seen["strict"] > seen["gsplat"]


# ---- readout against an independent recomputation from the frames ---------------------------------
def independent_readout(img, clean):
    """Footprint, changed and non-finite pixels, PSNR of two float32 RGBA frames, from their
    definitions (docs/conventions.md), not from seuwgpu.metrics."""
    f, c = img[..., :3].astype(np.float64), clean[..., :3].astype(np.float64)
    same = (img[..., :3].view(np.uint32) == clean[..., :3].view(np.uint32)).all(-1)
    nonfin = ~np.isfinite(f).all(-1)
    with np.errstate(invalid="ignore"):
        big = np.abs(img[..., :3] - clean[..., :3]) > np.float32(1 / 255)
    changed = (nonfin | big.any(-1)) & ~same
    if (changed & nonfin).any():
        psnr = float("nan")
    else:
        mse = np.mean((np.clip(f, 0, 1) - np.clip(np.nan_to_num(c), 0, 1)) ** 2)
        psnr = float("inf") if mse == 0 else 10 * np.log10(1 / mse)
    n_changed = int(changed.sum())
    return {"changed_pixels": n_changed, "footprint": changed.mean(), "psnr": psnr, "nonfinite": int(nonfin.sum())}


def test_nonfinite_frame_has_undefined_psnr(model, gpu):
    """A colour set to +Inf or NaN reaches pixels: the readout counts them and its PSNR is NaN, as
    in the records (it read 44 dB and 31 dB), and undoing restores the clean frame bit for bit."""
    from seuwgpu.apps.viewer import OrbitCamera, ViewerState

    st = ViewerState(model, "fp32", (48, 48), scene="spheres", orbit=OrbitCamera.for_scene("spheres"))
    st.frame()
    clean = st.last_image.copy()
    for value in (0x7F800000, 0x7FC00000):  # +Inf, NaN
        site = next(
            s
            for p in range(0, N, 25)
            if st.engine.inject(s := st.engine.site("sh_dc", p, 0, tuple(range(32)), "set", value))["nonfinite"]
        )
        st._add("set", [site])
        _, ro = st.frame()
        want = independent_readout(st.last_image, clean)
        assert want["nonfinite"] > 0 and ro["nonfinite_pixels"] == want["nonfinite"]
        assert ro["changed_pixels"] == want["changed_pixels"] and ro["footprint"] == want["footprint"]
        assert np.isnan(ro["psnr"]), ro["psnr"]
        st.undo_all()
        _, ro = st.frame()
        assert np.array_equal(st.last_image.view(np.uint32), clean.view(np.uint32))
        assert ro["footprint"] == 0.0 and ro["psnr"] == float("inf") and ro["nonfinite_pixels"] == 0


def test_the_panel_prints_the_readout_with_nan_and_inf_as_such(model, gpu, monkeypatch):
    """The panel's numbers are the readout's: frame time and fps, footprint in percent and pixels,
    PSNR (inf for an unchanged frame, NaN where it is undefined, as in the records and the README;
    it printed "n/a") and the non-finite pixels."""
    pytest.importorskip("rendercanvas")
    pytest.importorskip("imgui_bundle")
    from imgui_bundle import imgui
    from rendercanvas.offscreen import RenderCanvas

    from seuwgpu.apps.viewer import OrbitCamera, ViewerState
    from seuwgpu.apps.viewer_window import PANEL_WIDTH, ViewerApp

    rows = []
    text, colored = imgui.text, imgui.text_colored
    monkeypatch.setattr(imgui, "text", lambda s: (rows.append(s), text(s))[1])
    monkeypatch.setattr(imgui, "text_colored", lambda c, s: (rows.append(s), colored(c, s))[1])
    st = ViewerState(model, "fp32", (48, 400), scene="spheres", orbit=OrbitCamera.for_scene("spheres"))
    canvas = RenderCanvas(size=(PANEL_WIDTH + 48, 400))
    ViewerApp(st, canvas)

    def panel():
        rows.clear()
        canvas.draw()
        ro = st.readout
        ms = ro["frame_ms"]
        assert f"frame {ms:6.0f} ms {1000 / ms:6.1f} fps" in rows[1]
        foot = next(r for r in rows if r.startswith("footprint"))
        assert foot.split() == ["footprint", f"{100 * ro['footprint']:.2f}", "%", str(ro["changed_pixels"]), "px"]
        return next(r for r in rows if r.startswith("PSNR")).split()

    assert panel() == ["PSNR", "inf", "dB", "non-finite", "0", "px"]
    st.inject("log_scales", 31, primitive=17, component=2)
    assert panel() == ["PSNR", f"{st.readout['psnr']:.2f}", "dB", "non-finite", "0", "px"]
    st.undo_all()
    site = next(
        s
        for p in range(0, N, 25)
        if st.engine.inject(s := st.engine.site("sh_dc", p, 0, tuple(range(32)), "set", 0x7FC00000))["nonfinite"]
    )
    st._add("set", [site])
    got = panel()
    assert np.isnan(st.readout["psnr"]) and st.readout["nonfinite_pixels"] > 0
    assert got == ["PSNR", "NaN", "dB", "non-finite", str(st.readout["nonfinite_pixels"]), "px"]
    canvas.close()


def test_guarded_model_with_its_own_nan_is_measured_against_its_guarded_clean_render(model, gpu):
    """A user's model holding NaN/Inf (it loads with a warning): the guard changes the clean model
    itself, which is reported once, not charged to every frame. With the guard on and no fault the
    viewer read an 84% footprint and a clamp alert; a guarded fault is measured against the guarded
    clean render, which is the render of the model with those values replaced by the box's bounds."""
    import copy

    from seuwgpu.apps.viewer import OrbitCamera, ViewerState

    m = copy.deepcopy(model)
    m.log_scales[3, 0] = np.nan  # NaN -> the box's lower bound
    m.sh_dc[7, 1] = np.inf  # +Inf -> the upper bound
    fixed = copy.deepcopy(m)
    fin = np.delete(np.arange(m.n), [3, 7])
    fixed.log_scales[3, 0] = m.log_scales[fin, 0].min()
    fixed.sh_dc[7, 1] = m.sh_dc[fin, 1].max()

    st = ViewerState(m, "fp32", (48, 48), scene="spheres", orbit=OrbitCamera.for_scene("spheres"))
    st.set_guard("guard")
    _, ro = st.frame()
    assert ro["footprint"] == 0.0 and ro["psnr"] == float("inf") and not ro["alert"]
    assert ro["clamps"] == 2  # the clean model's own two values
    guarded_clean = direct_render(fixed, st.camera())
    np.testing.assert_array_equal(st.last_image, guarded_clean)

    st.inject("opacity", 30, primitive=11)  # a fault: guarded frame against the guarded clean one
    st.orbit_by(30, 0)  # a new view: its clean reference is rendered with the fault undone
    _, ro = st.frame()
    want = independent_readout(st.last_image, direct_render(fixed, st.camera()))
    assert ro["changed_pixels"] == want["changed_pixels"] and ro["footprint"] == want["footprint"]
    assert ro["alert"] == (ro["clamps"] > 2)
    st.set_guard("off")  # unguarded: against the unguarded clean render (its NaN pixels identical)
    _, ro = st.frame()
    want = independent_readout(st.last_image, direct_render(m, st.camera()))
    assert ro["changed_pixels"] == want["changed_pixels"] and not ro["alert"]
    st.undo_all()
    _, ro = st.frame()
    np.testing.assert_array_equal(st.last_image.view(np.uint32), direct_render(m, st.camera()).view(np.uint32))


def test_worst_of_a_sample_is_scored_on_the_capture_view_shown(model, gpu):
    """With a capture view shown, 'worst of a sample' scores the sample on that view (it scored
    them on the orbit camera, which may not see the same primitives)."""
    from seuwgpu.apps.viewer import OrbitCamera, ViewerState, letterbox
    from seuwgpu.faults.engine import Engine
    from seuwgpu.model.scenes import scene_cameras

    views = scene_cameras("spheres", 4, 48, 48)
    orbit = OrbitCamera.for_scene("spheres")
    orbit.zoom(0.25)  # a close-up orbit: it sees other primitives than the capture views
    st = ViewerState(model, "fp32", (64, 64), scene="spheres", orbit=orbit, views=views, sample=16, probe=32)
    for step in range(len(views)):
        st.step_view(1)
        prim, _ = st.worst_primitive("log_scales", 2, 31)
        eng = Engine(model, [letterbox(views[step], 32, 32)], "fp32", gpu=gpu)
        want, _ = eng.worst_primitive("log_scales", 2, 31, sample=16, seed=st.seed)
        assert prim == want, (step, prim, want)
