"""Scale-out on Ray: campaigns spread over many GPUs (or lavapipe devices), and a sort-first
renderer whose screen regions are rendered by separate Ray actors.

Campaigns (`run_ray`). A campaign is already a deterministic list of blocks (`Runner.blocks()`),
each written as one atomic Parquet part named after its first injection id and count, and a
Runner skips the parts it finds. The driver splits the (shard of the) campaign into S Ray tasks
(S = 4 x workers by default, at most one per block); task s runs `Runner(spec, out,
shard=(i + n*s, n*S))`, which are exactly the blocks of shard (i, n) taken in turn, and writes its
parts into the same RUN_DIR (shared storage on a cluster: every node must see RUN_DIR at the same
path). Records are therefore identical to a local run of the same spec, bit for bit.
- Resources: one task holds one GPU (`num_gpus=1`) where the cluster has GPUs, else one CPU (a
  lavapipe device per worker process). At most `workers` tasks are in flight.
- Fault tolerance: a task whose worker dies is retried by Ray (`max_retries`), and resubmitted by
  the driver if Ray gives up on it for a system reason (node lost, ...). A re-run skips the parts
  written before the crash, and a part is only ever a complete file (temp file + rename), so no
  record is lost or duplicated; the driver checks at the end that every expected part exists.
  Errors raised by the campaign code itself (a bad PLY, ...) are not retried: they stop the run.
- The run directory is prepared once (manifest, stale temp files swept) by one task before the
  shards start, so concurrent shards never sweep each other's temp files.
- Progress: the driver polls RUN_DIR's parts (the one source of truth, so a retried shard is never
  counted twice) and shows one combined display: injections, rate, ETA, catastrophic count.
- Worker processes are reused across tasks: each keeps its wgpu device and the engine of the last
  context it ran, so S > workers costs no extra device or engine set-up.
- Multi-GPU nodes: Vulkan ignores CUDA_VISIBLE_DEVICES, so a worker that Ray gave GPU id g opens
  the g-th non-CPU adapter of the default backend (enumeration order; best effort).

Sort-first rendering (`sort_first`). The frame is split into P tile-aligned regions (a px x py
grid of tiles, as square as possible); rank r is a Ray actor with its own device and its own copy
of the model, rendering only its region (`Renderer(viewport=...)`, equal to the full frame bit for
bit), and the driver assembles the composite. An upset is applied to every rank's copy (each rank
stores the whole model); the node-local guard runs on each rank before it renders: `scrub` (the
default) repairs the rank's stored buffers with `guard.scrub`, `clamp` clamps in the pipeline.
A rank is contaminated when any of its pixels changes by more than 1/255 in a channel (the
footprint threshold of the metrics) or changes finiteness. The ranks a primitive's footprint
reaches are those holding a pixel it contributes to by the compositing rule, occlusion aside
(inside its binned tile rectangle, alpha >= 1/255; computed with the numpy twin's projection), in
some view: only those ranks can change, and they do unless what lies in front hides it.
Per-rank render times are measured with one rank rendering at a time (medians of `repeats`), so
that ranks sharing one machine's CPU (lavapipe) do not inflate each other; the wall time of a
concurrent frame (all ranks at once) is reported beside them.
"""

from __future__ import annotations

import json
import logging
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

INSTALL_HINT = "Ray is not installed; install it with: pip install 'seuwgpu[ray]'  (or: pip install 'ray[default]')"


class RayUnavailable(RuntimeError):
    """Ray cannot be imported."""


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def _ray():
    try:
        import ray
    except ImportError as e:
        raise RayUnavailable(INSTALL_HINT) from e
    return ray


def init_ray(address: str | None = None, num_cpus: int | None = None, quiet: bool = True) -> bool:
    """Connect to a cluster (`address`, e.g. "auto" or "ray://head:10001") or start a local
    instance; returns True if this call started/connected (the caller then shuts it down)."""
    ray = _ray()
    if ray.is_initialized():
        return False
    kw = {"logging_level": logging.WARNING if quiet else logging.INFO}
    if address:
        ray.init(address=address, **kw)
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False, object_store_memory=256 * 1024 ** 2, **kw)
    return True


# ---- per-worker device ------------------------------------------------------------------------
_WORKER = {"gpu": None, "engine_key": None, "engine": None}


def _pinned_gpu():
    """A GPU on the adapter matching the Ray GPU id of this worker, when the node has several."""
    try:
        import ray
        ids = ray.get_gpu_ids() if ray.is_initialized() else []
    except Exception:
        return None
    if not ids:
        return None
    import wgpu
    from .gpu import device as dev
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
    default = wgpu.gpu.request_adapter_sync(power_preference="high-performance")
    if default is None:
        return None
    backend = default.info.get("backend_type")
    cands = [a for a in wgpu.gpu.enumerate_adapters_sync()
             if a.info.get("backend_type") == backend and str(a.info.get("adapter_type", "")).lower() != "cpu"]
    if len(cands) <= 1:
        return None
    adapter = cands[int(float(ids[0])) % len(cands)]

    class _PinnedGPU(dev.GPU):
        def __init__(self, adapter):  # GPU.__init__ with a chosen adapter
            self.adapter = adapter
            alimits = adapter.limits
            limits = {k: alimits[k] for k in dev._WANTED_LIMITS if k in alimits}
            feats = [f for f in ("timestamp-query",) if f in adapter.features]
            self.device = adapter.request_device_sync(required_features=feats, required_limits=limits)
            self.limits = dict(self.device.limits)
            self.features = set(self.device.features)
            self.queue = self.device.queue
            self._modules, self._pipelines = {}, {}

    gpu = _PinnedGPU(adapter)
    dev._GPU = gpu  # code that calls get_gpu() in this worker process uses the same device
    return gpu


def worker_gpu():
    """This process's device (created once per Ray worker process)."""
    if _WORKER["gpu"] is None:
        from .gpu.device import get_gpu
        _WORKER["gpu"] = _pinned_gpu() or get_gpu()
    return _WORKER["gpu"]


# ---- campaigns --------------------------------------------------------------------------------
def _shard_runner_class():
    from .campaign import Runner, SpecError

    class ShardRunner(Runner):
        """A Runner for one Ray task: the run directory was prepared by the driver's prepare task
        (no temp-file sweep under concurrent shards), and the engine is cached per worker process."""

        def _prepare_dir(self):
            mpath = self.out / "manifest.json"
            if not mpath.exists():
                return super()._prepare_dir()
            (self.out / "records").mkdir(parents=True, exist_ok=True)
            old = json.loads(mpath.read_text())
            if old.get("spec_hash") != self.hash:
                raise SpecError(f"{self.out} holds a run of a different spec ({old.get('spec_hash')} != {self.hash})")

        def _engine(self, ctx):
            key = (self.hash, ctx.kind, ctx.scene_index, ctx.n, ctx.precision, self.full)
            if _WORKER["engine_key"] != key:
                _WORKER["engine_key"] = _WORKER["engine"] = None  # one engine at a time: bounded memory
                _WORKER["engine"] = super()._engine(ctx)
                _WORKER["engine_key"] = key
            return _WORKER["engine"]

    return ShardRunner


class _WorkerProgress:
    """Workers report nothing themselves (the driver watches the parts); `kill_once` is a test hook:
    the first task of the run to write a part creates that file and kills its own worker process."""

    def __init__(self, kill_once: str | None = None):
        self.kill_once = kill_once

    def advance(self, n: int, cat: int):
        if self.kill_once:
            try:
                fd = os.open(self.kill_once, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                return
            os.write(fd, str(os.getpid()).encode())
            os.close(fd)
            os._exit(17)

    def close(self):
        pass


def _chdir(cwd):
    if cwd and os.path.isdir(cwd):
        os.chdir(cwd)  # relative PLY / camera paths of the spec resolve as on the driver


def _prepare_task(spec: dict, out: str, cwd: str | None):
    from .campaign import Runner
    _chdir(cwd)
    gpu = worker_gpu()
    Runner(spec, Path(out), quiet=True, gpu=gpu)._prepare_dir()
    return {k: str(v) for k, v in gpu.info.items()}


def _shard_task(spec: dict, out: str, shard: tuple[int, int], full: bool, cwd: str | None,
                kill_once: str | None = None) -> dict:
    _chdir(cwd)
    runner = _shard_runner_class()(spec, Path(out), shard=tuple(shard), quiet=True, full=full, gpu=worker_gpu())
    stats = runner.run(progress=_WorkerProgress(kill_once))
    stats["pid"] = os.getpid()
    return stats


def _parts_in(rec_dir: Path) -> set[tuple[int, int]]:
    out = set()
    try:
        it = os.scandir(rec_dir)
    except FileNotFoundError:
        return out
    with it:
        for e in it:
            if e.name.startswith("part-") and e.name.endswith(".parquet"):
                a, b = e.name[:-8].split("-")[1:3]
                out.add((int(a), int(b)))
    return out


def _is_system_failure(ray, exc) -> bool:
    """A failure of the machinery (worker or node lost), as opposed to an error raised by the code."""
    if isinstance(exc, ray.exceptions.RayTaskError):
        return False
    return isinstance(exc, ray.exceptions.RayError)


def run_ray(spec: dict, out, workers: int | None = None, address: str | None = None, quiet: bool = False,
            full: bool = False, shard: tuple[int, int] = (0, 1), shards: int | None = None,
            max_retries: int = 3, poll_s: float = 0.5, _kill_once: str | None = None) -> dict:
    """Run (shard `shard` of) a campaign on Ray; returns stats like `Runner.run` plus `workers`,
    `shards`, `resources` and `resubmitted`. Uses the Ray instance already initialised in this
    process, else connects to `address` or starts a local one with `workers` CPUs."""
    ray = _ray()
    from .campaign import Runner, SpecError, _Progress, _atomic_write

    out = Path(out).resolve()
    base = Runner(spec, out, shard=shard)
    blocks = list(base.blocks())
    expected = {(a, m): ctx for ctx, a, m in blocks}
    mpath = out / "manifest.json"
    if mpath.exists():
        old = json.loads(mpath.read_text())
        if old.get("spec_hash") != base.hash:
            raise SpecError(f"{out} holds a run of a different spec (hash {old.get('spec_hash')} != {base.hash}); "
                            "use a new --out directory, or the original spec to resume")
    started = init_ray(address, num_cpus=workers if not address else None)
    try:
        res = ray.cluster_resources()
        gpus = int(res.get("GPU", 0))
        if workers is None:
            workers = gpus or max(1, int(res.get("CPU", 1)))
        workers = max(1, int(workers))
        opts = {"num_gpus": 1} if gpus else {"num_cpus": 1}
        S = max(1, min(len(blocks), shards or 4 * workers))
        i, n = shard
        subs = [(i + n * s, n * S) for s in range(S)]
        rec_dir = out / "records"
        seen = _parts_in(rec_dir) & set(expected)
        todo = [sub for sub in subs
                if any((a, m) not in seen for _, a, m in Runner(spec, out, shard=sub).blocks())]
        total = sum(m for _, m in expected)
        already = sum(m for _, m in seen)
        stats = {"injections": already, "total": total, "campaign_total": base.total, "new": 0, "catastrophic": 0,
                 "seconds": 0.0, "workers": workers,
                 "shards": S, "resources": opts, "resubmitted": 0, "tasks": len(todo)}
        t0 = time.perf_counter()
        cwd = os.getcwd()
        if todo:
            prep = ray.remote(_prepare_task).options(max_retries=max_retries, **opts)
            try:
                ray.get(prep.remote(spec, str(out), cwd))
            except ray.exceptions.RayTaskError as e:
                raise RuntimeError(f"preparing {out} failed: {getattr(e, 'cause', None) or e}") from None
        task = ray.remote(_shard_task).options(max_retries=max_retries, retry_exceptions=False, **opts)
        bar = _Progress(total, already, quiet)

        def poll():
            for key in sorted(_parts_in(rec_dir) - seen):
                if key not in expected:
                    continue
                seen.add(key)
                ctx = expected[key]
                try:
                    import pandas as pd
                    df = pd.read_parquet(rec_dir / f"part-{key[0]:010d}-{key[1]:06d}.parquet",
                                         columns=["defense", "catastrophic"])
                    cat = int(df.loc[df.defense == ctx.defenses[0], "catastrophic"].sum())
                except Exception:
                    cat = 0
                stats["new"] += key[1]
                stats["injections"] += key[1]
                stats["catastrophic"] += cat
                bar.advance(key[1], cat)

        pending, inflight = list(todo), {}
        budget = {sub: max_retries for sub in todo}
        try:
            while pending or inflight:
                while pending and len(inflight) < workers:
                    sub = pending.pop(0)
                    inflight[task.remote(spec, str(out), sub, full, cwd, _kill_once)] = sub
                ready, _ = ray.wait(list(inflight), num_returns=1, timeout=poll_s)
                for ref in ready:
                    sub = inflight.pop(ref)
                    try:
                        ray.get(ref)
                    except Exception as e:  # noqa: BLE001
                        if _is_system_failure(ray, e) and budget[sub] > 0:
                            budget[sub] -= 1
                            stats["resubmitted"] += 1
                            pending.append(sub)  # re-run: it skips the parts already written
                            continue
                        cause = getattr(e, "cause", None) or e
                        raise RuntimeError(f"campaign shard {sub[0]}/{sub[1]} failed: {cause} "
                                           "(completed parts are kept; re-run to resume)") from None
                poll()
            poll()
        except BaseException:
            for r in inflight:  # stop the other shards too (on a cluster they would run on)
                ray.cancel(r, force=True)
            raise
        finally:
            bar.close()
        stats["seconds"] = time.perf_counter() - t0
        missing = sorted(set(expected) - seen)
        if missing:
            raise RuntimeError(f"{len(missing)} record parts are missing after the run (first: ids {missing[0][0]}.."
                               f"{missing[0][0] + missing[0][1] - 1}); re-run the same command to resume")
        if mpath.exists() and todo:
            m = json.loads(mpath.read_text())
            m["executor"] = {"kind": "ray", "workers": workers, "shards": S, "resources": opts,
                             "address": address or "local", "nodes": len(ray.nodes())}
            _atomic_write(mpath, json.dumps(m, indent=1).encode())
        return stats
    finally:
        if started:
            ray.shutdown()


def run_campaign(spec: dict, out, executor: str = "local", workers: int | None = None,
                 address: str | None = None, shard=(0, 1), quiet: bool = False, full: bool = False) -> dict:
    """The `seuwgpu campaign --executor ...` entry: Ray if asked and importable, else the local
    executor (with a message saying how to install Ray); prints the one-line summary."""
    import sys
    if executor == "ray" and not ray_available():
        print(f"seuwgpu campaign: {INSTALL_HINT}; running on the local executor instead", file=sys.stderr)
        executor = "local"
    if executor == "local":
        from .cli import run_campaign as local_run
        return local_run(spec, Path(out), shard, quiet, full)
    try:
        stats = run_ray(spec, out, workers=workers, address=address, quiet=quiet, full=full, shard=shard)
    except RuntimeError as e:
        from .cli import CliError
        raise CliError(str(e)) from None
    rate = stats["new"] / stats["seconds"] if stats["seconds"] > 0 and stats["new"] else float("nan")
    print(f"{out}: {stats['injections']} of {stats['campaign_total']} injections recorded "
          f"({stats['new']} new in {stats['seconds']:.1f} s, "
          f"{rate:.1f} injections/s on {stats['workers']} Ray worker{'s' if stats['workers'] != 1 else ''}, "
          f"{stats['shards']} shards{', ' + str(stats['resubmitted']) + ' resubmitted' if stats['resubmitted'] else ''}"
          f"{', full re-render' if full else ''})")
    return stats


# ---- sort-first rendering ---------------------------------------------------------------------
TILE = 16


def grid_shape(ranks: int, tiles_x: int, tiles_y: int) -> tuple[int, int]:
    """(px, py) with px * py = ranks, each within the tile grid, regions as square as possible."""
    if ranks < 1:
        raise ValueError("--ranks must be at least 1")
    best = None
    for px in range(1, ranks + 1):
        if ranks % px:
            continue
        py = ranks // px
        if px > tiles_x or py > tiles_y:
            continue
        cost = abs(math.log((tiles_x / px) / (tiles_y / py)))
        if best is None or cost < best[0] - 1e-12:
            best = (cost, px, py)
    if best is None:
        raise ValueError(f"{ranks} ranks do not fit a grid of the frame's {tiles_x}x{tiles_y} tiles "
                         f"({TILE} px); use fewer ranks or a larger --size")
    return best[1], best[2]


def split_regions(ranks: int, width: int, height: int) -> tuple[list[tuple[int, int, int, int]], tuple[int, int]]:
    """Tile-aligned regions (x0, y0, w, h), row-major, and the grid (px, py)."""
    tx, ty = -(-width // TILE), -(-height // TILE)
    px, py = grid_shape(ranks, tx, ty)
    xb = [min(round(k * tx / px) * TILE, width) for k in range(px + 1)]
    yb = [min(round(k * ty / py) * TILE, height) for k in range(py + 1)]
    regions = [(xb[c], yb[r], xb[c + 1] - xb[c], yb[r + 1] - yb[r]) for r in range(py) for c in range(px)]
    return regions, (px, py)


def changed_pixels(a: np.ndarray, b: np.ndarray, threshold: float = 1.0 / 255.0) -> np.ndarray:
    """[..., H, W] bool: any channel differs by more than `threshold` or in finiteness (bitwise
    equal values, Inf included, are unchanged)."""
    same = (a.view(np.uint32) == b.view(np.uint32))
    with np.errstate(invalid="ignore", over="ignore"):
        close = np.abs(a.astype(np.float64) - b.astype(np.float64)) <= threshold
    return (~(same | close)).any(axis=-1)


class RankRenderer:
    """One rank of the sort-first renderer (a Ray actor): its own device, its own copy of the
    model, its region of every view, and the node-local guard."""

    def __init__(self, model, cameras, precision: str, viewport, rank: int = 0, guard_variant: str = "guard"):
        from .faults import GUARDED_FIELDS
        from .guard import component_mask, support_box
        from .render import Renderer
        t0 = time.perf_counter()
        self.rank, self.model, self.cameras, self.precision = rank, model, cameras, precision
        self.gpu = worker_gpu()
        self.r = Renderer(model, cameras, precision, gpu=self.gpu, viewport=viewport)
        self.box = support_box(self.r.layout.decode(self.r.clean_words), precision)
        self.guard_fields = GUARDED_FIELDS[guard_variant]
        self.mask = component_mask(self.guard_fields, model.sh_degree)
        self.r.set_guard(self.box.rows(), 0)
        self.clean = self.r.render()  # also the warm-up
        self.setup_s = time.perf_counter() - t0

    def info(self) -> dict:
        import socket
        return {"rank": self.rank, "pid": os.getpid(), "host": socket.gethostname(), "viewport": self.r.viewport,
                "adapter": str(self.gpu.info.get("device")), "setup_s": self.setup_s}

    def clean_image(self) -> np.ndarray:
        return self.clean

    def render(self) -> tuple[np.ndarray, float]:
        t0 = time.perf_counter()
        img = self.r.render()
        return img, time.perf_counter() - t0

    def time_render(self, repeats: int = 3) -> list[float]:
        return [self.render()[1] for _ in range(max(1, repeats))]

    def _flip(self, site):
        from .faults import mask_of
        from .gpu.device import UNIFORM, dispatch_dims
        L = self.r.layout
        ch, word, shift = L.locate([site.primitive], [site.flat_component()])
        pairs = np.array([[int(word[0]), (mask_of(site.bits) << int(shift[0])) & 0xFFFFFFFF]], np.uint32)
        g = self.gpu
        pipe = g.pipeline("flip")
        bg = g.bind(pipe, {0: g.upload(np.array([1, 0, 0, 0], np.uint32), UNIFORM), 1: g.upload(pairs),
                           2: self.r.chunks[int(ch[0])]})
        enc = g.device.create_command_encoder()
        p = enc.begin_compute_pass()
        p.set_pipeline(pipe)
        p.set_bind_group(0, bg)
        p.dispatch_workgroups(*dispatch_dims(1))
        p.end()
        g.submit(enc)

    def _restore(self):
        for c, words in enumerate(self.r.clean_words):
            self.gpu.write(self.r.chunks[c], words)

    def _measure(self, img, seconds, clamps=0) -> dict:
        ch = changed_pixels(img, self.clean)
        with np.errstate(invalid="ignore"):
            peak = float(np.nanmax(np.abs(img.astype(np.float64) - self.clean))) if img.size else 0.0
        return {"changed": int(ch.sum()), "pixels": int(ch.size), "peak_error": peak,
                "nonfinite": bool((~np.isfinite(img)).any()), "clamps": int(clamps), "seconds": seconds}

    def contamination(self, site, guard: str = "scrub") -> dict:
        """The upset on this rank's copy: this rank's pixels without and with the node-local guard."""
        from .guard import scrub
        out = {}
        self._flip(site)
        try:
            img, s = self.render()
            out["none"] = self._measure(img, s)
            t0 = time.perf_counter()
            if guard == "scrub":
                counts = scrub(self.r, self.box, self.guard_fields)
                img = self.r.render()
                clamps = sum(counts.values())
            elif guard == "clamp":
                self.r.set_guard(None, self.mask)
                self.r.reset_guard_counts()
                try:
                    img = self.r.render()
                    clamps = int(self.r.read_guard_counts().sum())
                finally:
                    self.r.set_guard(None, 0)
            else:
                raise ValueError(f"unknown guard mode {guard!r}; expected scrub or clamp")
            out["guard"] = self._measure(img, time.perf_counter() - t0, clamps)
        finally:
            self._restore()  # exact: the clean words (also undoes a scrub's repair of the flipped word)
        return out

    def worst_primitive(self, field: str, component: int, bits, sample: int, seed: int) -> int:
        """Most harmful primitive of a sample (full-frame footprint), as `seuwgpu inject` picks it."""
        from .engine import Engine
        eng = Engine(self.model, self.cameras, self.precision, gpu=self.gpu)
        prim, _ = eng.worst_primitive(field, component, bits, sample=sample, seed=seed)
        return prim


def footprint_mask(values: np.ndarray, degree: int, cam) -> np.ndarray:
    """[H, W] bool: the pixels one primitive (flat stored values [ncomp]) contributes to in this
    view by the compositing rule, occlusion aside: inside its binned tile rectangle, sigma >= 0
    and alpha >= 1/255 (a NaN alpha contributes, as in the renderer). float32, as the numpy twin."""
    from .model import Model
    from .reference import ALPHA_MAX, ALPHA_MIN, F, project
    m = Model.from_flat(np.asarray(values, np.float32).reshape(1, -1), degree)
    p = project(m, cam)
    mask = np.zeros((cam.height, cam.width), bool)
    if not p["visible"][0]:
        return mask
    x0, y0, x1, y1 = (int(v) for v in p["rect"][0])
    xa, xb = x0 * TILE, min(x1 * TILE, cam.width)
    ya, yb = y0 * TILE, min(y1 * TILE, cam.height)
    if xa >= xb or ya >= yb:
        return mask
    px = np.arange(xa, xb, dtype=F) + F(0.5)
    py = np.arange(ya, yb, dtype=F) + F(0.5)
    mx, my = p["mean2d"][0]
    cxx, cxy, czz = p["conic"][0]
    with np.errstate(all="ignore"):
        dx = (mx - px)[None, :]
        dy = (my - py)[:, None]
        sigma = F(0.5) * ((cxx * dx) * dx + (czz * dy) * dy) + (cxy * dx) * dy
        alpha = np.minimum(ALPHA_MAX, p["opacity"][0] * np.exp(-sigma))
        mask[ya:yb, xa:xb] = ~((sigma < 0) | (alpha < ALPHA_MIN))
    return mask


def footprint_reach(values: np.ndarray, degree: int, cameras, regions) -> set[int]:
    """Ranks whose region holds a pixel of the primitive's footprint (`footprint_mask`) in some view."""
    reach = set()
    for cam in cameras:
        fm = footprint_mask(values, degree, cam)
        for r, (x0, y0, w, h) in enumerate(regions):
            if fm[y0:y0 + h, x0:x0 + w].any():
                reach.add(r)
    return reach


def parse_upset(text: str) -> tuple[str, tuple[int, ...]]:
    """'field:bit' or 'field:bit,bit' -> (canonical field, bits)."""
    from .model import canonical_field
    try:
        field, bits = text.split(":")
        return canonical_field(field.strip()), tuple(int(b) for b in bits.split(","))
    except ValueError as e:
        raise ValueError(f"--upset must look like log_scales:31 (field:bit), got {text!r} ({e})") from None


def sort_first(model, cameras, precision: str = "fp32", ranks: int = 4, upset=None, component: int = 0,
               primitive: int | None = None, sample: int = 32, seed: int = 0, guard: str = "scrub",
               repeats: int = 3, address: str | None = None, composite: bool = True) -> dict:
    """Render `cameras` with `ranks` Ray actors (sort-first), time the ranks, and (with `upset` =
    (field, bits)) find the ranks a single upset contaminates without and with the node-local guard."""
    ray = _ray()
    from .faults import GUARDED_FIELDS, make_site
    from .guard import clamp_values, component_mask, support_box
    from . import formats
    from .render import check_cameras
    width, height = check_cameras(cameras)
    regions, grid = split_regions(ranks, width, height)
    started = init_ray(address)
    actors = []
    try:
        gpus = int(ray.cluster_resources().get("GPU", 0))
        opts = {"num_gpus": min(1.0, gpus / ranks)} if gpus else {}
        Actor = ray.remote(RankRenderer)
        mref = ray.put(model)
        t0 = time.perf_counter()
        actors = [Actor.options(**opts).remote(mref, cameras, precision, vp, r) for r, vp in enumerate(regions)]
        infos = ray.get([a.info.remote() for a in actors])
        setup_wall = time.perf_counter() - t0
        out = {"ranks": ranks, "grid": grid, "regions": regions, "width": width, "height": height,
               "views": len(cameras), "n": model.n, "precision": precision, "infos": infos,
               "setup_wall_s": setup_wall, "guard_mode": guard}
        if composite:
            parts = ray.get([a.clean_image.remote() for a in actors])
            img = np.zeros((len(cameras), height, width, 3), np.float32)
            for (x0, y0, w, h), part in zip(regions, parts):
                img[:, y0:y0 + h, x0:x0 + w] = part
            out["composite"] = img
        times = [statistics.median(ray.get(a.time_render.remote(repeats))) for a in actors]  # one rank at a time
        t0 = time.perf_counter()
        ray.get([a.render.remote() for a in actors])  # a concurrent frame
        out["frame_wall_s"] = time.perf_counter() - t0
        out["times"] = times
        out["slowest"] = int(np.argmax(times))
        out["imbalance"] = float(max(times) / (sum(times) / len(times)))
        if upset is not None:
            field, bits = upset
            if primitive is None:
                primitive = ray.get(actors[0].worst_primitive.remote(field, component, bits, sample, seed))
                out["primitive_chosen"] = f"most harmful of {min(sample, model.n)} sampled"
            site = make_site(model, field, primitive, component, bits, precision)
            res = ray.get([a.contamination.remote(site, guard) for a in actors])
            stored = model.quantized(precision)
            box = support_box(stored, precision)
            row = stored.flat()[site.primitive].astype(np.float32)
            c = site.flat_component()
            bad = row.copy()
            bad[c] = formats.from_bits(formats.flip_bits(formats.to_bits(row[c:c + 1], precision), list(site.bits),
                                                         precision), precision)[0]
            clamped, _ = clamp_values(bad[None], box, component_mask(GUARDED_FIELDS["guard"], model.sh_degree))
            out.update({
                "site": site, "clean_value": float(row[c]), "corrupted_value": float(bad[c]),
                "guarded_value": float(clamped[0, c]), "per_rank": res,
                "reach_clean": footprint_reach(row, model.sh_degree, cameras, regions),
                "reach_upset": footprint_reach(bad, model.sh_degree, cameras, regions),
                "reach_guarded": footprint_reach(clamped[0], model.sh_degree, cameras, regions),
                "touched_none": {r for r, x in enumerate(res) if x["none"]["changed"]},
                "touched_guard": {r for r, x in enumerate(res) if x["guard"]["changed"]},
            })
        return out
    finally:
        for a in actors:
            ray.kill(a)
        if started:
            ray.shutdown()


def _fmt_set(s) -> str:
    s = sorted(s)
    if not s:
        return "{}"
    return "{" + ", ".join(map(str, s)) + "}"


def print_sort_first(res: dict, console=None):
    """The per-rank table and the contamination summary (rich)."""
    from rich.console import Console
    from rich.table import Table
    if console is None:
        console = Console()
        if not console.is_terminal:
            console = Console(width=150)
    P, (px, py) = res["ranks"], res["grid"]
    t = Table(title=f"sort-first: {P} ranks ({px}x{py} grid) over {res['views']} view(s) of {res['width']}x"
                    f"{res['height']}, {res['n']} primitives at {res['precision']}")
    for col in ("rank", "region x,y,w,h", "render ms"):
        t.add_column(col, justify="right")
    up = "site" in res
    if up:
        for col in ("reached", "changed px", "changed px, guard", "guard clamps", "reached, guarded"):
            t.add_column(col, justify="right")
    for r, vp in enumerate(res["regions"]):
        row = [str(r), ",".join(map(str, vp)), f"{1000 * res['times'][r]:.2f}" + (" *" if r == res["slowest"] else "")]
        if up:
            pr = res["per_rank"][r]
            row += ["yes" if r in res["reach_upset"] else "", str(pr["none"]["changed"]), str(pr["guard"]["changed"]),
                    str(pr["guard"]["clamps"]), "yes" if r in res["reach_guarded"] else ""]
        t.add_row(*row)
    console.print(t)
    times = res["times"]
    console.print(f"slowest rank: {res['slowest']} ({1000 * max(times):.2f} ms; mean {1000 * sum(times) / len(times):.2f} ms)"
                  f"  load imbalance (max/mean): {res['imbalance']:.3f}  concurrent frame: "
                  f"{1000 * res['frame_wall_s']:.1f} ms wall  (rank times measured one rank at a time)")
    if up:
        s = res["site"]
        how = f" ({res['primitive_chosen']})" if "primitive_chosen" in res else ""
        console.print(f"upset: {s.field}[{s.primitive}][{s.component}] bit {','.join(map(str, s.bits))}{how}: "
                      f"{res['clean_value']:.6g} -> {res['corrupted_value']:.6g}; guard reads {res['guarded_value']:.6g}")
        console.print(f"  ranks its clean footprint reaches:     {_fmt_set(res['reach_clean'])}")
        console.print(f"  ranks its corrupted footprint reaches: {_fmt_set(res['reach_upset'])}")
        console.print(f"  ranks contaminated, no guard:          {_fmt_set(res['touched_none'])} "
                      f"({len(res['touched_none'])} of {P})")
        console.print(f"  ranks contaminated, node-local guard:  {_fmt_set(res['touched_guard'])} "
                      f"({len(res['touched_guard'])} of {P}; its clamped footprint reaches {_fmt_set(res['reach_guarded'])})")


def sort_first_tables(model, cameras, precision: str, ranks_list, upset=None, address: str | None = None,
                      console=None, **kw) -> list[dict]:
    """`seuwgpu distributed`: one Ray instance, one table per rank count. The worst primitive is
    chosen once (on the first rank count) so every table shows the same upset."""
    started = init_ray(address)
    out = []
    try:
        chosen = None
        for p in ranks_list:
            res = sort_first(model, cameras, precision, p, upset, composite=False, **kw)
            if upset is not None and kw.get("primitive") is None:
                kw["primitive"], chosen = res["site"].primitive, res.get("primitive_chosen")
            elif chosen:
                res["primitive_chosen"] = chosen
            print_sort_first(res, console)
            out.append(res)
    finally:
        if started:
            _ray().shutdown()
    return out
