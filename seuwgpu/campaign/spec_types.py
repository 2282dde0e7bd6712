"""The campaign spec, typed: what `normalize_spec` (campaign/spec.py) returns after validating a
TOML spec, and the form a run's manifest stores (`to_dict`, `from_dict`).

Each TOML key is written once, as a field (`key(...)`: its help, the value a spec that leaves it
out takes, an example), or as a table's `INPUT_KEYS` when it is read but not stored (`ply =`, the
alias of `model =`; `k_max` and `points`, which make `k`). The key sets spec.py checks, its
defaults and the reference text (`reference()`, spec.py's docstring) are derived from them."""

from __future__ import annotations

import textwrap
from dataclasses import MISSING, dataclass, field, fields
from typing import ClassVar

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


def key(
    help: str,
    *,
    default=MISSING,
    toml=MISSING,
    example: str | None = None,
    stored_only: bool = False,
    alternative: bool = False,
):
    """A spec key. `default`: the field's when a stored spec leaves it out (None: recorded only
    when given); `toml`: what normalize_spec takes when a TOML spec leaves the key out, if not the
    default (a function: computed when asked); `example`: TOML text the reference shows instead
    of the default. `stored_only`: a field the spec computes (a file's sha256), no TOML key.
    `alternative`: shown commented out, as it excludes a key shown (model = beside scene =)."""
    meta = {"help": help, "toml": toml, "example": example, "key": not stored_only, "alternative": alternative}
    return field(metadata=meta) if default is MISSING else field(default=default, metadata=meta)


@dataclass(frozen=True)
class InputKey:
    """A TOML key read but not stored as given (an alias, the inputs of a computed value)."""

    help: str
    toml: object = field(default_factory=lambda: MISSING)  # MISSING as a default would mean none
    example: str | None = None
    alternative: bool = False


def table_keys(cls) -> dict[str, dict]:
    """{TOML key: its help, defaults and example} of a spec table, in the reference's order."""
    out = {f.name: {**f.metadata, "default": f.default} for f in fields(cls) if f.metadata.get("key")}
    for name, k in getattr(cls, "INPUT_KEYS", {}).items():
        out[name] = {**vars(k), "default": MISSING}
    return out


def key_names(cls) -> list[str]:
    """The TOML keys a spec table takes (any other is refused, naming these)."""
    return list(table_keys(cls))


def toml_default(cls, name: str):
    """What a TOML spec that leaves the key out takes: its `toml`, else the field's default."""
    k = table_keys(cls)[name]
    value = k["default"] if k["toml"] is MISSING else k["toml"]
    if value is MISSING:
        raise KeyError(f"{cls.__name__}.{name} has no default")
    return value() if callable(value) else value


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

    sh_degree: int = key("SH degree of an embedded scene; a model file's is read from it (recorded)", toml=3)
    seed: int = key("seed of an embedded scene (and of a [sizes] subset of a model file)", toml=0)
    scene: str | None = key(
        "an embedded scene (`seuwgpu scene --list`: procedural or real), or model = FILE",
        default=None,
        example='"spheres"',
    )
    n: int | None = key(
        "primitives of an embedded scene (a real capture: all of them by default)", default=None, toml=100_000
    )
    model: str | None = key(
        "a model file in any format `seuwgpu render` reads, or an INRIA output folder; recorded resolved",
        default=None,
        example='"point_cloud.ply"',
        alternative=True,
    )
    INPUT_KEYS: ClassVar[dict[str, InputKey]] = {
        "ply": InputKey("an alias of model =", example='"point_cloud.ply"', alternative=True)
    }
    model_sha256: str | None = key("the sha256 of the model file's content", default=None, stored_only=True)
    lod: int | None = key(
        "with a PlayCanvas LOD set (lod-meta.json or its folder): the level read (0, the finest, by default; "
        "named NAME-lod2 in records)",
        default=None,
        example="2",
        alternative=True,
    )
    up: str | None = key("optional: up axis of the orbit views (default: the format's)", default=None, example='"-y"')
    cameras: str | None = key(
        "optional: the capture's cameras (CAMS.json, INRIA cameras.json, a COLMAP model folder, nerfstudio "
        "transforms.json) instead of orbits; their views keep their own sizes, so not with `size =` (use scale)",
        default=None,
        example='"cameras.json"',
    )
    cameras_sha256: str | None = key("the sha256 of the camera files", default=None, stored_only=True)


_FAULTS = (
    'fault model: "bit" (single-bit flip), "adjacent" (2-4 neighbouring bits of the value from the cell\'s '
    'bit up), "burst" (2-8), "stuck0"/"stuck1" (the cell\'s bit stuck), "random"/"zero" (the whole value '
    "replaced by random bits / 0: one cell per field, bits ignored)"
)
_REGIONS = (
    "optional: sort-first contamination columns regions_pred_P and regions_meas_P (int64 bitmasks of the P regions "
    "reached/changed in any view), regions_pred_frame_P and regions_meas_frame_P (the share one view's frame "
    "reaches, averaged over the views)"
)
_SAMPLES = (
    "injections per (field, bit) cell, or a plan: samples = {margin = 0.02, confidence = 0.95} (Leveugle et al. "
    "2009, worst case p = 0.5; sites drawn with replacement, so no finite-population correction)"
)
_SAMPLING = (
    'or "uniform": `samples` x cells injections drawn uniformly over all stored bits (weight column = bits '
    "each sample stands for)"
)


@dataclass(frozen=True, kw_only=True)
class SamplePlan:
    """`samples = {margin, confidence}`: the samples per cell planned from a margin of error."""

    margin: float = key("the margin of error of a cell's rate, a proportion", example="0.02")
    confidence: float = key("its confidence", toml=0.95)


@dataclass(frozen=True, kw_only=True)
class UpsetSpec(_Stored):
    """[single]: single upsets stratified by (field, bit) cell. `bits` is "all" or the bit list."""

    precisions: tuple[str, ...] = key("stored precisions (fp32, fp16, bf16)", toml=["fp32"])
    fields: tuple[str, ...] = key("the fields each model holds (no sh_rest at SH degree 0), or a list", toml="all")
    bits: str | tuple[int, ...] = key("or a list of bit indices (those valid for each precision)", toml="all")
    samples: int = key(_SAMPLES, toml=20)
    sampling: str = key(_SAMPLING, toml="stratified")
    defenses: tuple[str, ...] = key("`seuwgpu defenses` lists them all", toml=["none", "guard"])
    regions: tuple[int, ...] = key(_REGIONS, default=(), example="[4, 16, 64]")
    fault: str = key(_FAULTS, default="bit")

    def to_dict(self) -> dict:
        d = super().to_dict()
        if d["fault"] == toml_default(UpsetSpec, "fault"):  # recorded only when not the default (hash)
            del d["fault"]
        return d


@dataclass(frozen=True, kw_only=True)
class SizesSpec(UpsetSpec):
    """[sizes]: single upsets at each primitive count `n`, of the [[scenes]] `scenes` (None:
    the first, and not recorded)."""

    n: tuple[int, ...] = key(
        "the primitive counts: a procedural scene is generated at N; a capture or model file cut to a seeded subset",
        example="[5000, 20000, 80000]",
    )
    scenes: tuple[int, ...] | None = key(
        'optional: [[scenes]] indices swept, or "all" (default: [0], the first)', default=None, toml=[0]
    )
    samples: int = key(_SAMPLES, toml=10)
    defenses: tuple[str, ...] = key("`seuwgpu defenses` lists them all", toml=["none"])

    @property
    def scene_indices(self) -> tuple[int, ...]:
        return (0,) if self.scenes is None else self.scenes


@dataclass(frozen=True, kw_only=True)
class DoseSpec(_Stored):
    """[dose]: k simultaneous upsets drawn uniformly over the stored bits, `repeats` times each."""

    precisions: tuple[str, ...] = key("stored precisions", toml=["fp32"])
    k: tuple[int, ...] = key("upsets per injection, or k_max and points", example="[1, 10, 100]")
    INPUT_KEYS: ClassVar[dict[str, InputKey]] = {
        "k_max": InputKey("instead of k: up to this many upsets", toml=20_000, alternative=True),
        "points": InputKey("with k_max: this many log-spaced levels (rounded, distinct)", toml=12, alternative=True),
    }
    repeats: int = key("injections per k", toml=3)
    defenses: tuple[str, ...] = key("`seuwgpu defenses` lists them all", toml=["none", "guard"])


def _pixel_threshold() -> float:
    from seuwgpu.metrics.image import PIXEL_THRESHOLD

    return PIXEL_THRESHOLD


def _footprint_threshold() -> float:
    from seuwgpu.metrics.image import FOOTPRINT_THRESHOLD

    return FOOTPRINT_THRESHOLD


@dataclass(frozen=True, kw_only=True)
class OutcomesSpec(_Stored):
    """[outcomes]: the outcome-class thresholds."""

    pixel_threshold: float = key("a channel change above it is visible (SDC), 1/255", toml=_pixel_threshold)
    footprint: float = key(
        "a frame with more changed pixels than this share is catastrophic", toml=_footprint_threshold
    )


@dataclass(frozen=True, kw_only=True)
class RateSpec(_Stored):
    environment: str = key("where the upsets happen", example='"ground"')
    per_bit_hour: float = key("upsets per stored bit and hour", example="1e-12")
    source: str = key("where the rate comes from", example='"..."')


@dataclass(frozen=True, kw_only=True)
class ReliabilitySpec(_Stored):
    """[reliability]: inputs of the MTBF analysis (they change no injection)."""

    scrub_hours: float | None = key(
        "the model is restored from protected storage this often", default=None, example="24.0"
    )
    rates: tuple[RateSpec, ...] | None = key(
        "upset rates, each {environment, per_bit_hour, source}",
        default=None,
        example='[{environment = "ground", per_bit_hour = 1e-12, source = "where the rate comes from"}]',
    )
    check_every: int | dict | None = key(
        "a check defense checks every S frames (or {parity4r = 10, checksum = 20}): what it repairs is drawn "
        "until then; default 10",
        default=None,
        example="10",
    )
    frames_per_second: float | None = key(
        "the frame rate the check's exposure (frames) turns into hours", default=None, example="30.0"
    )

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

    target: float | None = key(
        "residual catastrophic rate per upset the cheapest defense must meet", default=None, toml=0.001
    )


@dataclass(frozen=True, kw_only=True)
class Spec(_Stored):
    """A validated campaign spec with its defaults filled in (module docstring: the TOML keys).
    `profile` None: the default renderer profile ("strict"), not recorded."""

    name: str = key("the campaign's name", toml="campaign")
    seed: int = key("master seed", toml=0)
    views: int = key("orbit views per scene (K), or K of the capture's views, evenly", toml=4)
    size: tuple[int, int] = key("WxH of orbit views", toml="256x256")
    batch: int = key("injections per GPU batch and per Parquet part", toml=256)
    scenes: tuple[SceneSpec, ...] = key("one or more")
    scale: float | None = key(
        "optional: render at this fraction of the views' resolution", default=None, example="0.25"
    )
    profile: str | None = key(
        'optional renderer profile: "strict" or "gsplat" (docs/renderer.md)', default=None, example='"strict"'
    )
    lpips: bool = key(
        "optional: LPIPS (AlexNet) of every record, re-rendered in full (slow: ~1 s per 256 px view on a CPU; "
        "pip install 'seuwgpu[lpips]')",
        default=False,
        example="true",
    )
    outcomes: OutcomesSpec | None = key("optional: outcome-class thresholds (defaults: the paper's)", default=None)
    reliability: ReliabilitySpec | None = key(
        "optional: inputs of the MTBF analysis (they change no injection)", default=None
    )
    summary: SummarySpec | None = key("optional: the report's opening summary (it changes no injection)", default=None)
    single: UpsetSpec | None = key("single upsets, stratified by (field, bit) cell", default=None)
    dose: DoseSpec | None = key("k simultaneous upsets drawn uniformly over the whole bit budget", default=None)
    sizes: SizesSpec | None = key("primitive-count sweep: single upsets at each N", default=None)

    TABLES: ClassVar[dict[str, type]] = {}  # filled below: key -> the table's class

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
        kw = {k: v for k, v in d.items() if k not in cls.TABLES and k != "size"}
        kw["size"] = tuple(d["size"])
        for name, kind in cls.TABLES.items():
            if name == "scenes":
                kw[name] = tuple(SceneSpec.from_dict(sc) for sc in d[name])
            elif name in d:
                kw[name] = kind.from_dict(d[name])
        return cls(**kw)


Spec.TABLES.update(
    scenes=SceneSpec,
    single=UpsetSpec,
    dose=DoseSpec,
    outcomes=OutcomesSpec,
    reliability=ReliabilitySpec,
    summary=SummarySpec,
    sizes=SizesSpec,
)


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(map(_toml, value)) + "]"
    return repr(value)


def _lines(cls, indent: str) -> list[str]:
    out = []
    for name, k in table_keys(cls).items():
        if name in Spec.TABLES and cls is Spec:
            continue
        if k["example"] is not None:
            shown = k["example"]
        else:
            shown = _toml(toml_default(cls, name))
        mark = "# " if k.get("alternative") else ""
        out.append(_commented(f"{indent}{mark}{name} = {shown}", k["help"], indent))
    return out


def _commented(text: str, help: str, indent: str, column: int = 29) -> str:
    """`text  # help`, the help wrapped under itself."""
    wrapped = [f"{'':<{column}}# {w}" for w in textwrap.wrap(help, 96 - column)]
    if len(text) >= column:  # a long value: its help on the lines below
        return "\n".join([text, *wrapped])
    return "\n".join([f"{text:<{column}}{wrapped[0][column:]}" if wrapped else text, *wrapped[1:]])


def reference(indent: str = "    ") -> str:
    """Every TOML key of a campaign spec, with its default (or an example) and its help, as the
    module docstring of campaign/spec.py shows them."""
    blocks = ["\n".join(_lines(Spec, indent))]
    for name, kind in Spec.TABLES.items():
        header = f"[[{name}]]" if name == "scenes" else f"[{name}]"
        help = table_keys(Spec)[name]["help"]
        blocks.append("\n".join([_commented(f"{indent}{header}", help, indent), *_lines(kind, indent)]))
    return "\n\n".join(blocks)


def stored_table(manifest: dict, key: str):
    """The typed `[key]` table (Spec.TABLES: reliability, summary, ...) of a run manifest's
    stored spec, or None where it has none (or the manifest no spec). One table is read, not the
    whole spec: the analyses take manifests of runs written by older versions, and parts of them."""
    spec = manifest.get("spec") if isinstance(manifest, dict) else None
    table = spec.get(key) if isinstance(spec, dict) else None
    return Spec.TABLES[key].from_dict(table) if isinstance(table, dict) else None


def stored_scenes(manifest: dict) -> tuple[SceneSpec, ...]:
    """The typed [[scenes]] of a run manifest's stored spec (none where it has no spec). The
    analyses take manifests of runs of older versions: a key those did not store (sh_degree,
    seed) reads as None, and a key this version no longer knows is left out."""
    spec = manifest.get("spec") if isinstance(manifest, dict) else None
    scenes = spec.get("scenes") if isinstance(spec, dict) else None
    known = {f.name for f in fields(SceneSpec)}
    return tuple(
        SceneSpec.from_dict({"sh_degree": None, "seed": None} | {k: v for k, v in sc.items() if k in known})
        for sc in scenes or ()
        if isinstance(sc, dict)
    )


def stored_size(manifest: dict) -> tuple[int, int] | None:
    """(W, H) of a run manifest's stored spec, or None where it does not say."""
    spec = manifest.get("spec") if isinstance(manifest, dict) else None
    size = spec.get("size") if isinstance(spec, dict) else None
    return (int(size[0]), int(size[1])) if isinstance(size, (list, tuple)) and len(size) == 2 else None


def spec_dict(spec: Spec | dict) -> dict:
    """The stored form of a spec (a manifest's is one already)."""
    return spec.to_dict() if isinstance(spec, Spec) else spec


def as_spec(spec: Spec | dict) -> Spec:
    """A Spec, from a Spec or its stored form."""
    return spec if isinstance(spec, Spec) else Spec.from_dict(spec)
