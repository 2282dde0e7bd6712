"""Build the API reference (docs/api/) from the public API's docstrings with pdoc.

    python tools/build_docs.py [--out docs/api]

tests/test_docs.py builds it again into a temporary folder and fails when the committed copy
differs, so the reference cannot go stale: re-run this after changing seuwgpu/api/.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def build(out: Path) -> list[Path]:
    import pdoc
    import pdoc.render

    pdoc.render.configure(docformat="markdown", show_source=False, search=False, footer_text="seuwgpu")
    if out.exists():
        shutil.rmtree(out)
    pdoc.pdoc("seuwgpu.api", output_directory=out)
    return sorted(p for p in out.rglob("*") if p.is_file())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "api")
    args = ap.parse_args(argv)
    for p in build(args.out):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
