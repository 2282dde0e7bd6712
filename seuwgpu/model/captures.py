"""Real trained captures shipped in the package (model/data/, CC0, see its README.md), usable
by name like the procedural scenes: `leica-sofort`, `yashica-t4` and their `-wide` variants.

`widen` puts back what the shipped crops removed, the way real exports look: a far background
shell of large splats (Scaniverse appends ~10k on a sphere of radius ~240) and faint floaters
around the object. It is deterministic (fixed seed per scene) and goes through the SPZ quantiser,
so a widened model is exactly what an SPZ export of it would hold.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import cache
from importlib.resources import files

import numpy as np

from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.formats import spz

SHELL_SPLATS = 1536
SHELL_RADIUS = 240.0
FLOATERS = 256
FLOATER_RANGE = (2.0, 20.0)  # in object radii (the robust region's)
UP = "+y"  # SPZ's RUB axes


@dataclass(frozen=True)
class Capture:
    name: str
    file: str
    description: str
    wide: bool = False


CAPTURES = {}
for _base, _file, _what in (
    ("leica-sofort", "leica-sofort.spz", "an instant camera on a desk"),
    ("yashica-t4", "yashica-t4.spz", "a compact film camera"),
):
    CAPTURES[_base] = Capture(_base, _file, f"real capture (Scaniverse, CC0, 8,192 splats): {_what}")
    CAPTURES[_base + "-wide"] = Capture(
        _base + "-wide",
        _file,
        f"{_base} with a far background shell and floaters added back, as real exports have",
        wide=True,
    )


@cache
def _decoded(file: str) -> tuple[Model, spz.SpzInfo]:
    data = files("seuwgpu.model.data").joinpath(file).read_bytes()
    return spz.decode_spz(data, f"seuwgpu/model/data/{file}")


@cache
def _full(name: str) -> Model:
    c = CAPTURES[name]
    model, _ = _decoded(c.file)
    return widen(model, seed=zlib.crc32(c.name.encode())) if c.wide else model


def capture_antialiased(name: str) -> bool:
    """Whether the capture's SPZ header flags it as trained antialiased (mip-splatting): kept by
    `seuwgpu scene NAME --out X.spz` and noted when the scene is loaded."""
    return _decoded(CAPTURES[name].file)[1].antialiased


def capture_model(name: str, n: int | None = None, sh_degree: int = 3, seed: int = 0) -> Model:
    """The capture `name`: all its splats, or a seeded random subset of `n` in file order; SH
    truncated to `sh_degree` (the lower bands are a prefix)."""
    full = _full(name)
    if n is not None and not 1 <= n <= full.n:
        raise ValueError(f"scene {name} has {full.n} splats; n must be 1..{full.n}, got {n}")
    model = full.sample(n, seed, name) if n is not None else full.copy()
    if sh_degree < model.sh_degree:
        model.sh_rest = np.ascontiguousarray(model.sh_rest[:, : (sh_degree + 1) ** 2 - 1])
    return model


def _fibonacci_sphere(m: int) -> np.ndarray:
    i = np.arange(m) + 0.5
    z = 1.0 - 2.0 * i / m
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _quat_z_to(d: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) rotating +z onto the unit vectors d."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    w = 1.0 + d @ z
    q = np.concatenate([w[:, None], axis], axis=1)
    flip = w < 1e-9  # d == -z: half turn about x
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def widen(model: Model, seed: int = 0) -> Model:
    """`model` plus a far background shell and floaters (module docstring), SPZ-quantised."""
    from seuwgpu.model.framing import bounding_region

    rng = np.random.default_rng(seed)
    region = bounding_region(model.means)
    r_deg = model.sh_rest.shape[1]

    # the shell: flat discs tangent to a sphere, sized to the spacing, opaque, smooth colours
    d = _fibonacci_sphere(SHELL_SPLATS)
    spacing = np.sqrt(4 * np.pi * SHELL_RADIUS**2 / SHELL_SPLATS)
    tangent = np.log(0.9 * spacing) + 0.15 * rng.standard_normal((SHELL_SPLATS, 2))
    shell_scales = np.concatenate([tangent, tangent.min(axis=1, keepdims=True) - 2.0], axis=1)
    k = rng.standard_normal((6, 3))
    tone = 0.5 + 0.12 * np.sin(d @ k[:3].T * 2.0).sum(axis=1) / 3 + 0.05 * rng.standard_normal(SHELL_SPLATS)
    tint = np.array([1.0, 0.96, 0.9])
    shell_rgb = np.clip(tone[:, None] * tint + 0.03 * np.sin(d @ k[3:].T * 3.0), 0.05, 0.95)
    shell = Model(
        means=region.center + SHELL_RADIUS * d,
        log_scales=shell_scales,
        quats=_quat_z_to(d),
        opacity=rng.uniform(2.0, 4.0, SHELL_SPLATS),
        sh_dc=(shell_rgb - 0.5) / 0.28209479177387814,
        sh_rest=np.zeros((SHELL_SPLATS, r_deg, 3)),
    )

    # floaters: faint, larger than the object's splats, log-uniform in distance
    u = rng.standard_normal((FLOATERS, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    lo, hi = np.log(FLOATER_RANGE[0]), np.log(FLOATER_RANGE[1])
    dist = region.radius * np.exp(rng.uniform(lo, hi, FLOATERS))
    q = rng.standard_normal((FLOATERS, 4))
    floaters = Model(
        means=region.center + dist[:, None] * u,
        log_scales=rng.uniform(-5.0, -2.5, (FLOATERS, 3)),
        quats=q / np.linalg.norm(q, axis=1, keepdims=True),
        opacity=-np.log(1 / rng.uniform(0.05, 0.4, FLOATERS) - 1),  # logit of 0.05..0.4
        sh_dc=(rng.uniform(0.2, 0.8, (FLOATERS, 3)) - 0.5) / 0.28209479177387814,
        sh_rest=0.05 * rng.standard_normal((FLOATERS, r_deg, 3)),
    )
    extra = spz.spz_values(Model(**{f: np.concatenate([getattr(shell, f), getattr(floaters, f)]) for f in FIELDS}))
    return Model(**{f: np.concatenate([getattr(model, f), getattr(extra, f)]) for f in FIELDS})
