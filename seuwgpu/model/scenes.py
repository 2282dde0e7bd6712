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
from dataclasses import dataclass
from functools import cache

import numpy as np

from seuwgpu.model.budget import check_scene
from seuwgpu.model.cameras import Camera, orbit_cameras
from seuwgpu.model.captures import CAPTURES, capture_model
from seuwgpu.model.captures import UP as CAPTURE_UP
from seuwgpu.model.fields import Model, sh_rest_count
from seuwgpu.model.framing import orbit_views
from seuwgpu.model.scene_layouts import layout_blocks, layout_plant, layout_spheres
from seuwgpu.model.scene_sampler import CHUNK, allocate, sample_part

DEFAULT_SCENE = "spheres"
DEFAULT_N = 100_000


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
        layout_spheres,
        target=(0.0, 0.0, 0.05),
    ),
    "blocks": SceneSpec("blocks", "high-frequency blocky geometry: lego-like stacked bricks on a plate", layout_blocks),
    "plant": SceneSpec(
        "plant", "thin structures: stems and many small thin leaves in a pot", layout_plant, target=(0.0, 0.0, -0.05)
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
    counts = allocate(np.array([p.area * p.weight for p in parts]), n)

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
        for lo in range(0, int(m), CHUNK):
            dest = slots[lo : lo + CHUNK]
            for key, val in sample_part(part, spacing, dest.size, rng, nrest).items():
                out[key][dest] = val
    return Model(**out)
