"""The report's opening section: the answer to the user's question, before the paper's claims.

Every number comes from `analysis.summary.user_summary` (one function over the records); this
module writes them as a Section (tables, the worst flip's panel, notes, summary.json numbers)
and trims the claims table to the rows these records measure (`trim_claims`).

The worst flip's panel is rendered again here (clean | faulted | guarded | error, report/panel.py)
from the run's spec: the model (an embedded scene, or the model file where the report is built),
its views and precision, the recorded site flipped under no defense and under the guard. Where
that cannot be done (the model file is not on this machine, no GPU), the section says why and
gives the `seuwgpu inject` command line that draws that panel.
"""

from __future__ import annotations

import math
import shlex

import numpy as np
import pandas as pd

from seuwgpu.analysis import summary as S
from seuwgpu.analysis.records import FIELD_LABELS
from seuwgpu.campaign.spec_types import SceneSpec, stored_scenes, stored_size
from seuwgpu.faults.schedule import DEFAULT_CHECK_EVERY
from seuwgpu.report.sections import FigureItem, Section, TableItem

KEY = "summary"
MODEL_COLUMNS = {"n_primitives": "primitives", "sh_degree": "SH degree", "loader_notes": "what the loader changed"}
TITLE = "Summary: your model, its risk and the cheapest defense"


def _pct(p: float, lo: float | None = None, hi: float | None = None) -> str:
    if p is None or not np.isfinite(p):
        return "not measured"
    s = f"{100 * p:.3g}%"
    if lo is not None and np.isfinite(lo) and np.isfinite(hi):
        s += f" [{100 * lo:.3g}, {100 * hi:.3g}]"
    return s


def _ms(t: float) -> str:
    return f"{t:.3g} ms" if t is not None and np.isfinite(t) else "not measured"


def _bytes(b: float) -> str:
    """Device bytes; n/a for an arm the defenses registry no longer knows (NaN, never 0)."""
    return f"{int(b):,} B" if np.isfinite(b) else "n/a"


def _frames(mean: float, worst: float) -> str:
    if math.isinf(mean):
        return "until reloaded"
    if mean == 0 and worst == 0:
        return "0 (every frame)"
    return f"{mean:g} mean, {worst:g} worst"


def _model_name(r) -> str:
    return f"{r['scene']} (N={int(r['n_primitives']):,})"


def inject_command(worst: dict, manifests: list[dict]) -> str:
    """The `seuwgpu inject` command line that draws the worst flip's panel."""
    sc = _scene_spec(worst, manifests) or SceneSpec(sh_degree=None, seed=None)
    spec = _spec_of(worst, manifests)
    size = stored_size(_manifest_of(worst, manifests))
    args = ["seuwgpu", "inject"]
    if sc.model:
        args += ["--model", str(sc.model)]
    else:
        args += ["--scene", str(worst["scene"]), "--n", str(int(worst["n_primitives"]))]
        if sc.sh_degree is not None:
            args += ["--sh-degree", str(int(sc.sh_degree))]
        if sc.seed:
            args += ["--seed", str(int(sc.seed))]
    if sc.cameras:
        args += ["--cameras", str(sc.cameras)]
    if spec.get("views"):
        args += ["--views", str(int(spec["views"]))]
    if size and not sc.cameras:
        args += ["--size", f"{size[0]}x{size[1]}"]
    if spec.get("scale") is not None:
        args += ["--scale", f"{float(spec['scale']):g}"]
    args += ["--precision", str(worst["precision"]), "--field", str(worst["field"])]
    args += ["--primitive", str(worst["primitive"]), "--component", str(worst.get("component") or 0)]
    args += ["--bit", str(int(worst["bit"])), "--out", "worst_flip"]
    return " ".join(shlex.quote(a) for a in args)


def _spec_of(worst: dict, manifests: list[dict]) -> dict:
    return _manifest_of(worst, manifests).get("spec") or {}


def _manifest_of(worst: dict, manifests: list[dict]) -> dict:
    run = worst.get("run")
    return next((m for m in manifests if run is None or m.get("_run") == run), manifests[0] if manifests else {})


def _scene_spec(worst: dict, manifests: list[dict]):
    """The typed [[scenes]] entry of the worst flip's run that its records name, or None."""
    from seuwgpu.campaign.spec import scene_label

    scenes = stored_scenes(_manifest_of(worst, manifests))
    return next((sc for sc in scenes if scene_label(sc) == str(worst["scene"])), None)


def worst_flip_frames(worst: dict, manifests: list[dict], gpu=None) -> dict:
    """The worst flip rendered again: {"clean", "none", "guard"} frames [K, H, W, 3] and the
    measured footprints. Raises (with the reason) where the model or a GPU is not at hand."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.gpu.device import get_gpu
    from seuwgpu.model.sources import load_source, source_views

    if not _one_flip(worst):
        raise ValueError("the worst record is not one bit flip at a recorded site")
    sc = _scene_spec(worst, manifests)
    if sc is None:
        raise ValueError(f"no [[scenes]] entry of the runs' specs names {worst['scene']!r}")
    spec = _spec_of(worst, manifests)
    n = int(worst["n_primitives"])
    if sc.model:
        src = load_source(path=sc.model, up=sc.up)
    else:
        sh_degree = 3 if sc.sh_degree is None else int(sc.sh_degree)
        src = load_source(scene=sc.scene, n=n, sh_degree=sh_degree, seed=int(sc.seed or 0))
        src.up = sc.up or src.up
    size = stored_size(_manifest_of(worst, manifests)) or (256, 256)
    views = source_views(src, sc.cameras, spec.get("views"), size, spec.get("scale"))
    model = src.model
    if sc.model and model.n != n:
        model = model.sample(n, int(sc.seed or 0), src.name)
    profile = (manifests[0].get("profile") if manifests else None) or "strict"
    eng = Engine(model, views, str(worst["precision"]), gpu=gpu or get_gpu(), scene=src.name, profile=profile)
    site = eng.site(str(worst["field"]), worst["primitive"], worst.get("component") or 0, (int(worst["bit"]),))
    out = {"clean": eng.clean.copy()}
    for d in ("none", "guard"):
        rec = eng.inject(site, d)
        out[d] = eng.last_frame()[..., :3].copy()
        out[f"{d}_footprint"] = float(rec["footprint"])
        out[f"{d}_nonfinite"] = bool(rec["nonfinite"])
    return out


def summary_section(df: pd.DataFrame, manifests: list[dict], target: float | None = None, panel: bool = True):
    """The summary Section (module notes); panel=False leaves the worst flip's panel out (its
    command line stays)."""
    res = S.user_summary(df, manifests, target)
    sec = Section(KEY, TITLE)
    models, pc, cells, defs, cheap = res["models"], res["p_c"], res["cells"], res["defenses"], res["cheapest"]
    lead = []
    # the model(s)
    if len(models):
        sec.tables.append(
            TableItem(
                "summary_models",
                "The model",
                models.rename(columns=MODEL_COLUMNS),
                "Each model of the records: its file format (or embedded scene), primitives, SH degree, "
                "the stored precisions measured, and what the loader changed (its notes, kept in the run's "
                "manifest; n/a: a run of an older version, which did not keep them).",
            )
        )
        for r in models.to_dict("records"):
            fmt = r["format"] if isinstance(r["format"], str) else "format not recorded"
            notes = r["loader_notes"] if isinstance(r["loader_notes"], str) else "not recorded"
            lead.append(
                f"Model {r['scene']}: {fmt}, {int(r['n_primitives']):,} primitives, SH degree {int(r['sh_degree'])}, "
                f"stored as {r['precisions']}; what the loader changed: {notes}."
            )
    # p_c
    if len(pc):
        t = pd.DataFrame(
            {
                "model": [_model_name(r) for _, r in pc.iterrows()],
                "precision": pc["precision"],
                "n": pc["n"],
                "catastrophic": pc["events"],
                "p_c (%, 95% CI)": [_pct(r.rate, r.ci_lo, r.ci_hi) for r in pc.itertuples()],
            }
        )
        sec.tables.append(
            TableItem(
                "summary_pc",
                "p_c: catastrophic probability per upset, no defense",
                t,
                "Per model and precision (never pooled over models): the probability that one upset, drawn "
                "uniformly over the stored bits, makes a catastrophic frame (footprint over the threshold or "
                "a non-finite pixel), weighted by the stored bits each record stands for, with its 95% "
                "interval (stratified Wilson).",
            )
        )
        for r in pc.itertuples():
            lead.append(
                f"{r.scene} (N={int(r.n_primitives):,}, {r.precision}): p_c = {_pct(r.rate, r.ci_lo, r.ci_hi)} "
                f"per upset ({int(r.events)} catastrophic of {int(r.n)} flips, no defense)."
            )
    # the most dangerous fields and bits
    if len(cells):
        t = pd.DataFrame(
            {
                "model": [_model_name(r) for _, r in cells.iterrows()],
                "precision": cells["precision"],
                "field": [FIELD_LABELS.get(f, f) for f in cells["field"]],
                "bit": cells["bit"].astype(int),
                "n": cells["n"].astype(int),
                "catastrophic": cells["events"].astype(int),
                "rate (%, 95% CI)": [_pct(r.rate, r.ci_lo, r.ci_hi) for r in cells.itertuples()],
                "share of p_c (%)": [f"{100 * s:.3g}" if np.isfinite(s) else "n/a" for s in cells["share_of_pc"]],
            }
        )
        sec.tables.append(
            TableItem(
                "summary_cells",
                "The most dangerous fields and bits",
                t,
                f"Per model and precision, the (field, bit) cells of highest catastrophic rate under no defense "
                f"(at most {S.TOP_CELLS}, those with a catastrophe), with their 95% Wilson interval and the share of "
                "p_c each carries (its share of the stored bits times its rate, over p_c).",
            )
        )
        first = cells.groupby([*S.MODEL, "precision"], sort=False)
        for _, g in first:
            share = float(g["share_of_pc"].sum())
            top = ", ".join(f"{FIELD_LABELS.get(r.field, r.field)} bit {int(r.bit)}" for r in g.head(3).itertuples())
            lead.append(f"Most dangerous: {top} ({100 * share:.3g}% of p_c in the top {len(g)} cells).")
    # the worst flip
    worst = res["worst"]
    if worst is not None:
        _worst_flip(sec, worst, manifests, panel)
    # the defenses
    if len(defs):
        t = pd.DataFrame(
            {
                "model": [_model_name(r) for _, r in defs.iterrows()],
                "precision": defs["precision"],
                "defense": defs["defense"],
                "n": defs["n"],
                "residual catastrophic (%, 95% CI)": [_pct(r.rate, r.ci_lo, r.ci_hi) for r in defs.itertuples()],
                "device memory": [
                    "n/a" if not np.isfinite(b) else f"{_bytes(b)} ({p:.3g}% of the model)"
                    for b, p in zip(defs["device_bytes"], defs["device_pct"])
                ],
                "time per frame": [_ms(x) for x in defs["time_ms"]],
                "time vs none": [
                    "reference" if d == "none" else (f"{x:+.3g}%" if np.isfinite(x) else "not measured")
                    for d, x in zip(defs["defense"], defs["time_vs_none_pct"])
                ],
                "exposure (frames)": [
                    _frames(a, b) for a, b in zip(defs["exposure_frames"], defs["exposure_worst_frames"])
                ],
            }
        )
        sec.tables.append(
            TableItem(
                "summary_defenses",
                "Each defense measured",
                t,
                "Per model, precision and defense: the residual catastrophic rate per upset (95% interval), "
                "the memory it adds on the device (bytes, and % of the stored model), the time per frame "
                "measured in the run (the median time_ms of its records: one view of the clean model under the "
                "defense's in-pipeline guard; a check's own time is not in it; not measured: a run that kept "
                f"no time) and its exposure: frames drawn from a corrupted model before a check repairs it, at "
                f"a check every S = {res['check_every']} frame(s) (`[reliability] check_every`, default "
                f"{DEFAULT_CHECK_EVERY}; (S - 1) / 2 "
                "mean, S - 1 worst), 0 for a guard that clamps every frame or a code corrected at every read, "
                "until reloaded without a defense.",
            )
        )
    # the cheapest defense that meets the target
    target = res["target"]
    if len(cheap):
        rows = []
        for r in cheap.to_dict("records"):
            if r["met"] and r["defense"] == "none":
                what = f"no defense needed: without one the rate is at most {_pct(r['ci_hi'])}"
            elif r["met"]:
                what = (
                    f"{r['defense']}: residual {_pct(r['rate'])} (at most {_pct(r['ci_hi'])}), "
                    f"{_ms(r['time_ms'])} a frame, {_bytes(r['device_bytes'])} on the device; "
                    f"{int(r['candidates'])} defense(s) meet the target"
                )
            else:
                what = (
                    f"not met by any defense measured: the closest is {r['closest']}, at most "
                    f"{_pct(r['closest_ci_hi'])}; more samples narrow the intervals"
                )
            rows.append({"model": _model_name(r), "precision": r["precision"], "cheapest meeting the target": what})
            lead.append(f"Target {_pct(target)} per upset on {_model_name(r)}: {what}.")
        sec.tables.append(
            TableItem(
                "summary_cheapest",
                f"The cheapest defense meeting the target ({_pct(target)} per upset)",
                pd.DataFrame(rows),
                f"A defense meets the target when the upper end of its residual rate's 95% interval is at most "
                f"{_pct(target)} per upset (here: {res['target_source']}; set it with `[summary] target` in the spec "
                f"or `seuwgpu report --target`; default {_pct(S.DEFAULT_TARGET)}). Cheapest: {S.CHEAPEST_ORDER[0]} "
                f"when that meets the target, else by {' then by '.join(S.CHEAPEST_ORDER[1:])}; a defense whose "
                "time was not measured comes after those whose time was.",
            )
        )
    if len(models) and not len(pc):
        lead.append('p_c: not measured (no single upset without a defense: add "none" to [single] defenses).')
    if not len(models):
        lead.append(
            "These records hold no single upset (campaign [single], k = 1): the summary rests on them; run the "
            "default campaign (`seuwgpu demo`) or a spec with [single]."
        )
    sec.text = " ".join(lead)
    sec.numbers["summary"] = _numbers(res)
    return sec


def _worst_flip(sec: Section, worst: dict, manifests: list[dict], panel: bool):
    cmd = inject_command(worst, manifests) if _one_flip(worst) else ""
    bit = int(worst["bit"])
    prim = "?" if worst.get("primitive") is None else worst["primitive"]
    values = [worst.get(k) for k in ("clean_value", "corrupted_value")]
    known = worst.get("primitive") is not None and all(isinstance(v, (int, float)) for v in values)
    change = " -> ".join(f"{float(v):.6g}" for v in values) if known else "values not kept"
    what = (
        f"{worst['scene']} (N={int(worst['n_primitives']):,}, {worst['precision']}): "
        f"{FIELD_LABELS.get(worst['field'], worst['field'])}[{prim}][{worst.get('component') or 0}] bit {bit}, "
        f"{change}: footprint {100 * float(worst['footprint']):.3g}%"
        + (", non-finite pixels" if worst.get("nonfinite") else "")
    )
    sec.notes.append(f"Worst flip found (no defense): {what}.")
    made = None
    if panel:
        try:
            frames = worst_flip_frames(worst, manifests)
            from seuwgpu.report.panel import panel_figure

            fig = panel_figure(frames["clean"], frames["none"], frames["guard"], f"Worst flip: {what}")
            made = FigureItem(
                "fig_worst_flip",
                "The worst flip found",
                fig,
                f"{what}; rendered again for this report: footprint {100 * frames['none_footprint']:.3g}% without "
                f"a defense, {100 * frames['guard_footprint']:.3g}% under the support guard. The same panel: `{cmd}`.",
            )
            sec.figures.append(made)
        except Exception as e:  # noqa: BLE001 - any failure leaves the command line, with its reason
            sec.notes.append(f"Its panel could not be drawn here ({type(e).__name__}: {e}).")
    if made is None and cmd:
        sec.notes.append(f"Its panel (clean | faulted | guarded | error): `{cmd}`")
    elif made is None:
        sec.notes.append(
            "Its site was not kept (records folded as read keep few sites: `seuwgpu report --fold no` names it)."
        )


def _one_flip(worst: dict) -> bool:
    """The record is one bit flipped at a recorded site (what `seuwgpu inject` draws)."""
    fault = worst.get("fault")
    return worst.get("primitive") is not None and (fault is None or fault == "bit" or pd.isna(fault))


def _numbers(res: dict) -> dict:
    def records(t: pd.DataFrame) -> list[dict]:
        return t.to_dict("records") if len(t) else []

    worst = res["worst"]
    keep = ("scene", "n_primitives", "precision", "field", "primitive", "component", "bit", "footprint", "nonfinite")
    return {
        "target": res["target"],
        "target_source": res["target_source"],
        "check_every": res["check_every"],
        "models": records(res["models"]),
        "p_c": records(res["p_c"].drop(columns=["method"], errors="ignore")),
        "cells": records(res["cells"].drop(columns=["method"], errors="ignore")),
        "worst": None if worst is None else {k: worst.get(k) for k in keep},
        "defenses": records(res["defenses"]),
        "cheapest": records(res["cheapest"]),
    }


def trim_claims(sec: Section) -> None:
    """The claims table with only the rows these records measure; the others named in one line."""
    if not sec.tables or sec.tables[0].name != "claims":
        return
    t = sec.tables[0].df
    missing = t["verdict"] == "not measured"
    if not missing.any():
        return
    if missing.all():
        sec.tables.pop(0)
    else:
        sec.tables[0].df = t[~missing].reset_index(drop=True)
    names = [str(c) for c in t.loc[missing, "claim"]]
    table2 = [c for c in names if c.startswith("Table 2:")]
    rest = [c for c in names if not c.startswith("Table 2:")]
    if table2:
        rest.append(f"{len(table2)} per-field rows of Table 2")
    sec.notes.insert(0, f"{len(names)} rows not measured by these records: " + "; ".join(rest) + ".")
