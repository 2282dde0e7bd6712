"""`seuwgpu render` on bad and valid camera files and model files (PLY, SPZ and what only looks
like one): a clear one-line error, or a render of the right size with finite pixels."""

from __future__ import annotations

import json

import numpy as np
import pytest

from robustness.checks import npz_shape
from robustness.outcomes import expect_outcome

BAD_CAMERA = {
    "nan viewmat": {"viewmat": [[float("nan")] * 4] * 4},
    "inf K": {"K": [[float("inf"), 0, 8], [0, 20, 8], [0, 0, 1]]},
    "singular": {"viewmat": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 4], [0, 0, 0, 1]]},
    "mirrored": {"viewmat": [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]},
    "fx 0": {"K": [[0, 0, 8], [0, 20, 8], [0, 0, 1]]},
    "fy negative": {"K": [[20, 0, 8], [0, -20, 8], [0, 0, 1]]},
    "width 12.5": {"width": 12.5},
    "width true": {"width": True},
    "width null": {"width": None},
    "width 0": {"width": 0},
    "height -16": {"height": -16},
    "width text": {"width": "16"},
    "viewmat 3x3": {"viewmat": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
    "viewmat text": {"viewmat": "eye"},
    "K booleans": {"K": [[True, 0, 8], [0, 20, 8], [0, 0, 1]]},
    "last row": {"viewmat": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 1, 1]]},
}
INRIA = {"width": 16, "height": 16, "position": [0, 0, 4], "rotation": np.eye(3).tolist(), "fx": 20, "fy": 20}
FRAME = {"fl_x": 20, "w": 16, "h": 16, "frames": [{"transform_matrix": np.eye(4).tolist()}]}
BAD_CAMERA_TEXT = {
    '{"cameras": 5}': lambda good: '{"cameras": 5}',
    '{"cameras": []}': lambda good: '{"cameras": []}',
    "not JSON": lambda good: "{",
    "a list of numbers": lambda good: "[1, 2]",
    "camera lacks K": lambda good: json.dumps({"cameras": [{k: v for k, v in good.items() if k != "K"}]}),
    "frames = 5": lambda good: '{"frames": 5}',
    "frame w null": lambda good: json.dumps(dict(FRAME, w=None)),
    "frame fl_x text": lambda good: json.dumps(dict(FRAME, fl_x="x")),
    "inria width null": lambda good: json.dumps([dict(INRIA, width=None)]),
    "inria fx bool": lambda good: json.dumps([dict(INRIA, fx=True)]),
}


@pytest.fixture(scope="module")
def good_camera():
    from seuwgpu.model.scenes import scene_cameras

    return {
        "viewmat": scene_cameras("spheres", 1, 16, 16)[0].viewmat.tolist(),
        "K": [[20, 0, 8], [0, 20, 8], [0, 0, 1]],
        "width": 16,
        "height": 16,
    }


def render(fresh, extra, expect, shape=None, model=None):
    """`render` of the tiny spheres scene (or `model`) with `extra` arguments, expecting `expect`."""
    out = fresh("render", ".npz")
    src = ["--model", model] if model is not None else ["--scene", "spheres", "--n", "80"]
    check = npz_shape(out, shape) if expect == "ok" else None
    expect_outcome(["render", *src, *extra, "--out", out], expect, check)


@pytest.mark.parametrize("change", list(BAD_CAMERA.values()), ids=list(BAD_CAMERA))
def test_a_bad_camera(fresh, good_camera, change):
    p = fresh("cams", ".json")
    p.write_text(json.dumps({"cameras": [dict(good_camera, **change)]}))
    render(fresh, ["--cameras", p], "error")


@pytest.mark.parametrize("text", list(BAD_CAMERA_TEXT.values()), ids=list(BAD_CAMERA_TEXT))
def test_a_camera_file_of_the_wrong_shape(fresh, good_camera, text):
    p = fresh("cams", ".json")
    p.write_text(text(good_camera))
    render(fresh, ["--cameras", p], "error")


@pytest.mark.parametrize("path", ["nope.json", "dir", "good.ply"], ids=["missing", "folder without cameras", "binary"])
def test_a_camera_path_that_is_no_camera_file(fresh, work, path):
    render(fresh, ["--cameras", work / path], "error")


def test_a_valid_camera_file(fresh, good_camera):
    p = fresh("cams", ".json")
    p.write_text(json.dumps({"cameras": [good_camera, good_camera]}))
    render(fresh, ["--cameras", p], "ok", (2, 16, 16, 3))


def ply_variants(g: bytes, spz: bytes) -> dict:
    """Damaged model files made from a valid PLY `g` (80 primitives) and SPZ."""
    head, body = g.split(b"end_header\n", 1)
    return {
        "empty file": b"",
        "garbage": b"\x00\x01garbage" * 10,
        "header only": head + b"end_header\n",
        "truncated header": head[: len(head) // 2],
        "truncated data": head + b"end_header\n" + body[: len(body) // 2],
        "one byte short": g[:-1],
        "header count below data": g.replace(b"element vertex 80\n", b"element vertex 60\n"),
        "header count above data": g.replace(b"element vertex 80\n", b"element vertex 99\n"),
        "zero vertices": g.replace(b"element vertex 80\n", b"element vertex 0\n"),
        "negative count": g.replace(b"element vertex 80\n", b"element vertex -5\n"),
        "unknown format": g.replace(b"binary_little_endian", b"binary_middle_endian"),
        "missing opacity": g.replace(b"property float opacity\n", b""),
        "property twice": g.replace(b"property float opacity\n", b"property float opacity\nproperty float opacity\n"),
        "unknown type": g.replace(b"property float opacity\n", b"property quad opacity\n"),
        "non-UTF-8 header": g.replace(b"format", b"\xff\xfeformat", 1),
        "spz truncated": spz[:40],
        "spz garbage after magic": b"\x1f\x8b\x08\x00" + b"\x00" * 50,
        "splat odd size": b"\x00" * 33,
        "torch magic": b"PK\x03\x04" + b"\x00" * 60,
        "ascii malformed": b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\nabc\n",
    }


PLY_VARIANTS = list(ply_variants(b"ply\nend_header\n", b"").keys())
ONE_VIEW = ["--views", "1", "--size", "16x16"]


@pytest.mark.parametrize("name", PLY_VARIANTS)
def test_a_damaged_model_file(fresh, work, name):
    data = ply_variants((work / "good.ply").read_bytes(), (work / "good.spz").read_bytes())[name]
    p = fresh("model", ".spz" if "spz" in name else ".ply")
    p.write_bytes(data)
    render(fresh, ONE_VIEW, "error", model=p)


@pytest.fixture(scope="module")
def nan_models(work):
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.scenes import make_scene

    nan_model = make_scene("spheres", n=10, seed=2)
    nan_model.means[:] = np.nan
    save_model(nan_model, work / "allnan.ply")
    part = make_scene("spheres", n=10, seed=2)
    part.means[3] = np.nan
    save_model(part, work / "somenan.ply")


@pytest.mark.parametrize("path", ["allnan.ply", "nope.ply", "dir"], ids=["all-NaN model", "missing", "a folder"])
def test_a_model_path_that_is_no_usable_model(fresh, work, nan_models, path):
    render(fresh, ONE_VIEW, "error", model=work / path)


@pytest.mark.parametrize("path", ["good.ply", "good.spz", "somenan.ply"], ids=["PLY", "SPZ", "one NaN primitive"])
def test_a_valid_model(fresh, work, nan_models, path):
    render(fresh, ONE_VIEW, "ok", (1, 16, 16, 3), work / path)
