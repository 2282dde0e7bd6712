"""GPU prefix sum and stable radix sort (seuwgpu/gpu/sort.py) against numpy.

Stability is checked with values = input index: a stable sort's values are exactly
np.argsort(keys, kind="stable"). Small `max_binding` / `max_groups_x` force the chunked-binding
and 2-D dispatch paths that real sizes (tens of millions) would take, at test-friendly sizes.
"""

import numpy as np
import pytest

from seuwgpu.gpu.sort import FUSED_MAX_BLOCKS, WG, PrefixSum, RadixSort

SENTINEL = 0xDEADBEEF
PERS = (16, 64)  # elements per thread: the GPU and the CPU-adapter defaults
# RadixSort's fused_max_blocks: a GPU's (these sizes scatter from the unscanned histogram) and 0 (a
# PrefixSum between upsweep and scatter: CPU adapters, and histograms over FUSED_MAX_BLOCKS blocks).
FUSED = {"fused": {"fused_max_blocks": FUSED_MAX_BLOCKS}, "scanned": {"fused_max_blocks": 0}}


def run(gpu, *encodes):
    enc = gpu.device.create_command_encoder()
    for f in encodes:
        f(enc)
    gpu.submit(enc)


def exclusive(x):
    return ((np.cumsum(x.astype(np.uint64)) - x) % 2**32).astype(np.uint32)


def padded(gpu, a, n_total, fill=SENTINEL):
    """Buffer holding `a` followed by `fill` up to n_total elements."""
    full = np.full(n_total, fill, np.uint32)
    full[: len(a)] = a
    return gpu.upload(full)


def check_sort(gpu, keys_in, vals_in, keys_buf, vals_buf, n, key_bits):
    mask = np.uint32(0xFFFFFFFF if key_bits >= 32 else (1 << key_bits) - 1)
    order = np.argsort(keys_in[:n] & mask, kind="stable")
    k, v = gpu.read(keys_buf), gpu.read(vals_buf)
    np.testing.assert_array_equal(v[:n], vals_in[:n][order])
    np.testing.assert_array_equal(k[:n], keys_in[:n][order])
    # past count: untouched
    np.testing.assert_array_equal(k[n : len(keys_in)], keys_in[n:])
    np.testing.assert_array_equal(v[n : len(vals_in)], vals_in[n:])


# ---- prefix sum ------------------------------------------------------------------------------
@pytest.mark.parametrize("per", PERS)
@pytest.mark.parametrize("blocks,extra", [(0, 0), (0, 1), (0, 7), (1, -1), (1, 0), (1, 1), (17, 1234)])
def test_scan_matches_cumsum_with_total(gpu, per, blocks, extra):
    n = blocks * WG * per + extra
    rng = np.random.default_rng(n)
    x = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)  # sums wrap like u32
    ps = PrefixSum(gpu, max(n, 1), per=per)
    src = padded(gpu, x, n + 5)
    dst = padded(gpu, np.zeros(0, np.uint32), n + 5)
    tot = gpu.upload(np.full(4, SENTINEL, np.uint32))
    run(gpu, lambda e: ps.encode(e, src, dst, n, total=(tot, 8)))
    out = gpu.read(dst)
    np.testing.assert_array_equal(out[:n], exclusive(x))
    assert (out[n : n + 5] == SENTINEL).all()
    assert gpu.read(tot).tolist() == [SENTINEL, SENTINEL, int(x.astype(np.uint64).sum() % 2**32), SENTINEL]


def test_scan_in_place_chunked_and_2d(gpu):
    """src is dst; 16 KiB bindings (4096-element chunks) and 3 workgroups per dispatch row."""
    n = 100_003
    x = np.random.default_rng(1).integers(0, 1000, n).astype(np.uint32)
    ps = PrefixSum(gpu, 120_000, per=4, max_binding=16384, max_groups_x=3)
    assert len(ps._slots[0]) > 1
    buf = padded(gpu, x, 120_000)
    tot = gpu.buffer(16)
    run(gpu, lambda e: ps.encode(e, buf, buf, n, total=(tot, 0)))
    out = gpu.read(buf)
    np.testing.assert_array_equal(out[:n], exclusive(x))
    assert (out[n:] == SENTINEL).all()
    assert gpu.read(tot)[0] == x.sum()


def test_scan_dynamic_count_three_levels(gpu):
    """Count read on the GPU (unaligned offset), clamped to the buffers; a capacity above
    block^2 gives three levels even though the buffers are small."""
    ps = PrefixSum(gpu, (WG * 16) ** 2 + 1, per=16)
    assert ps.levels == 2
    x = np.random.default_rng(2).integers(0, 50, 20_000).astype(np.uint32)
    src = gpu.upload(x)
    counts = gpu.upload(np.array([0, 0, 0, 9_999, 10**9, 0, 0, 0], np.uint32))
    dst1, dst2 = gpu.buffer(4 * 20_000), gpu.buffer(4 * 20_000)
    tot = gpu.upload(np.zeros(4, np.uint32))
    run(
        gpu,
        lambda e: ps.encode(e, src, dst1, (counts, 12), total=(tot, 0)),
        lambda e: ps.encode(e, src, dst2, (counts, 16), total=(tot, 4)),
    )  # clamped to 20000
    np.testing.assert_array_equal(gpu.read(dst1)[:9_999], exclusive(x[:9_999]))
    assert (gpu.read(dst1)[9_999:] == 0).all()
    np.testing.assert_array_equal(gpu.read(dst2), exclusive(x))
    assert gpu.read(tot)[:2].tolist() == [x[:9_999].sum(), x.sum()]


# ---- radix sort ------------------------------------------------------------------------------
@pytest.mark.parametrize("path", FUSED)
@pytest.mark.parametrize("per", PERS)
@pytest.mark.parametrize(
    "n,key_bits,hi",
    [
        (50_000, 32, 2**32),  # 8 passes, full range incl. 0xFFFFFFFF
        (50_000, 32, 17),  # many duplicates: stability
        (40_961, 10, 1 << 10),  # 3 passes (odd: copy first), n not a multiple of the block
        (5_000, 4, 2**32),  # 1 pass, high bits ignored and kept
        (3_000, 1, 2**32),  # 1-bit digit
        (4_096, 13, 2**32),  # one block at 16 per thread, partial last digit
    ],
)
def test_radix_sort_stable(gpu, n, key_bits, hi, per, path):
    rng = np.random.default_rng(n + key_bits)
    keys = rng.integers(0, hi, n, dtype=np.uint64).astype(np.uint32)
    keys[::97] = 0xFFFFFFFF
    vals = np.arange(n, dtype=np.uint32)
    rs = RadixSort(gpu, n, per=per, **FUSED[path])
    assert rs.fused == (path == "fused") and (rs.scan is None) == rs.fused
    kb, vb = gpu.upload(keys), gpu.upload(vals)
    run(gpu, lambda e: rs.encode(e, kb, vb, n, key_bits=key_bits))
    check_sort(gpu, keys, vals, kb, vb, n, key_bits)


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4097])
def test_radix_sort_small_counts(gpu, n):
    keys = np.array([5, 0xFFFFFFFF, 5, 0, 3, 0xFFFFFFFF, 1, 5] * 600, np.uint32)
    vals = np.arange(len(keys), dtype=np.uint32)
    rs = RadixSort(gpu, len(keys))
    kb, vb = gpu.upload(keys), gpu.upload(vals)
    run(gpu, lambda e: rs.encode(e, kb, vb, n))
    check_sort(gpu, keys, vals, kb, vb, n, 32)
    # the same through a GPU count
    cnt = gpu.upload(np.array([n], np.uint32))
    kb, vb = gpu.upload(keys), gpu.upload(vals)
    run(gpu, lambda e: rs.encode(e, kb, vb, (cnt, 0)))
    check_sort(gpu, keys, vals, kb, vb, n, 32)


@pytest.mark.parametrize("path", FUSED)
@pytest.mark.parametrize("per", [4, None])
def test_radix_sort_dynamic_count(gpu, per, path):
    """Count from a GPU buffer, below capacity: only that prefix is sorted, the rest untouched;
    a count beyond the capacity is clamped to it."""
    cap = 30_000
    rng = np.random.default_rng(3)
    keys = rng.integers(0, 300, cap + 1000).astype(np.uint32)
    vals = np.arange(cap + 1000, dtype=np.uint32)
    rs = RadixSort(gpu, cap, per=per, **FUSED[path])
    counts = gpu.upload(np.array([0, 12_345, 2**31, 0], np.uint32))
    kb1, vb1 = gpu.upload(keys), gpu.upload(vals)
    kb2, vb2 = gpu.upload(keys), gpu.upload(vals)
    run(
        gpu,
        lambda e: rs.encode(e, kb1, vb1, (counts, 4), key_bits=9),
        lambda e: rs.encode(e, kb2, vb2, (counts, 8), key_bits=9),
    )
    check_sort(gpu, keys, vals, kb1, vb1, 12_345, 9)
    check_sort(gpu, keys, vals, kb2, vb2, cap, 9)


@pytest.mark.parametrize("path", FUSED)
@pytest.mark.parametrize("per", PERS)
def test_radix_sort_two_bindings(gpu, per, path):
    """96 KiB bindings: 16384-element chunks, so 30000 pairs span two bindings (chunked reads,
    split writes); 2-D dispatch rows of 3 workgroups; dynamic count; odd and even passes."""
    n = 30_000
    rng = np.random.default_rng(4)
    keys = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
    keys[rng.random(n) < 0.3] = 77
    vals = np.arange(n, dtype=np.uint32)
    rs = RadixSort(gpu, n, per=per, max_binding=98304, max_groups_x=3, **FUSED[path])
    assert rs.nch == 2
    # runs are lengthened when the per-thread offsets would not fit one binding
    assert RadixSort(gpu, n, per=4, max_binding=98304).per == 16
    cnt = gpu.upload(np.array([n - 3], np.uint32))
    for bits in (32, 12):
        kb, vb = gpu.upload(keys), gpu.upload(vals)
        run(gpu, lambda e, kb=kb, vb=vb, bits=bits: rs.encode(e, kb, vb, (cnt, 0), key_bits=bits))
        check_sort(gpu, keys, vals, kb, vb, n - 3, bits)


def test_one_encoder_many_calls(gpu):
    """Calls recorded in one encoder with different counts do not share parameters: the
    renderer's pattern of scan (total on the GPU) then sort by that dynamic count, twice."""
    rng = np.random.default_rng(5)
    ps, rs = PrefixSum(gpu, 1000), RadixSort(gpu, 20_000)
    stats = gpu.upload(np.zeros(4, np.uint32))
    cases = []
    for m in (700, 300):
        counts = rng.integers(0, 40, 1000).astype(np.uint32)
        keys = rng.integers(0, 64, 20_000).astype(np.uint32)
        vals = np.arange(20_000, dtype=np.uint32)
        bufs = gpu.upload(counts), gpu.buffer(4000), gpu.upload(keys), gpu.upload(vals)
        cases.append((m, counts, keys, vals, bufs))
    encs = []
    for v, (m, _counts, _keys, _vals, (cb, ob, kb, vb)) in enumerate(cases):
        encs.append(lambda e, m=m, cb=cb, ob=ob, v=v: ps.encode(e, cb, ob, m, total=(stats, 4 * v)))
        encs.append(lambda e, kb=kb, vb=vb, v=v: rs.encode(e, kb, vb, (stats, 4 * v), key_bits=6))
    run(gpu, *encs)
    for v, (m, counts, keys, vals, (_cb, ob, kb, vb)) in enumerate(cases):
        total = int(counts[:m].sum())
        assert gpu.read(stats)[v] == total
        np.testing.assert_array_equal(gpu.read(ob)[:m], exclusive(counts[:m]))
        check_sort(gpu, keys, vals, kb, vb, total, 6)


def test_bad_arguments(gpu):
    rs = RadixSort(gpu, 100)
    kb, vb = gpu.buffer(400), gpu.buffer(400)
    enc = gpu.device.create_command_encoder()
    with pytest.raises(ValueError):
        rs.encode(enc, kb, vb, 101)
    with pytest.raises(ValueError):
        rs.encode(enc, kb, vb, 10, key_bits=33)
    with pytest.raises(ValueError):
        RadixSort(gpu, 3 * 16384, max_binding=65536)  # needs three bindings
    with pytest.raises(ValueError):
        RadixSort(gpu, 100, per=6)
    odd = gpu.device.create_buffer(size=404, usage=kb.usage)  # vec4 access needs 16-byte multiples
    with pytest.raises(ValueError):
        rs.encode(enc, odd, vb, 10)
    with pytest.raises(ValueError):
        PrefixSum(gpu, 100).encode(enc, odd, vb, 10)


class _Counting:
    """A command encoder's stand-in that counts the dispatches recorded in its passes."""

    def __init__(self):
        self.dispatches = 0

    def begin_compute_pass(self, **kw):
        return self

    def __getattr__(self, name):
        if name.startswith("dispatch_workgroups"):
            self.dispatches += 1
        return lambda *a, **kw: None


@pytest.mark.parametrize("path", FUSED)
def test_fused_scatter_saves_a_dispatch_per_pass(gpu, path):
    """The depth sort's 8 passes: a plan, then upsweep + scatter each (17) when fused; a scanned
    histogram adds a plan for the PrefixSum and its scan (one dispatch at this size) per pass."""
    n = 20_000
    rs = RadixSort(gpu, n, **FUSED[path])
    kb, vb = gpu.buffer(4 * n), gpu.buffer(4 * n)
    enc = _Counting()
    rs.encode(enc, kb, vb, n)
    assert enc.dispatches == (17 if path == "fused" else 1 + 1 + 8 * 3)


def test_fused_path_by_adapter_and_threshold(gpu):
    """The default is the adapter's (CPU adapters never fuse: the scatter's barriers cost lavapipe
    more than the dispatch saved); a histogram of exactly the threshold's blocks is fused, one
    more block is scanned, and both sort alike."""
    assert RadixSort(gpu, 5000).fused == (not gpu.is_cpu)
    rng = np.random.default_rng(8)
    for cap, fused in ((3 * 1024, True), (3 * 1024 + 1, False)):  # per=4: 1024 pairs a block
        rs = RadixSort(gpu, cap, per=4, fused_max_blocks=3)
        assert rs.fused == fused and (rs.scan is None) == fused
        keys = rng.integers(0, 2**32, cap, dtype=np.uint64).astype(np.uint32)
        vals = np.arange(cap, dtype=np.uint32)
        kb, vb = gpu.upload(keys), gpu.upload(vals)
        run(gpu, lambda e, rs=rs, kb=kb, vb=vb, cap=cap: rs.encode(e, kb, vb, cap))
        check_sort(gpu, keys, vals, kb, vb, cap, 32)
