"""Embedded procedural 3DGS scenes: stand-ins for the NeRF-synthetic scenes, shipped as code.

Every scene is an object centred at the origin, z up, inside a sphere of radius ~1.3, meant to be
seen over a white background by `camera.orbit_cameras` (radius 4, fov 40 deg, elevation 25 deg):

- ``spheres`` (default): smooth surfaces - coloured spheres (one striped, one glossy) and a
  standing torus on a round checkered platform.
- ``blocks``: high-frequency blocky geometry - a lego-like stack of bricks (exposed faces of a
  brick voxel grid, studs on the free tops, dark seams between bricks) on a base plate.
- ``plant``: thin structures - a terracotta pot with soil, curved tapering stems and twigs and
  several hundred small thin leaves (the foliage holds most of the primitives, as in a trained
  ficus).

How a scene becomes a model that looks trained (`make_scene`):
- The scene is a fixed list of surface *parts* (quads, discs, spheres, tori, frusta, leaves; each
  part is a batch of instances). Its layout depends on the scene name only; `seed` changes the
  sampling, never the geometry.
- Exactly `n` primitives are shared among parts in proportion to area x a per-part density weight
  (largest-remainder rounding), then sampled area-uniformly on each part's surface.
- Each Gaussian is a flat disc on the surface: tangent log-scales `log(0.9 * sqrt(area / m))`
  (local spacing, so doubling n shrinks splats by sqrt 2) with log-normal jitter, capped on thin
  parts (leaves, stems); the normal axis is 1.5-2.5 units of log thinner than the smaller
  tangent axis. The quaternion (w, x, y, z; norm within a few % of 1) rotates the local frame
  (t1, t2, normal) onto the world, i.e. local z (the flat axis) = the surface normal.
- Opacity logits: ~88% high (sigmoid 0.9-0.99), a tail of ~12% faint (sigmoid 0.05-0.5), a bit
  larger (+0.35 log) and fuzzier (off the surface), like the low-opacity primitives of trained
  models.
- Means sit on the surface with a small jitter along the normal (0.05 x spacing; 0.3 x for the
  faint tail).
- Colour: per-part base colours with procedural texture (checker, stripes, seams, veins, noise)
  and per-primitive noise; `sh_dc = (rgb - 0.5) / C0`. `sh_rest` is small (|c| ~ 0.01-0.05):
  random view dependence decaying with degree (Irwin-Hall noise, sd 0.02 / 0.012 / 0.008 for
  degrees 1 / 2 / 3, clipped to +-0.1) plus a normal-aligned degree-1 sheen on glossy parts.
  `sh_rest` is coefficient-major [N, (d+1)^2 - 1, 3]; the coefficients of a lower degree
  are a prefix of those of degree 3 (same seed).
- The primitives are returned in a random order (trained models are not sorted by part; any
  prefix is a fair subsample of the scene).

Real captures (`leica-sofort`, `yashica-t4` and their `-wide` variants, model/captures.py) are
scenes too: `make_scene` returns them (all splats, or a seeded subset of n) and `scene_cameras`
frames them with model/framing.py (y up, SPZ's axes).

Everything is vectorised numpy (processed in chunks of 64k primitives to bound temporaries):
100k primitives take ~0.2 s, 4M ~5-10 s and ~1.3 GB peak. The output is deterministic for
(name, n, seed, sh_degree). `SCENES` maps names to `SceneSpec` (description, layout builder and
the orbit the scene is framed by, see `scene_cameras`).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache

import numpy as np

from seuwgpu.model.budget import check_scene
from seuwgpu.model.cameras import Camera, orbit_cameras
from seuwgpu.model.captures import CAPTURES, capture_model
from seuwgpu.model.captures import UP as CAPTURE_UP
from seuwgpu.model.fields import Model, sh_rest_count
from seuwgpu.model.framing import orbit_views
from seuwgpu.model.sh import rotmat_to_quat

C0 = 0.28209479177387814
DEFAULT_SCENE = "spheres"
DEFAULT_N = 100_000

# Generator constants (documented in the module docstring).
SPLAT_C = 0.9  # tangent sigma = SPLAT_C * local spacing
TANGENT_JITTER = (0.2, 0.12)  # log-scale jitter: shared by both tangent axes, per axis
FLAT_GAP = (1.5, 2.5)  # normal-axis log-scale below the smaller tangent one
LOW_OPACITY_FRACTION = 0.12
HIGH_OPACITY = (0.9, 0.99)
LOW_OPACITY = (0.05, 0.5)
SH_REST_SD = (0.02, 0.012, 0.008)  # per-degree noise (degree 1, 2, 3)
SHEEN = 0.045  # degree-1 normal-aligned coefficient for gloss = 1


# --------------------------------------------------------------------------------------------
# Parts: batches of instances of one surface kind.
# --------------------------------------------------------------------------------------------


@dataclass
class _Part:
    """A batch of `I` instances of one surface kind.

    `origin` [I, 3] and `frame` [I, 3, 3] (columns e1, e2, e3; e3 = the local "up"/normal axis)
    place each instance; `params` holds per-instance shape parameters [I]; `colour` [I, 3] is
    the base colour. `texture(ctx)` may modify the per-sample colours. `cap` [I, 2] bounds the
    tangent sigmas (thin parts). `weight` scales the sampling density; `gloss` the sheen.
    """

    name: str
    kind: str
    origin: np.ndarray
    frame: np.ndarray
    params: dict
    colour: np.ndarray
    weight: float = 1.0
    gloss: float = 0.0
    cap: np.ndarray | None = None
    texture: Callable | None = None
    noise: float = 0.04
    areas: np.ndarray = field(init=False)

    def __post_init__(self):
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(-1, 3)
        count = self.origin.shape[0]
        self.frame = np.broadcast_to(np.asarray(self.frame, dtype=np.float64), (count, 3, 3)).copy()
        self.params = {
            k: np.broadcast_to(np.asarray(v, dtype=np.float64), (count,)).copy() for k, v in self.params.items()
        }
        self.colour = np.broadcast_to(np.asarray(self.colour, dtype=np.float64), (count, 3)).copy()
        if self.cap is not None:
            self.cap = np.broadcast_to(np.asarray(self.cap, dtype=np.float64), (count, 2)).copy()
        self.areas = _AREA[self.kind](self.params)

    @property
    def area(self) -> float:
        return float(self.areas.sum())


def _area_quad(p):
    return 4.0 * p["hx"] * p["hy"]


def _area_disk(p):
    return np.pi * (p["r1"] ** 2 - p["r0"] ** 2)


def _area_sphere(p):
    return 4.0 * np.pi * p["r"] ** 2


def _area_frustum(p):
    return np.pi * (p["r0"] + p["r1"]) * np.hypot(p["h"], p["r1"] - p["r0"])


def _area_torus(p):
    return 4.0 * np.pi**2 * p["R"] * p["r"]


def _area_leaf(p):
    return 4.0 * p["w"] * p["l"] / np.pi


_AREA = {
    "quad": _area_quad,
    "disk": _area_disk,
    "sphere": _area_sphere,
    "frustum": _area_frustum,
    "torus": _area_torus,
    "leaf": _area_leaf,
}


# Samplers: (params gathered per sample, rng, m) -> local point, local normal, local tangent hint
# (or None: random in-plane orientation), uv texture coordinates.


def _sample_quad(p, rng, m):
    u = rng.random((m, 2)) * 2.0 - 1.0
    loc = np.stack([u[:, 0] * p["hx"], u[:, 1] * p["hy"], np.zeros(m)], axis=1)
    nrm = np.broadcast_to([0.0, 0.0, 1.0], (m, 3))
    return loc, nrm, None, u


def _sample_disk(p, rng, m):
    u = rng.random((m, 2))
    r = np.sqrt(p["r0"] ** 2 + u[:, 0] * (p["r1"] ** 2 - p["r0"] ** 2))
    phi = 2.0 * np.pi * u[:, 1]
    loc = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(m)], axis=1)
    nrm = np.broadcast_to([0.0, 0.0, 1.0], (m, 3))
    return loc, nrm, None, np.stack([r / p["r1"], u[:, 1]], axis=1)


def _sample_sphere(p, rng, m):
    u = rng.random((m, 2))
    z = 2.0 * u[:, 0] - 1.0
    phi = 2.0 * np.pi * u[:, 1]
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    nrm = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    return nrm * p["r"][:, None], nrm, None, np.stack([u[:, 1], z], axis=1)


def _sample_frustum(p, rng, m):
    """Side of a truncated cone (radius r0 at local z=0, r1 at z=h); area-uniform; `flip` > 0
    turns the normals inwards (inner wall of a pot)."""
    u = rng.random((m, 2))
    r0, r1, h = p["r0"], p["r1"], p["h"]
    a = 0.5 * (r1 - r0)
    c = u[:, 0] * 0.5 * (r0 + r1)
    t = 2.0 * c / np.maximum(r0 + np.sqrt(np.maximum(r0 * r0 + 4.0 * a * c, 0.0)), 1e-30)
    t = np.clip(t, 0.0, 1.0)
    r = r0 + (r1 - r0) * t
    phi = 2.0 * np.pi * u[:, 1]
    cp, sp = np.cos(phi), np.sin(phi)
    loc = np.stack([r * cp, r * sp, h * t], axis=1)
    nrm = np.stack([h * cp, h * sp, -(r1 - r0) * np.ones(m)], axis=1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm *= np.where(p["flip"] > 0, -1.0, 1.0)[:, None]
    hint = np.stack([(r1 - r0) * cp, (r1 - r0) * sp, h], axis=1)
    hint /= np.linalg.norm(hint, axis=1, keepdims=True)
    return loc, nrm, hint, np.stack([u[:, 1], t], axis=1)


def _sample_torus(p, rng, m):
    R, r = p["R"], p["r"]
    u = rng.random(m)
    v = np.empty(m)
    todo = np.arange(m)
    while todo.size:  # rejection sampling of the tube angle: density ∝ R + r cos v
        cand = 2.0 * np.pi * rng.random(todo.size)
        keep = rng.random(todo.size) * (R[todo] + r[todo]) < R[todo] + r[todo] * np.cos(cand)
        v[todo[keep]] = cand[keep]
        todo = todo[~keep]
    phi = 2.0 * np.pi * u
    nrm = np.stack([np.cos(v) * np.cos(phi), np.cos(v) * np.sin(phi), np.sin(v)], axis=1)
    rho = R + r * np.cos(v)
    loc = np.stack([rho * np.cos(phi), rho * np.sin(phi), r * np.sin(v)], axis=1)
    return loc, nrm, None, np.stack([u, v / (2.0 * np.pi)], axis=1)


def _sample_leaf(p, rng, m):
    """Lanceolate leaf along local x (length l, half-width w * sin(pi s)), bent by `bend`
    (droop along the length) and `curl` (cupped across), area-uniform in the flat layout."""
    u = rng.random((m, 2))
    s = np.arccos(1.0 - 2.0 * u[:, 0]) / np.pi
    t = 2.0 * u[:, 1] - 1.0
    x = s * p["l"]
    y = t * p["w"] * np.sin(np.pi * s)
    z = p["bend"] * x * x / p["l"] + p["curl"] * y * y / p["w"]
    nrm = np.stack([-2.0 * p["bend"] * x / p["l"], -2.0 * p["curl"] * y / p["w"], np.ones(m)], axis=1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return np.stack([x, y, z], axis=1), nrm, None, np.stack([s, t], axis=1)


_SAMPLE = {
    "quad": _sample_quad,
    "disk": _sample_disk,
    "sphere": _sample_sphere,
    "frustum": _sample_frustum,
    "torus": _sample_torus,
    "leaf": _sample_leaf,
}


# --------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------


def _normalize(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(e3, e1_hint=None):
    """[..., 3, 3] right-handed frames with columns (e1, e2, e3); e1 follows `e1_hint`
    projected onto the plane normal to e3 (or any perpendicular when no hint)."""
    e3 = _normalize(e3)
    if e1_hint is None:
        e1_hint = np.where(np.abs(e3[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1_hint = np.broadcast_to(np.asarray(e1_hint, dtype=np.float64), e3.shape)
    e1 = e1_hint - np.sum(e1_hint * e3, axis=-1, keepdims=True) * e3
    bad = np.linalg.norm(e1, axis=-1) < 1e-9
    if np.any(bad):
        alt = np.where(np.abs(e3[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        alt = alt - np.sum(alt * e3, axis=-1, keepdims=True) * e3
        e1 = np.where(bad[..., None], alt, e1)
    e1 = _normalize(e1)
    e2 = np.cross(e3, e1)
    return np.stack([e1, e2, e3], axis=-1)


class _Noise:
    """Smooth procedural noise: a fixed sum of random plane waves (deterministic per seed)."""

    def __init__(self, seed: int, freq: float, octaves: int = 6):
        rng = np.random.default_rng(seed)
        dirs = _normalize(rng.standard_normal((octaves, 3)))
        f = freq * 1.7 ** np.arange(octaves)
        self.k = dirs * f[:, None]
        self.phase = rng.random(octaves) * 2.0 * np.pi
        self.amp = 0.6 ** np.arange(octaves)
        self.amp /= np.sqrt(np.sum(self.amp**2) / 2.0)  # unit standard deviation

    def __call__(self, p):
        arg = np.asarray(p, dtype=np.float32) @ self.k.T.astype(np.float32) + self.phase.astype(np.float32)
        return (np.sin(arg, out=arg) @ self.amp.astype(np.float32)).astype(np.float64)


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# --------------------------------------------------------------------------------------------
# Scene layouts (fixed per scene name)
# --------------------------------------------------------------------------------------------

Z = np.array([0.0, 0.0, 1.0])
EYE3 = np.eye(3)

SPHERES_BASE_TOP = -0.42  # z of the platform top of the "spheres" scene (tests use it)


def _layout_spheres() -> list[_Part]:
    top, thick, rb = SPHERES_BASE_TOP, 0.12, 1.0
    noise = _Noise(11, 3.0)
    parts = []

    def checker(ctx):
        p = ctx["pts"]
        cell = (np.floor(p[:, 0] / 0.25) + np.floor(p[:, 1] / 0.25)) % 2
        light, dark = np.array([0.80, 0.79, 0.74]), np.array([0.36, 0.42, 0.52])
        col = np.where(cell[:, None] > 0, light, dark)
        r = np.hypot(p[:, 0], p[:, 1])
        ring = _smoothstep(0.035, 0.0, np.abs(r - 0.93))  # a dark ring near the rim
        return col * (1.0 - 0.6 * ring[:, None]) * (1.0 + 0.03 * noise(p))[:, None]

    parts.append(_Part("base_top", "disk", [0, 0, top], EYE3, {"r0": 0.0, "r1": rb}, [0.6, 0.6, 0.6], texture=checker))
    parts.append(
        _Part(
            "base_side",
            "frustum",
            [0, 0, top - thick],
            EYE3,
            {"r0": rb, "r1": rb, "h": thick, "flip": 0.0},
            [0.22, 0.23, 0.27],
            gloss=0.3,
        )
    )

    def marble(ctx):
        p = ctx["pts"]
        v = 0.5 + 0.5 * np.sin(9.0 * p[:, 0] + 4.0 * noise(p * 1.5))
        return ctx["colour"] * (0.7 + 0.45 * v[:, None])

    def gores(ctx):  # beach-ball stripes around the local pole
        lp = ctx["local"]
        k = np.floor(4.0 * (np.arctan2(lp[:, 1], lp[:, 0]) / np.pi + 1.0)) % 2
        white = np.array([0.95, 0.95, 0.93])
        col = np.where(k[:, None] > 0, ctx["colour"], white)
        cap = np.abs(ctx["uv"][:, 1]) > 0.93
        return np.where(cap[:, None], np.array([0.9, 0.85, 0.2]), col)

    def speckle(ctx):
        v = noise(ctx["pts"] * 4.0)
        return ctx["colour"] * (1.0 + 0.12 * v[:, None])

    tilt = _frame(_normalize([0.3, -0.5, 1.0]))
    spheres = [  # name, centre xy, radius, colour, gloss, texture, frame
        ("red", (0.35, -0.25), 0.40, (0.85, 0.14, 0.12), 1.0, speckle, EYE3),
        ("blue", (-0.45, -0.35), 0.28, (0.14, 0.32, 0.85), 0.3, gores, tilt),
        ("yellow", (-0.08, 0.14), 0.17, (0.95, 0.78, 0.12), 0.5, speckle, EYE3),
        ("green", (0.55, 0.45), 0.24, (0.22, 0.68, 0.36), 0.6, marble, EYE3),
    ]
    for name, (x, y), r, col, gloss, tex, fr in spheres:
        parts.append(_Part(name, "sphere", [x, y, top + r], fr, {"r": r}, col, gloss=gloss, texture=tex))
    # a small magenta sphere resting on top of the red one
    parts.append(
        _Part(
            "magenta",
            "sphere",
            [0.35, -0.25, top + 0.80 + 0.15],
            EYE3,
            {"r": 0.15},
            [0.80, 0.25, 0.65],
            gloss=0.5,
            texture=speckle,
        )
    )
    # a gold torus standing upright
    R, r = 0.28, 0.085
    axis = _normalize([1.0, -1.0, 0.0])
    parts.append(
        _Part(
            "torus",
            "torus",
            [-0.42, 0.42, top + R + r],
            _frame(axis, Z),
            {"R": R, "r": r},
            [0.92, 0.66, 0.22],
            gloss=1.0,
            texture=speckle,
        )
    )
    return parts


BLOCKS_PITCH = 0.16
BLOCKS_PLATE = 0.064
BLOCKS_BRICK = 0.192
_LEGO = np.array(
    [
        [0.78, 0.10, 0.10],
        [0.05, 0.34, 0.75],
        [0.98, 0.80, 0.10],
        [0.14, 0.55, 0.22],
        [0.95, 0.95, 0.93],
        [0.12, 0.12, 0.14],
        [0.95, 0.50, 0.10],
        [0.55, 0.75, 0.90],
        [0.62, 0.64, 0.66],
        [0.45, 0.25, 0.15],
        [0.80, 0.35, 0.60],
        [0.60, 0.80, 0.20],
    ]
)


def _brick_grid(nx=10, layers=5):
    """Random stacked bricks on a plate: an id per voxel (-1 empty; 0 = the base plate)."""
    rng = np.random.default_rng(20240611)
    occ = -np.ones((nx, nx, layers + 1), dtype=np.int64)
    occ[:, :, 0] = 0
    colours = [np.array([0.25, 0.55, 0.30])]
    sizes = [(2, 4), (2, 3), (2, 2), (1, 4), (1, 3), (1, 2), (2, 6), (1, 1)]
    next_id = 1
    for z in range(1, layers + 1):
        lo, hi = (1, nx - 1) if z == 1 else (1 + (z - 1) // 2, nx - 1 - (z - 1) // 2)
        tries = 220 if z == 1 else 160
        for _ in range(tries):
            a, b = sizes[rng.integers(len(sizes))]
            if rng.random() < 0.5:
                a, b = b, a
            x0 = rng.integers(lo, max(lo + 1, hi - a + 1))
            y0 = rng.integers(lo, max(lo + 1, hi - b + 1))
            if x0 + a > hi or y0 + b > hi:
                continue
            cells = occ[x0 : x0 + a, y0 : y0 + b, z]
            below = occ[x0 : x0 + a, y0 : y0 + b, z - 1]
            if np.any(cells >= 0) or np.mean(below >= 0) < (1.0 if z == 1 else 0.6):
                continue
            occ[x0 : x0 + a, y0 : y0 + b, z] = next_id
            colours.append(_LEGO[rng.integers(len(_LEGO))] * (0.92 + 0.16 * rng.random()))
            next_id += 1
    return occ, np.array(colours)


def _layout_blocks() -> list[_Part]:
    occ, brick_col = _brick_grid()
    nx, ny, nz = occ.shape
    p = BLOCKS_PITCH
    z_edges = np.concatenate([[0.0], BLOCKS_PLATE + BLOCKS_BRICK * np.arange(nz)]) - 0.55
    x_edges = (np.arange(nx + 1) - nx / 2) * p
    padded = -np.ones((nx + 2, ny + 2, nz + 2), dtype=np.int64)
    padded[1:-1, 1:-1, 1:-1] = occ

    def nb(ix, iy, iz, d):
        return padded[ix + 1 + d[0], iy + 1 + d[1], iz + 1 + d[2]]

    ix, iy, iz = np.nonzero(occ >= 0)
    ids = occ[ix, iy, iz]
    cx = 0.5 * (x_edges[ix] + x_edges[ix + 1])
    cy = 0.5 * (x_edges[iy] + x_edges[iy + 1])
    z0, z1 = z_edges[iz], z_edges[iz + 1]
    cz = 0.5 * (z0 + z1)
    hz = 0.5 * (z1 - z0)
    origins, frames, hx, hy, flags, cols = [], [], [], [], [], []
    dirs = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1)]  # bottoms are never seen
    for d in dirs:
        d = np.array(d)
        free = nb(ix, iy, iz, d) < 0
        if not np.any(free):
            continue
        n = d.astype(np.float64)
        if d[2] != 0:
            e1 = np.array([1.0, 0.0, 0.0])
            half = (np.full(free.sum(), p / 2), np.full(free.sum(), p / 2))
            o = np.stack([cx, cy, z1], axis=1)[free]
        else:
            e1 = np.cross(Z, n)  # horizontal tangent; e2 = n x e1 = +z
            half = (np.full(free.sum(), p / 2), hz[free])
            o = np.stack([cx + n[0] * p / 2, cy + n[1] * p / 2, cz], axis=1)[free]
        fr = _frame(n, e1)
        e2 = fr[:, 1]
        # seams: flag the face edges where the neighbouring voxel belongs to another brick
        fl = []
        for e in (-e1, e1, -e2, e2):
            di = np.rint(e).astype(int)
            fl.append(nb(ix[free], iy[free], iz[free], di) != ids[free])
        origins.append(o)
        frames.append(np.broadcast_to(fr, (o.shape[0], 3, 3)))
        hx.append(half[0])
        hy.append(half[1])
        flags.append(np.stack(fl, axis=1))
        cols.append(brick_col[ids[free]])
    flags = np.concatenate(flags).astype(np.float64)
    noise = _Noise(23, 6.0)

    def seams(ctx):
        uv = ctx["uv"]
        f = flags[ctx["inst"]]
        dist = np.stack([uv[:, 0] + 1.0, 1.0 - uv[:, 0], uv[:, 1] + 1.0, 1.0 - uv[:, 1]], axis=1)
        dist = dist * np.stack([ctx["p"]["hx"], ctx["p"]["hx"], ctx["p"]["hy"], ctx["p"]["hy"]], axis=1)
        edge = np.max(f * _smoothstep(0.012, 0.0, dist), axis=1)
        return ctx["colour"] * (1.0 - 0.55 * edge)[:, None] * (1.0 + 0.03 * noise(ctx["pts"]))[:, None]

    parts = [
        _Part(
            "faces",
            "quad",
            np.concatenate(origins),
            np.concatenate(frames),
            {"hx": np.concatenate(hx), "hy": np.concatenate(hy)},
            np.concatenate(cols),
            gloss=0.6,
            texture=seams,
        )
    ]
    # studs on every free top
    top_free = nb(ix, iy, iz, (0, 0, 1)) < 0
    so = np.stack([cx, cy, z1], axis=1)[top_free]
    sc = brick_col[ids[top_free]]
    rs, hs = 0.3 * p, 0.034
    parts.append(
        _Part(
            "stud_sides",
            "frustum",
            so,
            EYE3,
            {"r0": rs, "r1": rs, "h": hs, "flip": 0.0},
            sc * 0.9,
            gloss=0.8,
            cap=[0.5 * hs, np.inf],
        )
    )
    parts.append(
        _Part(
            "stud_tops",
            "disk",
            so + [0.0, 0.0, hs],
            EYE3,
            {"r0": 0.0, "r1": rs},
            sc,
            gloss=0.6,
            texture=lambda ctx: ctx["colour"] * (1.0 - 0.25 * _smoothstep(0.75, 1.0, ctx["uv"][:, 0]))[:, None],
        )
    )
    return parts


PLANT_SOIL = -0.52


def _layout_plant() -> list[_Part]:
    rng = np.random.default_rng(77)
    noise = _Noise(31, 4.0)
    parts = []
    zb, zt, rbot, rtop = -1.0, -0.45, 0.30, 0.42
    band = _Noise(5, 8.0)

    def terracotta(ctx):
        z = ctx["pts"][:, 2]
        stripe = _smoothstep(0.012, 0.0, np.abs(z - (zt - 0.09)))  # a darker groove below the rim
        return ctx["colour"] * (1.0 - 0.35 * stripe[:, None]) * (1.0 + 0.05 * band(ctx["pts"]))[:, None]

    parts.append(
        _Part(
            "pot",
            "frustum",
            [0, 0, zb],
            EYE3,
            {"r0": rbot, "r1": rtop, "h": zt - zb, "flip": 0.0},
            [0.74, 0.38, 0.22],
            texture=terracotta,
            gloss=0.2,
        )
    )
    rin = rbot + (rtop - rbot) * (PLANT_SOIL - zb) / (zt - zb) - 0.03
    parts.append(
        _Part(
            "pot_inner",
            "frustum",
            [0, 0, PLANT_SOIL],
            EYE3,
            {"r0": rin, "r1": rtop - 0.03, "h": zt - PLANT_SOIL, "flip": 1.0},
            [0.55, 0.27, 0.16],
        )
    )
    parts.append(
        _Part(
            "rim",
            "torus",
            [0, 0, zt],
            EYE3,
            {"R": rtop - 0.012, "r": 0.03},
            [0.78, 0.42, 0.25],
            texture=terracotta,
            gloss=0.3,
        )
    )

    def soil(ctx):
        v = noise(ctx["pts"] * 6.0)
        grit = np.sin(ctx["pts"][:, 0] * 173.0) * np.sin(ctx["pts"][:, 1] * 191.0)
        return ctx["colour"] * (1.0 + 0.25 * v + 0.15 * grit)[:, None]

    parts.append(
        _Part(
            "soil",
            "disk",
            [0, 0, PLANT_SOIL],
            EYE3,
            {"r0": 0.0, "r1": rin},
            [0.26, 0.17, 0.11],
            texture=soil,
            weight=0.6,
        )
    )

    # stems and twigs: chains of tapering frusta; leaves at their upper nodes
    seg_o, seg_ax, seg_r0, seg_r1, seg_h = [], [], [], [], []
    leaf_nodes = []  # (position, branch direction)

    def grow(start, direction, length, nseg, r0, r1, droop, spawn):
        pos, d = np.array(start, float), _normalize(direction)
        for i in range(nseg):
            h = length / nseg
            ra = r0 + (r1 - r0) * i / nseg
            rb = r0 + (r1 - r0) * (i + 1) / nseg
            seg_o.append(pos.copy())
            seg_ax.append(d.copy())
            seg_r0.append(ra)
            seg_r1.append(rb)
            seg_h.append(h)
            pos = pos + d * h
            horiz = _normalize(d * [1, 1, 0] + 1e-6)
            d = _normalize(d + droop * (horiz * 0.6 - Z * 0.4) + 0.12 * rng.standard_normal(3))
            frac = (i + 1) / nseg
            if frac > 0.35:
                leaf_nodes.append((pos.copy(), d.copy(), 3 + int(rng.integers(3))))
            if spawn and 0.3 < frac < 0.85 and rng.random() < 0.45:
                side = _normalize(np.cross(d, Z) * (1 if rng.random() < 0.5 else -1) + 0.3 * d + 0.2 * Z)
                grow(pos, side, 0.22 + 0.18 * rng.random(), 4, rb * 0.8, 0.004, 0.35, False)

    nstem = 8
    for k in range(nstem):
        az = 2 * np.pi * k / nstem + 0.4 * rng.random()
        rad = 0.03 + 0.09 * rng.random()
        start = [rad * np.cos(az), rad * np.sin(az), PLANT_SOIL - 0.02]
        tilt = 0.08 + 0.3 * rng.random()
        direction = [np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
        grow(start, direction, 1.0 + 0.5 * rng.random(), 11, 0.02, 0.006, 0.05 + 0.06 * rng.random(), True)

    seg_ax = np.array(seg_ax)
    parts.append(
        _Part(
            "stems",
            "frustum",
            np.array(seg_o),
            _frame(seg_ax),
            {"r0": np.array(seg_r0), "r1": np.array(seg_r1), "h": np.array(seg_h), "flip": 0.0},
            [0.36, 0.27, 0.15],
            weight=1.5,
            cap=np.stack([np.full(len(seg_r0), np.inf), 0.8 * np.array(seg_r1)], axis=1),
            texture=lambda ctx: ctx["colour"] * (1.0 + 0.15 * noise(ctx["pts"] * 5.0))[:, None],
        )
    )

    lo, le1, le3, ll, lw, lbend, lcurl, lcol = [], [], [], [], [], [], [], []
    for pos, d, count in leaf_nodes:
        for _ in range(count):
            az = 2 * np.pi * rng.random()
            side = _normalize(np.cross(d, [np.cos(az), np.sin(az), 0.3]))
            droop = -0.2 + 0.9 * rng.random()
            e1 = _normalize(side + 0.5 * d - droop * Z)
            e3 = _normalize(Z - np.dot(Z, e1) * e1 + 0.35 * rng.standard_normal(3))
            lo.append(pos + 0.01 * side)
            le1.append(e1)
            le3.append(e3)
            ll.append(0.10 + 0.09 * rng.random())
            lw.append(0.022 + 0.02 * rng.random())
            lbend.append(-0.05 - 0.15 * rng.random())
            lcurl.append(-0.1 - 0.2 * rng.random())
            g = rng.random()
            lcol.append(np.array([0.10 + 0.18 * g, 0.36 + 0.28 * g, 0.08 + 0.10 * rng.random()]))
    lw = np.array(lw)

    def veins(ctx):
        s, t = ctx["uv"][:, 0], ctx["uv"][:, 1]
        rib = _smoothstep(0.12, 0.0, np.abs(t)) * (1.0 - s)
        side_veins = 0.5 + 0.5 * np.cos(2 * np.pi * (7.0 * s - 2.5 * np.abs(t)))
        tip = _smoothstep(0.7, 1.0, s)
        col = ctx["colour"] * (1.0 + 0.45 * rib - 0.10 * side_veins + 0.15 * tip)[:, None]
        return col + np.array([0.05, 0.06, 0.0]) * rib[:, None]

    e1 = np.array(le1)
    parts.append(
        _Part(
            "leaves",
            "leaf",
            np.array(lo),
            _frame(np.array(le3), e1),
            {"l": np.array(ll), "w": lw, "bend": np.array(lbend), "curl": np.array(lcurl)},
            np.array(lcol),
            weight=2.0,
            gloss=0.7,
            cap=np.stack([0.4 * lw, 0.4 * lw], axis=1),
            texture=veins,
        )
    )
    return parts


@dataclass(frozen=True)
class SceneSpec:
    """A registered scene: its layout builder and the orbit that frames it (`scene_cameras`)."""

    name: str
    description: str
    layout: Callable[[], list]
    radius: float = 4.0
    elevation_deg: float = 25.0
    fov_x_deg: float = 40.0
    target: tuple = (0.0, 0.0, 0.0)


SCENES: dict[str, SceneSpec] = {
    "spheres": SceneSpec(
        "spheres",
        "smooth surfaces: coloured spheres and a torus on a checkered platform",
        _layout_spheres,
        target=(0.0, 0.0, 0.05),
    ),
    "blocks": SceneSpec(
        "blocks", "high-frequency blocky geometry: lego-like stacked bricks on a plate", _layout_blocks
    ),
    "plant": SceneSpec(
        "plant", "thin structures: stems and many small thin leaves in a pot", _layout_plant, target=(0.0, 0.0, -0.05)
    ),
}


def list_scenes() -> list[str]:
    """Every scene name: the procedural scenes, then the real captures (model/captures.py)."""
    return list(SCENES) + list(CAPTURES)


def is_capture(name) -> bool:
    return isinstance(name, str) and name in CAPTURES


def scene_description(name: str) -> str:
    return CAPTURES[name].description if is_capture(name) else scene_spec(name).description


def scene_spec(name) -> SceneSpec:
    if not isinstance(name, str) or name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; valid scenes: {', '.join(list_scenes())}")
    return SCENES[name]


@cache
def _parts(name: str) -> tuple:
    return tuple(scene_spec(name).layout())


def scene_cameras(name: str, k: int, width: int, height: int) -> list[Camera]:
    """`k` orbit cameras (evenly spaced azimuths) that frame the scene: a procedural scene's
    registered orbit (z up), or for a real capture the robust framing of model/framing.py (y up)."""
    if is_capture(name):
        return orbit_views(capture_model(name).means, k, width, height, up=CAPTURE_UP)
    s = scene_spec(name)
    return orbit_cameras(
        k, width, height, radius=s.radius, elevation_deg=s.elevation_deg, fov_x_deg=s.fov_x_deg, target=s.target
    )


def _allocate(weights: np.ndarray, n: int) -> np.ndarray:
    """Exactly n samples shared in proportion to weights (largest remainder, ties by index)."""
    quota = n * weights / weights.sum()
    counts = np.floor(quota).astype(np.int64)
    rest = n - int(counts.sum())
    if rest > 0:
        order = np.lexsort((np.arange(len(quota)), -(quota - counts)))
        counts[order[:rest]] += 1
    return counts


def _approx_normal(rng, shape) -> np.ndarray:
    """float32 noise of unit variance, ~2x cheaper than standard_normal: the sum of three
    uniform bytes (Irwin-Hall, bounded at 3 sd). Used for the bulky sh_rest field."""
    count = int(np.prod(shape))
    b = np.frombuffer(rng.bytes(3 * count), dtype=np.int8).reshape(3, count)
    acc = b[0].astype(np.int16)
    acc += b[1]
    acc += b[2]
    out = acc.astype(np.float32)
    out *= np.float32(1.0 / 128.0)  # sd of the sum is 128.0 (3 * (256^2 - 1) / 12 = 127.998^2)
    return out.reshape(shape)


def _logit(p):
    return np.log(p / (1.0 - p))


def make_scene(name: str = DEFAULT_SCENE, n: int | None = None, sh_degree: int = 3, seed: int = 0) -> Model:
    """A trained-looking 3DGS model of scene `name` with exactly `n` primitives (module docs;
    default 100,000), or a real capture: all its splats, or a seeded subset of `n`."""
    if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer))):
        raise ValueError(f"n must be an integer, got {n!r}")
    if n is not None and n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    nrest = sh_rest_count(int(sh_degree))
    if is_capture(name):
        return capture_model(name, None if n is None else int(n), int(sh_degree), seed)
    spec = scene_spec(name)
    n = DEFAULT_N if n is None else int(n)
    check_scene(n, int(sh_degree))
    parts = _parts(spec.name)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed) % (1 << 64), zlib.crc32(name.encode()), 0x3D65]))
    counts = _allocate(np.array([p.area * p.weight for p in parts]), n)

    # The primitives come out in a random order (trained models are not sorted by part, and a
    # prefix is then a fair subsample): each slot gets a part label (exact counts, shuffled) and
    # each part fills its slots in increasing order with iid samples. Parts are processed in
    # chunks so that the temporaries stay small (4M primitives at degree 3 is ~1 GB of output).
    labels = np.repeat(np.arange(len(parts), dtype=np.int16), counts)[rng.permutation(n)]
    out = {
        "means": np.empty((n, 3), np.float32),
        "log_scales": np.empty((n, 3), np.float32),
        "quats": np.empty((n, 4), np.float32),
        "opacity": np.empty(n, np.float32),
        "sh_dc": np.empty((n, 3), np.float32),
        "sh_rest": np.empty((n, nrest, 3), np.float32),
    }
    for k, (part, m) in enumerate(zip(parts, counts)):
        if m == 0:
            continue
        slots = np.flatnonzero(labels == k)
        spacing = np.sqrt(part.area / int(m))
        for lo in range(0, int(m), _CHUNK):
            dest = slots[lo : lo + _CHUNK]
            for key, val in _sample_part(part, spacing, dest.size, rng, nrest).items():
                out[key][dest] = val
    return Model(**out)


_CHUNK = 1 << 16


def _sample_part(part: _Part, spacing: float, m: int, rng, nrest: int) -> dict:
    """`m` primitives on `part` (local spacing `spacing`): the Model fields of those rows."""
    cum = np.cumsum(part.areas)
    inst = np.minimum(np.searchsorted(cum, rng.random(m) * cum[-1], side="right"), len(cum) - 1)
    p = {k: v[inst] for k, v in part.params.items()}
    loc, lnrm, lhint, uv = _SAMPLE[part.kind](p, rng, m)
    F = part.frame[inst]
    pts = part.origin[inst] + np.einsum("mij,mj->mi", F, loc)
    nrm = np.einsum("mij,mj->mi", F, lnrm)
    # tangent frame: along the hint (stems, studs) with a little jitter, else random in-plane
    if lhint is not None:
        t1 = _normalize(np.einsum("mij,mj->mi", F, lhint) + 0.15 * rng.standard_normal((m, 3)))
    else:
        t1 = rng.standard_normal((m, 3))
    fr = _frame(nrm, t1)
    nrm = fr[:, :, 2]

    # scales: tangent sigmas from the local spacing, the normal axis much thinner
    base = np.log(SPLAT_C * spacing) + TANGENT_JITTER[0] * rng.standard_normal(m)
    logs = np.empty((m, 3))
    logs[:, :2] = base[:, None] + TANGENT_JITTER[1] * rng.standard_normal((m, 2))
    if part.cap is not None:
        np.minimum(logs[:, :2], np.log(part.cap[inst]), out=logs[:, :2])
    logs[:, 2] = logs[:, :2].min(axis=1) - rng.uniform(*FLAT_GAP, size=m)

    # opacity: mostly high, a faint tail that is a bit larger and fuzzier (off the surface)
    low = rng.random(m) < LOW_OPACITY_FRACTION
    u = rng.random(m)
    hi_l, lo_l = _logit(np.array(HIGH_OPACITY)), _logit(np.array(LOW_OPACITY))
    opacity = np.where(low, lo_l[0] + (lo_l[1] - lo_l[0]) * u, hi_l[0] + (hi_l[1] - hi_l[0]) * u**0.7)
    offset = rng.standard_normal(m) * spacing * np.where(low, 0.3, 0.05)
    pts = pts + nrm * offset[:, None]
    logs[low] += 0.35

    # quaternion: the frame (t1, t2, normal) with a small wobble and a near-unit norm
    q = rotmat_to_quat(fr) + 0.01 * rng.standard_normal((m, 4))
    q *= (np.exp(0.03 * rng.standard_normal(m)) / np.linalg.norm(q, axis=1))[:, None]

    # colour: base colour, procedural texture, per-primitive noise
    ctx = {"pts": pts, "local": loc, "uv": uv, "inst": inst, "p": p, "colour": part.colour[inst]}
    col = part.texture(ctx) if part.texture is not None else ctx["colour"]
    col = col * (1.0 + part.noise * rng.standard_normal((m, 1))) + 0.015 * rng.standard_normal((m, 3))
    sh_dc = (np.clip(col, 0.01, 0.99) - 0.5) / C0

    # sh_rest: always drawn for degree 3 so that lower degrees are prefixes (same seed)
    sd = np.repeat(np.array(SH_REST_SD, dtype=np.float32), [3, 5, 7])
    rest = _approx_normal(rng, (m, 15, 3))
    rest *= sd[None, :, None]
    if part.gloss:
        a = ((SHEEN * part.gloss) * (1.0 + 0.2 * rng.standard_normal(m)))[:, None] * nrm
        # colour += C1 * (-y s1 + z s2 - x s3) = -C1 * a * dot(dir, n): bright where seen face-on
        rest[:, 0, :] += a[:, 1:2].astype(np.float32)
        rest[:, 1, :] -= a[:, 2:3].astype(np.float32)
        rest[:, 2, :] += a[:, 0:1].astype(np.float32)
    np.clip(rest, -0.1, 0.1, out=rest)
    return {
        "means": pts,
        "log_scales": logs,
        "quats": q,
        "opacity": opacity,
        "sh_dc": sh_dc,
        "sh_rest": rest[:, :nrest],
    }
