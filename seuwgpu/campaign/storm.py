"""Fault storms: k upsets per frame accumulating in the stored model over time, the memory
reloaded from the golden copy every S frames (scrubbing), and the image quality of every frame
under each defense.

Per frame: k new upsets, each anchored at a stored bit drawn uniformly (the dose campaign's draw)
and shaped by the fault model (`fault`: a single-bit flip by default; a burst of 2-8 bits, a
random value, or a multi-cell upset over two values of one primitive or the neighbouring word of
the device layout: faults/sites.py), written into the memory state; then the defense acts.
Defenses that check and repair memory
(a checked defense, `Defense.writes_back`: parity culls, checksum and parity4r reload, scalebound clamps) write their
repair back, so a repaired primitive stays repaired; read-time defenses (guard, ECC, duplication)
leave the memory corrupted and correct what the renderer reads, so upsets pile up in one value
until the scrub (two in an ECC word are no longer correctable). A check defense checks before
every `check_every`-th frame (frames 0, S, 2S, ...: its check schedule); between checks the
frames are drawn from the memory as it is (its pipeline clamp, scalebound's, still acts), so an
upset is seen for its exposure (schedule.exposure). The frame is rendered and measured against
the clean render (all K views); a frame that draws exactly what its arm's clean frame or the frame
before it drew (the same stored bits through the same views: the renderer is deterministic) takes that frame's
metrics instead of rendering it again (REUSE_DRAWN), which makes a `defenses --visible` window,
one state from its upset to its reload, cost a few renders instead of one a frame. Every arm sees
the same upset sequence (paired); `upsets` gives a hand-made one (a list of frames, each a list of
sites).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.errors import TooBig
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.sites import (
    Site,
    apply_sites,
    check_fault_model,
    draw_uniform_sites,
    model_bits,
    multi_cell_sites,
)
from seuwgpu.metrics.image import catastrophic
from seuwgpu.model.budget import HOST_SHARE, available_host_bytes, available_text, gb

SITE_BYTES = 320  # host bytes of one drawn upset (a Site), measured with tracemalloc
ROW_BYTES = 700  # host bytes of one record (a dict) before the DataFrame is made
# a frame that draws what the clean frame or the frame before it drew takes its metrics (False:
# every frame rendered): a window of `defenses --visible` draws one state from its upset to its reload
REUSE_DRAWN = True


def check_storm(k: int, frames: int, arms: int):
    """Refuse a storm whose upsets (all drawn before the first frame) and records would not fit
    in host memory, saying how many frames fit."""
    per_frame = k * SITE_BYTES + arms * ROW_BYTES
    need, have = frames * per_frame, HOST_SHARE * available_host_bytes()
    if need > have:
        raise TooBig(
            f"a storm of {frames:,} frames of k = {k:,} upsets under {arms} defense(s) needs about {gb(need)} "
            f"of host memory for its upsets and records; {available_text(have)}: at most "
            f"{max(1, int(have // per_frame)):,} frames fit"
        )


def storm(
    engine,
    k: int,
    frames: int,
    scrub_every: int,
    defenses=("none",),
    seed: int = 0,
    progress=None,
    rows=None,
    check_every: int = 1,
    upsets=None,
    fault: str = "bit",
):
    """Records (one per frame and defense) of a fault storm; scrub_every 0 = never. `rows`: a list
    the records are appended to as they are measured (what an interrupted storm has done:
    `storm_records(rows)`). Records already in it are those of a resumed storm of the same
    arguments (its first records, in order: the arms one after the other, frame by frame): the storm
    goes on after them, drawing the same upsets (all are drawn before the first frame) and replaying
    the measured frames' upsets, repairs and scrubs into the memory state without rendering them.
    `fault`: the fault model of every drawn upset (sites.FAULT_MODELS; "bit" draws as before)."""
    check_fault_model(fault)
    if k < 1 or frames < 1 or scrub_every < 0 or check_every < 1:
        raise ValueError(
            "storm needs k >= 1, frames >= 1, scrub_every >= 0, check_every >= 1 "
            f"(got {k}, {frames}, {scrub_every}, {check_every})"
        )
    if upsets is not None:
        upsets = [list(u) for u in upsets]
        if len(upsets) != frames:
            raise ValueError(f"a hand-made storm of {frames} frames needs {frames} lists of upsets (got {len(upsets)})")
    else:
        rng = np.random.default_rng(seed)
        first = draw_uniform_sites(engine.n, engine.degree, engine.precision, k, rng)  # k over the stored bits: refused
        check_storm(k, frames, len(defenses))
        upsets = [
            first,
            *(draw_uniform_sites(engine.n, engine.degree, engine.precision, k, rng) for _ in range(frames - 1)),
        ]
        if fault != "bit":
            upsets = [shape_upsets(u, fault, engine.n, engine.degree, engine.precision, rng) for u in upsets]
    rows = [] if rows is None else rows
    done = len(rows)  # records of a resumed storm
    if done > frames * len(defenses):
        raise ValueError(f"{done} records given for a storm of {frames * len(defenses)}")
    for a, d in enumerate(defenses):
        arm = dfn.get(d)
        if (a + 1) * frames <= done:
            continue  # every frame of this arm measured before the storm was resumed
        clean_frame = last_frame = None  # (what it drew, its metrics): the clean frame's, the last one's
        memory: dict[int, np.ndarray] = {}  # primitive -> its stored bits now (absent: clean)
        for f in range(frames):
            if scrub_every and f and f % scrub_every == 0:
                memory.clear()  # reloaded from the golden copy
            for s in upsets[f]:
                row = memory.get(s.primitive)
                if row is None:
                    row = engine.primitive_bits([s.primitive])[0]
                c = s.flat_component()
                row[c] = apply_sites(row[c : c + 1], [s])[0]
                memory[s.primitive] = row
            prims = np.sort(np.fromiter(memory, dtype=np.int64, count=len(memory)))
            clean = engine.primitive_bits(prims)
            now = np.stack([memory[p] for p in prims]) if prims.size else clean
            # a per-word frame code's clean pair partners: dropped with a failing pair (Defense.partners)
            prims, clean, now = engine.with_partners(prims, clean, now, d)
            checking = not arm.checked or f % check_every == 0  # a check defense acts on its schedule
            seen, after = engine.frame_through(prims, clean, now, d) if prims.size and checking else (now, None)
            if arm.writes_back and checking:  # the repair is written back
                memory = {int(p): r.copy() for p, r in zip(prims, seen)}
            # measured before the storm was resumed: its memory state replayed, not rendered (below)
            if after is not None:  # repaired between this frame and the next (the check inside the frame)
                memory = {int(p): r.copy() for p, r in zip(prims, after)}
            if a * frames + f < done:
                continue
            # a frame that draws what the clean frame or the frame before it drew (the same stored
            # bits through the same views: from an upset to the reload, or clean) is that frame, bit
            # for bit: its metrics are taken, not rendered again
            changed = (seen != clean).any(axis=1) if prims.size else np.zeros(0, bool)
            key = prims[changed].tobytes() + b"|" + np.ascontiguousarray(seen[changed]).tobytes()
            m = None
            for known in (clean_frame, last_frame) if REUSE_DRAWN else ():
                if known is not None and known[0] == key:
                    m = known[1]
            if m is None:
                xors = engine.xor_rows(prims, clean, seen)
                engine.flips.apply(xors)
                try:
                    m = engine.measure_current(d)
                finally:
                    engine.flips.apply(xors)
            if changed.any():
                last_frame = (key, m)
            else:
                clean_frame = (key, m)
            corrupted = int((now != clean).any(axis=1).sum()) if prims.size else 0
            rows.append(
                {
                    "scene": engine.scene,
                    "precision": engine.precision,
                    "defense": d,
                    "frame": f,
                    "k": k,
                    "scrub_every": scrub_every,
                    "check_every": check_every if arm.checked else 0,
                    "corrupted_primitives": corrupted,
                    "footprint": m["footprint"],
                    "psnr": m["psnr"],
                    "ssim": m["ssim"],
                    "peak_error": m["peak_error"],
                    "nonfinite": bool(m["nonfinite"]),
                }
            )
            if progress:
                progress()
    return storm_records(rows)


def shape_upsets(anchors: list[Site], fault: str, n: int, degree: int, precision: str, rng) -> list[Site]:
    """The sites of upsets of fault model `fault` anchored at single-bit sites `anchors` (one
    random number each from `rng`): a value model's value, a burst's width, a multi-cell
    upset's partner value (sites.model_bits, sites.multi_cell_sites)."""
    out = []
    for a, r in zip(anchors, rng.integers(0, 2**63, size=len(anchors))):
        bits, op, value = model_bits(fault, a.bits[0], precision, int(r))
        out.extend(
            multi_cell_sites(
                Site(a.field, a.primitive, a.component, bits, op, value), fault, n, degree, precision, int(r)
            )
        )
    return out


def storm_records(rows: list) -> pd.DataFrame:
    # the rows of a resumed storm, read back from its partial records, carry `catastrophic` already
    df = pd.DataFrame(rows).drop(columns="catastrophic", errors="ignore")
    df["catastrophic"] = catastrophic(df["footprint"].to_numpy(), df["nonfinite"].to_numpy())
    return df
