"""The report's sections: one builder per analysis, each returning the tables, figures, notes and
headline numbers of one `Section`; `run_sections` runs those the records support and lists the
others as skipped (with the campaign that would supply them)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np
import pandas as pd

from seuwgpu.analysis import (
    claims,
    contamination,
    criticality,
    dose,
    guard,
    mitigation,
    outcomes,
    prediction,
    reliability,
    scaling,
    scenes,
    theory,
)
from seuwgpu.analysis import estimate as E
from seuwgpu.analysis.records import (
    InsufficientData,
    dose_records,
    n_records,
    precisions_present,
    provenance_text,
    record_weights,
    reference_precision,
    scale_sign_flips,
    single_upsets,
)
from seuwgpu.errors import MissingExtra
from seuwgpu.faults.defenses import DEFENSES, FIRST_DEFENSES


@dataclass
class TableItem:
    name: str  # file stem
    title: str
    df: pd.DataFrame
    caption: str  # what it shows (provenance is appended)
    prov: dict | None = None
    csv_only: bool = False  # a long table: linked as CSV/Markdown, not inlined in the page

    def full_caption(self) -> str:
        prov = self.prov if self.prov is not None else self.df.attrs.get("provenance", {})
        return f"{self.caption} {provenance_text(prov)}".strip()


@dataclass
class FigureItem:
    name: str
    title: str
    fig: object  # matplotlib Figure
    caption: str
    prov: dict | None = None

    def full_caption(self) -> str:
        return f"{self.caption} {provenance_text(self.prov or {})}".strip()


@dataclass
class Section:
    key: str
    title: str
    text: str = ""
    tables: list[TableItem] = dc_field(default_factory=list)
    figures: list[FigureItem] = dc_field(default_factory=list)
    notes: list[str] = dc_field(default_factory=list)
    skipped: list[tuple[str, str, str]] = dc_field(default_factory=list)  # partial skips
    numbers: dict = dc_field(default_factory=dict)


def _prov(t) -> dict:
    return t.attrs.get("provenance", {}) if hasattr(t, "attrs") else {}


def _sec_claims(df, manifests, ctx) -> Section:
    rates = ctx["results"]["model_rates"] = claims.arm_model_rates(df)  # p_c rows and per-model table
    t = claims.claims_table(df, ctx["results"], manifests=manifests)
    sec = Section(
        "claims",
        "Claims of the paper against these records",
        "Each quantitative claim of the paper, the value measured here with its 95% interval, the "
        "paper's value and the verdict: reproduced (the interval meets the paper's value as printed, i.e. "
        "give or take half a unit of its last digit: 0.997 is any value in [0.9965, 0.9975]), differs, "
        "or not measured. The paper's models are not these: a difference is a finding, not an error.",
    )
    sec.tables.append(
        TableItem(
            "claims",
            "Claims",
            t,
            "Claims of the paper, measured on these records. interval_over says what the interval (and "
            "so the verdict) is over: the models (a t interval of the per-model estimates, n_models - 1 "
            "degrees of freedom: reproduced when it holds the paper's value, differs when not, "
            "inconclusive with under 3 models or when it also holds 0), or the records of these models; "
            "pooled: the estimate over all records with its within-model interval. A NaN paper value: "
            "this project's own estimate.",
        )
    )
    me = claims.model_estimates(df, rates=rates)
    if len(me):
        sec.tables.append(
            TableItem(
                "claims_models",
                "p_c per model",
                me,
                "Per model, fp32 (%, stratified 95% intervals): p_c as the plain mean of the per-field rates "
                "(fields_*, the paper's definition) and weighted by stored bits (bits_*), without and with the "
                "guard, and the guard's share 1 - p_c(guard) / p_c(none) of the per-field means.",
            )
        )
    th = ctx["results"].get("theory")
    if th is not None and th.get("precision") == "fp32":
        sec.tables.append(
            TableItem(
                "claims_theory_windows",
                "Mantissa slope against the fit window",
                claims.theory_windows(th),
                "The log2 slope of the mean peak error per mantissa bit over other fit windows (bits in, "
                "95% t interval over bits) and the verdict each would give against the paper's value.",
            )
        )
    sec.notes += [f"The paper's own inconsistency: {n}" for n in claims.PAPER_INCONSISTENCIES]
    sec.numbers["claims"] = t.to_dict("records")
    return sec


def profile_section(all_records: pd.DataFrame) -> Section | None:
    """Headline catastrophe rates under each renderer profile, when the runs hold more than one
    (the other sections then rest on the strict profile's records alone, never on a mix)."""
    if all_records["profile"].nunique() < 2:
        return None
    t = outcomes.catastrophic_by_profile(all_records)
    if t.empty:
        return None
    sec = Section(
        "profiles",
        "Renderer profiles",
        "The runs hold records under several renderer profiles (docs/renderer.md, Profiles: strict "
        "draws a non-finite covariance as a frame-covering sheet, gsplat follows gsplat's CUDA "
        "arithmetic and culls it). Every other section rests on the strict records alone; this "
        "table gives the weighted single-upset catastrophe rate under each profile.",
    )
    sec.tables.append(
        TableItem(
            "profiles",
            "Catastrophe rate by renderer profile",
            E.percent(t[["profile", "scene", "precision", "defense", "n", "events", "rate", "ci_lo", "ci_hi"]]),
            "Weighted catastrophe rate (%) of single upsets per profile, scene, precision and defense, "
            "with its 95% interval (Wilson per cell, stratified when pooled over cells).",
        )
    )
    sec.numbers["catastrophic_by_profile"] = [
        {
            k: (x[k] if k in ("profile", "scene", "precision", "defense") else float(x[k]))
            for k in ("profile", "scene", "precision", "defense", "rate", "ci_lo", "ci_hi")
        }
        | {"n": int(x["n"])}
        for _, x in t.iterrows()
    ]
    return sec


def _sec_outcomes(df, manifests, ctx) -> Section:
    long = outcomes.outcome_table(df)
    thr = long.attrs.get("thresholds", {})
    sec = Section(
        "outcomes",
        "Outcome classes of single upsets",
        "Every single upset in one class: masked (frame bit-identical to clean), tolerable (changed, "
        f"no channel by more than {thr.get('pixel_threshold', 1 / 255):.4g}), SDC (visible change, "
        f"footprint at most {100 * thr.get('footprint_threshold', 0.01):g}%), catastrophic (footprint "
        f"over {100 * thr.get('footprint_threshold', 0.01):g}% or a non-finite pixel). Shares are weighted "
        "by the stored bits each record stands for (a uniform upset's view), pooled over scenes.",
    )
    wide = outcomes.outcome_wide(long)
    sec.tables.append(
        TableItem(
            "outcomes",
            "Outcome classes by precision and defense",
            wide,
            "Weighted share (%) of single upsets per outcome class with its 95% stratified interval.",
        )
    )
    sec.tables.append(
        TableItem("outcomes_long", "Outcome classes (long form)", long, "The same, one row per class.", csv_only=True)
    )
    sec.numbers["outcome_thresholds"] = thr
    sec.numbers["outcomes"] = long[
        ["precision", "defense", "outcome", "n", "rate_pct", "ci_lo_pct", "ci_hi_pct"]
    ].to_dict("records")
    return sec


def _sec_scenes(df, manifests, ctx) -> Section:
    t, notes = scenes.scene_table(df, manifests)
    sec = Section(
        "scenes",
        "Table 1: scenes",
        "The models the records rest on; box_<field>: the widest component of the support guard's "
        "box (max - min of the clean stored values) in each field.",
    )
    sec.tables.append(TableItem("scenes", "Scenes", t, "Scenes, primitive counts, SH degree and support boxes."))
    sec.notes.extend(notes)
    return sec


def _sec_criticality(df, manifests, ctx) -> Section:
    crit = criticality.criticality(df)
    prec = crit.attrs["precision"]
    fb = criticality.field_bit_table(df)
    sec = Section(
        "criticality",
        "Concentration of single-bit criticality",
        "Single-bit upsets of the single-upset campaign without defense. Footprint is "
        "the percent of pixels whose colour changes by more than 1/255 (mean over "
        "views); catastrophic means footprint > 1% or a non-finite pixel. Quantiles, means "
        "and rates are weighted by the stored bits each record stands for.",
    )
    sec.tables.append(
        TableItem(
            "criticality",
            f"Per-field severity at {prec}",
            crit,
            f"Per-field single-bit upset severity at {prec}, pooled over scenes and bits: weighted footprint "
            "quantiles (% of frame) and catastrophe rate (%) with its 95% stratified interval.",
        )
    )
    sec.figures.append(
        FigureItem(
            "fig_heatmap",
            "Field x bit mean footprint",
            criticality.plot_field_bit_heatmap(fb),
            "Mean corruption footprint (% of frame, log colour scale) over field and bit position, "
            "one panel per precision, pooled over scenes; grey cells: zero mean footprint.",
            _prov(fb),
        )
    )
    sec.tables.append(
        TableItem(
            "field_bit",
            "Per (precision, field, bit) cell",
            fb,
            "Per-cell sample count, weight share, mean and max footprint (%) and catastrophe rate with "
            "its 95% interval (Wilson; stratified over scenes where a cell pools several); the data "
            "behind the heat map.",
            csv_only=True,
        )
    )
    s = single_upsets(df, prec, "none")
    sign = scale_sign_flips(s)
    if len(sign):
        fp, w = sign["footprint"].to_numpy(float) * 100, record_weights(sign)
        mean, p99 = E.wmean(fp, w), E.wquantile(fp, w, 0.99)
        sec.numbers.update(
            scale_sign_footprint_mean_pct=mean, scale_sign_footprint_p99_pct=p99, scale_sign_n=n_records(sign)
        )
        sec.notes.append(
            f"log-scale sign bit at {prec}: mean footprint {mean:.4g}%, p99 {p99:.4g}% (n = {n_records(sign):,})."
        )
    cells = fb[fb["precision"] == prec]
    if len(cells):
        sec.notes.append(
            f"{prec}: {len(cells)} (field, bit) cells sampled; fewest samples in a "
            f"cell: {int(cells['n'].min()):,}, most: {int(cells['n'].max()):,}."
        )
        sec.numbers["min_samples_per_cell"] = int(cells["n"].min())
    return sec


def _sec_precision(df, manifests, ctx) -> Section:
    rates = criticality.precision_rates(df)
    precs = precisions_present(rates)
    if len(precs) < 2:
        raise InsufficientData(
            f"single-upset records at one precision only ({', '.join(precs)})",
            "run the single-upset campaign at fp32, fp16 and bf16",
        )
    sec = Section(
        "precision",
        "Numeric precision changes the exposure",
        "Weighted catastrophe rate by field for each stored precision (no defense).",
    )
    sec.figures.append(
        FigureItem(
            "fig_precision",
            "Catastrophe rate by field and precision",
            criticality.plot_precision_rates(rates),
            "Weighted catastrophic-upset rate (%, log scale) by field and numeric format, with 95% "
            "stratified intervals, pooled over scenes and bits; open triangles: no event, the rate lies "
            "below the interval's upper end.",
            _prov(rates),
        )
    )
    sec.tables.append(
        TableItem(
            "precision_rates",
            "Catastrophe rate by precision and field",
            rates,
            "Weighted catastrophe rate (%) per precision and field with 95% stratified intervals, and "
            "the weighted mean footprint (%).",
        )
    )
    return sec


def _sec_theory(df, manifests, ctx) -> Section:
    res = theory.theory_check(df)
    ctx["results"]["theory"] = res
    t = res["table"]
    sec = Section(
        "theory",
        "Validation of the perturbation bound",
        "Lemma (value perturbation): a mantissa flip of bit b changes the value by "
        "2^(e+b-p), so the peak image error doubles per bit (unit slope in log2) until "
        "one primitive's contribution saturates the pixels it covers.",
    )
    sec.figures.append(
        FigureItem(
            "fig_theory",
            "Peak error against mantissa bit",
            theory.plot_theory(res),
            f"Weighted mean peak error |dI|_inf against mantissa bit index for {res['field']} at "
            f"{res['precision']} (log2 axis), the fitted line over bits {res['fit_bits'][0]}.."
            f"{res['fit_bits'][1]} and the unit-slope prediction.",
            _prov(t),
        )
    )
    fit = pd.DataFrame(
        [
            {
                "field": res["field"],
                "precision": res["precision"],
                "fitted_log2_slope": res["slope"],
                "slope_ci_lo": res["slope_lo"],
                "slope_ci_hi": res["slope_hi"],
                "predicted_slope": 1.0,
                "r2": res["r2"],
                "fit_bits": f"{res['fit_bits'][0]}..{res['fit_bits'][1]}",
                "n_fit_bits": res["n_fit_bits"],
            }
        ]
    )
    sec.tables.append(
        TableItem(
            "theory_fit",
            "Fitted slope",
            fit,
            "Fitted log2 slope of the mean peak error per mantissa bit (95% t interval) against the unit "
            "slope of the perturbation lemma.",
            _prov(t),
        )
    )
    sec.tables.append(TableItem("theory", "Mean peak error per mantissa bit", t, "Per mantissa bit.", csv_only=True))
    if res["note"]:
        sec.notes.append(res["note"])
    sec.numbers.update(
        theory_slope=res["slope"], theory_slope_ci=[res["slope_lo"], res["slope_hi"]], theory_r2=res["r2"]
    )
    return sec


def _sec_guard(df, manifests, ctx) -> Section:
    res = guard.guard_analysis(df)
    ctx["results"]["guard"] = res
    sec = Section(
        "guard",
        "Support guard evaluation",
        "The same single-upset fault sites rendered without defense and with the "
        "support guard (records paired by injection id); rates and shares weighted.",
    )
    sec.figures.append(
        FigureItem(
            "fig_guard",
            "Footprint distribution with and without the guard",
            guard.plot_guard_ccdf(df),
            "Weighted complementary CDF of the corruption footprint (% of frame) of a uniform upset, "
            "without defense and with the support guard, all precisions pooled; dotted: the 1% threshold.",
            _prov(res["summary"]),
        )
    )
    sec.tables.append(
        TableItem(
            "guard_summary",
            "Footprint and catastrophe rate by defense",
            res["summary"],
            "Weighted footprint statistics (% of frame) and catastrophe rate with its 95% stratified "
            "interval, without and with the guard, per precision.",
        )
    )
    sec.tables.append(
        TableItem(
            "guard_paired",
            "Catastrophic upsets neutralised",
            res["paired"],
            "On paired fault sites: catastrophic upsets without defense, the weighted share the guard "
            "neutralises (95% stratified interval), residual catastrophic events, of which catastrophic "
            "without the guard too (catastrophic_both) and turned catastrophic by it (turned_catastrophic, "
            "not catastrophic without it; turned_share_pct: their weighted share of the paired sites), worst "
            "guarded footprint (%).",
        )
    )
    if len(res["sign_psnr"]):
        sec.tables.append(
            TableItem(
                "guard_sign_psnr",
                "Image quality after log-scale sign flips",
                res["sign_psnr"],
                "Log-scale sign-bit upsets without and with the guard: share of frames with a non-finite "
                "pixel (their PSNR and SSIM are undefined), median PSNR and PSNR of the mean MSE over the "
                "finite frames (dB; identical frames count as infinite / zero error), mean SSIM, footprint.",
            )
        )
    sec.notes.append(
        f"{res['n_guarded']:,} guarded single-bit upsets: worst footprint "
        f"{res['worst_guarded_footprint_pct']:.4g}% of the frame, "
        f"{res['residual_catastrophic']} residual catastrophic events "
        f"({res['catastrophic_both']} catastrophic without the guard too, {res['turned_catastrophic']} "
        "turned catastrophic by it: not catastrophic without it); "
        f"weighted share of catastrophic upsets neutralised {res['share_pct']:.4g}% "
        f"[{res['share_ci'][0]:.4g}, {res['share_ci'][1]:.4g}] "
        + (
            "(every precision pooled, weighted by stored bits; per precision in the paired table)."
            if res["share_precision"] == "all"
            else f"({res['share_precision']})."
        )
    )
    sec.numbers.update(
        guard_share_neutralised_pct=res["share_pct"],
        guard_share_neutralised_ci_pct=list(res["share_ci"]),
        # which records the share pools: one precision, or "all" (weighted by stored bits)
        guard_share_precision=res["share_precision"],
        guard_worst_footprint_pct=res["worst_guarded_footprint_pct"],
        guard_residual_catastrophic=res["residual_catastrophic"],
        # of the residual on paired sites: catastrophic under both arms, and made catastrophic by the guard
        guard_catastrophic_both=res["catastrophic_both"],
        guard_turned_catastrophic=res["turned_catastrophic"],
        guard_n_sites=res["n_guarded"],
    )
    return sec


def _sec_mitigation(df, manifests, ctx) -> Section:
    t = mitigation.mitigation_table(df, manifests)
    sec = Section(
        "mitigation",
        "Alternative defenses",
        "Each defense on the shared fault grid (the fault sites measured under every "
        "defense present) at one precision, with its measured cost.",
    )
    cap = (
        f"Mitigations at {t.attrs['precision']}"
        + (" on a shared (paired) fault grid" if t.attrs.get("paired") else " (unpaired: no shared site)")
        + ": weighted catastrophe rate (%) with 95% stratified interval, footprint (%), memory overhead "
        "(% of the stored model; memory_basis) and time overhead (% of one view's render time, measured "
        "in the same run; time_basis; time_overhead_mean_pct with its 95% t interval over the models, each "
        "model's mean time with the defense over its mean time without, and time_resolved: 'not resolved' "
        "where the interval holds 0). Per scene and precision, on the dangerous cells and against the "
        "Pareto front: the defenses table (Defenses against cost), where the records hold its defenses."
    )
    sec.figures.append(
        FigureItem(
            "fig_mitigation",
            "Catastrophe rate by defense",
            mitigation.plot_mitigation(t),
            "The mitigation table's weighted catastrophe rate (%, log scale) per defense with its 95% "
            "stratified interval and its memory overhead; open triangles: no catastrophic event, the rate "
            "lies below the interval's upper end.",
            _prov(t),
        )
    )
    sec.tables.append(TableItem("mitigation", "Mitigation table", t, cap))
    sec.numbers["mitigation"] = t[
        [
            "defense",
            "n",
            "cat_rate_pct",
            "cat_ci_lo_pct",
            "cat_ci_hi_pct",
            "memory_overhead_pct",
            "time_ms",
            "time_overhead_pct",
            "time_overhead_mean_pct",
            "time_overhead_lo_pct",
            "time_overhead_hi_pct",
            "time_resolved",
        ]
    ].to_dict("records")
    for _, r in t[t["time_resolved"] == "not resolved"].iterrows():
        sec.notes.append(
            f"{r['label']}: time overhead {r['time_overhead_mean_pct']:.3g}% "
            f"[{r['time_overhead_lo_pct']:.3g}, {r['time_overhead_hi_pct']:.3g}] over {int(r['time_groups'])} "
            "models: not resolved (the interval holds 0)"
        )
    if t["time_ms"].isna().all():
        sec.notes.append("no time_ms recorded (records of an older run): time cost not reported")
    return sec


def _sec_defenses(df, manifests, ctx) -> Section:
    from seuwgpu.analysis import defenses as D  # issue 16: defenses against cost (own module)

    if not D.has_new_defenses(df):
        others = ", ".join(d for d in DEFENSES if d not in FIRST_DEFENSES)
        raise InsufficientData(
            "no defense beyond guard/ECC/duplication in the records",
            f"run the single-upset campaign with defenses from {others} beside none (`seuwgpu defenses` lists them)",
        )
    t = D.defense_table(df, manifests=manifests)
    sec = Section("defenses", "Defenses against cost", "Residual catastrophic rate of every defense (paired arms).")
    cap = (
        "Per scene and defense: catastrophic rate (%) stratified by (field, bit) cell with 95% interval, "
        "the same on the dangerous cells (log-scale sign and top exponent bit, opacity top exponent bit) and "
        "relative to no defense, memory overhead (% of the stored model). Time: `seuwgpu defenses` "
        "(not measured here, so meets_goal is <NA> where every other criterion passes). "
        "Pooled over scenes on the shared fault grid, with footprints and the time measured in the run: "
        "the mitigation table (Alternative defenses)."
    )
    sec.tables.append(TableItem("defenses", "Defenses against cost", t, cap))
    sec.figures.append(FigureItem("fig_pareto", "Pareto", D.pareto_figure(t), "Residual rate against memory."))
    return sec


def _sec_dose(df, manifests, ctx) -> Section:
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
            _prov(curves),
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
    for m in models.itertuples():
        g = ref_curves[(ref_curves["scene"] == m.scene) & (ref_curves["n_primitives"] == m.n_primitives)]
        kmax = int(g["k"].max())
        tail = f"_{m.key}" if per_model else ""
        sec.numbers[f"dose_kmax{tail}"] = kmax
        for dfn in ("none", "guard"):
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


def _sec_budget(df, manifests, ctx) -> Section:
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
                _prov(b),
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


def _sec_size(df, manifests, ctx) -> Section:
    res = scaling.size_scaling(df, frame_size=scaling.frame_size_of(manifests))
    ctx["results"]["size"] = res
    sec = Section(
        "size",
        "Single-upset error against primitive count",
        "Single upsets on models of several sizes; error is the frame MSE over finite frames (from "
        "PSNR, peak 1), weighted. alpha = -exponent of the log-log fit (sigma^2(N) = Theta(N^-alpha)), "
        "95% t interval; zero values cannot be fitted and are shown, not dropped. The upsets sampled "
        f"the fields {', '.join(res['fields'])} and bits {', '.join(map(str, res['bits']))}: the error is "
        "over those, not over every stored bit.",
    )
    sec.figures.append(
        FigureItem(
            "fig_size",
            "Single-upset error against N",
            scaling.plot_size_scaling(res),
            "Weighted mean single-upset frame MSE against primitive count (log-log), fitted power laws "
            "with alpha and its 95% interval in the legend; open triangles at the foot: zero.",
            _prov(res["table"]),
        )
    )
    sec.tables.append(
        TableItem(
            "size_fits",
            "Log-log fits",
            res["fits"],
            "Log-log least-squares fits against N: sizes, sizes fitted, zero points, exponent and alpha "
            "with 95% t intervals (NaN with fewer than three positive sizes: two points fit any line), R^2.",
        )
    )
    sec.tables.append(
        TableItem(
            "size_scaling",
            "Error per size",
            res["table"],
            f"Per scene, precision, defense and N (source campaign: {res['source_campaign']}).",
            csv_only=True,
        )
    )
    floor = res["median_floor"]
    sec.tables.append(
        TableItem(
            "size_groups",
            "Two experiments: procedural scenes and captures",
            res["groups"],
            "Procedural scenes (regenerated at each N, smaller splats) and captures (random subsets of one "
            "model) fitted apart: one exponent per group with an intercept per scene (alpha_common, 95% t "
            "interval), the mean of the per-scene alphas with its t interval over scenes, and the F test "
            "(extra sum of squares) of equal slopes in the two groups. The median is fitted only at sizes "
            + (
                f"where it exceeds one 8-bit level on one channel of one pixel, {floor:.3g} of frame MSE "
                "(size_scaling's median_above_floor says where)."
                if np.isfinite(floor)
                else "with a positive median (the runs do not give one frame size: no 8-bit floor)."
            ),
        )
    )
    below = res["table"][~res["table"]["median_above_floor"]]
    if len(below):
        sec.notes.append(
            f"The median single-upset MSE lies below the 8-bit floor ({floor:.3g}) at {len(below)} of "
            f"{len(res['table'])} (scene, defense, N) points: there it is float32 rounding of a frame no display "
            "changes, and it is not fitted."
        )
    f = res["fits"]
    for _, r in f[f["metric"] == "mean_mse"].iterrows():
        sec.numbers[f"size_alpha_{r['scene']}_{r['precision']}_{r['defense']}"] = [
            float(r["alpha"]),
            float(r["alpha_lo"]),
            float(r["alpha_hi"]),
        ]
    if len(res["guard_factor"]):
        sec.tables.append(
            TableItem(
                "size_guard_factor",
                "Guard factor at the largest N",
                res["guard_factor"],
                "Mean single-upset MSE without / with the guard at the largest primitive count.",
            )
        )
    return sec


def _schedule_text(res) -> str:
    """The check schedule the MTBF rows used: one S, or S per check defense."""
    per = res.get("check_every_of") or {}
    if isinstance(res["check_every"], dict) and per:
        return ", ".join(f"{d} S = {s}" for d, s in per.items())
    return f"S = {res['check_every']}"


def _sec_reliability(df, manifests, ctx) -> Section:
    # the single-upset p_c alone (analysis.reliability notes): no dose fit's p as a per-upset probability
    res = reliability.reliability(df, manifests)
    prec = res["precision"]
    per_model = res["per_model"]
    sec = Section(
        "reliability",
        "Reliability under realistic upset rates",
        "p_c is the probability that one upset, uniform over the stored bits, is catastrophic (the "
        "weighted single-upset rate), each model's own. The MTBF uses it alone: at these rates the "
        "expected upsets alive per scrub interval (live_upsets_per_scrub in mtbf_detail, with its regime) "
        "stay far below the tens to thousands where the dose fits' p was measured. Upsets accumulate "
        "until the next scrub, every "
        f"{res['scrub_hours']:g} h: MTBF = T / (1 - exp(-rate x bits x p x T)). Rates and scrub interval: "
        f"{res['rates_from']}. A check defense repairs what it detects at its next check, every S frames "
        f"({_schedule_text(res)}; S from {res['check_every_from']}) at {res['frames_per_second']:g} frames/s: "
        "what it repairs counts for the frames it is drawn until then, (S - 1) / 2 on average (exposure_hours)."
        + (
            f" These records hold {len(res['models'])} models (scenes): each has its own p_c, stored bits, "
            "MTBF rows; none is pooled over scenes."
            if per_model
            else ""
        ),
    )
    cap = (
        "Per-upset catastrophe probability per precision and defense with its 95% stratified "
        "interval and the share of stored bits covered by sampled cells. Upsets are drawn over "
        "the model's stored values only: ECC's check bits and duplication's second copy are "
        "assumed intact (faults/defenses.py), so for those arms p_c is per upset in the data "
        "bits, and duplication's 0 follows from that assumption, not from the sample."
    )
    if per_model:
        cap = "Per model (scene, primitive count), its own rows: p" + cap[1:]
    sec.tables.append(TableItem("reliability_pc", "p_c", res["pc"], cap))
    if res["mtbf_wide"] is not None and len(res["mtbf_wide"]):
        if per_model:
            cap = (
                f"Per model at {prec}, each with its own single-upset p_c and its own "
                f"stored bits (model_bits), scrubbed every {res['scrub_hours']:g} h "
                "('> x': no event, bound from the upper limit of p)."
            )
        else:
            cap = (
                f"For a model of {res['bits']:.3g} stored bits at {prec}, scrubbed every {res['scrub_hours']:g} h "
                "('> x': no event, bound from the upper limit of p)."
            )
        sec.tables.append(
            TableItem("mtbf", "Mean time between catastrophic frames", res["mtbf_wide"], cap, _prov(res["mtbf"]))
        )
        sec.tables.append(
            TableItem(
                "mtbf_detail",
                "MTBF inputs and intervals",
                res["mtbf"],
                "Per model and environment." if per_model else "Per environment.",
                csv_only=True,
            )
        )
        sec.figures.append(
            FigureItem(
                "fig_reliability",
                "MTBF against the upset rate",
                reliability.plot_sensitivity(res),
                "MTBF of catastrophic frames against the per-bit upset rate, per defense and source of p "
                "(colour: defense; single-upset p_c; bands: 95% interval of p); "
                "triangles: no catastrophic event, the line is the lower bound from the upper limit of p; "
                "dotted: the named environments."
                + (" A panel per model, with its own p and stored bits." if per_model else ""),
                _prov(res["mtbf"]),
            )
        )
    for env in res["rates"]:
        sec.notes.append(
            f"rate, {env['environment']}: {float(env['per_bit_hour']):.3g} upsets/bit/h "
            f"({float(env['per_bit_hour']) * 1e15:.3g} FIT/Mbit). {env.get('source', '')}"
        )
    sec.notes.extend(res["notes"])
    pc = res["pc"]
    for m in res["models"]:
        rows = pc[(pc["scene"] == m["scene"]) & (pc["n_primitives"] == m["n_primitives"])] if per_model else pc
        for dfn in ("none", "guard"):
            r = reliability.pc_lookup(rows, prec, dfn)
            if r is not None:
                key = f"p_c_{m['key']}_{dfn}_pct" if per_model else f"p_c_{dfn}_pct"
                sec.numbers[key] = [100 * float(r["p_c"]), 100 * float(r["ci_lo"]), 100 * float(r["ci_hi"])]
    sec.numbers["model_bits"] = res["bits"]  # a number for one model, {model key: bits} for several
    sec.numbers["scrub_hours"] = res["scrub_hours"]
    sec.numbers["check_every"] = res["check_every"]
    sec.numbers["frames_per_second"] = res["frames_per_second"]
    return sec


def _sec_contamination(df, manifests, ctx) -> Section:
    cont = contamination.contamination(df)
    sec = Section(
        "contamination",
        "Cross-node contamination in distributed rendering",
        "Sort-first partitions of the screen into P tile-aligned regions (the grid the Ray ranks "
        "render): the weighted share of regions one upset contaminates, predicted from the projected "
        "footprint and measured from changed pixels, and their IoU.",
    )
    sec.figures.append(
        FigureItem(
            "fig_contamination",
            "Contaminated regions against P",
            contamination.plot_contamination(cont),
            "Share of regions contaminated by one log-scale sign-bit upset against P at the reference "
            "precision, predicted (solid) and measured (dashed), without and with the guard.",
            _prov(cont),
        )
    )
    cap = (
        "Per subset, precision, defense and P. Per frame, as the paper counts: pred_frame_pct, the share "
        "of the regions of one rendered frame that the tile rectangle of the primitive as the renderer "
        "reads it after the upset and the defense reaches (the whole primitive, also where the frame does "
        "not change: a corrected upset still predicts its clean footprint), and meas_frame_pct, the share "
        "of one frame's regions holding a pixel changed by more than 1/255, each averaged over the views "
        "(NaN for records that predate them). Over the union of the views: pred_fraction_pct and "
        "meas_fraction_pct, the same shares of the regions reached in any view. All "
        "weighted by stored bits, without interval. iou_mean: over the n_iou records where either set is "
        "non-empty (0 where nothing changed). slowest_region_ms and imbalance: plain means over records."
    )
    sec.tables.append(TableItem("contamination", "Region contamination", cont, cap))
    sub = cont[(cont["subset"] == "log-scale sign") & cont["defense"].isin(["none", "guard"])]
    if len(sub):
        sub = sub[sub["precision"] == reference_precision(sub)]
        pmax = int(sub["P"].max())
        for _, r in sub[sub["P"] == pmax].iterrows():
            key = f"{r['precision']}_{r['defense']}_P{pmax}"
            sec.numbers[f"contam_sign_pred_pct_{key}"] = float(r["pred_fraction_pct"])
            sec.numbers[f"contam_sign_meas_pct_{key}"] = float(r["meas_fraction_pct"])
            sec.numbers[f"contam_sign_pred_frame_pct_{key}"] = float(r["pred_frame_pct"])
            sec.numbers[f"contam_sign_meas_frame_pct_{key}"] = float(r["meas_frame_pct"])
            sec.numbers[f"contam_sign_iou_{key}"] = float(r["iou_mean"])
    if cont["slowest_region_ms"].isna().all():
        ctx["skipped"].append(
            (
                "Slowest-region render time and load imbalance",
                "no region_ms_max_P / region_ms_mean_P columns",
                "time the regions with `seuwgpu distributed --scene NAME --ranks 4 16 64` "
                "(each region rendered on its own Ray rank)",
            )
        )
    return sec


def _sec_prediction(df, manifests, ctx) -> Section:
    res = prediction.prediction(df, max_rows=ctx.get("max_pred_rows", 200_000))
    ctx["results"]["prediction"] = res
    sec = Section(
        "prediction",
        "Predicting criticality without injection",
        f"At {res['precision']}: a gradient-boosted classifier of 'catastrophic' from static fault-site "
        "features against the (field, bit) lookup and a constant, record-weighted, on a stratified 30% "
        "held-out split and leave-one-scene-out; AUC with 95% bootstrap intervals (each class "
        "resampled apart; none where the weights leave < 5 effective records of a class). The intervals "
        "know only the events held out: where the AUC's shortfall from 1 rests on rare cells a split "
        "holds none of, they are too narrow (analysis/stats.py auc_interval).",
    )
    if res["roc"]:
        sec.figures.append(
            FigureItem(
                "fig_roc",
                "ROC curves",
                prediction.plot_roc(res),
                "Held-out ROC curves of the classifier and both baselines, AUC [95% bootstrap interval].",
                _prov(res["summary"]),
            )
        )
    sec.tables.append(TableItem("prediction", "AUC against baselines", res["summary"], "Held-out and LOSO AUC, Brier."))
    if len(res["importance"]):
        sec.tables.append(
            TableItem(
                "prediction_importance", "Permutation importance", res["importance"], "Drop in held-out weighted AUC."
            )
        )
    if len(res["loso"]):
        sec.tables.append(
            TableItem("prediction_loso", "Leave-one-scene-out AUC", res["loso"], "Trained on the other scenes.")
        )
    sec.notes.extend(res["notes"])
    s = res["summary"].set_index("model")
    sec.numbers.update(
        pred_auc=[float(s["auc_holdout"].iloc[0]), float(s["auc_lo"].iloc[0]), float(s["auc_hi"].iloc[0])],
        pred_auc_lookup=[float(s["auc_holdout"].iloc[1]), float(s["auc_lo"].iloc[1]), float(s["auc_hi"].iloc[1])],
        pred_lookup_as_good=res["lookup_as_good"],
        pred_top_feature=res["top_feature"],
    )
    return sec


# (key, label, builder); the claims table is built last (it reads the others' results) but shown first
SECTIONS: list[tuple[str, str, Callable]] = [
    ("outcomes", "Outcome classes", _sec_outcomes),
    ("scenes", "Table 1: scenes", _sec_scenes),
    ("criticality", "Criticality (per-field table, field x bit heat map)", _sec_criticality),
    ("precision", "Per-precision catastrophe rates", _sec_precision),
    ("theory", "Theory check (mantissa slope)", _sec_theory),
    ("guard", "Guard evaluation", _sec_guard),
    ("mitigation", "Mitigation table", _sec_mitigation),
    ("defenses", "Defenses against cost (Pareto)", _sec_defenses),
    ("dose", "Dose response (quality and catastrophes against k)", _sec_dose),
    ("budget", "Redundancy budget", _sec_budget),
    ("size", "Single-upset error against N", _sec_size),
    ("reliability", "Reliability (p_c, MTBF with scrubbing)", _sec_reliability),
    ("contamination", "Distributed contamination", _sec_contamination),
    ("prediction", "Prediction of criticality", _sec_prediction),
    ("claims", "Claims table", _sec_claims),
]


def run_sections(df: pd.DataFrame, manifests: list[dict], ctx: dict) -> list[Section]:
    """Every analysis the records support, in report order; the others go to ctx["skipped"]."""
    sections: list[Section] = []
    ctx.setdefault("skipped", [])
    ctx.setdefault("max_pred_rows", 200_000)
    ctx.setdefault("results", {})
    for _key, label, builder in SECTIONS:
        try:
            sections.append(builder(df, manifests, ctx))
        except (InsufficientData, MissingExtra) as e:  # too few records, or a library the install left out
            ctx["skipped"].append((label, e.reason, e.remedy))
    return sections


def section_figures(df: pd.DataFrame, manifests: list[dict]) -> dict:
    """The report's matplotlib figures by name (what the Python API hands to a notebook)."""
    return {fi.name: fi.fig for sec in run_sections(df, manifests, {}) for fi in sec.figures}
