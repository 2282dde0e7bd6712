"""The public Python API (seuwgpu/api/), used only through the package root, as a user would."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import tifffile

import seuwgpu as sg
from seuwgpu.model.fields import FIELD_OFFSET

SIZE = (40, 32)


@pytest.fixture(scope="module")
def scene():
    return sg.load_model("spheres", n=600, sh_degree=1)


@pytest.fixture(scope="module")
def views(scene):
    return sg.cameras(scene, views=2, size=SIZE)


def test_root_exports_the_api():
    from seuwgpu import api

    assert set(sg.__all__) == {"__version__", *api.__all__}  # the lazy list in __init__ agrees with seuwgpu.api
    assert all(getattr(sg, name) is getattr(api, name) for name in api.__all__)
    with pytest.raises(AttributeError):
        sg.no_such_function  # noqa: B018


def test_render_matches_the_numpy_twin(scene, views):
    from seuwgpu.render.reference import render as render_twin

    images = sg.render_views(scene, views)
    assert images.shape == (2, SIZE[1], SIZE[0], 3) and images.dtype == np.float32
    ref = render_twin(scene.model, views)[..., :3]
    mse = float(np.mean((images.astype(np.float64) - ref) ** 2))
    assert 10 * np.log10(1.0 / max(mse, 1e-20)) >= 50
    assert np.array_equal(images, sg.render_views(scene.model, views))  # a Model works as well as a Scene


def _footprint(clean, faulted):
    """Independent footprint: share of pixels with a channel changed by more than 1/255 (or
    non-finite), mean over views."""
    with np.errstate(invalid="ignore", over="ignore"):
        d = np.abs(faulted.astype(np.float32) - clean)
    changed = (~np.isfinite(d)).any(-1) | (np.where(np.isfinite(d), d, 0) > 1 / 255).any(-1)
    return float(changed.mean(axis=(1, 2)).mean())


def test_inject_measures_restores_and_saves(scene, views, tmp_path):
    before = sg.render_views(scene, views)
    inj = sg.inject(scene, views, field="log_scale", bit=30, primitive=7, defenses=["none", "guard"])
    assert inj.site["field"] == "log_scales" and inj.site["bits"] == [30] and inj.site["primitive"] == 7
    clean_bits = np.float32(scene.model.log_scales[7, 0]).view(np.uint32)
    assert np.float32(inj.site["corrupted_value"]).view(np.uint32) == clean_bits ^ (1 << 30)
    assert np.array_equal(inj.frames["clean"], before)
    for d in ("none", "guard"):
        m = inj.metrics[d]
        assert 0.0 <= m["footprint"] <= 1.0  # a fraction, not a percent
        assert m["footprint"] == pytest.approx(_footprint(inj.frames["clean"], inj.frames[d]), abs=1e-9)
    assert inj.metrics["none"]["footprint"] > 0
    from seuwgpu.metrics.lpips import lpips

    for d in ("none", "guard"):  # LPIPS (AlexNet), mean over the views
        want = float(np.mean(lpips(inj.frames["clean"], inj.frames[d])))
        assert inj.metrics[d]["lpips"] == pytest.approx(want, rel=1e-6)
    assert np.array_equal(sg.render_views(scene, views), before)  # the stored model is restored exactly
    assert list(inj.table()["defense"]) == ["none", "guard"]

    files = inj.save(tmp_path, formats=("png", "tiff"))
    assert all(f.exists() for f in files)
    assert np.array_equal(tifffile.imread(tmp_path / "faulted_001.tiff"), inj.frames["none"][1])
    assert np.array_equal(tifffile.imread(tmp_path / "guard_000.tiff"), inj.frames["guard"][0])
    err = tifffile.imread(tmp_path / "error_faulted_000.tiff")
    with np.errstate(invalid="ignore"):  # independent: max |faulted - clean| over r, g, b; NaN if non-finite
        d = np.abs(inj.frames["none"][0].astype(np.float64) - inj.frames["clean"][0])
    want = np.where(np.isfinite(d).all(-1), np.nan_to_num(d).max(-1), np.nan).astype(np.float32)
    assert err.max() > 0 and np.array_equal(err, want, equal_nan=True)
    doc = json.loads((tmp_path / "metrics.json").read_text())
    assert doc["metrics"]["none"]["footprint"] == inj.metrics["none"]["footprint"]
    assert doc["units"]["footprint"].startswith("fraction")


def test_png_is_the_display_frame_and_tiff_keeps_unclamped_values(tmp_path):
    import imageio.v3 as iio

    img = np.array([[[[2.0, -1.0, np.nan], [0.5, np.inf, 0.25]]]], np.float32)  # [1, 1, 2, 3]
    sg.save_frames(img, tmp_path, "x", formats=["png", "tiff", "npz"])
    assert iio.imread(tmp_path / "x_000.png").tolist() == [[[255, 0, 0], [128, 255, 64]]]
    back = tifffile.imread(tmp_path / "x_000.tiff")
    assert back.dtype == np.float32 and np.array_equal(back, img[0], equal_nan=True)
    assert np.array_equal(np.load(tmp_path / "x.npz")["images"], img, equal_nan=True)


def test_campaign_records_and_report(tmp_path):
    spec = {
        "name": "api",
        "seed": 3,
        "views": 1,
        "size": "32x32",
        "batch": 4,
        "scenes": [{"scene": "spheres", "n": 300}],
        "single": {
            "precisions": ["fp32"],
            "fields": ["opacity", "log_scales"],
            "bits": [30, 31],
            "samples": 2,
            "defenses": ["none", "guard"],
        },
    }
    calls = []
    stats = sg.run_campaign(spec, tmp_path / "run", progress=lambda *a: calls.append(a))
    assert stats["injections"] == 8 and stats["new"] == 8
    assert [c[0] for c in calls] == sorted(c[0] for c in calls) and calls[-1][:2] == (8, 8)
    df = sg.read_records(tmp_path / "run")
    assert len(df) == 16 and set(df["defense"]) == {"none", "guard"}
    assert calls[-1][2] == int(df.loc[df.defense == "none", "catastrophic"].sum())
    assert df["footprint"].between(0, 1).all()
    again = sg.run_campaign(spec, tmp_path / "run")  # resume: nothing left to do
    assert again["new"] == 0 and again["injections"] == 8 and again["campaign_total"] == 8
    assert sg.read_records([tmp_path / "run"]).equals(df)  # a list of runs, as make_report takes
    # another spec into that run (other row counts per part), with a progress function: refused, its
    # parts untouched (the progress adapter read, and deleted as damaged, them before the check)
    other = {**spec, "single": {**spec["single"], "defenses": ["none"]}}
    with pytest.raises(sg.InputError, match="holds a run of a different spec"):
        sg.run_campaign(other, tmp_path / "run", progress=lambda *a: None)
    assert sg.read_records(tmp_path / "run").equals(df)
    # a shard outside 0 <= I < N ran nothing and returned as done ((0, 0): a ZeroDivisionError)
    for shard in [(2, 2), (0, 0), (0.5, 2), (-1, 2), "0/2", (True, 2)]:
        with pytest.raises(sg.InputError, match="^shard must be \\(I, N\\), integers with 0 <= I < N"):
            sg.run_campaign(spec, tmp_path / "shard", shard=shard)
    assert not (tmp_path / "shard").exists()
    (tmp_path / "a-file").write_text("x")  # an output path that is a file: one clear error, not an OSError
    in_the_way = f"^--out {re.escape(str(tmp_path / 'a-file'))}: it is a file, not a folder$"  # store.make_out_dir's
    with pytest.raises(sg.InputError, match=in_the_way):
        sg.run_campaign(spec, tmp_path / "a-file")
    with pytest.raises(sg.InputError, match=in_the_way):
        sg.make_report(tmp_path / "run", tmp_path / "a-file")

    read = []
    index = sg.make_report(tmp_path / "run", tmp_path / "report", progress=lambda i, n: read.append((i, n)))
    assert index.exists() and (tmp_path / "report" / "summary.json").exists()
    parts = len(list((tmp_path / "run" / "records").glob("part-*.parquet")))
    assert read and read[-1] == (parts, parts)  # every part read, counted as it was
    figs = sg.report_figures([tmp_path / "run"])
    import matplotlib.figure

    assert figs and all(isinstance(f, matplotlib.figure.Figure) for f in figs.values())


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda s, v: sg.load_model("no-such-scene"), "neither a file nor an embedded scene"),
        (lambda s, v: sg.load_model("missing/model.ply"), "no such model file"),
        (
            lambda s, v: sg.cameras(s, size=(0, 10)),
            r"^size: width and height must be whole numbers of at least 16 px, got \(0, 10\)",
        ),
        (lambda s, v: sg.cameras(s, scale=-1), r"scale must be a number in \(0, 16\]"),
        (lambda s, v: sg.render_views(s, []), "views must be a non-empty list"),
        (lambda s, v: sg.render_views(s, v, precision="fp8"), "unknown precision"),
        (lambda s, v: sg.render_views(s, v, profile="cuda"), "^unknown renderer profile 'cuda'; expected one of"),
        (lambda s, v: sg.render_views(s, v, compositor="quad"), "^unknown compositor shape 'quad': choose one of"),
        (lambda s, v: sg.inject(s, v, field="colour", bit=1, primitive=0), "colour"),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=32, primitive=0), "bit"),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=3, primitive=10**6), "out of range"),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=3, defenses=["armour"]), "unknown defense"),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=3, sample=0), "^sample must be at least 1, got 0"),
        (lambda s, v: sg.save_frames(np.zeros((1, 2, 2, 3)), "/tmp", "x", formats=["jpg"]), "unknown frame format"),
        (lambda s, v: sg.run_campaign(5, "/tmp/x"), "spec must be a dict"),
        (lambda s, v: sg.read_records("/no/such/run"), "no such run directory"),
    ],
)
def test_bad_input_is_a_clear_error(scene, views, call, message):
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        call(scene, views)


@pytest.mark.parametrize(
    "call, message",
    [  # a float index was truncated (primitive 1.7 injected into primitive 1), True taken as 1,
        # a float bit or view count was a TypeError, a negative seed numpy's unnamed error
        (
            lambda s, v: sg.inject(s, v, field="opacity", bit=30, primitive=1.7),
            "^primitive must be an integer, got 1.7",
        ),
        (
            lambda s, v: sg.inject(s, v, field="opacity", bit=30, primitive=True),
            "^primitive must be an integer, got True",
        ),
        (lambda s, v: sg.inject(s, v, field="means", bit=30, primitive=1, component=1.5), "^component must be an int"),
        (
            lambda s, v: sg.inject(s, v, field="means", bit=30, primitive=1, component=-1),
            "^component must be at least 0",
        ),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=3.0, primitive=1), "^bit must be an integer or a list"),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=[3, 4.0], primitive=1), "^bit must be an integer, got 4.0"),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=True, primitive=1), "^bit must be an integer, got True"),
        (lambda s, v: sg.inject(s, v, field="opacity", bit=None, fault="random", seed=-1), "^seed must be at least 0"),
        (lambda s, v: sg.cameras(s, views=1.5), "^views must be an integer, got 1.5"),
        (lambda s, v: sg.cameras(s, views=True), "^views must be an integer, got True"),
        # the command line's limits (model/budget.py); size (1, 1) rendered, then inject failed in SSIM
        (lambda s, v: sg.cameras(s, views=65), "^views must be at most 64, got 65"),
        (
            lambda s, v: sg.cameras(s, size=(15, 64)),
            r"^size: width and height must be whole numbers of at least 16 px, got \(15, 64\)",
        ),
        (lambda s, v: sg.cameras(s, scale=16.5), r"^scale must be a number in \(0, 16\], got 16.5"),
        (lambda s, v: sg.cameras(s, scale=True), r"^scale must be a number in \(0, 16\], got True"),
        (lambda s, v: sg.load_model(None), "^source must be a scene name or a model path, got None"),
    ],
)
def test_arguments_of_the_wrong_type_are_refused_not_truncated(scene, views, call, message):
    with pytest.raises(sg.InputError, match=message):
        call(scene, views)


def test_cli_inject_and_render_write_every_frame(tmp_path, capsys):
    from seuwgpu.apps.cli import main

    common = ["--scene", "spheres", "--n", "400", "--views", "1", "--size", "32x24"]
    out = tmp_path / "inj"
    assert main(["inject", *common, "--field", "opacity", "--bit", "30", "--primitive", "3", "--out", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"panel.png", "metrics.json", "clean_000.tiff", "faulted_000.png", "guard_000.tiff"} <= names
    printed = capsys.readouterr().out
    fraction = json.loads((out / "metrics.json").read_text())["metrics"]["none"]["footprint"]
    assert f"footprint: {100 * fraction:.4f}%" in printed  # a percent only in text for people
    assert main(["render", *common, "--formats", "tiff,png", "--out", str(tmp_path / "r")]) == 0
    assert {p.name for p in (tmp_path / "r").iterdir()} == {"view_000.tiff", "view_000.png"}
    with pytest.raises(SystemExit) as e:  # argparse: usage and a one-line error, status 2
        main(["render", *common, "--formats", "jpg", "--out", str(tmp_path / "r")])
    assert e.value.code == 2 and "--formats takes" in capsys.readouterr().err


def test_inject_fault_models(scene, views):
    """Each fault model corrupts the stored word as it says (hand-computed bit patterns)."""
    word = int(np.float32(scene.model.opacity[5]).view(np.uint32))

    def stored(inj):
        return int(np.float32(inj.site["corrupted_value"]).view(np.uint32))

    adj = sg.inject(scene, views, field="opacity", bit=27, primitive=5, fault="adjacent", width=3, defenses="none")
    assert adj.site["bits"] == [25, 26, 27] and stored(adj) == word ^ (0b111 << 25)
    s1 = sg.inject(scene, views, field="opacity", bit=30, primitive=5, fault="stuck1", defenses="none")
    assert stored(s1) == word | (1 << 30) and s1.site["fault"] == "stuck1"
    s0 = sg.inject(scene, views, field="opacity", bit=31, primitive=5, fault="stuck0", defenses="none")
    assert stored(s0) == word & ~(1 << 31) & 0xFFFFFFFF
    zero = sg.inject(scene, views, field="opacity", bit=None, primitive=5, fault="zero", defenses="none")
    assert stored(zero) == 0
    with pytest.raises(ValueError, match="unknown fault model"):
        sg.inject(scene, views, field="opacity", bit=3, primitive=5, fault="cosmic")
    with pytest.raises(ValueError, match="needs bit"):
        sg.inject(scene, views, field="opacity", bit=None, primitive=5, fault="stuck1")


def test_load_model_refuses_n_for_a_model_file(tmp_path):
    """n shapes an embedded scene; with a model file it is refused, as the command line refuses
    --n with --model (it used to be ignored silently)."""
    from seuwgpu.model.formats import save_model

    save_model(sg.load_model("spheres", n=50).model, tmp_path / "m.ply")
    assert sg.load_model(tmp_path / "m.ply").model.n == 50
    with pytest.raises(sg.InputError, match="n sets the primitives of an embedded scene; a model file keeps all"):
        sg.load_model(str(tmp_path / "m.ply"), n=10)


def test_views_of_several_sizes_render_size_by_size(scene, tmp_path):
    """A capture mixing portrait and landscape views: render_views renders each size apart and
    returns the frames in the views' order; inject, which needs one frame set, says why not."""
    land, port = sg.cameras(scene, views=3, size=(40, 32)), sg.cameras(scene, views=3, size=(32, 40))
    mixed = [land[0], port[1], land[2]]
    frames = sg.render_views(scene, mixed)
    assert [f.shape for f in frames] == [(32, 40, 3), (40, 32, 3), (32, 40, 3)]
    want_land, want_port = sg.render_views(scene, [land[0], land[2]]), sg.render_views(scene, [port[1]])
    assert np.array_equal(frames[0], want_land[0]) and np.array_equal(frames[2], want_land[1])
    assert np.array_equal(frames[1], want_port[0])
    paths = sg.save_frames(frames, tmp_path, "view", formats=["png", "tiff"])
    assert [p.name for p in paths if p.suffix == ".tiff"] == ["view_000.tiff", "view_001.tiff", "view_002.tiff"]
    assert np.array_equal(tifffile.imread(tmp_path / "view_001.tiff"), frames[1])
    with pytest.raises(sg.InputError, match="npz"):
        sg.save_frames(frames, tmp_path, "view", formats=["npz"])
    with pytest.raises(sg.InputError, match=r"2 image sizes, 40x32 \(2 views\), 32x40 \(1 view\)"):
        sg.inject(scene, mixed, field="opacity", bit=30, primitive=0)


def test_size_beside_a_cameras_file_is_refused_not_ignored(scene, tmp_path):
    """sg.cameras(scene, cameras=FILE, size=(64, 64)) returned the file's views at their own size
    (48 x 40 here), the size silently dropped, where the command line refuses --size with
    --cameras; it is refused the same way, and `scale` still resizes the file's views."""
    from seuwgpu.model.cameras import save_cameras

    save_cameras(sg.cameras(scene, views=2, size=(48, 40)), tmp_path / "CAMS.json")
    with pytest.raises(sg.InputError, match="^size sets orbit views; a cameras file gives each view its own size"):
        sg.cameras(scene, cameras=tmp_path / "CAMS.json", size=(64, 64))
    views = sg.cameras(scene, cameras=tmp_path / "CAMS.json", scale=0.5)
    assert [(c.width, c.height) for c in views] == [(24, 20), (24, 20)]
    assert [(c.width, c.height) for c in sg.cameras(scene, views=1)] == [(256, 256)]  # the orbit default


def test_inject_samples_as_many_primitives_as_the_command_line(scene, views, capsys):
    """Without a primitive, `seuwgpu inject` took the worst of 64 sampled primitives and
    sg.inject the worst of 32, neither documented: one default, said in both places, and the
    same primitive picked for the same seed."""
    import inspect

    from seuwgpu.apps.cli import build_parser

    argv = ["inject", "--scene", "spheres", "--field", "opacity", "--bit", "30", "--out", "o"]
    default = inspect.signature(sg.inject).parameters["sample"].default
    assert build_parser().parse_args(argv).sample == default == 64
    with pytest.raises(SystemExit):
        build_parser().parse_args(["inject", "--help"])
    assert f"given (default {default}," in " ".join(capsys.readouterr().out.split())
    assert f"(default {default}," in sg.inject.__doc__
    a = sg.inject(scene, views, field="log_scales", bit=30, defenses=("none",))
    b = sg.inject(scene, views, field="log_scales", bit=30, defenses=("none",), sample=64)
    assert a.site["primitive"] == b.site["primitive"]


def test_worst_case_finds_the_flip_inject_measures():
    """sg.worst_case's flip, injected through sg.inject (a full render), has the footprint the
    search reported."""
    scene = sg.load_model("spheres", n=40, sh_degree=0)
    cams = sg.cameras(scene, views=1, size=(32, 32))
    found = sg.worst_case(scene, cams, defenses=("none",), fields=["opacity"], bits=[30, 31])
    assert list(found) == ["none"]
    wc = found["none"]
    assert wc.sites == 40 * 2 and wc.certified == wc.footprint > 0
    s = wc.site
    inj = sg.inject(scene, cams, field=s.field, primitive=s.primitive, component=s.component, bit=s.bit)
    assert inj.metrics["none"]["footprint"] == wc.footprint
    with pytest.raises(ValueError, match="unknown defense 'nope'"):
        sg.worst_case(scene, cams, defenses=["nope"])


def test_storm_and_state_flips_are_the_engine_runs_they_name():
    """sg.storm and sg.state_flips return what campaign/storm.py and faults/state.py record on an
    engine of the same model, views and arguments."""
    import pandas.testing as pd_testing

    from seuwgpu.campaign.storm import storm
    from seuwgpu.faults.engine import Engine
    from seuwgpu.faults.state import state_campaign

    scene = sg.load_model("spheres", n=60, sh_degree=0)
    cams = sg.cameras(scene, views=1, size=(32, 32))
    steps = []
    df = sg.storm(scene, cams, k=3, frames=2, scrub_every=1, defenses=("none", "guard"), seed=4,
                  progress=lambda: steps.append(1))  # fmt: skip
    assert len(df) == 4 == len(steps) and list(df["defense"].unique()) == ["none", "guard"]
    eng = Engine(scene.model, cams, "fp32", scene=scene.name)
    pd_testing.assert_frame_equal(df, storm(eng, 3, 2, 1, ("none", "guard"), 4))
    flips = sg.state_flips(scene, cams, targets=["xy", "conic"], samples=1, bits=[31, 0, 31], seed=2)
    assert len(flips) == 2 * 2 and set(flips["target"]) == {"proj_xy", "proj_conic"}
    pd_testing.assert_frame_equal(flips, state_campaign(eng, ["xy", "conic"], 1, [31, 0], 2))
    with pytest.raises(sg.InputError, match="k must be an integer"):
        sg.storm(scene, cams, k=1.5)


def test_run_campaign_logs_lines_when_asked(tmp_path, capsys):
    """progress="log" (the command line's --quiet): a line on stderr with the count and the rate;
    another word is refused."""
    spec = {"views": 1, "size": "16x16", "scenes": [{"scene": "spheres", "n": 50}],
            "single": {"fields": ["opacity"], "bits": [31], "samples": 2, "defenses": ["none"]}}  # fmt: skip
    stats = sg.run_campaign(spec, tmp_path / "run", progress="log")
    assert stats["new"] == stats["campaign_total"] == 2
    assert re.search(r"^2/2 injections, [\d.]+/s, ETA ", capsys.readouterr().err, re.M)
    with pytest.raises(sg.InputError, match='progress must be a function, True, "log" or None'):
        sg.run_campaign(spec, tmp_path / "run", progress="bar")
    with pytest.raises(sg.InputError, match='executor must be "local" or "ray"'):
        sg.run_campaign(spec, tmp_path / "run", executor="dask")


def test_the_readme_example_runs_from_another_directory(tmp_path, monkeypatch):
    """The README's Python example, from a folder that is not the checkout: the default spec is
    the packaged one (a path relative to the checkout stopped it with a SpecError), and the
    campaign it names starts (a thin shard of it: the test stays seconds) and writes where asked."""
    import tomllib

    from seuwgpu.campaign.store import read_manifest

    monkeypatch.chdir(tmp_path)
    spec = sg.default_spec()
    assert spec.is_absolute() and spec.is_file() and tmp_path not in spec.parents
    assert tomllib.loads(spec.read_text())["name"] == "default"
    scene = sg.load_model("spheres", n=300)  # the example's calls, on a small scene
    views = sg.cameras(scene, views=1, size=(32, 32))
    inj = sg.inject(scene, views, field="log_scales", bit=31, defenses=["none", "guard"])
    inj.save("out/inject", formats=["png"])
    assert (tmp_path / "out" / "inject" / "metrics.json").is_file()
    stats = sg.run_campaign(sg.default_spec(), "runs/x", shard=(999, 1000))  # a slice without blocks
    assert stats["new"] == 0
    assert read_manifest(tmp_path / "runs" / "x")["spec"]["name"] == "default"


def test_demo_runs_the_spec_the_api_names(tmp_path, monkeypatch, capsys):
    """`seuwgpu demo` reads the spec `seuwgpu.api.default_spec()` names (a smaller one here)."""
    from seuwgpu import api
    from seuwgpu.apps.cli import main
    from seuwgpu.campaign.store import read_manifest

    small = tmp_path / "small.toml"
    small.write_text(
        'name = "small"\nviews = 1\nsize = "16x16"\n[[scenes]]\nscene = "spheres"\nn = 50\n'
        '[single]\nfields = ["opacity"]\nbits = [31]\nsamples = 2\ndefenses = ["none"]\n'
    )
    monkeypatch.setattr(api, "default_spec", lambda: small)
    assert main(["demo", "--quiet", "--no-report", "--out", str(tmp_path / "d")]) == 0
    assert "1 views at 16x16" in capsys.readouterr().out
    m = read_manifest(tmp_path / "d")
    assert m["spec"]["name"] == "small" and m["total_injections"] == 2


def test_save_models_leaves_out_an_spz_that_cannot_hold_the_damage(tmp_path):
    """An exponent stuck at ones (a non-finite value): faulted.ply holds it, an SPZ cannot, so
    faulted.spz is left out with a warning; without models=True there is nothing to save."""
    scene = sg.load_model("spheres", n=200, sh_degree=0)
    cams = sg.cameras(scene, views=1, size=(32, 32))
    args = dict(field="opacity", primitive=3, bit=list(range(23, 31)), fault="stuck1", defenses=("none",))
    with pytest.raises(sg.InputError, match="models=True"):
        sg.inject(scene, cams, **args).save_models(tmp_path)
    inj = sg.inject(scene, cams, **args, models=True)
    assert list(inj.models) == ["faulted"]
    with pytest.warns(UserWarning, match="faulted.spz not written: .*non-finite"):
        written = inj.save_models(tmp_path)
    assert [p.name for p in written] == ["faulted.ply"]
    with pytest.warns(Warning, match="1 non-finite values"):
        back = sg.load_model(tmp_path / "faulted.ply").model
    assert not np.isfinite(back.opacity[3]) and np.array_equal(back.opacity[:3], scene.model.opacity[:3])


def test_merge_runs_joins_the_shards_of_a_spec(tmp_path):
    """sg.merge_runs: the records of two --shard slices joined are theirs, together; one slice
    alone is refused unless allow_partial, which lists the parts it lacks."""
    import pandas as pd

    spec = {"views": 1, "size": "16x16", "batch": 2, "scenes": [{"scene": "spheres", "n": 60}],
            "single": {"fields": ["opacity"], "bits": [31, 30], "samples": 2, "defenses": ["none"]}}  # fmt: skip
    shards = [tmp_path / f"s{i}" for i in range(2)]
    for i, d in enumerate(shards):
        sg.run_campaign(spec, d, shard=(i, 2))
    merged = sg.merge_runs(shards, tmp_path / "all")
    assert merged == {"parts": 2, "missing_parts": []}
    key = ["injection_id", "defense"]

    def records(*runs):  # without the `run` label read_records adds
        df = pd.concat([sg.read_records(d) for d in runs]).drop(columns="run")
        return df.sort_values(key).reset_index(drop=True)

    pd.testing.assert_frame_equal(records(tmp_path / "all"), records(*shards))
    with pytest.raises(sg.InputError, match="missing"):
        sg.merge_runs(shards[0], tmp_path / "part")
    assert sg.merge_runs(shards[0], tmp_path / "part2", allow_partial=True)["missing_parts"] == [[2, 2]]


def test_device_info_export_scene_and_defense_costs(tmp_path):
    """The functions behind `info`, `scene` and `defenses`: the adapter's limits as wgpu reports
    them, an embedded scene written and read back unchanged, and every defense's cost row."""
    from seuwgpu.gpu.device import get_gpu
    from seuwgpu.model.formats import read_model
    from seuwgpu.model.scenes import make_scene

    info = sg.device_info()
    gpu = get_gpu()
    assert info["limits"]["max-buffer-size"] == gpu.limits["max-buffer-size"]
    assert info["features"] == sorted(gpu.adapter.features) and info["device"] == gpu.info.get("device")
    model, fmt = sg.export_scene("spheres", tmp_path / "s.ply", n=40, sh_degree=1)
    assert fmt == "ply" and np.array_equal(read_model(tmp_path / "s.ply").model.flat(), model.flat())
    assert np.array_equal(model.flat(), make_scene("spheres", n=40, sh_degree=1).flat())
    with pytest.raises(sg.InputError, match="not an embedded scene"):
        sg.export_scene("nope", tmp_path / "n.ply")
    scene = sg.load_model("spheres", n=40)
    rows = sg.defense_costs(scene, sg.cameras(scene, views=1, size=(32, 32))[0], time_it=False)
    assert [r["name"] for r in rows] == list(sg.DEFENSES)
    assert all(np.isnan(r["time_fraction"]) and r["memory_overhead"] >= 0 for r in rows)
    assert rows[0]["name"] == "none" and rows[0]["memory_overhead"] == 0


def test_plan_campaign_counts_what_a_spec_runs(tmp_path):
    """sg.plan_campaign (what `seuwgpu plan` prints): cells x samples injections per context, a
    record per defense, the worst-case margin z * 0.5 / sqrt(samples) of a cell's rate, and <NA>
    for a model file's primitive count."""
    import math

    sg.export_scene("spheres", tmp_path / "m.ply", n=50)
    spec = {"scenes": [{"scene": "spheres", "n": 1000}, {"model": str(tmp_path / "m.ply")}],
            "single": {"fields": ["opacity", "means"], "bits": [31, 30, 29], "samples": 3},
            "dose": {"k": [1, 2], "repeats": 2, "defenses": ["none"]}}  # fmt: skip
    plan = sg.plan_campaign(spec)
    assert plan["campaign"].tolist() == ["single", "single", "dose", "dose"]
    assert plan["scene"].tolist() == ["spheres", "m", "spheres", "m"]
    assert plan["n"].iloc[0] == 1000 and plan["n"].isna().tolist() == [False, True, False, True]
    single = plan.iloc[0]
    assert (single.cells, single.per_cell, single.injections, single.arms, single.records) == (6, 3, 18, 2, 36)
    assert single.margin == pytest.approx(1.959964 * 0.5 / math.sqrt(3), rel=1e-5)
    dose = plan.iloc[2]
    assert (dose.cells, dose.per_cell, dose.injections, dose.records) == (2, 2, 4, 4) and math.isnan(dose.margin)


def test_the_guards_kept_model_is_what_its_frame_draws(tmp_path):
    """models=True under the guard: the kept model is the faulted one with the hit value clamped
    into the clean box (here the log-scale's clean maximum), every other value clean, and a plain
    render of it is the guard's frame bit for bit."""
    scene = sg.load_model("spheres", n=300, sh_degree=0)
    cams = sg.cameras(scene, views=1, size=(32, 32))
    inj = sg.inject(scene, cams, field="log_scales", primitive=7, component=1, bit=30, defenses=("none", "guard"),
                    models=True)  # fmt: skip
    clean = scene.model.flat()
    col = FIELD_OFFSET["log_scales"] + 1
    faulted, guarded = inj.models["faulted"].flat(), inj.models["guard"].flat()
    assert faulted[7, col] > clean[:, col].max()  # bit 30 of a small log-scale: a huge value
    assert guarded[7, col] == clean[:, col].max()
    others = np.ones(clean.shape, bool)
    others[7, col] = False
    assert np.array_equal(guarded[others], clean[others]) and np.array_equal(faulted[others], clean[others])
    assert np.array_equal(sg.render_views(inj.models["guard"], cams), inj.frames["guard"])
    assert not np.array_equal(inj.frames["none"], inj.frames["guard"])
