"""Sort-first screen regions: the P-way grid that splits a frame between ranks."""

from __future__ import annotations

import math

import numpy as np


def region_grid(P: int, H: int | None = None, W: int | None = None) -> tuple[int, int]:
    """(rows, cols) of a P-way sort-first screen partition, as square as possible.

    rows is the largest divisor of P not above sqrt(P), cols = P // rows; for a portrait image
    (H > W) the two are swapped so the longer screen side gets more regions."""
    P = int(P)
    if P < 1:
        raise ValueError("P must be >= 1")
    r = int(math.isqrt(P))
    while P % r:
        r -= 1
    rows, cols = r, P // r
    if H is not None and W is not None and H > W:
        rows, cols = cols, rows
    return rows, cols


def grid_edges(n: int, parts: int) -> np.ndarray:
    return (np.arange(parts + 1) * n) // parts


def region_edges(P: int, H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column pixel edges of the P-way grid: region (i, j) spans rows ey[i]..ey[i+1]-1
    and columns ex[j]..ex[j+1]-1."""
    rows, cols = region_grid(P, H, W)
    return grid_edges(H, rows), grid_edges(W, cols)


def region_id_map(P: int, H: int, W: int) -> np.ndarray:
    """[H, W] region index (row-major) of every pixel, consistent with region_set."""
    ey, ex = region_edges(P, H, W)
    ry = np.searchsorted(ey, np.arange(H), side="right") - 1
    rx = np.searchsorted(ex, np.arange(W), side="right") - 1
    return (ry[:, None] * (len(ex) - 1) + rx[None, :]).astype(np.int64)
