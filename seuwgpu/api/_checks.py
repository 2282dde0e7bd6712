"""The API's checks of its arguments: each names the argument and the problem in an InputError
(a ValueError), as the command line prints it."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from seuwgpu.campaign.spec_types import Spec
from seuwgpu.errors import InputError
from seuwgpu.faults.defenses import check_defense
from seuwgpu.faults.sites import (
    ADJACENT_WIDTHS,
    BURST_WIDTHS,
    VALUE_MODELS,
    check_site_model,
    model_bits,
)
from seuwgpu.model import checks, encoding
from seuwgpu.model.cameras import Camera, check_one_size
from seuwgpu.model.fields import Model
from seuwgpu.model.sources import Source


def fault_bits(fault, bit, width, precision, seed) -> tuple[tuple[int, ...], str, int]:
    """(bits, op, value) of one fault, as faults/sites.py applies it."""
    check_site_model(fault)
    if fault in VALUE_MODELS:
        return model_bits(fault, -1, precision, int(np.random.default_rng(seed).integers(2**63)))
    if bit is None:
        raise InputError(f"fault {fault!r} needs bit=")
    if isinstance(bit, (str, bytes)) or not isinstance(bit, (int, np.integer, Iterable)):
        raise InputError(f"bit must be an integer or a list of integers, got {bit!r}")
    bits = [bit] if isinstance(bit, (int, np.integer)) else list(bit)
    for b in bits:  # the bit asked for, named before an adjacent burst moves below it
        encoding.check_bit(precision, b)
    if fault in ("adjacent", "burst") and len(bits) == 1:
        widths = ADJACENT_WIDTHS if fault == "adjacent" else BURST_WIDTHS
        if width not in widths:
            raise InputError(f"{fault} width must be one of {', '.join(map(str, widths))}, got {width!r}")
        return model_bits(fault, int(bits[0]), precision, widths.index(width))
    return tuple(int(b) for b in bits), ("flip" if fault in ("bit", "adjacent", "burst") else fault), 0


def spec_of(spec) -> Spec:
    """A validated spec from a dict (files relative to the working folder), a TOML path or a Spec."""
    from seuwgpu.campaign.spec import load_spec, normalize_spec

    if isinstance(spec, dict):
        return normalize_spec(spec, base_dir=Path.cwd())
    if isinstance(spec, (str, Path)):
        return load_spec(spec)
    if not isinstance(spec, Spec):
        raise InputError(f"spec must be a dict, a Spec or the path of a TOML file, got {type(spec).__name__}")
    return spec


def engine_for(scene, views, precision: str, profile: str, what: str):
    """The fault-injection engine (faults/engine.py) of a model and its views, one image size."""
    from seuwgpu.faults.engine import Engine
    from seuwgpu.render.project import check_profile

    model = model_from(scene)
    name = scene.name if isinstance(scene, Source) else "model"
    views = view_list(views)
    check_one_size(views, "views", what)
    return Engine(model, views, encoding.check_precision(precision), scene=name, profile=check_profile(profile))


def defense_names(defenses) -> tuple[str, ...]:
    """Defense names checked, each named once (a defense named twice is refused, as a spec's
    `defenses` and the command line's --defense refuse it: checks.listed_once)."""
    names = tuple(checks.listed_once([check_defense(d) for d in names_of(defenses, "defenses")], "defenses"))
    if not names:
        raise InputError("defenses must name at least one defense")
    return names


def check_scene(scene):
    if not isinstance(scene, Source):
        raise InputError(f"expected a scene from load_model(), got {type(scene).__name__}")


def model_from(scene) -> Model:
    if isinstance(scene, Source):
        return scene.model
    if isinstance(scene, Model):
        return scene
    raise InputError(f"expected a scene from load_model() or a Model, got {type(scene).__name__}")


def view_list(views) -> list[Camera]:
    if isinstance(views, Camera):
        views = [views]
    views = list(views) if isinstance(views, (list, tuple)) else None
    if not views or not all(isinstance(c, Camera) for c in views):
        raise InputError("views must be a non-empty list of Camera (from cameras())")
    return views


def paths_of(values) -> list:
    """One path, or an iterable of them, as a list."""
    return [values] if isinstance(values, (str, Path)) else list(values)


def names_of(values, what: str) -> list[str]:
    if isinstance(values, str):
        return [values]
    try:
        values = list(values)
    except TypeError:
        raise InputError(f"{what} must be a name or a list of names, got {values!r}") from None
    if not all(isinstance(v, str) for v in values):
        raise InputError(f"{what} must be names (strings), got {values!r}")
    return values


def out_path(path, what: str) -> Path:
    """The path of an output folder (store.make_out_dir makes it, or says why it cannot: a run's
    through store.lock, a report's here)."""
    if not isinstance(path, (str, Path)):
        raise InputError(f"{what} must be a path, got {path!r}")
    return Path(path)


def existing_path(path, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such {what}")
    return p
