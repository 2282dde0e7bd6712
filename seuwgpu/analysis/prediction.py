"""Predicting criticality without injection: can static fault-site features say which upsets are
catastrophic? Compared, on the same splits, with the obvious (field, bit) lookup and a constant,
because a classifier that only re-learns the lookup adds nothing."""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import stats
from seuwgpu.analysis.records import (
    PREDICTION_SAMPLE,
    draw_share,
    figure,
    prediction_draw,
    reference_precision,
    require_single,
    tag,
    unique_sorted,
)
from seuwgpu.errors import require

PREDICTION_FEATURES = ("field", "bit", "bit_class", "log_abs_value", "sign")
FIELD_BIT_FEATURES = ("field", "bit")


def prediction_features(d: pd.DataFrame) -> pd.DataFrame:
    """Static fault-site features: field, bit, bit class, log10|stored value|, sign of the value.
    A zero value gets log10 = -46 (below the smallest fp32 subnormal), a non-finite one +39."""
    v = d["clean_value"].to_numpy(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        la = np.log10(np.abs(v))
    la = np.where(v == 0, -46.0, la)
    la = np.where(~np.isfinite(v), 39.0, la)
    return pd.DataFrame(
        {
            "field": d["field"].astype(str).to_numpy(),
            "bit": d["bit"].to_numpy(np.int64).astype(float),
            "bit_class": d["bit_class"].astype(str).to_numpy(),
            "log_abs_value": la,
            "sign": np.signbit(v).astype(float),
        },
        index=d.index,
    )


def _classifier(features, seed):
    from sklearn.compose import ColumnTransformer
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import OneHotEncoder

    cat = [f for f in features if f in ("field", "bit_class")]
    pre = ColumnTransformer(
        [("cat", OneHotEncoder(handle_unknown="ignore", sparse_output=False), cat)], remainder="passthrough"
    )
    # early stopping on a 10% validation split (log-loss, 10 rounds without improvement)
    clf = HistGradientBoostingClassifier(
        max_iter=200,
        learning_rate=0.1,
        max_leaf_nodes=31,
        early_stopping=True,
        validation_fraction=0.1,
        n_iter_no_change=10,
        random_state=seed,
    )
    return Pipeline([("pre", pre), ("clf", clf)])


def prediction(
    df: pd.DataFrame,
    precision: str | None = None,
    seed: int = 0,
    max_rows: int = 200_000,
    test_size: float = 0.3,
    n_repeats: int = 5,
    n_boot: int = 2000,
    n_threads: int | None = 1,
) -> dict:
    """Predict "catastrophic" from static fault-site features (single-upset campaign, no defense,
    one precision: a bit index means different things in different formats).

    Three scorers, all evaluated with record weights (a uniform upset's view): a gradient-boosted
    classifier (scikit-learn HistGradientBoosting) on field, bit, bit class, log10|stored value|
    and sign; the (field, bit) lookup (each cell's weighted catastrophe rate in the training
    data, the global rate for unseen cells); a constant (the training base rate: AUC 0.5, Brier
    score of the base rate). Held-out ROC AUC on a stratified split with a bootstrap interval
    (stats.auc_interval: none when the weights leave < 5 effective records of a class, a note
    says so); leave-one-scene-out AUC per held-out scene with >= 2 scenes; Brier scores;
    permutation importance of the classifier, weighted as the AUCs are. When the data cannot
    support it (too few events, one class in a split) the numbers are NaN and `notes` says why:
    the report never fails on a small run.
    Returns {"summary", "importance", "loso", "top_feature", "roc", "precision", "notes",
    "lookup_as_good"}.
    """
    # imported first: it loads its OpenMP runtime before threadpoolctl limits it
    require("sklearn.ensemble", "analysis", "the criticality prediction")
    from threadpoolctl import threadpool_limits

    # One OpenMP thread by default: on small or shared machines gradient boosting with several
    # spinning threads can be 20x slower than with one (seen on a loaded 2-core CI box).
    with threadpool_limits(limits=n_threads):
        return _prediction(df, precision, seed, max_rows, test_size, n_repeats, n_boot)


def lookup_scores(train: pd.DataFrame, y_train: np.ndarray, test: pd.DataFrame, w_train=None) -> np.ndarray:
    """The (field, bit) lookup: each test site scored by its cell's weighted catastrophe rate in
    the training records (the training base rate for cells it never saw)."""
    w = np.ones(len(train)) if w_train is None else np.asarray(w_train, float)
    t = pd.DataFrame({"field": train["field"].to_numpy(), "bit": train["bit"].to_numpy(), "wy": w * y_train, "w": w})
    cell = t.groupby(["field", "bit"])[["wy", "w"]].sum()
    rate = (cell["wy"] / cell["w"]).to_dict()
    base = float(t["wy"].sum() / t["w"].sum())
    return np.array([rate.get((f, b), base) for f, b in zip(test["field"], test["bit"])], dtype=float)


def _effective_events(y, w, where: str, notes: list) -> float:
    """Effective number of catastrophic upsets in a test set (Kish, from their weights); a note
    when it or the benign side's is too small for an AUC interval (stats.auc_interval)."""
    pos, neg = stats.effective_size(w[y]), stats.effective_size(w[~y])
    if min(pos, neg) < stats.MIN_EFFECTIVE_EVENTS:
        notes.append(
            f"{where}: the weights leave {pos:.1f} effective catastrophic and {neg:.1f} effective "
            f"benign upsets (of {int(y.sum())} and {int((~y).sum())} records; need >= "
            f"{stats.MIN_EFFECTIVE_EVENTS} of each): no AUC interval"
        )
    return pos


def _brier(y, score, w) -> float:
    return float(np.sum(w * (score - y) ** 2) / np.sum(w)) if len(y) else float("nan")


def _scores(Xtr, ytr, wtr, Xte, seed):
    """(classifier, {model name: held-out scores}) trained on one split."""
    feats = list(PREDICTION_FEATURES)
    # trained on the stratified sample as drawn (rare cells are well represented there; weighting
    # them down, as the population does, left the boosted trees with too few of their events to
    # learn from: AUC 0.977 against 0.99999 on a 11,520-record run); evaluated with the weights
    clf = _classifier(feats, seed).fit(Xtr[feats], ytr)
    base = float(np.sum(wtr * ytr) / np.sum(wtr))
    return clf, {
        "classifier (field, bit, class, value, sign)": clf.predict_proba(Xte[feats])[:, 1],
        "(field, bit) lookup": lookup_scores(Xtr, ytr, Xte, wtr),
        "constant (base rate)": np.full(len(Xte), base),
    }


def _prediction(df, precision, seed, max_rows, test_size, n_repeats, n_boot) -> dict:
    from sklearn.inspection import permutation_importance
    from sklearn.metrics import roc_curve
    from sklearn.model_selection import train_test_split

    s = require_single(df, "none")
    precision = precision or reference_precision(s)
    s = s[(s["precision"] == precision) & (s["bit"] >= 0)]
    # a random draw of about max_rows records (records.draw_share: what folding keeps of a
    # planner-sized run, so that a report gives the same numbers folded or not), then exactly
    # max_rows of them
    if PREDICTION_SAMPLE in s:  # folded: the records analysis.folding kept
        s = s[s[PREDICTION_SAMPLE].fillna(False).astype(bool)]
    elif len(s) > max_rows:
        s = s[draw_share(s) < prediction_draw(len(s), max_rows)]
    if len(s) > max_rows:
        s = s.sample(n=max_rows, random_state=seed)
    y = s["catastrophic"].astype(bool).to_numpy()
    w = s["weight"].to_numpy(float)
    npos, nneg = int(y.sum()), int((~y).sum())
    X = prediction_features(s)
    names = ["classifier (field, bit, class, value, sign)", "(field, bit) lookup", "constant (base rate)"]
    notes, rows, loso_rows, roc = [], [], [], {}
    imp = pd.DataFrame(columns=["feature", "importance_mean", "importance_std"])
    scenes = unique_sorted(s["scene"])
    if npos < 5 or nneg < 5:
        notes.append(
            f"too few catastrophic ({npos}) or benign ({nneg}) upsets at {precision} to train and test "
            "a classifier (need >= 5 of each): AUCs not computed"
        )
        rows = [{"model": m, "auc_holdout": np.nan, "auc_lo": np.nan, "auc_hi": np.nan} for m in names]
    else:
        idx_tr, idx_te = train_test_split(np.arange(len(s)), test_size=test_size, stratify=y, random_state=seed)
        Xtr, Xte = X.iloc[idx_tr], X.iloc[idx_te]
        clf, sc = _scores(Xtr, y[idx_tr], w[idx_tr], Xte, seed)
        eff = _effective_events(y[idx_te], w[idx_te], "the held-out split", notes)
        for m in names:
            a = stats.auc(y[idx_te], sc[m], w[idx_te])
            lo, hi = stats.auc_interval(y[idx_te], sc[m], w[idx_te], n_boot, seed=seed)
            fpr, tpr, _ = roc_curve(y[idx_te], sc[m], sample_weight=w[idx_te])
            roc[m] = (fpr, tpr, a)
            rows.append(
                {
                    "model": m,
                    "auc_holdout": a,
                    "auc_lo": lo,
                    "auc_hi": hi,
                    "brier": _brier(y[idx_te], sc[m], w[idx_te]),
                    "n_train": len(idx_tr),
                    "n_test": len(idx_te),
                    "positives": npos,  # of train and test together
                    "test_positives_effective": eff,
                }
            )
        feats = list(PREDICTION_FEATURES)
        # weighted as the AUCs above are (a uniform upset's view), not the sample's
        pi = permutation_importance(
            clf,
            Xte[feats],
            y[idx_te],
            scoring="roc_auc",
            n_repeats=n_repeats,
            random_state=seed,
            sample_weight=w[idx_te],
        )
        imp = (
            pd.DataFrame(
                {"feature": feats, "importance_mean": pi.importances_mean, "importance_std": pi.importances_std}
            )
            .sort_values("importance_mean", ascending=False)
            .reset_index(drop=True)
        )
    if len(scenes) >= 2 and npos >= 5:
        for sc_name in scenes:
            te = (s["scene"] == sc_name).to_numpy()
            if y[~te].sum() < 2 or (~y[~te]).sum() < 2:
                notes.append(f"leave-one-scene-out: training without {sc_name} leaves one class")
                continue
            _, scs = _scores(X[~te], y[~te], w[~te], X[te], seed)
            eff = _effective_events(y[te], w[te], f"held-out scene {sc_name}", notes)
            for m in names:
                a = stats.auc(y[te], scs[m], w[te])
                lo, hi = stats.auc_interval(y[te], scs[m], w[te], n_boot, seed=seed)
                loso_rows.append(
                    {
                        "model": m,
                        "held_out_scene": sc_name,
                        "n": int(te.sum()),
                        "positives": int(y[te].sum()),
                        "positives_effective": eff,
                        "auc": a,
                        "auc_lo": lo,
                        "auc_hi": hi,
                    }
                )
    elif len(scenes) < 2:
        notes.append("one scene only: no leave-one-scene-out evaluation")
    loso = pd.DataFrame(
        loso_rows,
        columns=["model", "held_out_scene", "n", "positives", "positives_effective", "auc", "auc_lo", "auc_hi"],
    )
    summary = pd.DataFrame(rows)
    for m in names:
        a = loso.loc[loso["model"] == m, "auc"].dropna()
        summary.loc[summary["model"] == m, "loso_auc_mean"] = float(a.mean()) if len(a) else np.nan
        summary.loc[summary["model"] == m, "loso_auc_min"] = float(a.min()) if len(a) else np.nan
        summary.loc[summary["model"] == m, "loso_scenes"] = len(a)
    lookup_as_good = None
    if len(summary) and summary["auc_holdout"].notna().all():
        full = summary.iloc[0]
        look = summary.iloc[1]
        lookup_as_good = bool(look["auc_holdout"] >= full["auc_lo"]) if np.isfinite(full["auc_lo"]) else None
        if lookup_as_good is False:
            notes.append(
                f"the classifier (AUC {full['auc_holdout']:.5f}, 95% CI {full['auc_lo']:.5f}..{full['auc_hi']:.5f}) "
                f"beats the (field, bit) lookup (AUC {look['auc_holdout']:.5f}) by "
                f"{full['auc_holdout'] - look['auc_holdout']:.2g}: "
                "most of what it knows is the lookup"
            )
        if lookup_as_good:
            notes.append(
                f"the (field, bit) lookup (AUC {look['auc_holdout']:.3f}) is as good as the classifier "
                f"(AUC {full['auc_holdout']:.3f}, 95% CI {full['auc_lo']:.3f}..{full['auc_hi']:.3f}): "
                "the value features add nothing measurable"
            )
    tag(summary, s, precision=precision)
    tag(imp, s, precision=precision)
    tag(loso, s)
    return {
        "summary": summary,
        "importance": imp,
        "loso": loso,
        "top_feature": str(imp["feature"].iloc[0]) if len(imp) else "",
        "roc": roc,
        "precision": precision,
        "notes": notes,
        "lookup_as_good": lookup_as_good,
    }


def plot_roc(res: dict):
    """Held-out ROC curves (record-weighted) of the classifier and both baselines, AUC with its
    bootstrap interval in the legend."""
    fig = figure(4.8, 4.4)
    ax = fig.subplots()
    s = res["summary"].set_index("model")
    for name, (fpr, tpr, a) in res["roc"].items():
        lo, hi = s.loc[name, "auc_lo"], s.loc[name, "auc_hi"]
        ax.plot(fpr, tpr, label=f"{name}: AUC {a:.3f} [{lo:.3f}, {hi:.3f}]")
    ax.plot([0, 1], [0, 1], "k:", lw=1)
    ax.set_xlabel("false positive rate (weighted)")
    ax.set_ylabel("true positive rate (weighted)")
    ax.legend(fontsize=6, loc="lower right")
    return fig


# ---- claims rows (analysis.claims gathers them) ----------------------------------------------------


def prediction_rows(pr: dict | None, conf: float = 0.95, scenes=None) -> list[dict]:
    """The held-out AUC rows (lookup and classifier) and the leave-one-scene-out AUC: its mean over
    the held-out scenes (t interval over scenes) and its minimum with that scene's bootstrap interval.
    `scenes`: the population's models; the pooled AUC rows are given only when the classifier saw
    those models alone (never a pool of populations)."""
    from seuwgpu.analysis.claimrows import over_models, row

    rows = []
    ok = pr is not None and len(pr.get("summary", [])) and pr.get("precision") == "fp32"
    loso = pr["loso"] if ok and "loso" in pr else pd.DataFrame()
    seen = set(loso["held_out_scene"]) if len(loso) and "held_out_scene" in loso else None
    alone = scenes is None or seen is None or seen <= set(scenes)
    if ok and alone:
        t = pr["summary"].set_index("model")
        for key, model in (("auc_fieldbit", "(field, bit) lookup"), ("auc_full", t.index[0])):
            r = t.loc[model]
            rows.append(row(key, r["auc_holdout"], r["auc_lo"], r["auc_hi"], f"held-out, {model}"))
    else:
        why = "" if not ok else "the classifier was trained on records of several populations: not split"
        rows += [row("auc_fieldbit", basis=why), row("auc_full", basis=why)]
    if len(loso):
        clf = pr["summary"]["model"].iloc[0]
        c = loso[(loso["model"] == clf) & loso["auc"].notna()]
        if scenes is not None:
            c = c[c["held_out_scene"].isin(scenes)]
        per = c.rename(columns={"held_out_scene": "scene"}).assign(v=c["auc"].to_numpy(float))
        if "n_primitives" not in per:
            per["n_primitives"] = 0
        note = "" if alone else "; trained on every population's other scenes"
        rows.append(
            over_models("auc_loso_mean", per, "v", f"{clf}; t interval over the held-out scenes{note}", conf, scale=1.0)
        )
        if len(c):
            w = c.loc[c["auc"].idxmin()]
            rows.append(
                row(
                    "auc_loso_min",
                    w["auc"],
                    w["auc_lo"],
                    w["auc_hi"],
                    f"{clf}; held out {w['held_out_scene']} (its bootstrap interval){note}",
                )
            )
        else:
            rows.append(row("auc_loso_min"))
    else:
        rows += [row("auc_loso_mean"), row("auc_loso_min")]
    return rows
