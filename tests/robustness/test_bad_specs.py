"""`seuwgpu plan` on bad and valid campaign specs: each bad value ends in a clear one-line error,
each valid one in a plan."""

from __future__ import annotations

import pytest

from robustness.outcomes import SINGLE, expect_outcome, spec_text, table

BAD_TOP = {
    "seed": ["-1", "1.5", "true", '"x"', "18446744073709551616"],
    "views": ["0", "-3", "65", "1.5", "true", '"4"'],
    "size": ['"0x0"', '"15x16"', '"abc"', "[16]", "[16.5, 16]", '"16x16x16"', "5"],
    "scale": ["0", "-1", "17", "true", '"x"', "nan", "inf"],
    "batch": ["0", "65537", "1.5", "true"],
    "name": ["5", '""'],
    "bogus": ["1"],
}
GOOD_TOP = {"seed": ["5"], "views": ["3"], "size": ['"16x32"', "[32, 16]"], "scale": ["0.5"], "batch": ["1"]}
BAD_SCENE = [
    'scene = "nope"',
    "scene = 5",
    'scene = "spheres"\nn = 0',
    'scene = "spheres"\nn = -1',
    'scene = "spheres"\nn = 1.5',
    'scene = "spheres"\nn = true',
    'scene = "spheres"\nsh_degree = 4',
    'scene = "spheres"\nsh_degree = -1',
    'scene = "spheres"\nmodel = "good.ply"',
    'model = "good.ply"\nply = "good.ply"',
    'model = "good.ply"\nn = 50',
    "ply = 5",
    'model = "missing.ply"',
    'model = "dir"',
    'model = "."',
    'scene = "spheres"\ncameras = "missing.json"',
    'scene = "spheres"\ncameras = 5',
    'scene = "spheres"\nup = "q"',
    'scene = "spheres"\nup = 3',
    'scene = "spheres"\nseed = -1',
    'scene = "spheres"\nbogus = 1',
    "n = 5",
]
BAD_SINGLE = {
    "precisions": ['["fp64"]', "[]", '"fp32"', '["fp32", "fp32"]'],
    "fields": ['["nope"]', "[]", '["opacity", "opacity"]', '["log_scales", "log_scale"]', "5"],
    "bits": ["[32]", "[-1]", "[true]", '"some"', "[]"],
    "samples": ["0", "-1", "1.5", "{margin = 2}", "{margin = 0.1, bogus = 1}", "true"],
    "sampling": ['"bogus"', "5"],
    "defenses": ['["nope"]', '["none", "none"]', "[]", '"none"'],
    "regions": ["[1]", "[65]", "[true]", "5"],
    "bogus": ["1"],
}
GOOD_SINGLE = [
    '[single]\nfields = "all"\nbits = [0, 31]\nsamples = 1\n',
    '[single]\nsamples = {margin = 0.3}\nfields = ["opacity"]\nbits = [1]\n',
    '[single]\nfields = ["opacity"]\nbits = [30, 30]\nsamples = 1\n',
]
BAD_DOSE = [
    "k = []",
    "k = [0]",
    "k = [-1]",
    "k = [1.5]",
    "k = [true]",
    "k = [1]\nk_max = 10",
    "k_max = 0",
    "points = 0",
    "points = 201",
    "repeats = 0",
    'k = [1]\ndefenses = ["guard", "guard"]',
    "k = [100000000]",
    "bogus = 1",
]
BAD_SIZES = ["n = []", "n = [0]", "n = [1.5]", 'n = ["x"]', "n = [10]\nbogus = 1"]
CAMS = 'scene = "spheres"\ncameras = "cams.json"\n'  # the camera file's size rules: no size = its own


def cases():
    """(name, spec text, expected outcome) of every spec case."""
    for key, vals in BAD_TOP.items():
        for v in vals:
            yield f"{key} = {v}", spec_text(top={key: v}), "error"
    for key, vals in GOOD_TOP.items():
        for v in vals:
            yield f"{key} = {v}", spec_text(top={key: v}), "ok"
    for s in BAD_SCENE:
        yield s.replace("\n", "; "), spec_text(scene=s + "\n"), "error"
    for s in ('model = "good.ply"', 'ply = "good.spz"'):
        yield s, spec_text(scene=s + "\n"), "ok"
    yield "scene with cameras, no size", spec_text(top={"size": None}, scene=CAMS), "ok"
    yield "scene with cameras, and size (ignored: refused)", spec_text(scene=CAMS), "error"
    yield "no scenes", "views = 1\n" + table("single", SINGLE), "error"
    yield "scenes = 5", "scenes = 5\n" + table("single", SINGLE), "error"
    yield "no campaign table", spec_text(single=""), "error"
    for key, vals in BAD_SINGLE.items():
        for v in vals:
            yield f"single.{key} = {v}", spec_text(single=table("single", SINGLE, **{key: v})), "error"
    fp16 = '[single]\nprecisions = ["fp16"]\nbits = [16]\nsamples = 1\n'
    yield "single bit 16 at fp16", spec_text(single=fp16), "error"
    for t in GOOD_SINGLE:
        yield f"single ok: {t.splitlines()[1]}", spec_text(single=t), "ok"
    for d in BAD_DOSE:
        yield f"dose {d}".replace("\n", "; "), spec_text(single="", extra=f"[dose]\n{d}\n"), "error"
    yield "dose ok", spec_text(single="", extra="[dose]\nk = [1, 2, 2]\nrepeats = 1\n"), "ok"
    for z in BAD_SIZES:
        yield f"sizes {z}".replace("\n", "; "), spec_text(single="", extra=f"[sizes]\n{z}\n"), "error"
    # a model file is cut to seeded subsets (Model.sample), not above its count
    on_model = 'model = "good.ply"\n'
    yield "sizes on a model file", spec_text(scene=on_model, single="", extra="[sizes]\nn = [10]\n"), "ok"
    big = "[sizes]\nn = [10000000]\n"
    yield "sizes above a model file's count", spec_text(scene=on_model, single="", extra=big), "error"
    yield "not TOML", "[[scenes\n", "error"


CASES = list(cases())


@pytest.mark.parametrize("text, expect", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_plan_of_a_spec(fresh, text, expect):
    spec = fresh("spec", ".toml")  # in the work folder: its relative model and camera paths resolve there
    spec.write_text(text)

    def check(out):
        assert "total:" in out

    expect_outcome(["plan", spec], expect, check)


@pytest.mark.parametrize("path", ["dir", "nope.toml", "good.ply", "empty"])
def test_plan_of_a_file_that_is_no_spec(work, path):
    """A folder, a missing file, a binary file, an empty file."""
    expect_outcome(["plan", work / path], "error")
