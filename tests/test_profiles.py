"""Renderer profiles (docs/renderer.md "Profiles"): strict and gsplat, GPU against the numpy twin,
and the rules where they differ, checked against hand-computed pixels."""

import numpy as np
import pytest
from conftest import psnr_finite, random_model

from seuwgpu.model.cameras import Camera, orbit_cameras
from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.render import reference
from seuwgpu.render.project import project
from seuwgpu.render.renderer import Renderer

W, H = 64, 48
F = np.float32


def corrupt(model: Model, field: str, prim: int, comp: int, value: float) -> Model:
    m = model.copy()
    m.field(field)[prim, comp] = value
    return m


def single(opacity=0.0, quats=(1.0, 0.0, 0.0, 0.0), log_scale=-3.0):
    """One grey Gaussian 2 units in front of a 32x32 pinhole camera (identity pose)."""
    dc = np.full((1, 3), (0.3 - 0.5) / 0.28209479177387814)
    model = Model(
        means=np.array([[0.0, 0.0, 2.0]]),
        log_scales=np.full((1, 3), log_scale),
        quats=np.array([quats], dtype=np.float64),
        opacity=np.array([opacity]),
        sh_dc=dc,
        sh_rest=np.zeros((1, 0, 3)),
    )
    cam = Camera(np.eye(4), [[32.0, 0, 16.0], [0, 32.0, 16.0], [0, 0, 1]], 32, 32)
    return model, cam


@pytest.mark.parametrize("profile", ["strict", "gsplat"])
def test_clean_scene_matches_twin(profile):
    model = random_model(400, seed=21)
    cams = orbit_cameras(2, W, H)
    g = Renderer(model, cams, profile=profile).render()
    assert psnr_finite(g, reference.render(model, cams, profile=profile)) >= 50


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 3.0e38])
def test_gsplat_profile_matches_twin_on_corrupted_values(field, value):
    model = random_model(300, seed=5)
    cams = orbit_cameras(2, W, H)
    comp = 1 if field != "opacity" else 0
    bad = corrupt(model, field, 17, comp, value)
    bad = corrupt(bad, "log_scales", 40, 0, 4.5)  # a finite frame-covering Gaussian as well
    g = Renderer(bad, cams, profile="gsplat").render()
    assert psnr_finite(g, reference.render(bad, cams, profile="gsplat")) >= 50


def test_nan_quaternion_is_a_sheet_under_strict_and_culled_under_gsplat():
    model = random_model(300, seed=7)
    cams = orbit_cameras(2, W, H)
    bad = corrupt(model, "quats", 11, 2, np.nan)
    gone = corrupt(model, "opacity", 11, 0, -1e30)  # alpha 0: skipped everywhere, as if culled
    strict = Renderer(bad, cams, profile="strict").render()
    clean = Renderer(model, cams, profile="strict").render()
    changed = (np.abs(strict - clean) > 1 / 255).any(-1)
    assert changed.mean() > 0.5, "strict: the NaN covariance is an unbounded, frame-covering sheet"
    gs = Renderer(bad, cams, profile="gsplat")
    assert np.array_equal(gs.render().view(np.uint32), Renderer(gone, cams, profile="gsplat").render().view(np.uint32))
    p = project(bad, cams[0], "gsplat")
    assert not p["visible"][11] and np.isnan(p["radius"][11]).all()


def test_gsplat_nan_opacity_is_nearly_opaque_not_nan():
    # gsplat: alpha = min(0.99, NaN) with CUDA's fminf is 0.99; strict lets the NaN through.
    model, cam = single(opacity=np.nan)
    strict = Renderer(model, [cam], profile="strict").render()[0]
    gs = Renderer(model, [cam], profile="gsplat").render()[0]
    assert np.isnan(strict[16, 16]).all()
    want = F(0.3) * (F(0.99) * F(1)) + (F(1) - F(0.99)) * F(1)  # C + T * white background
    np.testing.assert_allclose(gs[16, 16], want, rtol=1e-6)
    assert np.isfinite(gs).all()
    # every pixel of the primitive's tiles: NaN sigma nowhere, alpha 0.99 where exp(-sigma) > 0
    np.testing.assert_allclose(gs, reference.render_view(model, cam, profile="gsplat"), rtol=1e-5)


def test_gsplat_infinite_scale_is_culled_via_nan_covariance():
    # exp(huge) = Inf: gsplat forms Sigma = M M^T and W Sigma W^T, where Inf - Inf gives NaN,
    # so the radius is NaN and CUDA's (int)NaN = 0 culls it; strict draws the unbounded sheet.
    model, cam = single(quats=(0.9, 0.3, 0.2, 0.1))
    model = corrupt(model, "log_scales", 0, 0, 1e30)
    p = project(model, cam, "gsplat")
    assert not p["visible"][0]
    assert project(model, cam, "strict")["unbounded"][0]
    gs = Renderer(model, [cam], profile="gsplat").render()[0]
    assert (gs == 1.0).all()  # background only


def test_profile_is_recorded_and_checked():
    from seuwgpu.faults.engine import Engine

    model = random_model(120, seed=8)
    eng = Engine(model, orbit_cameras(1, 32, 32), profile="gsplat")
    site = eng.site("quats", 3, 0, 30)
    assert eng.inject(site)["profile"] == "gsplat"
    assert set(eng.evaluate_frame([site])["profile"]) == {"gsplat"}
    with pytest.raises(ValueError, match="profile"):
        Renderer(model, orbit_cameras(1, 32, 32), profile="cuda")


def test_spec_profile_key():
    from seuwgpu.campaign.spec import SpecError, normalize_spec

    raw = {"scenes": [{"scene": "spheres", "n": 100}], "single": {"samples": 1}}
    assert "profile" not in normalize_spec(raw).to_dict()  # default strict, old specs keep their hash
    assert normalize_spec({**raw, "profile": "gsplat"}).profile == "gsplat"
    with pytest.raises(SpecError, match="^profile: unknown renderer profile 'cuda'; expected one of strict, gsplat$"):
        normalize_spec({**raw, "profile": "cuda"})
    with pytest.raises(SpecError, match=r"^profile: unknown renderer profile \['gsplat'\]; expected one of"):
        normalize_spec({**raw, "profile": ["gsplat"]})
