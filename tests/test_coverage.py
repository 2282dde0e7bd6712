"""Coverage under every fault model (faults/coverage.py), by exhaustive sweep of the faults of a
tiny made model, against hand-computed references: which bits parity4r covers, where its
interleaved ways cancel, what ECC corrects, and that the checksum misses nothing."""

import numpy as np
from conftest import random_model

from seuwgpu.faults import codes, coverage
from seuwgpu.faults import defenses as dfn
from seuwgpu.model import encoding

COVERED_FROM = 32 - 13  # parity4r covers sign, exponent and the top 4 mantissa bits: 19..31


def _rows():
    return encoding.to_bits(random_model(2, seed=8).flat(), "fp32")


def _outcomes(defense, fam, rows):
    cols, masks = coverage.family(fam, 59, 32, rows[0], np.random.default_rng(0))
    prims = np.zeros(len(cols), np.int64)
    return cols, masks, coverage.outcomes(defense, rows, prims, cols, masks, "fp32", 3)


def test_parity4r_single_flips_and_bursts_by_hand():
    rows = _rows()
    cols, masks, (caught, restored) = _outcomes("parity4r", "bit", rows)
    bit = np.array([int(m).bit_length() - 1 for m in masks[:, 0]])
    np.testing.assert_array_equal(caught, bit >= COVERED_FROM)
    np.testing.assert_array_equal(restored, caught)  # a reload restores the clean row bit for bit
    for w in range(2, 9):
        cols, masks, (caught, _) = _outcomes("parity4r", f"burst{w}", rows)
        lo = np.array([(int(m) & -int(m)).bit_length() - 1 for m in masks[:, 0]])
        covered = np.clip(lo + w - np.maximum(lo, COVERED_FROM), 0, None)  # burst bits in 19..31
        # each way counts the covered bits at positions = way mod 4: a run of L is odd in some
        # way unless L is 0 or 8 (two of each)
        want = (covered > 0) & (covered % 8 != 0)
        np.testing.assert_array_equal(caught, want, err_msg=f"burst{w}")
    # an 8-bit burst at bits 24-31 passes, as the audit found
    hit = (masks[:, 0] == np.uint64(0xFF << 24)) & (cols[:, 0] == 4)
    assert hit.sum() == 1 and not caught[hit].any()


def test_pairs_that_defeat_parity_and_the_checksum_that_catches_them():
    rows = _rows()
    _, _, (caught, _) = _outcomes("parity4r", "mcu_prim", rows)
    assert caught.size == 59 * 58 // 2 * 32 and not caught.any()  # the same bit twice: every way even
    cols, masks, (caught, _) = _outcomes("parity4r", "dangerous_pairs", rows)
    same_way = np.array([(int(a).bit_length() - int(b).bit_length()) % 4 == 0 for a, b in masks])
    assert caught.size == 28 and (~caught).sum() == 12
    np.testing.assert_array_equal(caught, ~same_way)
    # log-scale bit 31 and opacity bit 31 together: log-scale -x becomes +x, unseen
    both31 = (masks[:, 0] == np.uint64(1 << 31)) & (masks[:, 1] == np.uint64(1 << 31)) & (cols[:, 1] == 10)
    assert both31.sum() == 3 and not caught[both31].any()
    for fam in ("bit", "burst8", "mcu_prim", "dangerous_pairs", "random"):
        assert _outcomes("checksum", fam, rows)[2][0].all(), fam


def test_ecc_corrects_each_value_of_a_neighbour_upset_and_the_fast_parity_is_the_twin():
    rows = _rows()
    cols, masks, (caught, restored) = _outcomes("ecc", "mcu_prim", rows)
    bit = np.array([int(m).bit_length() - 1 for m in masks[:, 0]])
    np.testing.assert_array_equal(restored, bit >= 23)  # one error per value: corrected in both
    table = {
        (r["family"], r["defense"]): r
        for r in coverage.coverage_table(
            rows, "fp32", 3, families=("bit", "mcu_neighbour"), defenses=("ecc", "parity4r")
        )
    }
    assert table[("mcu_neighbour", "ecc")]["restored"] == 9 * 59  # both primitives, each corrected
    assert table[("mcu_neighbour", "parity4r")]["caught_se"] == 9 * 59
    # the shader's parity (Parity.detect: XOR of the covered bits, a count per way) against the
    # code recomputed bit by bit from the corrupted rows (codes.parity_bits)
    for d in ("parity", "parity4", "parity4r", "parity4f", "parity2f"):
        for fam in ("burst3", "mcu_prim"):
            cols, masks, (caught, _) = _outcomes(d, fam, rows)
            bad = np.repeat(rows[:1], len(cols), 0)
            for k in range(2):
                bad[np.arange(len(cols)), cols[:, k]] ^= masks[:, k].astype(np.uint32)
            code = dfn.get(d).code

            def bit_by_bit(x, code=code):
                return codes.parity_bits(x, "fp32", 3, code.ways, code.fields, code.diagonal)

            changed = (bit_by_bit(bad) != bit_by_bit(rows[:1])).any(axis=1)
            np.testing.assert_array_equal(caught, changed, err_msg=f"{d} {fam}")
            assert caught.any() or (fam == "mcu_prim" and d != "parity2f"), d


def _way(bit, value):
    """parity2f's way of a bit, by hand: (bit + value) mod 2."""
    return (bit + value) % 2


def test_parity2f_groups_diagonally_by_hand():
    """parity2f's two ways, bit b of value c in way (b + c) mod 2, over bits 19..31 of every value:
    single flips, 2- and 3-bit bursts and the same bit in two values of different index parity are
    seen; 4-bit bursts and the same bit in two values of equal index parity cancel."""
    rows = _rows()
    cols, masks, (caught, restored) = _outcomes("parity2f", "bit", rows)
    bit = np.array([int(m).bit_length() - 1 for m in masks[:, 0]])
    np.testing.assert_array_equal(caught, bit >= COVERED_FROM)
    np.testing.assert_array_equal(restored, caught)  # dropped, then reloaded: the clean row
    for w in range(2, 9):
        cols, masks, (caught, _) = _outcomes("parity2f", f"burst{w}", rows)
        lo = np.array([(int(m) & -int(m)).bit_length() - 1 for m in masks[:, 0]])
        covered = np.clip(lo + w - np.maximum(lo, COVERED_FROM), 0, None)
        # a run of L covered bits puts L // 2 or L // 2 + 1 in each way: all even only if L % 4 == 0
        np.testing.assert_array_equal(caught, (covered > 0) & (covered % 4 != 0), err_msg=f"burst{w}")
    four = (masks[:, 0] == np.uint64(0xF << 24)) & (cols[:, 0] == 4)  # burst8's masks: bits 24..31
    eight = (masks[:, 0] == np.uint64(0xFF << 24)) & (cols[:, 0] == 4)
    assert four.sum() == 0 and eight.sum() == 1 and not caught[eight].any()
    cols, masks, (caught, _) = _outcomes("parity2f", "burst4", rows)
    one = (masks[:, 0] == np.uint64(0xF << 24)) & (cols[:, 0] == 4)
    assert one.sum() == 1 and not caught[one].any()  # bits 24..27: two in each way, unseen
    cols, masks, (caught, _) = _outcomes("parity2f", "mcu_prim", rows)
    bit = np.array([int(m).bit_length() - 1 for m in masks[:, 0]])
    np.testing.assert_array_equal(caught, (bit >= COVERED_FROM) & ((cols[:, 0] + cols[:, 1]) % 2 == 1))
    pick = (cols[:, 0] == 3) & (bit == 30)  # log-scale x's exponent top bit with each other value's
    assert caught[pick & (cols[:, 1] == 4)].all() and not caught[pick & (cols[:, 1] == 5)].any()
    # the dangerous pairs: the 8 cells split 4 and 4 between the ways; the 12 pairs inside a way pass
    cols, masks, (caught, _) = _outcomes("parity2f", "dangerous_pairs", rows)
    ways = [[_way(int(m).bit_length() - 1, int(c)) for c, m in zip(cs, ms)] for cs, ms in zip(cols, masks)]
    np.testing.assert_array_equal(caught, [a != b for a, b in ways])
    assert (~caught).sum() == 12
    # log-scale x or z bit 31 (way 0) with opacity bit 31 (way 1): seen, where parity4r misses them
    both31 = (masks[:, 0] == np.uint64(1 << 31)) & (masks[:, 1] == np.uint64(1 << 31)) & (cols[:, 1] == 10)
    np.testing.assert_array_equal(caught[both31], [c % 2 == 1 for c in cols[both31, 0]])  # x, z: ways 0, 1
    assert caught[both31 & (cols[:, 0] == 3)].all() and not caught[both31 & (cols[:, 0] == 4)].any()
    # any two cells of the primitive: seen when one alone is covered, or both are, in different ways
    cols, masks, (caught, _) = _outcomes("parity2f", "pair", rows)
    b = np.log2(masks.astype(np.float64)).astype(np.int64)  # one bit a mask: exact
    cov = b >= COVERED_FROM
    want = (cov[:, 0] ^ cov[:, 1]) | (cov[:, 0] & cov[:, 1] & (_way(b[:, 0], cols[:, 0]) != _way(b[:, 1], cols[:, 1])))
    np.testing.assert_array_equal(caught, want)
    # a random value c: the changed covered bits, counted per way bit by bit
    cols, masks, (caught, _) = _outcomes("parity2f", "random", rows)
    odd = [
        any(sum((int(m) >> k) & 1 for k in range(COVERED_FROM, 32) if _way(k, int(c)) == w) % 2 for w in (0, 1))
        for c, m in zip(cols[:, 0], masks[:, 0])
    ]
    np.testing.assert_array_equal(caught, odd)
    assert 0.7 < np.mean(caught) < 0.8  # about 3 in 4 changes of the covered bits are odd in a way
    # neighbouring words (planar layout: two primitives, one flip each) are caught when each is
    table = {
        r["family"]: r
        for r in coverage.coverage_table(rows, "fp32", 3, families=("bit", "mcu_neighbour"), defenses=("parity2f",))
    }
    assert table["mcu_neighbour"]["caught"] == 13 * 59  # the covered bits of every value, in both
