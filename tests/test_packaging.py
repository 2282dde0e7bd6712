"""Packaging and habits: the wheel carries everything a render needs and works from outside the
checkout; pyproject lists every package; ruff is clean; `python -m seuwgpu --version` works."""

from __future__ import annotations

import ast
import os
import re
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


def _distribution(requirement: str) -> str:
    """A requirement's distribution name, normalised (PEP 503): "scikit-learn>=1.3" -> "scikit-learn"."""
    return re.sub(r"[-_.]+", "-", re.match(r"[A-Za-z0-9_.-]+", requirement).group()).lower()


def _third_party_imports(folder: Path) -> dict[str, Path]:
    """Top-level modules of other packages imported anywhere under `folder` (inside functions
    too), including those imported through seuwgpu.errors.require("module", ...)."""
    found = {}
    local = {p.stem for p in folder.glob("*.py")} | {p.name for p in folder.iterdir() if (p / "__init__.py").exists()}
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "require" and node.args:
                names = [node.args[0].value]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                ours = top == "seuwgpu" or top in local  # the folder's own modules (tests/robustness)
                if top not in sys.stdlib_module_names and not ours:
                    found.setdefault(top, path)
    return found


def _declared_distribution(module: str) -> str:
    """The distribution that provides an import name, as installed here; the import name itself
    for one not installed (torch, an extra the tests skip without)."""
    from importlib.metadata import packages_distributions

    dists = packages_distributions().get(module, [module])
    return _distribution(dists[0])


def test_every_imported_library_is_declared():
    """Every library seuwgpu imports is a base dependency or in an extra, and every library the
    tests import is in what `./dev test` installs (base, test and ray extras; torch is skipped
    without): a library that only came as another's dependency (tifffile came with scikit-image)
    would vanish when that one became optional."""
    project = _pyproject()["project"]
    base = {_distribution(r) for r in project["dependencies"]}
    extras = {k: {_distribution(r) for r in v} for k, v in project["optional-dependencies"].items()}
    anywhere = base.union(*extras.values())
    for module, path in _third_party_imports(ROOT / "seuwgpu").items():
        assert _declared_distribution(module) in anywhere, f"{path.relative_to(ROOT)} imports {module}, undeclared"
    tested = base | extras["test"] | extras["ray"] | {"torch"}
    for module, path in _third_party_imports(ROOT / "tests").items():
        assert _declared_distribution(module) in tested, f"{path.relative_to(ROOT)} imports {module}, not in [test]"


def test_the_main_install_leaves_the_study_libraries_to_extras():
    """The main job's install (docs/install.md): scipy and scikit-learn serve only the study's
    analyses (the `analysis` extra), scikit-image only the tests' reference SSIM; zstandard is in
    the base so that a plain install opens SPZ v4."""
    project = _pyproject()["project"]
    base = {_distribution(r) for r in project["dependencies"]}
    extras = {k: {_distribution(r) for r in v} for k, v in project["optional-dependencies"].items()}
    assert not base & {"scipy", "scikit-learn", "scikit-image"}
    assert {"zstandard", "tifffile"} <= base
    assert {"scipy", "scikit-learn"} <= extras["analysis"] <= extras["test"]
    assert "scikit-image" in extras["test"]
    assert extras["formats"] == set()  # kept for old install lines
    pinned = {_distribution(line) for line in (ROOT / "constraints.txt").read_text().splitlines() if "==" in line}
    locked = base | extras["analysis"] | extras["test"]  # what ./dev installs (torch's extra is not locked)
    assert locked <= pinned, f"constraints.txt lacks pins for {locked - pinned} (./dev lock)"


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
    assert "seuwgpu/model/corpus.toml" in names  # the corpus manifest (seuwgpu corpus)
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
