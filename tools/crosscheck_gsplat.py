"""The second renderer of tools/crosscheck.py: gsplat's pure-PyTorch reference functions on the CPU.

Per Gaussian (projection, covariance, colour) it calls gsplat's own torch code, unchanged:
`gsplat.cuda._torch_impl._quat_scale_to_covar_preci`, `_fully_fused_projection` and
`_spherical_harmonics`, as `gsplat.rendering._rasterization` chains them (colour = max(SH + 0.5, 0),
direction mean - camera centre, camera centre from `torch.inverse(viewmat)`). gsplat's torch
rasterizer (`_rasterize_to_pixels`) cannot run here: it calls the CUDA `rasterize_to_indices_in_range`
and nerfacc, and `_isect_tiles` is a Python loop per Gaussian (minutes per frame at 500k). So the tile
lists and the compositing are written here in torch, from gsplat's code: the tile box is
`_isect_tiles`'s arithmetic vectorised (tests/test_crosscheck.py checks it against `_isect_tiles`),
the depth order is its sort key (tile, then the depth's float bits, stably: CUDA's radix sort), and
compositing follows the CUDA kernel `RasterizeToPixels3DGSFwd.cu` of the installed gsplat line by line:
pixel centres at +0.5, `sigma = 0.5 (a dx^2 + c dy^2) + b dx dy`, `alpha = min(ALPHA_CAP, o exp(-sigma))`
with CUDA's `fminf` (a NaN alpha is the cap), skip when `sigma < 0 || alpha < 1/255`, stop (exclusive)
when `T (1 - alpha) <= 1e-4`, output `C + T * background`. Nothing here imports seuwgpu's renderer.

A single upset changes one primitive, and every stage before compositing is per primitive, so a
faulted frame is the clean frame with the tiles that the primitive's clean or faulted box covers
composited again (every other tile composites the same list in the same order: the same pixels).
"""

from __future__ import annotations

import numpy as np
import torch
from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci, _spherical_harmonics

TILE = 16
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
ALPHA_CAP = 0.999  # gsplat 1.5.3's RasterizeToPixels3DGSFwd.cu (and its torch `accumulate`)
CHUNK = 2048  # at most this many Gaussians composited at a time per tile (all 256 pixels)
FIRST_CHUNK = 128  # the first batch; each next one doubles (most pixels saturate early)


def _t(a) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))


def project(fields: dict, viewmat: np.ndarray, K: np.ndarray, width: int, height: int, degree: int, dtype=None):
    """gsplat's torch projection and colour of the primitives in `fields` (float32 numpy arrays:
    means [N,3], log_scales [N,3], quats [N,4], opacity [N], sh_dc [N,3], sh_rest [N,R,3]) for one
    view: radii [N,2] int32, means2d [N,2], depths [N], conics [N,3], opacities [N], colors [N,3].
    `dtype` torch.float64: the covariance and the projection (gsplat's functions are dtype-generic)
    in float64 from the float32 values, their results rounded to float32 (crosscheck --fp64)."""
    dt = dtype or torch.float32
    means, quats = _t(fields["means"]), _t(fields["quats"])
    scales = torch.exp(_t(fields["log_scales"]).to(dt))
    covars, _ = _quat_scale_to_covar_preci(quats.to(dt), scales, True, False, triu=False)
    vm, ks = _t(viewmat)[None], _t(K)[None]
    radii, means2d, depths, conics, _ = _fully_fused_projection(
        means.to(dt), covars, vm.to(dt), ks.to(dt), width, height, eps2d=0.3, near_plane=0.01, far_plane=1e10
    )
    means2d, depths, conics = means2d.float(), depths.float(), conics.float()
    campos = torch.inverse(vm)[0, :3, 3]
    dirs = means - campos
    coeffs = torch.cat([_t(fields["sh_dc"])[:, None, :], _t(fields["sh_rest"]).reshape(len(means), -1, 3)], dim=1)
    colors = torch.clamp_min(_spherical_harmonics(degree, dirs, coeffs) + 0.5, 0.0)
    opac = torch.sigmoid(_t(fields["opacity"]))
    return {
        "radii": radii[0],
        "means2d": means2d[0],
        "depths": depths[0],
        "conics": conics[0],
        "opacities": opac,
        "colors": colors,
    }


def tile_boxes(means2d: torch.Tensor, radii: torch.Tensor, tiles_x: int, tiles_y: int) -> torch.Tensor:
    """`_isect_tiles`'s tile rectangle per Gaussian, [N, 4] int (x0, y0, x1, y1; exclusive max), an
    empty one (x0 = x1) where a radius is <= 0."""
    tm = means2d / TILE
    tr = radii / TILE
    mins = torch.floor(tm - tr).int()
    maxs = torch.ceil(tm + tr).int()
    x0, x1 = mins[:, 0].clamp(0, tiles_x), maxs[:, 0].clamp(0, tiles_x)
    y0, y1 = mins[:, 1].clamp(0, tiles_y), maxs[:, 1].clamp(0, tiles_y)
    drawn = (radii > 0).all(dim=-1)
    x1 = torch.where(drawn, x1, x0)
    return torch.stack([x0, y0, x1, y1], dim=-1)


def depth_keys(depths: torch.Tensor) -> torch.Tensor:
    """The depth half of `_isect_tiles`'s sort key: the float's bits, zero-extended (int64)."""
    return depths.contiguous().view(torch.int32).to(torch.int64) & 0xFFFFFFFF


def tile_lists(p: dict, tiles_x: int, tiles_y: int) -> dict[int, torch.Tensor]:
    """{tile id: Gaussian ids front to back} (key (tile, depth bits), ties by index)."""
    box = tile_boxes(p["means2d"], p["radii"], tiles_x, tiles_y)
    w = (box[:, 2] - box[:, 0]).clamp(min=0)
    h = (box[:, 3] - box[:, 1]).clamp(min=0)
    n_t = (w * h).to(torch.int64)
    ids = torch.repeat_interleave(torch.arange(len(n_t)), n_t)
    if len(ids) == 0:
        return {}
    start = torch.cumsum(n_t, 0) - n_t
    k = torch.arange(len(ids)) - start[ids]
    tx = box[ids, 0] + k % w[ids]
    ty = box[ids, 1] + k // w[ids]
    tile = ty.to(torch.int64) * tiles_x + tx
    key = (tile << 32) | depth_keys(p["depths"])[ids]
    order = torch.sort(key, stable=True).indices
    tile, ids = tile[order], ids[order]
    uniq, counts = torch.unique_consecutive(tile, return_counts=True)
    return dict(zip(uniq.tolist(), torch.split(ids, counts.tolist())))


def composite_tile(rows: dict, tx: int, ty: int, width: int, height: int, cap: float = ALPHA_CAP) -> np.ndarray:
    """One tile's pixels [16, 16, 3] float32 (rows beyond the image cut), white background, from
    `rows`: the tile's Gaussians front to back (means2d, conics, opacities, colors)."""
    ys, xs = torch.meshgrid(torch.arange(TILE), torch.arange(TILE), indexing="ij")
    img = composite_pixels(rows, tx * TILE + xs.reshape(-1), ty * TILE + ys.reshape(-1), cap)
    img = img.reshape(TILE, TILE, 3)
    return img[: min(TILE, height - ty * TILE), : min(TILE, width - tx * TILE)]


def raw_alpha(rows: dict, px: torch.Tensor, py: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(sigma, o * exp(-sigma)) [P, M] of each Gaussian of `rows` at pixel centres (px, py) + 0.5."""
    m, c = rows["means2d"], rows["conics"]
    dx = m[None, :, 0] - (px.float() + 0.5)[:, None]
    dy = m[None, :, 1] - (py.float() + 0.5)[:, None]
    sigma = 0.5 * (c[None, :, 0] * dx * dx + c[None, :, 2] * dy * dy) + c[None, :, 1] * dx * dy
    return sigma, rows["opacities"][None, :] * torch.exp(-sigma)


def composite_pixels(rows: dict, px: torch.Tensor, py: torch.Tensor, cap: float = ALPHA_CAP) -> np.ndarray:
    """Pixels (px, py) (integer coordinates; all covered by the list `rows`) composited front to
    back over a white background: [P, 3] float32."""
    n_px = px.shape[0]
    T = torch.ones(n_px)
    out = torch.zeros(n_px, 3)
    done = torch.zeros(n_px, dtype=torch.bool)
    cap_t = torch.tensor(cap, dtype=torch.float32)
    n, s, step = len(rows["opacities"]), 0, FIRST_CHUNK
    while s < n:
        g = slice(s, s + step)
        s, step = s + step, min(2 * step, CHUNK)
        sigma, raw = raw_alpha({k: v[g] for k, v in rows.items()}, px, py)
        n_g = sigma.shape[1]
        alpha = torch.where(torch.isnan(raw), cap_t, torch.minimum(raw, cap_t))  # CUDA fminf
        valid = ~(sigma < 0) & ~(alpha < ALPHA_MIN) & ~done[:, None]
        a = torch.where(valid, alpha, torch.zeros(()))
        Tc = torch.cumprod(torch.cat([T[:, None], 1.0 - a], dim=1), dim=1)  # sequential: T_k = T_{k-1}(1-a_k)
        before, after = Tc[:, :-1], Tc[:, 1:]
        stop = valid & (after <= T_MIN)
        any_stop = stop.any(dim=1)
        first = torch.where(any_stop, stop.int().argmax(dim=1), torch.full((n_px,), n_g))
        keep = valid & (torch.arange(n_g)[None, :] < first[:, None])
        vis = a * before
        col = rows["colors"][g]
        contrib = torch.where(keep[:, :, None], col[None, :, :] * vis[:, :, None], torch.zeros(()))
        acc = torch.cumsum(torch.cat([out[:, None, :], contrib], dim=1), dim=1)
        out = torch.where(done[:, None], out, acc[torch.arange(n_px), first])
        T_new = torch.where(any_stop, before[torch.arange(n_px), first.clamp(max=n_g - 1)], Tc[:, -1])
        T = torch.where(done, T, T_new)
        done = done | any_stop
        if bool(done.all()):
            break
    return (out + T[:, None] * 1.0).numpy()


KEYS = ("means2d", "conics", "opacities", "colors")
EMPTY = torch.zeros(0, dtype=torch.int64)


class GsplatView:
    """One view: the clean projection, tile lists and frame; `faulted(p, row)` re-renders the frame
    with primitive p's fields replaced by `row` (a dict of that primitive's values)."""

    def __init__(
        self, fields: dict, degree: int, viewmat, K, width: int, height: int, cap: float = ALPHA_CAP, dtype=None
    ):
        self.fields, self.degree, self.dtype = fields, degree, dtype
        self.viewmat, self.K, self.W, self.H, self.cap = viewmat, K, width, height, cap
        self.tx, self.ty = -(-width // TILE), -(-height // TILE)
        self.p = project(fields, viewmat, K, width, height, degree, dtype)
        self.lists = tile_lists(self.p, self.tx, self.ty)
        self.frame = np.empty((height, width, 3), np.float32)
        for t in range(self.tx * self.ty):
            ids = self.lists.get(t, EMPTY)
            self._put(self.frame, t, self._composite(t, {k: self.p[k][ids] for k in KEYS}))

    def _composite(self, t: int, rows: dict) -> np.ndarray:
        return composite_tile(rows, t % self.tx, t // self.tx, self.W, self.H, self.cap)

    def _put(self, frame, t: int, img):
        x, y = (t % self.tx) * TILE, (t // self.tx) * TILE
        frame[y : y + img.shape[0], x : x + img.shape[1]] = img

    def project_one(self, row: dict) -> dict:
        return project(row, self.viewmat, self.K, self.W, self.H, self.degree, self.dtype)

    def faulted(self, prim: int, row: dict) -> tuple[np.ndarray, np.ndarray, dict]:
        """(clean frame, faulted frame, info). Compositing is per pixel, and a Gaussian that a pixel
        skips (alpha < 1/255) leaves it bit for bit as it was, so only the pixels of the tiles the
        primitive covers (clean or faulted) where its alpha, clean or faulted, is at least 0.5/255
        (or NaN) are composited again, with the clean list and with the faulted one, by the same
        code: an unaffected pixel comes out bit-identical in both. gsplat's projection of the lone
        primitive may differ in its last bits from its row of the batched projection; the clean
        pixels use the lone one too (`info["row_exact"]` says whether they were equal). `info` also
        gives the faulted primitive's radii, its tiles and the pixels composited again."""
        clean_row = {k: v[prim : prim + 1] for k, v in self.fields.items()}
        one_clean, one_bad = self.project_one(clean_row), self.project_one(row)
        exact = all(_same_bits(one_clean[k][0], self.p[k][prim]) for k in self.p)
        boxes = {}
        for name, q in (("clean", one_clean), ("bad", one_bad)):
            b = tile_boxes(q["means2d"], q["radii"], self.tx, self.ty)[0].tolist()
            boxes[name] = {y * self.tx + x for y in range(b[1], b[3]) for x in range(b[0], b[2])}
        base, bad = self.frame.copy(), self.frame.copy()
        ys, xs = torch.meshgrid(torch.arange(TILE), torch.arange(TILE), indexing="ij")
        redone = 0
        for t in sorted(boxes["clean"] | boxes["bad"]):
            px, py = (t % self.tx) * TILE + xs.reshape(-1), (t // self.tx) * TILE + ys.reshape(-1)
            inside = (px < self.W) & (py < self.H)
            hit = torch.zeros_like(inside)
            for name, q in (("clean", one_clean), ("bad", one_bad)):
                if t in boxes[name]:
                    _, raw = raw_alpha({k: q[k] for k in KEYS}, px, py)
                    hit |= ~(raw[:, 0] < 0.5 * ALPHA_MIN)
            sel = inside & hit
            if not bool(sel.any()):
                continue
            px, py = px[sel], py[sel]
            redone += int(sel.sum())
            others = self.lists.get(t, EMPTY)
            others = others[others != prim]
            for frame, name, q in ((base, "clean", one_clean), (bad, "bad", one_bad)):
                img = composite_pixels(self._rows(others, prim, q, t in boxes[name]), px, py, self.cap)
                frame[py.numpy(), px.numpy()] = img
        info = {
            "row_exact": bool(exact),
            "radius_x": int(one_bad["radii"][0, 0]),
            "radius_y": int(one_bad["radii"][0, 1]),
            "tiles": len(boxes["bad"]),
            "pixels_redone": redone,
        }
        return base, bad, info

    def _rows(self, others: torch.Tensor, prim: int, one: dict, inside: bool) -> dict:
        """The tile's rows front to back, with `prim` (projected as `one`) at its place in the
        (depth bits, index) order when its box covers the tile."""
        rows = {k: self.p[k][others] for k in KEYS}
        if not inside:
            return rows
        keys = depth_keys(self.p["depths"][others])
        k = int(depth_keys(one["depths"])[0])
        pos = int(((keys < k) | ((keys == k) & (others < prim))).sum())
        return {key: torch.cat([v[:pos], one[key], v[pos:]]) for key, v in rows.items()}


def _same_bits(a: torch.Tensor, b: torch.Tensor) -> bool:
    if a.is_floating_point():
        a, b = a.contiguous().view(torch.int32), b.contiguous().view(torch.int32)
    return torch.equal(a, b)
