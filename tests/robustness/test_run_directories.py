"""Campaign run directories: resumes (by another path, after a model changed, over damaged,
stray or deleted parts), another spec on the same folder, and merges of shards."""

from __future__ import annotations

import shutil

import pytest

from robustness.checks import records_equal, records_of
from robustness.outcomes import SINGLE, expect_outcome, spec_text, table
from seuwgpu.campaign import store


@pytest.fixture(scope="module")
def reference(work):
    """(spec, run): a run of 6 injections in batches of 2 (3 parts), uninterrupted."""
    spec = work / "rd.toml"
    spec.write_text(spec_text(top={"batch": "2"}, single=table("single", SINGLE, samples="6")))
    ref = work / "rd_ref"
    expect_outcome(["campaign", spec, "--out", ref, "--quiet"], "ok", records_of(ref, 6, "spheres"))
    return spec, ref


@pytest.fixture(scope="module")
def model_run(work):
    """A run on a model file (changing.ply, a copy of good.ply) and its spec."""
    mspec = work / "rd_model.toml"
    shutil.copy(work / "good.ply", work / "changing.ply")
    mspec.write_text(spec_text(scene='model = "changing.ply"\n'))
    run = work / "rd_model"
    expect_outcome(["campaign", mspec, "--out", run, "--quiet"], "ok")
    return mspec, run


def test_the_reference_run(reference):
    """Its 6 records (the fixture checks their count and metrics) are 6 injections, none twice:
    the runs below are compared with it."""
    r = store.read_records(reference[1])
    assert len(store.part_files(reference[1])) == 3
    assert len(set(zip(r["injection_id"], r["defense"]))) == len(r) == 6


def test_rates_by_a_column_named_twice(reference):
    def check(out):
        assert "│ spheres │" in out, out
        assert "dtype" not in out, out

    expect_outcome(["rates", reference[1], "--by", "scene,scene"], "ok", check)


def test_the_same_spec_by_another_path_resumes(reference, work):
    spec, ref = reference
    (work / "sub").mkdir(exist_ok=True)

    def check(out):
        assert "6 of 6 injections recorded (nothing new to run)" in out, out

    expect_outcome(["campaign", work / "sub" / ".." / spec.name, "--out", ref, "--quiet"], "ok", check)


def test_another_spec_on_the_same_out(reference, work):
    other = work / "rd_other.toml"
    other.write_text(spec_text(top={"seed": "9"}))
    expect_outcome(["campaign", other, "--out", reference[1], "--quiet"], "error")


def test_resume_after_the_model_changed(model_run, work):
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.scenes import make_scene

    mspec, run = model_run
    save_model(make_scene("spheres", n=80, seed=5), work / "changing.ply")
    try:
        expect_outcome(["campaign", mspec, "--out", run, "--quiet"], "error")
    finally:
        shutil.copy(work / "good.ply", work / "changing.ply")


def test_a_failed_validation_does_not_block_the_corrected_spec(reference, work):
    spec, ref = reference
    bad = work / "rd_bad.toml"
    (work / "bad.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n")
    bad.write_text(spec_text(scene='model = "bad.ply"\n'))
    fixed_out = work / "rd_fixed"
    expect_outcome(["campaign", bad, "--out", fixed_out, "--quiet"], "error")
    expect_outcome(["campaign", spec, "--out", fixed_out, "--quiet"], "ok", records_equal(fixed_out, ref))


DAMAGES = {
    "a 0-byte part": lambda d: store.part_files(d)[0].write_bytes(b""),
    "an unreadable part": lambda d: store.part_files(d)[0].write_bytes(b"PAR1xx"),
    "a stray part": lambda d: shutil.copy(store.part_files(d)[0], store.part_path(d, 999_999, 2)),
    "a deleted part": lambda d: store.part_files(d)[0].unlink(),
    "a part of another batch": lambda d: shutil.copy(store.part_files(d)[0], store.part_path(d, 0, 5)),
}


@pytest.mark.parametrize("damage", list(DAMAGES.values()), ids=list(DAMAGES))
def test_resume_over_a_damaged_run(reference, fresh, damage):
    spec, ref = reference
    d = fresh("rd_damaged")
    shutil.copytree(ref, d)
    damage(d)
    expect_outcome(["campaign", spec, "--out", d, "--quiet"], "ok", records_equal(d, ref))


def test_an_unreadable_manifest(reference, fresh):
    spec, ref = reference
    d = fresh("rd_manifest")
    shutil.copytree(ref, d)
    (d / "manifest.json").write_text("{not json")
    expect_outcome(["campaign", spec, "--out", d, "--quiet"], "error")


# ---- merges ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def shards(reference, work):
    spec = reference[0]
    runs = [work / f"rd_shard{i}" for i in range(3)]
    for i, s in enumerate(runs):
        expect_outcome(["campaign", spec, "--out", s, "--shard", f"{i}/3", "--quiet"], "ok")
    return runs


def test_merge_of_2_of_3_shards(shards, fresh):
    expect_outcome(["merge", *shards[:2], "--out", fresh("merged")], "error")


def test_merge_of_2_of_3_shards_allowed_partial(shards, fresh):
    partial = fresh("merged")

    def lists_missing(_out):
        m = store.read_manifest(partial)
        assert m["missing_parts"] and m["injections_recorded"] < m["total_injections"], m

    expect_outcome(["merge", *shards[:2], "--out", partial, "--allow-partial"], "ok", lists_missing)


def test_merge_of_all_shards(reference, shards, fresh):
    full = fresh("merged")
    expect_outcome(["merge", *shards, "--out", full], "ok", records_equal(full, reference[1]))


def test_merge_of_a_whole_run_beside_its_shards(reference, shards, fresh):
    """The parts of a whole run and of its shards: the same records, timed anew."""
    both = fresh("merged")
    expect_outcome(["merge", reference[1], *shards, "--out", both], "ok", records_equal(both, reference[1]))


def test_merge_whose_out_is_an_input(shards):
    expect_outcome(["merge", *shards, "--out", shards[0]], "error")


def test_merge_of_shards_of_two_specs(shards, model_run, fresh):
    expect_outcome(["merge", shards[0], model_run[1], "--out", fresh("merged")], "error")


def test_merge_into_a_run_of_another_spec(shards, model_run):
    expect_outcome(["merge", *shards, "--out", model_run[1]], "error")


@pytest.mark.parametrize("folder", ["dir", "nope"], ids=["a folder that is no run", "a missing folder"])
def test_merge_of_what_is_no_run(work, fresh, folder):
    expect_outcome(["merge", work / folder, "--out", fresh("merged")], "error")
