"""Check an assembled corpus against its manifest: load every model and compare its primitives and
SH degree with what the manifest says.

    python tools/check_corpus.py /work/corpus            # every model in the folder's corpus.json

A LOD set loads at its finest level. A model the publisher also published in other formats (the
manifest's `also`) is loaded in each of them too and must hold the same primitives at the same
SH degree. Prints one line a model (and one a further format); exits 1 if any differs.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def check(folder: Path) -> bool:
    from seuwgpu import api

    manifest = {m.name: m for m in api.corpus_models()}
    ok = True
    for entry in json.loads((folder / "corpus.json").read_text())["models"]:
        m, path = manifest[entry["name"]], folder / entry["model"]
        model = api.load_model(path).model
        n, degree = model.n, model.sh_degree
        good = n == m.primitives and degree == m.sh_degree
        for fmt, rel in m.also.items():  # the same model in the publisher's other formats
            other = api.load_model(folder / m.name / rel).model  # `also` paths: in the model's folder
            same = other.n == n and other.sh_degree == degree
            good &= same
            flag = "" if same else " DIFFERS"
            print(f"    {m.name} as {fmt} ({rel}): {other.n:,} primitives, SH {other.sh_degree}{flag}")
        ok &= good
        print(f"{'ok ' if good else 'BAD'} {m.name:<10} {n:>9,} primitives, SH {degree} ({m.format}: {entry['model']})")
    return ok


if __name__ == "__main__":
    sys.exit(0 if check(Path(sys.argv[1] if len(sys.argv) > 1 else ".")) else 1)
