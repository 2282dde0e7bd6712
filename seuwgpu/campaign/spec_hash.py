"""What names a run: the spec's hash with the files it names standing for their content, the same
hash without the models' labels (merge tells renamed models apart), and the key of the sites a
spec draws (runs that differ only in what measures no site may share their sites)."""

from __future__ import annotations

import hashlib
import json

from seuwgpu.campaign.spec import scene_label
from seuwgpu.campaign.spec_types import Spec, spec_dict


def spec_hash(spec: Spec | dict) -> str:
    """The run's name: a hash of the normalised spec in which the files it names stand for their
    content (their sha256), so the same spec is the same run whatever folder reaches the files, and
    a changed model or camera file is another run. A model file's label (scene_label: its file or
    INRIA output folder name) is hashed too: records name the scene by it, so the same content
    under another name writes other records, and resuming or merging with them would split one
    model into two scenes."""
    spec = spec_dict(spec)
    keyed = _by_content(spec)
    for sc, k in zip(spec.get("scenes", []), keyed["scenes"]):
        if sc.get("model") and "model_sha256" in sc:
            k["label"] = scene_label(sc)
    return _short_hash(keyed)


def unlabelled_spec_hash(spec: Spec | dict) -> str:
    """The spec hash as seuwgpu computed it before a model file's label was hashed (spec_hash):
    the name of runs made by those versions, whose shards `merge` still joins (checking them for a
    renamed model, which that hash did not tell apart)."""
    return _short_hash(_by_content(spec_dict(spec)))


def renamed_models(a: Spec | dict, b: Spec | dict) -> list[str]:
    """Scenes that two specs read from the same model content under different labels, said for
    an error message (why their hashes differ)."""
    a, b = spec_dict(a), spec_dict(b)
    out = []
    for i, (x, y) in enumerate(zip(a.get("scenes", []), b.get("scenes", []))):
        if x.get("model") and y.get("model") and x.get("model_sha256") == y.get("model_sha256"):
            lx, ly = scene_label(x), scene_label(y)
            if lx != ly:
                out.append(f"scenes[{i}] is the same model named {lx!r} ({x['model']}) and {ly!r} ({y['model']})")
    return out


def _by_content(spec: dict, leave_out=()) -> dict:
    """The spec without the entries `leave_out`, its scenes' files standing for their content."""
    keyed = {k: v for k, v in spec.items() if k not in leave_out}
    keyed["scenes"] = [
        {k: v for k, v in sc.items() if not (k in ("model", "cameras") and f"{k}_sha256" in sc)}
        for sc in spec.get("scenes", [])
    ]
    return keyed


def _short_hash(keyed: dict) -> str:
    return hashlib.sha256(json.dumps(keyed, sort_keys=True).encode()).hexdigest()[:16]


# Spec entries that change no drawn site and no measurement of one: the campaign's label, the
# part size (injection ids, and so every draw, do not depend on it), the analysis inputs, and
# extra metrics recorded beside the others (LPIPS, sort-first region columns).
_NOT_SITES = ("name", "batch", "outcomes", "reliability", "summary", "lpips", "profile")
_NOT_SITES_IN = ("regions",)


def sites_key(spec: Spec | dict) -> str:
    """A hash of what decides a campaign's fault sites and how each is measured (seed, scenes and
    their content, views, size, scale, sections with their precisions, cells, samples, sampling,
    fault model and defenses), defaults spelled out. Two specs of one sites key (and one renderer
    profile: the manifest's, kept apart by the caller) draw the same site for each injection id, so
    their records pooled would count the same sites twice; their spec hashes may differ
    (`spec_hash` covers every entry, as it names the run directory's contents)."""
    keyed = _by_content(spec_dict(spec), _NOT_SITES)
    if keyed.get("scale") == 1.0:
        del keyed["scale"]  # the views' own resolution, as without scale
    for section in ("single", "dose", "sizes"):
        if section in keyed:
            t = {k: v for k, v in keyed[section].items() if k not in _NOT_SITES_IN}
            if section != "dose":
                t.setdefault("fault", "bit")
            if section == "sizes":
                t.setdefault("scenes", [0])
            keyed[section] = t
    return _short_hash(keyed)
