"""The surfaces procedural scenes are built of: a `Part` is a batch of instances of one surface
kind (quad, disc, sphere, frustum, torus, leaf) with its areas and its area-uniform sampler, plus
the small geometry helpers the layouts share (surface frames, smooth noise). model/scene_layouts.py places
parts; model/scene_sampler.py turns them into Gaussians."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

# --------------------------------------------------------------------------------------------
# Parts: batches of instances of one surface kind.
# --------------------------------------------------------------------------------------------


@dataclass
class Part:
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


SAMPLERS = {
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


def normalize(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def surface_frame(e3, e1_hint=None):
    """[..., 3, 3] right-handed frames with columns (e1, e2, e3); e1 follows `e1_hint`
    projected onto the plane normal to e3 (or any perpendicular when no hint)."""
    e3 = normalize(e3)
    if e1_hint is None:
        e1_hint = np.where(np.abs(e3[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1_hint = np.broadcast_to(np.asarray(e1_hint, dtype=np.float64), e3.shape)
    e1 = e1_hint - np.sum(e1_hint * e3, axis=-1, keepdims=True) * e3
    bad = np.linalg.norm(e1, axis=-1) < 1e-9
    if np.any(bad):
        alt = np.where(np.abs(e3[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        alt = alt - np.sum(alt * e3, axis=-1, keepdims=True) * e3
        e1 = np.where(bad[..., None], alt, e1)
    e1 = normalize(e1)
    e2 = np.cross(e3, e1)
    return np.stack([e1, e2, e3], axis=-1)


class Noise:
    """Smooth procedural noise: a fixed sum of random plane waves (deterministic per seed)."""

    def __init__(self, seed: int, freq: float, octaves: int = 6):
        rng = np.random.default_rng(seed)
        dirs = normalize(rng.standard_normal((octaves, 3)))
        f = freq * 1.7 ** np.arange(octaves)
        self.k = dirs * f[:, None]
        self.phase = rng.random(octaves) * 2.0 * np.pi
        self.amp = 0.6 ** np.arange(octaves)
        self.amp /= np.sqrt(np.sum(self.amp**2) / 2.0)  # unit standard deviation

    def __call__(self, p):
        arg = np.asarray(p, dtype=np.float32) @ self.k.T.astype(np.float32) + self.phase.astype(np.float32)
        return (np.sin(arg, out=arg) @ self.amp.astype(np.float32)).astype(np.float64)


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
