"""GPU time of compute passes, read from timestamp queries, and dispatch counts, for benchmarks.

An encoder proxy gives every compute pass begin/end timestamp writes (WebGPU's portable way:
`timestamp_writes` on begin_compute_pass) and remembers the label of the first pipeline each pass
sets (Kernel labels its passes and device.pipeline its pipelines "<shader>:<entry>"), so that a
caller can map passes to stages without the renderer knowing it is timed. Passes past the query
set's size are left untimed and counted.
"""

from __future__ import annotations


class TimedPass:
    """Forwards to a real compute pass; remembers the label of the first pipeline set on it."""

    def __init__(self, cpass, record: dict):
        self._p, self._rec = cpass, record

    def set_pipeline(self, pipeline):
        if self._rec["label"] is None:
            self._rec["label"] = pipeline.label
        self._p.set_pipeline(pipeline)

    def __getattr__(self, name):
        return getattr(self._p, name)


class CountingEncoder:
    """Forwards to a real command encoder and counts the dispatches recorded in its passes."""

    def __init__(self, encoder):
        self._e, self.dispatches = encoder, 0

    def begin_compute_pass(self, **kw):
        return CountingPass(self._e.begin_compute_pass(**kw), self)

    def __getattr__(self, name):
        return getattr(self._e, name)


class CountingPass:
    def __init__(self, cpass, counter: CountingEncoder):
        self._p, self._c = cpass, counter

    def dispatch_workgroups(self, *a):
        self._c.dispatches += 1
        self._p.dispatch_workgroups(*a)

    def dispatch_workgroups_indirect(self, *a):
        self._c.dispatches += 1
        self._p.dispatch_workgroups_indirect(*a)

    def __getattr__(self, name):
        return getattr(self._p, name)


def count_dispatches(renderer) -> int:
    """Dispatches `renderer.encode(encoder)` records (recorded, then dropped unsubmitted)."""
    enc = CountingEncoder(renderer.gpu.device.create_command_encoder())
    renderer.encode(enc)
    enc.finish()
    return enc.dispatches


class TimedEncoder:
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
        return TimedPass(cpass, rec)

    def __getattr__(self, name):
        return getattr(self._e, name)
