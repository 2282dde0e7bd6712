"""model/checks.py: the API, the command line and a campaign spec refuse the same bad value with
the same line, each naming the input as its user knows it (`views`, `--views`, `spec.views`)."""

from __future__ import annotations

import numpy as np
import pytest

import seuwgpu as sg
from seuwgpu.apps.cli import main
from seuwgpu.campaign.spec import SpecError, normalize_spec
from seuwgpu.errors import InputError
from seuwgpu.model import checks


def spec(**top):
    scene = top.pop("scene", {"scene": "spheres", "n": 100})
    single = top.pop("single", {})
    return {"scenes": [scene], "single": {"samples": 1, **single}, **top}


def spec_error(raw) -> str:
    with pytest.raises(SpecError) as e:
        normalize_spec(raw)
    return str(e.value)


def cli_error(capsys, argv) -> str:
    """The line `seuwgpu` prints (argparse's own for an argument's type, exit status 2 both ways)."""
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    assert code == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


@pytest.fixture(scope="module")
def scene():
    return sg.load_model("spheres", n=100)


def test_views_beyond_the_limit_one_wording(scene, capsys, tmp_path):
    with pytest.raises(InputError) as api:
        sg.cameras(scene, views=65)
    cli = cli_error(capsys, ["render", "--views", "65", "--out", str(tmp_path / "r.npz")])
    assert str(api.value) == "views must be at most 64, got 65"
    assert cli.endswith("argument --views: must be at most 64, got 65")
    assert spec_error(spec(views=65)) == "spec.views must be at most 64, got 65"


def test_an_image_size_under_one_tile_one_wording(scene, capsys, tmp_path):
    problem = "width and height must be whole numbers of at least 16 px, got "
    with pytest.raises(InputError) as api:
        sg.cameras(scene, size=(15, 64))
    cli = cli_error(capsys, ["render", "--size", "15x64", "--out", str(tmp_path / "r.npz")])
    assert str(api.value) == "size: " + problem + "(15, 64)"
    assert cli.endswith("argument --size: " + problem + "'15x64'")
    assert spec_error(spec(size="15x64")) == "size: " + problem + "'15x64'"


def test_a_level_of_an_embedded_scene_is_refused_once_worded(capsys, tmp_path):
    problem = "picks a level of a PlayCanvas LOD set (a model file: lod-meta.json or its folder), not of "
    with pytest.raises(InputError) as api:
        sg.load_model("spheres", lod=1)
    cli = cli_error(capsys, ["render", "--scene", "spheres", "--lod", "1", "--out", str(tmp_path / "r.npz")])
    assert str(api.value) == "lod " + problem + "the embedded scene 'spheres'"
    assert cli == "seuwgpu render: error: --lod " + problem + "the embedded scene 'spheres'"
    raw = spec(scene={"scene": "spheres", "lod": 1})
    assert spec_error(raw) == "scenes[0].lod " + problem + "the embedded scene 'spheres'"
    # the default scene, not named: still refused
    cli = cli_error(capsys, ["render", "--lod", "2", "--out", str(tmp_path / "r.npz")])
    assert cli == "seuwgpu render: error: --lod " + problem + "an embedded scene"


def test_a_bit_out_of_range_and_an_unknown_name_one_wording(scene, capsys, tmp_path):
    problem = "bit 16 is out of range for fp16 (valid bits are 0..15)"
    with pytest.raises(InputError) as api:
        sg.inject(scene, sg.cameras(scene, views=1, size=(16, 16)), field="opacity", bit=16, precision="fp16")
    assert str(api.value) == problem
    assert spec_error(spec(single={"precisions": ["fp16"], "bits": [16]})) == "single.bits: " + problem
    expected = "unknown defense 'armour'; expected one of " + ", ".join(sg.DEFENSES)
    with pytest.raises(InputError, match="^" + expected):
        sg.inject(scene, [], field="opacity", bit=3, defenses=["armour"])
    assert spec_error(spec(single={"defenses": ["none", "armour"]})) == "single.defenses: " + expected
    cli = cli_error(capsys, ["storm", "--defense", "none", "armour", "--out", str(tmp_path / "s")])
    assert cli.endswith("argument --defense: " + expected)
    precision = "unknown precision 'fp8'; expected one of fp32, fp16, bf16"
    assert spec_error(spec(single={"precisions": ["fp8"]})) == "single.precisions: " + precision
    cli = cli_error(capsys, ["render", "--precision", "fp8", "--out", str(tmp_path / "r.npz")])
    assert cli.endswith("argument --precision: " + precision)
    with pytest.raises(InputError, match="^" + precision + "$"):
        sg.render_views(scene, sg.cameras(scene, views=1, size=(16, 16)), precision="fp8")
    field = "unknown field 'colour'; expected one of " + ", ".join(sg.FIELDS)
    assert spec_error(spec(single={"fields": ["colour"]})) == "single.fields: " + field


def test_positive_counts_and_numbers_hand_checked():
    assert checks.integer(np.int64(3), "n", 1) == 3 and type(checks.integer(np.int64(3), "n", 1)) is int
    for bad, why in (
        (True, "must be an integer, got True"),
        (2.0, "must be an integer, got 2.0"),
        (0, "must be at least 1, got 0"),
        (9, "must be at most 8, got 9"),
    ):
        with pytest.raises(InputError, match=f"^n {why}$"):
            checks.integer(bad, "n", 1, 8)
    with pytest.raises(InputError, match="^must be an integer, got '1.5'$"):  # a command-line word
        checks.integer("1.5", None, 1)
    assert checks.number(16, "scale", 16) == 16.0
    for bad in (0, -1, float("inf"), float("nan"), 16.5, True, "2"):
        with pytest.raises(InputError, match=r"^scale must be a number in \(0, 16\], got "):
            checks.number(bad, "scale", 16)
    for bad in (0, 1, 1.5, True):
        with pytest.raises(InputError, match=r"^target must be a proportion in \(0, 1\), e.g. 0.001; got "):
            checks.proportion(bad, "target", "0.001")
    assert checks.image_size((np.int64(32), 16)) == (32, 16) and checks.image_size("64X48") == (64, 48)
    with pytest.raises(InputError, match="^single.defenses lists 'guard', 'none' more than once$"):
        checks.listed_once(["none", "guard", "none", "guard"], "single.defenses")


def test_n_beside_a_model_file_one_wording(capsys, tmp_path):
    """n shapes an embedded scene: beside a model file the API, --n and a spec refuse it (not
    ignore it) with checks.n_of_an_embedded_scene's line, each naming the input its way."""
    from seuwgpu.model.formats import save_model

    ply = tmp_path / "m.ply"
    save_model(sg.load_model("spheres", n=50).model, ply)
    problem = f"sets the primitives of an embedded scene; a model file keeps all of its own ({ply})"
    with pytest.raises(InputError) as api:
        sg.load_model(str(ply), n=10)
    assert str(api.value) == "n " + problem
    cli = cli_error(capsys, ["render", "--model", str(ply), "--n", "10", "--out", str(tmp_path / "r.npz")])
    assert cli == "seuwgpu render: error: --n " + problem
    raw = spec(scene={"model": str(ply), "n": 10})
    assert spec_error(raw) == "scenes[0].n " + problem + "; a [sizes] table cuts it to subsets"


def test_size_beside_a_cameras_file_one_wording(scene, capsys, tmp_path):
    """A cameras file gives each view its own size: a size beside it is refused by the API, --size
    and a spec (whose every scene has one) with checks.size_of_orbit_views's line."""
    from seuwgpu.model.cameras import save_cameras

    cams = tmp_path / "CAMS.json"
    save_cameras(sg.cameras(scene, views=1, size=(48, 32)), cams)
    problem = "sets orbit views; a cameras file gives each view its own size (use "
    with pytest.raises(InputError) as api:
        sg.cameras(scene, cameras=cams, size=(64, 64))
    assert str(api.value) == "size " + problem + "scale)"
    argv = ["render", "--cameras", str(cams), "--size", "64x64", "--out", str(tmp_path / "r.npz")]
    assert cli_error(capsys, argv) == "seuwgpu render: error: --size " + problem + "--scale)"
    raw = spec(scene={"scene": "spheres", "n": 100, "cameras": str(cams)}, size="64x64")
    assert spec_error(raw) == "size " + problem + "scale); every scene has one"


def test_a_defense_named_twice_is_refused_everywhere(scene, capsys, tmp_path):
    """An arm named twice would be run and counted twice: the API's defenses (inject, storm,
    worst_case, defense_costs), the command line's --defense / --visible-defenses and a spec's
    defenses refuse it with checks.listed_once's line (they used to merge it silently, but for the
    spec)."""
    twice = ["none", "guard", "none"]
    line = "lists 'none' more than once"
    calls = (
        lambda: sg.inject(scene, [], field="opacity", bit=3, defenses=twice),
        lambda: sg.storm(scene, [], defenses=twice),
        lambda: sg.worst_case(scene, [], defenses=twice),
        lambda: sg.defense_costs(scene, sg.cameras(scene, views=1, size=(16, 16))[0], visible_defenses=twice),
    )
    for call in calls:
        with pytest.raises(InputError, match=f"^defenses {line}$"):
            call()
    out = tmp_path / "s"
    for command, option in (("storm", "--defense"), ("worstcase", "--defense"), ("defenses", "--visible-defenses")):
        argv = [command, "--scene", "spheres", "--n", "50", option, *twice]
        argv += ["--out", str(out)] if command == "storm" else []
        assert cli_error(capsys, argv) == f"seuwgpu {command}: error: {option} {line}"
    assert not out.exists()
    assert spec_error(spec(single={"defenses": twice})) == f"single.defenses {line}"


def test_a_profile_and_a_target_are_input_errors_one_wording(scene, capsys, tmp_path):
    """render's check_profile and faults/state's check_target are checks.one_of: an InputError
    no caller re-wraps, the same line from the API, --profile and a spec."""
    from seuwgpu.faults.state import TARGETS, check_target

    problem = "unknown renderer profile 'fast'; expected one of strict, gsplat"
    with pytest.raises(InputError, match=f"^{problem}$"):
        sg.render_views(scene, sg.cameras(scene, views=1, size=(16, 16)), profile="fast")
    cli = cli_error(capsys, ["render", "--profile", "fast", "--out", str(tmp_path / "r.npz")])
    assert cli.endswith("argument --profile: " + problem)
    assert spec_error(spec(profile="fast")) == "profile: " + problem
    target = "unknown pipeline-state target 'rects'; expected one of " + ", ".join(TARGETS)
    with pytest.raises(InputError, match=f"^{target}$"):
        sg.state_flips(scene, [], targets=["rects"])
    with pytest.raises(InputError, match="^targets: unknown pipeline-state target 1; "):
        check_target(1, "targets")
