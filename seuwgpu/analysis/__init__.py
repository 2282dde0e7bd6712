"""Analyses of campaign records, one module per analysis, over one estimator layer.

records (selection, weights, outcome classes, provenance) -> estimate (every rate, mean,
quantile and interval) -> criticality, theory, guard, mitigation, dose, scaling, reliability,
contamination, prediction, outcomes, scenes, claims. `stats` holds the textbook helpers
(Wilson interval, fits, AUC) the estimator layer builds on.
"""
