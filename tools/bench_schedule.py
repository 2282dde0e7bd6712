"""A defense's time measured as a schedule, with many rounds (issue 47 point 6): S plain frames,
S frames with parity4r's check before the first, and S frames checked inside the projection
(parity4f, parity2f; each frame's detection count read, as a repair needs), interleaved round by
round on one renderer; the median of each configuration's paired ratio to the plain rounds with
its distribution-free 95% interval.

    python tools/bench_schedule.py [--scene leica-sofort | --model FILE] [--size 256x256] [--every 10] [--rounds 41]
        [--defenses parity4r parity4f parity2f]

Fewer defenses give more rounds in the same time (each round runs every configuration).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

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

    def in_frame(fc):  # each frame and the 4-byte read of its detections, which decides a repair
        fc.on()
        for _ in range(a.every):
            r.run()
            fc.count()
        fc.off()

    runs = {"plain": plain, **({"parity4r": checked} if chk else {})}
    runs.update({d: (lambda fc=fc: in_frame(fc)) for d, fc in frame_checks.items()})
    got = interleaved_samples(runs, a.rounds)
    p = np.asarray(got["plain"])
    print(
        f"{name}: {model.n:,} primitives, {w}x{h}, S = {a.every}, {len(p)} interleaved rounds, "
        f"{r.gpu.info.get('device', '?')}; a plain frame {1000 * np.median(p) / a.every:.1f} ms (median)"
    )
    for k in [k for k in runs if k != "plain"]:
        med, lo, hi = median_interval((np.asarray(got[k]) - p) / p)
        print(f"  {k}: {100 * med:+.2f}% of a frame [95% {100 * lo:+.2f}, {100 * hi:+.2f}]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
