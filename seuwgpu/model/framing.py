"""Framing a model without cameras: the one rule every command uses (render, inject, campaign,
viewer) for a model file or a real scene; the procedural scenes keep their registered orbits.

The bounding region is robust, made of percentiles, never of min/max, because trained models
carry a far background shell (Scaniverse appends ~10k splats on a sphere 1000x the object's
size), sky splats and floaters that would shrink the object to a dot:
1. centre c0 = the median of the finite means, r50 = the median distance from c0;
2. the core = the means within CORE_FACTOR * r50 of c0 (drops the shell, the sky and far
   floaters however many there are, as long as the object holds most splats);
3. the centre = the middle of the core's per-axis 1st-99th percentile box, the radius = the 98th
   percentile of the core's distances from it.
Orbit views then look at the centre from a distance at which a sphere of 1.1 x that radius fits
the field of view across the shorter image side, so the object is seen whole, not filling the
frame, at any image size. Their up axis is the file format's convention (see model/formats) or
the user's choice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seuwgpu.model.cameras import Camera, look_at

CORE_FACTOR = 5.0
MARGIN = 1.1
AXES = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}
# (e1, e2) per up axis, with e1 x e2 = up; azimuth 0 looks from e1. For +z this is the x/y
# orbit of camera.orbit_cameras; for +y (SPZ's RUB) the first view is from +z (the front);
# for -y (COLMAP's y down) from -z (where the capture's first camera stood, roughly).
_BASES = {
    "+z": ("+x", "+y"),
    "-z": ("+x", "-y"),
    "+y": ("+z", "+x"),
    "-y": ("-z", "+x"),
    "+x": ("+y", "+z"),
    "-x": ("+y", "-z"),
}


def axis_vector(axis: str) -> np.ndarray:
    if axis not in AXES:
        raise ValueError(f"unknown up axis {axis!r}; expected one of {', '.join(AXES)}")
    return np.array(AXES[axis])


def orbit_basis(up: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(e1, e2, up) unit vectors, right-handed, for an up axis named like '+y'."""
    u = axis_vector(up)
    e1, e2 = (axis_vector(a) for a in _BASES[up])
    return e1, e2, u


@dataclass(frozen=True)
class Region:
    """A robust bounding sphere of a model's means."""

    center: np.ndarray
    radius: float
    core_fraction: float  # share of the finite means inside the core


def bounding_region(means: np.ndarray, log_scales: np.ndarray | None = None) -> Region:
    """The robust bounding region of a model's means (see the module docstring). When the means
    span no volume (one primitive, or all of them at one point) and `log_scales` is given, the
    radius is the primitives' own extent, 3 sigma of their largest axis: the means alone gave a
    radius of 1e-3 of the distance from the origin, which put the camera nearer than the
    renderer's near plane (0.01), so such a model rendered as an empty frame."""
    m = np.asarray(means, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(m).all(axis=1)
    m = m[finite]
    if len(m) == 0:
        return Region(np.zeros(3), 1.0, 0.0)
    c0 = np.median(m, axis=0)
    d = np.linalg.norm(m - c0, axis=1)
    r50 = float(np.median(d))
    core = m[d <= CORE_FACTOR * r50] if r50 > 0 else m
    lo, hi = np.percentile(core, [1.0, 99.0], axis=0)
    center = 0.5 * (lo + hi)
    radius = float(np.percentile(np.linalg.norm(core - center, axis=1), 98.0))
    if not radius > 0:
        radius = max(float(np.abs(center).max()) * 1e-3, 1e-3)
        if log_scales is not None:
            with np.errstate(over="ignore"):
                extent = 3.0 * np.exp(np.asarray(log_scales, dtype=np.float64).reshape(-1, 3)[finite].max(axis=1))
            extent = extent[np.isfinite(extent)]
            if len(extent):
                radius = max(radius, float(np.percentile(extent, 98.0)))
    return Region(center, radius, len(core) / len(m))


def framing_distance(radius: float, fov_deg: float) -> float:
    """Camera distance at which a sphere of MARGIN * radius fits the field of view."""
    return MARGIN * radius / np.sin(np.radians(fov_deg) / 2)


def orbit_views(
    means: np.ndarray,
    k: int,
    width: int,
    height: int,
    up: str = "+z",
    elevation_deg: float = 25.0,
    fov_deg: float = 40.0,
    phase_deg: float = 30.0,
    log_scales: np.ndarray | None = None,
) -> list[Camera]:
    """`k` views evenly spaced in azimuth around the model's robust region, `fov_deg` across the
    shorter image side, seeing the object whole at any image size (`log_scales`: see
    bounding_region)."""
    if k < 1:
        raise ValueError(f"need at least one view, got {k}")
    region = bounding_region(means, log_scales)
    dist = framing_distance(region.radius, fov_deg)
    e1, e2, u = orbit_basis(up)
    f = 0.5 * min(width, height) / np.tan(np.radians(fov_deg) / 2)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    el = np.radians(elevation_deg)
    cams = []
    for i in range(k):
        az = np.radians(phase_deg) + 2 * np.pi * i / k
        direction = np.cos(el) * np.cos(az) * e1 + np.cos(el) * np.sin(az) * e2 + np.sin(el) * u
        eye = region.center + dist * direction
        cams.append(Camera(look_at(eye, region.center, u), K, width, height))
    return cams
