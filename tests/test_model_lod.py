"""PlayCanvas streamed LOD sets (formats/lod.py) on tiny sets written here: a level is the union of
its leaves' tile ranges in (tile, offset) order, the level option (API, spec, command line) picks
it, and a missing, short or damaged tile is refused in one line naming it."""

from __future__ import annotations

import io
import json
import re
import shutil

import numpy as np
import pytest
from PIL import Image

from seuwgpu.apps.cli import build_parser, main, parse_arguments
from seuwgpu.apps.cli.options import load_source
from seuwgpu.campaign.spec import SpecError, normalize_spec, scene_label
from seuwgpu.campaign.spec_hash import spec_hash
from seuwgpu.model.fields import FIELDS
from seuwgpu.model.formats import ModelFileError, detect_format, model_files, read_model, save_model
from seuwgpu.model.scenes import make_scene

BOOK = np.linspace(-4.0, 1.0, 256).tolist()


def webp(rgba: np.ndarray, width: int) -> bytes:
    """A lossless WebP of these texels (row-major, `width` a row)."""
    buf = io.BytesIO()
    Image.fromarray(rgba.reshape(-1, width, 4), "RGBA").save(buf, "WEBP", lossless=True, exact=True)
    return buf.getvalue()


def write_tile(folder, n: int, seed: int, count: int | None = None):
    """An unbundled SOG of n random splats (SH degree 0) in `folder`; meta.json states `count`."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    w = 8
    texels = -(-n // w) * w

    def img(name, alpha=None):
        t = rng.integers(0, 256, (texels, 4), dtype=np.uint8)
        t[:, 3] = 255 if alpha is None else alpha
        (folder / name).write_bytes(webp(t, w))

    for name in ("means_l.webp", "means_u.webp", "scales.webp"):
        img(name)
    img("quats.webp", alpha=rng.integers(252, 256, texels))
    img("sh0.webp", alpha=rng.integers(0, 256, texels))
    meta = {
        "version": 2,
        "count": n if count is None else count,
        "means": {"mins": [-1.0, -1.0, -1.0], "maxs": [1.0, 1.0, 1.0], "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": BOOK, "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": BOOK, "files": ["sh0.webp"]},
    }
    (folder / "meta.json").write_text(json.dumps(meta))


# filenames in an order unlike the tree's: level 0 = A (40) and B (32, its last two in no leaf),
# level 1 = C (12); the tree lists B's first range before A
TILES = {"1_0": 12, "0_0": 40, "0_1": 32}
NAMES = ["1_0/meta.json", "0_0/meta.json", "0_1/meta.json"]
TREE = {
    "bound": {"min": [-1, -1, -1], "max": [1, 1, 1]},
    "children": [
        {"lods": {"0": {"file": 2, "offset": 0, "count": 10}, "1": {"file": 0, "offset": 0, "count": 5}}},
        {
            "children": [
                {"lods": {"0": {"file": 1, "offset": 0, "count": 40}, "1": {"file": 0, "offset": 5, "count": 7}}},
                {"lods": {"0": {"file": 2, "offset": 10, "count": 20}}},
            ]
        },
    ],
}


@pytest.fixture(scope="module")
def lod_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("sets") / "garden"
    for i, (name, n) in enumerate(TILES.items()):
        write_tile(root / name, n, seed=i)
    (root / "lod-meta.json").write_text(json.dumps({"lodLevels": 2, "filenames": NAMES, "tree": TREE}))
    return root


def copy_set(lod_set, tmp_path):
    return shutil.copytree(lod_set, tmp_path / "garden")


def tile(root, name, start, stop):
    """Splats start..stop of a tile, as the SOG reader decodes the tile alone."""
    return read_model(root / name / "meta.json").model.subset(slice(start, stop))


def assert_same(model, parts):
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(model, f), np.concatenate([getattr(p, f) for p in parts]), err_msg=f)


def test_a_level_is_its_tiles_ranges_in_tile_then_offset_order(lod_set):
    mf = read_model(lod_set)  # the folder; level 0 by default
    assert detect_format(lod_set / "lod-meta.json") == "lod" and mf.format == "lod" and mf.name == "garden"
    assert_same(mf.model, [tile(lod_set, "0_0", 0, 40), tile(lod_set, "0_1", 0, 10), tile(lod_set, "0_1", 10, 30)])
    assert mf.model.n == 70
    assert mf.notes[0].startswith("LOD set: level 0 of 2 (levels 0-1; 0 the finest), 70 splats merged from 2 tile(s)")
    one = read_model(lod_set / "lod-meta.json", lod=1)
    assert_same(one.model, [tile(lod_set, "1_0", 0, 12)])
    assert one.name == "garden-lod1" and "level 1 of 2" in one.notes[0] and "from 1 tile(s)" in one.notes[0]
    # what a campaign hashes: lod-meta.json and every tile's meta.json and images
    files = model_files(lod_set)
    assert files[0].name == "lod-meta.json" and len(files) == 1 + 3 * 6


def test_a_level_the_set_lacks_is_refused_naming_the_levels(lod_set):
    with pytest.raises(ModelFileError, match=r"lod-meta.json: the LOD set has no level 2; it has levels 0-1$"):
        read_model(lod_set, lod=2)


def test_a_level_of_a_model_that_is_no_lod_set_is_refused(tmp_path):
    save_model(make_scene("spheres", n=16, sh_degree=0), tmp_path / "m.ply")
    with pytest.raises(ModelFileError, match=r"m.ply: a level of detail \(lod = 1\) picks a level of a PlayCanvas"):
        read_model(tmp_path / "m.ply", lod=1)


def _missing_meta(root):
    (root / "0_1" / "meta.json").unlink()


def _missing_image(root):
    (root / "0_0" / "sh0.webp").unlink()


def _short_count(root):
    meta = json.loads((root / "0_1" / "meta.json").read_text())
    meta["count"] = 25  # level 0 takes splats up to 30
    (root / "0_1" / "meta.json").write_text(json.dumps(meta))


def _truncated_image(root):
    p = root / "0_1" / "quats.webp"
    p.write_bytes(p.read_bytes()[:60])


@pytest.mark.parametrize(
    "damage, tile_file, match",
    [
        (_missing_meta, "0_1/meta.json", "tile 0_1/meta.json of LOD set .* is missing"),
        (_missing_image, "0_0/meta.json", r"SOG image sh0.webp \(sh0\) is missing"),
        (_short_count, "0_1/meta.json", "tile 0_1/meta.json holds 25 splats .*; level 0 of .* takes splats up to 30"),
        (_truncated_image, "0_1/meta.json", r"SOG image quats.webp \(quats\) is no readable WebP image"),
    ],
    ids=["missing meta.json", "missing webp", "count short of the ranges", "truncated webp"],
)
def test_a_missing_or_damaged_tile_is_named_in_one_line(lod_set, tmp_path, damage, tile_file, match):
    root = copy_set(lod_set, tmp_path)
    damage(root)
    with pytest.raises(ModelFileError) as e:
        read_model(root)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(root / tile_file)) and re.search(match, msg), msg
    read_model(root, lod=1)  # the other level's tile is whole: still read


def test_spec_lod_key(lod_set, tmp_path):
    def spec(**scene):
        return {"single": {"samples": 1}, "scenes": [scene]}

    s = normalize_spec(spec(model=str(lod_set), lod=1), tmp_path)
    sc = s.scenes[0]
    assert sc.lod == 1 and sc.sh_degree == 0 and scene_label(sc) == "garden-lod1"
    zero = normalize_spec(spec(model=str(lod_set), lod=0), tmp_path)
    assert zero.scenes[0].lod is None and scene_label(zero.scenes[0]) == "garden"  # the default level
    assert spec_hash(zero) == spec_hash(normalize_spec(spec(model=str(lod_set)), tmp_path)) != spec_hash(s)
    with pytest.raises(SpecError, match=r"scenes\[0\].lod picks a level of a PlayCanvas LOD set"):
        normalize_spec(spec(scene="spheres", lod=1), tmp_path)
    with pytest.raises(SpecError, match="the LOD set has no level 3; it has levels 0-1"):
        normalize_spec(spec(model=str(lod_set), lod=3), tmp_path)
    save_model(make_scene("spheres", n=16, sh_degree=0), tmp_path / "m.ply")
    with pytest.raises(SpecError, match=r"scenes\[0\]: .*m.ply: a level of detail \(lod = 1\)"):
        normalize_spec(spec(model=str(tmp_path / "m.ply"), lod=1), tmp_path)


def test_every_command_taking_a_model_takes_its_level(lod_set, tmp_path, capsys):
    parser = build_parser()
    taking = [name for name, p in parser.commands.items() if "--model" in p._option_string_actions]
    assert {"render", "inject", "view", "demo"} <= set(taking)
    assert all("--lod" in parser.commands[name]._option_string_actions for name in taking)
    args = parse_arguments(["render", "--model", str(lod_set), "--lod", "1", "--out", str(tmp_path / "r.npz")])
    src = load_source(args)
    assert_same(src.model, [tile(lod_set, "1_0", 0, 12)])
    assert src.name == "garden-lod1" and "LOD set: level 1 of 2" in capsys.readouterr().err
    assert main(["render", "--scene", "spheres", "--lod", "1", "--out", str(tmp_path / "r.npz")]) == 2
    assert "--lod picks a level of a PlayCanvas LOD set (a model file: lod-meta.json" in capsys.readouterr().err
    assert main(["render", "--model", str(lod_set), "--lod", "4", "--out", str(tmp_path / "r.npz")]) != 0
    assert "has no level 4; it has levels 0-1" in capsys.readouterr().err


def test_api_load_model_takes_the_level(lod_set):
    from seuwgpu import api
    from seuwgpu.errors import InputError

    scene = api.load_model(lod_set / "lod-meta.json", lod=1)
    assert scene.name == "garden-lod1" and scene.model.n == 12
    with pytest.raises(InputError, match="^lod picks a level of a PlayCanvas LOD set .*embedded scene 'spheres'$"):
        api.load_model("spheres", lod=1)


def test_recognised_by_content_and_overlapping_ranges_refused(lod_set, tmp_path):
    root = copy_set(lod_set, tmp_path)
    meta = json.loads((root / "lod-meta.json").read_text())
    (root / "set.json").write_text(json.dumps(meta))  # another name: its content says what it is
    assert detect_format(root / "set.json") == "lod" and read_model(root / "set.json").model.n == 70
    meta["tree"]["children"][0]["lods"]["0"]["count"] = 11  # 0_1's splats 0..10, and 10.. again
    (root / "lod-meta.json").write_text(json.dumps(meta))
    with pytest.raises(ModelFileError, match=r"level 0 takes splats 10\.\. of tile 0_1/meta.json twice"):
        read_model(root)
