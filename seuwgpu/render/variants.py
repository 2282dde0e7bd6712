"""Variant re-compositing stage: shaders/variants.wgsl (entry points `variants` and
`checkpoints`), its host wrapper `VariantCompositing` and its numpy twins.

`variants` re-composites tiles of single-upset variants from a clean frame's kept state
(render/incremental.py keeps it and lists the tiles): the clean tile list with the corrupted
primitive removed and its re-projected record merged in at its depth (`variant_list`), one chunk
per dispatch, from the clean frame's checkpoints to where the changed pixels end. `checkpoints`
is the pass that keeps those checkpoints and every pixel's end (`tile_checkpoints`). Both run the
compositors' per-pixel rule (shaders/blend.wgsl over composite_lanes.wgsl's pixels), so a slab
equals the tile of a full re-render of the variant bit for bit (tests/test_variants.py).
"""

from __future__ import annotations

import numpy as np

from seuwgpu.gpu.constants import CHUNK, PROFILE_CODE, TILE
from seuwgpu.gpu.device import GPU, STORAGE, Readback
from seuwgpu.gpu.kernel import Kernel, Uniforms
from seuwgpu.render.composite import (
    SLAB_BYTES,
    TILE_PIXELS,
    blend_chunk,
    check_chunk,
    merge_chunk,
    unfused_products,
)

OPEN = 0x80000000
"""kv_stop_pos's flag of a pixel that never ends (variants_walk.wgsl `within`)."""


class VariantCompositing:
    """variants.wgsl:variants: re-composite listed (variant, view, tile, primitive) entries into
    slabs (one TILE x TILE vec4 tile each), from a clean frame's kept per-view state with the
    primitive's clean entry removed and its variant record merged in at its depth (ordered by
    (depth bits, index) as the depth sort orders them). Chunk c of every entry's list runs in
    dispatch c, merged into the entry's slab (running state between dispatches), so no workgroup
    walks more than one chunk (llvmpipe's loop limit: docs/renderer.md). When both lists are one
    chunk, a pixel that neither record reaches, or whose reaching records lie behind the record
    it stopped at in the clean frame (`kv_stop_pos`), is copied from the clean image. Owns the
    entries, the slabs and the `Recomp` parameters (one slot per chunk dispatch)."""

    def __init__(self, gpu: GPU, max_entries: int, profile: str = "strict", chunk: int = CHUNK, exact: bool = True):
        self.gpu = gpu
        self.chunk = check_chunk(chunk)
        # exact: the clean frames were binned exactly (render/bin.py), so a variant record is listed
        # where the binning would list it (its footprint reaches the tile), not on its whole rectangle
        constants = {
            "PROFILE": PROFILE_CODE[profile],
            "CHUNK_PAIRS": self.chunk,
            "EXACT_BIN": int(bool(exact)),
            "UNFUSED": int(unfused_products(gpu)),
        }
        self.kernel = Kernel(gpu, "variants", "variants", constants=constants)
        self.params = Uniforms(gpu, self.kernel.struct("Recomp"), 1, "recomp")
        self.entry = self.kernel.struct("VariantEntry")
        self.max_entries = int(max_entries)
        self.entries = gpu.buffer(self.entry.size * self.max_entries, STORAGE, "variants.entries")
        self.slabs = gpu.buffer(SLAB_BYTES * self.max_entries, STORAGE, "variants.slabs")
        # which pixels ended, between chunk dispatches: one u32 per invocation of an entry
        lanes = int(np.prod(self.kernel.workgroup_size))
        self.ended = gpu.buffer(4 * lanes * self.max_entries, STORAGE, "variants.ended")
        # per entry, the tile-local box of the pixels whose rgb bits differ from the clean frame's
        self.changed = gpu.buffer(4 * self.max_entries, STORAGE, "variants.changed")
        self.changed_readback = Readback(gpu, 4 * self.max_entries, "variants.changed.readback")
        self.entry_next = gpu.buffer(4 * self.max_entries, STORAGE, "variants.entry_next")
        self.k_checkpoints = Kernel(gpu, "variants", "checkpoints", constants={**constants, "RECORD": 1})

    def _dispatches(self, entries: dict, longest: int, params: dict, groups) -> list[tuple]:
        """Write the entries (sorted by view) and the `Recomp` slot of every dispatch: one per chunk
        pass and kept view group [v0, v1) (Renderer.kept_view_groups; default all views);
        returns (slot, v0, v1, first entry, end) per dispatch in recording order (queue writes:
        one encode per submission)."""
        views = np.asarray(entries["view"], np.int64)
        n_e = len(views)
        if n_e > self.max_entries:
            raise ValueError(f"{n_e} entries > max_entries={self.max_entries}")
        if np.any(np.diff(views) < 0):
            raise ValueError("entries must be sorted by view")
        if n_e:
            self.gpu.write(self.entries, self.entry.fill(self.entry.zeros(n_e), **entries))
        groups = list(groups or [(0, int(views.max(initial=0)) + 1)])
        spans = [(v0, v1, *np.searchsorted(views, [v0, v1])) for v0, v1 in groups]
        spans = [sp for sp in spans if sp[3] > sp[2]]
        passes = max(1, -(-(int(longest) + 1) // self.chunk))
        slots = passes * max(1, len(spans))
        if slots > self.params.slots:
            self.params = Uniforms(self.gpu, self.params.struct, slots, "recomp")
        params = {**params, "background": np.append(np.asarray(params["background"], np.float32), 0.0)}
        rows = self.params.rows[:slots]
        self.params.struct.fill(rows, **params)
        out = []
        for c in range(passes if spans else 0):
            for i, (v0, v1, e0, e1) in enumerate(spans):
                slot = c * len(spans) + i
                rows[slot]["chunk_pass"], rows[slot]["first_view"] = c, v0
                rows[slot]["first_entry"], rows[slot]["n_entries"] = e0, e1
                out.append((slot, int(v0), int(v1), int(e0), int(e1)))
        self.params.write()
        return out

    def _kept_bindings(self, slot: int, kept: dict, v0: int, v1: int, stride: int, capacity: int) -> dict:
        """What both entry points bind: a dispatch's parameters, the entries and their running
        state, and the clean frame's kept buffers (by their shader names), views [v0, v1) of the
        per-view records (`stride` records a view) and tile lists (`capacity` pairs a view)."""
        per_view = {"kv_isect_prims": 4 * capacity, "kv_isect_box": 4 * capacity}
        per_view.update(kv_proj_xy=8 * stride, kv_proj_conic=16 * stride, kv_proj_rgb=16 * stride)
        views = {name: (kept[name], size * v0, size * (v1 - v0)) for name, size in per_view.items()}
        return {**kept, **views, "rc": self.params.binding(slot), "entries": self.entries}

    def encode(
        self, encoder, entries: dict, kept: dict, variant: dict, clean_image, longest: int, groups=None, **params
    ):
        """Record the slabs of `entries` ({variant, view, tile, prim: int arrays [E]}, sorted by
        view); `longest`: the longest clean tile list (a variant's list holds at most one pair
        more); `groups`: the kept view groups bound one at a time (Renderer.kept_view_groups).
        kept, by the shader's names: the clean frame's per-view `kv_ranges`, `kv_isect_prims` and `kv_isect_box`
        (tile lists and the pairs' pixel boxes, `capacity` apart), `kv_stop_pos` (per pixel, its end
        in its list), `kv_proj_xy`, `kv_proj_conic`, `kv_proj_rgb` (w = depth) of n_prims records per view, and
        its checkpoints (`ckpt_base`, `ckpt_states`) and later chunks' results (`chunk_base`,
        `chunk_states`; both from encode_checkpoints); variant: the variants' `var_xy`,
        `var_conic`, `var_rgb`, `var_rect` (n_variants per
        view); params: width, height, tiles_x, n_tiles, n_prims, n_variants, capacity,
        background, ckpt_every."""
        dispatches = self._dispatches(entries, longest, params, groups)
        for slot, v0, v1, e0, e1 in dispatches:
            self.kernel.dispatch(
                encoder,
                {**self._kept_bindings(slot, kept, v0, v1, params["n_prims"], params["capacity"]), **variant},
                clean_image=clean_image,
                slabs=self.slabs,
                variant_ended=self.ended,
                slab_changed=self.changed,
                entry_next=self.entry_next,
                workgroups=e1 - e0,
            )
        n_e = len(entries["tile"])
        self.changed_readback.encode(encoder, self.changed, 0, 4 * n_e)

    def encode_checkpoints(self, encoder, entries: dict, kept: dict, longest: int, groups=None, **params):
        """Record the checkpoint pass (variants.wgsl:checkpoints) over `entries` ({view, tile},
        sorted by view): the pixels' state at every `ckpt_every` positions of those tiles' clean
        lists into `ckpt_states` (slots from `ckpt_base`), each later chunk's own result into
        `chunk_states` (slots from `chunk_base`) and each pixel's end into `kv_stop_pos`. Same kept
        buffers, groups and params as `encode`."""
        n = len(entries["tile"])
        entries = {"variant": np.zeros(n, np.int64), "prim": np.zeros(n, np.int64), **entries}
        dispatches = self._dispatches(entries, max(int(longest) - 1, 0), params, groups)
        for slot, v0, v1, e0, e1 in dispatches:
            self.k_checkpoints.dispatch(
                encoder,
                self._kept_bindings(slot, kept, v0, v1, params["n_prims"], params["capacity"]),
                slabs=self.slabs,
                variant_ended=self.ended,
                workgroups=e1 - e0,
            )

    def read_changed(self, n: int) -> np.ndarray:
        """[n, 4] int (x0, x1, y0, y1, inclusive, tile-local) of the last submitted encode: the box
        of each entry's pixels inside the frame whose rgb bits differ from the clean frame's;
        x0 > x1 where none does. Waits for that submission only (gpu/device.py Readback)."""
        b = self.changed_readback.read(np.uint32).astype(np.int64)
        if b.size < n:
            raise ValueError(f"the last encode listed {b.size} entries, not {n}")
        b = b[:n]
        return np.stack([b & 0xFF, (b >> 8) & 0xFF, (b >> 16) & 0xFF, b >> 24], axis=1)

    def read_slabs(self, n: int) -> np.ndarray:
        """[n, TILE, TILE, 4] float32 of the last submitted encode."""
        return self.gpu.read(self.slabs, np.float32, 0, SLAB_BYTES * n).reshape(n, TILE, TILE, 4)


def walk_round(chunk: int) -> int:
    """List positions per round of variants_walk.wgsl's walk_list: 1024 (ROUND_MAX) where it divides
    the chunk, else 512, else one batch (TILE * TILE)."""
    chunk = check_chunk(chunk)
    return next(r for r in (4 * TILE_PIXELS, 2 * TILE_PIXELS, TILE_PIXELS) if chunk % r == 0)


CHECKPOINT_EVERY = 1024
"""List positions between the checkpoints of a kept clean frame (render/incremental.py): a
variant's walk starts at most this far before its change. Less is faster and takes more memory
(a TILE x TILE vec4 state, 4 KiB, per checkpoint)."""


def checkpoint_every(chunk: int, want: int = CHECKPOINT_EVERY) -> int:
    """The checkpoint interval nearest `want` that the walk allows: a multiple of its round that
    divides the chunk."""
    chunk, r = check_chunk(chunk), walk_round(chunk)
    every = min(chunk, max(r, int(want) // r * r))
    while chunk % every:
        every -= r
    return every


# ---- numpy twins ---------------------------------------------------------------------------------
def variant_list(clean_ids, keys, prim: int, new_key: int, covers: bool) -> np.ndarray:
    """Twin of the variants entry's list: the clean tile list `clean_ids` (ordered by (key,
    index), `keys` the depth-key bits of every primitive) without `prim`, and with `prim` merged
    back at (new_key, prim) if its variant rectangle `covers` the tile."""
    ids = [int(i) for i in clean_ids if int(i) != prim]
    if covers:
        pos = sum(1 for i in ids if (int(keys[i]), i) < (int(new_key), prim))
        ids.insert(pos, prim)
    return np.array(ids, dtype=np.int64)


def tile_checkpoints(ids, pxs, pys, mx, my, conic, opac, rgb, chunk: int, every: int, profile: str = "strict"):
    """Twin of variants.wgsl:checkpoints for one tile list `ids` at pixel centres (pxs, pys) [P]
    (records as composite.py's composite_tile takes them): ({position: (C [P, 3], T [P])} at every
    checkpoint position (at a chunk's first position the chunks before it merged, elsewhere the
    chunk's own walk so far), ends [P] as kv_stop_pos holds them (the last position each pixel's value
    depends on; for a pixel that never ends OPEN | (1 + the last position of a record blended into
    it, 0 for none))). Only a pixel alive at a position reads that checkpoint."""
    chunk = check_chunk(chunk)
    n, P = len(ids), len(pxs)
    kw = {"profile": profile}
    states, ends, last = {}, np.full(P, -1, np.int64), np.full(P, -1, np.int64)
    C, T, ended = np.zeros((P, 3), np.float32), np.ones(P, np.float32), np.zeros(P, bool)
    for c0 in range(0, n, chunk):
        if c0:
            states[c0] = (C.copy(), T.copy())
        for s in range(c0 + every, min(n, c0 + chunk), every):
            states[s] = blend_chunk(ids[c0:s], pxs, pys, mx, my, conic, opac, rgb, **kw)[:2]
        c, t, stopped, at, took = blend_chunk(
            ids[c0 : c0 + chunk], pxs, pys, mx, my, conic, opac, rgb, where=True, **kw
        )
        last = np.where(~ended & (took >= 0), c0 + took, last)
        before = ended.copy()
        if c0 == 0:
            C, T, ended = c, t, stopped.copy()
        else:
            merge_chunk(C, T, ended, c, t, stopped)
        now = ended & ~before
        ends[now] = np.where(stopped[now], c0 + at[now], min(n, c0 + chunk) - 1)
    ends[~ended] = OPEN | (last[~ended] + 1)
    return states, ends
