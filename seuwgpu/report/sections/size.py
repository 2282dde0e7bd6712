"""Single-upset error against the primitive count (analysis/scaling.py)."""

from __future__ import annotations

import numpy as np

from seuwgpu.analysis import (
    scaling,
)
from seuwgpu.analysis.records import (
    model_file_scenes,
)
from seuwgpu.report.sections.base import FigureItem, Section, TableItem, prov


def size_section(df, manifests, ctx) -> Section:
    res = scaling.size_scaling(
        df, frame_size=scaling.frame_size_of(manifests), model_scenes=model_file_scenes(manifests)
    )
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
            prov(res["table"]),
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
