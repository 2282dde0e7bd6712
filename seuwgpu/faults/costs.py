"""What each defense costs on this device: memory (the bytes it holds on the device beside the
model, side.device_bytes, and their fraction of the model's stored bytes), time (extra time
per rendered frame as a fraction of an unprotected view, measured here, amortised over its check
schedule) and its exposure (frames drawn from a corrupted model before its check repairs it).

A check defense checks every `check_every` frames (S): its check's time counts once per S frames,
and an upset is drawn for up to S - 1 frames, (S - 1) / 2 on average (schedule.exposure). The
in-pipeline guard clamps on every frame; read-time codes act on every read (exposure 0); with no
defense an upset stays until the model is reloaded (exposure unbounded: "inf" in JSON).

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
from seuwgpu.faults import side
from seuwgpu.faults.check import Checker
from seuwgpu.faults.guard import component_mask, stored_box
from seuwgpu.model import encoding
from seuwgpu.model.budget import check_model
from seuwgpu.render.renderer import Renderer


def defense_costs(
    model, camera, precision: str = "fp32", repeats: int = 7, gpu=None, time_it: bool = True, check_every: int = 1
) -> list:
    """[{name, device_bytes, memory_overhead, check_every, time_fraction, check_fraction,
    exposure_frames, exposure_frames_worst, time_basis, description}] for every defense, the time
    measured on one view of `camera`, a check defense's check amortised over `check_every` frames."""
    rows = []
    parts, device, chunks = _times(model, camera, precision, repeats, gpu) if time_it else ({}, "?", 1)
    t = {d: amortised_time(d, g, c, check_every) for d, (g, c) in parts.items()}
    for d in dfn.DEFENSES:
        frac = t.get(d, float("nan"))
        obj = dfn.get(d)
        ex = obj.upset_exposure(check_every)
        if not time_it:
            basis = "not measured"
        elif d in t:
            basis = f"measured: {device}, {model.n} primitives, {camera.width}x{camera.height}, median of {repeats}"
        else:
            basis = "no GPU implementation (modelled by what it reads)"
        rows.append(
            {
                "name": d,
                "device_bytes": side.device_bytes(d, precision, model.sh_degree, model.n, chunks),
                "memory_overhead": side.device_overhead(d, precision, model.sh_degree, model.n, chunks),
                "check_every": check_every if obj.checked else None,
                "time_fraction": frac,
                "check_fraction": parts[d][1] if obj.checked and d in parts else float("nan"),
                "exposure_frames": ex.expected,
                "exposure_frames_worst": ex.worst,
                "time_basis": basis,
                "description": dfn.get(d).info,
            }
        )
    return rows


def interleaved_samples(
    configs: dict, repeats: int, budget_s: float | None = None, least: int = 3, warm_up: bool = True
) -> dict:
    """{name: [seconds of each round]} of calling each of `configs` (name -> callable that returns
    when the GPU is done). Timed interleaved, round by round, so a drift of the machine's load hits
    every configuration alike. `warm_up`: one untimed round first (pipelines, bind groups).
    `budget_s`: once `least` rounds ran, a round starts only if it would end within that many
    seconds at the rounds' mean so far (a large model's measurement would otherwise outlast the
    campaign it is made for; starting any round that began within the budget overran it by up to
    a round: at 1M primitives a third round of about 1.3 s)."""
    for f in configs.values() if warm_up else ():
        f()
    samples = {k: [] for k in configs}
    t_start = time.perf_counter()
    for r in range(max(int(repeats), 1)):
        spent = time.perf_counter() - t_start
        if budget_s is not None and r >= max(least, 1) and spent + spent / r > budget_s:
            break
        for k, f in configs.items():
            t0 = time.perf_counter()
            f()
            samples[k].append(time.perf_counter() - t0)
    return samples


def interleaved_medians(configs: dict, repeats: int, budget_s: float | None = None, least: int = 3) -> dict:
    """{name: median seconds} of interleaved_samples, after a warm-up round of every configuration."""
    samples = interleaved_samples(configs, repeats, budget_s, least)
    return {k: float(np.median(v)) for k, v in samples.items()}


def _times(model, camera, precision, repeats, gpu) -> tuple[dict, str, int]:
    """({defense: (guard clamp per frame, one check) as fractions of a view}, the device, the
    model's chunks)."""
    # a renderer plus the model's flat copy and bits: an engine's share, not a renderer's
    check_model(model.n, model.sh_degree, "a model of", "time the defenses of")
    r = Renderer(model, [camera], precision, gpu=gpu)
    box = stored_box(r.layout, r.clean_words, precision)
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
    out = {"none": (0.0, 0.0)}
    for d in dfn.DEFENSES:
        if d in masks or d in checkers:
            guard = (med[d] - base) / base if d in masks else 0.0
            check = med[f"check:{d}"] / base if d in checkers else 0.0
            out[d] = (guard, check)
    return out, r.gpu.info.get("device", "?"), r.layout.n_chunks


def amortised_time(defense: str, guard_fraction: float, check_fraction: float, check_every: int = 1) -> float:
    """Extra time per frame (fraction of a view) as the formula gives it: the in-pipeline clamp
    every frame, one timed check over `check_every` frames (0: never). NaN stays NaN. The
    measured schedule (schedule.schedule_samples) is what `defense_costs` reports."""
    d = dfn.get(defense)
    total = guard_fraction if d.guard_fields else 0.0
    if d.checked and check_every:
        total += check_fraction / check_every
    return total
