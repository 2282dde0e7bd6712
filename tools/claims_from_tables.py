"""Re-derive the claims rows of issue 36 from a report's stored tables, for a report whose records
are not at hand (it was written for docs/study/full, about 2 GB of Parquet, removed since: issue 46).

    python tools/claims_from_tables.py REPORT     # writes claims_rederived.csv and .md there

Every row comes from the library's functions over the stored CSVs (and summary.json's per-model
rates), never from new arithmetic here:
* p_c as the equal-field mean: the plain mean of precision_rates.csv's per-field rates (pooled over
  the models), its interval stratified over field_bit.csv's cells with each field weighing 1/6.
  The tables keep no per-model field rates and no guarded field rates: no interval over models,
  and no guarded equal-field p_c or guard share (rows say so);
* p_c weighted by stored bits, without and with the guard: summary.json's per-model rates, the
  t interval over the models;
* alpha, median with median and mean with mean, each experiment apart: size_scaling.csv through
  `scaling.group_fits` (the median above the 8-bit floor of the runs' frame size);
* PSNR at the paper's heaviest dose per primitive: dose_curves.csv per model, over models;
* the mantissa slope over other windows: theory.csv;
* Table 2 per field (fp32): criticality.csv, pooled over the models (rates with their stratified
  interval; footprint statistics without one);
* the budget on the mean PSNR: dose_curves.csv per model, over models;
* sign-flip PSNR without and with the guard: guard_sign_psnr.csv (pooled, no interval);
* the worst guarded footprint and the residual share: guard_paired.csv's row of every precision;
* the IoU of the union masks at P = 64: contamination.csv (the records held no per-frame shares);
* the guard factor and the leave-one-scene-out AUC: size_guard_factor.csv, prediction_loso.csv.
Rows the tables cannot give are listed with verdict "not derivable" and the reason in basis.

    python tools/claims_from_tables.py docs/study/cpu --reverdict   # issue 46's rule on a report's claims.csv

--reverdict reads a report's own claims.csv (made by an older rule) and writes it again with the
verdict of issue 46's rule (`population.claim_verdict`: the interval inside the row's margin,
and at least 3 models of one population): per population where the basis lists the per-model
values (real models and procedural scenes never pooled: the population claims.csv names, else each
model's, with the report's model files from scenes.csv; a model at -inf keeps the mean at -inf),
the old verdict kept beside (`verdict_issue36`), and what the margins alone would give on the pooled interval
(`verdict_margin_pooled`); claims_verdicts.md lists the rows whose verdict changed.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from seuwgpu.analysis import claimrows, claims, dose, paper, population, prediction, scaling, stats, theory  # noqa: E402
from seuwgpu.analysis import estimate as E  # noqa: E402
from seuwgpu.report.format import markdown_table  # noqa: E402


def equal_field_row(d: Path) -> dict:
    rates = pd.read_csv(d / "precision_rates.csv")
    rates = rates[rates["precision"] == "fp32"]
    cells = pd.read_csv(d / "field_bit.csv")
    cells = cells[cells["precision"] == "fp32"]
    share = cells["weight_share_pct"] / cells.groupby("field")["weight_share_pct"].transform("sum")
    W = share / cells["field"].nunique()
    p, lo, hi, _ = E.stratified_interval(cells["cat_rate_pct"] / 100, cells["n"], W)
    value = float(rates["cat_rate_pct"].mean())
    assert abs(100 * p - value) < 1e-6 * max(value, 1e-12), (100 * p, value)  # the two tables agree
    return claimrows.row(
        "pc_none",
        value,
        100 * lo,
        100 * hi,
        f"plain mean of the {len(rates)} per-field rates of precision_rates.csv (pooled over the models); "
        "interval stratified over field_bit.csv's cells; per-model field rates are not stored: no interval "
        "over models, so the verdict is on the records' interval",
    )


def bit_weighted_rows(d: Path) -> list[dict]:
    cat = pd.DataFrame(json.loads((d / "summary.json").read_text())["catastrophic"])
    rows = []
    for dfn in ("none", "guard"):
        per = cat[(cat["precision"] == "fp32") & (cat["defense"] == dfn)].rename(columns={"rate": "p"})
        rows.append(
            claimrows.over_models(
                f"pc_{dfn}_bits", per, "p", "summary.json's per-model weighted rates (catastrophic)", 0.95
            )
        )
    return rows


def not_derivable(key: str, why: str) -> dict:
    return claimrows.row(key, basis=why) | {"verdict": "not derivable"}


def alpha_and_dose_rows(d: Path, frame_size) -> list[dict]:
    floor = scaling.median_floor(*frame_size)
    t = scaling.mark_groups(pd.read_csv(d / "size_scaling.csv"), floor)
    rows = scaling.alpha_rows({"groups": scaling.group_fits(t), "median_floor": floor})
    # the finite-frame rows only: these reports predate the rows that count a non-finite frame
    rows += [r for r in dose.dose_rows(pd.read_csv(d / "dose_curves.csv"), 0.95) if not r["key"].endswith("_all")]
    return rows


def paper_rows(d: Path) -> list[dict]:
    """The rows of issue 36's item 10 that the stored tables can give (module notes)."""
    rows = []
    crit = pd.read_csv(d / "criticality.csv").set_index("field")
    for f in claims.PAPER_FIELD_RATES:
        r = crit.loc[f]
        basis = f"n = {int(r['n']):,}; criticality.csv, fp32, pooled over the models (no per-model table)"
        rows.append(claimrows.row(f"field_rate_{f}", r["cat_rate_pct"], r["cat_ci_lo_pct"], r["cat_ci_hi_pct"], basis))
        for q in claims.PAPER_FIELD_FOOTPRINT[f]:
            rows.append(claimrows.row(f"field_{q}_{f}", r[f"{q}_pct"], basis=basis))
    rows.append(dose.budget_rows(pd.read_csv(d / "dose_curves.csv"), 0.95)[0])  # the finite-frame budget
    sign = pd.read_csv(d / "guard_sign_psnr.csv")
    for dfn in ("none", "guard"):
        r = sign[(sign["precision"] == "fp32") & (sign["defense"] == dfn)].iloc[0]
        basis = f"n = {int(r['n']):,}; guard_sign_psnr.csv, pooled over the models"
        rows.append(claimrows.row(f"sign_psnr_{dfn}", r["psnr_mean_mse_db"], basis=basis))
    paired = pd.read_csv(d / "guard_paired.csv").set_index("precision").loc["all"]
    n, k = int(paired["pairs"]), int(paired["residual_catastrophic"])
    both = int(paired["catastrophic_none"]) - int(paired["neutralised"])
    lo, hi = stats.wilson_interval(k, n, 0.95)
    basis = f"guard_paired.csv, every precision: {n:,} guarded sites; no per-model table"
    rows.append(claimrows.row("guard_worst_footprint", paired["worst_guarded_footprint_pct"], basis=basis))
    rows.append(
        claimrows.row(
            "guard_residual_share",
            100 * k / n,
            100 * lo,
            100 * hi,
            f"{k:,} residual of {n:,}; {basis}; Wilson; of the residual, {both:,} catastrophic without the guard "
            f"too (catastrophic_none - neutralised) and {k - both:,} turned catastrophic by it",
        )
    )
    cont = pd.read_csv(d / "contamination.csv")
    why = "contamination.csv of these records holds the union over the views only, no per-frame share"
    rows += [not_derivable("contam_none", why), not_derivable("contam_guard", why)]
    c = cont[
        (cont["subset"] == "log-scale sign")
        & (cont["precision"] == "fp32")
        & (cont["defense"] == "none")
        & (cont["P"] == claims.PAPER_CONTAMINATION_P)
    ]
    rows.append(claimrows.row("contam_iou", c["iou_mean"].iloc[0], basis="IoU of the union masks over the views"))
    rows.append(scaling.guard_factor_row({"guard_factor": pd.read_csv(d / "size_guard_factor.csv")}, 0.95))
    pr = {
        "loso": pd.read_csv(d / "prediction_loso.csv"),
        "summary": pd.read_csv(d / "prediction.csv"),
        "precision": "fp32",
    }
    return rows + prediction.prediction_rows(pr, 0.95)[2:]  # the leave-one-scene-out rows


def claim_key(text: str) -> str | None:
    """The key of a stored claim's text: the same text, or the shortest current text it begins
    (rows that gained a label since, e.g. "(finite frames only)")."""
    exact = {v[0]: k for k, v in paper.PAPER.items()}
    if text in exact:
        return exact[text]
    longer = sorted((v[0], k) for k, v in paper.PAPER.items() if v[0].startswith(text))
    return min(longer, key=lambda x: len(x[0]))[1] if longer else None


def per_model_values(basis: str) -> dict[str, float]:
    """{scene: value} from a basis' "per model: a 1.2; b -inf; c nan" (empty where it lists none);
    the note after a list with models at -inf ("2 of 3 models at -inf") is not a model."""
    if "per model: " not in str(basis):
        return {}
    out = {}
    for part in str(basis).split("per model: ", 1)[1].split(";"):
        bits = part.strip().rsplit(" ", 1)
        if len(bits) != 2 or re.fullmatch(r"\d+ of \d+ models at", bits[0]):
            break
        try:
            out[bits[0]] = float(bits[1])
        except ValueError:
            break
    return out


def model_scenes(d: Path) -> frozenset[str]:
    """The report's scenes read from model files (scenes.csv's kind "model file"): a corpus model
    named like a procedural scene (plant) is a real model (`population.population_of`)."""
    f = d / "scenes.csv"
    if not f.exists():
        return frozenset()
    s = pd.read_csv(f)
    return frozenset(s.loc[s["kind"] == "model file", "scene"].astype(str))


def reverdict(d: Path) -> pd.DataFrame:
    """claims.csv of report `d` under issue 46's rule (module notes); one row a (claim, population).
    A row's population is the one claims.csv names where it names one, else each model's
    (`population.population_of` with the report's model files, scenes.csv)."""
    old = pd.read_csv(d / "claims.csv")
    files = model_scenes(d)
    rows = []
    for _, r in old.iterrows():
        stored_key = r.get("key")
        key = stored_key if isinstance(stored_key, str) and stored_key in paper.PAPER else claim_key(r["claim"])
        keep = r["verdict"] in ("not measured", "no paper value", "not derivable") or key is None
        # a maximum is compared only at the paper's number of upsets (`claimrows.tail_row` says so)
        matched = "(the paper's number)" in str(r["basis"])
        margin_pooled = r["verdict"]
        if not keep:
            n = int(r["n_models"]) if np.isfinite(r["n_models"]) else None
            margin_pooled = population.claim_verdict(key, r["ci_lo"], r["ci_hi"], n, matched=matched)
        base = {
            "claim": r["claim"],
            "unit": r["unit"],
            "paper": r["paper"],
            "margin": paper.margin_text(key) if key else "",
            "verdict_issue36": r["verdict"],
            "verdict_margin_pooled": margin_pooled,
        }
        per = per_model_values(r["basis"])
        stored_pop = r.get("population")
        groups: dict[str, dict] = {}
        for scene, v in per.items():
            pop = stored_pop if stored_pop in (population.REAL, population.PROCEDURAL) else None
            groups.setdefault(pop or population.population_of(scene, files), {})[scene] = v
        if keep:
            rows.append(
                base
                | {
                    "population": "as stored",
                    "measured": r["measured"],
                    "ci_lo": r["ci_lo"],
                    "ci_hi": r["ci_hi"],
                    "n_models": r["n_models"],
                    "verdict": r["verdict"],
                    "basis": r["basis"],
                }
            )
            continue
        if not groups:  # an interval over the records of every model: both populations pooled
            n = int(r["n_models"]) if np.isfinite(r["n_models"]) else None
            rows.append(
                base
                | {
                    "population": "both (pooled; not split by the stored table)",
                    "measured": r["measured"],
                    "ci_lo": r["ci_lo"],
                    "ci_hi": r["ci_hi"],
                    "n_models": r["n_models"],
                    "verdict": population.claim_verdict(
                        key, r["ci_lo"], r["ci_hi"], n, population.POOLED, matched=matched
                    ),
                    "basis": f"{r['basis']}; pooled over both populations: no verdict",
                }
            )
            continue
        for pop, vals in groups.items():
            mi = claimrows.models_interval(key, list(vals.values()))
            basis = "per model: " + "; ".join(f"{k} {x:.4g}" for k, x in vals.items())
            if mi.at_neg_inf:
                basis += f"; {mi.at_neg_inf} of {mi.n_models} models at -inf"
            rows.append(
                base
                | {
                    "population": pop,
                    "measured": mi.mean,
                    "ci_lo": mi.lo,
                    "ci_hi": mi.hi,
                    "n_models": mi.n_models,
                    "verdict": population.claim_verdict(key, mi.lo, mi.hi, mi.n_models, pop, matched=matched),
                    "basis": basis,
                }
            )
    cols = [
        "population",
        "claim",
        "unit",
        "measured",
        "ci_lo",
        "ci_hi",
        "paper",
        "margin",
        "n_models",
        "verdict",
        "verdict_issue36",
        "verdict_margin_pooled",
        "basis",
    ]
    return pd.DataFrame(rows)[cols]


def write_reverdict(d: Path, note: str) -> pd.DataFrame:
    t = reverdict(d)
    t.to_csv(d / "claims.csv", index=False)
    (d / "claims.md").write_text(f"{note}\n\n" + markdown_table(t) + "\n")
    firm = t["verdict_issue36"].isin(["reproduced", "differs"])
    changed = t[(t["verdict"] != t["verdict_issue36"]) & (firm | t["verdict"].isin(["reproduced", "differs"]))]
    (d / "claims_verdicts.md").write_text(
        f"{note}\n\n**Rows whose verdict changed** (issue 36's rule -> issue 46's), {len(changed)} of {len(t)}; "
        "verdict_margin_pooled: what the margins alone give on the stored interval over all four models.\n\n"
        + markdown_table(changed[["population", "claim", "verdict_issue36", "verdict_margin_pooled", "verdict"]])
        + "\n"
    )
    return changed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", help="a report folder (docs/study/cpu)")
    ap.add_argument("--size", default="256x256", help="the runs' frame size W x H (the median's 8-bit floor)")
    ap.add_argument("--reverdict", action="store_true", help="rewrite claims.csv/.md with issue 46's verdict rule")
    ap.add_argument("--note", default="", help="with --reverdict: the first line of claims.md (provenance)")
    args = ap.parse_args(argv)
    d = Path(args.report)
    if args.reverdict:
        changed = write_reverdict(d, args.note)
        with pd.option_context("display.width", 220, "display.max_colwidth", 90):
            print(changed[["population", "claim", "verdict_issue36", "verdict"]].to_string())
        return 0
    frame = tuple(int(v) for v in args.size.lower().split("x"))
    rows = [equal_field_row(d)]
    rows += bit_weighted_rows(d)
    why = "the stored tables keep no guarded per-field rates"
    rows += [not_derivable("pc_guard", why), not_derivable("guard_share", why)]
    rows += alpha_and_dose_rows(d, frame)
    rows += paper_rows(d)
    out = pd.DataFrame(rows)
    th = pd.read_csv(d / "theory.csv")
    fit = th[th["in_fit"]]
    windows = theory.theory_windows({"table": th, "fit_bits": (int(fit["bit"].min()), int(fit["bit"].max()))})
    out.to_csv(d / "claims_rederived.csv", index=False)
    windows.to_csv(d / "claims_theory_windows.csv", index=False)
    (d / "claims_rederived.md").write_text(
        "**Claims re-derived from the stored tables** (tools/claims_from_tables.py; the records are not "
        "in the repository).\n\n"
        + markdown_table(out)
        + "\n\n**Mantissa slope against the fit window** (from theory.csv).\n\n"
        + markdown_table(windows)
        + "\n"
    )
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(out[["claim", "measured", "ci_lo", "ci_hi", "paper", "verdict", "n_models"]].to_string())
        print(windows.to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
