"""Measured floors of tools/bench.py, on the device benchmarked, in the same run: an exp-loop
microbenchmark (exp evaluations per second) and a buffer copy (bytes per second), and the floor
each stage's time is set against (the bytes it must move, or the exps compositing must evaluate)."""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.gpu.constants import TILE  # noqa: E402
from seuwgpu.gpu.device import GPU  # noqa: E402
from seuwgpu.render.sort import tile_key_bits  # noqa: E402

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
# order, writes counts, scans them (24 B a primitive) and emits 8 B per pair. Keyed by the
# PIPELINE stages' names (tools/bench_stages.py STAGES).
STAGE_BYTES = {
    "project": lambda n, pairs, n_tiles, model_bytes: model_bytes + 56 * n,
    "depth_sort": lambda n, pairs, n_tiles, model_bytes: 8 * 16 * n,
    "emit": lambda n, pairs, n_tiles, model_bytes: 24 * n + 16 * n + 8 * pairs,
    "tile_sort": lambda n, pairs, n_tiles, model_bytes: -(-tile_key_bits(n_tiles) // 4) * 16 * pairs,
    "ranges": lambda n, pairs, n_tiles, model_bytes: None,
}
