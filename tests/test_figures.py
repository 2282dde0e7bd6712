"""Figures read as a reviewer reads them: labels inside the figure, legends off the data, series
told apart by more than colour, censored values drawn as bounds, panel columns named for what
they show."""

from __future__ import annotations

import numpy as np
import pandas as pd

from seuwgpu.analysis import dose, reliability, scaling
from seuwgpu.analysis.records import PALETTE
from seuwgpu.report.panel import panel_figure, panel_labels

SCENES = ("lego", "ficus", "drums", "ship")
KS = (1, 3, 10, 30, 100, 300)


def _drawn(fig):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _inside_figure(fig):
    """Every axis label and title lies inside the figure (a long label was cut off at its edge)."""
    r = _drawn(fig)
    box = fig.bbox
    for ax in fig.axes:
        for t in (ax.xaxis.label, ax.yaxis.label, ax.title):
            if t.get_text():
                e = t.get_window_extent(r)
                assert e.x0 >= box.x0 - 1 and e.x1 <= box.x1 + 1, t.get_text()
                assert e.y0 >= box.y0 - 1 and e.y1 <= box.y1 + 1, t.get_text()


def _legends_off_axes(fig):
    """Legends are the figure's, outside every axes: none covers a data point."""
    r = _drawn(fig)
    assert fig.legends
    for ax in fig.axes:
        assert ax.get_legend() is None
        for leg in fig.legends:
            assert not leg.get_window_extent(r).overlaps(ax.get_window_extent(r))


def _curves():
    rows = []
    for i, scene in enumerate(SCENES):
        for d in ("none", "guard"):
            for j, k in enumerate(KS):
                med = 120 - 20 * j - 3 * i
                if d == "none" and k >= 100:  # most frames non-finite: the median is -inf
                    med = -np.inf
                if scene == "lego" and k == 1:  # the median frame identical to clean
                    med = np.inf
                rate = min(100.0, 10.0 * j)
                rows.append(
                    {
                        "scene": scene,
                        "n_primitives": 1000,
                        "precision": "fp32",
                        "defense": d,
                        "k": k,
                        "psnr_median_db": med,
                        "psnr_q25_db": med - 5 if np.isfinite(med) else -np.inf,
                        "psnr_q75_db": med + 5 if np.isfinite(med) else np.inf,
                        "cat_rate_pct": rate,
                        "cat_ci_lo_pct": max(0.0, rate - 10),
                        "cat_ci_hi_pct": min(100.0, rate + 10),
                    }
                )
    fits = pd.DataFrame(
        [
            {"scene": s, "n_primitives": 1000, "precision": "fp32", "defense": d, "p_pct": 1.0}
            for s in SCENES
            for d in ("none", "guard")
        ]
    )
    return pd.DataFrame(rows), fits


def test_dose_figure_labels_fit_and_legend_hides_nothing():
    fig = dose.plot_dose(*_curves())
    _inside_figure(fig)
    _legends_off_axes(fig)
    ax = fig.axes[0]
    assert ax.get_ylabel() == "median PSNR (dB)" and ax.get_xscale() == "log"
    assert fig.axes[1].get_ylabel() == "catastrophic frames (%)"


def test_dose_figure_colours_models_and_lines_defenses():
    fig = dose.plot_dose(*_curves())
    lines = [ln for ln in fig.axes[0].get_lines() if ln.get_marker() in ("o", "s")]
    assert len(lines) == 8
    colours = {ln.get_color() for ln in lines}
    assert colours <= set(PALETTE) and len(colours) == 4  # one per model, not one per series
    styles = {(ln.get_color(), ln.get_linestyle()) for ln in lines}
    assert len(styles) == 8  # none solid, guard dashed


def test_dose_figure_non_finite_medians_of_several_series_never_overlap():
    fig = dose.plot_dose(*_curves())
    ax = fig.axes[0]
    foot = [ln for ln in ax.get_lines() if ln.get_marker() == "v"]
    assert len(foot) == 4  # every unguarded model
    points = {(x, y) for ln in foot for x, y in zip(ln.get_xdata(), ln.get_ydata())}
    assert len(points) == sum(len(ln.get_xdata()) for ln in foot)
    lo, hi = ax.get_ylim()
    assert all(lo <= y <= hi for _, y in points)
    top = [ln for ln in ax.get_lines() if ln.get_marker() == "^"]  # inf dB: at the top, not dropped
    assert len(top) == 2 and all(y <= hi for ln in top for y in ln.get_ydata())
    # the catastrophic panel: each series its own k offset, so equal rates stay apart
    marks = [ln for ln in fig.axes[1].get_lines() if ln.get_linestyle() == "None" and ln.get_marker() in ("o", "s")]
    firsts = [ln.get_xdata()[0] for ln in marks]
    assert len(set(firsts)) == len(firsts) == 8


def _size_res():
    rows, fits = [], []
    ns = (1000, 2000, 4000, 8000)
    for i, scene in enumerate(SCENES):
        for d in ("none", "guard"):
            y = [(3e-5 if d == "none" else 1e-6) * (n / 1000) ** -0.5 * (1 + 0.1 * i) for n in ns]
            if scene == "ship" and d == "guard":
                y[1] = 0.0  # no logarithm: drawn at the foot
            rows += [
                {"scene": scene, "precision": "fp32", "defense": d, "n_primitives": n, "mean_mse": v}
                for n, v in zip(ns, y)
            ]
            fits.append(
                {
                    "scene": scene,
                    "precision": "fp32",
                    "defense": d,
                    "metric": "mean_mse",
                    "alpha": 0.5,
                    "alpha_lo": 0.4,
                    "alpha_hi": 0.6,
                    "exponent": -0.5,
                }
            )
    return {"table": pd.DataFrame(rows), "fits": pd.DataFrame(fits)}


def test_size_figure_legend_outside_and_defenses_by_marker():
    fig = scaling.plot_size_scaling(_size_res())
    _inside_figure(fig)
    _legends_off_axes(fig)
    ax = fig.axes[0]
    assert ax.get_xscale() == ax.get_yscale() == "log"
    assert "MSE" in ax.get_ylabel()
    pts = [ln for ln in ax.get_lines() if ln.get_linestyle() == "None" and ln.get_marker() in ("o", "s")]
    assert {ln.get_marker() for ln in pts} == {"o", "s"}
    assert any(ln.get_marker() == "v" for ln in ax.get_lines())  # the zero, shown
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("alpha 0.50 [0.40, 0.60]" in t for t in texts) and "zero (no logarithm)" in texts


def _two_scenes_res():
    from test_reliability_models import fits_of, two_scenes

    df = two_scenes()
    # 'small' under the guard: no catastrophic event at all (p_c = 0, its MTBF only bounded below)
    guard = (df["scene"] == "small") & (df["defense"] == "guard") & (df["campaign"] == "single")
    df.loc[guard, "footprint"] = 0.0
    df.loc[guard, "nonfinite"] = False
    return reliability.reliability(df, dose_fits=fits_of(df))


def test_reliability_figure_draws_the_bound_of_an_arm_without_events():
    res = _two_scenes_res()
    pc = res["pc"].set_index(["scene", "defense"])
    assert pc.loc[("small", "guard"), "p_c"] == 0 and pc.loc[("small", "guard"), "ci_hi"] > 0
    fig = reliability.plot_sensitivity(res)
    small = [ax for ax in fig.axes if ax.get_title().startswith("small:")][0]
    bound = [ln for ln in small.get_lines() if "no event" in ln.get_label()]
    assert len(bound) == 1 and bound[0].get_marker() == "^"
    y = np.asarray(bound[0].get_ydata(), float)
    assert np.isfinite(y).all() and (y > 0).all()  # drawn, not an infinite (invisible) line
    names = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "guard, single-upset p_c: no event, MTBF >" in names and "guard, single-upset p_c" in names
    # a colour per defense, its p sources by line
    lines = {ln.get_label(): ln for ax in fig.axes for ln in ax.get_lines() if not ln.get_label().startswith("_")}
    assert lines["none, single-upset p_c"].get_color() == lines["none, dose fit p"].get_color()
    assert lines["none, single-upset p_c"].get_linestyle() != lines["none, dose fit p"].get_linestyle()


def test_panel_columns_name_the_defense_they_show():
    assert panel_labels("none")[1] == "faulted (no defense)"
    assert panel_labels("guard")[1] == "faulted, defense guard"  # was 'faulted': it showed the guarded frame
    clean = np.full((1, 16, 16, 3), 0.5, np.float32)
    faulted = clean.copy()
    faulted[0, 2:5, 2:5] = np.nan
    faulted[0, 8, 8] = 0.9
    fig = panel_figure(clean, faulted, clean, "t", defense="ecc")
    titles = [ax.get_title() for ax in fig.axes[:4]]
    assert titles == ["clean", "faulted, defense ecc", "faulted, support guard", "|faulted - clean| (ecc)"]
    bar = fig.axes[4]
    assert "difference" in bar.get_ylabel()
    leg = fig.axes[3].get_legend()
    assert leg is not None and [t.get_text() for t in leg.get_texts()] == ["non-finite pixel"]
    assert panel_figure(clean, clean, clean).axes[3].get_legend() is None  # nothing non-finite


def test_reliability_figure_of_one_model_has_its_legend_below_too():
    from test_reliability_models import fits_of, two_scenes

    df = two_scenes()
    small = df[df["scene"] == "small"]
    res = reliability.reliability(small, dose_fits=fits_of(small))
    assert not res["per_model"]
    fig = reliability.plot_sensitivity(res)
    _inside_figure(fig)
    _legends_off_axes(fig)


def test_budget_figure_legend_below_and_bounds_open():
    rows = []
    for i, scene in enumerate(SCENES):
        for d in ("none", "guard"):
            for n, cens in ((1000, ""), (4000, ">=" if d == "guard" else ""), (16000, "<=" if i == 0 else "")):
                kb = 100.0 * (1 + i) * (2 if d == "guard" else 1)
                rows.append(
                    {
                        "scene": scene,
                        "precision": "fp32",
                        "defense": d,
                        "n_primitives": n,
                        "k_budget": kb,
                        "k_lo": kb / 2,
                        "k_hi": kb * 2,
                        "censored": cens,
                    }
                )
    fig = dose.plot_budget(pd.DataFrame(rows))
    _inside_figure(fig)
    _legends_off_axes(fig)
    marks = [ln for ln in fig.axes[0].get_lines() if ln.get_marker() in ("^", "v") and len(ln.get_xdata())]
    assert marks and all(ln.get_markerfacecolor() == "none" for ln in marks)


def test_precision_and_mitigation_rates_on_log_axes_with_no_event_as_bounds():
    from seuwgpu.analysis import criticality, mitigation

    rates = pd.DataFrame(
        [
            {"precision": p, "field": f, "cat_rate_pct": r, "cat_ci_lo_pct": r / 2, "cat_ci_hi_pct": max(2 * r, 0.06)}
            for p in ("fp32", "fp16")
            for f, r in (("means", 0.03), ("log_scales", 7.3), ("sh_rest", 0.0))
        ]
    )
    fig = criticality.plot_precision_rates(rates)
    ax = fig.axes[0]
    assert ax.get_yscale() == "log"
    bounds = [ln for ln in ax.get_lines() if ln.get_marker() == "v" and len(ln.get_ydata())]
    assert len(bounds) == 2 and all(ln.get_ydata()[0] == 0.06 for ln in bounds)  # no event: at the upper end
    _legends_off_axes(fig)
    t = pd.DataFrame(
        {
            "label": ["none", "guard", "ECC"],
            "cat_rate_pct": [0.47, 0.012, 0.0],
            "cat_ci_lo_pct": [0.37, 0.002, 0.0],
            "cat_ci_hi_pct": [0.59, 0.058, 0.037],
            "memory_overhead_pct": [0.0, 0.006, 15.6],
        }
    )
    fig = mitigation.plot_mitigation(t)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log"
    (bound,) = [ln for ln in ax.get_lines() if ln.get_marker() == "<" and len(ln.get_xdata())]
    assert bound.get_xdata()[0] == 0.037
    top = max(ax.get_yticklabels(), key=lambda tl: tl.get_position()[1])
    assert top.get_text().startswith("none")  # the table's order, top down
    _inside_figure(fig)


def test_rate_points_draw_an_undefined_rate_as_nothing_not_as_no_event():
    """A rate of 0 (no event) is an open triangle at its interval's upper end; a NaN rate (no
    records) is undefined: no mark, and not counted as a no-event bound."""
    from seuwgpu.analysis.records import figure, rate_points

    ax = figure().subplots()
    nan = float("nan")
    n = rate_points(ax, [0, 1, 2], [0.5, 0.0, nan], [0.3, 0.0, nan], [0.8, 0.1, nan], "k")
    assert n == 1
    bounds = [ln for ln in ax.lines if ln.get_marker() == "v"]
    assert len(bounds) == 1 and list(bounds[0].get_xdata()) == [1.0] and list(bounds[0].get_ydata()) == [0.1]
