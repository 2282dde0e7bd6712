"""Join the run directories of a campaign's shards into one.

A merge is refused (SpecError, naming the directory) when a shard holds no run, when the shards
come from different specs, when `out` is one of the shards, when `out` already holds a run of
another spec, when two shards disagree on a part (on more than its wall-clock times: a shard run
twice agrees), and when parts of the campaign are missing: `allow_partial` merges what there is
and records the missing parts in the manifest (`missing_parts`: [first id, count] pairs;
`injections_recorded` < `total_injections`). The shards' visible-damage records (`seuwgpu
defenses --visible N --out SHARD`) are copied along (`merge_visible`).
"""

from __future__ import annotations

from pathlib import Path

from seuwgpu.campaign import schema, store
from seuwgpu.campaign.spec import SpecError
from seuwgpu.campaign.spec_hash import renamed_models, spec_hash, unlabelled_spec_hash


def same_records(a: Path, b: Path) -> bool:
    """Two copies of a part hold the same records: the same bytes, or the same values in every
    column but the wall-clock ones (schema.TIMED_COLUMNS): a shard run twice (a re-run after a lost
    node, or a whole run beside its shards) times its renders anew and reproduces everything else."""
    if a.read_bytes() == b.read_bytes():
        return True
    import pandas as pd

    x, y = pd.read_parquet(a), pd.read_parquet(b)
    if list(x.columns) != list(y.columns):
        return False
    timed = [c for c in schema.TIMED_COLUMNS if c in x.columns]
    return x.drop(columns=timed).equals(y.drop(columns=timed))


def merge_visible(out: Path, shard_dirs: list[Path]) -> int:
    """Copy the shards' visible-damage records (store.visible_path: `seuwgpu defenses --visible N
    --out SHARD`) into `out`, so its report shows them; returns the files copied. One measurement
    kept in two shards (the same file name) must hold the same bytes: two differing copies are
    refused, naming both, rather than one silently kept."""
    seen: dict[str, Path] = {}
    for d in [out, *shard_dirs]:
        for f in sorted(store.visible_path(d, "*").parent.glob("*.parquet")):
            if f.name in seen:
                if seen[f.name].resolve() != f.resolve() and seen[f.name].read_bytes() != f.read_bytes():
                    raise SpecError(
                        f"visible-damage records {f.name} differ between {seen[f.name].parent.parent} and {d}"
                    )
                continue
            seen[f.name] = f
    copied = 0
    for name, f in seen.items():
        dst = store.visible_path(out, name.removesuffix(".parquet"))
        if f.resolve() != dst.resolve():
            dst.parent.mkdir(parents=True, exist_ok=True)
            store.atomic_write(dst, f.read_bytes())
            copied += 1
    return copied


def merge(out: Path, shard_dirs: list[Path], allow_partial: bool = False) -> int:
    """Join shard run directories (same spec) into `out`; returns the number of parts merged."""
    out = Path(out)
    if not shard_dirs:
        raise SpecError("merge needs at least one shard directory")
    manifests = []
    for d in shard_dirs:
        if not Path(d).is_dir():
            raise SpecError(f"{d}: no such run directory")
        m = store.read_manifest(d)
        if m is None or "spec" not in m:
            raise SpecError(f"{d}: not a run directory (no {store.MANIFEST} with a spec)")
        manifests.append(m)
        if out.resolve() == Path(d).resolve():
            raise SpecError(f"--out {out} is one of the shards being merged; merge into a new directory")
    hashes = {m["spec_hash"] for m in manifests}
    renamed = [r for m in manifests[1:] for r in renamed_models(manifests[0]["spec"], m["spec"])]
    why = f" ({'; '.join(dict.fromkeys(renamed))}: records name a model by its file name)" if renamed else ""
    if len(hashes) != 1:
        by = ", ".join(f"{d} ({m['spec_hash']})" for d, m in zip(shard_dirs, manifests))
        raise SpecError(f"the shards come from different specs: {by}{why}")
    spec = manifests[0]["spec"]
    if spec_hash(spec) != manifests[0]["spec_hash"]:
        if unlabelled_spec_hash(spec) != manifests[0]["spec_hash"]:
            raise SpecError(f"{shard_dirs[0]}: its manifest's spec does not match its spec hash (edited by hand?)")
        if renamed:  # shards of an earlier seuwgpu, whose hash left the model's file name out
            raise SpecError(f"the shards come from different specs{why}")
    expected = store.expected_parts(spec)
    with store.lock(out):
        existing = store.read_manifest(out)
        if existing is not None and existing.get("spec_hash") != manifests[0]["spec_hash"]:
            raise SpecError(
                f"--out {out} already holds a run of another spec (hash {existing.get('spec_hash')}); "
                "merge into a new directory"
            )
        store.records_dir(out).mkdir(parents=True, exist_ok=True)
        found = {}
        for d in [out, *shard_dirs]:  # parts already merged into out count, and must agree
            for p in store.record_parts(d, manifests[0]):
                key = store.parse_part_name(p.name)
                if store.part_rows(p) != expected[key]:
                    continue  # an empty or damaged part: as good as missing
                if key in found:
                    if found[key].resolve() != p.resolve() and not same_records(p, found[key]):
                        raise SpecError(f"part {p.name} differs between {found[key].parent.parent} and {d}")
                    continue
                found[key] = p
        missing = sorted(set(expected) - set(found))
        if missing and not allow_partial:
            n_missing = sum(c for _, c in missing)
            a, c = missing[0]
            raise SpecError(
                f"the shards hold {len(found)} of the campaign's {len(expected)} parts: {n_missing:,} injections "
                f"are missing (first: ids {a}..{a + c - 1}); run the missing shards, or merge with --allow-partial"
            )
        merge_visible(out, shard_dirs)
        for key, p in found.items():
            dst = store.part_path(out, *key)
            if p.resolve() != dst.resolve():
                store.atomic_write(dst, p.read_bytes())
        m = dict(manifests[0])
        m["merged_from"] = [str(d) for d in shard_dirs]
        m["injections_recorded"] = sum(c for _, c in found)
        if missing:
            m["missing_parts"] = [list(k) for k in missing]
        else:
            m.pop("missing_parts", None)
        store.write_manifest(out, m)
    return len(found)
