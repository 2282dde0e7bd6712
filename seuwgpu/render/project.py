"""Projection stage: shaders/project.wgsl and its numpy twin `project`.

Per primitive and view: decode the stored words, EWA-project (gsplat's conventions and the rules
of docs/renderer.md), evaluate the SH colour, and compute the tile rectangle. The GPU stage
(`Projection`) runs one thread per primitive of one model chunk and writes screen records; the
twin follows the same rules in float32 numpy. Floating-point operation order (the GPU uses the
same; it only matters at the last bit, or where 0 * Inf decides between a finite value and NaN):

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
  a*c - b*b would cancel catastrophically for needles); conic = (c/det, -b/det, a/det).

One rule docs/renderer.md leaves implicit: with finite a, b, c, det > 0, a or c may still be
negative (rounding in a huge covariance), which would make the radius sqrt(a) NaN. Such a
primitive is culled (its Gaussian is negative definite: sigma < 0 everywhere but its centre).

The numeric rules (near plane, dilation, extent, ...) are deliberately restated here rather than
shared with the shader: the twin is an independent implementation of docs/renderer.md.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.constants import EXP_MAX, EXP_MIN, PRECISION_CODE, PROFILE_CODE, TILE
from seuwgpu.gpu.device import GPU, STORAGE
from seuwgpu.gpu.kernel import Kernel, Uniforms
from seuwgpu.model import checks
from seuwgpu.model.cameras import Camera
from seuwgpu.model.fields import Model
from seuwgpu.model.sh import sh_basis
from seuwgpu.render.stage import Output, Stage

# ---------------------------------------------------------------------------------------------
# numpy twin
# ---------------------------------------------------------------------------------------------

F = np.float32
NEAR = F(0.01)
FAR = F(1e10)
LOWPASS = F(0.3)
EXTENT = F(3.33)
CLIP = F(0.3)


def exp_f32(x):
    """exp in float32 as the shaders evaluate it (docs/renderer.md rule 4, gpu/constants.py):
    0 below EXP_MIN, +Inf above EXP_MAX, NaN -> NaN."""
    x = np.asarray(x, dtype=F)
    with np.errstate(all="ignore"):
        e = np.where(x < F(EXP_MIN), F(0), np.exp(x))
        return np.where(x > F(EXP_MAX), F(np.inf), e).astype(F)[()]


def n_tiles_xy(cam: Camera) -> tuple[int, int]:
    return -(-cam.width // TILE), -(-cam.height // TILE)


def camera_params(cam: Camera):
    """(R, t, fx, fy, cx, cy, campos) in float32."""
    K = cam.K
    fx, fy, cx, cy = F(K[0, 0]), F(K[1, 1]), F(K[0, 2]), F(K[1, 2])
    R = cam.viewmat[:3, :3].astype(F)
    t = cam.viewmat[:3, 3].astype(F)
    campos = cam.position.astype(F)  # computed in float64 from the float32 viewmat, then rounded
    return R, t, fx, fy, cx, cy, campos


def camera_space(means, R, t):
    """Camera-space means (p.x, p.y, p.z) = R @ mean + t, each sum left to right."""
    m = means
    with np.errstate(all="ignore"):
        p = ((m[:, 0, None] * R[None, :, 0] + m[:, 1, None] * R[None, :, 1]) + m[:, 2, None] * R[None, :, 2]) + t
    return p[:, 0], p[:, 1], p[:, 2]


def jacobian_limits(cam: Camera, fx, fy, cx, cy):
    """gsplat's clamp of the EWA Jacobian, 30% beyond the image edge: (lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg)."""
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
        pos = F(1) / (F(1) + exp_f32(-x))
        e = exp_f32(x)
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


def batched_matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Batched matrix product [N, i, k] @ [N, k, j] with each sum taken left to right."""
    out = A[:, :, 0, None] * B[:, None, 0, :]
    for k in range(1, A.shape[2]):
        out = out + A[:, :, k, None] * B[:, None, k, :]
    return out


def cov2d(t1: np.ndarray, t2: np.ndarray):
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


def check_profile(profile: str, what: str | None = None) -> str:
    """A renderer profile's name (the one definition of the names: PROFILE_CODE), InputError otherwise."""
    return checks.one_of(profile, "renderer profile", PROFILE_CODE, what)


def project(model: Model, cam: Camera, profile: str = "strict") -> dict:
    """Per-primitive projection of `model` (decoded float32 values) for one camera.

    Returns arrays over all N primitives: depth (p.z), visible (bool), proj_xy [N,2] (the screen mean),
    cov2d [N,3] (a, b, c, dilated), conic [N,3], unbounded (bool), radius [N,2] (rx, ry),
    opacity [N], rgb [N,3], rect [N,4] int32 (x0, y0, x1, y1 in tiles, exclusive max; zeros
    when culled), n_tiles [N] int64 (0 when culled).
    """
    if check_profile(profile) == "gsplat":
        return project_gsplat(model, cam)
    n = model.n
    R, t, fx, fy, cx, cy, campos = camera_params(cam)
    TX, TY = n_tiles_xy(cam)
    lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg = jacobian_limits(cam, fx, fy, cx, cy)
    m = model.means
    with np.errstate(all="ignore"):
        # 2. camera-space mean
        px, py, pz = camera_space(m, R, t)
        ok = np.isfinite(pz) & (pz >= NEAR) & (pz <= FAR)
        # 3. screen mean
        rz = F(1) / pz
        mx = (fx * px) * rz + cx
        my = (fy * py) * rz + cy
        ok &= np.isfinite(mx) & np.isfinite(my)
        # 4. scales and rotation
        s = exp_f32(model.log_scales)
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
        T = batched_matmul(J, batched_matmul(Wm, Rq)) * s[:, None, :]
        a, b, c, det = cov2d(T[:, 0, :], T[:, 1, :])
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
        # 8. opacity, 9. colour
        return records(model, campos, pz, ok, (mx, my), (a, b, c), conic, unb & ok, (rx, ry), rectf)


def records(model: Model, campos, pz, ok, screen_xy, cov, conic, unbounded, radius, rectf) -> dict:
    """The projection's outputs (see `project`): culled rows' rectangles cleared, then opacity
    and colour."""
    with np.errstate(all="ignore"):
        rectf[~ok] = 0
        rect = rectf.astype(np.int32)
        n_tiles = (rect[:, 2] - rect[:, 0]).astype(np.int64) * (rect[:, 3] - rect[:, 1])
        opacity = sigmoid(model.opacity)
        rgb = sh_to_rgb(model.sh_dc, model.sh_rest, model.means - campos[None, :])
    return {
        "depth": pz.astype(F),
        "visible": ok,
        "proj_xy": np.stack(screen_xy, axis=1).astype(F),
        "cov2d": np.stack(cov, axis=1).astype(F),
        "conic": conic.astype(F),
        "unbounded": unbounded,
        "radius": np.stack(radius, axis=1).astype(F),
        "opacity": opacity.astype(F),
        "rgb": rgb.astype(F),
        "rect": rect,
        "n_tiles": n_tiles,
    }


def glm_min(a, b):
    """glm::min(a, b) = (b < a) ? b : a: a NaN b is dropped."""
    return np.where(b < a, b, a)


def glm_max(a, b):
    """glm::max(a, b) = (a < b) ? b : a: a NaN b is dropped."""
    return np.where(a < b, b, a)


def cuda_f2i(x):
    """CUDA's float-to-int32 conversion, kept in float: NaN -> 0, saturating at +-2^31."""
    x = np.asarray(x, dtype=F)
    return np.where(np.isnan(x), F(0), np.clip(x, F(-(2.0**31)), F(2.0**31))).astype(F)


def project_gsplat(model: Model, cam: Camera) -> dict:
    """The gsplat profile's projection (docs/renderer.md, "Profiles"): gsplat's CUDA arithmetic
    (ProjectionEWA3DGSFused.cu, Utils.cuh persp_proj / quat_scale_to_covar_preci / add_blur,
    IntersectTile.cu's tile box). Same outputs as `project`; `unbounded` is always False (a
    non-finite covariance gives a NaN radius, culled, or an infinite one, the whole screen)."""
    n = model.n
    R, t, fx, fy, cx, cy, campos = camera_params(cam)
    TX, TY = n_tiles_xy(cam)
    W, H = F(cam.width), F(cam.height)
    lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg = jacobian_limits(cam, fx, fy, cx, cy)
    m = model.means
    with np.errstate(all="ignore"):
        px, py, pz = camera_space(m, R, t)
        ok = ~((pz < NEAR) | (pz > FAR))  # NaN passes
        rz = F(1) / pz
        mx = (fx * px) * rz + cx
        my = (fy * py) * rz + cy
        s = exp_f32(model.log_scales)
        M = quat_to_rotmat(model.quats) * s[:, None, :]  # R S: column k scaled by s[k]
        sigma = batched_matmul(M, M.transpose(0, 2, 1))
        Wm = np.broadcast_to(R, (n, 3, 3))
        cov_c = batched_matmul(batched_matmul(Wm, sigma), Wm.transpose(0, 2, 1))
        tx = pz * glm_min(lim_x_pos, glm_max(-lim_x_neg, px * rz))
        ty = pz * glm_min(lim_y_pos, glm_max(-lim_y_neg, py * rz))
        J = np.zeros((n, 2, 3), dtype=F)
        J[:, 0, 0] = fx * rz
        J[:, 0, 2] = ((-fx * tx) * rz) * rz
        J[:, 1, 1] = fy * rz
        J[:, 1, 2] = ((-fy * ty) * rz) * rz
        cov2 = batched_matmul(batched_matmul(J, cov_c), J.transpose(0, 2, 1))
        a = cov2[:, 0, 0] + LOWPASS
        c = cov2[:, 1, 1] + LOWPASS
        b01, b10 = cov2[:, 1, 0], cov2[:, 0, 1]  # glm m[0][1] (column 0, row 1), m[1][0]
        det = a * c - b01 * b10
        ok &= ~(det <= 0)
        inv = F(1) / det
        conic = np.stack([c * inv, -b01 * inv, a * inv], axis=1)
        rx = np.ceil(EXTENT * np.sqrt(a))
        ry = np.ceil(EXTENT * np.sqrt(c))
        ok &= ~((rx <= 0) & (ry <= 0))
        ok &= ~((mx + rx <= 0) | (mx - rx >= W) | (my + ry <= 0) | (my - ry >= H))
        irx, iry = cuda_f2i(rx), cuda_f2i(ry)
        ok &= (irx > 0) & (iry > 0)
        ft = F(TILE)

        def bound(v, hi):
            return np.clip(cuda_f2i(v), F(0), F(hi))

        rectf = np.stack(
            [
                bound(np.floor(mx / ft - irx / ft), TX),
                bound(np.floor(my / ft - iry / ft), TY),
                bound(np.ceil(mx / ft + irx / ft), TX),
                bound(np.ceil(my / ft + iry / ft), TY),
            ],
            axis=1,
        )
        ok &= (rectf[:, 2] > rectf[:, 0]) & (rectf[:, 3] > rectf[:, 1])
    return records(model, campos, pz, ok, (mx, my), (a, b01, c), conic, np.zeros(n, dtype=bool), (rx, ry), rectf)


# ---------------------------------------------------------------------------------------------
# GPU stage
# ---------------------------------------------------------------------------------------------


class Projection:
    """project.wgsl: one model chunk's primitives into one view, one thread per primitive.

    Owns the screen records of `capacity` primitives (written at chunk_base + j), PROJECT's
    outputs in `buffers` by their shader names: `proj_xy` (screen mean), `proj_conic` (conic.xyz,
    opacity), `proj_rgb` (colour, depth p.z), `proj_rect` (packed tile rectangle (x0 | y0 << 16,
    x1 | y1 << 16), zero when culled), `depth_keys` / `depth_vals` (f32 bits of p.z, 0xffffffff
    when culled; primitive index) for the depth sort. Parameters: one `View` slot
    per (view, chunk) in `params` (fill with `set_view`, then `params.write()`). Culled
    primitives get only their rectangle and depth key written.

    The shader is specialised (WGSL overrides) per stored precision, SH degree and in-pipeline
    guard mask (a handful of pipelines per renderer): `encode` picks the pipeline from the slot's
    `fmt`, `sh_degree`, `guard_lo` and `guard_hi`, so a variant cannot disagree with the
    parameters."""

    def __init__(self, gpu: GPU, capacity: int, slots: int = 1, label: str = "proj", profile: str = "strict"):
        self.gpu, self.label = gpu, label
        self.profile = check_profile(profile)
        self._kernels: dict[tuple, Kernel] = {}
        # the check inside the frame (off: FRAME_CHECK 0, today's pipeline): set_frame_check
        self.set_frame_check(None)
        self.kernel = self.variant(PRECISION_CODE["fp32"], 3, 0, 0)
        self.set_slots(slots)
        self.capacity = 0
        self.set_capacity(capacity)

    def set_capacity(self, capacity: int):
        """(Re)allocate the screen records for `capacity` primitives (a batched renderer's K views
        hold K n: render/renderer.py)."""
        if int(capacity) == self.capacity:
            return
        gpu, label = self.gpu, self.label
        self.capacity = n = int(capacity)
        self.buffers = {o.name: gpu.buffer(4 * o.words * n, STORAGE, f"{label}.{o.name}") for o in PROJECT.outputs}

    def set_slots(self, slots: int):
        """(Re)allocate the parameter slots (one per view and model chunk)."""
        self.params = Uniforms(self.gpu, self.kernel.struct("View"), slots, f"{self.label}.view")

    def set_view(
        self,
        slot: int,
        cam: Camera,
        *,
        tiles: tuple[int, int],
        n_total: int,
        chunk: tuple[int, int],
        plane_words: int,
        degree: int,
        precision: str,
        view_index: int,
        guard_mask: int = 0,
        tile_origin: tuple[int, int] = (0, 0),
        background=(1.0, 1.0, 1.0),
        records_at: int | None = None,
    ):
        """Parameters of slot `slot`: camera `cam` (full frame; `tiles` and `tile_origin`, in
        tiles, describe the rendered viewport); `chunk` = (first primitive, count) of the n_total,
        stored `plane_words` words per component plane; the in-pipeline guard mask (bit c clamps
        flat component c; view 0 counts the clamps). The chunk's records (and depth values) go to
        records_at + j (default: its first primitive; a batched renderer puts view v's at v n +
        that)."""
        self.params.struct.fill(
            self.params.rows[slot : slot + 1],
            viewmat=cam.viewmat.T,  # WGSL matrices are column-major
            campos=np.append(cam.position.astype(np.float32), 0.0),
            intr=[cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]],
            background=np.append(np.asarray(background, np.float32), 0.0),
            width=cam.width,
            height=cam.height,
            tiles_x=tiles[0],
            tiles_y=tiles[1],
            n_total=n_total,
            chunk_base=chunk[0] if records_at is None else records_at,
            chunk_count=chunk[1],
            plane_words=plane_words,
            sh_degree=degree,
            fmt=PRECISION_CODE[precision],
            view_index=view_index,
            guard_lo=int(guard_mask) & 0xFFFFFFFF,
            guard_hi=int(guard_mask) >> 32,
            tile_x0=tile_origin[0],
            tile_y0=tile_origin[1],
        )

    def set_frame_check(
        self, side=None, out=None, cover: int = 0, ways: int = 4, diagonal: int = 0, flags=True, per_word=False
    ):
        """The check inside the frame: `side` the packed parity codes (`ways` bits) of every
        primitive (with `per_word`, at fp16/bf16, of every stored word pair: the whole word folded),
        `out` its output (a CheckOut: count twice, 2 words, with `flags` a flag bit per primitive),
        `cover` the bits of each folded pattern the parity covers, bit b of value c counted in way
        (b + diagonal c) % ways; None: off (today's pipeline)."""
        if side is None:  # placeholders (a buffer is never bound both read-only and writable), made once
            if getattr(self, "_frame_off", None) is None:
                self._frame_off = (
                    self.gpu.buffer(16, STORAGE, f"{self.label}.frame_side_off"),
                    self.gpu.buffer(16, STORAGE, f"{self.label}.frame_out_off"),
                )
            self.frame_code = None
            self.frame_side, self.frame_out = self._frame_off
            return
        self.frame_side, self.frame_out = side, out
        self.frame_code = (int(cover), int(ways), int(diagonal), int(bool(flags)), int(bool(per_word)))

    def variant(self, fmt: int, degree: int, guard_lo: int, guard_hi: int, code=None) -> Kernel:
        """The pipeline for stored precision code `fmt`, SH `degree`, guard mask words and the
        frame check's code (cover, ways, diagonal, flags, per_word; None: no check in the frame)."""
        key = (int(fmt), int(degree), int(guard_lo), int(guard_hi), code)
        k = self._kernels.get(key)
        if k is None:
            names = ("FMT", "SH_DEGREE", "GUARD_LO", "GUARD_HI")
            constants = {**dict(zip(names, key[:4])), "PROFILE": PROFILE_CODE[self.profile]}
            if code is not None:
                frame = ("FRAME_COVER", "FRAME_WAYS", "FRAME_DIAGONAL", "FRAME_FLAGS", "FRAME_PER_WORD")
                constants.update(FRAME_CHECK=1, **dict(zip(frame, code)))
            k = self._kernels[key] = Kernel(self.gpu, "project", constants=constants)
        return k

    def encode(self, encoder, slot: int, words, count: int, box, guard_counts, buffers=None):
        """Project `count` primitives of the stored chunk `words` with slot `slot`'s parameters.
        `box`: the guard's Bound per component; `guard_counts`: its atomic clamp counters;
        `buffers`: where the records go (default: this stage's own `buffers`)."""
        row = self.params.rows[slot]
        kernel = self.variant(row["fmt"], row["sh_degree"], row["guard_lo"], row["guard_hi"], self.frame_code)
        kernel.dispatch(
            encoder,
            self.buffers if buffers is None else buffers,
            view=self.params.binding(slot),
            model=words,
            box=box,
            guard_counts=guard_counts,
            frame_side=self.frame_side,
            frame_out=self.frame_out,
            threads=count,
        )

    def read(self, n: int | None = None) -> dict:
        """Records of primitives [0, n) as numpy arrays (tests, inspection): proj_xy [n, 2], conic
        [n, 3], opacity, rgb [n, 3], depth, rect [n, 4] (x0, y0, x1, y1), depth_keys, depth_vals."""
        n = self.capacity if n is None else int(n)
        g = self.gpu
        b = self.buffers
        conic = g.read(b["proj_conic"], np.float32, 0, 16 * n).reshape(n, 4)
        rgb = g.read(b["proj_rgb"], np.float32, 0, 16 * n).reshape(n, 4)
        return {
            "proj_xy": g.read(b["proj_xy"], np.float32, 0, 8 * n).reshape(n, 2),
            "conic": conic[:, :3],
            "opacity": conic[:, 3],
            "rgb": rgb[:, :3],
            "depth": rgb[:, 3],
            "rect": unpack_rects(g.read(b["proj_rect"], np.uint32, 0, 8 * n).reshape(n, 2)),
            "depth_keys": g.read(b["depth_keys"], np.uint32, 0, 4 * n),
            "depth_vals": g.read(b["depth_vals"], np.uint32, 0, 4 * n),
        }


def unpack_rects(packed: np.ndarray) -> np.ndarray:
    """Packed rectangles [..., 2] u32 (x0 | y0 << 16, x1 | y1 << 16) -> [..., 4] (x0, y0, x1, y1)."""
    p = packed.astype(np.int64)
    return np.stack([p[..., 0] & 0xFFFF, p[..., 0] >> 16, p[..., 1] & 0xFFFF, p[..., 1] >> 16], axis=-1)


def depth_keys(proj: dict) -> np.ndarray:
    """Twin of the stage's depth keys: f32 bits of p.z for drawn primitives, 0xffffffff for culled."""
    keys = np.ascontiguousarray(proj["depth"], np.float32).view(np.uint32).copy()
    keys[~proj["visible"]] = 0xFFFFFFFF
    return keys


# ---- the stage ----------------------------------------------------------------------------------
def project_twin(model: Model, view: Camera, profile: str) -> dict:
    """`project` as the kernel's buffers: culled primitives' records zero but for their depth key
    (the kernel writes only their rectangle and keys; run_stage clears the rest)."""
    with np.errstate(all="ignore"):
        proj = project(model, view, profile)
    vis = proj["visible"]
    rect = proj["rect"].astype(np.uint32)
    out = {
        "proj_xy": proj["proj_xy"],
        "proj_conic": np.column_stack([proj["conic"], proj["opacity"]]),
        "proj_rgb": np.column_stack([proj["rgb"], proj["depth"]]),
    }
    out = {name: np.where(vis[:, None], rows, F(0)).astype(F) for name, rows in out.items()}
    out["proj_rect"] = np.stack([rect[:, 0] | rect[:, 1] << 16, rect[:, 2] | rect[:, 3] << 16], axis=1)
    out["depth_keys"] = depth_keys(proj)
    out["depth_vals"] = np.arange(model.n, dtype=np.uint32)
    return out


def _encode_project(encoder, buffers, r, slot, views):
    for v in views:
        r.encode_projection(encoder, v, buffers)


PROJECT = Stage(
    "project",
    inputs=("model", "view"),
    params=("profile",),
    outputs=(
        Output("proj_xy", 2, "primitive", "f32", exact=False, fault=True, kept=True, former="xy"),
        Output("proj_conic", 4, "primitive", "f32", exact=False, fault=True, kept=True, former="conic"),
        Output("proj_rgb", 4, "primitive", "f32", used=3, exact=False, fault=True, kept=True, former="rgb"),
        Output("proj_rect", 2, "primitive", kept=True),
        # the depth sort's keys and values, flipped before it sorts them
        Output("depth_keys", 1, "primitive", exact=False, fault=True, former="depth_key"),
        Output("depth_vals", 1, "primitive"),
    ),
    run=_encode_project,
    twin_of=project_twin,
)
