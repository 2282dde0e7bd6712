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

import contextlib
import logging
import os
import signal
import threading
import time
from pathlib import Path

INSTALL_HINT = "Ray is not installed; install it with: pip install 'seuwgpu[ray]'  (or: pip install 'ray[default]')"


class RayUnavailable(RuntimeError):
    """Ray cannot be imported."""


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def get_ray():
    try:
        import ray
    except ImportError as e:
        raise RayUnavailable(INSTALL_HINT) from e
    return ray


def init_ray(address: str | None = None, num_cpus: int | None = None, quiet: bool = True) -> bool:
    """Connect to a cluster (`address`, e.g. "auto" or "ray://head:10001") or start a local
    instance; returns True if this call started/connected (the caller then shuts it down)."""
    ray = get_ray()
    if ray.is_initialized():
        return False
    kw = {"logging_level": logging.WARNING if quiet else logging.INFO}
    # ray.init replaces the SIGTERM handler with sys.exit; the command line's (apps/cli/
    # console_main: stop as Ctrl-C does, exit 143) is put back
    on_term = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
    if address:
        check_reachable(address)
    try:
        with _interrupt_after_start(ray):
            if address:
                ray.init(address=address, **kw)
            else:
                ray.init(num_cpus=num_cpus, include_dashboard=False, object_store_memory=256 * 1024**2, **kw)
    finally:  # also when a Ctrl-C stopped the start: Ray's handler would outlive its node
        if on_term is not None:
            signal.signal(signal.SIGTERM, on_term)
    return True


@contextlib.contextmanager
def _interrupt_after_start(ray):
    """Ctrl-C while ray.init starts a node takes effect once it has started, and stops it: cut
    short, the node's raylet died with this process and left its dashboard and runtime-env agents
    running, orphaned (docs/renderer.md "Measurements"). A second Ctrl-C stops at once."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending = []

    def hold(signum, frame):
        if pending:
            raise KeyboardInterrupt
        pending.append(signum)

    old = signal.signal(signal.SIGINT, hold)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
    if pending:
        ray.shutdown()
        raise KeyboardInterrupt


def check_reachable(address: str, timeout_s: float = 10.0):
    """Refuse at once a cluster address (HOST:PORT or ray://HOST:PORT) where nothing accepts a
    connection: Ray itself retries such an address for many minutes, printing a warning every few
    seconds. Other forms ("auto", ...) are left to Ray, which refuses them quickly."""
    import re
    import socket

    m = re.fullmatch(r"(?:ray://)?\[?([^\s\[\]/]+?)\]?:(\d+)", address.strip())
    if not m:
        return
    host, port = m.group(1), int(m.group(2))
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as e:
        why = "timed out" if isinstance(e, TimeoutError) else (e.strerror or str(e))
        raise ConnectionError(f"Ray cluster address {address}: cannot connect ({why})") from None


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

    from seuwgpu.gpu import device as dev

    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
    default = wgpu.gpu.request_adapter_sync(power_preference="high-performance")
    if default is None:
        return None
    backend = default.info.get("backend_type")
    cands = [
        a
        for a in wgpu.gpu.enumerate_adapters_sync()
        if a.info.get("backend_type") == backend and str(a.info.get("adapter_type", "")).lower() != "cpu"
    ]
    if len(cands) <= 1:
        return None
    adapter = cands[int(float(ids[0])) % len(cands)]

    gpu = dev.GPU(adapter=adapter)
    dev.set_gpu(gpu)  # code that calls get_gpu() in this worker process uses the same device
    return gpu


def worker_gpu():
    """This process's device (created once per Ray worker process)."""
    if _WORKER["gpu"] is None:
        from seuwgpu.gpu.device import get_gpu

        _WORKER["gpu"] = _pinned_gpu() or get_gpu()
    return _WORKER["gpu"]


# ---- campaigns --------------------------------------------------------------------------------
def _shard_runner_class():
    from seuwgpu.campaign import store
    from seuwgpu.campaign.runner import Runner

    class ShardRunner(Runner):
        """A Runner for one Ray task: the run directory was prepared by the driver's prepare task
        (no temp-file sweep under concurrent shards), and the engine is cached per worker process."""

        def run(self, progress=None) -> dict:
            # no lock here: the driver holds the run directory's lock for the whole Ray run
            self.prepare_dir()
            return self._run(progress)

        def prepare_dir(self):
            old = store.read_manifest(self.out)
            if old is None or old.get("spec_hash") != self.hash:
                return super().prepare_dir()
            store.records_dir(self.out).mkdir(parents=True, exist_ok=True)

        def engine_for(self, ctx):
            key = (self.hash, ctx.kind, ctx.scene_index, ctx.n, ctx.precision, self.full)
            if _WORKER["engine_key"] != key:
                _WORKER["engine_key"] = _WORKER["engine"] = None  # one engine at a time: bounded memory
                _WORKER["engine"] = super().engine_for(ctx)
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


def _prepare_task(spec, out: str, cwd: str | None):
    from seuwgpu.campaign.runner import Runner

    _chdir(cwd)
    gpu = worker_gpu()
    Runner(spec, Path(out), quiet=True, gpu=gpu).prepare_dir()
    return {k: str(v) for k, v in gpu.info.items()}


def _shard_task(
    spec, out: str, shard: tuple[int, int], full: bool, cwd: str | None, kill_once: str | None = None
) -> dict:
    _chdir(cwd)
    runner = _shard_runner_class()(spec, Path(out), shard=tuple(shard), quiet=True, full=full, gpu=worker_gpu())
    stats = runner.run(progress=lambda total, done: _WorkerProgress(kill_once))  # Runner.run takes a factory
    stats["pid"] = os.getpid()
    return stats


def _is_system_failure(ray, exc) -> bool:
    """A failure of the machinery (worker or node lost), as opposed to an error raised by the code."""
    if isinstance(exc, ray.exceptions.RayTaskError):
        return False
    return isinstance(exc, ray.exceptions.RayError)


def run_ray(
    spec,
    out,
    workers: int | None = None,
    address: str | None = None,
    quiet: bool = False,
    full: bool = False,
    shard: tuple[int, int] = (0, 1),
    shards: int | None = None,
    max_retries: int = 3,
    poll_s: float = 0.5,
    _kill_once: str | None = None,
) -> dict:
    """Run (shard `shard` of) a campaign on Ray; returns stats like `Runner.run` plus `workers`,
    `shards`, `resources` and `resubmitted`. Uses the Ray instance already initialised in this
    process, else connects to `address` or starts a local one with `workers` CPUs. `spec`: a
    Spec, or its stored form."""
    ray = get_ray()
    from seuwgpu.campaign import store
    from seuwgpu.campaign.budget import check_campaign
    from seuwgpu.campaign.spec_types import as_spec

    spec = as_spec(spec)
    if workers is not None and (isinstance(workers, bool) or int(workers) != workers or workers < 1):
        # 0 started a Ray instance without CPUs, where the tasks waited forever
        raise ValueError(f"workers must be a whole number of at least 1, got {workers!r}")
    check_campaign(spec)
    out = Path(out).resolve()
    with store.lock(out, shard):
        return _run_ray(ray, spec, out, workers, address, quiet, full, shard, shards, max_retries, poll_s, _kill_once)


def _run_ray(ray, spec, out, workers, address, quiet, full, shard, shards, max_retries, poll_s, _kill_once) -> dict:
    """run_ray with the run directory's lock held."""
    from seuwgpu.campaign import store
    from seuwgpu.campaign.progress import injection_bar
    from seuwgpu.campaign.runner import Runner

    base = Runner(spec, out, shard=shard)
    blocks = list(base.blocks())
    expected = {(a, m): ctx for ctx, a, m in blocks}
    store.check_same_run(out, store.read_manifest(out), spec, base.hash)
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
        rows = store.expected_parts(spec)
        seen = store.completed_parts(out, {key: rows[key] for key in expected})
        todo = [sub for sub in subs if any((a, m) not in seen for _, a, m in Runner(spec, out, shard=sub).blocks())]
        total = sum(m for _, m in expected)
        already = sum(m for _, m in seen)
        stats = {
            "injections": already,
            "total": total,
            "campaign_total": base.total,
            "new": 0,
            "catastrophic": 0,
            "seconds": 0.0,
            "workers": workers,
            "shards": S,
            "resources": opts,
            "resubmitted": 0,
            "tasks": len(todo),
        }
        t0 = time.perf_counter()
        cwd = os.getcwd()
        if todo:
            prep = ray.remote(_prepare_task).options(max_retries=max_retries, **opts)
            try:
                ray.get(prep.remote(spec, str(out), cwd))
            except ray.exceptions.RayTaskError as e:
                raise RuntimeError(f"preparing {out} failed: {getattr(e, 'cause', None) or e}") from None
        task = ray.remote(_shard_task).options(max_retries=max_retries, retry_exceptions=False, **opts)
        bar = injection_bar(total, already, quiet)

        def poll():
            for key in sorted(store.parts_in(out) - seen):
                if key not in expected:
                    continue
                seen.add(key)
                ctx = expected[key]
                try:
                    import pandas as pd

                    df = pd.read_parquet(store.part_path(out, *key), columns=["defense", "catastrophic"])
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
                        raise RuntimeError(
                            f"campaign shard {sub[0]}/{sub[1]} failed: {cause} "
                            "(completed parts are kept; re-run to resume)"
                        ) from None
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
            raise RuntimeError(
                f"{len(missing)} record parts are missing after the run (first: ids {missing[0][0]}.."
                f"{missing[0][0] + missing[0][1] - 1}); re-run the same command to resume"
            )
        m = store.read_manifest(out)
        if m is not None and todo:
            m["executor"] = {
                "kind": "ray",
                "workers": workers,
                "shards": S,
                "resources": opts,
                "address": address or "local",
                "nodes": len(ray.nodes()),
            }
            store.write_manifest(out, m)
        return stats
    finally:
        if started:
            ray.shutdown()
