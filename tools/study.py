"""Regenerate the study of docs/study: run its campaigns, then the report, and time each step.

    python tools/study.py --out runs/study               # the full study (long: see docs/study)
    python tools/study.py --out runs/study-small --small # the same pipeline at a tiny scale
    python tools/study.py --out runs/study-cpu --cpu     # a CPU-sized study (minutes on lavapipe)

--small keeps the scenes, precisions, defenses and analyses but shrinks every spec (64 px, 2 views,
2 samples per cell, 3 dose repeats up to k = 1,000, sizes sampled 2 per cell) so the whole chain
can be checked in minutes. Campaigns resume: re-running the same command skips finished parts.
Timings (seconds per step, device, injections) go to OUT/timings.json and are printed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPECS = ("study.toml", "study_gsplat.toml", "study_dose.toml", "study_size.toml", "study_size_large.toml")


def shrink(raw: dict) -> dict:
    """The spec at a tiny scale, everything else kept."""
    raw = dict(raw, views=2, size="64x64", batch=512)
    raw["name"] = raw.get("name", "study") + "-small"
    if "single" in raw:
        raw["single"] = dict(raw["single"], samples=2, regions=[4, 16])
    if "dose" in raw:
        d = {k: v for k, v in raw["dose"].items() if k not in ("k", "k_max", "points")}
        raw["dose"] = dict(d, k_max=1000, points=5, repeats=3)
    if "sizes" in raw:
        raw["sizes"] = dict(raw["sizes"], samples=2)
    return raw


def cpu_sized(raw: dict, samples: int = 16) -> dict:
    """The study at the scale a 2-core CPU (lavapipe) runs in minutes (docs/study/cpu; its time in
    docs/renderer.md "Measurements"): the same scenes, 256 px, 4 views, precisions, defenses and analyses, with
    fewer samples per cell (`samples` single upsets per (field, bit) cell and scene, default 16; 4
    per cell and size in the size sweep); the dose sweep unchanged."""
    raw = dict(raw)
    raw["name"] = raw.get("name", "study") + "-cpu"
    if "single" in raw:
        raw["single"] = dict(raw["single"], samples=samples)
    if "sizes" in raw:
        raw["sizes"] = dict(raw["sizes"], samples=4)
    return raw


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="folder for the runs, the report and timings.json")
    scale = ap.add_mutually_exclusive_group()
    scale.add_argument("--small", action="store_true", help="a tiny version of every spec (minutes)")
    scale.add_argument(
        "--cpu",
        action="store_true",
        help="fewer samples per cell (minutes on lavapipe: --samples 48, docs/study/cpu, took 574 s on 2 cores)",
    )
    ap.add_argument("--samples", type=int, default=16, help="with --cpu: single upsets per (field, bit) cell and model")
    ap.add_argument("--specs", nargs="*", default=list(SPECS), help="spec files of docs/study to run")
    args = ap.parse_args(argv)

    from seuwgpu.campaign import store
    from seuwgpu.campaign.runner import Runner
    from seuwgpu.campaign.spec import normalize_spec
    from seuwgpu.errors import TooBig
    from seuwgpu.gpu.device import get_gpu
    from seuwgpu.report.build import build_report

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    gpu = get_gpu()
    timings = {"device": str(gpu.info.get("device", gpu.info)), "small": args.small, "cpu": args.cpu, "steps": []}
    runs = []
    for name in args.specs:
        path = ROOT / "docs" / "study" / name
        raw = tomllib.loads(path.read_text())
        if args.small:
            raw = shrink(raw)
        elif args.cpu:
            raw = cpu_sized(raw, args.samples)
        spec = normalize_spec(raw, path.parent)
        run_dir = out / Path(name).stem
        t0 = time.perf_counter()
        stats = Runner(spec, run_dir, quiet=True, gpu=gpu).run()
        dt = time.perf_counter() - t0
        # a resumed campaign's wall time here covers only this invocation's blocks; its parts
        # carry their own compute time, so the sum over them is the campaign's whole cost
        compute, untimed = store.run_seconds(run_dir)
        timings["steps"].append(
            {
                "step": f"campaign {name}",
                "seconds": dt,
                "injections": stats["injections"],
                "new_injections": stats["new"],
                "compute_seconds": compute,
                "untimed_parts": untimed,
            }
        )
        (out / "timings.json").write_text(json.dumps(timings, indent=2))
        print(
            f"{name}: {stats['injections']:,} injections ({stats['new']:,} new) in {dt:.1f} s; "
            f"{compute:.1f} s of compute over all its parts"
            + (f" ({untimed} parts without a recorded time)" if untimed else ""),
            file=sys.stderr,
        )
        runs.append(run_dir)
    t0 = time.perf_counter()
    status = 0
    try:  # folds the records as it reads them when they would not fit in memory unfolded
        last = [0.0]

        def progress(i, n):
            if time.perf_counter() - last[0] > 60 or i == n:
                last[0] = time.perf_counter()
                print(f"report: read {i:,} of {n:,} parts", file=sys.stderr)

        build_report(runs, out / "report", progress=progress)
    except TooBig as e:  # the campaigns are kept; their rates are `seuwgpu rates`'s
        timings["report_skipped"] = str(e)
        print(f"report: skipped: {e}", file=sys.stderr)
        status = 2
    dt = time.perf_counter() - t0
    timings["steps"].append({"step": "report", "seconds": dt})
    timings["total_seconds"] = sum(s["seconds"] for s in timings["steps"])
    timings["total_compute_seconds"] = sum(s.get("compute_seconds", s["seconds"]) for s in timings["steps"])
    (out / "timings.json").write_text(json.dumps(timings, indent=2))
    print(
        f"report: {dt:.1f} s; {timings['total_seconds']:.1f} s this run, {timings['total_compute_seconds']:.1f} s of "
        f"compute in all (campaign parts of earlier, interrupted runs included) on {timings['device']}",
        file=sys.stderr,
    )
    return status


if __name__ == "__main__":
    from seuwgpu.errors import SeuwgpuError

    try:
        sys.exit(main())
    except (SeuwgpuError, ValueError) as e:  # a spec or a size this machine cannot take: one line
        print(f"study.py: error: {e}", file=sys.stderr)
        sys.exit(2)
