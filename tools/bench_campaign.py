"""Injections per second of single-upset campaigns: incremental (dirty-tile) path vs full re-render,
measured in one run on the same engine set-up and the same sites.

    python tools/bench_campaign.py [--scene spheres] [--n 100000] [--views 4] [--size 128x128]
                                   [--samples 512] [--full-samples 64] [--defenses none]
                                   [--json out.json]

Sites are drawn stratified over every (field, bit) cell at fp32, as the default campaign does; each
injection is evaluated under every arm of --defenses (paired, as a campaign does: the study's
`none,guard,selective,ecc,dup`), and injections/s counts injections with all their arms. The full
path re-renders all K views for each injection and arm (what the paper's engine does).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.faults.defenses import check_defense  # noqa: E402
from seuwgpu.faults.engine import Engine  # noqa: E402
from seuwgpu.model import encoding  # noqa: E402
from seuwgpu.model.fields import FIELDS, field_components  # noqa: E402
from seuwgpu.model.scenes import make_scene, scene_cameras  # noqa: E402


def draw_sites(eng: Engine, count: int, seed: int):
    rng = np.random.default_rng(seed)
    cells = [(f, b) for f in FIELDS for b in range(encoding.bits_per_value(eng.precision))]
    out = []
    for i in range(count):
        f, b = cells[i % len(cells)]
        out.append(eng.site(f, int(rng.integers(eng.n)), int(rng.integers(field_components(f, eng.degree))), b))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="spheres")
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", default="128x128")
    ap.add_argument("--precision", default="fp32")
    ap.add_argument("--samples", type=int, default=512, help="injections timed on the incremental path")
    ap.add_argument("--full-samples", type=int, default=48, help="injections timed with full re-rendering")
    ap.add_argument("--defenses", default="none", help="comma-separated arms per injection, e.g. none,guard,ecc")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
        arms = tuple(check_defense(d.strip()) for d in args.defenses.split(",") if d.strip()) or ("none",)
    except ValueError as e:
        ap.error(f"--size WxH (e.g. 128x128) and --defenses a comma-separated list: {e}")
    model = make_scene(args.scene, n=args.n)
    eng = Engine(model, scene_cameras(args.scene, args.views, w, h), args.precision, scene=args.scene)
    sites = draw_sites(eng, args.samples, 0)
    eng.evaluate(sites[:32], arms)  # warm-up: pipelines, buffers
    t = time.perf_counter()
    inc = eng.evaluate(sites, arms)  # rows arm-major: arm a's records at a * len(sites) ..
    t_inc = time.perf_counter() - t
    full_sites = sites[: args.full_samples]
    eng.inject(full_sites[0])
    t = time.perf_counter()
    full = [eng.inject(s, d) for d in arms for s in full_sites]
    t_full = time.perf_counter() - t
    common = [r for a in range(len(arms)) for r in inc[a * len(sites) : a * len(sites) + len(full_sites)]]
    same = all(a["footprint"] == b["footprint"] and a["peak_error"] == b["peak_error"] for a, b in zip(common, full))
    res = {
        "adapter": eng.gpu.info.get("device"),
        "backend": eng.gpu.info.get("backend_type"),
        "scene": args.scene,
        "n": args.n,
        "views": args.views,
        "size": args.size,
        "precision": args.precision,
        "defenses": list(arms),
        "incremental_injections": len(sites),
        "incremental_seconds": t_inc,
        "incremental_per_s": len(sites) / t_inc,
        "full_injections": len(full_sites),
        "full_seconds": t_full,
        "full_per_s": len(full_sites) / t_full,
        "speedup": (len(sites) / t_inc) / (len(full_sites) / t_full),
        "records_identical_on_common_sites": same,
    }
    from rich.console import Console
    from rich.table import Table

    tab = Table(
        title=f"campaign throughput: {args.scene} {args.n} primitives, K={args.views}, {args.size}, "
        f"{args.precision}, arms {','.join(arms)} on {res['adapter']} ({res['backend']})"
    )
    for c in ("path", "injections", "seconds", "injections/s"):
        tab.add_column(c, justify="right")
    tab.add_row("incremental", str(len(sites)), f"{t_inc:.2f}", f"{res['incremental_per_s']:.1f}")
    tab.add_row("full re-render", str(len(full_sites)), f"{t_full:.2f}", f"{res['full_per_s']:.1f}")
    tab.add_row("ratio", "", "", f"{res['speedup']:.1f}x")
    Console().print(tab)
    print(f"records identical on the {len(full_sites)} common sites: {same}")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
