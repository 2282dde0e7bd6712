"""Real models at their real size: load time, peak host memory, ms a frame and campaign
injections/s of each model file given, each measured in a process of its own (so each peak RSS is
that model's alone), back to back in one run with the same settings.

    python tools/bench_models.py MODEL [MODEL ...] [--views 4] [--size 256x256] [--repeats 3]
                                 [--samples 512] [--defenses none,guard] [--lod N] [--json out.json]

A MODEL is anything `seuwgpu --model` takes (a file, an INRIA output or SOG folder, a LOD set).
Per model:
- load: `seuwgpu.api.load_model` (reading and decoding the file), wall seconds;
- ms a frame: K orbit views of the given size that frame the model, rendered in one submission
  after a first (compiling) one, median of `--repeats` renders divided by K;
- campaign: single upsets stratified over every (field, bit) cell at fp32, each evaluated under
  every arm of `--defenses` on the incremental path, as a campaign does (the engine's set-up and a
  32-site warm-up are not timed); injections/s count injections with all their arms;
- peak RSS: the process's maximum resident set, after all of the above (on lavapipe the device
  buffers live in host memory, so it includes them).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def measure(path: str, views: int, size: str, repeats: int, samples: int, arms: tuple[str, ...], lod) -> dict:
    """One model, in this process."""
    from bench_campaign import draw_sites

    import seuwgpu.api as sg
    from seuwgpu.faults.engine import Engine
    from seuwgpu.model.checks import image_size as parse_size
    from seuwgpu.render.renderer import Renderer

    w, h = parse_size(size)
    t = time.perf_counter()
    scene = sg.load_model(path, lod=lod) if lod is not None else sg.load_model(path)
    load_s = time.perf_counter() - t
    model = scene.model
    cams = sg.cameras(scene, views=views, size=(w, h))
    r = Renderer(model, cams, precision="fp32")
    r.run()  # compiles the pipelines, grows the tile lists
    frame_s = []
    for _ in range(repeats):
        t = time.perf_counter()
        r.run()
        frame_s.append((time.perf_counter() - t) / views)
    adapter = r.gpu.adapter.info.get("device", "?")
    del r
    eng = Engine(model, cams, "fp32", scene=scene.name)
    sites = draw_sites(eng, samples, 0)
    eng.evaluate(sites[:32], arms)
    t = time.perf_counter()
    eng.evaluate(sites, arms)
    inj_s = time.perf_counter() - t
    return {
        "model": scene.name,
        "path": str(path),
        "primitives": int(model.n),
        "sh_degree": int(model.sh_degree),
        "load_s": load_s,
        "ms_per_frame": 1000 * statistics.median(frame_s),
        "views": views,
        "size": size,
        "campaign_injections": samples,
        "campaign_arms": list(arms),
        "campaign_per_s": samples / inj_s,
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "adapter": adapter,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+", help="model files or folders")
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--samples", type=int, default=512, help="injections timed per model")
    ap.add_argument("--defenses", default="none,guard", help="comma-separated arms per injection")
    ap.add_argument("--lod", type=int, help="the level of a LOD set (default: its finest)")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # the per-model child
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    arms = tuple(d.strip() for d in args.defenses.split(",") if d.strip())
    if args.one:
        res = measure(args.models[0], args.views, args.size, args.repeats, args.samples, arms, args.lod)
        args.json.write_text(json.dumps(res))
        return 0
    for m in args.models:
        if not Path(m).exists():
            ap.error(f"{m}: no such model file or folder")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, m in enumerate(args.models):
            out = Path(tmp) / f"{i}.json"
            cmd = [sys.executable, __file__, m, "--one", "--json", str(out), "--views", str(args.views)]
            cmd += ["--size", args.size, "--repeats", str(args.repeats), "--samples", str(args.samples)]
            cmd += ["--defenses", args.defenses] + (["--lod", str(args.lod)] if args.lod is not None else [])
            t = time.perf_counter()
            subprocess.run(cmd, check=True)
            res = json.loads(out.read_text())
            res["process_s"] = time.perf_counter() - t
            results.append(res)
            print(
                f"{res['model']}: {res['primitives']:,} primitives, load {res['load_s']:.1f} s, "
                f"{res['ms_per_frame']:.0f} ms a frame, {res['campaign_per_s']:.1f} inj/s, "
                f"peak RSS {res['peak_rss_bytes'] / 2**30:.2f} GiB",
                flush=True,
            )
    from rich.console import Console
    from rich.table import Table

    tab = Table(
        title=f"real models: K={args.views}, {args.size}, fp32, arms {','.join(arms)}, "
        f"on {results[0]['adapter']}, {time.strftime('%Y-%m-%d')}"
    )
    for c in ("model", "primitives", "SH", "load s", "peak RSS GiB", "ms a frame", "campaign inj/s"):
        tab.add_column(c, justify="right")
    for r in results:
        tab.add_row(
            r["model"],
            f"{r['primitives']:,}",
            str(r["sh_degree"]),
            f"{r['load_s']:.2f}",
            f"{r['peak_rss_bytes'] / 2**30:.2f}",
            f"{r['ms_per_frame']:.0f}",
            f"{r['campaign_per_s']:.1f}",
        )
    Console().print(tab)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
