"""Coverage of every defense under every fault model, by exhaustive sweep (faults/coverage.py):
the table of docs/defenses.md.

    python tools/defense_coverage.py [--scene leica-sofort] [--prims 4] [--precision fp32] [--json out.json]

Sweeps every single flip, every 2-8-bit burst, every same-bit pair of values (mcu_prim), the 28
dangerous-cell pairs, RANDOM_DRAWS random values per value and the neighbouring-word upset on the
first `--prims` primitives of the model, and every pair of (value, bit) cells of its first
primitive. scalebound's class table and cellbox's boxes are the whole model's.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.faults import coverage  # noqa: E402
from seuwgpu.faults import defenses as dfn  # noqa: E402
from seuwgpu.faults.guard import support_box  # noqa: E402
from seuwgpu.model import encoding  # noqa: E402
from seuwgpu.model.scenes import make_scene  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="leica-sofort")
    ap.add_argument("--prims", type=int, default=4)
    ap.add_argument("--precision", default="fp32")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    model = make_scene(a.scene)
    rows = encoding.to_bits(model.flat(), a.precision)
    box = support_box(model, a.precision)
    cells = dfn.get("cellbox").model_state(rows, a.precision, model.sh_degree)
    t0 = time.perf_counter()
    table = coverage.coverage_table(rows[: a.prims], a.precision, model.sh_degree, box, cells, index=np.arange(a.prims))
    print(
        f"{a.scene}, {a.precision}, primitives 0..{a.prims - 1}: caught % (restored %) of every fault, "
        f"{time.perf_counter() - t0:.0f} s"
    )
    print(coverage.markdown(table))
    print("\nof the faults that touch a sign or exponent bit:")
    print(coverage.markdown(table, harmful=True))
    if a.json:
        a.json.write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
