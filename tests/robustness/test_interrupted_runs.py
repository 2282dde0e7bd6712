"""Campaign, storm and state runs killed, interrupted (Ctrl-C, SIGTERM) or started twice on one
folder, as real processes: a resumed run ends with the records of an uninterrupted one, a second
run beside a first one is refused, and a damaged or foreign partial file is replaced or refused.

Each case starts several `seuwgpu` processes (seconds each) and storm's and state's wait seconds
before their signal: minutes in all. They carry the `heavy` marker: `pytest -m heavy` runs them."""

from __future__ import annotations

import shutil
import signal

import pytest

from robustness.checks import file_exists, records_equal, same_results
from robustness.outcomes import SINGLE, assert_clear_error, assert_correct, expect_outcome, spec_text, table
from robustness.processes import beside_a_running_one, interrupt_once, interrupted_then_resumed, run

pytestmark = [pytest.mark.heavy, pytest.mark.slow]


# ---- campaigns ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def kill_spec(work):
    """A campaign in parts of 4 and its uninterrupted run (a process). The single upsets (72, in
    18 parts) are evaluated in one call and written together; the dose blocks (96 injections, 24
    parts, each a full render per injection and arm) one at a time over seconds: a signal after
    the first part lands mid-run."""
    spec = work / "kill.toml"
    single = table(
        "single",
        SINGLE,
        fields='["opacity", "log_scales"]',
        bits="[0, 30, 31]",
        samples="12",
        defenses='["none", "guard"]',
    )
    dose = table("dose", {"k": "[1, 3]", "repeats": "48", "defenses": '["none", "guard"]'})
    spec.write_text(spec_text(top={"views": "2", "size": '"48x48"'}, single=single, extra=dose))
    ref = work / "kill_ref"
    assert_correct(run(["campaign", spec, "--out", ref, "--quiet"]))
    return spec, ref


@pytest.mark.parametrize("delay", [0.0, 0.3, 0.6, 0.1, 0.45])
def test_a_campaign_killed_3_times_after_a_new_part_resumes(kill_spec, fresh, delay):
    spec, ref = kill_spec
    d = fresh("kill_")
    argv = ["campaign", spec, "--out", d, "--quiet"]
    assert_correct(interrupted_then_resumed(argv, signal.SIGKILL, delay, 3), records_equal(d, ref))


# SIGTERM stops a run as Ctrl-C does: exit 143, the part in hand written whole
@pytest.mark.parametrize("sig, times", [(signal.SIGINT, 1), (signal.SIGTERM, 2)], ids=["SIGINT", "2 x SIGTERM"])
def test_a_campaign_interrupted_then_resumed(kill_spec, fresh, sig, times):
    spec, ref = kill_spec
    d = fresh("kill_graceful")
    argv = ["campaign", spec, "--out", d, "--quiet"]
    assert_correct(interrupted_then_resumed(argv, sig, 0.0, times), records_equal(d, ref))


def test_a_second_campaign_while_the_first_runs(kill_spec, fresh):
    argv = ["campaign", kill_spec[0], "--out", fresh("busy"), "--quiet"]
    assert_clear_error(beside_a_running_one(argv), argv)


# ---- storm and state: partial records, resumed -------------------------------------------------
STORM = ["storm", "--scene", "spheres", "--n", "50", "--size", "16x16", "--k", "2", "--frames", "600"]
STATE = ["state", "--scene", "spheres", "--n", "50", "--views", "1", "--size", "16x16", "--samples", "8"]
RUNS = {"storm": [*STORM, "--defense", "none", "guard"], "state": STATE}


@pytest.fixture(scope="module")
def references(work):
    """name -> its uninterrupted run (work/NAME_ref), made on first use."""
    made = {}

    def reference(name: str):
        if name not in made:
            ref = work / f"{name}_ref"
            assert_correct(run([*RUNS[name], "--out", ref]), file_exists(ref / f"{name}.parquet"))
            made[name] = ref
        return made[name]

    return reference


@pytest.fixture(scope="module")
def interrupted(work):
    """copy(name, d): d holds an interrupted run of RUNS[name] (SIGINT 4 s after it took its
    lock, once it has measured a while; on a loaded host, where it had not yet measured
    anything, 8 or 16 s), made once per command and copied."""

    def copy(name: str, d):
        master = work / f"{name}_interrupted"
        partial = master / f"{name}.partial.parquet"
        for delay in (4.0, 8.0, 16.0):
            if partial.exists():
                break
            shutil.rmtree(master, ignore_errors=True)
            interrupt_once([*RUNS[name], "--out", master], signal.SIGINT, delay, "lock")
        assert partial.exists(), f"no interrupted {name} run to start from (SIGINT 4, 8, 16 s after its lock)"
        shutil.copytree(master, d)

    return copy


@pytest.mark.parametrize("name", list(RUNS))
@pytest.mark.parametrize(
    "sig, delay, times, after",
    [  # the lock is taken before the engine starts (about 2 s here): measuring starts later
        (signal.SIGINT, 4.0, 1, "lock"),
        (signal.SIGTERM, 3.5, 2, "lock"),
        (signal.SIGKILL, 0.3, 1, "save"),
    ],
    ids=["SIGINT mid-run", "2 x SIGTERM mid-run", "SIGKILL after a periodic save"],
)
def test_an_interrupted_run_resumes_to_the_uninterrupted_records(references, fresh, name, sig, delay, times, after):
    ref = references(name)
    d = fresh(f"{name}_kill")
    outcome = interrupted_then_resumed([*RUNS[name], "--out", d], sig, delay, times, after)
    assert_correct(outcome, same_results(d, ref, name))


@pytest.mark.parametrize("name", list(RUNS))
def test_a_second_run_while_the_first_runs(fresh, name):
    argv = [*RUNS[name], "--out", fresh(f"{name}_busy")]
    assert_clear_error(beside_a_running_one(argv), argv)


OTHER_ARGUMENTS = [
    ("storm", ["--k", "3"]),
    ("storm", ["--seed", "9"]),
    ("state", ["--samples", "9"]),
    ("state", ["--targets", "xy"]),
]


@pytest.mark.parametrize("name, extra", OTHER_ARGUMENTS, ids=[f"{n} {' '.join(e)}" for n, e in OTHER_ARGUMENTS])
def test_resuming_with_other_arguments_is_refused(interrupted, fresh, name, extra):
    d = fresh(f"{name}_other")
    interrupted(name, d)
    expect_outcome([*RUNS[name], *extra, "--out", d], "error")


def strip_run_meta(path):
    """Rewrite a partial file without the run's arguments in its metadata (as before they were kept)."""
    import pyarrow.parquet as pq

    from seuwgpu.campaign.partial import RUN_META

    t = pq.read_table(path)
    pq.write_table(
        t.replace_schema_metadata({k: v for k, v in (t.schema.metadata or {}).items() if k != RUN_META}), path
    )


DAMAGES = [  # two each, for time
    ("storm", "garbage", lambda p: p.write_bytes(b"PAR1 not a parquet file")),
    ("storm", "no run arguments (an older seuwgpu's)", strip_run_meta),
    ("state", "a 0-byte file", lambda p: p.write_bytes(b"")),
    ("state", "half of it", lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])),
]


@pytest.mark.parametrize("name, damage", [(n, f) for n, _, f in DAMAGES], ids=[f"{n}: {w}" for n, w, _ in DAMAGES])
def test_a_damaged_partial_file_is_replaced(references, interrupted, fresh, name, damage):
    ref = references(name)
    d = fresh(f"{name}_damaged")
    interrupted(name, d)
    damage(d / f"{name}.partial.parquet")
    outcome = run([*RUNS[name], "--out", d])
    assert_correct(outcome, same_results(d, ref, name), stderr_has="starting over (it is replaced)")


def test_a_storm_resumed_with_a_defense_named_twice_is_the_same_run(references, interrupted, fresh):
    ref = references("storm")
    d = fresh("storm_spelt")
    interrupted("storm", d)
    outcome = run([*STORM, "--defense", "none", "guard", "guard", "--out", d])
    assert_correct(outcome, same_results(d, ref, "storm"))


def test_a_storms_partial_file_as_states_is_refused(interrupted, fresh):
    d = fresh("state_swapped")
    interrupted("storm", d)
    (d / "storm.partial.parquet").rename(d / "state.partial.parquet")
    expect_outcome([*STATE, "--out", d], "error")
