"""Quick look at the embedded scenes without the GPU renderer: a small numpy splatter.

It projects each Gaussian with the EWA covariance (gsplat conventions, no Jacobian clamp), cuts
its footprint at 3.33 sigma (at most MAX_RADIUS px), and composites every fragment front to back
over white with alpha = min(0.99, o * exp(-sigma)), alpha >= 1/255, colour from the SH DC term
(plus degree 1 when present). Exact per-pixel ordering via a sort of all fragments, so it is only
meant for previews (a few 100k primitives at a few 100 px).

    python tools/scene_preview.py [--scene NAME ...] [--n 100000] [--size 320] [--views 4] [--out DIR]

Writes DIR/<scene>.png (the views side by side) and DIR/scenes.png (one row per scene).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.model import scenes  # noqa: E402
from seuwgpu.model.cameras import Camera  # noqa: E402
from seuwgpu.render.project import quat_to_rotmat  # noqa: E402

C0 = 0.28209479177387814
C1 = 0.4886025119029199
MAX_RADIUS = 24


def render(model, cam: Camera, background=(1.0, 1.0, 1.0)) -> np.ndarray:
    W, H = cam.width, cam.height
    R = cam.viewmat[:3, :3].astype(np.float64)
    t = cam.viewmat[:3, 3].astype(np.float64)
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    means = model.means.astype(np.float64)
    p = means @ R.T + t
    keep = p[:, 2] > 0.01
    idx = np.nonzero(keep)[0]
    p = p[keep]
    z = p[:, 2]
    S = np.exp(model.log_scales[idx].astype(np.float64))
    M = quat_to_rotmat(model.quats[idx]).astype(np.float64) * S[:, None, :]
    cov = M @ np.swapaxes(M, 1, 2)
    cov_c = R @ cov @ R.T
    J = np.zeros((len(idx), 2, 3))
    J[:, 0, 0] = fx / z
    J[:, 0, 2] = -fx * p[:, 0] / z**2
    J[:, 1, 1] = fy / z
    J[:, 1, 2] = -fy * p[:, 1] / z**2
    c2 = J @ cov_c @ np.swapaxes(J, 1, 2) + 0.3 * np.eye(2)
    a, b, c = c2[:, 0, 0], c2[:, 0, 1], c2[:, 1, 1]
    det = a * c - b * b
    conic = np.stack([c / det, -b / det, a / det], axis=1)
    mx = fx * p[:, 0] / z + cx
    my = fy * p[:, 1] / z + cy
    rad = np.minimum(np.ceil(3.33 * np.sqrt(np.maximum(a, c))), MAX_RADIUS).astype(np.int64)
    opac = 1.0 / (1.0 + np.exp(-model.opacity[idx].astype(np.float64)))
    rgb = 0.5 + C0 * model.sh_dc[idx].astype(np.float64)
    if model.sh_rest.shape[1] >= 3:
        d = means[idx] - cam.position
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        sh = model.sh_rest[idx].astype(np.float64)
        rgb += C1 * (-d[:, 1:2] * sh[:, 0] + d[:, 2:3] * sh[:, 1] - d[:, 0:1] * sh[:, 2])
    rgb = np.maximum(rgb, 0.0)

    pix_l, dep_l, alp_l, g_l = [], [], [], []
    for r in np.unique(rad):
        sel = np.nonzero(rad == r)[0]
        off = np.arange(-r, r + 1)
        ox, oy = [o.ravel() for o in np.meshgrid(off, off)]
        for chunk in np.array_split(sel, max(1, len(sel) * len(ox) // 4_000_000 + 1)):
            px = np.floor(mx[chunk])[:, None].astype(np.int64) + ox
            py = np.floor(my[chunk])[:, None].astype(np.int64) + oy
            dx = mx[chunk, None] - (px + 0.5)
            dy = my[chunk, None] - (py + 0.5)
            co = conic[chunk]
            sig = 0.5 * (co[:, 0:1] * dx * dx + co[:, 2:3] * dy * dy) + co[:, 1:2] * dx * dy
            al = np.minimum(0.99, opac[chunk, None] * np.exp(-sig))
            ok = (sig >= 0) & (al >= 1 / 255) & (px >= 0) & (px < W) & (py >= 0) & (py < H)
            gi = np.broadcast_to(chunk[:, None], ok.shape)[ok]
            pix_l.append((py * W + px)[ok])
            dep_l.append(z[gi])
            alp_l.append(al[ok])
            g_l.append(gi)
    img = np.tile(np.asarray(background, dtype=np.float64), (H * W, 1))
    if not pix_l:
        return img.reshape(H, W, 3).astype(np.float32)
    pix, dep, alp, gi = (np.concatenate(v) for v in (pix_l, dep_l, alp_l, g_l))
    order = np.lexsort((gi, dep, pix))
    pix, alp, gi = pix[order], alp[order], gi[order]
    la = np.log1p(-alp)
    cs = np.cumsum(la)
    first = np.r_[True, pix[1:] != pix[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(len(pix)), 0))
    excl = cs - la - (cs[start] - la[start])  # log T before this fragment
    w = alp * np.exp(excl)
    col = np.zeros((H * W, 3))
    for ch in range(3):
        col[:, ch] = np.bincount(pix, weights=w * rgb[gi, ch], minlength=H * W)
    tfin = np.exp(np.bincount(pix, weights=la, minlength=H * W))
    img = col + tfin[:, None] * np.asarray(background)
    return img.reshape(H, W, 3).astype(np.float32)


def to_png(img: np.ndarray, path) -> None:
    from PIL import Image

    Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)).save(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", nargs="*", default=scenes.list_scenes())
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--out", default="/tmp/seuwgpu-preview")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.scene:
        t0 = time.perf_counter()
        model = scenes.make_scene(name, args.n, seed=args.seed)
        t1 = time.perf_counter()
        cams = scenes.scene_cameras(name, args.views, args.size, args.size)
        row = np.concatenate([render(model, c) for c in cams], axis=1)
        t2 = time.perf_counter()
        to_png(row, out / f"{name}.png")
        rows.append(row)
        print(
            f"{name}: n={model.n} generated in {t1 - t0:.2f} s, {len(cams)} views splatted in {t2 - t1:.2f} s"
            f" -> {out / (name + '.png')}"
        )
    to_png(np.concatenate(rows, axis=0), out / "scenes.png")
    print(f"montage -> {out / 'scenes.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
