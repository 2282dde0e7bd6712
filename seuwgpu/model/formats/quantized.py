"""Helpers shared by the quantised formats (SPZ, compressed PLY, .splat, .ksplat, SOG).

Saturated opacity codes: the reference decoders turn an alpha byte of 255 (or 0) into a logit of
+Inf (or -Inf). Such splats are common (44% of leica-sofort's are fully opaque), and a clean
model full of Inf would trip every non-finite check and the guard's box. They are decoded to
+-SATURATED_LOGIT instead: the renderer's float32 sigmoid of 20 is exactly 1.0, the same as of
+Inf, and a splat at sigmoid(-20) = 2e-9 is skipped like one at 0, so renders are unchanged.
"""

from __future__ import annotations

import numpy as np

from seuwgpu.model.formats.errors import ModelFileError

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


# ---------------------------------------------------------------------------------------- writing
#
# What the quantised writers (compressed PLY, .splat, SOG, .ksplat) do with a corrupted value, one rule for
# all three (docs/models.md, "Writing a damaged model"):
# - NaN has no code in any of them: the file is refused (ModelFileError naming the format and the
#   fields), and the exact float32 PLY is the file to open.
# - +-Inf in a field stored over a data-derived range (positions, log-scales, colours, SOG's
#   codebooks) becomes +-F32_MAX, the most extreme finite float32: a range end of Inf would turn
#   the range's other codes into NaN (Inf * 0) in every reader. In an 8-bit field with a fixed
#   range (opacity, compressed PLY's SH) an infinite value is the end code, as a huge finite one.
# - A rotation is stored normalised: an infinite component leaves the limit direction (the signs
#   of the infinite components, the others zero), a zero quaternion the identity.
# - A huge finite value keeps its value where the format stores a range end or codebook entry
#   (the range is widened to hold it), else becomes the format's extreme code.

F32_MAX = float(np.finfo(np.float32).max)
RANGED = ("means", "log_scales", "sh_dc", "sh_rest")  # fields whose +-Inf become +-F32_MAX


def storable(model, path: str, title: str) -> dict[str, np.ndarray]:
    """The model's fields as float64 arrays ready to quantise, under the rule above: NaN refused
    (one line naming the file, the format and the fields), +-Inf of the ranged fields clamped to
    +-F32_MAX, quaternions normalised (unit_quats)."""
    if model.n == 0:
        raise ModelFileError(f"{path}: refusing to write a model with zero primitives as {title}")
    nan = [f for f in (*RANGED, "quats", "opacity") if np.isnan(getattr(model, f)).any()]
    if nan:
        raise ModelFileError(
            f"{path}: {title} cannot store NaN (found in {', '.join(nan)}); write .ply for the exact values"
        )
    out = {f: np.clip(getattr(model, f).astype(np.float64), -F32_MAX, F32_MAX) for f in RANGED}
    out["opacity"] = model.opacity.astype(np.float64)
    out["quats"] = unit_quats(model.quats)
    return out


def unit_quats(quats: np.ndarray) -> np.ndarray:
    """float64 unit quaternions: q / |q|; a row with an infinite component: the signs of its
    infinite components (normalised), the others zero; a zero row: the identity (1, 0, 0, 0)."""
    q = np.asarray(quats, dtype=np.float64).copy()
    inf = np.isinf(q).any(axis=1)
    q[inf] = np.where(np.isinf(q[inf]), np.sign(q[inf]), 0.0)
    norm = np.sqrt((q * q).sum(axis=1))
    q[norm == 0] = (1.0, 0.0, 0.0, 0.0)
    norm[norm == 0] = 1.0
    return q / norm[:, None]


def sigmoid(opacity: np.ndarray) -> np.ndarray:
    """float64 sigmoid without overflow warnings (+-Inf and huge logits give 1 and 0)."""
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + np.exp(-np.asarray(opacity, dtype=np.float64)))


def unorm_codes(v: np.ndarray, bits: int) -> np.ndarray:
    """uint32 codes of values in [0, 1] on 2^bits - 1 steps, rounded to nearest (halves up) and
    clamped: clip(floor(v * (2^bits - 1) + 0.5), 0, 2^bits - 1)."""
    top = (1 << bits) - 1
    return np.clip(np.floor(v * top + 0.5), 0, top).astype(np.uint32)


def alpha_bytes(opacity: np.ndarray) -> np.ndarray:
    """uint8 alphas of logits, sigmoid(opacity) as an 8-bit code (compressed PLY, .splat, .ksplat, SOG)."""
    return unorm_codes(sigmoid(opacity), 8).astype(np.uint8)


def colour_bytes(sh_dc: np.ndarray) -> np.ndarray:
    """uint8 colours of SH DC coefficients, 0.5 + SH_C0 * f_dc as 8-bit codes (.splat, .ksplat)."""
    return unorm_codes(0.5 + SH_C0 * np.asarray(sh_dc, dtype=np.float64), 8).astype(np.uint8)


def linear_scales(log_scales: np.ndarray) -> np.ndarray:
    """exp(log_scales) kept inside float32's range, 2^-149 .. F32_MAX (.splat, .ksplat store scales)."""
    with np.errstate(over="ignore"):
        return np.clip(np.exp(log_scales), float(np.finfo(np.float32).smallest_subnormal), F32_MAX)


def largest_component(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index of each quaternion's largest |component|, the first of equal magnitudes as the
    reference encoders pick it; whether that component is negative): the "smallest three"
    rotation codes of compressed PLY, SOG and SPZ store the others of the quaternion whose
    largest component is made positive."""
    n = len(q)
    a = np.abs(q)
    largest = np.zeros(n, dtype=np.int64)
    for i in (1, 2, 3):  # strictly greater: the first of equal magnitudes wins
        largest = np.where(a[:, i] > a[np.arange(n), largest], i, largest)
    return largest, q[np.arange(n), largest] < 0


def turned_to_minus_y(model, up: str | None):
    """The model turned so that `up` points to -y, the convention of .splat, SOG and compressed
    PLY viewers (positions, orientations and SH together); unchanged for None or -y."""
    if up in (None, "-y"):
        return model
    from seuwgpu.model.sh import rotate_model, rotation_to_y

    return rotate_model(model, np.diag([1.0, -1.0, -1.0]) @ rotation_to_y(up))
