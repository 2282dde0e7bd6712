"""Bad command-line arguments of every command: a clear one-line error naming the argument; a
valid oddity (a sign flip) gives the right result."""

from __future__ import annotations

import pytest

from robustness.checks import printed
from robustness.outcomes import expect_outcome, spec_text

BAD_RENDER = {
    "--n 0": ["--n", "0"],
    "--n -5": ["--n", "-5"],
    "--n abc": ["--n", "abc"],
    "--views 0": ["--views", "0"],
    "--size 0x0": ["--size", "0x0"],
    "--size 10x": ["--size", "10x"],
    "--scale 0": ["--scale", "0"],
    "--scale -1": ["--scale", "-1"],
    "--scale nan": ["--scale", "nan"],
    "--scale inf": ["--scale", "inf"],
    "--precision fp64": ["--precision", "fp64"],
    "--up q": ["--up", "q"],
    "--sh-degree 4": ["--sh-degree", "4"],
}
INJECT = ["inject", "--scene", "spheres", "--n", "60", "--views", "1", "--size", "16x16"]
BAD_INJECT = {
    "inject --sample 0": ["--field", "opacity", "--bit", "3", "--sample", "0"],
    "inject --primitive -1": ["--field", "opacity", "--bit", "3", "--primitive", "-1"],
    "inject --primitive 60": ["--field", "opacity", "--bit", "3", "--primitive", "60"],
    "inject --component 9": ["--field", "opacity", "--bit", "3", "--primitive", "1", "--component", "9"],
    "inject --bit 32": ["--field", "opacity", "--bit", "32", "--primitive", "1"],
    "inject --bit 16 at fp16": ["--field", "opacity", "--bit", "16", "--primitive", "1", "--precision", "fp16"],
    "inject --field nope": ["--field", "nope", "--bit", "3", "--primitive", "1"],
    "inject --defense nope": ["--field", "opacity", "--bit", "3", "--defense", "nope"],
}
SMALL = ["--scene", "spheres", "--n", "50", "--views", "1", "--size", "16x16"]
# other commands' bad arguments: {WORK} stands for the work folder, {FRESH} for a new path in it
# and {SPEC} for a tiny valid spec
BAD_OTHER = {
    "render --out under a file": ["render", "--n", "50", "--out", "{WORK}/file/x.npz"],
    "render --out in /proc": ["render", "--n", "50", "--out", "/proc/seuwgpu/x.npz"],
    "--shard 2/2": ["campaign", "{SPEC}", "--out", "{FRESH}", "--shard", "2/2"],
    "--shard 0/0": ["campaign", "{SPEC}", "--out", "{FRESH}", "--shard", "0/0"],
    "--shard x": ["campaign", "{SPEC}", "--out", "{FRESH}", "--shard", "x"],
    "--shard -1/2": ["campaign", "{SPEC}", "--out", "{FRESH}", "--shard=-1/2"],  # "-1/2" alone: an option
    "campaign --workers 0": ["campaign", "{SPEC}", "--out", "{FRESH}", "--workers", "0"],
    "campaign --out is a file": ["campaign", "{SPEC}", "--out", "{WORK}/file"],
    "campaign --out under a file": ["campaign", "{SPEC}", "--out", "{WORK}/file/run"],
    "campaign --out in /proc": ["campaign", "{SPEC}", "--out", "/proc/seuwgpu-run"],
    "report of a missing dir": ["report", "{WORK}/nope", "--out", "{FRESH}"],
    "report of an empty dir": ["report", "{WORK}/dir", "--out", "{FRESH}"],
    "rates of a missing dir": ["rates", "{WORK}/nope"],
    "rates of an empty dir": ["rates", "{WORK}/dir"],
    "rates --by typo": ["rates", "{WORK}/dir", "--by", "precison"],
    "scene without --out": ["scene", "spheres", "--n", "10"],
    "scene to .obj": ["scene", "spheres", "--n", "10", "--out", "{FRESH}.obj"],
    "plan --margin 2": ["plan", "{SPEC}", "--margin", "2"],
    "plan --confidence 0": ["plan", "{SPEC}", "--confidence", "0"],
    "distributed --ranks 0": ["distributed", "--n", "50", "--ranks", "0"],
    "distributed --upset bad": ["distributed", "--n", "50", "--upset", "nope"],
    "view --sample 0": ["view", "--n", "50", "--sample", "0"],
    "state --bit 32": ["state", *SMALL, "--bit", "32", "--out", "{FRESH}"],
    "state --bit -1": ["state", *SMALL, "--bit", "-1", "--out", "{FRESH}"],
    "worstcase --bit 32": ["worstcase", *SMALL, "--bit", "32", "--fields", "opacity"],
    "worstcase --bit 16 at fp16": ["worstcase", *SMALL, "--precision", "fp16", "--bit", "16", "--fields", "opacity"],
    "no command": [],
    "unknown command": ["frobnicate"],
}
# what the error must say where another error could stand in for the one due (an empty folder, no
# display, an argument read as an option)
NAMED = {"--shard -1/2": "0 <= I < N", "rates --by typo": "--by precison", "view --sample 0": "--sample"}
assert NAMED.keys() <= BAD_OTHER.keys()


@pytest.mark.parametrize("extra", list(BAD_RENDER.values()), ids=list(BAD_RENDER))
def test_a_bad_render_argument(fresh, extra):
    argv = ["render", "--scene", "spheres", "--n", "50", *extra, "--out", fresh("o", ".npz")]
    expect_outcome(argv, "error", stderr_has=f"argument {extra[0]}:")


def test_an_unknown_scene(fresh):
    expect_outcome(["render", "--scene", "nope", "--out", fresh("o", ".npz")], "error")


@pytest.mark.parametrize("name, extra", list(BAD_INJECT.items()), ids=list(BAD_INJECT))
def test_a_bad_inject_argument(fresh, name, extra):
    bad = name.split()[1].lstrip("-")  # "inject --bit 32": the error names the bit
    expect_outcome([*INJECT, *extra, "--out", fresh("inj")], "error", stderr_has=bad)


def test_inject_a_sign_flip(fresh):
    out = fresh("inj")

    def sign_flip(stdout):
        lines = printed(stdout)
        assert float(lines["corrupted_value"]) == -float(lines["clean_value"]), lines
        assert (out / "panel.png").is_file()

    argv = [*INJECT, "--field", "log_scales", "--primitive", "2", "--bit", "31", "--out", out]
    expect_outcome(argv, "ok", sign_flip)


@pytest.fixture(scope="module")
def tiny_spec(work):
    spec = work / "arguments.toml"
    spec.write_text(spec_text())
    return spec


@pytest.mark.parametrize("name, argv", list(BAD_OTHER.items()), ids=list(BAD_OTHER))
def test_a_bad_argument_of_another_command(fresh, work, tiny_spec, name, argv):
    def fill(a: str) -> str:
        return a.replace("{WORK}", str(work)).replace("{SPEC}", str(tiny_spec)).replace("{FRESH}", str(fresh("o")))

    expect_outcome([fill(a) for a in argv], "error", stderr_has=NAMED.get(name, ""))
