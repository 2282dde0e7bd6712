"""`.ksplat` and SOG files made from the committed fixtures (tests/data/formats): the valid ones
render like splat-transform's decode of them and work in inject and campaigns; damaged or
inconsistent ones end in a clear one-line error; consistent oddities are read as they say."""

from __future__ import annotations

import io
import json
import os
import shutil
import struct
import zipfile
import zlib

import numpy as np
import pytest
from PIL import Image

from robustness.checks import bit_flipped, npz_like, npz_shape, records_of
from robustness.conftest import FIXTURES, FORMAT_FIXTURES
from robustness.outcomes import expect_outcome, spec_text

SECTION = 4096  # a .ksplat's first section header


def render(fresh, work, model, expect="ok", views=None):
    """A render of `model` with the two 16x16 cameras of cams.json (or `views` framed by the
    model), checked for its size and finite pixels."""
    extra = ["--views", str(views), "--size", "16x16"] if views else ["--cameras", work / "cams.json"]
    out = fresh("render", ".npz")
    check = npz_shape(out, ((views or 2), 16, 16, 3)) if expect == "ok" else None
    expect_outcome(["render", "--model", model, *extra, "--out", out], expect, check)


# ---- the valid fixtures ------------------------------------------------------------------------
@pytest.mark.parametrize("name", FORMAT_FIXTURES)
def test_a_valid_file_renders_like_its_decode_by_splat_transform(fresh, work, name):
    cams = ["--cameras", work / "cams.json"]
    ref = fresh("render", ".npz")
    expect_outcome(
        ["render", "--model", work / f"{name}.ref.ply", *cams, "--out", ref], "ok", npz_shape(ref, (2, 16, 16, 3))
    )
    out = fresh("render", ".npz")
    expect_outcome(["render", "--model", work / name, *cams, "--out", out], "ok", npz_like(out, ref, (2, 16, 16, 3)))


def test_a_valid_unbundled_sog_by_its_meta_json(fresh, work):
    render(fresh, work, work / "sog_meta" / "meta.json")


@pytest.mark.parametrize("name", ["sog_meta", "sh3.sog", "level1_sh1.ksplat"])
def test_a_valid_file_framed_by_the_model(fresh, work, name):
    render(fresh, work, work / name, views=1)


@pytest.mark.parametrize(
    "src, suffix", [("level2_sh2.ksplat", ".bin"), ("sh3.sog", ".zip")], ids=["ksplat named .bin", "sog named .zip"]
)
def test_a_valid_file_under_another_suffix_is_recognised_by_content(fresh, work, src, suffix):
    p = fresh("model", suffix)
    shutil.copy(FIXTURES / src, p)
    render(fresh, work, p)


def sog_folder(fresh, change=None, drop=(), replace=None, meta_bytes=None):
    """A copy of the unbundled fixture sog_meta/ with meta.json changed, images dropped or replaced."""
    d = fresh("sogdir")
    shutil.copytree(FIXTURES / "sog_meta", d)
    if change is not None:
        meta = json.loads((d / "meta.json").read_text())
        change(meta)
        (d / "meta.json").write_text(json.dumps(meta))
    if meta_bytes is not None:
        (d / "meta.json").write_bytes(meta_bytes)
    for name in drop:
        (d / name).unlink()
    for name, data in (replace or {}).items():
        (d / name).write_bytes(data)
    return d


def test_a_valid_unbundled_sog_as_scene_json(fresh, work):
    d = sog_folder(fresh)
    (d / "meta.json").rename(d / "scene.json")
    render(fresh, work, d / "scene.json")


@pytest.mark.parametrize("name", ["sh3.sog", "sog_meta", "level2_sh2.ksplat"])
def test_inject_into_a_valid_file(fresh, work, name):
    out = fresh("inj")
    argv = ["inject", "--model", work / name, "--views", "1", "--size", "16x16", "--field", "opacity"]
    expect_outcome([*argv, "--primitive", "3", "--bit", "30", "--out", out], "ok", bit_flipped(out, 30))


@pytest.mark.parametrize(
    "name, label",
    [
        ("sh3.sog", "sh3"),
        ("sog_meta", "sog_meta"),
        ("sog_meta/meta.json", "sog_meta"),
        ("level1_sh1.ksplat", "level1_sh1"),
    ],
)
def test_a_campaign_on_a_valid_file(fresh, work, name, label):
    spec = fresh("spec", ".toml")
    spec.write_text(spec_text(scene=f'model = "{name}"\n'))
    out = fresh("run")
    expect_outcome(["campaign", spec, "--out", out, "--quiet"], "ok", records_of(out, 2, label))


# ---- .ksplat -----------------------------------------------------------------------------------
def ksplat(level: int) -> bytes:
    return (FIXTURES / f"level{level}_sh{(2, 1, 2)[level]}.ksplat").read_bytes()


def put(data: bytes, *edits) -> bytes:
    """data with (offset, struct format, value) edits."""
    b = bytearray(data)
    for offset, fmt, value in edits:
        struct.pack_into(fmt, b, offset, value)
    return bytes(b)


S = SECTION
BAD_KSPLAT = {  # name: (level of the fixture, change of its bytes)
    "empty .ksplat": (2, lambda k: b""),
    "cut to 100 bytes": (2, lambda k: k[:100]),
    "cut to 4095 bytes": (2, lambda k: k[:4095]),
    "cut to its main header": (2, lambda k: k[:4096]),
    "cut in its section header": (2, lambda k: k[: S + 512]),
    "cut after its headers": (2, lambda k: k[: S + 1024]),
    "cut in its bucket table": (2, lambda k: k[: S + 1024 + 60]),
    "cut mid-records": (2, lambda k: k[: len(k) // 2 + 7]),
    "one byte short": (2, lambda k: k[:-1]),
    "level 0, one byte short": (0, lambda k: k[:-1]),
    "a byte past its end": (2, lambda k: k + b"\0"),
    "4096 zeros past its end": (1, lambda k: k + bytes(4096)),
    "version 1.1": (2, lambda k: put(k, (0, "B", 1))),
    "version 0.0": (2, lambda k: put(k, (1, "B", 0))),
    "compression level 3": (2, lambda k: put(k, (20, "<H", 3))),
    "compression level 65535": (2, lambda k: put(k, (20, "<H", 65535))),
    "level 0 marked level 1": (0, lambda k: put(k, (20, "<H", 1))),
    "level 2 marked level 1": (2, lambda k: put(k, (20, "<H", 1))),
    "level 1 marked level 0": (1, lambda k: put(k, (20, "<H", 0))),
    "0 sections": (2, lambda k: put(k, (4, "<I", 0))),
    "2 sections": (2, lambda k: put(k, (4, "<I", 2))),
    "2**32-1 sections": (2, lambda k: put(k, (4, "<I", 2**32 - 1))),
    "header counts 300 splats": (2, lambda k: put(k, (16, "<I", 300))),
    "header counts 0 splats": (2, lambda k: put(k, (16, "<I", 0))),
    "header counts 2**32-1 splats": (2, lambda k: put(k, (16, "<I", 2**32 - 1))),
    "0 splats in header and section": (2, lambda k: put(k, (16, "<I", 0), (S, "<I", 0))),
    "a section over its capacity": (2, lambda k: put(k, (16, "<I", 257), (S, "<I", 257))),
    "section capacity 255": (2, lambda k: put(k, (S + 4, "<I", 255))),
    "section capacity 2**32-1": (2, lambda k: put(k, (S + 4, "<I", 2**32 - 1))),
    "2**32-1 buckets": (2, lambda k: put(k, (S + 12, "<I", 2**32 - 1))),
    "24 buckets of 25": (2, lambda k: put(k, (S + 12, "<I", 24))),
    "8-byte buckets": (1, lambda k: put(k, (S + 20, "<H", 8))),
    "0-byte buckets": (2, lambda k: put(k, (S + 20, "<H", 0))),
    "no full buckets": (2, lambda k: put(k, (S + 32, "<I", 0))),
    "2**32-1 partial buckets": (2, lambda k: put(k, (S + 36, "<I", 2**32 - 1))),
    "bucket size 0": (1, lambda k: put(k, (S + 8, "<I", 0))),
    "SH degree 3": (2, lambda k: put(k, (S + 40, "<H", 3))),
    "SH degree 65535": (2, lambda k: put(k, (S + 40, "<H", 65535))),
    "SH degree 1 in a degree-2 file": (2, lambda k: put(k, (S + 40, "<H", 1))),
    "SH degree 2 in a degree-1 file": (1, lambda k: put(k, (S + 40, "<H", 2))),
    "bucket block NaN": (1, lambda k: put(k, (S + 16, "<f", float("nan")))),
    "bucket block inf": (2, lambda k: put(k, (S + 16, "<f", float("inf")))),
}
GOOD_KSPLAT = {  # consistent files: read as they say
    "255 of its 256 splats": (2, lambda k: put(k, (16, "<I", 255), (S, "<I", 255))),
    "position range 1": (1, lambda k: put(k, (S + 24, "<I", 1))),
    "bucket block 1e30": (1, lambda k: put(k, (S + 16, "<f", 1e30))),
    "SH range NaN": (2, lambda k: put(k, (36, "<f", float("nan")), (40, "<f", float("nan")))),
    "SH range +-1e30": (2, lambda k: put(k, (36, "<f", -1e30), (40, "<f", 1e30))),
    "unused section count 9": (2, lambda k: put(k, (8, "<I", 9))),
}


@pytest.mark.parametrize("level, change", list(BAD_KSPLAT.values()), ids=list(BAD_KSPLAT))
def test_a_damaged_ksplat(fresh, work, level, change):
    p = fresh("model", ".ksplat")
    p.write_bytes(change(ksplat(level)))
    render(fresh, work, p, "error")


def test_a_damaged_ksplat_named_bin(fresh, work):
    p = fresh("model", ".bin")
    p.write_bytes(ksplat(2)[:-1])
    render(fresh, work, p, "error")


@pytest.mark.parametrize("level, change", list(GOOD_KSPLAT.values()), ids=list(GOOD_KSPLAT))
def test_a_consistent_odd_ksplat_is_read_as_it_says(fresh, work, level, change):
    p = fresh("model", ".ksplat")
    p.write_bytes(change(ksplat(level)))
    render(fresh, work, p, "ok", views=1)


# ---- SOG ---------------------------------------------------------------------------------------
def webp_claiming(width: int, height: int) -> bytes:
    """A lossless WebP of 16 x 16 texels whose header claims width x height (no data for them)."""
    buf = io.BytesIO()
    Image.fromarray(np.zeros((16, 16, 4), np.uint8)).save(buf, "WEBP", lossless=True)
    b = bytearray(buf.getvalue())
    assert b[12:16] == b"VP8L" and b[20] == 0x2F
    bits = struct.unpack_from("<I", b, 21)[0] & ~0xFFFFFFF
    struct.pack_into("<I", b, 21, bits | (width - 1) | (height - 1) << 14)
    return bytes(b)


def crc_broken(zip_bytes: bytes, member: str) -> bytes:
    """A zip whose `member`'s stored bytes no longer match its CRC (one byte flipped)."""
    with zipfile.ZipFile(io.BytesIO(zip_bytes)) as z:
        info = z.getinfo(member)
    b = bytearray(zip_bytes)
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    b[start + info.compress_size // 2] ^= 0xFF
    assert zlib.crc32(b[start : start + info.compress_size]) != info.CRC
    return bytes(b)


def image(size: int, kind: str) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.zeros((size, size, 4), np.uint8)).save(buf, kind, lossless=True)
    return buf.getvalue()


class Sog:
    """The sh3.sog fixture's members, and zips made from them."""

    def __init__(self):
        self.whole = (FIXTURES / "sh3.sog").read_bytes()
        with zipfile.ZipFile(FIXTURES / "sh3.sog") as z:
            self.members = {n: z.read(n) for n in z.namelist()}
        self.meta = json.loads(self.members["meta.json"])

    def zip(self, change=None, drop=(), replace=None) -> bytes:
        """sh3.sog with meta.json changed (`change(meta)`), members dropped or replaced."""
        meta = json.loads(json.dumps(self.meta))
        if change is not None:
            change(meta)
        members = {**self.members, "meta.json": json.dumps(meta).encode(), **(replace or {})}
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            for name, data in members.items():
                if name not in drop:
                    z.writestr(name, data)
        return buf.getvalue()


def at(key, **values):
    return lambda meta: meta[key].update(values)


def top(**values):
    return lambda meta: meta.update(values)


def pop(*path):
    def change(meta):
        d = meta
        for k in path[:-1]:
            d = d[k]
        d.pop(path[-1])

    return change


def nan_entry(meta):
    meta["scales"]["codebook"][5] = float("nan")


def centroids(s: Sog) -> bytes:
    return s.members["shN_centroids.webp"]


BAD_SOG = {  # name: the .sog's bytes from Sog
    "empty .sog": lambda s: b"",
    "a .sog that is text": lambda s: b"not a zip, not a model\n",
    "a .sog that is JSON": lambda s: json.dumps(s.meta).encode(),
    "cut to 100 bytes": lambda s: s.whole[:100],
    "cut in half": lambda s: s.whole[: len(s.whole) // 2],
    "cut before its directory's end": lambda s: s.whole[:-22],
    "one byte short": lambda s: s.whole[:-1],
    "an empty zip": lambda s: s.zip(drop=tuple(s.members)),
    "a zip without meta.json": lambda s: s.zip(drop=("meta.json",)),
    "meta.json not JSON": lambda s: s.zip(replace={"meta.json": b"{not json"}),
    "meta.json a list": lambda s: s.zip(replace={"meta.json": b"[1, 2]"}),
    "meta.json not UTF-8": lambda s: s.zip(replace={"meta.json": b'{"version": 2, "\xff": 1}'}),
    "meta.json without version": lambda s: s.zip(pop("version")),
    "version 3": lambda s: s.zip(top(version=3)),
    'version "2"': lambda s: s.zip(top(version="2")),
    "version true": lambda s: s.zip(top(version=True)),
    "version null": lambda s: s.zip(top(version=None)),
    "count 0": lambda s: s.zip(top(count=0)),
    "count -1": lambda s: s.zip(top(count=-1)),
    "count 257, above its images": lambda s: s.zip(top(count=257)),
    "count 2**40": lambda s: s.zip(top(count=2**40)),
    'count "256"': lambda s: s.zip(top(count="256")),
    "count 256.5": lambda s: s.zip(top(count=256.5)),
    "count missing": lambda s: s.zip(pop("count")),
    "means.mins NaN": lambda s: s.zip(at("means", mins=[float("nan")] * 3)),
    "means.maxs Infinity": lambda s: s.zip(at("means", maxs=[float("inf")] * 3)),
    "means.mins -1e308, maxs 1e308": lambda s: s.zip(at("means", mins=[-1e308] * 3, maxs=[1e308] * 3)),
    "means.mins 2 numbers": lambda s: s.zip(at("means", mins=[0.0, 0.0])),
    "means.mins text": lambda s: s.zip(at("means", mins=["a", "b", "c"])),
    "means.maxs missing": lambda s: s.zip(pop("means", "maxs")),
    "means lists one image": lambda s: s.zip(at("means", files=["means_l.webp"])),
    "means.files not a list": lambda s: s.zip(at("means", files="means_l.webp")),
    "an image named 5": lambda s: s.zip(at("quats", files=[5])),
    "quats missing": lambda s: s.zip(pop("quats")),
    "scales codebook of 255": lambda s: s.zip(at("scales", codebook=[0.0] * 255)),
    "scales codebook all NaN": lambda s: s.zip(at("scales", codebook=[float("nan")] * 256)),
    "sh0 codebook of text": lambda s: s.zip(at("sh0", codebook=["x"] * 256)),
    "shN.bands 4": lambda s: s.zip(at("shN", bands=4)),
    'shN.bands "3"': lambda s: s.zip(at("shN", bands="3")),
    "shN.bands true": lambda s: s.zip(at("shN", bands=True)),
    "shN.count 0": lambda s: s.zip(at("shN", count=0)),
    "shN.count 3, below its labels": lambda s: s.zip(at("shN", count=3)),
    "shN.bands 2 for degree-3 centroids": lambda s: s.zip(at("shN", bands=2)),
    "shN without files": lambda s: s.zip(pop("shN", "files")),
    "an image missing": lambda s: s.zip(drop=("quats.webp",)),
    "an image of 0 bytes": lambda s: s.zip(replace={"sh0.webp": b""}),
    "an image of garbage": lambda s: s.zip(replace={"scales.webp": b"RIFF\x10\0\0\0WEBPgarbage!"}),
    "a PNG where a WebP belongs": lambda s: s.zip(replace={"quats.webp": image(16, "PNG")}),
    "an image of 8 x 8 texels": lambda s: s.zip(replace={"means_u.webp": image(8, "WEBP")}),
    "centroids as labels": lambda s: s.zip(replace={"shN_labels.webp": centroids(s)}),
    "an image cut in half": lambda s: s.zip(replace={"shN_centroids.webp": centroids(s)[: len(centroids(s)) // 2]}),
    # 268 M pixels: Pillow's decompression-bomb limit
    "an image claiming 16383 x 16383 texels": lambda s: s.zip(replace={"sh0.webp": webp_claiming(16383, 16383)}),
    # 108 M pixels: under it, but no image data behind
    "an image claiming 12000 x 9000 texels": lambda s: s.zip(replace={"sh0.webp": webp_claiming(12000, 9000)}),
    "a member's CRC broken": lambda s: crc_broken(s.zip(), "quats.webp"),
}
GOOD_SOG = {  # read as they say
    "count 100, below its images": lambda s: s.zip(top(count=100)),
    "version 2.0": lambda s: s.zip(top(version=2.0)),
    "mins above maxs": lambda s: s.zip(at("means", mins=s.meta["means"]["maxs"], maxs=s.meta["means"]["mins"])),
    "mins equal to maxs": lambda s: s.zip(at("means", mins=[0.1] * 3, maxs=[0.1] * 3)),
    "maxs 60 (positions near 1e26)": lambda s: s.zip(at("means", maxs=[60.0] * 3)),
    "one NaN scales codebook entry": lambda s: s.zip(nan_entry),
    "shN.bands 0": lambda s: s.zip(at("shN", bands=0)),
    "no shN": lambda s: s.zip(pop("shN")),
    'model "2dgs"': lambda s: s.zip(top(model="2dgs")),
    'model "bogus"': lambda s: s.zip(top(model="bogus")),
    "meta.json with a BOM": lambda s: s.zip(replace={"meta.json": b"\xef\xbb\xbf" + s.members["meta.json"]}),
    "an extra member": lambda s: s.zip(replace={"readme.txt": b"hello"}),
}
IMAGES = [n for n in os.listdir(FIXTURES / "sog_meta") if n.endswith(".webp")]
BAD_SOG_FOLDER = {  # name: keyword arguments of sog_folder
    "a folder with meta.json, no images": {"drop": IMAGES},
    "a folder without sh0.webp": {"drop": ("sh0.webp",)},
    "a folder whose meta.json is empty": {"meta_bytes": b""},
    'a folder whose meta.json is {"a": 1}': {"meta_bytes": b'{"a": 1}'},
    "a folder, image named ../good.ply": {"change": at("quats", files=["../good.ply"])},
    "a folder, image named .": {"change": at("quats", files=["."])},
    "a folder, an image of garbage": {"replace": {"quats.webp": b"garbage"}},
    "a folder, labels of 8 x 8 texels": {"replace": {"shN_labels.webp": image(8, "WEBP")}},
    "a folder, count 257": {"change": top(count=257)},
    "a folder, means.maxs NaN": {"change": at("means", maxs=[float("nan")] * 3)},
}


@pytest.fixture(scope="module")
def sog():
    return Sog()


@pytest.mark.parametrize("make", list(BAD_SOG.values()), ids=list(BAD_SOG))
def test_a_damaged_sog(fresh, work, sog, make):
    p = fresh("model", ".sog")
    p.write_bytes(make(sog))
    render(fresh, work, p, "error")


@pytest.mark.parametrize("make", list(GOOD_SOG.values()), ids=list(GOOD_SOG))
def test_a_consistent_odd_sog_is_read_as_it_says(fresh, work, sog, make):
    p = fresh("model", ".sog")
    p.write_bytes(make(sog))
    render(fresh, work, p, "ok", views=1)


@pytest.mark.parametrize("how", list(BAD_SOG_FOLDER.values()), ids=list(BAD_SOG_FOLDER))
def test_a_damaged_unbundled_sog(fresh, work, how):
    render(fresh, work, sog_folder(fresh, **how), "error")


def test_the_meta_json_of_a_damaged_unbundled_sog(fresh, work):
    d = sog_folder(fresh, drop=("sh0.webp",))
    render(fresh, work, d / "meta.json", "error")


def test_a_folder_whose_meta_json_is_a_folder(fresh, work):
    d = fresh("sogdir")
    (d / "meta.json").mkdir(parents=True)
    render(fresh, work, d, "error")


def test_a_folder_with_nothing(fresh, work):
    render(fresh, work, work / "dir", "error")


@pytest.mark.parametrize(
    "name, make",
    [
        ("cut.ksplat", lambda s: ksplat(2)[:-100]),
        ("noimage.sog", lambda s: s.zip(drop=("quats.webp",))),
        ("v3.sog", lambda s: s.zip(top(version=3))),
    ],
    ids=["cut.ksplat", "noimage.sog", "v3.sog"],
)
def test_a_campaign_on_a_damaged_file(fresh, work, sog, name, make):
    (work / name).write_bytes(make(sog))
    spec = fresh("spec", ".toml")
    spec.write_text(spec_text(scene=f'model = "{name}"\n'))
    expect_outcome(["campaign", spec, "--out", fresh("run"), "--quiet"], "error")
