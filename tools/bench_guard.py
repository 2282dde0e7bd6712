"""Cost of the support guard per frame, as a ratio to one rendered view, measured in one run.

    python tools/bench_guard.py [--n 100000 1000000] [--size 256x256] [--repeats 5] [--json out.json]

Two modes: the scrub (one pass over the stored model that clamps and rewrites it; run once per
frame or per scrub period) and the in-pipeline clamp (extra work inside the projection of every
view). Reported: median seconds of one rendered view (K = 1), of one scrub, of one guarded view
(timed in interleaved rounds, after a warm-up on GPU adapters), and the ratios scrub / view and
(guarded view - view) / view.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.faults.guard import component_mask, guard_fields, scrub, stored_box  # noqa: E402
from seuwgpu.model.checks import image_size as parse_size  # noqa: E402
from seuwgpu.model.scenes import make_scene, scene_cameras  # noqa: E402
from seuwgpu.render.renderer import Renderer  # noqa: E402

WARM_UP_S = 1.0
"""Seconds of rendering before timing on a GPU adapter: an idle NVIDIA GPU runs at a fraction of
its clock, so a view timed after a single warm-up is several times too slow (docs/renderer.md
"Measurements")."""


def _seconds(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def measure(r, box, fields, repeats: int) -> tuple[float, float, float]:
    """Median seconds of a view, a scrub and a guarded view, timed in interleaved rounds (so that
    clock or load drift reaches all three alike) after a warm-up."""
    rows, mask = box.rows(), component_mask(fields, r.degree)
    r.run()
    if not r.gpu.is_cpu:
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < WARM_UP_S:
            r.run()
    scrub(r, box, fields)
    r.set_guard(rows, mask)
    r.run()  # the guarded projection's pipeline is built on first use
    times = {"view": [], "scrub": [], "guarded": []}
    for _ in range(repeats):
        r.set_guard(None, 0)
        times["view"].append(_seconds(r.run))
        times["scrub"].append(_seconds(lambda: scrub(r, box, fields)))
        r.set_guard(rows, mask)
        times["guarded"].append(_seconds(r.run))
    r.set_guard(None, 0)
    return tuple(float(np.median(times[k])) for k in ("view", "scrub", "guarded"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="spheres")
    ap.add_argument("--n", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--precision", default="fp32")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    w, h = parse_size(args.size)
    rows = []
    for n in args.n:
        model = make_scene(args.scene, n=n)
        r = Renderer(model, scene_cameras(args.scene, 1, w, h), args.precision)
        box = stored_box(r.layout, r.clean_words, args.precision)
        t_view, t_scrub, t_guarded = measure(r, box, guard_fields("guard"), args.repeats)
        rows.append(
            {
                "n": n,
                "size": args.size,
                "view_s": t_view,
                "scrub_s": t_scrub,
                "guarded_view_s": t_guarded,
                "scrub_over_view": t_scrub / t_view,
                "in_pipeline_overhead": (t_guarded - t_view) / t_view,
            }
        )
    from rich.console import Console
    from rich.table import Table

    from seuwgpu.gpu.device import get_gpu

    info = get_gpu().info
    tab = Table(
        title=f"support guard cost, {args.scene} {args.size} {args.precision} on {info.get('device')} "
        f"({info.get('backend_type')})"
    )
    for c in ("primitives", "view ms", "scrub ms", "scrub / view", "guarded view ms", "in-pipeline overhead"):
        tab.add_column(c, justify="right")
    for row in rows:
        tab.add_row(
            f"{row['n']:,}",
            f"{1e3 * row['view_s']:.1f}",
            f"{1e3 * row['scrub_s']:.1f}",
            f"{row['scrub_over_view']:.3f}",
            f"{1e3 * row['guarded_view_s']:.1f}",
            f"{100 * row['in_pipeline_overhead']:+.1f}%",
        )
    Console().print(tab)
    if args.json:
        args.json.write_text(json.dumps({"adapter": info.get("device"), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
