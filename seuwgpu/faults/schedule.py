"""A check defense's schedule: a check before every S-th frame. What an upset costs the user under it
(`exposure`: the frames drawn from the corrupted model before the check repairs it); what it costs
in time is measured as a schedule (faults/costs.py `schedule_time`: S frames and a check against
S frames, interleaved round by round), summarised by `median_interval`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

DEFAULT_CHECK_EVERY = 10  # S when a spec or command names none: (S - 1) / 2 = 4.5 frames drawn on average


def check_every_of(check_every, defense: str) -> int:
    """S for `defense` from a schedule that is one S for every check defense or a {defense: S}
    table (a defense it does not name: DEFAULT_CHECK_EVERY)."""
    if isinstance(check_every, dict):
        return int(check_every.get(defense, DEFAULT_CHECK_EVERY))
    return int(check_every)


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


def median_interval(x, conf: float = 0.95) -> tuple[float, float, float]:
    """(median, lo, hi): the median of `x` and its distribution-free interval from order
    statistics (ranks k and n + 1 - k, k the largest with P(Binomial(n, 1/2) < k) <= (1 - conf) / 2).
    Too few values for the interval (n < 6 at 95%): lo and hi are NaN."""
    from math import comb

    v = np.sort(np.asarray(x, dtype=np.float64))
    v = v[~np.isnan(v)]
    n = v.size
    if n == 0:
        return float("nan"), float("nan"), float("nan")
    med = float(np.median(v))
    k = 0
    below = 0.0  # P(B <= k)
    while k + 1 <= n:
        below += comb(n, k) / 2.0**n
        if below > (1 - conf) / 2:
            break
        k += 1
    if k == 0:
        return med, float("nan"), float("nan")
    return med, float(v[k - 1]), float(v[n - k])
