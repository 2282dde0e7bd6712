"""Coverage under every fault model (faults/coverage.py), by exhaustive sweep of the faults of a
tiny made model, against hand-computed references: which bits parity4r covers, where its
interleaved ways cancel, what ECC corrects, and that the checksum misses nothing."""

import numpy as np
from conftest import random_model

from seuwgpu.faults import coverage
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
    # code recomputed bit by bit from the corrupted rows (codes.parity_bits, side_data's)
    for d in ("parity", "parity4", "parity4r", "parity4f"):
        cols, masks, (caught, _) = _outcomes(d, "burst3", rows)
        bad = np.repeat(rows[:1], len(cols), 0)
        bad[np.arange(len(cols)), cols[:, 0]] ^= masks[:, 0].astype(np.uint32)
        code = dfn.get(d).code if d == "parity4f" else d
        side = dfn.side_data(code, rows[:1], "fp32", 3)
        np.testing.assert_array_equal(caught, dfn.side_data(code, bad, "fp32", 3) != side, err_msg=d)
        assert caught.any() and not caught.all(), d  # bursts inside and outside the covered bits
