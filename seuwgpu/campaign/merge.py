"""Join the run directories of a campaign's shards into one."""

from __future__ import annotations

import shutil
from pathlib import Path

from seuwgpu.campaign import store
from seuwgpu.campaign.spec import SpecError


def merge(out: Path, shard_dirs: list[Path]) -> int:
    """Join shard run directories (same spec) into one; refuses mixed specs and duplicates."""
    out = Path(out)
    manifests = [store.read_manifest(d) for d in shard_dirs]
    for d, m in zip(shard_dirs, manifests):
        if m is None:
            raise FileNotFoundError(store.manifest_path(d))
    hashes = {m["spec_hash"] for m in manifests}
    if len(hashes) != 1:
        raise SpecError(f"shards come from different specs: {sorted(hashes)}")
    store.records_dir(out).mkdir(parents=True, exist_ok=True)
    seen = {}
    for d in shard_dirs:
        for p in store.part_files(d):
            if p.name in seen:
                if p.read_bytes() != seen[p.name].read_bytes():
                    raise SpecError(f"part {p.name} differs between {seen[p.name].parent.parent} and {d}")
                continue
            seen[p.name] = p
            shutil.copyfile(p, store.records_dir(out) / p.name)
    m = dict(manifests[0])
    m["merged_from"] = [str(d) for d in shard_dirs]
    store.write_manifest(out, m)
    return len(seen)
