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
from seuwgpu.faults.check import Checker, DeviceRepair, FrameCheck
from seuwgpu.faults.guard import component_mask, stored_box
from seuwgpu.faults.schedule import median_interval
from seuwgpu.model import encoding
from seuwgpu.model.budget import check_model
from seuwgpu.render.renderer import Renderer


def defense_costs(
    model, camera, precision: str = "fp32", repeats: int = 7, gpu=None, time_it: bool = True, check_every: int = 1
) -> list:
    """[{name, device_bytes, memory_overhead, check_every, time_fraction, time_lo, time_hi,
    check_fraction, repair_fraction, exposure_frames, exposure_frames_worst, time_basis,
    description}] for every defense. Time is measured on one view of `camera` as a schedule
    (`schedule_time`): a guard's guarded frames against plain ones; a check defense's S frames
    and a check against S frames (S = `check_every`), interleaved, the median of the rounds'
    paired ratios with its 95% interval (time_lo, time_hi; NaN with fewer than 6 rounds).
    check_fraction: one check alone over one frame; repair_fraction: one detection's reload
    (the flags read and the primitive's words rewritten from the golden copy) over one frame."""
    rows = []
    parts, device, chunks = _times(model, camera, precision, repeats, gpu, check_every) if time_it else ({}, "?", 1)
    nan = float("nan")
    for d in dfn.DEFENSES:
        obj = dfn.get(d)
        ex = obj.upset_exposure(check_every)
        m = parts.get(d, {})
        if not time_it:
            basis = "not measured"
        elif d in parts:
            what = "guarded frames against plain"
            if obj.checked:
                what = f"{check_every} frame(s) and a check against {check_every}"
            elif obj.frame_check:
                what = f"{check_every} frames checked in the projection against {check_every} plain"
            basis = (
                f"measured as a schedule: {device}, {model.n} primitives, {camera.width}x{camera.height}, "
                f"{what}, interleaved, median of {repeats} rounds"
            )
        else:
            basis = "no GPU implementation (modelled by what it reads)"
        rows.append(
            {
                "name": d,
                "device_bytes": side.device_bytes(d, precision, model.sh_degree, model.n, chunks),
                "memory_overhead": side.device_overhead(d, precision, model.sh_degree, model.n, chunks),
                "check_every": check_every if obj.checked else None,
                "time_fraction": m.get("time", nan),
                "time_lo": m.get("lo", nan),
                "time_hi": m.get("hi", nan),
                "check_fraction": m.get("check", nan) if obj.checked else nan,
                "repair_fraction": m.get("repair", nan) if obj.checked or obj.frame_check else nan,
                "exposure_frames": ex.expected,
                "exposure_frames_worst": ex.worst,
                "time_basis": basis,
                "description": dfn.get(d).info,
            }
        )
    return rows


def schedule_time(
    frame, check, every: int, repeats: int, clock=time.perf_counter, warm_up: bool = True, guarded=None
) -> dict:
    """A check schedule's time, measured as one: rounds of `every` frames with `check()` before
    the first (what the user's device runs) against rounds of `every` frames alone, interleaved
    round by round, every other round in reverse order (interleaved_samples), on `clock`.
    `guarded`: the frame as the defense draws it (a pipeline clamp), default `frame`. Returns
    {"plain": [s], "checked": [s], "fraction": [(checked - plain) / plain per round], "time",
    "lo", "hi": median_interval of the fractions}."""
    every = int(every)
    if every < 1:
        raise ValueError(f"a check schedule is every S >= 1 frames (got {every})")
    guarded = frame if guarded is None else guarded

    def plain():
        for _ in range(every):
            frame()

    def checked():
        if check is not None:
            check()
        for _ in range(every):
            guarded()

    got = interleaved_samples(
        {"plain": plain, "checked": checked}, repeats, warm_up=warm_up, clock=clock, alternate=True
    )
    p, c = np.asarray(got["plain"]), np.asarray(got["checked"])
    frac = (c - p) / p
    med, lo, hi = median_interval(frac)
    return {
        "plain": got["plain"],
        "checked": got["checked"],
        "fraction": frac.tolist(),
        "time": med,
        "lo": lo,
        "hi": hi,
    }


def interleaved_samples(
    configs: dict,
    repeats: int,
    budget_s: float | None = None,
    least: int = 3,
    warm_up: bool = True,
    clock=None,
    alternate: bool = False,
) -> dict:
    """{name: [seconds of each round]} of calling each of `configs` (name -> callable that returns
    when the GPU is done). Timed interleaved, round by round, so a drift of the machine's load hits
    every configuration alike. `warm_up`: one untimed round first (pipelines, bind groups).
    `budget_s`: once `least` rounds ran, a round starts only if it would end within that many
    seconds at the rounds' mean so far (a large model's measurement would otherwise outlast the
    campaign it is made for; starting any round that began within the budget overran it by up to
    a round: at 1M primitives a third round of about 1.3 s). `clock`: seconds now (default
    time.perf_counter; a test's fake clock). `alternate`: every other round runs the
    configurations in reverse order, so that what follows a configuration (a pipeline switched
    back, a cache another one filled) does not always fall on the same one."""
    clock = time.perf_counter if clock is None else clock
    for f in configs.values() if warm_up else ():
        f()
    samples = {k: [] for k in configs}
    t_start = clock()
    for r in range(max(int(repeats), 1)):
        spent = clock() - t_start
        if budget_s is not None and r >= max(least, 1) and spent + spent / r > budget_s:
            break
        order = list(configs.items())
        for k, f in reversed(order) if alternate and r % 2 else order:
            t0 = clock()
            f()
            samples[k].append(clock() - t0)
    return samples


def interleaved_medians(configs: dict, repeats: int, budget_s: float | None = None, least: int = 3) -> dict:
    """{name: median seconds} of interleaved_samples, after a warm-up round of every configuration."""
    samples = interleaved_samples(configs, repeats, budget_s, least)
    return {k: float(np.median(v)) for k, v in samples.items()}


def _times(model, camera, precision, repeats, gpu, check_every) -> tuple[dict, str, int]:
    """({defense: {time, lo, hi (schedule_time's), check (one check / one frame), repair (one
    reload / one frame)}}, the device, the model's chunks)."""
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

    out = {"none": {"time": 0.0, "lo": 0.0, "hi": 0.0}}
    for d in (x for x in dfn.REGISTRY.values() if x.frame_check):  # the check inside every frame
        fc = FrameCheck(r, clean, d.name)
        fc.off()

        def checked_frame(fc=fc):  # a frame and its detections (repair or not), carried in its read
            fc.on()
            r.run()
            fc.frame_count()
            fc.off()

        res = schedule_time(lambda: view(0), None, check_every, repeats, guarded=checked_frame)
        out[d.name] = {"time": res["time"], "lo": res["lo"], "hi": res["hi"]}
        rep = DeviceRepair(r, clean, fc)
        out[d.name]["repair"] = _device_repair_time(r, fc, rep, repeats)
    one = interleaved_medians({"none": lambda: view(0), **{d: c.run for d, c in checkers.items()}}, repeats)
    for d in dfn.DEFENSES:
        if d not in masks and d not in checkers:
            continue  # (the frame checks were measured above)
        m = masks.get(d, 0)
        chk = checkers.get(d)
        every = check_every if chk is not None else 1
        res = schedule_time(lambda: view(0), chk.run if chk else None, every, repeats, guarded=lambda m=m: view(m))
        out[d] = {"time": res["time"], "lo": res["lo"], "hi": res["hi"]}
        if chk is not None:
            out[d]["check"] = one[d] / one["none"]
            out[d]["repair"] = _repair_time(r, chk, clean, repeats) / one["none"]
    for m in out.values():
        m.setdefault("check", float("nan"))
    r.set_guard(None, 0)
    return out, r.gpu.info.get("device", "?"), r.layout.n_chunks


def _device_repair_time(r, fc, rep, repeats: int) -> float:
    """Median seconds of one device repair (DeviceRepair.run, its two counts read back) of one
    primitive the check inside the frame flagged, over one plain frame's median."""
    L = r.layout
    chunk, word, shift = L.locate(np.array([0]), np.array([3]))
    words = r.read_words(int(chunk[0]))
    bad = words.copy()
    bad[word] ^= np.uint32(1 << (encoding.bits_per_value(L.precision) - 2)) << shift.astype(np.uint32)
    times, frames = [], []
    for _ in range(max(int(repeats), 1)):
        r.gpu.write(r.chunks[int(chunk[0])], bad)
        fc.on()
        t0 = time.perf_counter()
        r.run()
        frames.append(time.perf_counter() - t0)
        fc.off()
        t0 = time.perf_counter()
        repaired, _ = rep.run()
        times.append(time.perf_counter() - t0)
        if repaired != 1:
            raise RuntimeError("timing a device repair: the frame's check did not flag the upset it was given")
    return float(np.median(times)) / float(np.median(frames))


def _repair_time(r, chk, clean: np.ndarray, repeats: int) -> float:
    """Median seconds of one detection's repair after the check that flagged it: a primitive's
    log-scale exponent flipped in the device buffer, the check run and its flags read (untimed),
    then the primitive's words rewritten from the golden copy and the device waited on (a reload;
    what the host path of check.py does). Timed on its own, not as a difference of two noisy
    checks, which could come out negative."""
    L = r.layout
    nb = encoding.bits_per_value(L.precision)
    flip, big = clean[:1].copy(), clean[:1].copy()
    flip[0, 3] ^= flip.dtype.type(1 << (nb - 2))  # what every parity and the checksum see
    big[0, 3] = encoding.to_bits(np.float32([1e4]), L.precision)[0]  # above every scale class
    chunk, word, shift = L.locate(np.zeros(L.ncomp, np.int64), np.arange(L.ncomp))
    words = r.read_words(int(chunk[0])).copy()

    def write(rows):
        w = words.copy()
        vals = rows[0].astype(np.uint32) << shift.astype(np.uint32)
        keep = ~(np.uint32((1 << encoding.bits_per_value(L.precision)) - 1) << shift.astype(np.uint32))
        w[word] = (w[word] & keep) | vals
        r.gpu.write(r.chunks[int(chunk[0])], w)

    for bad in (flip, big):
        write(bad)
        chk.run()
        if chk.flags()[0]:
            break
    times = []
    for _ in range(max(int(repeats), 1)):
        write(bad)
        chk.run()
        if not chk.flags()[0]:
            raise RuntimeError("timing a repair: the check did not flag the upset it was given")
        t0 = time.perf_counter()
        write(clean[:1])
        r.gpu.sync()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
