"""The render pipeline, declared once: its stages in order (render/stage.py).

The renderer records them in this order, the reference renderer runs their twins in it, and the
pipeline-state fault targets, the kept-view copies and the benchmark's per-stage times are read
from their declared outputs. A new stage is a shader, a module declaring its `Stage`, and its
entry here (CONTRIBUTING.md)."""

from __future__ import annotations

from seuwgpu.render.bin import EMIT, RANGES
from seuwgpu.render.composite import COMPOSITE
from seuwgpu.render.project import PROJECT
from seuwgpu.render.sort import DEPTH_SORT, TILE_SORT
from seuwgpu.render.stage import Output, Stage

PIPELINE: tuple[Stage, ...] = (PROJECT, DEPTH_SORT, EMIT, TILE_SORT, RANGES, COMPOSITE)

FAULT_TARGETS: dict[str, tuple[Stage, Output]] = {o.name: (s, o) for s in PIPELINE for o in s.outputs if o.fault}
"""Pipeline-state fault targets (faults/state.py), in pipeline order: a flip in buffer NAME lands
after the stage that declares it a fault target."""

KEPT: tuple[Output, ...] = tuple({o.name: o for s in PIPELINE for o in s.outputs if o.kept}.values())
"""The outputs a keep_views renderer copies per view (as `kv_<name>`) for the incremental
re-compositor: the last stage's declaration of each."""


def run_twins(**context) -> dict:
    """Every stage's twin in order on `context` (the first stage's inputs and every stage's
    params); returns the context with every stage's outputs, by name."""
    state = dict(context)
    for stage in PIPELINE:
        state.update(stage.twin(**state))
    return state
