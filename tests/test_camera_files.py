"""Camera files: one set of views written by hand as seuwgpu CAMS.json, INRIA cameras.json,
COLMAP text and binary models and nerfstudio transforms.json; each must load to the same float32
cameras and render the same images as the CAMS.json, bit for bit."""

from __future__ import annotations

import json
import struct
import warnings

import numpy as np
import pytest
from conftest import fifo_with_writer

from seuwgpu.model.cameras import Camera, CameraFileError, read_cameras, scale_cameras, select_views

W, H = 40, 30


def rotation(q):
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# three views of the spheres scene: world-to-camera rotation (quaternion), translation, intrinsics
VIEWS = []
for i, az in enumerate((0.3, 2.2, 4.1)):
    target = np.array([0.11, -0.07, 0.05])  # off the origin: no translation component is ~0
    eye = 4.0 * np.array([np.cos(az), np.sin(az), 0.45])
    f = (target - eye) / np.linalg.norm(target - eye)
    r = np.cross(f, [0, 0, 1.0])
    r /= np.linalg.norm(r)
    R = np.stack([r, np.cross(f, r), f])  # rows: camera x, y (down), z (forward)
    # the quaternion of R (w > 0), and R recomputed from it so that every file describes one pose
    w = 0.5 * np.sqrt(1 + np.trace(R))
    q = np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    R = rotation(q)
    t = -R @ eye
    fx, fy = 38.0 + 2 * i, 37.5 + 2 * i
    VIEWS.append({"name": f"img_{2 - i:03d}.png", "q": q, "R": R, "t": t, "fx": fx, "fy": fy, "cx": W / 2, "cy": H / 2})


def cams_json(path):
    cams = []
    for v in VIEWS:
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = v["R"], v["t"]
        K = [[v["fx"], 0, v["cx"]], [0, v["fy"], v["cy"]], [0, 0, 1]]
        cams.append({"viewmat": M.tolist(), "K": K, "width": W, "height": H})
    path.write_text(json.dumps({"cameras": cams}))
    return path


def inria_json(path):
    out = []
    for i, v in enumerate(VIEWS):
        c2w_rot = v["R"].T  # the INRIA file holds the camera-to-world rotation and the centre
        out.append(
            {
                "id": i,
                "img_name": v["name"],
                "width": W,
                "height": H,
                "position": (-v["R"].T @ v["t"]).tolist(),
                "rotation": c2w_rot.tolist(),
                "fy": v["fy"],
                "fx": v["fx"],
            }
        )
    path.write_text(json.dumps(out))
    return path


def transforms_json(path, per_frame: bool):
    frames = []
    for v in VIEWS:
        c2w = np.eye(4)
        c2w[:3, :3] = v["R"].T @ np.diag([1.0, -1.0, -1.0])  # OpenGL camera axes
        c2w[:3, 3] = -v["R"].T @ v["t"]
        fr = {"file_path": v["name"], "transform_matrix": c2w.tolist()}
        if per_frame:
            fr.update(fl_x=v["fx"], fl_y=v["fy"], cx=v["cx"], cy=v["cy"], w=W, h=H)
        frames.append(fr)
    data = {"camera_model": "OPENCV", "frames": frames}
    if not per_frame:  # one intrinsics for all: only meaningful when they agree
        v = VIEWS[0]
        data.update(fl_x=v["fx"], fl_y=v["fy"], cx=v["cx"], cy=v["cy"], w=W, h=H)
    path.write_text(json.dumps(data))
    return path


def colmap_txt(folder, model="PINHOLE", extra=()):
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    for i, v in enumerate(VIEWS):
        params = [v["fx"], v["fy"], v["cx"], v["cy"]] if model != "SIMPLE_PINHOLE" else [v["fx"], v["cx"], v["cy"]]
        lines.append(" ".join(str(x) for x in [i + 1, model, W, H, *map(float, params), *extra]))
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    img = ["# Image list with two lines of data per image:"]
    for i, v in reversed(list(enumerate(VIEWS))):  # not in name order: the reader sorts by name
        img.append(
            " ".join(repr(x) for x in [i + 1, *map(float, v["q"]), *map(float, v["t"]), i + 1]) + " " + v["name"]
        )
        img.append("" if i == 1 else "1.5 2.5 -1 3.0 4.0 7")  # POINTS2D, possibly empty
    (folder / "images.txt").write_text("\n".join(img) + "\n")
    return folder


def colmap_bin(folder):
    folder.mkdir(parents=True, exist_ok=True)
    b = struct.pack("<Q", len(VIEWS))
    for i, v in enumerate(VIEWS):
        b += struct.pack("<iiQQ4d", i + 1, 1, W, H, v["fx"], v["fy"], v["cx"], v["cy"])  # 1 = PINHOLE
    (folder / "cameras.bin").write_bytes(b)
    b = struct.pack("<Q", len(VIEWS))
    for i, v in enumerate(VIEWS):
        b += struct.pack("<i7di", i + 1, *v["q"], *v["t"], i + 1) + v["name"].encode() + b"\0"
        b += struct.pack("<Q", 2) + struct.pack("<ddq", 1.0, 2.0, 5) * 2
    (folder / "images.bin").write_bytes(b)
    return folder


def by_name(cams, names):
    order = np.argsort(names)
    return [cams[i] for i in order]


def assert_same(a: list[Camera], b: list[Camera]):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert (x.width, x.height) == (y.width, y.height)
        np.testing.assert_array_equal(x.viewmat, y.viewmat)
        np.testing.assert_array_equal(x.K, y.K)


@pytest.fixture
def reference(tmp_path):
    cams, names, fmt = read_cameras(cams_json(tmp_path / "CAMS.json"))
    assert fmt == "cams" and len(cams) == 3
    return cams


def test_every_format_gives_the_same_cameras(tmp_path, reference):
    cams, names, fmt = read_cameras(inria_json(tmp_path / "cameras.json"))
    assert fmt == "inria" and names == [v["name"] for v in VIEWS]  # the file's order
    assert_same(cams, reference)
    cams, names, fmt = read_cameras(transforms_json(tmp_path / "transforms.json", per_frame=True))
    assert fmt == "nerfstudio"
    assert_same(cams, reference)
    for folder in (colmap_txt(tmp_path / "txt"), colmap_bin(tmp_path / "bin")):
        cams, names, fmt = read_cameras(folder)
        assert fmt == "colmap" and names == sorted(v["name"] for v in VIEWS)  # COLMAP: by image name
        assert_same(cams, by_name(reference, [v["name"] for v in VIEWS]))
    # a COLMAP file names its folder; an INRIA output folder holds cameras.json
    assert_same(read_cameras(tmp_path / "txt" / "images.txt")[0], read_cameras(tmp_path / "txt")[0])
    assert_same(read_cameras(tmp_path)[0], reference)


def test_top_level_intrinsics_and_simple_pinhole(tmp_path):
    cams, _, _ = read_cameras(transforms_json(tmp_path / "transforms.json", per_frame=False))
    for c in cams:
        np.testing.assert_array_equal(c.K, np.array([[38.0, 0, 20], [0, 37.5, 15], [0, 0, 1]], np.float32))
    cams, _, _ = read_cameras(colmap_txt(tmp_path / "simple", "SIMPLE_PINHOLE"))
    assert all(c.K[0, 0] == c.K[1, 1] for c in cams)


def test_distortion_is_ignored_with_a_warning_and_fisheye_refused(tmp_path, reference):
    with pytest.warns(UserWarning, match="distortion of the OPENCV camera model ignored"):
        cams, _, _ = read_cameras(colmap_txt(tmp_path / "cv", "OPENCV", extra=(0.1, -0.02, 0.001, 0.0)))
    assert_same(cams, by_name(reference, [v["name"] for v in VIEWS]))
    with pytest.raises(CameraFileError, match="OPENCV_FISHEYE model, which is not a pinhole"):
        read_cameras(colmap_txt(tmp_path / "fish", "OPENCV_FISHEYE", extra=(0.1, 0.0, 0.0, 0.0)))


def test_camera_file_errors(tmp_path):
    (tmp_path / "bad.json").write_text("{nope")
    with pytest.raises(CameraFileError, match="not JSON") as e:
        read_cameras(tmp_path / "bad.json")
    assert str(tmp_path / "bad.json") in str(e.value)
    (tmp_path / "other.json").write_text('{"hello": 1}')
    with pytest.raises(CameraFileError, match="no known camera file"):
        read_cameras(tmp_path / "other.json")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CameraFileError, match="folder without"):
        read_cameras(tmp_path / "empty")
    colmap_bin(tmp_path / "trunc")
    data = (tmp_path / "trunc" / "images.bin").read_bytes()
    (tmp_path / "trunc" / "images.bin").write_bytes(data[:50])
    with pytest.raises(CameraFileError, match="truncated"):
        read_cameras(tmp_path / "trunc")
    # the file and frame are named once, not twice
    frame = {"transform_matrix": np.eye(4).tolist(), "w": 32, "h": 32}
    (tmp_path / "transforms.json").write_text(json.dumps({"frames": [frame]}))
    with pytest.raises(CameraFileError) as e:
        read_cameras(tmp_path / "transforms.json")
    want = "frame 0: focal length fl_x missing (top level or per frame)"
    assert str(e.value) == f"{tmp_path / 'transforms.json'}: {want}"


def test_select_views_and_scale(reference):
    assert select_views(list(range(10)), 4) == [0, 2, 5, 7]  # evenly: i * n // k
    assert select_views(reference, None) == reference and select_views(reference, 10) == reference
    half = scale_cameras(reference, 0.5)
    assert (half[0].width, half[0].height) == (20, 15)
    np.testing.assert_allclose(half[0].K[:2], reference[0].K[:2] * 0.5)
    np.testing.assert_array_equal(half[0].viewmat, reference[0].viewmat)


def test_renders_identical_to_cams_json(tmp_path, reference):
    """The GPU renders of the views read from each format equal the CAMS.json renders bit for bit."""
    from seuwgpu.model.scenes import make_scene
    from seuwgpu.render.renderer import Renderer

    model = make_scene("spheres", n=2000)
    want = Renderer(model, reference).render()
    assert (np.abs(want - 1.0) > 0.05).mean() > 0.05  # the views see the scene
    names = [v["name"] for v in VIEWS]
    files = {
        "inria": inria_json(tmp_path / "cameras.json"),
        "nerfstudio": transforms_json(tmp_path / "transforms.json", per_frame=True),
        "colmap-bin": colmap_bin(tmp_path / "bin"),
    }
    for fmt, path in files.items():
        cams, got_names, _ = read_cameras(path)
        got = Renderer(model, cams).render()
        order = [got_names.index(n) for n in names]
        np.testing.assert_array_equal(got[order], want, err_msg=fmt)


def test_colmap_images_txt_without_points2d_lines_is_refused(tmp_path, reference):
    """COLMAP gives every image two lines; a file written without the (possibly empty) POINTS2D
    lines would lose every other image if the line after each image were skipped unread."""
    folder = colmap_txt(tmp_path / "txt")
    lines = (folder / "images.txt").read_text().splitlines()
    (folder / "images.txt").write_text("\n".join(ln for ln in lines if ln.startswith("#") or len(ln.split()) >= 10))
    with pytest.raises(CameraFileError, match="line 3 should be the POINTS2D line of image 'img_000.png'"):
        read_cameras(folder)


def test_a_named_colmap_file_reads_its_own_encoding(tmp_path):
    """A folder with both encodings: naming cameras.txt reads the .txt model, not the .bin one."""
    folder = colmap_bin(tmp_path / "both")
    colmap_txt(folder)
    (folder / "images.txt").write_text(
        "\n".join((folder / "images.txt").read_text().splitlines()[:3]) + "\n"  # the comment and one image
    )
    assert len(read_cameras(folder / "cameras.txt")[0]) == 1
    assert len(read_cameras(folder / "images.txt")[0]) == 1
    assert len(read_cameras(folder / "images.bin")[0]) == 3
    assert len(read_cameras(folder)[0]) == 3  # a folder: the binary model, as COLMAP writes both
    from seuwgpu.model.cameras import camera_files

    assert camera_files(folder / "cameras.txt") == [folder / "cameras.txt", folder / "images.txt"]
    (folder / "images.txt").unlink()
    with pytest.raises(CameraFileError, match="needs cameras.txt and images.txt"):
        read_cameras(folder / "cameras.txt")


def test_colmap_zero_quaternion_is_named(tmp_path):
    folder = colmap_txt(tmp_path / "txt")
    text = (folder / "images.txt").read_text().splitlines()
    words = text[1].split()
    words[1:5] = ["0", "0", "0", "0"]
    text[1] = " ".join(words)
    (folder / "images.txt").write_text("\n".join(text) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy division warning on the way
        with pytest.raises(CameraFileError, match="rotation quaternion .* is zero"):
            read_cameras(folder)


@pytest.mark.parametrize(
    "K, why",
    [
        ([[38.0, 0, 0], [0, 37.5, 0], [20, 15, 1]], "transposed"),
        ([[38.0, 2.0, 20], [0, 37.5, 15], [0, 0, 1]], "skew"),
        ([[38.0, 0, 20], [0, 37.5, 15], [0, 0, 2]], "last row"),
    ],
)
def test_camera_K_the_renderer_cannot_honour_is_refused(tmp_path, K, why):
    """The renderer reads fx, fy, cx and cy alone: a K with anything else would render as another
    camera without a word (a transposed K puts the principal point at the corner)."""
    cams = json.loads(cams_json(tmp_path / "CAMS.json").read_text())
    cams["cameras"][1]["K"] = K
    (tmp_path / "CAMS.json").write_text(json.dumps(cams))
    with pytest.raises(CameraFileError, match=r"camera 1: camera K must be \[\[fx, 0, cx\]"):
        read_cameras(tmp_path / "CAMS.json")


def test_camera_viewmat_must_hold_a_rotation(tmp_path):
    M = np.eye(4)
    M[:3, :3] = [[1, 0.9, 0], [0, 1, 0], [0, 0, 1]]  # sheared (determinant 1)
    with pytest.raises(ValueError, match="not a rotation"):
        Camera(M, [[38.0, 0, 20], [0, 37.5, 15], [0, 0, 1]], W, H)
    M[:3, :3] = np.diag([2.0, 1.0, 1.0])  # stretched along one axis
    with pytest.raises(ValueError, match="not a rotation"):
        Camera(M, [[38.0, 0, 20], [0, 37.5, 15], [0, 0, 1]], W, H)
    M[:3, :3] = 3.0 * VIEWS[0]["R"]  # a rotation times a uniform scale stays allowed
    Camera(M, [[38.0, 0, 20], [0, 37.5, 15], [0, 0, 1]], W, H)


def test_camera_path_that_is_no_regular_file_is_refused(tmp_path):
    from seuwgpu.model.cameras import camera_files

    with fifo_with_writer(tmp_path / "cams.json") as fifo:
        with pytest.raises(CameraFileError, match="not a regular file"):
            read_cameras(fifo)
        with pytest.raises(CameraFileError, match="not a regular file"):
            camera_files(fifo)


def test_a_uniformly_scaled_viewmat_keeps_its_camera_centre():
    """A viewmat s [R | t] (a rotation times a uniform scale, which Camera accepts) maps the same
    camera centre to the origin as [R | t]: the centre is -(sR)^-1 (s t) = -R^T t, not
    -(sR)^T (s t) = -s^2 R^T t. The SH view direction (mean - centre) depends on it: with the
    wrong centre a scaled camera drew other view-dependent colours than the same pose unscaled."""
    from seuwgpu.model.scenes import make_scene
    from seuwgpu.render.renderer import Renderer

    v = VIEWS[0]
    eye = -v["R"].T @ v["t"]  # the centre, from the unscaled pose in float64
    K = [[v["fx"], 0, v["cx"]], [0, v["fy"], v["cy"]], [0, 0, 1]]
    cams = []
    for s in (1.0, 3.0, 0.5):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = s * v["R"], s * v["t"]
        cams.append(Camera(M, K, W, H))
        np.testing.assert_allclose(cams[-1].position, eye, rtol=1e-6, atol=1e-6, err_msg=f"scale {s}")
    model = make_scene("spheres", n=500)
    assert model.sh_degree > 0 and np.abs(model.sh_rest).max() > 0.05  # view-dependent colour
    frames = Renderer(model, cams).render()
    assert (np.abs(frames[0] - 1.0) > 0.05).mean() > 0.05  # the view sees the scene
    np.testing.assert_allclose(frames[1], frames[0], atol=1e-4)
    np.testing.assert_allclose(frames[2], frames[0], atol=1e-4)
