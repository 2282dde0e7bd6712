"""The fault studies beyond single injections, as the commands run them: fault storms,
pipeline-state flips, the worst case by bounded search, the defenses' costs and sort-first
rendering over ranks."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import pandas as pd

from seuwgpu.api._checks import (
    defense_names,
    engine_for,
    model_from,
    names_of,
    view_list,
)
from seuwgpu.errors import InputError
from seuwgpu.faults.defenses import DEFENSES, pipeline_guards
from seuwgpu.faults.schedule import DEFAULT_CHECK_EVERY
from seuwgpu.faults.sites import (
    check_fault_model,
)
from seuwgpu.model import checks, encoding
from seuwgpu.model.cameras import Camera
from seuwgpu.model.fields import Model
from seuwgpu.model.sources import Source


def storm(
    scene: Source | Model,
    views: Sequence[Camera],
    *,
    k: int = 10,
    frames: int = 50,
    scrub_every: int = 10,
    defenses: Sequence[str] = ("none", "guard", "parity4r"),
    seed: int = 0,
    precision: str = "fp32",
    profile: str = "strict",
    progress: Callable[[], None] | None = None,
    rows: list | None = None,
    check_every: int = 1,
    fault: str = "bit",
) -> pd.DataFrame:
    """A fault storm (campaign/storm.py): `k` upsets per frame accumulating in the stored model for
    `frames` frames, reloaded every `scrub_every` frames (0: never), each defense an arm that sees
    the same upsets; a check defense checks (and repairs) every `check_every` frames. `fault`: the
    upsets' fault model (FAULT_MODELS: a burst, a random value, a multi-cell upset). One record
    per frame and defense. `progress()` is called after each frame;
    `rows`: a list the records are appended to as they are measured (a resumed storm's records
    first: it goes on after them). To resume as `seuwgpu storm` does: `campaign.partial.resumed`
    with the `run_identity` of the arguments yields the `rows` and `progress` to pass."""
    from seuwgpu.campaign.storm import storm as run_storm

    defenses = defense_names(defenses)
    for value, what in ((k, "k"), (frames, "frames"), (scrub_every, "scrub_every"), (seed, "seed")):
        checks.integer(value, what)  # the ranges: campaign/storm.py's own check, which names all three
    checks.integer(check_every, "check_every", 1)
    check_fault_model(fault)
    eng = engine_for(scene, views, precision, profile, "storm")
    return run_storm(
        eng, k, frames, scrub_every, defenses, seed, progress, rows=rows, check_every=check_every, fault=fault
    )


def state_flips(
    scene: Source | Model,
    views: Sequence[Camera],
    *,
    targets: Sequence[str] | None = None,
    samples: int = 10,
    bits: Sequence[int] | None = None,
    seed: int = 0,
    precision: str = "fp32",
    profile: str = "strict",
    progress: Callable[[], None] | None = None,
    rows: list | None = None,
) -> pd.DataFrame:
    """Transient bit flips in one frame's pipeline state (faults/state.py): `samples` flips per
    (target, bit) cell, `targets` the pipeline-state buffers (default: all), `bits` 0..31 (default:
    all). One record per flip; `progress` and `rows` as `storm`'s."""
    from seuwgpu.faults.state import TARGETS, check_target, state_campaign

    if targets is not None:  # a former name and its new one are the same target
        targets = list(dict.fromkeys(check_target(t) for t in names_of(targets, "targets")))
    targets = list(TARGETS) if targets is None else targets
    bits = list(range(32)) if bits is None else list(dict.fromkeys(checks.integer(b, "bit") for b in bits))
    checks.integer(samples, "samples", 1)
    checks.integer(seed, "seed")
    eng = engine_for(scene, views, precision, profile, "state_flips")
    return state_campaign(eng, targets, samples, bits, seed, progress, rows=rows)


def worst_case(
    scene: Source | Model,
    views: Sequence[Camera],
    *,
    defenses: Sequence[str] = ("none",),
    fields: Sequence[str] | None = None,
    bits: Sequence[int] | None = None,
    max_evaluations: int | None = None,
    precision: str = "fp32",
    profile: str = "strict",
) -> dict:
    """The single-bit flip with the largest footprint under each defense, by bounded search
    (faults/worstcase.py): {defense: WorstCase(site, footprint, certified bound, evaluated,
    sites)}. `fields`: default every field the model stores; `bits`: default all;
    `max_evaluations`: stop after this many renders (the bound stays certified)."""
    from seuwgpu.faults.worstcase import worst_case as search
    from seuwgpu.model.fields import canonical_field

    defenses = defense_names(defenses)
    if fields is not None:
        fields = [canonical_field(f) for f in names_of(fields, "fields")]
    if bits is not None:
        bits = [checks.integer(b, "bit", 0) for b in bits]
    if max_evaluations is not None:
        checks.integer(max_evaluations, "max_evaluations", 1)
    eng = engine_for(scene, views, precision, profile, "worst_case")
    return {d: search(eng, d, fields, bits, max_evaluations=max_evaluations) for d in defenses}


def defense_costs(
    scene: Source | Model,
    view: Camera,
    *,
    precision: str = "fp32",
    repeats: int = 7,
    time_it: bool = True,
    check_every: int = DEFAULT_CHECK_EVERY,
    visible: int = 0,
    window: int = 20,
    visible_defenses: Sequence[str] | None = None,
    seed: int = 0,
    fault: str = "bit",
    out: str | Path | None = None,
    progress: Callable[[], None] | None = None,
    rows: list | None = None,
) -> list[dict]:
    """Every defense with the bytes it holds on the device (and as a fraction of the model's), its
    time per frame (a fraction of the undefended view's on this device, measured as a schedule:
    `check_every` frames and a check against `check_every` frames, interleaved, the median of
    `repeats` rounds with its 95% interval; NaN with time_it=False), its exposure and, with
    `visible` upsets, what the user sees (campaign/visible.py: catastrophic and SDC frames per
    upset, exposure counted, measured by running `visible` windows of `window` frames on `view`,
    for `visible_defenses` (default every defense); NaN for those not measured):
    [{name, device_bytes, memory_overhead, check_every, time_fraction, time_lo, time_hi,
    check_fraction, repair_fraction, exposure_frames, exposure_frames_worst,
    catastrophic_frames_per_upset, catastrophic_lo, catastrophic_hi, sdc_frames_per_upset,
    residue_frames_per_upset, of_none, of_none_lo, of_none_hi, visible_basis, time_basis,
    description}]. `out`: a run folder that keeps the `visible` measurement's per-upset records
    for its report (campaign/visible.py save_counts). `progress()` is called after each frame of
    the `visible` measurement; `rows`: a list its frame records are appended to as they are
    measured (an interrupted measurement's records first: it goes on after them; `seuwgpu defenses
    --visible N --out RUN` resumes so, as storm does)."""
    from seuwgpu.faults.costs import defense_costs as costs

    checks.integer(repeats, "repeats", 1)
    checks.integer(check_every, "check_every", 1)
    checks.integer(visible, "visible", 0)
    checks.integer(window, "window", 1)
    check_fault_model(fault)
    if not isinstance(view, Camera):
        raise InputError(f"view must be a Camera (from cameras()), got {type(view).__name__}")
    if out is not None and not visible:
        raise InputError("out keeps the records of the visible-damage measurement: give visible = N upsets too")
    names = defense_names(visible_defenses) if visible_defenses is not None else list(DEFENSES)
    model = model_from(scene)
    table = costs(model, view, encoding.check_precision(precision), repeats, time_it=time_it, check_every=check_every)
    keys = ("catastrophic_frames_per_upset", "catastrophic_lo", "catastrophic_hi", "sdc_frames_per_upset")
    keys += ("residue_frames_per_upset", "of_none", "of_none_lo", "of_none_hi")
    got, basis = {}, "not measured (--visible N)"
    if visible:
        from seuwgpu.campaign.visible import visible_damage

        eng = engine_for(scene, [view], precision, "strict", "measure visible damage")
        summary, recs = visible_damage(
            eng, names, check_every, visible, window, fault=fault, seed=seed, progress=progress, rows=rows
        )
        got = {r["defense"]: r for r in summary.to_dict("records")}
        w = int(summary["window"].iloc[0])
        if out is not None:
            _save_visible(out, eng, recs, visible, w, check_every, fault, seed)
        basis = (
            f"measured: {visible} upsets ({fault} faults of the dangerous cells), one per window of {w} frames "
            f"reloaded at its start, landing at a uniform frame; {view.width}x{view.height}, seed {seed}"
        )
    for r in table:
        m = got.get(r["name"])
        for k in keys:
            r[k] = float(m[k]) if m is not None else float("nan")
        r["visible_basis"] = basis if m is not None else "not measured"
    return table


def _save_visible(out, eng, recs, upsets: int, window: int, check_every: int, fault: str, seed: int):
    """The visible-damage measurement's per-upset records into the run folder `out`, with the
    model, view, device and date each number depends on."""
    from datetime import UTC, datetime

    from seuwgpu.campaign.visible import save_counts, upset_counts

    r = eng.renderer
    save_counts(
        out,
        upset_counts(recs, upsets, window, check_every),
        scene=eng.scene,
        n_primitives=eng.n,
        precision=eng.precision,
        width=r.width,
        height=r.height,
        fault=fault,
        seed=seed,
        device=str(r.gpu.info.get("device", "?")),
        date=datetime.now(UTC).date().isoformat(),
    )


def sort_first(
    scene: Source | Model,
    views: Sequence[Camera],
    *,
    ranks: Sequence[int] = (4,),
    upset: str | None = None,
    component: int = 0,
    primitive: int | None = None,
    sample: int = 32,
    seed: int = 0,
    guard: str = "scrub",
    repeats: int = 3,
    precision: str = "fp32",
    address: str | None = None,
    guard_variant: str = "guard",
) -> list[dict]:
    """Sort-first rendering over Ray ranks (campaign/sortfirst.py; needs `seuwgpu[ray]`): for each
    rank count P, the per-rank render times and, with `upset` ("field:bit", e.g. "log_scales:31",
    applied to every rank's copy), the ranks it contaminates with and without the node-local
    `guard` ("scrub" the stored copy, or "clamp" in the pipeline) of the fields `guard_variant`
    clamps ("guard", "guard_all", ...: a defense with guard fields). Without `primitive`, the most
    harmful of `sample` primitives. Prints a table per rank count; returns the results."""
    from seuwgpu.campaign.ray import INSTALL_HINT, ray_available
    from seuwgpu.campaign.sortfirst import parse_upset, sort_first_tables

    if not ray_available():
        raise InputError(f"sort-first rendering needs Ray. {INSTALL_HINT}")
    for p in ranks:
        checks.integer(p, "ranks", 1)
    parsed = None if upset is None else parse_upset(upset)
    kw = {"component": component, "primitive": primitive, "sample": sample, "seed": seed, "guard": guard}
    kw["guard_variant"] = checks.one_of(guard_variant, "guard variant", pipeline_guards())
    return sort_first_tables(
        model_from(scene), view_list(views), encoding.check_precision(precision), list(ranks), parsed,
        address=address, repeats=repeats, **kw,
    )  # fmt: skip
