"""Injections per second of single-upset campaigns: incremental (dirty-tile) path vs full re-render,
measured in one run on the same engine set-up and the same sites, at one or several model sizes.

    python tools/bench_campaign.py [--scene spheres] [--n 100000 [1000000 ...]] [--views 4]
                                   [--size 128x128] [--samples 512] [--full-samples 48]
                                   [--defenses none] [--json out.json]

With several --n the sizes run back to back in one process (one device), and the table ends with
each size's rate as a fraction of the first's and the growth exponent of an injection's cost
against N (least squares of log(1 / rate) on log N): 1 means an upset costs as much more as the
model is larger, 0 that it costs the same.

Sites are drawn stratified over every (field, bit) cell at fp32, as the default campaign does; each
injection is evaluated under every arm of --defenses (paired, as a campaign does: the study's
`none,guard,selective,ecc,dup`), and injections/s counts injections with all their arms. The full
path re-renders all K views for each injection and arm (what the paper's engine does).
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.faults.defenses import check_defense  # noqa: E402
from seuwgpu.faults.engine import Engine  # noqa: E402
from seuwgpu.model import encoding  # noqa: E402
from seuwgpu.model.checks import image_size as parse_size  # noqa: E402
from seuwgpu.model.fields import FIELDS, field_components  # noqa: E402
from seuwgpu.model.scenes import make_scene, scene_cameras  # noqa: E402


def draw_sites(eng: Engine, count: int, seed: int):
    rng = np.random.default_rng(seed)
    fields = [f for f in FIELDS if field_components(f, eng.degree) > 0]  # SH degree 0 stores no sh_rest
    cells = [(f, b) for f in fields for b in range(encoding.bits_per_value(eng.precision))]
    out = []
    for i in range(count):
        f, b = cells[i % len(cells)]
        out.append(eng.site(f, int(rng.integers(eng.n)), int(rng.integers(field_components(f, eng.degree))), b))
    return out


def measure(args, n: int, arms) -> dict:
    """One size: the incremental and the full path on the same sites."""
    w, h = parse_size(args.size)
    model = make_scene(args.scene, n=n)
    t = time.perf_counter()
    eng = Engine(model, scene_cameras(args.scene, args.views, w, h), args.precision, scene=args.scene)
    sites = draw_sites(eng, args.samples, 0)
    eng.evaluate(sites[:32], arms)  # warm-up: pipelines, buffers, the clean views' checkpoints
    t_setup = time.perf_counter() - t
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
        "n": n,
        "views": args.views,
        "size": args.size,
        "precision": args.precision,
        "defenses": list(arms),
        "setup_seconds": t_setup,
        "incremental_injections": len(sites),
        "incremental_seconds": t_inc,
        "incremental_per_s": len(sites) / t_inc,
        "full_injections": len(full_sites),
        "full_seconds": t_full,
        "full_per_s": len(full_sites) / t_full,
        "speedup": (len(sites) / t_inc) / (len(full_sites) / t_full),
        "records_identical_on_common_sites": same,
    }
    del eng
    gc.collect()
    return res


def growth_exponent(ns, rates) -> float:
    """Slope of log(cost per injection) against log N (NaN for fewer than two sizes)."""
    if len(ns) < 2:
        return float("nan")
    return float(np.polyfit(np.log(np.asarray(ns, float)), -np.log(np.asarray(rates, float)), 1)[0])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="spheres")
    ap.add_argument("--n", type=int, nargs="+", default=[100_000], help="primitive counts, run back to back")
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", default="128x128")
    ap.add_argument("--precision", default="fp32")
    ap.add_argument("--samples", type=int, default=512, help="injections timed on the incremental path")
    ap.add_argument("--full-samples", type=int, default=48, help="injections timed with full re-rendering")
    ap.add_argument("--defenses", default="none", help="comma-separated arms per injection, e.g. none,guard,ecc")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    try:
        w, h = parse_size(args.size)
        arms = tuple(check_defense(d.strip()) for d in args.defenses.split(",") if d.strip()) or ("none",)
    except ValueError as e:
        ap.error(f"--size WxH (e.g. 128x128) and --defenses a comma-separated list: {e}")
    if any(n <= 0 for n in args.n):
        ap.error("--n takes positive primitive counts")
    from rich.console import Console
    from rich.table import Table

    results = []
    for n in args.n:
        results.append(measure(args, n, arms))
        r = results[-1]
        print(f"N={n}: incremental {r['incremental_per_s']:.1f}/s, full {r['full_per_s']:.2f}/s", flush=True)
    first = results[0]
    tab = Table(
        title=f"campaign throughput: {args.scene}, K={args.views}, {args.size}, {args.precision}, "
        f"arms {','.join(arms)} on {first['adapter']} ({first['backend']}), {time.strftime('%Y-%m-%d')}"
    )
    for c in ("primitives", "set-up s", "incremental inj/s", "of the first", "full re-render inj/s", "ratio"):
        tab.add_column(c, justify="right")
    for r in results:
        tab.add_row(
            f"{r['n']:,}",
            f"{r['setup_seconds']:.1f}",
            f"{r['incremental_per_s']:.1f}",
            f"{r['incremental_per_s'] / first['incremental_per_s']:.2f}",
            f"{r['full_per_s']:.2f}",
            f"{r['speedup']:.1f}x",
        )
    Console().print(tab)
    ns = [r["n"] for r in results]
    exp_inc = growth_exponent(ns, [r["incremental_per_s"] for r in results])
    exp_full = growth_exponent(ns, [r["full_per_s"] for r in results])
    if len(ns) > 1:
        print(f"growth exponent of an injection's cost against N: incremental {exp_inc:.2f}, full {exp_full:.2f}")
    for r in results:
        print(
            f"records identical on the {r['full_injections']} common sites at N={r['n']}: "
            f"{r['records_identical_on_common_sites']}"
        )
    if args.json:
        out = {"sizes": results, "growth_exponent": {"incremental": exp_inc, "full": exp_full}}
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
