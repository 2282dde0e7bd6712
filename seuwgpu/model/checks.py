"""The checks of what a user gives, each written once with one wording: the API (`bit`), the
command line (`--bit`) and a campaign spec (`single.bits`) call the same check with the name the
user knows the input by, so a value one refuses the others refuse with the same line.

Every check raises InputError (a ValueError) whose message names the input and the problem. It
lives in the lowest layer so that the model, the renderer, the defenses' registry, the spec, the
API and the command line can all call it; it imports nothing of the model: the checks of a
registry's names are `one_of` over that registry (encoding.check_precision, fields.canonical_field,
encoding.check_bit, defenses.get).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from seuwgpu.errors import InputError

# The views a command renders (apps/cli/ --size, --views), a campaign spec names (size, views)
# and the API's cameras() makes: one set of limits, so that a value one accepts none refuses.
MIN_VIEW_SIZE = 16  # px, width and height: one 16 px tile; the image metrics' 7x7 windows need >= 7
MAX_VIEWS = 64  # views rendered for each injection of a campaign, or by one command
MAX_SCALE = 16  # --scale and a spec's `scale`: at most 16 times the views' own resolution


def _named(what: str | None, problem: str) -> str:
    """`what problem`, or the problem alone where the caller names the input (argparse does)."""
    return f"{what} {problem}" if what else problem


def prefix(what: str | None) -> str:
    """`what: ` before a problem that names its value (unknown precision 'fp8'), or nothing."""
    return f"{what}: " if what else ""


def integer(value, what: str | None, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (not a bool, not a float to be truncated) in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(_named(what, f"must be an integer, got {value!r}"))
    if lo is not None and value < lo:
        raise InputError(_named(what, f"must be at least {lo}, got {value}"))
    if hi is not None and value > hi:
        raise InputError(_named(what, f"must be at most {hi}, got {value}"))
    return int(value)


def number(value, what: str | None, most: float | None = None) -> float:
    """A finite number above 0 (and at most `most`)."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float, np.number)) and math.isfinite(value)
    if not (ok and value > 0 and (most is None or value <= most)):
        wanted = "a positive number" if most is None else f"a number in (0, {most:g}]"
        raise InputError(_named(what, f"must be {wanted}, got {value!r}"))
    return float(value)


def proportion(value, what: str | None, example: str = "0.02") -> float:
    """A number strictly between 0 and 1 (a margin, a confidence, a rate per upset)."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float, np.number))
    if not (ok and 0 < value < 1):
        raise InputError(_named(what, f"must be a proportion in (0, 1), e.g. {example}; got {value!r}"))
    return float(value)


def one_of(value, kind: str, choices: Iterable[str], what: str | None = None) -> str:
    """A name from a registry (a precision, a field, a defense, a profile, a scene, ...)."""
    choices = list(choices)
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{prefix(what)}unknown {kind} {value!r}; expected one of {', '.join(choices)}")
    return value


def listed_once(values: list, what: str, hint: str = "") -> list:
    """Names each given once: an arm (a precision, a defense, a field) listed twice would be run
    and counted twice."""
    twice = sorted({x for x in values if values.count(x) > 1}, key=str)
    if twice:
        raise InputError(f"{what} lists {', '.join(map(repr, twice))} more than once{hint}")
    return values


def shard(value, what: str | None = "shard") -> tuple[int, int]:
    """Shard I of N as (I, N): integers with 0 <= I < N (an I >= N ran no block and returned as
    done, N = 0 divided by zero)."""
    try:
        i, n = value
        whole = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (i, n))
    except (TypeError, ValueError):
        whole = False
    if not (whole and 0 <= i < n):
        raise InputError(_named(what, f"must be (I, N), integers with 0 <= I < N, got {value!r}"))
    return int(i), int(n)


def image_size(value, what: str | None = "size") -> tuple[int, int]:
    """A view's `WxH` (text such as "128x96", or a (width, height) pair), each side at least
    MIN_VIEW_SIZE: what --size, a campaign spec's `size` and the API's `size` take."""
    if isinstance(value, str):
        try:
            w, h = (int(x) for x in value.lower().split("x"))
        except ValueError:
            raise InputError(_named(what, f'must look like "128x96", got {value!r}')) from None
    elif isinstance(value, (list, tuple)) and len(value) == 2:
        w, h = value
    else:
        raise InputError(_named(what, f'must look like "128x96" or (width, height), got {value!r}'))
    whole = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (w, h))
    if not whole or w < MIN_VIEW_SIZE or h < MIN_VIEW_SIZE:
        raise InputError(
            f"{prefix(what)}width and height must be whole numbers of at least {MIN_VIEW_SIZE} px, got {value!r}"
        )
    return int(w), int(h)


def views(value, what: str | None = "views") -> int:
    """A number of views: 1 to MAX_VIEWS (a command's, a spec's, the API's)."""
    return integer(value, what, 1, MAX_VIEWS)


def scale(value, what: str | None = "scale") -> float:
    """A resolution factor in (0, MAX_SCALE]."""
    return number(value, what, MAX_SCALE)


def lod_level(value, what: str | None = "lod") -> int:
    """A level of a PlayCanvas LOD set: 0 (the finest), 1, 2, ..."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise InputError(_named(what, f"must be a level 0, 1, 2, ..., got {value!r}"))
    return int(value)


def lod_of_a_model_file(lod, scene: str | None, what: str = "lod"):
    """A LOD level picks a level of a model file (a PlayCanvas LOD set): with an embedded scene
    it is refused, not ignored."""
    if lod is not None:
        which = f"the embedded scene {scene!r}" if scene else "an embedded scene"
        raise InputError(
            f"{what} picks a level of a PlayCanvas LOD set (a model file: lod-meta.json or its folder), not of {which}"
        )


def n_of_an_embedded_scene(n, model, what: str = "n", hint: str = ""):
    """A primitive count shapes an embedded scene: beside a model file (`model`, as the user named
    it) it is refused, not ignored, for a model file keeps all of its primitives."""
    if n is not None and model is not None:
        raise InputError(
            f"{what} sets the primitives of an embedded scene; a model file keeps all of its own ({model}){hint}"
        )


def size_of_orbit_views(size, from_files: bool, what: str = "size", scale: str = "scale", hint: str = ""):
    """An image size shapes orbit views: where the views come from camera files (`from_files`),
    which give each view its own size, it is refused, not ignored; `scale` (named as the user
    knows it) resizes those views."""
    if size is not None and from_files:
        raise InputError(f"{what} sets orbit views; a cameras file gives each view its own size (use {scale}){hint}")
