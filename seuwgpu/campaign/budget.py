"""A campaign's memory, checked before its run directory is touched (model/budget.py has the
per-render estimates): every embedded scene it generates, and the bookkeeping of its parts (the
runner lists every block of its shard, and a resume checks each part it finds), so that
`samples = 1000000000000` is refused at once with a size that fits instead of a MemoryError
after minutes."""

from __future__ import annotations

from seuwgpu.campaign.sampling import enumerate_contexts
from seuwgpu.campaign.spec_types import Spec
from seuwgpu.errors import TooBig
from seuwgpu.model.budget import HOST_SHARE, available_host_bytes, available_text, check_model, gb

PART_BYTES = 400  # host bytes per part of the block list, the parts found and the expected set


def check_campaign(spec: Spec):
    """Raise TooBig when the spec's scenes or its part bookkeeping would not fit in host memory."""
    for i, sc in enumerate(spec.scenes):
        if sc.scene and sc.n:
            check_model(sc.n, sc.sh_degree, f"scenes[{i}].n =")
    if spec.sizes is not None:
        check_model(max(spec.sizes.n), spec.scenes[0].sh_degree, "sizes.n =")
    ctxs = enumerate_contexts(spec)
    batch = spec.batch
    parts = sum(-(-c.count // batch) for c in ctxs)
    need, have = parts * PART_BYTES, HOST_SHARE * available_host_bytes()
    if need <= have:
        return
    total = sum(c.count for c in ctxs)
    hint = ""
    for key in ("single", "sizes"):
        section = getattr(spec, key)
        if section is not None:
            hint = f"; at most about samples = {max(1, int(section.samples * have / need)):,} in [{key}] fits"
            break
    raise TooBig(
        f"the campaign has {total:,} injections in {parts:,} parts of batch = {batch}: listing them alone needs "
        f"about {gb(need)} of host memory, and {available_text(have)}{hint} (or raise batch)"
    )
