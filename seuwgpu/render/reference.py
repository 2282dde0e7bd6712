"""The numpy twin of the whole renderer: the stage twins composed into full frames, and a naive
per-pixel twin of that (strict profile).

Each stage's twin lives beside its GPU wrapper (render/project.py `project`, render/sort.py
`stable_sort`, render/bin.py `emit` and `tile_ranges`, render/composite.py `composite_frame`),
declared with it as a `Stage` (render/stage.py) that takes and returns the kernel's buffers by
name, and follows docs/renderer.md to the letter, with gsplat's conventions, in float32
arithmetic. Run in PIPELINE's order here, they give `render_view` / `render`, against which
tests compare the GPU image (PSNR >= 50 dB) and the benchmark reports a speed ratio. NaN and Inf
are ordinary inputs: a corrupted parameter takes the path the rules define (culling of a
non-finite depth or screen mean, the "unbounded footprint" sheet for a non-finite 2-D
covariance, saturating tile rectangles, NaN-propagating alpha, ...).

`render_view_naive` is a plain per-pixel Python loop over numpy float32 scalars, with its own
per-primitive scalar projection: obviously correct and slow (tiny images only). The vectorised
twin equals it bit for bit (tests/test_reference.py).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.constants import TILE
from seuwgpu.model.cameras import Camera
from seuwgpu.model.fields import Model
from seuwgpu.model.sh import SH_C0, SH_C1, SH_C2, SH_C3
from seuwgpu.render.composite import ALPHA_MAX, ALPHA_MIN, T_MIN
from seuwgpu.render.pipeline import run_twins
from seuwgpu.render.project import (
    EXTENT,
    FAR,
    NEAR,
    F,
    camera_params,
    cov2d,
    exp_f32,
    jacobian_limits,
    n_tiles_xy,
)


def render_view(model: Model, cam: Camera, background=(1.0, 1.0, 1.0), profile: str = "strict") -> np.ndarray:
    """Float32 image [H, W, 3] (unclamped) of one view: the twins of PIPELINE's stages in order,
    under a renderer profile (docs/renderer.md)."""
    TX, TY = n_tiles_xy(cam)
    with np.errstate(all="ignore"):
        out = run_twins(
            model=model,
            view=cam,
            profile=profile,
            tiles_x=TX,
            n_tiles=TX * TY,
            exact_binning=True,
            width=cam.width,
            height=cam.height,
            background=background,
        )
    return out["image"].reshape(cam.height, cam.width, 4)[..., :3].copy()


def render(model: Model, cams: list[Camera], background=(1.0, 1.0, 1.0), profile: str = "strict") -> np.ndarray:
    """Float32 images [K, H, W, 3] (unclamped), one per camera (cameras share a size)."""
    if isinstance(cams, Camera):
        cams = [cams]
    return np.stack([render_view(model, c, background, profile) for c in cams])


# ---------------------------------------------------------------------------------------------
# Naive reference: per-primitive scalar projection, per-pixel loop (tiny scenes only)
# ---------------------------------------------------------------------------------------------


def _finite(x) -> bool:
    return bool(np.isfinite(x))


def _naive_project_one(model: Model, i: int, cam: Camera, TX: int, TY: int):
    """Scalar projection of primitive i; None if culled, else (z, mx, my, conic, o, rgb, rect)."""
    R, t, fx, fy, cx, cy, campos = camera_params(cam)
    lxp, lxn, lyp, lyn = jacobian_limits(cam, fx, fy, cx, cy)
    m = model.means[i]
    p = [((R[r, 0] * m[0] + R[r, 1] * m[1]) + R[r, 2] * m[2]) + t[r] for r in range(3)]
    x, y, z = p
    if not _finite(z) or z < NEAR or z > FAR:
        return None
    rz = F(1) / z
    mx = (fx * x) * rz + cx
    my = (fy * y) * rz + cy
    if not (_finite(mx) and _finite(my)):
        return None
    s = [exp_f32(model.log_scales[i, k]) for k in range(3)]
    qw, qx, qy, qz = model.quats[i]
    inq = F(1) / np.sqrt(((qw * qw + qx * qx) + qy * qy) + qz * qz)
    qw, qx, qy, qz = qw * inq, qx * inq, qy * inq, qz * inq
    one, two = F(1), F(2)
    Rq = [
        [one - two * (qy * qy + qz * qz), two * (qx * qy - qw * qz), two * (qx * qz + qw * qy)],
        [two * (qx * qy + qw * qz), one - two * (qx * qx + qz * qz), two * (qy * qz - qw * qx)],
        [two * (qx * qz - qw * qy), two * (qy * qz + qw * qx), one - two * (qx * qx + qy * qy)],
    ]

    def mm(A, B):
        return [
            [sum_lr([A[r][k] * B[k][col] for k in range(len(B))]) for col in range(len(B[0]))] for r in range(len(A))
        ]

    def tr(A):
        return [list(col) for col in zip(*A)]

    Wm = [[R[r, k] for k in range(3)] for r in range(3)]
    txc = z * min_nan(lxp, max_nan(-lxn, x * rz))
    tyc = z * min_nan(lyp, max_nan(-lyn, y * rz))
    zero = F(0)
    J = [[fx * rz, zero, ((-fx * txc) * rz) * rz], [zero, fy * rz, ((-fy * tyc) * rz) * rz]]
    JWR = mm(J, mm(Wm, Rq))
    t1 = np.array([JWR[0][k] * s[k] for k in range(3)], dtype=F)
    t2 = np.array([JWR[1][k] * s[k] for k in range(3)], dtype=F)
    a, b, c, det = (F(v) for v in cov2d(t1, t2))
    if not (_finite(a) and _finite(b) and _finite(c) and _finite(det)):
        conic = (zero, zero, zero)
        rect = (0, 0, TX, TY)
    else:
        if not det > 0 or a < 0 or c < 0:
            return None
        conic = (c / det, -b / det, a / det)
        rx = np.ceil(EXTENT * np.sqrt(a))
        ry = np.ceil(EXTENT * np.sqrt(c))

        def clampf(v, hi):
            return int(min(max(v, F(0)), F(hi)))

        rect = (
            clampf(np.floor((mx - rx) / F(TILE)), TX),
            clampf(np.floor((my - ry) / F(TILE)), TY),
            clampf(np.ceil((mx + rx) / F(TILE)), TX),
            clampf(np.ceil((my + ry) / F(TILE)), TY),
        )
        if rect[2] <= rect[0] or rect[3] <= rect[1]:
            return None
    lg = model.opacity[i]
    if np.isnan(lg):
        o = lg
    elif lg >= 0:
        o = one / (one + exp_f32(-lg))
    else:
        e = exp_f32(lg)
        o = e / (one + e)
    # colour: scalar SH
    d = [m[k] - campos[k] for k in range(3)]
    ind = F(1) / np.sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2])
    dx_, dy_, dz_ = d[0] * ind, d[1] * ind, d[2] * ind
    basis = _naive_sh_basis(dx_, dy_, dz_, model.sh_degree)
    rgb = []
    for ch in range(3):
        v = basis[0] * model.sh_dc[i, ch]
        for k in range(1, len(basis)):
            v = v + basis[k] * model.sh_rest[i, k - 1, ch]
        v = v + F(0.5)
        rgb.append(v if np.isnan(v) else max(v, F(0)))
    return z, mx, my, conic, o, rgb, rect


def sum_lr(terms):
    acc = terms[0]
    for v in terms[1:]:
        acc = acc + v
    return acc


def min_nan(a, b):
    return a if np.isnan(a) else (b if np.isnan(b) else min(a, b))


def max_nan(a, b):
    return a if np.isnan(a) else (b if np.isnan(b) else max(a, b))


def _naive_sh_basis(x, y, z, degree):
    b = [SH_C0]
    if degree >= 1:
        b += [-(SH_C1 * y), SH_C1 * z, -(SH_C1 * x)]
    if degree >= 2:
        b += [
            SH_C2[0] * (x * y),
            SH_C2[1] * (y * z),
            SH_C2[2] * ((F(2) * (z * z) - x * x) - y * y),
            SH_C2[3] * (x * z),
            SH_C2[4] * (x * x - y * y),
        ]
    if degree >= 3:
        xx, yy, zz = x * x, y * y, z * z
        b += [
            (SH_C3[0] * y) * (F(3) * xx - yy),
            (SH_C3[1] * (x * y)) * z,
            (SH_C3[2] * y) * ((F(4) * zz - xx) - yy),
            (SH_C3[3] * z) * ((F(2) * zz - F(3) * xx) - F(3) * yy),
            (SH_C3[4] * x) * ((F(4) * zz - xx) - yy),
            (SH_C3[5] * z) * (xx - yy),
            (SH_C3[6] * x) * (xx - F(3) * yy),
        ]
    return b


def render_view_naive(model: Model, cam: Camera, background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Obviously-correct per-pixel loop (pure Python over float32 scalars). Tiny scenes only."""
    bg = [F(v) for v in background]
    W, H = cam.width, cam.height
    TX, TY = n_tiles_xy(cam)
    img = np.empty((H, W, 3), dtype=F)
    with np.errstate(all="ignore"):
        prims = []
        for i in range(model.n):
            pr = _naive_project_one(model, i, cam, TX, TY)
            if pr is not None:
                prims.append((pr[0], i, pr))
        prims.sort(key=lambda e: (float(e[0]), e[1]))  # depth, then index
        for yy in range(H):
            for xx in range(W):
                tile_x, tile_y = xx // TILE, yy // TILE
                px, py = F(xx) + F(0.5), F(yy) + F(0.5)
                T = F(1)
                C = [F(0), F(0), F(0)]
                for _, _, (_z, mx, my, conic, o, rgb, rect) in prims:
                    if not (rect[0] <= tile_x < rect[2] and rect[1] <= tile_y < rect[3]):
                        continue
                    dx, dy = mx - px, my - py
                    sigma = F(0.5) * ((conic[0] * dx) * dx + (conic[2] * dy) * dy) + (conic[1] * dx) * dy
                    if sigma < 0:
                        continue
                    a = o * exp_f32(-sigma)
                    alpha = a if np.isnan(a) else min(ALPHA_MAX, a)
                    if alpha < ALPHA_MIN:
                        continue
                    next_T = T * (F(1) - alpha)
                    if next_T <= T_MIN:
                        break
                    vis = alpha * T
                    C = [C[k] + rgb[k] * vis for k in range(3)]
                    T = next_T
                img[yy, xx] = [C[k] + T * bg[k] for k in range(3)]
    return img
