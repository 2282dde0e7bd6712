"""Writing PlayCanvas SOG version 2: a bundled `.sog` zip, or an unbundled `meta.json` with its
WebP images beside it (the layout sog.py reads; splat-transform's write-sog.ts writes the same).

The files: meta.json with the keys write-sog.ts writes (version 2, asset.generator, count, means
{mins, maxs, files}, scales {codebook, files}, quats {files}, sh0 {codebook, files} and, with SH,
shN {count, bands, codebook, files}), and lossless WebP images (Pillow, `exact` so that RGB under an
alpha of 0 survives) named means_l, means_u, quats, scales, sh0, shN_centroids, shN_labels, of W x
H texels, W = ceil(sqrt(N) / 4) * 4, H = ceil(N / W / 4) * 4, texel i holding splat i (the
model's order: no Morton sort, so splat i is primitive i). The zip stores its members
uncompressed (WebP is compressed already).

What is exact and what is re-quantised:
- positions: 16 bits per axis over [min, max] of sign(x) log(|x| + 1), rounded to nearest (the
  reference truncates); the min and max are float64 in meta.json, so each axis's extremes survive
  to float32 precision, and an upset position (1e30, or +-3.4e38 for +-Inf) keeps its value while
  widening the range of every other splat: all of them lose precision (a 1e30 position leaves
  the clean ones a few codes of the 65,536).
- log-scales (the three axes pooled) and SH DC (the three channels pooled): a 256-entry codebook
  each. Fewer than 257 distinct values: the codebook is those values, exact. Otherwise a 1D
  k-means (as write-sog.ts fits it) whose first and last entries are pinned to the smallest and
  the largest value, so an upset that leaves the clean range (a flipped exponent) is itself an
  entry and survives exactly, where a free centroid would average it away; every value is stored
  as its nearest entry. The upset's entry is one of 256: the clean values share the other 255,
  and a far outlier pulls no other entry towards it.
- rotations: "smallest three" in 8 bits (rounded to nearest), as quantized.unit_quats normalises.
- opacity: the sh0 image's alpha, sigmoid(opacity) * 255 rounded to nearest: saturates at 0 and
  255 (read as -+20).
- SH rest: a palette of coefficient vectors (shN_centroids, 64 entries a row) indexed by a 16-bit
  label per splat, the palette's values through a 256-entry codebook built as above (extremes
  exact). Up to 65,536 splats each splat is its own palette entry (the vectors then differ from
  the model only by the codebook); beyond, the palette holds 65,536 entries: the splats holding
  the smallest and the largest coefficient keep entries of their own, the others are drawn evenly
  (seeded), every splat takes its nearest entry (squared distance) among the entries of its coarse
  group (512 seeded centres), and each entry becomes the mean of the splats that took it (one
  k-means step; write-sog.ts runs several).
- NaN is refused, +-Inf stored as +-3.4e38 (quantized.py, "writing"); a model whose up axis is
  not -y is turned to -y first.
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
from pathlib import Path

import numpy as np

from seuwgpu.model.fields import Model
from seuwgpu.model.formats.quantized import (
    alpha_bytes,
    largest_component,
    storable,
    turned_to_minus_y,
    unorm_codes,
)

BOOK = 256  # codebook entries
MAX_PALETTE = 1 << 16  # 16-bit labels
PALETTE_ROW = 64
ASSIGN_BLOCK = 512  # rows per block of a nearest-centre search (x 65,536 centres in float32: 128 MiB)
GROUPS = 512  # coarse groups of the palette's nearest-entry search


def texture_size(n: int) -> tuple[int, int]:
    """(W, H) of a SOG's per-splat images for n splats, as write-sog.ts sizes them."""
    w = math.ceil(math.sqrt(n) / 4) * 4
    return w, math.ceil(n / w / 4) * 4


def codebook(values: np.ndarray, iterations: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(256 float64 entries in ascending order, uint8 index of each value's nearest entry; ties
    to the lower). At most 256 distinct values: those values (the last repeated to fill), exact.
    Otherwise a 1D k-means (Lloyd, `iterations` steps from the values at 256 evenly spaced ranks)
    whose first and last entries stay the smallest and the largest value, so the extremes (an
    upset that left the clean range) are stored exactly."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    u, count = np.unique(v, return_counts=True)
    if len(u) <= BOOK:
        book = np.concatenate([u, np.full(BOOK - len(u), u[-1])])
    else:
        book = u[np.round(np.linspace(0, len(u) - 1, BOOK)).astype(np.int64)]
        weight = count.astype(np.float64)
        for _ in range(iterations):
            label = _nearest(book, u)
            total = np.bincount(label, weights=u * weight, minlength=BOOK)
            held = np.bincount(label, weights=weight, minlength=BOOK)
            book = np.where(held > 0, total / np.maximum(held, 1.0), book)
            book[0], book[-1] = u[0], u[-1]
            book = np.sort(book)
    return book, _nearest(book, v).astype(np.uint8).reshape(np.shape(values))


def _nearest(book: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The index of each value's nearest entry of an ascending book (ties to the lower)."""
    hi = np.clip(np.searchsorted(book, v), 1, len(book) - 1)
    lo = hi - 1
    return np.where(np.abs(v - book[lo]) <= np.abs(book[hi] - v), lo, hi)


def _log_transform(x: np.ndarray) -> np.ndarray:
    return np.sign(x) * np.log(np.abs(x) + 1.0)


def _means(means: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mins, maxs, uint16 codes [N, 3]) of the log-transformed positions."""
    lt = _log_transform(means)
    mins, maxs = lt.min(axis=0), lt.max(axis=0)
    span = np.where(maxs > mins, maxs - mins, 1.0)
    codes = unorm_codes((lt - mins) / span, 16).astype(np.uint16)
    return mins, maxs, codes


def _quats(q: np.ndarray) -> np.ndarray:
    """RGBA bytes [N, 4]: the three components other than the largest (made positive), in
    (w, x, y, z) order, as (c * sqrt(2) * 0.5 + 0.5) * 255; A = 252 + the largest's index."""
    n = len(q)
    largest, negative = largest_component(q)
    q = np.where(negative[:, None], -q, q)
    others = np.array([[j for j in range(4) if j != m] for m in range(4)])[largest]
    abc = q[np.arange(n)[:, None], others] * math.sqrt(2.0)
    out = np.empty((n, 4), dtype=np.uint8)
    out[:, :3] = unorm_codes(abc * 0.5 + 0.5, 8)
    out[:, 3] = 252 + largest
    return out


def _palette(rows: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(palette [K, D], label of each row): the rows themselves up to MAX_PALETTE, else one
    k-means step from MAX_PALETTE seeded rows (the rows holding the extreme values included), each
    row labelled with its nearest entry among those of its coarse group (GROUPS seeded centres:
    the search costs N x (GROUPS + MAX_PALETTE / GROUPS), not N x MAX_PALETTE)."""
    n = len(rows)
    if n <= MAX_PALETTE:
        return rows, np.arange(n)
    flat = rows.reshape(n, -1)
    x = np.clip(flat, -1e18, 1e18).astype(np.float32)  # squared distances stay finite in float32
    rng = np.random.default_rng(seed)
    forced = np.unique([int(np.argmin(flat.min(axis=1))), int(np.argmax(flat.max(axis=1)))])
    rest = np.setdiff1d(rng.permutation(n)[:MAX_PALETTE], forced)
    init = np.concatenate([forced, rest[: MAX_PALETTE - len(forced)]])
    group = _nearest_rows(x, x[rng.choice(n, min(GROUPS, n), replace=False)])
    labels = np.full(n, -1, dtype=np.int64)
    entry_group = group[init]
    by_group = np.argsort(entry_group, kind="stable")
    bounds = np.searchsorted(entry_group[by_group], np.arange(GROUPS + 1))
    order = np.argsort(group, kind="stable")
    row_bounds = np.searchsorted(group[order], np.arange(GROUPS + 1))
    for g in range(GROUPS):
        members, entries = order[row_bounds[g] : row_bounds[g + 1]], by_group[bounds[g] : bounds[g + 1]]
        if len(members) and len(entries):
            labels[members] = entries[_nearest_rows(x[members], x[init[entries]])]
    lost = np.nonzero(labels < 0)[0]  # a group without an entry (rare): searched among all
    if len(lost):
        labels[lost] = _nearest_rows(x[lost], x[init])
    labels[init] = np.arange(len(init))  # an entry's own row keeps it
    sums = np.zeros((len(init), flat.shape[1]))
    np.add.at(sums, labels, flat)
    counts = np.bincount(labels, minlength=len(init))
    palette = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], flat[init])
    return palette, labels


def _nearest_rows(x: np.ndarray, cen: np.ndarray) -> np.ndarray:
    """The index of each row's nearest centre (squared distance, float32), in blocks of rows."""
    c2 = (cen * cen).sum(axis=1)
    out = np.empty(len(x), dtype=np.int64)
    for s in range(0, len(x), ASSIGN_BLOCK):
        out[s : s + ASSIGN_BLOCK] = np.argmin(c2[None, :] - 2.0 * (x[s : s + ASSIGN_BLOCK] @ cen.T), axis=1)
    return out


def _webp(texels: np.ndarray, w: int, h: int) -> bytes:
    from PIL import Image

    img = np.zeros((w * h, 4), dtype=np.uint8)
    img[:, 3] = 255
    img[: len(texels), : texels.shape[1]] = texels
    buf = io.BytesIO()
    Image.fromarray(img.reshape(h, w, 4), "RGBA").save(buf, "WEBP", lossless=True, exact=True, quality=50)
    return buf.getvalue()


def sog_files(model: Model, path: str = "<model>") -> dict[str, bytes]:
    """The WebP images and meta.json of a model's SOG (module docstring), by file name."""
    v = storable(model, path, "PlayCanvas SOG")
    n, r = model.n, model.sh_rest.shape[1]
    w, h = texture_size(n)
    mins, maxs, codes = _means(v["means"])
    files = {
        "means_l.webp": _webp((codes & 0xFF).astype(np.uint8), w, h),
        "means_u.webp": _webp((codes >> 8).astype(np.uint8), w, h),
        "quats.webp": _webp(_quats(v["quats"]), w, h),  # storable normalised them
    }
    scale_book, scale_idx = codebook(v["log_scales"])
    files["scales.webp"] = _webp(scale_idx, w, h)
    dc_book, dc_idx = codebook(v["sh_dc"])
    alpha = alpha_bytes(v["opacity"])
    files["sh0.webp"] = _webp(np.concatenate([dc_idx, alpha[:, None]], axis=1), w, h)
    meta = {
        "version": 2,
        "asset": {"generator": "seuwgpu"},
        "count": n,
        "means": {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": scale_book.tolist(), "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": dc_book.tolist(), "files": ["sh0.webp"]},
    }
    if r:
        palette, labels = _palette(v["sh_rest"])  # [K, R, 3] (or [K, 3R]): coefficient-major, channel innermost
        k = len(palette)
        sh_book, sh_idx = codebook(palette)
        cen = sh_idx.reshape(k * r, 3)  # texel j of entry e: coefficient j's R, G, B
        rows = -(-k // PALETTE_ROW)
        files["shN_centroids.webp"] = _webp(cen, PALETTE_ROW * r, rows)
        lab = np.stack([labels & 0xFF, labels >> 8], axis=1).astype(np.uint8)
        files["shN_labels.webp"] = _webp(lab, w, h)
        meta["shN"] = {
            "count": k,
            "bands": model.sh_degree,
            "codebook": sh_book.tolist(),
            "files": ["shN_centroids.webp", "shN_labels.webp"],
        }
    return {**files, "meta.json": json.dumps(meta, allow_nan=False).encode("utf-8")}  # write-sog.ts's order


def write_sog(model: Model, path, up: str | None = None, **_options) -> None:
    """Write `model` as SOG: for a `meta.json` path (or a folder), an unbundled SOG of meta.json
    and its images in that folder; any other path (`x.sog`), a bundled zip."""
    spath = os.fspath(path)
    p = Path(spath)
    bundled = not (p.name.lower() == "meta.json" or p.is_dir())
    files = sog_files(turned_to_minus_y(model, up), spath)
    if bundled:
        with zipfile.ZipFile(spath, "w", compression=zipfile.ZIP_STORED) as z:
            for name, data in files.items():
                z.writestr(name, data)
        return
    folder = p if p.is_dir() else p.parent
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (folder / name).write_bytes(data)
