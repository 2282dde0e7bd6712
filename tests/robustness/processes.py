"""Running `seuwgpu` as a real process, interrupting it (a signal some time after a sign of
progress) and starting a second one beside it: what the kill-and-resume tests need."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from robustness.outcomes import Outcome
from seuwgpu.campaign import store

ROOT = Path(__file__).resolve().parents[2]
GRACEFUL = {signal.SIGINT: (130, b"interrupted"), signal.SIGTERM: (143, b"terminated (SIGTERM)")}


def command(argv) -> list[str]:
    return [sys.executable, "-m", "seuwgpu", *[str(a) for a in argv]]


def default_sigint():
    """A process started from one that ignores SIGINT (a shell's background job) would ignore it
    too, and the SIGINT tests would test nothing."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(argv) -> subprocess.Popen:
    return subprocess.Popen(
        command(argv), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=default_sigint
    )


def run(argv, timeout: float = 300) -> Outcome:
    try:
        p = subprocess.run(
            command(argv), cwd=ROOT, capture_output=True, text=True, timeout=timeout, preexec_fn=default_sigint
        )
    except subprocess.TimeoutExpired:
        return Outcome(None, "", "", timeout=True)
    return Outcome(p.returncode, p.stdout, p.stderr, "Traceback" in p.stderr)


def out_dir(argv) -> Path:
    return Path(argv[list(argv).index("--out") + 1])


def holds_lock(folder: Path, name: str, pid: int) -> bool:
    """Whether process `pid` holds a storm's or state's lock on `folder` (the lock file names the
    process that took it; the file stays when its run ends)."""
    try:
        return (folder / f".lock-{name}").read_text().startswith(f"pid {pid} ")
    except OSError:
        return False


def progress_sign(argv, after: str, proc, started: float, parts_before: int) -> bool:
    """Whether the run `proc` shows what a kill waits for: "part" (a campaign wrote a new part),
    "lock" (a storm or state run holds its folder: it is past its arguments and loading), "save"
    (a storm or state run rewrote its partial file while running, every 10 s)."""
    name, folder = str(argv[0]), out_dir(argv)
    if after == "lock":
        return holds_lock(folder, name, proc.pid)
    if after == "save":
        partial = folder / f"{name}.partial.parquet"
        return partial.exists() and partial.stat().st_mtime >= started
    return folder.exists() and len(store.part_files(folder)) > parts_before


def interrupt_once(argv, sig, delay: float, after: str = "part") -> tuple[int, bytes, bool]:
    """Run argv and send it `sig` `delay` s after its sign of progress: (exit status, stderr,
    whether it had ended before the signal)."""
    folder = out_dir(argv)
    before = len(store.part_files(folder)) if folder.exists() else 0
    started = time.time()
    proc = start(argv)
    while proc.poll() is None and time.time() - started < 120:
        if progress_sign(argv, after, proc, started, before):
            break
        time.sleep(0.02)
    time.sleep(delay)
    ended = proc.poll() is not None
    if not ended:
        proc.send_signal(sig)
    _, e = proc.communicate(timeout=60)
    return proc.returncode, e, ended


def kept_after(argv) -> str:
    """A fault in what an interrupted run left, or "": a campaign's parts must all be whole, a
    storm's or state's partial file readable (pyarrow)."""
    name, folder = str(argv[0]), out_dir(argv)
    if name in ("storm", "state"):
        partial = folder / f"{name}.partial.parquet"
        unreadable = partial.exists() and store.part_rows(partial) is None  # its Parquet footer
        return f"{partial.name} unreadable after the interrupt" if unreadable else ""
    parts = store.part_files(folder) if folder.exists() else []
    broken = [p.name for p in parts if not store.part_rows(p)]
    return f"damaged parts after the interrupt: {broken}" if broken else ""


def left_work(argv) -> bool:
    """Whether the run in argv's folder has something left to do: a campaign's parts not all
    written, a storm's or state's records not yet final."""
    name, folder = str(argv[0]), out_dir(argv)
    if name in ("storm", "state"):
        return not (folder / f"{name}.parquet").exists()
    manifest = store.read_manifest(folder)
    if manifest is None:
        return True
    want = store.expected_parts(manifest["spec"])
    return len(store.completed_parts(folder, want)) < len(want)


def interrupted_then_resumed(argv, sig, delay: float, times: int, after: str = "part") -> Outcome:
    """Interrupt `times` runs of argv, each `delay` s after its sign of progress, checking what
    each left; then run it to the end. A graceful signal (SIGINT, SIGTERM) must end a run with its
    exit status and message, or let it end well. At least one interrupt must leave work to resume:
    a case whose signals all come after the run's end would test nothing."""
    cut_short = 0
    for _ in range(times):
        rc, e, _ = interrupt_once(argv, sig, delay, after)
        assert b"Traceback" not in e, e.decode()
        cut_short += left_work(argv)
        if sig in GRACEFUL:
            code, said = GRACEFUL[sig]
            assert rc in (0, code), f"exit {rc} after {signal.Signals(sig).name}: {e.decode()[-500:]}"
            if rc == code:
                assert said in e, f"{signal.Signals(sig).name} without the '{said.decode()}' message: {e.decode()}"
                fault = kept_after(argv)
                assert not fault, fault
    assert cut_short, f"every {signal.Signals(sig).name} came after the run had done its work: nothing was resumed"
    return run(argv)


def beside_a_running_one(argv, timeout: float = 300) -> Outcome:
    """Start argv, and once it holds its folder, argv again: the second one's outcome."""
    first = start(argv)
    folder, name = out_dir(argv), str(argv[0])
    t0 = time.time()
    while time.time() - t0 < 60 and first.poll() is None:
        if name in ("storm", "state"):
            if holds_lock(folder, name, first.pid):
                break
        elif (folder / "manifest.json").exists():
            break
        time.sleep(0.1)
    second = run(argv, timeout)
    first.kill()
    first.communicate()
    return second
