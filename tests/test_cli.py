"""Every command of the command line, end to end at tiny sizes, checked against the library
calls it stands for. (`view` runs end to end on an offscreen canvas in tests/test_viewer.py:
test_view_offscreen_command and test_view_without_display_says_what_to_do.)"""

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from seuwgpu.apps.cli import main
from seuwgpu.campaign.schema import REPRODUCIBLE_COLUMNS
from seuwgpu.campaign.store import read_manifest, read_records
from seuwgpu.model.formats import read_model
from seuwgpu.model.scenes import make_scene, scene_cameras
from seuwgpu.render.renderer import Renderer
from seuwgpu.version import __version__

ROOT = Path(__file__).resolve().parents[1]
SPEC = textwrap.dedent("""
    seed = 3
    views = 1
    size = "16x16"
    batch = 3
    [[scenes]]
    scene = "spheres"
    n = 120
    [single]
    fields = ["opacity", "log_scales"]
    bits = [30, 31]
    samples = 2
    defenses = ["none", "guard"]
""")


def run(argv, capsys):
    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_version_and_errors_through_a_real_process(tmp_path):
    p = subprocess.run([sys.executable, "-m", "seuwgpu", "--version"], capture_output=True, text=True, cwd=ROOT)
    assert p.returncode == 0 and p.stdout.strip() == f"seuwgpu {__version__}"
    p = subprocess.run(
        [sys.executable, "-m", "seuwgpu", "campaign", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "r")],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip() == f"seuwgpu campaign: error: {tmp_path / 'missing.toml'}: file not found"


def test_info(capsys):
    from seuwgpu.gpu.device import get_gpu

    rc, out, _ = run(["info"], capsys)
    assert rc == 0
    limit = get_gpu().limits["max-storage-buffer-binding-size"]
    assert f"max-storage-buffer-binding-size: {limit}" in out


def test_scene_list_and_export(tmp_path, capsys):
    rc, out, _ = run(["scene", "--list"], capsys)
    assert rc == 0 and re.search(r"^spheres\s", out, re.M)
    rc, out, _ = run(["scene", "spheres", "--n", "50", "--sh-degree", "1", "--out", tmp_path / "s.ply"], capsys)
    assert rc == 0
    got, want = read_model(tmp_path / "s.ply").model, make_scene("spheres", n=50, sh_degree=1)
    assert np.array_equal(got.flat(), want.flat())


def test_output_paths_checked_before_the_work(tmp_path, capsys, monkeypatch):
    """A file where --out wants a folder is refused before anything runs (inject used to render
    for seconds and then print "File exists"); `scene --out` without a NAME says which is missing."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    import seuwgpu.api  # noqa: F401  (imported first: it binds the real loader, kept for the tests after this one)
    from seuwgpu.model import sources

    def no_work(*a, **k):
        raise AssertionError("loaded the model before checking --out")

    monkeypatch.setattr(sources, "load_source", no_work)
    for out in (afile, afile / "sub"):
        args = ["inject", "--scene", "spheres", "--n", "500", "--field", "log_scale", "--bit", "31", "--out", str(out)]
        assert main(args) == 2
        assert "is a file, not a folder" in capsys.readouterr().err
    for cmd in ("render", "storm", "state"):  # render: a folder, or an npz under a file
        for out in (afile, afile / "x.npz") if cmd == "render" else (afile,):
            assert main([cmd, "--scene", "spheres", "--n", "500", "--out", str(out)]) == 2
            assert "is a file, not a folder" in capsys.readouterr().err
    assert main(["scene", "--out", str(tmp_path / "q.ply")]) == 2
    assert "which scene? give its NAME" in capsys.readouterr().err and not (tmp_path / "q.ply").exists()


def test_options_the_others_make_meaningless_are_refused(tmp_path, capsys):
    """An option that would be ignored is refused with the reason (a user who asked for 64x64
    frames from a cameras file got the file's sizes, silently)."""
    (tmp_path / "m.ply").write_bytes(b"")  # never read: the options are checked first
    cams = tmp_path / "CAMS.json"
    cams.write_text("[]")
    base = ["--out", str(tmp_path / "o")]
    cases = [
        (["render", "--model", str(tmp_path / "m.ply"), "--n", "10", *base], "--n sets the primitives"),
        (["render", "--scene", "spheres", "--cameras", str(cams), "--size", "64x64", *base], "--size sets orbit"),
        # demo builds a spec; its refusal named the spec's key ("remove it (scale = S ...)"), not --size
        (["demo", "--scene", "spheres", "--cameras", str(cams), "--size", "64x64", *base], "--size sets orbit"),
        (["demo", "--model", str(tmp_path / "m.ply"), "--n", "10", *base], "--n sets the primitives"),
        (
            ["render", "--scene", "spheres", "--n", "500", "--out", str(tmp_path / "x.npz"), "--formats", "png"],
            "one npz",
        ),
        (["inject", "--scene", "spheres", "--field", "opacity", "--bit", "3", "--width", "3", *base], "--width sets"),
        (
            ["inject", "--scene", "spheres", "--field", "opacity", "--fault", "zero", "--bit", "3", *base],
            "--bit does not",
        ),
    ]
    cases.append(
        (
            ["inject", "--scene", "spheres", "--field", "opacity", "--bit", "3", "4", "--width", "3", *base],
            "--width sets the burst",
        )
    )
    for args, why in cases:
        assert main(args) == 2, args
        assert why in capsys.readouterr().err, args
    assert not (tmp_path / "o").exists() and not (tmp_path / "x.npz").exists()
    # `view`'s --size is its window, which goes with --cameras
    from seuwgpu.apps.cli import build_parser, refuse_ignored_options

    refuse_ignored_options(build_parser().parse_args(["view", "--scene", "spheres", "--cameras", str(cams)]))
    with pytest.raises(Exception, match="--size sets orbit"):
        refuse_ignored_options(
            build_parser().parse_args(["render", "--cameras", str(cams), "--size", "64x64", "--out", "o"])
        )


def test_render_equals_the_renderer(tmp_path, capsys, monkeypatch):
    rc, _, _ = run(
        ["render", "--scene", "spheres", "--n", "300", "--views", "2", "--size", "32x24", "--out", tmp_path / "r.npz"],
        capsys,
    )
    assert rc == 0
    images = np.load(tmp_path / "r.npz")["images"]
    want = Renderer(make_scene("spheres", n=300), scene_cameras("spheres", 2, 32, 24)).render()
    assert images.shape == (2, 24, 32, 3) and np.array_equal(images, want)
    rc, out, _ = run(
        ["render", "--scene", "spheres", "--n", "300", "--size", "32x24", "--out", tmp_path / "png"], capsys
    )
    assert rc == 0 and len(list((tmp_path / "png").glob("view_*.png"))) == 4
    shapes = []  # the shape each Renderer was built with: "wide" frames equal "lanes" ones by design
    real_init = Renderer.__init__

    def spy(self, *a, **k):
        real_init(self, *a, **k)
        shapes.append(self.compositing.shape)

    monkeypatch.setattr(Renderer, "__init__", spy)
    rc, _, _ = run(
        ["render", "--scene", "spheres", "--n", "300", "--views", "2", "--size", "32x24", "--compositor", "wide",
         "--out", tmp_path / "w.npz"],
        capsys,
    )  # fmt: skip
    assert rc == 0 and shapes == ["wide"]  # the option reaches the renderer through api.render_views
    assert np.array_equal(np.load(tmp_path / "w.npz")["images"], want)  # the same frames bit for bit
    # more --views than a cameras file holds: all are rendered, and the user is told
    cams = [
        {"viewmat": c.viewmat.tolist(), "K": c.K.tolist(), "width": c.width, "height": c.height}
        for c in scene_cameras("spheres", 2, 32, 24)
    ]
    (tmp_path / "CAMS.json").write_text(json.dumps({"cameras": cams}))
    args = ["render", "--scene", "spheres", "--n", "300", "--cameras", tmp_path / "CAMS.json", "--views", "5"]
    rc, _, err = run([*args, "--out", tmp_path / "c.npz"], capsys)
    assert rc == 0 and "--views 5:" in err and "holds 2, all rendered" in err
    assert np.array_equal(np.load(tmp_path / "c.npz")["images"], want)


def test_inject_reports_the_flip_and_writes_the_panel(tmp_path, capsys):
    rc, out, _ = run(
        [
            "inject", "--scene", "spheres", "--n", "300", "--views", "1", "--size", "32x32",
            "--field", "log_scales", "--primitive", "5", "--component", "1", "--bit", "31", "--out", tmp_path,
        ],
        capsys,
    )  # fmt: skip
    assert rc == 0
    lines = dict(line.split(": ", 1) for line in out.splitlines() if ": " in line)
    assert lines["field"] == "log_scales" and lines["primitive"] == "5" and lines["bit"] == "31"
    clean = make_scene("spheres", n=300).log_scales[5, 1]
    assert float(lines["clean_value"]) == pytest.approx(clean) and float(lines["corrupted_value"]) == -float(
        lines["clean_value"]
    )
    assert (tmp_path / "panel.png").is_file()


def test_plan_campaign_shards_merge_and_report(tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    rc, out, _ = run(["plan", spec, "--margin", "0.1"], capsys)
    assert rc == 0
    total = int(re.search(r"total: ([\d,]+) injections", out).group(1).replace(",", ""))
    assert total == 2 * 2 * 2  # fields x bits x samples
    for i in range(2):
        rc, out, _ = run(["campaign", spec, "--out", tmp_path / f"s{i}", "--shard", f"{i}/2", "--quiet"], capsys)
        assert rc == 0
    rc, out, err = run(["merge", tmp_path / "s0", "--out", tmp_path / "m"], capsys)
    assert rc == 2 and "--allow-partial" in err
    rc, out, _ = run(["merge", tmp_path / "s0", tmp_path / "s1", "--out", tmp_path / "m"], capsys)
    assert rc == 0 and "merged" in out
    rc, out, _ = run(["campaign", spec, "--out", tmp_path / "one", "--quiet"], capsys)
    assert rc == 0 and f"{total} of {total} injections recorded" in out
    # every column but the wall-clock time_ms is reproduced bit for bit
    a = read_records(tmp_path / "m").sort_values(["injection_id", "defense"]).reset_index(drop=True)
    b = read_records(tmp_path / "one").sort_values(["injection_id", "defense"]).reset_index(drop=True)
    assert len(a) == 2 * total and a[REPRODUCIBLE_COLUMNS].equals(b[REPRODUCIBLE_COLUMNS])
    assert read_manifest(tmp_path / "m")["total_injections"] == total
    rc, out, _ = run(["report", tmp_path / "m", "--out", tmp_path / "rep"], capsys)
    assert rc == 0 and (tmp_path / "rep" / "index.html").is_file()
    # folded as read: the same tables, and the criticality table from the report's own file
    rc, out2, _ = run(["report", tmp_path / "m", "--out", tmp_path / "rep2", "--fold", "yes"], capsys)
    assert rc == 0 and "records folded as read" in out2
    assert (tmp_path / "rep2" / "criticality.md").read_text() == (tmp_path / "rep" / "criticality.md").read_text()
    assert json.loads((tmp_path / "rep2" / "summary.json").read_text())["folded"]["records"] == 2 * total


@pytest.mark.slow
def test_demo_on_a_corpus_model(tmp_path, capsys):
    """The main job on a user's model (issue 45): a subset of the corpus model "plant" (a real
    .splat capture, tests/data/corpus), its report opening with the summary."""
    model = ROOT / "tests" / "data" / "corpus" / "plant-2000.splat"
    rc, out, _ = run(
        ["demo", "--model", model, "--views", "1", "--size", "16x16", "--samples", "1", "--quiet",
         "--out", tmp_path / "demo"],
        capsys,
    )  # fmt: skip
    assert rc == 0 and "Per-field single-upset criticality at fp32" in out
    m = read_manifest(tmp_path / "demo")
    assert len(read_records(tmp_path / "demo")) == m["total_injections"] * len(m["spec"]["single"]["defenses"])
    assert (tmp_path / "demo" / "report" / "index.html").is_file()
    # the report opens with the summary: the model as loaded, its p_c, the worst flip's panel
    assert m["models"] == [{"name": "plant-2000", "format": "splat", "primitives": 2000, "sh_degree": 0, "notes": []}]
    md = (tmp_path / "demo" / "report" / "report.md").read_text()
    summary = md.split("\n## ")[1]
    assert (
        summary.startswith("Summary") and "p_c = " in summary and "Model plant-2000: splat, 2,000 primitives" in summary
    )
    assert (tmp_path / "demo" / "report" / "fig_worst_flip.png").is_file()


@pytest.mark.slow
def test_distributed_sort_first(capsys, monkeypatch):
    pytest.importorskip("ray")
    from seuwgpu.campaign import sortfirst

    shown = []  # what the command computed, as handed to its printer
    printer = sortfirst.print_sort_first
    monkeypatch.setattr(
        sortfirst, "print_sort_first", lambda res, console=None: (shown.append(res), printer(res, console))
    )
    rc, out, _ = run(
        ["distributed", "--scene", "spheres", "--n", "300", "--views", "1", "--size", "32x32", "--ranks", "2",
         "--repeats", "1", "--upset", "log_scales:31", "--primitive", "3"],
        capsys,
    )  # fmt: skip
    assert rc == 0 and len(shown) == 1
    res = shown[0]
    # two ranks whose regions tile the frame, each timed; the asked-for upset: a scale's sign flip
    assert res["ranks"] == 2 and len(res["regions"]) == len(res["times"]) == len(res["per_rank"]) == 2
    assert sum(w * h for _, _, w, h in res["regions"]) == 32 * 32 and all(t > 0 for t in res["times"])
    s = res["site"]
    assert (s.field, s.primitive, s.component, s.bits) == ("log_scales", 3, 0, (31,))
    assert res["corrupted_value"] == -res["clean_value"]
    # a rank is contaminated only where the corrupted (or the clamped) footprint reaches
    assert res["touched_none"] <= res["reach_upset"] and res["touched_guard"] <= res["reach_guarded"]
    assert {r for r, pr in enumerate(res["per_rank"]) if pr["none"]["changed"]} == res["touched_none"]
    # and the printed table says the same
    assert re.search(rf"ranks contaminated, no guard: +\S.* \({len(res['touched_none'])} of 2\)", out)
    assert "upset: log_scales[3][0] bit 31" in out


def test_the_command_line_and_a_spec_share_the_size_and_view_limits(capsys):
    """One set of limits (model/budget.py): a --size, --views or --scale a command accepts, a campaign spec
    accepts too (`demo` turns them into one), and the other way round."""
    import tomllib

    from seuwgpu.apps.cli import build_parser
    from seuwgpu.campaign.spec import SpecError, normalize_spec
    from seuwgpu.model.checks import MAX_SCALE, MAX_VIEWS, MIN_VIEW_SIZE

    required = {"render": ["--out", "o"], "inject": ["--field", "opacity", "--bit", "3", "--out", "o"]}

    def cli(cmd, option, value):
        try:
            build_parser().parse_args([cmd, "--scene", "spheres", *required.get(cmd, []), option, value])
        except SystemExit:
            err = capsys.readouterr().err
            assert f"argument {option}: " in err and value in err, err  # one line naming the option
            return False
        return True

    def spec(key, value):
        raw = tomllib.loads(SPEC)
        raw[key] = value
        try:
            normalize_spec(raw)
        except SpecError:
            return False
        return True

    lo = MIN_VIEW_SIZE
    for w, h in [(lo - 1, lo), (lo, lo - 1), (lo, lo), (lo + 1, 300), (0, 0)]:
        ok = min(w, h) >= lo
        for cmd in ("render", "inject", "demo"):
            assert cli(cmd, "--size", f"{w}x{h}") == ok, (cmd, w, h)
        assert spec("size", f"{w}x{h}") == ok, (w, h)
    for k in (0, 1, MAX_VIEWS, MAX_VIEWS + 1):
        ok = 1 <= k <= MAX_VIEWS
        for cmd in ("render", "inject", "demo", "view"):
            assert cli(cmd, "--views", str(k)) == ok, (cmd, k)
        assert spec("views", k) == ok, k
    for f in (0.0, 0.25, float(MAX_SCALE), MAX_SCALE + 0.5):
        ok = 0 < f <= MAX_SCALE
        for cmd in ("render", "inject"):
            assert cli(cmd, "--scale", str(f)) == ok, (cmd, f)
        assert spec("scale", f) == ok, f


def test_render_a_cameras_file_of_several_image_sizes(tmp_path, capsys):
    """A capture mixing portrait and landscape views (COLMAP, INRIA): `render` renders each size
    apart and writes view_K as for one size; the commands that render one frame set (inject, a
    campaign through demo) refuse it with the sizes and their view counts, before any work."""
    land, port = scene_cameras("spheres", 3, 64, 48), scene_cameras("spheres", 3, 48, 64)
    mixed = [land[0], port[1], land[2]]
    cams = tmp_path / "CAMS.json"
    cams.write_text(json.dumps({"cameras": [c.to_json() for c in mixed]}))
    common = ["--scene", "spheres", "--n", "300", "--cameras", cams]
    rc, out, err = run(["render", *common, "--formats", "png,tiff", "--out", tmp_path / "r"], capsys)
    assert rc == 0, err
    assert sorted(p.name for p in (tmp_path / "r").glob("view_*.tiff")) == [f"view_{k:03d}.tiff" for k in range(3)]
    model = make_scene("spheres", n=300)
    want_land, want_port = Renderer(model, [land[0], land[2]]).render(), Renderer(model, [port[1]]).render()
    import tifffile

    for k, want in enumerate((want_land[0], want_port[0], want_land[1])):
        assert np.array_equal(tifffile.imread(tmp_path / "r" / f"view_{k:03d}.tiff"), want)
    rc, _, err = run(["render", *common, "--out", tmp_path / "r.npz"], capsys)
    assert rc == 2 and "do not fit one npz array" in err and not (tmp_path / "r.npz").exists()
    sizes = "2 image sizes, 64x48 (2 views), 48x64 (1 view)"
    inject = ["inject", *common, "--field", "opacity", "--bit", "30", "--primitive", "0", "--out", tmp_path / "i"]
    rc, _, err = run(inject, capsys)
    assert rc == 2 and f"--cameras {cams}: the views have {sizes}" in err and "one size at a time" in err
    rc, _, err = run(["demo", *common, "--samples", "1", "--quiet", "--out", tmp_path / "d"], capsys)
    assert rc == 2 and sizes in err and not (tmp_path / "d").exists()
    # views of one size picked from the file run as before: --views 1 takes the first
    rc, _, err = run([*inject[:-2], "--views", "1", "--out", tmp_path / "i"], capsys)
    assert rc == 0, err


def test_view_checks_its_arguments_before_the_display(tmp_path, capsys, monkeypatch):
    """A bad argument is exit status 2 whether or not a display opens (it used to be 3, no
    display); more --views than the cameras file holds is said, as `render` says it."""
    from seuwgpu.apps import viewer_window

    for var in ("DISPLAY", "WAYLAND_DISPLAY", "RENDERCANVAS_BACKEND", "RENDERCANVAS_FORCE_OFFSCREEN"):
        monkeypatch.delenv(var, raising=False)
    (tmp_path / "m.ply").write_bytes(b"")
    rc, _, err = run(["view", "--model", tmp_path / "m.ply", "--n", "3"], capsys)
    assert rc == 2 and "--n sets the primitives" in err
    for option in ("--model", "--cameras"):  # a missing file too (it was 3, no display)
        rc, _, err = run(["view", option, tmp_path / "missing.json"], capsys)
        assert rc == 2 and f"{option} {tmp_path / 'missing.json'}: no such file" in err, err
    cams = tmp_path / "CAMS.json"
    cams.write_text(json.dumps({"cameras": [c.to_json() for c in scene_cameras("spheres", 2, 64, 64)]}))
    monkeypatch.setenv("RENDERCANVAS_BACKEND", "offscreen")
    opened = []
    monkeypatch.setattr(viewer_window, "run_viewer", lambda *a, **k: opened.append(k["views"]) or 0)
    rc, _, err = run(["view", "--scene", "spheres", "--n", "300", "--cameras", cams, "--views", "5"], capsys)
    assert rc == 0 and len(opened[0]) == 2
    assert f"--views 5: {cams} holds 2, all rendered" in err


def test_scene_export_keeps_the_antialiased_flag(tmp_path, capsys):
    """A real capture flagged antialiased in its SPZ header keeps the flag when exported as SPZ,
    so reloading it still says so; loading the scene by name says so too."""
    from seuwgpu.model.formats.spz import read_spz

    rc, _, err = run(["scene", "leica-sofort", "--n", "64", "--out", tmp_path / "x.spz"], capsys)
    assert rc == 0, err
    assert read_spz(tmp_path / "x.spz")[1].antialiased
    assert any(n.startswith("trained antialiased") for n in read_model(tmp_path / "x.spz").notes)
    rc, _, err = run(["scene", "spheres", "--n", "64", "--out", tmp_path / "s.spz"], capsys)
    assert rc == 0 and not read_spz(tmp_path / "s.spz")[1].antialiased  # procedural: not flagged
    rc, _, err = run(["render", "--scene", "leica-sofort", "--n", "64", "--views", "1", "--size", "32x32",
                      "--out", tmp_path / "r"], capsys)  # fmt: skip
    assert rc == 0 and "seuwgpu: leica-sofort: trained antialiased (mip-splatting)" in err


@pytest.fixture
def console_signals():
    """console_main sets the SIGINT and SIGTERM handlers of the process: put back as they were."""
    import signal

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    yield
    signal.signal(signal.SIGINT, before[0])
    signal.signal(signal.SIGTERM, before[1])


def test_console_entry_ignores_ctrl_c_while_the_interpreter_shuts_down(monkeypatch, console_signals):
    """`seuwgpu` (and python -m seuwgpu) return main's status, then ignore SIGINT: an interrupt
    landing while a finished campaign's process shuts down killed it with SIGINT (exit -2)."""
    import signal

    from seuwgpu.apps.cli import console_main

    monkeypatch.setattr(sys, "argv", ["seuwgpu", "scene", "--list"])
    assert console_main() == 0
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN


def test_sigterm_stops_a_command_as_ctrl_c_does(monkeypatch, capsys, console_signals):
    """SIGTERM while a command runs raises Terminated (a KeyboardInterrupt) where it is, so the
    command ends as Ctrl-C ends it (records kept), with exit 143 and one line."""
    import os
    import signal

    from seuwgpu.apps import cli

    def job(args):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("SIGTERM did not stop the command")

    real = cli.build_parser

    def parser():
        p = real()
        p._subparsers._group_actions[0].choices["scene"].set_defaults(func=job)
        return p

    monkeypatch.setattr(cli, "build_parser", parser)
    monkeypatch.setattr(sys, "argv", ["seuwgpu", "scene", "--list"])
    assert cli.console_main() == 143
    assert capsys.readouterr().err.strip() == "seuwgpu scene: terminated (SIGTERM)"


@pytest.fixture(scope="module")
def spec_run(tmp_path_factory):
    """A finished run of SPEC (8 injections, 2 defenses)."""
    tmp = tmp_path_factory.mktemp("spec_run")
    (tmp / "spec.toml").write_text(SPEC)
    assert main(["campaign", str(tmp / "spec.toml"), "--out", str(tmp / "run"), "--quiet"]) == 0
    return tmp / "spec.toml", tmp / "run"


def test_rates_by_a_column_named_twice(spec_run, tmp_path, capsys):
    """`--by scene,scene` printed each row's whole Series repeated in a garbled table; a column named
    twice is one column."""
    import pandas as pd

    _, run_dir = spec_run
    assert main(["rates", str(run_dir), "--by", "scene", "--csv", str(tmp_path / "once.csv")]) == 0
    once = capsys.readouterr().out
    assert main(["rates", str(run_dir), "--by", "scene,scene", "--csv", str(tmp_path / "twice.csv")]) == 0
    twice = capsys.readouterr().out
    assert twice == once and "dtype" not in twice
    assert pd.read_csv(tmp_path / "twice.csv").equals(pd.read_csv(tmp_path / "once.csv"))


def test_a_signal_while_the_arguments_are_read_is_one_line(monkeypatch, capsys):
    """SIGTERM (or Ctrl-C) landing while main reads its arguments ends it as one while the command
    runs: exit 143 (130) and one line, no traceback."""
    from seuwgpu.apps import cli
    from seuwgpu.errors import Terminated

    for exc, code, said in ((Terminated, 143, "terminated (SIGTERM)"), (KeyboardInterrupt, 130, "interrupted")):

        def parser(exc=exc):
            raise exc()

        monkeypatch.setattr(cli, "build_parser", parser)
        assert cli.main(["info"]) == code
        assert capsys.readouterr().err.strip() == f"seuwgpu: {said}"


def test_up_axis_with_a_minus_sign_as_its_own_argument(tmp_path, capsys):
    """`--up -y`, the README's axis names written as two arguments, failed in argparse ('argument
    --up: expected one argument': a value starting with '-' reads as an option); it now renders
    the same frames as `--up=-y`."""
    args = ["render", "--scene", "spheres", "--n", "200", "--views", "1", "--size", "16x16"]
    rc, _, err = run([*args, "--up", "-y", "--out", tmp_path / "a.npz"], capsys)
    assert rc == 0, err
    rc, _, _ = run([*args, "--up=-y", "--out", tmp_path / "b.npz"], capsys)
    a, b = (np.load(tmp_path / f"{x}.npz")["images"] for x in "ab")
    assert rc == 0 and np.array_equal(a, b)
    rc, _, _ = run([*args, "--out", tmp_path / "c.npz"], capsys)  # the default (+z) frames otherwise
    assert not np.array_equal(a, np.load(tmp_path / "c.npz")["images"])


def test_an_unknown_option_is_the_commands_error(capsys):
    """README: a bad option prints the command's usage before one `seuwgpu CMD: error: ...` line
    (exit 2). An option no command knows was left to the top-level parser, which printed the list
    of commands and `seuwgpu: error: unrecognized arguments: ...`."""
    with pytest.raises(SystemExit) as e:
        main(["render", "--scene", "spheres", "--bogus", "1", "--out", "x"])
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert err.startswith("usage: seuwgpu render ")
    assert err.strip().splitlines()[-1] == "seuwgpu render: error: unrecognized arguments: --bogus 1"


def test_scene_options_beside_a_model_file_are_refused(tmp_path, capsys):
    """README: an option the others make meaningless is refused, not ignored. --sh-degree and
    --seed (help: "of an embedded scene") beside --model rendered the file unchanged, silently;
    --seed stays accepted where the command also draws from it (inject's sample, storm's upsets)."""
    from seuwgpu.apps.cli import build_parser, refuse_ignored_options
    from seuwgpu.model.formats import save_model

    ply = tmp_path / "m.ply"
    save_model(make_scene("spheres", n=200), ply)
    base = ["render", "--model", ply, "--views", "1", "--size", "16x16", "--out", tmp_path / "x.npz"]
    for option, why in (("--sh-degree", "--sh-degree sets the SH degree"), ("--seed", "--seed seeds an embedded")):
        rc, _, err = run([*base, option, "1"], capsys)
        assert rc == 2 and why in err, err
    assert not (tmp_path / "x.npz").exists()
    for cmd in (["inject", "--field", "opacity", "--bit", "30"], ["storm"], ["state"]):
        argv = [cmd[0], "--model", str(ply), *cmd[1:], "--seed", "5", "--out", "o"]
        refuse_ignored_options(build_parser().parse_args(argv))  # not refused
    rc, _, err = run(["render", "--scene", "spheres", "--n", "200", *base[3:], "--sh-degree", "1"], capsys)
    assert rc == 0, err  # an embedded scene takes both
    args = build_parser().parse_args(["render", "--scene", "spheres", "--out", "o"])
    assert args.sh_degree is None and args.seed is None  # an embedded scene's defaults: 3 and 0


def test_view_refuses_views_without_a_camera_file(capsys):
    """`view --views K` picks K views of a --cameras file (its help); without one it was ignored."""
    from seuwgpu.apps.cli import build_parser, refuse_ignored_options

    with pytest.raises(Exception, match="--views picks views of a --cameras file"):
        refuse_ignored_options(build_parser().parse_args(["view", "--scene", "spheres", "--views", "3"]))
    refuse_ignored_options(build_parser().parse_args(["view", "--scene", "spheres"]))
    refuse_ignored_options(build_parser().parse_args(["render", "--scene", "spheres", "--views", "3", "--out", "o"]))


@pytest.mark.parametrize("defense", ["parity4r", "ecc"])
def test_inject_save_model_writes_the_damage_and_each_repair(tmp_path, capsys, defense):
    """`inject --save-model DIR` of a PLY model writes PLY only (the source's format); faulted.ply
    read back differs from the clean model in exactly the flipped bit; DEFENSE.ply holds what the
    defense restored (parity4r reloads the primitive, ECC corrects the single flip: the clean model
    bit for bit), guard.ply the faulted value clamped into the clean model's [min, max] of that
    component (the support box) and nothing else changed."""
    from seuwgpu.model.formats import save_model

    clean_path = tmp_path / "clean.ply"
    save_model(make_scene("spheres", n=300, sh_degree=1), clean_path)
    clean = read_model(clean_path).model.flat()
    prim, comp, bit = 7, 3 + 1, 30  # log_scales[7][1]: its exponent's top bit
    argv = ["inject", "--model", clean_path, "--views", "1", "--size", "32x32", "--field", "log_scales",
            "--primitive", str(prim), "--component", "1", "--bit", str(bit), "--defense", defense,
            "--formats", "png", "--out", tmp_path / "o", "--save-model", tmp_path / "m"]  # fmt: skip
    rc, out, err = run(argv, capsys)
    assert rc == 0, err
    assert f"models: faulted.ply, {defense}.ply, guard.ply in" in out  # a PLY source: PLY only
    faulted = read_model(tmp_path / "m" / "faulted.ply").model.flat()
    assert np.isfinite(faulted).all()  # -2.0 turned into a denormal: an SPZ holds it (a NaN it cannot)
    diff = clean.view(np.uint32) ^ faulted.view(np.uint32)
    assert list(zip(*np.nonzero(diff))) == [(prim, comp)] and diff[prim, comp] == 1 << bit
    repaired = read_model(tmp_path / "m" / f"{defense}.ply").model.flat()
    assert np.array_equal(repaired.view(np.uint32), clean.view(np.uint32))
    guarded = read_model(tmp_path / "m" / "guard.ply").model.flat()
    want = clean.copy()
    want[prim, comp] = np.clip(faulted[prim, comp], clean[:, comp].min(), clean[:, comp].max())
    assert want[prim, comp] != faulted[prim, comp] and np.array_equal(guarded, want)
