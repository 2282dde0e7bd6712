"""Memory per splat of the renderer, measured: the device buffers a Renderer allocates (grouped by
what they hold), bytes per primitive and per tile-list pair, the process's peak host memory, and
the time of one rendered view, for each model size given.

    python tools/memory.py [--scene spheres] [--n 100000 4000000] [--size 256x256] [--json out.json]

Device bytes are the sizes of the wgpu buffers reachable from the Renderer (each counted once),
after one frame (the tile-list buffers have grown to the frame's pairs). Per primitive: everything
that scales with N (the stored model, the projection records, the depth-sort and binning scratch)
divided by N; per pair: the tile-list buffers (pairs, their sort scratch, pixel boxes) divided by
their capacity. On lavapipe device buffers live in host memory, so the peak RSS includes them.
The largest model a device holds follows from these numbers and its memory; the output says
which per-binding limit bounds it first.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import wgpu

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.model.checks import image_size as parse_size  # noqa: E402
from seuwgpu.model.scenes import make_scene, scene_cameras  # noqa: E402
from seuwgpu.render.renderer import Renderer  # noqa: E402

# What a buffer holds, from its label: the tile-list pairs (and the chunk slabs sized by them),
# the pixels, the radix sorts' ping-pong
# scratch (shared by the depth and the tile sort: one entry per primitive plus one per pair slot),
# or the primitives (everything else that is not a fixed-size parameter block).
PAIR_LABELS = ("bin.isect", "composite.slabs", "composite.extra_list", "composite.merge_list")
PIXEL_LABELS = ("composite.image",)
SCRATCH_LABELS = ("sort.keys_tmp", "sort.vals_tmp")


def buffers(obj, seen=None, depth=0) -> dict:
    """{id: buffer} of every wgpu buffer reachable from obj's attributes (lists, dicts, tuples)."""
    seen = {} if seen is None else seen
    if depth > 6:
        return seen
    if isinstance(obj, wgpu.GPUBuffer):
        seen.setdefault(id(obj), obj)
        return seen
    if isinstance(obj, (list, tuple)):
        for x in obj:
            buffers(x, seen, depth + 1)
        return seen
    if isinstance(obj, dict):
        for x in obj.values():
            buffers(x, seen, depth + 1)
        return seen
    if hasattr(obj, "__dict__") and type(obj).__module__.startswith(("seuwgpu", "__main__")):
        for x in vars(obj).values():
            buffers(x, seen, depth + 1)
    return seen


def kind(label: str) -> str:
    if label.startswith(PIXEL_LABELS):
        return "pixels"
    if label.startswith(PAIR_LABELS):
        return "pairs"
    if label.startswith(SCRATCH_LABELS):
        return "scratch"
    return "primitives"


def note(text: str):
    """Progress on stderr: at 100M primitives each phase takes minutes."""
    print(text, file=sys.stderr, flush=True)


def measure(scene: str, n: int, w: int, h: int, precision: str) -> dict:
    t = time.perf_counter()
    model = make_scene(scene, n, 3, 0)
    make_s = time.perf_counter() - t
    note(f"N={n:,}: scene made in {make_s:.1f} s")
    cams = scene_cameras(scene, 1, w, h)
    t = time.perf_counter()
    r = Renderer(model, cams, precision=precision)
    note(f"N={n:,}: encoded and uploaded in {time.perf_counter() - t:.1f} s")
    totals = r.run()
    first_s = time.perf_counter() - t
    note(f"N={n:,}: first frame done {first_s:.1f} s after the upload began")
    times = []
    for _ in range(3):
        t = time.perf_counter()
        r.run()
        times.append(time.perf_counter() - t)
    by_kind: dict[str, int] = {"primitives": 0, "pairs": 0, "pixels": 0, "scratch": 0}
    by_label: dict[str, int] = {}
    for buf in buffers(r).values():
        label = buf.label or "?"
        by_kind[kind(label)] += buf.size
        by_label[label] = by_label.get(label, 0) + buf.size
    pairs = int(totals[0])
    return {
        "scene": scene,
        "n": n,
        "size": f"{w}x{h}",
        "precision": precision,
        "pairs": pairs,
        "capacity": int(r.capacity),
        "device_bytes": sum(by_kind.values()),
        "bytes_per_primitive": by_kind["primitives"] / n,
        "bytes_per_pair_capacity": by_kind["pairs"] / max(1, r.capacity),
        "sort_scratch_bytes_per_entry": by_kind["scratch"] / (n + r.capacity),
        "pixel_bytes": by_kind["pixels"],
        "by_label": dict(sorted(by_label.items(), key=lambda kv: -kv[1])),
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "make_scene_s": make_s,
        "first_frame_s": first_s,
        "view_s": sorted(times)[1],
        "max_storage_binding": int(r.gpu.max_binding),
        "adapter": r.gpu.adapter.info.get("device", "?"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="spheres")
    ap.add_argument("--n", type=int, nargs="+", default=[100_000, 4_000_000])
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--precision", default="fp32")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    w, h = parse_size(a.size)
    out = []
    for n in a.n:
        rec = measure(a.scene, n, w, h, a.precision)
        out.append(rec)
        top = ", ".join(f"{k} {v / n:.0f}" for k, v in list(rec["by_label"].items())[:6])
        print(
            f"{a.scene} N={n:,} {rec['size']} {a.precision}: device {rec['device_bytes'] / 2**20:,.0f} MiB = "
            f"{rec['bytes_per_primitive']:.0f} B/primitive + {rec['bytes_per_pair_capacity']:.0f} B/pair x "
            f"{rec['capacity']:,} pair capacity ({rec['pairs']:,} used) + sort scratch "
            f"{rec['sort_scratch_bytes_per_entry']:.0f} B x (primitives + pair capacity) + "
            f"{rec['pixel_bytes'] / 2**20:.1f} MiB frames; "
            f"peak RSS {rec['peak_rss_bytes'] / 2**30:.2f} GiB; view {1000 * rec['view_s']:.0f} ms "
            f"(first frame {rec['first_frame_s']:.1f} s, scene {rec['make_scene_s']:.1f} s)\n"
            f"  largest (B/primitive): {top}"
        )
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
