"""Values that the host code and the WGSL shaders must agree on, defined here once.

Every shader is compiled with `wgsl_header()` prepended (gpu/device.py `shader_source`), so the
shaders use these names (`TILE`, `FMT_BF16`, ...) and never restate the numbers; Python imports
them from here. See gpu/kernel.py for the rules (header constants vs pipeline overrides).
"""

from __future__ import annotations

TILE = 16
"""Pixels per side of a screen tile: binning, one compositing workgroup, one metrics slab."""

CHUNK = 32768
"""Pairs of a tile list composited by one workgroup (a multiple of the compositor's batch,
TILE * TILE): a longer list is cut by list position into chunks composited in parallel and merged
front to back (docs/renderer.md, "Long tile lists"). Why 32768: no workgroup walks more than one
chunk (full frames: one per workgroup; variants: one per dispatch), which keeps every walk under
llvmpipe's silent limit of 65,535 loop iterations per invocation (about 1.2 iterations a pair,
so lists past ~54k pairs came out wrong: docs/renderer.md): do not raise it past that; and fewer
chunks mean fewer chunk dispatches of the incremental re-compositor (docs/benchmarks.md).
composite.wgsl's `CHUNK_PAIRS` override (default this) lets tests use small chunks."""

GPU_CHUNK = 2048
"""CHUNK for full frames on a GPU adapter (render/composite.py default_chunk). A GPU holds every
tile's workgroup at once, so a frame lasts as long as its longest walk: 2048 was near the fastest
at a quarter of the slab memory of smaller chunks. Campaigns keep CHUNK (faults/engine.py): the
incremental re-compositor runs one dispatch per chunk of the longest list (docs/renderer.md
"Measurements")."""

PRECISION_CODE = {"fp32": 0, "fp16": 1, "bf16": 2}
"""Code of each stored precision in the shaders' uniforms (`FMT_FP32`, `FMT_FP16`, `FMT_BF16`)."""

PROFILE_CODE = {"strict": 0, "gsplat": 1}
"""Renderer profile codes (docs/renderer.md, "Profiles"): the value of the `PROFILE` pipeline
override of project.wgsl and blend.wgsl (`PROFILE_STRICT`, `PROFILE_GSPLAT`)."""

PROFILES = tuple(PROFILE_CODE)

COMPOSITORS = ("lanes", "wide")
"""Shapes of the full-frame compositor (render/composite.py SHAPES, docs/renderer.md): "lanes",
8 pixels per invocation and 32 invocations a tile (composite.wgsl), and "wide", one pixel per
invocation and 256 a tile (composite_wide.wgsl). The same frames bit for bit."""

WG = 256
"""Threads per workgroup of the one-thread-per-element kernels and of the scan and radix sort."""

MAX_GROUPS_X = 32768
"""Workgroups per dispatch row: a longer 1-D grid is split into rows (gpu/device.dispatch_dims;
shaders read the linear id back with `linear_wg`). WebGPU's default per-dimension limit is 65535."""

UNIFORM_STRIDE = 256
"""Bytes between uniform slots bound by offset: the largest min-uniform-buffer-offset-alignment
in the wild (host only)."""

EXP_MIN = -87.33
"""exp(x) is 0 below this (docs/renderer.md rule 4), in every shader and in the numpy twin: there
its value would be below about 1.18e-38, the smallest normal float32, which GPUs may flush
(lavapipe does, from x = -87.3366); -87.33 leaves a margin for a device exp's error."""

EXP_MAX = 88.72283
"""exp(x) is +Inf above this (rule 4): past float32's largest finite exp, pinned, as WGSL leaves
overflow to the driver."""

SHARED = {
    "TILE": TILE,
    "CHUNK": CHUNK,
    "WG": WG,
    "MAX_GROUPS_X": MAX_GROUPS_X,
    "EXP_MIN": EXP_MIN,
    "EXP_MAX": EXP_MAX,
    **{f"FMT_{p.upper()}": code for p, code in PRECISION_CODE.items()},
    **{f"PROFILE_{p.upper()}": code for p, code in PROFILE_CODE.items()},
}
"""What `wgsl_header` declares in every shader."""


def wgsl_const(name: str, value) -> str:
    """One WGSL `const` declaration of a Python bool, int (u32 when >= 0, else i32) or float."""
    if isinstance(value, bool):
        return f"const {name}: bool = {str(value).lower()};"
    if isinstance(value, int):
        return f"const {name}: u32 = {value}u;" if value >= 0 else f"const {name}: i32 = {value}i;"
    if isinstance(value, float):
        return f"const {name}: f32 = {value!r};"
    raise TypeError(f"shader constant {name} must be a bool, int or float, got {type(value).__name__}")


def wgsl_header(defines: dict | None = None) -> str:
    """The constants every shader is compiled with, then a module's own `defines`."""
    both = {**SHARED, **(defines or {})}
    lines = ["// Generated from seuwgpu/gpu/constants.py (and the module's defines): do not restate."]
    lines += [wgsl_const(k, v) for k, v in both.items()]
    return "\n".join(lines) + "\n"
