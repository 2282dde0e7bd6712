"""Prediction of criticality (analysis/prediction.py)."""

from __future__ import annotations

from seuwgpu.analysis import (
    prediction,
)
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def prediction_section(df, manifests, ctx) -> Section:
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
                prov(res["summary"]),
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
