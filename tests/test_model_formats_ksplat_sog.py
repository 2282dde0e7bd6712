"""The .ksplat (GaussianSplats3D) and SOG (PlayCanvas) readers, against files the official tools
wrote from one source PLY (tests/data/formats/README.md says which tool, version and command):

- against the tools' own decode (splat-transform 3.7 read each file and wrote a PLY): the
  same float32 values, an independent reference;
- against the source PLY, within each format's quantisation, derived from how the writer
  quantises (not from observed errors). Both tools reorder splats, so each decoded splat is
  matched to its source by position first;
- malformed files refused with one line, through read_model and the CLI.
"""

from __future__ import annotations

import json
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import traced_peak

from seuwgpu.apps.cli import main
from seuwgpu.model.formats import ModelFileError, detect_format, read_model
from seuwgpu.model.formats.quantized import SH_C0

DATA = Path(__file__).resolve().parent / "data" / "formats"
KSPLATS = ["level0_sh2.ksplat", "level1_sh1.ksplat", "level2_sh2.ksplat"]
F32_EPS = 2.0**-23


def source():
    return read_model(DATA / "source.ply").model


def matched(model, src):
    """The source rows in the decoded model's order (nearest position; a permutation)."""
    d = ((model.means[:, None, :].astype(np.float64) - src.means[None, :, :]) ** 2).sum(-1)
    j = d.argmin(axis=1)
    assert len(np.unique(j)) == model.n == src.n
    return j


def sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


def unit(q):
    q = q.astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def assert_same_as_tool(model, ref):
    """The tool's decode: equal float32 values; opacity compared as alpha, since splat-transform
    clamps alpha to [1e-6, 1 - 1e-6] where this reader turns a saturated byte into +-20."""
    for f in ("means", "log_scales", "quats", "sh_dc", "sh_rest"):
        a, b = getattr(model, f), getattr(ref, f)
        assert a.shape == b.shape, f
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7, err_msg=f)
    np.testing.assert_allclose(sigmoid(model.opacity), sigmoid(ref.opacity), rtol=0, atol=1e-6)


def assert_colour_floor(model, s):
    """Colour and alpha are floor(value * 255) / 255 (GaussianSplats3D's PLY parser): the decoded
    value lies up to one step of 1/255 below the source's (in colour and alpha space)."""
    dc = (model.sh_dc.astype(np.float64) - s.sh_dc) * SH_C0
    assert dc.max() <= 1e-6 and dc.min() >= -1 / 255 - 1e-6
    a = sigmoid(model.opacity) - sigmoid(s.opacity)
    assert a.max() <= 1e-6 and a.min() >= -1 / 255 - 1e-6


# --------------------------------------------------------------------------------------- ksplat


@pytest.mark.parametrize("name", KSPLATS)
def test_ksplat_equals_splat_transforms_decode(name):
    mf = read_model(DATA / name)
    assert mf.format == "ksplat" and mf.up == "-y" and mf.name == name.removesuffix(".ksplat")
    level = int(name[5])
    assert mf.notes[0].startswith(f"ksplat v0.1, compression level {level} (")
    assert_same_as_tool(mf.model, read_model(DATA / f"{name}.ref.ply").model)


def ksplat_section(path):
    """(bucket block size, position quantisation range, SH min, SH max) from the headers."""
    b = Path(path).read_bytes()
    sh_min, sh_max = struct.unpack_from("<2f", b, 36)
    (block,) = struct.unpack_from("<f", b, 4096 + 16)
    (rng,) = struct.unpack_from("<I", b, 4096 + 24)
    return block, rng, sh_min, sh_max


@pytest.mark.parametrize("name", KSPLATS)
def test_ksplat_against_the_source(name):
    """Level 0 keeps float32 (scales as exp, rotations normalised); levels 1 and 2 store the
    position as a 16-bit offset from its bucket's centre, rounded (error <= half a step of
    block / 2 / range), and scales, rotations (and level 1's SH) as float16 through three.js's
    toHalfFloat, which truncates the mantissa (error below one ulp: 2^-10 relative); level 2's
    SH is floor((v - min) / (max - min) * 255) (up to (max - min) / 255 below)."""
    m = read_model(DATA / name).model
    src = source()
    j = matched(m, src)
    s = type(src)(**{f: getattr(src, f)[j] for f in ("means", "log_scales", "quats", "opacity", "sh_dc", "sh_rest")})
    level, degree = int(name[5]), int(name[9])
    assert m.sh_degree == degree
    rest = s.sh_rest[:, : m.sh_rest.shape[1]].astype(np.float64)
    q = unit(s.quats)
    if level == 0:
        np.testing.assert_array_equal(m.means, s.means)
        np.testing.assert_allclose(m.log_scales, s.log_scales, rtol=0, atol=4 * F32_EPS)  # float32 exp, then log
        np.testing.assert_allclose(m.quats, q, rtol=0, atol=2 * F32_EPS)
        np.testing.assert_array_equal(m.sh_rest, rest.astype(np.float32))
    else:
        block, rng, sh_min, sh_max = ksplat_section(DATA / name)
        step = block / 2 / rng
        assert np.abs(m.means - s.means).max() <= step / 2 + 4 * F32_EPS
        d = m.log_scales.astype(np.float64) - s.log_scales  # truncation towards zero: never above
        assert d.max() <= 1e-6 and d.min() >= np.log1p(-(2.0**-10)) - 1e-6
        assert np.abs(m.quats - q).max() <= 2.0**-11 + 2 * F32_EPS  # |v| <= 1: one ulp of float16
        if level == 1:
            assert (np.abs(m.sh_rest - rest) <= np.abs(rest) * 2.0**-10 + 2.0**-24).all()
        else:
            d = m.sh_rest - rest
            assert d.max() <= 1e-6 and d.min() >= -(sh_max - sh_min) / 255 - 1e-6
    assert_colour_floor(m, s)


def test_ksplat_recognised_by_content_without_its_extension(tmp_path):
    shutil.copy(DATA / "level2_sh2.ksplat", tmp_path / "model.bin")
    assert detect_format(tmp_path / "model.bin") == "ksplat"
    want = read_model(DATA / "level2_sh2.ksplat").model.means
    np.testing.assert_array_equal(read_model(tmp_path / "model.bin").model.means, want)


def edited(tmp_path, name, offset=None, data=b"", cut=0, out=None):
    b = bytearray((DATA / name).read_bytes())
    if offset is not None:
        b[offset : offset + len(data)] = data
    if cut:
        b = b[:-cut]
    p = tmp_path / (out or name)
    p.write_bytes(bytes(b))
    return p


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(cut=100), "truncated: its headers describe 17804 bytes, the file has 17704"),
        (dict(cut=17804 - 1000), "1000 bytes, shorter than the 4096-byte header"),
        (dict(offset=0, data=b"\x01"), r"version 1\.1 \(this reader takes 0\.1"),
        (dict(offset=1, data=b"\x00"), r"version 0\.0 "),
        (dict(offset=20, data=struct.pack("<H", 7)), "compression level 7 "),
        (dict(offset=16, data=struct.pack("<I", 300)), "header counts 300 splats, its sections 256"),
        (dict(offset=4, data=struct.pack("<I", 40)), "40 section headers do not fit"),
        (dict(offset=4096 + 40, data=struct.pack("<H", 3)), "section 0 has SH degree 3"),
        (
            dict(offset=4096 + 32, data=struct.pack("<I", 0)),
            r"\(0 full of 32, 24 partial holding \d+, 25 in all\) do not",
        ),
        (dict(offset=4096 + 36, data=struct.pack("<I", 23)), "has 4 bytes past the sections its headers describe"),
    ],
)
def test_ksplat_malformed_files_are_refused_in_one_line(tmp_path, change, match):
    p = edited(tmp_path, "level2_sh2.ksplat", **change)
    with pytest.raises(ModelFileError, match=match) as e:
        read_model(p)
    assert "\n" not in str(e.value) and str(e.value).startswith(str(p))


def refused_with_peak(path, match):
    """read_model's ModelFileError for `path` (matching `match`) and the peak memory traced meanwhile."""
    with traced_peak() as peak, pytest.raises(ModelFileError, match=match) as e:
        read_model(path)
    return e.value, peak[0]


@pytest.mark.parametrize("full, size", [(2**12, 2**12), (2**31, 2**31)], ids=["128 MB", "2^62 splats"])
def test_ksplat_huge_bucket_counts_are_refused_before_allocating(tmp_path, full, size):
    """A section header's full-bucket count and bucket size (uint32 each) may describe far more
    splats than the file holds: the reader listed every splat's bucket before checking them (a
    17 kB file took 1 GB of memory for 2^13 buckets of 2^13; 2^31 of 2^31 raised numpy's 'array
    is too big'). Refused now from the counts alone."""
    p = edited(tmp_path, "level2_sh2.ksplat", 4096 + 8, struct.pack("<I", size))  # section 0's bucket size
    b = bytearray(p.read_bytes())
    struct.pack_into("<I", b, 4096 + 32, full)  # its full buckets
    p.write_bytes(bytes(b))
    e, peak = refused_with_peak(p, rf"\({full} full of {size}, 24 partial holding \d+, 25 in all\)")
    assert "\n" not in str(e) and peak < 16 << 20, peak


def test_ksplat_damaged_without_its_extension_is_no_model(tmp_path):
    p = edited(tmp_path, "level0_sh2.ksplat", cut=44, out="model.bin")
    with pytest.raises(ModelFileError, match="unrecognised model file"):
        read_model(p)


def test_ksplat_nan_sh_range_reads_as_the_librarys_default(tmp_path):
    """The library reads the header's 8-bit SH range as `value || 1.5`: NaN, like 0, is unset.
    Read as a range, NaN made every SH value NaN and the render NaN (robustness battery)."""
    nan = struct.pack("<f", float("nan"))
    unset = read_model(edited(tmp_path, "level2_sh2.ksplat", 36, bytes(8), out="zero.ksplat")).model
    for data in (nan + nan, nan + struct.pack("<f", 0.0)):
        m = read_model(edited(tmp_path, "level2_sh2.ksplat", 36, data, out="nan.ksplat")).model
        assert np.isfinite(m.sh_rest).all()
        np.testing.assert_array_equal(m.sh_rest, unset.sh_rest)
    assert np.abs(unset.sh_rest).max() <= 1.5 and np.abs(unset.sh_rest).max() > 0.1  # the range -1.5..1.5


# ------------------------------------------------------------------------------------------ SOG


@pytest.mark.parametrize(
    "name, ref", [("sh3.sog", "sh3.sog"), ("sog_meta/meta.json", "sog_meta"), ("sog_meta", "sog_meta")]
)
def test_sog_equals_splat_transforms_decode(name, ref):
    mf = read_model(DATA / name)
    assert mf.format == "sog" and mf.up == "-y" and mf.name == ref.removesuffix(".sog")
    quantised = "16-bit log positions, 8-bit rotations, 256-entry codebooks, SH palette of 256"
    assert mf.notes == [f"SOG version 2 (quantised: {quantised})"]
    assert mf.model.sh_degree == (3 if name == "sh3.sog" else 1)
    assert_same_as_tool(mf.model, read_model(DATA / f"{ref}.ref.ply").model)


def sog_meta(name):
    if name.endswith(".sog"):
        return json.loads(zipfile.ZipFile(DATA / name).read("meta.json"))
    return json.loads((DATA / name / "meta.json").read_text())


def nearest_entry_error(values, codebook):
    c = np.asarray(codebook, np.float32).astype(np.float64)
    return np.abs(values.reshape(-1)[:, None] - c[None, :]).min(axis=1).reshape(values.shape)


@pytest.mark.parametrize("name", ["sh3.sog", "sog_meta"])
def test_sog_against_the_source(name):
    """Positions: 65535 * (t - min) / (max - min) of t = sign(x) log(|x| + 1), truncated to 16
    bits (t lies up to one step of (max - min) / 65535 below); rotations: the three smaller
    components of the unit quaternion (largest made positive) times sqrt(2), truncated to bytes
    over [-1, 1] (each up to sqrt(2) / 255 off; the largest, rebuilt from them, up to 3 times
    that); log-scales and SH DC: the nearest entry of a 256-entry codebook; alpha: truncated to
    bytes (up to 1/255 below). Higher SH goes through a k-means palette, which the format
    bounds only by its codebook: with a palette of one entry per splat (256 here) each value is
    within half a codebook gap of the source."""
    m = read_model(DATA / name).model
    src = source()
    j = matched(m, src)
    meta = sog_meta(name)
    t = lambda x: np.sign(x) * np.log1p(np.abs(x.astype(np.float64)))  # noqa: E731
    step = (np.array(meta["means"]["maxs"]) - np.array(meta["means"]["mins"])) / 65535
    d = (t(m.means) - t(src.means[j])) / step
    assert d.max() <= 1e-4 and d.min() >= -1 - 1e-4
    q = unit(src.quats[j])
    big = np.abs(q).argmax(axis=1)
    q *= np.sign(q[np.arange(m.n), big])[:, None]
    err = np.abs(m.quats - q)
    tol = np.where(np.eye(4, dtype=bool)[big], 3, 1) * np.sqrt(2) / 255 + 1e-6
    assert (err <= tol).all()
    for field, key in (("log_scales", "scales"), ("sh_dc", "sh0")):
        want = getattr(src, field)[j].astype(np.float64)
        dist = np.abs(getattr(m, field) - want)
        assert (dist <= nearest_entry_error(want, meta[key]["codebook"]) + 1e-6).all(), field
    a = sigmoid(m.opacity) - sigmoid(src.opacity[j])
    assert a.max() <= 1e-6 and a.min() >= -1 / 255 - 1e-6
    shn = meta["shN"]
    assert shn["count"] >= m.n
    rest = src.sh_rest[j][:, : m.sh_rest.shape[1]]
    half_gap = np.diff(np.sort(np.asarray(shn["codebook"], np.float32))).max() / 2
    assert np.abs(m.sh_rest - rest).max() <= half_gap + 1e-6
    assert np.isin(m.sh_rest, np.asarray(shn["codebook"], np.float32)).all()


def test_sog_recognised_by_content(tmp_path):
    shutil.copy(DATA / "sh3.sog", tmp_path / "scene.zip")
    assert detect_format(tmp_path / "scene.zip") == "sog"
    shutil.copytree(DATA / "sog_meta", tmp_path / "capture")
    (tmp_path / "capture" / "meta.json").rename(tmp_path / "capture" / "scene.json")
    assert detect_format(tmp_path / "capture" / "scene.json") == "sog"
    mf = read_model(tmp_path / "capture" / "scene.json")
    np.testing.assert_array_equal(mf.model.means, read_model(DATA / "sog_meta").model.means)


def sog_copy(tmp_path, meta_change=None, drop=None):
    d = tmp_path / "sog"
    shutil.copytree(DATA / "sog_meta", d)
    if meta_change:
        meta = json.loads((d / "meta.json").read_text())
        meta_change(meta)
        (d / "meta.json").write_text(json.dumps(meta))
    if drop:
        (d / drop).unlink()
    return d


def _set(key, value):
    def change(meta):
        meta[key] = value

    return change


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda p: sog_copy(p, _set("version", 3)), r"unsupported SOG version 3 \(this reader takes version 2"),
        (lambda p: sog_copy(p, lambda m: m.pop("version")), "SOG version 1 .* is not supported; convert it"),
        (lambda p: sog_copy(p, _set("count", 257)), r"has 16 x 16 texels, fewer than its 257 splats"),
        (lambda p: sog_copy(p, _set("count", 0)), "count must be a positive integer, got 0"),
        (lambda p: sog_copy(p, lambda m: m.pop("quats")), "SOG meta.json lacks quats.files"),
        (lambda p: sog_copy(p, lambda m: m["scales"].update(codebook=[0.0] * 10)), "scales.codebook must be 256"),
        (lambda p: sog_copy(p, drop="quats.webp"), r"SOG image quats.webp \(quats\) is missing"),
        (lambda p: sog_copy(p, lambda m: m["shN"].update(count=3)), r"shN label \d+ is beyond the palette \(3 entries"),
    ],
)
def test_sog_malformed_folders_are_refused_in_one_line(tmp_path, make, match):
    d = make(tmp_path)
    with pytest.raises(ModelFileError, match=match) as e:
        read_model(d)
    assert "\n" not in str(e.value)


def test_sog_malformed_zips_are_refused_in_one_line(tmp_path):
    with zipfile.ZipFile(tmp_path / "empty.sog", "w") as z:
        z.writestr("means_l.webp", b"")
    (tmp_path / "cut.sog").write_bytes((DATA / "sh3.sog").read_bytes()[:20000])
    with zipfile.ZipFile(DATA / "sh3.sog") as src, zipfile.ZipFile(tmp_path / "noimg.sog", "w") as z:
        for n in src.namelist():
            if n != "sh0.webp":
                z.writestr(n, src.read(n))
    (tmp_path / "bad.webp.json").write_text('{"version": 2, "means": ')
    cases = {
        "empty.sog": "not a SOG: a zip without meta.json",
        "cut.sog": "not a SOG: a broken zip archive",
        "noimg.sog": "the SOG zip lacks sh0.webp, which meta.json lists",
        "bad.webp.json": "SOG meta.json is not valid JSON",
    }
    for name, match in cases.items():
        with pytest.raises(ModelFileError, match=match) as e:
            read_model(tmp_path / name)
        assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "member, padding, limit",
    [("meta.json", b" " * (17 << 20), 16 << 20), ("sh0.webp", bytes(9 << 20), 8 * (256 + (1 << 20)))],
    ids=["meta.json of 17 MiB", "sh0.webp of 9 MiB"],
)
def test_sog_zip_members_declaring_more_than_a_sog_needs_are_not_inflated(tmp_path, member, padding, limit):
    """A few kB of deflated zeros can declare gigabytes: a member larger than any SOG of its count
    needs (meta.json: kilobytes; an image: about 4 bytes a texel) is refused from its declared
    size before it is inflated. Here the padding is harmless (JSON whitespace, bytes after the
    WebP), so the file read before, inflating all of it."""
    bomb = tmp_path / "bomb.sog"
    with zipfile.ZipFile(DATA / "sh3.sog") as src, zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as z:
        for n in src.namelist():
            z.writestr(n, src.read(n) + (padding if n == member else b""))
    assert bomb.stat().st_size < 100_000
    e, peak = refused_with_peak(bomb, rf"{member} in the SOG zip declares [\d,]+ bytes uncompressed")
    assert f"over the {limit:,} its SOG could need" in str(e) and "\n" not in str(e)
    assert peak < len(padding) / 4, peak


def webp(width, height, claimed=None):
    """A lossless WebP of zeros; `claimed`: the (width, height) its header says instead (VP8L's
    14-bit fields), with no data for them."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.zeros((height, width, 4), np.uint8)).save(buf, "WEBP", lossless=True)
    b = bytearray(buf.getvalue())
    if claimed:
        assert b[12:16] == b"VP8L"
        bits = struct.unpack_from("<I", b, 21)[0] & ~0xFFFFFFF
        struct.pack_into("<I", b, 21, bits | (claimed[0] - 1) | (claimed[1] - 1) << 14)
    return bytes(b)


def test_sog_image_too_large_to_read_is_refused_in_one_line(tmp_path):
    """An image whose header claims more texels than Pillow decodes (16383 x 16383) raised
    Pillow's DecompressionBombError, which escaped as a traceback (robustness battery)."""
    d = sog_copy(tmp_path)
    (d / "sh0.webp").write_bytes(webp(16, 16, claimed=(16383, 16383)))
    with pytest.raises(ModelFileError, match=r"SOG image sh0.webp \(sh0\) is too large to read") as e:
        read_model(d)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "name, image, shown",
    [
        ("sh0.webp", webp(16, 16, claimed=(12000, 9000)), "12000 x 9000"),
        ("quats.webp", webp(32, 16), "32 x 16"),
        ("shN_labels.webp", webp(16, 32), "16 x 32"),
    ],
    ids=["sh0 claiming 12000x9000", "quats 32x16", "labels 16x32"],
)
def test_sog_images_of_another_size_than_the_means_are_refused(tmp_path, name, image, shown):
    """Texel i of every per-splat image is splat i, so they share the means images' size: one of
    another size is a damaged SOG (a 12000 x 9000 image of zeros was decoded, 432 MB in 6 s, and
    read as transparent splats). Refused before decoding it."""
    d = sog_copy(tmp_path)
    (d / name).write_bytes(image)
    with pytest.raises(ModelFileError, match=f"SOG image {name} .* has {shown} texels, the means images 16 x 16") as e:
        read_model(d)
    assert "\n" not in str(e.value)


def test_bad_files_through_the_cli_exit_2_with_one_line(tmp_path, capsys):
    bad = edited(tmp_path, "level2_sh2.ksplat", cut=100, out="bad.ksplat")
    (tmp_path / "empty.sog").write_bytes((DATA / "sh3.sog").read_bytes()[:100])
    for model in (bad, tmp_path / "empty.sog", sog_copy(tmp_path, _set("version", 3))):
        rc = main(["render", "--model", str(model), "--views", "1", "--size", "16x16", "--out", str(tmp_path / "r")])
        err = capsys.readouterr().err
        assert rc == 2 and len(err.strip().splitlines()) == 1 and str(model) in err, err


def test_render_a_sog_end_to_end(tmp_path, capsys):
    """The SOG renders like its source (the same orbit: --up +z, the scene's up axis, where a
    SOG's convention is -y), within what its quantisation changes."""
    frames = {}
    for name in ("sh3.sog", "source.ply"):
        out = tmp_path / f"{name}.npz"
        args = ["--model", str(DATA / name), "--up", "+z", "--views", "1", "--size", "64x64", "--out", str(out)]
        rc = main(["render", *args])
        assert rc == 0, capsys.readouterr().err
        frames[name] = np.load(out)["images"]
    img = frames["sh3.sog"]
    assert img.shape == (1, 64, 64, 3) and np.isfinite(img).all()
    assert (np.abs(img - 1.0).max(axis=-1) > 0.1).mean() > 0.05  # the scene covers part of the frame
    assert np.abs(img - frames["source.ply"]).mean() < 0.02


def test_a_campaign_hashes_an_unbundled_sogs_images(tmp_path):
    """A spec's model entry naming an unbundled SOG stands for its meta.json and every image it
    lists: changing an image changes the model's hash (a resumed campaign notices)."""
    from seuwgpu.campaign.spec import content_files, content_hash

    d = sog_copy(tmp_path)
    files = content_files("model", d)
    assert files == content_files("model", d / "meta.json")
    assert files[0] == d / "meta.json" and sorted(f.name for f in files[1:]) == sorted(p.name for p in d.glob("*.webp"))
    before = content_hash("model", d)
    (d / "quats.webp").write_bytes((d / "quats.webp").read_bytes() + b"\0")
    assert content_hash("model", d) != before
    assert content_files("model", DATA / "sh3.sog") == [DATA / "sh3.sog"]


def test_a_sog_count_beyond_host_memory_is_refused_before_any_image(tmp_path):
    """meta.json's count sizes what the images may hold (and WebP packs a constant image into
    bytes): a count no host holds is refused from meta.json, in one line, before an image is read."""
    from seuwgpu.errors import TooBig
    from seuwgpu.model.formats import sog

    d = sog_copy(tmp_path, _set("count", 2**40))
    read = []
    real = sog._Files.image

    def image(self, *a, **k):
        read.append(a[0])
        return real(self, *a, **k)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sog._Files, "image", image)
        with pytest.raises(TooBig, match="SOG count 1099511627776 needs about") as e:
            read_model(d)
    assert not read and "\n" not in str(e.value)
