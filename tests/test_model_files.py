"""Model files by content: SPZ, compressed PLY, .splat and gsplat checkpoints read against bytes
written here from each format's spec (struct/numpy, never with our writers), the two real SPZ
captures, the SPZ and PLY writers' round trips, and the errors."""

from __future__ import annotations

import gzip
import struct
import warnings

import numpy as np
import pytest
from conftest import fifo_with_writer, traced_peak

from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.formats import (
    ModelFileError,
    NonFiniteWarning,
    detect_format,
    load_model,
    read_model,
    save_model,
)
from seuwgpu.model.formats.gsplat import model_from_splats
from seuwgpu.model.formats.ply import save_ply
from seuwgpu.model.formats.spz import read_spz, save_spz, spz_values

F32 = np.float32
C0 = 0.28209479177387814
DATA = __import__("pathlib").Path(__file__).resolve().parents[1] / "seuwgpu" / "model" / "data"


def bits(a):
    return np.asarray(a, dtype=np.float32).view(np.uint32)


def assert_bit_equal(a: Model, b: Model):
    assert a.n == b.n and a.sh_degree == b.sh_degree
    for f in FIELDS:
        np.testing.assert_array_equal(bits(getattr(a, f)), bits(getattr(b, f)), err_msg=f)


# ------------------------------------------------------------------------------------------ SPZ
def spz_bytes(version, n, degree, planes, fbits=12, flags=0):
    """An SPZ file from its planes, laid out per the spec (16-byte header, planes, gzip)."""
    header = struct.pack("<IIIBBBB", 0x5053474E, version, n, degree, fbits, flags, 0)
    order = ("positions", "alphas", "colors", "scales", "rotations", "sh")
    return gzip.compress(header + b"".join(np.asarray(planes[k], np.uint8).tobytes() for k in order))


def fixed24(values, fbits=12):
    v = np.round(np.asarray(values, np.float64) * (1 << fbits)).astype(np.int64) & 0xFFFFFF
    return np.stack([v & 0xFF, (v >> 8) & 0xFF, v >> 16], axis=-1).astype(np.uint8).reshape(-1)


def spz_planes(version, degree=1):
    """Three Gaussians with hand-picked codes, and what the spec says they decode to."""
    n, dim = 3, {0: 0, 1: 3, 2: 8, 3: 15}[degree]
    pos = np.array([[0.5, -1.25, 2.0], [-2047.0, 0.0, 1 / 4096], [3.75, -0.000244140625, 100.0]])
    alphas = np.array([0, 128, 255], np.uint8)
    colors = np.array([[0, 128, 255], [64, 191, 17], [255, 0, 100]], np.uint8)
    scales = np.array([[0, 160, 255], [1, 2, 3], [150, 100, 50]], np.uint8)
    sh = (np.arange(n * dim * 3).reshape(n, dim, 3) * 7 % 256).astype(np.uint8)
    x128 = F32(128) / F32(255)
    expect = {
        "means": pos.astype(F32),
        "log_scales": scales.astype(F32) / F32(16) - F32(10),
        # log(x / (1 - x)) of the float32 x = byte / 255 (the reference's float32 steps); 0, 255 -> -+20
        "opacity": np.array([-20.0, np.log(float(x128 / (F32(1) - x128))), 20.0], F32),
        "sh_dc": ((colors.astype(F32) / F32(255)) - F32(0.5)) / F32(0.15),
        "sh_rest": (sh.astype(F32) - F32(128)) / F32(128),
    }
    if version <= 2:  # x, y, z bytes; w = sqrt(1 - |xyz|^2)
        rot = np.array([[127, 128, 128], [255, 128, 128], [200, 60, 128]], np.uint8)
        xyz = rot.astype(F32) * (F32(1) / F32(127.5)) - F32(1)
        w = np.sqrt(np.maximum(F32(0), F32(1) - (xyz**2).sum(axis=1, dtype=F32)))
        expect["quats"] = np.concatenate([w[:, None], xyz], axis=1)
    else:  # smallest three: 2 bits index of the largest (x=0 .. w=3), then 3 x (sign, 9-bit magnitude)

        def pack(largest, others):  # others: (sign, magnitude) of the remaining components in order
            c = largest
            for sgn, mag in others:
                c = (c << 10) | (sgn << 9) | mag
            return struct.pack("<I", c)

        rot = np.frombuffer(
            pack(3, [(0, 0), (0, 0), (0, 0)])
            + pack(0, [(1, 511), (0, 0), (0, 0)])
            + pack(2, [(0, 100), (1, 200), (0, 50)]),
            np.uint8,
        ).reshape(3, 4)
        s = F32(0.707106781186547524401)

        def comp(sgn, mag):
            v = s * F32(mag) / F32(511)
            return -v if sgn else v

        xyzw = np.zeros((3, 4), F32)
        xyzw[0] = (0, 0, 0, 1)
        a = comp(1, 511)
        xyzw[1] = (np.sqrt(F32(1) - a * a), a, 0, 0)
        x, y, w = comp(0, 100), comp(1, 200), comp(0, 50)
        xyzw[2] = (x, y, np.sqrt(F32(1) - ((w * w + y * y) + x * x)), w)  # summed from the last component
        expect["quats"] = xyzw[:, [3, 0, 1, 2]]
    planes = {
        "positions": fixed24(pos),
        "alphas": alphas,
        "colors": colors,
        "scales": scales,
        "rotations": rot,
        "sh": sh,
    }
    return n, planes, expect


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("degree", [0, 1, 3])
def test_spz_read_against_the_spec(tmp_path, version, degree):
    n, planes, expect = spz_planes(version, degree)
    p = tmp_path / "m.bin"  # recognised by content, not by name
    p.write_bytes(spz_bytes(version, n, degree, planes, flags=1))
    mf = read_model(p)
    assert mf.format == "spz" and mf.up == "+y" and f"SPZ version {version}" in mf.notes
    m = mf.model
    assert m.n == n and m.sh_degree == degree
    for f, want in expect.items():
        np.testing.assert_array_equal(bits(getattr(m, f)), bits(want), err_msg=f)


def test_spz_version4_zstd_streams(tmp_path):
    import zstandard as zstd  # a base dependency: a plain install opens SPZ v4

    n, planes, expect = spz_planes(3, 1)
    order = ("positions", "alphas", "colors", "scales", "rotations", "sh")
    streams = [zstd.ZstdCompressor().compress(np.asarray(planes[k], np.uint8).tobytes()) for k in order]
    sizes = [np.asarray(planes[k]).size for k in order]
    header = struct.pack("<IIIBBBBI12x", 0x5053474E, 4, n, 1, 12, 0, len(streams), 32)
    toc = b"".join(struct.pack("<QQ", len(c), u) for c, u in zip(streams, sizes))
    p = tmp_path / "v4.spz"
    p.write_bytes(header + toc + b"".join(streams))
    m = load_model(p)
    for f, want in expect.items():
        np.testing.assert_array_equal(bits(getattr(m, f)), bits(want), err_msg=f)


def test_a_zstd_spz_allocates_no_more_than_its_header_sizes(tmp_path):
    """SPZ v4: a header claiming 2^32 - 1 points is refused before any frame is inflated, and a
    frame declaring more bytes than its plane holds is refused before zstandard allocates them
    (it allocates a frame's declared size whatever max_output_size says: a MemoryError before)."""
    import zstandard as zstd

    from seuwgpu.errors import TooBig

    n, planes, _ = spz_planes(3, 0)
    order = ("positions", "alphas", "colors", "scales", "rotations")
    plain = [np.asarray(planes[k], np.uint8).tobytes() for k in order]
    frames = [zstd.ZstdCompressor().compress(p) for p in plain]

    def v4(count, frames):
        header = struct.pack("<IIIBBBBI12x", 0x5053474E, 4, count, 0, 12, 0, len(frames), 32)
        toc = b"".join(struct.pack("<QQ", len(c), len(p)) for c, p in zip(frames, plain))
        return header + toc + b"".join(frames)

    huge, lying = tmp_path / "huge.spz", tmp_path / "lying.spz"
    huge.write_bytes(v4(2**32 - 1, frames))
    small = frames[1]  # the alphas' frame: single segment, its size (3) in a 1-byte field
    assert small[4] & 0xE0 == 0x20 and small[5] == len(plain[1])
    big = small[:4] + bytes([small[4] | 0xC0]) + struct.pack("<Q", 1 << 61) + small[6:]  # an 8-byte field: 2^61
    lying.write_bytes(v4(n, frames[:1] + [big] + frames[2:]))
    with traced_peak() as peak:
        with pytest.raises(TooBig, match="SPZ point count 4294967295 needs about"):
            load_model(huge)
        declares = rf"stream 1 \(alphas\): its frame declares {1 << 61} bytes, expected 3"
        with pytest.raises(ModelFileError, match=declares):
            load_model(lying)
    assert peak[0] < 16 << 20


@pytest.mark.parametrize("name", ["leica-sofort", "yashica-t4"])
def test_real_captures(name):
    raw = gzip.decompress((DATA / f"{name}.spz").read_bytes())
    magic, version, n, degree, fbits, flags, _ = struct.unpack("<IIIBBBB", raw[:16])
    assert (magic, version, n, degree, fbits, flags) == (0x5053474E, 2, 8192, 3, 12, 1)
    m, info = read_spz(DATA / f"{name}.spz")
    assert m.n == 8192 and m.sh_degree == 3 and info.version == 2 and info.antialiased
    # the first Gaussian, decoded by hand from its bytes
    off = 16
    p = raw[off : off + 9]
    xyz = [int.from_bytes(p[3 * j : 3 * j + 3], "little", signed=True) / 4096 for j in range(3)]
    off += 9 * n
    alpha = raw[off]
    off += n
    rgb = raw[off : off + 3]
    off += 3 * n
    sc = raw[off : off + 3]
    off += 3 * n
    rot = raw[off : off + 3]
    off += 3 * n
    sh = np.frombuffer(raw[off : off + 45], np.uint8)
    np.testing.assert_array_equal(m.means[0], np.array(xyz, F32))
    np.testing.assert_array_equal(m.log_scales[0], np.array([b / 16 - 10 for b in sc], F32))
    np.testing.assert_allclose(m.sh_dc[0], [(b / 255 - 0.5) / 0.15 for b in rgb], rtol=1e-6)
    want_alpha = 20.0 if alpha == 255 else np.log((alpha / 255) / (1 - alpha / 255))
    np.testing.assert_allclose(m.opacity[0], want_alpha, rtol=1e-6)
    np.testing.assert_allclose(m.quats[0, 1:], [b / 127.5 - 1 for b in rot], atol=1e-6)
    np.testing.assert_allclose(m.sh_rest[0].reshape(-1), (sh.astype(float) - 128) / 128)
    # every value is finite (saturated alphas are +-20), and the writer reproduces the file
    assert all(np.isfinite(getattr(m, f)).all() for f in FIELDS)
    assert (m.opacity == 20.0).sum() == (np.frombuffer(raw[16 + 9 * n : 16 + 10 * n], np.uint8) == 255).sum()
    from seuwgpu.model.formats.spz import pack_spz

    assert pack_spz(m, version=2, antialiased=True) == raw  # byte for byte


def test_spz_writer_round_trips(tmp_path):
    rng = np.random.default_rng(3)
    n = 300
    m = Model(
        means=rng.uniform(-3, 3, (n, 3)),
        log_scales=rng.uniform(-9, 3, (n, 3)),
        quats=rng.standard_normal((n, 4)),
        opacity=rng.uniform(-6, 6, n),
        sh_dc=rng.uniform(-2, 2, (n, 3)),
        sh_rest=rng.uniform(-0.9, 0.9, (n, 15, 3)),
    )
    for version in (2, 3):
        p = tmp_path / f"m{version}.spz"
        save_model(m, p, version=version)
        back = load_model(p)
        # quantisation steps of the format
        np.testing.assert_allclose(back.means, m.means, atol=0.5 / 4096 + 1e-6)
        np.testing.assert_allclose(back.log_scales, m.log_scales, atol=0.5 / 16 + 1e-6)
        np.testing.assert_allclose(back.sh_rest, m.sh_rest, atol=0.5 / 128 + 1e-6)
        q = m.quats / np.linalg.norm(m.quats, axis=1, keepdims=True)
        dots = np.abs((back.quats * q).sum(axis=1))
        assert dots.min() > (0.99 if version == 2 else 0.9995)
        # a second round trip is exact: quantised values are fixed points of the writer (up to
        # the sign of a zero quaternion component, which the smallest-three code cannot keep)
        p2 = tmp_path / f"again{version}.spz"
        save_spz(back, p2, version=version)
        again = load_model(p2)
        for f in FIELDS:
            np.testing.assert_array_equal(getattr(again, f), getattr(back, f), err_msg=f)
        if version == 2:
            assert gzip.decompress(p.read_bytes()) == gzip.decompress(p2.read_bytes())
        assert_bit_equal(back, spz_values(m, version))


def test_a_gzip_spz_is_inflated_no_further_than_its_header_needs(tmp_path):
    """A few kB of gzip can inflate to gigabytes: an SPZ claiming 2^32 - 1 points is refused from
    its header (host memory, one line), and megabytes of zeros after a small model's planes are
    counted only up to 1 MiB; neither inflates the stream whole (peak traced memory, which was
    the 64 MiB of the stream before)."""
    from seuwgpu.errors import TooBig

    n, planes, _ = spz_planes(2, 1)
    good = gzip.decompress(spz_bytes(2, n, 1, planes))
    zeros = bytes(64 << 20)
    huge = tmp_path / "huge.spz"
    huge.write_bytes(gzip.compress(good[:8] + struct.pack("<I", 2**32 - 1) + good[12:16] + zeros, 1))
    tail = tmp_path / "tail.spz"
    tail.write_bytes(gzip.compress(good + zeros, 1))
    with traced_peak() as peak:
        with pytest.raises(TooBig, match="SPZ point count 4294967295 needs about") as e:
            load_model(huge)
        assert str(e.value).startswith(str(huge)) and "\n" not in str(e.value)
        with pytest.warns(UserWarning, match="over 1048576 bytes after the SPZ data ignored"):
            load_model(tail)
    assert peak[0] < 16 << 20


def test_spz_errors(tmp_path):
    n, planes, _ = spz_planes(2, 1)
    good = gzip.decompress(spz_bytes(2, n, 1, planes))
    cases = {
        "trunc.spz": (gzip.compress(good[:-5]), "truncated"),
        "magic.spz": (gzip.compress(b"XXXX" + good[4:]), "not SPZ"),
        "version.spz": (gzip.compress(good[:4] + struct.pack("<I", 9) + good[8:]), "version 9"),
        "zero.spz": (gzip.compress(good[:8] + struct.pack("<I", 0) + good[12:]), "zero"),
        "badgzip.spz": (b"\x1f\x8b" + b"\x00" * 40, "gzip"),
    }
    for name, (data, frag) in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(ModelFileError, match=frag) as e:
            load_model(p)
        assert str(p) in str(e.value)
    # bytes after the data with no extensions flagged: read as the reference reads it, with a word
    (tmp_path / "tail.spz").write_bytes(gzip.compress(good + b"tail"))
    with pytest.warns(UserWarning, match="4 bytes after the SPZ data ignored"):
        tail = load_model(tmp_path / "tail.spz")
    (tmp_path / "plain.spz").write_bytes(gzip.compress(good))
    assert np.array_equal(tail.flat(), load_model(tmp_path / "plain.spz").flat())
    with pytest.raises(ModelFileError, match="non-finite"):
        save_spz(Model.from_flat(np.full((1, 14), np.nan, F32), 0), tmp_path / "nan.spz")
    far = Model.from_flat(np.zeros((1, 14), F32), 0)
    far.means[0, 0] = 5000.0
    with pytest.raises(ModelFileError, match="24-bit"):
        save_spz(far, tmp_path / "far.spz")


# ------------------------------------------------------------------------------ compressed PLY
def test_compressed_ply_against_the_spec(tmp_path):
    n = 300  # two chunks
    rng = np.random.default_rng(0)
    chunk_names = [f"{m}_{a}" for m in ("min", "max") for a in "xyz"]
    chunk_names += [f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"]
    chunk_names += [f"{m}_{c}" for m in ("min", "max") for c in "rgb"]
    chunks = np.zeros(2, [(k, "<f4") for k in chunk_names])
    for c in range(2):
        lo, hi = rng.uniform(-2, 0, 3), rng.uniform(0.5, 2, 3)
        for j, a in enumerate("xyz"):
            chunks[f"min_{a}"][c], chunks[f"max_{a}"][c] = lo[j], hi[j]
            chunks[f"min_scale_{a}"][c], chunks[f"max_scale_{a}"][c] = -7 + c, -2 - c
        for ch in "rgb":
            chunks[f"min_{ch}"][c], chunks[f"max_{ch}"][c] = -0.2, 1.1
    px, py, pz = rng.integers(0, 2048, n), rng.integers(0, 1024, n), rng.integers(0, 2048, n)
    which = rng.integers(0, 4, n)
    abc = rng.integers(0, 1024, (n, 3))
    col = rng.integers(0, 256, (n, 4))
    col[:, 3] = rng.integers(1, 255, n)  # unsaturated alphas, but for the first two
    col[:2, 3] = (255, 0)
    vert = np.zeros(
        n, [("packed_position", "<u4"), ("packed_rotation", "<u4"), ("packed_scale", "<u4"), ("packed_color", "<u4")]
    )
    vert["packed_position"] = (px << 21) | (py << 11) | pz
    vert["packed_rotation"] = (which << 30) | (abc[:, 0] << 20) | (abc[:, 1] << 10) | abc[:, 2]
    vert["packed_scale"] = (pz << 21) | (py << 11) | px
    vert["packed_color"] = (col[:, 0] << 24) | (col[:, 1] << 16) | (col[:, 2] << 8) | col[:, 3]
    sh = rng.integers(0, 256, (n, 9)).astype(np.uint8)
    sh[0, :2] = (0, 255)
    head = ["ply", "format binary_little_endian 1.0", "comment Generated by splat-transform ✓", "element chunk 2"]
    head += [f"property float {k}" for k in chunk_names] + [f"element vertex {n}"]
    head += [f"property uint {k}" for k in vert.dtype.names] + [f"element sh {n}"]
    head += [f"property uchar f_rest_{i}" for i in range(9)] + ["end_header"]
    p = tmp_path / "scene.compressed.ply"
    p.write_bytes(("\n".join(head) + "\n").encode() + chunks.tobytes() + vert.tobytes() + sh.tobytes())
    assert detect_format(p) == "compressed-ply"
    m = load_model(p)
    ci = np.arange(n) // 256

    def lerp(name_lo, name_hi, code, bits_):
        lo = chunks[name_lo].astype(np.float64)[ci]
        hi = chunks[name_hi].astype(np.float64)[ci]
        t = code / (2**bits_ - 1)
        return (lo * (1 - t) + hi * t).astype(F32)

    np.testing.assert_array_equal(m.means[:, 0], lerp("min_x", "max_x", px, 11))
    np.testing.assert_array_equal(m.means[:, 1], lerp("min_y", "max_y", py, 10))
    np.testing.assert_array_equal(m.log_scales[:, 2], lerp("min_scale_z", "max_scale_z", px, 11))
    r = lerp("min_r", "max_r", col[:, 0], 8).astype(np.float64)
    np.testing.assert_allclose(m.sh_dc[:, 0], (r - 0.5) / C0, rtol=1e-6, atol=1e-6)
    assert m.opacity[0] == 20.0 and m.opacity[1] == -20.0
    full, empty = int((col[:, 3] == 255).sum()), int((col[:, 3] == 0).sum())  # the reference's +-inf rows
    assert read_model(p).notes == [
        f"opacity +inf in {full} rows, from packed alpha 1.0, as the reference decoder gives: read as +20, drawn the "
        "same (alpha 1, capped at 0.99)",
        f"opacity -inf in {empty} rows, from packed alpha 0.0, as the reference decoder gives: read as -20, drawn the "
        "same (skipped)",
    ]
    a = col[2:, 3] / 255
    np.testing.assert_allclose(m.opacity[2:], np.log(a / (1 - a)), rtol=1e-5, atol=1e-5)
    # quaternion: the largest component at `which`, the others in order, each (code/1023 - 0.5) * sqrt 2
    others = (abc / 1023 - 0.5) * np.sqrt(2)
    for i in range(n):
        rest = [k for k in range(4) if k != which[i]]
        np.testing.assert_allclose(m.quats[i, rest], others[i], atol=1e-6)
        np.testing.assert_allclose(m.quats[i, which[i]], np.sqrt(max(0.0, 1 - (others[i] ** 2).sum())), atol=1e-6)
    # SH: byte b -> ((b + 0.5) / 256 - 0.5) * 8 (0 and 255 at the ends), channel-major f_rest
    v = np.where(sh == 0, 0.0, np.where(sh == 255, 1.0, (sh + 0.5) / 256))
    want = ((v - 0.5) * 8).reshape(n, 3, 3).transpose(0, 2, 1)
    np.testing.assert_allclose(m.sh_rest, want, atol=1e-6)
    assert m.sh_rest[0, 0, 0] == -4.0 and m.sh_rest[0, 1, 0] == 4.0


def test_small_gzip_file_is_not_spz_before_too_short(tmp_path):
    """A gzipped file shorter than SPZ's 16-byte header is first of all not SPZ (no NGSP magic):
    said so, not "SPZ stream too short"; an NGSP stream cut short is still too short."""
    for name, raw in (("text.spz", b"hello"), ("empty.spz", b""), ("twelve.spz", b"not spz, no!")):
        (tmp_path / name).write_bytes(gzip.compress(raw))
        with pytest.raises(ModelFileError, match="gzip file that is not SPZ") as e:
            load_model(tmp_path / name)
        assert str(tmp_path / name) in str(e.value) and "too short" not in str(e.value)
    (tmp_path / "cut.spz").write_bytes(gzip.compress(struct.pack("<II", 0x5053474E, 2)))
    with pytest.raises(ModelFileError, match="SPZ stream too short for its 16-byte header"):
        load_model(tmp_path / "cut.spz")


# ------------------------------------------------------------------------------------- .splat
def test_splat_against_the_spec(tmp_path):
    rec = np.zeros(4, [("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
    rec["pos"] = [[1, 2, 3], [-1, 0.5, 0], [0, 0, 0], [7, 8, 9]]
    rec["scale"] = [[0.01, 0.02, 0.5], [1, 1, 1], [2e-4, 1e-3, 3.0], [0.1, 0.1, 0.1]]
    rec["rgba"] = [[255, 0, 128, 200], [10, 20, 30, 255], [0, 0, 0, 0], [128, 128, 128, 1]]
    rec["rot"] = [[255, 128, 128, 128], [128, 255, 0, 128], [128, 128, 128, 128], [200, 100, 150, 50]]
    p = tmp_path / "scene.splat"
    p.write_bytes(rec.tobytes())
    mf = read_model(p)
    assert mf.format == "splat" and mf.model.sh_degree == 0
    m = mf.model
    np.testing.assert_array_equal(m.means, rec["pos"])
    np.testing.assert_array_equal(m.log_scales, np.log(rec["scale"].astype(np.float64)).astype(F32))
    np.testing.assert_array_equal(m.sh_dc, ((rec["rgba"][:, :3] / 255 - 0.5) / C0).astype(F32))
    a = rec["rgba"][[0, 3], 3] / 255
    np.testing.assert_array_equal(m.opacity[[0, 3]], np.log(a / (1 - a)).astype(F32))
    assert m.opacity[1] == 20.0 and m.opacity[2] == -20.0
    q = (rec["rot"] / 128 - 1).astype(F32)
    q[2] = (1, 0, 0, 0)  # an all-128 rotation is the identity
    np.testing.assert_array_equal(m.quats, q)
    (tmp_path / "bad.splat").write_bytes(rec.tobytes()[:-3])
    with pytest.raises(ModelFileError, match="multiple of the 32-byte record"):
        load_model(tmp_path / "bad.splat")


def test_splat_recognised_by_content_but_not_text(tmp_path):
    """Without the extension, 8 or more records of encoded unit quaternions are a .splat; text
    (whose bytes read as finite positive floats) and short files are not."""
    rng = np.random.default_rng(3)
    n = 9
    rec = np.zeros(n, [("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
    rec["pos"] = rng.normal(size=(n, 3))
    rec["scale"] = rng.uniform(0.01, 0.1, (n, 3))
    q = rng.normal(size=(n, 4))
    rec["rot"] = np.clip(np.round(q / np.linalg.norm(q, axis=1, keepdims=True) * 128 + 128), 0, 255)
    p = tmp_path / "scene.data"
    p.write_bytes(rec.tobytes())
    assert read_model(p).format == "splat" and read_model(p).model.n == n
    for name, data in (
        ("notes.ply", b"abcdefghijklmnopqrstuvwxyz012345" * 10),
        ("short.data", rec[:7].tobytes()),  # 7 records: too few to tell without the extension
    ):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ModelFileError, match="unrecognised model file"):
            read_model(tmp_path / name)
    (tmp_path / "short.splat").write_bytes(rec[:7].tobytes())
    assert read_model(tmp_path / "short.splat").model.n == 7


def test_splat_named_file_must_look_like_one(tmp_path):
    """The .splat extension skips format sniffing, not the content check: a text file (whose size
    happens to be a multiple of 32) is refused with the reason instead of loading as garbage."""
    for name, data, why in (
        ("notes.splat", b"abcdefghijklmnopqrstuvwxyz012345" * 10, "its first bytes are text"),
        ("short.splat", b"0123456789abcdef" * 4, "its first bytes are text"),  # 2 records of text
        ("empty.splat", b"", "the file is empty"),
        ("noise.splat", np.full(9 * 32, 255, np.uint8).tobytes(), "finite positions and positive scales"),
    ):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ModelFileError, match=f"does not look like an antimatter15 .splat file: .*{why}") as e:
            read_model(tmp_path / name)
        assert str(e.value).startswith(str(tmp_path / name))


# ------------------------------------------------------------------------------------- gsplat
def test_gsplat_splats_dict():
    rng = np.random.default_rng(1)
    n = 5
    splats = {
        "means": rng.standard_normal((n, 3)),
        "scales": rng.standard_normal((n, 3)),
        "quats": rng.standard_normal((n, 4)),
        "opacities": rng.standard_normal(n),
        "sh0": rng.standard_normal((n, 1, 3)),
        "shN": rng.standard_normal((n, 8, 3)),
    }
    m = model_from_splats(splats)
    assert m.sh_degree == 2
    np.testing.assert_array_equal(m.log_scales, splats["scales"].astype(F32))
    np.testing.assert_array_equal(m.quats, splats["quats"].astype(F32))  # w, x, y, z as gsplat
    np.testing.assert_array_equal(m.sh_dc, splats["sh0"][:, 0].astype(F32))
    np.testing.assert_array_equal(m.sh_rest, splats["shN"].astype(F32))
    with pytest.raises(ModelFileError, match="lacks opacities"):
        model_from_splats({k: v for k, v in splats.items() if k != "opacities"}, "ckpt.pt")


def test_gsplat_checkpoint(tmp_path):
    p = tmp_path / "ckpt_29999.pt"
    try:
        import torch
    except ImportError:
        import pickle
        import zipfile

        with zipfile.ZipFile(p, "w") as z:  # what torch.save writes: a zip with a pickle inside
            z.writestr("archive/data.pkl", pickle.dumps({"step": 1}))
        assert detect_format(p) == "gsplat"
        with pytest.raises(ModelFileError, match=r"seuwgpu\[torch\]"):
            load_model(p)
        return
    n = 4
    splats = {
        "means": torch.randn(n, 3),
        "scales": torch.randn(n, 3),
        "quats": torch.randn(n, 4),
        "opacities": torch.randn(n),
        "sh0": torch.randn(n, 1, 3),
        "shN": torch.randn(n, 15, 3),
    }
    torch.save({"step": 29999, "splats": splats}, p)
    m = load_model(p)
    np.testing.assert_array_equal(m.means, splats["means"].numpy())
    assert m.sh_degree == 3


# ------------------------------------------------------------------------------ by content, writers
def test_detection_by_content_not_extension(tmp_path):
    m = spz_values(Model.from_flat(np.random.default_rng(2).uniform(-1, 1, (6, 14 + 9)).astype(F32), 1))
    save_ply(m, tmp_path / "a.ply")
    save_spz(m, tmp_path / "a.spz")
    (tmp_path / "ply_named.spz").write_bytes((tmp_path / "a.ply").read_bytes())
    (tmp_path / "spz_named.ply").write_bytes((tmp_path / "a.spz").read_bytes())
    assert detect_format(tmp_path / "ply_named.spz") == "ply"
    assert detect_format(tmp_path / "spz_named.ply") == "spz"
    assert_bit_equal(load_model(tmp_path / "ply_named.spz"), m)
    assert_bit_equal(load_model(tmp_path / "spz_named.ply"), m)
    (tmp_path / "junk.ply").write_bytes(b"hello world, not a model" * 3)
    with pytest.raises(ModelFileError, match="unrecognised model file") as e:
        load_model(tmp_path / "junk.ply")
    assert str(tmp_path / "junk.ply") in str(e.value)
    with pytest.raises(ModelFileError, match="write .ply"):
        save_model(m, tmp_path / "a.obj")


def test_ply_up_comment_and_save_model(tmp_path):
    m = Model.from_flat(np.zeros((2, 14), F32), 0)
    save_model(m, tmp_path / "z.ply", up="+z")
    assert read_model(tmp_path / "z.ply").up == "+z"
    save_model(m, tmp_path / "plain.ply")
    assert read_model(tmp_path / "plain.ply").up == "-y"  # COLMAP's y-down convention


def test_nonfinite_values_warn_with_count_and_fields(tmp_path):
    m = Model.from_flat(np.zeros((4, 14), F32), 0)
    m.opacity[1] = np.nan
    m.means[2, 0] = np.inf
    m.means[3, 1] = -np.inf
    save_ply(m, tmp_path / "nan.ply")
    with pytest.warns(NonFiniteWarning, match=r"3 non-finite values \(means 2, opacity 1\)"):
        load_model(tmp_path / "nan.ply")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_ply(Model.from_flat(np.zeros((1, 14), F32), 0), tmp_path / "ok.ply")
        load_model(tmp_path / "ok.ply")


def test_compressed_ply_packed_properties_must_be_32_bit_words(tmp_path):
    """packed_* are bit fields: declared as floats they would decode to garbage (with numpy cast
    warnings), so such a file is refused naming the properties."""
    chunk_names = [f"{m}_{a}" for m in ("min", "max") for a in "xyz"]
    chunk_names += [f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"]
    head = ["ply", "format binary_little_endian 1.0", "element chunk 1"]
    head += [f"property float {k}" for k in chunk_names] + ["element vertex 4"]
    packed = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
    head += [f"property float {k}" for k in packed] + ["end_header"]
    p = tmp_path / "scene.compressed.ply"
    data = np.zeros(12, "<f4").tobytes() + np.full((4, 4), 3.5e9, "<f4").tobytes()
    p.write_bytes(("\n".join(head) + "\n").encode() + data)
    assert detect_format(p) == "compressed-ply"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ModelFileError, match=r"packed properties must be uint32, got packed_position \(float32\)"):
            load_model(p)
    # int32 holds the same bits as uint32: accepted
    p.write_bytes(p.read_bytes().replace(b"property float packed", b"property int packed"))
    assert load_model(p).n == 4
    # a list property is no 32-bit word either: named, not a numpy TypeError
    p.write_bytes(p.read_bytes().replace(b"property int packed_color", b"property list uchar uint packed_color"))
    with pytest.raises(ModelFileError, match=r"packed properties must be uint32, got packed_color \(list\)"):
        load_model(p)


@pytest.mark.parametrize(
    "change, match",
    [
        ({"sh0": np.zeros((5, 2, 3))}, "inconsistent shapes"),
        ({"shN": np.zeros((5, 7))}, "inconsistent shapes"),
        ({"means": "abc"}, "not numeric"),
        ("empty", "zero splats"),
    ],
)
def test_gsplat_bad_splats_name_the_file(change, match):
    n = 5
    splats = {
        "means": np.zeros((n, 3)),
        "scales": np.zeros((n, 3)),
        "quats": np.tile([1.0, 0, 0, 0], (n, 1)),
        "opacities": np.zeros(n),
        "sh0": np.zeros((n, 1, 3)),
        "shN": np.zeros((n, 3, 3)),
    }
    splats = {k: v[:0] for k, v in splats.items()} if change == "empty" else dict(splats, **change)
    with pytest.raises(ModelFileError, match=f"ckpt.pt: .*{match}"):
        model_from_splats(splats, "ckpt.pt")


def test_model_path_that_is_no_regular_file_is_refused(tmp_path):
    with fifo_with_writer(tmp_path / "model.ply") as fifo:
        with pytest.raises(ModelFileError, match="not a regular file"):
            read_model(fifo)


def test_a_zip_that_is_no_torch_checkpoint_is_not_called_one(tmp_path):
    """Every zip (a .npz of renders, a zipped output folder) starts like torch.save's output;
    only one holding data.pkl is a checkpoint, the others are named for what they are."""
    import zipfile

    np.savez(tmp_path / "frames.npz", images=np.zeros(3))
    with zipfile.ZipFile(tmp_path / "scene.zip", "w") as z:
        z.writestr("output/point_cloud.ply", "ply\n")
    for name, holds in (("frames.npz", "images.npy"), ("scene.zip", "output/point_cloud.ply")):
        with pytest.raises(ModelFileError, match=f"zip archive that is no PyTorch checkpoint \\(it holds {holds}\\)"):
            read_model(tmp_path / name)
    # a truncated one is named broken (its central directory is gone), whatever its name says
    (tmp_path / "cut.pt").write_bytes((tmp_path / "scene.zip").read_bytes()[:40])
    with pytest.raises(ModelFileError, match="cut.pt: a broken zip archive"):
        read_model(tmp_path / "cut.pt")


def test_inria_output_folder_names_the_iteration_read(tmp_path):
    """An INRIA output folder is read from its last iteration, and the notes (printed by the
    commands as one line) say which."""
    run = tmp_path / "run"
    m = Model.from_flat(np.zeros((2, 14), F32), 0)
    for it in (7000, 30000, 900):
        (run / "point_cloud" / f"iteration_{it}").mkdir(parents=True)
        save_ply(m, run / "point_cloud" / f"iteration_{it}" / "point_cloud.ply")
    mf = read_model(run)
    assert mf.path == run / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    assert "iteration 30000 (point_cloud/iteration_30000/point_cloud.ply, the last of 3)" in mf.notes
    assert not any("iteration" in n for n in read_model(mf.path).notes)  # the file itself: no note
