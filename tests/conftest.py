import contextlib
import os
import threading

import numpy as np
import pytest

os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")


def pytest_collection_modifyitems(config, items):
    """`heavy` tests run only when the marker expression names them (`-m heavy`): they take
    minutes, more than CI's budget for the whole suite allows."""
    if "heavy" in (config.getoption("markexpr") or ""):
        return
    skip = pytest.mark.skip(reason="minutes of processes or memory: run with -m heavy")
    for item in items:
        if item.get_closest_marker("heavy"):
            item.add_marker(skip)


@pytest.fixture(scope="session")
def gpu():
    from seuwgpu.gpu.device import get_gpu

    return get_gpu()


@contextlib.contextmanager
def undrawn_report_figures():
    """Reports built in the block make every figure (its data, artists and caption) and write its
    file, but do not rasterise it: the PNG is a 1x1 stub. For tests of a report's tables, numbers
    and file lists, where drawing was ~40% of a small report's build. Figures are drawn for real by
    test_report.py::test_end_to_end_report, test_report_profiles.py's
    test_profiles_get_their_own_table_and_the_rest_rests_on_strict (records and folded) and
    test_report_browser.py (which loads them in Chromium)."""
    from seuwgpu.report import build

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(build, "_png", lambda fig: _STUB_PNG)
        yield


_STUB_PNG = bytes.fromhex(  # a valid 1x1 transparent PNG
    "89504e470d0a1a0a0000000d49484452000000010000000108060000001f15c489"
    "0000000d49444154789c63f8ffff3f030008fc02fea79aa0a00000000049454e44ae426082"
)


@pytest.fixture
def undrawn_figures():
    """undrawn_report_figures() around one test."""
    with undrawn_report_figures():
        yield


def psnr_finite(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (data range 1) over pixels finite in both images; the non-finite masks must match.

    Values of huge magnitude (a corrupted colour of 1e38) are compared relatively (1e-4) and
    left out of the PSNR, where one ulp would swamp the mean."""
    fa, fb = np.isfinite(a), np.isfinite(b)
    assert np.array_equal(fa, fb), f"non-finite masks differ: {(~fa).sum()} vs {(~fb).sum()} values"
    big = fa & (np.abs(b) > 16)
    if big.any():
        rel = np.abs(a[big].astype(np.float64) - b[big]) / np.abs(b[big].astype(np.float64))
        assert rel.max() < 1e-4, f"huge values differ by {rel.max():.2e} relative"
        fa = fa & ~big
    if not fa.any():
        return float("inf")
    mse = float(np.mean((a[fa].astype(np.float64) - b[fa].astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def random_model(n: int, degree: int = 3, seed: int = 0, spread: float = 0.8):
    """Small random scene around the origin with trained-model-like parameters."""
    from seuwgpu.model.fields import Model, sh_rest_count

    rng = np.random.default_rng(seed)
    return Model(
        means=rng.uniform(-spread, spread, (n, 3)),
        log_scales=rng.uniform(-3.5, -1.5, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        opacity=rng.uniform(-1, 4, n),
        sh_dc=rng.normal(0, 0.8, (n, 3)),
        sh_rest=rng.normal(0, 0.1, (n, sh_rest_count(degree), 3)),
    )


@contextlib.contextmanager
def fifo_with_writer(path):
    """A named pipe at `path` that a thread writes "{}" into once: a reader that opens it does not
    hang (an old reader that read pipes would fail its test, not block it)."""
    os.mkfifo(path)

    def write():
        try:
            path.write_text("{}")
        except BrokenPipeError:  # the reader closed first (the reader under test refused the pipe)
            pass

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    try:
        yield path
    finally:
        os.close(os.open(path, os.O_RDONLY | os.O_NONBLOCK))  # lets the writer finish
        writer.join(5)


@contextlib.contextmanager
def traced_peak():
    """Trace Python's allocations in the block; the list it yields holds their peak in bytes after
    it (a reader that inflates or allocates more than a bad file deserves shows here)."""
    import tracemalloc

    peak: list[int] = []
    tracemalloc.start()
    try:
        yield peak
    finally:
        peak.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()


def close_records(got, want, tol=1e-5):
    """Same non-finite pattern; finite rows within tol of their largest component."""
    got = got.astype(np.float64).reshape(len(got), -1)
    want = want.astype(np.float64).reshape(len(want), -1)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.array_equal(np.isinf(got), np.isinf(want))
    assert np.array_equal(got[np.isinf(got)], want[np.isinf(want)])
    ok = np.isfinite(want).all(axis=1)
    scale = np.maximum(np.abs(want[ok]).max(axis=1, keepdims=True), np.finfo(np.float32).tiny)
    err = np.abs(got[ok] - want[ok]) / scale
    assert err.max(initial=0) <= tol, err.max()
