"""Sort-first screen regions: the one P-way grid that splits a frame between ranks.

The Ray ranks render these regions (campaign/sortfirst.py) and the contamination analysis counts
the regions an upset reaches (render/incremental.py predicts, faults/incremental.py measures), so
both must use this grid. It is tile-aligned: every region is a union of whole TILE x TILE tiles
(the renderer's binning unit), so a primitive's binned tile rectangle reaches exactly the regions
its tiles lie in, and P can be at most the number of tiles. The grid (px columns x py rows,
px * py = P) is the factorisation whose regions are closest to square in tiles; ties go to more
columns. Regions are numbered row-major: index = row * px + column.

REGION_GRID_VERSION names this definition in run manifests (1 was an untiled grid, as square as
possible in pixels, that disagreed with the Ray ranks').
"""

from __future__ import annotations

import math

import numpy as np

from seuwgpu.gpu.constants import TILE

REGION_GRID_VERSION = 2


def region_grid(P: int, H: int, W: int) -> tuple[int, int]:
    """(rows, cols) of the P-way tile-aligned partition of an H x W frame (ValueError when P
    regions do not fit its tiles)."""
    P = int(P)
    if P < 1:
        raise ValueError("P must be >= 1")
    tx, ty = -(-int(W) // TILE), -(-int(H) // TILE)
    best = None
    for px in range(P, 0, -1):
        if P % px:
            continue
        py = P // px
        if px > tx or py > ty:
            continue
        cost = abs(math.log((tx / px) / (ty / py)))
        if best is None or cost < best[0] - 1e-12:
            best = (cost, px, py)
    if best is None:
        raise ValueError(
            f"{P} regions do not fit a grid of the frame's {tx}x{ty} tiles ({TILE} px); "
            "use fewer regions or a larger frame"
        )
    return best[2], best[1]


def region_edges(P: int, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column pixel edges of the grid, multiples of TILE (the last clipped to the frame):
    region (i, j) spans rows ey[i]..ey[i+1]-1 and columns ex[j]..ex[j+1]-1."""
    rows, cols = region_grid(P, H, W)
    tx, ty = -(-int(W) // TILE), -(-int(H) // TILE)
    ex = np.array([min(round(k * tx / cols) * TILE, int(W)) for k in range(cols + 1)], dtype=np.int64)
    ey = np.array([min(round(k * ty / rows) * TILE, int(H)) for k in range(rows + 1)], dtype=np.int64)
    return ey, ex


def region_rects(P: int, H: int, W: int) -> list[tuple[int, int, int, int]]:
    """The regions as (x0, y0, width, height) rectangles, row-major."""
    ey, ex = region_edges(P, H, W)
    return [
        (int(ex[c]), int(ey[r]), int(ex[c + 1] - ex[c]), int(ey[r + 1] - ey[r]))
        for r in range(len(ey) - 1)
        for c in range(len(ex) - 1)
    ]


def region_id_map(P: int, H: int, W: int) -> np.ndarray:
    """[H, W] region index (row-major) of every pixel."""
    ey, ex = region_edges(P, H, W)
    ry = np.searchsorted(ey, np.arange(H), side="right") - 1
    rx = np.searchsorted(ex, np.arange(W), side="right") - 1
    return (ry[:, None] * (len(ex) - 1) + rx[None, :]).astype(np.int64)
