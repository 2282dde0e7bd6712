"""LPIPS (AlexNet, v0.1) in numpy against the reference implementation's distances."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from seuwgpu.metrics import lpips

DATA = Path(__file__).parent / "data" / "lpips"


def _img(name: str) -> np.ndarray:
    return iio.imread(DATA / f"{name}.png")[..., :3].astype(np.float32) / 255.0


def test_weights_are_installed():
    # ./dev test installs them; without them every other test here would have nothing to check
    assert lpips.available(), lpips.INSTALL_HINT


def test_reference_example_images():
    # lpips 0.1.4 (torch 2.14.1), lpips.LPIPS(net="alex"): 0.7218807 and 0.1375656; its README: 0.722
    ref = _img("ex_ref")
    d = lpips.lpips(np.stack([ref, ref]), np.stack([_img("ex_p0"), _img("ex_p1")]))
    assert d[0] == pytest.approx(0.7218807, abs=2e-6)
    assert d[1] == pytest.approx(0.1375656, abs=2e-6)


def test_random_pairs_against_the_reference():
    # pairs drawn here; distances from lpips 0.1.4 (torch 2.14.1) on the same arrays (non-square frames)
    rng = np.random.default_rng(0)
    a = rng.random((2, 48, 40, 3)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1).astype(np.float32)
    assert lpips.lpips(a, b) == pytest.approx([0.0086527886, 0.0134111047], abs=2e-7)


def test_identity_symmetry_nan_and_bad_shapes():
    a, b = _img("ex_ref"), _img("ex_p1")
    assert lpips.lpips(a, a) == 0.0
    assert lpips.lpips(a, b) == pytest.approx(lpips.lpips(b, a), rel=1e-6)
    bad = b.copy()
    bad[3, 4, 1] = np.nan
    assert np.isnan(lpips.lpips(a, bad))  # undefined, not a number made up
    over = np.clip(b * 3, 0, None)
    assert lpips.lpips(a, over) == pytest.approx(lpips.lpips(a, np.clip(over, 0, 1)))  # display-referred
    with pytest.raises(ValueError, match="same shape"):
        lpips.lpips(a, b[:32])
    with pytest.raises(ValueError, match="at least 32x32"):
        lpips.lpips(a[:16, :16], b[:16, :16])


def test_missing_weights_name_the_extra(monkeypatch):
    monkeypatch.setattr(lpips, "weights_path", lambda: None)
    lpips._load.cache_clear()
    try:
        with pytest.raises(lpips.LpipsUnavailable, match=r"seuwgpu\[lpips\]"):
            lpips.lpips(_img("ex_ref"), _img("ex_p0"))
    finally:
        lpips._load.cache_clear()


def test_campaign_records_lpips_when_asked(tmp_path):
    from seuwgpu.campaign.runner import Runner
    from seuwgpu.campaign.spec import normalize_spec
    from seuwgpu.campaign.store import read_records

    spec = normalize_spec(
        {
            "views": 1,
            "size": "32x32",
            "lpips": True,
            "scenes": [{"scene": "spheres", "n": 300}],
            "single": {"fields": ["log_scales", "sh_dc"], "bits": [0, 30, 31], "samples": 2},
        }
    )
    Runner(spec, tmp_path / "run", quiet=True).run()
    df = read_records(tmp_path / "run")
    assert df.loc[df["peak_error"] == 0, "lpips"].eq(0).all()
    assert df.loc[df["nonfinite"], "lpips"].isna().all()
    # visibly changed pixels: a positive distance; no visible change: ~0 (float32 noise)
    shown = (df["footprint"] > 0) & ~df["nonfinite"]
    assert shown.any() and (df.loc[shown, "lpips"] > 0).all()
    assert (df.loc[df["footprint"] == 0, "lpips"] < 1e-6).all()
    without = normalize_spec({"scenes": [{"scene": "spheres", "n": 300}], "single": {"samples": 1}, "lpips": False})
    assert "lpips" not in without.to_dict()  # off by default, and an explicit false keeps the hash
