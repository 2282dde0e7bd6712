"""Pinhole cameras (gsplat conventions): `viewmat` is world-to-camera in OpenCV axes
(x right, y down, z forward), `K` in pixels, pixel centres at +0.5.

CAMS.json contract: {"cameras": [{"viewmat": 4x4, "K": 3x3, "width": W, "height": H}, ...]}.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class Camera:
    viewmat: np.ndarray  # [4, 4] world-to-camera
    K: np.ndarray  # [3, 3]
    width: int
    height: int

    def __post_init__(self):
        self.viewmat = np.asarray(self.viewmat, dtype=np.float32).reshape(4, 4)
        self.K = np.asarray(self.K, dtype=np.float32).reshape(3, 3)
        self.width, self.height = int(self.width), int(self.height)
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (np.isfinite(self.viewmat).all() and np.isfinite(self.K).all()):
            raise ValueError("camera viewmat and K must be finite")

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates (float64 for accuracy)."""
        R = self.viewmat[:3, :3].astype(np.float64)
        t = self.viewmat[:3, 3].astype(np.float64)
        return -R.T @ t

    def to_json(self) -> dict:
        return {"viewmat": self.viewmat.tolist(), "K": self.K.tolist(), "width": self.width, "height": self.height}


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World-to-camera matrix (OpenCV axes) for a camera at `eye` looking at `target`."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    if np.linalg.norm(r) < 1e-9:
        r = np.cross(f, np.array([0.0, 1.0, 0.0]))
    r /= np.linalg.norm(r)
    d = np.cross(f, r)  # camera y axis points down in the image
    R = np.stack([r, d, f])  # rows: camera axes in world coordinates
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = -R @ eye
    return M.astype(np.float32)


def intrinsics(width: int, height: int, fov_x_deg: float) -> np.ndarray:
    fx = 0.5 * width / np.tan(np.radians(fov_x_deg) / 2)
    return np.array([[fx, 0, width / 2], [0, fx, height / 2], [0, 0, 1]], dtype=np.float32)


def orbit_cameras(
    k: int,
    width: int,
    height: int,
    radius: float = 4.0,
    elevation_deg: float = 25.0,
    fov_x_deg: float = 40.0,
    target=(0.0, 0.0, 0.0),
    phase_deg: float = 30.0,
) -> list[Camera]:
    """K cameras evenly spaced on a circle around `target` (z up), like NeRF-synthetic test views."""
    cams = []
    el = np.radians(elevation_deg)
    for i in range(k):
        az = np.radians(phase_deg) + 2 * np.pi * i / max(k, 1)
        eye = np.asarray(target) + radius * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(Camera(look_at(eye, target), intrinsics(width, height, fov_x_deg), width, height))
    return cams


def load_cameras(path) -> list[Camera]:
    try:
        data = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(data, dict) or "cameras" not in data:
        raise ValueError(f'{path}: expected {{"cameras": [...]}}')
    cams = []
    for i, c in enumerate(data["cameras"]):
        missing = {"viewmat", "K", "width", "height"} - set(c)
        if missing:
            raise ValueError(f"{path}: camera {i} lacks {', '.join(sorted(missing))}")
        try:
            cams.append(Camera(c["viewmat"], c["K"], c["width"], c["height"]))
        except ValueError as e:
            raise ValueError(f"{path}: camera {i}: {e}") from None
    if not cams:
        raise ValueError(f"{path}: no cameras")
    return cams


def save_cameras(cams: list[Camera], path) -> None:
    Path(path).write_text(json.dumps({"cameras": [c.to_json() for c in cams]}, indent=1))
