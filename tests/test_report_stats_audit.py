"""An independent audit of the report's analyses that tests/test_report_numbers.py does not cover:
intervals, fits and edge cases recomputed here from first principles (scipy root finding, plain
pandas), not through the code under test."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import brentq
from scipy.stats import chi2

from seuwgpu.analysis import claimrows, claims, dose


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
        # an interval narrower than a step of a 400-point grid of log p (it gave none at all)
        ([1, 10, 100], [2000, 18000, 80000], [1e6, 1e6, 1e6]),
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


def _single_records(sign_per_scene: int, scenes=("a",)):
    rows, iid = [], 0
    for scene in scenes:
        for field, bit, cls, fp, m in (
            ("log_scales", 31, "sign", 0.08, sign_per_scene),
            ("log_scales", 3, "mantissa", 0.0, 3),
            ("opacity", 3, "mantissa", 0.001, 3),
        ):
            for i in range(m):
                iid += 1
                rows.append(
                    dict(
                        campaign="single",
                        scene=scene,
                        n_primitives=1000,
                        precision="fp32",
                        field=field,
                        bit=bit,
                        bit_class=cls,
                        component=0,
                        defense="none",
                        footprint=fp * (1 + 0.5 * i),
                        peak_error=0.5 if fp else 0.0,
                        psnr=30.0,
                        ssim=0.9,
                        nonfinite=False,
                        k=1,
                        weight=1000.0 * (3 if field == "log_scales" else 1) / m,
                        injection_id=iid,
                    )
                )
    return pd.DataFrame(rows)


@pytest.mark.parametrize("scenes", [("a",), ("a", "b")])
def test_sign_claim_of_one_record_per_cell_has_no_interval(scenes):
    """A log-scale sign cell holding one record per scene: resampling within cells returns the same
    records every time, so the bootstrap "interval" is the point itself (width 0) and the claim's
    verdict compared the paper's value with it. One record says nothing of its spread: no interval,
    no verdict."""
    t = claims.claims_table(_single_records(1, scenes)).set_index("claim")
    r = t.loc[claims.PAPER["sign_mean"][0]]
    assert r["measured"] == pytest.approx(8.0)
    assert math.isnan(r["ci_lo"]) and math.isnan(r["ci_hi"])
    assert r["verdict"] == "not measured"


def test_sign_claim_bootstrap_interval_with_several_records():
    """With several records in the cell the bootstrap stands: an interval around the weighted mean
    (footprints 8, 12, 16, 20 %: mean 14 %), inside the range of the records."""
    t = claims.claims_table(_single_records(4)).set_index("claim")
    r = t.loc[claims.PAPER["sign_mean"][0]]
    assert r["measured"] == pytest.approx(14.0)
    # one model: the bootstrap interval stays beside (pooled), no interval over models, no verdict
    assert 8.0 <= r["pooled_lo"] < 14.0 < r["pooled_hi"] <= 20.0
    assert math.isnan(r["ci_lo"]) and r["verdict"] == "inconclusive"


def test_pc_claim_needs_every_stored_bit():
    """p_c is the claim about a uniform upset over all of a model's stored bits. Records of three
    (field, bit) cells stand for 7 of the 59 x 32 (component, bit) positions (log-scale bits 31 and
    3: 3 components each; opacity bit 3: 1): their rate says nothing about the others, so it gets
    no verdict (it had 'reproduced' from a 0.4% sample)."""
    t = claims.claims_table(_single_records(4)).set_index("claim")
    r = t.loc[claims.PAPER["pc_none_bits"][0]]  # the stored-bit-weighted p_c
    assert r["verdict"] == "not measured"
    assert f"covers {100 * 7 / (59 * 32):.3g}% of the stored bits" in r["basis"]
    # the measured value and its interval stay: the weighted rate of the cells sampled (the sign
    # cell, 3 of their 7 weight units, is catastrophic)
    assert r["measured"] == pytest.approx(100 * 3 / 7) and r["pooled_lo"] < r["measured"] < r["pooled_hi"]
    # the plain mean over fields needs every field: two of six give no verdict either
    assert t.loc[claims.PAPER["pc_none"][0], "verdict"] == "not measured"


def test_pc_claim_over_every_field_and_bit_has_a_verdict():
    rows, iid = [], 0
    for field, nc in {"means": 3, "log_scales": 3, "quats": 4, "opacity": 1, "sh_dc": 3, "sh_rest": 45}.items():
        for bit in range(32):
            for rep in range(2):
                iid += 1
                bad = field == "log_scales" and bit == 31 and rep == 0
                rows.append(
                    dict(
                        campaign="single",
                        scene="a",
                        n_primitives=100,
                        precision="fp32",
                        field=field,
                        bit=bit,
                        component=0,
                        bit_class="sign" if bit == 31 else ("exponent" if bit >= 23 else "mantissa"),
                        defense="none",
                        footprint=0.5 if bad else 0.0,
                        peak_error=0.5 if bad else 0.0,
                        nonfinite=False,
                        k=1,
                        weight=100 * nc / 2,
                        injection_id=iid,
                    )
                )
    t = claims.claims_table(pd.DataFrame(rows)).set_index("claim")
    r = t.loc[claims.PAPER["pc_none_bits"][0]]  # the stored-bit-weighted p_c
    # one event in the log-scale sign cell: 300 / 2 of 100 x 59 x 32 stored bits
    assert r["measured"] == pytest.approx(100 * 150 / (100 * 59 * 32))
    # one model: a verdict is given (not "not measured"), but never firmer than inconclusive
    assert r["verdict"] == "inconclusive" and "covers" not in r["basis"]
    # the plain mean of the six field rates: log-scales 1 event of 64 records (its 32 bits weigh
    # alike), the others 0
    r = t.loc[claims.PAPER["pc_none"][0]]
    assert r["measured"] == pytest.approx(100 * (0.5 / 32) / 6)
    assert r["verdict"] == "inconclusive" and r["pooled_lo"] < r["measured"] < r["pooled_hi"]


@pytest.mark.parametrize(
    "key, lo, hi, verdict",
    [
        # the CPU study's lookup AUC: [0.97605, 0.99687] against the paper's 0.997 (any AUC in
        # [0.9965, 0.9975]) with a margin of +-0.005: it reaches below the band, so neither
        ("auc_fieldbit", 0.976053035333644, 0.9968686293160773, "inconclusive"),
        ("auc_fieldbit", 0.9750, 0.99649, "inconclusive"),
        ("auc_fieldbit", 0.99751, 0.9990, "reproduced"),
        ("auc_fieldbit", 0.9500, 0.9800, "differs"),
        # the CPU study's guarded p_c (%): 0.0612 stands for [0.06115, 0.06125], x/2: [0.0306, 0.1225]
        ("pc_guard", 0.0023291132055587647, 0.057615824266086156, "inconclusive"),
        ("pc_guard", 0.0350, 0.1000, "reproduced"),
        ("pc_guard", 0.1300, 0.2000, "differs"),
        ("alpha_median_procedural", 0.2341, 0.6204, "differs"),  # the paper's 2.78, +-0.5
    ],
)
def test_verdict_reads_the_paper_value_to_its_printed_digits(key, lo, hi, verdict):
    """The paper prints rounded values; its 0.997 is any number that rounds to it, widened by the
    row's margin (paper.MARGINS): reproduced needs the interval inside, differs wholly outside
    (paper_half_unit: half a unit of the last printed digit)."""
    r = claimrows.row(key, (lo + hi) / 2, lo, hi)
    assert r["verdict"] == verdict
    assert claims.paper_half_unit(0.997) == pytest.approx(5e-4)
    assert claims.paper_half_unit(10.3) == pytest.approx(0.05)
    assert claims.paper_half_unit(0.0612) == pytest.approx(5e-5)
    assert claims.paper_half_unit(100.0) == pytest.approx(0.05)
