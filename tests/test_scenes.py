"""Embedded procedural scenes: exact counts, determinism, trained-model-like statistics, framing."""

import numpy as np
import pytest

from seuwgpu.model import scene_layouts, scenes
from seuwgpu.model.fields import FIELDS, Model, n_components

C0 = 0.28209479177387814
N = 6000


@pytest.fixture(scope="module")
def models():
    return {name: scenes.make_scene(name, N) for name in scenes.SCENES}  # the procedural ones


def _rotmat(q):
    q = q.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x.astype(np.float64)))


def test_registry():
    names = scenes.list_scenes()
    assert {"spheres", "blocks", "plant"} <= set(names)
    assert scenes.DEFAULT_SCENE == "spheres" and scenes.DEFAULT_SCENE in scenes.SCENES
    assert names == list(scenes.SCENES) + ["leica-sofort", "leica-sofort-wide", "yashica-t4", "yashica-t4-wide"]


@pytest.mark.parametrize("name", ["spheres", "blocks", "plant"])
def test_exact_count_shapes_dtypes(name):
    for n in (1, 2, 3, 17, 1000):
        for deg in (0, 1, 2, 3):
            m = scenes.make_scene(name, n, sh_degree=deg)
            assert isinstance(m, Model) and m.n == n and m.sh_degree == deg
            assert m.flat().shape == (n, n_components(deg))
            assert m.sh_rest.shape == (n, (deg + 1) ** 2 - 1, 3)
            for f in FIELDS:
                a = getattr(m, f)
                assert a.dtype == np.float32 and a.flags.c_contiguous
                assert np.isfinite(a).all(), (name, n, deg, f)
    m = scenes.make_scene(name, np.int64(5))  # numpy integers are fine
    assert m.n == 5


def test_determinism_and_seed(models):
    for name, m in models.items():
        again = scenes.make_scene(name, N)
        for f in FIELDS:
            assert np.array_equal(getattr(m, f), getattr(again, f)), (name, f)
        other = scenes.make_scene(name, N, seed=1)
        assert not np.array_equal(m.means, other.means)
        # same geometry, other samples: the bounding boxes agree
        assert np.allclose(
            np.quantile(m.means, [0.01, 0.99], axis=0), np.quantile(other.means, [0.01, 0.99], axis=0), atol=0.08
        )


def test_lower_degree_is_prefix():
    m3 = scenes.make_scene("plant", 2000, sh_degree=3)
    for deg in (0, 1, 2):
        m = scenes.make_scene("plant", 2000, sh_degree=deg)
        r = (deg + 1) ** 2 - 1
        assert np.array_equal(m.sh_rest, m3.sh_rest[:, :r])
        for f in ("means", "log_scales", "quats", "opacity", "sh_dc"):
            assert np.array_equal(getattr(m, f), getattr(m3, f))


def test_flat_gaussians(models):
    for name, m in models.items():
        ls = m.log_scales.astype(np.float64)
        # the third (normal) axis is the thin one, 1.5-2.5 units of log below the tangent ones
        assert np.mean(np.argmin(ls, axis=1) == 2) > 0.99, name
        gap = np.minimum(ls[:, 0], ls[:, 1]) - ls[:, 2]
        assert 1.4 < np.median(gap) < 2.6 and gap.min() > 1.0, name
        # tangent sigmas are of the order of the point spacing of a ~1 m^2 object
        assert -6.5 < np.median(ls[:, :2]) < -2.5, name
        qn = np.linalg.norm(m.quats, axis=1)
        assert 0.85 < qn.min() and qn.max() < 1.15 and not np.allclose(qn, 1.0), name


def test_flat_axis_follows_the_surface_normal(models):
    m = models["spheres"]
    normal_axis = _rotmat(m.quats)[:, :, 2]  # local z in world coordinates
    # primitives on the platform top: normal = z
    top = (np.abs(m.means[:, 2] - scene_layouts.SPHERES_BASE_TOP) < 0.004) & (
        np.hypot(m.means[:, 0], m.means[:, 1]) < 0.9
    )
    assert top.sum() > 200
    assert np.median(np.abs(normal_axis[top, 2])) > 0.99
    # primitives on the big red sphere: normal = radial
    c, r = np.array([0.35, -0.25, scene_layouts.SPHERES_BASE_TOP + 0.40]), 0.40
    d = m.means - c
    on = np.abs(np.linalg.norm(d, axis=1) - r) < 0.004
    assert on.sum() > 200
    radial = d[on] / np.linalg.norm(d[on], axis=1, keepdims=True)
    assert np.median(np.abs(np.sum(radial * normal_axis[on], axis=1))) > 0.99


def test_opacity_distribution(models):
    for name, m in models.items():
        o = _sigmoid(m.opacity)
        assert 0.8 < np.mean(o >= 0.9) < 0.95, name
        tail = np.mean((o > 0.045) & (o < 0.505))
        assert 0.08 < tail < 0.17, name
        assert o.min() > 0.045 and o.max() < 0.995, name


def test_colours_and_sh(models):
    means = []
    for name, m in models.items():
        rgb = 0.5 + C0 * m.sh_dc.astype(np.float64)
        assert rgb.min() >= 0.0 and rgb.max() <= 1.0, name
        assert rgb.std(axis=0).max() > 0.1, name  # diverse colours
        means.append(rgb.mean(axis=0))
        a = np.abs(m.sh_rest)
        assert 0.004 < a.mean() < 0.03 and a.max() <= 0.1 + 1e-6, name
        assert np.mean(a > 0.05) < 0.05, name
        # view dependence decays with the SH degree
        per_coef = a.mean(axis=(0, 2))
        assert per_coef[:3].mean() > per_coef[8:].mean(), name
    # the scenes do not look alike
    means = np.array(means)
    d = np.linalg.norm(means[:, None] - means[None], axis=-1)
    assert d[np.triu_indices(len(means), 1)].min() > 0.05


def test_splats_shrink_with_n():
    # (the plant's leaves cap the splat size at low n: compare where the caps do not bind)
    for name, n in (("spheres", 4000), ("blocks", 4000), ("plant", 50_000)):
        a = scenes.make_scene(name, n, sh_degree=0)
        b = scenes.make_scene(name, 4 * n, sh_degree=0)
        da = np.median(a.log_scales[:, :2]) - np.median(b.log_scales[:, :2])
        assert abs(da - 0.5 * np.log(4.0)) < 0.15, (name, da)  # sigma ~ 1/sqrt(n)


def test_scene_fits_and_is_framed(models):
    for name, m in models.items():
        r = np.linalg.norm(m.means, axis=1)
        assert np.quantile(r, 0.999) < 1.35, name
        cams = scenes.scene_cameras(name, 6, 160, 120)
        assert len(cams) == 6
        for cam in cams:
            R, t, K = (
                cam.viewmat[:3, :3].astype(np.float64),
                cam.viewmat[:3, 3].astype(np.float64),
                cam.K.astype(np.float64),
            )
            p = m.means @ R.T + t
            assert (p[:, 2] > 1.0).all(), name  # everything well in front of the camera
            u = K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2]
            v = K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]
            inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
            assert inside.mean() > 0.99, name
            # the object fills a good part of the frame (not a speck)
            assert np.ptp(u[inside]) > 0.35 * cam.width and np.ptp(v[inside]) > 0.35 * cam.height, name


def test_layout_does_not_depend_on_seed_or_n():
    a = scenes.make_scene("blocks", 3000, seed=0)
    b = scenes.make_scene("blocks", 30000, seed=5)
    lo_a, hi_a = a.means.min(axis=0), a.means.max(axis=0)
    lo_b, hi_b = b.means.min(axis=0), b.means.max(axis=0)
    assert np.allclose(lo_a, lo_b, atol=0.05) and np.allclose(hi_a, hi_b, atol=0.05)


def test_errors():
    with pytest.raises(ValueError) as e:
        scenes.make_scene("lego", 100)
    for name in ("spheres", "blocks", "plant"):
        assert name in str(e.value)
    with pytest.raises(ValueError, match="unknown scene"):
        scenes.scene_cameras("nope", 4, 64, 64)
    for bad in (0, -3):
        with pytest.raises(ValueError, match="at least 1"):
            scenes.make_scene("spheres", bad)
    for bad in (2.5, "10", True):
        with pytest.raises(ValueError):
            scenes.make_scene("spheres", bad)
    with pytest.raises(ValueError):
        scenes.make_scene("spheres", 10, sh_degree=4)
