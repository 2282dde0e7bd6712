"""Real spherical harmonics as 3DGS evaluates them (INRIA's sh_utils, gsplat), and rotating a
model's frame: positions, orientations and view-dependent colour together.

The basis (signs and expressions) is the renderer's: render/project.py (the numpy twin of
shaders/project.wgsl) evaluates colour with it, in float32, operations in the order written.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.model.fields import Model

F = np.float32

# Real SH constants (INRIA's sh_utils / gsplat), as float64 numbers, and as the float32 the
# renderer uses.
_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
SH_C0 = F(_C0)
SH_C1 = F(_C1)
SH_C2 = tuple(F(v) for v in _C2)
SH_C3 = tuple(F(v) for v in _C3)


def sh_basis(dirs: np.ndarray, degree: int, dtype=F) -> np.ndarray:
    """Real SH basis values [N, (degree+1)^2] at unit directions [N, 3] (INRIA's signs and
    expressions; in `dtype`, float32 as the renderer, operations in the order written)."""
    T = np.dtype(dtype).type
    d = np.asarray(dirs, dtype=T)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    n = d.shape[0]
    c1, c2, c3 = T(_C1), [T(v) for v in _C2], [T(v) for v in _C3]
    out = np.empty((n, (degree + 1) ** 2), dtype=T)
    out[:, 0] = T(_C0)
    if degree >= 1:
        out[:, 1] = -(c1 * y)
        out[:, 2] = c1 * z
        out[:, 3] = -(c1 * x)
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        out[:, 4] = c2[0] * xy
        out[:, 5] = c2[1] * yz
        out[:, 6] = c2[2] * ((T(2) * zz - xx) - yy)
        out[:, 7] = c2[3] * xz
        out[:, 8] = c2[4] * (xx - yy)
    if degree >= 3:
        out[:, 9] = (c3[0] * y) * (T(3) * xx - yy)
        out[:, 10] = (c3[1] * xy) * z
        out[:, 11] = (c3[2] * y) * ((T(4) * zz - xx) - yy)
        out[:, 12] = (c3[3] * z) * ((T(2) * zz - T(3) * xx) - T(3) * yy)
        out[:, 13] = (c3[4] * x) * ((T(4) * zz - xx) - yy)
        out[:, 14] = (c3[5] * z) * (xx - yy)
        out[:, 15] = (c3[6] * x) * (xx - T(3) * yy)
    return out


# Proper rotations taking each axis to +y (SPZ's up): about x for +-z and -y, about z for +-x.
_TO_Y = {
    "+y": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "-y": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "+z": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    "-z": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "+x": ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    "-x": ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
}


def rotation_to_y(up: str) -> np.ndarray:
    """The proper rotation (float64 3x3) that takes the axis `up` ("+z", "-y", ...) to +y."""
    if up not in _TO_Y:
        raise ValueError(f"unknown up axis {up!r}; expected one of {', '.join(_TO_Y)}")
    return np.array(_TO_Y[up], dtype=np.float64)


def sh_rotation(R: np.ndarray, degree: int) -> list[np.ndarray]:
    """Per band l = 1..degree the matrix M_l with Y_l(R^T d) = M_l Y_l(d) for every direction d
    (float64). Fitted by least squares on 64 fixed directions: each band's functions are
    polynomials of degree l on the sphere, so the fit is exact up to rounding."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    y = sh_basis(d, degree, np.float64)
    yr = sh_basis(d @ np.asarray(R, np.float64), degree, np.float64)  # rows: (R^T d_i)^T = d_i^T R
    out = []
    for lvl in range(1, degree + 1):
        s = slice(lvl * lvl, (lvl + 1) * (lvl + 1))
        mt, *_ = np.linalg.lstsq(y[:, s], yr[:, s], rcond=None)
        out.append(mt.T)
    return out


def rotate_model(model: Model, R: np.ndarray) -> Model:
    """The model seen in a frame rotated by the proper rotation R: means R m, orientations
    R R_q (quaternions q_R q), and SH coefficients carried so that the colour seen from
    direction R d equals the original's from d. Scales, opacity and DC are unchanged."""
    R = np.asarray(R, np.float64)
    means = (model.means.astype(np.float64) @ R.T).astype(F)
    qr = rotmat_to_quat(R)[0]
    q = model.quats.astype(np.float64)
    w1, x1, y1, z1 = qr
    w2, x2, y2, z2 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    quats = np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=1,
    ).astype(F)
    rest = model.sh_rest.astype(np.float64)  # [N, (deg+1)^2 - 1, 3]
    out = np.empty_like(rest)
    for lvl, M in enumerate(sh_rotation(R, model.sh_degree), start=1):
        s = slice(lvl * lvl - 1, (lvl + 1) * (lvl + 1) - 1)
        # colour'(R d) = c'.Y(R d) must equal c.Y(d), and Y(d) = Y(R^T (R d)) = M Y(R d): c' = M^T c
        out[:, s, :] = np.einsum("jk,njc->nkc", M, rest[:, s, :])
    return Model(
        means=means,
        log_scales=model.log_scales.copy(),
        quats=quats,
        opacity=model.opacity.copy(),
        sh_dc=model.sh_dc.copy(),
        sh_rest=out.astype(F),
    )


def rotmat_to_quat(R):
    """Rotation matrices [N, 3, 3] -> unit quaternions [N, 4] (w, x, y, z), Shepperd's method."""
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    d = np.stack([R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2], R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    which = np.argmax(d, axis=1)
    q = np.empty((R.shape[0], 4))
    for k in range(4):
        sel = np.nonzero(which == k)[0]
        if sel.size == 0:
            continue
        m = R[sel]
        m00, m01, m02 = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
        m10, m11, m12 = m[:, 1, 0], m[:, 1, 1], m[:, 1, 2]
        m20, m21, m22 = m[:, 2, 0], m[:, 2, 1], m[:, 2, 2]
        if k == 0:
            s = 2.0 * np.sqrt(1.0 + m00 + m11 + m22)
            c = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
        elif k == 1:
            s = 2.0 * np.sqrt(1.0 + m00 - m11 - m22)
            c = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
        elif k == 2:
            s = 2.0 * np.sqrt(1.0 + m11 - m00 - m22)
            c = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
        else:
            s = 2.0 * np.sqrt(1.0 + m22 - m00 - m11)
            c = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
        q[sel] = np.stack(c, axis=1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)
