"""Memory estimates made before allocating, so that a job too big for the machine is refused with a
message saying what would fit, instead of being killed by the kernel or failing deep in wgpu.

The estimates are deliberately simple (bytes per stored value and per pixel, measured on this
code: `make_scene` peaks at ~5.5 bytes per value; a renderer holds the model and the clean stored
words, an engine also their decoded copy and its flat views) and a little generous. Host memory is
what the OS reports as available (MemAvailable); `SEUWGPU_HOST_MEMORY` (bytes) overrides it,
for tests and for sharing a machine. WebGPU does not expose a device's memory size, so the device
side is checked against the adapter's limits: every buffer the renderer binds must fit
max_storage_buffer_binding_size (the model and the sorts are already split into chunks that do);
on a CPU adapter (lavapipe) device buffers live in host memory and count there.
"""

from __future__ import annotations

import os

from seuwgpu.errors import TooBig
from seuwgpu.model.fields import n_components

SCENE_BYTES_PER_VALUE = 6  # generating an embedded scene (float64 intermediates, float32 result)
MODEL_BYTES_PER_VALUE = 16  # a loaded model plus the renderer's and engine's copies of it
# A renderer alone: the caller's model and the clean stored words (4 + 4 at fp32), plus the
# temporaries of the one component plane being encoded (StoredLayout.encode).
RENDER_BYTES_PER_VALUE = 8
PROJECTED_BYTES = 16  # the largest per-primitive projection record (conic, rgb: vec4 f32)
PIXEL_BYTES = 16  # one rgba f32 pixel of one view
BUFFER_ALIGN = 16  # every GPU buffer's size is a multiple of this (gpu/device.py GPU.buffer)
HOST_SHARE = 0.8  # of the available memory a job may plan to use


def n_values(degree: int) -> int:
    """Stored values per primitive at an SH degree."""
    return n_components(int(degree))


def available_host_bytes() -> int:
    env = os.environ.get("SEUWGPU_HOST_MEMORY")
    if env:
        return int(float(env))
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 1 << 62  # unknown: do not refuse


def gb(nbytes: float) -> str:
    return f"{nbytes / 1e9:.1f} GB" if nbytes >= 1e9 else f"{nbytes / 1e6:.0f} MB"


def available_text(planned: float) -> str:
    """What a refusal says of the memory it had: the available memory and the HOST_SHARE of it a job
    plans on (`planned`). "needs 23.6 GB; 24.4 GB is available" read as a refusal of what fits."""
    return f"{gb(planned / HOST_SHARE)} is available, of which a job plans on {HOST_SHARE:.0%} ({gb(planned)})"


def check_scene(n: int, degree: int, what: str = "--n", per_value: int = SCENE_BYTES_PER_VALUE, use: str = "generate"):
    """Refuse to make (`use`) a model of n primitives that would not fit in host memory."""
    per = per_value * n_values(degree)
    need, have = int(n) * per, HOST_SHARE * available_host_bytes()
    if need > have:
        fits = max(1, int(have // per))
        raise TooBig(
            f"{what} {n} needs about {gb(need)} of host memory to {use} the model; "
            f"{available_text(have)}: at most {what} {fits} fits"
        )


def check_model(n: int, degree: int, what: str = "--n", use: str = "render"):
    """Refuse, before generating it, a model too big to render and inject into on this host."""
    check_scene(n, degree, what, MODEL_BYTES_PER_VALUE, use)


def check_frames(k: int, width: int, height: int):
    """Refuse frames (k views of width x height, float32 RGB on the host) that do not fit in host
    memory; frames larger than a storage binding are rendered in parts (render_split)."""
    need, have = 12 * int(k) * int(width) * int(height), HOST_SHARE * available_host_bytes()
    if need > have:
        raise TooBig(
            f"{k} view(s) of {width}x{height} need {gb(need)} of host memory for the frames alone; "
            f"{available_text(have)}: render fewer views, or at a smaller size (--size or --scale)"
        )


def render_host_bytes(n: int, degree: int, k: int, width: int, height: int, binding: int = 0) -> int:
    """Host memory of a renderer: the model and its stored words, the encoding's temporaries
    (one component plane at a time: counted generously as two binding-sized arrays), and a few
    copies of the frames. An engine, the defense timings and sort-first hold more
    (MODEL_BYTES_PER_VALUE): they call check_model."""
    model = int(n) * RENDER_BYTES_PER_VALUE * n_values(degree)
    chunk = min(2 * int(binding), model) if binding else 0
    return model + chunk + 4 * int(k) * int(width) * int(height) * PIXEL_BYTES


def render_device_bytes(n: int, degree: int, k: int, width: int, height: int, keep_views: bool) -> int:
    """Device memory of a renderer/engine: stored words, per-primitive projection and sort/bin
    scratch (~64 B), the intersection buffers (~16 B for each of >= 4n pairs, per view when kept,
    and the slabs of long tiles' chunks: under 1 B a pair at the default chunk), and the clean and
    current frames (and, kept, where each pixel stopped: 4 B a pixel)."""
    per_prim = 4 * n_values(degree) + 64 + 8 + 64 * (k if keep_views else 1) + (48 * k if keep_views else 0)
    per_pixel = 2 * PIXEL_BYTES + (4 if keep_views else 0)
    return int(n) * per_prim + int(k) * int(width) * int(height) * per_pixel


def binding_limit(limits: dict) -> int:
    """Bytes one storage binding may hold, floored to BUFFER_ALIGN: buffers are bound whole, and
    NVIDIA's limit (2**31 - 4) would otherwise round up past itself (a 2**29-entry u32 list became
    a 2**31-byte buffer and failed to bind at 100M primitives on an H200)."""
    limit = int(min(limits["max-storage-buffer-binding-size"], limits["max-buffer-size"]))
    return limit // BUFFER_ALIGN * BUFFER_ALIGN


def check_render(limits: dict, is_cpu: bool, n: int, degree: int, k: int, width: int, height: int, keep_views: bool):
    """Refuse a render (n primitives, k views of width x height) that does not fit the device's
    binding limit or the host's memory, saying what would."""
    binding = binding_limit(limits)
    per_prim = PROJECTED_BYTES  # one view's records in one binding (kept views: a view group at a time)
    if int(n) * per_prim > binding:
        raise TooBig(
            f"{n:,} primitives need a {gb(int(n) * per_prim)} projection buffer, above the device's storage "
            f"binding limit ({gb(binding)}): at most {binding // per_prim:,} primitives fit"
        )
    buffer = int(limits["max-buffer-size"]) // BUFFER_ALIGN * BUFFER_ALIGN
    if keep_views and int(n) * per_prim * int(k) > buffer:
        raise TooBig(
            f"{n:,} primitives x {k} kept view(s) need a {gb(int(n) * per_prim * int(k))} buffer of their projections, "
            f"above the device's buffer size limit ({gb(buffer)}): at most {buffer // (per_prim * int(k)):,} "
            "primitives fit at this view count (or use fewer views)"
        )
    frame = int(k) * int(width) * int(height) * PIXEL_BYTES
    if frame > binding:
        fits = max(0, binding // (int(width) * int(height) * PIXEL_BYTES))
        raise TooBig(
            f"{k} view(s) of {width}x{height} need a {gb(frame)} frame buffer, above the device's storage "
            f"binding limit ({gb(binding)}): "
            + (f"at most {fits} view(s) of that size fit" if fits else "render at a smaller size (--size or --scale)")
        )
    need = render_host_bytes(n, degree, k, width, height, binding)
    if is_cpu:
        need += render_device_bytes(n, degree, k, width, height, keep_views)
    have = HOST_SHARE * available_host_bytes()
    if need > have:
        per = need / max(1, int(n))
        raise TooBig(
            f"{n:,} primitives with {k} view(s) of {width}x{height} need about {gb(need)} of host memory; "
            f"{available_text(have)}: about {int(have // per):,} primitives would fit"
        )
