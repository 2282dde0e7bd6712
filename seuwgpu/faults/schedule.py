"""A check defense's schedule: a check before every S-th frame. What an upset costs the user under it
(`exposure`: the frames drawn from the corrupted model before the check repairs it) and what the
schedule costs in time, measured as a schedule (`schedule_samples`: S frames and a check against
S frames, interleaved round by round; faults/costs.py runs it on the renderer)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Exposure(NamedTuple):
    per_upset: np.ndarray  # frames rendered from the corrupted model, per upset of the schedule
    expected: float  # over an upset landing in a uniformly drawn frame gap
    worst: float


def exposure(check_every: int, upset_frames=None) -> Exposure:
    """Frames rendered from a corrupted model between an upset and the check that repairs it,
    for a check before every `check_every`-th frame (before frames 0, S, 2S, ...; 0 = never).

    An upset "at frame f" lands after frame f - 1 was drawn and before frame f's check: frames
    f .. c - 1 are drawn corrupted, c the first check frame >= f, so (-f) mod S of them: none
    when f is a check frame, S - 1 when it lands just after one. `expected` and `worst` are over
    every phase (f = 0 .. S - 1, each equally likely); `per_upset` is for `upset_frames` (a
    hand-made schedule; every phase when None). Never checked: infinite exposure."""
    s = int(check_every)
    if s < 0:
        raise ValueError(f"a check schedule is every S >= 1 frames, or 0 for never (got {s})")
    frames = np.arange(max(s, 1)) if upset_frames is None else np.asarray(upset_frames, dtype=np.int64)
    if s == 0:
        per = np.full(frames.shape, np.inf)
        return Exposure(per, float("inf"), float("inf"))
    per = (-frames) % s
    phases = (-np.arange(s)) % s
    return Exposure(per.astype(np.float64), float(phases.mean()), float(phases.max()))
