"""PlayCanvas streamed LOD sets (`lod-meta.json` and its SOG tiles): one level read as one model.

Layout (github playcanvas/splat-transform, src/lib/writers/write-lod.ts writes it; the engine's
src/scene/gsplat-unified/gsplat-octree.js reads it): a folder holding `lod-meta.json` and one
folder per tile, each an unbundled SOG (a `meta.json` and its WebP images, sog.py):

- `lod-meta.json`: {"lodLevels": L, "environment"?: ..., "filenames": [tile meta.json paths,
  relative to lod-meta.json], "tree": node}; a node is a branch {"bound", "children": [node, ...]}
  or a leaf {"bound", "lods": {"0": {"file", "offset", "count"}, ...}}: at each level the leaf's
  splats are `count` splats of tile `filenames[file]` from splat `offset` on.
- level 0 is the finest (all the capture's splats), each further level coarser.

One level is read (the finest, 0, unless asked for another: `--lod N`, a spec's `lod = N`,
`load_model(path, lod=N)`): the union of the leaves' ranges at that level, merged in a fixed
order: by tile (its index in `filenames`), then by offset within the tile. A tile's ranges in
that order are its splats in stored order, so a level whose leaves cover whole tiles is the
tiles' decodes one after the other. Each tile is decoded once, as sog.py decodes a SOG. The
engine renders the leaves in tree order instead; the order of splats changes nothing drawn (the
renderer sorts by depth) but is the order of the model's primitives, which fault sites index.

Refused in one line naming the input: a tile whose meta.json or image is missing or unreadable
(sog.py's messages name the tile's meta.json), a range beyond its tile's count, overlapping
ranges (splats drawn twice), tiles of different SH degrees, a level the set does not hold (the
message lists those it does). The `environment` (a SOG of background splats drawn at every level)
is not read: the note says so.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from seuwgpu.model.budget import check_model
from seuwgpu.model.fields import FIELDS, Model
from seuwgpu.model.formats import sog
from seuwgpu.model.formats.base import ANTIALIASED_NOTE, ModelFormat, Probe
from seuwgpu.model.formats.errors import ModelFileError

NAME = "lod-meta.json"
META_BYTES = 64 << 20  # a lod-meta.json's tree: tens of kB for millions of splats
MAX_NODES = 1 << 20


class LodError(ModelFileError):
    """A LOD set that cannot be read."""


def is_lod_meta(head: bytes) -> bool:
    """The start of a lod-meta.json: a JSON object naming "lodLevels" (splat-transform writes it first)."""
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    return text[:1] == b"{" and b'"lodLevels"' in head


def lod_meta_path(path) -> Path:
    """lod-meta.json itself, or the one a folder holds."""
    p = Path(path)
    return p / NAME if p.is_dir() else p


def _meta(path: Path) -> dict:
    if path.stat().st_size > META_BYTES:
        raise LodError(f"{path}: {path.stat().st_size:,} bytes, over the {META_BYTES:,} a lod-meta.json could need")
    try:
        meta = json.loads(path.read_bytes().decode("utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise LodError(f"{path}: LOD set lod-meta.json is not valid JSON ({e})") from None
    if not isinstance(meta, dict):
        raise LodError(f"{path}: LOD set lod-meta.json must hold a JSON object")
    names = meta.get("filenames")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise LodError(f"{path}: LOD set lod-meta.json filenames must be a non-empty list of tile paths")
    if not isinstance(meta.get("tree"), dict):
        raise LodError(f"{path}: LOD set lod-meta.json lacks its tree (an object)")
    return meta


def _leaves(tree: dict, path: Path) -> list[dict]:
    """The leaves' `lods` objects, depth first with children in listed order (the engine's order)."""
    out, stack, seen = [], [tree], 0
    while stack:
        node = stack.pop()
        seen += 1
        if seen > MAX_NODES or not isinstance(node, dict):
            raise LodError(f"{path}: LOD set tree holds a node that is not an object, or over {MAX_NODES:,} nodes")
        if isinstance(node.get("lods"), dict):
            out.append(node["lods"])
        elif isinstance(node.get("children"), list):
            stack.extend(reversed(node["children"]))
    return out


def _levels(leaves: list[dict]) -> list[int]:
    return sorted({int(k) for lods in leaves for k in lods if isinstance(k, str) and k.isdigit()})


def _level_text(levels: list[int]) -> str:
    if levels == list(range(len(levels))):
        return f"levels 0-{levels[-1]}" if len(levels) > 1 else "level 0 only"
    return "levels " + ", ".join(map(str, levels))


def _ranges(leaves: list[dict], level: int, n_files: int, path: Path) -> list[tuple[int, int, int]]:
    """(file, offset, count) of every leaf at `level`, sorted by file then offset; empty ones left out."""
    out = []
    for lods in leaves:
        r = lods.get(str(level))
        if r is None:
            continue
        vals = [r.get(k, 0) if isinstance(r, dict) else None for k in ("file", "offset", "count")]
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in vals) or vals[0] >= n_files:
            raise LodError(
                f"{path}: LOD set level {level} has a range {r!r}; file (below {n_files}), offset and count "
                "must be non-negative integers"
            )
        if vals[2]:
            out.append(tuple(vals))
    return sorted(out)


def _tile_count(tile: Path) -> int | None:
    """The splat count a tile's meta.json states (None when it cannot say; read_sog then says why)."""
    try:
        n = json.loads(tile.read_bytes().decode("utf-8-sig")).get("count")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        return None
    return n if isinstance(n, int) and not isinstance(n, bool) else None


def _shown(names: list[str], k: int = 4) -> str:
    return ", ".join(names[:k]) + (f" and {len(names) - k} more" if len(names) > k else "")


def read_lod(path, level: int | None = None) -> tuple[Model, list[str]]:
    """One level of a LOD set (lod-meta.json, or the folder holding it): level 0 unless given."""
    meta_path = lod_meta_path(os.fspath(path))
    meta = _meta(meta_path)
    leaves = _leaves(meta["tree"], meta_path)
    levels = _levels(leaves)
    if not levels:
        raise LodError(f"{meta_path}: LOD set tree has no leaf with lods")
    level = levels[0] if level is None else level
    if level not in levels:
        raise LodError(f"{meta_path}: the LOD set has no level {level}; it has {_level_text(levels)}")
    names = meta["filenames"]
    ranges = _ranges(leaves, level, len(names), meta_path)
    if not ranges:
        raise LodError(f"{meta_path}: LOD set level {level} holds no splats")
    for (f0, o0, c0), (f1, o1, _) in zip(ranges, ranges[1:]):
        if f0 == f1 and o0 + c0 > o1:
            raise LodError(
                f"{meta_path}: LOD set level {level} takes splats {o1}.. of tile {names[f0]} twice (overlapping ranges)"
            )
    total = sum(c for _, _, c in ranges)
    check_model(total, 0, what=f"{meta_path}: LOD set level {level}", use="read and render")
    base = meta_path.parent
    parts, tiles, degree, first, kinds = [], [], None, None, set()
    for f in sorted({f for f, _, _ in ranges}):
        tile = base / names[f]
        if not tile.is_file():
            raise LodError(f"{tile}: tile {names[f]} of LOD set {meta_path} is missing")
        need = max(o + c for g, o, c in ranges if g == f)
        held = _tile_count(tile)
        if held is not None and held < need:
            raise LodError(
                f"{tile}: tile {names[f]} holds {held} splats (its count); level {level} of {meta_path} "
                f"takes splats up to {need}"
            )
        model, info = sog.read_sog(tile)
        if degree is None:
            degree, first = model.sh_degree, names[f]
        elif model.sh_degree != degree:
            raise LodError(
                f"{tile}: tile {names[f]} holds SH degree {model.sh_degree}, tile {first} {degree} "
                "(a level's tiles must share one)"
            )
        kinds.add(info.model)
        tiles.append(names[f])
        for _, o, c in (r for r in ranges if r[0] == f):
            parts.append(model.subset(slice(o, o + c)))
    merged = Model(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in FIELDS})
    notes = [
        f"LOD set: level {level} of {len(levels)} ({_level_text(levels)}; 0 the finest), "
        f"{total} splats merged from {len(tiles)} tile(s) ({_shown(tiles)}), each read as SOG version 2"
    ]
    if "antialiased" in kinds:
        notes.append(ANTIALIASED_NOTE)
    if meta.get("environment"):
        notes.append(f"the environment ({meta['environment']}) is not read: the model is the level's tiles only")
    return merged, notes


def lod_files(path) -> list[Path]:
    """A LOD set's lod-meta.json and every tile's files (meta.json and the images present), in
    filenames order: what a campaign hashes to know its model."""
    meta_path = lod_meta_path(path)
    try:
        names = _meta(meta_path)["filenames"]
    except (OSError, ModelFileError):
        return [meta_path]
    files = [meta_path]
    for n in names:
        tile = meta_path.parent / n
        files += sog.unbundled_files(tile) if tile.is_file() else []
    return files


def _sniff(probe: Probe) -> bool:
    return is_lod_meta(probe.head)


FORMAT = ModelFormat(
    name="lod",
    title="PlayCanvas LOD set (lod-meta.json)",
    suffixes=(NAME,),
    up="-y",
    sniff=_sniff,
    read=read_lod,
    read_level=read_lod,
)
