"""Transient faults in the pipeline state of one frame: a bit flipped in what one stage hands the
next, in one view, between the two stages (a flip dispatch recorded into the frame's command
stream, renderer.state_fault). The next frame is clean: every stage rewrites its outputs.

Targets (the stage after which the flip lands, the buffer, its words per record):
- xy, conic, rgb: the projected per-splat records (screen mean; conic + opacity; colour), after
  projection (binning reads xy and conic too: exact binning pairs tiles by the footprint);
  depth_key: the depth sort keys, before the depth sort;
- tile_key: the (tile) keys of the intersection list, before the tile sort; isect_prim: the
  tile-sorted primitive ids, before the ranges are found;
- tile_range: each tile's [start, end) of the sorted list, before compositing;
- pixel: the compositor's accumulators (colour and transmittance) of one pixel as written at the
  end of its loop (the shader keeps them in registers; the written pixel is where a flip can be
  placed from outside).
A tile_range flip that makes a range run backwards or past the intersection list would make the
compositor loop over ~2^32 entries reading out of bounds: on a real GPU a watchdog reset. Such
flips are recorded as `due` (detected unrecoverable error) and not rendered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from seuwgpu.faults.flips import Flips
from seuwgpu.metrics.image import catastrophic

# target -> (stage point, words per record, words used per record)
TARGETS = {
    "xy": ("projected", 2, 2),
    "conic": ("projected", 4, 4),
    "rgb": ("projected", 4, 3),
    "depth_key": ("projected", 1, 1),
    "tile_key": ("emitted", 1, 1),
    "isect_prim": ("sorted", 1, 1),
    "tile_range": ("ranged", 2, 2),
    "pixel": ("composited", 4, 4),
}


def check_target(name: str) -> str:
    if name not in TARGETS:
        raise ValueError(f"unknown pipeline-state target {name!r}; expected one of {', '.join(TARGETS)}")
    return name


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
        r, p, b = self.r, self.r.projection, self.r.binning
        return {
            "xy": p.xy,
            "conic": p.conic,
            "rgb": p.rgb,
            "depth_key": p.depth_keys,
            "tile_key": b.isect_tiles,
            "isect_prim": b.isect_prims,
            "tile_range": b.ranges,
            "pixel": r.image,
        }[check_target(target)]

    def records(self, target: str, view: int) -> int:
        r = self.r
        if target in ("tile_key", "isect_prim"):
            return int(self.totals[view])
        if target == "tile_range":
            return r.n_tiles
        if target == "pixel":
            return r.width * r.height
        return r.n

    def word(self, target: str, view: int, index: int, comp: int) -> int:
        per = TARGETS[target][1]
        base = view * self.r.width * self.r.height * 4 if target == "pixel" else 0
        return base + index * per + comp

    def is_due(self, target: str, view: int, index: int, comp: int, bit: int) -> bool:
        if target != "tile_range":
            return False
        rng = self.ranges[view, index].astype(np.int64)
        rng[comp] ^= 1 << bit
        return bool(rng[0] > rng[1] or rng[1] > self.totals[view])

    def _arm(self, target: str, view: int, index: int, comp: int, bit: int):
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
        e = self.engine
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
