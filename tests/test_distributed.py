"""Scale-out on Ray (one machine, a local Ray instance, 2 workers on lavapipe): campaign records
equal the local executor's, a killed worker's shard is redone without loss or duplicates, the
sort-first composite equals the single-device render bit for bit, and a node-local guard contains
a scale sign-bit upset that otherwise contaminates every rank its footprint reaches."""

import dataclasses
import textwrap

import numpy as np
import pandas as pd
import pytest

from seuwgpu.apps.cli import run_campaign
from seuwgpu.campaign import ray as distributed
from seuwgpu.campaign import sortfirst
from seuwgpu.campaign.ray import ray_available
from seuwgpu.campaign.runner import Runner
from seuwgpu.campaign.schema import REPRODUCIBLE_COLUMNS
from seuwgpu.campaign.sortfirst import split_regions
from seuwgpu.campaign.spec import normalize_spec
from seuwgpu.campaign.store import read_records
from seuwgpu.render.regions import region_id_map

needs_ray = pytest.mark.skipif(
    not ray_available(), reason="ray is not importable (install the extra: pip install 'seuwgpu[ray]')"
)

SPEC = textwrap.dedent("""
    seed = 11
    views = 2
    size = "32x32"
    batch = 12

    [[scenes]]
    scene = "blocks"
    n = 1200

    [single]
    fields = ["log_scales", "opacity"]
    bits = [0, 23, 30, 31]
    samples = 6
    defenses = ["none", "guard"]

    [dose]
    k = [1, 20]
    repeats = 2
    defenses = ["none", "guard"]
""")


def canonical(df: pd.DataFrame) -> pd.DataFrame:
    # every column but the wall-clock ones (time_ms) is reproduced bit for bit
    return df.sort_values(["injection_id", "defense"]).reset_index(drop=True)[REPRODUCIBLE_COLUMNS]


@pytest.fixture(scope="module")
def spec():
    import tomllib

    return normalize_spec(tomllib.loads(SPEC))


@pytest.fixture(scope="module")
def local_records(spec, tmp_path_factory):
    out = tmp_path_factory.mktemp("local") / "run"
    Runner(spec, out, quiet=True).run()
    return canonical(read_records(out))


@pytest.fixture(scope="module")
def ray_instance():
    import ray

    started = distributed.init_ray(num_cpus=2)
    yield ray
    if started:
        ray.shutdown()


def test_regions_tile_the_frame():
    for ranks, (w, h), grid in [
        (4, (64, 64), (2, 2)),
        (16, (64, 64), (4, 4)),
        (4, (80, 48), (2, 2)),
        (3, (96, 40), (3, 1)),
        (6, (100, 70), (3, 2)),
    ]:
        regions, g = split_regions(ranks, w, h)
        assert g == grid and len(regions) == ranks
        cover = np.zeros((h, w), int)
        for x0, y0, rw, rh in regions:
            assert x0 % 16 == 0 and y0 % 16 == 0 and rw > 0 and rh > 0
            cover[y0 : y0 + rh, x0 : x0 + rw] += 1
        assert (cover == 1).all()
    with pytest.raises(ValueError, match="do not fit"):
        split_regions(5, 32, 32)
    # the contamination analysis counts exactly the regions the ranks render (one grid)
    for ranks, (w, h) in [(4, (80, 64)), (6, (128, 128)), (16, (128, 96)), (4, (50, 38))]:
        rid = region_id_map(ranks, h, w)
        for r, (x0, y0, rw, rh) in enumerate(split_regions(ranks, w, h)[0]):
            assert (rid[y0 : y0 + rh, x0 : x0 + rw] == r).all()


def test_without_ray_the_local_executor_runs_and_says_how_to_get_ray(
    spec, local_records, tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(distributed, "ray_available", lambda: False)
    small = dataclasses.replace(spec, dose=None)
    run_campaign(small, tmp_path / "run", executor="ray", quiet=True)
    err = capsys.readouterr().err
    assert "pip install 'seuwgpu[ray]'" in err and "local executor" in err
    got = canonical(read_records(tmp_path / "run"))
    want = local_records[local_records.campaign == "single"].reset_index(drop=True)
    pd.testing.assert_frame_equal(got, want)


@needs_ray
def test_ray_run_records_equal_the_local_run(ray_instance, spec, local_records, tmp_path):
    stats = distributed.run_ray(spec, tmp_path / "run", workers=2, quiet=True)
    assert stats["workers"] == 2 and stats["new"] == stats["total"] == local_records.injection_id.nunique()
    pd.testing.assert_frame_equal(canonical(read_records(tmp_path / "run")), local_records)
    import json

    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["executor"]["kind"] == "ray"
    # nothing left to do: a re-run schedules no task and rewrites nothing
    again = distributed.run_ray(spec, tmp_path / "run", workers=2, quiet=True)
    assert again["tasks"] == 0 and again["new"] == 0


@needs_ray
def test_a_killed_worker_has_its_shard_redone_without_loss_or_duplicates(ray_instance, spec, local_records, tmp_path):
    run = tmp_path / "run"
    Runner(spec, run, shard=(4, 5), quiet=True).run()  # a resumed run: the last of 5 blocks is already written
    pre = {p.name: p.stat().st_mtime_ns for p in (run / "records").glob("part-*.parquet")}
    flag = tmp_path / "killed"
    # two shards with two blocks to do each: the first task to write a part kills its worker mid-shard
    stats = distributed.run_ray(spec, run, workers=2, shards=2, quiet=True, _kill_once=str(flag))
    assert flag.exists(), "a worker should have been killed"
    parts = sorted((run / "records").glob("part-*.parquet"))
    assert len(parts) == len(list(Runner(spec, run).blocks()))
    assert all(p.stat().st_mtime_ns == pre[p.name] for p in parts if p.name in pre)  # skipped, not rewritten
    assert stats["new"] == stats["total"] - sum(int(n.split("-")[2][:6]) for n in pre)
    got = canonical(read_records(run))
    assert not got.duplicated(["injection_id", "defense"]).any()
    pd.testing.assert_frame_equal(got, local_records)


@pytest.fixture(scope="module")
def sort_first_run(ray_instance):
    from seuwgpu.model.scenes import make_scene, scene_cameras

    model = make_scene("spheres", n=3000)
    cams = scene_cameras("spheres", 2, 80, 64)  # 5x4 tiles: the 2x2 regions are uneven (32/48 px wide)
    res = sortfirst.sort_first(
        model, cams, "fp32", ranks=4, upset=("log_scales", (31,)), sample=8, guard="scrub", repeats=1
    )
    return model, cams, res


@needs_ray
def test_sort_first_composite_equals_the_single_device_render(sort_first_run):
    from seuwgpu.render.renderer import Renderer

    model, cams, res = sort_first_run
    full = Renderer(model, cams).render()
    assert res["composite"].shape == full.shape
    assert np.array_equal(res["composite"].view(np.uint32), full.view(np.uint32))
    assert len({i["pid"] for i in res["infos"]}) == 4  # four processes, four devices
    assert len(res["times"]) == 4 and res["imbalance"] >= 1.0 and res["times"][res["slowest"]] == max(res["times"])


@needs_ray
def test_node_local_guard_contains_a_scale_sign_upset(sort_first_run):
    _, _, res = sort_first_run
    s = res["site"]
    assert (s.field, s.bits) == ("log_scales", (31,)) and res["corrupted_value"] == -res["clean_value"]
    # unguarded, the blown-up primitive contaminates every rank its footprint reaches (here all of them)
    assert res["touched_none"] <= res["reach_upset"]
    assert res["touched_none"] == res["reach_upset"] == set(range(4))
    # each rank's own guard clamps its own copy; what is left stays inside the clamped footprint
    assert all(r["guard"]["clamps"] >= 1 for r in res["per_rank"])
    assert res["touched_guard"] <= res["reach_guarded"]
    assert len(res["touched_guard"]) < len(res["touched_none"])


@needs_ray
def test_an_address_where_nothing_listens_is_refused_at_once(tmp_path):
    """`--address HOST:PORT` with no cluster there: one line and exit 2 within seconds (Ray itself
    retried it for over ten minutes, printing a warning every few seconds)."""
    import os
    import socket
    import subprocess
    import sys

    with socket.socket() as s:  # a port nobody listens on once closed
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    env = {**os.environ, "XDG_RUNTIME_DIR": "/tmp"}
    for args in (
        ["campaign", str(spec), "--out", str(tmp_path / "run"), "--executor", "ray", "--quiet"],
        ["distributed", "--scene", "blocks", "--n", "200", "--size", "32x32", "--ranks", "2"],
    ):
        for address in (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}"):
            p = subprocess.run(
                [sys.executable, "-m", "seuwgpu", *args, "--address", address],
                capture_output=True,
                text=True,
                timeout=60,
                env=env,
            )
            assert p.returncode == 2, (args, address, p.stderr[-2000:])
            err = p.stderr.strip().splitlines()
            assert len(err) == 1 and address in err[0] and "cannot connect" in err[0], err


@needs_ray
def test_zero_workers_is_refused(tmp_path):
    """run_ray(workers=0) started a local Ray instance with no CPU, where its tasks waited forever;
    it is a ValueError, as --workers 0 is on the command line. In a fresh process: an instance
    already running in this one would serve the tasks."""
    import subprocess
    import sys

    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    code = (
        "import sys\n"
        "from seuwgpu.campaign.spec import load_spec\n"
        "from seuwgpu.campaign.ray import run_ray\n"
        "for w in (0, -1, 1.5):\n"
        "    try:\n"
        f"        run_ray(load_spec({str(spec)!r}), {str(tmp_path / 'run')!r}, workers=w, quiet=True)\n"
        "    except ValueError as e:\n"
        "        assert 'workers' in str(e), e\n"
        "    else:\n"
        "        sys.exit(f'workers={w} ran')\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr[-2000:]
    assert not (tmp_path / "run").exists()  # refused before anything was written


@needs_ray
def test_a_bad_upset_is_one_line_before_any_rank_starts(capsys):
    """`distributed --upset log_scales:32` (or a component the field lacks) without --primitive was
    refused by the first rank's worst-primitive search: exit 2, but a remote traceback as the
    message, after Ray and every rank had started."""
    from seuwgpu.apps.cli import main

    base = ["distributed", "--scene", "blocks", "--n", "200", "--size", "32x32", "--views", "1", "--repeats", "1"]
    for extra, why in (
        (["--upset", "log_scales:32"], "bit 32 is out of range for fp32"),
        (["--upset", "opacity:31", "--component", "3"], "component 3 is out of range for field opacity"),
        (["--upset", "log_scales:16", "--precision", "bf16", "--primitive", "3"], "bit 16 is out of range for bf16"),
    ):
        assert main(base + extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0], err


def test_init_ray_keeps_the_command_lines_sigterm_handler(monkeypatch):
    """ray.init sets a SIGTERM handler that calls sys.exit (exit 15, no orderly stop); init_ray
    puts back the one it found (the command line's: stop as Ctrl-C does, exit 143)."""
    import signal
    import types

    from seuwgpu.campaign import ray as ray_exec

    def rays_own(signum, frame):
        raise SystemExit(signum)

    def fake_init(**kw):
        signal.signal(signal.SIGTERM, rays_own)

    fake = types.SimpleNamespace(is_initialized=lambda: False, init=fake_init)
    monkeypatch.setattr(ray_exec, "get_ray", lambda: fake)

    def ours(signum, frame):
        pass

    before = signal.signal(signal.SIGTERM, ours)
    try:
        assert ray_exec.init_ray(num_cpus=1) is True
        assert signal.getsignal(signal.SIGTERM) is ours
    finally:
        signal.signal(signal.SIGTERM, before)


def test_ctrl_c_while_ray_starts_stops_the_started_node(monkeypatch):
    """Ctrl-C during ray.init (a terminal's SIGINT) takes effect once the node has started, and
    that node is shut down, so no Ray agent is left orphaned; a second Ctrl-C stops at once."""
    import os
    import signal
    import types

    from seuwgpu.campaign import ray as ray_exec

    events = []

    def fake_init(**kw):
        os.kill(os.getpid(), signal.SIGINT)  # delivered between bytecodes, inside init
        for _ in range(1000):
            pass
        events.append("init done")

    fake = types.SimpleNamespace(
        is_initialized=lambda: False, init=fake_init, shutdown=lambda: events.append("shutdown")
    )
    monkeypatch.setattr(ray_exec, "get_ray", lambda: fake)
    with pytest.raises(KeyboardInterrupt):
        ray_exec.init_ray(num_cpus=1)
    assert events == ["init done", "shutdown"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler

    def init_twice(**kw):
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):
            pass
        events.append("init done")

    events.clear()
    fake.init = init_twice
    with pytest.raises(KeyboardInterrupt):
        ray_exec.init_ray(num_cpus=1)
    assert events == [] and signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_ctrl_c_while_ray_starts_keeps_the_command_lines_sigterm_handler(monkeypatch):
    """ray.init replaces the SIGTERM handler; init_ray puts the caller's back, also when a Ctrl-C
    during ray.init stops the start (the restore came after the interrupt, so Ray's sys.exit
    handler stayed installed for the rest of the process)."""
    import os
    import signal
    import types

    from seuwgpu.campaign import ray as ray_exec

    def rays_own(signum, frame):
        raise SystemExit(signum)

    def fake_init(**kw):
        signal.signal(signal.SIGTERM, rays_own)
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):
            pass

    fake = types.SimpleNamespace(is_initialized=lambda: False, init=fake_init, shutdown=lambda: None)
    monkeypatch.setattr(ray_exec, "get_ray", lambda: fake)

    def ours(signum, frame):
        pass

    before = signal.signal(signal.SIGTERM, ours)
    try:
        with pytest.raises(KeyboardInterrupt):
            ray_exec.init_ray(num_cpus=1)
        assert signal.getsignal(signal.SIGTERM) is ours
    finally:
        signal.signal(signal.SIGTERM, before)
