"""Models of different SH degrees in one run (a degree-0 model file beside an embedded scene at
degree 2): each report table that depends on a model's stored components counts its own (14
at degree 0, 38 at degree 2), by hand here."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seuwgpu.campaign.runner import Runner
from seuwgpu.campaign.spec import load_spec
from seuwgpu.campaign.store import read_records
from seuwgpu.model.formats import save_model
from seuwgpu.model.scenes import make_scene

N0, N2, SUB = 200, 150, 60  # the degree-0 file, the degree-2 scene, the [sizes] subset


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mixed")
    save_model(make_scene("spheres", n=N0, sh_degree=0, seed=5), tmp / "flat.ply")
    (tmp / "spec.toml").write_text(f"""
views = 1
size = "32x32"
[[scenes]]
model = "{tmp / "flat.ply"}"
[[scenes]]
scene = "spheres"
n = {N2}
sh_degree = 2
[single]
precisions = ["fp32"]
fields = ["opacity"]
bits = [30]
samples = 2
defenses = ["none", "guard", "parity"]
[sizes]
n = [{SUB}]
scenes = "all"
fields = ["opacity"]
bits = [30]
samples = 1
""")
    Runner(load_spec(tmp / "spec.toml"), tmp / "run", quiet=True).run()
    manifest = json.loads((tmp / "run" / "manifest.json").read_text())
    manifest["_run"] = "run"
    return read_records(tmp / "run"), [manifest], tmp / "flat.ply"


def test_scene_table_rows_are_their_own_models(run):
    """A [sizes] row of the embedded scene listed after a model file was re-made from that file
    (kind 'model file', SH degree 0, the file's boxes), and a model file's [sizes] row had the
    whole model's boxes, not those of the subset the campaign ran."""
    from seuwgpu.analysis.scenes import scene_table
    from seuwgpu.faults.guard import support_box
    from seuwgpu.model.formats import read_model

    df, manifests, path = run
    t = scene_table(df, manifests)[0].set_index(["scene", "primitives"])
    assert t.loc[("spheres", SUB), "kind"] == "embedded" and t.loc[("spheres", SUB), "sh_degree"] == 2
    assert t.loc[("flat", SUB), "sh_degree"] == 0 and np.isnan(t.loc[("flat", SUB), "box_sh_rest"])
    sub = read_model(path).model.sample(SUB, 0, "flat")
    box = support_box(sub, "fp32")
    width = np.asarray(box.hi, float) - np.asarray(box.lo, float)
    assert t.loc[("flat", SUB), "box_means"] == pytest.approx(float(width[:3].max()))  # means: components 0-2


def test_defense_overheads_count_each_models_stored_bits(run):
    """defense_table counted a degree-0 model at degree 3 (59 components): guard 0.0475% of a
    1,000-primitive model instead of 0.2%; the mitigation table pooled two models at the first
    one's degree (guard 0.2% where their stored bits give 0.108%)."""
    from seuwgpu.analysis.defenses import defense_table
    from seuwgpu.analysis.mitigation import mitigation_table

    df, manifests, _ = run
    t = defense_table(df, manifests=manifests).set_index(["scene", "defense"])["memory_overhead_pct"]
    box = 2 * 14 * 32  # the guard's box: two fp32 bounds of the 14 components it guards
    assert t[("flat", "guard")] == pytest.approx(100 * box / (N0 * 14 * 32))
    assert t[("spheres", "guard")] == pytest.approx(100 * box / (N2 * 38 * 32))
    assert t[("flat", "parity")] == pytest.approx(100 / (14 * 32))
    assert t[("spheres", "parity")] == pytest.approx(100 / (38 * 32))
    m = mitigation_table(df, manifests).set_index("defense")["memory_overhead_pct"]
    stored = (N0 * 14 + N2 * 38) * 32
    assert m["guard"] == pytest.approx(100 * 2 * box / stored)
    assert m["parity"] == pytest.approx(100 * (N0 + N2) / stored)
