"""The paper's qualitative panel: clean | faulted | guarded | |error| heat map, one row per view."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def display(img: np.ndarray) -> np.ndarray:
    """What a display shows: NaN -> black, clipped to [0, 1]."""
    return np.clip(np.nan_to_num(img[..., :3], nan=0.0, posinf=1.0, neginf=0.0), 0, 1)


def error_map(clean: np.ndarray, faulted: np.ndarray) -> np.ndarray:
    """Per-pixel max |difference| over channels; non-finite pixels count as +inf."""
    d = np.abs(faulted[..., :3].astype(np.float64) - clean[..., :3])
    d[~np.isfinite(d)] = np.inf
    return d.max(axis=-1)


def panel_labels(defense: str = "none") -> tuple[str, str, str, str]:
    """Column titles of the panel whose second column is the faulted model read through `defense`
    (its command-line name; the third column is always read through the support guard, the
    error map is the second column's)."""
    if defense == "none":
        return ("clean", "faulted (no defense)", "faulted, support guard", "|faulted - clean|")
    return ("clean", f"faulted, defense {defense}", "faulted, support guard", f"|faulted - clean| ({defense})")


def save_panel(path, clean, faulted, guarded, title: str = "", labels=None, defense: str = "none"):
    """panel_figure written to path (PNG)."""
    fig = panel_figure(clean, faulted, guarded, title, labels, defense)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return Path(path)


def panel_figure(clean, faulted, guarded, title: str = "", labels=None, defense: str = "none"):
    """clean | faulted | guarded | error heat map, one row per view. defense: what the faulted
    column was read through (it names the columns; labels overrides them). The error map is the
    largest channel difference per pixel (linear, 0..1 per view, its colour bar marking the
    1/255 change that counts a pixel in the footprint); non-finite pixels are drawn in cyan."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    labels = tuple(labels) if labels is not None else panel_labels(defense)
    k = clean.shape[0]
    fig = Figure(figsize=(12, 3.1 * k + 0.4))  # pyplot-free: nothing to close
    axes = fig.subplots(k, 4, squeeze=False)
    any_nonfinite = False
    for v in range(k):
        err = error_map(clean[v], faulted[v])
        finite = np.isfinite(err)
        shown = np.where(finite, err, np.nan)
        for c, img in enumerate((clean[v], faulted[v], guarded[v])):
            axes[v, c].imshow(display(img), interpolation="nearest")
        vmax = max(float(np.nanmax(shown)) if finite.any() else 1.0, 1 / 255)
        im = axes[v, 3].imshow(shown, cmap="inferno", vmin=0, vmax=vmax, interpolation="nearest")
        if (~finite).any():
            any_nonfinite = True
            ys, xs = np.nonzero(~finite)
            axes[v, 3].scatter(xs, ys, s=1, c="cyan", marker="s")
        bar = fig.colorbar(im, ax=axes[v, 3], fraction=0.046, pad=0.04)
        bar.set_label("max |difference| over RGB (0-1)", fontsize=7)
        bar.ax.axhline(1 / 255, color="cyan", lw=1)  # the footprint's threshold
        for c in range(4):
            axes[v, c].set_xticks([])
            axes[v, c].set_yticks([])
            if v == 0:
                axes[v, c].set_title(labels[c], fontsize=10)
        axes[v, 0].set_ylabel(f"view {v}")
    if any_nonfinite:
        axes[0, 3].legend(
            handles=[Line2D([], [], color="cyan", marker="s", ls="", ms=4, label="non-finite pixel")],
            loc="upper right",
            fontsize=7,
        )
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
