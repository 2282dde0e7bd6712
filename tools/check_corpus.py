"""Check an assembled corpus against its manifest: load every model and compare its primitives and
SH degree with what the manifest says.

    python tools/check_corpus.py /work/corpus            # every model in the folder's corpus.json

A LOD set (format sog-lod) is checked without a LOD loader: the finest level's count in
lod-meta.json (its tree nodes' lods["0"].count summed) must equal the manifest's primitives and
the `count` of the tiles that level points to, and each of those tiles (a plain SOG folder) is
loaded and must hold that many primitives at the manifest's SH degree. Prints one line a model;
exits 1 if any differs.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def lod_level0(lod_meta: Path) -> tuple[int, dict[str, int]]:
    """(the finest level's count, {tile meta.json: the count the tree assigns it})."""
    meta = json.loads(lod_meta.read_text())
    tiles: dict[str, int] = {}

    def walk(node):
        lod = node.get("lods", {}).get("0")
        if lod is not None:
            name = meta["filenames"][lod["file"]]
            tiles[name] = tiles.get(name, 0) + lod["count"]
        for child in node.get("children", []):
            walk(child)

    walk(meta["tree"])
    return sum(tiles.values()), tiles


def check(folder: Path) -> bool:
    from seuwgpu import api

    manifest = {m.name: m for m in api.corpus_models()}
    ok = True
    for entry in json.loads((folder / "corpus.json").read_text())["models"]:
        m, path = manifest[entry["name"]], folder / entry["model"]
        if m.format == "sog-lod":
            total, tiles = lod_level0(path)
            found = []
            for tile, count in tiles.items():
                model = api.load_model(path.parent / Path(tile).parent).model
                found.append((model.n, model.sh_degree))
                ok &= model.n == count
            good = total == m.primitives and all(d == m.sh_degree for _, d in found)
            n, degree = total, found[0][1]
        else:
            model = api.load_model(path).model
            n, degree = model.n, model.sh_degree
            good = n == m.primitives and degree == m.sh_degree
        ok &= good
        print(f"{'ok ' if good else 'BAD'} {m.name:<10} {n:>9,} primitives, SH {degree} ({m.format}: {entry['model']})")
    return ok


if __name__ == "__main__":
    sys.exit(0 if check(Path(sys.argv[1] if len(sys.argv) > 1 else ".")) else 1)
