"""Campaign planning: how many injections a cell needs for a margin of error, and the margin a
sample gives (Leveugle et al., "Statistical fault injection: quantified error and confidence",
DATE 2009): n = N / (1 + e^2 (N-1) / (t^2 p (1-p))), N the population (fault sites in the cell),
e the margin, t the two-sided normal quantile of the confidence level, p the expected proportion
(worst case 0.5). With no population (N -> infinity) it is n = t^2 p (1-p) / e^2.

The finite-population form holds for draws without replacement. Campaigns draw each cell's sites
with replacement (campaign/sampling.py), so specs plan with the unbounded form (campaign/spec.py)."""

from __future__ import annotations

import math
from statistics import NormalDist


def z_value(conf: float = 0.95) -> float:
    """Two-sided standard-normal quantile t for a confidence level (1.959964 at 0.95)."""
    conf = float(conf)
    if not 0.0 < conf < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {conf}")
    return NormalDist().inv_cdf(0.5 + conf / 2.0)


def sample_size(margin: float, confidence: float = 0.95, population=None, p: float = 0.5) -> int:
    """Fault injections needed per cell for a margin of error at a confidence level.

    Leveugle et al. (DATE 2009), eq. for a finite population of N fault sites:
        n = N / (1 + e^2 (N - 1) / (t^2 p (1 - p)))
    with e = margin (absolute, as a proportion: 0.01 is +-1 percentage point), t the two-sided
    normal quantile of `confidence` and p the expected proportion (0.5 is the worst case).
    population=None means an unbounded population: n = t^2 p (1 - p) / e^2.
    The result is rounded up and never exceeds the population.
    """
    e = float(margin)
    if not 0.0 < e < 1.0:
        raise ValueError(f"margin must lie in (0, 1), got {margin}")
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must lie in (0, 1), got {p}")
    t = z_value(confidence)
    pq = p * (1.0 - p)
    if population is None or (isinstance(population, float) and math.isinf(population)):
        n = t * t * pq / (e * e)
    else:
        N = float(population)
        if N < 1:
            raise ValueError(f"population must be >= 1, got {population}")
        n = N / (1.0 + e * e * (N - 1.0) / (t * t * pq))
        n = min(n, N)
    # Guard against 9604.000000001 -> 9605 from floating-point noise.
    return int(math.ceil(round(n, 9)))


def margin_of_error(n: int, confidence: float = 0.95, population=None, p: float = 0.5) -> float:
    """Inverse of `sample_size`: the margin e achieved by n samples (Leveugle et al. 2009)."""
    n = float(n)
    if n <= 0:
        raise ValueError("n must be positive")
    t = z_value(confidence)
    pq = p * (1.0 - p)
    if population is None:
        return t * math.sqrt(pq / n)
    N = float(population)
    if n >= N:
        return 0.0
    return t * math.sqrt(pq * (N - n) / (n * (N - 1.0)))
