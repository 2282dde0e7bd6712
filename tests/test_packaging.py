"""Packaging and habits: the wheel carries everything a render needs and works from outside the
checkout; pyproject lists every package; ruff is clean; `python -m seuwgpu --version` works."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_pyproject_lists_every_package():
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    on_disk = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "seuwgpu").rglob("__init__.py")}
    on_disk.add("seuwgpu.shaders")  # shaders/ is mapped into the package (package-dir)
    assert listed == on_disk, f"missing from pyproject: {on_disk - listed}; listed but absent: {listed - on_disk}"


def test_version_from_the_command_line():
    from seuwgpu import __version__

    out = subprocess.run([sys.executable, "-m", "seuwgpu", "--version"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip() == f"seuwgpu {__version__}"
    assert _pyproject()["project"]["requires-python"] == ">=3.11"


def test_ruff_lint_and_format_are_clean():
    for args in (["check", "--no-cache", "."], ["format", "--check", "--no-cache", "."]):
        out = subprocess.run([sys.executable, "-m", "ruff", *args], capture_output=True, text=True, cwd=ROOT)
        assert out.returncode == 0, f"ruff {' '.join(args)}:\n{out.stdout}{out.stderr}"


@pytest.mark.slow
def test_the_wheel_renders_from_outside_the_checkout(tmp_path):
    # build from a copy of the tracked files: what a clean clone builds, and no build/ left in the tree
    src = tmp_path / "src"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in filter(None, files.decode().split("\0")):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    dist = tmp_path / "dist"
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(src)],
        capture_output=True,
        text=True,
    )
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = dist.glob("seuwgpu-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    shaders = {p.name for p in (ROOT / "shaders").glob("*.wgsl")}
    assert shaders and shaders <= {Path(n).name for n in names if n.startswith("seuwgpu/shaders/")}
    assert any(n.startswith("seuwgpu/campaign/specs/") and n.endswith(".toml") for n in names)
    # install the wheel alone into a folder outside the checkout; dependencies come from this
    # environment, seuwgpu itself only from the wheel
    site = tmp_path / "site"
    inst = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
        capture_output=True,
        text=True,
    )
    assert inst.returncode == 0, inst.stderr[-3000:]
    code = (
        "import seuwgpu, numpy as np\n"
        "from importlib import resources\n"
        "from seuwgpu.model.scenes import make_scene, scene_cameras\n"
        "from seuwgpu.render.renderer import Renderer\n"
        "img = Renderer(make_scene('spheres', n=2000), scene_cameras('spheres', 1, 32, 32)).render()\n"
        "print(seuwgpu.__file__)\n"
        "print(resources.files('seuwgpu.shaders'))\n"
        "print(float(np.isfinite(img).mean()), float(img.std()))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(site)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    module_file, shader_dir, stats = run.stdout.strip().splitlines()
    assert module_file.startswith(str(site)) and shader_dir.startswith(str(site))
    finite, spread = map(float, stats.split())
    assert finite == 1.0 and spread > 0.01  # a real image, not a blank frame
