"""Per-stage GPU times of a render (tools/bench.py): a Renderer whose next submission carries
timestamp queries around every compute pass (seuwgpu/gpu/timing.py), and the PIPELINE stage
each pass belongs to: the one that recorded it (Renderer.encode_stage)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import wgpu

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.gpu.device import GPU  # noqa: E402
from seuwgpu.gpu.timing import TimedEncoder  # noqa: E402
from seuwgpu.render.pipeline import PIPELINE  # noqa: E402
from seuwgpu.render.renderer import Renderer  # noqa: E402

STAGES = tuple(stage.name for stage in PIPELINE)
"""The render pipeline's stages (render/pipeline.py): each compute pass is timed under the stage
that recorded it, so a new stage gets its own column (emit includes the tile counts and their scan)."""


def timestamp_period_ns(gpu: GPU) -> float:
    """Nanoseconds per timestamp tick: wgpu-native's wgpuQueueGetTimestampPeriod (Vulkan's
    timestampPeriod; WebGPU itself specifies nanoseconds, wgpu-native returns ticks), 1.0 where it
    is absent. wgpu-py 0.32 wraps no such call, so this reaches the queue's native handle, which
    the package never does: it stays here, in the benchmark."""
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
        self._proxy = None
        self._stage_of_pass: dict[int, str] = {}  # timed pass index -> the stage that recorded it

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
        proxy = self._proxy = TimedEncoder(encoder, qs, cap)
        self._stage_of_pass = {}
        try:
            super().encode(proxy, views)  # timed: one encoder (no split), so every pass is in one query set
        finally:
            self._proxy = None
        if proxy.records:
            encoder.resolve_query_set(qs, 0, 2 * len(proxy.records), buf, 0)
        self._last = proxy
        return encoder

    def encode_stage(self, stage, encoder, buffers, slot, views):
        before = len(self._proxy.records) if self._proxy is not None else 0
        super().encode_stage(stage, encoder, buffers, slot, views)
        if self._proxy is not None:
            self._stage_of_pass.update(dict.fromkeys(range(before, len(self._proxy.records)), stage.name))

    def stage_times(self) -> dict:
        """Seconds per stage (summed over views) of the last timed submission, plus 'gaps',
        'other' (passes of no known stage) and 'untimed_passes'."""
        proxy, (_, _, buf) = self._last, self._ts
        n = len(proxy.records)
        ticks = np.frombuffer(self.gpu.queue.read_buffer(buf, 0, 16 * n), np.uint64).astype(np.int64)
        ns = timestamp_period_ns(self.gpu)
        begin, end = ticks[0::2], ticks[1::2]
        out = {s: 0.0 for s in STAGES}
        out["other"] = 0.0  # passes recorded outside the stages (none today)
        for i, (b, e) in enumerate(zip(begin, end)):
            out[self._stage_of_pass.get(i, "other")] += max(0, int(e - b)) * ns * 1e-9
        span = (int(end.max()) - int(begin.min())) * ns * 1e-9 if n else 0.0
        out["gaps"] = max(0.0, span - sum(out[s] for s in (*STAGES, "other")))
        out["untimed_passes"] = proxy.untimed
        out["passes"] = n
        return out
