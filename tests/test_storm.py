"""Fault storms (campaign/storm.py): accumulated upsets measured like one multi-upset injection,
scrubbing restarts the accumulation, reloading defenses keep every frame clean, memory restored."""

import numpy as np
import pytest

from seuwgpu.campaign.storm import storm
from seuwgpu.faults import schedule
from seuwgpu.faults.engine import Engine
from seuwgpu.faults.sites import draw_uniform_sites
from seuwgpu.model.scenes import make_scene, scene_cameras


def test_storm_accumulates_scrubs_and_restores():
    model = make_scene("blocks", n=200, seed=4)
    eng = Engine(model, scene_cameras("blocks", 1, 32, 32), "fp32", scene="blocks")
    words = [eng.renderer.read_words(c).copy() for c in range(eng.layout.n_chunks)]
    k, frames, seed = 40, 4, 9
    df = storm(eng, k, frames, scrub_every=3, defenses=("none", "checksum", "guard"), seed=seed)
    rng = np.random.default_rng(seed)
    ups = [draw_uniform_sites(eng.n, eng.degree, "fp32", k, rng) for _ in range(frames)]
    none = df[df.defense == "none"].set_index("frame")
    for f, since in ((0, 0), (1, 0), (2, 0), (3, 3)):  # scrub before frame 3
        sites = [s for g in range(since, f + 1) for s in ups[g]]
        want = eng.inject(sites, "none")
        assert none.loc[f, "footprint"] == want["footprint"]
        assert none.loc[f, "psnr"] == want["psnr"] or (np.isnan(want["psnr"]) and np.isnan(none.loc[f, "psnr"]))
    assert none.loc[2, "corrupted_primitives"] >= none.loc[0, "corrupted_primitives"] > 0
    chk = df[df.defense == "checksum"]
    assert (chk.footprint == 0).all() and np.isinf(chk.psnr).all()
    guard = df[df.defense == "guard"].set_index("frame")
    want = eng.inject([s for g in range(3) for s in ups[g]], "guard")
    assert guard.loc[2, "footprint"] == want["footprint"]
    for c, w in enumerate(words):
        np.testing.assert_array_equal(eng.renderer.read_words(c), w)


def test_storm_command_writes_records_and_plot(tmp_path, capsys):
    import pandas as pd

    from seuwgpu.apps.cli import main

    args = ["storm", "--scene", "blocks", "--n", "300", "--size", "32x32", "--k", "5", "--frames", "3"]
    assert main([*args, "--scrub-every", "2", "--defense", "none", "parity4r", "--out", str(tmp_path)]) == 0
    df = pd.read_parquet(tmp_path / "storm.parquet")
    assert len(df) == 6 and set(df.defense) == {"none", "parity4r"} and (tmp_path / "storm.png").stat().st_size
    assert main([*args, "--scrub-every", "-1", "--out", str(tmp_path)]) == 2
    assert "scrub_every >= 0" in capsys.readouterr().err
    out = tmp_path / "every2"
    assert main([*args, "--check-every", "2", "--defense", "none", "parity4r", "--out", str(out)]) == 0
    df = pd.read_parquet(out / "storm.parquet")
    assert set(df.loc[df.defense == "parity4r", "check_every"]) == {2} and set(
        df.loc[df.defense == "none", "check_every"]
    ) == {0}


def test_a_storm_too_long_for_host_memory_is_refused_at_once(monkeypatch):
    """--frames 1000000000 drew every frame's upsets before the first render: minutes of a silent
    hang, then a MemoryError; now refused at once saying how many frames fit."""
    from types import SimpleNamespace

    import pytest

    from seuwgpu.errors import TooBig

    monkeypatch.setenv("SEUWGPU_HOST_MEMORY", str(10**9))
    eng = SimpleNamespace(n=200, degree=0, precision="fp32")
    with pytest.raises(TooBig, match=r"1,000,000,000 frames .* at most [\d,]+ frames fit"):
        storm(eng, 1, 10**9, 10, ("none", "guard"))
    with pytest.raises(ValueError, match="exceeds the model's"):  # k over the stored bits: that error first
        storm(eng, 10**9, 10**9, 10, ("none",))


def test_storm_command_refuses_a_defense_named_twice(tmp_path):
    """A defense named twice was merged into one arm; it is refused, as the API and a spec refuse
    it (tests/test_checks.py), before anything is written."""
    import pandas as pd

    from seuwgpu.apps.cli import main

    args = ["storm", "--scene", "blocks", "--n", "100", "--size", "16x16", "--k", "2", "--frames", "2"]
    assert main([*args, "--defense", "none", "none", "--out", str(tmp_path / "s")]) == 2
    assert not (tmp_path / "s").exists()
    assert main([*args, "--defense", "none", "--out", str(tmp_path / "s")]) == 0
    df = pd.read_parquet(tmp_path / "s" / "storm.parquet")
    assert len(df) == 2 and list(df.frame) == [0, 1]


def test_a_resumed_storm_draws_and_replays_what_an_uninterrupted_one_did(monkeypatch):
    """A storm given the first m records of a run (a resumed one) renders only the others, and
    its records equal the uninterrupted run's: the same upsets drawn, the measured frames' upsets,
    repairs (parity4r) and scrubs replayed into the memory state without rendering them."""
    import pandas as pd
    import pytest

    model = make_scene("blocks", n=200, seed=4)
    eng = Engine(model, scene_cameras("blocks", 1, 32, 32), "fp32", scene="blocks")
    args = (eng, 30, 4, 3, ("none", "parity4r", "guard"), 9)
    whole = storm(*args)
    assert whole.footprint.nunique() > 4  # frames that differ: a wrong replay would show
    real, calls = Engine.measure_current, []
    monkeypatch.setattr(Engine, "measure_current", lambda self, d: calls.append(d) or real(self, d))
    for m in (1, 5, 6, 11, 12):  # in the first arm, mid-arm after a scrub, at an arm's end, the last, all
        calls.clear()
        got = storm(*args, rows=whole.iloc[:m].to_dict("records"))
        assert len(calls) == len(whole) - m
        pd.testing.assert_frame_equal(got, whole)
    with pytest.raises(ValueError, match="13 records given for a storm of 12"):
        storm(*args, rows=[{}] * 13)


def run_counting(patch, cls, name, stop_at=None, check=None):
    """Count calls of cls.name; the call numbered stop_at runs `check` then raises KeyboardInterrupt."""
    real, calls = getattr(cls, name), []

    def wrapped(self, *a, **kw):
        calls.append(1)
        if len(calls) == stop_at:
            if check:
                check()
            raise KeyboardInterrupt
        return real(self, *a, **kw)

    patch.setattr(cls, name, wrapped)
    return calls


def storm_and_state_runs(tmp_path):
    from seuwgpu.faults.state import StateFaults

    common = ["--scene", "blocks", "--n", "100", "--size", "16x16", "--out", str(tmp_path)]
    storm_args = ["storm", *common, "--k", "3", "--frames", "3", "--defense", "none", "guard"]
    state_args = ["state", *common, "--samples", "3", "--targets", "xy", "--bit", "30", "31"]
    return {"storm": (storm_args, Engine, "measure_current"), "state": (state_args, StateFaults, "inject")}


def test_an_interrupted_storm_or_state_run_resumes(tmp_path, monkeypatch, capsys):
    """Ctrl-C (here: a KeyboardInterrupt raised by the third measurement) ends the command with
    exit 130 after writing the records measured so far, the first records of a whole run; the
    same command then resumes: interrupted again (mid-arm for storm), then to the end, it measures
    only what is missing and writes the whole run's records, and removes the partial file. The
    partial file is also written while the run goes (here after every record), so a
    killed run keeps it."""
    import pandas as pd

    from seuwgpu.apps.cli import main
    from seuwgpu.campaign import partial

    monkeypatch.setattr(partial, "SAVE_EVERY_S", 0.0)
    monkeypatch.setattr(partial, "WRITE_SHARE", 0)
    for name, (argv, cls, method) in storm_and_state_runs(tmp_path).items():
        whole, part = tmp_path / f"{name}.parquet", tmp_path / f"{name}.partial.parquet"
        assert main(argv) == 0 and not part.exists()
        want = pd.read_parquet(whole)
        assert len(want) == 6
        whole.unlink()

        def written_before_the_interrupt(part, done):  # what a kill -9 would leave
            assert len(pd.read_parquet(part)) == done

        for done in (2, 4):  # measured before each interrupt
            with monkeypatch.context() as patch:
                run_counting(patch, cls, method, 3, lambda p=part, d=done: written_before_the_interrupt(p, d))
                assert main(argv) == 130
            err = capsys.readouterr().err
            assert f"the {done} records measured so far are in {part} (re-run the same command to resume)" in err
            pd.testing.assert_frame_equal(pd.read_parquet(part), want.iloc[:done], check_dtype=False)
            assert not whole.exists()
        with monkeypatch.context() as patch:
            calls = run_counting(patch, cls, method)
            assert main(argv) == 0
        assert len(calls) == 2 and not part.exists()
        pd.testing.assert_frame_equal(pd.read_parquet(whole), want)


def test_a_partial_run_of_other_arguments_is_refused(tmp_path, monkeypatch, capsys):
    """A re-run with other record-changing arguments into a folder holding an interrupted run is
    refused in one line naming what differs (exit 2), before any rendering; the partial file is
    left as it was. An unreadable partial file (or one without its arguments) is replaced."""
    from seuwgpu.apps.cli import main

    other = {"storm": ["--k", "4", "--seed", "1"], "state": ["--bit", "30"]}
    for name, (argv, cls, method) in storm_and_state_runs(tmp_path).items():
        part = tmp_path / f"{name}.partial.parquet"
        with monkeypatch.context() as patch:
            run_counting(patch, cls, method, 3)
            assert main(argv) == 130
        capsys.readouterr()
        before = part.read_bytes()
        with monkeypatch.context() as patch:
            calls = run_counting(patch, cls, method)
            assert main([*argv, *other[name]]) == 2
        assert not calls and part.read_bytes() == before and not (tmp_path / f"{name}.parquet").exists()
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"seuwgpu {name}: error: {part} holds an interrupted")
        differs = {"storm": "(--seed 0 there, 1 now; --k 3 there, 4 now)", "state": "(--bit 30 31 there, 30 now)"}
        assert differs[name] in err[0] and f"or use another --out, or delete {part} to start over" in err[0]
        part.write_bytes(b"not parquet")
        assert main(argv) == 0 and not part.exists()
        assert "unreadable; starting over" in capsys.readouterr().err


def test_up_naming_the_default_axis_resumes_the_same_run(tmp_path, monkeypatch, capsys):
    """The run's identity holds the up axis that frames the orbit views, not the --up given: a
    run with `--up +z` (the embedded scene's own axis) is resumed without it, and one with
    --cameras (which frames nothing) whatever --up says. Spelled as given, the harmless re-run
    was refused ('--up +z there, unset now')."""
    from seuwgpu.apps.cli import main
    from seuwgpu.model.cameras import orbit_cameras, save_cameras

    argv, cls, method = storm_and_state_runs(tmp_path)["storm"]
    cams = tmp_path / "cams.json"
    save_cameras(orbit_cameras(1, 16, 16), cams)
    with_cameras = [*argv[: argv.index("--size")], *argv[argv.index("--size") + 2 :], "--cameras", str(cams)]
    for first, again in ((["--up=+z"], []), (["--up=+x"], ["--up=-y"])):
        run = with_cameras if first == ["--up=+x"] else argv
        with monkeypatch.context() as patch:
            run_counting(patch, cls, method, 3)
            assert main([*run, *first]) == 130
        with monkeypatch.context() as patch:
            calls = run_counting(patch, cls, method)
            assert main([*run, *again]) == 0, capsys.readouterr().err
        assert len(calls) == 4 and not (tmp_path / "storm.partial.parquet").exists()
        capsys.readouterr()


def test_one_storm_or_state_run_per_folder_at_a_time(tmp_path, monkeypatch, capsys):
    """While a run holds the folder (its flock), another run of the command there is refused in
    one line before it reads the partial file or renders; the lock is released when a run ends,
    interrupted or finished, so the next run goes ahead."""
    from seuwgpu.apps.cli import main
    from seuwgpu.campaign.store import lock

    for name, (argv, cls, method) in storm_and_state_runs(tmp_path).items():
        with lock(tmp_path, command=name), monkeypatch.context() as patch:
            calls = run_counting(patch, cls, method)
            assert main(argv) == 2
        assert not calls
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"is in use: a `seuwgpu {name}` run (pid " in err[0]
        with monkeypatch.context() as patch:
            run_counting(patch, cls, method, 2)
            assert main(argv) == 130  # interrupted: the lock is released all the same
        assert main(argv) == 0 and not (tmp_path / f"{name}.partial.parquet").exists()
        with lock(tmp_path, command=name):  # and after a finished run
            pass
        capsys.readouterr()


def test_a_check_schedule_shows_each_upset_for_its_exposure():
    """A hand-made schedule: two catastrophic upsets (frames 1 and 5) under a check every 4
    frames (before frames 0, 4): parity4r draws each corrupted until the next check, so its
    catastrophic frames are exactly defenses.exposure's (3 + 3) and at the frames it names; with
    no defense and no scrub they stay (frames 1..7)."""

    model = make_scene("blocks", n=200, seed=4)
    eng = Engine(model, scene_cameras("blocks", 1, 32, 32), "fp32", scene="blocks")
    big = np.argsort(model.opacity)[::-1]
    a, b = eng.site("log_scales", int(big[0]), 0, 30), eng.site("log_scales", int(big[1]), 1, 30)
    assert eng.inject(a)["catastrophic"] and eng.inject(b)["catastrophic"]
    plan = [[], [a], [], [], [], [b], [], []]
    df = storm(eng, 1, 8, scrub_every=0, defenses=("none", "parity4r"), check_every=4, upsets=plan)
    cat = {d: set(g.loc[g.catastrophic, "frame"]) for d, g in df.groupby("defense")}
    assert cat["none"] == set(range(1, 8))
    assert cat["parity4r"] == {1, 2, 3, 5, 6, 7}
    assert len(cat["parity4r"]) == schedule.exposure(4, [1, 5]).per_upset.sum()
    assert (df[df.defense == "parity4r"].check_every == 4).all() and (df[df.defense == "none"].check_every == 0).all()
    every = storm(eng, 1, 8, scrub_every=0, defenses=("parity4r",), check_every=1, upsets=plan)
    assert not every.catastrophic.any()  # checked before every frame: exposure 0
    # checked inside every frame: the upset's frame drops the primitive (these two are the scene's
    # most opaque splats: at 32x32 their absence alone changes over 1% of the pixels), the next
    # frame is repaired: never more than the upset's own frame
    infr = storm(eng, 1, 8, scrub_every=0, defenses=("parity4f",), check_every=4, upsets=plan).set_index("frame")
    assert set(infr.index[infr.catastrophic]) <= {1, 5}
    assert list(infr.corrupted_primitives) == [0, 1, 0, 0, 0, 1, 0, 0]  # corrupted only in its own frame


def test_a_storm_of_multi_cell_upsets_defeats_parity4r_and_not_the_checksum():
    """fault="mcu_prim": each upset flips one bit in two values of a primitive. parity4r's ways
    each see the bit twice and detect none, so every primitive hit stays corrupted; the checksum
    reloads every one before the frame is drawn (each frame equals the clean render)."""
    from seuwgpu.campaign.storm import shape_upsets

    model = make_scene("blocks", n=200, seed=4)
    eng = Engine(model, scene_cameras("blocks", 1, 32, 32), "fp32", scene="blocks")
    k, frames, seed = 6, 2, 3
    df = storm(eng, k, frames, 0, defenses=("parity4r", "checksum"), seed=seed, fault="mcu_prim")
    rng = np.random.default_rng(seed)
    ups = [draw_uniform_sites(eng.n, eng.degree, "fp32", k, rng) for _ in range(frames)]
    shaped = [shape_upsets(u, "mcu_prim", eng.n, eng.degree, "fp32", rng) for u in ups]
    assert all(len(s) == 2 * k for s in shaped)
    hit = {s.primitive for f in shaped for s in f}
    p4 = df[df.defense == "parity4r"].set_index("frame")
    assert p4.loc[frames - 1, "corrupted_primitives"] == len(hit)
    chk = df[df.defense == "checksum"].set_index("frame")  # corrupted before the check: that frame's only
    assert chk.loc[frames - 1, "corrupted_primitives"] == len({s.primitive for s in shaped[-1]})
    assert (chk.peak_error == 0).all() and (p4.peak_error > 0).any()


def test_the_run_identity_names_files_by_content_and_the_resolved_up(tmp_path):
    """campaign/partial.py run_identity (what the CLI's storm and state resume by, and what an API
    user's own resumable loop can use): an embedded scene by its name, size and degree; a model
    file by the sha256 of its content, whatever path reaches it; the up axis as resolved."""
    import hashlib
    import shutil

    from seuwgpu.campaign.partial import run_identity
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.sources import load_source

    src = load_source(scene="blocks", n=50)
    views = [None, None]
    common = {"sh_degree": 3, "seed": 0, "size": (16, 24), "scale": None, "precision": "fp32", "profile": "strict"}
    run = run_identity("storm", src, views, **common, k=3)
    assert run == {
        "command": "storm",
        "model": None,
        "scene": "blocks",
        "n": 50,
        "sh-degree": 3,
        "seed": 0,
        "up": "+z",
        "cameras": None,
        "views": 2,
        "size": "16x24",
        "scale": 1.0,
        "precision": "fp32",
        "profile": "strict",
        "k": 3,
    }
    save_model(src.model, tmp_path / "m.ply")
    (tmp_path / "other").mkdir()
    shutil.copy(tmp_path / "m.ply", tmp_path / "other" / "m.ply")
    sha = "sha256:" + hashlib.sha256((tmp_path / "m.ply").read_bytes()).hexdigest()
    for path in (tmp_path / "m.ply", tmp_path / "other" / "m.ply"):
        run = run_identity("state", load_source(path=path), views, model=path, **common)
        assert run["model"] == sha and run["scene"] is None and run["n"] is None and run["sh-degree"] is None


def test_an_interrupted_visible_damage_measurement_resumes(tmp_path, monkeypatch, capsys):
    """`defenses --visible N --out RUN` keeps its frames as it goes: interrupted in the unguarded
    arm, then in the parity2f arm, it resumes each time after the frames it holds, renders only
    the missing ones, and keeps the per-upset records an uninterrupted run keeps (the partial
    file removed)."""
    import pandas as pd

    from seuwgpu.apps.cli import main
    from seuwgpu.campaign import partial
    from seuwgpu.campaign import storm as storm_module

    monkeypatch.setattr(partial, "SAVE_EVERY_S", 0.0)
    monkeypatch.setattr(partial, "WRITE_SHARE", 0)
    argv = ["defenses", "--scene", "blocks", "--n", "100", "--size", "16x16", "--no-time", "--json"]
    argv += ["--visible", "3", "--window", "4", "--check-every", "2", "--visible-defenses", "none", "parity2f"]
    argv += ["--out", str(tmp_path)]
    part = tmp_path / "defenses-visible.partial.parquet"
    assert main(argv) == 0 and not part.exists()
    (kept,) = (tmp_path / "visible").glob("*.parquet")
    want = pd.read_parquet(kept).drop(columns="date")
    kept.unlink()
    for stop, done in ((5, 4), (12, 15)):  # the 5th frame of the first arm, the 3rd of the second
        with monkeypatch.context() as patch:
            patch.setattr(storm_module, "REUSE_DRAWN", False)  # a render a frame: the stop's frame known
            run_counting(patch, Engine, "measure_current", stop)
            assert main(argv) == 130
        assert f"the {done} records measured so far are in {part}" in capsys.readouterr().err
        assert len(pd.read_parquet(part)) == done and not kept.exists()
    with monkeypatch.context() as patch:
        calls = run_counting(patch, Engine, "measure_current")
        assert main(argv) == 0
    assert 0 < len(calls) <= 24 - 15 and not part.exists()  # the missing frames at most
    pd.testing.assert_frame_equal(pd.read_parquet(kept).drop(columns="date"), want)


def test_frames_that_draw_the_same_state_take_its_metrics_and_equal_rendering_each():
    """A visible-damage measurement (one upset a window, held until the reload) renders only the
    frames whose drawn state is new: its frame records equal those of rendering every frame
    (REUSE_DRAWN off), with far fewer renders."""
    import pandas as pd

    from seuwgpu.campaign import storm as storm_module
    from seuwgpu.campaign.visible import visible_damage

    eng = Engine(make_scene("blocks", n=100), scene_cameras("blocks", 1, 16, 16))
    runs = {}
    for kept in (True, False):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(storm_module, "REUSE_DRAWN", kept)
            calls = run_counting(patch, Engine, "measure_current")
            _, recs = visible_damage(eng, ("none", "parity2f", "guard"), 2, upsets=6, window=8, seed=3)
        runs[kept] = (recs, len(calls))
    (memo, memo_calls), (every, every_calls) = runs[True], runs[False]
    assert every_calls == 6 * 8 * 3 and memo_calls < every_calls / 2
    pd.testing.assert_frame_equal(memo, every)
    assert memo["catastrophic"].any()  # the upsets drew something
    # one primitive upset again with other bits, then flipped back: each frame draws anew
    from seuwgpu.faults.sites import Site

    scale = [Site("log_scales", 5, 0, (b,)) for b in (30, 29, 30)]
    plan = [[scale[0]], [], [scale[1]], [], [scale[2]], [Site("log_scales", 5, 0, (29,))], []]
    runs = {}
    for kept in (True, False):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(storm_module, "REUSE_DRAWN", kept)
            runs[kept] = storm(eng, 1, len(plan), 0, ("none",), upsets=plan)
    pd.testing.assert_frame_equal(runs[True], runs[False])
    assert runs[True]["footprint"].iloc[-1] == 0 and len(set(runs[True]["footprint"].iloc[:5])) > 1
