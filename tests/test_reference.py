"""The numpy twin (render/reference.py composing the stage twins) against its naive per-pixel
twin, and the projection twin (render/project.py) against hand-checkable cases of docs/renderer.md."""

import numpy as np
import pytest

from seuwgpu.model import encoding
from seuwgpu.model.cameras import Camera, orbit_cameras
from seuwgpu.model.fields import Model
from seuwgpu.render import reference as ref
from seuwgpu.render.project import project, quat_to_rotmat, sh_basis, sh_to_rgb, sigmoid
from seuwgpu.render.sort import depth_order

F = np.float32


def pinhole(width, height, f, cx=None, cy=None, viewmat=None):
    cx = width / 2 if cx is None else cx
    cy = height / 2 if cy is None else cy
    K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]
    return Camera(np.eye(4) if viewmat is None else viewmat, K, width, height)


def prims(means, log_scales=-3.0, quats=(1, 0, 0, 0), opacity=0.0, rgb=(0.2, 0.6, 0.9), degree=0, sh_rest=None):
    """Model from per-primitive values (scalars broadcast); rgb sets sh_dc so that the
    degree-0 colour is rgb."""
    means = np.atleast_2d(np.asarray(means, dtype=np.float64))
    n = means.shape[0]
    ls = np.broadcast_to(np.asarray(log_scales, dtype=np.float64), (n, 3))
    q = np.broadcast_to(np.asarray(quats, dtype=np.float64), (n, 4))
    op = np.broadcast_to(np.asarray(opacity, dtype=np.float64), (n,))
    dc = (np.broadcast_to(np.asarray(rgb, dtype=np.float64), (n, 3)) - 0.5) / 0.28209479177387814
    r = (degree + 1) ** 2 - 1
    rest = np.zeros((n, r, 3)) if sh_rest is None else np.broadcast_to(sh_rest, (n, r, 3))
    return Model(means=means, log_scales=ls, quats=q, opacity=op, sh_dc=dc, sh_rest=rest)


def composite_one(rgb, alpha, bg=1.0):
    """Expected pixel for a single contribution at T = 1, in float32 as the rules compute it."""
    rgb = np.asarray(rgb, dtype=F)
    alpha = F(alpha)
    return rgb * (alpha * F(1)) + (F(1) - alpha) * F(bg)


def sigmoid32(x):
    x = F(x)
    if x >= 0:
        return F(1) / (F(1) + np.exp(-x))
    e = np.exp(x)
    return e / (F(1) + e)


def random_scene(rng, n, degree, spread=0.8):
    r = (degree + 1) ** 2 - 1
    return Model(
        means=rng.normal(0, spread, (n, 3)),
        log_scales=rng.uniform(-4, -1.2, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        opacity=rng.normal(0.5, 2, n),
        sh_dc=rng.normal(0, 1, (n, 3)),
        sh_rest=rng.normal(0, 0.3, (n, r, 3)),
    )


SPECIAL = np.array([np.nan, np.inf, -np.inf, 100, -100, 1e30, -1e30, 0, 45, 20, 12, 1e20, -0.0], dtype=F)


def corrupt(rng, model, n_special=4, n_flips=4):
    flat = model.flat()
    for _ in range(n_special):
        flat[rng.integers(model.n), rng.integers(flat.shape[1])] = SPECIAL[rng.integers(len(SPECIAL))]
    bits = encoding.to_bits(flat, "fp32").reshape(-1)
    for _ in range(n_flips):
        k = rng.integers(bits.size)
        bits[k] = encoding.flip_bits(bits[k], int(rng.integers(20, 32)), "fp32")
    return Model.from_flat(encoding.from_bits(bits, "fp32").reshape(flat.shape), model.sh_degree)


# ---------------------------------------------------------------------------------------------
# vectorised == naive
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(16))
def test_vectorised_matches_naive_on_corrupted_scenes(seed):
    rng = np.random.default_rng(seed)
    degree = seed % 4
    model = corrupt(rng, random_scene(rng, int(rng.integers(20, 51)), degree, spread=0.8 + seed % 3))
    size = [(32, 24), (20, 13), (32, 32), (17, 30)][seed % 4]
    cam = orbit_cameras(5, *size, radius=3.0 + seed % 2)[seed % 5]
    fast = ref.render_view(model, cam)
    slow = ref.render_view_naive(model, cam)
    assert fast.dtype == np.float32 and fast.shape == (size[1], size[0], 3)
    # The vectorised recurrences are sequential float32: the images agree bit for bit.
    np.testing.assert_array_equal(fast, slow)


@pytest.mark.parametrize("precision", ["fp16", "bf16"])
def test_vectorised_matches_naive_on_quantized_models(precision):
    rng = np.random.default_rng(7)
    model = corrupt(rng, random_scene(rng, 40, 3)).quantized(precision)
    cam = orbit_cameras(2, 24, 24, radius=3.0)[1]
    np.testing.assert_array_equal(ref.render_view(model, cam), ref.render_view_naive(model, cam))


def test_dense_scene_saturates_like_naive():
    # Many opaque primitives: exercises early stop across blocks and pixels stopping at different times.
    rng = np.random.default_rng(3)
    model = random_scene(rng, 50, 1, spread=0.3)
    model.opacity[:] = 6.0
    model.log_scales[:] = -1.5
    cam = orbit_cameras(1, 32, 32, radius=2.5)[0]
    fast = ref.render_view(model, cam)
    np.testing.assert_array_equal(fast, ref.render_view_naive(model, cam))
    assert (fast < 0.9).all(axis=-1).mean() > 0.3


def test_render_batches_views_and_background():
    rng = np.random.default_rng(5)
    model = random_scene(rng, 30, 2)
    cams = orbit_cameras(3, 24, 16)
    imgs = ref.render(model, cams)
    assert imgs.shape == (3, 16, 24, 3) and imgs.dtype == np.float32
    for k in range(3):
        np.testing.assert_array_equal(imgs[k], ref.render_view(model, cams[k]))
    empty = prims([[0, 0, -5.0]])
    np.testing.assert_array_equal(ref.render(empty, cams[:1], background=(0, 0, 0)), 0)


# ---------------------------------------------------------------------------------------------
# hand-checkable cases
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("logit", [0.0, 10.0, -2.0])
def test_isotropic_gaussian_at_image_centre(logit):
    # 33x33 image with the principal point at a pixel centre: pixel (16, 16) is the peak.
    f, z, s = 40.0, 2.0, 0.05
    cam = pinhole(33, 33, f, cx=16.5, cy=16.5)
    model = prims([[0, 0, z]], log_scales=np.log(s), opacity=logit, rgb=(0.2, 0.6, 0.9))
    p = project(model, cam)
    assert p["visible"][0] and not p["unbounded"][0]
    a_expect = (f * s / z) ** 2 + 0.3
    np.testing.assert_allclose(p["cov2d"][0], [a_expect, 0, a_expect], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(p["proj_xy"][0], [16.5, 16.5])
    r = np.ceil(3.33 * np.sqrt(a_expect))
    assert tuple(p["rect"][0]) == (
        int(np.floor((16.5 - r) / 16)),
        int(np.floor((16.5 - r) / 16)),
        int(np.ceil((16.5 + r) / 16)),
        int(np.ceil((16.5 + r) / 16)),
    )
    img = ref.render_view(model, cam)
    alpha = min(F(0.99), sigmoid32(logit))
    np.testing.assert_array_equal(img[16, 16], composite_one(p["rgb"][0], alpha))
    np.testing.assert_allclose(img[16, 16], np.array([0.2, 0.6, 0.9]) * alpha + (1 - alpha), rtol=1e-6)
    # one pixel to the right: sigma = 0.5 / a
    a1 = min(0.99, sigmoid32(logit) * np.exp(-0.5 / a_expect))
    np.testing.assert_allclose(img[16, 17], np.array([0.2, 0.6, 0.9]) * a1 + (1 - a1), rtol=1e-5)
    # radial symmetry and white far away
    np.testing.assert_allclose(img[16, 17], img[16, 15], rtol=1e-6)
    np.testing.assert_allclose(img[15, 16], img[17, 16], rtol=1e-6)
    np.testing.assert_array_equal(img[0, 0], 1.0)


def test_pixel_centre_convention():
    # fx = 32, cx = 16, z = 1: mean x = -5.5/32 lands on mx = 10.5, the centre of pixel column 10.
    cam = pinhole(32, 32, 32.0)
    model = prims([[-5.5 / 32, (7.5 - 16) / 32, 1.0]], log_scales=-12.0, opacity=1.0, rgb=(0.1, 0.1, 0.1))
    p = project(model, cam)
    assert tuple(p["proj_xy"][0]) == (10.5, 7.5)
    img = ref.render_view(model, cam)
    peak = composite_one(p["rgb"][0], sigmoid32(1.0))
    np.testing.assert_array_equal(img[7, 10], peak)  # sigma = 0 exactly at the pixel centre
    np.testing.assert_array_equal(img[7, 9], img[7, 11])
    np.testing.assert_array_equal(img[6, 10], img[8, 10])
    np.testing.assert_allclose(img[7, 9], img[6, 10], rtol=1e-5)
    assert (img[7, 9] > peak).all()
    lum = img.sum(-1)
    assert np.unravel_index(np.argmin(lum), lum.shape) == (7, 10)


@pytest.mark.parametrize("z", [-2.0, 0.0, 0.009, 2e10])
def test_culled_by_depth_draws_nothing(z):
    cam = pinhole(32, 32, 32.0)
    model = prims([[0, 0, z]], log_scales=2.0, opacity=5.0)
    p = project(model, cam)
    assert not p["visible"][0] and p["n_tiles"][0] == 0
    np.testing.assert_array_equal(ref.render_view(model, cam), 1.0)


def test_near_plane_is_inclusive():
    cam = pinhole(32, 32, 32.0)
    model = prims([[0, 0, 0.01]], log_scales=-8.0, opacity=5.0)
    assert project(model, cam)["visible"][0]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_mean_draws_nothing(bad):
    cam = pinhole(32, 32, 32.0)
    for k in range(3):
        mean = [0.1, -0.1, 2.0]
        mean[k] = bad
        model = prims([mean, [0.0, 0.0, 3.0]], log_scales=[[-2.0] * 3, [-9.0] * 3], opacity=3.0)
        model.opacity[1] = -50.0  # an invisible companion: the image must be exactly white
        p = project(model, cam)
        assert not p["visible"][0]
        np.testing.assert_array_equal(ref.render_view(model, cam), 1.0)


def test_behind_camera_in_orbit_view():
    cam = orbit_cameras(1, 32, 32, radius=4.0)[0]
    eye = cam.position
    model = prims([eye + (eye - 0) * 0.5], log_scales=0.0, opacity=5.0)  # behind the eye
    np.testing.assert_array_equal(ref.render_view(model, cam), 1.0)


@pytest.mark.parametrize("log_scales", [(100.0, -3.0, -3.0), (100.0, 100.0, 100.0), (-3.0, -3.0, np.inf)])
def test_overflowing_scale_is_the_frame_covering_sheet(log_scales):
    cam = pinhole(40, 24, 30.0)
    model = prims([[0.3, -0.2, 3.0]], log_scales=log_scales, opacity=0.5, rgb=(0.9, 0.1, 0.4))
    p = project(model, cam)
    assert p["visible"][0] and p["unbounded"][0]
    np.testing.assert_array_equal(p["conic"][0], 0)
    assert tuple(p["rect"][0]) == (0, 0, 3, 2) and p["n_tiles"][0] == 6
    img = ref.render_view(model, cam)
    expect = composite_one(p["rgb"][0], min(F(0.99), sigmoid32(0.5)))
    np.testing.assert_array_equal(img, np.broadcast_to(expect, img.shape))


def test_sheet_with_far_off_screen_centre_is_still_a_sheet():
    # mean2d ~ 3e21: dx*dx overflows, but sigma = 0.5*((0*dx)*dx + ...) = 0 (left to right).
    cam = pinhole(32, 32, 32.0)
    model = prims([[1e20, 0.0, 1.0]], log_scales=100.0, opacity=2.0)
    p = project(model, cam)
    assert p["visible"][0] and p["unbounded"][0] and np.isfinite(p["proj_xy"][0]).all()
    img = ref.render_view(model, cam)
    expect = composite_one(p["rgb"][0], sigmoid32(2.0))
    np.testing.assert_array_equal(img, np.broadcast_to(expect, img.shape))


def test_huge_finite_scale_saturates_rect_not_unbounded():
    cam = pinhole(48, 32, 40.0)
    model = prims([[0.0, 0.0, 2.0]], log_scales=15.0, opacity=0.0)
    p = project(model, cam)
    assert p["visible"][0] and not p["unbounded"][0]
    assert tuple(p["rect"][0]) == (0, 0, 3, 2)
    img = ref.render_view(model, cam)
    np.testing.assert_allclose(img, np.broadcast_to(composite_one(p["rgb"][0], 0.5), img.shape), rtol=1e-6)


def test_zero_quaternion_is_unbounded():
    # No special case: q / |q| = NaN, so the covariance is NaN and the footprint unbounded.
    cam = pinhole(32, 32, 32.0)
    model = prims([[0.0, 0.0, 2.0]], quats=(0, 0, 0, 0), opacity=0.0)
    p = project(model, cam)
    assert p["visible"][0] and p["unbounded"][0]
    assert np.isfinite(ref.render_view(model, cam)).all()


def test_off_screen_small_primitive_is_culled():
    cam = pinhole(32, 32, 32.0)
    model = prims([[10.0, 0.0, 1.0], [1e30, 0.0, 1.0]], log_scales=-5.0)
    p = project(model, cam)
    assert not p["visible"].any() and (p["n_tiles"] == 0).all() and (p["rect"] == 0).all()


def test_nan_opacity_gives_nan_exactly_inside_its_rect():
    # Rect gating made visible: NaN * exp(-sigma) is NaN on every pixel of every tile of the rect,
    # however far from the centre, and on no other pixel.
    cam = pinhole(64, 64, 64.0)
    model = prims([[0.0, 0.0, 2.0], [-0.8, -0.8, 2.5]], log_scales=np.log(0.02), opacity=[np.nan, 1.0])
    p = project(model, cam)
    assert p["visible"].all()
    img = ref.render_view(model, cam)
    x0, y0, x1, y1 = p["rect"][0]
    inside = np.zeros((64, 64), bool)
    inside[16 * y0 : 16 * y1, 16 * x0 : 16 * x1] = True
    assert 0 < inside.sum() < inside.size
    np.testing.assert_array_equal(np.isnan(img).any(-1), inside)
    np.testing.assert_array_equal(np.isnan(img).all(-1), inside)
    assert np.isfinite(img[~inside]).all() and (img[~inside] < 1).any()


def test_inf_colour_reaches_the_pixels():
    cam = pinhole(48, 48, 48.0)
    finite = prims([[0.05, 0.0, 2.0]], log_scales=np.log(0.05), opacity=1.0, rgb=(0.3, 0.3, 0.3))
    touched = (ref.render_view(finite, cam) != 1.0).any(-1)
    assert touched.sum() > 4
    for ch in range(3):
        m = finite.copy()
        m.sh_dc[0, ch] = np.inf
        img = ref.render_view(m, cam)
        assert not np.isnan(img).any()
        np.testing.assert_array_equal(np.isposinf(img[..., ch]), touched)
        assert np.isfinite(np.delete(img, ch, axis=-1)).all()
        m.sh_dc[0, ch] = -np.inf  # -> colour 0: finite, darker
        img = ref.render_view(m, cam)
        assert np.isfinite(img).all() and (img[..., ch][touched] < 1).all()


def test_early_stop_drops_the_contribution_that_crosses_the_threshold():
    # Two alpha = 0.99 layers: T = 1 - 0.99 = 0.0099999905, next_T = 9.9999e-5 <= 1e-4 -> stop.
    cam = pinhole(33, 33, 33.0, cx=16.5, cy=16.5)
    model = prims([[0, 0, 1.0], [0, 0, 2.0]], log_scales=-1.0, opacity=12.0, rgb=[(1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
    img = ref.render_view(model, cam)
    p = project(model, cam)
    np.testing.assert_array_equal(img[16, 16], composite_one(p["rgb"][0], 0.99))
    assert img[16, 16, 1] == F(1) - F(0.99)  # nothing of the green layer
    np.testing.assert_array_equal(img, ref.render_view_naive(model, cam))


def test_depth_order_then_index_order():
    cam = pinhole(33, 33, 33.0, cx=16.5, cy=16.5)
    red, green = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    for rgbs in ([red, green], [green, red]):
        tie = prims([[0, 0, 2.0], [0, 0, 2.0]], log_scales=-2.0, opacity=3.0, rgb=rgbs)
        img = ref.render_view(tie, cam)
        assert np.argmax(img[16, 16]) == np.argmax(rgbs[0])  # same depth: lower index in front
        order = prims([[0, 0, 2.0], [0, 0, 1.5]], log_scales=-2.0, opacity=3.0, rgb=rgbs)
        img = ref.render_view(order, cam)
        assert np.argmax(img[16, 16]) == np.argmax(rgbs[1])  # nearer one in front
    p = project(prims([[0, 0, 3.0], [0, 0, 1.0], [0, 0, 3.0], [0, 0, 2.0]]), cam)
    np.testing.assert_array_equal(depth_order(p), [1, 3, 0, 2])


# ---------------------------------------------------------------------------------------------
# spherical harmonics
# ---------------------------------------------------------------------------------------------


def test_stable_sigmoid():
    x = np.array([np.nan, np.inf, -np.inf, 0, 100, -100, -200, 3, -3], F)
    with np.errstate(all="ignore"):
        o = sigmoid(x)
    assert o.dtype == np.float32 and np.isnan(o[0])
    np.testing.assert_array_equal(o[1:4], [1, 0, 0.5])
    assert o[4] == 1 and o[5] == 0 and o[6] == 0  # exp(-100) is flushed (rule 4)
    np.testing.assert_allclose(o[7:], 1 / (1 + np.exp(-x[7:].astype(np.float64))), rtol=1e-7)
    assert o[8] == sigmoid32(-3.0)


def test_normalisation_edge_cases():
    with np.errstate(all="ignore"):
        # squared norm overflows: q * rsqrt(Inf) = 0 -> identity rotation (gsplat's CUDA kernel)
        R = quat_to_rotmat(np.array([[3e19, 1e19, 0, 0], [0, 0, 0, 0], [np.nan, 0, 0, 1]], F))
    np.testing.assert_array_equal(R[0], np.eye(3))
    assert np.isnan(R[1]).all() and np.isnan(R[2]).any()


def test_sh_basis_is_orthonormal():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(400_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    B = sh_basis(d.astype(F), 3).astype(np.float64)
    gram = 4 * np.pi * B.T @ B / len(d)
    np.testing.assert_allclose(gram, np.eye(16), atol=0.03)


def test_sh_basis_signs_match_inria():
    C1 = 0.4886025119029199
    B = sh_basis(np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], F), 3)
    np.testing.assert_allclose(B[:, 1:4], [[0, 0, -C1], [-C1, 0, 0], [0, C1, 0]], atol=1e-7)
    np.testing.assert_allclose(B[2, 6], 2 * 0.31539156525252005, rtol=1e-6)
    np.testing.assert_allclose(B[2, 12], 2 * 0.3731763325901154, rtol=1e-6)
    np.testing.assert_allclose(B[0, 15], -0.5900435899266435, rtol=1e-6)


def test_sh_to_rgb_sums_basis_and_clamps():
    rng = np.random.default_rng(1)
    for degree in range(4):
        r = (degree + 1) ** 2 - 1
        dc = rng.normal(size=(50, 3)).astype(F)
        rest = rng.normal(size=(50, r, 3)).astype(F)
        dirs = rng.normal(size=(50, 3)).astype(F) * 3
        got = sh_to_rgb(dc, rest, dirs)
        unit = dirs / np.linalg.norm(dirs.astype(np.float64), axis=1, keepdims=True)
        B = sh_basis(unit.astype(F), degree).astype(np.float64)
        coeffs = np.concatenate([dc[:, None], rest], axis=1).astype(np.float64)
        want = np.maximum(np.einsum("nk,nkc->nc", B, coeffs) + 0.5, 0)
        np.testing.assert_allclose(got, want, atol=2e-5)
    rgb = sh_to_rgb(np.array([[np.nan, -np.inf, np.inf]], F), np.zeros((1, 0, 3), F), np.ones((1, 3), F))
    assert np.isnan(rgb[0, 0]) and rgb[0, 1] == 0 and np.isposinf(rgb[0, 2])


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_view_dependence_only_above_degree_zero(degree):
    rng = np.random.default_rng(degree)
    r = (degree + 1) ** 2 - 1
    model = prims([[0.0, 0.0, 0.0]], log_scales=-2.0, opacity=2.0, degree=degree, sh_rest=rng.normal(0, 0.4, (r, 3)))
    cams = orbit_cameras(4, 33, 33)
    cols = np.stack([project(model, c)["rgb"][0] for c in cams])
    imgs = ref.render(model, cams)
    if degree == 0:
        assert (cols == cols[0]).all()
        np.testing.assert_allclose(imgs[:, 16, 16], np.broadcast_to(imgs[0, 16, 16], (4, 3)), rtol=1e-5)
    else:
        assert np.ptp(cols, axis=0).max() > 1e-2
        assert np.ptp(imgs[:, 16, 16], axis=0).max() > 1e-3


# ---------------------------------------------------------------------------------------------
# projection against independent constructions
# ---------------------------------------------------------------------------------------------


def test_quaternion_convention():
    th = 0.7
    R = quat_to_rotmat(np.array([[np.cos(th / 2), 0, 0, np.sin(th / 2)], [2.0, 0, 0, 0]], F))
    np.testing.assert_allclose(R[0], [[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]], atol=1e-6)
    np.testing.assert_allclose(R[1], np.eye(3), atol=1e-7)  # normalised, not assumed unit


def test_ewa_covariance_matches_sampled_projection():
    # Sample points of a small 3-D Gaussian, project them exactly through the pinhole: their
    # screen covariance is the EWA cov2d (minus the 0.3 px dilation) to first order.
    rng = np.random.default_rng(11)
    cam = orbit_cameras(3, 64, 48, radius=4.0)[1]
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    model = prims([[0.3, -0.2, 0.4]], log_scales=np.log([0.05, 0.015, 0.03]), quats=q)
    p = project(model, cam)
    Rq = quat_to_rotmat(model.quats).astype(np.float64)[0]
    X = model.means[0].astype(np.float64) + (rng.normal(size=(400_000, 3)) * np.exp(model.log_scales[0])) @ Rq.T
    V = cam.viewmat.astype(np.float64)
    P = X @ V[:3, :3].T + V[:3, 3]
    K = cam.K.astype(np.float64)
    uv = np.stack([K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2], K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]], 1)
    emp = np.cov(uv.T)
    a, b, c = p["cov2d"][0]
    np.testing.assert_allclose(
        [a - 0.3, b, c - 0.3], [emp[0, 0], emp[0, 1], emp[1, 1]], rtol=0.03, atol=0.03 * np.sqrt(emp[0, 0] * emp[1, 1])
    )
    np.testing.assert_allclose(p["proj_xy"][0], uv.mean(0), atol=0.05)
    a_, b_, c_ = a, b, c
    det = a_ * c_ - b_ * b_
    np.testing.assert_allclose(p["conic"][0], [c_ / det, -b_ / det, a_ / det], rtol=1e-5)


def test_jacobian_clamped_beyond_the_frame():
    # A primitive far to the right of the frame: its J uses tx clamped at lim_x_pos * z.
    f, W, H, z = 32.0, 32, 32, 2.0
    cam = pinhole(W, H, f)
    x = 3.0  # x/z = 1.5 > lim_x_pos = (32-16)/32 + 0.3*0.5 = 0.65
    model = prims([[x, 0.0, z]], log_scales=np.log(0.5))
    p = project(model, cam)
    s2 = 0.25
    tx = z * 0.65
    J0 = np.array([f / z, 0, -f * tx / z**2])
    a = J0 @ (s2 * np.eye(3)) @ J0 + 0.3
    np.testing.assert_allclose(p["cov2d"][0, 0], a, rtol=1e-5)
    np.testing.assert_allclose(p["proj_xy"][0, 0], f * x / z + W / 2, rtol=1e-6)


def test_needles_are_never_culled_by_cancellation():
    """A log-scale flipped to a large positive value makes a needle; its 2-D determinant must not
    be lost to float32 cancellation (a*c - b*b), or culling would depend on the device's FMAs."""
    from seuwgpu.model.cameras import orbit_cameras
    from seuwgpu.model.fields import Model
    from seuwgpu.render.renderer import Renderer

    rng = np.random.default_rng(21)
    n = 400
    ls = rng.uniform(-6, -4, (n, 3)).astype(np.float32)
    ls[np.arange(n), rng.integers(0, 3, n)] = rng.uniform(4, 20, n)  # one huge axis each
    m = Model(
        means=rng.uniform(-0.3, 0.3, (n, 3)),
        log_scales=ls,
        quats=rng.normal(size=(n, 4)),
        opacity=np.full(n, 2.0),
        sh_dc=rng.normal(size=(n, 3)),
        sh_rest=np.zeros((n, 0, 3)),
    )
    cam = orbit_cameras(1, 64, 64)[0]
    pr = project(m, cam)
    finite = ~pr["unbounded"]
    assert finite.sum() > n // 2
    assert pr["visible"][finite].all()
    det_ok = pr["conic"][finite]
    assert np.isfinite(det_ok).all()
    # the GPU draws the same needles: one intersection list entry per touched tile, none culled
    r = Renderer(m, [cam], keep_views=True)
    r.capture_views = True
    r.render()
    rects = r.gpu.read(r.kv_proj_rect, np.uint32, 0, 8 * n).reshape(n, 2)
    assert (rects[:, 1] != 0).all()
