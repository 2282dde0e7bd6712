"""The campaign spec, typed: what `normalize_spec` (campaign/spec.py) returns after validating a
TOML spec, and the form a run's manifest stores (`to_dict`, `from_dict`)."""

from __future__ import annotations

from dataclasses import dataclass

# ---- the spec, typed -----------------------------------------------------------------------------
# normalize_spec validates a TOML spec and returns a Spec. Its `to_dict()` is the spec as the run's
# manifest stores it and as its hash covers it (entries given only optionally are left out when not
# given, so older specs keep their hash); `Spec.from_dict` reads that form back (a manifest's).


def _plain(value):
    """Tuples as JSON lists, dataclasses as their dicts (what a manifest holds)."""
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if hasattr(value, "to_dict"):
        return value.to_dict()
    return value


class _Stored:
    """A spec table's stored form: its entries that are not None, tuples as JSON lists, and back."""

    def to_dict(self) -> dict:
        return {k: _plain(v) for k, v in vars(self).items() if v is not None}

    @classmethod
    def from_dict(cls, d: dict):
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


@dataclass(frozen=True, kw_only=True)
class SceneSpec(_Stored):
    """One [[scenes]] entry: an embedded scene (`scene`, `n`) or a model file (`model`, resolved,
    with the sha256 of its content), and optionally a camera file and an up axis."""

    sh_degree: int
    seed: int
    scene: str | None = None
    n: int | None = None
    model: str | None = None
    model_sha256: str | None = None
    lod: int | None = None  # the level of a PlayCanvas LOD set (recorded when given and not 0)
    up: str | None = None
    cameras: str | None = None
    cameras_sha256: str | None = None


@dataclass(frozen=True, kw_only=True)
class UpsetSpec(_Stored):
    """[single]: single upsets stratified by (field, bit) cell. `bits` is "all" or the bit list."""

    precisions: tuple[str, ...]
    fields: tuple[str, ...]
    bits: str | tuple[int, ...]
    samples: int
    sampling: str
    defenses: tuple[str, ...]
    regions: tuple[int, ...] = ()
    fault: str = "bit"

    def to_dict(self) -> dict:
        d = super().to_dict()
        if d["fault"] == "bit":  # recorded only when not the default (older specs keep their hash)
            del d["fault"]
        return d


@dataclass(frozen=True, kw_only=True)
class SizesSpec(UpsetSpec):
    """[sizes]: single upsets at each primitive count `n`, of the [[scenes]] `scenes` (None:
    the first, and not recorded)."""

    n: tuple[int, ...]
    scenes: tuple[int, ...] | None = None

    @property
    def scene_indices(self) -> tuple[int, ...]:
        return (0,) if self.scenes is None else self.scenes


@dataclass(frozen=True, kw_only=True)
class DoseSpec(_Stored):
    """[dose]: k simultaneous upsets drawn uniformly over the stored bits, `repeats` times each."""

    precisions: tuple[str, ...]
    k: tuple[int, ...]
    repeats: int
    defenses: tuple[str, ...]


@dataclass(frozen=True, kw_only=True)
class OutcomesSpec(_Stored):
    """[outcomes]: the outcome-class thresholds."""

    pixel_threshold: float
    footprint: float


@dataclass(frozen=True, kw_only=True)
class RateSpec(_Stored):
    environment: str
    per_bit_hour: float
    source: str


@dataclass(frozen=True, kw_only=True)
class ReliabilitySpec(_Stored):
    """[reliability]: inputs of the MTBF analysis (they change no injection)."""

    scrub_hours: float | None = None
    rates: tuple[RateSpec, ...] | None = None
    check_every: int | dict | None = None
    frames_per_second: float | None = None

    @classmethod
    def from_dict(cls, d: dict) -> ReliabilitySpec:
        rates = d.get("rates")
        return cls(
            scrub_hours=d.get("scrub_hours"),
            rates=None if rates is None else tuple(RateSpec(**r) for r in rates),
            check_every=d.get("check_every"),
            frames_per_second=d.get("frames_per_second"),
        )


@dataclass(frozen=True, kw_only=True)
class SummarySpec(_Stored):
    """[summary]: the report summary's target (a residual catastrophic rate per upset)."""

    target: float | None = None


@dataclass(frozen=True, kw_only=True)
class Spec(_Stored):
    """A validated campaign spec with its defaults filled in (module docstring: the TOML keys).
    `profile` None: the default renderer profile ("strict"), not recorded."""

    name: str
    seed: int
    views: int
    size: tuple[int, int]
    batch: int
    scenes: tuple[SceneSpec, ...]
    scale: float | None = None
    profile: str | None = None
    lpips: bool = False
    outcomes: OutcomesSpec | None = None
    reliability: ReliabilitySpec | None = None
    summary: SummarySpec | None = None
    single: UpsetSpec | None = None
    dose: DoseSpec | None = None
    sizes: SizesSpec | None = None

    @property
    def renderer_profile(self) -> str:
        return self.profile or "strict"

    def to_dict(self) -> dict:
        """The spec as the manifest stores it and its hash covers it."""
        d = super().to_dict()
        if not self.lpips:
            del d["lpips"]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Spec:
        """A Spec from its stored form (a manifest's `spec`), not validated again: the files it
        names may be on another machine."""
        sections = {"single": UpsetSpec, "dose": DoseSpec, "sizes": SizesSpec}
        tables = ("scenes", "size", *sections, "outcomes", "reliability", "summary")
        kw = {k: v for k, v in d.items() if k not in tables}
        kw["size"] = tuple(d["size"])
        kw["scenes"] = tuple(SceneSpec.from_dict(sc) for sc in d["scenes"])
        for key, kind in sections.items():
            if key in d:
                kw[key] = kind.from_dict(d[key])
        if "outcomes" in d:
            kw["outcomes"] = OutcomesSpec.from_dict(d["outcomes"])
        if "reliability" in d:
            kw["reliability"] = ReliabilitySpec.from_dict(d["reliability"])
        if "summary" in d:
            kw["summary"] = SummarySpec.from_dict(d["summary"])
        return cls(**kw)


def spec_dict(spec: Spec | dict) -> dict:
    """The stored form of a spec (a manifest's is one already)."""
    return spec.to_dict() if isinstance(spec, Spec) else spec


def as_spec(spec: Spec | dict) -> Spec:
    """A Spec, from a Spec or its stored form."""
    return spec if isinstance(spec, Spec) else Spec.from_dict(spec)
