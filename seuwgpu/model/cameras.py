"""Pinhole cameras (gsplat conventions): `viewmat` is world-to-camera in OpenCV axes
(x right, y down, z forward), `K` in pixels, pixel centres at +0.5.

Camera files (`read_cameras`, recognised by content, views in the file's order):
- seuwgpu CAMS.json: {"cameras": [{"viewmat": 4x4, "K": 3x3, "width": W, "height": H}, ...]}.
- INRIA 3DGS `cameras.json` (graphdeco-inria utils/camera_utils.py `camera_to_JSON`): a list of
  {"img_name", "width", "height", "position", "rotation", "fx", "fy"}; `rotation` is the
  camera-to-world rotation (columns: the camera's x, y, z axes, OpenCV), `position` the camera
  centre; the principal point is the image centre unless a fork adds "cx"/"cy".
- A COLMAP model folder (cameras + images, .bin or .txt; colmap doc/format.rst and
  scripts/python/read_write_model.py): images hold the world-to-camera rotation as a quaternion
  (w, x, y, z) and the translation; views sorted by image name. PINHOLE and SIMPLE_PINHOLE are
  exact; SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV are read with their distortion ignored
  (a warning says so); fisheye and other models are refused. COLMAP's principal point already
  uses pixel centres at +0.5. A folder holding both encodings is read from its .bin files; naming
  one of the files (images.txt) reads that encoding. images.txt gives every image two lines, the
  second its POINTS2D (maybe empty): a file without them is refused, not read every other image.
- nerfstudio `transforms.json` (nerfstudio_dataparser.py): frames[i].transform_matrix is
  camera-to-world in OpenGL axes (x right, y up, z back); intrinsics fl_x, fl_y, cx, cy, w, h at
  the top level (as nerfstudio, these win) or per frame; camera_angle_x stands in for fl_x. The
  poses must be in the model's world: nerfstudio trains in a re-oriented, re-scaled frame
  (dataparser_transforms.json), so apply that transform first for a splatfacto export.
A folder holding cameras.json, transforms.json, a COLMAP model or sparse/0/ is searched for them.
Every camera must be a pinhole the renderer draws as written: a viewmat whose 3x3 part is a
rotation (a uniform scale allowed) and K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (the renderer
reads fx, fy, cx, cy alone, so a skew or a transposed K is refused rather than dropped).
"""

from __future__ import annotations

import json
import struct
import warnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seuwgpu.errors import InputError


def _is_number(x) -> bool:
    """A JSON number: int or float, not a bool (True is no width), None or text."""
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _size(v, what: str) -> int:
    """An image size: a positive integer (an integral float such as 640.0 is accepted; a bool, a
    fraction, None or text is not)."""
    if not _is_number(v) or not (np.isfinite(v) and float(v) == int(v) and v > 0):
        raise InputError(f"camera {what} must be a positive integer, got {v!r}")
    return int(v)


def _matrix(v, shape: tuple, what: str) -> np.ndarray:
    """A finite numeric matrix of `shape` (booleans and text refused)."""
    a = np.asarray(v, dtype=object)
    flat = a.ravel()
    if a.shape != shape and a.size != shape[0] * shape[1]:
        raise InputError(f"camera {what} must be {shape[0]}x{shape[1]} numbers, got shape {a.shape}")
    if not all(_is_number(x) for x in flat):
        raise InputError(f"camera {what} must hold numbers only")
    m = np.asarray(flat.astype(np.float64), dtype=np.float32).reshape(shape)
    if not np.isfinite(m).all():
        raise InputError(f"camera {what} must be finite, got {m.tolist()}")
    return m


@dataclass
class Camera:
    viewmat: np.ndarray  # [4, 4] world-to-camera
    K: np.ndarray  # [3, 3]
    width: int
    height: int

    def __post_init__(self):
        self.width, self.height = _size(self.width, "width"), _size(self.height, "height")
        self.viewmat = _matrix(self.viewmat, (4, 4), "viewmat")
        self.K = _matrix(self.K, (3, 3), "K")
        R = self.viewmat[:3, :3].astype(np.float64)
        # a view matrix maps the world into the camera with determinant > 0: a singular one
        # projects everything onto a plane, a mirrored one flips the image, so either render
        # would quietly be something else. (A uniform scale is left alone: some captures have one.)
        det = float(np.linalg.det(R))
        if not abs(det) > 1e-6:
            raise InputError(f"camera viewmat is singular (rotation determinant {det:.3g})")
        if det < 0:
            raise InputError(f"camera viewmat is mirrored (rotation determinant {det:.3g} < 0)")
        if not np.array_equal(self.viewmat[3], np.array([0, 0, 0, 1], np.float32)):
            raise InputError(f"camera viewmat's last row must be 0 0 0 1, got {self.viewmat[3].tolist()}")
        # a rotation (times a uniform scale): its rows orthogonal and of one length. A sheared or
        # unevenly scaled matrix is no camera pose (a file mixing up rows, or a transform that is
        # not a pose); the renderer would draw it without a word
        gram = R @ R.T / abs(det) ** (2 / 3)
        if not np.allclose(gram, np.eye(3), atol=1e-3):
            raise InputError(
                "camera viewmat's 3x3 part is not a rotation (rows not orthogonal or not of one length): "
                f"{np.round(R, 6).tolist()}"
            )
        # the renderer reads fx, fy, cx, cy alone: anything else in K would be dropped silently
        # (a skew, or a transposed K whose principal point sits in the last row)
        K = self.K
        if not (K[0, 1] == 0 and K[1, 0] == 0 and np.array_equal(K[2], np.array([0, 0, 1], np.float32))):
            raise InputError(
                f"camera K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew; not transposed), got {K.tolist()}"
            )
        fx, fy = float(self.K[0, 0]), float(self.K[1, 1])
        if not (fx > 0 and fy > 0):
            raise InputError(f"camera focal lengths must be positive, got fx={fx:g}, fy={fy:g}")

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates (float64 for accuracy): -R^-1 t. R is a rotation
        times a uniform scale s (__post_init__), so R^-1 = R^T / s^2 with s^2 = |det R|^(2/3); a
        float32 rotation's own rounding (|s^2 - 1| ~ 1e-7) is not divided out, so the centre of an
        unscaled pose is -R^T t bit for bit."""
        R = self.viewmat[:3, :3].astype(np.float64)
        t = self.viewmat[:3, 3].astype(np.float64)
        s2 = abs(float(np.linalg.det(R))) ** (2.0 / 3.0)
        centre = -R.T @ t
        return centre if abs(s2 - 1.0) < 1e-5 else centre / s2

    def to_json(self) -> dict:
        return {"viewmat": self.viewmat.tolist(), "K": self.K.tolist(), "width": self.width, "height": self.height}


class CameraFileError(InputError):
    """A camera file that cannot be read (the message names the file and the problem)."""


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
    """The cameras of any supported camera file or folder (see the module docstring)."""
    return read_cameras(path)[0]


def save_cameras(cams: list[Camera], path) -> None:
    Path(path).write_text(json.dumps({"cameras": [c.to_json() for c in cams]}, indent=1))


def select_views(cams: list[Camera], k: int | None) -> list[Camera]:
    """`k` of the views, evenly spread over the file's order (all of them when k is None or
    not smaller than their number)."""
    if k is None or k >= len(cams):
        return list(cams)
    if k < 1:
        raise ValueError(f"--views must be at least 1, got {k}")
    n = len(cams)
    return [cams[i * n // k] for i in range(k)]


def image_sizes(cams: list[Camera]) -> dict[tuple[int, int], int]:
    """{(width, height): number of views} in the order the sizes first appear."""
    return dict(Counter((c.width, c.height) for c in cams))


def check_one_size(cams: list[Camera], where, what: str) -> None:
    """Refuse views of several image sizes where `what` (a command, a campaign) renders its views
    as one frame set; the message lists each size with its number of views."""
    sizes = image_sizes(cams)
    if len(sizes) > 1:
        listed = ", ".join(f"{w}x{h} ({k} view{'s' if k != 1 else ''})" for (w, h), k in sizes.items())
        raise InputError(
            f"{where}: the views have {len(sizes)} image sizes, {listed}, and {what} renders one size at a time: "
            "use a camera file whose views share one size (`seuwgpu render` renders mixed sizes)"
        )


def scale_cameras(cams: list[Camera], scale: float) -> list[Camera]:
    """The views rendered at `scale` times their resolution, intrinsics scaled to match (pixel
    edges scale with the image, so fx, cx scale by new_width / width and fy, cy by the heights)."""
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"--scale must be a positive number, got {scale}")
    out = []
    for c in cams:
        w, h = max(1, round(c.width * scale)), max(1, round(c.height * scale))
        K = c.K.astype(np.float64)
        K[0] *= w / c.width
        K[1] *= h / c.height
        out.append(Camera(c.viewmat, K, w, h))
    return out


# ------------------------------------------------------------------------------- camera files


_COLMAP_FILES = ("cameras.bin", "images.bin", "cameras.txt", "images.txt")


def read_cameras(path) -> tuple[list[Camera], list[str], str]:
    """(cameras, view names, format) of a CAMS.json, INRIA cameras.json, COLMAP model (folder, or
    one of its files) or nerfstudio transforms.json, recognised by content."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such camera file or folder")
    if p.is_dir() or p.name in _COLMAP_FILES:  # the files camera_files finds there
        files = camera_files(p)
        return read_cameras(files[0]) if files[0].suffix == ".json" else _read_colmap(*files)
    if not p.is_file():
        raise CameraFileError(f"{p}: not a regular file or folder (a pipe or device cannot be read as cameras)")
    raw = p.read_bytes()
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CameraFileError(
            f"{p}: not a camera file (not JSON: {e}); expected CAMS.json, INRIA cameras.json, "
            "nerfstudio transforms.json or a COLMAP model folder"
        ) from None
    if isinstance(data, dict) and "cameras" in data:
        return _read_cams_json(p, data)
    if isinstance(data, dict) and "frames" in data:
        return _read_transforms_json(p, data)
    if isinstance(data, list) and data and isinstance(data[0], dict) and "rotation" in data[0]:
        return _read_inria(p, data)
    raise CameraFileError(
        f'{p}: JSON that is no known camera file (expected {{"cameras": [...]}}, '
        '{"frames": [...]} or an INRIA list of cameras)'
    )


def camera_files(path) -> list[Path]:
    """The files read_cameras reads for `path` (what a campaign hashes to notice a change)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such camera file or folder")
    if not (p.is_file() or p.is_dir()):
        raise CameraFileError(f"{p}: not a regular file or folder (a pipe or device cannot be read as cameras)")
    if p.is_file():
        if p.name not in _COLMAP_FILES:
            return [p]
        # a COLMAP file names its model in its own encoding
        found = _colmap_pair(p.parent, (p.suffix[1:],))
        if found is None:
            raise CameraFileError(f"{p}: a COLMAP model needs cameras{p.suffix} and images{p.suffix} in one folder")
        return found
    for name in ("cameras.json", "transforms.json", "CAMS.json"):
        if (p / name).is_file():
            return [p / name]
    folder = p
    for sub in (p, p / "sparse" / "0", p / "sparse"):
        if any((sub / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            folder = sub
            break
    found = _colmap_pair(folder)
    if found is None:
        raise CameraFileError(
            f"{p}: folder without cameras.json, transforms.json or a COLMAP model (cameras and images .bin/.txt)"
        )
    return found


def _colmap_pair(folder: Path, exts=("bin", "txt")) -> list[Path] | None:
    """[cameras, images] files of the COLMAP model in `folder`, in the first encoding of `exts`
    that has both (.bin before .txt, as COLMAP writes both), or None."""
    for ext in exts:
        found = [folder / f"cameras.{ext}", folder / f"images.{ext}"]
        if all(f.is_file() for f in found):
            return found
    return None


def _num(p: Path, where: str, v, shape=None) -> np.ndarray:
    try:
        o = np.asarray(v, dtype=object)
        if not all(_is_number(x) for x in o.ravel()):
            raise ValueError
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraFileError(f"{p}: {where} is not numeric") from None
    if shape is not None and a.shape != shape:
        raise CameraFileError(f"{p}: {where} has shape {a.shape}, expected {shape}")
    if not np.isfinite(a).all():
        raise CameraFileError(f"{p}: {where} is not finite")
    return a


def _scalar(v, what: str) -> float:
    """A finite number from a camera file (booleans, None and text refused)."""
    if not _is_number(v):
        raise InputError(f"{what} must be a number, got {v!r}")
    if not np.isfinite(v):
        raise InputError(f"{what} must be finite, got {v!r}")
    return float(v)


def _intrinsics(fx, fy, cx, cy) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _from_c2w(rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """World-to-camera 4x4 from a camera-to-world rotation (OpenCV axes) and centre."""
    M = np.eye(4)
    M[:3, :3] = rot.T
    M[:3, 3] = -rot.T @ pos
    return M


def _read_cams_json(p: Path, data: dict):
    cams, names = [], []
    entries = data["cameras"]
    if not isinstance(entries, list):
        raise CameraFileError(f'{p}: "cameras" must be a list')
    for i, c in enumerate(entries):
        if not isinstance(c, dict):
            raise CameraFileError(f"{p}: camera {i} is not an object")
        missing = {"viewmat", "K", "width", "height"} - set(c)
        if missing:
            raise CameraFileError(f"{p}: camera {i} lacks {', '.join(sorted(missing))}")
        try:
            cams.append(Camera(c["viewmat"], c["K"], c["width"], c["height"]))
        except (ValueError, TypeError) as e:
            raise CameraFileError(f"{p}: camera {i}: {e}") from None
        names.append(str(c.get("name", i)))
    if not cams:
        raise CameraFileError(f"{p}: no cameras")
    return cams, names, "cams"


def _read_inria(p: Path, data: list):
    cams, names = [], []
    for i, c in enumerate(data):
        if not isinstance(c, dict):
            raise CameraFileError(f"{p}: camera {i} is not an object")
        missing = {"position", "rotation", "fx", "fy", "width", "height"} - set(c)
        if missing:
            raise CameraFileError(f"{p}: INRIA camera {i} lacks {', '.join(sorted(missing))}")
        rot = _num(p, f"camera {i} rotation", c["rotation"], (3, 3))
        pos = _num(p, f"camera {i} position", c["position"], (3,))
        try:
            w, h = _size(c["width"], "width"), _size(c["height"], "height")
            fx, fy = (_scalar(c[k], k) for k in ("fx", "fy"))
            cx, cy = _scalar(c.get("cx", w / 2), "cx"), _scalar(c.get("cy", h / 2), "cy")
            cams.append(Camera(_from_c2w(rot, pos), _intrinsics(fx, fy, cx, cy), w, h))
        except ValueError as e:
            raise CameraFileError(f"{p}: camera {i}: {e}") from None
        names.append(str(c.get("img_name", i)))
    return cams, names, "inria"


_GL_TO_CV = np.diag([1.0, -1.0, -1.0])
_NS_UNSUPPORTED = ("OPENCV_FISHEYE", "EQUIRECTANGULAR", "FISHEYE624")


def _read_transforms_json(p: Path, data: dict):
    frames = data["frames"]
    if not isinstance(frames, list) or not frames:
        raise CameraFileError(f'{p}: "frames" must be a non-empty list')
    model = str(data.get("camera_model", "OPENCV"))
    if model in _NS_UNSUPPORTED:
        raise CameraFileError(f"{p}: nerfstudio camera_model {model} is not a pinhole camera (unsupported)")
    cams, names, distorted = [], [], False

    def get(frame, key):
        return data[key] if key in data else frame.get(key)

    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or "transform_matrix" not in fr:
            raise CameraFileError(f"{p}: frame {i} lacks transform_matrix")
        w, h = get(fr, "w"), get(fr, "h")
        if w is None or h is None:
            raise CameraFileError(f"{p}: frame {i}: image size w, h missing (top level or per frame)")
        T = _num(p, f"frame {i} transform_matrix", fr["transform_matrix"])
        if T.shape not in ((4, 4), (3, 4)):
            raise CameraFileError(f"{p}: frame {i} transform_matrix has shape {T.shape}, expected 4x4")
        try:
            w, h = _size(w, "w"), _size(h, "h")
            fx = get(fr, "fl_x")
            if fx is None and get(fr, "camera_angle_x") is not None:
                fx = 0.5 * w / np.tan(0.5 * _scalar(get(fr, "camera_angle_x"), "camera_angle_x"))
            if fx is None:
                raise CameraFileError("focal length fl_x missing (top level or per frame)")  # prefixed below
            fx = _scalar(fx, "fl_x")
            fy = fx if get(fr, "fl_y") is None else _scalar(get(fr, "fl_y"), "fl_y")
            cx = w / 2 if get(fr, "cx") is None else _scalar(get(fr, "cx"), "cx")
            cy = h / 2 if get(fr, "cy") is None else _scalar(get(fr, "cy"), "cy")
            if any(_scalar(get(fr, k) or 0.0, k) != 0.0 for k in ("k1", "k2", "k3", "k4", "p1", "p2")):
                distorted = True
            rot = T[:3, :3] @ _GL_TO_CV  # OpenGL camera axes (y up, z back) -> OpenCV (y down, z forward)
            cams.append(Camera(_from_c2w(rot, T[:3, 3]), _intrinsics(fx, fy, cx, cy), w, h))
        except ValueError as e:
            raise CameraFileError(f"{p}: frame {i}: {e}") from None
        names.append(str(fr.get("file_path", i)))
    if distorted:
        warnings.warn(f"{p}: lens distortion (k1..k4, p1, p2) ignored: rendered as a pinhole camera")
    return cams, names, "nerfstudio"


# COLMAP camera models: id -> (name, parameter count); the pinhole part of each usable model.
COLMAP_MODELS = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
}
_COLMAP_IDS = {name: i for i, (name, _) in COLMAP_MODELS.items()}
_SINGLE_F = ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")
_DISTORTED = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")


def _colmap_intrinsics(p: Path, cam_id: int, model: str, params) -> np.ndarray:
    if model in _SINGLE_F:
        f, cx, cy = params[:3]
        return _intrinsics(f, f, cx, cy)
    if model in ("PINHOLE", "OPENCV", "FULL_OPENCV"):
        fx, fy, cx, cy = params[:4]
        return _intrinsics(fx, fy, cx, cy)
    raise CameraFileError(
        f"{p}: COLMAP camera {cam_id} uses the {model} model, which is not a pinhole camera; "
        "supported: SIMPLE_PINHOLE, PINHOLE and (distortion ignored) SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV"
    )


def _qvec_to_rotmat(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
            [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
            [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y],
        ]
    )


def _read_colmap(cameras_file: Path, images_file: Path):
    """The COLMAP model of one encoding (the pair camera_files found)."""
    folder = cameras_file.parent
    read_cameras_of, read_images_of = _COLMAP_READERS[cameras_file.suffix]
    cameras = read_cameras_of(cameras_file)
    images = read_images_of(images_file)
    if not images:
        raise CameraFileError(f"{folder}: the COLMAP model has no registered images")
    cams, names, distorted = [], [], set()
    for name, qvec, tvec, cam_id in sorted(images, key=lambda im: im[0]):
        if cam_id not in cameras:
            raise CameraFileError(f"{folder}: image {name!r} refers to camera {cam_id}, which is not in the model")
        model, w, h, params = cameras[cam_id]
        K = _colmap_intrinsics(folder, cam_id, model, params)
        if model in _DISTORTED and any(v != 0 for v in params[3 if model in _SINGLE_F else 4 :]):
            distorted.add(model)
        norm = float(np.linalg.norm(np.asarray(qvec, dtype=np.float64)))
        if not (np.isfinite(norm) and norm > 1e-12):
            raise CameraFileError(f"{folder}: image {name!r}: rotation quaternion {list(qvec)} is zero or not finite")
        M = np.eye(4)
        M[:3, :3] = _qvec_to_rotmat(qvec)
        M[:3, 3] = tvec
        try:
            cams.append(Camera(M, K, w, h))
        except ValueError as e:
            raise CameraFileError(f"{folder}: image {name!r}: {e}") from None
        names.append(name)
    if distorted:
        warnings.warn(
            f"{folder}: lens distortion of the {', '.join(sorted(distorted))} camera model ignored: "
            "rendered as a pinhole camera"
        )
    return cams, names, "colmap"


def _text(path: Path) -> str:
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise CameraFileError(f"{path}: not a UTF-8 text file ({e.reason} at byte {e.start})") from None


def _colmap_cameras_txt(path: Path) -> dict:
    out = {}
    for lineno, line in enumerate(_text(path).splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        e = line.split()
        try:
            cam_id, model, w, h = int(e[0]), e[1], int(e[2]), int(e[3])
            params = [float(v) for v in e[4:]]
        except (IndexError, ValueError):
            raise CameraFileError(f"{path}: malformed camera line {lineno}: {line!r}") from None
        if model not in _COLMAP_IDS:
            raise CameraFileError(f"{path}: unknown COLMAP camera model {model!r} (line {lineno})")
        if len(params) != COLMAP_MODELS[_COLMAP_IDS[model]][1]:
            raise CameraFileError(f"{path}: camera {cam_id} ({model}) has {len(params)} parameters (line {lineno})")
        out[cam_id] = (model, w, h, params)
    return out


def _colmap_images_txt(path: Path) -> list:
    """Two lines an image: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then its 2D points (maybe
    empty); comment lines start with '#'."""
    lines = _text(path).splitlines()
    out, i = [], 0
    while i < len(lines):
        line = lines[i].strip()
        i += 1
        if not line or line.startswith("#"):
            continue
        e = line.split()
        try:
            q = [float(v) for v in e[1:5]]
            t = [float(v) for v in e[5:8]]
            cam_id, name = int(e[8]), " ".join(e[9:])
        except (IndexError, ValueError):
            raise CameraFileError(f"{path}: malformed image line {i}: {line!r}") from None
        if not name:
            raise CameraFileError(f"{path}: image line {i} has no image name")
        out.append((name, q, t, cam_id))
        if i < len(lines) and not _points2d_line(lines[i]):
            # a file written without the (possibly empty) POINTS2D lines: skipping the next line
            # as COLMAP's reader does would drop every other image without a word
            raise CameraFileError(
                f"{path}: line {i + 1} should be the POINTS2D line of image {name!r} (X Y POINT3D_ID "
                f"triples, or an empty line) but reads {lines[i].strip()!r}; COLMAP's images.txt gives "
                "every image two lines"
            )
        i += 1  # the POINTS2D line that follows every image line
    return out


def _points2d_line(line: str) -> bool:
    """An images.txt POINTS2D line: empty, or numeric X Y POINT3D_ID triples."""
    e = line.split()
    if len(e) % 3:
        return False
    try:
        [float(v) for v in e]
    except ValueError:
        return False
    return True


class _Reader:
    def __init__(self, path: Path):
        self.path, self.data, self.off = path, path.read_bytes(), 0

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.off + size > len(self.data):
            raise CameraFileError(f"{self.path}: truncated COLMAP binary file (at byte {self.off})")
        v = struct.unpack_from(fmt, self.data, self.off)
        self.off += size
        return v

    def skip(self, size: int):
        if self.off + size > len(self.data):
            raise CameraFileError(f"{self.path}: truncated COLMAP binary file (at byte {self.off})")
        self.off += size

    def cstring(self) -> str:
        end = self.data.find(b"\0", self.off)
        if end < 0:
            raise CameraFileError(f"{self.path}: truncated COLMAP binary file (unterminated image name)")
        s = self.data[self.off : end].decode("utf-8", errors="replace")
        self.off = end + 1
        return s


def _colmap_cameras_bin(path: Path) -> dict:
    r = _Reader(path)
    (count,) = r.take("<Q")
    out = {}
    for _ in range(count):
        cam_id, model_id, w, h = r.take("<iiQQ")
        if model_id not in COLMAP_MODELS:
            raise CameraFileError(f"{path}: unknown COLMAP camera model id {model_id} (camera {cam_id})")
        name, nparams = COLMAP_MODELS[model_id]
        out[cam_id] = (name, w, h, list(r.take(f"<{nparams}d")))
    return out


def _colmap_images_bin(path: Path) -> list:
    r = _Reader(path)
    (count,) = r.take("<Q")
    out = []
    for _ in range(count):
        v = r.take("<idddddddi")
        name = r.cstring()
        (npoints,) = r.take("<Q")
        r.skip(24 * npoints)
        out.append((name, list(v[1:5]), list(v[5:8]), v[8]))
    return out


# The readers of each COLMAP encoding (cameras, images), by file extension.
_COLMAP_READERS = {
    ".bin": (_colmap_cameras_bin, _colmap_images_bin),
    ".txt": (_colmap_cameras_txt, _colmap_images_txt),
}
