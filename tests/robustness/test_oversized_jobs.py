"""Jobs too big for the host or the device: refused before any work with a clear one-line error,
except a frame over one storage binding, which is rendered in bands of tile rows."""

from __future__ import annotations

import pytest

from robustness.checks import npz_shape
from robustness.outcomes import expect_outcome, spec_text

HEAVY = [pytest.mark.heavy, pytest.mark.slow]
TWO_GB_HOST = {"SEUWGPU_HOST_MEMORY": str(2 * 10**9)}
STORM = ["storm", "--scene", "spheres", "--n", "50", "--size", "16x16"]
# {FRESH} stands for a new path in the work folder
TOO_BIG = {
    "--n 50000000": (["render", "--scene", "spheres", "--n", "50000000", "--out", "{FRESH}.npz"], None),
    "--n 9000000 (binding limit)": pytest.param(
        ["render", "--scene", "spheres", "--n", "9000000", "--views", "1", "--size", "16x16", "--out", "{FRESH}.npz"],
        {"SEUWGPU_HOST_MEMORY": str(10**12)},
        marks=HEAVY,  # makes the 9 M primitives first: a minute and gigabytes
    ),
    "storm --frames 1000000000": ([*STORM, "--out", "{FRESH}", "--k", "1", "--frames", "1000000000"], None),
    "storm --k 1000000000": ([*STORM, "--out", "{FRESH}", "--k", "1000000000", "--frames", "2"], None),
    "64 views of 2048x2048, 2 GB host": (
        ["render", "--n", "50", "--views", "64", "--size", "2048x2048", "--out", "{FRESH}.npz"],
        TWO_GB_HOST,
    ),
    "one view of 20000x20000, 2 GB host": (
        ["render", "--n", "50", "--views", "1", "--size", "20000x20000", "--out", "{FRESH}.npz"],
        TWO_GB_HOST,
    ),
    "--scale 16, 2 GB host": (
        ["render", "--n", "50", "--views", "1", "--size", "2048x2048", "--scale", "16", "--out", "{FRESH}.npz"],
        TWO_GB_HOST,
    ),
    "little host memory": (
        ["render", "--n", "100000", "--out", "{FRESH}.npz"],
        {"SEUWGPU_HOST_MEMORY": "100000000"},
    ),
}
TOO_BIG_SPECS = {
    "samples = 1000000000000": spec_text(single='[single]\nsamples = 1000000000000\ndefenses = ["none"]\n'),
    "samples = 10**15": spec_text(single='[single]\nsamples = 1000000000000000\ndefenses = ["none"]\n'),
    "spec n = 50000000": spec_text(scene='scene = "spheres"\nn = 50000000\n'),
    "sizes.n up to 60000000": spec_text(single="", extra="[sizes]\nn = [100, 60000000]\nsamples = 1\n"),
}


@pytest.mark.parametrize(
    "argv, env", [pytest.param(*c) if type(c) is tuple else c for c in TOO_BIG.values()], ids=list(TOO_BIG)
)
def test_a_job_too_big_is_refused(fresh, argv, env):
    expect_outcome([a.replace("{FRESH}", str(fresh("o"))) for a in argv], "error", env=env)


@pytest.mark.parametrize("text", list(TOO_BIG_SPECS.values()), ids=list(TOO_BIG_SPECS))
def test_a_campaign_too_big_is_refused(fresh, text):
    p = fresh("spec", ".toml")
    p.write_text(text)
    expect_outcome(["campaign", p, "--out", fresh("run"), "--quiet"], "error")


@pytest.mark.heavy
@pytest.mark.slow
def test_a_view_over_one_storage_binding_is_rendered_in_bands_of_tile_rows(fresh):
    """lavapipe's binding limit is 128 MiB (8.4 Mpx): 4096 x 2112 takes two bands."""
    out = fresh("o", ".npz")
    argv = ["render", "--n", "80", "--views", "1", "--size", "4096x2112", "--out", out]
    expect_outcome(argv, "ok", npz_shape(out, (1, 2112, 4096, 3)))
