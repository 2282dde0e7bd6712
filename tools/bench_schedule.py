"""A defense's time measured as a schedule, with many rounds (issue 47 point 6): S plain frames,
S frames with parity4r's check before the first, and S frames checked inside the projection
(parity4f, parity2f; each frame's detection count taken, as a repair needs: it rides on the
frame's own read of its stats, Renderer.carry_back), interleaved round by round on one renderer,
every other round in reverse order;
the median of each configuration's paired ratio to the plain rounds with its distribution-free
95% interval, by two clocks: the wall clock, and the process's CPU time (on a CPU adapter the
device's threads are this process's, so its CPU time is the frame's work without the time other
tenants of a shared host take the cores away; on a GPU it is the host's share alone: read the
wall clock there).

--stages N adds the decomposition a frame check's cost allows (it changes the projection alone):
N interleaved rounds of one frame per configuration on a renderer with timestamp queries around
every pass (tools/bench_stages.py), the projection's time with each check minus the plain one's in
the same round (median, 95% interval), as shares of the plain frame: far less noisy than the whole
frame's wall clock on a shared host; beside it the device's whole frame by the same queries (the
first pass's start to the last pass's end: the frame without the host's recording and waiting).

    python tools/bench_schedule.py [--scene leica-sofort | --model FILE] [--size 256x256] [--every 10] [--rounds 41]
        [--defenses parity4r parity4f parity2f]

Fewer defenses give more rounds in the same time (each round runs every configuration).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from seuwgpu import api  # noqa: E402
from seuwgpu.faults.check import Checker, FrameCheck  # noqa: E402
from seuwgpu.faults.costs import interleaved_samples  # noqa: E402
from seuwgpu.faults.schedule import median_interval  # noqa: E402
from seuwgpu.model import encoding  # noqa: E402
from seuwgpu.model.checks import image_size as parse_size  # noqa: E402
from seuwgpu.render.renderer import Renderer  # noqa: E402

FRAME_CHECKS = ("parity4f", "parity2f")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="leica-sofort")
    ap.add_argument("--model")
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=41)
    ap.add_argument("--stages", type=int, default=0, help="rounds of the projection-stage decomposition")
    ap.add_argument(
        "--defenses", nargs="+", default=["parity4r", "parity4f", "parity2f"], choices=FRAME_CHECKS + ("parity4r",)
    )
    a = ap.parse_args(argv)
    w, h = parse_size(a.size)
    src = api.load_model(a.model or a.scene)  # framed as every command frames it
    model, cam, name = src.model, api.cameras(src, views=1, size=(w, h))[0], a.model or a.scene
    r = Renderer(model, [cam], "fp32")
    clean = encoding.to_bits(model.flat(), "fp32")
    chk = Checker(r, "parity4r", clean) if "parity4r" in a.defenses else None
    frame_checks = {d: FrameCheck(r, clean, d) for d in FRAME_CHECKS if d in a.defenses}
    for fc in frame_checks.values():
        fc.off()

    def plain():
        for _ in range(a.every):
            r.run()

    def checked():
        chk.run()
        plain()

    def in_frame(fc):  # each frame and its detections (carried back in its stats), which decide a repair
        fc.on()
        for _ in range(a.every):
            r.run()
            fc.frame_count()
        fc.off()

    runs = {"plain": plain, **({"parity4r": checked} if chk else {})}
    runs.update({d: (lambda fc=fc: in_frame(fc)) for d, fc in frame_checks.items()})
    clocks = lambda: np.array([time.perf_counter(), time.process_time()])  # noqa: E731
    got = interleaved_samples(runs, a.rounds, clock=clocks, alternate=True)
    p = np.asarray(got["plain"])
    print(
        f"{name}: {model.n:,} primitives, {w}x{h}, S = {a.every}, {len(p)} interleaved rounds, "
        f"{r.gpu.info.get('device', '?')}; a plain frame {1000 * np.median(p[:, 0]) / a.every:.1f} ms wall, "
        f"{1000 * np.median(p[:, 1]) / a.every:.1f} ms CPU (medians)"
    )
    for k in [k for k in runs if k != "plain"]:
        x = np.asarray(got[k])
        shares = []
        for c, clock in enumerate(("wall", "CPU")):
            med, lo, hi = median_interval((x[:, c] - p[:, c]) / p[:, c])
            shares.append(f"{clock} {100 * med:+.2f}% of a frame [95% {100 * lo:+.2f}, {100 * hi:+.2f}]")
        print(f"  {k}: " + "; ".join(shares))
    if a.stages and frame_checks:
        stage_decomposition(model, cam, clean, list(frame_checks), a.stages, float(np.median(p[:, 0])) / a.every)
    return 0


def stage_decomposition(model, cam, clean, defenses, rounds: int, frame_s: float):
    """The projection stage's time with each frame check minus without, by timestamp queries,
    interleaved round by round, and the detection count's read, as shares of a plain frame."""
    from bench_stages import STAGES, StageTimedRenderer

    r = StageTimedRenderer(model, [cam], "fp32")
    checks = {d: FrameCheck(r, clean, d) for d in defenses}
    for fc in checks.values():
        fc.off()
    r.timed = True

    def project_time(fc=None):  # (the projection's seconds, the device's: first pass's start to last's end)
        if fc is not None:
            fc.on()
        r.render()
        t = r.stage_times()
        if fc is not None:
            fc.off()
        return t["project"], sum(t[k] for k in (*STAGES, "other", "gaps"))

    project_time()  # compiles
    for fc in checks.values():
        project_time(fc)
    got = {k: [] for k in ("plain", *checks)}
    order = [("plain", None), *checks.items()]
    for i in range(rounds):  # every other round in reverse order (interleaved_samples' alternate)
        for d, fc in reversed(order) if i % 2 else order:
            got[d].append(project_time(fc))
    plain = np.asarray(got["plain"])
    print(
        f"  by timestamp queries, {rounds} interleaved rounds: the projection stage {1e3 * np.median(plain[:, 0]):.2f} "
        f"ms, the device's frame {1e3 * np.median(plain[:, 1]):.2f} ms (plain, medians); the detection count rides "
        "on the frame's read of its stats (no read of its own)"
    )
    for d in checks:
        x = np.asarray(got[d])
        med, lo, hi = median_interval(x[:, 0] - plain[:, 0])
        share = [100 * v / frame_s for v in (med, lo, hi)]
        fmed, flo, fhi = (100 * v for v in median_interval((x[:, 1] - plain[:, 1]) / plain[:, 1]))
        print(
            f"  {d}: projection {1e3 * med:+.3f} ms [95% {1e3 * lo:+.3f}, {1e3 * hi:+.3f}], "
            f"{share[0]:+.2f}% of a frame [95% {share[1]:+.2f}, {share[2]:+.2f}]; the device's frame "
            f"{fmed:+.2f}% [95% {flo:+.2f}, {fhi:+.2f}]"
        )


if __name__ == "__main__":
    raise SystemExit(main())
