"""GPU exclusive prefix sum and stable LSD radix sort (shaders/scan.wgsl, shaders/radix_sort.wgsl).

The renderer sorts primitives by depth and tile intersections by tile inside the one command
encoder that records a whole frame (and K views), so these classes only *encode* compute passes:
no submit, no readback. A count may live on the GPU (the intersection total written by a scan):
a one-thread plan kernel turns it into indirect dispatch arguments.

Portability choices: reduce-then-scan everywhere (decoupled look-back / OneSweep rely on
forward-progress guarantees that lavapipe and some GPUs do not give), 256 invocations and under
16 KiB of workgroup memory per workgroup (WebGPU defaults), at most 8 storage buffers per stage,
and arrays larger than one storage binding (128 MiB on lavapipe and WebGPU defaults) processed in
chunks, so a sort holds up to two bindings' worth of elements (64 Mi on such devices).

Speed on lavapipe (what CI and the development machines run): it executes 8 invocations per SIMD
instruction but every memory access lane by lane, and a workgroup barrier costs ~5 us (it runs a
workgroup as 32 coroutines). Hence vec4 loads, per-thread counters in registers, a barrier-free
scatter on CPU adapters (GPUs take a fused one with two barriers: FUSED_MAX_BLOCKS), and 64
elements per thread on CPU adapters (16 on GPUs, which need many workgroups).
Buffers passed in must therefore have sizes that are multiples of 16 bytes (GPU.buffer's are).

Per-call parameters (counts, digit shifts) never go through `queue.write_buffer` into a shared
buffer: queue writes land before the whole submission, so two encoded calls would see the same
value. They live in small immutable buffers, one per distinct value, cached, or in GPU-written
plan buffers that each call rewrites on the GPU timeline.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from seuwgpu.gpu.constants import WG
from seuwgpu.gpu.device import GPU, INDIRECT, STORAGE, UNIFORM
from seuwgpu.gpu.kernel import Kernel, Uniforms

# Word positions in the GPU-written plan buffers, compiled into the shaders as header constants.
# scan.wgsl: [0, 4) element count per level, [PS_TOTAL] grand total, [PS_ARGS + 3k ..) indirect
# arguments of dispatch slot k.
SCAN_PLAN = {"PS_TOTAL": 4, "PS_ARGS": 8}
# radix_sort.wgsl: [0] count, [1] blocks, [RS_HIST_COUNT] 16 * blocks (the histogram scan's count),
# [RS_ARGS + 3c ..) indirect arguments of chunk c; RS_OFFS: vec4 header of the offsets buffer.
RADIX_PLAN = {"RS_HIST_COUNT": 2, "RS_ARGS": 4, "RS_OFFS": 16}
_OFFS_HEADER = 16 * RADIX_PLAN["RS_OFFS"]  # bytes
if WG != 256:  # both shaders scan a workgroup's values as 16 groups of 16
    raise ImportError(f"scan.wgsl and radix_sort.wgsl need 256-thread workgroups, constants.WG is {WG}")
_CACHE_SIZE = 512
# On a GPU, a sort whose histogram has at most this many blocks (1 Mi pairs at 16 per thread)
# scatters with rs_scatter's RS_FUSED variant, which computes its bases from the unscanned
# histogram: no PrefixSum between upsweep and scatter, so 2 dependent dispatches a pass instead of
# 3, and 17 instead of 26 for a 32-bit sort (a GPU waits on each; Python spends ~8 us recording
# each). Each scatter thread then reads at most 16 histogram words (the reads grow as blocks
# squared: 256 keeps them at 4 MiB a pass). CPU adapters keep the scanned path: there the fused
# scatter's two barriers cost more than the recording it saves (docs/renderer.md "Measurements").
FUSED_MAX_BLOCKS = 256


def _ceil_div(a: int, b: int) -> int:
    return -(-int(a) // int(b))


class _LRU(OrderedDict):
    """Bounded cache of small immutable parameter buffers (counts, plan arguments)."""

    def get_or(self, key, make):
        if key in self:
            self.move_to_end(key)
            return self[key]
        value = self[key] = make()
        if len(self) > _CACHE_SIZE:
            self.popitem(last=False)
        return value


def _per_thread(gpu: GPU, per: int | None) -> int:
    """Elements per thread. Lavapipe runs a workgroup's 256 invocations as 32 coroutines and a
    workgroup barrier costs ~5 us there, more than the work of a 4096-element block, so CPU
    adapters get long runs (few workgroups); GPUs get 16 (enough workgroups to fill the device)."""
    if per is None:
        per = 64 if gpu.is_cpu else 16
    per = int(per)
    if per % 4 or not 4 <= per <= 252:
        raise ValueError(f"elements per thread must be a multiple of 4 in [4, 252], got {per}")
    return per


def _chunk_elems(gpu: GPU, max_binding: int | None, block: int) -> int:
    """Elements per chunk: the largest multiple of `block` whose bytes fit one storage binding.
    `max_binding` (bytes) lowers the device limit; the tests use it to exercise chunking."""
    limit = gpu.max_binding if max_binding is None else min(int(max_binding), gpu.max_binding)
    s = (limit // 4) // block * block
    if s < block:
        raise ValueError(f"storage bindings of {limit} bytes are too small for a {block}-element block")
    return s


def _is_int(count) -> bool:
    return isinstance(count, (int, np.integer)) and not isinstance(count, bool)


class _Counts:
    """Where a kernel reads its element count: a caller's (buffer, byte_offset), or, for a python
    int, a cached immutable buffer holding it (so encoded-but-unsubmitted calls cannot clash)."""

    def __init__(self, gpu: GPU):
        self.gpu = gpu
        self.align = int(gpu.limits.get("min-storage-buffer-offset-alignment", 256))
        self._consts = _LRU()

    def binding(self, count) -> tuple:
        """-> ((buffer, offset, size) to bind, word index of the count inside that range)."""
        if _is_int(count):
            buf = self._consts.get_or(
                int(count), lambda: self.gpu.upload(np.array([int(count)], np.uint32), label="sort.count")
            )
            return (buf, 0, 16), 0
        buf, off = count
        off = int(off)
        if off % 4 or off < 0 or off + 4 > buf.size:
            raise ValueError(f"count offset {off} is not a valid u32 position in a {buf.size}-byte buffer")
        aoff = off - off % self.align
        return (buf, aoff, off + 4 - aoff), (off - aoff) // 4


class _PlanArgs:
    """Immutable uniform buffers of a plan kernel's arguments, one per distinct value."""

    def __init__(self, gpu: GPU, struct):
        self.gpu, self.struct = gpu, struct
        self._bufs = _LRU()

    def get(self, **values):
        key = tuple(values.items())
        return self._bufs.get_or(
            key, lambda: self.gpu.upload(self.struct.pack(**values), UNIFORM, f"{self.struct.name}")
        )


def _range(buf, offset: int, size: int) -> tuple:
    """A binding of at most `size` bytes of `buf` from `offset` (None when nothing is left)."""
    size = min(int(size), (int(buf.size) - int(offset)) // 4 * 4)
    return (buf, int(offset), size) if size > 0 else None


class PrefixSum:
    """Exclusive scan of u32 (reduce-then-scan, WG x `per` elements per workgroup, multi-level).

    `encode(encoder, src, dst, count, total=None)` writes dst[i] = src[0] + ... + src[i-1] for
    i < count (u32, wrapping). `src` may be `dst` (in place). `count` is a python int or
    (buffer, byte_offset) of a u32 on the GPU, clamped to the capacity and the buffer sizes.
    `total=(buffer, byte_offset)` also stores the sum of the `count` elements there (a 4-byte
    copy, so that buffer needs COPY_DST). Elements of dst at or past count keep their values.
    src and dst sizes must be multiples of 16 bytes. Twin: `exclusive_scan`.
    """

    def __init__(
        self,
        gpu: GPU,
        capacity: int,
        *,
        per: int | None = None,
        max_binding: int | None = None,
        max_groups_x: int | None = None,
    ):
        """`per`: elements per thread (default by adapter type). `max_binding` (bytes) and
        `max_groups_x` lower the binding size and the workgroups per dispatch row below the
        device's, for tests of the chunked and 2-D dispatch paths."""
        self.gpu = gpu
        self.capacity = max(1, int(capacity))
        if self.capacity >= 2**31:
            raise ValueError(f"PrefixSum capacity {capacity} exceeds 2^31 - 1 elements")
        self.per = _per_thread(gpu, per)
        self.block = block = WG * self.per
        self.chunk = _chunk_elems(gpu, max_binding, block)
        caps = [self.capacity]
        while caps[-1] > block:
            caps.append(_ceil_div(caps[-1], block))
        self.caps = caps
        self.levels = len(caps) - 1
        if self.levels > 3:
            raise ValueError(f"PrefixSum capacity {capacity} needs more than 3 levels")
        self._sums = [None] + [gpu.buffer(4 * c, label=f"scan.sums{l}") for l, c in enumerate(caps[1:], 1)]

        consts = {"PS_PER": self.per}
        self._k = {
            e: Kernel(gpu, "scan", e, constants=consts, defines=SCAN_PLAN, label="prefix_sum")
            for e in ("ps_reduce", "ps_downsweep", "ps_downsweep_inplace", "ps_top", "ps_top_inplace")
        }
        plan_consts = dict(consts, PS_MAX_X=max_groups_x) if max_groups_x else consts
        self._k["ps_plan_main"] = Kernel(
            gpu, "scan", "ps_plan_main", constants=plan_consts, defines=SCAN_PLAN, label="prefix_sum"
        )

        # One uniform slot per (level, chunk) dispatch, in the order ps_plan_main numbers its
        # indirect arguments, then one for the top level.
        bpc = self.chunk // block
        self._slots: list[list[int]] = []
        rows = []
        for lev in range(self.levels):
            ids = []
            for c in range(_ceil_div(caps[lev], self.chunk)):
                ids.append(len(rows))
                rows.append((lev, c * bpc, bpc))
            self._slots.append(ids)
        self._nargs = len(rows)
        self._top_slot = len(rows)
        rows.append((self.levels, 0, 1))
        self._pass = Uniforms(gpu, self._k["ps_reduce"].struct("PsPass"), len(rows), "scan.pass")
        level, block0, bpc_ = np.array(rows).T
        self._pass.struct.fill(self._pass.rows, level=level, block0=block0, bpc=bpc_)
        self._pass.write()
        self.plan = gpu.buffer(4 * (SCAN_PLAN["PS_ARGS"] + 3 * max(1, self._nargs)), INDIRECT, "scan.plan")
        self._counts = _Counts(gpu)
        self._plan_args = _PlanArgs(gpu, self._k["ps_plan_main"].struct("PsPlanArgs"))

    # ---- encoding ------------------------------------------------------------------------------
    def limit(self, src, dst) -> int:
        """Largest count these buffers can hold."""
        return int(min(self.capacity, src.size // 4, dst.size // 4))

    def encode(self, encoder, src, dst, count, total=None):
        """Exclusive scan of `count` u32 of `src` into `dst` (`src is dst` allowed); with
        total=(buffer, byte_offset) the sum of the count elements is also written there."""
        if src.size % 16 or dst.size % 16:
            raise ValueError(
                "PrefixSum reads vec4: src and dst sizes must be multiples of 16 bytes (GPU.buffer rounds sizes up)"
            )
        limit = self.limit(src, dst)
        if _is_int(count) and not 0 <= int(count) <= limit:
            raise ValueError(f"count {count} outside [0, {limit}] (capacity / buffer sizes)")
        cpass = encoder.begin_compute_pass(label="prefix_sum")
        self.encode_plan(cpass, count, limit)
        self.encode_scan(cpass, src, dst, limit)
        cpass.end()
        if total is not None:
            buf, off = total
            encoder.copy_buffer_to_buffer(self.plan, 4 * SCAN_PLAN["PS_TOTAL"], buf, int(off), 4)

    def encode_plan(self, cpass, count, limit: int):
        """Dispatch the plan kernel (inside the caller's compute pass): count -> level counts and
        indirect arguments for the next `encode_scan` calls."""
        rng, word = self._counts.binding(count)
        pargs = self._plan_args.get(word=word, limit=int(limit), capacity=self.capacity, chunk=self.chunk)
        self._k["ps_plan_main"].record(cpass, ps_plan_w=self.plan, ps_count=rng, ps_pargs=pargs, workgroups=(1, 1, 1))

    def encode_scan(self, cpass, src, dst, limit: int):
        """Dispatch the scan itself (after `encode_plan`, inside the caller's compute pass)."""
        S4 = 4 * self.chunk
        arrays = [(src, dst)] + [(b, b) for b in self._sums[1:]]

        def chunks(lev):
            for k, c in zip(self._slots[lev], range(len(self._slots[lev]))):
                if lev == 0 and c * self.chunk >= limit:
                    break
                yield k, c

        def dispatch(entry, k, entries):
            entries["ps_pass"] = self._pass.binding(k)
            if k == self._top_slot:
                self._k[entry].record(cpass, entries, workgroups=(1, 1, 1))
            else:
                self._k[entry].record(cpass, entries, indirect=(self.plan, 4 * (SCAN_PLAN["PS_ARGS"] + 3 * k)))

        for lev in range(self.levels):
            a, _ = arrays[lev]
            for k, c in chunks(lev):
                dispatch(
                    "ps_reduce",
                    k,
                    {"ps_src": _range(a, c * S4, S4), "ps_sums": self._sums[lev + 1], "ps_plan": self.plan},
                )
        a, b = arrays[self.levels]
        if a is b:
            dispatch("ps_top_inplace", self._top_slot, {"ps_dst": _range(b, 0, S4), "ps_plan_w": self.plan})
        else:
            dispatch(
                "ps_top",
                self._top_slot,
                {"ps_src": _range(a, 0, S4), "ps_dst": _range(b, 0, S4), "ps_plan_w": self.plan},
            )
        for lev in reversed(range(self.levels)):
            a, b = arrays[lev]
            offs = self._sums[lev + 1]
            for k, c in chunks(lev):
                if a is b:
                    dispatch(
                        "ps_downsweep_inplace",
                        k,
                        {"ps_dst": _range(b, c * S4, S4), "ps_offs": offs, "ps_plan": self.plan},
                    )
                else:
                    dispatch(
                        "ps_downsweep",
                        k,
                        {
                            "ps_src": _range(a, c * S4, S4),
                            "ps_dst": _range(b, c * S4, S4),
                            "ps_offs": offs,
                            "ps_plan": self.plan,
                        },
                    )


class RadixSort:
    """Stable ascending LSD radix sort of (u32 key, u32 value) pairs, 4 bits per pass.

    `encode(encoder, keys, values, count, key_bits=32)` sorts the first `count` pairs by the low
    `key_bits` bits of the keys (higher bits are ignored and kept), equal keys in input order,
    result in place in `keys`/`values`; elements at or past count are not touched. `count` is a
    python int or (buffer, byte_offset) of a u32 on the GPU (clamped to the capacity and to the
    buffer sizes; the dispatches are then indirect). Needs ceil(key_bits / 4) passes of two
    dispatches when fused (see FUSED_MAX_BLOCKS), else of upsweep, the PrefixSum's one to three
    and scatter, plus one plan dispatch per sort (two when scanned); an odd
    number of passes costs one extra copy into the internal buffers first. `keys` and `values`
    must be distinct buffers whose sizes are multiples of 16 bytes. Twin: `stable_sort`.

    Holds two internal buffers of `capacity` pairs, a histogram of 16 words per block and 32
    bytes of per-thread offsets per thread (0.5 byte per pair at 64 per thread, 2 at 16).
    Capacity is limited to two storage bindings (64 Mi pairs where bindings are 128 MiB).
    """

    def __init__(
        self,
        gpu: GPU,
        capacity: int,
        *,
        per: int | None = None,
        max_binding: int | None = None,
        max_groups_x: int | None = None,
        fused_max_blocks: int | None = None,
    ):
        """`per`, `max_binding` and `max_groups_x`: as for PrefixSum. `fused_max_blocks`: the
        largest histogram (in blocks, at full capacity) scattered without a PrefixSum (None: the
        adapter's default, FUSED_MAX_BLOCKS on GPUs and 0, never, on CPU adapters; the tests set
        it to reach both paths)."""
        self.gpu = gpu
        self.capacity = max(1, int(capacity))
        self.per = _per_thread(gpu, per)
        # Per-thread offsets (32 bytes per thread) must fit one binding: lengthen runs if not.
        binding = gpu.max_binding if max_binding is None else min(int(max_binding), gpu.max_binding)
        while _OFFS_HEADER + 32 * WG * _ceil_div(self.capacity, WG * self.per) > binding and self.per * 2 <= 252:
            self.per *= 2
        self.block = block = WG * self.per
        self.chunk = _chunk_elems(gpu, max_binding, block)
        self.nch = _ceil_div(self.capacity, self.chunk)
        if self.nch > 2 or self.capacity >= 2**31:
            raise ValueError(
                f"RadixSort capacity {capacity} exceeds two storage bindings ({2 * self.chunk} elements) on this device"
            )
        self.bpc = self.chunk // block
        nb = _ceil_div(self.capacity, block)
        self.keys_tmp = gpu.buffer(4 * self.capacity, STORAGE, "sort.keys_tmp")
        self.vals_tmp = gpu.buffer(4 * self.capacity, STORAGE, "sort.vals_tmp")
        self.hist = gpu.buffer(4 * 16 * nb, STORAGE, "sort.hist")
        self.offs = gpu.buffer(_OFFS_HEADER + 32 * WG * nb, STORAGE, "sort.offs")
        if self.offs.size > binding:
            raise ValueError(f"RadixSort capacity {capacity} too large for this device's storage bindings")
        self.plan = gpu.buffer(4 * (RADIX_PLAN["RS_ARGS"] + 3 * self.nch), INDIRECT, "sort.plan")
        self._dummy = gpu.buffer(16, STORAGE, "sort.dummy")
        # Decided by the capacity, so that every count the sort may be given takes the same path.
        if fused_max_blocks is None:
            fused_max_blocks = 0 if gpu.is_cpu else FUSED_MAX_BLOCKS
        self.fused = nb <= int(fused_max_blocks)
        self.scan = (
            None if self.fused else PrefixSum(gpu, 16 * nb, per=per, max_binding=max_binding, max_groups_x=max_groups_x)
        )

        consts = {"RS_PER": self.per}

        def kernel(entry, constants=consts):
            return Kernel(gpu, "radix_sort", entry, constants=constants, defines=RADIX_PLAN, label="radix_sort")

        self._k = {e: kernel(e) for e in ("rs_upsweep", "rs_copy")}
        self._k["rs_plan_main"] = kernel(
            "rs_plan_main", dict(consts, RS_MAX_X=max_groups_x) if max_groups_x else consts
        )
        # The second output half is compiled in only when a sort spans two bindings.
        scatter = dict(consts, RS_FUSED=int(self.fused))
        self._k["rs_scatter"] = kernel("rs_scatter", dict(scatter, RS_TWO_PARTS=1) if self.nch > 1 else scatter)
        # Uniform slot per (pass, digit width, chunk).
        self._pass = Uniforms(gpu, self._k["rs_upsweep"].struct("RsPass"), 8 * 4 * self.nch, "sort.pass")
        p, m, c = (a.reshape(-1) for a in np.meshgrid(np.arange(8), np.arange(4), np.arange(self.nch), indexing="ij"))
        self._pass.struct.fill(
            self._pass.rows, shift=4 * p, mask=(1 << (m + 1)) - 1, block0=c * self.bpc, bpc=self.bpc, split=self.chunk
        )
        self._pass.write()
        self._counts = _Counts(gpu)
        self._plan_args = _PlanArgs(gpu, self._k["rs_plan_main"].struct("RsPlanArgs"))

    def limit(self, keys, values) -> int:
        """Largest count these buffers can hold."""
        return int(min(self.capacity, keys.size // 4, values.size // 4))

    def encode(self, encoder, keys, values, count, key_bits: int = 32):
        """Stable ascending sort of the first `count` (key, value) pairs by the low `key_bits` bits
        of the keys, in place; count: python int or (buffer, byte_offset) of a GPU u32."""
        key_bits = int(key_bits)
        if not 0 <= key_bits <= 32:
            raise ValueError(f"key_bits must be in [0, 32], got {key_bits}")
        if keys is values:
            raise ValueError("keys and values must be distinct buffers")
        if keys.size % 16 or values.size % 16:
            raise ValueError(
                "RadixSort reads vec4: key and value buffer sizes must be multiples of 16 bytes "
                "(GPU.buffer rounds sizes up)"
            )
        limit = self.limit(keys, values)
        if _is_int(count):
            if not 0 <= int(count) <= limit:
                raise ValueError(f"count {count} outside [0, {limit}] (capacity / buffer sizes)")
            if int(count) <= 1:
                return
        passes = _ceil_div(key_bits, 4)
        if passes == 0:
            return
        cpass = encoder.begin_compute_pass(label="radix_sort")
        self._encode_plan(cpass, count, limit)
        if self.scan is not None:
            self.scan.encode_plan(cpass, (self.plan, 4 * RADIX_PLAN["RS_HIST_COUNT"]), self.scan.capacity)
        chunks = [c for c in range(self.nch) if c * self.chunk < limit]
        # each array's chunk-c input range and its two output halves, computed once per call
        io = {b: ([self._in(b, c) for c in chunks], self._out(b)) for b in (keys, values, self.keys_tmp, self.vals_tmp)}
        user, tmp = (keys, values), (self.keys_tmp, self.vals_tmp)
        if passes % 2:
            for c in chunks:
                bindings = {"rs_keys_in": io[keys][0][c], "rs_vals_in": io[values][0][c], "rs_plan": self.plan}
                bindings["rs_keys_out4"], bindings["rs_vals_out4"] = io[tmp[0]][0][c], io[tmp[1]][0][c]
                self._dispatch(cpass, "rs_copy", 0, 3, c, bindings)
            cur, oth = tmp, user
        else:
            cur, oth = user, tmp
        for p in range(passes):
            m = min(4, key_bits - 4 * p) - 1
            for c in chunks:
                self._dispatch(
                    cpass,
                    "rs_upsweep",
                    p,
                    m,
                    c,
                    {
                        "rs_keys_in": io[cur[0]][0][c],
                        "rs_hist_w": self.hist,
                        "rs_plan": self.plan,
                        "rs_offs_w": self.offs,
                    },
                )
            if self.scan is not None:
                self.scan.encode_scan(cpass, self.hist, self.hist, self.scan.capacity)
            (klo, khi), (vlo, vhi) = io[oth[0]][1], io[oth[1]][1]
            for c in chunks:
                bindings = {
                    "rs_keys_in": io[cur[0]][0][c],
                    "rs_vals_in": io[cur[1]][0][c],
                    "rs_keys_lo": klo,
                    "rs_keys_hi": khi,
                    "rs_vals_lo": vlo,
                    "rs_vals_hi": vhi,
                    "rs_hist": self.hist,
                    "rs_offs": self.offs,
                }
                self._dispatch(cpass, "rs_scatter", p, m, c, bindings)
            cur, oth = oth, cur
        cpass.end()

    # ---- internals -----------------------------------------------------------------------------
    def _dispatch(self, cpass, entry, p, m, c, bindings):
        bindings["rs_pass"] = self._pass.binding((p * 4 + m) * self.nch + c)
        self._k[entry].record(cpass, bindings, indirect=(self.plan, 4 * (RADIX_PLAN["RS_ARGS"] + 3 * c)))

    def _encode_plan(self, cpass, count, limit):
        rng, word = self._counts.binding(count)
        pargs = self._plan_args.get(word=word, limit=int(limit), chunk=self.chunk, nch=self.nch)
        self._k["rs_plan_main"].record(
            cpass,
            rs_plan_w=self.plan,
            rs_count=rng,
            rs_pargs=pargs,
            rs_offs_w=(self.offs, 0, _OFFS_HEADER),
            workgroups=(1, 1, 1),
        )

    def _in(self, buf, c):
        return _range(buf, c * 4 * self.chunk, 4 * self.chunk)

    def _out(self, buf):
        """The two halves of an output array: [0, split) and [split, 2 split)."""
        S4 = 4 * self.chunk
        return _range(buf, 0, S4), (_range(buf, S4, S4) or self._dummy)


# ---- numpy twins -----------------------------------------------------------------------------------
def exclusive_scan(x: np.ndarray) -> np.ndarray:
    """Twin of PrefixSum: the exclusive prefix sum of u32, wrapping."""
    x = np.asarray(x, np.uint32)
    return ((np.cumsum(x.astype(np.uint64)) - x) % 2**32).astype(np.uint32)


def stable_sort(keys: np.ndarray, values: np.ndarray, key_bits: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Twin of RadixSort: pairs ordered by the low `key_bits` bits of the keys, ties in input order."""
    keys = np.asarray(keys, np.uint32)
    mask = np.uint32(0xFFFFFFFF if key_bits >= 32 else (1 << key_bits) - 1)
    order = np.argsort(keys & mask, kind="stable")
    return keys[order], np.asarray(values)[order]
