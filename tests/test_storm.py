"""Fault storms (campaign/storm.py): accumulated upsets measured like one multi-upset injection,
scrubbing restarts the accumulation, reloading defenses keep every frame clean, memory restored."""

import numpy as np

from seuwgpu.campaign.storm import storm
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


def test_storm_command_runs_a_defense_named_twice_once(tmp_path):
    import pandas as pd

    from seuwgpu.apps.cli import main

    args = ["storm", "--scene", "blocks", "--n", "100", "--size", "16x16", "--k", "2", "--frames", "2"]
    assert main([*args, "--defense", "none", "none", "--out", str(tmp_path)]) == 0
    df = pd.read_parquet(tmp_path / "storm.parquet")
    assert len(df) == 2 and list(df.frame) == [0, 1]


def test_an_interrupted_storm_or_state_run_keeps_what_it_measured(tmp_path, monkeypatch, capsys):
    """Ctrl-C (here: a KeyboardInterrupt raised by the third measurement) ends the command with
    exit 130 after writing the records measured so far, equal to the first records of a whole run;
    a finished run removes the partial file."""
    import pandas as pd

    from seuwgpu.apps.cli import main
    from seuwgpu.faults.state import StateFaults

    def interrupt_third(patch, cls, name):
        real, calls = getattr(cls, name), []

        def wrapped(self, *a, **kw):
            calls.append(1)
            if len(calls) == 3:
                raise KeyboardInterrupt
            return real(self, *a, **kw)

        patch.setattr(cls, name, wrapped)

    common = ["--scene", "blocks", "--n", "100", "--size", "16x16", "--out", str(tmp_path)]
    storm_args = ["storm", *common, "--k", "2", "--frames", "4", "--defense", "none", "guard"]
    state_args = ["state", *common, "--samples", "2", "--targets", "xy", "--bit", "30", "31"]
    runs = {"storm": (storm_args, Engine, "measure_current"), "state": (state_args, StateFaults, "inject")}
    for name, (argv, cls, method) in runs.items():
        whole = tmp_path / f"{name}.parquet"
        assert main(argv) == 0
        want = pd.read_parquet(whole)
        whole.unlink()
        with monkeypatch.context() as patch:
            interrupt_third(patch, cls, method)
            assert main(argv) == 130
        assert "the 2 records measured so far" in capsys.readouterr().err
        part = pd.read_parquet(tmp_path / f"{name}.partial.parquet")
        pd.testing.assert_frame_equal(part, want.iloc[:2].reset_index(drop=True), check_dtype=False)
        assert not whole.exists()
        assert main(argv) == 0 and not (tmp_path / f"{name}.partial.parquet").exists()
