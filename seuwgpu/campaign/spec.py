"""Campaign specs: parse, validate and normalise a TOML spec; its hash names the run.

Files a spec names (model, cameras) are resolved to absolute paths and recorded with the sha256
of their content (`model_sha256`, `cameras_sha256`; reading costs about a second per GB); the hash
covers the content, not the folder, so a changed file is another run and one moved to another
folder the same; a model renamed is another run (records name it by its file or INRIA output
folder name).
Lists of names (precisions, defenses, fields with their aliases) must not repeat an entry; lists of
numbers (bits, k, sizes.n, regions) are merged. Seeds are integers in [0, 2**63).

Every key, its default (or an example) and what it means is written once, as a field of
campaign/spec_types.py; the reference below (alternatives commented out), the key sets checked
here and the defaults come from there.

Spec (TOML; unknown keys and bad values fail at once, naming the key):
"""

from __future__ import annotations

import hashlib
import tomllib
from pathlib import Path

import numpy as np

from seuwgpu.campaign.spec_types import (
    DoseSpec,
    OutcomesSpec,
    RateSpec,
    ReliabilitySpec,
    SamplePlan,
    SceneSpec,
    SizesSpec,
    Spec,
    SummarySpec,
    UpsetSpec,
    key_names,
    reference,
    toml_default,
)
from seuwgpu.errors import InputError
from seuwgpu.faults.defenses import DEFENSES, REGISTRY, partner_drop_refusal
from seuwgpu.model import checks, encoding
from seuwgpu.model.budget import n_values
from seuwgpu.model.fields import FIELDS, canonical_field
from seuwgpu.model.formats import UP_AXES

SAMPLINGS = ("stratified", "uniform")
SEED_MAX = 2**63 - 1  # seeds are TOML integers (signed 64-bit), used as unsigned 64-bit hash keys


class SpecError(InputError):
    """A campaign spec (or a run directory or shard set it meets) that cannot be run as given."""


def _keys(table: dict, cls, where: str):
    """Refuse a key the table `cls` (spec_types) does not take, naming those it does."""
    if not isinstance(table, dict):
        raise SpecError(f"{where} must be a table")
    allowed = key_names(cls)
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise SpecError(
            f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(repr(k) for k in unknown)} in {where} "
            f"(allowed: {', '.join(sorted(allowed))})"
        )


def _get(table, cls, key: str, where: str):
    """The key's value, or the default of the table `cls` (spec_types) where it is left out."""
    if key in table:
        return table[key]
    try:
        return toml_default(cls, key)
    except KeyError:
        raise SpecError(f"{where}.{key} is required") from None


def _int(table, cls, key, where, lo=None, hi=None):
    return checks.integer(_get(table, cls, key, where), f"{where}.{key}", lo, hi)


def _counts(table, cls, key, where) -> list[int]:
    """A non-empty list of positive integers (dose.k, sizes.n)."""
    v = _get(table, cls, key, where)
    if not isinstance(v, list) or not v:
        raise SpecError(f"{where}.{key} must be a non-empty list")
    return [checks.integer(x, f"{where}.{key}", 1) for x in v]


def _model_file(scene: dict, path, where: str, lod: int | None = None):
    """A scene's model file, read once by the spec: its SH degree is the scene's (the spec's
    sh_degree shapes embedded scenes; one that differs from the file's is refused, not ignored),
    recorded so that the runs' cells (no sh_rest at degree 0) and every analysis of stored bits
    are the model's; its primitive count bounds a [sizes] sweep."""
    from seuwgpu.model.formats import read_model

    try:
        model = read_model(path, warn_nonfinite=False, lod=lod).model
    except ValueError as e:  # ModelFileError: the file named, the problem said
        raise SpecError(f"{where}: {e}") from None
    if "sh_degree" in scene and scene["sh_degree"] != model.sh_degree:
        raise SpecError(
            f"{where}.sh_degree = {scene['sh_degree']!r} shapes an embedded scene; the model file holds SH degree "
            f"{model.sh_degree} (remove sh_degree)"
        )
    return model


def _no_missing_fields(table, where: str, scenes: list):
    """A field listed by name that a scene's model does not hold (sh_rest at SH degree 0) is
    refused; "all" means the fields each model holds (campaign/sampling.py scene_fields)."""
    if table.get("fields", "all") == "all":  # "all": each model's own fields, whatever the default
        return
    for i, sc in enumerate(scenes):
        if sc["sh_degree"] == 0 and "sh_rest" in [canonical_field(f) for f in table["fields"]]:
            raise SpecError(
                f"{where}.fields lists sh_rest, which scenes[{i}] (SH degree 0) does not hold; "
                'remove it, or use fields = "all" (each model\'s own fields)'
            )


def _fields(table, cls, where):
    v = _get(table, cls, "fields", where)
    if v == "all":
        return list(FIELDS)
    if not isinstance(v, list) or not v:
        raise SpecError(f'{where}.fields must be "all" or a list of fields')
    out = [canonical_field(f, f"{where}.fields") for f in v]
    return checks.listed_once(out, f"{where}.fields", " (a field and its alias?)")


def _bits(table, cls, where, precisions):
    v = _get(table, cls, "bits", where)
    if v == "all":
        return "all"
    if not isinstance(v, list) or not v or not all(isinstance(b, int) and not isinstance(b, bool) for b in v):
        raise SpecError(f'{where}.bits must be "all" or a list of bit indices')
    for p in precisions:
        for b in v:
            encoding.check_bit(p, b, f"{where}.bits")
    return sorted(set(v))


def _samples(table, cls, where):
    """`samples` as an int, or planned from {margin, confidence} (campaign.plan.sample_size)."""
    v = _get(table, cls, "samples", where)
    if isinstance(v, dict):
        _keys(v, SamplePlan, f"{where}.samples")
        from seuwgpu.campaign.plan import sample_size

        margin = checks.proportion(v.get("margin"), f"{where}.samples.margin", "0.02")
        conf = _get(v, SamplePlan, "confidence", f"{where}.samples")
        conf = checks.proportion(conf, f"{where}.samples.confidence", "0.95")
        # No finite-population correction: a cell's sites are drawn with replacement (each
        # injection from its own hash stream, campaign/sampling.py, so any block can be re-run or
        # resumed alone), and the correction only holds for draws without replacement.
        return int(sample_size(float(margin), float(conf)))
    return _int(table, cls, "samples", where, 1)


def _spec_file(table, key, where, base_dir: Path | None) -> str:
    """A file named in the spec, relative to the spec's folder; it must exist. Returned resolved
    (absolute, links followed), so one spec reached through another path names the same file."""
    v = table[key]
    if not isinstance(v, str) or not v:
        raise SpecError(f'{where}.{key} must be a file name in quotes, e.g. {key} = "point_cloud.ply"; got {v!r}')
    path = Path(v).expanduser()
    if base_dir is not None and not path.is_absolute():
        path = base_dir / path
    if not path.exists():
        raise SpecError(f"{where}.{key}: file not found: {path}")
    return str(path.resolve())


def content_files(key: str, path) -> list[Path]:
    """The files whose content a spec's `model` or `cameras` entry stands for: the model file (an
    INRIA output folder: its last iteration's PLY; an unbundled SOG: its meta.json and images), or
    the camera files read_cameras reads."""
    from seuwgpu.model.cameras import camera_files
    from seuwgpu.model.formats import model_files

    path = Path(path)
    if key == "cameras":
        return camera_files(path)
    files = model_files(path)
    if files == [path] and path.is_dir():
        raise SpecError(
            f"model {path} is a folder, not a model file (and holds no point_cloud/iteration_*/point_cloud.ply "
            "or SOG meta.json)"
        )
    return files


def content_hash(key: str, path) -> str:
    """sha256 of the content a spec entry names (several files: of their names and contents)."""
    files = content_files(key, path)
    h = hashlib.sha256()
    for f in files:
        if len(files) > 1:
            h.update(f.name.encode() + b"\0")
        try:
            with open(f, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
        except OSError as e:
            raise SpecError(f"{key} {f}: cannot be read ({e.strerror or e})") from None
    return h.hexdigest()


def _names(table, cls, key, where, kind, valid) -> list:
    """A list of names (precisions, defenses), each at most once, or "all" of them."""
    if table.get(key) == "all":
        return list(valid)
    v = _get(table, cls, key, where)
    if not isinstance(v, list) or not v:
        raise SpecError(f'{where}.{key} must be a non-empty list or "all"')
    return checks.listed_once([checks.one_of(x, kind, valid, f"{where}.{key}") for x in v], f"{where}.{key}")


def _upsets(t: dict, cls, where: str, size) -> dict:
    """The single-upset keys [single] and [sizes] share (spec_types.UpsetSpec), checked."""
    precisions = _names(t, cls, "precisions", where, "precision", encoding.PRECISIONS)
    out = {
        "precisions": precisions,
        "fields": _fields(t, cls, where),
        "bits": _bits(t, cls, where, precisions),
        "samples": _samples(t, cls, where),
        "sampling": checks.one_of(_get(t, cls, "sampling", where), "sampling", SAMPLINGS, f"{where}.sampling"),
        "defenses": _names(t, cls, "defenses", where, "defense", DEFENSES),
        "regions": _regions(t, cls, where, size),
    }
    if out["regions"]:  # the incremental path draws one primitive a variant (faults/engine.py evaluate_frame)
        for d in out["defenses"]:
            for p in precisions:
                refusal = partner_drop_refusal(f"{where}.regions", d, p)
                if refusal:
                    raise SpecError(refusal)
    return out


def _regions(table, cls, where, size):
    """Sort-first partition sizes P for contamination columns (regions_pred_P, regions_meas_P);
    each must fit the tile-aligned region grid of the frame (render/regions.py)."""
    from seuwgpu.render.regions import region_grid

    v = _get(table, cls, "regions", where)
    v = list(v) if isinstance(v, tuple) else v  # the default, ()
    if not isinstance(v, list) or not all(isinstance(p, int) and not isinstance(p, bool) for p in v):
        raise SpecError(f"{where}.regions must be a list of partition sizes, e.g. [4, 16, 64]")
    for p in v:
        if not 2 <= p <= 64:
            raise SpecError(f"{where}.regions: P = {p} is out of range [2, 64] (regions are 64-bit masks)")
        try:
            region_grid(p, size[1], size[0])
        except ValueError as e:
            raise SpecError(f"{where}.regions: {e}") from None
    return sorted(set(v))


def _fault(table, cls, out, where):
    """The fault model, recorded only when not the default single-bit flip (older specs keep their
    hash)."""
    from seuwgpu.faults.sites import check_site_model

    v = check_site_model(_get(table, cls, "fault", where), f"{where}.fault")
    if v != toml_default(cls, "fault"):
        out["fault"] = v


def _name(raw) -> str:
    v = _get(raw, Spec, "name", "spec")
    if not isinstance(v, str) or not v.strip():
        raise SpecError(f"name must be a non-empty string, got {v!r}")
    return v


def dose_levels(k_max: int, points: int) -> list[int]:
    ks = np.unique(np.round(np.logspace(0, np.log10(k_max), points)).astype(int))
    return [int(k) for k in ks]


def _outcomes(t) -> dict:

    _keys(t, OutcomesSpec, "outcomes")
    out = {}
    for key in key_names(OutcomesSpec):
        v = _get(t, OutcomesSpec, key, "outcomes")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < 1:
            raise SpecError(f"outcomes.{key} must be a number in [0, 1), got {v!r}")
        out[key] = float(v)
    return out


def _reliability(t) -> dict:
    _keys(t, ReliabilitySpec, "reliability")
    out = {}
    if "check_every" in t:
        v = t["check_every"]
        if isinstance(v, dict):  # a schedule per check defense: frames between checks
            checked = [x for x, o in REGISTRY.items() if o.checked]
            for d, s in v.items():
                checks.one_of(d, "check defense", checked, "reliability.check_every")
                checks.integer(s, f"reliability.check_every.{d}", 1)
            out["check_every"] = dict(v)
        else:
            out["check_every"] = checks.integer(v, "reliability.check_every", 1)
    for key in ("frames_per_second", "scrub_hours"):
        if key in t:
            out[key] = checks.number(t[key], f"reliability.{key}")
    if "rates" in t:
        rates = t["rates"]
        if not isinstance(rates, list) or not rates:
            raise SpecError("reliability.rates must be a non-empty list of {environment, per_bit_hour, source}")
        out["rates"] = []
        for i, r in enumerate(rates):
            _keys(r, RateSpec, f"reliability.rates[{i}]")
            lam = checks.number(r.get("per_bit_hour"), f"reliability.rates[{i}].per_bit_hour")
            if not isinstance(r.get("environment"), str) or not isinstance(r.get("source"), str):
                raise SpecError(f"reliability.rates[{i}] needs environment and source (strings)")
            out["rates"].append({"environment": r["environment"], "per_bit_hour": float(lam), "source": r["source"]})
    return out


def scene_label(entry: SceneSpec | dict) -> str | None:
    """The scene name records give a spec's [[scenes]] entry: an embedded scene's name, a model's
    file or INRIA output folder name (formats.model_label); None for neither."""
    from seuwgpu.model.formats import model_label

    if isinstance(entry, SceneSpec):
        entry = entry.to_dict()
    if entry.get("scene"):
        return str(entry["scene"])
    return model_label(entry["model"], entry.get("lod")) if entry.get("model") else None


def _distinct_labels(scenes: list[dict]):
    """Records name a scene by its label (an embedded scene's name, a model's file or INRIA
    output folder name: formats.model_label); two different models under one label would be
    pooled as one scene in every estimate."""
    seen: dict[str, tuple[int, str]] = {}
    for i, sc in enumerate(scenes):
        label = scene_label(sc)
        what = sc.get("model_sha256") or f"embedded {sc.get('scene')}"
        j, other = seen.setdefault(label, (i, what))
        if other != what:
            raise SpecError(
                f"scenes[{j}] and scenes[{i}] are different models that records would both name {label!r} "
                "(the same file or folder name): rename one of them"
            )


def normalize_spec(raw: dict, base_dir: Path | None = None) -> Spec:
    """The validated spec with its defaults filled in (`to_dict()`: what is hashed and stored in
    the manifest). The shared checks (model/checks.py) raise InputError: a spec's is a SpecError."""
    try:
        return _normalize(raw, base_dir)
    except InputError as e:
        if type(e) is not InputError:
            raise
        raise SpecError(str(e)) from None


def _normalize(raw: dict, base_dir: Path | None) -> Spec:
    from seuwgpu.model.scenes import is_capture, list_scenes, make_scene

    _keys(raw, Spec, "the spec")
    spec = {
        "name": _name(raw),
        "seed": _int(raw, Spec, "seed", "spec", 0, SEED_MAX),
        "views": checks.views(_get(raw, Spec, "views", "spec"), "spec.views"),
        "size": list(checks.image_size(_get(raw, Spec, "size", "spec"))),
        "batch": _int(raw, Spec, "batch", "spec", 1, 65536),
    }
    if "scale" in raw:  # recorded only when given, so older specs keep their hash
        spec["scale"] = checks.scale(raw["scale"])
    if "profile" in raw:  # renderer profile (docs/renderer.md); recorded only when given (hash)
        from seuwgpu.render.project import check_profile  # the one definition of the profile names

        spec["profile"] = check_profile(raw["profile"], "profile")
    scenes = raw.get("scenes")
    if not isinstance(scenes, list) or not scenes:
        raise SpecError("the spec needs at least one [[scenes]] table")
    spec["scenes"] = []
    held = {}  # scene index -> primitives of a capture or a model file (what a [sizes] n may not exceed)
    for i, s in enumerate(scenes):
        where = f"scenes[{i}]"
        _keys(s, SceneSpec, where)
        if sum(k in s for k in ("scene", "model", "ply")) != 1:
            raise SpecError(f"{where} needs exactly one of scene = NAME or model = FILE (ply = FILE is an alias)")
        out = {
            "sh_degree": _int(s, SceneSpec, "sh_degree", where, 0, 3),
            "seed": _int(s, SceneSpec, "seed", where, 0, SEED_MAX),
        }
        if "scene" in s:
            out["scene"] = checks.one_of(s["scene"], "scene", list_scenes(), f"{where}.scene")
            checks.lod_of_a_model_file(s.get("lod"), s["scene"], f"{where}.lod")
            if is_capture(s["scene"]):
                held[i] = make_scene(s["scene"]).n
                out["n"] = _int({"n": held[i], **s}, SceneSpec, "n", where, 1, held[i])  # all of it by default
            else:
                out["n"] = _int(s, SceneSpec, "n", where, 1)
        else:
            key = "model" if "model" in s else "ply"
            hint = "; a [sizes] table cuts it to subsets"  # refused, not ignored, as --n with --model
            checks.n_of_an_embedded_scene(s.get("n"), s[key], f"{where}.n", hint)
            out["model"] = _spec_file(s, key, where, base_dir)
            out["model_sha256"] = content_hash("model", out["model"])
            lod = checks.lod_level(s["lod"], f"{where}.lod") if "lod" in s else None
            model = _model_file(s, out["model"], where, lod)
            if lod:  # level 0 is the default: the same run as without the key
                out["lod"] = lod
            out["sh_degree"], held[i] = model.sh_degree, model.n
        if "up" in s:
            out["up"] = checks.one_of(s["up"], "up axis", UP_AXES, f"{where}.up")
        if "cameras" in s:
            out["cameras"] = _spec_file(s, "cameras", where, base_dir)
            out["cameras_sha256"] = content_hash("cameras", out["cameras"])
            from seuwgpu.model.cameras import check_one_size, load_cameras, select_views

            views = select_views(load_cameras(out["cameras"]), spec["views"])
            check_one_size(views, f"{where}.cameras {out['cameras']}", "a campaign")
        spec["scenes"].append(out)
    _distinct_labels(spec["scenes"])
    # refused, not ignored, as --size with --cameras; where a scene has no camera file, size applies
    every_scene_has_cameras = all("cameras" in sc for sc in spec["scenes"])
    checks.size_of_orbit_views(raw.get("size"), every_scene_has_cameras, hint="; every scene has one")
    # recorded only when given, so older specs keep their hash (the manifest states the thresholds)
    if "lpips" in raw:
        if not isinstance(raw["lpips"], bool):
            raise SpecError(f"lpips must be true or false, got {raw['lpips']!r}")
        if raw["lpips"]:
            spec["lpips"] = True
    if "outcomes" in raw:
        spec["outcomes"] = _outcomes(raw["outcomes"])
    if "reliability" in raw:
        spec["reliability"] = _reliability(raw["reliability"])
    if "summary" in raw:
        _keys(raw["summary"], SummarySpec, "summary")
        target = _get(raw["summary"], SummarySpec, "target", "summary")
        spec["summary"] = {"target": checks.proportion(target, "summary.target", "0.001")}
    if not any(k in raw for k in ("single", "dose", "sizes")):
        raise SpecError("the spec needs at least one of [single], [dose], [sizes]")
    if "single" in raw:
        t = raw["single"]
        _keys(t, UpsetSpec, "single")
        spec["single"] = _upsets(t, UpsetSpec, "single", spec["size"])
        _no_missing_fields(t, "single", spec["scenes"])
        _fault(t, UpsetSpec, spec["single"], "single")
    if "dose" in raw:
        t = raw["dose"]
        _keys(t, DoseSpec, "dose")
        if "k" in t and ("k_max" in t or "points" in t):
            raise SpecError("dose: give either k = [...] or k_max and points, not both")
        if "k" in t:
            ks = _counts(t, DoseSpec, "k", "dose")
        else:
            ks = dose_levels(_int(t, DoseSpec, "k_max", "dose", 1), _int(t, DoseSpec, "points", "dose", 1, 200))
        spec["dose"] = {
            "precisions": _names(t, DoseSpec, "precisions", "dose", "precision", encoding.PRECISIONS),
            "k": sorted(set(int(k) for k in ks)),
            "repeats": _int(t, DoseSpec, "repeats", "dose", 1),
            "defenses": _names(t, DoseSpec, "defenses", "dose", "defense", DEFENSES),
        }
        for i, sc in enumerate(spec["scenes"]):  # model files: checked when loaded (runner)
            for p in spec["dose"]["precisions"]:
                stored = sc["n"] * n_values(sc["sh_degree"]) * encoding.bits_per_value(p) if "n" in sc else None
                if stored is not None and spec["dose"]["k"][-1] > stored:
                    raise SpecError(
                        f"dose.k = {spec['dose']['k'][-1]} is more upsets than scenes[{i}] stores bits at {p} "
                        f"({sc['n']} primitives x {n_values(sc['sh_degree'])} values x "
                        f"{encoding.bits_per_value(p)} bits = {stored})"
                    )
    if "sizes" in raw:
        t = raw["sizes"]
        _keys(t, SizesSpec, "sizes")
        which = _get(t, SizesSpec, "scenes", "sizes")
        if which == "all":
            which = list(range(len(spec["scenes"])))
        if (
            not isinstance(which, list)
            or not which
            or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(spec["scenes"]) for i in which)
        ):
            raise SpecError(f'sizes.scenes must be "all" or a list of [[scenes]] indices 0..{len(spec["scenes"]) - 1}')
        ns = _counts(t, SizesSpec, "n", "sizes")
        for i in which:
            # a procedural scene is generated at each n; a capture or a model file is cut to a
            # seeded random subset of n (model/fields.py Model.sample), framed as the whole model
            sc = spec["scenes"][i]
            name, have = sc.get("scene") or sc["model"], held.get(i)
            if have is not None and max(ns) > have:
                raise SpecError(f"sizes.n: {name} has {have} primitives; n must not exceed it (got {max(ns)})")
        spec["sizes"] = {"n": sorted(set(ns)), **_upsets(t, SizesSpec, "sizes", spec["size"])}
        _no_missing_fields(t, "sizes", [spec["scenes"][i] for i in which])
        if "scenes" in t:  # recorded only when given (the first scene by default), older hashes stay
            spec["sizes"]["scenes"] = sorted(set(which))
        _fault(t, SizesSpec, spec["sizes"], "sizes")
    return Spec.from_dict(spec)


def default_spec_path() -> Path:
    """The packaged default spec (specs/default.toml: the main job, `seuwgpu demo`), wherever the
    package is installed."""
    from importlib.resources import files

    return Path(str(files("seuwgpu.campaign.specs").joinpath("default.toml")))


def load_spec(path) -> Spec:
    path = Path(path)
    if path.is_dir():
        raise SpecError(f"{path}: is a folder; give the campaign spec file (TOML)")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: not valid TOML ({e})") from None
    except UnicodeDecodeError:
        raise SpecError(f"{path}: not a text file (a campaign spec is TOML)") from None
    except FileNotFoundError:
        raise SpecError(f"{path}: file not found") from None
    except OSError as e:
        raise SpecError(f"{path}: cannot be read ({e.strerror or e})") from None
    return normalize_spec(raw, path.resolve().parent)


__doc__ += "\n" + reference() + "\n"
