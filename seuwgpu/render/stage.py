"""A render stage, declared once: its name, the buffers it reads and writes (named as its shader's
bindings), how it records its passes, and its numpy twin, which takes and returns the same names.

The renderer (`encode_view`, `encode_batch`), the numpy reference renderer, the pipeline-state
faults, the benchmark's per-stage timing, the kept-view copies and the stage test harness are all
loops over `render/pipeline.py`'s PIPELINE, so a stage is written in one place (CONTRIBUTING.md,
"How to add a render stage").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

RECORDS = ("primitive", "pair", "tile", "pixel")
"""What one record of a buffer is: a buffer holds one record per primitive (of a view), per
(tile, primitive) pair of the view's list, per tile or per pixel."""

KEPT_PREFIX = "kv_"
"""A kept-view copy of buffer NAME is KEPT_PREFIX + NAME (the incremental re-compositor's
inputs, shaders/variants.wgsl)."""


@dataclass(frozen=True)
class Output:
    """A buffer a stage writes. `words`: u32 words per record; `used`: the words that carry data
    (a state fault flips one of them); `dtype`: how its words read; `exact`: the GPU equals the twin
    bit for bit (else float32 to the stage's documented tolerance, render/project.py); `fault`: a
    pipeline-state target (faults/state.py): a flip lands here, after this stage; `kept`: copied
    per view for the incremental re-compositor; `twinned`: the twin computes it (else a
    by-product its consumer's tests check); `former`: the state-fault target's name before the
    buffers took their shader names (still accepted)."""

    name: str
    words: int
    record: str
    dtype: str = "u32"
    used: int | None = None
    exact: bool = True
    fault: bool = False
    kept: bool = False
    twinned: bool = True
    former: str = ""

    def __post_init__(self):
        if self.record not in RECORDS:
            raise ValueError(f"output {self.name}: record {self.record!r} is not one of {RECORDS}")

    @property
    def used_words(self) -> int:
        return self.words if self.used is None else self.used

    @property
    def kept_name(self) -> str:
        return KEPT_PREFIX + self.name

    def view_of(self, words: np.ndarray) -> np.ndarray:
        """u32 words -> records [n, words] of this buffer's type."""
        arr = np.ascontiguousarray(words, np.uint32).view(np.float32 if self.dtype == "f32" else np.uint32)
        return arr.reshape(-1, self.words)


@dataclass(frozen=True)
class Stage:
    """One render stage. `inputs` / `outputs`: buffers named as the shader binds them; `params`:
    what else its twin needs (a camera, the tile grid, ...), named as the reference renderer's
    context holds it; `run(encoder, buffers, renderer, slot, views)` records its passes for view
    `slot` (or a batched renderer's K views: `slot` = the batched Binning slot, `views` all K);
    `twin_of(**inputs, **params)` returns its outputs by name; `split_before`: on a GPU the
    renderer submits what it recorded before this stage (render/renderer.py)."""

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[Output, ...]
    run: Callable = field(repr=False)
    twin_of: Callable = field(repr=False)
    params: tuple[str, ...] = ()
    split_before: bool = False

    def encode(self, encoder, buffers: dict, renderer, slot: int, views: range):
        """Record this stage's passes into `encoder`. Of `buffers` ({name: buffer}) it is given
        only those it declares: a stage binds nothing it does not declare."""
        declared = {name: buffers[name] for name in (*self.inputs, *self.output_names) if name in buffers}
        self.run(encoder, declared, renderer, slot, views)

    def twin(self, **arrays) -> dict:
        """The numpy twin on the named inputs (and params); its outputs carry the buffers' names."""
        missing = [name for name in (*self.inputs, *self.params) if name not in arrays]
        if missing:
            raise TypeError(f"stage {self.name}'s twin needs {', '.join(missing)}")
        got = self.twin_of(**{name: arrays[name] for name in (*self.inputs, *self.params)})
        want = {o.name for o in self.outputs if o.twinned}
        if set(got) != want:
            raise RuntimeError(f"stage {self.name}'s twin returned {sorted(got)}, not its outputs {sorted(want)}")
        return got

    @property
    def output_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.outputs)
