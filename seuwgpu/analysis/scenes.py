"""Table 1: the models the records rest on (primitives, SH degree, views, support-box width per
field). The box is the support guard's (`faults.guard.support_box` of the clean model); the
models are re-made from the runs' specs (embedded scenes are deterministic; model files are read
where they still are), so a width the report cannot re-make is NaN with a note, never a guess."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from seuwgpu.analysis.records import InsufficientData, prepare, tag
from seuwgpu.campaign.spec import scene_label
from seuwgpu.campaign.spec_types import SceneSpec, stored_scenes, stored_size
from seuwgpu.model.fields import FIELD_OFFSET, FIELDS, field_components


def _box_widths(entry: SceneSpec, n: int | None, precision: str) -> dict:
    from seuwgpu.faults.guard import support_box
    from seuwgpu.model.sources import load_source

    src = load_source(
        scene=entry.scene,
        path=entry.model,
        n=n,
        sh_degree=3 if entry.sh_degree is None else entry.sh_degree,
        seed=entry.seed or 0,
        up=entry.up,
        lod=entry.lod,
    )
    model = src.model
    if entry.model and n is not None and n < model.n:
        model = model.sample(n, entry.seed or 0, src.name)  # a [sizes] row: the runner's subset
    box = support_box(model, precision)
    width = np.asarray(box.hi, float) - np.asarray(box.lo, float)
    deg = model.sh_degree
    out = {"name": src.name, "sh_degree": deg, "n": model.n}
    for f in FIELDS:
        c = field_components(f, deg)
        out[f"box_{f}"] = float(width[FIELD_OFFSET[f] : FIELD_OFFSET[f] + c].max()) if c else np.nan
    return out


def scene_table(df: pd.DataFrame, manifests: Iterable[dict] = ()) -> tuple[pd.DataFrame, list[str]]:
    """(table, notes): one row per (scene, primitive count) in the records: kind (embedded or
    file), primitives, SH degree, views and size of the run, and the widest support-box component
    of each field (stored units: log-scale, logit opacity, ...)."""
    d = prepare(df)
    if d.empty:
        raise InsufficientData("no records", "run a campaign")
    notes: list[str] = []
    rows, seen = [], set()
    for m in manifests or ():
        spec = m.get("spec") if isinstance(m.get("spec"), dict) else {}
        run = m.get("_run", "run")
        prec = ((spec.get("single") or spec.get("dose") or spec.get("sizes") or {}).get("precisions") or ["fp32"])[0]
        have = d[d["run"] == run] if "run" in d else d
        for key, _ in have.groupby(["scene", "n_primitives"]):
            if key in seen:
                continue
            # the spec's entry of this scene, by the label its records carry (an embedded scene's
            # name, a model file's label): a [sizes] row of an embedded scene listed after a
            # model file was re-made from that file (its SH degree and boxes)
            entries = [e for e in stored_scenes(m) if scene_label(e) == key[0]]
            entry = next((e for e in entries if e.n in (None, key[1])), entries[0] if entries else None)
            row = {
                "scene": key[0],
                "kind": "embedded" if entry and entry.scene else "model file",
                "primitives": int(key[1]),
                "views": spec.get("views"),
                "size": "x".join(map(str, stored_size(m) or ())),
            }
            try:
                if entry is None:
                    raise ValueError("not in the run's spec")
                info = _box_widths(entry, int(key[1]), prec)
                row["sh_degree"] = info["sh_degree"]
                row.update({k: v for k, v in info.items() if k.startswith("box_")})
            except (OSError, ValueError) as e:
                notes.append(f"{key[0]} (N = {int(key[1]):,}): support box not re-made ({e})")
                row["sh_degree"] = spec.get("sh_degree", np.nan)
            rows.append(row)
            seen.add(key)
    if not rows:  # records without manifests: what the records alone say
        for key, _ in d.groupby(["scene", "n_primitives"]):
            rows.append({"scene": key[0], "kind": "?", "primitives": int(key[1])})
        notes.append("no run manifests: views, SH degree and support boxes unknown")
    out = pd.DataFrame(rows).sort_values(["scene", "primitives"]).reset_index(drop=True)
    return tag(out, d), notes
