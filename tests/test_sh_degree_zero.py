"""Models without higher-order SH (degree 0: every .splat file, many SPZ and SOG files): a
campaign over "all" fields samples the fields the model holds, its runs record the model's own
degree, and reliability counts its stored bits (14 components, not 59). Both a model file and an
embedded scene at sh_degree = 0 ended in an IndexError on their first block before (sh_rest cells
of zero components)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seuwgpu.analysis import reliability
from seuwgpu.campaign.runner import Runner
from seuwgpu.campaign.sampling import enumerate_contexts
from seuwgpu.campaign.spec import SpecError, load_spec
from seuwgpu.campaign.store import read_records
from seuwgpu.model.formats import save_model
from seuwgpu.model.scenes import make_scene

N = 300


def spec_text(scene: str, single: str = 'fields = "all"') -> str:
    return f"""
name = "d0"
views = 1
size = "32x32"
[[scenes]]
{scene}
[single]
precisions = ["fp32"]
bits = [30, 31]
samples = 2
defenses = ["none"]
{single}
"""


@pytest.fixture(scope="module")
def degree0_model(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("d0")
    path = tmp / "flat.ply"
    save_model(make_scene("spheres", n=N, sh_degree=0), path)
    return path


def write(tmp_path, text):
    p = tmp_path / "spec.toml"
    p.write_text(text)
    return p


def test_a_spec_records_a_model_files_own_sh_degree(tmp_path, degree0_model):
    spec = load_spec(write(tmp_path, spec_text(f'model = "{degree0_model}"')))
    assert spec.scenes[0].sh_degree == 0
    fields = {f for c in enumerate_contexts(spec) for f, _ in c.cells}
    assert fields == {"means", "log_scales", "quats", "opacity", "sh_dc"}
    # a spec's sh_degree that is the file's is accepted; another is refused, not ignored
    load_spec(write(tmp_path, spec_text(f'model = "{degree0_model}"\nsh_degree = 0')))
    with pytest.raises(SpecError, match="holds SH degree 0"):
        load_spec(write(tmp_path, spec_text(f'model = "{degree0_model}"\nsh_degree = 3')))
    # sh_rest named for a model that holds none is refused; "all" is each model's own fields
    with pytest.raises(SpecError, match="lists sh_rest, which scenes\\[0\\] \\(SH degree 0\\)"):
        load_spec(write(tmp_path, spec_text(f'model = "{degree0_model}"', 'fields = ["means", "sh_rest"]')))


@pytest.mark.parametrize("kind", ["model file", "embedded scene"])
def test_a_degree_0_campaign_runs_and_counts_its_own_stored_bits(tmp_path, degree0_model, kind):
    scene = f'model = "{degree0_model}"' if kind == "model file" else f'scene = "spheres"\nn = {N}\nsh_degree = 0'
    spec = load_spec(write(tmp_path, spec_text(scene)))
    Runner(spec, tmp_path / "run", quiet=True).run()
    df = read_records(tmp_path / "run")
    assert len(df) == 5 * 2 * 2 and "sh_rest" not in set(df["field"])
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    res = reliability.reliability(df, [manifest])
    stored = N * 14 * 32  # 14 components at degree 0, 32 bits each
    assert res["bits"] == stored
    # the records' weights stand for the bits of the cells they sample: two of 32 bits here
    assert float(df["weight"].sum()) == pytest.approx(stored * 2 / 32)
    pc = res["pc"].iloc[0]
    assert pc["sh_degree"] == 0 and pc["coverage_pct"] == pytest.approx(100 * 2 / 32)
    want = float(np.average(df["catastrophic"], weights=df["weight"]))
    assert pc["p_c"] == pytest.approx(want)


def test_sh_rest_named_for_a_degree_0_model_is_one_clear_line(tmp_path, capsys):
    """inject (and every site: distributed, the viewer) said 'component 0 is out of range for
    field sh_rest (valid 0..-1)' for a model without higher-order SH."""
    from seuwgpu.apps.cli import main
    from seuwgpu.faults.sites import make_site

    with pytest.raises(ValueError, match=r"field sh_rest is not stored in this model: .*\(SH degree 0\)"):
        make_site(N, "sh_rest", 0, 0, 30, "fp32", degree=0)
    assert make_site(N, "sh_rest", 0, 8, 30, "fp32", degree=1).component == 8
    with pytest.raises(ValueError, match=r"component 9 is out of range for field sh_rest \(valid 0..8\)"):
        make_site(N, "sh_rest", 0, 9, 30, "fp32", degree=1)
    scene = ["--scene", "spheres", "--n", "40", "--sh-degree", "0", "--size", "16x16", "--views", "1"]
    assert main(["inject", *scene, "--field", "sh_rest", "--bit", "30", "--out", str(tmp_path / "i")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "field sh_rest is not stored in this model" in err[0] and "0..-1" not in err[0]


def test_worstcase_searches_the_fields_a_degree_0_model_stores(capsys):
    """`worstcase --fields sh_rest` on a degree-0 model searched nothing and printed 'worst flip
    none: footprint 0.0000% (certified bound -100.0000%), 0 of 0 flips rendered' with exit 0."""
    from seuwgpu.apps.cli import main

    scene = ["worstcase", "--scene", "blocks", "--n", "20", "--size", "16x16", "--views", "1", "--bit", "30"]
    assert main([*scene, "--sh-degree", "0", "--fields", "sh_rest"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "field sh_rest is not stored in this model" in err[0]
    assert main([*scene, "--sh-degree", "0", "--fields", "means", "sh_rest"]) == 2
    capsys.readouterr()
    assert main([*scene, "--sh-degree", "0", "--max-evaluations", "1"]) == 0  # default: the 14 components it stores
    assert "of 280 flips rendered" in capsys.readouterr().out
    assert main([*scene, "--sh-degree", "1", "--fields", "sh_rest", "--max-evaluations", "1"]) == 0
    assert "of 180 flips rendered" in capsys.readouterr().out  # 9 components at degree 1
