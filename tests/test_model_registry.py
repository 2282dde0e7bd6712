"""The model-format registry: every format module registered once, every writable format round
trips through save_model and read_model, sniffing by content, the messages listing the registry,
and a new format (the worked example of CONTRIBUTING.md, run from there) being one entry."""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

import numpy as np
import pytest
from test_model_files import assert_bit_equal

import seuwgpu.model.formats as formats
from seuwgpu.model.fields import FIELDS
from seuwgpu.model.formats import (
    REGISTRY,
    ModelFileError,
    ModelFormat,
    detect_format,
    format_named,
    model_label,
    read_model,
    save_model,
)
from seuwgpu.model.formats.base import Probe
from seuwgpu.model.scenes import make_scene

WRITABLE = [f.name for f in REGISTRY if f.write is not None]


def test_every_format_module_is_registered_once():
    exported = {}
    for info in pkgutil.iter_modules(formats.__path__):
        module = importlib.import_module(f"seuwgpu.model.formats.{info.name}")
        if isinstance(getattr(module, "FORMAT", None), ModelFormat):
            exported[info.name] = module.FORMAT
    assert set(exported.values()) == set(REGISTRY) and len(REGISTRY) == len(set(REGISTRY))
    names = [f.name for f in REGISTRY]
    suffixes = [s for f in REGISTRY for s in f.suffixes]
    assert len(set(names)) == len(names) and len(set(suffixes)) == len(suffixes)
    assert set(WRITABLE) == {"ply", "spz", "compressed-ply", "sog", "ksplat", "splat"}
    assert all(f.up in formats.UP_AXES for f in REGISTRY)


@pytest.mark.parametrize("name", WRITABLE)
def test_writable_formats_round_trip(tmp_path, name):
    fmt = format_named(name)
    m = make_scene("spheres", n=64, sh_degree=2, seed=7)
    path = tmp_path / f"m{fmt.suffixes[0]}"
    assert save_model(m, path) == name  # chosen by the suffix
    first = read_model(path)
    assert first.format == name and first.up == fmt.up
    np.testing.assert_allclose(first.model.means, m.means, atol=1e-3)  # SPZ: 1/4096 steps
    np.testing.assert_allclose(first.model.sh_dc, m.sh_dc, atol=0.03)  # SPZ: 8 bits over +-3.3
    # what a format holds survives a second trip, whatever the name (chosen by `format`); equal
    # values (SPZ's smallest-three rotations may turn a zero component's sign: the same rotation)
    assert save_model(first.model, tmp_path / "again.bin", format=name) == name
    again = read_model(tmp_path / "again.bin")
    assert again.format == name and again.notes == first.notes
    for f in FIELDS:
        if f == "quats" and name in ("compressed-ply", "sog"):
            continue  # smallest three: two components within a step may swap which one is stored
        np.testing.assert_array_equal(getattr(again.model, f), getattr(first.model, f), err_msg=f)
    q1, q2 = (np.asarray(x.model.quats, np.float64) for x in (first, again))
    q1, q2 = (q / np.linalg.norm(q, axis=1, keepdims=True) for q in (q1, q2))
    assert np.abs(np.abs((q1 * q2).sum(axis=1)) - 1).max() < 1e-5  # the same rotation


def test_ply_round_trip_is_exact_and_records_up(tmp_path):
    m = make_scene("spheres", n=32, sh_degree=1, seed=2)
    save_model(m, tmp_path / "z.ply", up="+z")
    mf = read_model(tmp_path / "z.ply")
    assert mf.up == "+z" and mf.notes == []
    assert_bit_equal(mf.model, m)


def test_sniffing_reads_content_not_names(tmp_path):
    m = make_scene("spheres", n=16, sh_degree=0, seed=1)
    for name in WRITABLE:
        save_model(m, tmp_path / f"{name}.data", format=name)
    swapped = {"ply": "spz", "spz": "ply"}
    for name, other in swapped.items():  # each file under the other's suffix
        p = tmp_path / f"as{format_named(other).suffixes[0]}"
        p.write_bytes((tmp_path / f"{name}.data").read_bytes())
        assert detect_format(p) == name
    probe = Probe.of(str(tmp_path / "spz.data"))
    assert [f.name for f in REGISTRY if f.sniff(probe)] == ["spz"]  # no other sniffer claims it


def test_unrecognised_file_names_every_format(tmp_path):
    p = tmp_path / "notes.txt"
    p.write_text("not a model, just some words\n" * 40)
    with pytest.raises(ModelFileError, match="unrecognised model file") as e:
        read_model(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p))
    assert all(f.title in msg for f in REGISTRY)
    assert "a .splat file, which has no header, is recognised by its extension" in msg


def test_write_errors_name_the_writable_formats(tmp_path):
    m = make_scene("spheres", n=8, seed=1)
    with pytest.raises(ModelFileError, match=r"cannot write this format; write \.ply \(INRIA 3DGS PLY\), \.compressed"):
        save_model(m, tmp_path / "a.obj")
    with pytest.raises(ModelFileError, match="cannot write this format"):
        save_model(m, tmp_path / "a.pt", format="gsplat")  # a registered format without a writer
    with pytest.raises(ModelFileError, match="unknown model format 'obj'; known: compressed-ply, ply, spz"):
        format_named("obj")


@pytest.mark.parametrize("fmt", REGISTRY, ids=lambda f: f.name)
def test_model_label_strips_every_registered_suffix(tmp_path, fmt):
    for suffix in fmt.suffixes:
        assert model_label(tmp_path / f"garden{suffix}") == "garden"
        assert model_label(tmp_path / f"garden{suffix.upper()}") == "garden"
    assert model_label(tmp_path / "garden.tar") == "garden"  # not a model suffix: the stem


# --------------------------------------------------------- the worked example of CONTRIBUTING.md
def contributing_example() -> ModelFormat:
    """The `.npz` format of CONTRIBUTING.md's "How to add a model file format", run as written there."""
    text = (Path(__file__).resolve().parents[1] / "CONTRIBUTING.md").read_text(encoding="utf-8")
    section = text.split("## How to add a model file format", 1)[1].split("\n## ", 1)[0]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    namespace: dict = {}
    exec(compile(code, "CONTRIBUTING.md", "exec"), namespace)
    return namespace["FORMAT"]


def test_a_new_format_is_one_registry_entry(tmp_path, monkeypatch):
    # a zip: it goes before the gsplat checkpoint, whose sniffer refuses a zip without data.pkl
    at = [f.name for f in REGISTRY].index("gsplat")
    monkeypatch.setattr(formats, "REGISTRY", REGISTRY[:at] + (contributing_example(),) + REGISTRY[at:])
    m = make_scene("spheres", n=40, sh_degree=3, seed=4)
    assert save_model(m, tmp_path / "scene.npz") == "npz"
    assert detect_format(tmp_path / "scene.npz") == "npz"
    mf = read_model(tmp_path / "scene.npz")
    assert (mf.format, mf.up, mf.notes, mf.name) == ("npz", "+z", ["npz of 6 arrays"], "scene")
    assert_bit_equal(mf.model, m)
    with pytest.raises(ModelFileError, match=r"write \.ply \(INRIA 3DGS PLY\), .*\.npz \(NumPy"):
        save_model(m, tmp_path / "a.obj")
    monkeypatch.undo()  # unregistered, the same file is a zip no reader takes
    with pytest.raises(ModelFileError, match="no PyTorch checkpoint"):
        detect_format(tmp_path / "scene.npz")
