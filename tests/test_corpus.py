"""The corpus of real trained models: the packaged manifest, and `seuwgpu corpus` / assemble_corpus
on a small manifest whose files the tests write (no network: folders and file:// URLs)."""

from __future__ import annotations

import hashlib
import json
import re

import pytest

from seuwgpu import api
from seuwgpu.apps.cli import main
from seuwgpu.model import corpus

HEX64 = re.compile(r"^[0-9a-f]{64}$")


def _entry(name: str, files: dict[str, bytes], base_url: str, model: str | None = None) -> str:
    rows = "\n".join(
        f'  {{ path = "{p}", size = {len(b)}, sha256 = "{hashlib.sha256(b).hexdigest()}" }},' for p, b in files.items()
    )
    return f"""
[[model]]
name = "{name}"
subject = "a test object"
source = "someone/somerepo@{"0" * 40}"
base_url = "{base_url}"
licence = "CC0-1.0"
licence_url = "https://example.org/LICENSE"
licence_sha256 = "{"a" * 64}"
credit = "{name} by someone, CC0"
primitives = 2
sh_degree = 0
trainer = "not stated"
format = "splat"
model = "{model or next(iter(files))}"
capture = "capture"
files = [
{rows}
]
"""


@pytest.fixture
def small(tmp_path):
    """A two-model manifest, its files in a publisher-like folder `pub`: one model is a tile set."""
    files = {
        "one": {"one.splat": bytes(range(64))},
        "tiles": {"lod-meta.json": b'{"lodLevels": 1}', "0_0/meta.json": b"{}", "1_0/meta.json": b'{"x": 1}'},
    }
    pub = tmp_path / "pub"
    for name, fs in files.items():
        for rel, data in fs.items():
            (pub / name / rel).parent.mkdir(parents=True, exist_ok=True)
            (pub / name / rel).write_bytes(data)
    text = "".join(_entry(n, fs, (pub / n).as_uri() + "/") for n, fs in files.items())
    manifest = tmp_path / "corpus.toml"
    manifest.write_text(text)
    return manifest, pub, files


def test_assembles_from_a_folder_and_resumes(small, tmp_path):
    manifest, pub, files = small
    flat = tmp_path / "flat"  # another layout: one.splat at the top, the tiles under their own folders
    flat.mkdir()
    (flat / "one.splat").write_bytes((pub / "one" / "one.splat").read_bytes())
    for rel in files["tiles"]:
        (flat / "x" / rel).parent.mkdir(parents=True, exist_ok=True)
        (flat / "x" / rel).write_bytes(files["tiles"][rel])
    out = tmp_path / "out"
    lines = []
    paths = api.assemble_corpus(out, source=flat, manifest=manifest, log=lines.append)
    assert paths == {"one": out / "one" / "one.splat", "tiles": out / "tiles" / "lod-meta.json"}
    for name, fs in files.items():
        for rel, data in fs.items():
            assert (out / name / rel).read_bytes() == data
    index = json.loads((out / "corpus.json").read_text())["models"]
    assert [(e["name"], e["model"]) for e in index] == [("one", "one/one.splat"), ("tiles", "tiles/lod-meta.json")]
    assert "`tiles/lod-meta.json`" in (out / "INDEX.md").read_text()
    assert lines[1].startswith("tiles: 3 file(s)") and "(3 fetched, 0 already there)" in lines[1]
    lines.clear()  # again, from an empty folder: the files already there with their hash are kept
    (tmp_path / "empty").mkdir()
    api.assemble_corpus(out, source=tmp_path / "empty", manifest=manifest, models=["tiles"], log=lines.append)
    assert lines == ["tiles: 3 file(s), 26 bytes (0 fetched, 3 already there)"]


def test_a_file_whose_hash_differs_is_refused_and_not_kept(small, tmp_path):
    manifest, pub, _ = small
    (pub / "tiles" / "1_0" / "meta.json").write_bytes(b'{"x": 2}')  # same size, other bytes
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"^tiles/1_0/meta.json: sha256 [0-9a-f]{64} from .*refused$"):
        api.assemble_corpus(out, source=pub, manifest=manifest, models=["tiles"])
    assert not (out / "tiles" / "1_0" / "meta.json").exists()
    assert not list(out.rglob("*.part"))
    assert (out / "tiles" / "0_0" / "meta.json").exists()  # the files before it were checked and kept


def test_the_cli_refuses_a_wrong_file_with_exit_status_2(small, tmp_path, capsys):
    manifest, pub, _ = small
    (pub / "one" / "one.splat").write_bytes(bytes(65))
    code = main(["corpus", "--manifest", str(manifest), "--out", str(tmp_path / "o"), "--from", str(pub)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("seuwgpu corpus: error: one/one.splat: 65 bytes from ")


def test_unknown_model_names_the_known_ones(small, tmp_path):
    manifest, pub, _ = small
    with pytest.raises(ValueError, match=r"unknown corpus model 'two'; known: one, tiles"):
        api.assemble_corpus(tmp_path / "o", source=pub, manifest=manifest, models=["one", "two"])
    assert not (tmp_path / "o").exists()


def test_downloads_by_url(small, tmp_path, capsys):
    manifest, _, files = small
    out = tmp_path / "dl"
    assert main(["corpus", "--manifest", str(manifest), "--out", str(out)]) == 0
    assert (out / "tiles" / "1_0" / "meta.json").read_bytes() == files["tiles"]["1_0/meta.json"]
    assert f"one: --model {out / 'one' / 'one.splat'}" in capsys.readouterr().out


def test_a_missing_url_is_a_one_line_error(small, tmp_path):
    manifest, pub, _ = small
    (pub / "one" / "one.splat").unlink()
    with pytest.raises(ValueError, match=r"^one/one.splat: cannot download file://.*one.splat"):
        api.assemble_corpus(tmp_path / "o", manifest=manifest, models=["one"])


def test_list_prints_every_model(small, capsys):
    manifest, _, _ = small
    assert main(["corpus", "--list", "--manifest", str(manifest)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out[1:]] == ["one", "tiles"]


def test_a_malformed_manifest_names_the_model(tmp_path):
    bad = tmp_path / "m.toml"
    bad.write_text(_entry("one", {"a.splat": b"x"}, "file:///x/").replace(', sha256 = "', ', sha256 = "Z'))
    with pytest.raises(ValueError, match=r"model 'one': file 'a.splat' needs a size and a sha256 of 64 hex"):
        corpus.load_manifest(bad)


# the file each published format is opened by (its --model path)
SUFFIX_OF = {
    "splat": ".splat",
    "spz": ".spz",
    "compressed-ply": ".compressed.ply",
    "sog": ".sog",
    "sog-lod": "lod-meta.json",
    "ply": ".ply",
}


def test_the_packaged_manifest_is_complete_and_consistent():
    models = api.corpus_models()
    assert len(models) >= 8
    assert len({m.source.split("@")[0] for m in models}) >= 3
    # issue 45 asks for two of 500k or more; one could be reached (docs/corpus.md, "Sources tried")
    assert sum(m.primitives >= 500_000 for m in models) >= 1
    for m in models:
        repo, commit = m.source.split("@")
        assert re.fullmatch(r"[0-9a-f]{40}", commit), m.name
        assert m.base_url.startswith(f"https://raw.githubusercontent.com/{repo}/{commit}/"), m.name
        # (hash shapes and `also` among the files: load_manifest refuses those already)
        assert m.licence and m.credit and m.licence_url.startswith("https://") and m.primitives > 0
        assert m.trainer and m.capture and m.subject and m.sh_degree in range(4)
        assert all(f.size > 0 for f in m.files)
        assert m.model in {f.path for f in m.files}, m.name
        assert m.model.endswith(SUFFIX_OF[m.format]), (m.name, m.format, m.model)  # the format as published
        assert m.model not in m.also.values() and all(m.also[k].endswith(SUFFIX_OF[k]) for k in m.also), m.name


def test_another_published_format_must_be_one_of_the_files(tmp_path):
    bad = tmp_path / "m.toml"
    bad.write_text(_entry("one", {"a.splat": b"x"}, "file:///x/") + 'also = { spz = "a.spz" }\n')
    with pytest.raises(ValueError, match=r"model 'one': also maps formats to paths among its files"):
        corpus.load_manifest(bad)


def test_each_file_is_hashed_once_as_it_is_copied(small, tmp_path, monkeypatch):
    """From a folder, a file is hashed while it is copied, not once to find it and again to copy
    it; a same-named decoy of the right size is hashed once, refused, and its bytes taken back
    from the progress."""
    manifest, pub, files = small
    hashed, real = [], hashlib.sha256

    class Counting:
        def __init__(self):
            self.h = real()

        def update(self, block):
            hashed.append(len(block))
            self.h.update(block)

        def hexdigest(self):
            return self.h.hexdigest()

    monkeypatch.setattr(corpus.hashlib, "sha256", Counting)
    decoy = tmp_path / "src" / "a" / "meta.json"  # found by name before the real one, same size
    decoy.parent.mkdir(parents=True)
    decoy.write_bytes(b'{"x": 9}')
    for rel, data in files["tiles"].items():
        (tmp_path / "src" / "x" / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "src" / "x" / rel).write_bytes(data)
    seen = []
    api.assemble_corpus(
        tmp_path / "out",
        source=tmp_path / "src",
        manifest=manifest,
        models=["tiles"],
        progress=lambda d, t: seen.append((d, t)),
    )
    total = sum(len(b) for b in files["tiles"].values())
    assert sum(hashed) == total + len(decoy.read_bytes())  # the decoy once, each file once
    assert seen[-1] == (total, total) and max(d for d, _ in seen) <= total
    assert (tmp_path / "out" / "tiles" / "1_0" / "meta.json").read_bytes() == files["tiles"]["1_0/meta.json"]
