"""Checks of a correct outcome: each returns check(stdout), raising AssertionError when the
result is wrong."""

from __future__ import annotations

import numpy as np

from seuwgpu.campaign import store
from seuwgpu.campaign.schema import REPRODUCIBLE_COLUMNS


def npz_shape(path, shape):
    def check(_out):
        images = np.load(path)["images"]
        assert images.shape == shape, images.shape
        assert np.isfinite(images).all()

    return check


def npz_like(path, ref, shape, tol=0.02):
    """A render of `shape`, finite, within `tol` of the render in `ref` (at most 1/255 mean)."""

    def check(_out):
        images = np.load(path)["images"]
        assert images.shape == shape, images.shape
        assert np.isfinite(images).all()
        diff = np.abs(images - np.load(ref)["images"])
        assert diff.max() <= tol and diff.mean() <= 1 / 255, (float(diff.max()), float(diff.mean()))

    return check


def printed(stdout: str) -> dict:
    return dict(line.split(": ", 1) for line in stdout.splitlines() if ": " in line)


def bit_flipped(out, bit):
    """inject's corrupted value is its clean one with `bit` flipped (float32), and the panel is written."""

    def check(stdout):
        lines = printed(stdout)
        clean = np.float32(lines["clean_value"])
        want = (clean.view(np.uint32) ^ np.uint32(1 << bit)).view(np.float32)
        assert np.isfinite(clean) and np.isclose(float(lines["corrupted_value"]), want, rtol=1e-6), lines
        assert (out / "panel.png").is_file()

    return check


def records_of(run, n, scene):
    """A campaign's records: n of them, of the scene named `scene`, with finite metrics."""

    def check(_out):
        r = store.read_records(run)
        assert len(r) == n and set(r["scene"]) == {scene}, (len(r), set(r["scene"]))
        assert np.isfinite(r["footprint"]).all()

    return check


def records_equal(run, ref):
    """The run's reproducible records equal the reference run's, none twice."""

    def check(_out):
        a, b = (
            store.read_records(d).sort_values(["injection_id", "defense"]).reset_index(drop=True)[REPRODUCIBLE_COLUMNS]
            for d in (run, ref)
        )
        assert len(a) == len(b) and a.equals(b), (len(a), len(b))
        assert len(set(zip(a["injection_id"], a["defense"]))) == len(a), "duplicated records"

    return check


def file_exists(path):
    def check(_out):
        assert path.is_file(), f"no {path}"

    return check


def same_results(run, ref, name):
    """A storm's or state's records equal the uninterrupted reference run's, and no partial file
    is left."""

    def check(_out):
        import pandas as pd

        a, b = (pd.read_parquet(d / f"{name}.parquet") for d in (run, ref))
        assert len(a) == len(b) and a.equals(b), (len(a), len(b))
        assert not (run / f"{name}.partial.parquet").exists(), "the partial file was left"

    return check
