"""One wgpu device per process, with cached shader modules and compute pipelines.

Device creation (~0.6 s on lavapipe) and pipelines (~60 ms each) are paid once. Shaders live in
the repository's top-level `shaders/` folder, which the wheel ships as the resource package
`seuwgpu.shaders` (an editable install maps it to the folder). Every stage is compiled as the
generated constants header (gpu/constants.py), then the files its `shaders/NAME.wgsl` imports,
then the file itself. Stages record their work through gpu/kernel.py's Kernel.

Imports
-------
A shader file names the files it needs in `// #import NAME` lines at its top (before its first
declaration; a comment to WGSL tools, so every file stays valid WGSL). `shader_files` resolves
them depth first: each import's own imports before it, every file once (the first time it is
reached), the stage's file last. A missing file or an import cycle is an error that names the
chain of files.
"""

from __future__ import annotations

import os
import re
import time
from importlib import resources
from pathlib import Path

import numpy as np
import wgpu

from seuwgpu.gpu.constants import MAX_GROUPS_X, wgsl_header
from seuwgpu.model.budget import BUFFER_ALIGN, binding_limit


def shader_text(name: str) -> str:
    """Source of `shaders/NAME.wgsl`: the installed resource package, else (a checkout imported
    without installing it) the repository's folder."""
    try:
        return resources.files("seuwgpu.shaders").joinpath(f"{name}.wgsl").read_text()
    except ModuleNotFoundError:
        return (Path(__file__).resolve().parents[2] / "shaders" / f"{name}.wgsl").read_text()


_IMPORT = re.compile(r"\s*//\s*#import\b(.*)")


def shader_imports(text: str, name: str = "shader") -> list[str]:
    """The names of the `// #import NAME` lines at the top of a shader file (before its first
    line that is neither blank nor a comment); one further down, or one that is not a single
    name, is an error (never a comment silently skipped)."""
    names, top = [], True
    for number, line in enumerate(text.splitlines(), 1):
        m = _IMPORT.fullmatch(line)
        if m and not top:
            raise ValueError(
                f"shaders/{name}.wgsl line {number}: #import below the first declaration; put it at the top"
            )
        if m:
            if not re.fullmatch(r"\s*\w+\s*", m.group(1)):
                raise ValueError(
                    f"shaders/{name}.wgsl line {number}: #import takes one shader name, not {m.group(1).strip()!r}"
                )
            names.append(m.group(1).strip())
        elif line.strip() and not line.lstrip().startswith("//"):
            top = False
    return names


def shader_files(name: str, read=shader_text) -> list[tuple[str, str]]:
    """(name, source) of the files stage NAME is compiled from, in order: its imports resolved
    depth first, each file once, then NAME itself. `read(name)` returns a file's text (raising
    FileNotFoundError for none)."""
    order: list[tuple[str, str]] = []
    done: set[str] = set()

    def visit(n: str, chain: tuple):
        if n in chain:
            cycle = " -> ".join(f"{c}.wgsl" for c in (*chain[chain.index(n) :], n))
            raise ValueError(f"shader imports form a cycle: {cycle}")
        if n in done:
            return
        try:
            text = read(n)
        except FileNotFoundError:
            via = f" (imported by {' -> '.join(f'{c}.wgsl' for c in chain)})" if chain else ""
            raise FileNotFoundError(f"shaders/{n}.wgsl does not exist{via}") from None
        for dep in shader_imports(text, n):
            visit(dep, (*chain, n))
        done.add(n)
        order.append((n, text))

    visit(name, ())
    return order


def shader_source(name: str, defines: dict | None = None) -> str:
    """What a stage is compiled from: the constants header (shared values, then the module's own
    `defines`), then shaders/NAME.wgsl with its imports (`shader_files`)."""
    return wgsl_header(defines) + "\n".join(text for _, text in shader_files(name))


STORAGE = wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC | wgpu.BufferUsage.COPY_DST
UNIFORM = wgpu.BufferUsage.UNIFORM | wgpu.BufferUsage.COPY_DST
INDIRECT = STORAGE | wgpu.BufferUsage.INDIRECT
MAP_READ = wgpu.BufferUsage.MAP_READ | wgpu.BufferUsage.COPY_DST

# Limits we ask for, up to what the adapter offers (WebGPU defaults are too small for big models).
_WANTED_LIMITS = (
    "max-storage-buffer-binding-size",
    "max-buffer-size",
    "max-storage-buffers-per-shader-stage",
    "max-compute-workgroup-storage-size",
    "max-compute-invocations-per-workgroup",
    "max-compute-workgroups-per-dimension",
    "max-bind-groups",
)


class GPU:
    def __init__(self, power_preference: str = "high-performance", adapter=None):
        """The default adapter of `power_preference`, or `adapter` (one of
        wgpu.gpu.enumerate_adapters_sync(), e.g. the GPU a Ray worker was given)."""
        os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
        self.adapter = adapter or wgpu.gpu.request_adapter_sync(power_preference=power_preference)
        if self.adapter is None:
            raise RuntimeError("no WebGPU adapter found: install a Vulkan driver (Debian: mesa-vulkan-drivers)")
        alimits = self.adapter.limits
        limits = {k: alimits[k] for k in _WANTED_LIMITS if k in alimits}
        feats = [f for f in ("timestamp-query",) if f in self.adapter.features]
        self.device = self.adapter.request_device_sync(required_features=feats, required_limits=limits)
        self.limits = dict(self.device.limits)
        self.features = set(self.device.features)
        self.queue = self.device.queue
        self._modules: dict = {}
        self._pipelines: dict = {}

    # ---- description -------------------------------------------------------------------------
    @property
    def info(self) -> dict:
        return dict(self.adapter.info)

    @property
    def max_binding(self) -> int:
        """Bytes one binding may hold (model/budget.py binding_limit: floored to BUFFER_ALIGN)."""
        return binding_limit(self.limits)

    @property
    def is_cpu(self) -> bool:
        return str(self.info.get("adapter_type", "")).lower() == "cpu"

    # ---- shaders and pipelines -----------------------------------------------------------------
    def module(self, name: str, defines: dict | None = None):
        key = (name, tuple(sorted((defines or {}).items())))
        if key not in self._modules:
            self._modules[key] = self.device.create_shader_module(label=name, code=shader_source(name, defines))
        return self._modules[key]

    def pipeline(self, name: str, entry: str = "main", constants: dict | None = None, defines: dict | None = None):
        """Compute pipeline of `entry` in shaders/NAME.wgsl; `constants` set its `override`s,
        `defines` add module-scope consts to its header (gpu/kernel.py)."""
        key = (name, entry, tuple(sorted((constants or {}).items())), tuple(sorted((defines or {}).items())))
        if key not in self._pipelines:
            compute = {"module": self.module(name, defines), "entry_point": entry}
            if constants:
                compute["constants"] = {k: float(v) for k, v in constants.items()}
            self._pipelines[key] = self.device.create_compute_pipeline(
                label=f"{name}:{entry}", layout="auto", compute=compute
            )
        return self._pipelines[key]

    def bind(self, pipeline, entries: dict, group: int = 0):
        """A new bind group; entries: {binding number: buffer | (buffer, offset, size)}, as wgpu
        numbers them. Stages bind by name through gpu/kernel.py Kernel, which resolves the names
        to these numbers and caches the groups."""
        out = []
        for binding, res in sorted(entries.items()):
            if isinstance(res, tuple):
                buf, off, size = res
            else:
                buf, off, size = res, 0, res.size
            out.append({"binding": binding, "resource": {"buffer": buf, "offset": off, "size": size}})
        return self.device.create_bind_group(layout=pipeline.get_bind_group_layout(group), entries=out)

    # ---- buffers -------------------------------------------------------------------------------
    def buffer(self, size: int, usage=STORAGE, label: str = ""):
        size = max(BUFFER_ALIGN, -(-int(size) // BUFFER_ALIGN) * BUFFER_ALIGN)
        return self.device.create_buffer(size=size, usage=usage, label=label)

    def upload(self, array, usage=STORAGE, label: str = ""):
        data = _raw(array)
        buf = self.buffer(data.nbytes, usage, label)
        if data.nbytes:
            self.queue.write_buffer(buf, 0, data)
        return buf

    def write(self, buf, array, offset: int = 0):
        data = _raw(array)
        self.queue.write_buffer(buf, offset, data)

    def read(self, buf, dtype=np.uint32, offset: int = 0, size: int | None = None) -> np.ndarray:
        size = buf.size - offset if size is None else size
        return np.frombuffer(self.queue.read_buffer(buf, offset, size), dtype=dtype).copy()

    def submit(self, encoder):
        self.queue.submit([encoder.finish()])

    def sync(self):
        """Wait for submitted work (a tiny readback; on_submitted_work_done_sync is unreliable)."""
        if not hasattr(self, "_sync_buf"):
            self._sync_buf = self.buffer(16, STORAGE, "sync")
        self.queue.read_buffer(self._sync_buf, 0, 4)


class Readback:
    """Results copied, inside the submission that computes them, to a mappable buffer of their
    own. Waiting for them waits for that submission only, so the host can work on one batch's
    results while later submissions run (faults/incremental.py keeps two batches in flight):
    queue.read_buffer submits its copy behind everything queued, and waits for all of it."""

    def __init__(self, gpu: GPU, size: int, label: str = "readback"):
        self.gpu, self.label = gpu, label
        self.buffer = gpu.buffer(max(int(size), 4), MAP_READ, label)
        self.size = 0  # bytes copied by the last encode

    def encode(self, encoder, src, offset: int = 0, size: int | None = None):
        """Record the copy of `size` bytes of `src` from `offset` (to be read after the submit)."""
        size = src.size - offset if size is None else int(size)
        if size > self.buffer.size:  # nothing of it is in flight: the last copy was read
            self.buffer = self.gpu.buffer(size, MAP_READ, self.label)
        self.size = size
        if size:
            encoder.copy_buffer_to_buffer(src, offset, self.buffer, 0, size)

    def read(self, dtype=np.uint32) -> np.ndarray:
        """The copied bytes (after the submission that holds the copy)."""
        if self.size == 0:
            return np.zeros(0, dtype)
        promise = self.buffer.map_async(_MAP_NOW, 0, self.size)
        _wait(self.gpu.device, promise)
        data = np.frombuffer(self.buffer.read_mapped(0, self.size), dtype=dtype)  # a copy (copy=True)
        self.buffer.unmap()
        return data


# wgpu-py 0.32 (pinned <0.33 in pyproject.toml) would submit an empty command buffer before a read
# mapping ("READ"; wgpu-native issue 305), which lavapipe makes wait for all queued work; the copy
# this mapping reads was submitted already, as queue.read_buffer's own "READ_NOSYNC" assumes.
_MAP_NOW = "READ_NOSYNC"


def _wait(device, promise):
    """Wait for a mapping by polling without blocking: wgpu-py's poll thread blocks until all
    queued work is done before it resolves any mapping, which would serialise the batches. Both
    names are wgpu-py 0.32 internals (pinned <0.33); without them this is a plain blocking wait."""
    try:
        while promise._state == "pending":
            device._poll(False)
            if promise._state == "pending":
                time.sleep(5e-5)
    except AttributeError:
        pass
    promise.sync_wait()


def _raw(array) -> np.ndarray:
    """Contiguous data for a queue write; structured records (gpu/kernel.py Struct) as bytes."""
    data = np.ascontiguousarray(array)
    return data.reshape(-1).view(np.uint8) if data.dtype.names else data


_GPU: GPU | None = None


def get_gpu() -> GPU:
    """This process's device (made on first use)."""
    global _GPU
    if _GPU is None:
        _GPU = GPU()
    return _GPU


def set_gpu(gpu: GPU) -> None:
    """Make `gpu` the device get_gpu() returns in this process."""
    global _GPU
    _GPU = gpu


def dispatch_dims(groups: int, max_x: int = MAX_GROUPS_X) -> tuple[int, int, int]:
    """Split a 1-D workgroup count into (x, y, 1) within the per-dimension limit; shaders compute
    `wid = wg.y * num_wg.x + wg.x` and return when wid is past the end."""
    groups = max(1, int(groups))
    if groups <= max_x:
        return groups, 1, 1
    return max_x, -(-groups // max_x), 1
