"""Rendering benchmark: Mpix/s, ms per view, per-stage GPU times, and the speed ratio to the numpy twin.

    python tools/bench.py                      # the default grid (see below); tables only
    python tools/bench.py --quick              # a tiny grid (seconds), for a smoke check
    python tools/bench.py --scenes spheres --n 100000 --sizes 256 --views 1 8 --repeats 5 --out b.json

Runs from any directory with the package installed (or from a checkout); the JSON goes only where
--out says (never into the repository by default).

For each (scene, N, size, K) the embedded scene is rendered from K orbit views by one
`Renderer.run()` (the Renderer's unit of work: the K views batched into one command buffer whose
dispatches they share, render/renderer.py; or, where they are not batched, one command buffer a
view on a GPU, so that encoding view v + 1 overlaps the device's work on view v; a "submission"
below is one such run). What is measured, per configuration:

- wall time of a submission: time.perf_counter() around encode + submit + the Renderer's tiny
  readback of its per-view intersection totals (which waits for the GPU), i.e. `Renderer.run()`.
  The image itself is not read back. The first submission is a warm-up and is discarded (on a
  GPU adapter, submissions go on for WARM_UP_S seconds: an idle NVIDIA GPU runs at a fraction of
  its clock, docs/renderer.md "Measurements"); the reported time
  is the median of R timed submissions (fewer than --repeats when one submission
  is slower than the --budget allows; the JSON and the table give R). Python-side encoding is
  part of the time (command buffers cannot be replayed in WebGPU); `encode_ms` reports it apart
  (the fastest of 5 recordings),
  with `dispatches_per_view` and `encode_ceiling_mpix_s` = K * W * H / encode time: the most a
  submission could reach if the device took no time (the bound that recording puts on Mpix/s).
- Mpix/s = K * W * H / median seconds per submission; ms/view = median / K.
- per-stage GPU times, from timestamp queries when the device has "timestamp-query": one more,
  separate, instrumented submission (so the timestamps cannot slow the timed ones), each compute
  pass getting begin/end timestamps, passes summed per stage over the K views. "gaps" is the time
  between passes (barriers, buffer copies) inside the instrumented submission. Without the
  feature only the whole submission's wall time is reported (and the output says so).
- the numpy twin (`seuwgpu.render.reference.render`) in the same run, on view 0 of the same camera set
  (orbit view 0 is the same camera for every K), at the same N and size, unless N exceeds
  --twin-max-n: then it is measured at --twin-max-n primitives of the same scene and NO ratio is
  given (the output names the N it measured). ratio = twin s/view / GPU s/view, both at the same
  scene, N and size; the twin renders views one by one, so its per-view time does not depend on K.
  The GPU's view 0 is read back once, untimed, and compared with the twin (PSNR) as a sanity check.

- measured floors, in the same run, on the same device: an exp-loop microbenchmark (WGSL, vec4
  exp chains: exp evaluations per second) and a buffer copy (bytes per second). Each stage's time
  per view is set against a floor: compositing against (tile-list pairs x TILE^2 pixels) exp
  evaluations at the measured exp rate (what a renderer evaluating every listed pair at every
  pixel of its tile would need; ours skips most evaluations that provably cannot contribute, so
  it may run faster than this floor), every other stage against the bytes it must read and write
  at the measured copy rate (a lower bound: STAGE_BYTES below). "% of floor" = floor / time.
- per compositor shape (--compositors; render/composite.py SHAPES): on a GPU adapter every
  configuration is timed with both full-frame compositors, "lanes" (8 pixels per invocation, the
  CPU default) and "wide" (one pixel per invocation, 256 a tile, the GPU default), one after the
  other in the same run; each record carries a SHA-256 of view 0's bits, and the log says whether
  the shapes' frames are bit-equal (expected: the shapes run the same operations per pixel, and
  GPU builds keep products out of multiply-adds, blend.wgsl UNFUSED; a mismatch is logged). On a
  CPU adapter only the default is timed unless asked.
- batched views against views one at a time (--one-by-one; the default on a GPU adapter): each
  K > 1 configuration is also timed with `batch_views=False`, its record's `batched` false and its
  row marked "1 by 1"; the log compares the two and their frames.
- with --dense FACTOR: load balance of long tile lists. The scene shrunk about its centre by
  FACTOR (means and scales; a few tiles list most pairs) is timed with the default CHUNK and with
  chunking off (every tile list on one workgroup), in the same run (render/composite.py).
- injections per second of a campaign (the incremental single-upset path of faults/engine.py on
  the same scene: K = 4 views at 128x128, stratified sites as tools/bench_campaign.py draws them),
  unless --campaign-samples 0.

Default grid (the issue's required one): scene spheres, N = 100k and 1M, 256x256 and 512x512,
K = 1 and 8 (`--scenes all` for every embedded scene). On lavapipe (2 CPU cores) it takes several
minutes, most of it 1M-primitive submissions.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import importlib.util
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import wgpu  # noqa: E402

from seuwgpu.gpu.constants import CHUNK, COMPOSITORS, TILE  # noqa: E402
from seuwgpu.gpu.device import GPU, get_gpu  # noqa: E402
from seuwgpu.model import scenes  # noqa: E402
from seuwgpu.model.fields import Model  # noqa: E402
from seuwgpu.render import reference  # noqa: E402
from seuwgpu.render.composite import check_chunk, default_shape  # noqa: E402
from seuwgpu.render.renderer import Renderer  # noqa: E402
from seuwgpu.render.sort import tile_key_bits  # noqa: E402

STAGES = ("project", "depth sort", "count+scan", "emit", "tile sort", "ranges", "composite")

# Stage of a compute pass, from its label or the label of the first pipeline it sets (Kernel
# labels its passes and device.pipeline its pipelines "<shader>:<entry>"; the sorters label their
# passes "radix_sort" / "prefix_sum").
_STAGE_OF = {
    "project:main": "project",
    "bin:count_tiles": "count+scan",
    "bin:gather_counts": "count+scan",  # the counts into depth order for the scan
    "bin:scatter_offsets": "count+scan",  # and the offsets back to the records
    "prefix_sum": "count+scan",
    "bin:emit": "emit",
    "bin:tile_ranges": "ranges",
    "composite:main": "composite",
    "composite:chunks": "composite",
    "composite:merge": "composite",
    "composite_wide:main": "composite",
    "composite_wide:chunks": "composite",
}


# ---- timestamp instrumentation ---------------------------------------------------------------------
class _TimedPass:
    """Forwards to a real compute pass; remembers the label of the first pipeline set on it."""

    def __init__(self, cpass, record: dict):
        self._p, self._rec = cpass, record

    def set_pipeline(self, pipeline):
        if self._rec["label"] is None:
            self._rec["label"] = pipeline.label
        self._p.set_pipeline(pipeline)

    def __getattr__(self, name):
        return getattr(self._p, name)


class _CountingEncoder:
    """Forwards to a real command encoder and counts the dispatches recorded in its passes."""

    def __init__(self, encoder):
        self._e, self.dispatches = encoder, 0

    def begin_compute_pass(self, **kw):
        return _CountingPass(self._e.begin_compute_pass(**kw), self)

    def __getattr__(self, name):
        return getattr(self._e, name)


class _CountingPass:
    def __init__(self, cpass, counter: _CountingEncoder):
        self._p, self._c = cpass, counter

    def dispatch_workgroups(self, *a):
        self._c.dispatches += 1
        self._p.dispatch_workgroups(*a)

    def dispatch_workgroups_indirect(self, *a):
        self._c.dispatches += 1
        self._p.dispatch_workgroups_indirect(*a)

    def __getattr__(self, name):
        return getattr(self._p, name)


def count_dispatches(r: Renderer) -> int:
    """Dispatches `r` records for its K views (recorded, then dropped unsubmitted)."""
    enc = _CountingEncoder(r.gpu.device.create_command_encoder())
    r.encode(enc)
    enc.finish()
    return enc.dispatches


class _TimedEncoder:
    """Forwards to a real command encoder, giving every compute pass begin/end timestamp writes
    (WebGPU's portable way: `timestamp_writes` on begin_compute_pass; writes inside an encoder or a
    pass are native-only features). Passes past the query set's size are left untimed and counted."""

    def __init__(self, encoder, query_set, capacity: int):
        self._e, self._qs, self._cap = encoder, query_set, capacity
        self.records: list[dict] = []
        self.untimed = 0

    def begin_compute_pass(self, *, label=None, **kw):
        rec = {"label": label}
        i = 2 * len(self.records)
        if i + 2 <= self._cap:
            kw["timestamp_writes"] = {
                "query_set": self._qs,
                "beginning_of_pass_write_index": i,
                "end_of_pass_write_index": i + 1,
            }
            self.records.append(rec)
        else:
            self.untimed += 1
        cpass = self._e.begin_compute_pass(label=label, **kw) if label else self._e.begin_compute_pass(**kw)
        return _TimedPass(cpass, rec)

    def __getattr__(self, name):
        return getattr(self._e, name)


def timestamp_period_ns(gpu: GPU) -> float:
    """Nanoseconds per timestamp tick (wgpu-native's wgpuQueueGetTimestampPeriod; 1.0 if absent)."""
    try:
        from wgpu.backends.wgpu_native._api import libf

        return float(libf.wgpuQueueGetTimestampPeriod(gpu.queue._internal))
    except Exception:  # noqa: BLE001 - another backend: WebGPU specifies nanoseconds
        return 1.0


class StageTimedRenderer(Renderer):
    """A Renderer whose next submission(s) carry timestamp queries around every compute pass.
    Only `encode` is wrapped; what the Renderer records is unchanged."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.timed = False
        self._ts = None

    def _ensure_queries(self):
        want = min(4096, 2 * self.k * (self.layout.n_chunks + 16))  # ~9 passes per view today
        if self._ts is None or self._ts[1] < want:
            qs = self.gpu.device.create_query_set(type=wgpu.QueryType.timestamp, count=want)
            buf = self.gpu.device.create_buffer(
                size=8 * want, usage=wgpu.BufferUsage.QUERY_RESOLVE | wgpu.BufferUsage.COPY_SRC
            )
            self._ts = (qs, want, buf)
        return self._ts

    def submission_groups(self) -> list[range]:
        return [range(self.k)] if self.timed else super().submission_groups()  # timed: one encoder

    def encode(self, encoder, views=None, split=None):
        if not self.timed:
            return super().encode(encoder, views, split)
        qs, cap, buf = self._ensure_queries()
        proxy = _TimedEncoder(encoder, qs, cap)
        super().encode(proxy, views)  # timed: one encoder (no split), so every pass is in one query set
        if proxy.records:
            encoder.resolve_query_set(qs, 0, 2 * len(proxy.records), buf, 0)
        self._last = proxy
        return encoder

    def stage_times(self) -> dict:
        """Seconds per stage (summed over views) of the last timed submission, plus 'gaps',
        'other' (passes of no known stage) and 'untimed_passes'."""
        proxy, (_, _, buf) = self._last, self._ts
        n = len(proxy.records)
        ticks = np.frombuffer(self.gpu.queue.read_buffer(buf, 0, 16 * n), np.uint64).astype(np.int64)
        ns = timestamp_period_ns(self.gpu)
        begin, end = ticks[0::2], ticks[1::2]
        out = {s: 0.0 for s in STAGES}
        out["other"] = 0.0
        after_emit = False  # a radix sort before a view's emit is the depth sort, after it the tile sort
        for rec, b, e in zip(proxy.records, begin, end):
            name = rec["label"] or ""
            if name == "project:main":
                after_emit = False
            elif name == "bin:emit":
                after_emit = True
            stage = (
                ("tile sort" if after_emit else "depth sort") if name == "radix_sort" else _STAGE_OF.get(name, "other")
            )
            out[stage] += max(0, int(e - b)) * ns * 1e-9
        span = (int(end.max()) - int(begin.min())) * ns * 1e-9 if n else 0.0
        out["gaps"] = max(0.0, span - sum(out[s] for s in (*STAGES, "other")))
        out["untimed_passes"] = proxy.untimed
        out["passes"] = n
        return out


# ---- floors -----------------------------------------------------------------------------------------
_EXP_LOOP = """
override ITERS: u32 = 256u;
@group(0) @binding(0) var<storage, read_write> out: array<vec4<f32>>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    // four independent dependent chains per invocation; x stays in (0, 1], exp(-x) in [0.36, 1]
    var x = vec4<f32>(f32(gid.x & 255u) * 1e-3, 0.25, 0.5, 0.75);
    for (var i = 0u; i < ITERS; i = i + 1u) {
        x = exp(-x);
    }
    out[gid.x] = x;
}
"""


def _median_s(fn, repeats: int) -> float:
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def measure_floors(gpu: GPU, repeats: int = 3, groups: int = 1024, iters: int = 256, copy_mb: int = 32) -> dict:
    """Exp evaluations per second (the WGSL exp loop, `groups` x 64 invocations x `iters` vec4 exps)
    and copy bytes per second (copy_buffer_to_buffer of `copy_mb` MiB), each the median of
    `repeats` submissions waited for."""
    dev = gpu.device
    module = dev.create_shader_module(label="floor-exp", code=_EXP_LOOP)
    pipe = dev.create_compute_pipeline(
        label="floor-exp",
        layout="auto",
        compute={"module": module, "entry_point": "main", "constants": {"ITERS": iters}},
    )
    out = gpu.buffer(16 * 64 * groups)
    # a raw wgpu pipeline of the benchmark's own WGSL (not a stage's): bound as wgpu binds
    bg = dev.create_bind_group(
        layout=pipe.get_bind_group_layout(0),
        entries=[{"binding": 0, "resource": {"buffer": out, "offset": 0, "size": out.size}}],
    )

    def exp_loop():
        enc = dev.create_command_encoder()
        cp = enc.begin_compute_pass()
        cp.set_pipeline(pipe)
        cp.set_bind_group(0, bg)
        cp.dispatch_workgroups(groups, 1, 1)
        cp.end()
        gpu.submit(enc)
        gpu.sync()

    nbytes = copy_mb << 20
    src, dst = gpu.buffer(nbytes), gpu.buffer(nbytes)

    def copy():
        enc = dev.create_command_encoder()
        enc.copy_buffer_to_buffer(src, 0, dst, 0, nbytes)
        gpu.submit(enc)
        gpu.sync()

    t_exp, t_copy, t_sync = _median_s(exp_loop, repeats), _median_s(copy, repeats), _median_s(gpu.sync, repeats)
    evals = 4 * 64 * groups * iters
    return {
        "exp_per_s": evals / max(t_exp - t_sync, 1e-9),
        "copy_bytes_per_s": nbytes / max(t_copy - t_sync, 1e-9),
        "exp_evals": evals,
        "copy_bytes": nbytes,
        "what": f"exp: {evals:,} vec4-lane exps in one dispatch; copy: {copy_mb} MiB buffer to buffer; "
        "each the median of submissions waited for, minus an empty round trip",
    }


def stage_floor_s(stage: str, *, n: int, pairs: int, n_tiles: int, model_bytes: int, floors: dict) -> float | None:
    """Floor of one stage for one view (seconds): compositing from the exp rate, the others from
    the bytes they must move (STAGE_BYTES) at the copy rate (a copy reads and writes each byte)."""
    if stage == "composite":
        return pairs * TILE * TILE / floors["exp_per_s"]
    moved = STAGE_BYTES[stage](n=n, pairs=pairs, n_tiles=n_tiles, model_bytes=model_bytes)
    return None if moved is None else moved / (2 * floors["copy_bytes_per_s"])


# Bytes each stage must read + write per view, at least (n primitives, `pairs` tile intersections):
# projection reads the stored model and writes 56 B of records per primitive; a 4-bit LSD radix
# sort pass reads and writes a (key, value) pair per element; binning reads rectangles and the
# order, writes counts, scans them and emits 8 B per pair.
STAGE_BYTES = {
    "project": lambda n, pairs, n_tiles, model_bytes: model_bytes + 56 * n,
    "depth sort": lambda n, pairs, n_tiles, model_bytes: 8 * 16 * n,
    "count+scan": lambda n, pairs, n_tiles, model_bytes: 24 * n,
    "emit": lambda n, pairs, n_tiles, model_bytes: 16 * n + 8 * pairs,
    "tile sort": lambda n, pairs, n_tiles, model_bytes: -(-tile_key_bits(n_tiles) // 4) * 16 * pairs,
    "ranges": lambda n, pairs, n_tiles, model_bytes: None,
}


@functools.cache
def _bench_campaign():
    """tools/bench_campaign.py (its site draw), loaded once however many campaigns are timed."""
    spec = importlib.util.spec_from_file_location(
        "seuwgpu_bench_campaign", Path(__file__).with_name("bench_campaign.py")
    )
    camp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(camp)
    return camp


def measure_campaign(
    scene: str, model, samples: int, views: int = 4, size: int = 128, chunk: int | None = None
) -> dict:
    """Injections per second of the incremental single-upset path (faults/engine.py) on `model`,
    K = `views` at size x size, sites drawn as tools/bench_campaign.py draws them."""
    from seuwgpu.faults.engine import Engine

    camp = _bench_campaign()
    eng = Engine(model, scenes.scene_cameras(scene, views, size, size), "fp32", scene=scene, chunk=chunk)
    sites = camp.draw_sites(eng, samples, 0)
    eng.evaluate_frame(sites[: min(32, samples)])  # warm-up: pipelines, buffers
    t = time.perf_counter()
    eng.evaluate_frame(sites)  # what campaign/runner.py calls (evaluate adds a per-record dict conversion)
    dt = time.perf_counter() - t
    return {
        "injections": samples,
        "seconds": dt,
        "injections_per_s": samples / dt,
        "views": views,
        "size": size,
        "chunk": eng.renderer.compositing.chunk,
    }


# ---- measurement -----------------------------------------------------------------------------------
def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else float(10 * np.log10(1.0 / mse))


WARM_UP_S = 1.0  # seconds of warm-up submissions on GPU adapters (none on CPU adapters: no clocks to raise)


def _warm_up(r: Renderer) -> tuple[float, np.ndarray]:
    """The first submission's (seconds, totals); on a GPU adapter, more submissions until WARM_UP_S
    have passed, so that the timed ones run at the clocks of a busy GPU."""
    first, totals = _submission(r)
    if not r.gpu.is_cpu:
        t = time.perf_counter()
        while time.perf_counter() - t < WARM_UP_S:
            _submission(r)
    return first, totals


def _submission(r: Renderer) -> tuple[float, np.ndarray]:
    """Seconds for one submission, and the per-view intersection totals it read back."""
    t = time.perf_counter()
    totals = r.run()  # encode + submit + read of the per-view totals (waits for the GPU); grows buffers if needed
    return time.perf_counter() - t, totals


def bench_config(
    model,
    scene: str,
    size: int,
    k: int,
    *,
    repeats: int = 3,
    budget: float = 100.0,
    gpu: GPU | None = None,
    twin: dict | None = None,
    stages: bool = True,
    floors: dict | None = None,
    compositor: str | None = None,
    batch_views: bool | None = None,
) -> dict:
    """Measure one (scene, N, size, K) with the full-frame `compositor` shape (None: the device's
    default); `batch_views` False renders the views one at a time (render/renderer.py). `twin`
    (from measure_twin) adds the ratio when its N and size are this config's; `floors` (from
    measure_floors) the stages' floors. Returns the JSON record."""
    gpu = gpu or get_gpu()
    w = h = int(size)
    cams = scenes.scene_cameras(scene, k, w, h)
    r = StageTimedRenderer(model, cams, gpu=gpu, compositor=compositor, batch_views=batch_views)
    warm, totals = _warm_up(r)  # discarded (first use of buffers, possible buffer growth, GPU clocks)
    # Repeats: at most `repeats`, and no more than the budget allows (at least one).
    reps = max(1, min(int(repeats), int(budget // max(warm, 1e-9))))
    times = [_submission(r)[0] for _ in range(reps)]
    med = statistics.median(times)
    # Python-side encoding alone (recorded as run() records it, one encoder per submission group,
    # then dropped unsubmitted): the fastest of 5, since one recording of a few ms is easily
    # doubled by other load on the host (seen on lavapipe's VM)
    encode_times = []
    for _ in range(5):
        t = time.perf_counter()
        for views in r.submission_groups():
            enc = gpu.device.create_command_encoder()
            r.encode(enc, views)
            enc.finish()
        encode_times.append(time.perf_counter() - t)
    encode_s = min(encode_times)

    rec = {
        "scene": scene,
        "n": int(model.n),
        "sh_degree": int(model.sh_degree),
        "precision": r.precision,
        "width": w,
        "height": h,
        "k": k,
        "chunk": r.compositing.chunk,  # pairs a compositing workgroup walks (the device's default)
        "compositor": r.compositing.shape,
        # the bits of view 0 (rgb, T) of the last timed submission: equal digests = the same frame
        # (the compositor shapes are expected to agree bit for bit; the log says where they do not)
        "view0_sha256": hashlib.sha256(gpu.read(r.image, np.uint32, 0, 16 * w * h).tobytes()).hexdigest(),
        "repeats": reps,
        "warmup_s": warm,
        "times_s": times,
        "seconds_per_submission": med,
        "ms_per_view": 1e3 * med / k,
        "mpix_per_s": k * w * h / med / 1e6,
        "min_ms_per_view": 1e3 * min(times) / k,  # the least disturbed run (shared machines are noisy)
        "encode_ms": 1e3 * encode_s,
        "encode_ceiling_mpix_s": k * w * h / encode_s / 1e6,
        "dispatches_per_view": count_dispatches(r) / k,
        "batched": bool(r.batched),  # the K views share their dispatches (render/renderer.py)
        "model_chunks": r.layout.n_chunks,
        "intersections_per_view": [int(x) for x in totals[:k]],
    }

    if stages and "timestamp-query" in gpu.features:
        r.timed = True
        t = time.perf_counter()
        r.run()
        rec["timed_submission_s"] = time.perf_counter() - t
        st = r.stage_times()
        r.timed = False
        rec["stage_source"] = (
            "timestamp-query (one separate instrumented submission; per-pass begin/end, summed over views)"
        )
        rec["stages_ms"] = {s: 1e3 * st[s] for s in (*STAGES, "other", "gaps")}
        # Consistency check: the stages + gaps should add up to about the instrumented wall time.
        rec["stage_sum_ms"] = sum(rec["stages_ms"].values())
        rec["timed_passes"], rec["untimed_passes"] = st["passes"], st["untimed_passes"]
        if floors is not None:
            model_bytes = sum(4 * r.layout.chunk_words for _ in range(r.layout.n_chunks))
            rec["floors_ms_per_view"] = {}
            for stage in STAGES:
                f = stage_floor_s(
                    stage,
                    n=r.n,
                    pairs=int(np.mean(totals[:k])),
                    n_tiles=r.n_tiles,
                    model_bytes=model_bytes,
                    floors=floors,
                )
                rec["floors_ms_per_view"][stage] = None if f is None else 1e3 * f
    else:
        rec["stage_source"] = (
            "none: the device has no timestamp-query feature; only the whole submission's wall time is measured"
            if stages
            else "disabled (--no-stages)"
        )
        rec["stages_ms"] = None

    if twin is not None:
        rec["twin"] = {key: twin[key] for key in ("n", "width", "height", "views", "seconds_per_view", "what")}
        same = twin["n"] == model.n and twin["width"] == w and twin["height"] == h
        rec["twin_ratio"] = twin["seconds_per_view"] / (med / k) if same else None
        if same and "image" in twin:
            # Sanity: the GPU's view 0 (left in the image buffer by the last submission; untimed
            # readback, no re-render) against the twin's.
            img0 = gpu.read(r.image, np.float32, 0, 16 * w * h).reshape(h, w, 4)[..., :3]
            rec["psnr_view0_vs_twin_db"] = _psnr(img0, twin["image"])
    return rec


CHUNK_OFF = 1 << 30  # a chunk longer than any tile list: every tile on one workgroup


def dense_model(model, factor: float = 0.1):
    """The scene shrunk about its centre by `factor` (means and scales): the same primitives drawn
    into a few tiles, each listing a large share of them (the load-balance case of long tile lists)."""
    flat = model.flat().copy()
    centre = flat[:, 0:3].mean(axis=0)
    flat[:, 0:3] = centre + factor * (flat[:, 0:3] - centre)
    flat[:, 3:6] += np.log(factor)
    return Model.from_flat(flat, model.sh_degree)


def _time_at_chunk(
    model, cams, chunk: int, repeats: int, gpu: GPU, compositor: str | None = None
) -> tuple[float, np.ndarray, np.ndarray]:
    """(ms per view, view 0's rgb, the last view's pairs per tile) of `cams` composited in chunks
    of `chunk` pairs by the `compositor` shape: one warm-up, then the median of `repeats`
    submissions."""
    r = Renderer(model, cams, gpu=gpu, chunk=int(chunk), compositor=compositor)
    _warm_up(r)
    times = [_submission(r)[0] for _ in range(max(1, int(repeats)))]
    w, h = r.width, r.height
    img = gpu.read(r.image, np.float32, 0, 16 * w * h).reshape(h, w, 4)[..., :3]
    counts = np.diff(gpu.read(r.binning.ranges).reshape(-1, 2), axis=1)[:, 0]
    return 1e3 * statistics.median(times) / len(cams), img, counts


def measure_chunking(
    model, scene: str, size: int, k: int, *, repeats: int = 3, gpu: GPU | None = None, chunk: int = CHUNK
) -> dict:
    """ms per view of the same frames composited in chunks of `chunk` pairs (default CHUNK) and
    with chunking off (CHUNK_OFF), in this run, on the same device; `model` is typically
    dense_model(...)."""
    gpu = gpu or get_gpu()
    cams = scenes.scene_cameras(scene, k, size, size)
    out = {"scene": scene, "n": int(model.n), "width": size, "height": size, "k": k, "chunk": int(chunk)}
    images = {}
    for name, ch in (("chunked", chunk), ("off", CHUNK_OFF)):
        out[f"ms_per_view_{name}"], images[name], counts = _time_at_chunk(model, cams, ch, repeats, gpu)
    out["max_pairs_per_tile"] = int(counts.max())
    out["long_tiles"] = int((counts > chunk).sum())
    out["tiles"] = int(counts.size)
    out["speedup"] = out["ms_per_view_off"] / out["ms_per_view_chunked"]
    out["psnr_view0_chunked_vs_off_db"] = _psnr(images["chunked"], images["off"])
    return out


def measure_chunk_sweep(
    model,
    scene: str,
    size: int,
    k: int,
    chunks,
    *,
    repeats: int = 3,
    gpu: GPU | None = None,
    compositor: str | None = None,
) -> list:
    """ms per view of the same frames at each compositing chunk (pairs a workgroup walks), in this
    run, with each image's PSNR to the first chunk's: where the critical path is the longest
    walk (a GPU with more workgroup slots than a frame has tiles), smaller chunks shorten it."""
    gpu = gpu or get_gpu()
    cams = scenes.scene_cameras(scene, k, size, size)
    out, first = [], None
    for ch in chunks:
        ms, img, _ = _time_at_chunk(model, cams, ch, repeats, gpu, compositor)
        out.append(
            {
                "scene": scene,
                "n": int(model.n),
                "width": size,
                "height": size,
                "k": k,
                "chunk": int(ch),
                "compositor": compositor or default_shape(gpu),  # what the Renderer uses when told none
                "ms_per_view": ms,
                # None, not inf, for the first chunk (JSON has no infinity)
                "psnr_view0_vs_first_chunk_db": None if first is None else _psnr(img, first),
            }
        )
        first = img if first is None else first
    return out


def measure_twin(scene: str, model, size: int, views: int = 1, max_n: int = 1_000_000, seed: int = 0) -> dict:
    """Seconds per view of reference.render on view(s) 0.. of the orbit set, at the model's N
    (or at `max_n` primitives of the same scene when the model is larger)."""
    n = int(model.n)
    if n > max_n:
        model, n = scenes.make_scene(scene, max_n, model.sh_degree, seed), max_n
    cams = scenes.scene_cameras(scene, max(views, 1), size, size)[: max(views, 1)]
    t = time.perf_counter()
    imgs = reference.render(model, cams)
    s = (time.perf_counter() - t) / len(cams)
    what = (
        f"reference.render on {len(cams)} view(s) of a {len(cams)}-camera orbit (its view 0 = every "
        f"config's view 0), N={n}, {size}x{size}"
    )
    return {
        "n": n,
        "width": size,
        "height": size,
        "views": len(cams),
        "seconds_per_view": s,
        "what": what,
        "image": imgs[0],
    }


def adapter_info(gpu: GPU) -> dict:
    info = gpu.info
    return {
        "device": info.get("device"),
        "description": info.get("description"),
        "vendor": info.get("vendor"),
        "adapter_type": info.get("adapter_type"),
        "backend": info.get("backend_type"),
        "features": sorted(gpu.features),
        "timestamp_period_ns": timestamp_period_ns(gpu) if "timestamp-query" in gpu.features else None,
    }


def run_grid(
    scene_names,
    ns,
    sizes,
    ks,
    *,
    repeats=3,
    budget=100.0,
    twin=True,
    twin_views=1,
    twin_max_n=1_000_000,
    stages=True,
    sh_degree=3,
    seed=0,
    campaign_samples=256,
    dense=None,
    chunks=None,
    compositors=None,
    one_by_one=None,
    log=print,
) -> dict:
    """The whole benchmark; returns the JSON document. `compositors`: the full-frame compositor
    shapes to time each configuration with (render/composite.py SHAPES); None: both on a GPU
    adapter, and the default alone on a CPU adapter (there "wide" is several times slower:
    docs/renderer.md). `one_by_one`: also time each K > 1 configuration (first shape) with its
    views rendered one at a time, the comparison batched views are judged by; None: on a GPU
    adapter, where the two differ most (docs/renderer.md "Measurements")."""
    gpu = get_gpu()
    if compositors is None:
        compositors = [default_shape(gpu)] if gpu.is_cpu else list(COMPOSITORS)
    if one_by_one is None:
        one_by_one = not gpu.is_cpu
    t0 = time.perf_counter()
    floors = measure_floors(gpu)
    log(
        f"floors: {floors['exp_per_s'] / 1e6:,.0f} M exp/s, copy {floors['copy_bytes_per_s'] / 1e9:.2f} GB/s "
        f"({floors['what']})"
    )
    doc = {
        "adapter": adapter_info(gpu),
        "host": {"platform": platform.platform(), "cpus": os.cpu_count(), "loadavg_start": list(os.getloadavg())},
        "settings": {
            "repeats": repeats,
            "budget_s": budget,
            "twin_views": twin_views,
            "twin_max_n": twin_max_n,
            "sh_degree": sh_degree,
            "seed": seed,
            "precision": "fp32",
            "date": time.strftime("%Y-%m-%d"),
        },
        "floors": floors,
        "results": [],
        "campaigns": [],
        "chunking": [],
        "chunk_sweep": [],
        "campaign_chunks": [],
        "compositor_errors": {},  # shape -> the error that dropped it from the run
    }
    for scene in scene_names:
        # a real capture holds what it holds: a larger N is its whole model (once)
        cap = scenes.make_scene(scene).n if scenes.is_capture(scene) else None
        for n in dict.fromkeys(min(n, cap) if cap else n for n in ns):
            t = time.perf_counter()
            model = scenes.make_scene(scene, n, sh_degree, seed)
            log(f"[{scene} N={n}] scene generated in {time.perf_counter() - t:.1f} s")
            for size in sizes:
                tw = None
                if twin:
                    tw = measure_twin(scene, model, size, twin_views, twin_max_n, seed)
                    log(f"[{scene} N={n} {size}x{size}] twin: {tw['seconds_per_view']:.2f} s/view ({tw['what']})")
                for k in ks:
                    first = None
                    config = functools.partial(
                        bench_config,
                        model,
                        scene,
                        size,
                        k,
                        repeats=repeats,
                        budget=budget,
                        gpu=gpu,
                        twin=tw,
                        stages=stages,
                        floors=floors,
                    )
                    for shape in [s for s in compositors if s not in doc["compositor_errors"]]:
                        try:
                            rec = config(compositor=shape)
                            sweep = (
                                measure_chunk_sweep(
                                    model, scene, size, k, chunks, repeats=repeats, gpu=gpu, compositor=shape
                                )
                                if chunks
                                else []
                            )
                        except Exception as e:  # noqa: BLE001 - a candidate shape failing on a device is a result
                            if shape == compositors[0]:
                                raise
                            # the rest of the run (device time is scarce) goes on without this shape
                            doc["compositor_errors"][shape] = f"{type(e).__name__}: {str(e).strip()}"[:2000]
                            log(
                                f"[{scene} N={n} {size}x{size} K={k} {shape}] FAILED, dropped from this run: "
                                + doc["compositor_errors"][shape].splitlines()[0]
                            )
                            continue
                        if first is None:
                            first = rec
                        rec["view0_same_as_first_compositor"] = rec["view0_sha256"] == first["view0_sha256"]
                        doc["results"].append(rec)
                        same = ""
                        if rec is not first:
                            same = f"; view 0 bit-equal to {first['compositor']}'s: " + (
                                "yes" if rec["view0_same_as_first_compositor"] else "NO"
                            )
                        log(
                            f"[{scene} N={n} {size}x{size} K={k} {shape}] {rec['mpix_per_s']:.3f} Mpix/s, "
                            f"{rec['ms_per_view']:.1f} ms/view (median of {rec['repeats']}){same}; recording "
                            f"{rec['encode_ms'] / k:.2f} ms/view, {rec['dispatches_per_view']:g} dispatches/view "
                            f"(at most {rec['encode_ceiling_mpix_s']:,.0f} Mpix/s if the device took no time)"
                        )
                        if one_by_one and k > 1 and rec is first and rec["batched"]:
                            alone = config(compositor=shape, batch_views=False)
                            alone["view0_same_as_first_compositor"] = alone["view0_sha256"] == first["view0_sha256"]
                            doc["results"].append(alone)
                            log(
                                f"[{scene} N={n} {size}x{size} K={k} {shape}, views one at a time] "
                                f"{alone['ms_per_view']:.1f} ms/view against {rec['ms_per_view']:.1f} batched; "
                                f"view 0 bit-equal: {'yes' if alone['view0_same_as_first_compositor'] else 'NO'}"
                            )
                        if sweep:
                            doc["chunk_sweep"].extend(sweep)
                            log(
                                f"[{scene} N={n} {size}x{size} K={k} {shape}] ms/view by chunk: "
                                + ", ".join(f"{c['chunk']}: {c['ms_per_view']:.2f}" for c in sweep)
                            )
                    if dense:
                        c = measure_chunking(dense_model(model, dense), scene, size, k, repeats=repeats, gpu=gpu)
                        c["dense_factor"] = dense
                        doc["chunking"].append(c)
                        log(
                            f"[{scene} N={n} {size}x{size} K={k} shrunk x{dense}] {c['ms_per_view_chunked']:.1f} "
                            f"ms/view in chunks of {CHUNK}, {c['ms_per_view_off']:.1f} without "
                            f"({c['speedup']:.2f}x; up to {c['max_pairs_per_tile']:,} pairs a tile)"
                        )
            if campaign_samples:
                c = measure_campaign(scene, model, campaign_samples)
                doc["campaigns"].append({"scene": scene, "n": int(n), **c})
                log(f"[{scene} N={n}] campaign: {c['injections_per_s']:,.1f} injections/s (incremental, K=4, 128x128)")
                for ch in chunks or ():
                    c = measure_campaign(scene, model, campaign_samples, chunk=int(ch))
                    doc["campaign_chunks"].append({"scene": scene, "n": int(n), **c})
                    log(f"[{scene} N={n}] campaign at chunk {ch}: {c['injections_per_s']:,.1f} injections/s")
            del model
    doc["host"]["loadavg_end"] = list(os.getloadavg())
    doc["total_wall_s"] = time.perf_counter() - t0
    return doc


# ---- output ----------------------------------------------------------------------------------------
def _fmt(x, spec=".1f"):
    return "-" if x is None else format(x, spec)


def _config_label(r: dict) -> str:
    """A record's compositor shape, and ", 1 by 1" where its K > 1 views were not batched."""
    return r.get("compositor", "lanes") + ("" if r.get("batched", True) or r["k"] == 1 else ", 1 by 1")


def print_table(doc: dict, console=None) -> None:
    from rich.console import Console
    from rich.table import Table

    console = console or Console(width=200)
    a = doc["adapter"]
    stages_known = any(r.get("stages_ms") for r in doc["results"])
    title = f"seuwgpu render benchmark - {a['device']} ({a['backend']}, {a['adapter_type']}; {a['description']})"
    table = Table(title=title, title_justify="left")
    for col in ("scene", "N", "size", "K", "compositor", "R", "Mpix/s", "ms/view", "min ms/view"):
        table.add_column(col, justify="right" if col not in ("scene", "compositor") else "left")
    if stages_known:
        for s in (*STAGES, "gaps"):
            table.add_column(s, justify="right")
    table.add_column("twin s/view", justify="right")
    table.add_column("GPU/twin speed", justify="right")
    table.add_column("PSNR v0", justify="right")
    for r in doc["results"]:
        row = [
            r["scene"],
            f"{r['n']:,}",
            f"{r['width']}x{r['height']}",
            str(r["k"]),
            _config_label(r),
            str(r["repeats"]),
            f"{r['mpix_per_s']:.3f}",
            f"{r['ms_per_view']:.1f}",
            f"{r['min_ms_per_view']:.1f}",
        ]
        if stages_known:
            st = r.get("stages_ms") or {}
            row += [_fmt(st.get(s)) for s in (*STAGES, "gaps")]
        tw = r.get("twin")
        if tw is None:
            row += ["-", "-"]
        elif r.get("twin_ratio") is None:
            row += [f"{tw['seconds_per_view']:.2f} @N={tw['n']:,}", "n/a (other N)"]
        else:
            row += [f"{tw['seconds_per_view']:.2f}", f"{r['twin_ratio']:.1f}x"]
        row.append(_fmt(r.get("psnr_view0_vs_twin_db")))
        table.add_row(*row)
    console.print(table)
    notes = []
    if stages_known:
        notes.append(
            "Stage columns: GPU ms per submission (summed over the K views) from timestamp queries on one "
            "separate instrumented submission; 'count+scan' = tile counts + prefix sum; 'gaps' = time "
            "between passes. Mpix/s and ms/view come from un-instrumented submissions."
        )
    else:
        notes.append("No per-stage times: " + (doc["results"][0]["stage_source"] if doc["results"] else "no results"))
    notes.append(
        "Mpix/s = K*W*H / median wall time of R submissions (encode + submit + wait), warm-up excluded; "
        "ms/view = median / K; min ms/view = fastest of the R / K (other load on the host slows runs)."
    )
    notes.append(
        "twin s/view: numpy reference.render measured in this run on orbit view 0 (K=1) at the same N and "
        "size; GPU/twin speed = twin s/view / GPU s/view of the row. PSNR v0: GPU view 0 vs the twin's."
    )
    h = doc["host"]
    notes.append(
        f"Host: {h['cpus']} CPUs, load average {h['loadavg_start'][0]:.1f} at start, "
        f"{h['loadavg_end'][0]:.1f} at end; total wall time {doc['total_wall_s']:.0f} s."
    )
    for n in notes:
        console.print(n)
    fl = doc.get("floors")
    if fl and any(r.get("floors_ms_per_view") for r in doc["results"]):
        ft = Table(
            title=f"stages against measured floors (per view): exp {fl['exp_per_s'] / 1e6:,.0f} M/s, "
            f"copy {fl['copy_bytes_per_s'] / 1e9:.2f} GB/s",
            title_justify="left",
        )
        for col in ("scene", "N", "size", "K", "compositor", *STAGES):
            ft.add_column(col, justify="left" if col in ("scene", "compositor") else "right")
        for r in doc["results"]:
            fms, st = r.get("floors_ms_per_view"), r.get("stages_ms")
            if not fms or not st:
                continue
            cells = []
            for s in STAGES:
                t = st[s] / r["k"]
                f = fms.get(s)
                cells.append(f"{t:.1f} ms" if f is None else f"{t:.1f} / {f:.1f} ms ({100 * f / max(t, 1e-9):.0f}%)")
            ft.add_row(
                r["scene"],
                f"{r['n']:,}",
                f"{r['width']}x{r['height']}",
                str(r["k"]),
                _config_label(r),
                *cells,
            )
        console.print(ft)
        console.print(
            "Cells: stage time / floor (ms per view) and % of floor (floor / time). Compositing's floor evaluates "
            "every listed pair at every pixel of its tile at the exp-loop rate; the others move their bytes at the "
            "copy rate (tools/bench.py STAGE_BYTES)."
        )
    for c in doc.get("chunking", []):
        console.print(
            f"Long tile lists ({c['scene']}, N={c['n']:,} shrunk x{c['dense_factor']}, {c['width']}x{c['height']}, "
            f"K={c['k']}; {c['long_tiles']} of {c['tiles']} tiles over {c['chunk']} pairs, up to "
            f"{c['max_pairs_per_tile']:,}): {c['ms_per_view_chunked']:.1f} ms/view in chunks, "
            f"{c['ms_per_view_off']:.1f} ms/view with chunking off ({c['speedup']:.2f}x; PSNR between them "
            f"{c['psnr_view0_chunked_vs_off_db']:.1f} dB)"
        )
    for shape, err in doc.get("compositor_errors", {}).items():
        console.print(f"Compositor {shape} failed on this device and was dropped from the run: {err.splitlines()[0]}")
    for c in doc.get("campaigns", []):
        console.print(
            f"Campaign ({c['scene']}, N={c['n']:,}, K={c['views']} at {c['size']}x{c['size']}, incremental path): "
            f"{c['injections_per_s']:,.1f} injections/s ({c['injections']} injections in {c['seconds']:.2f} s)"
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--scenes",
        nargs="+",
        default=["spheres"],
        help=f"scene names or 'all' ({', '.join(scenes.list_scenes())}); default spheres",
    )
    ap.add_argument("--n", nargs="+", type=int, default=[100_000, 1_000_000], help="primitive counts")
    ap.add_argument("--sizes", nargs="+", type=int, default=[256, 512], help="square image sizes (px)")
    ap.add_argument("--views", nargs="+", type=int, default=[1, 8], help="views per submission (K)")
    ap.add_argument("--repeats", type=int, default=3, help="timed submissions per config (median)")
    ap.add_argument(
        "--budget",
        type=float,
        default=100.0,
        help="seconds of timed submissions per config; caps the repeats (at least 1)",
    )
    ap.add_argument("--twin-views", type=int, default=1, help="views the numpy twin renders per (scene, N, size)")
    ap.add_argument(
        "--twin-max-n",
        type=int,
        default=1_000_000,
        help="largest N the twin renders; above it the twin runs at this N and no ratio is given",
    )
    ap.add_argument("--no-twin", action="store_true", help="skip the numpy twin")
    ap.add_argument("--no-stages", action="store_true", help="skip the timestamp-instrumented submission")
    ap.add_argument("--sh-degree", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="tiny grid: every scene, N=20k, 128x128, K=1 and 4")
    ap.add_argument(
        "--campaign-samples",
        type=int,
        default=256,
        help="injections timed per (scene, N) on the incremental campaign path; 0 skips it",
    )
    ap.add_argument(
        "--dense",
        type=float,
        metavar="FACTOR",
        help="also time each configuration's scene shrunk by FACTOR (e.g. 0.1: a dense region of a few tiles) "
        "with the default CHUNK and with chunking off",
    )
    ap.add_argument(
        "--chunks",
        nargs="+",
        type=int,
        metavar="PAIRS",
        help="also time every configuration, and the campaign, at each of these compositing chunks "
        "(pairs of a tile list per workgroup; the device's default is chosen by render/composite.py default_chunk)",
    )
    ap.add_argument(
        "--compositors",
        nargs="+",
        choices=COMPOSITORS,
        help="full-frame compositor shapes to time every configuration with (render/composite.py SHAPES); "
        "default: all of them on a GPU adapter, the default shape on a CPU adapter",
    )
    ap.add_argument(
        "--one-by-one",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also time each K > 1 configuration with its views rendered one at a time, not batched "
        "(default: on a GPU adapter)",
    )
    ap.add_argument("--out", type=Path, help="write the JSON document here (default: none)")
    args = ap.parse_args(argv)

    for c in args.chunks or ():
        try:
            check_chunk(c)
        except ValueError as e:
            ap.error(f"--chunks: {e}")
    names = scenes.list_scenes() if "all" in args.scenes else args.scenes
    ns, sizes, ks = args.n, args.sizes, args.views
    if args.quick:
        names, ns, sizes, ks = scenes.list_scenes(), [20_000], [128], [1, 4]
        args.campaign_samples = min(args.campaign_samples, 64)
    for s in names:
        if s not in scenes.list_scenes():
            ap.error(f"unknown scene {s!r}; valid: {', '.join(scenes.list_scenes())}")

    from rich.console import Console

    console = Console(width=200)
    doc = run_grid(
        names,
        ns,
        sizes,
        ks,
        repeats=args.repeats,
        budget=args.budget,
        twin=not args.no_twin,
        twin_views=args.twin_views,
        twin_max_n=args.twin_max_n,
        stages=not args.no_stages,
        sh_degree=args.sh_degree,
        seed=args.seed,
        campaign_samples=args.campaign_samples,
        dense=args.dense,
        chunks=args.chunks,
        compositors=args.compositors,
        one_by_one=args.one_by_one,
        log=lambda m: console.print(m, highlight=False, markup=False),
    )
    print_table(doc, console)
    if args.out:
        args.out.write_text(json.dumps(doc, indent=1))
        console.print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
