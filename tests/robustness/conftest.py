"""The robustness tests' shared work folder: a valid model (PLY and SPZ), a camera file, a file,
an empty file and a folder, and copies of the committed .ksplat and SOG fixtures with
splat-transform's decode of each (X.ref.ply). Made once per session."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

FIXTURES = Path(__file__).resolve().parents[1] / "data" / "formats"
FORMAT_FIXTURES = ("level0_sh2.ksplat", "level1_sh1.ksplat", "level2_sh2.ksplat", "sh3.sog", "sog_meta")


@pytest.fixture(scope="session")
def work(tmp_path_factory) -> Path:
    from seuwgpu.model.cameras import save_cameras
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.scenes import make_scene, scene_cameras

    w = tmp_path_factory.mktemp("robustness")
    model = make_scene("spheres", n=80, seed=4)
    save_model(model, w / "good.ply")
    save_model(model, w / "good.spz")
    save_cameras(scene_cameras("spheres", 2, 16, 16), w / "cams.json")
    (w / "file").write_text("a file, not a folder")
    (w / "empty").write_bytes(b"")
    (w / "dir").mkdir()
    for name in FORMAT_FIXTURES:
        src = FIXTURES / name
        if src.is_dir():
            shutil.copytree(src, w / name)
        else:
            shutil.copy(src, w / name)
        shutil.copy(FIXTURES / f"{name}.ref.ply", w / f"{name}.ref.ply")
    return w


@pytest.fixture(autouse=True)
def in_work(work, monkeypatch):
    """Relative outputs (an --out without a folder) land in the work folder."""
    monkeypatch.chdir(work)


_counter = iter(range(10**9))


@pytest.fixture
def fresh(work):
    """fresh(stem, suffix=""): a new path in the work folder (nothing there yet)."""

    def make(stem: str, suffix: str = "") -> Path:
        return work / f"{stem}{next(_counter)}{suffix}"

    return make
