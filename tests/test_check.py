"""Check stage (faults/check.py, shaders/check.wgsl) against its twin defenses.detect, flag for
flag, at every precision and for every checked defense, on a model with many kinds of damage."""

import numpy as np
import pytest
from conftest import random_model

from seuwgpu.faults import codes
from seuwgpu.faults import defenses as dfn
from seuwgpu.faults.check import Checker
from seuwgpu.faults.guard import support_box
from seuwgpu.model import encoding
from seuwgpu.model.scenes import scene_cameras
from seuwgpu.render.renderer import Renderer

CHECKED = [d.name for d in dfn.REGISTRY.values() if d.checked]


@pytest.mark.parametrize("precision", encoding.PRECISIONS)
def test_gpu_checks_equal_the_twin(precision):
    model = random_model(301, seed=21)
    r = Renderer(model, scene_cameras("spheres", 1, 32, 32), precision, chunk_prims=128)
    clean = encoding.to_bits(model.flat(), precision)
    box = support_box(r.layout.decode(r.clean_words), precision)
    rng = np.random.default_rng(5)
    nb = encoding.bits_per_value(precision)
    bad = clean.copy()
    hit = rng.choice(model.n, 120, replace=False)
    for i, p in enumerate(hit):
        c = int(rng.integers(0, 14)) if i % 3 else int(rng.integers(3, 6))
        w = 1 + i % 4
        top = int(rng.integers(w - 1, nb))
        bad[p, c] ^= bad.dtype.type(((1 << w) - 1) << (top - w + 1))
    bad[hit[0], 20] ^= bad.dtype.type(1 << (nb - 2))  # sh_rest: the checksum and parity4r see it
    bad[hit[1], 4] = encoding.to_bits(np.float32([np.nan]), precision)[0]  # NaN log-scale: not scalebound's
    for c, words in enumerate(r.layout.encode_bits(bad)):
        r.gpu.write(r.chunks[c], words)
    for d in CHECKED:
        chk = Checker(r, d, clean, box)
        want = dfn.detect(d, dfn.side_data(d, clean, precision, 3, box), bad, precision, 3, box)
        count = chk.run()
        np.testing.assert_array_equal(chk.flags(), want, err_msg=d)
        assert count == want.sum() and 0 < count < model.n, (d, count)
    # clean model: nothing flagged
    for c, words in enumerate(r.layout.encode_bits(clean)):
        r.gpu.write(r.chunks[c], words)
    assert all(Checker(r, d, clean, box).run() == 0 for d in CHECKED)


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_gpu_detection_equals_a_brute_force_sweep_of_every_flip_and_burst(precision):
    """Every single flip and every burst of 2-4 adjacent bits of every value of two primitives of
    a tiny made model, one corrupted copy per row (as worstcase sweeps every flip): the GPU check
    flags exactly the rows its twin flags, the checksum every one, parity4r every one touching a
    covered bit, and scalebound exactly the rows whose log-scales rose above their class bound."""
    base = random_model(2, seed=8)
    clean2 = encoding.to_bits(base.flat(), precision)
    nb = encoding.bits_per_value(precision)
    src, bad = [], []
    for p in range(2):
        for c in range(clean2.shape[1]):
            for w in (1, 2, 3, 4):
                for lo in range(nb - w + 1):
                    row = clean2[p].copy()
                    row[c] ^= row.dtype.type(((1 << w) - 1) << lo)
                    src.append(p)
                    bad.append(row)
    src, bad = np.array(src), np.stack(bad)
    clean = clean2[src]
    model = type(base).from_flat(encoding.from_bits(clean, precision), 3)
    r = Renderer(model, scene_cameras("spheres", 1, 16, 16), precision)
    box = support_box(r.layout.decode(r.clean_words), precision)
    for c, words in enumerate(r.layout.encode_bits(bad)):
        r.gpu.write(r.chunks[c], words)
    cover = codes.parity_cover_mask(precision)
    touches = ((bad ^ clean).astype(np.uint64) & np.uint64(cover)).any(axis=1)
    for d in CHECKED:
        chk = Checker(r, d, clean, box)
        count = chk.run()
        got = chk.flags()
        want = dfn.detect(d, dfn.side_data(d, clean, precision, 3, box), bad, precision, 3, box)
        np.testing.assert_array_equal(got, want, err_msg=d)
        assert count == got.sum(), d
        if d == "checksum":
            assert got.all()
        if d == "parity4r":
            np.testing.assert_array_equal(got, touches)
        if d == "scalebound":
            bound = codes.scale_table(box, precision)[dfn.side_data(d, clean, precision, 3, box)]
            ls = encoding.from_bits(bad[:, 3:6], precision)
            with np.errstate(invalid="ignore"):
                np.testing.assert_array_equal(got, (ls > bound[:, None]).any(axis=1))


@pytest.mark.slow  # every defense timed as a schedule of 6 rounds: ~14 s on 2 shared cores
def test_defense_costs_times_what_runs_on_the_gpu():
    """The measured cost rows (faults/costs.py): a time for every defense with a pipeline clamp or
    a GPU check (measured as a schedule of check_every frames), NaN for the read-time codes, the
    device and model size named in the basis of each measured row, each time inside its interval."""
    from seuwgpu.faults.costs import defense_costs

    model = random_model(300, seed=3)
    camera = scene_cameras("spheres", 1, 32, 32)[0]
    rows = {r["name"]: r for r in defense_costs(model, camera, repeats=6, check_every=2)}
    assert list(rows) == list(dfn.DEFENSES) and rows["none"]["time_fraction"] == 0
    for name, row in rows.items():
        d = dfn.get(name)
        measured = bool(d.guard_fields) or d.checked or d.frame_check or name == "none"
        assert np.isfinite(row["time_fraction"]) == measured, name
        assert row["time_basis"].startswith("measured as a schedule: ") == measured, name
        if measured and name != "none":
            assert row["time_lo"] <= row["time_fraction"] <= row["time_hi"] and row["time_lo"] < row["time_hi"], name
        if d.checked:
            assert row["check_fraction"] > 0 and row["repair_fraction"] > 0 and row["check_every"] == 2, name
            assert "2 frame(s) and a check against 2" in row["time_basis"]
        else:
            assert np.isnan(row["check_fraction"]) and row["check_every"] is None, name
    assert f"{model.n} primitives" in rows["checksum"]["time_basis"]
    assert "checked in the projection" in rows["parity4f"]["time_basis"] and rows["parity4f"]["repair_fraction"] > 0


def test_a_schedule_is_timed_as_run_on_a_fake_clock():
    """schedule_time on a clock the calls advance: a frame takes 1.0, a check 0.5 and, in every
    other round, a repair 2.0 more. The measured fraction is what the rounds ran (0.05 or 0.25 at
    S = 10, median 0.15), not one check over S (0.05); the rounds alternate plain and checked, every
    other round in reverse order."""
    from seuwgpu.faults.costs import schedule_time

    now, calls, checks = [0.0], [], [0]

    def frame():
        now[0] += 1.0
        calls.append("f")

    def check():
        checks[0] += 1
        now[0] += 0.5 + (2.0 if checks[0] % 2 else 0.0)
        calls.append("c")

    res = schedule_time(frame, check, 10, 8, clock=lambda: now[0], warm_up=False)
    assert res["plain"] == [10.0] * 8
    assert res["checked"] == [12.5, 10.5] * 4
    assert res["fraction"] == pytest.approx([0.25, 0.05] * 4) and res["time"] == pytest.approx(0.15)
    assert (res["lo"], res["hi"]) == pytest.approx((0.05, 0.25))
    # plain round, checked round; then checked first, plain second (every other round reversed)
    assert "".join(calls) == ("f" * 10 + "c" + "f" * 10 + "c" + "f" * 10 + "f" * 10) * 4
    few = schedule_time(frame, check, 1, 3, clock=lambda: now[0], warm_up=False)
    assert np.isnan(few["lo"]) and np.isnan(few["hi"])  # 3 rounds: no 95% interval of a median
    with pytest.raises(ValueError, match="every S >= 1 frames"):
        schedule_time(frame, check, 0, 3)


def test_each_check_binds_its_own_shader_mode_by_name():
    from seuwgpu.gpu.device import get_gpu, shader_source
    from seuwgpu.gpu.kernel import Kernel, wgsl_constants

    kernel = Kernel(get_gpu(), "check")
    modes = {dfn.REGISTRY[d].check_mode for d in CHECKED}
    declared = {k for k in wgsl_constants(shader_source("check")) if k.startswith("MODE_")}
    assert modes == declared  # every mode used, no stray one
    assert len({kernel.const(m) for m in modes}) == len(modes)
    with pytest.raises(KeyError, match="no integer const 'MODE_PARTIY'"):
        kernel.const("MODE_PARTIY")


def test_an_upset_in_the_checkers_parameters_is_caught_and_the_check_rerun():
    """Every bit of chunk_count and cover flipped in the uniform buffer the shader reads (the
    host's copy intact): the seal mismatches, the host rewrites the parameters and checks again,
    so all 120 corrupted primitives are still found. The same flips re-sealed (what the checker
    without a seal saw) miss corrupted primitives or flag clean ones: the seal is what saves them."""
    from seuwgpu.faults.check import seal_words
    from seuwgpu.gpu.kernel import as_bytes

    model = random_model(300, seed=21)
    r = Renderer(model, scene_cameras("spheres", 1, 32, 32), "fp32")
    clean = encoding.to_bits(model.flat(), "fp32")
    bad = clean.copy()
    hit = np.random.default_rng(3).choice(model.n, 120, replace=False)
    bad[hit, 4] ^= np.uint32(1 << 30)
    for c, words in enumerate(r.layout.encode_bits(bad)):
        r.gpu.write(r.chunks[c], words)
    chk = Checker(r, "parity4r", clean)
    assert chk.run() == 120 and chk.param_faults == 0
    table = np.zeros(1, np.float32)
    wrong = 0
    for field in ("chunk_count", "cover"):
        for b in range(32):
            upset = chk.params.rows.copy()
            upset[field] ^= np.uint32(1 << b)
            r.gpu.write(chk.params.buffer, as_bytes(upset))
            before = chk.param_faults
            assert chk.run() == 120 and chk.param_faults == before + 1, (field, b)
            assert chk.run() == 120 and chk.param_faults == before + 1  # rewritten: clean again
            upset["seal"] = seal_words(upset, table)  # as if there were no seal
            r.gpu.write(chk.params.buffer, as_bytes(upset))
            chk.run()
            flags = chk.flags()
            wrong += not flags[hit].all() or flags.sum() != 120  # a miss or a false alarm
            chk.params.write()
    # at least chunk_count's 4 set bits (300 = 0b100101100: fewer primitives checked) and cover's 13
    # (bits 19..31 dropped from the parity)
    assert wrong >= 17
