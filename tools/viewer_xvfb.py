"""Start the real viewer window (glfw) on a private Xvfb server, drive it, and screenshot it.

    python tools/viewer_xvfb.py [--out DIR] [--scene spheres] [--n 3000] [--size 1100x720]
                                [--precision fp32] [--component 0] [--prefix viewer_]

Steps: start `Xvfb -displayfd` (a free display number) with `-fbdir`, so the X server keeps its
screen in an XWD file we can read; open the viewer (`ViewerApp` on a glfw canvas, its own event
loop); then, from a task inside that loop:
  1. wait for the first frame, drag the mouse across the render (orbit) and check the camera
     moved, press R (reset view);
  2. capture the X screen -> DIR/<prefix>clean.png (the window, panel included);
  3. press "Inject flip" through the panel's own action (log_scales sign bit, component
     --component (default 2, the flat normal axis), worst primitive of a sample for the
     current view) -> DIR/<prefix>sheet.png;
  4. press S (the viewer's screenshot key: the swap chain read back through wgpu) and check the
     X screen shows the same pixels as the swap chain;
  5. G (guard on): the same flip must now change far fewer pixels; U undoes; Q closes the window.
Readouts and checks go to DIR/<prefix>report.json. Exit status 0 when every check passed.
The screenshots come from the X server's framebuffer: what a user would see in the window.
Needs Debian's `xvfb` (Xvfb) and the viewer extra (rendercanvas, glfw, imgui-bundle).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


# ---- Xvfb ------------------------------------------------------------------------------------
def start_xvfb(width: int, height: int, fbdir: Path, timeout: float = 20.0):
    """Start Xvfb on a free display; returns (process, ':N')."""
    exe = shutil.which("Xvfb")
    if exe is None:
        raise SystemExit("viewer_xvfb: Xvfb is not installed (Debian: apt-get install xvfb)")
    r, w = os.pipe()
    proc = subprocess.Popen(
        [
            exe,
            "-displayfd",
            str(w),
            "-screen",
            "0",
            f"{width}x{height}x24",
            "-fbdir",
            str(fbdir),
            "-nolisten",
            "tcp",
            "-noreset",
        ],
        pass_fds=(w,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    os.close(w)
    buf = b""
    t0 = time.time()
    os.set_blocking(r, False)
    while not buf.endswith(b"\n"):
        if proc.poll() is not None:
            raise RuntimeError("Xvfb exited: " + proc.stderr.read().decode(errors="replace")[-500:])
        if time.time() - t0 > timeout:
            proc.kill()
            raise RuntimeError("Xvfb did not report a display number")
        try:
            buf += os.read(r, 64)
        except BlockingIOError:
            time.sleep(0.05)
    os.close(r)
    return proc, ":" + buf.decode().strip()


def read_xwd(path: Path) -> np.ndarray:
    """The X screen from Xvfb's -fbdir XWD file, as [H, W, 3] RGB uint8 (24/32-bit TrueColor)."""
    data = Path(path).read_bytes()
    hdr = np.frombuffer(data[:100], ">u4")
    header_size, _ver, _fmt, _depth, width, height = (int(v) for v in hdr[:6])
    byte_order, bpp, bpl, ncolors = int(hdr[7]), int(hdr[11]), int(hdr[12]), int(hdr[19])
    masks = [int(v) for v in hdr[14:17]]
    if bpp != 32:
        raise ValueError(f"expected a 32-bit XWD screen, got {bpp} bits per pixel")
    off = header_size + 12 * ncolors
    px = np.frombuffer(data, "<u4" if byte_order == 0 else ">u4", count=height * bpl // 4, offset=off)
    px = px.reshape(height, bpl // 4)[:, :width]
    out = np.empty((height, width, 3), np.uint8)
    for c, m in enumerate(masks):
        shift = (m & -m).bit_length() - 1
        out[..., c] = (px & m) >> shift
    return out


# ---- the drive -------------------------------------------------------------------------------
def main(argv=None) -> int:
    from seuwgpu.apps.cli import parse_size

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("viewer_xvfb_out"))
    p.add_argument("--scene", default="spheres")
    p.add_argument("--n", type=int, default=3000)
    p.add_argument("--size", type=parse_size, default=parse_size("1100x720"))
    p.add_argument("--precision", default="fp32", choices=("fp32", "fp16", "bf16"))
    p.add_argument(
        "--component", type=int, default=2, help="log_scales component to flip (0..2; default 2, the flat normal axis)"
    )
    p.add_argument("--sample", type=int, default=16)
    p.add_argument("--prefix", default="viewer_")
    p.add_argument("--timeout", type=float, default=240.0)
    p.add_argument("--report", type=Path, help="JSON report path (default OUT/<prefix>report.json)")
    args = p.parse_args(argv)
    W, H = args.size
    args.out.mkdir(parents=True, exist_ok=True)
    fbdir = Path(tempfile.mkdtemp(prefix="seuwgpu-xvfb-"))
    xvfb, disp = start_xvfb(W + 64, H + 64, fbdir)
    os.environ["DISPLAY"] = disp
    os.environ.pop("WAYLAND_DISPLAY", None)
    os.environ.pop("RENDERCANVAS_FORCE_OFFSCREEN", None)
    os.environ["RENDERCANVAS_BACKEND"] = "glfw"
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
    try:
        return drive(args, fbdir / "Xvfb_screen0")
    finally:
        xvfb.terminate()
        try:
            xvfb.wait(10)
        except subprocess.TimeoutExpired:
            xvfb.kill()
        shutil.rmtree(fbdir, ignore_errors=True)


def drive(args, xwd: Path) -> int:
    from seuwgpu.apps.viewer_window import make_canvas
    from seuwgpu.model.scenes import make_scene

    W, H = args.size
    t_start = time.time()
    model = make_scene(args.scene, n=args.n)
    canvas, loop = make_canvas("glfw", (W, H), f"seuwgpu view - {args.scene} ({args.n} primitives)")
    try:
        return _drive(args, xwd, model, canvas, loop, t_start)
    finally:  # let glfw let go of the X server before Xvfb goes (else Xlib aborts at exit)
        try:
            canvas.close()
            import glfw

            glfw.terminate()
        except Exception:
            pass


def _drive(args, xwd, model, canvas, loop, t_start) -> int:
    import imageio.v3 as iio
    from rendercanvas.utils.asyncs import sleep

    from seuwgpu.apps.viewer import OrbitCamera, ViewerState
    from seuwgpu.apps.viewer_window import PANEL_WIDTH, ViewerApp
    from seuwgpu.model.fields import FIELDS

    W, H = args.size
    state = ViewerState(
        model,
        args.precision,
        (W - PANEL_WIDTH, H),
        scene=args.scene,
        orbit=OrbitCamera.for_scene(args.scene),
        sample=args.sample,
    )
    app = ViewerApp(state, canvas, screenshot_dir=args.out)
    report = {
        "display": os.environ["DISPLAY"],
        "size": [W, H],
        "scene": args.scene,
        "n": args.n,
        "precision": args.precision,
        "checks": {},
    }
    errors: list[str] = []

    def check(name, ok, detail=""):
        report["checks"][name] = {"ok": bool(ok), "detail": detail}
        if not ok:
            errors.append(f"{name}: {detail}")

    def window_origin():
        try:
            import glfw

            return glfw.get_window_pos(canvas._window)
        except Exception:
            return 0, 0

    def grab() -> np.ndarray:
        x, y = window_origin()
        w, h = canvas.get_physical_size()
        screen = read_xwd(xwd)
        return screen[y : y + h, x : x + w]

    async def frames(n=2, timeout=60.0):
        """Let the loop draw n more frames (and the X server show them)."""
        target = app.frames + n
        t0 = time.time()
        while app.frames < target:
            canvas.request_draw()
            await sleep(0.02)
            if time.time() - t0 > timeout:
                raise TimeoutError("the window stopped drawing")
        await sleep(0.3)

    def send(ev):
        ev.setdefault("modifiers", ())
        canvas.submit_event(ev)

    def key(k):
        send({"event_type": "key_down", "key": k})
        send({"event_type": "key_up", "key": k})

    async def script():
        try:
            await frames(3)
            check(
                "first_frame",
                app.renders >= 1 and state.readout.get("footprint") == 0.0,
                f"renders={app.renders} readout={state.readout.get('footprint')}",
            )
            # 1. orbit with the mouse, then R
            az0 = state.orbit.azimuth_deg
            pw, ph = canvas.get_physical_size()
            report["window"] = {"origin": list(window_origin()), "size": [pw, ph]}
            x0, y0 = PANEL_WIDTH + (pw - PANEL_WIDTH) // 2, ph // 2
            send({"event_type": "pointer_down", "x": x0, "y": y0, "button": 1, "buttons": (1,)})
            for i in range(1, 6):
                send({"event_type": "pointer_move", "x": x0 + 20 * i, "y": y0 + 4 * i, "button": 0, "buttons": (1,)})
            send({"event_type": "pointer_up", "x": x0 + 100, "y": y0 + 20, "button": 1, "buttons": ()})
            await frames(2)
            az1 = state.orbit.azimuth_deg
            check("mouse_orbit", abs(az1 - az0) > 1.0, f"azimuth {az0:.1f} -> {az1:.1f}")
            send({"event_type": "wheel", "dx": 0.0, "dy": 200.0, "x": x0, "y": y0, "buttons": ()})
            await frames(2)
            key("r")
            await frames(2)
            check("reset_view", abs(state.orbit.azimuth_deg - az0) < 1e-9, f"azimuth {state.orbit.azimuth_deg:.3f}")
            # 2. clean, the panel already set for the flip of step 3
            app.ui.update(
                field=FIELDS.index("log_scales"), component=args.component, bit=state.bits_per_value() - 1, worst=True
            )
            await frames(2)
            clean = grab()
            iio.imwrite(args.out / f"{args.prefix}clean.png", clean)
            report["clean"] = dict(state.readout)
            check(
                "clean_not_blank",
                clean.std() > 10 and len(np.unique(clean.reshape(-1, 3), axis=0)) > 50,
                f"std={clean.std():.1f}",
            )
            # 3. sign-bit flip of a log-scale through the panel's action
            app.inject_from_panel()
            await frames(3)
            sheet = grab()
            iio.imwrite(args.out / f"{args.prefix}sheet.png", sheet)
            report["sheet"] = dict(state.readout)
            foot = state.readout.get("footprint", 0.0)
            check("flip_visible", foot > 0.01, f"footprint {foot:.4f}")
            region = (slice(None), slice(PANEL_WIDTH, None))
            diff = np.abs(sheet[region].astype(int) - clean[region].astype(int)).max(axis=-1)
            check(
                "window_changed",
                (diff > 2).mean() > 0.01,
                f"{(diff > 2).mean():.4f} of the render area changed on screen",
            )
            # 4. S: the viewer's own screenshot (swap chain), compared with the X screen
            key("s")
            await frames(2)
            check("s_key_screenshot", len(app.saved) == 1 and app.saved[0].exists(), f"saved {app.saved}")
            if app.last_window is not None:
                onscreen = grab()
                d = np.abs(onscreen.astype(int) - app.last_window[..., :3].astype(int)).max(axis=-1)
                # the render area must match exactly; the panel's text moves on (status line, fps)
                check(
                    "screen_matches_swapchain",
                    (d[:, PANEL_WIDTH:] <= 1).all(),
                    f"render area: max |X screen - swap chain| = {d[:, PANEL_WIDTH:].max()}; "
                    f"panel: {int((d[:, :PANEL_WIDTH] > 1).sum())} px changed since",
                )
            # 5. guard on, then undo and close
            key("g")
            await frames(2)
            report["guard"] = dict(state.readout)
            g = state.readout
            check(
                "guard_bounds_flip",
                g["footprint"] < foot and g["alert"],
                f"footprint {g['footprint']:.4f}, clamps {g['clamps']}, alert {g['alert']}",
            )
            key("u")
            await frames(2)
            check(
                "undo_restores",
                state.readout["footprint"] == 0.0 and not state.active_sites,
                f"footprint {state.readout['footprint']}",
            )
        except Exception as e:  # report, close the window, fail
            import traceback

            errors.append(f"driver: {type(e).__name__}: {e}")
            traceback.print_exc()
        finally:
            key("q")
            canvas.close()

    loop.add_task(script, name="viewer-driver")
    loop.call_later(args.timeout, lambda: (errors.append(f"timeout after {args.timeout:.0f} s"), canvas.close()))
    loop.run()
    report["seconds"] = round(time.time() - t_start, 1)
    report["errors"] = errors
    for k in ("clean", "sheet", "guard"):
        if k in report:
            report[k] = {
                kk: (vv if not isinstance(vv, float) or np.isfinite(vv) else str(vv)) for kk, vv in report[k].items()
            }
    (args.report or args.out / f"{args.prefix}report.json").write_text(json.dumps(report, indent=1, default=str))
    for name, c in report["checks"].items():
        print(f"{'ok  ' if c['ok'] else 'FAIL'} {name}: {c['detail']}")
    for p_ in app.saved:
        p_.unlink(missing_ok=True)  # the S-key PNG duplicates the sheet: keep the folder tidy
    if errors:
        print("viewer_xvfb: " + "; ".join(errors), file=sys.stderr)
        return 1
    print(
        f"wrote {args.out / (args.prefix + 'clean.png')}, {args.out / (args.prefix + 'sheet.png')} "
        f"({report['seconds']} s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
