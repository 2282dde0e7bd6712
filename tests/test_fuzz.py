"""Property-based fuzzing (hypothesis, bounded examples): arbitrary bytes and mutated valid files for
every model format, camera format and campaign spec give either a loaded object or the project's
own error type (SeuwgpuError), never another exception."""

import gzip
import io
import json
import os
import struct
import warnings

import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seuwgpu.campaign.spec import load_spec, normalize_spec
from seuwgpu.errors import SeuwgpuError
from seuwgpu.model.cameras import read_cameras, save_cameras
from seuwgpu.model.formats import read_model, save_model
from seuwgpu.model.scenes import make_scene, scene_cameras

# SEUWGPU_FUZZ_EXAMPLES raises the bound for a deeper local search (CI keeps it small)
FUZZ = settings(
    max_examples=int(os.environ.get("SEUWGPU_FUZZ_EXAMPLES", 120)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def spz_v4_of(v3: bytes) -> bytes:
    """The SPZ v4 file holding a gzip v3 file's planes: a 32-byte header, a table of (compressed,
    plain) sizes and one zstd frame a plane (Niantic's load-spz.cc layout)."""
    raw = gzip.decompress(v3)
    _, _, n, degree, fbits, flags, _ = struct.unpack("<IIIBBBB", raw[:16])
    sizes = [9 * n, n, 3 * n, 3 * n, 4 * n, 3 * n * {0: 0, 1: 3, 2: 8, 3: 15}[degree]]
    planes, off = [], 16
    for size in filter(None, sizes):
        planes.append(raw[off : off + size])
        off += size
    frames = [zstandard.ZstdCompressor().compress(p) for p in planes]
    header = struct.pack("<IIIBBBBI12x", 0x5053474E, 4, n, degree, fbits, flags, len(frames), 32)
    toc = b"".join(struct.pack("<QQ", len(c), len(p)) for c, p in zip(frames, planes))
    return header + toc + b"".join(frames)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    """Valid files of every format, as bytes, to mutate."""
    tmp = tmp_path_factory.mktemp("seeds")
    model = make_scene("spheres", n=6, sh_degree=1, seed=3)
    out = {}
    for name, opts in (("m.ply", {}), ("v2.spz", {"version": 2}), ("v3.spz", {"version": 3})):
        save_model(model, tmp / name, **opts)
        out[name] = (tmp / name).read_bytes()
    out["v4.spz"] = spz_v4_of(out["v3.spz"])  # read, not written, by seuwgpu: laid out here
    ascii_ply = out["m.ply"].split(b"end_header\n")[0].replace(b"binary_little_endian", b"ascii") + b"end_header\n"
    rows = np.frombuffer(out["m.ply"].split(b"end_header\n", 1)[1], "<f4").reshape(6, -1)
    out["a.ply"] = ascii_ply + b"\n".join(b" ".join(b"%r" % float(v) for v in r) for r in rows) + b"\n"
    rec = np.zeros(6, dtype=[("p", "<f4", 3), ("s", "<f4", 3), ("c", "u1", 4), ("q", "u1", 4)])
    rec["p"], rec["s"], rec["c"], rec["q"] = 1.0, 0.1, 128, [255, 128, 128, 128]
    out["m.splat"] = rec.tobytes()
    cams = scene_cameras("spheres", 2, 16, 16)
    save_cameras(cams, tmp / "cams.json")
    out["cams.json"] = (tmp / "cams.json").read_bytes()
    inria = [
        {"id": 0, "img_name": "a", "width": 16, "height": 16, "position": [0, -4, 1], "rotation": np.eye(3).tolist()}
    ]
    inria[0].update(fx=20.0, fy=20.0)
    out["cameras.json"] = json.dumps(inria).encode()
    out["transforms.json"] = json.dumps(
        {"fl_x": 20, "w": 16, "h": 16, "frames": [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}]}
    ).encode()
    out["cameras.txt"] = b"# c\n1 PINHOLE 16 16 20 20 8 8\n"
    out["images.txt"] = b"# i\n1 1 0 0 0 0 0 4 1 a.png\n\n"
    b = io.BytesIO()
    b.write(struct.pack("<Q", 1) + struct.pack("<iiQQ", 1, 1, 16, 16) + struct.pack("<4d", 20, 20, 8, 8))
    out["cameras.bin"] = b.getvalue()
    out["images.bin"] = struct.pack("<Q", 1) + struct.pack("<idddddddi", 1, 1, 0, 0, 0, 0, 0, 4, 1) + b"a.png\0"
    out["images.bin"] += struct.pack("<Q", 0)
    out["tmp"] = tmp
    return Seeds(out)


class Seeds(dict):
    """The seed files (a short repr: hypothesis prints the arguments of a failing example)."""

    def __repr__(self):
        return f"<seed files: {', '.join(k for k in self if k != 'tmp')}>"


def mutate(data: bytes, edits) -> bytes:
    """Apply (kind, position, value) edits: overwrite a byte, insert, delete or truncate."""
    b = bytearray(data)
    for kind, pos, val in edits:
        if not b:
            break
        i = pos % len(b)
        if kind == 0:
            b[i] = val
        elif kind == 1:
            b[i:i] = bytes([val])
        elif kind == 2:
            del b[i]
        else:
            del b[i:]
    return bytes(b)


EDITS = st.lists(st.tuples(st.integers(0, 3), st.integers(0, 1 << 20), st.integers(0, 255)), min_size=1, max_size=6)


def loads_or_own_error(fn, *args):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return fn(*args)
        except SeuwgpuError:
            return None


def check_model_bytes(tmp, name: str, data: bytes):
    p = tmp / name
    p.write_bytes(data)
    mf = loads_or_own_error(read_model, p)
    if mf is not None:
        assert mf.model.n >= 1 and mf.model.means.shape == (mf.model.n, 3)


@FUZZ
@given(data=st.binary(max_size=600), suffix=st.sampled_from([".ply", ".spz", ".splat", ".pt", ".bin"]))
def test_arbitrary_bytes_as_a_model_file(seeds, data, suffix):
    check_model_bytes(seeds["tmp"], "fuzz" + suffix, data)


@FUZZ
@given(data=st.binary(max_size=300))
def test_arbitrary_bytes_behind_a_model_magic(seeds, data):
    for magic in (b"ply\nformat binary_little_endian 1.0\n", b"NGSP", b"\x1f\x8b\x08\x00", b"PK\x03\x04"):
        check_model_bytes(seeds["tmp"], "magic.bin", magic + data)


@FUZZ
@given(which=st.sampled_from(["m.ply", "a.ply", "v2.spz", "v3.spz", "v4.spz", "m.splat"]), edits=EDITS)
def test_mutated_model_files(seeds, which, edits):
    check_model_bytes(seeds["tmp"], "mut_" + which, mutate(seeds[which], edits))


def check_camera_files(tmp, files: dict):
    folder = tmp / "camfuzz"
    folder.mkdir(exist_ok=True)
    for old in folder.iterdir():
        old.unlink()
    for name, data in files.items():
        (folder / name).write_bytes(data)
    target = folder / next(iter(files)) if len(files) == 1 else folder
    got = loads_or_own_error(read_cameras, target)
    if got is not None:
        cams, names, _ = got
        assert cams and len(cams) == len(names)
        assert all(np.isfinite(c.viewmat).all() and c.width > 0 and c.K[0, 0] > 0 for c in cams)


@FUZZ
@given(data=st.binary(max_size=400), name=st.sampled_from(["cams.json", "cameras.json", "transforms.json"]))
def test_arbitrary_bytes_as_a_camera_file(seeds, data, name):
    check_camera_files(seeds["tmp"], {name: data})


JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**20), 10**20) | st.floats() | st.text(max_size=8),
    lambda kids: st.lists(kids, max_size=5) | st.dictionaries(st.text(max_size=10), kids, max_size=5),
    max_leaves=30,
)


@FUZZ
@given(
    top=st.dictionaries(st.sampled_from(["cameras", "frames", "w", "h", "fl_x", "camera_model"]), JSON, max_size=4),
    cam=st.dictionaries(
        st.sampled_from(["viewmat", "K", "width", "height", "transform_matrix", "position", "rotation", "fx", "fy"]),
        JSON,
        max_size=6,
    ),
)
def test_json_camera_files_of_any_shape(seeds, top, cam):
    for doc in (dict(top, cameras=[cam]), dict(top, frames=[cam]), [dict(cam, rotation=top.get("w"))]):
        text = json.dumps(doc, allow_nan=True).encode()
        check_camera_files(seeds["tmp"], {"cams.json": text})


@FUZZ
@given(
    which=st.sampled_from(["cams.json", "cameras.json", "transforms.json", "colmap-txt", "colmap-bin"]),
    edits=EDITS,
    pick=st.integers(0, 1),
)
def test_mutated_camera_files(seeds, which, edits, pick):
    if which.startswith("colmap"):
        ext = which.split("-")[1]
        files = {f"cameras.{ext}": seeds[f"cameras.{ext}"], f"images.{ext}": seeds[f"images.{ext}"]}
        name = list(files)[pick]
        files[name] = mutate(files[name], edits)
    else:
        files = {which: mutate(seeds[which], edits)}
    check_camera_files(seeds["tmp"], files)


@FUZZ
@given(text=st.text(max_size=300))
def test_arbitrary_text_as_a_spec(seeds, text):
    p = seeds["tmp"] / "fuzz.toml"
    p.write_text(text, encoding="utf-8")
    loads_or_own_error(load_spec, p)


VALUE = st.none() | st.booleans() | st.integers(-(2**65), 2**65) | st.floats() | st.text(max_size=6)
VALUE = VALUE | st.lists(VALUE, max_size=4)
SCENE = st.dictionaries(
    st.sampled_from(["scene", "model", "ply", "n", "sh_degree", "cameras", "seed", "up", "bogus"]),
    VALUE | st.sampled_from(["spheres", "blocks", "+z", "fuzz.toml", "."]),
    max_size=4,
)
TABLE = st.dictionaries(
    st.sampled_from(
        ["precisions", "fields", "bits", "samples", "sampling", "defenses", "regions", "k", "repeats", "fault"]
    ),
    VALUE | st.sampled_from(["all", ["none", "none"], ["fp32"], ["opacity"], [0, 31], {"margin": 0.1}]),
    max_size=4,
)


@FUZZ
@given(
    top=st.dictionaries(
        st.sampled_from(["seed", "views", "size", "scale", "batch", "name", "profile", "outcomes"]),
        VALUE | st.dictionaries(st.sampled_from(["pixel_threshold", "footprint", "x"]), VALUE, max_size=2),
        max_size=4,
    ),
    scenes=st.lists(SCENE, max_size=2),
    tables=st.dictionaries(st.sampled_from(["single", "dose", "sizes"]), TABLE, max_size=2),
)
def test_specs_of_any_shape(seeds, top, scenes, tables):
    spec = loads_or_own_error(normalize_spec, dict(top, scenes=scenes, **tables), seeds["tmp"])
    if spec is not None:
        stored = spec.to_dict()
        json.dumps(stored)  # what the manifest stores
        assert stored["scenes"] and any(k in stored for k in ("single", "dose", "sizes"))


def test_the_fuzz_seeds_are_valid(seeds):
    """The mutated files start from files that load (so mutations explore the readers' depths)."""
    for name in ("m.ply", "a.ply", "v2.spz", "v3.spz", "m.splat"):
        p = seeds["tmp"] / ("ok_" + name)
        p.write_bytes(seeds[name])
        assert read_model(p).model.n == 6
    for name in ("cams.json", "cameras.json", "transforms.json"):
        p = seeds["tmp"] / name
        p.write_bytes(seeds[name])
        assert read_cameras(p)[0]
    for kind in ("txt", "bin"):  # the COLMAP seeds the camera fuzzing mutates load too
        folder = seeds["tmp"] / f"ok_colmap_{kind}"
        folder.mkdir(exist_ok=True)
        for stem in ("cameras", "images"):
            (folder / f"{stem}.{kind}").write_bytes(seeds[f"{stem}.{kind}"])
        assert len(read_cameras(folder)[0]) == 1
