"""Defenses (faults/defenses.py): identity on the clean model, what each one catches and misses
(hand-built faults), memory overheads by hand, and a culled primitive rendering as if removed."""

import numpy as np
import pytest

from seuwgpu.faults import codes, schedule
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults import side as sd
from seuwgpu.faults.engine import Engine
from seuwgpu.faults.guard import support_box
from seuwgpu.model import encoding
from seuwgpu.model.fields import Model
from seuwgpu.model.scenes import make_scene, scene_cameras

CHECKED = [d.name for d in dfn.REGISTRY.values() if d.checked]


@pytest.fixture(scope="module")
def real():
    return make_scene("leica-sofort-wide")


def stored_rows(model, precision):
    return encoding.to_bits(model.flat(), precision)


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_every_defense_is_the_identity_on_the_clean_model(real, precision):
    rows = stored_rows(real, precision)
    box = support_box(Model.from_flat(encoding.from_bits(rows, precision), real.sh_degree), precision)
    cells = codes.CellBoxes(rows, precision, real.sh_degree)
    prims = np.arange(real.n)
    for d in dfn.DEFENSES:
        got = dfn.read(d, rows, rows, precision, real.sh_degree, box, prims, cells)
        np.testing.assert_array_equal(got, rows, err_msg=d)
    # the scale classes hold every clean log-scale
    bound = codes.scale_class_bounds(rows, float(box.lo[3:6].min()), float(box.hi[3:6].max()), precision)
    assert (encoding.from_bits(rows[:, 3:6], precision) <= bound[:, None]).all()
    assert np.unique(bound).size > 4  # the classes separate small from large splats


def test_parity_catches_what_it_covers_and_culls(real):
    p, deg = "fp32", real.sh_degree
    rows = stored_rows(real, p)[:200]
    cover = codes.parity_cover_mask(p)
    assert cover == 0xF8000000 | (0xF << 19) | 0x07800000  # sign, exponent, 4 top mantissa bits
    nan3 = np.full(3, 0x7FC00000, np.uint32)
    for comp in (0, 3, 6, 10, 13):  # means, log_scales, quats, opacity, sh_dc
        for top in (31, 30, 24, 22):  # bursts inside the covered bits
            for w in (1, 2, 3, 4):
                bits = [b for b in range(top - w + 1, top + 1)]
                bad = rows.copy()
                bad[:, comp] ^= np.uint32(sum(1 << b for b in bits))
                got4 = dfn.read("parity4", rows, bad, p, deg)
                assert (got4[:, :3] == nan3).all(), (comp, bits)  # every burst <= 4 bits: culled
                np.testing.assert_array_equal(got4[:, 3:], bad[:, 3:])
                got1 = dfn.read("parity", rows, bad, p, deg)
                assert (got1[:, :3] == nan3).all() == (w % 2 == 1)  # 1 parity bit: odd counts only
    # low mantissa bits and sh_rest are not covered: they pass
    bad = rows.copy()
    bad[:, 3] ^= np.uint32(1 << 10)
    bad[:, 20] ^= np.uint32(1 << 30)
    for d in ("parity", "parity4"):
        np.testing.assert_array_equal(dfn.read(d, rows, bad, p, deg), bad)
    # parity4r covers sh_rest too and reloads: the sh_rest flip is undone, the low mantissa one not
    got = dfn.read("parity4r", rows, bad, p, deg)
    np.testing.assert_array_equal(got[:, 20], rows[:, 20])
    np.testing.assert_array_equal(got[:, 3], rows[:, 3])  # reloaded whole: its primitive was flagged
    only_low = rows.copy()
    only_low[:, 3] ^= np.uint32(1 << 10)
    np.testing.assert_array_equal(dfn.read("parity4r", rows, only_low, p, deg), only_low)


def test_checksum_reloads_every_single_value_change(real):
    p, deg = "bf16", real.sh_degree
    rows = stored_rows(real, p)[:300]
    rng = np.random.default_rng(4)
    bad = rows.copy()
    comp = rng.integers(0, rows.shape[1], 300)
    bad[np.arange(300), comp] = rng.integers(0, 2**16, 300).astype(np.uint16)
    changed = (bad != rows).any(axis=1)
    assert changed.sum() > 290
    np.testing.assert_array_equal(dfn.read("checksum", rows, bad, p, deg), rows)

    # a row of zeros, by hand: 59 MurmurHash3 finaliser steps from the seed
    def fmix(h):
        h ^= h >> 16
        h = (h * 0x85EBCA6B) & 0xFFFFFFFF
        h ^= h >> 13
        h = (h * 0xC2B2AE35) & 0xFFFFFFFF
        return h ^ (h >> 16)

    h = 0x811C9DC5
    for _ in range(59):
        h = fmix(h)
    assert codes.checksum(np.zeros((1, 59), np.uint16))[0] == h
    # two sign-bit flips in one primitive (they cancel in FNV-1a) are caught
    two = rows.copy()
    two[:, [39, 50]] ^= np.uint16(0x8000)
    np.testing.assert_array_equal(dfn.read("checksum", rows, two, p, deg), rows)


def test_ecc_crit_corrects_singles_culls_doubles_and_ignores_other_fields(real):
    p, deg = "fp32", real.sh_degree
    rows = stored_rows(real, p)[:100]
    for comp in (3, 10):
        bad = rows.copy()
        bad[:, comp] ^= np.uint32(1 << 30)
        np.testing.assert_array_equal(dfn.read("ecc_crit", rows, bad, p, deg), rows)
        bad[:, comp] ^= np.uint32(1 << 29)
        got = dfn.read("ecc_crit", rows, bad, p, deg)
        assert (got[:, :3] == 0x7FC00000).all()
    bad = rows.copy()
    bad[:, 7] ^= np.uint32(1 << 30)  # a quaternion: not covered
    np.testing.assert_array_equal(dfn.read("ecc_crit", rows, bad, p, deg), bad)


def test_ecc_crit_culls_only_what_its_decoder_flags(real):
    """ecc_crit culled every value left wrong after correction, knowing the clean bits; a SEC-DED
    decoder knows only its syndrome and parity. fp32 sign+exponent bits 23..31 sit at Hamming
    positions 3, 5, 6, 7, 9, 10, 11, 12, 13 (check bits at 1, 2, 4, 8); by hand:"""
    p, deg = "fp32", real.sh_degree
    rows = stored_rows(real, p)[:5]
    nan3 = np.full(3, 0x7FC00000, np.uint32)
    cases = [  # (bits flipped in log_scales[.][0], culled, bits still wrong after decoding)
        ([30], False, []),  # a single: corrected
        ([29, 30], True, None),  # a double: syndrome 11 ^ 12 = 7, even parity: flagged, culled
        ([23, 24, 25], False, [23, 24, 25]),  # 3 ^ 5 ^ 6 = 0: read as the overall parity bit's error
        ([23, 24, 26], False, [23, 24, 26]),  # 3 ^ 5 ^ 7 = 1: read as check bit 1's error
        ([29, 30, 31], False, [28, 29, 30, 31]),  # 11 ^ 12 ^ 13 = 10: bit 28 "corrected" too
        ([24, 25, 31], True, None),  # 5 ^ 6 ^ 13 = 14: no such position, flagged
        ([24, 25, 27, 28], False, [24, 25, 27, 28]),  # 5 ^ 6 ^ 9 ^ 10 = 0: four errors unseen
        ([24, 25, 26, 27], True, None),  # a 4-bit burst: 5 ^ 6 ^ 7 ^ 9 = 13, even parity: flagged
    ]
    for bits, culled, wrong in cases:
        bad = rows.copy()
        bad[:, 3] ^= np.uint32(sum(1 << b for b in bits))
        got = dfn.read("ecc_crit", rows, bad, p, deg)
        assert (got[:, :3] == nan3).all() == culled and (got[:, :3] == nan3).any() == culled, bits
        if not culled:
            want = rows[:, 3] ^ np.uint32(sum(1 << b for b in wrong))
            np.testing.assert_array_equal(got[:, 3], want, err_msg=str(bits))
            np.testing.assert_array_equal(dfn.read("ecc", rows, bad, p, deg)[:, 3], want, err_msg=str(bits))


def test_scalebound_clamps_a_grown_log_scale_to_its_class(real):
    p, deg = "fp32", real.sh_degree
    rows = stored_rows(real, p)
    box = support_box(real, p)
    vals = encoding.from_bits(rows[:, 3], p)
    small = int(np.argmin(vals))  # the smallest splat: its class bound is far below the box top
    bad = rows[small : small + 1].copy()
    bad[0, 3] ^= np.uint32(1 << 31)  # -x -> +x
    got = dfn.read("scalebound", rows[small : small + 1], bad, p, deg, box)
    bound = codes.scale_class_bounds(rows[small : small + 1], float(box.lo[3:6].min()), float(box.hi[3:6].max()), p)
    assert encoding.from_bits(got[0, 3], p) == bound[0] < box.hi[3]
    np.testing.assert_array_equal(got[0, 4:], bad[0, 4:])


def test_cellbox_clamps_into_the_cell_and_is_tighter_than_the_guard(real):
    p = "fp32"
    rows = stored_rows(real, p)
    cells = codes.CellBoxes(rows, p, real.sh_degree)
    box = support_box(real, p)
    assert np.unique(cells.cell).size > 20  # the object spreads over many cells
    i = int(np.argmin(encoding.from_bits(rows[:, 3], p)))
    bad = rows[[i]].copy()
    bad[0, 3] ^= np.uint32(1 << 31)  # the smallest splat's log-scale sign
    got = dfn.read("cellbox", rows[[i]], bad, p, real.sh_degree, prims=[i], cells=cells)
    top = encoding.from_bits(got[0, 3], p)
    mine = cells.cell == cells.cell[i]
    assert top == encoding.from_bits(rows[mine, 3], p).max() <= box.hi[3]
    with pytest.raises(ValueError, match="cellbox needs"):
        dfn.read("cellbox", rows[[i]], bad, p, real.sh_degree)


def test_memory_overheads_by_hand():
    bits = 59 * 32
    n = 1000
    assert sd.memory_overhead("none", "fp32", 3, n) == 0
    assert sd.memory_overhead("parity", "fp32", 3, n) == pytest.approx(1 / bits)
    assert sd.memory_overhead("parity4", "fp32", 3, n) == pytest.approx(4 / bits)
    assert sd.memory_overhead("checksum", "fp16", 3, n) == pytest.approx(32 / (59 * 16))
    assert sd.memory_overhead("ecc", "fp32", 3, n) == pytest.approx(5 / 32)
    assert sd.memory_overhead("ecc_crit", "fp32", 3, n) == pytest.approx(4 * 5 / bits)
    assert sd.memory_overhead("dup", "bf16", 0, n) == pytest.approx(2.0)
    assert sd.memory_overhead("guard", "fp32", 3, n) == pytest.approx(2 * 14 * 32 / (n * bits))
    assert sd.memory_overhead("scalebound", "fp32", 3, n) == pytest.approx((4 * n + 2 * 14 * 32) / (n * bits))
    assert sd.memory_overhead("cellbox", "fp32", 3, n) == pytest.approx((9 * n + 2 * 14 * 32 * 512) / (n * bits))
    with pytest.raises(ValueError, match="unknown defense 'tmr'"):
        sd.memory_overhead("tmr", "fp32", 3, n)


def test_defense_names_outside_the_list_are_defined_only_in_it():
    """Labels and the first study's set name real defenses (a rename cannot leave them stale)."""
    assert set(dfn.REGISTRY) == set(dfn.DEFENSES)
    assert set(dfn.FIRST_DEFENSES) <= set(dfn.DEFENSES)
    assert dfn.defense_label("guard") == "support guard" and dfn.defense_label("parity4") == "parity4"


def test_a_culled_primitive_renders_as_if_removed():
    model = make_scene("blocks", n=400, seed=5)
    cams = scene_cameras("blocks", 2, 48, 48)
    eng = Engine(model, cams, "fp32", scene="blocks")
    victim = int(np.argmax(model.opacity))
    site = eng.site("log_scales", victim, 1, 31)
    h = eng.apply([site], "parity4")
    got, _ = eng.render_current("parity4")
    eng.undo(h)
    keep = np.arange(model.n) != victim
    rest = Model.from_flat(model.flat()[keep], model.sh_degree)
    want = Engine(rest, cams, "fp32", gpu=eng.gpu).clean_rgba
    np.testing.assert_array_equal(got, want)
    assert not np.array_equal(got, eng.clean_rgba)  # the victim was visible
    rec = eng.inject(site, "parity4")
    assert rec["footprint"] == float(np.mean(np.any(np.abs(want[..., :3] - eng.clean) > 1 / 255, axis=-1)))


def test_defenses_command_lists_every_defense_as_json_and_as_a_table(capsys):
    import json
    import math

    from seuwgpu.apps.cli import main

    def strict(text):  # plain JSON: a NaN or Infinity literal is refused, as jq and browsers do
        def refuse(name):
            raise ValueError(f"{name} is not JSON (undefined values are null)")

        return json.loads(text, parse_constant=refuse)

    cmd = ["defenses", "--scene", "blocks", "--n", "300", "--size", "32x32", "--repeats", "1", "--json"]
    assert main([*cmd, "--check-every", "4"]) == 0
    rows = strict(capsys.readouterr().out)
    assert [r["name"] for r in rows] == list(dfn.DEFENSES)
    keys = {"name", "device_bytes", "memory_overhead", "check_every", "time_fraction", "check_fraction"}
    keys |= {"exposure_frames", "exposure_frames_worst", "time_basis", "description", "time_lo", "time_hi"}
    keys |= {"repair_fraction", "catastrophic_frames_per_upset", "catastrophic_lo", "catastrophic_hi"}
    keys |= {"sdc_frames_per_upset", "residue_frames_per_upset", "of_none", "of_none_lo", "of_none_hi"}
    keys |= {"visible_basis"}
    for r in rows:
        assert set(r) == keys
        # the memory column: what the device holds (issue 39), of a model of 300 x 59 fp32 values
        assert r["device_bytes"] == sd.device_bytes(r["name"], "fp32", 3, 300)
        assert r["memory_overhead"] == pytest.approx(r["device_bytes"] / (300 * 59 * 4))
        checked = dfn.get(r["name"]).checked
        assert r["check_every"] == (4 if checked else None)
        want = (1.5, 3.0) if checked else ("inf", "inf") if r["name"] == "none" else (0.0, 0.0)
        assert (r["exposure_frames"], r["exposure_frames_worst"]) == want, r["name"]
        d = dfn.get(r["name"])
        gpu_side = d.checked or d.frame_check or bool(d.guard_fields) or r["name"] == "none"
        assert (r["time_fraction"] is not None and math.isfinite(r["time_fraction"])) == gpu_side, r
        assert r["time_basis"].startswith("measured") == gpu_side
        assert r["catastrophic_frames_per_upset"] is None and r["visible_basis"] == "not measured"
    assert main(["defenses", "--scene", "blocks", "--n", "300", "--no-time", "--json"]) == 0
    rows = strict(capsys.readouterr().out)  # undefined (not measured): null, not a NaN literal
    assert all(r["time_fraction"] is None and r["time_basis"] == "not measured" for r in rows)
    assert all(r["check_every"] in (None, 10) for r in rows)  # the default schedule, S = 10
    # what the user sees, for two arms: counts per upset, none's ratio 1, the others' null
    vis = [*cmd[:-1], "--no-time", "--visible", "3", "--window", "4", "--visible-defenses", "none", "checksum"]
    assert main([*vis, "--check-every", "2", "--json"]) == 0
    seen = {r["name"]: r for r in strict(capsys.readouterr().out)}
    assert seen["none"]["of_none"] in (1.0, None) and seen["guard"]["catastrophic_frames_per_upset"] is None
    assert seen["checksum"]["residue_frames_per_upset"] == 0
    assert seen["checksum"]["catastrophic_frames_per_upset"] <= seen["none"]["catastrophic_frames_per_upset"]
    assert seen["checksum"]["visible_basis"].startswith("measured: 3 upsets")
    # the table: one line per defense with the JSON's device bytes and exposure, whole at 80 columns
    assert main(["defenses", "--scene", "blocks", "--n", "300", "--no-time", "--check-every", "5"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for r in rows:
        line = next(x for x in lines if x.startswith(f"│ {r['name']} "))
        cells = [c.strip() for c in line.strip("│").split("│")]
        assert cells[1] == f"{r['device_bytes']:,}", line
        assert cells[3] == ("5" if dfn.get(r["name"]).checked else ""), line
        assert cells[6] == ("until reloaded" if r["name"] == "none" else "2 (4)" if cells[3] else "0 (0)"), line


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_checksum_and_parity4r_undo_every_single_and_adjacent_flip(real, precision):
    """Exhaustive over one primitive: every bit of every value, every burst of 2-4 bits: checksum
    reloads all of them; parity4r all those touching its covered bits (the rest: low mantissa)."""
    rows = stored_rows(real, precision)[[7]]
    nb = encoding.bits_per_value(precision)
    cover = codes.parity_cover_mask(precision)
    bad, covered = [], []
    for c in range(rows.shape[1]):
        for w in (1, 2, 3, 4):
            for lo in range(nb - w + 1):
                m = ((1 << w) - 1) << lo
                r = rows.copy()
                r[0, c] ^= r.dtype.type(m)
                bad.append(r[0])
                covered.append(bool(m & cover))
    bad = np.stack(bad)
    clean = np.repeat(rows, len(bad), axis=0)
    np.testing.assert_array_equal(dfn.read("checksum", clean, bad, precision, 3), clean)
    got = dfn.read("parity4r", clean, bad, precision, 3)
    covered = np.array(covered)
    np.testing.assert_array_equal(got[covered], clean[covered])
    np.testing.assert_array_equal(got[~covered], bad[~covered])


def test_the_memory_column_says_what_the_gpu_check_stores(real):
    """memory_overhead charges the packed encodings (1 or 4 parity bits, a 4-bit class, a 32-bit
    checksum per primitive), and the GPU check (faults/check.py) now uploads exactly that, packed
    (issue 39): its buffers are device_bytes, which the memory column of `seuwgpu defenses`
    reports; docs/defenses.md says so."""
    from pathlib import Path

    from seuwgpu.faults.check import Checker
    from seuwgpu.render.renderer import Renderer

    p, deg = "fp32", real.sh_degree
    rows = stored_rows(real, p)[:50]
    box = support_box(real, p)
    for d in CHECKED:
        side = dfn.side_data(d, rows, p, deg, box)
        assert side.dtype == np.uint32 and side.shape == (50,), d
    packed = {"parity": 1, "parity4": 4, "parity4r": 4, "scalebound": 4, "checksum": 32}
    bits = 59 * 32
    for d, b in packed.items():
        box_bits = 2 * 14 * 32 if d == "scalebound" else 0
        assert sd.memory_overhead(d, p, 3, 1000) == pytest.approx((b * 1000 + box_bits) / (1000 * bits))
        assert dfn.get(d).side_bits == b
    model = make_scene("blocks", n=333, seed=2)
    r = Renderer(model, scene_cameras("blocks", 1, 32, 32), p, chunk_prims=128)
    clean = stored_rows(model, p)
    mbox = support_box(model, p)
    guard_bytes = sd.device_bytes("guard", p, 3, model.n)
    assert guard_bytes == r.box_buf.size + r.guard_counts.size  # what the pipeline's guard reads
    for d in CHECKED:
        chk = Checker(r, d, clean, mbox)
        extra = guard_bytes if dfn.get(d).guard_fields else 0
        assert chk.device_bytes() + extra == sd.device_bytes(d, p, 3, model.n, r.layout.n_chunks), d
        # the side data: 333 codes of side_bits each, in whole 16-byte-aligned u32 words
        assert chk.side.size == max(16, -(-(-(-333 * dfn.get(d).side_bits // 32) * 4) // 16) * 16), d
    text = " ".join((Path(__file__).resolve().parents[1] / "docs" / "defenses.md").read_text().split())
    assert "uploads the side data packed as the memory column charges it" in text


@pytest.mark.parametrize("bits", [1, 2, 4, 8, 16, 32])
def test_each_side_data_packing_round_trips(bits):
    rng = np.random.default_rng(bits)
    for m in (0, 1, 31, 32, 33, 1000):
        codes = rng.integers(0, 1 << bits, m, dtype=np.uint64).astype(np.uint32)
        words = sd.pack_side(codes, bits)
        assert words.dtype == np.uint32 and words.size == -(-m * bits // 32)
        np.testing.assert_array_equal(sd.unpack_side(words, bits, m), codes)
    # by hand: four 4-bit codes in one word, the first in the low nibble
    assert sd.pack_side(np.array([1, 2, 3, 15], np.uint32), 4)[0] == 0xF321
    with pytest.raises(ValueError, match="does not fit in 4 bits"):
        sd.pack_side(np.array([16], np.uint32), 4)


def test_the_packed_side_data_of_every_checked_defense_round_trips(real):
    p = "fp16"
    rows = stored_rows(real, p)[:77]
    box = support_box(real, p)
    for d in CHECKED:
        side = dfn.side_data(d, rows, p, 3, box)
        bits = dfn.get(d).side_bits
        assert int(side.max()) < (1 << bits) if bits < 32 else True
        np.testing.assert_array_equal(sd.unpack_side(sd.pack_side(side, bits), bits, len(side)), side, err_msg=d)


def test_exposure_on_hand_made_upset_schedules():
    """Checks before frames 0, S, 2S, ...: an upset landing before frame f is drawn for
    (-f) mod S frames (counted by hand below)."""
    e = schedule.exposure(4, [0, 1, 2, 3, 4, 5, 9, 12])
    np.testing.assert_array_equal(e.per_upset, [0, 3, 2, 1, 0, 3, 3, 0])
    assert (e.expected, e.worst) == (1.5, 3.0)  # phases 0, 3, 2, 1 equally likely
    e1 = schedule.exposure(1, [0, 5, 7])
    np.testing.assert_array_equal(e1.per_upset, [0, 0, 0])
    assert (e1.expected, e1.worst) == (0.0, 0.0)
    e10 = schedule.exposure(10)
    assert (e10.expected, e10.worst) == (4.5, 9.0) and len(e10.per_upset) == 10
    never = schedule.exposure(0, [3])
    assert never.per_upset[0] == np.inf and never.expected == np.inf
    with pytest.raises(ValueError, match="every S >= 1 frames"):
        schedule.exposure(-1)


def test_the_measured_table_states_the_spec_and_seed_that_produced_it():
    """docs/defenses.md quoted leica-sofort's guard at 0.86% of dangerous-cell flips without the
    seed that drew its sites (a seed-0 rerun of its spec gave 0.43%); the page now holds the whole
    spec of its rerun, seed included, and that spec is one a campaign takes."""
    import re
    import tomllib
    from pathlib import Path

    from seuwgpu.campaign.spec import normalize_spec

    text = (Path(__file__).resolve().parents[1] / "docs" / "defenses.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, re.S)
    assert len(blocks) == 1
    raw = tomllib.loads(blocks[0])
    assert raw["seed"] == 0 and raw["single"]["samples"] == 300
    spec = normalize_spec(raw)
    assert [s.scene for s in spec.scenes] == ["leica-sofort", "yashica-t4"]
    flat = " ".join(text.split())  # the counts of its seed-0 rerun, as the page states them
    assert "Of 900 on leica-sofort / yashica-t4: none 600 / 685 catastrophic, guard 3 / 74" in flat


def test_guard_all_clamps_sh_rest_where_the_guard_does_not():
    """The paper's Algorithm 1 (guard_all) clamps every field: an sh_rest exponent flip renders
    as the model with that value clamped into its box (the guard's twin, clamp_bits); the guard,
    which skips sh_rest, draws the flip as it is."""
    from seuwgpu.faults.guard import clamp_bits, component_mask
    from seuwgpu.model.fields import FIELDS

    model = make_scene("blocks", n=300, seed=4)
    cams = scene_cameras("blocks", 2, 40, 40)
    eng = Engine(model, cams, "fp32", scene="blocks")
    victim = int(np.argmax(model.opacity))
    site = eng.site("sh_rest", victim, 0, 30)
    guarded, paper = eng.inject(site, "guard"), eng.inject(site, "guard_all")
    assert guarded["clamps"] == 0 and paper["clamps"] == 1
    assert guarded["footprint"] > 0
    rows = stored_rows(model, "fp32")
    bad = rows.copy()
    bad[victim, 14] ^= np.uint32(1 << 30)  # sh_rest component 0 is flat component 14
    fixed, _ = clamp_bits(bad, eng.box, component_mask(FIELDS, 3))
    want = Engine(Model.from_flat(encoding.from_bits(fixed, "fp32"), 3), cams, "fp32", gpu=eng.gpu).clean_rgba
    h = eng.apply([site], "guard_all")
    got, _ = eng.render_current("guard_all")
    eng.undo(h)
    np.testing.assert_array_equal(got, want)
    assert dfn.get("guard_all").guard_fields == FIELDS and "sh_rest" not in dfn.get("guard").guard_fields


def test_the_model_derived_tables_come_from_the_model_itself():
    """scalebound's class table and cellbox's boxes are computed from the model they protect,
    not from the embedded captures: on a model made here (log-scales shifted by +2 from a
    random one) the table spans that model's own log-scale range, every class bound holds its
    primitives and the class below would not, each primitive lies in its cell's box, and every
    defense is the identity on it."""
    from conftest import random_model

    made = random_model(500, seed=12)
    made = Model.from_flat(made.flat() + np.r_[np.zeros(3), 2 * np.ones(3), np.zeros(53)].astype(np.float32), 3)
    p = "fp32"
    rows = stored_rows(made, p)
    box = support_box(made, p)
    table = codes.scale_table(box, p)
    assert table[-1] == made.log_scales.max() and table[0] > made.log_scales.min()
    assert table.size == codes.SCALE_CLASSES and np.all(np.diff(table) >= 0)
    cls = dfn.get("scalebound").side_data(rows, p, 3, box).astype(np.int64)
    top = made.log_scales.max(axis=1)
    assert np.all(table[cls] >= top)
    assert np.all((cls == 0) | (table[np.maximum(cls - 1, 0)] < top))
    cells = dfn.get("cellbox").model_state(rows, p, 3)
    vals = made.flat()[:, cells.cols]
    assert np.all(vals >= cells.box_lo[cells.cell]) and np.all(vals <= cells.box_hi[cells.cell])
    prims = np.arange(made.n)
    for d in dfn.DEFENSES:
        np.testing.assert_array_equal(dfn.read(d, rows, rows, p, 3, box, prims, cells), rows, err_msg=d)


def test_reads_stored_bits_says_which_defenses_change_what_is_read(real):
    """`reads_stored_bits` (the viewer and the engine skip the twin for those) is true exactly for
    the defenses whose read leaves a log-scale sign flip as stored: none and the guards (they
    clamp later, in the pipeline); every other defense corrects, culls, reloads or clamps it."""
    p = "fp32"
    rows = stored_rows(real, p)[:40]
    box = support_box(real, p)
    cells = dfn.get("cellbox").model_state(stored_rows(real, p), p, 3)
    prims = np.arange(40)
    bad = rows.copy()
    bad[:, 3] ^= np.uint32(1 << 31)
    for d in dfn.DEFENSES:
        got = dfn.read(d, rows, bad, p, 3, box, prims, cells)
        assert np.array_equal(got, bad) == dfn.get(d).reads_stored_bits, d
        assert bool(dfn.get(d).guard_fields) <= dfn.get(d).reads_stored_bits or d == "scalebound", d


def test_the_guard_arm_is_the_guard_the_run_ran():
    """The none/guard comparisons of the report take the run's own guard: `guard` where it ran
    (the paper's; a run with guard and guard_all keeps it), else the other pipeline guard it ran
    in registry order (guard_all for a run that clamps every field); none without a guard."""
    from seuwgpu.faults.defenses import guard_arm, guard_arms

    assert guard_arm(["none", "guard", "parity4r"]) == "guard"
    assert guard_arm(["guard_all", "none", "guard"]) == "guard"
    assert guard_arm(["none", "guard_all", "parity4r"]) == "guard_all"
    assert guard_arm(["none", "parity4r"]) is None
    assert guard_arms(["parity4r", "guard_all", "none"]) == ("none", "guard_all")
    assert guard_arms(["guard"]) == ("guard",) and guard_arms(["parity4r"]) == ()
