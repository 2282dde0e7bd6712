"""Independent check of every outcome class: seuwgpu's renderer against gsplat's PyTorch reference.

    tools/crosscheck_env.sh                       # .venv-crosscheck: CPU torch, gsplat, seuwgpu -e .
    .venv-crosscheck/bin/python tools/crosscheck.py run --out out/crosscheck \\
        --model plant=/work/corpus/plant/plant.splat --model leica-sofort ...
    .venv-crosscheck/bin/python tools/crosscheck.py table out/crosscheck/records.csv > table.md

`run` draws a seeded, stratified sample of single-bit upsets in the fp32 stored models (every field
the model stores; each sign and exponent bit in every field; random mantissa bits besides), renders
each faulted model with seuwgpu (the `gsplat` profile, like for like, and optionally `strict`) and
with gsplat's torch functions (tools/crosscheck_gsplat.py), each against its own clean render, and
writes one record per site as it goes (a rerun resumes: sites already in records.csv are skipped).
`table` makes the agreement tables (docs/crosscheck.md). Only `run` needs torch and gsplat; the
sampler, the metrics, the classes and the tables here are plain numpy/pandas (tests/test_crosscheck.py).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seuwgpu.analysis.stats import wilson_interval  # noqa: E402
from seuwgpu.model.fields import field_components  # noqa: E402

FIELDS = ("means", "log_scales", "quats", "opacity", "sh_dc", "sh_rest")
SIGN_BIT = 31
EXPONENT_BITS = tuple(range(23, 31))
TOP_BITS = (*EXPONENT_BITS, SIGN_BIT)
PIXEL_THRESHOLD = 1.0 / 255.0  # a pixel changed: a channel moved by more than this (or non-finite)
FOOTPRINT_THRESHOLD = 0.01  # catastrophic above 1% of the frame
AGREE_FOOTPRINT = 0.005  # footprints agree within 0.5% of the frame
CLASSES = ("masked", "tolerable", "sdc", "catastrophic")


# ---- sites --------------------------------------------------------------------------------------
def bit_kind(bit: int) -> str:
    return "sign" if bit == SIGN_BIT else "exponent" if bit in EXPONENT_BITS else "mantissa"


def sample_sites(models: list[tuple[str, int, int]], seed: int = 0, top: int = 1, mantissa: int = 3) -> pd.DataFrame:
    """Sites for each model (name, primitives, SH degree): for every field the model stores, `top`
    sites at each sign and exponent bit and `mantissa` at uniformly drawn mantissa bits; primitive
    and component uniform. Seeded per model (the seed and the model's name), so adding a model
    leaves the other models' sites as they were."""
    rows = []
    for name, n, degree in models:
        rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
        for field in FIELDS:
            nc = field_components(field, degree)
            if nc == 0:
                continue
            bits = [b for b in TOP_BITS for _ in range(top)] + [int(b) for b in rng.integers(0, 23, mantissa)]
            for b in bits:
                rows.append(
                    {
                        "model": name,
                        "field": field,
                        "primitive": int(rng.integers(n)),
                        "component": int(rng.integers(nc)),
                        "bit": int(b),
                        "bit_kind": bit_kind(int(b)),
                    }
                )
    df = pd.DataFrame(rows, columns=["model", "field", "primitive", "component", "bit", "bit_kind"])
    df.insert(0, "site_id", [f"{r.model}/{r.field}/{r.primitive}/{r.component}/{r.bit}" for r in df.itertuples()])
    return df.drop_duplicates("site_id").reset_index(drop=True)


def flip_fp32(value, bit: int) -> np.float32:
    """The fp32 value with stored bit `bit` (0 = least significant) flipped."""
    word = np.array([value], np.float32).view(np.uint32) ^ np.uint32(1 << bit)
    return word.view(np.float32)[0]


def same_bits(a, b) -> bool:
    return bool(np.array([a], np.float32).view(np.uint32)[0] == np.array([b], np.float32).view(np.uint32)[0])


# ---- metrics and classes ------------------------------------------------------------------------
def frame_metrics(clean: np.ndarray, faulted: np.ndarray) -> dict:
    """Footprint (mean over views of the fraction of pixels changed: a channel non-finite or moved by
    more than 1/255; a pixel bit-identical to clean is unchanged), peak error (largest finite
    channel change; +inf where a pixel is non-finite), non-finite flag (a non-finite channel in a
    pixel that is not bit-identical to clean) and `identical` (every pixel bit-identical), for
    frames [K, H, W, 3]."""
    c = np.asarray(clean, np.float32)[..., :3]
    f = np.asarray(faulted, np.float32)[..., :3]
    same = (c.view(np.uint32) == f.view(np.uint32)).all(axis=-1)
    with np.errstate(invalid="ignore", over="ignore"):
        d = np.abs(f - c)
    bad = ~np.isfinite(f) | ~np.isfinite(d)
    changed = (bad | (np.where(bad, 0, d) > np.float32(PIXEL_THRESHOLD))).any(axis=-1) & ~same
    nonfinite = bool((bad.any(axis=-1) & ~same).any())
    fin = np.where(bad | same[..., None], 0, d)
    peak = math.inf if nonfinite else float(fin.max(initial=0.0))
    footprint = float(changed.reshape(changed.shape[0], -1).mean(axis=1).mean())
    return {"footprint": footprint, "peak_error": peak, "nonfinite": nonfinite, "identical": bool(same.all())}


def classify(footprint: float, peak_error: float, nonfinite: bool, identical: bool) -> str:
    """masked (bit-identical frames), tolerable (changed, no channel by more than 1/255), sdc
    (visible, footprint <= 1%), catastrophic (footprint > 1% or a non-finite pixel)."""
    if nonfinite or footprint > FOOTPRINT_THRESHOLD:
        return "catastrophic"
    if identical:
        return "masked"
    return "sdc" if peak_error > PIXEL_THRESHOLD else "tolerable"


# ---- tables -------------------------------------------------------------------------------------
def compare(df: pd.DataFrame, a: str = "sg", b: str = "gs") -> pd.DataFrame:
    """Per site: same class, |footprint difference| and whether it is within 0.5% of the frame."""
    out = df.copy()
    out["same_class"] = out[f"{a}_class"] == out[f"{b}_class"]
    merged = {"masked": "invisible", "tolerable": "invisible"}
    out["same_visible"] = out[f"{a}_class"].replace(merged) == out[f"{b}_class"].replace(merged)
    out["d_footprint"] = (out[f"{a}_footprint"] - out[f"{b}_footprint"]).abs()
    out["footprint_ok"] = out["d_footprint"] <= AGREE_FOOTPRINT
    return out


def agreement(df: pd.DataFrame, by: str | None, a: str = "sg", b: str = "gs") -> pd.DataFrame:
    """Agreement rows (per value of `by`, or one overall row): sites, same class (% and Wilson 95%),
    same class with masked and tolerable merged (both invisible: no channel moved by 1/255), footprint
    within 0.5% (% and interval), largest |footprint difference| (% of the frame)."""
    c = compare(df, a, b)
    groups = [("all", c)] if by is None else list(c.groupby(by, sort=False))
    rows = []
    for key, g in groups:
        n = len(g)
        rows.append(
            {
                by or "": key,
                "sites": n,
                "same class": _rate(int(g["same_class"].sum()), n),
                "same class, masked = tolerable": _rate(int(g["same_visible"].sum()), n),
                "footprint within 0.5%": _rate(int(g["footprint_ok"].sum()), n),
                "max |Δ footprint|": f"{100 * g['d_footprint'].max():.3f}%",
            }
        )
    return pd.DataFrame(rows)


def _rate(k: int, n: int) -> str:
    lo, hi = wilson_interval(k, n)  # seuwgpu's: the interval is statistics, not the renderer under check
    return f"{k} ({100 * k / n:.1f}%, {100 * lo:.1f}-{100 * hi:.1f})"


def confusion(df: pd.DataFrame, a: str = "sg", b: str = "gs") -> pd.DataFrame:
    """Sites by (a's class, b's class); rows a, columns b, every class listed."""
    t = pd.crosstab(pd.Categorical(df[f"{a}_class"], CLASSES), pd.Categorical(df[f"{b}_class"], CLASSES), dropna=False)
    t.index.name, t.columns.name = a, b
    return t


def markdown(df: pd.DataFrame, index: bool = False) -> str:
    d = df.reset_index() if index else df
    cols = [str(c) for c in d.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in d.itertuples(index=False)]
    return "\n".join(lines)


def disagreements(df: pd.DataFrame, a: str = "sg", b: str = "gs") -> pd.DataFrame:
    c = compare(df, a, b)
    bad = c[~c["same_class"] | ~c["footprint_ok"]]
    cols = ["site_id", "clean_value", "corrupted_value", f"{a}_class", f"{b}_class", f"{a}_footprint", f"{b}_footprint"]
    cols += [k for k in ("gs_radius", "gs_pixels", "cause") if k in c]
    return bad[cols]


def tables(df: pd.DataFrame, a: str = "sg", b: str = "gs") -> str:
    parts = [f"### Overall ({a} vs {b})", markdown(agreement(df, None, a, b))]
    needle = (df["field"] == "log_scales") & (df["bit"] == SIGN_BIT)
    split = df.assign(sites_of=np.where(needle, "log-scale sign flips", "all but log-scale sign flips"))
    parts += ["### Log-scale sign flips and the rest", markdown(agreement(split, "sites_of", a, b))]
    for by in ("model", "field", "bit_kind"):
        parts += [f"### Per {by}", markdown(agreement(df, by, a, b))]
    parts += ["### Classes (rows: seuwgpu, columns: gsplat)", markdown(confusion(df, a, b), index=True)]
    dis = disagreements(df, a, b)
    if "cause" in dis and len(dis):
        counts = dis.groupby("cause").agg(sites=("site_id", "size"), classes_differ=("site_id", "size"))
        differ = dis[dis[f"{a}_class"] != dis[f"{b}_class"]].groupby("cause").size()
        counts["classes_differ"] = differ.reindex(counts.index).fillna(0).astype(int)
        counts["what"] = [CAUSES.get(c, "") for c in counts.index]
        parts += ["### Causes", markdown(counts.sort_values("sites", ascending=False), index=True)]
    parts += [f"### Disagreements ({len(dis)})", markdown(dis) if len(dis) else "none"]
    return "\n\n".join(parts) + "\n"


# ---- the run ------------------------------------------------------------------------------------
def _load(spec: str):
    """NAME=PATH, a path (named by its stem) or an embedded scene's name."""
    import seuwgpu as sg

    path = spec.partition("=")[2] if "=" in spec else spec
    return _name(spec), sg.load_model(path)


def _sg_records(eng, sites: pd.DataFrame, profile: str) -> pd.DataFrame:
    """seuwgpu's records of the sites (its campaign engine: incremental re-compositing, exact)."""
    from seuwgpu.metrics.image import outcome_class

    objs = [eng.site(r.field, r.primitive, r.component, (r.bit,)) for r in sites.itertuples()]
    recs = eng.evaluate_frame(objs, ("none",))
    p = "sg" if profile == "gsplat" else "strict"
    out = pd.DataFrame(
        {
            f"{p}_footprint": recs["footprint"].to_numpy(float),
            f"{p}_peak": recs["peak_error"].to_numpy(float),
            f"{p}_nonfinite": recs["nonfinite"].to_numpy(bool),
            f"{p}_class": outcome_class(recs["peak_error"], recs["footprint"], recs["nonfinite"]),
        }
    )
    if profile == "gsplat":
        out["sg_corrupted"] = recs["corrupted_value"].to_numpy(np.float32)
    return out


def _gs_record(views, model, r) -> dict:
    """gsplat's frames of one site, against its own clean frames."""
    fields = views[0].fields
    row = {k: v[r.primitive : r.primitive + 1].copy() for k, v in fields.items()}
    flat = row[r.field].reshape(-1)
    clean_value = np.float32(flat[r.component])
    flat[r.component] = flip_fp32(clean_value, r.bit)
    cleans, bads, infos = [], [], []
    for v in views:
        c, b, info = v.faulted(r.primitive, row)
        cleans.append(c)
        bads.append(b)
        infos.append(info)
    m = frame_metrics(np.stack(cleans), np.stack(bads))
    return {
        "clean_value": float(clean_value),
        "corrupted_value": float(flat[r.component]),
        "gs_footprint": m["footprint"],
        "gs_peak": m["peak_error"],
        "gs_nonfinite": m["nonfinite"],
        "gs_class": classify(m["footprint"], m["peak_error"], m["nonfinite"], m["identical"]),
        "gs_row_exact": all(i["row_exact"] for i in infos),
        "gs_radius": ";".join(f"{i['radius_x']},{i['radius_y']}" for i in infos),
        "gs_tiles": sum(i["tiles"] for i in infos),
        "gs_pixels": sum(i["pixels_redone"] for i in infos),
    }


def run(args) -> int:
    import torch

    import seuwgpu as sg
    from seuwgpu.faults.engine import Engine
    from seuwgpu.model.fields import FIELDS as SG_FIELDS

    sys.path.insert(0, str(Path(__file__).parent))
    from crosscheck_gsplat import ALPHA_CAP, GsplatView

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rec_path = out / "records.csv"
    done = set(pd.read_csv(rec_path)["site_id"]) if rec_path.exists() else set()
    cap = ALPHA_CAP if args.alpha_cap is None else args.alpha_cap
    loaded = []
    for spec in args.model:
        try:
            name, scene = _load(spec)
        except Exception as e:  # a model that does not load is skipped, and said
            print(f"skip {spec}: {type(e).__name__}: {e}", flush=True)
            continue
        loaded.append((name, scene))
    sites = sample_sites([(n, s.model.n, s.model.sh_degree) for n, s in loaded], args.seed, args.top, args.mantissa)
    print(f"{len(sites)} sites over {len(loaded)} models; {len(done)} already in {rec_path}", flush=True)
    for name, scene in loaded:
        todo = sites[(sites["model"] == name) & ~sites["site_id"].isin(done)]
        if args.field:
            todo = todo[todo["field"].isin(args.field)]
        if todo.empty:
            continue
        model = scene.model
        t0 = time.time()
        cams = sg.cameras(scene, views=args.views, size=(args.size, args.size))
        fields = {f: getattr(model, f) for f in SG_FIELDS}
        dtype = torch.float64 if args.fp64 else None
        views = [GsplatView(fields, model.sh_degree, c.viewmat, c.K, c.width, c.height, cap, dtype) for c in cams]
        np.savez(out / f"clean_{name}.npz", gsplat=np.stack([v.frame for v in views]))
        t1 = time.time()
        profiles = ("gsplat", "strict") if args.strict else ("gsplat",)
        engines = {p: Engine(model, cams, "fp32", scene=name, profile=p) for p in profiles}
        print(
            f"{name}: {model.n} primitives, SH {model.sh_degree}; clean: gsplat {t1 - t0:.1f} s, "
            f"seuwgpu {time.time() - t1:.1f} s",
            flush=True,
        )
        for s in range(0, len(todo), args.batch):
            batch = todo.iloc[s : s + args.batch]
            t1 = time.time()
            sgr = pd.concat([_sg_records(engines[p], batch, p) for p in engines], axis=1)
            t2 = time.time()
            gsr = pd.DataFrame([_gs_record(views, model, r) for r in batch.itertuples()])
            t3 = time.time()
            recs = pd.concat([batch.reset_index(drop=True), gsr, sgr], axis=1)
            recs.insert(2, "n", model.n)
            recs.insert(3, "sh_degree", model.sh_degree)
            recs["value_match"] = [same_bits(a, b) for a, b in zip(recs["corrupted_value"], recs["sg_corrupted"])]
            recs["views"], recs["size"], recs["alpha_cap"] = args.views, args.size, cap
            recs["gs_projection"] = "float64" if args.fp64 else "float32"
            recs["s_seuwgpu"], recs["s_gsplat"] = (t2 - t1) / len(batch), (t3 - t2) / len(batch)
            if rec_path.exists():  # appended under the file's own header (a column it lacks is dropped)
                recs = recs.reindex(columns=pd.read_csv(rec_path, nrows=0).columns)
            recs.to_csv(rec_path, mode="a", header=not rec_path.exists(), index=False)
            agree = (recs["sg_class"] == recs["gs_class"]).mean()
            print(
                f"  {name} {s + len(batch)}/{len(todo)}: seuwgpu {t2 - t1:.1f} s, gsplat {t3 - t2:.1f} s, "
                f"same class {agree:.2f}",
                flush=True,
            )
    return 0


CAUSES = {
    "rounding": "last-bit rounding: the frames differ in their last bits in one renderer and are bit-identical in the "
    "other (invisible in both: no channel moves by 1/255)",
    "needle-clamp": "needle (a huge scale along one axis): det = a*c - b*b of the 2-D covariance cancels "
    "in fp32 and came out <= 0 in gsplat's torch reference in a view, where it clamps det to 1e-10 (a "
    "line of sub-pixel width, nearly invisible) while gsplat's CUDA kernel culls det <= 0 "
    "(ProjectionEWA3DGSFused.cu); seuwgpu's det there came out > 0 (drawn wide) or <= 0 (culled)",
    "needle-det": "needle: det = a*c - b*b cancels catastrophically in fp32, so its sign depends on the "
    "order of the operations; one renderer's det came out <= 0 (culled), the other's > 0 (drawn)",
    "needle-conic": "needle drawn by both: the conic inverts a cancelling det, so the ellipse (and its "
    "footprint) differs with the rounding",
    "radius-int": "a needle whose radius reaches 2^31 px in a view: torch's float-to-int gives INT_MIN on "
    "x86 there (culled) where CUDA saturates (a frame-covering sheet)",
    "threshold": "both footprints within 0.5% of the frame on either side of the 1% threshold, or a peak "
    "change at 1/255",
    "nonfinite": "non-finite handling differs",
    "other": "not classified automatically: see the record",
}


def explain_site(r, scene, cams) -> str:
    """The cause of one disagreement (a CAUSES key), from both renderers' projection of the faulted
    primitive in each view (seuwgpu: its numpy twin of the gsplat profile)."""
    import crosscheck_gsplat as gs

    from seuwgpu.model.fields import FIELDS as SG_FIELDS
    from seuwgpu.model.fields import Model
    from seuwgpu.render.project import project

    model = scene.model
    row = {f: getattr(model, f)[r.primitive : r.primitive + 1].copy() for f in SG_FIELDS}
    flat = row[r.field].reshape(-1)
    flat[r.component] = flip_fp32(flat[r.component], r.bit)
    invisible = {r.sg_class, r.gs_class} <= {"masked", "tolerable"}
    if invisible and r.sg_footprint == 0 and r.gs_footprint == 0:
        return "rounding"
    if bool(r.sg_nonfinite) != bool(r.gs_nonfinite):
        return "nonfinite"
    per_view = []
    for cam in cams:
        g = project(Model(**row), cam, "gsplat")
        q = gs.project(row, cam.viewmat, cam.K, cam.width, cam.height, model.sh_degree)
        radii = q["radii"][0].tolist()
        box = gs.tile_boxes(q["means2d"], q["radii"], -(-cam.width // gs.TILE), -(-cam.height // gs.TILE))[0]
        gs_drawn = min(radii) > 0 and bool(box[2] > box[0]) and bool(box[3] > box[1])
        big = max(abs(float(x)) for x in g["cov2d"][0][[0, 2]]) > 1e6
        per_view.append((cam, radii, gs_drawn, bool(g["n_tiles"][0] > 0), big))
    if any(min(radii) < 0 for _, radii, *_ in per_view):
        return "radius-int"
    for cam, _, gs_drawn, sg_drawn, big in per_view:
        if gs_drawn != sg_drawn and big:
            return "needle-clamp" if _torch_det(row, cam) <= 0 else "needle-det"
    if any(v[-1] for v in per_view):
        return "needle-conic"
    d = abs(r.sg_footprint - r.gs_footprint)
    near_foot = d <= AGREE_FOOTPRINT and min(r.sg_footprint, r.gs_footprint) <= FOOTPRINT_THRESHOLD
    near_peak = 0.5 * PIXEL_THRESHOLD <= min(r.sg_peak, r.gs_peak) <= 2 * PIXEL_THRESHOLD
    return "threshold" if near_foot or near_peak else "other"


def _lone_footprints(r, scene, cams) -> tuple[float, float]:
    """The faulted primitive alone (gsplat profile) on white: the fraction of pixels it changes, as
    seuwgpu's GPU draws it and as its numpy twin (render.reference) does (for a needle, the cull
    and the ellipse hang on a cancelling det, and so on the device's rounding)."""
    import seuwgpu as sg
    from seuwgpu.model.fields import FIELDS as SG_FIELDS
    from seuwgpu.model.fields import Model
    from seuwgpu.render import reference

    model = scene.model
    row = {f: getattr(model, f)[r.primitive : r.primitive + 1].copy() for f in SG_FIELDS}
    flat = row[r.field].reshape(-1)
    flat[r.component] = flip_fp32(flat[r.component], r.bit)
    one = Model(**row)
    gpu = np.asarray(sg.render_views(one, cams, profile="gsplat"))[..., :3]
    twin = np.asarray(reference.render(one, cams, profile="gsplat"))[..., :3]
    white = np.ones_like(gpu)
    return frame_metrics(white, gpu)["footprint"], frame_metrics(white, twin)["footprint"]


def _torch_det(row: dict, cam) -> float:
    """gsplat's torch det of the 2-D covariance before its clamp (as `_fully_fused_projection`)."""
    import torch
    from gsplat.cuda._torch_impl import _persp_proj, _quat_scale_to_covar_preci, _world_to_cam

    covars, _ = _quat_scale_to_covar_preci(
        torch.from_numpy(row["quats"]), torch.exp(torch.from_numpy(row["log_scales"])), True, False
    )
    vm, ks = torch.from_numpy(cam.viewmat)[None], torch.from_numpy(cam.K)[None]
    means_c, covars_c = _world_to_cam(torch.from_numpy(row["means"]), covars, vm)
    _, cov2 = _persp_proj(means_c, covars_c, ks, cam.width, cam.height)
    cov2 = cov2 + torch.eye(2) * 0.3
    return float((cov2[..., 0, 0] * cov2[..., 1, 1] - cov2[..., 0, 1] * cov2[..., 1, 0]).reshape(-1)[0])


def explain(args) -> int:
    """Label every disagreement of records.csv with its cause (causes.csv beside it)."""
    import torch

    import seuwgpu as sg

    sys.path.insert(0, str(Path(__file__).parent))
    torch.set_num_threads(1)
    rec_path = Path(args.records)
    df = compare(pd.read_csv(rec_path))
    bad = df[~df["same_class"] | ~df["footprint_ok"]]
    specs = {(_name(s)): s for s in args.model}
    rows = []
    for name, g in bad.groupby("model"):
        _, scene = _load(specs[name])
        r0 = g.iloc[0]
        cams = sg.cameras(scene, views=int(r0["views"]), size=(int(r0["size"]), int(r0["size"])))
        for r in g.itertuples():
            cause = explain_site(r, scene, cams)
            lone = _lone_footprints(r, scene, cams) if cause.startswith(("needle", "radius")) else (math.nan,) * 2
            rows.append({"site_id": r.site_id, "cause": cause, "lone_gpu": lone[0], "lone_twin": lone[1]})
    out = pd.DataFrame(rows, columns=["site_id", "cause", "lone_gpu", "lone_twin"])
    out.to_csv(rec_path.with_name("causes.csv"), index=False)
    print(out["cause"].value_counts().to_string())
    return 0


def clean(args) -> int:
    """Each model's clean frames, gsplat's torch (at alpha caps 0.999 and 0.99) against seuwgpu's
    gsplat and strict profiles: the largest channel difference and the pixels changed (clean.csv)."""
    import torch

    import seuwgpu as sg
    from seuwgpu.model.fields import FIELDS as SG_FIELDS

    sys.path.insert(0, str(Path(__file__).parent))
    from crosscheck_gsplat import GsplatView

    torch.set_num_threads(args.threads)
    rows = []
    for spec in args.model:
        try:
            name, scene = _load(spec)
        except Exception as e:  # as in run: a model that does not load is skipped, and said
            print(f"skip {spec}: {type(e).__name__}: {e}", flush=True)
            continue
        model = scene.model
        cams = sg.cameras(scene, views=args.views, size=(args.size, args.size))
        fields = {f: getattr(model, f) for f in SG_FIELDS}
        for cap in (0.999, 0.99):
            gs = np.stack(
                [GsplatView(fields, model.sh_degree, c.viewmat, c.K, c.width, c.height, cap).frame for c in cams]
            )
            for profile in ("gsplat", "strict"):
                ref = np.asarray(sg.render_views(scene, cams, profile=profile))[..., :3]
                m = frame_metrics(ref, gs)
                rows.append(
                    {
                        "model": name,
                        "gsplat_alpha_cap": cap,
                        "seuwgpu_profile": profile,
                        "max_abs_diff": float(np.nanmax(np.abs(gs - ref))),
                        "pixels_changed": m["footprint"],
                    }
                )
                print(rows[-1], flush=True)
    out = pd.DataFrame(rows)
    out.to_csv(Path(args.out), index=False)
    return 0


def _name(spec: str) -> str:
    return spec.partition("=")[0] if "=" in spec else Path(spec).stem


def table(args) -> int:
    df = pd.read_csv(args.records)
    causes = Path(args.records).with_name("causes.csv")
    if causes.exists():
        df = df.merge(pd.read_csv(causes)[["site_id", "cause"]], on="site_id", how="left")
    text = tables(df)
    if "strict_class" in df:
        text += "\n## seuwgpu strict profile against gsplat\n\n" + "\n\n".join(
            [markdown(agreement(df, None, "strict", "gs")), markdown(agreement(df, "field", "strict", "gs"))]
        )
    print(text)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="render the sampled sites with both renderers")
    r.add_argument("--model", action="append", required=True, help="NAME=PATH, a model file or an embedded scene")
    r.add_argument("--out", required=True)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--top", type=int, default=1, help="sites per (field, sign or exponent bit)")
    r.add_argument("--mantissa", type=int, default=3, help="sites per field at random mantissa bits")
    r.add_argument("--views", type=int, default=2)
    r.add_argument("--size", type=int, default=128)
    r.add_argument("--batch", type=int, default=32)
    r.add_argument("--threads", type=int, default=1, help="torch threads")
    r.add_argument("--strict", action="store_true", help="also seuwgpu's strict profile")
    r.add_argument("--field", action="append", help="only the sites of this field (repeatable)")
    r.add_argument("--fp64", action="store_true", help="gsplat's covariance and projection in float64")
    r.add_argument("--alpha-cap", type=float, default=None, help="gsplat's alpha cap (default: 1.5.3's 0.999)")
    r.set_defaults(fn=run)
    t = sub.add_parser("table", help="agreement tables (markdown) from records.csv")
    t.add_argument("records")
    t.set_defaults(fn=table)
    e = sub.add_parser("explain", help="label each disagreement with its cause (causes.csv)")
    e.add_argument("records")
    e.add_argument("--model", action="append", required=True, help="as for run")
    e.set_defaults(fn=explain)
    c = sub.add_parser("clean", help="clean frames of both renderers compared (a CSV)")
    c.add_argument("--model", action="append", required=True, help="as for run")
    c.add_argument("--out", required=True, help="the CSV to write")
    c.add_argument("--views", type=int, default=2)
    c.add_argument("--size", type=int, default=128)
    c.add_argument("--threads", type=int, default=1)
    c.set_defaults(fn=clean)
    args = ap.parse_args(argv)
    return args.fn(args)


if __name__ == "__main__":
    sys.exit(main())
