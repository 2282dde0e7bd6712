"""Transient faults in the pipeline state of one frame: a bit flipped in what one stage hands the
next, in one view, between the two stages (a flip dispatch recorded into the frame's command
stream, renderer.state_fault). The next frame is clean: every stage rewrites its outputs.

Targets: the outputs render/pipeline.py declares fault targets, by their buffers' (shader)
names, each flipped after the stage that declares it (FAULT_TARGETS):
- proj_xy, proj_conic, proj_rgb: the projected per-splat records (screen mean; conic + opacity;
  colour), after projection (binning reads proj_xy and proj_conic too: exact binning pairs tiles
  by the footprint); depth_keys: the depth sort keys, before the depth sort;
- isect_tiles: the (tile) keys of the intersection list, before the tile sort; isect_prims: the
  tile-sorted primitive ids, before the ranges are found;
- ranges: each tile's [start, end) of the sorted list, before compositing;
- image: the compositor's accumulators (colour and transmittance) of one pixel as written at the
  end of its loop (the shader keeps them in registers; the written pixel is where a flip can be
  placed from outside).
The names these targets had before (xy, conic, rgb, depth_key, tile_key, isect_prim, tile_range,
pixel) are still accepted as aliases (FORMER_NAMES); records carry the buffers' names.
A ranges flip that makes a range run backwards or past the intersection list would make the
compositor loop over ~2^32 entries reading out of bounds: on a real GPU a watchdog reset. Such
flips are recorded as `due` (detected unrecoverable error) and not rendered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from seuwgpu.faults.flips import Flips
from seuwgpu.metrics.image import catastrophic
from seuwgpu.model import checks
from seuwgpu.render.pipeline import FAULT_TARGETS

# target -> (the stage it lands after, words per record, words used per record)
TARGETS = {name: (stage.name, o.words, o.used_words) for name, (stage, o) in FAULT_TARGETS.items()}
FORMER_NAMES = {o.former: name for name, (_, o) in FAULT_TARGETS.items() if o.former}
"""The targets' names before they took their buffers' names: accepted, read as the new ones."""
FLOAT_TARGETS = frozenset(
    name for target, (_, o) in FAULT_TARGETS.items() if o.dtype == "f32" for name in (target, o.former) if name
)
"""Targets of float32 words, by either name (records made before the rename carry the former)."""


def check_target(name: str, what: str | None = None) -> str:
    """The target's buffer name (a former name is read as its new one), InputError otherwise."""
    name = FORMER_NAMES.get(name, name) if isinstance(name, str) else name
    return checks.one_of(name, "pipeline-state target", TARGETS, what)


def _record(target: str) -> str:
    return FAULT_TARGETS[target][1].record


TARGET_CHUNK = 0  # a state fault's Flips holds one buffer, the target's: its chunk 0


@dataclass
class _Fault:
    view: int
    point: str
    flips: Flips
    pairs: np.ndarray

    def encode(self, encoder):
        self.flips.encode(encoder, {TARGET_CHUNK: self.pairs})


class StateFaults:
    """Transient pipeline-state flips on an engine's renderer, measured against its clean frame."""

    def __init__(self, engine):
        r = engine.renderer
        if not r.keep_views:
            raise ValueError("pipeline-state faults need the engine's kept clean views (incremental=True)")
        self.engine, self.r = engine, r
        self.totals = np.asarray(r.run(), dtype=np.int64)  # intersections per view (clean)
        self.ranges = r.gpu.read(r.kv_ranges, np.uint32, 0, 8 * r.n_tiles * r.k).reshape(r.k, r.n_tiles, 2)
        self._flips: dict[int, Flips] = {}

    def buffer(self, target: str):
        return self.r.buffers[check_target(target)]

    def records(self, target: str, view: int) -> int:
        r, record = self.r, _record(check_target(target))
        if record == "pair":
            return int(self.totals[view])
        if record == "tile":
            return r.n_tiles
        if record == "pixel":
            return r.width * r.height
        return r.n

    def word(self, target: str, view: int, index: int, comp: int) -> int:
        target = check_target(target)
        per = TARGETS[target][1]
        # the frames of all K views lie in one image; the other buffers hold the view being drawn
        base = view * self.r.width * self.r.height * per if _record(target) == "pixel" else 0
        return base + index * per + comp

    def is_due(self, target: str, view: int, index: int, comp: int, bit: int) -> bool:
        if check_target(target) != "ranges":
            return False
        rng = self.ranges[view, index].astype(np.int64)
        rng[comp] ^= 1 << bit
        return bool(rng[0] > rng[1] or rng[1] > self.totals[view])

    def _arm(self, target: str, view: int, index: int, comp: int, bit: int):
        target = check_target(target)
        buf = self.buffer(target)
        fl = self._flips.get(id(buf))
        if fl is None:
            fl = self._flips[id(buf)] = Flips(self.engine.gpu, [buf])
        pairs = np.array([[self.word(target, view, index, comp), 1 << bit]], np.uint32)
        self.r.state_fault = _Fault(view, TARGETS[target][0], fl, pairs)

    def render(self, target: str, view: int, index: int, comp: int, bit: int) -> np.ndarray:
        """[K, H, W, 4] images of the frame with the flip (DUE flips are refused)."""
        if self.is_due(target, view, index, comp, bit):
            raise ValueError(f"{target}[{index}] word {comp} bit {bit} is a DUE flip (range past the list)")
        self._arm(target, view, index, comp, bit)
        try:
            return self.engine.render_current("none")[0]
        finally:
            self.r.state_fault = None

    def inject(self, target: str, view: int, index: int, comp: int, bit: int) -> dict:
        """Flip bit `bit` of word `comp` of record `index` of `target` in view `view`, render the
        frame (all views; the others clean), measure against the clean frame."""
        e, target = self.engine, check_target(target)
        rec = {"target": target, "view": view, "index": index, "comp": comp, "bit": bit}
        if self.is_due(target, view, index, comp, bit):
            nan = float("nan")
            rec.update(footprint=nan, peak_error=nan, psnr=nan, ssim=nan, nonfinite=False, due=True)
            rec["catastrophic"] = False
            return rec
        self._arm(target, view, index, comp, bit)
        try:
            m = e.measure_current("none")
        finally:
            self.r.state_fault = None
        rec.update({k: m[k] for k in ("footprint", "peak_error", "psnr", "ssim")}, nonfinite=bool(m["nonfinite"]))
        rec["due"] = False
        rec["catastrophic"] = bool(catastrophic(rec["footprint"], rec["nonfinite"]))
        return rec


def state_campaign(
    engine, targets=tuple(TARGETS), samples: int = 20, bits=range(32), seed: int = 0, progress=None, rows=None
):
    """Records of `samples` flips per (target, bit) cell, record, word and view uniform. `rows`: a
    list the records are appended to as they are measured (what an interrupted run has done).
    Records already in it are those of a resumed run of the same arguments (its first records, in
    order): the run goes on after them, replaying their draws without rendering them, so it flips
    what an uninterrupted run would."""
    targets = [check_target(t) for t in targets]  # all refused before any rendering
    bits = [int(b) for b in bits]
    for b in bits:
        if not 0 <= b < 32:  # every pipeline-state word is 32 bits
            raise ValueError(f"bit {b} is out of range for a pipeline-state word (0..31)")
    sf = StateFaults(engine)
    rng = np.random.default_rng(seed)
    rows = [] if rows is None else rows
    done, drawn = len(rows), 0  # records of a resumed run; flips drawn
    for t in targets:
        for bit in bits:
            for _ in range(samples):
                v = int(rng.integers(engine.k))
                n = sf.records(t, v)
                if n == 0:
                    continue
                i, c = int(rng.integers(n)), int(rng.integers(TARGETS[t][2]))
                drawn += 1
                if drawn <= done:
                    continue  # measured before the run was resumed
                rows.append(sf.inject(t, v, i, c, bit) | {"scene": engine.scene, "weight": float(n)})
                if progress:
                    progress()
    if done > drawn:
        raise ValueError(f"{done} records given for a pipeline-state run of {drawn}")
    return pd.DataFrame(rows)
