"""CPU reference renderer (numpy): the independent twin of the WGSL renderer.

It follows docs/renderer.md to the letter, with gsplat's conventions, in float32 arithmetic, so
that tests can compare the GPU image against it (PSNR >= 50 dB) and the benchmark can report a
speed ratio. NaN and Inf are ordinary inputs here: a corrupted parameter takes the path the rules
define (culling of a non-finite depth or screen mean, the "unbounded footprint" sheet for a
non-finite 2-D covariance, saturating tile rectangles, NaN-propagating alpha, ...).

Two renderers:
- `render_view`: vectorised. Per 16x16 tile, over the tile's pixels, walking the tile's
  depth-sorted primitive list in blocks. The transmittance and colour recurrences use
  `np.multiply.accumulate` / `np.add.accumulate`, which are strictly sequential in float32, so
  the result is the same, bit for bit, as the per-pixel loop `T = T * (1 - alpha)`,
  `C = C + rgb * (alpha * T)` with the early stop evaluated on every step.
- `render_view_naive`: a plain per-pixel Python loop over numpy float32 scalars, with its own
  per-primitive scalar projection; obviously correct and slow (tiny images only).

Floating-point operation order (the GPU should use the same; the order only matters at the
last bit, or where 0 * Inf decides between a finite value and NaN):
- matrix products are full 3x3 / 2x3 products (zeros of J included), each entry summed
  left to right: (a0*b0 + a1*b1) + a2*b2;
- p = R @ mean + t; rz = 1 / p.z; mx = (fx * p.x) * rz + cx (gsplat's form of fx * p.x / p.z);
  tx = p.z * min(lim_x_pos, max(-lim_x_neg, p.x * rz)); J = [[fx*rz, 0, ((-fx*tx)*rz)*rz], ...];
- quaternion normalised as q * rsqrt(((w*w + x*x) + y*y) + z*z) with rsqrt(v) = 1 / sqrt(v)
  (rsqrt(0) = +Inf, rsqrt(+Inf) = 0); rotation matrix as gsplat's quat_to_rotmat;
  T = (J @ (W @ R)) * diag(s) (2x3: T[i,k] = (J W R)[i,k] * s[k]), rows t1, t2;
- SH direction d * rsqrt(((dx*dx + dy*dy) + dz*dz)); opacity = the stable sigmoid of
  docs/renderer.md rule 8;
- aa = (t1.x*t1.x + t1.y*t1.y) + t1.z*t1.z (cc likewise for t2), b = t1.t2 in the same order,
  a = aa + 0.3, c = cc + 0.3; det = ((|t1 x t2|^2 + 0.3 * (aa + cc)) + 0.09) (Lagrange's identity:
  a*c - b*b would cancel catastrophically for needles); conic = (c/det, -b/det, a/det);
- sigma = 0.5 * ((conic.x*dx)*dx + (conic.z*dy)*dy) + (conic.y*dx)*dy with dx = mx - px
  (gsplat's left-to-right order: with conic = 0, sigma is 0 even where dx*dx overflows);
- C += rgb * (alpha * T) (gsplat's `vis = alpha * T`).

One rule docs/renderer.md leaves implicit: with finite a, b, c, det > 0, a or c may still be
negative (rounding in a huge covariance), which would make the radius sqrt(a) NaN. Such a
primitive is culled (its Gaussian is negative definite: sigma < 0 everywhere but its centre).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.model.cameras import Camera
from seuwgpu.model.fields import Model

TILE = 16

F = np.float32
NEAR = F(0.01)
FAR = F(1e10)
LOWPASS = F(0.3)
EXTENT = F(3.33)
ALPHA_MAX = F(0.99)
ALPHA_MIN = F(1.0 / 255.0)
T_MIN = F(1e-4)
CLIP = F(0.3)

# Real SH constants (INRIA's sh_utils / gsplat).
SH_C0 = F(0.28209479177387814)
SH_C1 = F(0.4886025119029199)
SH_C2 = tuple(
    F(v)
    for v in (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
)
SH_C3 = tuple(
    F(v)
    for v in (
        -0.5900435899266435,
        2.890611442640554,
        -0.4570457994644658,
        0.3731763325901154,
        -0.4570457994644658,
        1.445305721320277,
        -0.5900435899266435,
    )
)


def n_tiles_xy(cam: Camera) -> tuple[int, int]:
    return -(-cam.width // TILE), -(-cam.height // TILE)


def _cam_params(cam: Camera):
    K = cam.K
    fx, fy, cx, cy = F(K[0, 0]), F(K[1, 1]), F(K[0, 2]), F(K[1, 2])
    R = cam.viewmat[:3, :3].astype(F)
    t = cam.viewmat[:3, 3].astype(F)
    campos = cam.position.astype(F)  # computed in float64 from the float32 viewmat, then rounded
    return R, t, fx, fy, cx, cy, campos


def _lims(cam: Camera, fx, fy, cx, cy):
    W, H = F(cam.width), F(cam.height)
    tan_fov_x = (F(0.5) * W) / fx
    tan_fov_y = (F(0.5) * H) / fy
    lim_x_pos = (W - cx) / fx + CLIP * tan_fov_x
    lim_x_neg = cx / fx + CLIP * tan_fov_x
    lim_y_pos = (H - cy) / fy + CLIP * tan_fov_y
    lim_y_neg = cy / fy + CLIP * tan_fov_y
    return lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg


# ---------------------------------------------------------------------------------------------
# Spherical harmonics
# ---------------------------------------------------------------------------------------------


def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """Real SH basis values [N, (degree+1)^2] at unit directions [N, 3] (INRIA's signs and
    expressions; float32, operations in the order written)."""
    d = np.asarray(dirs, dtype=F)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    n = d.shape[0]
    out = np.empty((n, (degree + 1) ** 2), dtype=F)
    out[:, 0] = SH_C0
    if degree >= 1:
        out[:, 1] = -(SH_C1 * y)
        out[:, 2] = SH_C1 * z
        out[:, 3] = -(SH_C1 * x)
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        out[:, 4] = SH_C2[0] * xy
        out[:, 5] = SH_C2[1] * yz
        out[:, 6] = SH_C2[2] * ((F(2) * zz - xx) - yy)
        out[:, 7] = SH_C2[3] * xz
        out[:, 8] = SH_C2[4] * (xx - yy)
    if degree >= 3:
        out[:, 9] = (SH_C3[0] * y) * (F(3) * xx - yy)
        out[:, 10] = (SH_C3[1] * xy) * z
        out[:, 11] = (SH_C3[2] * y) * ((F(4) * zz - xx) - yy)
        out[:, 12] = (SH_C3[3] * z) * ((F(2) * zz - F(3) * xx) - F(3) * yy)
        out[:, 13] = (SH_C3[4] * x) * ((F(4) * zz - xx) - yy)
        out[:, 14] = (SH_C3[5] * z) * (xx - yy)
        out[:, 15] = (SH_C3[6] * x) * (xx - F(3) * yy)
    return out


def normalize_dirs(d: np.ndarray) -> np.ndarray:
    """d * rsqrt((x*x + y*y) + z*z) in float32 (NaN for a zero vector, 0 where the squared
    norm overflows)."""
    d = np.asarray(d, dtype=F)
    with np.errstate(all="ignore"):
        return d * rsqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])[:, None]


def rsqrt(v):
    """1 / sqrt(v) in float32: rsqrt(0) = +Inf, rsqrt(+Inf) = 0, NaN -> NaN."""
    with np.errstate(all="ignore"):
        return F(1) / np.sqrt(np.asarray(v, dtype=F))


def sigmoid(x):
    """Stable logistic (docs/renderer.md rule 8): 1 / (1 + exp(-x)) for x >= 0, else e / (1 + e)
    with e = exp(x); NaN stays NaN, sigmoid(+Inf) = 1, sigmoid(-Inf) = 0."""
    x = np.asarray(x, dtype=F)
    with np.errstate(all="ignore"):
        pos = F(1) / (F(1) + np.exp(-x))
        e = np.exp(x)
        neg = e / (F(1) + e)
        return np.where(x >= 0, pos, np.where(np.isnan(x), x, neg)).astype(F)


def sh_to_rgb(sh_dc, sh_rest, dirs, normalize: bool = True) -> np.ndarray:
    """Colour [N, 3] from SH: degree from sh_rest's shape ([N, R, 3], R in 0, 3, 8, 15),
    direction `dirs` (mean - campos; normalised here unless normalize=False).
    rgb = C0*dc + sum_k basis_k * sh_rest[k-1] (accumulated in order k = 1..R) + 0.5, then
    NaN-preserving max(rgb, 0)."""
    sh_dc = np.asarray(sh_dc, dtype=F).reshape(-1, 3)
    n = sh_dc.shape[0]
    sh_rest = np.asarray(sh_rest, dtype=F).reshape(n, -1, 3)
    r = sh_rest.shape[1]
    degree = {0: 0, 3: 1, 8: 2, 15: 3}[r]
    with np.errstate(all="ignore"):
        d = normalize_dirs(dirs) if normalize else np.asarray(dirs, dtype=F)
        basis = sh_basis(d, degree)
        res = basis[:, 0:1] * sh_dc
        for k in range(1, r + 1):
            res = res + basis[:, k : k + 1] * sh_rest[:, k - 1, :]
        rgb = res + F(0.5)
        return np.maximum(rgb, F(0))  # np.maximum propagates NaN; -Inf -> 0, +Inf stays


# ---------------------------------------------------------------------------------------------
# Projection (vectorised)
# ---------------------------------------------------------------------------------------------


def _mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Batched matrix product [N, i, k] @ [N, k, j] with each sum taken left to right."""
    out = A[:, :, 0, None] * B[:, None, 0, :]
    for k in range(1, A.shape[2]):
        out = out + A[:, :, k, None] * B[:, None, k, :]
    return out


def _cov2d(t1: np.ndarray, t2: np.ndarray):
    """(a, b, c, det) of T T^T + 0.3 I from the rows t1, t2 of T = J W R S, det by Lagrange's
    identity (no cancellation between a*c and b*b), each sum left to right as the shader does."""
    aa = (t1[..., 0] * t1[..., 0] + t1[..., 1] * t1[..., 1]) + t1[..., 2] * t1[..., 2]
    cc = (t2[..., 0] * t2[..., 0] + t2[..., 1] * t2[..., 1]) + t2[..., 2] * t2[..., 2]
    b = (t1[..., 0] * t2[..., 0] + t1[..., 1] * t2[..., 1]) + t1[..., 2] * t2[..., 2]
    x0 = t1[..., 1] * t2[..., 2] - t1[..., 2] * t2[..., 1]
    x1 = t1[..., 2] * t2[..., 0] - t1[..., 0] * t2[..., 2]
    x2 = t1[..., 0] * t2[..., 1] - t1[..., 1] * t2[..., 0]
    det = (((x0 * x0 + x1 * x1) + x2 * x2) + LOWPASS * (aa + cc)) + F(0.09)
    return aa + LOWPASS, b, cc + LOWPASS, det


def quat_to_rotmat(quats: np.ndarray) -> np.ndarray:
    """[N, 4] (w, x, y, z) -> [N, 3, 3] rotation of q / |q| (gsplat's formula, no special case)."""
    q = np.asarray(quats, dtype=F)
    with np.errstate(all="ignore"):
        q = q * rsqrt(((q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1]) + q[:, 2] * q[:, 2]) + q[:, 3] * q[:, 3])[:, None]
        w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        x2, y2, z2 = x * x, y * y, z * z
        xy, xz, yz = x * y, x * z, y * z
        wx, wy, wz = w * x, w * y, w * z
        one, two = F(1), F(2)
        R = np.empty((q.shape[0], 3, 3), dtype=F)
        R[:, 0, 0] = one - two * (y2 + z2)
        R[:, 0, 1] = two * (xy - wz)
        R[:, 0, 2] = two * (xz + wy)
        R[:, 1, 0] = two * (xy + wz)
        R[:, 1, 1] = one - two * (x2 + z2)
        R[:, 1, 2] = two * (yz - wx)
        R[:, 2, 0] = two * (xz - wy)
        R[:, 2, 1] = two * (yz + wx)
        R[:, 2, 2] = one - two * (x2 + y2)
    return R


def project(model: Model, cam: Camera) -> dict:
    """Per-primitive projection of `model` (decoded float32 values) for one camera.

    Returns arrays over all N primitives: depth (p.z), visible (bool), mean2d [N,2],
    cov2d [N,3] (a, b, c, dilated), conic [N,3], unbounded (bool), radius [N,2] (rx, ry),
    opacity [N], rgb [N,3], rect [N,4] int32 (x0, y0, x1, y1 in tiles, exclusive max; zeros
    when culled), n_tiles [N] int64 (0 when culled).
    """
    n = model.n
    R, t, fx, fy, cx, cy, campos = _cam_params(cam)
    TX, TY = n_tiles_xy(cam)
    lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg = _lims(cam, fx, fy, cx, cy)
    m = model.means
    with np.errstate(all="ignore"):
        # 2. camera-space mean
        p = ((m[:, 0, None] * R[None, :, 0] + m[:, 1, None] * R[None, :, 1]) + m[:, 2, None] * R[None, :, 2]) + t[
            None, :
        ]
        px, py, pz = p[:, 0], p[:, 1], p[:, 2]
        ok = np.isfinite(pz) & (pz >= NEAR) & (pz <= FAR)
        # 3. screen mean
        rz = F(1) / pz
        mx = (fx * px) * rz + cx
        my = (fy * py) * rz + cy
        ok &= np.isfinite(mx) & np.isfinite(my)
        # 4. scales and rotation
        s = np.exp(model.log_scales)
        Rq = quat_to_rotmat(model.quats)
        Wm = np.broadcast_to(R, (n, 3, 3))
        # 5. EWA with gsplat's clamp
        tx = pz * np.minimum(lim_x_pos, np.maximum(-lim_x_neg, px * rz))
        ty = pz * np.minimum(lim_y_pos, np.maximum(-lim_y_neg, py * rz))
        J = np.zeros((n, 2, 3), dtype=F)
        J[:, 0, 0] = fx * rz
        J[:, 0, 2] = ((-fx * tx) * rz) * rz
        J[:, 1, 1] = fy * rz
        J[:, 1, 2] = ((-fy * ty) * rz) * rz
        T = _mm(J, _mm(Wm, Rq)) * s[:, None, :]
        a, b, c, det = _cov2d(T[:, 0, :], T[:, 1, :])
        # 6. determinant, unbounded footprint, conic
        unb = ~(np.isfinite(a) & np.isfinite(b) & np.isfinite(c) & np.isfinite(det))
        conic = np.stack([c / det, -b / det, a / det], axis=1)
        conic[unb] = 0
        ok &= unb | ((det > 0) & (a >= 0) & (c >= 0))
        # 7. radius and tile rectangle (float, clamped before integer conversion)
        rx = np.ceil(EXTENT * np.sqrt(a))
        ry = np.ceil(EXTENT * np.sqrt(c))
        ft = F(TILE)
        x0 = np.clip(np.floor((mx - rx) / ft), F(0), F(TX))
        x1 = np.clip(np.ceil((mx + rx) / ft), F(0), F(TX))
        y0 = np.clip(np.floor((my - ry) / ft), F(0), F(TY))
        y1 = np.clip(np.ceil((my + ry) / ft), F(0), F(TY))
        rectf = np.stack([x0, y0, x1, y1], axis=1)
        rectf[unb] = np.array([0, 0, TX, TY], dtype=F)
        rectf[~ok] = 0  # also clears NaN rows (culled) before the integer conversion
        ok &= (rectf[:, 2] > rectf[:, 0]) & (rectf[:, 3] > rectf[:, 1])
        rectf[~ok] = 0
        rect = rectf.astype(np.int32)
        n_tiles = (rect[:, 2] - rect[:, 0]).astype(np.int64) * (rect[:, 3] - rect[:, 1])
        # 8. opacity, 9. colour
        opacity = sigmoid(model.opacity)
        rgb = sh_to_rgb(model.sh_dc, model.sh_rest, m - campos[None, :])
    return {
        "depth": pz.astype(F),
        "visible": ok,
        "mean2d": np.stack([mx, my], axis=1).astype(F),
        "cov2d": np.stack([a, b, c], axis=1).astype(F),
        "conic": conic.astype(F),
        "unbounded": unb & ok,
        "radius": np.stack([rx, ry], axis=1).astype(F),
        "opacity": opacity.astype(F),
        "rgb": rgb.astype(F),
        "rect": rect,
        "n_tiles": n_tiles,
    }


def depth_order(proj: dict) -> np.ndarray:
    """Indices of the visible primitives, front to back by depth, ties by index."""
    vis = np.nonzero(proj["visible"])[0]
    return vis[np.argsort(proj["depth"][vis], kind="stable")]


# ---------------------------------------------------------------------------------------------
# Compositing (vectorised per tile)
# ---------------------------------------------------------------------------------------------


def _composite_tile(ids, pxs, pys, mx, my, conic, opac, rgb, bg, block0=32, block_max=512):
    """Composite the depth-ordered primitive list `ids` over pixel centres (pxs, pys) [P].
    Exactly the sequential per-pixel rule, vectorised over pixels and blocks of primitives."""
    P = pxs.shape[0]
    T = np.ones(P, dtype=F)
    C = np.zeros((P, 3), dtype=F)
    active = np.arange(P)  # pixels not yet stopped
    pos, L, B = 0, len(ids), block0
    while pos < L and active.size:
        blk = ids[pos : pos + B]
        pos += len(blk)
        nb = len(blk)
        apx, apy = pxs[active], pys[active]
        dx = mx[blk, None] - apx[None, :]
        dy = my[blk, None] - apy[None, :]
        cxx, cxy, czz = conic[blk, 0, None], conic[blk, 1, None], conic[blk, 2, None]
        sigma = F(0.5) * ((cxx * dx) * dx + (czz * dy) * dy) + (cxy * dx) * dy
        a = opac[blk, None] * np.exp(-sigma)
        alpha = np.minimum(ALPHA_MAX, a)  # NaN propagates
        skip = (sigma < 0) | (alpha < ALPHA_MIN)
        f = F(1) - np.where(skip, F(0), alpha)
        Ta = T[active]
        Tc = np.multiply.accumulate(np.concatenate([Ta[None, :], f], axis=0), axis=0)  # [nb+1, Pa]
        stop = Tc[1:] <= T_MIN  # skipped steps keep T (> T_MIN), so they never stop
        any_stop = stop.any(axis=0)
        first = np.where(any_stop, np.argmax(stop, axis=0), nb)
        include = (np.arange(nb)[:, None] < first[None, :]) & ~skip
        vis = alpha * Tc[:-1]
        contrib = rgb[blk][:, None, :] * vis[:, :, None]
        contrib = np.where(include[:, :, None], contrib, F(0))
        Cc = np.add.accumulate(np.concatenate([C[active][None], contrib], axis=0), axis=0)
        cols = np.arange(active.size)
        C[active] = Cc[first, cols]
        T[active] = Tc[first, cols]
        active = active[~any_stop]
        B = min(2 * B, block_max)
    return C + T[:, None] * bg[None, :]


def render_view(model: Model, cam: Camera, background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Float32 image [H, W, 3] (unclamped) of one view, vectorised per 16x16 tile."""
    bg = np.asarray(background, dtype=F).reshape(3)
    W, H = cam.width, cam.height
    TX, TY = n_tiles_xy(cam)
    img = np.empty((H, W, 3), dtype=F)
    with np.errstate(all="ignore"):
        proj = project(model, cam)
        order = depth_order(proj)
        rect = proj["rect"][order]
        mx = proj["mean2d"][:, 0]
        my = proj["mean2d"][:, 1]
        conic, opac, rgb = proj["conic"], proj["opacity"], proj["rgb"]
        for ty in range(TY):
            row = order[(rect[:, 1] <= ty) & (rect[:, 3] > ty)]
            rrect = rect[(rect[:, 1] <= ty) & (rect[:, 3] > ty)]
            ya, yb = ty * TILE, min(H, (ty + 1) * TILE)
            for tx in range(TX):
                xa, xb = tx * TILE, min(W, (tx + 1) * TILE)
                ids = row[(rrect[:, 0] <= tx) & (rrect[:, 2] > tx)]
                gy, gx = np.mgrid[ya:yb, xa:xb]
                pxs = gx.reshape(-1).astype(F) + F(0.5)
                pys = gy.reshape(-1).astype(F) + F(0.5)
                out = _composite_tile(ids, pxs, pys, mx, my, conic, opac, rgb, bg)
                img[ya:yb, xa:xb] = out.reshape(yb - ya, xb - xa, 3)
    return img


def render(model: Model, cams: list[Camera], background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Float32 images [K, H, W, 3] (unclamped), one per camera (cameras share a size)."""
    if isinstance(cams, Camera):
        cams = [cams]
    return np.stack([render_view(model, c, background) for c in cams])


# ---------------------------------------------------------------------------------------------
# Naive reference: per-primitive scalar projection, per-pixel loop (tiny scenes only)
# ---------------------------------------------------------------------------------------------


def _finite(x) -> bool:
    return bool(np.isfinite(x))


def _naive_project_one(model: Model, i: int, cam: Camera, TX: int, TY: int):
    """Scalar projection of primitive i; None if culled, else (z, mx, my, conic, o, rgb, rect)."""
    R, t, fx, fy, cx, cy, campos = _cam_params(cam)
    lxp, lxn, lyp, lyn = _lims(cam, fx, fy, cx, cy)
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
    s = [np.exp(model.log_scales[i, k]) for k in range(3)]
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
    a, b, c, det = (F(v) for v in _cov2d(t1, t2))
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
        o = one / (one + np.exp(-lg))
    else:
        e = np.exp(lg)
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
                    a = o * np.exp(-sigma)
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
