"""What each defense costs on this device: memory overhead (fraction of the model's stored bytes,
defenses.memory_overhead) and time (extra time per rendered view as a fraction of an unprotected
view, measured here).

Time is measured for what runs on the GPU: the in-pipeline guard clamp (guard, selective,
scalebound) and the per-primitive checks of shaders/check.wgsl (parity, parity4, parity4r,
checksum, scalebound), one check per rendered view with its 4-byte readback of the detection count
(repairs only happen after a detection, which a healthy device never makes). ECC, ecc_crit and
duplication are modelled by what they read (defenses.read) and have no GPU decoder: their time is
NaN, never a made-up number. Configurations are timed interleaved, medians of `repeats` rounds,
so a busy machine slows them alike.
"""

from __future__ import annotations

import time

import numpy as np

from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.check import Checker
from seuwgpu.faults.guard import component_mask, support_box
from seuwgpu.model import encoding
from seuwgpu.model.budget import check_model
from seuwgpu.render.renderer import Renderer


def defense_costs(model, camera, precision: str = "fp32", repeats: int = 7, gpu=None, time_it: bool = True) -> list:
    """[{name, memory_overhead, time_fraction, time_basis, description}] for every defense, the time
    measured on one view of `camera`."""
    rows = []
    t = _times(model, camera, precision, repeats, gpu) if time_it else {}
    for d in dfn.DEFENSES:
        frac = t.get(d, float("nan"))
        if not time_it:
            basis = "not measured"
        elif d in t:
            basis = (
                f"measured: {t['_device']}, {model.n} primitives, {camera.width}x{camera.height}, median of {repeats}"
            )
        else:
            basis = "no GPU implementation (modelled by what it reads)"
        rows.append(
            {
                "name": d,
                "memory_overhead": dfn.memory_overhead(d, precision, model.sh_degree, model.n),
                "time_fraction": frac,
                "time_basis": basis,
                "description": dfn.get(d).info,
            }
        )
    return rows


def interleaved_medians(configs: dict, repeats: int, budget_s: float | None = None, least: int = 3) -> dict:
    """{name: median seconds} of calling each of `configs` (name -> callable that returns when the
    GPU is done), after one warm-up round (pipelines, bind groups). Timed interleaved, round by
    round, so a drift of the machine's load hits every configuration alike. `budget_s`: no round
    starts once the timed rounds took that long and at least `least` ran (a large model's
    measurement would otherwise outlast the campaign it is made for)."""
    for f in configs.values():
        f()
    samples = {k: [] for k in configs}
    t_start = time.perf_counter()
    for r in range(max(int(repeats), 1)):
        if budget_s is not None and r >= least and time.perf_counter() - t_start > budget_s:
            break
        for k, f in configs.items():
            t0 = time.perf_counter()
            f()
            samples[k].append(time.perf_counter() - t0)
    return {k: float(np.median(v)) for k, v in samples.items()}


def _times(model, camera, precision, repeats, gpu) -> dict:
    # a renderer plus the decoded model, its flat copy and bits: an engine's share, not a renderer's
    check_model(model.n, model.sh_degree, "a model of", "time the defenses of")
    r = Renderer(model, [camera], precision, gpu=gpu)
    box = support_box(r.layout.decode(r.clean_words), precision)
    clean = encoding.to_bits(model.flat(), precision)  # what the chunks hold (layout.encode)
    r.set_guard(box.rows(), 0)
    checkers = {d.name: Checker(r, d.name, clean, box) for d in dfn.REGISTRY.values() if d.checked}
    masks = {d: component_mask(f, r.degree) for d, f in dfn.pipeline_guards().items()}

    def view(mask):
        r.set_guard(None, mask)
        r.run()

    configs = {"none": lambda: view(0)}
    for d, m in masks.items():
        configs[d] = lambda m=m: view(m)
    for d, c in checkers.items():
        configs[f"check:{d}"] = c.run
    med = interleaved_medians(configs, repeats)
    r.set_guard(None, 0)
    base = med["none"]
    out = {"none": 0.0, "_device": r.gpu.info.get("device", "?")}
    for d in dfn.DEFENSES:
        extra = 0.0
        known = False
        if d in masks:
            extra += med[d] - base
            known = True
        if d in checkers:
            extra += med[f"check:{d}"]
            known = True
        if known:
            out[d] = extra / base
    return out
