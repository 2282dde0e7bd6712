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


def save_panel(path, clean, faulted, guarded, title: str = "", labels=("clean", "faulted", "guarded", "|error|")):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = clean.shape[0]
    fig, axes = plt.subplots(k, 4, figsize=(12, 3.1 * k + 0.4), squeeze=False)
    for v in range(k):
        err = error_map(clean[v], faulted[v])
        finite = np.isfinite(err)
        shown = np.where(finite, err, np.nan)
        for c, img in enumerate((clean[v], faulted[v], guarded[v])):
            axes[v, c].imshow(display(img), interpolation="nearest")
        vmax = max(float(np.nanmax(shown)) if finite.any() else 1.0, 1 / 255)
        im = axes[v, 3].imshow(shown, cmap="inferno", vmin=0, vmax=vmax, interpolation="nearest")
        if (~finite).any():
            ys, xs = np.nonzero(~finite)
            axes[v, 3].scatter(xs, ys, s=1, c="cyan", marker="s", label="non-finite")
        fig.colorbar(im, ax=axes[v, 3], fraction=0.046, pad=0.04)
        for c in range(4):
            axes[v, c].set_xticks([])
            axes[v, c].set_yticks([])
            if v == 0:
                axes[v, c].set_title(labels[c])
        axes[v, 0].set_ylabel(f"view {v}")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
