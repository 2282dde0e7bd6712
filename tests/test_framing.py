"""Framing without cameras (model/framing.py): the robust region ignores a far shell and floaters,
and the orbit views of both real captures see the object whole, not filling the frame; the one
source of models and views (model/sources.py) and the campaign spec keys that use it."""

from __future__ import annotations

import numpy as np
import pytest

from seuwgpu.model.framing import bounding_region, orbit_basis
from seuwgpu.model.scenes import make_scene, scene_cameras


def project(cam, pts):
    p = pts @ cam.viewmat[:3, :3].T.astype(np.float64) + cam.viewmat[:3, 3]
    K = cam.K.astype(np.float64)
    return K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2], K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2], p[:, 2]


def test_region_ignores_a_far_shell_and_floaters():
    rng = np.random.default_rng(0)
    obj = rng.normal(size=(5000, 3)) * [0.05, 0.03, 0.04] + [1.0, 2.0, 3.0]
    shell = rng.normal(size=(1500, 3))
    shell = 240 * shell / np.linalg.norm(shell, axis=1, keepdims=True)  # 23% of the splats
    floaters = [1.0, 2.0, 3.0] + rng.uniform(-3, 3, (200, 3))
    clean = bounding_region(obj)
    wide = bounding_region(np.concatenate([obj, shell, floaters, [[np.nan, 0, 0], [np.inf, 1, 1]]]))
    np.testing.assert_allclose(wide.center, clean.center, atol=0.01)
    assert 0.08 < clean.radius < 0.2 and abs(wide.radius - clean.radius) < 0.25 * clean.radius
    # min/max would have been 1000x off
    assert np.ptp(np.concatenate([obj, shell]), axis=0).max() > 400


@pytest.mark.parametrize("up", ["+x", "-x", "+y", "-y", "+z", "-z"])
def test_orbit_basis_is_right_handed(up):
    e1, e2, u = orbit_basis(up)
    np.testing.assert_array_equal(np.cross(e1, e2), u)


def test_z_up_orbit_matches_the_registered_orbit_cameras():
    from seuwgpu.model.cameras import orbit_cameras

    # same angles, and the same eye formula as camera.orbit_cameras for z up
    e1, e2, u = orbit_basis("+z")
    assert (e1 == [1, 0, 0]).all() and (e2 == [0, 1, 0]).all()
    assert len(orbit_cameras(3, 32, 32)) == 3


@pytest.mark.parametrize("name", ["leica-sofort", "yashica-t4", "leica-sofort-wide", "yashica-t4-wide"])
def test_real_captures_are_framed_in_every_view(name):
    """Object visible, whole and not filling the frame, in every view, at any aspect ratio."""
    model = make_scene(name)
    core = make_scene(name.replace("-wide", "")).means.astype(np.float64)  # the object's splats
    for w, h in ((64, 64), (96, 48)):
        cams = scene_cameras(name, 4, w, h)
        assert len(cams) == 4
        for cam in cams:
            u, v, z = project(cam, core)
            assert (z > 0.01).all()
            inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
            assert inside.mean() > 0.97, (name, w, h)
            span_u = np.ptp(np.percentile(u, [2, 98]))
            span_v = np.ptp(np.percentile(v, [2, 98]))
            assert max(span_u / w, span_v / h) > 0.2, (name, w, h)  # not a dot
            assert span_u < w and span_v < h  # not cropped
    region = bounding_region(model.means)
    assert region.radius < 0.3  # the shell at radius 240 does not shrink the object


@pytest.mark.parametrize("name", ["leica-sofort", "yashica-t4"])
def test_real_capture_renders_show_the_object(name):
    from seuwgpu.render.renderer import Renderer

    model = make_scene(name)
    img = Renderer(model, scene_cameras(name, 4, 64, 64)).render()
    covered = (np.abs(img - 1.0) > 0.05).any(axis=-1)  # not the white background
    for k in range(4):
        assert 0.05 < covered[k].mean() < 0.9, (name, k, covered[k].mean())


def test_wide_variants_are_wider_and_spz_exact():
    from seuwgpu.model.formats.spz import spz_values

    base, wide = make_scene("leica-sofort"), make_scene("leica-sofort-wide")
    assert wide.n == base.n + 1536 + 256
    for f in ("means", "log_scales", "quats", "opacity", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(wide, f)[: base.n], getattr(base, f))
    assert wide.log_scales.max() > base.log_scales.max() + 5  # the far shell's large splats
    assert np.abs(wide.means).max() > 200
    again = spz_values(wide, 2)  # already what SPZ holds
    np.testing.assert_array_equal(again.log_scales, wide.log_scales)
    np.testing.assert_array_equal(again.means, wide.means)
    np.testing.assert_array_equal(make_scene("leica-sofort-wide").means, wide.means)  # deterministic


def test_capture_subsets_and_degrees():
    full = make_scene("yashica-t4")
    sub = make_scene("yashica-t4", n=1000, sh_degree=1, seed=3)
    assert sub.n == 1000 and sub.sh_degree == 1
    flat_full, flat_sub = full.flat()[:, : 14 + 9], sub.flat()  # degree 1: the first 3 SH coefficients
    j, idx = 0, []
    for row in flat_sub:  # each subset row appears in the full model, in the file's order
        while not np.array_equal(flat_full[j].view(np.uint32), row.view(np.uint32)):
            j += 1
        idx.append(j)
        j += 1
    assert len(idx) == 1000
    with pytest.raises(ValueError, match="8192 splats"):
        make_scene("yashica-t4", n=9000)


def test_sources_and_cli_arguments(tmp_path):
    from seuwgpu.apps.cli import main
    from seuwgpu.model.formats import save_model
    from seuwgpu.model.sources import load_source, source_views

    src = load_source("leica-sofort")
    assert src.up == "+y" and src.scene == "leica-sofort"
    views = source_views(src, views=3, size=(64, 48), scale=0.5)
    assert len(views) == 3 and (views[0].width, views[0].height) == (32, 24)
    save_model(make_scene("spheres", n=500), tmp_path / "s.ply", up="+z")
    src = load_source(path=tmp_path / "s.ply")
    assert src.up == "+z" and src.scene is None and src.name == "s"
    assert (
        main(
            [
                "render",
                "--ply",
                str(tmp_path / "s.ply"),
                "--views",
                "2",
                "--size",
                "32x24",
                "--out",
                str(tmp_path / "a.npz"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "render",
                "--model",
                str(tmp_path / "s.ply"),
                "--views",
                "2",
                "--size",
                "32x24",
                "--out",
                str(tmp_path / "b.npz"),
            ]
        )
        == 0
    )
    a, b = np.load(tmp_path / "a.npz")["images"], np.load(tmp_path / "b.npz")["images"]
    assert a.shape == (2, 24, 32, 3) and np.array_equal(a, b)
    assert main(["render", "--model", str(tmp_path / "missing.spz"), "--out", str(tmp_path / "c.npz")]) == 2


def test_spec_model_cameras_scale_and_capture_defaults(tmp_path):
    from seuwgpu.campaign.spec import SpecError, normalize_spec
    from seuwgpu.model.formats import save_model

    save_model(make_scene("spheres", n=200), tmp_path / "m.spz")
    base = {"single": {"samples": 1}}
    spec = normalize_spec({**base, "scenes": [{"ply": "m.spz"}], "scale": 0.5}, tmp_path)
    assert spec.scenes[0].model == str(tmp_path / "m.spz") and spec.scale == 0.5
    assert spec.size == (256, 256) and spec.views >= 4  # campaign defaults
    spec = normalize_spec({**base, "scenes": [{"scene": "yashica-t4", "up": "+y"}]})
    assert spec.scenes[0].n == 8192 and spec.scenes[0].up == "+y"
    for bad, frag in (
        ({"scenes": [{"scene": "leica-sofort", "n": 9000}]}, r"^scenes\[0\]\.n must be at most 8192, got 9000$"),
        ({"scenes": [{"scene": "spheres", "model": "m.spz"}]}, "exactly one"),
        ({"scenes": [{"scene": "spheres", "up": "up"}]}, "unknown up axis 'up'; expected one of"),
        ({"scenes": [{"scene": "spheres"}], "scale": 0}, "scale"),
        ({"scenes": [{"scene": "leica-sofort"}], "sizes": {"n": [100, 10000]}}, "8192"),
    ):
        with pytest.raises(SpecError, match=frag):
            normalize_spec({**base, **bad}, tmp_path)


@pytest.mark.slow
def test_inria_output_folder_to_report_in_one_command(tmp_path):
    """The README's path: an INRIA output folder (point_cloud/iteration_*/point_cloud.ply and
    cameras.json) to a campaign and its report with `seuwgpu demo`."""
    import json

    from seuwgpu.apps.cli import main
    from seuwgpu.model.formats.ply import save_ply

    run = tmp_path / "output" / "run"
    for it in (7000, 30000):
        (run / "point_cloud" / f"iteration_{it}").mkdir(parents=True)
    save_ply(make_scene("spheres", n=1500), run / "point_cloud" / "iteration_30000" / "point_cloud.ply")
    (run / "point_cloud" / "iteration_7000" / "point_cloud.ply").write_text("an older iteration, not read")
    cams = []
    for i, c in enumerate(scene_cameras("spheres", 5, 96, 64)):
        R, t = c.viewmat[:3, :3].astype(float), c.viewmat[:3, 3].astype(float)
        cams.append(
            {
                "id": i,
                "img_name": f"{i:05d}",
                "width": 96,
                "height": 64,
                "position": (-R.T @ t).tolist(),
                "rotation": R.T.tolist(),
                "fx": float(c.K[0, 0]),
                "fy": float(c.K[1, 1]),
            }
        )
    (run / "cameras.json").write_text(json.dumps(cams))
    out = tmp_path / "runs" / "mine"
    args = ["demo", "--model", str(run), "--cameras", str(run), "--views", "2", "--scale", "0.5"]
    assert main([*args, "--samples", "1", "--quiet", "--out", str(out)]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["spec"]["scenes"][0]["cameras"] == str(run) and manifest["spec"]["scale"] == 0.5
    assert (out / "report" / "index.html").is_file()
    # records name the capture after its output folder, not "point_cloud" (every INRIA output's
    # file name): two captures in one spec would otherwise be pooled as one scene
    import pandas as pd

    from seuwgpu.campaign import store

    scenes_of = {s for p in store.record_parts(out) for s in pd.read_parquet(p, columns=["scene"])["scene"]}
    assert scenes_of == {"run"}
    # a complete run is not flagged; with a part gone, the report and `rates` say it is unfinished
    assert json.loads((out / "report" / "summary.json").read_text())["partial"] is None
    done = sum(store.parse_part_name(p.name)[1] for p in store.record_parts(out))
    m = json.loads((out / "manifest.json").read_text())
    assert m["total_injections"] == done
    (out / "manifest.json").write_text(json.dumps(dict(m, total_injections=done + 96)))  # as if unfinished
    assert main(["report", str(out), "--out", str(tmp_path / "rep2")]) == 0
    note = json.loads((tmp_path / "rep2" / "summary.json").read_text())["partial"]
    assert note.startswith(f"Unfinished: mine holds {done:,} of {done + 96:,} injections")
    assert "Unfinished: mine holds" in (tmp_path / "rep2" / "index.html").read_text()
    other = tmp_path / "output" / "other"
    (other / "point_cloud" / "iteration_100").mkdir(parents=True)
    save_ply(make_scene("blocks", n=700), other / "point_cloud" / "iteration_100" / "point_cloud.ply")
    twin = tmp_path / "elsewhere" / "run"  # another capture in a folder of the same name
    (twin / "point_cloud" / "iteration_5").mkdir(parents=True)
    save_ply(make_scene("blocks", n=600), twin / "point_cloud" / "iteration_5" / "point_cloud.ply")
    from seuwgpu.campaign.spec import SpecError, normalize_spec

    def spec(*models):
        return {"scenes": [{"model": str(m)} for m in models], "single": {"samples": 1}}

    assert len(normalize_spec(spec(run, other, run)).scenes) == 3  # the same model twice is one scene
    with pytest.raises(SpecError, match="scenes\\[0\\] and scenes\\[1\\] are different models .* 'run'"):
        normalize_spec(spec(run, twin))


@pytest.mark.parametrize("same_point", [False, True], ids=["one primitive", "all at one point"])
def test_a_model_whose_means_span_no_volume_is_seen(tmp_path, same_point):
    """A model of one primitive (or of primitives all at one point) was framed from a distance of
    ~3e-3 of its distance to the origin, nearer than the renderer's near plane (0.01): every view
    was the empty white background, without a word. Its region now spans the primitives' own
    3-sigma extent, and the orbit views show the Gaussian."""
    import seuwgpu as sg
    from seuwgpu.model.formats import save_model

    m = make_scene("spheres", n=200, seed=1)
    if same_point:
        m.means[:] = m.means[7]
    else:
        m = m.subset(np.array([7]))
    save_model(m, tmp_path / "m.ply")
    scene = sg.load_model(tmp_path / "m.ply")
    img = sg.render_views(scene, sg.cameras(scene, views=2, size=(32, 32)))
    covered = (np.abs(img - 1.0) > 1 / 255).any(axis=-1).mean(axis=(1, 2))
    assert (covered > 0.05).all(), covered
    region = bounding_region(m.means, m.log_scales)
    extent = 3 * np.exp(m.log_scales.max(axis=1))
    assert region.radius == pytest.approx(np.percentile(extent, 98))
