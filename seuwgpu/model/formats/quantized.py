"""Helpers shared by the quantised formats (SPZ, compressed PLY, .splat, .ksplat, SOG).

Saturated opacity codes: the reference decoders turn an alpha byte of 255 (or 0) into a logit of
+Inf (or -Inf). Such splats are common (44% of leica-sofort's are fully opaque), and a clean
model full of Inf would trip every non-finite check and the guard's box. They are decoded to
+-SATURATED_LOGIT instead: the renderer's float32 sigmoid of 20 is exactly 1.0, the same as of
+Inf, and a splat at sigmoid(-20) = 2e-9 is skipped like one at 0, so renders are unchanged.
"""

from __future__ import annotations

import numpy as np

SATURATED_LOGIT = np.float32(20.0)
SH_C0 = 0.28209479177387814


def finite_logit(logit: np.ndarray) -> np.ndarray:
    """float32 logits with +-Inf (saturated alpha codes) replaced by +-SATURATED_LOGIT."""
    out = np.asarray(logit, dtype=np.float32).copy()
    out[out == np.inf] = SATURATED_LOGIT
    out[out == -np.inf] = -SATURATED_LOGIT
    return out


def byte_opacity(alpha: np.ndarray) -> np.ndarray:
    """The opacity (logit) of 8-bit alphas, logit(byte / 255) in float64 rounded once to float32,
    as .splat, .ksplat and SOG store opacity (bytes 0 and 255: -+SATURATED_LOGIT)."""
    a = np.asarray(alpha, dtype=np.float64) / 255.0
    with np.errstate(divide="ignore"):
        return finite_logit(np.log(a / (1.0 - a)))


def byte_sh_dc(rgb: np.ndarray) -> np.ndarray:
    """The SH DC of 8-bit colours, (byte / 255 - 0.5) / SH_C0 (float64), as .splat and .ksplat store colour."""
    return (np.asarray(rgb, dtype=np.float64) / 255.0 - 0.5) / SH_C0


def round_half_away(x: np.ndarray) -> np.ndarray:
    """C's round(): halves away from zero (numpy's round is half to even)."""
    x = np.asarray(x, dtype=np.float64)  # exact for float32 inputs: |x| + 0.5 does not round
    return np.copysign(np.floor(np.abs(x) + 0.5), x)


def to_u8(x: np.ndarray) -> np.ndarray:
    """The spz library's toUint8: clamp(round(x), 0, 255)."""
    with np.errstate(invalid="ignore"):
        return np.clip(round_half_away(np.asarray(x, dtype=np.float32)), 0, 255).astype(np.uint8)
