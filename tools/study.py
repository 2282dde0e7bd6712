"""Regenerate the study of docs/study: run its campaigns, then the report, and time each step.

    python tools/study.py --out runs/study               # the full study (long: see docs/study)
    python tools/study.py --out runs/study-small --small # the same pipeline at a tiny scale
    python tools/study.py --out runs/study-cpu --cpu     # a CPU-sized study (minutes on lavapipe)
    python tools/study.py --real /work/corpus --out runs/real          # the study on the real corpus
    python tools/study.py --real /work/corpus --out runs/real --plan   # its plan and time, nothing run

--real CORPUS runs the specs of docs/study/real (issue 46) with their model paths read under the
corpus folder (`seuwgpu corpus --out CORPUS`), then writes the report and, beside it, the single
upsets' records cut to the columns the headline numbers need (records_single.parquet: what
tests/test_study_real.py recomputes them from).

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
# the real corpus' study (docs/study/real), cheapest-to-lose last: the report needs real.toml first
REAL_SPECS = (
    "real.toml",
    "real_size.toml",
    "real_size_131k.toml",
    "real_size_large.toml",
    "real_gsplat.toml",
    "real_fp16.toml",
    "real_dose.toml",
)
# the rates of the first run of the real study on this 2-core lavapipe host (docs/study/real/README.md,
# "Wall time"): 4 arms' injections a second after a (model, spec) context's start, that start, and
# a dose render (k upsets, every view drawn anew) per arm; 2 arms are taken at twice the 4 arms'
# rate, 3 at 4/3 of it (the gsplat profile and fp16 ran slower: the README gives their times)
REAL_RATES = {"single_4arms": 224.0, "setup_s": 10.0, "dose_render_s": 1.19}


def with_samples(raw: dict, samples: int) -> dict:
    """The spec with `samples` upsets a cell (single and sizes) and at most 2 dose repeats."""
    raw = dict(raw)
    for key in ("single", "sizes"):
        if key in raw:
            raw[key] = dict(raw[key], samples=samples)
    if "dose" in raw:
        raw["dose"] = dict(raw["dose"], repeats=min(2, raw["dose"].get("repeats", 2)))
    return raw


def estimate_seconds(plan, spec_raw: dict) -> float:
    """The plan's compute time from the measured rates (REAL_RATES): injections at the rate for the
    spec's arms, plus the start of each (model, size) context."""
    arms = len((spec_raw.get("single") or spec_raw.get("sizes") or spec_raw.get("dose"))["defenses"])
    total = REAL_RATES["setup_s"] * len(plan)
    for _, r in plan.iterrows():
        if r["campaign"] == "dose":
            total += r["injections"] * r["arms"] * REAL_RATES["dose_render_s"]
        else:
            total += r["injections"] / (REAL_RATES["single_4arms"] * 4 / arms)
    return total


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
    scale.add_argument(
        "--real", metavar="CORPUS", help="the real corpus' study (docs/study/real) on this corpus folder"
    )
    ap.add_argument(
        "--samples", type=int, default=None, help="upsets per (field, bit) cell (--cpu: default 16; --real: the specs')"
    )
    ap.add_argument("--specs", nargs="*", default=None, help="spec files of docs/study (or docs/study/real) to run")
    ap.add_argument(
        "--plan", action="store_true", help="with --real: print the plan and its estimated time, run nothing"
    )
    args = ap.parse_args(argv)
    if args.real:
        return run_real(args)
    args.samples = 16 if args.samples is None else args.samples
    args.specs = list(SPECS) if args.specs is None else args.specs
    from seuwgpu.campaign.spec import normalize_spec

    specs = []
    for name in args.specs:
        path = ROOT / "docs" / "study" / name
        raw = tomllib.loads(path.read_text())
        if args.small:
            raw = shrink(raw)
        elif args.cpu:
            raw = cpu_sized(raw, args.samples)
        specs.append((name, normalize_spec(raw, path.parent)))
    return run_specs(args, specs)


def run_specs(args, specs: list) -> int:
    """Run each (name, spec) into OUT/<name's stem> (resuming what is there), then the report of
    them all into OUT/report; timings.json says what each step took."""
    from seuwgpu.campaign import store
    from seuwgpu.campaign.runner import Runner
    from seuwgpu.errors import TooBig
    from seuwgpu.gpu.device import get_gpu
    from seuwgpu.report.build import build_report

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    gpu = get_gpu()
    timings = {"device": str(gpu.info.get("device", gpu.info)), "small": args.small, "cpu": args.cpu, "steps": []}
    timings.update(real=args.real)
    runs = []
    for name, spec in specs:
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
        if args.real:
            profile_claims(runs, out / "report")
            headline_records(runs, out / "report")
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


HEADLINE_COLUMNS = ["scene", "n_primitives", "precision", "profile", "field", "bit", "defense"]
HEADLINE_COLUMNS += ["catastrophic", "weight"]


def headline_records(runs: list, report: Path) -> None:
    """The single upsets' records (one upset each, k = 1) cut to the columns that the headline
    numbers need, small enough to commit beside the report (records_single.parquet), so a test
    recomputes those numbers from records and not from the report's own tables."""
    from seuwgpu.api import read_records

    single = [r for r in runs if (r / "manifest.json").exists() and "size" not in r.name and "dose" not in r.name]
    df = read_records(single)
    df = df.loc[(df["campaign"] == "single") & (df["k"] == 1), HEADLINE_COLUMNS].reset_index(drop=True)
    for c in ("scene", "precision", "profile", "field", "defense"):
        df[c] = df[c].astype("category")
    df["bit"] = df["bit"].astype("int8")
    df.to_parquet(report / "records_single.parquet", index=False, compression="zstd")


def profile_claims(runs: list, report: Path) -> None:
    """The sign-flip claims under each renderer profile (claims.sign_rows_by_profile), from the
    unfolded records of the runs that hold log-scale sign flips under several profiles, into the
    report folder as claims_by_profile.csv/.md (the report itself rests on the strict records)."""
    from seuwgpu.analysis import claims
    from seuwgpu.api import read_records
    from seuwgpu.report.format import markdown_table

    single = [r for r in runs if (r / "manifest.json").exists() and "size" not in r.name and "dose" not in r.name]
    df = read_records(single)
    df = df[(df["field"] == "log_scales") & (df["bit_class"] == "sign")]
    t = claims.sign_rows_by_profile(df)
    if t.empty:
        return
    t.to_csv(report / "claims_by_profile.csv", index=False)
    (report / "claims_by_profile.md").write_text(
        f"**Sign-flip claims by renderer profile.** {claims.PAPER_PROFILE_NOTE}\n\n" + markdown_table(t) + "\n"
    )


def run_real(args) -> int:
    """The real corpus' study: plan or run its specs, then the report (module notes)."""
    from seuwgpu.api import plan_campaign
    from seuwgpu.campaign.spec import normalize_spec

    corpus = Path(args.real).expanduser().resolve()
    specs = []
    for name in args.specs or REAL_SPECS:
        raw = tomllib.loads((ROOT / "docs" / "study" / "real" / name).read_text())
        if args.samples is not None:
            raw = with_samples(raw, args.samples)
        specs.append((name, raw, normalize_spec(raw, corpus)))
    if args.plan:
        total = 0.0
        for name, raw, spec in specs:
            plan = plan_campaign(spec)
            est = estimate_seconds(plan, raw)
            total += est
            print(
                f"## {name}: {int(plan['injections'].sum()):,} injections, {int(plan['records'].sum()):,} records, "
                f"about {est / 60:.0f} min at the measured rates"
            )
            print(plan.to_string(index=False))
        print(f"total: about {total / 3600:.2f} h of campaigns at the measured rates (REAL_RATES; the report on top)")
        return 0
    return run_specs(args, [(name, spec) for name, _, spec in specs])


if __name__ == "__main__":
    from seuwgpu.errors import SeuwgpuError

    try:
        sys.exit(main())
    except (SeuwgpuError, ValueError) as e:  # a spec or a size this machine cannot take: one line
        print(f"study.py: error: {e}", file=sys.stderr)
        sys.exit(2)
