"""The committed study on the real corpus (docs/study/real): its headline numbers recomputed from
its records (records_single.parquet, the single upsets cut to the columns these numbers need) with
plain pandas and the textbook Student-t interval, not through seuwgpu.analysis, must equal the
claims rows the report wrote and the headline table of its README."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

STUDY = Path(__file__).resolve().parents[1] / "docs" / "study" / "real"
FIVE = ["means", "log_scales", "quats", "opacity", "sh_dc"]  # Table 2's fields but sh_rest


@pytest.fixture(scope="module")
def records():
    return pd.read_parquet(STUDY / "records_single.parquet")


@pytest.fixture(scope="module")
def claims():
    c = pd.read_csv(STUDY / "claims.csv")
    return c[(c["population"] == "real models") & c["N"].str.startswith("full size")]


def t_interval(values) -> tuple[float, float, float]:
    v = np.asarray(values, float)
    half = stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v))
    return v.mean(), v.mean() - half, v.mean() + half


def rate(g: pd.DataFrame) -> float:
    """Catastrophic share weighted by the stored bits each record stands for."""
    return float((g["weight"] * g["catastrophic"]).sum() / g["weight"].sum())


def strict_fp32(records, defense):
    d = records[(records["precision"] == "fp32") & (records["profile"] == "strict") & (records["defense"] == defense)]
    assert d["scene"].nunique() == 8, "the study's population is the 8 corpus models"
    return d


def one(claims, key, guard="none"):
    r = claims[(claims["key"] == key) & (claims["guard"] == guard)]
    assert len(r) == 1, (key, guard)
    return r.iloc[0]


def check(row, mean, lo, hi, scale=100.0, floor=0.0, ceiling=np.inf):
    """The row's value and its interval, cut to the range the quantity can take."""
    assert row["measured"] == pytest.approx(scale * mean, rel=1e-9, abs=1e-12)
    assert row["ci_lo"] == pytest.approx(max(scale * lo, floor), rel=1e-9, abs=1e-12)
    assert row["ci_hi"] == pytest.approx(min(scale * hi, ceiling), rel=1e-9, abs=1e-12)


def test_p_c_per_upset_over_the_models(records, claims):
    """p_c weighted by stored bits (an upset uniform over the model's bits), one value a model,
    and the t interval over the 8 models."""
    per_model = strict_fp32(records, "none").groupby("scene", observed=True).apply(rate, include_groups=False)
    check(one(claims, "pc_none_bits"), *t_interval(per_model))


def five_field_mean(records, defense) -> pd.Series:
    """Table 2's p_c: the plain mean of the per-field rates (sh_rest left out: SH degree 0 models
    store none), one value a model."""
    d = strict_fp32(records, defense)
    d = d[d["field"].isin(FIVE)]
    fields = d.groupby(["scene", "field"], observed=True).apply(rate, include_groups=False)
    return fields.groupby(level="scene").mean()


def test_p_c_as_the_five_field_mean(records, claims):
    check(one(claims, "pc_none_5"), *t_interval(five_field_mean(records, "none")))


@pytest.mark.parametrize("guard", ["guard", "guard_all"])
def test_the_share_each_guard_neutralises(records, claims, guard):
    """1 - p_c(guard) / p_c(none) on the five-field means, one value a model."""
    share = 1 - five_field_mean(records, guard) / five_field_mean(records, "none")
    check(one(claims, "guard_share", guard), *t_interval(share), ceiling=100.0)


@pytest.mark.parametrize("field", FIVE)
def test_table_2_catastrophe_rate_of_each_field(records, claims, field):
    d = strict_fp32(records, "none")
    per_model = d[d["field"] == field].groupby("scene", observed=True).apply(rate, include_groups=False)
    check(one(claims, f"field_rate_{field}"), *t_interval(per_model))


def test_the_readme_headline_table_quotes_these_rows(claims):
    """Each row of the README's headline table (claim key, guard, measured [lo, hi], verdict) is
    the claims row it names, to the digits printed."""
    text = (STUDY / "README.md").read_text()
    row = r"^\| `(\w+)` \| (\w+) \| .*? \| ([-\d.]+) \[([-\d.]+), ([-\d.]+)\] \| .*? \| (\w[\w ]*) \|$"
    rows = re.findall(row, text, re.M)
    assert len(rows) >= 5, "the README's headline table"
    everything = pd.read_csv(STUDY / "claims.csv")
    for key, guard, measured, lo, hi, verdict in rows:
        r = everything[(everything["key"] == key) & (everything["guard"] == guard)]
        r = r[r["N"].str.startswith("full size")].iloc[0]
        for printed, value in ((measured, r["measured"]), (lo, r["ci_lo"]), (hi, r["ci_hi"])):
            assert float(printed) == pytest.approx(value, rel=5e-3, abs=5e-4), (key, printed, value)
        assert verdict == r["verdict"], key
