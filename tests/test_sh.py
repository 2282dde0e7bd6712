"""model/sh.py: the real SH basis shared with the renderer's twin, and turning a model's frame
(what SPZ export does to a model whose up is not +y)."""

import numpy as np
import pytest

from seuwgpu.model import sh
from seuwgpu.model.fields import Model
from seuwgpu.model.formats import read_model, save_model
from seuwgpu.model.scenes import make_scene
from seuwgpu.render.project import quat_to_rotmat


def _colour(model, dirs):
    """SH colour (before the +0.5 and clamp) of every primitive seen from unit directions dirs [N, 3]."""
    b = sh.sh_basis(dirs, model.sh_degree, np.float64)
    c = sh.SH_C0 * model.sh_dc.astype(np.float64)
    return c + np.einsum("nk,nkc->nc", b[:, 1:], model.sh_rest.astype(np.float64))


@pytest.mark.parametrize("up", ["+z", "-z", "+x", "-x", "-y"])
def test_rotate_model_turns_everything_together(up):
    rng = np.random.default_rng(4)
    n = 200
    m = Model(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        log_scales=rng.normal(-2, 0.5, (n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        opacity=rng.normal(size=n).astype(np.float32),
        sh_dc=rng.normal(size=(n, 3)).astype(np.float32),
        sh_rest=rng.normal(0, 0.3, (n, 15, 3)).astype(np.float32),
    )
    R = sh.rotation_to_y(up)
    axis = {"x": 0, "y": 1, "z": 2}[up[1]]
    u = np.zeros(3)
    u[axis] = 1.0 if up[0] == "+" else -1.0
    assert np.allclose(R @ u, [0, 1, 0]) and np.isclose(np.linalg.det(R), 1.0)
    r = sh.rotate_model(m, R)
    np.testing.assert_allclose(r.means, m.means @ R.T, atol=1e-6)
    # covariances turn as R S R^T
    s2 = np.exp(2 * m.log_scales.astype(np.float64))
    Q, Qr = quat_to_rotmat(m.quats).astype(np.float64), quat_to_rotmat(r.quats).astype(np.float64)  # the twin's
    cov = np.einsum("nij,nj,nkj->nik", Q, s2, Q)
    cov_r = np.einsum("nij,nj,nkj->nik", Qr, s2, Qr)
    np.testing.assert_allclose(cov_r, np.einsum("ij,njk,lk->nil", R, cov, R), atol=1e-5)
    # the colour seen from R d is the original's from d
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(_colour(r, d @ R.T), _colour(m, d), atol=2e-6)
    assert np.array_equal(r.opacity, m.opacity) and np.array_equal(r.log_scales, m.log_scales)


def test_basis_in_float32_is_the_renderers():
    from seuwgpu.render import project

    d = np.random.default_rng(2).normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    b32, b64 = sh.sh_basis(d, 3), sh.sh_basis(d, 3, np.float64)
    assert b32.dtype == np.float32 and project.sh_basis is sh.sh_basis
    np.testing.assert_allclose(b32, b64, atol=1e-6)


def test_spz_export_of_a_z_up_scene_stands_upright(tmp_path):
    """SPZ is y-up: a z-up procedural scene is turned on export, so what was up (+z) reads back
    as +y, with colours carried (SPZ quantisation aside)."""
    m = make_scene("blocks", n=300, sh_degree=1)
    save_model(m, tmp_path / "b.spz", up="+z")
    back = read_model(tmp_path / "b.spz")
    assert back.up == "+y"
    np.testing.assert_allclose(back.model.means[:, 1], m.means[:, 2], atol=2e-3)  # height stays height
    np.testing.assert_allclose(back.model.means[:, 2], -m.means[:, 1], atol=2e-3)
    d = np.array([[0.0, 0.0, 1.0]] * m.n)  # looking down +z before, down +y after
    np.testing.assert_allclose(_colour(back.model, d[:, [0, 2, 1]]), _colour(m, d), atol=0.05)
