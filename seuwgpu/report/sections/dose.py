"""Dose response and the redundancy budget (analysis/dose.py)."""

from __future__ import annotations

from seuwgpu.analysis import (
    dose,
    reliability,
)
from seuwgpu.analysis.records import (
    dose_records,
    reference_precision,
)
from seuwgpu.faults.defenses import guard_arms
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def dose_section(df, manifests, ctx) -> Section:
    curves = dose.dose_curves(df)
    fits = dose.dose_fits(curves)
    ctx["results"]["dose_fits"] = fits
    ctx["results"]["dose_curves"] = curves
    sec = Section(
        "dose",
        "Behavior under accumulated dose",
        "k simultaneous upsets drawn uniformly over one model's stored bits; every defense sees the "
        "same upset sets. Per model; PSNR over finite frames, non-finite frames counted apart (their "
        "PSNR is undefined) and ranked lowest in medians.",
    )
    sec.figures.append(
        FigureItem(
            "fig_dose",
            "Quality and catastrophes against dose",
            dose.plot_dose(curves, fits),
            "Left: median PSNR against k with the interquartile band, per model, precision and defense "
            "(colour: model; solid: none, dashed: defended); triangles at the foot, a row per series: the "
            "median frame is non-finite. "
            "Right: catastrophic fraction with 95% Wilson intervals and the fitted 1-(1-p)^k; dotted: 30 dB.",
            prov(curves),
        )
    )
    sec.tables.append(
        TableItem(
            "dose_fits",
            "Dose model fits",
            fits,
            "Per model, precision and defense: p of P(catastrophic | k) = 1-(1-p)^k by maximum likelihood "
            "(%, profile-likelihood 95% interval), deviance G^2 with its degrees of freedom and p-value, "
            "and the share of k points whose Wilson interval holds the fitted curve.",
        )
    )
    sec.tables.append(
        TableItem(
            "dose_curves",
            "Dose response",
            curves,
            "Per model, precision, defense and k: samples, non-finite share (%), PSNR quartiles over all "
            "frames (a frame with a non-finite pixel ranks lowest, shown as -inf) and PSNR of the mean MSE "
            "over finite frames (dB), mean SSIM, footprint (%), catastrophic fraction "
            "with its 95% Wilson interval.",
            csv_only=True,
        )
    )
    ref = reference_precision(curves)
    # per model (its key as p_c's: the scene, or scene_N<n>) when there are several: one model's
    # median stood for all of them (the last in row order), unnamed
    ref_curves = curves[curves["precision"] == ref]
    models = reliability.models_in(ref_curves)
    per_model = len(models) > 1
    arms = guard_arms(ref_curves["defense"])  # none and the guard the runs ran (guard, else guard_all, ...)
    for m in models.itertuples():
        g = ref_curves[(ref_curves["scene"] == m.scene) & (ref_curves["n_primitives"] == m.n_primitives)]
        kmax = int(g["k"].max())
        tail = f"_{m.key}" if per_model else ""
        sec.numbers[f"dose_kmax{tail}"] = kmax
        for dfn in arms:
            top = g[(g["defense"] == dfn) & (g["k"] == kmax)]
            if len(top):
                sec.numbers[f"dose_psnr_median_at_kmax{tail}_{dfn}_db"] = float(top["psnr_median_db"].iloc[0])
                sec.numbers[f"dose_nonfinite_at_kmax{tail}_{dfn}_pct"] = float(top["nonfinite_pct"].iloc[0])
    # did the grid reach the point where the unguarded render is destroyed (most frames catastrophic)?
    top = curves[curves["defense"] == "none"].sort_values("k").groupby(["scene", "n_primitives", "precision"]).tail(1)
    short = top[top["cat_rate_pct"] < 50]
    for _, r in short.iterrows():
        sec.notes.append(
            f"{r['scene']} (N = {int(r['n_primitives']):,}, {r['precision']}): at the largest k = {int(r['k']):,} only "
            f"{r['cat_rate_pct']:.3g}% of unguarded frames are catastrophic: the sweep stops before the render is "
            "destroyed (raise dose.k_max)"
        )
    reps = dose_records(df).groupby(["scene", "n_primitives", "precision", "defense", "k"]).size()
    if len(reps) and reps.min() < 10:
        sec.notes.append(f"only {int(reps.min())} repeats at some dose points (>= 10 recommended)")
    return sec


def budget_section(df, manifests, ctx) -> Section:
    b = dose.redundancy_budget(df)
    sec = Section(
        "budget",
        "Redundancy budget against primitive count",
        "The dose k at which the median PSNR first falls to 30 dB (non-finite frames ranked lowest), "
        "interpolated in log k inside its bracket (k_lo, k_hi] on the k grid; censored '>=' when it "
        "never falls within the sweep, '<=' when the bracket is open below.",
    )
    if b["n_primitives"].nunique() >= 2:
        sec.figures.append(
            FigureItem(
                "fig_budget",
                "Redundancy budget against N",
                dose.plot_budget(b),
                "Redundancy budget against primitive count, with the k-grid bracket as error bar; open "
                "markers are censored bounds: ^ at least (never reached in the sweep), v at most (reached "
                "at the first k).",
                prov(b),
            )
        )
    else:
        ctx["skipped"].append(
            (
                "Redundancy budget against N (figure)",
                "dose records at a single primitive count",
                "run a size campaign (dose sweeps on subsampled models)",
            )
        )
    for _, r in b.iterrows():
        key = f"budget_k_{r['scene']}_{r['n_primitives']}_{r['precision']}_{r['defense']}"
        sec.numbers[key] = f"{r['censored']}{r['k_budget']:.4g}"
    sec.tables.append(TableItem("redundancy_budget", "Redundancy budget", b, "Per model, precision and defense."))
    return sec
