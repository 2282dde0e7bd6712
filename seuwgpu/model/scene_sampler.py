"""Gaussians on a part's surface, looking trained (model/scenes.py's docstring gives the rules):
exactly `n` primitives shared among parts by area and weight, each a flat disc on the surface with
its scale, opacity, orientation and colour drawn as trained models hold them."""

from __future__ import annotations

import numpy as np

from seuwgpu.model.scene_parts import SAMPLERS, Part, normalize, surface_frame
from seuwgpu.model.sh import rotmat_to_quat

C0 = 0.28209479177387814

# Generator constants (documented in the module docstring).
SPLAT_C = 0.9  # tangent sigma = SPLAT_C * local spacing
TANGENT_JITTER = (0.2, 0.12)  # log-scale jitter: shared by both tangent axes, per axis
FLAT_GAP = (1.5, 2.5)  # normal-axis log-scale below the smaller tangent one
LOW_OPACITY_FRACTION = 0.12
HIGH_OPACITY = (0.9, 0.99)
LOW_OPACITY = (0.05, 0.5)
SH_REST_SD = (0.02, 0.012, 0.008)  # per-degree noise (degree 1, 2, 3)
SHEEN = 0.045  # degree-1 normal-aligned coefficient for gloss = 1


def allocate(weights: np.ndarray, n: int) -> np.ndarray:
    """Exactly n samples shared in proportion to weights (largest remainder, ties by index)."""
    quota = n * weights / weights.sum()
    counts = np.floor(quota).astype(np.int64)
    rest = n - int(counts.sum())
    if rest > 0:
        order = np.lexsort((np.arange(len(quota)), -(quota - counts)))
        counts[order[:rest]] += 1
    return counts


def _approx_normal(rng, shape) -> np.ndarray:
    """float32 noise of unit variance, ~2x cheaper than standard_normal: the sum of three
    uniform bytes (Irwin-Hall, bounded at 3 sd). Used for the bulky sh_rest field."""
    count = int(np.prod(shape))
    b = np.frombuffer(rng.bytes(3 * count), dtype=np.int8).reshape(3, count)
    acc = b[0].astype(np.int16)
    acc += b[1]
    acc += b[2]
    out = acc.astype(np.float32)
    out *= np.float32(1.0 / 128.0)  # sd of the sum is 128.0 (3 * (256^2 - 1) / 12 = 127.998^2)
    return out.reshape(shape)


def _logit(p):
    return np.log(p / (1.0 - p))


CHUNK = 1 << 16


def sample_part(part: Part, spacing: float, m: int, rng, nrest: int) -> dict:
    """`m` primitives on `part` (local spacing `spacing`): the Model fields of those rows."""
    cum = np.cumsum(part.areas)
    inst = np.minimum(np.searchsorted(cum, rng.random(m) * cum[-1], side="right"), len(cum) - 1)
    p = {k: v[inst] for k, v in part.params.items()}
    loc, lnrm, lhint, uv = SAMPLERS[part.kind](p, rng, m)
    F = part.frame[inst]
    pts = part.origin[inst] + np.einsum("mij,mj->mi", F, loc)
    nrm = np.einsum("mij,mj->mi", F, lnrm)
    # tangent frame: along the hint (stems, studs) with a little jitter, else random in-plane
    if lhint is not None:
        t1 = normalize(np.einsum("mij,mj->mi", F, lhint) + 0.15 * rng.standard_normal((m, 3)))
    else:
        t1 = rng.standard_normal((m, 3))
    fr = surface_frame(nrm, t1)
    nrm = fr[:, :, 2]

    # scales: tangent sigmas from the local spacing, the normal axis much thinner
    base = np.log(SPLAT_C * spacing) + TANGENT_JITTER[0] * rng.standard_normal(m)
    logs = np.empty((m, 3))
    logs[:, :2] = base[:, None] + TANGENT_JITTER[1] * rng.standard_normal((m, 2))
    if part.cap is not None:
        np.minimum(logs[:, :2], np.log(part.cap[inst]), out=logs[:, :2])
    logs[:, 2] = logs[:, :2].min(axis=1) - rng.uniform(*FLAT_GAP, size=m)

    # opacity: mostly high, a faint tail that is a bit larger and fuzzier (off the surface)
    low = rng.random(m) < LOW_OPACITY_FRACTION
    u = rng.random(m)
    hi_l, lo_l = _logit(np.array(HIGH_OPACITY)), _logit(np.array(LOW_OPACITY))
    opacity = np.where(low, lo_l[0] + (lo_l[1] - lo_l[0]) * u, hi_l[0] + (hi_l[1] - hi_l[0]) * u**0.7)
    offset = rng.standard_normal(m) * spacing * np.where(low, 0.3, 0.05)
    pts = pts + nrm * offset[:, None]
    logs[low] += 0.35

    # quaternion: the frame (t1, t2, normal) with a small wobble and a near-unit norm
    q = rotmat_to_quat(fr) + 0.01 * rng.standard_normal((m, 4))
    q *= (np.exp(0.03 * rng.standard_normal(m)) / np.linalg.norm(q, axis=1))[:, None]

    # colour: base colour, procedural texture, per-primitive noise
    ctx = {"pts": pts, "local": loc, "uv": uv, "inst": inst, "p": p, "colour": part.colour[inst]}
    col = part.texture(ctx) if part.texture is not None else ctx["colour"]
    col = col * (1.0 + part.noise * rng.standard_normal((m, 1))) + 0.015 * rng.standard_normal((m, 3))
    sh_dc = (np.clip(col, 0.01, 0.99) - 0.5) / C0

    # sh_rest: always drawn for degree 3 so that lower degrees are prefixes (same seed)
    sd = np.repeat(np.array(SH_REST_SD, dtype=np.float32), [3, 5, 7])
    rest = _approx_normal(rng, (m, 15, 3))
    rest *= sd[None, :, None]
    if part.gloss:
        a = ((SHEEN * part.gloss) * (1.0 + 0.2 * rng.standard_normal(m)))[:, None] * nrm
        # colour += C1 * (-y s1 + z s2 - x s3) = -C1 * a * dot(dir, n): bright where seen face-on
        rest[:, 0, :] += a[:, 1:2].astype(np.float32)
        rest[:, 1, :] -= a[:, 2:3].astype(np.float32)
        rest[:, 2, :] += a[:, 0:1].astype(np.float32)
    np.clip(rest, -0.1, 0.1, out=rest)
    return {
        "means": pts,
        "log_scales": logs,
        "quats": q,
        "opacity": opacity,
        "sh_dc": sh_dc,
        "sh_rest": rest[:, :nrest],
    }
