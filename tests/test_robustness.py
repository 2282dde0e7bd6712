"""Bad inputs, interrupted and concurrent runs, merges and oversized jobs: each ends in the project's
own one-line error naming the input, or in a correct result (issue 14)."""

import dataclasses
import json
import os
import shutil
import textwrap

import numpy as np
import pandas as pd
import pytest

from seuwgpu.apps.cli import main
from seuwgpu.campaign import store
from seuwgpu.campaign.budget import check_campaign
from seuwgpu.campaign.merge import merge
from seuwgpu.campaign.runner import Runner
from seuwgpu.campaign.schema import REPRODUCIBLE_COLUMNS
from seuwgpu.campaign.spec import SpecError, load_spec, normalize_spec
from seuwgpu.campaign.spec_hash import spec_hash
from seuwgpu.errors import InputError, RunInUse, SeuwgpuError, TooBig
from seuwgpu.model.budget import check_frames, check_render
from seuwgpu.model.cameras import CameraFileError, read_cameras
from seuwgpu.model.formats import ModelFileError, read_model, save_model
from seuwgpu.model.scenes import make_scene

TINY = textwrap.dedent("""
    views = 1
    size = "16x16"
    batch = 2
    [[scenes]]
    {scene}
    [single]
    fields = ["opacity"]
    bits = [30]
    samples = 4
    defenses = ["none"]
""")


def tiny_spec(tmp_path, scene='scene = "spheres"\n    n = 200', name="spec.toml"):
    p = tmp_path / name
    p.write_text(TINY.format(scene=scene))
    return p


def records(run):
    """A run's records in a canonical order, without the wall-clock time_ms (never reproduced)."""
    df = store.read_records(run).sort_values(["injection_id", "defense"]).reset_index(drop=True)
    return df[REPRODUCIBLE_COLUMNS]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tiny")
    spec = load_spec(tiny_spec(tmp))
    Runner(spec, tmp / "run", quiet=True).run()
    return spec, tmp / "run", records(tmp / "run")


def test_every_error_type_is_a_seuwgpu_error():
    for e in (SpecError, ModelFileError, CameraFileError, RunInUse, TooBig, InputError):
        assert issubclass(e, SeuwgpuError)
    assert issubclass(SpecError, ValueError) and issubclass(ModelFileError, ValueError)


# ---- run directories ---------------------------------------------------------------------------
def test_a_second_campaign_on_a_held_directory_is_refused(tiny_run, tmp_path):
    spec, run, _ = tiny_run
    with store.lock(tmp_path / "busy"):
        with pytest.raises(RunInUse, match=f"pid {os.getpid()}"):
            Runner(spec, tmp_path / "busy", quiet=True).run()
    assert store.read_manifest(tmp_path / "busy") is None  # nothing was written by the refused run
    # another shard of the same directory is not blocked by it
    with store.lock(tmp_path / "busy", (0, 2)):
        Runner(spec, tmp_path / "busy", shard=(1, 2), quiet=True).run()


def test_resuming_after_the_model_changed_is_refused_naming_the_file(tmp_path):
    model = tmp_path / "m.ply"
    save_model(make_scene("spheres", n=150, seed=1), model)
    spec_path = tiny_spec(tmp_path, 'model = "m.ply"')
    Runner(load_spec(spec_path), tmp_path / "run", quiet=True).run()
    Runner(load_spec(spec_path), tmp_path / "run", quiet=True).run()  # same content: resumes
    save_model(make_scene("spheres", n=150, seed=2), model)
    with pytest.raises(SpecError, match=r"other content in .*m\.ply.*scenes\[0\]\.model"):
        Runner(load_spec(spec_path), tmp_path / "run", quiet=True).run()


def test_the_same_spec_through_another_path_is_the_same_run(tmp_path):
    save_model(make_scene("spheres", n=150, seed=1), tmp_path / "m.ply")
    p = tiny_spec(tmp_path, 'model = "m.ply"')
    (tmp_path / "sub").mkdir()
    os.symlink(tmp_path / "m.ply", tmp_path / "sub" / "m.ply")  # another folder, the same file name
    (tmp_path / "sub" / "s.toml").write_text(TINY.format(scene='model = "m.ply"'))
    a = load_spec(p)
    b = load_spec(tmp_path / "sub" / ".." / "spec.toml")
    c = load_spec(tmp_path / "sub" / "s.toml")
    assert a == b and spec_hash(a) == spec_hash(b) == spec_hash(c)
    # a symlink of another name too: the spec resolves it to the file, whose name records use
    os.symlink(tmp_path / "m.ply", tmp_path / "sub" / "link.ply")
    (tmp_path / "sub" / "l.toml").write_text(TINY.format(scene='model = "link.ply"'))
    assert spec_hash(load_spec(tmp_path / "sub" / "l.toml")) == spec_hash(a)
    assert os.path.isabs(a.scenes[0].model) and len(a.scenes[0].model_sha256) == 64


def test_the_same_model_under_another_file_name_is_another_run(tmp_path):
    """Records name a model file by its file name, but the spec hash left the path out: shards
    reading one model as `a/scan.ply` and `b/copy.ply` merged into records of two scenes, 'scan'
    and 'copy', each estimated from half the sites (and a run resumed after a rename did the
    same). The name is hashed now: the merge and the resume are refused, saying why."""
    save_model(make_scene("spheres", n=150, seed=1), tmp_path / "scan.ply")
    shutil.copy(tmp_path / "scan.ply", tmp_path / "copy.ply")
    a = load_spec(tiny_spec(tmp_path, 'model = "scan.ply"', "a.toml"))
    b = load_spec(tiny_spec(tmp_path, 'model = "copy.ply"', "b.toml"))
    assert a.scenes[0].model_sha256 == b.scenes[0].model_sha256
    assert spec_hash(a) != spec_hash(b)
    Runner(a, tmp_path / "s0", shard=(0, 2), quiet=True).run()
    Runner(b, tmp_path / "s1", shard=(1, 2), quiet=True).run()
    why = r"scenes\[0\] is the same model named 'scan' \(.*scan\.ply\) and 'copy' \(.*copy\.ply\)"
    with pytest.raises(SpecError, match="the shards come from different specs: .*" + why):
        merge(tmp_path / "all", [tmp_path / "s0", tmp_path / "s1"])
    with pytest.raises(SpecError, match="holds a run whose records name its model otherwise: " + why):
        Runner(b, tmp_path / "s0", shard=(1, 2), quiet=True).run()
    Runner(a, tmp_path / "s0", shard=(1, 2), quiet=True).run()  # its own name: the run completes
    assert set(store.read_records(tmp_path / "s0")["scene"]) == {"scan"}


def test_shards_made_before_the_model_name_was_hashed_still_merge(tmp_path):
    """Shards of a model-file campaign made by an earlier seuwgpu carry the hash of their spec
    without the model's name (spec.unlabelled_spec_hash). Hashing the name made merge refuse them
    all as "its manifest's spec does not match its spec hash (edited by hand?)": finished shards
    could not be joined. They merge, and shards of such a campaign that name the model otherwise
    (scan.ply, copy.ply: one hash then) are still refused."""
    from seuwgpu.campaign.spec_hash import unlabelled_spec_hash

    save_model(make_scene("spheres", n=150, seed=1), tmp_path / "scan.ply")
    shutil.copy(tmp_path / "scan.ply", tmp_path / "copy.ply")
    specs = [load_spec(tiny_spec(tmp_path, f'model = "{f}.ply"', f"{f}.toml")) for f in ("scan", "copy")]
    for i, shard in enumerate(("s0", "s1")):
        Runner(specs[0], tmp_path / shard, shard=(i, 2), quiet=True).run()
    Runner(specs[1], tmp_path / "c1", shard=(1, 2), quiet=True).run()
    for shard in ("s0", "s1", "c1"):  # as an earlier seuwgpu wrote them
        path = store.manifest_path(tmp_path / shard)
        m = json.loads(path.read_text())
        m["spec_hash"] = unlabelled_spec_hash(m["spec"])
        path.write_text(json.dumps(m))
    assert merge(tmp_path / "all", [tmp_path / "s0", tmp_path / "s1"]) == 2
    assert set(store.read_records(tmp_path / "all")["scene"]) == {"scan"}
    why = r"scenes\[0\] is the same model named 'scan' \(.*scan\.ply\) and 'copy' \(.*copy\.ply\)"
    with pytest.raises(SpecError, match="the shards come from different specs .*" + why):
        merge(tmp_path / "mixed", [tmp_path / "s0", tmp_path / "c1"])
    m = json.loads(store.manifest_path(tmp_path / "s0").read_text())
    m["spec"]["seed"] += 1  # a spec edited by hand matches neither hash
    store.manifest_path(tmp_path / "s0").write_text(json.dumps(m))
    with pytest.raises(SpecError, match="edited by hand"):
        merge(tmp_path / "edited", [tmp_path / "s0", tmp_path / "s1"])


def test_a_run_that_failed_to_load_its_model_does_not_block_the_corrected_spec(tmp_path):
    broken = b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n"
    (tmp_path / "m.ply").write_bytes(broken)
    bad = tiny_spec(tmp_path, 'model = "m.ply"', "bad.toml")
    with pytest.raises(InputError, match="lacks required 3DGS properties"):  # the spec reads the model
        load_spec(bad)
    save_model(make_scene("spheres", n=200), tmp_path / "m.ply")
    spec = load_spec(bad)
    (tmp_path / "m.ply").write_bytes(broken)  # broken after the spec was read: the run refuses it
    with pytest.raises(ModelFileError):
        Runner(spec, tmp_path / "run", quiet=True).run()
    good = load_spec(tiny_spec(tmp_path))
    Runner(good, tmp_path / "run", quiet=True).run()
    assert store.read_manifest(tmp_path / "run")["spec_hash"] == spec_hash(good)


def test_damaged_parts_are_redone_and_stray_parts_never_counted(tiny_run, tmp_path):
    spec, run, want = tiny_run
    shutil.copytree(run, tmp_path / "run")
    parts = store.part_files(tmp_path / "run")
    shutil.copy(parts[0], store.records_dir(tmp_path / "run") / store.part_name(9_000_000, 2))  # a stray
    parts[0].write_bytes(b"")  # a 0-byte part (a full disk, a copy cut short)
    parts[1].write_bytes(b"PAR1 not really")  # an unreadable one
    stats = Runner(spec, tmp_path / "run", quiet=True).run()
    assert stats["new"] == 4  # the two damaged parts of 2 injections each
    pd.testing.assert_frame_equal(records(tmp_path / "run"), want)


def test_out_under_a_file_is_a_clear_error(tiny_run, tmp_path):
    spec, _, _ = tiny_run
    (tmp_path / "f").write_text("x")
    for out in (tmp_path / "f", tmp_path / "f" / "run"):
        with pytest.raises(InputError, match="--out"):
            Runner(spec, out, quiet=True).run()


# ---- merge -------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def shards(tiny_run, tmp_path_factory):
    spec, _, _ = tiny_run
    tmp = tmp_path_factory.mktemp("shards")
    dirs = [tmp / f"s{i}" for i in range(3)]
    for i, d in enumerate(dirs):
        Runner(spec, d, shard=(i, 3), quiet=True).run()
    return dirs


def test_merge_refuses_an_incomplete_shard_set_unless_allowed(tiny_run, shards, tmp_path):
    _, _, want = tiny_run
    with pytest.raises(SpecError, match="the shards hold 1 of the campaign's 2 parts: 2 injections are missing"):
        merge(tmp_path / "m", shards[:1])
    assert not store.part_files(tmp_path / "m")
    merge(tmp_path / "p", shards[:1], allow_partial=True)
    m = store.read_manifest(tmp_path / "p")
    assert m["missing_parts"] == [[2, 2]] and m["injections_recorded"] == 2 and m["total_injections"] == 4
    merge(tmp_path / "full", shards)
    assert "missing_parts" not in store.read_manifest(tmp_path / "full")
    pd.testing.assert_frame_equal(records(tmp_path / "full"), want)


def test_merge_refuses_other_specs_its_own_inputs_and_foreign_outputs(tiny_run, shards, tmp_path):
    spec, run, _ = tiny_run
    other = dataclasses.replace(spec, seed=99)
    Runner(other, tmp_path / "other", quiet=True).run()
    with pytest.raises(SpecError, match="different specs"):
        merge(tmp_path / "m", [shards[0], tmp_path / "other"])
    with pytest.raises(SpecError, match="one of the shards"):
        merge(shards[0], shards)
    with pytest.raises(SpecError, match="already holds a run of another spec"):
        merge(tmp_path / "other", shards)
    with pytest.raises(SpecError, match="not a run directory"):
        merge(tmp_path / "m", [tmp_path])


def test_merge_takes_a_shard_run_twice_but_not_parts_that_differ(tiny_run, shards, tmp_path):
    """A shard run again (after a lost node), or a whole run beside its shards, holds the same
    records timed anew: merging them was refused as 'part ... differs' (byte comparison)."""
    spec, run, want = tiny_run
    merge(tmp_path / "m", [run, *shards])
    pd.testing.assert_frame_equal(records(tmp_path / "m"), want)
    again = tmp_path / "s0-again"
    Runner(spec, again, shard=(0, 3), quiet=True).run()
    merge(tmp_path / "m2", [shards[0], again, *shards[1:]])
    pd.testing.assert_frame_equal(records(tmp_path / "m2"), want)
    part = store.part_files(again)[0]
    df = pd.read_parquet(part)
    df.loc[0, "footprint"] += 0.5  # a result that differs
    df.to_parquet(part, index=False)
    with pytest.raises(SpecError, match=f"part {part.name} differs between"):
        merge(tmp_path / "m3", [shards[0], again, *shards[1:]])


# ---- memory ------------------------------------------------------------------------------------
def test_too_big_jobs_are_refused_saying_what_fits(monkeypatch):
    monkeypatch.setenv("SEUWGPU_HOST_MEMORY", str(2 * 10**9))
    with pytest.raises(TooBig, match=r"--n 50000000 needs about .* at most --n \d+ fits"):
        main_or_raise(["render", "--scene", "spheres", "--n", "50000000", "--out", "x.npz"])
    spec = normalize_spec(
        {"scenes": [{"scene": "spheres", "n": 100}], "single": {"samples": 10**12, "defenses": ["none"]}}
    )
    with pytest.raises(TooBig, match=r"at most about samples = [\d,]+ in \[single\] fits"):
        check_campaign(spec)
    limits = {"max-storage-buffer-binding-size": 1 << 27, "max-buffer-size": 1 << 31}
    with pytest.raises(TooBig, match="at most 8,388,608 primitives fit"):
        check_render(limits, False, 9_000_000, 0, 1, 64, 64, False)
    with pytest.raises(TooBig, match="at most 2 view"):
        check_render(limits, False, 100, 0, 3, 2048, 2048, False)
    with pytest.raises(TooBig, match="64 view.* of 2048x2048 need 3.2 GB of host memory for the frames"):
        check_frames(64, 2048, 2048)


def test_a_refusal_of_what_fits_in_the_available_memory_says_why(monkeypatch):
    """A job needing less than the available memory but more than the share a job plans on
    (HOST_SHARE) is refused; the message said "needs about 23.6 GB ...; 24.4 GB is available: at
    most --n 41325085 fits", a refusal with no reason. It names the share and what it comes to."""
    from seuwgpu.model.budget import check_model

    monkeypatch.setenv("SEUWGPU_HOST_MEMORY", str(10 * 10**9))
    with pytest.raises(TooBig) as e:
        check_model(10_000_000, 3)  # 10M x 59 values x 16 B = 9.4 GB: under 10 GB, over 80% of it
    assert "needs about 9.4 GB" in str(e.value)
    assert "10.0 GB is available, of which a job plans on 80% (8.0 GB): at most --n 8474576 fits" in str(e.value)


def main_or_raise(argv):
    """Run a CLI command's function itself (errors propagate instead of being printed)."""
    from seuwgpu.apps.cli import build_parser

    args = build_parser().parse_args(argv)
    return args.func(args)


# ---- inputs ------------------------------------------------------------------------------------
SPEC_CASES = {
    'model = "."': "is a folder, not a model file",
    "ply = 5": "must be a file name in quotes",
    'scene = "spheres"\nseed = 18446744073709551616': r"^scenes\[0\]\.seed must be at most 9223372036854775807, got",
    'scene = "spheres"\nseed = -1': r"^scenes\[0\]\.seed must be at least 0, got -1$",
    'scene = "spheres"\nmodel = "x.ply"': "exactly one of",
    'scene = "spheres"\nup = 3': r"^scenes\[0\]\.up: unknown up axis 3; expected one of \+x, -x",
    # was ignored: the whole file ran, as if n were not there (the command line refuses --n with --model)
    'model = "x.ply"\nn = 50': r"scenes\[0\]\.n sets the primitives of an embedded scene; a model file",
    'ply = "x.ply"\nn = 50': r"a model file keeps all of its own \(x\.ply\); a \[sizes\] table cuts it",
}


@pytest.mark.parametrize("scene", list(SPEC_CASES))
def test_bad_scene_entries_are_refused(tmp_path, scene):
    with pytest.raises(SpecError, match=SPEC_CASES[scene]):
        load_spec(tiny_spec(tmp_path, scene.replace("\n", "\n    ")))


@pytest.mark.parametrize(
    "table, message",
    [
        ({"defenses": ["none", "none"]}, "lists 'none' more than once"),
        ({"precisions": ["fp16", "fp16"]}, "lists 'fp16' more than once"),
        ({"fields": ["log_scales", "log_scale"]}, "lists 'log_scales' more than once \\(a field and its alias\\?\\)"),
        ({"defenses": [["none"]]}, r"^single\.defenses: unknown defense \['none'\]; expected one of none, guard"),
    ],
)
def test_duplicate_list_entries_are_refused(table, message):
    with pytest.raises(SpecError, match=message):
        normalize_spec({"scenes": [{"scene": "spheres", "n": 50}], "single": table})


def test_spec_files_that_are_no_spec(tmp_path):
    with pytest.raises(SpecError, match="is a folder"):
        load_spec(tmp_path)
    (tmp_path / "b.toml").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(SpecError, match="not a text file"):
        load_spec(tmp_path / "b.toml")
    with pytest.raises(SpecError, match=r"dose.k = 100000 is more upsets than scenes\[0\] stores bits"):
        normalize_spec({"scenes": [{"scene": "spheres", "n": 2}], "dose": {"k": [100000]}})


CAMERA = {"viewmat": np.eye(4).tolist(), "K": [[50, 0, 8], [0, 50, 8], [0, 0, 1]], "width": 16, "height": 16}
CAMERA_CASES = {
    "non-finite": ({"viewmat": [[float("nan")] * 4] * 4}, "must be finite|not valid JSON|not a camera file"),
    "singular": ({"viewmat": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]}, "singular"),
    "mirrored": ({"viewmat": [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "mirrored"),
    "focal": ({"K": [[0, 0, 8], [0, 50, 8], [0, 0, 1]]}, "focal lengths must be positive"),
    "fraction": ({"width": 12.5}, "width must be a positive integer"),
    "bool": ({"width": True}, "width must be a positive integer"),
    "null": ({"width": None}, "width must be a positive integer"),
    "zero": ({"height": 0}, "height must be a positive integer"),
    "bool matrix": ({"K": [[True, 0, 8], [0, 50, 8], [0, 0, 1]]}, "numbers only"),
}


@pytest.mark.parametrize("case", list(CAMERA_CASES))
def test_bad_cameras_are_refused(tmp_path, case):
    change, message = CAMERA_CASES[case]
    p = tmp_path / "cams.json"
    p.write_text(json.dumps({"cameras": [dict(CAMERA, **change)]}).replace("NaN", "NaN"))
    with pytest.raises(CameraFileError, match=message):
        read_cameras(p)


def test_camera_files_of_the_wrong_shape(tmp_path):
    p = tmp_path / "c.json"
    for text, message in (('{"cameras": 5}', "must be a list"), ("[1, 2]", "no known camera file")):
        p.write_text(text)
        with pytest.raises(CameraFileError, match=message):
            read_cameras(p)
    inria = [{"img_name": "a", "width": None, "height": 16, "position": [0, 0, 0], "rotation": np.eye(3).tolist()}]
    inria[0].update(fx=50, fy=50)
    p.write_text(json.dumps(inria))
    with pytest.raises(CameraFileError, match="camera 0: camera width must be a positive integer, got None"):
        read_cameras(p)


def test_a_ply_whose_header_count_is_below_its_data_names_both_counts(tmp_path):
    save_model(make_scene("spheres", n=10, seed=1), tmp_path / "m.ply")
    data = (tmp_path / "m.ply").read_bytes().replace(b"element vertex 10\n", b"element vertex 7\n")
    (tmp_path / "short.ply").write_bytes(data)
    with pytest.raises(ModelFileError, match="declares 7 vertices but the data holds 10"):
        read_model(tmp_path / "short.ply")


def test_an_all_nan_model_is_refused(tmp_path):
    m = make_scene("spheres", n=5, seed=1)
    m.means[:] = np.nan
    save_model(m, tmp_path / "nan.ply")
    with pytest.raises(ModelFileError, match="none of its 5 primitives has a finite position"):
        read_model(tmp_path / "nan.ply")


def test_cli_errors_are_one_line_without_traceback(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    spec = tiny_spec(tmp_path)
    cases = [
        [
            "inject",
            "--scene",
            "spheres",
            "--n",
            "50",
            "--field",
            "opacity",
            "--bit",
            "3",
            "--sample",
            "0",
            "--out",
            "o",
        ],
        ["campaign", str(spec), "--out", str(tmp_path / "f" / "run")],
        ["campaign", str(tmp_path), "--out", str(tmp_path / "r")],
        ["render", "--model", str(tmp_path / "f"), "--out", str(tmp_path / "o.npz")],
        ["merge", str(tmp_path / "nope"), "--out", str(tmp_path / "m")],
    ]
    for argv in cases:
        if "--sample" in argv:  # argparse's own errors exit with status 2 by SystemExit
            with pytest.raises(SystemExit) as exited:
                main(argv)
            assert exited.value.code == 2, argv
        else:
            assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert err and "Traceback" not in "\n".join(err), argv
        assert "error:" in err[-1], (argv, err)


# ---- exhaustive sweep --------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("precision", ["fp32", "fp16", "bf16"])
def test_every_bit_of_a_tiny_model_under_every_defense(precision):
    """Every field, component and bit of one primitive, in every precision, under every defense:
    each renders (finite metrics or NaN-marked records, no crash or hang), the stored words come
    back exactly, the clean render is unchanged afterwards, and a sample agrees with full renders."""
    from seuwgpu.faults.defenses import DEFENSES
    from seuwgpu.faults.engine import Engine
    from seuwgpu.model import encoding
    from seuwgpu.model.fields import FIELDS, field_components
    from seuwgpu.model.scenes import scene_cameras

    eng = Engine(make_scene("spheres", n=4, seed=1), scene_cameras("spheres", 1, 16, 16), precision)
    r = eng.renderer
    words = [r.read_words(c).copy() for c in range(r.layout.n_chunks)]
    sites = [
        eng.site(f, 1, c, b)
        for f in FIELDS
        for c in range(field_components(f, eng.degree))
        for b in range(encoding.bits_per_value(precision))
    ]
    df = eng.evaluate_frame(sites, DEFENSES)
    assert len(sites) == 59 * encoding.bits_per_value(precision) and len(df) == len(sites) * len(DEFENSES)
    assert df["footprint"].between(0, 1).all() and (df["clamps"] >= 0).all()
    assert ((df["psnr"] > 0) | df["nonfinite"]).all()
    assert all(np.array_equal(a, r.read_words(c)) for c, a in enumerate(words))
    assert np.array_equal(r.render_rgba().view(np.uint32), eng.clean_rgba.view(np.uint32))
    for i in range(0, len(df), 211):
        rec = df.iloc[i]
        full = eng.inject(eng.site(rec["field"], 1, int(rec["component"]), int(rec["bit"])), rec["defense"])
        assert full["footprint"] == rec["footprint"] and full["clamps"] == rec["clamps"], (rec, full)
    assert all(np.array_equal(a, r.read_words(c)) for c, a in enumerate(words))


def test_spec_size_with_cameras_on_every_scene_is_refused(tmp_path):
    """size = is ignored where every scene reads its views from a camera file (their image size
    rules): refused, as --size with --cameras is; where a scene has no camera file it applies."""
    from seuwgpu.model.cameras import orbit_cameras, save_cameras

    save_cameras(orbit_cameras(2, 48, 32), tmp_path / "cams.json")
    cams = {"scene": "spheres", "n": 50, "cameras": str(tmp_path / "cams.json")}
    single = {"fields": ["opacity"], "bits": [30], "samples": 1, "defenses": ["none"]}
    with pytest.raises(SpecError, match=r"^size sets orbit views; .* \(use scale\); every scene has one$"):
        normalize_spec({"size": "64x64", "scenes": [cams], "single": single})
    assert normalize_spec({"scenes": [cams], "single": single}).scenes[0].cameras
    both = normalize_spec({"size": "64x64", "scenes": [cams, {"scene": "blocks", "n": 50}], "single": single})
    assert both.size == (64, 64)
