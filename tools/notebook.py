"""Write and execute the example notebook (docs/example.ipynb) that drives seuwgpu from Python.

    python tools/notebook.py [--out docs/example.ipynb] [--small]

The notebook is written from the cells below and executed with nbclient, so the committed copy
carries its outputs. tests/test_docs.py executes the same cells at small sizes (`--small`, or
SEUWGPU_NOTEBOOK_SMALL=1 in the kernel's environment) so the example cannot rot.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CELLS = [
    (
        "markdown",
        """# seuwgpu from Python

A real trained model (the CC0 Scaniverse capture `leica-sofort`, embedded in the package), seen
from orbit views that frame it; one flip of a scale's sign bit with and without the support guard;
a small campaign over the dangerous bits; a plot of its records. Every call is part of the public
API (`import seuwgpu as sg`); see the API reference in `docs/api/`.""",
    ),
    (
        "code",
        """import os, tempfile
import matplotlib.pyplot as plt
import numpy as np
import seuwgpu as sg

SMALL = os.environ.get("SEUWGPU_NOTEBOOK_SMALL") == "1"  # the test suite runs this notebook small
SIZE = (96, 72) if SMALL else (320, 240)
scene = sg.load_model("leica-sofort")
print(f"{scene.name}: {scene.model.n:,} primitives, SH degree {scene.model.sh_degree}")""",
    ),
    ("markdown", "## Render\n\nTwo orbit views; `render_views` returns unclamped float32 frames `[K, H, W, 3]`."),
    (
        "code",
        """views = sg.cameras(scene, views=2, size=SIZE)
images = sg.render_views(scene, views)
fig, axes = plt.subplots(1, len(images), figsize=(4 * len(images), 3))
for ax, img in zip(axes, images):
    ax.imshow(np.clip(img, 0, 1)); ax.axis("off")
plt.show()""",
    ),
    (
        "markdown",
        """## One upset: the sign bit of a log-scale

Bit 31 of a stored fp32 log-scale flips its sign: a small splat becomes huge. Without
`primitive=`, `inject` tries a sample of primitives and keeps the most harmful. The footprint is
the fraction of pixels whose colour changed by more than 1/255.""",
    ),
    (
        "code",
        """inj = sg.inject(scene, views, field="log_scales", bit=31, defenses=["none", "guard"],
                sample=8 if SMALL else 64)
print(f"primitive {inj.site['primitive']}: {inj.site['clean_value']:.4g} -> {inj.site['corrupted_value']:.4g}")
inj.table()[["defense", "footprint", "peak_error", "psnr", "catastrophic"]]""",
    ),
    (
        "code",
        """panels = [("clean", inj.frames["clean"][0]), ("faulted", inj.frames["none"][0]),
          ("guarded", inj.frames["guard"][0]), ("|error| unguarded", inj.error_map("none")[0])]
fig, axes = plt.subplots(1, 4, figsize=(16, 3))
for ax, (title, img) in zip(axes, panels):
    ax.imshow(np.clip(img, 0, 1), cmap="magma"); ax.set_title(title); ax.axis("off")
plt.show()""",
    ),
    (
        "markdown",
        """## A small campaign

Random primitives, every exponent and sign bit of the log-scales and the opacity, each upset
rendered with and without the guard. `progress=True` shows a progress bar; re-running the cell
resumes the run instead of starting over.""",
    ),
    (
        "code",
        """run = os.path.join(tempfile.mkdtemp(), "run")
spec = {
    "name": "notebook", "seed": 1, "views": 2, "size": f"{SIZE[0]}x{SIZE[1]}", "batch": 64,
    "scenes": [{"scene": "leica-sofort"}],
    "single": {"precisions": ["fp32"], "fields": ["log_scales", "opacity"], "bits": list(range(23, 32)),
               "samples": 2 if SMALL else 24, "defenses": ["none", "guard"]},
}
stats = sg.run_campaign(spec, run, progress=True)
records = sg.read_records(run)
print(f"{stats['injections']} injections, {len(records)} records")""",
    ),
    (
        "code",
        """rates = records.groupby(["field", "bit", "defense"])["catastrophic"].mean().unstack("defense")
ax = rates.plot.bar(figsize=(12, 3), ylabel="catastrophic share of injections")
ax.set_title("Catastrophic upsets by stored bit, with and without the guard")
plt.show()
rates""",
    ),
]


def notebook():
    import nbformat

    nb = nbformat.v4.new_notebook()
    new = {"markdown": nbformat.v4.new_markdown_cell, "code": nbformat.v4.new_code_cell}
    nb.cells = [new[kind](source) for kind, source in CELLS]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    return nb


def execute(nb, small: bool, timeout: int = 1200):
    """Run every cell in a fresh kernel (in a temporary working folder)."""
    from nbclient import NotebookClient

    env_before = os.environ.get("SEUWGPU_NOTEBOOK_SMALL")
    os.environ["SEUWGPU_NOTEBOOK_SMALL"] = "1" if small else "0"  # the kernel inherits it
    try:
        with tempfile.TemporaryDirectory() as cwd:
            NotebookClient(nb, timeout=timeout, kernel_name="python3", resources={"metadata": {"path": cwd}}).execute()
    finally:
        if env_before is None:
            os.environ.pop("SEUWGPU_NOTEBOOK_SMALL", None)
        else:
            os.environ["SEUWGPU_NOTEBOOK_SMALL"] = env_before
    return nb


def main(argv=None) -> int:
    import nbformat

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "example.ipynb")
    ap.add_argument("--small", action="store_true", help="small frames and samples (what the tests run)")
    args = ap.parse_args(argv)
    nb = execute(notebook(), args.small)
    nbformat.write(nb, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
