"""An independent audit of the report's analyses that tests/test_report_numbers.py does not cover:
intervals, fits and edge cases recomputed here from first principles (scipy root finding, plain
pandas), not through the code under test."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import chi2

from seuwgpu.analysis import dose


def _loglik(p, k, x, n):
    q = 1.0 - (1.0 - p) ** k
    with np.errstate(divide="ignore", invalid="ignore"):
        hit = np.where(x > 0, x * np.log(np.maximum(q, 1e-300)), 0.0)
        miss = np.where(n > x, (n - x) * np.log(np.maximum(1.0 - q, 1e-300)), 0.0)
    return float(np.sum(hit + miss))


@pytest.mark.parametrize(
    "k, x, n",
    [
        ([1, 10, 100, 1000], [0, 1, 2, 4], [4, 4, 4, 4]),
        ([1, 30, 300], [0, 3, 5], [5, 5, 5]),
        ([1, 30, 300], [1, 5, 5], [5, 5, 5]),
        ([1, 10, 100], [2, 15, 60], [100, 100, 100]),
    ],
)
def test_dose_fit_interval_is_the_profile_likelihood_one(k, x, n):
    """The 95% interval of the dose model's p is where the deviance 2 (l(p_hat) - l(p)) reaches the
    chi-square(1) 95% quantile: found here by root finding on each side of the MLE. A grid of p
    values alone gave ends up to a grid step (7%) inside: an interval narrower than 95%."""
    k, x, n = (np.asarray(v, float) for v in (k, x, n))
    f = dose.fit_dose_model(k, x, n)
    p_hat = f["p"]
    top = _loglik(p_hat, k, x, n)
    cut = chi2.ppf(0.95, 1) / 2

    def g(p):
        return top - _loglik(p, k, x, n) - cut

    lo = brentq(g, 1e-14, p_hat, xtol=1e-15)
    hi = brentq(g, p_hat, 1 - 1e-12, xtol=1e-15)
    assert f["p_lo"] == pytest.approx(lo, rel=1e-6)
    assert f["p_hi"] == pytest.approx(hi, rel=1e-6)
    assert math.isclose(2 * g(f["p_lo"]), 0.0, abs_tol=1e-5) and math.isclose(2 * g(f["p_hi"]), 0.0, abs_tol=1e-5)


def test_dose_fit_without_events_starts_at_zero():
    f = dose.fit_dose_model([1, 10, 100], [0, 0, 0], [5, 5, 5])
    assert f["p"] == 0 and f["p_lo"] == 0
    # the upper end: where the log-likelihood sum(n k log(1-p)) has fallen by chi2/2
    want = 1 - math.exp(-chi2.ppf(0.95, 1) / 2 / (5 * 111))
    assert f["p_hi"] == pytest.approx(want, rel=1e-6)
