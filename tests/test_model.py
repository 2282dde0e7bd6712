"""Model fields and the chunked raw-bit StoredLayout: round trips, locate(), budgets, aliases."""

from __future__ import annotations

import numpy as np
import pytest

from seuwgpu.model import encoding
from seuwgpu.model.fields import (
    FIELDS,
    Model,
    StoredLayout,
    canonical_field,
    field_components,
    n_components,
    sh_rest_count,
)


def random_model(n, degree, seed=0) -> Model:
    rng = np.random.default_rng(seed)
    return Model.from_flat(rng.standard_normal((n, n_components(degree))).astype(np.float32) * 3, degree)


# ------------------------------------------------------------------------------- model basics


def test_component_counts():
    assert [sh_rest_count(d) for d in range(4)] == [0, 3, 8, 15]
    assert [n_components(d) for d in range(4)] == [14, 23, 38, 59]
    assert [field_components(f, 3) for f in FIELDS] == [3, 3, 4, 1, 3, 45]
    with pytest.raises(ValueError, match="degree"):
        sh_rest_count(4)


def test_flat_order_and_from_flat():
    m = random_model(5, 2, seed=3)
    flat = m.flat()
    assert flat.shape == (5, 38)
    np.testing.assert_array_equal(flat[:, 0:3], m.means)
    np.testing.assert_array_equal(flat[:, 3:6], m.log_scales)
    np.testing.assert_array_equal(flat[:, 6:10], m.quats)
    np.testing.assert_array_equal(flat[:, 10], m.opacity)
    np.testing.assert_array_equal(flat[:, 11:14], m.sh_dc)
    for k in range(8):
        for c in range(3):
            np.testing.assert_array_equal(flat[:, 14 + 3 * k + c], m.sh_rest[:, k, c])
    back = Model.from_flat(flat, 2)
    np.testing.assert_array_equal(back.flat(), flat)


def test_model_shape_validation():
    m = random_model(4, 1)
    with pytest.raises(ValueError, match="quats"):
        Model(
            means=m.means,
            log_scales=m.log_scales,
            quats=m.quats[:, :3],
            opacity=m.opacity,
            sh_dc=m.sh_dc,
            sh_rest=m.sh_rest,
        )
    with pytest.raises(ValueError, match="no SH degree"):
        Model(
            means=m.means,
            log_scales=m.log_scales,
            quats=m.quats,
            opacity=m.opacity,
            sh_dc=m.sh_dc,
            sh_rest=np.zeros((4, 5, 3)),
        )


def test_empty_subset():
    m = random_model(4, 3)
    e = m.subset(np.zeros(4, bool))
    assert e.n == 0 and e.sh_rest.shape == (0, 15, 3) and e.sh_degree == 3


# ------------------------------------------------------------------------- aliases, budgets


@pytest.mark.parametrize(
    "alias,field",
    [
        ("means", "means"),
        ("xyz", "means"),
        ("Mean", "means"),
        ("log_scales", "log_scales"),
        ("scale", "log_scales"),
        (" SCALES ", "log_scales"),
        ("rotation", "quats"),
        ("rot", "quats"),
        ("quat", "quats"),
        ("opacities", "opacity"),
        ("opacity", "opacity"),
        ("color", "sh_dc"),
        ("dc", "sh_dc"),
        ("sh", "sh_rest"),
        ("sh_rest", "sh_rest"),
    ],
)
def test_canonical_field_aliases(alias, field):
    assert canonical_field(alias) == field


def test_unknown_field_error():
    with pytest.raises(ValueError) as e:
        canonical_field("colour")
    msg = str(e.value)
    assert "'colour'" in msg
    for f in FIELDS:
        assert f in msg
    with pytest.raises(ValueError, match="unknown field"):
        random_model(2, 0).field("normals")


def test_field_accessor():
    m = random_model(3, 1)
    assert m.field("xyz").shape == (3, 3)
    assert m.field("opacity").shape == (3, 1)
    assert m.field("sh").shape == (3, 9)
    np.testing.assert_array_equal(m.field("sh")[:, 3 * 2 + 1], m.sh_rest[:, 2, 1])


def test_bit_budget_hand_computed():
    m = random_model(10, 3)
    b = m.bit_budget("fp32")
    assert b == {
        "means": 960,
        "log_scales": 960,
        "quats": 1280,
        "opacity": 320,
        "sh_dc": 960,
        "sh_rest": 14400,
        "total": 18880,
    }  # 10 * 59 * 32
    b16 = m.bit_budget("fp16")
    assert b16 == {k: v // 2 for k, v in b.items()}
    assert m.bit_budget("bf16") == b16
    m0 = random_model(5, 0)
    assert m0.bit_budget("bf16") == {
        "means": 240,
        "log_scales": 240,
        "quats": 320,
        "opacity": 80,
        "sh_dc": 240,
        "sh_rest": 0,
        "total": 1120,
    }  # 5 * 14 * 16
    with pytest.raises(ValueError, match="unknown precision"):
        m.bit_budget("fp64")


def test_max_chunk_prims_hand_computed():
    mib128 = 128 << 20
    # degree 3 fp32: 59 * 4 = 236 bytes/primitive; 134217728 // 236 = 568719 -> even 568718
    assert StoredLayout.max_chunk_prims(3, "fp32", mib128) == 568718
    # fp16: 118 bytes; 134217728 // 118 = 1137438 (already even)
    assert StoredLayout.max_chunk_prims(3, "fp16", mib128) == 1137438
    # degree 0 bf16: 28 bytes; 134217728 // 28 = 4793490
    assert StoredLayout.max_chunk_prims(0, "bf16", mib128) == 4793490
    for d in range(4):
        for p in encoding.PRECISIONS:
            c = StoredLayout.max_chunk_prims(d, p, mib128)
            lay = StoredLayout(10 * c, d, p, c)
            assert lay.chunk_prims == c and lay.chunk_words * 4 <= mib128


def test_balanced_chunk_prims_hand_computed():
    """Chunks are allocated whole, so the renderer splits a model evenly: 10M degree-3 fp32
    primitives at a 2 GiB binding (at most 9,099,506 a chunk) take two chunks of 5M, not 9.1M."""
    mx = StoredLayout.max_chunk_prims(3, "fp32", 2**31 - 4)
    assert mx == 9_099_506
    assert StoredLayout.balanced_chunk_prims(10_000_000, mx) == 5_000_000
    assert StoredLayout.balanced_chunk_prims(9, 6) == 6  # two chunks: ceil(9 / 2) = 5, made even
    assert StoredLayout.balanced_chunk_prims(7, 4) == 4
    assert StoredLayout.balanced_chunk_prims(3, 100) == 4  # one chunk, even
    for n in range(1, 80):
        for cap in (2, 4, 6, 10, 64):
            c = StoredLayout.balanced_chunk_prims(n, cap)
            assert c % 2 == 0 and c <= max(cap, n + (n & 1)), (n, cap)
            assert -(-n // c) == -(-n // cap), (n, cap)  # no more chunks than the cap needs


# ------------------------------------------------------------------------------ stored layout

CASES = [(1, 1), (2, 2), (7, 2), (7, 3), (11, 4), (13, 13), (5, 100), (9, 8), (33, 10)]


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
@pytest.mark.parametrize("n,chunk", CASES)
def test_encode_decode_round_trip(precision, n, chunk):
    degree = (n + chunk) % 4
    m = random_model(n, degree, seed=n * 100 + chunk)
    lay = StoredLayout(n, degree, precision, chunk)
    assert lay.chunk_prims % 2 == 0 and lay.chunk_prims >= min(chunk, n)
    assert lay.n_chunks == -(-n // lay.chunk_prims)
    words = lay.encode(m)
    assert len(words) == lay.n_chunks
    per_word = 2 if encoding.bits_per_value(precision) == 16 else 1
    for w in words:
        assert w.dtype == np.uint32 and w.shape == (lay.ncomp * lay.chunk_prims // per_word,)
        assert w.shape == (lay.chunk_words,)
    back = lay.decode(words)
    expect = m.quantized(precision)
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(back, f).view(np.uint32), getattr(expect, f).view(np.uint32), err_msg=f)


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_layout_against_independent_reference(precision):
    """Plane p of chunk k holds component p of the chunk's primitives; 16-bit: 2j low, 2j+1 high."""
    n, degree, chunk = 9, 1, 4
    m = random_model(n, degree, seed=9)
    lay = StoredLayout(n, degree, precision, chunk)
    words = lay.encode(m)
    bits = encoding.to_bits(m.flat(), precision)
    # encode_bits packs given bit patterns into the same words (one packing, StoredLayout._words)
    assert all(np.array_equal(a, b) for a, b in zip(words, lay.encode_bits(bits), strict=True))
    half = encoding.bits_per_value(precision) == 16
    plane_words = chunk // 2 if half else chunk
    assert lay.plane_words == plane_words
    for i in range(n):
        k, j = divmod(i, chunk)
        for p in range(n_components(degree)):
            if half:
                wi, shift = p * plane_words + j // 2, 16 * (j % 2)
                got = (int(words[k][wi]) >> shift) & 0xFFFF
            else:
                wi, shift = p * plane_words + j, 0
                got = int(words[k][wi])
            assert got == int(bits[i, p]), (i, p)
            ck, cw, cs = lay.locate(i, p)
            assert (int(ck), int(cw), int(cs)) == (k, wi, shift), (i, p)
    # padding slots of the last chunk (primitives 9..11) are zero
    last = words[-1].reshape(lay.ncomp, plane_words)
    if half:
        assert (last[:, 0] >> 16 == 0).all() and (last[:, 1] == 0).all()
    else:
        assert (last[:, 1:] == 0).all()


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_flip_at_locate_changes_exactly_that_value(precision):
    n, degree, chunk = 13, 3, 6
    m = random_model(n, degree, seed=4)
    lay = StoredLayout(n, degree, precision, chunk)
    clean_words = lay.encode(m)
    clean = lay.decode(clean_words).flat()
    clean_bits = encoding.to_bits(clean, precision)
    width = encoding.bits_per_value(precision)
    rng = np.random.default_rng(0)
    sites = [(0, 0), (n - 1, lay.ncomp - 1), (5, 10), (6, 14), (7, 11), (12, 3)]
    sites += [(int(rng.integers(n)), int(rng.integers(lay.ncomp))) for _ in range(20)]
    for prim, comp in sites:
        bit = int(rng.integers(width))
        ck, cw, cs = lay.locate(prim, comp)
        words = [w.copy() for w in clean_words]
        words[int(ck)][int(cw)] ^= np.uint32(1 << (bit + int(cs)))
        hit_bits = encoding.to_bits(lay.decode(words).flat(), precision)
        changed = np.argwhere(hit_bits != clean_bits)
        assert changed.tolist() == [[prim, comp]], (prim, comp, bit)
        assert int(hit_bits[prim, comp]) == int(encoding.flip_bits(clean_bits[prim, comp], bit, precision))


def test_locate_vectorised():
    lay = StoredLayout(20, 2, "bf16", 8)
    prims = np.array([0, 1, 2, 7, 8, 9, 19])
    comps = np.array([0, 0, 5, 37, 1, 2, 10])
    ck, cw, cs = lay.locate(prims, comps)
    np.testing.assert_array_equal(ck, [0, 0, 0, 0, 1, 1, 2])
    np.testing.assert_array_equal(cw, [0, 0, 5 * 4 + 1, 37 * 4 + 3, 4, 2 * 4, 10 * 4 + 1])
    np.testing.assert_array_equal(cs, [0, 16, 0, 16, 0, 16, 16])


def test_layout_rejects_bad_input():
    with pytest.raises(ValueError, match="at least one primitive"):
        StoredLayout(0, 3, "fp32", 4)
    with pytest.raises(ValueError, match="unknown precision"):
        StoredLayout(4, 3, "fp8", 4)
    lay = StoredLayout(4, 3, "fp32", 4)
    with pytest.raises(ValueError, match="does not match"):
        lay.encode(random_model(5, 3))
    with pytest.raises(ValueError, match="does not match"):
        lay.encode(random_model(4, 2))
