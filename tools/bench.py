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


from seuwgpu.gpu.constants import CHUNK, COMPOSITORS  # noqa: E402
from seuwgpu.gpu.device import GPU, get_gpu  # noqa: E402
from seuwgpu.model import scenes  # noqa: E402
from seuwgpu.model.fields import Model  # noqa: E402
from seuwgpu.render import reference  # noqa: E402
from seuwgpu.render.composite import check_chunk, default_shape  # noqa: E402
from seuwgpu.render.renderer import Renderer  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_floors import measure_floors, stage_floor_s  # noqa: E402
from bench_stages import STAGES, StageTimedRenderer, timestamp_period_ns  # noqa: E402
from bench_table import print_table  # noqa: E402

from seuwgpu.gpu.timing import count_dispatches  # noqa: E402


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
