"""The corpus of real trained models: the packaged manifest (`corpus.toml`) and the assembly of
its files into a folder, checked byte for byte.

The manifest names each model's publisher, the repository and commit its files come from, its
licence (with the licence file's sha256) and the credit line to give, and every file with its
path, size and sha256. `assemble` fetches each file by URL (`base_url` + path; any scheme urllib
opens, file:// included) or copies it from a folder the user points to, checks the size and the
sha256 of every byte, and writes it under `OUT/<model>/<path>`; a file already there with the
right hash is kept (an interrupted assembly resumes). A file whose bytes differ is refused with a
one-line error naming it, and nothing of it is left behind. `OUT/corpus.json` and `OUT/INDEX.md`
say which path to pass to `--model` for each model.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tomllib
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from seuwgpu.errors import InputError

MANIFEST = Path(__file__).with_name("corpus.toml")
"""The packaged manifest."""

INDEX_JSON, INDEX_MD = "corpus.json", "INDEX.md"
_CHUNK = 1 << 20
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_NAME = re.compile(r"^[a-z0-9][a-z0-9_-]*$")
_MODEL_KEYS = (
    "name subject source base_url licence licence_url licence_sha256 credit primitives sh_degree "
    "trainer format model capture files"
).split()


class CorpusError(InputError):
    """A manifest, a model name or a file of the corpus that cannot be used as given."""


@dataclass(frozen=True)
class CorpusFile:
    path: str  # relative to the model's folder (and to its base_url)
    size: int
    sha256: str


@dataclass(frozen=True)
class CorpusModel:
    name: str
    subject: str
    source: str  # the publisher's repository, "owner/name@commit"
    base_url: str  # each file's URL is base_url + its path (raw files pinned to the commit)
    licence: str
    licence_url: str
    licence_sha256: str
    credit: str
    primitives: int
    sh_degree: int
    trainer: str
    format: str  # as published: "splat", "spz", "compressed-ply", "sog", "sog-lod"
    model: str  # what to pass to --model, relative to the model's folder
    capture: str  # how the publisher says it was made
    files: tuple[CorpusFile, ...]
    notes: str = ""
    # the same model as the publisher also published it, in other formats ({format: path}, each
    # path one of `files`): every one of them must load as the same model (tools/check_corpus.py)
    also: dict = field(default_factory=dict)

    @property
    def size(self) -> int:
        return sum(f.size for f in self.files)


def load_manifest(path: str | Path | None = None) -> dict[str, CorpusModel]:
    """The models of a corpus manifest (the packaged one by default), by name, in file order.
    A malformed manifest is a CorpusError naming the file and the model."""
    path = Path(MANIFEST if path is None else path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise CorpusError(f"{path}: not a TOML corpus manifest ({e})") from None
    models: dict[str, CorpusModel] = {}
    for i, m in enumerate(data.get("model", [])):
        where = f"{path}: model {m.get('name', i)!r}"
        missing = [k for k in _MODEL_KEYS if k not in m]
        if missing:
            raise CorpusError(f"{where} lacks {', '.join(missing)}")
        if not _NAME.match(str(m["name"])) or m["name"] in models:
            raise CorpusError(f"{where}: the name must be unique, lower case, letters, digits, - and _")
        files = []
        for f in m["files"]:
            rel = str(f.get("path", ""))
            if not rel or rel.startswith("/") or ".." in Path(rel).parts or "\\" in rel:
                raise CorpusError(f"{where}: file path {rel!r} must be relative, inside the model's folder")
            if not _SHA256.match(str(f.get("sha256", ""))) or not isinstance(f.get("size"), int) or f["size"] < 0:
                raise CorpusError(f"{where}: file {rel!r} needs a size and a sha256 of 64 hex digits")
            files.append(CorpusFile(rel, f["size"], f["sha256"]))
        if not files or len({f.path for f in files}) != len(files):
            raise CorpusError(f"{where}: needs files, each path once")
        if not _SHA256.match(str(m["licence_sha256"])):
            raise CorpusError(f"{where}: licence_sha256 must be 64 hex digits")
        also = m.get("also", {})
        if not isinstance(also, dict) or any(str(v) not in {f.path for f in files} for v in also.values()):
            raise CorpusError(f"{where}: also maps formats to paths among its files")
        fields = {k: m[k] for k in _MODEL_KEYS if k != "files"}
        models[m["name"]] = CorpusModel(**fields, files=tuple(files), notes=m.get("notes", ""), also=dict(also))
    if not models:
        raise CorpusError(f"{path}: no [[model]] entries")
    return models


def select(models: dict[str, CorpusModel], names: Iterable[str] | None) -> list[CorpusModel]:
    """The named models (all when `names` is None), or a CorpusError listing the known names."""
    if names is None:
        return list(models.values())
    names = [n.strip() for n in names if n.strip()]
    unknown = [n for n in names if n not in models]
    if unknown:
        raise CorpusError(f"unknown corpus model {', '.join(map(repr, unknown))}; known: {', '.join(models)}")
    if not names:
        raise CorpusError("no corpus model named")
    return [models[n] for n in dict.fromkeys(names)]


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def _has(path: Path, f: CorpusFile) -> bool:
    return path.is_file() and path.stat().st_size == f.size and sha256_of(path) == f.sha256


def _candidates(source: Path, model: CorpusModel, f: CorpusFile, by_name: dict[str, list[Path]]) -> list[Path]:
    """Where a file may be in a folder: `<model>/<path>`, `<path>`, then any file of its name."""
    out = [source / model.name / f.path, source / f.path]
    out += by_name.get(Path(f.path).name, [])
    return [p for p in dict.fromkeys(out) if p.is_file()]


def _copy_checked(read: Callable[[], object], dest: Path, f: CorpusFile, label: str, what: str, advance) -> None:
    """Stream `read()` (a binary file object) into dest, hashing it as it is copied (its only
    hash), checking size and sha256; on a mismatch the partial file is removed, its bytes taken
    back from the progress, and a CorpusError names the file."""
    part = dest.with_name(dest.name + ".part")
    dest.parent.mkdir(parents=True, exist_ok=True)
    h, n, sent = hashlib.sha256(), 0, 0
    try:
        with read() as src, open(part, "wb") as out:
            for block in iter(lambda: src.read(_CHUNK), b""):
                n += len(block)
                if n > f.size:
                    break
                h.update(block)
                out.write(block)
                advance(len(block))
                sent += len(block)
        if n != f.size or h.hexdigest() != f.sha256:
            advance(-sent)
            got = f"{n:,} bytes" if n != f.size else f"sha256 {h.hexdigest()}"
            raise CorpusError(
                f"{label}: {got} from {what}, the manifest says {f.size:,} bytes, sha256 {f.sha256}: refused"
            )
        os.replace(part, dest)
    finally:
        part.unlink(missing_ok=True)


def _copy_found(found: list[Path], dest: Path, f: CorpusFile, label: str, advance, src: Path, model: str):
    """Copy the first of the files `found` for `f` whose bytes check, trying those of its size in
    turn (each hashed once, as it is copied); none of its size: the best guess, refused naming
    its size; none that checks: the first refusal."""
    if not found:
        raise CorpusError(f"{label}: not found in {src} (as {model}/{f.path}, {f.path} or by its name)")
    refused = None
    for p in [q for q in found if q.stat().st_size == f.size] or found[:1]:
        try:
            _copy_checked(lambda p=p: open(p, "rb"), dest, f, label, str(p), advance)
            return
        except CorpusError as e:
            refused = refused or e
    raise refused


def assemble(
    out: str | Path,
    *,
    source: str | Path | None = None,
    models: Iterable[str] | None = None,
    manifest: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> dict[str, Path]:
    """Assemble the corpus (or the named `models`) under `out`: each file from the folder `source`
    when given (same relative layout, or found by its name), else downloaded from its URL; sizes and
    sha256 checked; files already present with the right hash kept. `progress(done, total)` gets
    bytes. Returns {model name: the path to pass to --model}; writes corpus.json and INDEX.md."""
    chosen = select(load_manifest(manifest), models)
    out = Path(out)
    src = None if source is None else Path(source)
    if src is not None and not src.is_dir():
        raise FileNotFoundError(2, "no such folder to read the corpus from", str(src))
    by_name: dict[str, list[Path]] = {}
    if src is not None:
        wanted = {Path(f.path).name for m in chosen for f in m.files}
        for p in sorted(src.rglob("*")):
            if p.name in wanted and p.is_file():
                by_name.setdefault(p.name, []).append(p)
    total, done = sum(m.size for m in chosen), 0

    def advance(k: int) -> None:
        nonlocal done
        done += k
        if progress:
            progress(done, total)

    for m in chosen:
        fetched = kept = 0
        for f in m.files:
            dest, label = out / m.name / f.path, f"{m.name}/{f.path}"
            if _has(dest, f):
                advance(f.size)
                kept += 1
                continue
            if src is None:
                url = m.base_url + f.path
                try:
                    _copy_checked(lambda url=url: urllib.request.urlopen(url, timeout=60), dest, f, label, url, advance)
                except (urllib.error.URLError, OSError) as e:
                    if isinstance(e, CorpusError):
                        raise
                    raise CorpusError(f"{label}: cannot download {url} ({getattr(e, 'reason', e)})") from None
            else:
                _copy_found(_candidates(src, m, f, by_name), dest, f, label, advance, src, m.name)
            fetched += 1
        if log:
            log(f"{m.name}: {len(m.files)} file(s), {m.size:,} bytes ({fetched} fetched, {kept} already there)")
    return write_index(out, chosen)


def write_index(out: Path, chosen: list[CorpusModel]) -> dict[str, Path]:
    """corpus.json and INDEX.md under `out`, merged with the models an earlier run put there."""
    index_path = out / INDEX_JSON
    entries: dict[str, dict] = {}
    if index_path.is_file():
        try:
            entries = {e["name"]: e for e in json.loads(index_path.read_text())["models"]}
        except (ValueError, KeyError, TypeError):
            entries = {}
    for m in chosen:
        entries[m.name] = {
            "name": m.name,
            "model": f"{m.name}/{m.model}",
            "primitives": m.primitives,
            "sh_degree": m.sh_degree,
            "format": m.format,
            "subject": m.subject,
            "licence": m.licence,
            "credit": m.credit,
            "source": m.source,
        }
    rows = list(entries.values())
    out.mkdir(parents=True, exist_ok=True)
    index_path.write_text(json.dumps({"models": rows}, indent=1) + "\n")
    lines = [
        "# seuwgpu corpus: real trained 3DGS models at their full size",
        "",
        "Pass the path to `--model` (relative to this folder). Assembled by `seuwgpu corpus`; "
        "every file's sha256 is checked against the packaged manifest (docs/corpus.md).",
        "",
        "| model | --model path | primitives | SH | format | licence | credit |",
        "|---|---|---:|---:|---|---|---|",
    ]
    for e in rows:
        lines.append(
            f"| {e['name']} | `{e['model']}` | {e['primitives']:,} | {e['sh_degree']} | {e['format']} | "
            f"{e['licence']} | {e['credit']} |"
        )
    if any(e["format"] == "sog-lod" for e in rows):
        lines += [
            "",
            "A `sog-lod` model is a LOD set: `lod-meta.json` names tile folders, each a plain SOG folder "
            "(`<model>/0_0` loads alone); its primitives are those of its finest level.",
        ]
    (out / INDEX_MD).write_text("\n".join(lines) + "\n")
    return {e["name"]: out / e["model"] for e in rows}
